"""Photo relighting with a folded model file: shapes, sRGB decode, capture-light consistency."""

import numpy as np
import torch
from PIL import Image

from train_py import ggx
from train_py.export import load_model
from train_py.relight import load_photo, relight

from .conftest import FIXTURES


def test_relight_of_png_photo_is_finite_nonnegative_and_full_size(tmp_path):
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)).save(tmp_path / "p.png")
    photo = load_photo(tmp_path / "p.png")
    assert photo.shape == (1, 12, 20, 3) and photo.max() <= 1.0
    model = load_model(FIXTURES / "net_tiny.safetensors")
    out = relight(model, photo, (1.0, 0.5, 3.0), (0.0, 0.0, ggx.CAPTURE_DISTANCE))
    assert out.shape == (12, 20, 3)
    assert torch.isfinite(out).all() and (out >= 0).all()


def test_relight_equals_per_query_render_of_estimated_params():
    model = load_model(FIXTURES / "net_tiny.safetensors")
    photo = torch.rand(1, 8, 8, 3)
    light, view = (0.3, -1.0, 2.0), (1.0, 1.0, 3.0)
    out = relight(model, photo, light, view)
    with torch.no_grad():
        params = model.estimate(ggx.network_input(photo, "ldr"))[0, :, 3, 5]
        wi, wo, wh = ggx.directions(torch.tensor(light), torch.tensor(view), 8, 8)
        dirs = torch.cat([wi[3, 5], wo[3, 5], wh[3, 5]])[None]
        ref = ggx.from_log(model.render_log(params[None], dirs))[0]
    torch.testing.assert_close(out[3, 5], ref, rtol=1e-5, atol=1e-6)
