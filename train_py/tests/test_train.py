"""Training pieces: Reflect sampling, pixel selection, loss decrease, DDP with one process, evaluation."""

import os
import subprocess
import sys

import torch

from train_py import ggx, protocols
from train_py.evaluate import evaluate_protocols, ssim
from train_py.model import CONFIGS, NamModel
from train_py.train import TrainStep, make_batch, select_pixels

from .conftest import REPO


def test_reflect_sampling_puts_mirror_highlight_at_sampled_point():
    g = torch.Generator().manual_seed(1)
    light, view = protocols.reflect(g, 3, 50)
    assert (light[..., 2] > 0).all() and (view[..., 2] >= 0).all()
    torch.testing.assert_close(torch.linalg.vector_norm(view, dim=-1), torch.full((3, 50), ggx.CAPTURE_DISTANCE))
    # p is where the view → mirrored-light line crosses z = 0; there the mirror condition must hold.
    t = view[..., 2] / (view[..., 2] + light[..., 2])
    p = view + t[..., None] * (light - view)
    p[..., 2] = 0.0
    wi, wo = ggx.normalize(light - p), ggx.normalize(view - p)
    torch.testing.assert_close(wi[..., :2], -wo[..., :2], atol=1e-4, rtol=0)
    dist = torch.linalg.vector_norm(light - p, dim=-1)
    assert dist.min() >= protocols.REFLECT_MIN_DIST - 1e-4


def test_hemisphere_protocol_positions_lie_on_radius_4():
    light, view = protocols.hemisphere(torch.Generator().manual_seed(2), 2, 64)
    torch.testing.assert_close(torch.linalg.vector_norm(light, dim=-1), torch.full((2, 64), 4.0))
    assert (view[..., 2] >= 0).all()


def test_pixel_selection_prefers_low_norm_params_without_repeats():
    params = torch.ones(1, 64, 8, 8)
    params[:, :, :4] *= 100.0  # top half: "garbage" high-norm parameters
    idx = select_pixels(params, 4, 0.25, torch.Generator().manual_seed(0))
    assert idx.shape == (1, 4, 16)
    for k in range(4):
        assert len(set(idx[0, k].tolist())) == 16
    assert (idx >= 32).float().mean() > 0.9


def test_a_few_training_steps_lower_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    model = NamModel(CONFIGS["tiny"])
    step = TrainStep(model)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    maps, net_input = make_batch([11, 12], 32, "cpu")
    g = torch.Generator().manual_seed(0)
    light, view = protocols.reflect(g, 2, 2)
    losses = []
    for _ in range(12):
        pred, target = step(net_input, 2, 0.6, torch.Generator().manual_seed(5), maps, light, view)
        loss = (pred - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert sum(losses[-4:]) / 4 < 0.4 * losses[0]


def test_torchrun_single_process_trains_and_writes_checkpoint(tmp_path):
    env = dict(os.environ, WORLD_SIZE="1", RANK="0", LOCAL_RANK="0", MASTER_ADDR="127.0.0.1", MASTER_PORT="29517")
    cmd = [
        sys.executable,
        "-m",
        "train_py.train",
        "--config",
        "tiny",
        "--steps",
        "2",
        "--size",
        "32",
        "--batch",
        "2",
        "--outputs",
        "2",
        "--out",
        str(tmp_path),
        "--val-every",
        "0",
        "--threads",
        "1",
    ]
    subprocess.run(cmd, cwd=REPO, env=env, check=True, capture_output=True, timeout=120)
    ckpt = torch.load(tmp_path / "ckpt.pt", weights_only=False)
    assert ckpt["step"] == 2
    resumed = subprocess.run(
        [*cmd[:6], "3", *cmd[7:], "--resume"],
        cwd=REPO,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "resumed" in resumed.stdout
    assert torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] == 3


def test_ssim_is_one_for_identical_and_lower_for_noisy_images():
    a = torch.rand(1, 24, 24, 3)
    assert abs(float(ssim(a, a)) - 1.0) < 1e-5
    assert float(ssim(a, (a + 0.3 * torch.rand_like(a)).clamp(0, 1))) < 0.97
    assert float(ssim(a, torch.rand_like(a))) < 0.2


def test_evaluation_baselines_are_exact_where_they_should_be():
    res = evaluate_protocols(None, [1_000_000_123], 24, hemisphere_k=2, reflect_k=2, protocol_names=("identity",))
    # Identity re-creates the capture, so the printout error is only the LDR clamp + 8-bit rounding.
    assert res["identity"]["printout"]["log_l1"] < 0.05
