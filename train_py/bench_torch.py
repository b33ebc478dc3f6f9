"""PyTorch CPU timings of the same work as `cargo bench -p nam-model --bench cpu`.

Same model structure (train_py.model), same sizes, same thread count (2 by default),
random weights, f32, eval mode, no autograd. Prints best-of-N milliseconds:

    .venv/bin/python -m train_py.bench_torch [--threads 2] [--reps 3]
"""

from __future__ import annotations

import argparse
import time

import torch

from train_py.model import ModelConfig, NamModel, query_dirs

CAPTURE_DISTANCE = 4.010781


def best_ms(fn, reps: int) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def pixel_dirs(size: int, light: tuple[float, float, float], view: tuple[float, float, float]):
    """Per-pixel (wi, wo) [1, H, W, 3] per DESIGN §3."""
    idx = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    y = 1.0 - 2.0 * idx
    x = 2.0 * idx - 1.0
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    p = torch.stack([xx, yy, torch.zeros_like(xx)], dim=-1)

    def unit(target):
        d = torch.tensor(target, dtype=torch.float32) - p
        return (d / d.norm(dim=-1, keepdim=True)).unsqueeze(0)

    return unit(light), unit(view)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    s = args.size

    n = 1024
    a, b = torch.rand(n, n), torch.rand(n, n)
    ms = best_ms(lambda: torch.mm(a, b), args.reps + 2)
    print(f"sgemm_1024: {ms:.2f} ms  ({2 * n**3 / ms / 1e6:.1f} GFLOP/s)")

    with torch.inference_mode():
        model = NamModel(ModelConfig(width=8)).eval()
        params = torch.rand(1, 64, s, s) * 2 - 1
        wi, wo = pixel_dirs(s, (1.5, 1.0, 3.5), (0.0, 0.0, CAPTURE_DISTANCE))
        ms = best_ms(lambda: model.relight_log(params, wi, wo), args.reps)
        print(f"relight_{s} (chunked relight_log): {ms:.1f} ms")
        p = params.permute(0, 2, 3, 1).reshape(-1, 64)
        dirs = query_dirs(wi.reshape(-1, 3), wo.reshape(-1, 3))
        ms = best_ms(lambda: model.render_log(p, dirs), args.reps)
        print(f"relight_{s} (one eager batch): {ms:.1f} ms")

        x = torch.rand(1, 4, s, s)
        # The shipped architecture (C = 8, head with the input skip), and C = 16.
        for width in (8, 16):
            m = NamModel(ModelConfig(width=width, input_skip=True)).eval()
            ms = best_ms(lambda m=m: m.estimate(x), args.reps)
            print(f"estimate_{s}_c{width}_input_skip: {ms:.1f} ms")


if __name__ == "__main__":
    main()
