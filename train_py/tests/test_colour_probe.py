import dataclasses

import torch

from train_py import gen
from train_py.colour_probe import colour_probe, probe_r2
from train_py.model import CONFIGS, PARAM_CHANNELS, NamModel


def test_probe_reports_every_stage_and_finds_the_colour_in_the_photo():
    torch.manual_seed(0)
    model = NamModel(CONFIGS["tiny"]).eval()
    rows = colour_probe(model, materials=4, size=32)
    assert [r[0] for r in rows][:3] == ["input", "stem", "enc1"]
    assert len(rows) == 11 and rows[-1][:2] == ("head (params)", PARAM_CHANNELS)
    # The photo carries the albedo's colour; no stage explains more than everything.
    assert rows[0][2] > 0.5
    assert all(r2 <= 1.0 + 1e-9 for _, _, r2 in rows)


def test_probe_follows_the_input_skip_into_the_head():
    torch.manual_seed(0)
    model = NamModel(dataclasses.replace(CONFIGS["tiny"], input_skip=True)).eval()
    with torch.no_grad():
        model.est.head.weight.zero_()
        model.est.head.weight[:3, 4:7, 3, 3] = torch.eye(3)  # params 0..2 = the log RGB input
    rows = colour_probe(model, materials=4, size=32)
    assert rows[-1][0] == "head (params)" and rows[-1][2] > 0.9 * rows[0][2]


def test_probe_of_unrelated_features_is_near_zero_and_of_the_target_itself_is_one():
    maps = gen.batch([gen.HELD_OUT_SEED_BASE + 5000 + i for i in range(4)], 32, "cpu")
    diffuse = maps["diffuse"]
    chroma = (diffuse / (diffuse.sum(-1, keepdim=True) + 1e-3)).permute(0, 3, 1, 2)
    noise = torch.randn(4, 8, 32, 32, generator=torch.Generator().manual_seed(1))
    assert probe_r2(noise, chroma) < 0.05
    assert probe_r2(chroma, chroma) > 0.999
    # Half resolution: the target is pooled to the features' size.
    assert probe_r2(torch.nn.functional.avg_pool2d(chroma, 2), chroma) > 0.999
