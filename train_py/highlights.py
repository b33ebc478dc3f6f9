"""Does a relit material move its highlight? A test on glossy variants of materials/test (issue 24).

    python -m train_py.highlights --model models/default.safetensors [-o models/default.highlights.md]

Each real test set gets a glossy variant (its roughness map rescaled so the median lies in
``ROUGHNESS_RANGE``, specular at least ``SPECULAR_MIN``). Its ideal capture (28°, co-located, 8-bit
sRGB: bright highlights clip) goes through the model, which then relights it with the light moved
away from the camera (``MOVED_LIGHTS``, view at the camera). Two checks per (material, light):

- **peak**: the relit highlight's peak (argmax of the luminance blurred with σ = ``PEAK_SIGMA`` px)
  lies within ``PEAK_TOLERANCE_PX`` of the GGX truth's;
- **clipped**: over the pixels the capture clipped, the mean relit radiance is within
  ``CLIPPED_RATIO`` of the truth's (neither a dark blob nor the capture highlight left in place);
- **peak brightness**: the relit blurred luminance at the truth's peak over the truth's there, within
  ``CLIPPED_RATIO`` (a highlight in the right place but ~20× too dim, as a diffuse relight gives,
  fails it; the peak check alone can pass on a diffuse relight's brightest spot, the foot of the
  light, which lies near the moved highlight).

The diffuse fit (Lambertian albedo from the photo) is scored the same way as a baseline.

``--oracle`` scores GGX renders of the *true* maps with one map perturbed (``PERTURBATIONS``): how
accurate an estimate of each map must be for the peak check to pass.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from . import ggx, materials
from .evaluate import diffuse_fit

#: Median roughness of the glossy variant, uniform per material in this range.
ROUGHNESS_RANGE = (0.1, 0.4)
#: Smallest specular F0 of the glossy variant (dielectrics: 0.04 in most sets).
SPECULAR_MIN = 0.04
#: Light positions of the relights (surface units): moved 1.2 units off the camera axis.
MOVED_LIGHTS = ((1.2, 0.0, 3.8), (-1.2, 0.0, 3.8), (0.0, 1.2, 3.8), (0.0, -1.2, 3.8))
#: Image side the peak tolerance is stated for; other sizes scale distances to it.
REFERENCE_SIZE = 256
PEAK_SIGMA = 4.0
PEAK_TOLERANCE_PX = 10.0
CLIPPED_RATIO = (0.5, 2.0)


def _box_blur(x: torch.Tensor) -> torch.Tensor:
    """``[1, H, W, C]`` averaged over windows 9 px wide at 256² (scaled to the size; replicate
    padding)."""
    side = 2 * round(4 * x.shape[2] / REFERENCE_SIZE) + 1
    y = F.pad(x.permute(0, 3, 1, 2), (side // 2,) * 4, mode="replicate")
    return F.avg_pool2d(y, side, 1).permute(0, 2, 3, 1)


def _with(maps: dict[str, torch.Tensor], key: str, value: torch.Tensor) -> dict[str, torch.Tensor]:
    return {**maps, key: value}


#: Perturbed true maps for ``--oracle``: (name, maps → maps).
PERTURBATIONS = (
    ("roughness × 1.3", lambda m: _with(m, "roughness", (m["roughness"] * 1.3).clamp(0.02, 1))),
    ("roughness ÷ 1.3", lambda m: _with(m, "roughness", (m["roughness"] / 1.3).clamp(0.02, 1))),
    (
        "roughness: its median everywhere",
        lambda m: _with(m, "roughness", torch.full_like(m["roughness"], float(m["roughness"].median()))),
    ),
    ("normals box-blurred over 9 px (256²)", lambda m: _with(m, "normal", F.normalize(_box_blur(m["normal"]), dim=-1))),
    ("normals flat", lambda m: _with(m, "normal", torch.tensor([0.0, 0.0, 1.0]).expand_as(m["normal"]).contiguous())),
    ("diffuse box-blurred over 9 px (256²)", lambda m: _with(m, "diffuse", _box_blur(m["diffuse"]))),
    ("specular × 1.5", lambda m: _with(m, "specular", m["specular"] * 1.5)),
)


def glossy_sets(size: int, count: int | None):
    """The test's glossy sets (the first ``count``; default all) at ``size``², each as its maps and,
    per moved light, ``(light [1, 1, 3], GGX truth [size, size, 3])``."""
    view = ggx.capture_position().view(1, 1, 3)
    for i, path in enumerate(materials.list_files("test")[:count]):
        maps = glossy(materials.load_maps(path, size), i)
        lights = [torch.tensor(xyz).view(1, 1, 3) for xyz in MOVED_LIGHTS]
        yield maps, [(light, ggx.render_maps(maps, light, view)[0, 0]) for light in lights]


def peak_stats(dists: list[float]) -> tuple[float, float]:
    """Share of peak errors within ``PEAK_TOLERANCE_PX`` and their median."""
    t = torch.tensor(dists)
    return float((t <= PEAK_TOLERANCE_PX).float().mean()), float(t.median())


def oracle(size: int = REFERENCE_SIZE, count: int | None = None) -> tuple[list[tuple[str, float, float]], int]:
    """(perturbation, share of peaks within the tolerance, median peak error in px of 256²) for GGX
    renders of perturbed true maps, over the cases :func:`run` scores; and the number of cases."""
    view = ggx.capture_position().view(1, 1, 3)
    dists: dict[str, list[float]] = {name: [] for name, _ in PERTURBATIONS}
    for maps, cases in glossy_sets(size, count):
        for light, truth in cases:
            no_clip = torch.zeros(truth.shape[:2], dtype=torch.bool)
            for name, perturb in PERTURBATIONS:
                dists[name].append(score(ggx.render_maps(perturb(maps), light, view)[0, 0], truth, no_clip)[0])
    rows = [(name, *peak_stats(d)) for name, d in dists.items()]
    return rows, len(next(iter(dists.values())))


def oracle_markdown(rows: list[tuple[str, float, float]], size: int, cases: int, seconds: float) -> str:
    lines = [
        "# Highlight test: how accurate the maps must be",
        "",
        f"GGX renders of the true glossy test maps with one map perturbed, scored by the peak check "
        f"against the unperturbed render ({cases} cases, {size}²). Command: `python -m "
        f"train_py.highlights --oracle --size {size}` ({seconds:.0f} s).",
        "",
        "| true maps, except | peak within 10 px | median peak error (px) |",
        "|---|---:|---:|",
    ]
    lines += [f"| {name} | {100 * share:.0f}% | {median:.1f} |" for name, share, median in rows]
    return "\n".join(lines) + "\n"


def glossy(maps: dict[str, torch.Tensor], index: int) -> dict[str, torch.Tensor]:
    """The glossy variant of test material ``index`` (deterministic)."""
    g = torch.Generator().manual_seed(1000 + index)
    target = ROUGHNESS_RANGE[0] + (ROUGHNESS_RANGE[1] - ROUGHNESS_RANGE[0]) * float(torch.rand((), generator=g))
    rough = maps["roughness"] * (target / maps["roughness"].median())
    return {**maps, "roughness": rough.clamp(0.02, 1), "specular": maps["specular"].clamp(min=SPECULAR_MIN)}


def blurred_luminance(radiance: torch.Tensor) -> torch.Tensor:
    """The luminance (channel mean) of ``[H, W, 3]`` blurred with a Gaussian of σ = ``PEAK_SIGMA``
    px (replicate padding), ``[H, W]``."""
    lum = radiance.mean(-1)[None, None]
    r = int(3 * PEAK_SIGMA)
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-(x**2) / (2 * PEAK_SIGMA**2))
    k = k / k.sum()
    lum = F.conv2d(F.pad(lum, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1))
    return F.conv2d(F.pad(lum, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1))[0, 0]


def argmax_2d(image: torch.Tensor) -> tuple[int, int]:
    """(row, col) of the maximum of ``[H, W]``."""
    return divmod(int(image.argmax()), image.shape[1])


def blurred_peak(radiance: torch.Tensor) -> tuple[int, int]:
    """(row, col) of the maximum of :func:`blurred_luminance`."""
    return argmax_2d(blurred_luminance(radiance))


def score(pred: torch.Tensor, truth: torch.Tensor, clipped: torch.Tensor) -> tuple[float, float, float | None]:
    """Peak distance (in pixels of a 256² image), peak brightness ratio (the relit blurred luminance
    at the truth's peak over the truth's) and clipped-region mean radiance ratio (None when nothing
    clipped)."""
    truth_lum, pred_lum = blurred_luminance(truth), blurred_luminance(pred)
    (tr, tc), (pr, pc) = argmax_2d(truth_lum), argmax_2d(pred_lum)
    dist = math.hypot(pr - tr, pc - tc) * REFERENCE_SIZE / pred.shape[1]
    bright = float(pred_lum[tr, tc] / truth_lum[tr, tc].clamp(min=1e-6))
    if not clipped.any():
        return dist, bright, None
    ratio = float(pred.mean(-1)[clipped].mean() / truth.mean(-1)[clipped].mean().clamp(min=1e-6))
    return dist, bright, ratio


def run(
    model, size: int = REFERENCE_SIZE, count: int | None = None, keep_clipped: bool = False
) -> dict[str, dict[str, float]]:
    """Pass rates and medians for the model (if given) and the diffuse fit, over the first ``count``
    test sets (default all); ``keep_clipped``: the network's own params where the capture clipped."""
    res: dict[str, list[tuple[float, float, float | None]]] = (
        {"model": [], "diffuse fit": []} if model else {"diffuse fit": []}
    )
    view = ggx.capture_position().view(1, 1, 3)
    for maps, cases in glossy_sets(size, count):
        photo = ggx.ldr_capture(ggx.render_capture(maps))
        clipped = ggx.clipped(photo[0])
        params = None
        if model is not None:
            with torch.no_grad():
                params = model.estimate_photo(photo, fill=not keep_clipped)
        for light, truth in cases:
            wi, wo, _ = ggx.directions(light, view, size, size)
            res["diffuse fit"].append(score(diffuse_fit(photo, wi)[0, 0], truth, clipped))
            if params is not None:
                with torch.no_grad():
                    pred = ggx.from_log(model.relight_log(params, wi[:, 0], wo[:, 0]))[0]
                res["model"].append(score(pred, truth, clipped))
    out = {}
    for method, rows in res.items():
        within, median = peak_stats([d for d, _, _ in rows])
        bright = torch.tensor([b for _, b, _ in rows])
        ratios = torch.tensor([r for _, _, r in rows if r is not None])
        ok = (ratios >= CLIPPED_RATIO[0]) & (ratios <= CLIPPED_RATIO[1])
        out[method] = {
            "cases": len(rows),
            "peak_within": within,
            "peak_median_px": median,
            "bright_within": float(((bright >= CLIPPED_RATIO[0]) & (bright <= CLIPPED_RATIO[1])).float().mean()),
            "bright_ratio_median": float(bright.median()),
            "clipped_cases": len(ratios),
            "clipped_within": float(ok.float().mean()) if len(ratios) else float("nan"),
            "clipped_ratio_median": float(ratios.median()) if len(ratios) else float("nan"),
        }
    return out


