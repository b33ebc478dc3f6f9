"""Stage 1 of the staged recipe: pretrain the decoder (``ND_enc`` + ``M_render``) on GGX renders.

    python -m train_py.pretrain --minutes 30 --out runs/decoder [--resume] [--bf16] [--threads 2]

A small per-pixel encoder ``E`` (GGX maps → 64-d latent, :class:`MapEncoder`) feeds the shipped
decoder, which must reproduce GGX radiance for random per-pixel maps and random light/view
directions, half of them near the mirror direction where the highlight lives. This is cheap
per-pixel work (no U-Net, no images) that teaches the decoder sharp, moving highlights; stage 2
(``train --decoder runs/decoder/ckpt.pt --latent-weight w``) then trains ``M_est`` to predict
``E(maps)`` densely. Not in the paper (which trains end to end only); kept only if it wins an A/B
at equal wall-clock time (train_py/README.md).

    python -m train_py.pretrain --from-model models/default.safetensors --out runs/enc ...

fits ``E`` alone to a trained model's frozen decoder instead, so that ``train --decoder
--latent-weight`` regresses a fine-tune of that model towards latents its own decoder renders.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from safetensors.torch import load_file, save_file
from torch import nn

from . import capture, ggx, materials, protocols
from . import gen as procedural
from .model import PARAM_CHANNELS, NDEnc, RenderMLP, init_linear, positional_encoding, query_dirs

#: Inputs of ``E``: diffuse (3), specular (3), roughness, ln roughness, normal (3).
MAP_FEATURES = 11
#: Hidden width of ``E``.
ENCODER_HIDDEN = 128
#: Share of queries whose light lies near the mirror direction of the view about the normal.
MIRROR_FRAC = 0.5
#: Largest tilt of a sampled shading normal from +z (radians).
MAX_TILT = 1.2
#: Smallest sampled roughness (α = 9e-4): sharper lobes than the glossiest real material sets.
ROUGHNESS_MIN = 0.03


class MapEncoder(nn.Module):
    """``E``: per-pixel GGX maps → the 64-d latent the decoder reads (stage-1 and -2 target)."""

    def __init__(self):
        super().__init__()
        self.l0 = nn.Linear(MAP_FEATURES, ENCODER_HIDDEN)
        self.l1 = nn.Linear(ENCODER_HIDDEN, ENCODER_HIDDEN)
        self.l2 = nn.Linear(ENCODER_HIDDEN, PARAM_CHANNELS)
        init_linear(self.l0, self.l1, self.l2)

    def forward(self, maps: dict[str, torch.Tensor]) -> torch.Tensor:
        """``maps`` channel-last ``[..., C]`` (roughness ``[...]``) → latent ``[..., 64]``."""
        r = maps["roughness"].clamp(min=0.01)[..., None]
        x = torch.cat([maps["diffuse"], maps["specular"], r, torch.log(r), maps["normal"]], dim=-1)
        x = F.leaky_relu(self.l0(x), 0.01)
        x = F.leaky_relu(self.l1(x), 0.01)
        return self.l2(x)


class Decoder(nn.Module):
    """``E`` + ``ND_enc`` + ``M_render`` with the model's module names (``nd_enc.*``, ``render.*``)."""

    def __init__(self):
        super().__init__()
        self.enc = MapEncoder()
        self.nd_enc = NDEnc()
        self.render = RenderMLP()

    def forward(self, maps: dict[str, torch.Tensor], dirs: torch.Tensor, straight_through: bool = True):
        return self.decode(self.enc(maps), dirs, straight_through)

    def decode(self, latent: torch.Tensor, dirs: torch.Tensor, straight_through: bool = True) -> torch.Tensor:
        """Log radiance ``[N, 3]`` of latents ``[N, 64]`` for query directions ``[N, 9]``."""
        nd = self.nd_enc(positional_encoding(dirs))
        return self.render(torch.cat([latent, nd], dim=-1), straight_through)


def random_maps(gen: torch.Generator, n: int) -> dict[str, torch.Tensor]:
    """``n`` random per-pixel GGX parameter sets: dielectrics (grey F0 0.02–0.08) and metals
    (coloured F0, dark diffuse), roughness log-uniform in [``ROUGHNESS_MIN``, 1], normals tilted up to
    ``MAX_TILT`` (half-normal, σ 0.35 rad)."""
    u = lambda *s: torch.rand(*s, generator=gen)  # noqa: E731
    grey = u(n, 1) ** 2.2
    diffuse = (grey * (0.5 + u(n, 3))).clamp(0, 1)
    metal = u(n, 1) < 0.25
    metal_f0 = (0.3 + 0.7 * u(n, 1)) * (0.7 + 0.3 * u(n, 3))
    specular = torch.where(metal, metal_f0, 0.02 + 0.06 * u(n, 1).expand(n, 3))
    diffuse = torch.where(metal, diffuse * 0.05, diffuse)
    roughness = torch.exp(math.log(ROUGHNESS_MIN) * (1 - u(n)))
    tilt = (0.35 * torch.randn(n, generator=gen)).abs().clamp(max=MAX_TILT)
    phi = 2 * math.pi * u(n)
    normal = torch.stack([tilt.sin() * phi.cos(), tilt.sin() * phi.sin(), tilt.cos()], dim=-1)
    return {"diffuse": diffuse, "specular": specular, "roughness": roughness, "normal": normal}


