import subprocess
import sys

import torch

from train_py import highlights, maps_net
from train_py.export import unfold_model

from .conftest import REPO

MODEL = REPO / "models" / "default.safetensors"


def test_maps_net_starts_from_the_model_files_unet_and_scores_like_the_oracle():
    # The net's U-Net computes exactly the shipped estimate; its BatchNorms stay frozen.
    net, frozen = maps_net.build(str(MODEL), width=8)
    assert frozen
    x = torch.rand(1, 4, 32, 32)
    with torch.no_grad():
        want = unfold_model(MODEL).eval().est(x)
        got = net.eval().est(x)
    assert torch.equal(got, want)
    # Its "flat normals" row is the oracle's, case for case (the same renders and peak check).
    res = maps_net.score_maps(net, size=64, count=2)
    oracle = dict((name, share) for name, share, _ in highlights.oracle(64, 2)[0])
    assert res["cases"] == 8 and res["peak flat normals"] == oracle["normals flat"]
    res["tilt_real"], res["tilt_procedural"] = maps_net.heldout_tilt(net, 1.0), maps_net.heldout_tilt(net, 0.0)
    assert all(torch.isfinite(torch.tensor(v)) for v in res.values()) and res["tilt_real"] > 0
    md = maps_net.markdown(res, "x.pt", 64)
    assert "| estimated normals |" in md and "| flat normals |" in md


def test_maps_net_training_writes_a_checkpoint_that_resumes_and_scores(tmp_path):
    cmd = [sys.executable, "-m", "train_py.maps_net", "--out", str(tmp_path), "--init-from", ""]
    cmd += ["--width", "4", "--sizes", "32", "--batch", "2", "--minutes", "0.05", "--score-every", "0"]
    subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, timeout=120)
    first = torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"]
    assert first >= 1
    cmd[cmd.index("0.05")] = "0.1"
    subprocess.run([*cmd, "--resume"], cwd=REPO, check=True, capture_output=True, timeout=120)
    assert torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] > first
    out = tmp_path / "score.md"
    scored = [sys.executable, "-m", "train_py.maps_net", "--score", str(tmp_path / "ckpt.pt"), "--size", "32"]
    subprocess.run([*scored, "-o", str(out)], cwd=REPO, check=True, capture_output=True, timeout=120)
    assert "estimated normals + roughness" in out.read_text()


def test_tilt_unexplained_is_one_for_flat_normals_and_zero_for_the_truth():
    truth = torch.nn.functional.normalize(torch.randn(2, 8, 8, 3) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    flat = torch.tensor([0.0, 0.0, 1.0]).expand_as(truth)
    assert float(maps_net.tilt_unexplained(flat, truth)) == 1.0
    assert float(maps_net.tilt_unexplained(truth, truth)) == 0.0
    assert abs(float(maps_net.tilt_unexplained(0.5 * truth, truth)) - 0.25) < 1e-6
