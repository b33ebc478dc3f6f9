"""Real CC0 material sets (``../shared/materials``) as training data, with augmentation (DESIGN.md §6).

Each file is a 4-panel SVBRDF (diffuse | specular | roughness | normal, 512² each; see the README
there). :class:`MaterialBank` keeps the 8-bit panels in memory and draws augmented crops:

- a random square crop at a random scale (real flash photos are close-ups of ~10–20 cm, the sets
  cover ~1–2 m), resized to the training size (area filter), normals renormalised;
- one of the 8 rotations/flips of the square, with the normals' x/y transformed to match;
- diffuse brightness and hue jitter (channel gains, sometimes a channel permutation), roughness
  jitter, glossy variants (roughness scaled down), dielectric F0 jitter and coloured-specular
  metals;
- sometimes two materials blended through a procedural mask.

Only ``train/`` may be used for training; ``test/`` is for evaluation.

    python -m train_py.materials --n 12 --out runs/materials   # contact sheet of augmented crops
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from . import gen, ggx

#: Where the material sets live: ``$NAM_MATERIALS``, else ``../shared/materials`` beside the repository
#: (a machine without ``../shared`` uses a pack made by ``--pack``, see scripts/train-gpu).
DEFAULT_ROOT = Path(
    os.environ.get("NAM_MATERIALS", Path(__file__).resolve().parent.parent.parent / "shared" / "materials")
)
#: Crop side, as a fraction of the 512² tile: log-uniform in this range (0.15 ≈ a 10–20 cm
#: close-up of a ~1 m set).
CROP_FRACTION = (0.15, 1.0)
#: Probability of a glossy variant (roughness × U(GLOSSY_SCALE)).
GLOSSY_P = 0.4
GLOSSY_SCALE = (0.12, 0.6)
#: Probability that two materials are blended through a procedural mask.
BLEND_P = 0.25
#: Probability of a coloured-specular metal variant (F0 from the diffuse colour, dark diffuse).
METAL_P = 0.1


def list_files(split: str, root: Path = DEFAULT_ROOT) -> list[Path]:
    """The 4-panel PNGs of ``split`` (``train`` or ``test``), sorted."""
    files = sorted((Path(root) / split).glob("*.png"))
    if not files:
        raise FileNotFoundError(f"no material PNGs in {Path(root) / split}")
    return files


def load_panels(path: Path, side: int | None = None) -> torch.Tensor:
    """uint8 ``[4, S, S, 3]`` (diffuse, specular, roughness, normal), optionally resized to ``side``."""
    img = Image.open(path).convert("RGB")
    s = img.height
    if side and side != s:
        img = img.resize((4 * side, side), Image.BOX)
        s = side
    a = torch.from_numpy(np.asarray(img).copy())
    return torch.stack([a[:, k * s : (k + 1) * s] for k in range(4)])


def decode(panels: torch.Tensor) -> dict[str, torch.Tensor]:
    """``[..., 4, H, W, 3]`` uint8 or float in [0, 1] → linear maps (gen.read_four_panel's decoding)."""
    a = panels.float() / 255 if panels.dtype == torch.uint8 else panels
    return {
        "diffuse": a[..., 0, :, :, :] ** 2.2,
        "specular": a[..., 1, :, :, :] ** 2.2,
        "roughness": a[..., 2, :, :, 0].clamp(min=0.01),
        "normal": ggx.decode_normal_map(a[..., 3, :, :, :]),
    }


def load_maps(path: Path, size: int | None) -> dict[str, torch.Tensor]:
    """A whole material set at ``size``² (None: as stored) as maps ``[1, size, size, ...]`` (evaluation)."""
    return {k: v[None] for k, v in decode(load_panels(path, size)).items()}


def flat_normals(maps: dict[str, torch.Tensor], pick: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """``maps`` ``[B, H, W, ...]`` with the normals of the materials ``pick`` (``[B]`` bool; None:
    all) replaced by ``+z``; the other maps untouched."""
    up = torch.zeros_like(maps["normal"])
    up[..., 2] = 1
    if pick is not None:
        up = torch.where(pick.view(-1, 1, 1, 1), up, maps["normal"])
    return {**maps, "normal": up}


def orient(maps: dict[str, torch.Tensor], k: int, flip: bool) -> dict[str, torch.Tensor]:
    """Maps ``[H, W, ...]`` rotated by ``k`` quarter turns counter-clockwise (as displayed), after an
    optional left-right flip; the normals' (x, y) turn with the image (x right, y up)."""
    out = {}
    for key, v in maps.items():
        if flip:
            v = v.flip(1)
        out[key] = torch.rot90(v, k, dims=(0, 1))
    n = out["normal"]
    nx, ny = (-n[..., 0], n[..., 1]) if flip else (n[..., 0], n[..., 1])
    for _ in range(k % 4):  # a CCW quarter turn maps (x, y) to (-y, x)
        nx, ny = -ny, nx
    out["normal"] = torch.stack([nx, ny, n[..., 2]], dim=-1)
    return out


class MaterialBank:
    """The real material sets of one split in memory (uint8, ``side``² per panel)."""

    def __init__(self, split: str = "train", root: Path = DEFAULT_ROOT, side: int | None = None):
        self.files = list_files(split, root)
        self.panels = torch.stack([load_panels(f, side) for f in self.files])  # [N, 4, S, S, 3]

    def __len__(self) -> int:
        return self.panels.shape[0]

    def crop(self, rng: gen.Rng, index: int, size: int) -> dict[str, torch.Tensor]:
        """An augmented-geometry crop of material ``index`` at ``size``² (linear maps)."""
        s = self.panels.shape[2]
        side = max(size // 2, round(s * rng.logu(*CROP_FRACTION)))
        side = min(side, s)
        y, x = rng.i(0, s - side), rng.i(0, s - side)
        a = self.panels[index, :, y : y + side, x : x + side].float() / 255  # [4, side, side, 3]
        a = a.permute(0, 3, 1, 2)
        a = F.interpolate(a, size=(size, size), mode="area" if side >= size else "bilinear", align_corners=None)
        maps = decode(a.permute(0, 2, 3, 1))
        return orient(maps, rng.i(0, 3), rng.u() < 0.5)

    def sample(self, rng: gen.Rng, size: int) -> dict[str, torch.Tensor]:
        """One augmented material ``[size, size, ...]``: crop, orientation, reflectance jitter, blends."""
        maps = jitter(rng, self.crop(rng, rng.i(0, len(self) - 1), size))
        if rng.u() < BLEND_P:
            other = jitter(rng, self.crop(rng, rng.i(0, len(self) - 1), size))
            noise = gen.fbm(rng, size, rng.i(2, 10), 5)
            mask = gen.soft_mask(noise, rng.u(0.2, 0.7), rng.u(5, 60))
            maps = gen.blend(maps, other, mask)
            maps["normal"] = ggx.normalize(maps["normal"])
        return maps


def jitter(rng: gen.Rng, maps: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Diffuse brightness/hue, roughness (incl. glossy variants) and specular jitter."""
    diffuse = maps["diffuse"]
    if rng.u() < 0.3:
        diffuse = diffuse[..., torch.randperm(3, generator=rng.gen)]
    gains = torch.tensor([math.exp(rng.u(-0.25, 0.25)) for _ in range(3)])
    diffuse = (diffuse * gains * rng.logu(0.5, 1.6)).clamp(0, 1)
    roughness = maps["roughness"] * rng.logu(0.75, 1.3)
    if rng.u() < GLOSSY_P:
        roughness = roughness * rng.u(*GLOSSY_SCALE)
    specular = maps["specular"]
    dielectric = specular.mean() < 0.1
    if dielectric:
        specular = specular * rng.u(0.5, 2.0)
    if dielectric and rng.u() < METAL_P:
        specular = (diffuse**0.5 * rng.u(0.7, 1.0)).clamp(0.2, 1)
        diffuse = diffuse * rng.u(0.0, 0.1)
    return {
        "diffuse": diffuse,
        "specular": specular.clamp(0, 1),
        "roughness": roughness.clamp(0.02, 1),
        "normal": maps["normal"],
    }


def batch(bank: MaterialBank, seeds: list[int], size: int, device="cpu") -> dict[str, torch.Tensor]:
    """Stacked augmented real materials ``[B, H, W, ...]``, one per seed (deterministic per seed)."""
    mats = [bank.sample(gen.Rng(s), size) for s in seeds]
    return {k: torch.stack([m[k] for m in mats]).to(device) for k in mats[0]}


def pack(out: Path, side: int, root: Path = DEFAULT_ROOT) -> None:
    """Copies both splits at ``side``² per panel (box filter), for machines without ``../shared``."""
    total = 0
    for split in ("train", "test"):
        (out / split).mkdir(parents=True, exist_ok=True)
        for path in list_files(split, root):
            panels = load_panels(path, side)
            Image.fromarray(torch.cat(list(panels), dim=1).numpy()).save(out / split / path.name, optimize=True)
            total += (out / split / path.name).stat().st_size
    print(f"packed {root} at {side}² into {out} ({total / 2**20:.1f} MiB)")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--split", default="train")
    ap.add_argument("--out", default="runs/materials")
    ap.add_argument("--pack", help="instead: write train/ and test/ resized to --side² per panel into this folder")
    ap.add_argument("--side", type=int, default=256)
    args = ap.parse_args(argv)
    if args.pack:
        pack(Path(args.pack), args.side)
        return
    bank = MaterialBank(args.split)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tiles = []
    for s in range(args.n):
        maps = bank.sample(gen.Rng(s), args.size)
        photo = gen.srgb_png(ggx.render_capture({k: v[None] for k, v in maps.items()})[0])
        tiles.append(np.concatenate([photo, gen.four_panel(maps)], axis=1))
    Image.fromarray(gen.contact_sheet(tiles, cols=2)).save(out / "contact_sheet.png")
    print(f"wrote {out / 'contact_sheet.png'} ({args.n} augmented crops of {len(bank)} {args.split} sets)")


if __name__ == "__main__":
    main()
