"""The clipped-pixel fill (train_py/clip_fill.py) and its use in estimate_photo and training."""

import torch

from train_py import ggx
from train_py.clip_fill import fill_clipped
from train_py.model import ModelConfig, NamModel
from train_py.train import TrainStep, input_clipped


def blob_mask(b: int, h: int, w: int) -> torch.Tensor:
    m = torch.zeros(b, h, w, dtype=torch.bool)
    m[:, 2:5, 3:8] = True
    return m


def test_only_clipped_pixels_change_and_an_all_clipped_image_is_left_alone():
    g = torch.Generator().manual_seed(0)
    params = torch.randn(2, 5, 7, 9, generator=g)
    clipped = blob_mask(2, 7, 9)
    clipped[1] = True
    out = fill_clipped(params, clipped)
    assert torch.equal(out[0][:, ~clipped[0]], params[0][:, ~clipped[0]])
    assert not torch.equal(out[0][:, clipped[0]], params[0][:, clipped[0]])
    assert torch.equal(out[1], params[1])
    assert torch.isfinite(out).all()


def test_a_constant_map_stays_constant_and_filled_values_lie_within_the_kept_range():
    g = torch.Generator().manual_seed(1)
    clipped = torch.rand(1, 11, 6, generator=g) > 0.3
    torch.testing.assert_close(
        fill_clipped(torch.full((1, 3, 11, 6), 2.5), clipped), torch.full((1, 3, 11, 6), 2.5), rtol=0, atol=1e-6
    )
    params = torch.rand(1, 4, 11, 6, generator=g)
    out = fill_clipped(params, clipped)
    kept = params[0][:, ~clipped[0]]
    assert (out >= kept.min() - 1e-6).all() and (out <= kept.max() + 1e-6).all()


def test_a_gradient_reaches_the_kept_pixels_from_the_filled_ones():
    params = torch.zeros(1, 2, 8, 8, requires_grad=True)
    clipped = torch.zeros(1, 8, 8, dtype=torch.bool)
    clipped[0, 3:5, 3:5] = True
    fill_clipped(params, clipped)[0, :, 3:5, 3:5].sum().backward()
    grad = params.grad[0, 0]
    assert (grad[clipped[0]] == 0).all()
    assert grad[~clipped[0]].sum() > 0


def test_estimate_photo_fills_ldr_models_where_the_photo_clipped():
    torch.manual_seed(0)
    photo = torch.full((1, 16, 16, 3), 0.3)
    photo[:, 4:8, 5:9] = 1.0
    clipped = ggx.clipped(photo)[0]
    for log_mode, fills in (("ldr", True), ("hdr", False)):
        model = NamModel(ModelConfig(width=4, log_mode=log_mode), folded=False).eval()
        with torch.no_grad():
            raw = model.estimate(ggx.network_input(photo, log_mode))
            filled = model.estimate_photo(photo)
            kept = model.estimate_photo(photo, fill=False)
        assert torch.equal(kept, raw)
        assert torch.equal(filled[0][:, ~clipped], raw[0][:, ~clipped])
        assert torch.equal(filled[0][:, clipped], raw[0][:, clipped]) != fills


def test_training_with_fill_clipped_renders_the_filled_params():
    torch.manual_seed(0)
    photo = torch.full((1, 16, 16, 3), 0.3)
    photo[:, 4:8, 5:9] = 1.0
    net_input = ggx.network_input(ggx.ldr_capture(photo), "ldr")
    assert torch.equal(input_clipped(net_input), ggx.clipped(photo))
    model = NamModel(ModelConfig(width=4), folded=False).eval()
    step = TrainStep(model, fill_clipped=True)
    with torch.no_grad():
        step.forward(net_input, 1, 1.0, torch.Generator().manual_seed(0), *_exemplar(16))
    torch.testing.assert_close(step.last_params, fill_clipped(model.estimate(net_input), ggx.clipped(photo)))


def _exemplar(size: int):
    maps = {
        "diffuse": torch.full((1, size, size, 3), 0.3),
        "specular": torch.full((1, size, size, 3), 0.04),
        "roughness": torch.full((1, size, size, 1), 0.3),
        "normal": torch.tensor([0.0, 0.0, 1.0]).expand(1, size, size, 3).contiguous(),
    }
    return maps, torch.tensor([[[0.5, 0.2, 3.0]]]), torch.tensor([[[0.0, 0.0, 4.0]]])
