"""Is bf16 autocast faster for training on this CPU? Interleaved timing of one training step.

    python -m train_py.bench_bf16 [--threads 1] [--rounds 3]

The answer depends on the machine (AMX / AVX-512 BF16 or not), so ``train --bf16`` is a choice to
make per machine with this script: it alternates f32 and bf16 steps (C = 8 with the input skip,
batch 8 at 64², shared geometry) so that other load on the machine affects both alike, and prints
the best time of each plus a 2048³ GEMM in both precisions.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import torch

from . import protocols
from .model import CONFIGS, NamModel
from .train import TrainStep, make_batch


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    for dtype in (torch.float32, torch.bfloat16):
        a, b = torch.randn(2048, 2048, dtype=dtype), torch.randn(2048, 2048, dtype=dtype)
        a @ b
        t0 = time.perf_counter()
        for _ in range(3):
            a @ b
        print(f"gemm 2048³ {dtype}: {(time.perf_counter() - t0) / 3 * 1e3:.1f} ms")
    torch.manual_seed(0)
    model = NamModel(dataclasses.replace(CONFIGS["small"], input_skip=True))
    step = TrainStep(model, shared_geometry=True)
    opt = torch.optim.Adam(model.parameters())
    maps, net_input = make_batch(list(range(8)), 64, "cpu")
    gen = torch.Generator().manual_seed(0)
    light, view = protocols.reflect(gen, 1, 4)

    def timed(bf16: bool) -> float:
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            pred, target = step(net_input, 4, 0.4, gen, maps, light, view)
        loss = (pred.float() - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        return time.perf_counter() - t0

    best = {False: float("inf"), True: float("inf")}
    for _ in range(args.rounds):
        for bf16 in (False, True):
            best[bf16] = min(best[bf16], *(timed(bf16) for _ in range(3)))
    print(f"train step f32 {best[False]:.2f} s, bf16 autocast {best[True]:.2f} s: {best[False] / best[True]:.2f}×")


if __name__ == "__main__":
    main()
