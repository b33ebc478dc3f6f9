"""Can the U-Net read the geometry of a highlight from one flash photo? (issue 24 diagnostic)

The highlight test passes only where the estimate knows the normals to a few pixels
(``highlights --oracle``: flat normals 43%, normals blurred over 9 px 59%), and a probe trained
with the rendering loss (``train --maps-weight``) never beat a flat-normal guess. This trains the
same U-Net, with the same data (real sets and procedural materials, phone-like captures), on
the maps alone: ``M_est`` → 64-d params → :class:`~train_py.train.MapProbe` → normal and roughness,
dense L1 against the true maps, no rendering loss. It measures the most any estimate of this
width can give the test at a CPU budget: its normals and roughness, with the true diffuse and
specular, rendered under the test's moved lights and scored by the test's peak check.

    python -m train_py.maps_net --out runs/maps --minutes 60 --threads 1 --bf16
    python -m train_py.maps_net --score runs/maps/ckpt.pt --size 256    # the table only

Not part of the shipped model: the model file and the runtime do not change.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from . import gen, ggx, materials
from .export import freeze_batchnorm, unfold_model
from .highlights import glossy_sets, peak_stats, score
from .model import CONFIGS, UNet
from .train import RUN_SEED_STRIDE, DataMix, MapProbe, draw_batch, lr_at, maps_l1

#: Side of the scoring renders (peak distances are scaled to 256²).
SCORE_SIZE = 128


class MapsNet(nn.Module):
    """``M_est`` followed by the map probe: network input ``[B, 4, H, W]`` → (normal ``[B, H, W,
    3]``, roughness ``[B, H, W]``)."""

    def __init__(self, width: int, input_skip: bool):
        super().__init__()
        self.est = UNet(width, folded=False, input_skip=input_skip)
        self.probe = MapProbe()

    def forward(self, net_input: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.probe(self.est(net_input))


def tilt_unexplained(normal: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Squared error of the normal's x, y against the truth's over the truth's own squared tilt
    (a flat guess scores 1, the truth 0): the mean regression of a weak signal. Under L1 alone a
    normal map that is only partly predictable from the photo is learnt as its median, flat."""
    err = (normal[..., :2] - truth[..., :2]).square().sum()
    return err / truth[..., :2].square().sum().clamp(min=1e-8)


def build(init_from: str | None, width: int) -> tuple[MapsNet, bool]:
    """The net, with its U-Net copied from a model file when given; and whether its BatchNorms
    stay frozen (they do for a folded model file, as in ``train --init-from``)."""
    if not init_from:
        return MapsNet(width, input_skip=True), False
    model = unfold_model(init_from)
    net = MapsNet(model.config.width, model.config.input_skip)
    net.est.load_state_dict(model.est.state_dict())
    return net, True


@torch.no_grad()
def score_maps(net: MapsNet, size: int = SCORE_SIZE, count: int | None = None) -> dict[str, float]:
    """The glossy test sets' ideal 28° captures through the net: normal and roughness L1 against
    the truth (and against flat normals / each material's median roughness), and the peak check of
    GGX renders with the estimated normals (and roughness) in place of the true ones."""
    net.eval()
    view = ggx.capture_position().view(1, 1, 3)
    sums = {"normal": 0.0, "normal_flat": 0.0, "tilt": 0.0, "rough": 0.0, "rough_median": 0.0}
    dists: dict[str, list[float]] = {"normals": [], "normals + roughness": [], "flat normals": []}
    sets = 0
    for maps, cases in glossy_sets(size, count):
        photo = ggx.ldr_capture(ggx.render_capture(maps))
        normal, rough = net(ggx.network_input(photo, "ldr"))
        normal, rough = normal.float(), rough.float()
        flat = torch.tensor([0.0, 0.0, 1.0]).expand_as(maps["normal"])
        sums["normal"] += float((normal - maps["normal"]).abs().mean())
        sums["normal_flat"] += float((flat - maps["normal"]).abs().mean())
        sums["tilt"] += float(tilt_unexplained(normal, maps["normal"]))
        sums["rough"] += float((rough - maps["roughness"]).abs().mean())
        sums["rough_median"] += float((maps["roughness"].median() - maps["roughness"]).abs().mean())
        sets += 1
        unit = F.normalize(normal, dim=-1)
        variants = {
            "normals": {**maps, "normal": unit},
            "normals + roughness": {**maps, "normal": unit, "roughness": rough.clamp(0.02, 1)},
            "flat normals": {**maps, "normal": flat.contiguous()},
        }
        no_clip = torch.zeros((size, size), dtype=torch.bool)
        for light, truth in cases:
            for name, m in variants.items():
                dists[name].append(score(ggx.render_maps(m, light, view)[0, 0], truth, no_clip)[0])
    out = {k: v / sets for k, v in sums.items()}
    for name, d in dists.items():
        out[f"peak {name}"], out[f"median px {name}"] = peak_stats(d)
    out["cases"] = len(dists["normals"])
    return out


