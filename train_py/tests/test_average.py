"""train_py.average: the mean of model files, weight by weight, and its refusals."""

import subprocess
import sys

import pytest
import torch

from train_py.average import average_models
from train_py.export import fold_state_dict, load_model, save_model
from train_py.model import CONFIGS, IN_CHANNELS, ModelConfig, NamModel

from .conftest import REPO


def saved(tmp_path, name: str, config: ModelConfig, seed: int):
    torch.manual_seed(seed)
    model = NamModel(config).eval()
    path = tmp_path / f"{name}.safetensors"
    save_model(fold_state_dict(model), model.config, path, "f32")
    return path


def test_the_soup_is_the_weightwise_mean_and_runs(tmp_path):
    a, b, c = (saved(tmp_path, n, CONFIGS["tiny"], s) for n, s in (("a", 1), ("b", 2), ("c", 3)))
    mean, cfg = average_models([a, b, c])
    ws = [load_model(p).render.l1.weight for p in (a, b, c)]
    torch.testing.assert_close(mean["render.l1.weight"], (ws[0] + ws[1] + ws[2]) / 3)
    assert cfg["width"] == CONFIGS["tiny"].width
    out = tmp_path / "soup.safetensors"
    subprocess.run(
        [sys.executable, "-m", "train_py.average", str(a), str(b), "-o", str(out), "--dtype", "f16"],
        cwd=REPO,
        check=True,
        capture_output=True,
        timeout=120,
    )
    soup = load_model(out)
    torch.testing.assert_close(soup.render.l1.weight, (ws[0] + ws[1]) / 2, rtol=1e-3, atol=1e-3)
    x = torch.rand(1, IN_CHANNELS, 16, 16)
    assert torch.isfinite(soup.estimate(x)).all()


def test_files_of_different_networks_or_one_file_are_refused(tmp_path):
    a = saved(tmp_path, "a", CONFIGS["tiny"], 1)
    wide = saved(tmp_path, "wide", ModelConfig(width=CONFIGS["tiny"].width * 2), 2)
    with pytest.raises(ValueError, match="differs"):
        average_models([a, wide])
    with pytest.raises(ValueError, match="at least two"):
        average_models([a])
    run = subprocess.run(
        [sys.executable, "-m", "train_py.average", str(a), str(wide), "-o", str(tmp_path / "x.safetensors")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode != 0 and "differs" in run.stderr and not (tmp_path / "x.safetensors").exists()
