"""The lean PyTorch relight of bench_torch computes what the training code computes."""

import torch

from train_py.bench_torch import LeanRelight, pixel_dirs
from train_py.model import ModelConfig, NamModel, query_dirs

#: f32 reassociation (split first layer, transposed weights) over 7 layers.
LEAN_TOL = 1e-4


def test_lean_relight_matches_relight_log():
    torch.manual_seed(3)
    model = NamModel(ModelConfig(width=8)).eval()
    params = torch.rand(1, 64, 24, 24) * 2 - 1
    wi, wo = pixel_dirs(24, (1.5, 1.0, 3.5), (0.3, -0.2, 4.0))
    with torch.inference_mode():
        ref = model.relight_log(params, wi, wo).reshape(-1, 3)
        p = params.permute(0, 2, 3, 1).reshape(-1, 64)
        dirs = query_dirs(wi.reshape(-1, 3), wo.reshape(-1, 3))
        out = LeanRelight(model).run(p, dirs, chunk=100)  # chunks that do not divide 576
    assert out.shape == ref.shape
    assert (out - ref).abs().max().item() < LEAN_TOL * max(1.0, ref.abs().max().item())
