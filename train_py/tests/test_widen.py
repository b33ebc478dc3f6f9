"""train_py.widen: a widened U-Net computes what the original does, and its copies can grow apart."""

import pytest
import torch

from train_py import widen
from train_py.export import load_model
from train_py.model import ModelConfig, NamModel


def random_folded(width: int, input_skip: bool) -> NamModel:
    """A folded model with every weight random (folded BatchNorms and biases included), so that a
    wrong channel map changes the params."""
    model = NamModel(ModelConfig(width=width, input_skip=input_skip), folded=True)
    gen = torch.Generator().manual_seed(width)
    with torch.no_grad():
        for name, p in model.est.named_parameters():
            noise = torch.randn(p.shape, generator=gen)
            p.copy_(1 + 0.2 * noise if name.endswith("scale") else 0.3 * noise if p.ndim == 1 else p + 0.05 * noise)
    return model.eval()


@pytest.mark.parametrize(("old", "new", "skip"), [(4, 6, True), (4, 8, False), (8, 12, True)])
def test_widened_model_computes_the_same_params(old, new, skip):
    model = random_folded(old, skip)
    wide = widen.widen(model, new, seed=3)
    assert wide.config.width == new and wide.config.input_skip == skip
    assert sum(p.numel() for p in wide.est.parameters()) > sum(p.numel() for p in model.est.parameters())
    assert widen.params_difference(model, wide, size=40) < widen.WIDEN_TOL
    # The decoder is copied unchanged.
    for a, b in zip(model.render.parameters(), wide.render.parameters(), strict=True):
        assert torch.equal(a, b)


def test_copies_of_a_channel_get_different_weights_that_sum_to_the_original():
    model = random_folded(4, True)
    wide = widen.widen(model, 8, seed=5)
    # The stem's outputs are copied: channel j of the width-8 stem is channel map[j] of the old.
    g = widen.channel_map(8, 4)
    assert torch.equal(wide.est.stem.weight, model.est.stem.weight[g])
    # The next conv reads both copies: its weights on them differ but add up to the original.
    w_old, w_new = model.est.enc1[0].ha1.gate.weight, wide.est.enc1[0].ha1.gate.weight
    for old_channel in range(4):
        copies = (g == old_channel).nonzero().flatten()
        assert len(copies) == 2
        a, b = w_new[:, copies[0]], w_new[:, copies[1]]
        assert not torch.allclose(a, b)
        torch.testing.assert_close(a + b, w_old[g][:, old_channel], rtol=1e-5, atol=1e-6)


def test_maps_keep_copies_within_each_half_and_refuse_to_narrow():
    assert widen.channel_map(12, 8).tolist() == [0, 1, 2, 3, 0, 1, 4, 5, 6, 7, 4, 5]
    with pytest.raises(ValueError, match="narrow"):
        widen.channel_map(4, 8)
    with pytest.raises(ValueError, match="even"):
        widen.channel_map(6, 3)


def test_cli_writes_a_file_that_loads_at_the_new_width(tmp_path, capsys):
    from train_py.export import save_model

    src = tmp_path / "m.safetensors"
    model = random_folded(4, True)
    save_model(dict(model.state_dict()), model.config, src)
    out = tmp_path / "w.safetensors"
    widen.main([str(src), "--width", "6", "-o", str(out)])
    assert "width 4 → 6" in capsys.readouterr().out
    loaded = load_model(out)
    assert loaded.config.width == 6
    assert widen.params_difference(model, loaded, size=24) < widen.WIDEN_TOL
