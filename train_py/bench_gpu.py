"""The measurement behind ``scripts/gpu-bench``: nam-gpu and PyTorch on the same device, one run.

For each image side it runs ``nam-cli bench --gpu-only`` (wgpu: the general point relight, the
directional plan and the U-Net estimate, each against the CPU fast path, and the
``shaders/fma_peak.wgsl`` probe), then the same networks in PyTorch on ``--device`` (random weights
of the same architecture, ``inference_mode``): the relight (ND_enc + render MLP per pixel, the lean
pipeline of ``bench_torch``) and the estimate (U-Net, C = 8 and 16, input skip), in f32, TF32 (CUDA
only) and bf16, eager and ``torch.compile`` where it works, plus two rates of the device: an FMA
chain (one fused kernel, 2 flops per element and step) and an f32 / TF32 GEMM. Writes
``gpu_bench.md`` (tables) and ``gpu_bench.json`` (every number) into ``--out``.

    .venv/bin/python -m train_py.bench_gpu --nam-cli gpu-bench/nam-cli --sizes 256,1024 --out $OUT

Every torch variant's output is compared with the f32 eager one (``max |Δ|`` in the table).
``--deadline-s`` bounds the whole run: compile variants are skipped (and say so) once half of
it is spent, since each compile costs tens of seconds.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

from train_py.bench_torch import LeanRelight, pixel_dirs
from train_py.model import ModelConfig, NamModel, query_dirs

CAPTURE_DISTANCE = 4.010781
#: Rows of one relight chunk on the device.
CHUNK = 65536
#: U-Net widths timed in PyTorch.
WIDTHS = (8, 16)
#: Steps of the FMA chain (2 flops each per element) and its elements.
FMA_STEPS = 128
FMA_ELEMS = 1 << 24


class Clock:
    """Wall time since the start, against the deadline."""

    def __init__(self, deadline_s: float):
        self.t0 = time.perf_counter()
        self.deadline_s = deadline_s

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def compile_allowed(self) -> bool:
        return self.elapsed() < 0.5 * self.deadline_s


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def best_ms(fn: Callable[[], object], reps: int, device: torch.device) -> float:
    fn()
    sync(device)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        sync(device)
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def parse_nam_table(stdout: str) -> dict:
    """The ``--gpu`` table of ``nam-cli bench``: header fields and one dict per row."""
    lines = stdout.splitlines()
    header = next((ln for ln in lines if ln.startswith("GPU: ")), None)
    if header is None:
        raise ValueError(f"no GPU table in nam-cli output:\n{stdout}")
    peak = float(header.split("FMA peak (shaders/fma_peak.wgsl) ")[1].split(" ")[0])
    rows = []
    for ln in lines:
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if len(cells) != 6 or not cells[0].startswith(("GPU ", "CPU ")):
            continue
        num = lambda v: None if v == "—" else float(v)  # noqa: E731
        rows.append(
            {
                "path": cells[0],
                "pixels": int(cells[1]),
                "ms": float(cells[2]),
                "gflops": float(cells[3]),
                "x_general_same_backend": num(cells[4]),
                "gpu_over_cpu_speed": num(cells[5]),
            }
        )
    if len(rows) != 6:
        raise ValueError(f"expected 6 rows in the GPU table, found {len(rows)}:\n{stdout}")
    return {"adapter": header[len("GPU: ") :].split(", f32")[0], "fma_peak_gflops": peak, "rows": rows}


def nam_bench(nam_cli: str, size: int, reps: int, timeout_s: float) -> dict:
    cmd = [nam_cli, "bench", "--gpu-only", "--size", str(size), "--repeat", str(reps)]
    t = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        return {"command": " ".join(cmd), "error": f"{type(e).__name__}: {e}"}
    out = {"command": " ".join(cmd), "seconds": round(time.perf_counter() - t, 1)}
    if p.returncode != 0:
        return {**out, "error": f"exit {p.returncode}: {(p.stderr or p.stdout).strip()[-2000:]}"}
    try:
        return {**out, **parse_nam_table(p.stdout)}
    except ValueError as e:
        return {**out, "error": str(e)}


def precisions(device: torch.device) -> list[str]:
    return ["f32", "tf32", "bf16"] if device.type == "cuda" else ["f32", "bf16"]


def set_tf32(on: bool) -> None:
    torch.backends.cuda.matmul.allow_tf32 = on
    torch.backends.cudnn.allow_tf32 = on


def compiled(fn, clock: Clock, enabled: bool, notes: list[str], what: str):
    if not enabled:
        return None
    if not clock.compile_allowed():
        notes.append(f"{what}: torch.compile skipped (half of the deadline spent)")
        return None
    try:
        return torch.compile(fn, dynamic=False)
    except Exception as e:  # any backend failure means "not available"
        notes.append(f"{what}: torch.compile unavailable ({type(e).__name__}: {e})")
        return None


def timed(rows, notes, job, variant, prec, fn, ref, reps, device) -> None:
    """Appends ``fn``'s row (best ms, max |Δ| vs ``ref``); a failing variant becomes a note."""
    try:
        err = (fn().float() - ref).abs().max().item()
        ms = best_ms(fn, reps, device)
        rows.append({"job": job, "variant": variant, "precision": prec, "ms": ms, "max_abs_diff": err})
    except Exception as e:
        notes.append(f"{job} [{variant}, {prec}]: failed ({type(e).__name__}: {str(e).splitlines()[0][:160]})")


