"""Average model files weight by weight (a "model soup": Wortsman et al. 2022, uniform soup).

    python -m train_py.average runs/a.safetensors runs/b.safetensors -o runs/soup.safetensors --dtype f16

The files must share one network (the same config and tensor names and shapes), e.g. runs
fine-tuned from one model file with different seeds; the mean is taken over the folded f32
weights (``export.load_model``), so it is the average of what each file computes its layers
with. Nothing checks that averaging is wise: evaluate the result like any other model.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from .export import DTYPES, fold_state_dict, load_model, read_config, save_model
from .model import ModelConfig


def average_models(paths: list[str | Path]) -> tuple[dict[str, torch.Tensor], dict]:
    """Mean folded f32 tensors of the model files at ``paths`` and the first file's config."""
    if len(paths) < 2:
        raise ValueError("averaging needs at least two model files")
    models = [load_model(p) for p in paths]
    first = models[0].config
    for path, model in zip(paths[1:], models[1:], strict=True):
        if model.config != first:
            raise ValueError(f"{path}: {model.config} differs from {paths[0]}: {first}")
    states = [fold_state_dict(m) for m in models]
    mean = {k: torch.stack([s[k] for s in states]).mean(0) for k in states[0]}
    return mean, read_config(paths[0])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", help="model files (.safetensors) of one network")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--dtype", choices=sorted(DTYPES), default="f32")
    args = ap.parse_args(argv)
    try:
        mean, cfg = average_models(args.models)
    except ValueError as e:
        raise SystemExit(f"train_py.average: {e}") from None
    extra = {"train": {**cfg.get("train", {}), "averaged_from": [Path(p).name for p in args.models]}}
    save_model(mean, ModelConfig.from_json_dict(cfg), args.output, args.dtype, extra)
    print(f"wrote {args.output}: the mean of {len(args.models)} models ({args.dtype})")


if __name__ == "__main__":
    main()
