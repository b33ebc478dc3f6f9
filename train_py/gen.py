"""Procedural SVBRDF generator: the training data (DESIGN.md §6).

Each material is a deterministic function of ``(seed, size)``: fractal noise, tiles, bricks,
planks, scratches and rust/paint masks; metals (coloured specular, dark diffuse) and dielectrics
(grey specular ≈ 0.04), roughness 0.01..1, normals from height fields, layers blended through
masks. Maps are channel-last and linear: ``diffuse``/``specular`` [H, W, 3], ``roughness`` [H, W],
``normal`` [H, W, 3] (unit, surface frame, z up).

    python -m train_py.gen --n 16 --out runs/gen        # 4-panel PNGs + contact sheet
    python -m train_py.gen --examples                   # assets/example_photo.png + example_material.png
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from . import ggx

#: Validation / example seeds live at and above this; training draws seeds below it.
HELD_OUT_SEED_BASE = 1_000_000_000
#: The material shown in assets/ (held out from training).
EXAMPLE_SEED = HELD_OUT_SEED_BASE + 7

METAL_COLOURS = [
    (1.00, 0.78, 0.34),  # gold
    (0.95, 0.64, 0.54),  # copper
    (0.95, 0.93, 0.88),  # silver
    (0.56, 0.57, 0.58),  # iron
    (0.91, 0.92, 0.92),  # aluminium
    (0.98, 0.82, 0.76),  # brass-ish pink
]


class Rng:
    """Thin wrapper over a seeded ``torch.Generator`` with scalar helpers."""

    def __init__(self, seed: int):
        self.gen = torch.Generator().manual_seed(int(seed))

    def u(self, lo: float = 0.0, hi: float = 1.0) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=self.gen))

    def logu(self, lo: float, hi: float) -> float:
        return math.exp(self.u(math.log(lo), math.log(hi)))

    def i(self, lo: int, hi: int) -> int:
        """Integer in [lo, hi]."""
        return int(torch.randint(lo, hi + 1, (), generator=self.gen))

    def choice(self, items: list, weights: list[float] | None = None):
        w = torch.tensor(weights if weights else [1.0] * len(items), dtype=torch.float64)
        return items[int(torch.multinomial(w, 1, generator=self.gen))]

    def rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.gen)


def value_noise(rng: Rng, size: int, cells: int) -> torch.Tensor:
    """Smooth noise in [0, 1] with about ``cells`` features across, ``[size, size]``."""
    cells = max(1, cells)
    lattice = rng.rand(1, 1, cells + 3, cells + 3)
    up = F.interpolate(lattice, scale_factor=size / cells, mode="bicubic", align_corners=False)
    off = rng.i(0, max(0, up.shape[-1] - size))
    return up[0, 0, off : off + size, off : off + size].clamp(0, 1)


def fbm(rng: Rng, size: int, cells: int, octaves: int = 5, gain: float = 0.5) -> torch.Tensor:
    """Fractal sum of value noise, normalised to [0, 1]. ``cells`` is capped at ``size`` so the
    first octave always exists (an empty sum was 0/0 = NaN for small maps)."""
    cells = min(cells, size)
    total = torch.zeros(size, size)
    amp, norm = 1.0, 0.0
    for o in range(octaves):
        c = cells * 2**o
        if c > size:
            break
        total += amp * value_noise(rng, size, c)
        norm += amp
        amp *= gain
    total = total / norm
    return (total - total.min()) / (total.max() - total.min() + 1e-8)


def grid_uv(size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel-centre coordinates in [0, 1): u along columns, v along rows, ``[size, size]``."""
    t = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    return t[None, :].expand(size, size), t[:, None].expand(size, size)


