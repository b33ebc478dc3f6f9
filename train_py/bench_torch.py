"""PyTorch CPU timings of the same work as `nam-cli bench` / `cargo bench -p nam-model --bench cpu`.

Same networks (train_py.model), same sizes, same thread count (2 by default), random weights, eval
mode, `inference_mode`. Each job is timed in several PyTorch variants, so that nam is compared
with the fastest PyTorch we can write, not with the training code:

- relight (point light, ND_enc and the render MLP per pixel): the training code's `relight_log`
  (16384-row chunks); a lean pipeline (weights pre-transposed, `addmm`/`mm` into the chunk,
  in-place LeakyReLU, the render MLP's first layer split so `cat` disappears) at several chunk
  sizes; the same in bf16 (weights and activations); `torch.compile` of the lean chunk.
- estimate (the U-Net, C = 8 and 16 with the input skip): eager NCHW, channels-last, bf16
  autocast (channels-last), `torch.compile`.

Every variant's output is checked against the f32 eager one (`max |Δ|`, printed; bf16 is
an approximation and says so). Prints best-of-N milliseconds per variant and, per job, the
fastest f32 variant and the fastest of all:

    .venv/bin/python -m train_py.bench_torch [--threads 2] [--reps 3] [--size 256] [--no-compile]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from train_py.model import (
    ND_SLOPE,
    RENDER_HIDDEN_SLOPE,
    RENDER_OUT_SLOPE,
    ModelConfig,
    NamModel,
    positional_encoding,
    query_dirs,
)

CAPTURE_DISTANCE = 4.010781
#: Chunk sizes (pixels) of the lean relight pipeline.
CHUNKS = (1024, 4096, 16384)


def best_ms(fn: Callable[[], object], reps: int) -> float:
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


class LeanRelight:
    """ND_enc + render MLP per query row, written for inference speed.

    Weights are transposed once (``x @ Wᵀ`` becomes a plain ``mm``), the render MLP's first layer
    is split into its params and ND_enc columns (``p·W_pᵀ + nd·W_ndᵀ``, no ``cat``), every
    LeakyReLU runs in place, and each chunk's output is written into one preallocated tensor.
    """

    def __init__(self, model: NamModel, dtype: torch.dtype = torch.float32):
        nd, r = model.nd_enc, model.render
        t = lambda w: w.detach().t().contiguous().to(dtype)  # noqa: E731
        self.dtype = dtype
        self.nd = [t(nd.l0.weight), t(nd.l1.weight), t(nd.l2.weight)]
        w0 = r.l0.weight
        self.r0p, self.r0n = t(w0[:, :64]), t(w0[:, 64:])
        self.r = [t(getattr(r, f"l{i}").weight) for i in range(1, 7)]

    def chunk(self, p: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """``p [n, 64]``, ``dirs [n, 9]`` (f32) → log radiance ``[n, 3]`` (f32)."""
        x = positional_encoding(dirs).to(self.dtype)
        x = F.leaky_relu_(x.mm(self.nd[0]), ND_SLOPE)
        x = F.leaky_relu_(x.mm(self.nd[1]), ND_SLOPE)
        nd = x.mm(self.nd[2])
        x = torch.addmm(nd.mm(self.r0n), p.to(self.dtype), self.r0p)
        for w in self.r[:-1]:
            x = F.leaky_relu_(x.mm(w), RENDER_HIDDEN_SLOPE)
        return F.leaky_relu_(x.mm(self.r[-1]), RENDER_OUT_SLOPE).float()

    def run(self, p: torch.Tensor, dirs: torch.Tensor, chunk: int, fn=None) -> torch.Tensor:
        fn = fn or self.chunk
        out = torch.empty(p.shape[0], 3, device=p.device)
        for i in range(0, p.shape[0], chunk):
            out[i : i + chunk] = fn(p[i : i + chunk], dirs[i : i + chunk])
        return out


def compiled(fn, enabled: bool):
    """``torch.compile(fn)``, or ``None`` with the reason printed when it is off or fails."""
    if not enabled:
        return None
    try:
        return torch.compile(fn, dynamic=False)
    except Exception as err:
        print(f"  torch.compile unavailable: {type(err).__name__}: {err}")
        return None


def report(job: str, rows: list[tuple[str, str, float, float]]) -> None:
    """Rows ``(variant, precision, ms, max |Δ| vs the f32 eager output)``; prints the fastest."""
    for name, prec, ms, err in rows:
        print(f"{job} [{name}, {prec}]: {ms:.1f} ms  (max |Δ| vs f32 eager {err:.2e})")
    f32 = min((r for r in rows if r[1] == "f32"), key=lambda r: r[2])
    best = min(rows, key=lambda r: r[2])
    print(f"{job} fastest f32: {f32[2]:.1f} ms ({f32[0]}); fastest: {best[2]:.1f} ms ({best[0]}, {best[1]})")


def try_time(rows, name, prec, fn, reps, reference):
    """Times ``fn`` and appends its row; a variant that fails is reported and left out."""
    try:
        err = (fn() - reference).abs().max().item()
        rows.append((name, prec, best_ms(fn, reps), err))
    except Exception as e:
        print(f"  {name}: failed ({type(e).__name__}: {str(e).splitlines()[0][:120]})")


def bench_relight(model: NamModel, size: int, reps: int, compile_: bool) -> None:
    params = torch.rand(1, 64, size, size) * 2 - 1
    wi, wo = pixel_dirs(size, (1.5, 1.0, 3.5), (0.0, 0.0, CAPTURE_DISTANCE))
    p = params.permute(0, 2, 3, 1).reshape(-1, 64).contiguous()
    dirs = query_dirs(wi.reshape(-1, 3), wo.reshape(-1, 3))
    ref = model.relight_log(params, wi, wo).reshape(-1, 3)
    rows: list[tuple[str, str, float, float]] = []
    try_time(
        rows, "relight_log, training code", "f32", lambda: model.relight_log(params, wi, wo).reshape(-1, 3), reps, ref
    )
    lean, lean16 = LeanRelight(model), LeanRelight(model, torch.bfloat16)
    for c in CHUNKS:
        try_time(rows, f"lean, chunk {c}", "f32", lambda c=c: lean.run(p, dirs, c), reps, ref)
    fastest_chunk = min((r for r in rows if r[0].startswith("lean")), key=lambda r: r[2])[0]
    chunk = int(fastest_chunk.rsplit(" ", 1)[1])
    try_time(rows, f"lean, chunk {chunk}", "bf16", lambda: lean16.run(p, dirs, chunk), reps, ref)
    fn = compiled(lean.chunk, compile_)
    if fn is not None:
        try_time(rows, f"torch.compile lean, chunk {chunk}", "f32", lambda: lean.run(p, dirs, chunk, fn), reps, ref)
    report(f"relight_{size}", rows)


def bench_estimate(width: int, size: int, reps: int, compile_: bool) -> None:
    m = NamModel(ModelConfig(width=width, input_skip=True)).eval()
    x = torch.rand(1, 4, size, size)
    ref = m.estimate(x)
    rows: list[tuple[str, str, float, float]] = []
    try_time(rows, "eager NCHW", "f32", lambda: m.estimate(x), reps, ref)
    m_cl = NamModel(ModelConfig(width=width, input_skip=True)).eval()
    m_cl.load_state_dict(m.state_dict())
    m_cl = m_cl.to(memory_format=torch.channels_last)
    x_cl = x.contiguous(memory_format=torch.channels_last)
    try_time(rows, "eager channels-last", "f32", lambda: m_cl.estimate(x_cl), reps, ref)

    def bf16():
        with torch.autocast("cpu", dtype=torch.bfloat16):
            return m_cl.estimate(x_cl).float()

    try_time(rows, "autocast channels-last", "bf16", bf16, reps, ref)
    fn = compiled(m.estimate, compile_)
    if fn is not None:
        try_time(rows, "torch.compile NCHW", "f32", lambda: fn(x), reps, ref)
    report(f"estimate_{size}_c{width}_input_skip", rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile variants")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {args.threads} threads, {args.size}², best of {args.reps}")

    n = 1024
    a, b = torch.rand(n, n), torch.rand(n, n)
    ms = best_ms(lambda: torch.mm(a, b), args.reps + 2)
    print(f"sgemm_1024: {ms:.2f} ms  ({2 * n**3 / ms / 1e6:.1f} GFLOP/s)")

    with torch.inference_mode():
        bench_relight(NamModel(ModelConfig(width=8)).eval(), args.size, args.reps, not args.no_compile)
        for width in (8, 16):
            bench_estimate(width, args.size, args.reps, not args.no_compile)


if __name__ == "__main__":
    main()