def markdown(res: dict, model_path: str | None, size: int, seconds: float, keep_clipped: bool = False) -> str:
    sets = res["diffuse fit"]["cases"] // len(MOVED_LIGHTS)
    lines = [
        "# Highlight test: glossy variants of materials/test, light moved from the camera",
        "",
        f"{sets} test sets, roughness median {ROUGHNESS_RANGE[0]}–{ROUGHNESS_RANGE[1]}, "
        f"{size}², 28° ideal 8-bit capture, {len(MOVED_LIGHTS)} moved lights each. Peak: blurred (σ {PEAK_SIGMA} px) "
        f"luminance maximum within {PEAK_TOLERANCE_PX:.0f} px of the GGX truth's. Clipped: mean radiance over "
        f"the pixels the capture clipped within {CLIPPED_RATIO[0]}–{CLIPPED_RATIO[1]}× the truth. Peak "
        f"brightness: the relit blurred luminance at the truth's peak within {CLIPPED_RATIO[0]}–{CLIPPED_RATIO[1]}× "
        "the truth's. Model: "
        f"`{model_path}`. Command: `python -m train_py.highlights --model {model_path} --size {size}"
        f"{' --keep-clipped' if keep_clipped else ''}` "
        f"({seconds:.0f} s). Peak errors are in pixels of a {REFERENCE_SIZE}² image.",
        "",
        "| method | peak within 10 px ↑ | median peak error (px) | peak brightness within 0.5–2× ↑ "
        "| median peak brightness ratio | clipped within 0.5–2× ↑ | median clipped ratio |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m, r in res.items():
        lines.append(
            f"| {m} | {100 * r['peak_within']:.0f}% of {r['cases']} | {r['peak_median_px']:.1f} | "
            f"{100 * r['bright_within']:.0f}% | {r['bright_ratio_median']:.2f} | "
            f"{100 * r['clipped_within']:.0f}% of {r['clipped_cases']} | {r['clipped_ratio_median']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", help="model .safetensors (omit: diffuse fit only)")
    ap.add_argument("--size", type=int, default=REFERENCE_SIZE, help="image side (quick checks: smaller)")
    ap.add_argument("--materials", type=int, default=None, help="only the first N test sets (quick checks)")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--oracle", action="store_true", help="score perturbed true maps instead of a model")
    ap.add_argument(
        "--keep-clipped", action="store_true", help="the network's own params where the capture clipped (not filled)"
    )
    ap.add_argument("-o", "--output")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.oracle:
        t0 = time.time()
        rows, cases = oracle(args.size, args.materials)
        md = oracle_markdown(rows, args.size, cases, time.time() - t0)
        print(md)
        if args.output:
            Path(args.output).write_text(md)
        return
    from .export import load_model

    model = load_model(args.model) if args.model else None
    t0 = time.time()
    res = run(model, args.size, args.materials, args.keep_clipped)
    md = markdown(res, args.model, args.size, time.time() - t0, args.keep_clipped)
    print(md)
    if args.output:
        Path(args.output).write_text(md)


if __name__ == "__main__":
    main()