def cell_pattern(rng: Rng, size: int, kind: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Tiles, bricks or planks: ``(height, per-cell random id in [0,1], joint mask)``."""
    u, v = grid_uv(size)
    angle = rng.choice([0.0, math.pi / 2]) + rng.u(-0.05, 0.05)
    ca, sa = math.cos(angle), math.sin(angle)
    uu, vv = ca * (u - 0.5) - sa * (v - 0.5) + 0.5, sa * (u - 0.5) + ca * (v - 0.5) + 0.5
    if kind == "tiles":
        nx = rng.i(2, 8)
        ny = nx if rng.u() < 0.7 else rng.i(2, 8)
        offset_rows = 0.0
    elif kind == "bricks":
        ny = rng.i(4, 12)
        nx = max(1, int(ny / rng.u(1.8, 3.0)))
        offset_rows = 0.5
    else:  # planks
        ny = rng.i(3, 10)
        nx = rng.i(1, 3)
        offset_rows = -1.0  # random per row
    gy = vv * ny
    row = torch.floor(gy)
    if offset_rows >= 0:
        shift = offset_rows * torch.remainder(row, 2)
    else:
        table = rng.rand(64)
        shift = table[torch.remainder(row, 64).long()]
    gx = uu * nx + shift
    col = torch.floor(gx)
    fx, fy = gx - col, gy - row
    joint_w = rng.u(0.01, 0.06) * (nx if kind != "planks" else 1.0 * nx) / 2
    jw_x = min(0.3, joint_w * 1.0)
    jw_y = min(0.3, rng.u(0.01, 0.06) * ny / 2)
    edge = torch.minimum(torch.minimum(fx, 1 - fx) / jw_x, torch.minimum(fy, 1 - fy) / jw_y)
    joint = (edge < 1.0).float()
    bevel = torch.clamp(edge, 0, 3) / 3
    ids_table = rng.rand(4096)
    cell_id = ids_table[torch.remainder((row * 97 + col * 13).long(), 4096)]
    tilt = (cell_id - 0.5) * rng.u(0.0, 0.3) * (fx - 0.5)
    height = 0.6 * bevel + tilt
    return height, cell_id, joint


def scratches(rng: Rng, size: int, count: int) -> torch.Tensor:
    """Mask of thin random line segments (1 on a scratch)."""
    u, v = grid_uv(size)
    mask = torch.zeros(size, size)
    main_angle = rng.u(0, math.pi)
    for _ in range(count):
        a = main_angle + rng.u(-0.4, 0.4) if rng.u() < 0.7 else rng.u(0, math.pi)
        length = rng.u(0.1, 0.8)
        cx, cy = rng.u(), rng.u()
        dx, dy = math.cos(a), math.sin(a)
        px, py = u - cx, v - cy
        t = torch.clamp(px * dx + py * dy, -length / 2, length / 2)
        dist = torch.sqrt((px - t * dx) ** 2 + (py - t * dy) ** 2)
        width = rng.u(0.5, 1.5) / size + rng.u(0, 0.002)
        mask = torch.maximum(mask, torch.clamp(1 - dist / width, 0, 1) * rng.u(0.4, 1.0))
    return mask


def soft_mask(noise: torch.Tensor, coverage: float, sharpness: float) -> torch.Tensor:
    """Threshold noise so that roughly ``coverage`` of the area is 1, with a soft edge."""
    thr = torch.quantile(noise.flatten()[:: max(1, noise.numel() // 4096)], 1.0 - coverage)
    return torch.sigmoid((noise - thr) * sharpness)


def hsv_colour(rng: Rng, sat: tuple[float, float], val: tuple[float, float]) -> torch.Tensor:
    """A random colour (linear RGB) from HSV ranges given in display (gamma) space."""
    h, s, v = rng.u(), rng.u(*sat), rng.u(*val)
    k = torch.tensor([5.0, 3.0, 1.0])
    kk = torch.remainder(k + h * 6, 6)
    rgb = v - v * s * torch.clamp(torch.minimum(kk, 4 - kk), 0, 1)
    return rgb**2.2


def sub_material(rng: Rng, size: int, kind: str) -> dict[str, torch.Tensor]:
    """One homogeneous-ish layer with noise variation: ``metal``, ``dielectric`` or ``rust``/``paint``."""
    var = fbm(rng, size, rng.i(2, 16), 4)
    vamt = rng.u(0.0, 0.5)
    if kind == "metal":
        base = torch.tensor(rng.choice(METAL_COLOURS)) * rng.u(0.8, 1.0)
        tint = hsv_colour(rng, (0.0, 0.3), (0.8, 1.0))
        spec = (base * tint) ** 0.5 * base**0.5
        diff = spec * rng.u(0.0, 0.08)
        rough = rng.logu(0.03, 0.6)
    elif kind == "rust":
        diff = hsv_colour(rng, (0.6, 0.9), (0.25, 0.6)) * torch.tensor([1.0, 0.55, 0.3])
        spec = torch.full((3,), rng.u(0.02, 0.05))
        rough = rng.u(0.6, 1.0)
        vamt = rng.u(0.3, 0.8)
    else:  # dielectric / paint
        diff = hsv_colour(rng, (0.0, 0.9), (0.1, 0.95))
        spec = torch.full((3,), rng.u(0.02, 0.08))
        rough = rng.logu(0.01, 1.0) if kind == "dielectric" else rng.logu(0.05, 0.6)
    m = 1 + vamt * (var - 0.5) * 2
    r_var = fbm(rng, size, rng.i(2, 24), 4)
    rough_map = torch.clamp(rough * (1 + rng.u(0, 0.6) * (r_var - 0.5) * 2), 0.01, 1.0)
    return {
        "diffuse": torch.clamp(diff[None, None, :] * m[..., None], 0, 1),
        "specular": torch.clamp(spec[None, None, :] * (1 + 0.3 * vamt * (var[..., None] - 0.5)), 0, 1),
        "roughness": rough_map,
    }


def blend(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor], mask: torch.Tensor) -> dict[str, torch.Tensor]:
    """``mask`` = 1 selects ``b``."""
    out = {}
    for k in a:
        m = mask[..., None] if a[k].dim() == 3 else mask
        out[k] = a[k] * (1 - m) + b[k] * m
    return out


def height_to_normal(height: torch.Tensor, strength: float) -> torch.Tensor:
    """Unit normals of the height field ``z = strength · height / 2`` over the [-1, 1]² surface.

    ``height`` is sampled at pixel centres (rows run towards -y); ``strength`` is the relief, in
    surface units, of a height change of 1, so normals do not depend on the resolution.
    """
    size = height.shape[-1]
    h = F.pad(height[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
    per_px = strength * size / 4  # central difference spans 2 pixels = 4/size surface units
    dz_dx = (h[1:-1, 2:] - h[1:-1, :-2]) * per_px
    dz_dy = -(h[2:, 1:-1] - h[:-2, 1:-1]) * per_px
    n = torch.stack([-dz_dx, -dz_dy, torch.ones_like(dz_dx)], dim=-1)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True)


def material(seed: int, size: int) -> dict[str, torch.Tensor]:
    """The procedural SVBRDF of ``seed`` at ``size``×``size`` (channel-last, linear, f32)."""
    rng = Rng(seed)
    pattern = rng.choice(["plain", "tiles", "bricks", "planks", "plain_layers"], [2, 2, 2, 1.5, 2])
    base_kind = rng.choice(["dielectric", "metal"], [0.65, 0.35])
    base = sub_material(rng, size, base_kind)
    height = fbm(rng, size, rng.i(2, 12), 5) * rng.u(0.05, 0.6)

    if pattern in ("tiles", "bricks", "planks"):
        ph, cell_id, joint = cell_pattern(rng, size, pattern)
        height = height + ph
        # Per-cell variation of colour and roughness.
        base["diffuse"] = base["diffuse"] * (1 + rng.u(0, 0.6) * (cell_id[..., None] - 0.5))
        base["roughness"] = base["roughness"] * (1 + rng.u(0, 0.5) * (cell_id - 0.5))
        if pattern == "planks":
            _, v = grid_uv(size)
            grain = torch.sin(
                (v * rng.u(20, 80) + fbm(rng, size, rng.i(2, 6), 3) * rng.u(2, 10)) * 2 * math.pi + cell_id * 50
            )
            base["diffuse"] = base["diffuse"] * (1 + rng.u(0.1, 0.4) * grain[..., None])
            height = height + 0.02 * grain
        grout = sub_material(rng, size, rng.choice(["dielectric", "metal"], [0.85, 0.15]))
        base = blend(base, grout, joint)
    if pattern == "plain_layers" or rng.u() < 0.5:
        layer = sub_material(rng, size, rng.choice(["dielectric", "metal", "paint"]))
        mask = soft_mask(fbm(rng, size, rng.i(2, 10), 5), rng.u(0.2, 0.7), rng.u(5, 60))
        base = blend(base, layer, mask)
        height = height + mask * rng.u(0, 0.3)
    if rng.u() < 0.3:  # rust patches
        rust = sub_material(rng, size, "rust")
        mask = soft_mask(fbm(rng, size, rng.i(3, 12), 6), rng.u(0.1, 0.5), rng.u(8, 40))
        base = blend(base, rust, mask)
        height = height + mask * fbm(rng, size, 32, 2) * 0.2
    if rng.u() < 0.4:
        sc = scratches(rng, size, rng.i(5, 60))
        base["roughness"] = torch.clamp(base["roughness"] * (1 - 0.5 * sc) + 0.3 * sc * rng.u(), 0.01, 1.0)
        height = height - sc * rng.u(0.05, 0.3)

    normal = height_to_normal(height, rng.logu(0.005, 0.08))
    return {
        "diffuse": base["diffuse"].clamp(0, 1).float(),
        "specular": base["specular"].clamp(0, 1).float(),
        "roughness": base["roughness"].clamp(0.01, 1).float(),
        "normal": normal.float(),
    }


def batch(seeds: list[int], size: int, device: str | torch.device = "cpu") -> dict[str, torch.Tensor]:
    """Stacked maps ``[B, H, W, ...]`` for the given seeds."""
    mats = [material(s, size) for s in seeds]
    return {k: torch.stack([m[k] for m in mats]).to(device) for k in mats[0]}


def four_panel(maps: dict[str, torch.Tensor]) -> np.ndarray:
    """DESIGN.md §3 layout: diffuse | specular | roughness | normal, uint8 ``[H, 4W, 3]``.

    Diffuse and specular use a pure 2.2 gamma; roughness and normal are linear.
    """
    d = maps["diffuse"].clamp(0, 1) ** (1 / 2.2)
    s = maps["specular"].clamp(0, 1) ** (1 / 2.2)
    r = maps["roughness"][..., None].expand(*maps["roughness"].shape, 3)
    n = ggx.encode_normal_map(maps["normal"])
    img = torch.cat([d, s, r, n], dim=1)
    return (img.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()


def read_four_panel(path: str | Path) -> dict[str, torch.Tensor]:
    """Inverse of :func:`four_panel` for a PNG file."""
    a = torch.from_numpy(np.asarray(Image.open(path).convert("RGB"))).float() / 255
    w = a.shape[1] // 4
    return {
        "diffuse": a[:, :w] ** 2.2,
        "specular": a[:, w : 2 * w] ** 2.2,
        "roughness": a[:, 2 * w : 3 * w, 0].clamp(min=0.01),
        "normal": ggx.decode_normal_map(a[:, 3 * w :]),
    }


def srgb_png(linear: torch.Tensor) -> np.ndarray:
    """Linear radiance ``[H, W, 3]`` → 8-bit sRGB array (clamped: an LDR photo)."""
    return (ggx.srgb_encode(linear) * 255 + 0.5).to(torch.uint8).numpy()


def contact_sheet(images: list[np.ndarray], cols: int, pad: int = 4) -> np.ndarray:
    h = max(i.shape[0] for i in images)
    w = max(i.shape[1] for i in images)
    rows = math.ceil(len(images) / cols)
    sheet = np.full((rows * (h + pad) + pad, cols * (w + pad) + pad, 3), 255, np.uint8)
    for k, img in enumerate(images):
        r, c = divmod(k, cols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        sheet[y : y + img.shape[0], x : x + img.shape[1]] = img
    return sheet


def write_examples(assets: Path, size: int = 256) -> None:
    maps = material(EXAMPLE_SEED, size)
    photo = ggx.render_capture({k: v[None] for k, v in maps.items()})[0]
    assets.mkdir(parents=True, exist_ok=True)
    Image.fromarray(srgb_png(photo)).save(assets / "example_photo.png")
    Image.fromarray(four_panel(maps)).save(assets / "example_material.png")
    print(f"wrote {assets / 'example_photo.png'} and {assets / 'example_material.png'} (seed {EXAMPLE_SEED})")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--out", default="runs/gen")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--examples", action="store_true", help="write assets/example_photo.png and example_material.png")
    ap.add_argument("--assets", default="assets")
    args = ap.parse_args(argv)
    if args.examples:
        write_examples(Path(args.assets), args.size)
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tiles = []
    for k in range(args.n):
        seed = args.seed + k
        maps = material(seed, args.size)
        panel = four_panel(maps)
        Image.fromarray(panel).save(out / f"material_{seed:06d}.png")
        photo = srgb_png(ggx.render_capture({key: v[None] for key, v in maps.items()})[0])
        tiles.append(np.concatenate([photo, panel], axis=1))
    Image.fromarray(contact_sheet(tiles, cols=2)).save(out / "contact_sheet.png")
    print(f"wrote {args.n} materials and {out / 'contact_sheet.png'}")


if __name__ == "__main__":
    main()