#: Held-out batches of the training distribution that :func:`heldout_tilt` reads: count, materials
#: per batch, side.
HELDOUT_BATCHES = (4, 8, 96)


@torch.no_grad()
def heldout_tilt(net: MapsNet, real_frac: float, root: Path = materials.DEFAULT_ROOT) -> float:
    """Mean :func:`tilt_unexplained` over :data:`HELDOUT_BATCHES` phone captures drawn like the
    training data (materials from ``materials/train`` with share ``real_frac``, the rest
    procedural; ``root``: the material sets), from seeds at ``gen.HELD_OUT_SEED_BASE`` that training
    never draws."""
    net.eval()
    count, batch, side = HELDOUT_BATCHES
    bank = materials.MaterialBank("train", root) if real_frac > 0 else None
    total = 0.0
    for b in range(count):
        seeds = [gen.HELD_OUT_SEED_BASE + batch * b + i for i in range(batch)]
        maps, net_input, _ = draw_batch(seeds, side, "cpu", bank, DataMix(real_frac, phone=1.0))
        total += float(tilt_unexplained(net(net_input)[0].float(), maps["normal"]))
    return total / count


def markdown(res: dict[str, float], source: str, size: int) -> str:
    lines = [
        "# Maps from one flash photo: what the highlight test could get",
        "",
        f"Net: `{source}`; glossy test sets, ideal 28° captures, {size}² "
        f"({int(res['cases'])} moved-light cases). Command: `python -m train_py.maps_net --score "
        f"{source} --size {size}`.",
        "",
        f"- normal L1 (per component) {res['normal']:.4f}; flat normals {res['normal_flat']:.4f}",
        f"- normal tilt unexplained (squared x, y error over the true tilt's; flat = 1) {res['tilt']:.3f}; "
        f"on held-out phone captures of the training data: real sets {res['tilt_real']:.3f}, procedural "
        f"{res['tilt_procedural']:.3f}",
        f"- roughness L1 {res['rough']:.4f}; each material's median {res['rough_median']:.4f}",
        "",
        "| GGX render of the true maps, except | peak within 10 px | median peak error (px, 256²) |",
        "|---|---:|---:|",
    ]
    for name in ("normals", "normals + roughness", "flat normals"):
        label = name if name == "flat normals" else f"estimated {name}"
        lines.append(f"| {label} | {100 * res[f'peak {name}']:.0f}% | {res[f'median px {name}']:.1f} |")
    return "\n".join(lines) + "\n"


