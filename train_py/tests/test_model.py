"""Network structure, positional encoding, BN folding/export round trip and the net_tiny golden."""

import json
import math

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file

from train_py import golden
from train_py.export import fold_state_dict, load_model, read_config, save_model, unfold_model
from train_py.model import ModelConfig, NamModel, positional_encoding, replicate_pad_by_cat

from .conftest import FIXTURES

#: f32 conv stacks (≈60 layers) vs a folded re-association of the same math.
FOLD_ATOL = 2e-4
#: f16 weights: relative rounding 2^-11 per weight, accumulated through the U-Net.
F16_ATOL = 5e-2
#: f32 forward vs the float64 fixture (same weights): accumulated f32 rounding only.
GOLDEN_F32_ATOL = 5e-4
GOLDEN_F32_RTOL = 1e-4


def test_paper_sized_model_has_papers_render_and_nd_enc_counts():
    m = NamModel(ModelConfig(width=8))
    assert sum(p.numel() for p in m.nd_enc.parameters()) == 548_262
    assert sum(p.numel() for p in m.render.parameters()) == 86_208


def test_unet_output_keeps_odd_input_size():
    m = NamModel(ModelConfig(width=4)).eval()
    with torch.no_grad():
        out = m.estimate(torch.rand(2, 4, 21, 35))
    assert out.shape == (2, 64, 21, 35)


def test_folded_state_dict_names_and_shapes_follow_format_md():
    c = 4
    sd = fold_state_dict(NamModel(ModelConfig(width=c)).eval())
    assert sd["est.stem.weight"].shape == (c, 4, 7, 7)
    assert sd["est.head.weight"].shape == (64, c, 7, 7)
    assert sd["est.enc1.0.ha1.gate.weight"].shape == (c, c, 3, 3)
    assert sd["est.enc2.0.ha1.inc1b.weight"].shape == (c, 2 * c, 3, 3)
    assert sd["est.enc2.0.ha1.inc2.weight"].shape == (c, c, 3, 3)
    assert sd["est.enc2.0.down.weight"].shape == (2 * c, c, 1, 1)
    assert sd["est.enc2.0.down.bias"].shape == (2 * c,)
    assert sd["est.enc1.0.bn1.scale"].shape == (c,)
    assert "est.enc1.0.down.weight" not in sd
    assert sd["est.dec1.0.up4.weight"].shape == (8 * c, 8 * c, 4, 4)
    assert sd["est.dec2.0.up4.weight"].shape == (12 * c, 4 * c, 4, 4)
    assert sd["est.dec2.0.up2.weight"].shape == (12 * c, 4 * c, 2, 2)
    assert sd["est.dec3.0.conv.bias"].shape == (2 * c,)
    assert sd["est.dec4.0.down.weight"].shape == (c, 3 * c, 1, 1)
    assert sd["nd_enc.l0.weight"].shape == (594, 297)
    assert sd["render.l0.weight"].shape == (128, 96)
    assert sd["render.l6.weight"].shape == (3, 64)
    assert not any("running" in k or "num_batches" in k for k in sd)


