"""Relight photos with the torch model (reference for the Rust `nam-cli relight`).

    python -m train_py.relight --model models/default.safetensors /work/shared/real_photos/*.png \\
        -o docs/real_photos_contact.png [--fov 28 45]

Each row of the contact sheet is one photo at one assumed capture field of view (``--fov``: the
camera, its flash and the network input's half-vector channel move to ``(0, 0, d(fov))``), each
column one light (view at that camera; the first light is the flash, so it re-creates the photo);
only relit outputs are drawn. Display transform: ``clamp(R, 0, 1)^(1/2.2)``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw

from . import ggx
from .export import load_model
from .gen import contact_sheet
from .model import NamModel

#: Lights of the contact sheet (surface units) after the capture's own flash.
OTHER_LIGHTS = [
    (1.5, 1.0, 3.5),
    (-2.5, 0.5, 2.0),
    (0.5, -3.0, 1.2),
]


def load_photo(path: str | Path) -> torch.Tensor:
    """8-bit sRGB image → linear RGB ``[1, H, W, 3]``."""
    a = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
    return ggx.srgb_decode(torch.from_numpy(a))[None]


def relight(model: NamModel, photo: torch.Tensor, light, view, distance: float = ggx.CAPTURE_DISTANCE) -> torch.Tensor:
    """Radiance ``[H, W, 3]`` of a linear photo ``[1, H, W, 3]`` taken from ``(0, 0, distance)``
    under a point light and view position."""
    h, w = photo.shape[1:3]
    with torch.no_grad():
        params = model.estimate_photo(photo, distance)
        lt = torch.tensor(light, dtype=torch.float32)[None]
        vw = torch.tensor(view, dtype=torch.float32)[None]
        wi, wo, _ = ggx.directions(lt, vw, h, w)
        return ggx.from_log(model.relight_log(params, wi, wo))[0]


def to_uint8(radiance: torch.Tensor) -> np.ndarray:
    return (torch.clamp(radiance, 0, 1) ** (1 / 2.2) * 255 + 0.5).to(torch.uint8).numpy()


def label(img: np.ndarray, text: str) -> np.ndarray:
    pil = Image.fromarray(img)
    ImageDraw.Draw(pil).text((4, 4), text, fill=(255, 255, 0))
    return np.asarray(pil)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photos", nargs="+")
    ap.add_argument("--model", default="models/default.safetensors")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--fov", type=float, nargs="+", default=[ggx.CAPTURE_FOV], help="capture field(s) of view, deg")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    model = load_model(args.model)
    tiles = []
    for path in args.photos:
        photo = load_photo(path)
        for fov in args.fov:
            d = ggx.capture_distance(fov)
            camera = (0.0, 0.0, d)
            for k, light in enumerate([camera, *OTHER_LIGHTS]):
                img = to_uint8(relight(model, photo, light, camera, d))
                what = "flash" if k == 0 else f"L=({light[0]:.1f},{light[1]:.1f},{light[2]:.1f})"
                tiles.append(label(img, f"{Path(path).stem[:16]} {fov:.0f}° {what}"))
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(contact_sheet(tiles, cols=1 + len(OTHER_LIGHTS))).save(args.output)
    print(f"wrote {args.output} ({len(args.photos)} photos × {len(args.fov)} fields of view × 4 lights)")


if __name__ == "__main__":
    main()
