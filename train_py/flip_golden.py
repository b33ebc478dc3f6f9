"""Seeded LDR-FLIP golden for the Rust port `crates/nam-eval/src/flip.rs` (issue 18 item 9).

    python -m train_py.flip_golden      # writes tests/fixtures/flip_golden.safetensors

The reference is NVIDIA's `flip-evaluator` (PyPI, the `flip` extra). Convention matched with
the Rust port: inputs are **linear** RGB in [0, 1] (`flip_linear` / `FlipImage::new` take linear
RGB), so they are passed with `inputsRGB=False` (no sRGB decode), dynamic range "LDR", and
`ppd = 67.0` (`nam_eval::flip::DEFAULT_PIXELS_PER_DEGREE`, passed explicitly rather than
FLIP's viewing-condition default of 67.02).

Stored tensors (F32; the images each once, so the file stays small):
    `gradient`, `edges`          (H, W, 3) linear RGB reference images;
    `{k}_test`                   (H, W, 3) test image of pair `k` (not for "identical", whose
                                 test is `edges` itself); `REFERENCE[k]` names its reference;
    `{k}_map`                    (H, W) per-pixel FLIP error;
    `{k}_mean`                   (1,) mean FLIP error as flip-evaluator reports it.
"""

from __future__ import annotations

import argparse
from importlib import metadata
from pathlib import Path

import numpy as np
from safetensors.numpy import save_file

SEED = 18_09
HEIGHT, WIDTH = 32, 48
PPD = 67.0
REFERENCE = {
    "gradient_noise": "gradient",
    "gradient_shift": "gradient",
    "gradient_colour": "gradient",
    "edges_blur": "edges",
    "identical": "edges",
}


def _gradient(h: int, w: int) -> np.ndarray:
    y, x = np.meshgrid(np.linspace(0.0, 1.0, h), np.linspace(0.0, 1.0, w), indexing="ij")
    return np.stack([0.1 + 0.8 * x, 0.2 + 0.6 * y, 0.5 + 0.4 * (x - y) / 2.0], axis=-1)


def _edges(h: int, w: int) -> np.ndarray:
    y, x = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    checker = ((x // 8 + y // 8) % 2).astype(np.float64)
    bars = ((x // 3) % 2).astype(np.float64)
    return np.stack([0.15 + 0.7 * checker, 0.2 + 0.6 * bars, 0.1 + 0.3 * checker + 0.3 * bars], axis=-1)


def _box_blur(img: np.ndarray, r: int) -> np.ndarray:
    out = img.copy()
    for axis in (0, 1):
        pad = [(0, 0)] * img.ndim
        pad[axis] = (r, r)
        p = np.pad(out, pad, mode="edge")
        n = img.shape[axis]
        out = sum(np.take(p, range(k, k + n), axis=axis) for k in range(2 * r + 1)) / (2 * r + 1)
    return out


def image_pairs(seed: int = SEED) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The deterministic (reference, test) pairs, float32 linear RGB in [0, 1], HWC."""
    rng = np.random.default_rng(seed)
    g = _gradient(HEIGHT, WIDTH)
    e = _edges(HEIGHT, WIDTH)
    pairs = {
        "gradient_noise": (g, g + rng.normal(0.0, 0.05, g.shape)),
        "gradient_shift": (g, np.roll(g, (2, 3), axis=(0, 1))),
        "gradient_colour": (g, g * np.array([1.1, 0.85, 0.7]) + 0.03),
        "edges_blur": (e, _box_blur(e, 2)),
        "identical": (e, e.copy()),
    }
    return {
        k: (np.clip(a, 0, 1).astype(np.float32), np.clip(b, 0, 1).astype(np.float32)) for k, (a, b) in pairs.items()
    }


def flip_golden(seed: int = SEED) -> dict[str, np.ndarray]:
    """Runs flip-evaluator on every pair; see the module docstring for the tensors."""
    import flip_evaluator as flip

    out: dict[str, np.ndarray] = {}
    for k, (ref, test) in image_pairs(seed).items():
        out[REFERENCE[k]] = ref
        if k != "identical":
            out[f"{k}_test"] = test
        err, mean, _ = flip.evaluate(
            ref, test, "LDR", inputsRGB=False, applyMagma=False, computeMeanError=True, parameters={"ppd": PPD}
        )
        err = np.asarray(err, dtype=np.float32).reshape(HEIGHT, WIDTH)
        out[f"{k}_map"] = err
        out[f"{k}_mean"] = np.array([mean], dtype=np.float32)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("tests/fixtures/flip_golden.safetensors"))
    args = ap.parse_args(argv)
    meta = {
        "source": "python -m train_py.flip_golden",
        "reference": f"flip-evaluator {metadata.version('flip-evaluator')}",
        "input": "linear RGB (inputsRGB=False), LDR",
        "ppd": str(PPD),
        "seed": str(SEED),
    }
    save_file(flip_golden(), str(args.out), metadata=meta)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
