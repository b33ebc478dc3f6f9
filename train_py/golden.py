"""Seeded golden fixtures for the Rust crates (docs/FORMAT.md "Golden fixtures").

    python -m train_py.golden                       # ggx_golden + net_tiny (+ its golden)
    python -m train_py.golden --model models/default.safetensors   # also net_default_golden

Everything is computed in float64 and stored as FORMAT.md says (F64 for GGX, F32 for networks),
so the fixtures hold the most accurate values an f32 implementation can be compared with.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch
from safetensors.torch import save_file

from . import ggx
from .export import fold_state_dict, load_model, save_model
from .model import ModelConfig, NamModel, positional_encoding, query_dirs

FIXTURES = Path("tests/fixtures")
SEED = 20240611
TINY_H, TINY_W = 20, 36
N_QUERIES = 64
#: Tilt of the most tilted normals of the extreme grid (DESIGN.md §7).
MAX_TILT_DEG = 89.9


def _frame(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors orthogonal to unit ``n`` [3] (float64)."""
    helper = (
        torch.tensor([1.0, 0.0, 0.0], dtype=n.dtype)
        if abs(float(n[0])) < 0.9
        else torch.tensor([0.0, 1.0, 0.0], dtype=n.dtype)
    )
    t = helper - n * torch.dot(helper, n)
    t = t / torch.linalg.vector_norm(t)
    b = torch.linalg.cross(n, t)
    return t, b


def _tilted_normal(theta_deg: float, phi: float) -> torch.Tensor:
    th = math.radians(theta_deg)
    return torch.tensor([math.sin(th) * math.cos(phi), math.sin(th) * math.sin(phi), math.cos(th)], dtype=torch.float64)


def _dir_with_cos(n: torch.Tensor, cos_theta: float, phi: float) -> torch.Tensor:
    """Unit direction at angle ``acos(cos_theta)`` from ``n``, azimuth ``phi`` in n's frame."""
    t, b = _frame(n)
    s = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    return cos_theta * n + s * (math.cos(phi) * t + math.sin(phi) * b)


def ggx_cases(gen: torch.Generator) -> dict[str, torch.Tensor]:
    """Pointwise inputs: random cases plus the DESIGN.md §7 extreme grid."""
    rows: list[tuple] = []
    # Extreme grid: roughness × NoL × NoV × F0 × normal tilt.
    for rough in (0.0, 1e-6, 1.0):
        for cl in (0.0, 1e-7, 1e-3):
            for cv in (0.0, 1e-7, 1e-3):
                for f0 in (0.0, 1.0):
                    for tilt in (0.0, MAX_TILT_DEG):
                        n = _tilted_normal(tilt, 0.7)
                        wi = _dir_with_cos(n, cl, 0.3)
                        wo = _dir_with_cos(n, cv, 0.3 + 2.1)
                        rows.append(((0.3, 0.5, 0.7), (f0,) * 3, rough, n, wi, wo))
    # Normal incidence (wi = wo = n): the NDF peak, largest value of D.
    for rough in (0.0, 1e-6, 0.01, 1.0):
        for f0 in (0.0, 1.0):
            for tilt in (0.0, MAX_TILT_DEG):
                n = _tilted_normal(tilt, -1.1)
                rows.append(((0.2, 0.2, 0.2), (f0,) * 3, rough, n, n.clone(), n.clone()))
    # Below the shading horizon: light, view, both.
    for cl, cv in ((-0.3, 0.5), (0.5, -0.3), (-0.2, -0.2)):
        n = _tilted_normal(30.0, 0.4)
        rows.append(((0.5, 0.5, 0.5), (0.04,) * 3, 0.5, n, _dir_with_cos(n, cl, 0.1), _dir_with_cos(n, cv, 2.0)))
    # Random well-behaved cases.
    for _ in range(64):
        u = torch.rand(12, generator=gen, dtype=torch.float64)
        n = _tilted_normal(60.0 * float(u[0]), 2 * math.pi * float(u[1]))
        wi = _dir_with_cos(n, 0.05 + 0.95 * float(u[2]), 2 * math.pi * float(u[3]))
        wo = _dir_with_cos(n, 0.05 + 0.95 * float(u[4]), 2 * math.pi * float(u[5]))
        rows.append(((float(u[6]), float(u[7]), float(u[8])), (float(u[9]),) * 3, float(u[10]), n, wi, wo))
    return {
        "diffuse": torch.tensor([r[0] for r in rows], dtype=torch.float64),
        "specular": torch.tensor([r[1] for r in rows], dtype=torch.float64),
        "roughness": torch.tensor([r[2] for r in rows], dtype=torch.float64),
        "normal": torch.stack([r[3] for r in rows]),
        "wi": torch.stack([r[4] for r in rows]),
        "wo": torch.stack([r[5] for r in rows]),
    }


def ggx_golden() -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(SEED)
    cases = ggx_cases(gen)
    cases["radiance"] = ggx.ggx_radiance(
        cases["diffuse"], cases["specular"], cases["roughness"], cases["normal"], cases["wi"], cases["wo"]
    )
    light = torch.tensor([1.3, -0.6, 2.5], dtype=torch.float64)
    view = torch.tensor([-0.8, 0.4, 3.7], dtype=torch.float64)
    wi, wo, wh = ggx.directions(light, view, 5, 7)
    cases.update({"geom_light": light, "geom_view": view, "geom_wi": wi, "geom_wo": wo, "geom_wh": wh})
    return {k: v.contiguous() for k, v in cases.items()}