def train(args) -> None:
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / "ckpt.pt"
    net, frozen_bn = build(args.init_from, args.width)
    groups = [
        {"params": list(net.est.parameters()), "lr_scale": 1.0},
        {"params": list(net.probe.parameters()), "lr_scale": MapProbe.LR_SCALE},
    ]
    opt = torch.optim.Adam(groups, lr=args.lr)
    state = {"step": 0, "elapsed": 0.0, "cpu": 0.0, "frozen_bn": frozen_bn}
    if args.resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, weights_only=False)
        net.load_state_dict(ckpt["net"])
        opt.load_state_dict(ckpt["optimizer"])
        state.update({k: ckpt[k] for k in state})
    bank = materials.MaterialBank("train", Path(args.materials_root))
    data_gen = torch.Generator().manual_seed(args.seed * RUN_SEED_STRIDE + state["step"])
    sizes = [int(v) for v in args.sizes.split(",")]
    log = open(out / "train.log", "a")  # noqa: SIM115 (kept open for the run)

    def emit(line: str) -> None:
        print(line, flush=True)
        log.write(line + "\n")
        log.flush()

    def save() -> None:
        torch.save({"net": net.state_dict(), "optimizer": opt.state_dict(), **state}, ckpt_path)

    emit(f"# {json.dumps(vars(args))}")
    start, cpu_start = time.time() - state["elapsed"], time.process_time() - state["cpu"]
    last_ckpt = last_score = time.time()
    ema = None
    while (elapsed := time.time() - start) < 60 * args.minutes:
        for group in opt.param_groups:
            group["lr"] = lr_at(elapsed / (60 * args.minutes), args.lr, args.lr_final) * group["lr_scale"]
        seeds = torch.randint(0, gen.HELD_OUT_SEED_BASE, (args.batch,), generator=data_gen).tolist()
        size = sizes[int(torch.randint(0, len(sizes), (), generator=data_gen))]
        maps, net_input, _ = draw_batch(seeds, size, "cpu", bank, DataMix(args.real_frac, phone=1.0))
        net.train()
        if state["frozen_bn"]:
            freeze_batchnorm(net)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=args.bf16):
            params = net.est(net_input)
        normal, rough = net.probe(params)
        loss = maps_l1(normal, rough, maps)
        if args.tilt_weight:
            loss = loss + args.tilt_weight * tilt_unexplained(normal, maps["normal"])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        state["step"] += 1
        val = float(loss.detach())
        ema = val if ema is None else 0.98 * ema + 0.02 * val
        state.update(elapsed=time.time() - start, cpu=time.process_time() - cpu_start)
        if state["step"] % args.log_every == 0:
            emit(f"step {state['step']:6d}  maps {val:.4f}  ema {ema:.4f}  {elapsed / 60:.1f} min")
        if time.time() - last_ckpt > 300:
            save()
            last_ckpt = time.time()
        if args.score_every and time.time() - last_score > 60 * args.score_every:
            res = score_maps(net, count=args.score_count)
            emit("score " + "  ".join(f"{k} {v:.4f}" for k, v in res.items()))
            last_score = time.time()
    save()
    emit(f"done: {state['step']} steps, {state['elapsed'] / 60:.1f} min ({state['cpu'] / 60:.1f} CPU-min)")
    log.close()


def load_net(path: str) -> MapsNet:
    """The net of a checkpoint written by :func:`train` (width and input skip read off its weights)."""
    state = torch.load(path, weights_only=False)["net"]
    width = state["est.stem.weight"].shape[0]
    net = MapsNet(width, input_skip=state["est.head.weight"].shape[1] != width)
    net.load_state_dict(state)
    return net


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="runs/maps")
    ap.add_argument("--score", metavar="CKPT", help="score a trained net's checkpoint and exit")
    ap.add_argument("--size", type=int, default=SCORE_SIZE, help="side of the scoring renders")
    ap.add_argument("-o", "--output", help="with --score: write the table here")
    ap.add_argument("--init-from", default="models/default.safetensors", help="model file for the U-Net; '' = fresh")
    ap.add_argument("--width", type=int, default=CONFIGS["small"].width, help="U-Net width of a fresh net")
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--sizes", default="64,96")
    ap.add_argument("--real-frac", type=float, default=0.5)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--lr-final", type=float, default=1e-5)
    ap.add_argument("--seed", type=int, default=70)
    ap.add_argument("--tilt-weight", type=float, default=0.0, help="weight of the normals' relative squared tilt error")
    ap.add_argument("--bf16", action="store_true", help="bf16 autocast for the U-Net")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--log-every", type=int, default=25)
    ap.add_argument("--score-every", type=float, default=15.0, help="minutes between scores (0: none)")
    ap.add_argument("--score-count", type=int, default=None, help="glossy test sets scored during training")
    ap.add_argument("--materials-root", default=str(materials.DEFAULT_ROOT))
    args = ap.parse_args(argv)
    if args.score:
        t0 = time.time()
        net = load_net(args.score)
        res = score_maps(net, args.size)
        root = Path(args.materials_root)
        res["tilt_real"], res["tilt_procedural"] = heldout_tilt(net, 1.0, root), heldout_tilt(net, 0.0, root)
        text = markdown(res, args.score, args.size)
        print(text + f"\n({time.time() - t0:.0f} s)")
        if args.output:
            Path(args.output).write_text(text)
        return
    if not math.isfinite(args.minutes) or args.minutes <= 0:
        raise SystemExit("--minutes must be a positive number")
    train(args)


if __name__ == "__main__":
    main()