def random_directions(gen: torch.Generator, maps: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit ``(wi, wo)`` ``[n, 3]`` in the surface frame (z up): ``wo`` uniform over the upper
    hemisphere; ``wi`` uniform too, or (share ``MIRROR_FRAC``) the mirror of ``wo`` about the shading
    normal, perturbed by ~2α so the queries cover the highlight lobe and its flanks."""
    n = maps["roughness"].shape[0]
    wo = protocols.uniform_hemisphere(gen, (n,))
    normal = maps["normal"]
    mirror = 2 * ggx.dot(wo, normal)[:, None] * normal - wo
    alpha = maps["roughness"].clamp(min=0.01) ** 2
    jitter = torch.randn(n, 3, generator=gen) * (2 * alpha + 0.02)[:, None]
    near = ggx.normalize(mirror + jitter)
    near = torch.cat([near[:, :2], near[:, 2:].abs()], dim=-1)
    use_mirror = torch.rand(n, 1, generator=gen) < MIRROR_FRAC
    wi = torch.where(use_mirror, near, protocols.uniform_hemisphere(gen, (n,)))
    return ggx.normalize(wi), wo


def queries(gen: torch.Generator, n: int):
    """A batch: maps, query directions ``[n, 9]`` and GGX log radiance ``[n, 3]``."""
    maps = random_maps(gen, n)
    wi, wo = random_directions(gen, maps)
    radiance = ggx.ggx_radiance(maps["diffuse"], maps["specular"], maps["roughness"], maps["normal"], wi, wo)
    return maps, query_dirs(wi, wo), ggx.to_log(radiance)


#: ``--queries scenes``: materials per step, their crop side (px) and the share of each step's
#: exemplars drawn as the Hemisphere protocol draws them (the rest Reflect, half of those moved light).
SCENE_MATERIALS = 8
SCENE_SIZE = 64
SCENE_HEMISPHERE = 0.5


class SceneQueries:
    """Queries as the model meets them: pixels of training materials (real sets from ``bank``
    and procedural ones, half their normals flattened, as the shipped recipe draws them) relit from
    light and view positions above a 64² crop (Reflect, moved light, Hemisphere), not random
    per-pixel maps and directions. Callable like :func:`queries`.

    With a ``model``, each material is photographed as in training (phone-like captures) and
    :attr:`anchor` holds the model's own params ``[n, 64]`` at the drawn pixels: what ``pretrain
    --anchor`` keeps ``E`` close to, so that its latents are ones the model's U-Net already makes."""

    def __init__(self, bank: materials.MaterialBank | None, exemplars: int = 4, model=None):
        from .train import DataMix

        self.bank = bank
        phone = 1.0 if model is not None else 0.0
        self.mix = DataMix(real_frac=0.5 if bank is not None else 0.0, phone=phone, flat_normal_frac=0.5)
        self.exemplars = exemplars
        self.model = model
        self.anchor: torch.Tensor | None = None

    def __call__(self, gen: torch.Generator, n: int):
        from .train import draw_batch, draw_maps, draw_seeds_and_size

        seeds, size = draw_seeds_and_size(gen, SCENE_MATERIALS, [], SCENE_SIZE)
        params = None
        if self.model is None:
            maps = draw_maps(seeds, size, self.bank, self.mix, procedural.Rng(seeds[0] * 31 + 7))
        else:
            maps, net_input, _ = draw_batch(seeds, size, "cpu", self.bank, self.mix)
            with torch.no_grad():
                params = self.model.estimate(net_input).float()
        light, view = protocols.reflect(gen, 1, self.exemplars)
        light, view = protocols.mix_moved_light(gen, light, view, 0.5, capture.Capture().camera())
        light, view = protocols.mix_hemisphere(gen, light, view, SCENE_HEMISPHERE)
        radiance = ggx.render_maps(maps, light, view)  # [B, K, H, W, 3]
        wi, wo, _ = ggx.directions(light, view, size, size)  # [1, K, H, W, 3]
        b, k = radiance.shape[:2]
        pick = torch.randint(0, b * k * size * size, (n,), generator=gen)
        material = pick // (k * size * size)
        exemplar_pixel = pick % (k * size * size)
        pixel = exemplar_pixel % (size * size)
        picked = {key: v.reshape(b, size * size, *v.shape[3:])[material, pixel] for key, v in maps.items()}
        dirs = query_dirs(wi.reshape(-1, 3)[exemplar_pixel], wo.reshape(-1, 3)[exemplar_pixel])
        if params is not None:
            self.anchor = params.permute(0, 2, 3, 1).reshape(b, size * size, -1)[material, pixel]
        return picked, dirs, ggx.to_log(radiance.reshape(-1, 3)[pick])


def held_out(n: int = 16384, seed: int = 777, source=None):
    """Fixed validation queries (from ``source``, default :func:`queries`), and the log-L1 of a
    render of the true maps without its specular term (what a perfect diffuse fit would score)."""
    gen = torch.Generator().manual_seed(seed)
    maps, dirs, target = (source or queries)(gen, n)
    wi, wo = dirs[:, 0:3], dirs[:, 3:6]
    n_dot_l, n_dot_v = ggx.dot(maps["normal"], wi), ggx.dot(maps["normal"], wo)
    visible = ((n_dot_l > 0) & (n_dot_v > 0))[:, None]
    diffuse_only = maps["diffuse"] * n_dot_l.clamp(min=0)[:, None] * visible
    base = (ggx.to_log(diffuse_only) - target).abs().mean()
    return maps, dirs, target, float(base)


def evaluate(decoder: Decoder, val) -> dict[str, float]:
    maps, dirs, target, base = val
    with torch.no_grad():
        pred = torch.cat(
            [
                decoder({k: v[i : i + 4096] for k, v in maps.items()}, dirs[i : i + 4096], False)
                for i in range(0, dirs.shape[0], 4096)
            ]
        )
    err = (pred - target).abs().mean(-1)
    # Highlight queries: the specular term is at least half the radiance.
    wi = dirs[:, 0:3]
    diffuse_part = ggx.to_log(maps["diffuse"] * wi[:, 2:3].clamp(min=0)).mean(-1)
    highlight = target.mean(-1) > diffuse_part + math.log(2)
    return {"log_l1": float(err.mean()), "highlight_log_l1": float(err[highlight].mean()), "diffuse_only": base}


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30, help="wall-clock budget")
    ap.add_argument("--cpu-minutes", type=float, default=None, help="CPU-time budget instead (all threads)")
    ap.add_argument("--out", default="runs/decoder")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--batch", type=int, default=8192, help="queries per step")
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--lr-final", type=float, default=5e-5)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--bf16", action="store_true", help="bfloat16 autocast (fast with AMX / AVX-512 BF16)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--val-every", type=int, default=250)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument(
        "--queries",
        choices=["random", "scenes"],
        default="random",
        help="random per-pixel maps and directions, or pixels of training materials relit from "
        "positions above them (SceneQueries)",
    )
    ap.add_argument("--materials-root", default=str(materials.DEFAULT_ROOT), help="folder holding train/")
    ap.add_argument(
        "--anchor",
        type=float,
        default=0.0,
        help="with --from-model and --queries scenes: weight of an L1 between E(maps) and the model's "
        "own params at the same pixels (its U-Net on a training photo of them)",
    )
    ap.add_argument(
        "--from-model",
        help="a model .safetensors: its ND_enc and M_render, frozen, are the decoder; only E trains",
    )
    ap.add_argument(
        "--export", help="instead of training: write the run's decoder (E, ND_enc, M_render; f32) to this .safetensors"
    )
    args = ap.parse_args(argv)
    if args.anchor and not (args.from_model and args.queries == "scenes"):
        ap.error("--anchor needs --from-model and --queries scenes")
    return args


