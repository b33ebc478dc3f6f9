"""Phone-like flash captures: the network input as a real photo looks (issue 24, DESIGN.md §6).

A :class:`Capture` is the camera of one training step (shared by its materials so that
``--shared-geometry`` still holds): a field of view drawn from ``FOV_RANGE`` (the paper trains at
28°; its real photos were taken at 45°; a centre-square crop of a phone photo lies anywhere
between), the camera at ``(0, 0, d)``, and the flash a little off the lens axis. Per material:
auto-exposure (the reflectances are scaled so the photo's median lands on a random grey, clamped
to [0, 1], so the photo stays a GGX render of the maps the targets use), sensor noise, clipping at
1, 8-bit sRGB, and sometimes JPEG artefacts.

    python -m train_py.capture --out runs/captures    # contact sheet: captures next to real photos
"""

from __future__ import annotations

import argparse
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from . import gen, ggx

#: Field of view of the capture camera, degrees (uniform).
FOV_RANGE = (26.0, 50.0)
#: Largest distance of the flash from the lens axis, surface units (the [-1, 1]² surface spans
#: ~10–20 cm in a close-up, a phone's flash sits ~1 cm from its lens).
FLASH_OFFSET_MAX = 0.2
#: Median of the exposed photo (linear), log-uniform.
EXPOSURE_MEDIAN = (0.06, 0.45)
#: Auto-exposure never scales the reflectances beyond this factor either way.
EXPOSURE_LIMIT = 4.0
#: Shot noise σ at radiance 1 (σ ∝ √R), and read noise σ, both uniform up to these.
SHOT_NOISE_MAX = 0.02
READ_NOISE_MAX = 0.004
#: Probability and quality range of a JPEG round trip.
JPEG_P = 0.3
JPEG_QUALITY = (60, 95)


@dataclass(frozen=True)
class Capture:
    """Camera of one step: field of view (degrees) and flash position (surface units)."""

    fov: float = ggx.CAPTURE_FOV
    flash_x: float = 0.0
    flash_y: float = 0.0

    @property
    def distance(self) -> float:
        return ggx.capture_distance(self.fov)

    def camera(self) -> torch.Tensor:
        """``(0, 0, d)``."""
        return torch.tensor([0.0, 0.0, self.distance])

    def flash(self) -> torch.Tensor:
        return torch.tensor([self.flash_x, self.flash_y, self.distance])

    @staticmethod
    def random(rng: torch.Generator) -> Capture:
        u = torch.rand(3, generator=rng).tolist()
        r, phi = FLASH_OFFSET_MAX * math.sqrt(u[1]), 2 * math.pi * u[2]
        return Capture(FOV_RANGE[0] + (FOV_RANGE[1] - FOV_RANGE[0]) * u[0], r * math.cos(phi), r * math.sin(phi))


def render(maps: dict[str, torch.Tensor], capture: Capture) -> torch.Tensor:
    """HDR radiance ``[B, H, W, 3]`` of the maps under the capture's flash, seen by its camera."""
    b = maps["roughness"].shape[0]
    light = capture.flash().to(maps["roughness"]).expand(b, 1, 3)
    view = capture.camera().to(maps["roughness"]).expand(b, 1, 3)
    return ggx.render_maps(maps, light, view)[:, 0]


def expose(
    maps: dict[str, torch.Tensor],
    capture: Capture,
    rng: gen.Rng,
    exposure: tuple[float, float] = EXPOSURE_MEDIAN,
) -> dict[str, torch.Tensor]:
    """Maps ``[B, ...]`` with diffuse and specular scaled (per material) so the capture's median
    radiance lands on a random grey (log-uniform in ``exposure``), as a phone's auto-exposure does;
    clamped to [0, 1]."""
    radiance = render(maps, capture)
    median = radiance.mean(-1).flatten(1).median(dim=1).values.clamp(min=1e-4)
    goal = torch.tensor([rng.logu(*exposure) for _ in range(median.shape[0])])
    k = (goal / median).clamp(1 / EXPOSURE_LIMIT, EXPOSURE_LIMIT)[:, None, None, None]
    return {**maps, "diffuse": (maps["diffuse"] * k).clamp(0, 1), "specular": (maps["specular"] * k).clamp(0, 1)}


def jpeg(srgb8: np.ndarray, quality: int) -> np.ndarray:
    buf = io.BytesIO()
    Image.fromarray(srgb8).save(buf, format="JPEG", quality=quality)
    return np.asarray(Image.open(buf).convert("RGB"))


def phone_photo(radiance: torch.Tensor, rng: gen.Rng) -> torch.Tensor:
    """What a phone keeps of HDR radiance ``[B, H, W, 3]``: noise, clipping at 1, 8-bit sRGB,
    sometimes JPEG; returned as linear values in [0, 1] (the decoded file)."""
    out = []
    for r in radiance:
        shot, read = rng.u(0, SHOT_NOISE_MAX), rng.u(0, READ_NOISE_MAX)
        noise = torch.randn(r.shape, generator=rng.gen) * (shot * r.clamp(min=0).sqrt() + read)
        srgb8 = gen.srgb_png(r + noise)
        if rng.u() < JPEG_P:
            srgb8 = jpeg(srgb8, rng.i(*JPEG_QUALITY))
        out.append(ggx.srgb_decode(torch.from_numpy(srgb8.copy()).float() / 255))
    return torch.stack(out).to(radiance.device)


def photograph(
    maps: dict[str, torch.Tensor],
    capture: Capture,
    rng: gen.Rng,
    exposure: tuple[float, float] = EXPOSURE_MEDIAN,
) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """Exposed maps (:func:`expose`) and the network input ``[B, 4, H, W]`` of their phone-like
    photo."""
    maps = expose(maps, capture, rng, exposure)
    photo = phone_photo(render(maps, capture), rng)
    return maps, ggx.network_input(photo, "ldr", capture.distance)


def main(argv: list[str] | None = None) -> None:
    from . import materials

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=16, help="synthetic captures (half real sets, half procedural)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--real-photos", default=str(materials.DEFAULT_ROOT.parent / "real_photos"))
    ap.add_argument("--out", default="runs/captures")
    args = ap.parse_args(argv)
    bank = materials.MaterialBank("train")
    rng = gen.Rng(12345)
    tiles = []
    for k in range(args.n):
        if k % 2:
            maps = {key: v[None] for key, v in gen.material(k, args.size).items()}
        else:
            maps = materials.batch(bank, [k], args.size)
        _, net_input = photograph(maps, Capture.random(rng.gen), rng)
        photo = torch.expm1(net_input[0, :3]).permute(1, 2, 0)
        tiles.append(gen.srgb_png(photo))
    for path in sorted(Path(args.real_photos).glob("*.png")):
        tiles.append(np.asarray(Image.open(path).convert("RGB").resize((args.size, args.size), Image.BOX)))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(gen.contact_sheet(tiles, cols=8)).save(out / "contact_sheet.png")
    print(f"wrote {out / 'contact_sheet.png'}: {args.n} training captures, then the real photos")


if __name__ == "__main__":
    main()
