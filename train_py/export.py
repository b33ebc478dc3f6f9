"""Checkpoint → safetensors model file with BatchNorm folded (docs/FORMAT.md), and its loader.

python -m train_py.export runs/small/ckpt.pt -o models/default.safetensors --dtype f16
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import nn

from .model import NORM_EPS, Conv, ConvBN, ModelConfig, NamModel

DTYPES = {"f32": torch.float32, "f16": torch.float16}
F16_MAX = 65504.0


def bn_scale_shift(bn: nn.BatchNorm2d) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode BatchNorm as ``y = x·scale + shift`` (running statistics, float64 math)."""
    var = bn.running_var.double()
    scale = bn.weight.detach().double() / torch.sqrt(var + bn.eps)
    shift = bn.bias.detach().double() - bn.running_mean.double() * scale
    return scale, shift


def fold_state_dict(model: NamModel) -> dict[str, torch.Tensor]:
    """Folded f32 tensors of an unfolded (training) model, named exactly as FORMAT.md."""
    if model.folded:
        return {k: v.detach().float().clone() for k, v in model.state_dict().items()}
    out: dict[str, torch.Tensor] = {}
    for name, mod in model.named_modules():
        prefix = f"{name}." if name else ""
        if isinstance(mod, ConvBN):
            scale, shift = bn_scale_shift(mod.bn)
            w = mod.weight.detach().double()
            # conv weights are [out, in, k, k], transposed-conv weights [in, out, k, k]
            w = w * (scale[:, None, None, None] if mod.kind == "conv" else scale[None, :, None, None])
            out[prefix + "weight"] = w.float()
            out[prefix + "bias"] = shift.float()
        elif isinstance(mod, nn.BatchNorm2d) and not name.endswith(".bn"):
            scale, shift = bn_scale_shift(mod)
            out[prefix + "scale"] = scale.float()
            out[prefix + "shift"] = shift.float()
        elif isinstance(mod, (Conv, nn.Linear)):
            out[prefix + "weight"] = mod.weight.detach().float().clone()
    expected = set(NamModel(model.config, folded=True).state_dict().keys())
    if set(out) != expected:
        raise RuntimeError(f"fold mismatch: missing {sorted(expected - set(out))}, extra {sorted(set(out) - expected)}")
    return out


def unfold_model(path: str | Path) -> NamModel:
    """A training (unfolded) model that computes exactly what the model file at ``path`` does
    once its BatchNorms are in eval mode: every BN gets running mean 0, running variance
    ``1 − eps`` (so it divides by exactly 1), weight 1 (or the folded ``scale``) and bias = the
    folded ``bias``/``shift``. Fine-tuning keeps those BNs in eval mode (``freeze_batchnorm``):
    batch statistics would renormalise what the folded weights already normalise."""
    folded = load_model(path)
    model = NamModel(folded.config, folded=False)
    src = dict(folded.state_dict())
    dst: dict[str, torch.Tensor] = {}
    for name, mod in model.named_modules():
        prefix = f"{name}." if name else ""
        if isinstance(mod, (Conv, nn.Linear, ConvBN)):
            dst[prefix + "weight"] = src[prefix + "weight"]
        if isinstance(mod, ConvBN):
            bn, scale, shift = prefix + "bn.", torch.ones_like(src[prefix + "bias"]), src[prefix + "bias"]
        elif isinstance(mod, nn.BatchNorm2d) and not name.endswith(".bn"):
            bn, scale, shift = prefix, src[prefix + "scale"], src[prefix + "shift"]
        else:
            continue
        dst[bn + "weight"] = scale
        dst[bn + "bias"] = shift
        dst[bn + "running_mean"] = torch.zeros_like(shift)
        dst[bn + "running_var"] = torch.full_like(shift, 1.0 - NORM_EPS)
        dst[bn + "num_batches_tracked"] = torch.tensor(0)
    model.load_state_dict(dst, strict=True)
    return freeze_batchnorm(model.eval())


def freeze_batchnorm(model: NamModel) -> NamModel:
    """Puts every BatchNorm of ``model`` in eval mode (running statistics, not updated); call
    after each ``model.train()``. Their affine weights still train."""
    for mod in model.modules():
        if isinstance(mod, nn.BatchNorm2d):
            mod.eval()
    return model


def save_model(
    tensors: dict[str, torch.Tensor],
    config: ModelConfig,
    path: str | Path,
    dtype: str = "f32",
    extra: dict | None = None,
) -> None:
    """Write a FORMAT.md model file; ``extra`` (e.g. ``{"train": {...}}``) is merged into the config."""
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}")
    if dtype == "f16":
        worst = max(float(t.abs().max()) for t in tensors.values())
        if worst > F16_MAX:
            raise ValueError(f"a weight of magnitude {worst:g} does not fit in f16")
    cfg = config.to_json_dict(dtype=dtype, bn_folded=True)
    if extra:
        cfg.update(extra)
    conv = {k: v.to(DTYPES[dtype]).contiguous() for k, v in tensors.items()}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_file(conv, str(path), metadata={"config": json.dumps(cfg)})


def read_config(path: str | Path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
    if "config" not in meta:
        raise ValueError(f"{path}: no __metadata__ config")
    return json.loads(meta["config"])


def load_model(path: str | Path, device: str = "cpu") -> NamModel:
    """Rebuild the folded inference model (f32, eval mode) from a model file."""
    cfg = read_config(path)
    config = ModelConfig.from_json_dict(cfg)
    model = NamModel(config, folded=True)
    with safe_open(str(path), framework="pt") as f:
        tensors = {k: f.get_tensor(k).float() for k in f.keys()}  # noqa: SIM118 (safe_open is not iterable)
    model.load_state_dict(tensors, strict=True)
    return model.to(device).eval()


def load_checkpoint(path: str | Path, averaged: bool = False) -> tuple[NamModel, dict]:
    """Unfolded training model (eval mode) and the raw checkpoint dict; ``averaged``: the run's
    moving average of the weights (``train --weight-ema``) instead of its last weights."""
    ckpt = torch.load(str(path), map_location="cpu", weights_only=False)
    model = NamModel(ModelConfig(**ckpt["config"]), folded=False)
    if averaged:
        if "averaged" not in ckpt:
            raise SystemExit(f"{path}: no averaged weights (the run had no --weight-ema)")
        # AveragedModel's state: the wrapped model's under "module." plus its update count.
        avg = ckpt["averaged"]
        model.load_state_dict({k.removeprefix("module."): v for k, v in avg.items() if k.startswith("module.")})
    else:
        model.load_state_dict(ckpt["model"])
    return model.eval(), ckpt


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--dtype", choices=sorted(DTYPES), default="f32")
    ap.add_argument(
        "--averaged", action="store_true", help="export the moving average of the weights (train --weight-ema)"
    )
    args = ap.parse_args(argv)
    model, ckpt = load_checkpoint(args.checkpoint, args.averaged)
    extra = {"train": {k: ckpt[k] for k in ("step", "loss", "minutes") if k in ckpt}}
    if args.averaged:
        extra["train"]["weight_ema"] = True
    save_model(fold_state_dict(model), model.config, args.output, args.dtype, extra)
    size = Path(args.output).stat().st_size
    print(f"wrote {args.output} ({size / 1e6:.2f} MB, {args.dtype}, width {model.config.width})")


if __name__ == "__main__":
    main()
