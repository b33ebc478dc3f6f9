"""Throughput of `nam.Material.eval` from Python against the Rust facade's `NeuralBrdf::eval`,
in the same run: both evaluate the same number of random queries (uv over the material,
directions in the upper hemisphere) on a material estimated from the bundled photo.

    .venv/bin/python crates/nam-py/bench/eval_throughput.py [--queries 1000000] [--reps 5]

It builds and runs `cargo run --release -p nam --example brdf_throughput` for the Rust figure.
"""

import argparse
import subprocess
import time
from pathlib import Path

import nam
import numpy as np

REPO = Path(__file__).resolve().parents[3]


def upper_hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    phi = 2 * np.pi * rng.random(n)
    z = 0.05 + 0.95 * rng.random(n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--queries", type=int, default=1_000_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--side", type=int, default=64)
    args = ap.parse_args()
    model = nam.Model.embedded()
    material = model.estimate_file(REPO / "assets" / "example_photo.png", resize=args.side)
    rng = np.random.default_rng(7)
    n = args.queries
    uv = rng.random((n, 2), dtype=np.float32)
    wi, wo = upper_hemisphere(rng, n), upper_hemisphere(rng, n)
    python_best = float("inf")
    for _ in range(args.reps):
        t = time.perf_counter()
        out = material.eval(uv, wi, wo)
        python_best = min(python_best, time.perf_counter() - t)
    assert out.shape == (n, 3)
    example = ["cargo", "run", "--release", "--locked", "-q", "-p", "nam", "--example", "brdf_throughput", "--"]
    rust = subprocess.run(
        [*example, "--queries", str(n), "--reps", str(args.reps), "--side", str(args.side)],
        cwd=REPO,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    rust_best = float(rust[rust.index("best_seconds") + 1])
    print(f"queries {n}: Python nam.Material.eval {python_best * 1e3:.1f} ms ({n / python_best / 1e6:.2f} M/s)")
    print(f"queries {n}: Rust NeuralBrdf::eval     {rust_best * 1e3:.1f} ms ({n / rust_best / 1e6:.2f} M/s)")
    print(f"Python / Rust throughput: {rust_best / python_best:.2f}")


if __name__ == "__main__":
    main()