def golden_photo(gen: torch.Generator) -> torch.Tensor:
    """A smooth random SVBRDF rendered at the capture geometry, linear ``[H, W, 3]`` (float64).

    Independent of ``gen.py`` so the fixture never changes when the generator does. Its
    highlight exceeds 1 so the LDR clamp of the network input is exercised.
    """

    def smooth(c: int) -> torch.Tensor:
        low = torch.rand(1, c, 4, 6, generator=gen, dtype=torch.float64)
        return torch.nn.functional.interpolate(low, size=(TINY_H, TINY_W), mode="bilinear", align_corners=False)[
            0
        ].permute(1, 2, 0)

    height = smooth(1)[..., 0]
    gy, gx = torch.gradient(height * 3.0)
    normal = ggx.normalize(torch.stack([-gx, gy, torch.ones_like(gx)], dim=-1))
    maps = {
        "diffuse": 0.05 + 0.6 * smooth(3),
        "specular": 0.02 + 0.3 * smooth(1).expand(TINY_H, TINY_W, 3),
        "roughness": 0.1 + 0.5 * smooth(1)[..., 0],
        "normal": normal,
    }
    return ggx.render_capture({k: v[None] for k, v in maps.items()})[0]


def query_set(gen: torch.Generator, params_map: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``N_QUERIES`` (params, dirs): mostly pixels of the map, some random; grazing/below-horizon dirs."""
    n_pix = N_QUERIES - 16
    flat = params_map.permute(1, 2, 0).reshape(-1, params_map.shape[0])
    idx = torch.randint(0, flat.shape[0], (n_pix,), generator=gen)
    params = torch.cat([flat[idx], torch.randn(16, flat.shape[1], generator=gen, dtype=torch.float64)])

    def hemi(count: int) -> torch.Tensor:
        v = torch.randn(count, 3, generator=gen, dtype=torch.float64)
        v[:, 2] = v[:, 2].abs()
        return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True)

    wi, wo = hemi(N_QUERIES), hemi(N_QUERIES)
    # Grazing and below-horizon queries, and co-located / normal-incidence ones.
    wi[0] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    wo[1] = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    wi[2] = torch.tensor([0.6, 0.8, 0.0], dtype=torch.float64)
    wo[2] = torch.tensor([-0.8, 0.6, 0.0], dtype=torch.float64)
    wi[3] = torch.tensor([0.0, 0.6, -0.8], dtype=torch.float64)
    wo[4] = torch.tensor([0.28, 0.0, -0.96], dtype=torch.float64)
    wi[5] = wo[5] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    wi[6] = wo[6]
    wi[7] = torch.tensor([math.sqrt(1 - 1e-12), 0.0, 1e-6], dtype=torch.float64)
    return params, query_dirs(wi, wo)


def network_golden(model: NamModel, seed: int) -> dict[str, torch.Tensor]:
    """Golden tensors of FORMAT.md for a folded model (computed in float64, stored F32)."""
    gen = torch.Generator().manual_seed(seed)
    photo = golden_photo(gen).float()
    m64 = model.double().eval()
    with torch.no_grad():
        net_in = ggx.network_input(photo.double()[None], model.config.log_mode)
        params = m64.estimate(net_in)[0]
        params_filled = m64.estimate_photo(photo.double()[None])[0]
        r_params, r_dirs = query_set(gen, params)
        r_params, r_dirs = r_params.float().double(), r_dirs.float().double()
        r_encoded = positional_encoding(r_dirs)
        r_nd = m64.nd_enc(r_encoded)
        r_log = m64.render(torch.cat([r_params, r_nd], dim=-1))
    model.float()
    out = {
        "photo": photo,
        "input": net_in[0],
        "params": params,
        "params_filled": params_filled,
        "r_params": r_params,
        "r_dirs": r_dirs,
        "r_encoded": r_encoded,
        "r_nd": r_nd,
        "r_log": r_log,
        "r_radiance": ggx.from_log(r_log),
    }
    return {k: v.float().contiguous() for k, v in out.items()}


def randomize_batchnorm(model: NamModel, gen: torch.Generator) -> None:
    """Non-trivial BN statistics so that folding is actually exercised."""
    for mod in model.modules():
        if isinstance(mod, torch.nn.BatchNorm2d):
            c = mod.num_features
            mod.running_mean.copy_(0.2 * torch.randn(c, generator=gen))
            mod.running_var.copy_(0.5 + 1.5 * torch.rand(c, generator=gen))
            mod.weight.data.copy_(0.5 + torch.rand(c, generator=gen))
            mod.bias.data.copy_(0.2 * torch.randn(c, generator=gen))


def tiny_model() -> NamModel:
    """The seeded random C=4 training model (unfolded) behind ``net_tiny.safetensors``."""
    torch.manual_seed(SEED + 1)
    model = NamModel(ModelConfig(width=4), folded=False)
    with torch.no_grad():
        randomize_batchnorm(model, torch.Generator().manual_seed(SEED + 2))
    return model.eval()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(FIXTURES))
    ap.add_argument("--model", help="shipped model file: also write net_default_golden.safetensors")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    save_file(ggx_golden(), str(out / "ggx_golden.safetensors"))
    tiny = tiny_model()
    save_model(fold_state_dict(tiny), tiny.config, out / "net_tiny.safetensors", "f32")
    folded = load_model(out / "net_tiny.safetensors")
    save_file(network_golden(folded, SEED + 3), str(out / "net_tiny_golden.safetensors"))
    written = ["ggx_golden", "net_tiny", "net_tiny_golden"]
    if args.model:
        save_file(network_golden(load_model(args.model), SEED + 4), str(out / "net_default_golden.safetensors"))
        written.append("net_default_golden")
    for name in written:
        p = out / f"{name}.safetensors"
        print(f"wrote {p} ({p.stat().st_size / 1e3:.1f} kB)")


if __name__ == "__main__":
    main()
