"""A sphere and a floor wearing a neural material estimated from the bundled photo, rendered by
Mitsuba 3 with nam's BSDF plugin: a point light plus a constant environment, 256².

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \\
        .venv/bin/python crates/nam-py/examples/mitsuba_scene.py -o docs/figures/mitsuba_scene.png

`--variant scalar_rgb` needs no LLVM but runs the network one ray at a time (slow).
"""

import argparse
import tempfile
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

REPO = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default="mitsuba_scene.png")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    args = ap.parse_args()
    mi.set_variant(args.variant)
    import nam
    import nam.mitsuba

    started = time.perf_counter()
    material = nam.Model.embedded().estimate_file(REPO / "assets" / "example_photo.png")
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "example.nam")
        material.save(path, exact=True)
        bsdf = {"type": "nam", "material": path}
        scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "path", "max_depth": 3},
                "sensor": {
                    "type": "perspective",
                    "fov": 38,
                    "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.6, 4.2], target=[0, 0.1, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": args.size, "height": args.size},
                    "sampler": {"type": "independent", "sample_count": args.spp},
                },
                "sphere": {"type": "sphere", "radius": 0.9, "center": [0, 0.9, 0], "bsdf": bsdf},
                "floor": {
                    "type": "rectangle",
                    "to_world": mi.ScalarTransform4f().translate([0, 0, 0]).rotate([1, 0, 0], -90).scale(2.5),
                    "bsdf": bsdf,
                },
                "light": {"type": "point", "position": [2.5, 4.0, 3.0], "intensity": {"type": "rgb", "value": 40.0}},
                "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.20, 0.24, 0.30]}},
            }
        )
        image = mi.render(scene)
    srgb = np.clip(np.array(image)[..., :3], 0, 1) ** (1 / 2.2)
    mi.util.write_bitmap(args.output, mi.Bitmap((srgb * 255 + 0.5).astype(np.uint8)))
    seconds = time.perf_counter() - started
    print(f"wrote {args.output} ({args.size}², {args.spp} spp, {args.variant}) in {seconds:.0f} s")


if __name__ == "__main__":
    main()
