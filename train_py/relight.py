"""Relight photos with the torch model (reference for the Rust `nam-cli relight`).

    python -m train_py.relight --model models/default.safetensors /work/shared/real_photos/*.png \\
        -o docs/real_photos_contact.png

Each row of the contact sheet is one photo, each column one light (view fixed at the capture
position); only relit outputs are drawn. Display transform: ``clamp(R, 0, 1)^(1/2.2)``.
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

#: Lights of the contact sheet (surface units); the first one re-creates the capture.
DEFAULT_LIGHTS = [
    (0.0, 0.0, ggx.CAPTURE_DISTANCE),
    (1.5, 1.0, 3.5),
    (-2.5, 0.5, 2.0),
    (0.5, -3.0, 1.2),
]


def load_photo(path: str | Path) -> torch.Tensor:
    """8-bit sRGB image → linear RGB ``[1, H, W, 3]``."""
    a = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
    return ggx.srgb_decode(torch.from_numpy(a))[None]


def relight(model: NamModel, photo: torch.Tensor, light, view) -> torch.Tensor:
    """Radiance ``[H, W, 3]`` of a linear photo ``[1, H, W, 3]`` under a point light and view position."""
    h, w = photo.shape[1:3]
    with torch.no_grad():
        params = model.estimate(ggx.network_input(photo, model.config.log_mode))
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
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    model = load_model(args.model)
    view = (0.0, 0.0, ggx.CAPTURE_DISTANCE)
    tiles = []
    for path in args.photos:
        photo = load_photo(path)
        for light in DEFAULT_LIGHTS:
            img = to_uint8(relight(model, photo, light, view))
            tiles.append(label(img, f"{Path(path).stem[:18]} L=({light[0]:.1f},{light[1]:.1f},{light[2]:.1f})"))
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(contact_sheet(tiles, cols=len(DEFAULT_LIGHTS))).save(args.output)
    print(f"wrote {args.output} ({len(args.photos)} photos × {len(DEFAULT_LIGHTS)} lights)")


if __name__ == "__main__":
    main()