@pytest.mark.parametrize("pad", [(1, 1, 1, 1), (3, 3, 3, 3), (0, 5, 0, 2)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_replicate_pad_by_cat_equals_torch_replicate_pad_with_its_gradient(pad, channels_last):
    g = torch.Generator().manual_seed(5)
    x = torch.randn(2, 3, 6, 7, generator=g)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    a = x.clone().requires_grad_(True)
    b = x.clone().requires_grad_(True)
    want = torch.nn.functional.pad(a, pad, mode="replicate")
    got = replicate_pad_by_cat(b, pad)
    assert torch.equal(got, want)
    up = torch.randn(want.shape, generator=g)
    (want * up).sum().backward()
    (got * up).sum().backward()
    # Each input pixel's gradient sums the same (up to 3 × 5 + 1) terms, in another order.
    torch.testing.assert_close(b.grad, a.grad, rtol=1e-6, atol=1e-6)


def test_positional_encoding_order_and_exact_range_reduction():
    dirs = (torch.rand(50, 9, dtype=torch.float64) * 2 - 1).float().double()
    enc = positional_encoding(dirs.float())
    assert enc.shape == (50, 297)
    ref = [dirs]
    for k in range(16):
        arg = (2.0**k) * math.pi * dirs
        ref.append(torch.stack([torch.sin(arg), torch.cos(arg)], dim=-1).reshape(50, 18))
    ref = torch.cat(ref, dim=-1)
    # f32 input is exact; reduced arguments lose only ~1 ulp of 2π·t, so 2^15·π·c stays accurate.
    torch.testing.assert_close(enc.double(), ref.float().double(), rtol=0, atol=2e-6)
    naive = torch.sin(2.0**15 * math.pi * dirs.float())
    assert (naive.double() - ref[:, 9 + 18 * 15 : 9 + 18 * 16 : 2]).abs().max() > 1e-3  # why the reduction exists


def random_bn_model(width: int = 4, seed: int = 3, input_skip: bool = False) -> NamModel:
    torch.manual_seed(seed)
    m = NamModel(ModelConfig(width=width, input_skip=input_skip))
    with torch.no_grad():
        golden.randomize_batchnorm(m, torch.Generator().manual_seed(seed))
    return m.eval()


def test_folded_model_matches_training_model_in_eval_mode(tmp_path):
    m = random_bn_model()
    path = tmp_path / "m.safetensors"
    save_model(fold_state_dict(m), m.config, path, "f32")
    folded = load_model(path)
    x = torch.rand(1, 4, 19, 30)
    with torch.no_grad():
        ref, out = m.estimate(x), folded.estimate(x)
    assert ref.abs().max() > 0.1
    torch.testing.assert_close(out, ref, rtol=0, atol=FOLD_ATOL)
    dirs = torch.nn.functional.normalize(torch.randn(40, 9), dim=-1)
    p = torch.randn(40, 64)
    with torch.no_grad():
        torch.testing.assert_close(folded.render_log(p, dirs), m.render_log(p, dirs))


def test_input_skip_head_sees_the_input_and_survives_export(tmp_path):
    m = random_bn_model(input_skip=True)
    assert m.est.head.weight.shape == (64, 4 + 4, 7, 7)
    path = tmp_path / "s.safetensors"
    save_model(fold_state_dict(m), m.config, path, "f32")
    assert read_config(path)["input_skip"] is True
    folded = load_model(path)
    assert folded.config.input_skip
    x = torch.rand(1, 4, 19, 30)
    with torch.no_grad():
        ref = m.estimate(x)
        torch.testing.assert_close(folded.estimate(x), ref, rtol=0, atol=FOLD_ATOL)
        # Only the skip's weights on the input change the output through that path.
        m.est.head.weight[:, 4:] = 0
        without = m.estimate(x)
    assert (ref - without).abs().max() > 1e-3
    # A config written before the flag existed reads as no skip.
    cfg = read_config(FIXTURES / "net_tiny.safetensors")
    cfg.pop("input_skip", None)
    assert ModelConfig.from_json_dict(cfg).input_skip is False


def test_unfolded_model_file_computes_what_the_file_does_and_folds_back_to_it(tmp_path):
    m = random_bn_model()
    path = tmp_path / "m.safetensors"
    save_model(fold_state_dict(m), m.config, path, "f32")
    folded, unfolded = load_model(path), unfold_model(path)
    bns = [mod for mod in unfolded.modules() if isinstance(mod, torch.nn.BatchNorm2d)]
    assert bns and not any(bn.training for bn in bns)
    x = torch.rand(1, 4, 19, 30)
    with torch.no_grad():
        ref, out = folded.estimate(x), unfolded.estimate(x)
    assert ref.abs().max() > 0.1
    torch.testing.assert_close(out, ref, rtol=0, atol=FOLD_ATOL)
    refolded = fold_state_dict(unfolded)
    for name, t in load_model(path).state_dict().items():
        torch.testing.assert_close(refolded[name], t, rtol=1e-6, atol=1e-7)


def test_f16_export_is_half_precision_and_close_to_f32(tmp_path):
    m = random_bn_model()
    save_model(fold_state_dict(m), m.config, tmp_path / "h.safetensors", "f16", {"train": {"step": 1}})
    with safe_open(str(tmp_path / "h.safetensors"), framework="pt") as f:
        assert f.get_tensor("render.l0.weight").dtype == torch.float16
    cfg = read_config(tmp_path / "h.safetensors")
    assert cfg["dtype"] == "f16" and cfg["bn_folded"] is True and cfg["train"] == {"step": 1}
    x = torch.rand(1, 4, 16, 16)
    with torch.no_grad():
        torch.testing.assert_close(
            load_model(tmp_path / "h.safetensors").estimate(x), m.estimate(x), rtol=0, atol=F16_ATOL
        )


def test_config_metadata_has_every_format_md_key():
    cfg = read_config(FIXTURES / "net_tiny.safetensors")
    for key in (
        "format",
        "version",
        "width",
        "in_channels",
        "param_channels",
        "log_mode",
        "pe_octaves",
        "nd_enc",
        "render",
        "slopes",
        "norm_eps",
        "bn_folded",
        "dtype",
    ):
        assert key in cfg
    assert cfg["width"] == 4 and cfg["dtype"] == "f32" and cfg["nd_enc"] == [297, 594, 594, 32]
    assert json.loads(json.dumps(cfg)) == cfg


def test_net_tiny_fixture_is_the_seeded_model_folded():
    fixture = load_file(str(FIXTURES / "net_tiny.safetensors"))
    fresh = fold_state_dict(golden.tiny_model())
    assert set(fixture) == set(fresh)
    for k in fixture:
        torch.testing.assert_close(fixture[k], fresh[k], rtol=0, atol=0)


def test_folded_model_f32_reproduces_net_tiny_golden():
    g = load_file(str(FIXTURES / "net_tiny_golden.safetensors"))
    m = load_model(FIXTURES / "net_tiny.safetensors")
    from train_py import ggx

    with torch.no_grad():
        inp = ggx.network_input(g["photo"][None], "ldr")[0]
        torch.testing.assert_close(inp, g["input"], rtol=1e-6, atol=1e-6)
        params = m.estimate(g["input"][None])[0]
        torch.testing.assert_close(params, g["params"], rtol=GOLDEN_F32_RTOL, atol=GOLDEN_F32_ATOL)
        enc = positional_encoding(g["r_dirs"])
        torch.testing.assert_close(enc, g["r_encoded"], rtol=0, atol=2e-6)
        nd = m.nd_enc(g["r_encoded"])
        torch.testing.assert_close(nd, g["r_nd"], rtol=GOLDEN_F32_RTOL, atol=GOLDEN_F32_ATOL)
        log = m.render_log(g["r_params"], g["r_dirs"])
        torch.testing.assert_close(log, g["r_log"], rtol=GOLDEN_F32_RTOL, atol=GOLDEN_F32_ATOL)
        torch.testing.assert_close(ggx.from_log(log), g["r_radiance"], rtol=1e-3, atol=1e-3)


@pytest.mark.skipif(not (FIXTURES / "net_default_golden.safetensors").exists(), reason="no shipped-model golden yet")
def test_shipped_default_model_reproduces_its_golden():
    from pathlib import Path

    model_path = Path(__file__).resolve().parents[2] / "models" / "default.safetensors"
    g = load_file(str(FIXTURES / "net_default_golden.safetensors"))
    m = load_model(model_path)
    with torch.no_grad():
        params = m.estimate(g["input"][None])[0]
        torch.testing.assert_close(params, g["params"], rtol=GOLDEN_F32_RTOL, atol=GOLDEN_F32_ATOL)
        log = m.render_log(g["r_params"], g["r_dirs"])
        torch.testing.assert_close(log, g["r_log"], rtol=GOLDEN_F32_RTOL, atol=GOLDEN_F32_ATOL)