def load_state(path: str | Path) -> dict[str, torch.Tensor]:
    """The decoder's weights from a run checkpoint (``ckpt.pt``) or an exported ``.safetensors``."""
    if Path(path).suffix == ".safetensors":
        return load_file(str(path))
    return torch.load(path, map_location="cpu", weights_only=False)["decoder"]


def export(ckpt: Path, path: str) -> None:
    """Weights only (no optimizer state): what a later stage or session needs from this run."""
    saved = torch.load(ckpt, map_location="cpu", weights_only=False)
    meta = {"format": "nam-decoder", "steps": str(saved["step"]), "minutes": f"{saved['elapsed'] / 60:.1f}"}
    save_file({k: v.float().contiguous() for k, v in saved["decoder"].items()}, path, metadata=meta)
    print(f"wrote {path} (step {saved['step']})")


def frozen_decoder(path: str | Path) -> Decoder:
    """A decoder whose ``ND_enc`` and ``M_render`` are a model file's, frozen; ``E`` fresh."""
    from .export import unfold_model

    model = unfold_model(path)
    decoder = Decoder()
    decoder.nd_enc.load_state_dict(model.nd_enc.state_dict())
    decoder.render.load_state_dict(model.render.state_dict())
    decoder.nd_enc.requires_grad_(False)
    decoder.render.requires_grad_(False)
    return decoder