def torch_relight(size, device, reps, clock, compile_, rows, notes) -> None:
    model = NamModel(ModelConfig(width=8)).eval().to(device)
    wi, wo = pixel_dirs(size, (1.5, 1.0, 3.5), (0.0, 0.0, CAPTURE_DISTANCE))
    p = (torch.rand(size * size, 64) * 2 - 1).to(device)
    dirs = query_dirs(wi.reshape(-1, 3), wo.reshape(-1, 3)).to(device)
    job = f"relight {size}²"
    lean = LeanRelight(model)
    set_tf32(False)
    ref = lean.run(p, dirs, CHUNK)
    for prec in precisions(device):
        set_tf32(prec == "tf32")
        net = LeanRelight(model, torch.bfloat16) if prec == "bf16" else lean
        timed(rows, notes, job, "eager", prec, lambda n=net: n.run(p, dirs, CHUNK), ref, reps, device)
        if prec != "tf32":
            fn = compiled(net.chunk, clock, compile_, notes, f"{job} {prec}")
            if fn is not None:
                run = lambda n=net, f=fn: n.run(p, dirs, CHUNK, f)  # noqa: E731
                timed(rows, notes, job, "torch.compile", prec, run, ref, reps, device)
    set_tf32(False)


def torch_estimate(size, width, device, reps, clock, compile_, rows, notes) -> None:
    m = NamModel(ModelConfig(width=width, input_skip=True)).eval().to(device)
    x = torch.rand(1, 4, size, size, device=device)
    job = f"estimate {size}² C={width}"
    set_tf32(False)
    ref = m.estimate(x)
    m_cl = NamModel(ModelConfig(width=width, input_skip=True)).eval()
    m_cl.load_state_dict(m.state_dict())
    m_cl = m_cl.to(device).to(memory_format=torch.channels_last)
    x_cl = x.contiguous(memory_format=torch.channels_last)

    def bf16(model, inp):
        with torch.autocast(device.type, dtype=torch.bfloat16):
            return model.estimate(inp)

    for prec in precisions(device):
        set_tf32(prec == "tf32")
        run = (lambda mm, xx: bf16(mm, xx)) if prec == "bf16" else (lambda mm, xx: mm.estimate(xx))
        timed(rows, notes, job, "eager NCHW", prec, lambda r=run: r(m, x), ref, reps, device)
        timed(rows, notes, job, "eager channels-last", prec, lambda r=run: r(m_cl, x_cl), ref, reps, device)
        if prec != "tf32":
            fn = compiled(lambda xx, r=run: r(m_cl, xx), clock, compile_, notes, f"{job} {prec}")
            if fn is not None:
                timed(rows, notes, job, "torch.compile channels-last", prec, lambda f=fn: f(x_cl), ref, reps, device)
    set_tf32(False)


def device_rates(device, reps, clock, compile_, notes) -> dict:
    """FMA-chain and GEMM rates of the device (GFLOP/s)."""
    out = {}
    n = 8192 if device.type == "cuda" else 1024
    a, b = torch.rand(n, n, device=device), torch.rand(n, n, device=device)
    for prec in precisions(device):
        if prec == "bf16":
            a16, b16 = a.bfloat16(), b.bfloat16()
            ms = best_ms(lambda a16=a16, b16=b16: a16 @ b16, reps + 2, device)
        else:
            set_tf32(prec == "tf32")
            ms = best_ms(lambda: a @ b, reps + 2, device)
        out[f"gemm_{n}_{prec}_gflops"] = 2 * n**3 / ms / 1e6
    set_tf32(False)

    def chain(x):
        for _ in range(FMA_STEPS):
            x = x * 0.999 + 0.001
        return x

    fn = compiled(chain, clock, compile_, notes, "FMA chain")
    if fn is not None:
        x = torch.rand(FMA_ELEMS, device=device)
        ms = best_ms(lambda: fn(x), reps + 2, device)
        out["fma_chain_gflops"] = 2 * FMA_STEPS * FMA_ELEMS / ms / 1e6
    return out


