"""Where the Hemisphere error lies: near the mirror direction, where a glossy material's highlight is.

    python -m train_py.mirror --model models/default.safetensors [--set test] [-o table.md]

The evaluation's Hemisphere pairs (``train_py.evaluate``: the same materials, sizes and seeded
pairs) with every pixel binned by the z of its half vector ``wh`` — its ``n·h`` on a flat
surface, ≈ 1 where the GGX highlight lies (``MIRROR_BINS``). Per bin and method: the share of the
pixels, the mean log-L1, the bin's share of the method's whole log error, and the mean signed log
error (negative: too dark). In the last bin also the median luminance of the truth and of the
relight. Methods: the model, the diffuse fit, and GGX of the *true* maps with flat normals (what an
estimate exact in everything but the normals would score).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from . import ggx, materials, protocols
from .evaluate import diffuse_fit, evaluation_sets, pair_seed

#: Bin edges of ``wh.z``: the rest, the highlight's skirt, its core.
MIRROR_BINS = (0.0, 0.99, 0.999, 1.0)
FLAT = "GGX, true maps, flat normals"


def bin_index(wh_z: torch.Tensor) -> torch.Tensor:
    """The ``MIRROR_BINS`` bin of each ``wh.z`` (the last bin includes 1)."""
    edges = torch.tensor(MIRROR_BINS[1:-1], dtype=wh_z.dtype)
    return torch.bucketize(wh_z.contiguous(), edges, right=True)


def breakdown(model, sets, hemisphere_k: int = 128) -> dict[str, dict]:
    """``{method: {"count", "abs", "signed": [per bin], "truth", "relit": [mirror luminances]}}`` summed
    over ``sets`` (``(seed, maps [1, H, W, ...])``, as ``evaluate.evaluate_maps`` takes them)."""
    bins = len(MIRROR_BINS) - 1
    methods = (["model"] if model is not None else []) + ["diffuse fit", FLAT]
    acc = {m: {"truth": [], "relit": [], **{s: torch.zeros(bins) for s in ("count", "abs", "signed")}} for m in methods}
    for seed, maps in sets:
        size = maps["roughness"].shape[-1]
        photo = ggx.ldr_capture(ggx.render_capture(maps))
        light, view = protocols.seeded_pairs("hemisphere", hemisphere_k, pair_seed(seed, "hemisphere"))
        light, view = light.float(), view.float()
        truth = ggx.render_maps(maps, light, view)[0]
        wi, wo, wh = ggx.directions(light, view, size, size)
        flat = ggx.render_maps(materials.flat_normals(maps), light, view)[0]
        preds = {"diffuse fit": diffuse_fit(photo, wi)[0], FLAT: flat}
        if model is not None:
            with torch.no_grad():
                params = model.estimate_photo(photo)
                logs = [model.relight_log(params, wi[:, k], wo[:, k]) for k in range(wi.shape[1])]
            preds["model"] = ggx.from_log(torch.cat(logs))
        index = bin_index(wh[0, ..., 2]).reshape(-1)
        mirror = index == bins - 1
        count = torch.bincount(index, minlength=bins).float()
        truth_log, truth_mirror = ggx.to_log(truth), truth.mean(-1).reshape(-1)[mirror]
        for m, pred in preds.items():
            err = (ggx.to_log(pred) - truth_log).mean(-1).reshape(-1)
            a = acc[m]
            a["count"] += count
            a["abs"] += torch.bincount(index, err.abs(), minlength=bins).float()
            a["signed"] += torch.bincount(index, err, minlength=bins).float()
            a["truth"].append(truth_mirror)
            a["relit"].append(pred.mean(-1).reshape(-1)[mirror])
    return acc


def markdown(acc: dict[str, dict], what: str, command: str, seconds: float) -> str:
    lines = [
        "# Where the Hemisphere error lies: pixels binned by the flat-surface n·h",
        "",
        f"{what}; Hemisphere pairs of `train_py.evaluate`. Per bin of `wh.z`: share of the pixels, "
        "mean log-L1, the bin's share of the method's whole log error, mean signed log error "
        f"(negative: too dark); median luminance of truth and relight where `wh.z ≥ {MIRROR_BINS[-2]}`. "
        f"Command: `{command}` ({seconds:.0f} s).",
        "",
        "| method | wh.z bin | pixels | log-L1 | share of the error | signed |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for m, a in acc.items():
        total = float(a["abs"].sum())
        for b in range(len(MIRROR_BINS) - 1):
            n = float(a["count"][b])
            lines.append(
                f"| {m} | [{MIRROR_BINS[b]}, {MIRROR_BINS[b + 1]}{']' if b == len(MIRROR_BINS) - 2 else ')'} | "
                f"{100 * n / float(a['count'].sum()):.1f}% | {float(a['abs'][b]) / max(n, 1):.4f} | "
                f"{100 * float(a['abs'][b]) / max(total, 1e-12):.0f}% | {float(a['signed'][b]) / max(n, 1):+.4f} |"
            )
    lines += [
        "",
        f"| method | median truth luminance (wh.z ≥ {MIRROR_BINS[-2]}) | median relit luminance |",
        "|---|---:|---:|",
    ]
    for m, a in acc.items():
        truth, relit = torch.cat(a["truth"]), torch.cat(a["relit"])
        if truth.numel() == 0:
            lines.append(f"| {m} | no pixel in the bin | — |")
        else:
            lines.append(f"| {m} | {float(truth.median()):.2f} | {float(relit.median()):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", help="model .safetensors (omit: the baselines only)")
    ap.add_argument("--set", default="procedural", choices=["procedural", "test"])
    ap.add_argument("--materials", type=int, default=None, help="how many (default: all)")
    ap.add_argument("--size", type=int, default=None, help="image side (procedural: 64 or a divisor; test: 128)")
    ap.add_argument("--hemisphere", type=int, default=None, help="pairs per material (procedural 128, test 32)")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("-o", "--output", help="write the Markdown table here")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    from .export import load_model

    model = load_model(args.model) if args.model else None
    t0 = time.time()
    k = args.hemisphere or (32 if args.set == "test" else 128)
    sets, size, what, _ = evaluation_sets(args.set, args.materials, args.size)
    what += f", {k} pairs each"
    acc = breakdown(model, sets, k)
    command = f"python -m train_py.mirror --model {args.model} --set {args.set} --size {size} --hemisphere {k}" + (
        f" --materials {args.materials}" if args.materials else ""
    )
    md = markdown(acc, what, command, time.time() - t0)
    print(md)
    if args.output:
        Path(args.output).write_text(md)


if __name__ == "__main__":
    main()
