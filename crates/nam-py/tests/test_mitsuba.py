"""nam.mitsuba: a flat quad wearing a neural material, rendered by Mitsuba 3, equals
`nam.relight` for the same light and viewer, in the scalar and the LLVM (wavefront) variant.

Each case runs in its own interpreter: a Mitsuba variant is chosen once per process."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
#: Debian 12's libLLVM 15 fails in Dr.Jit ("Cannot select … fmaximum"); scripts/test installs 19.
LIBLLVM19 = Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

#: Orthographic view and directional light: every sample in a pixel sees the same texel and
#: directions, so Mitsuba's random sub-pixel positions cannot matter — f32 rounding only
#: (measured 1.05e-4 at worst).
ORTHO_REL_TOL = 5e-4
#: Perspective camera at the capture position and a point light: Mitsuba averages 64 random
#: positions per pixel, nam.relight takes the pixel centre; the median pixel must agree within
#: this, and the mean over the image within the second (measured 0.4–0.5%: averaging over a
#: pixel's footprint is not the value at its centre where the radiance curves).
PERSPECTIVE_MEDIAN_REL_TOL = 2e-2
PERSPECTIVE_MEAN_REL_TOL = 1e-2

SCRIPT = r"""
import sys, numpy as np, mitsuba as mi
mi.set_variant(sys.argv[1])
import nam, nam.mitsuba
case, material_path = sys.argv[2], sys.argv[3]
model = nam.Model.embedded()
material = nam.Material.load(material_path, model=model)
side = material.shape[0]
d = 1.0 / np.tan(np.radians(14.0))
if case == "ortho":
    to_light = np.array([0.3, 0.2, 0.9327379])
    sensor = {"type": "orthographic",
              "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])}
    light = {"type": "directional", "direction": (-to_light).tolist(), "irradiance": {"type": "rgb", "value": 2.0}}
    want = nam.relight(model, material, light=to_light, view=(0, 0, 1), directional=True, orthographic=True,
                       intensity=2.0 / np.pi)
else:
    position = [1.2, 0.8, 3.5]
    sensor = {"type": "perspective", "fov": 28, "fov_axis": "x",
              "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, d], target=[0, 0, 0], up=[0, 1, 0])}
    light = {"type": "point", "position": position, "intensity": {"type": "rgb", "value": 30.0}}
    want = nam.relight(model, material, light=position, view=(0, 0, d), falloff=True,
                       intensity=30.0 / (np.pi * d * d))
sensor["film"] = {"type": "hdrfilm", "width": side, "height": side, "rfilter": {"type": "box"},
                  "pixel_format": "rgb"}
sensor["sampler"] = {"type": "independent", "sample_count": 64 if case != "ortho" else 4}
scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct", "bsdf_samples": 0},
                      "sensor": sensor, "light": light,
                      "quad": {"type": "rectangle", "bsdf": {"type": "nam", "material": material_path}}})
got = np.array(mi.render(scene), dtype=np.float32)
np.save(sys.argv[4], np.stack([got, want]))
"""


@pytest.fixture(scope="module")
def material_path(tmp_path_factory):
    import nam

    path = tmp_path_factory.mktemp("mitsuba") / "example.nam"
    nam.Model.embedded().estimate_file(REPO / "assets" / "example_photo.png", resize=32).save(path, exact=True)
    return path


def render(variant: str, case: str, material_path: Path, tmp_path: Path):
    import numpy as np

    env = dict(os.environ)
    if variant.startswith("llvm"):
        assert LIBLLVM19.exists(), "scripts/test installs libllvm19 for Dr.Jit's LLVM backend"
        env["DRJIT_LIBLLVM_PATH"] = str(LIBLLVM19)
    out = tmp_path / f"{variant}_{case}.npy"
    subprocess.run(
        [sys.executable, "-c", SCRIPT, variant, case, str(material_path), str(out)], check=True, env=env, timeout=600
    )
    got, want = np.load(out)
    return got, want


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_orthographic_directional_render_equals_relight(variant, material_path, tmp_path):
    import numpy as np

    got, want = render(variant, "ortho", material_path, tmp_path)
    rel = np.abs(got - want) / np.maximum(want, 1e-3)
    print(f"{variant}: worst relative difference {rel.max():.2e}")
    assert want.max() > 0.05
    assert rel.max() < ORTHO_REL_TOL, rel.max()


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_perspective_point_light_render_equals_relight(variant, material_path, tmp_path):
    import numpy as np

    got, want = render(variant, "perspective", material_path, tmp_path)
    rel = np.abs(got - want) / np.maximum(want, 1e-3)
    print(f"{variant}: median {np.median(rel):.2e}, mean ratio {got.mean() / want.mean():.4f}")
    assert np.median(rel) < PERSPECTIVE_MEDIAN_REL_TOL, np.median(rel)
    assert abs(got.mean() / want.mean() - 1) < PERSPECTIVE_MEAN_REL_TOL