def markdown(result: dict) -> str:
    t = [f"# nam-gpu vs PyTorch on {result['device_name']}", ""]
    t.append(f"Command: `{result['command']}`; {result['finished_in_s']:.0f} s; torch {result['torch']}.")
    t.append("")
    rates = ", ".join(f"{k} {v:.0f}" for k, v in result["rates"].items())
    t.append(f"PyTorch device rates (GFLOP/s): {rates or 'none'}.")
    for nam in result["nam"]:
        t.append("")
        if "error" in nam:
            t.append(f"`{nam['command']}` failed: {nam['error']}")
            continue
        t.append(f"`{nam['command']}`: {nam['adapter']}, FMA peak {nam['fma_peak_gflops']:.1f} GFLOP/s")
        t.append("")
        t.append("| nam path | ms | GFLOP/s | GPU/CPU speed |")
        t.append("|---|---:|---:|---:|")
        for r in nam["rows"]:
            ratio = "—" if r["gpu_over_cpu_speed"] is None else f"{r['gpu_over_cpu_speed']:.2f}"
            t.append(f"| {r['path']} | {r['ms']:.2f} | {r['gflops']:.1f} | {ratio} |")
    t.append("")
    t.append("| PyTorch job | variant | precision | ms | max abs diff vs f32 eager |")
    t.append("|---|---|---|---:|---:|")
    for r in result["torch_rows"]:
        t.append(f"| {r['job']} | {r['variant']} | {r['precision']} | {r['ms']:.2f} | {r['max_abs_diff']:.1e} |")
    if result["notes"]:
        t += ["", "Notes:", ""] + [f"- {n}" for n in result["notes"]]
    return "\n".join(t) + "\n"


def check(path: Path) -> list[str]:
    """What is missing or wrong in a ``gpu_bench.json`` (empty: complete)."""
    r = json.loads(path.read_text())
    problems = []
    for nam in r["nam"]:
        if "error" in nam:
            problems.append(f"{nam['command']}: {nam['error']}")
            continue
        bad = [row["path"] for row in nam["rows"] if not 0 < row["ms"] < float("inf")]
        if len(nam["rows"]) != 6 or bad or not nam["fma_peak_gflops"] > 0:
            peak = nam["fma_peak_gflops"]
            problems.append(f"{nam['command']}: rows {len(nam['rows'])}, bad times {bad}, peak {peak}")
    have = {(row["job"], row["precision"]) for row in r["torch_rows"] if row["variant"].startswith("eager")}
    for size in r["sizes"]:
        jobs = [f"relight {size}²"] + [f"estimate {size}² C={w}" for w in WIDTHS]
        for job in jobs:
            for prec in precisions(torch.device(r["device"])):
                if (job, prec) not in have:
                    problems.append(f"no eager {prec} row for {job}")
    for row in r["torch_rows"]:
        if not 0 < row["ms"] < float("inf"):
            problems.append(f"{row['job']} [{row['variant']}, {row['precision']}]: {row['ms']} ms")
        if row["precision"] == "f32" and not row["max_abs_diff"] <= 1e-3:
            problems.append(f"{row['job']} [{row['variant']}]: f32 differs by {row['max_abs_diff']} from f32 eager")
    if not r["rates"]:
        problems.append("no device rates")
    return problems


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", type=Path, help="only validate this gpu_bench.json (exit 1 when incomplete)")
    ap.add_argument("--nam-cli", help="nam-cli binary (built with the gpu feature)")
    ap.add_argument("--sizes", default="256,1024")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--no-compile", action="store_true")
    ap.add_argument("--deadline-s", type=float, default=420.0)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    if args.check:
        problems = check(args.check)
        if problems:
            raise SystemExit("gpu_bench.json incomplete:\n" + "\n".join(problems))
        print(f"{args.check}: complete")
        return
    if not args.nam_cli or not args.out:
        ap.error("--nam-cli and --out are required (or --check FILE)")
    clock = Clock(args.deadline_s)
    device = torch.device(args.device)
    sizes = [int(s) for s in args.sizes.split(",")]
    torch.manual_seed(0)
    notes: list[str] = []
    nam = [nam_bench(args.nam_cli, s, args.reps, 0.4 * args.deadline_s) for s in sizes]
    for r in nam:
        print(f"nam-cli {r['command']}: {r.get('error') or 'ok'}", flush=True)
    rows: list[dict] = []
    with torch.inference_mode():
        rates = device_rates(device, args.reps, clock, not args.no_compile, notes)
        for s in sizes:
            torch_relight(s, device, args.reps, clock, not args.no_compile, rows, notes)
            for w in WIDTHS:
                torch_estimate(s, w, device, args.reps, clock, not args.no_compile, rows, notes)
            print(f"torch {s}²: done at {clock.elapsed():.0f} s", flush=True)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "CPU"
    result = {
        "command": "python -m train_py.bench_gpu " + " ".join(sys.argv[1:] if argv is None else argv),
        "device": str(device),
        "device_name": name,
        "torch": torch.__version__,
        "sizes": sizes,
        "nam": nam,
        "rates": rates,
        "torch_rows": rows,
        "notes": notes,
        "finished_in_s": clock.elapsed(),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "gpu_bench.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "gpu_bench.md").write_text(markdown(result))
    print(markdown(result))
    failed = [r["command"] for r in nam if "error" in r]
    if failed:
        raise SystemExit(f"nam-cli failed: {failed} (see {out / 'gpu_bench.md'})")


if __name__ == "__main__":
    main()
