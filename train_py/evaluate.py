"""Evaluation on held-out SVBRDFs (paper §4, DESIGN.md §8) → Markdown table.

    python -m train_py.evaluate --model models/default.safetensors -o models/default.eval.md

The procedural set is ``assets/heldout`` (the files ``nam-cli report`` reads; box-downsampled in
linear space as nam-eval does), and the light/view pairs come from ``protocols.seeded_pairs``
(nam-ggx's sampler, draw for draw), so this table and the Rust report score the same images
(``python -m train_py.eval_agreement`` pins both).

Protocols: Reflect (training sampling), Identity (co-located at the capture position),
Hemisphere (independent light and view uniform on the hemisphere r = 4; 128 per material).
Methods: the model; "printout" (the LDR input photo reused for every light/view); "diffuse fit"
(per-pixel Lambertian albedo from the photo, n = +z, rendered with the new light).
Metrics: log-space L1 (mean over pixels and channels of |ln(1+R̂) - ln(1+R)|) and SSIM on
display images ``clamp(R, 0, 1)^(1/2.2)`` (11×11 Gaussian window, σ = 1.5).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from . import capture, gen, ggx, materials, protocols
from .model import NamModel

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2
#: Base of the per-material pair seeds (nam-eval's ``heldout::EVAL_SEED``).
EVAL_SEED = 4242
#: The held-out procedural set (``gen.HELD_OUT_SEED_BASE + 2000 + i``, 64², 8-bit 4-panel PNGs).
HELDOUT_DIR = Path(__file__).resolve().parent.parent / "assets" / "heldout"


def pair_seed(material_seed: int, protocol: str) -> int:
    """The pair seed of one material and protocol (nam-eval's ``Material::pairs``)."""
    return EVAL_SEED + material_seed % 100000 + 17 * protocols.PROTOCOLS.index(protocol)


def box_downsample(maps: dict[str, torch.Tensor], size: int) -> dict[str, torch.Tensor]:
    """Maps ``[1, S, S, ...]`` averaged over ``S/size``² blocks in linear space, normals
    renormalised (nam-eval's ``heldout::downsample``); ``size`` must divide ``S``."""
    side = maps["roughness"].shape[-1]
    if size == side:
        return maps
    if size <= 0 or side % size:
        raise SystemExit(f"cannot resample {side}² maps to {size}² (needs a divisor of {side})")
    pool = lambda v: F.avg_pool2d(v.movedim(-1, 1), side // size).movedim(1, -1)  # noqa: E731
    out = {k: pool(v) for k, v in maps.items() if k != "roughness"}
    out["normal"] = ggx.normalize(out["normal"])
    out["roughness"] = pool(maps["roughness"][..., None])[..., 0]
    return out


def heldout_sets(count: int | None, size: int | None):
    """``(seed, maps)`` of the first ``count`` files of ``assets/heldout`` at ``size``² (default: the
    files' own 64²); the seed comes from the file name."""
    files = sorted(HELDOUT_DIR.glob("material_*.png"))[:count]
    if not files:
        raise SystemExit(f"no material_*.png in {HELDOUT_DIR}")
    for f in files:
        maps = materials.load_maps(f, None)
        yield int(f.stem.rsplit("_", 1)[1]), box_downsample(maps, size or maps["roughness"].shape[-1])


def evaluation_sets(which: str, count: int | None, size: int | None) -> tuple[list, int, str, list[str]]:
    """The evaluation's materials as ``(seed, maps [1, S, S, ...])``, their side ``S``, a
    description and each material's name (a real set's file stem, a procedural one's seed):
    ``procedural`` (``assets/heldout``; 64² or a divisor) or ``test`` (the real sets of
    materials/test; default 128²); the first ``count`` (None: all)."""
    if which == "test":
        size = size or 128
        files = materials.list_files("test")[:count]
        sets = [(EVAL_SEED + i, materials.load_maps(f, size)) for i, f in enumerate(files)]
        what = f"{len(files)} real CC0 SVBRDFs of materials/test (never trained on) at {size}²"
        return sets, size, what, [f.stem for f in files]
    sets = list(heldout_sets(count, size))
    side = sets[0][1]["roughness"].shape[-1]
    seeds = [seed for seed, _ in sets]
    return (
        sets,
        side,
        f"{len(sets)} held-out procedural SVBRDFs (assets/heldout, seeds {seeds[0]}..{seeds[-1]}) at {side}²",
        [str(seed) for seed in seeds],
    )


def gaussian_window(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32) - size // 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of display images ``[N, H, W, 3]`` in [0, 1] (per channel, valid window)."""
    x = a.permute(0, 3, 1, 2).reshape(-1, 1, *a.shape[1:3])
    y = b.permute(0, 3, 1, 2).reshape(-1, 1, *b.shape[1:3])
    win = gaussian_window().to(a.device)
    mx, my = F.conv2d(x, win), F.conv2d(y, win)
    sxx = F.conv2d(x * x, win) - mx * mx
    syy = F.conv2d(y * y, win) - my * my
    sxy = F.conv2d(x * y, win) - mx * my
    s = ((2 * mx * my + SSIM_C1) * (2 * sxy + SSIM_C2)) / ((mx * mx + my * my + SSIM_C1) * (sxx + syy + SSIM_C2))
    return s.mean()


def to_display(radiance: torch.Tensor) -> torch.Tensor:
    return torch.clamp(radiance, 0, 1) ** (1 / 2.2)


def diffuse_fit(photo: torch.Tensor, wi: torch.Tensor, distance: float = ggx.CAPTURE_DISTANCE) -> torch.Tensor:
    """Lambertian relight of the LDR photo taken from ``(0, 0, distance)``: albedo = photo /
    cos θ_capture, times the new cos θ."""
    h, w = photo.shape[1:3]
    cos_capture = ggx.capture_half_z(h, w, photo.dtype, photo.device, distance)  # co-located: wi = wh
    albedo = photo / cos_capture[None, :, :, None]
    return albedo[:, None] * torch.clamp(wi[..., 2:3], min=0)


def evaluate_protocols(
    model: NamModel | None,
    seeds: list[int],
    size: int,
    hemisphere_k: int = 128,
    reflect_k: int = 8,
    device: str = "cpu",
    protocol_names: tuple[str, ...] = protocols.PROTOCOLS,
) -> dict[str, dict[str, dict[str, float]]]:
    """``{protocol: {method: {"log_l1", "ssim"}}}`` averaged over the procedural materials of
    ``seeds`` and light/view pairs."""
    sets = ((seed, gen.batch([seed], size, device)) for seed in seeds)
    return evaluate_maps(model, sets, len(seeds), hemisphere_k, reflect_k, device, protocol_names)


def photograph(seed: int, maps: dict[str, torch.Tensor], phone: bool) -> tuple[dict, torch.Tensor, float]:
    """The photo the evaluation gives a material, as ``(maps, photo [1, H, W, 3], capture distance)``:
    the ideal 28° co-located 8-bit capture, or (``phone``) a phone-like one drawn from ``seed``
    (``capture.Capture.random``: field of view, flash off the lens axis; auto-exposure, which
    rescales the maps the truth is rendered from; noise, clipping, 8-bit sRGB, sometimes JPEG)."""
    if not phone:
        return maps, ggx.ldr_capture(ggx.render_capture(maps)), ggx.CAPTURE_DISTANCE
    rng = gen.Rng(seed)
    cap = capture.Capture.random(rng.gen)
    maps = capture.expose(maps, cap, rng)
    return maps, capture.phone_photo(capture.render(maps, cap), rng), cap.distance


def evaluate_maps(
    model: NamModel | None,
    sets,
    count: int,
    hemisphere_k: int = 128,
    reflect_k: int = 8,
    device: str = "cpu",
    protocol_names: tuple[str, ...] = protocols.PROTOCOLS,
    keep_clipped: bool = False,
    per_material: list | None = None,
    phone: bool = False,
) -> dict[str, dict[str, dict[str, float]]]:
    """As :func:`evaluate_protocols` for ``count`` materials given as ``(seed, maps [1, H, W, ...])``;
    ``seed`` picks the light/view pairs. ``keep_clipped``: the network's own params where the
    capture clipped (``NamModel.estimate_photo``). ``per_material``: if given, one
    ``{protocol: {method: {"log_l1", "signed"}}}`` per material is appended to it (``signed``: the
    mean of ln(1+R̂) − ln(1+R), > 0 too bright). ``phone``: phone-like captures (:func:`photograph`)."""
    counts = {"reflect": reflect_k, "identity": 1, "hemisphere": hemisphere_k}
    sums: dict[str, dict[str, dict[str, float]]] = {}
    for p in protocol_names:
        methods = ["printout", "diffuse fit"] + (["model"] if model is not None else [])
        sums[p] = {m: {"log_l1": 0.0, "ssim": 0.0} for m in methods}
    for seed, maps in sets:
        own: dict[str, dict[str, dict[str, float]]] = {p: {} for p in protocol_names}
        size = maps["roughness"].shape[-1]
        maps, photo, distance = photograph(seed, maps, phone)
        params = None
        if model is not None:
            with torch.no_grad():
                params = model.estimate_photo(photo, distance, fill=not keep_clipped)
        for p in protocol_names:
            light, view = protocols.seeded_pairs(p, counts[p], pair_seed(seed, p))
            light, view = light.float().to(device), view.float().to(device)
            gt = ggx.render_maps(maps, light, view)[0]  # [K, H, W, 3]
            wi, wo, _ = ggx.directions(light, view, size, size)
            preds = {
                "printout": photo.expand_as(gt),
                "diffuse fit": diffuse_fit(photo, wi, distance)[0],
            }
            if params is not None:
                with torch.no_grad():
                    logs = [model.relight_log(params, wi[:, k], wo[:, k]) for k in range(wi.shape[1])]
                preds["model"] = ggx.from_log(torch.cat(logs, dim=0))
            gt_log = ggx.to_log(gt)
            for m, pred in preds.items():
                err = ggx.to_log(pred) - gt_log
                own[p][m] = {"log_l1": float(err.abs().mean()), "signed": float(err.mean())}
                sums[p][m]["log_l1"] += own[p][m]["log_l1"] / count
                sums[p][m]["ssim"] += float(ssim(to_display(pred), to_display(gt))) / count
        if per_material is not None:
            per_material.append(own)
    return sums


def markdown(results: dict, title: str, note: str) -> str:
    lines = [
        f"# {title}",
        "",
        note,
        "",
        "| method | " + " | ".join(f"{p} log-L1 ↓ | {p} SSIM ↑" for p in results) + " |",
        "|---|" + "---:|---:|" * len(results),
    ]
    methods = list(next(iter(results.values())).keys())
    for m in methods:
        cells = [f"{results[p][m]['log_l1']:.4f} | {results[p][m]['ssim']:.4f}" for p in results]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    if "model" in methods and "hemisphere" in results:
        h = results["hemisphere"]
        gain = 1 - h["model"]["log_l1"] / h["printout"]["log_l1"]
        ratio = h["model"]["log_l1"] / h["diffuse fit"]["log_l1"]
        lines += [
            "",
            f"Hemisphere log-L1: model is {100 * gain:.1f}% lower than printout, {ratio:.2f}× the diffuse fit.",
        ]
    return "\n".join(lines) + "\n"


def per_material_markdown(labels: list[str], rows: list[dict], protocol: str = "hemisphere") -> str:
    """One protocol's log-L1 per material (rows as :func:`evaluate_maps` appends them): the model,
    the diffuse fit, their ratio, the model's signed error and its share of the model's mean."""
    total = sum(r[protocol]["model"]["log_l1"] for r in rows)
    lines = [
        f"## {protocol.capitalize()} log-L1 per material",
        "",
        "| material | model | diffuse fit | model ÷ fit | model signed (> 0: too bright) | share of model error |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for label, r in zip(labels, rows, strict=True):
        m, f = r[protocol]["model"], r[protocol]["diffuse fit"]
        lines.append(
            f"| {label} | {m['log_l1']:.4f} | {f['log_l1']:.4f} | {m['log_l1'] / f['log_l1']:.2f} | "
            f"{m['signed']:+.4f} | {100 * m['log_l1'] / total:.0f}% |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", help="model .safetensors (omit: baselines only)")
    ap.add_argument(
        "--set",
        default="procedural",
        choices=["procedural", "test"],
        help="held-out procedural materials, or the real CC0 sets of materials/test",
    )
    ap.add_argument("--materials", type=int, default=None, help="how many (default: all; procedural 8, test 19)")
    ap.add_argument("--size", type=int, default=None, help="image side (procedural: 64 or a divisor; test: 128)")
    ap.add_argument("--hemisphere", type=int, default=128)
    ap.add_argument("--reflect", type=int, default=8)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument(
        "--keep-clipped", action="store_true", help="the network's own params where the capture clipped (not filled)"
    )
    ap.add_argument(
        "--per-material", action="store_true", help="add a table of each material's Hemisphere log-L1 (needs --model)"
    )
    ap.add_argument(
        "--phone-capture",
        action="store_true",
        help="give each material a seeded phone-like photo (field of view 26-50 deg, flash off the lens "
        "axis, auto-exposure, noise, clipping, JPEG) instead of the ideal 28 deg capture",
    )
    ap.add_argument("-o", "--output", help="write the Markdown table here")
    args = ap.parse_args(argv)
    if args.per_material and not args.model:
        ap.error("--per-material needs --model")
    if args.threads:
        torch.set_num_threads(args.threads)
    from .export import load_model

    model = load_model(args.model) if args.model else None
    t0 = time.time()
    sets, size, what, labels = evaluation_sets(args.set, args.materials, args.size)
    rows: list | None = [] if args.per_material else None
    res = evaluate_maps(
        model,
        sets,
        len(sets),
        args.hemisphere,
        args.reflect,
        keep_clipped=args.keep_clipped,
        per_material=rows,
        phone=args.phone_capture,
    )
    note = (
        f"{what}, "
        + ("seeded phone-like captures (`--phone-capture`)" if args.phone_capture else "ideal 28° LDR 8-bit capture")
        + f" input; Reflect {args.reflect}, Identity 1, Hemisphere {args.hemisphere} "
        f"light/view pairs per material. Model: `{args.model}`. "
        f"Command: `python -m train_py.evaluate --model {args.model} --set {args.set} "
        + (f"--materials {args.materials} " if args.materials else "")
        + f"--size {size} --hemisphere {args.hemisphere}"
        + (" --keep-clipped" if args.keep_clipped else "")
        + (" --per-material" if args.per_material else "")
        + (" --phone-capture" if args.phone_capture else "")
        + f"` ({time.time() - t0:.0f} s)."
    )
    md = markdown(res, "Evaluation: log-L1 and SSIM by protocol", note)
    if rows is not None:
        md += "\n" + per_material_markdown(labels, rows)
    print(md)
    if args.output:
        Path(args.output).write_text(md)


if __name__ == "__main__":
    main()