def save(path: Path, decoder: Decoder, opt, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save({"decoder": decoder.state_dict(), "optimizer": opt.state_dict(), **state}, tmp)
    os.replace(tmp, path)


def pretrain(args) -> dict:
    from .train import lr_at

    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "ckpt.pt"
    torch.manual_seed(args.seed)
    decoder = (frozen_decoder(args.from_model) if args.from_model else Decoder()).to(device)
    opt = torch.optim.Adam([p for p in decoder.parameters() if p.requires_grad], lr=args.lr)
    state = {"step": 0, "elapsed": 0.0, "cpu": 0.0, "history": [], "from_model": args.from_model}
    if args.resume and ckpt.exists():
        saved = torch.load(ckpt, map_location=device, weights_only=False)
        if saved.get("from_model") != args.from_model:
            raise SystemExit(f"--resume {ckpt}: the run had --from-model {saved.get('from_model')}")
        decoder.load_state_dict(saved["decoder"])
        opt.load_state_dict(saved["optimizer"])
        state = {**state, **{k: saved[k] for k in state if k in saved}}
    gen = torch.Generator().manual_seed(args.seed * 7919 + state["step"])
    source = queries
    if args.queries == "scenes":
        bank = materials.MaterialBank("train", Path(args.materials_root))
        anchor_model = None
        if args.anchor:
            from .export import load_model

            anchor_model = load_model(args.from_model).eval()
        source = SceneQueries(bank, model=anchor_model)
    val = held_out(source=source)
    log = open(out / "train.log", "a")  # noqa: SIM115 (kept open for the run)

    def emit(line: str) -> None:
        print(line, flush=True)
        log.write(line + "\n")
        log.flush()

    emit(f"# pretrain {json.dumps(vars(args))}")
    start = time.time() - state["elapsed"]
    cpu_start = time.process_time() - state["cpu"]
    last_ckpt = time.time()
    step = state["step"]

    def progress() -> float:
        if args.cpu_minutes is not None:
            spent, budget = time.process_time() - cpu_start, 60 * args.cpu_minutes
        else:
            spent, budget = time.time() - start, 60 * args.minutes
        return spent / budget if budget > 0 else 1.0  # a zero budget: no step, a checkpoint

    while progress() < 1:
        elapsed = time.time() - start
        lr = lr_at(progress(), args.lr, args.lr_final)
        for group in opt.param_groups:
            group["lr"] = lr
        maps, dirs, target = source(gen, args.batch)
        maps = {k: v.to(device) for k, v in maps.items()}
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.bf16):
            latent = decoder.enc(maps)
            pred = decoder.decode(latent, dirs.to(device))
        loss = (pred.float() - target.to(device)).abs().mean()
        if args.anchor:
            loss = loss + args.anchor * (latent.float() - source.anchor.to(device)).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        if step % 50 == 0 or step == 1:
            emit(f"step {step:6d}  loss {loss.item():.4f}  lr {lr:.2e}  {elapsed / 60:.1f} min")
        state.update(step=step, elapsed=time.time() - start, cpu=time.process_time() - cpu_start)
        if step % args.val_every == 0:
            res = evaluate(decoder.cpu(), val)
            decoder.to(device)
            state["history"].append({"step": step, "minutes": state["elapsed"] / 60, **res})
            emit(f"val   {step:6d}  " + "  ".join(f"{k} {v:.4f}" for k, v in res.items()))
        if time.time() - last_ckpt > 180:
            save(ckpt, decoder, opt, state)
            last_ckpt = time.time()
    res = evaluate(decoder.cpu(), val)
    state["history"].append({"step": step, "minutes": state["elapsed"] / 60, **res})
    save(ckpt, decoder, opt, state)
    emit(
        f"done: {step} steps, {state['elapsed'] / 60:.1f} min ({state['cpu'] / 60:.1f} CPU-min); "
        + "  ".join(f"{k} {v:.4f}" for k, v in res.items())
    )
    log.close()
    return state


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.export:
        export(Path(args.out) / "ckpt.pt", args.export)
    else:
        pretrain(args)


if __name__ == "__main__":
    main()
