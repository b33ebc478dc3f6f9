"""The evaluation golden: ``train_py.evaluate``'s pairs and scores that ``nam-cli report`` must
reproduce (issue 18 item 8).

    python -m train_py.eval_agreement     # writes tests/fixtures/eval_agreement.safetensors

Both sides read the held-out files of ``assets/heldout`` (here box-downsampled to ``SIZE``² in
linear space, as nam-eval does) and draw their light/view pairs from one seeded definition
(``protocols.seeded_pairs`` = nam-ggx's ``ProtocolSampler``). ``crates/nam-eval/tests/
eval_agreement.rs`` checks the pairs to 1e-12 and the Rust runner's per-protocol log-L1 and SSIM
of the printout, the diffuse fit and ``MODEL`` (nam's CPU path) to named tolerances.

Stored (float64): ``pairs.{protocol}.{i}`` ``[n, 6]`` (light xyz, view xyz) of material ``i``;
``scores`` ``[protocol, method, metric]`` in the orders of ``PROTOCOLS``, ``METHODS``, ``METRICS``.
The metadata names the model, size and counts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from safetensors.torch import save_file

from . import protocols
from .evaluate import evaluate_maps, heldout_sets, pair_seed
from .export import load_model

REPO = Path(__file__).resolve().parent.parent
#: A model that does not change when the shipped one does.
MODEL = "models/tiny.safetensors"
MATERIALS = 2
#: A divisor of the files' 64²: the downsampling is part of what both sides must agree on.
SIZE = 32
COUNTS = {"reflect": 3, "identity": 1, "hemisphere": 4}
METHODS = ("printout", "diffuse fit", "model")
METRICS = ("log_l1", "ssim")
OUT = REPO / "tests" / "fixtures" / "eval_agreement.safetensors"


def compute() -> dict[str, torch.Tensor]:
    """The fixture's tensors (deterministic)."""
    torch.manual_seed(0)
    model = load_model(str(REPO / MODEL))
    sets = list(heldout_sets(MATERIALS, SIZE))
    tensors = {}
    for i, (seed, _) in enumerate(sets):
        for p in protocols.PROTOCOLS:
            light, view = protocols.seeded_pairs(p, COUNTS[p], pair_seed(seed, p))
            tensors[f"pairs.{p}.{i}"] = torch.cat([light[0], view[0]], dim=-1)
    res = evaluate_maps(model, sets, len(sets), COUNTS["hemisphere"], COUNTS["reflect"])
    tensors["scores"] = torch.tensor(
        [[[res[p][m][k] for k in METRICS] for m in METHODS] for p in protocols.PROTOCOLS], dtype=torch.float64
    )
    return tensors


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default=str(OUT))
    args = ap.parse_args(argv)
    tensors = compute()
    meta = {
        "model": MODEL,
        "materials": str(MATERIALS),
        "size": str(SIZE),
        **{f"count.{p}": str(n) for p, n in COUNTS.items()},
        "protocols": ",".join(protocols.PROTOCOLS),
        "methods": ",".join(METHODS),
        "metrics": ",".join(METRICS),
    }
    save_file({k: v.contiguous() for k, v in tensors.items()}, args.output, metadata=meta)
    for pi, p in enumerate(protocols.PROTOCOLS):
        print(p, "  ".join(f"{m} {tensors['scores'][pi, mi, 0]:.5f}" for mi, m in enumerate(METHODS)))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
