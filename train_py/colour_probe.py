"""Where a model loses colour: how much of the diffuse chromaticity each U-Net stage still carries.

    python -m train_py.colour_probe --model models/default.safetensors [--materials 16 --size 64]

On held-out procedural materials, the chromaticity of the diffuse albedo (``ρ / (ρ_r + ρ_g + ρ_b)``)
is regressed per pixel on each stage's features: least squares on the features, their squares and
a constant, with the target average-pooled to the stage's resolution. R² near 1: the stage can
still tell a red material from a grey one; near 0: colour is gone, and no later layer can bring it
back (the render MLP only sees the params). A model that relights every material grey shows
where in ``M_est`` that happens.
"""

from __future__ import annotations

import argparse

import torch
import torch.nn.functional as F

from . import gen, ggx
from .export import load_model
from .model import NamModel

#: Keeps the chromaticity of a black albedo finite.
ALBEDO_EPS = 1e-3
#: First held-out seed probed (the evaluation set's seeds, gen.HELD_OUT_SEED_BASE + 2000.., are
#: not reused, so the probe does not select on the reported numbers).
PROBE_SEED = gen.HELD_OUT_SEED_BASE + 5000


def stage_features(model: NamModel, net_input: torch.Tensor) -> list[tuple[str, torch.Tensor]]:
    """``(name, [B, C, h, w])`` after every stage of ``M_est``, input first, params last."""
    u = model.est
    out = [("input", net_input)]
    x = u.stem(net_input)
    out.append(("stem", x))
    skips = []
    for k in range(1, 5):
        x = getattr(u, f"enc{k}")(x)
        skips.append(x)
        out.append((f"enc{k}", x))
    x = u.dec1(torch.atan(x))
    out.append(("dec1", x))
    for k, skip in zip((2, 3, 4), reversed(skips[:3]), strict=True):
        x = getattr(u, f"dec{k}")(torch.cat([x, skip], dim=1))
        out.append((f"dec{k}", x))
    out.append(("head (params)", u.head(u.head_input(x, net_input))))
    return out


def probe_r2(features: torch.Tensor, chroma: torch.Tensor) -> float:
    """R² of the quadratic least-squares fit of ``chroma`` [B, 3, H, W] from ``features``."""
    target = F.adaptive_avg_pool2d(chroma, features.shape[-2:]) if features.shape[-1] != chroma.shape[-1] else chroma
    x = features.permute(0, 2, 3, 1).reshape(-1, features.shape[1]).double()
    y = target.permute(0, 2, 3, 1).reshape(-1, 3).double()
    design = torch.cat([x, x.square(), torch.ones(x.shape[0], 1, dtype=x.dtype)], dim=1)
    solution = torch.linalg.lstsq(design, y).solution
    residual = y - design @ solution
    return float(1.0 - residual.var(dim=0).sum() / y.var(dim=0).sum())


def colour_probe(model: NamModel, materials: int, size: int) -> list[tuple[str, int, float]]:
    """``(stage, channels, R²)`` for every stage, on ``materials`` held-out captures of ``size``²."""
    maps = gen.batch([PROBE_SEED + i for i in range(materials)], size, "cpu")
    photo = ggx.ldr_capture(ggx.render_capture(maps))
    diffuse = maps["diffuse"]
    chroma = (diffuse / (diffuse.sum(-1, keepdim=True) + ALBEDO_EPS)).permute(0, 3, 1, 2)
    with torch.no_grad():
        stages = stage_features(model, ggx.network_input(photo, model.config.log_mode))
    return [(name, f.shape[1], probe_r2(f, chroma)) for name, f in stages]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="models/default.safetensors")
    ap.add_argument("--materials", type=int, default=16)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    model = load_model(args.model)
    print(f"| stage | channels | R² of diffuse chromaticity ({args.materials} materials, {args.size}²) |")
    print("|---|---:|---:|")
    for name, channels, r2 in colour_probe(model, args.materials, args.size):
        print(f"| {name} | {channels} | {r2:.3f} |")


if __name__ == "__main__":
    main()
