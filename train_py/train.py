"""Train the neural appearance model on procedural SVBRDFs (paper §3.6, DESIGN.md §6).

    python -m train_py.train --config small --steps 2000 --out runs/small [--minutes 60] [--resume]
                             [--threads 1] [--device cpu|cuda]

Each step: ``--batch`` procedural materials at ``--size``² → LDR capture render (8-bit sRGB
round trip) → network input (log RGB + capture half-z) → params; ``--outputs`` exemplars per
material with Reflect sampling; 60% of the pixels of each exemplar drawn by inverse param-norm
(paper masking method 1) go through ND_enc + M_render; loss = L1 of log radiance.
Perceptual (LPIPS) and discriminator losses need pretrained / extra networks and are left out:
only the data loss is used, as the paper's own ablations make it the primary term.
Checkpoints (``ckpt.pt``) are written every ``--ckpt-minutes`` and at the end; ``--resume``
continues from one. ``--init-from`` starts a new schedule from a checkpoint's weights, or from a
(BN-folded) model file such as ``models/default.safetensors``: then the BatchNorms stay in eval
mode for the whole run (``export.unfold_model``), so a model can be fine-tuned across sessions.
Under ``torchrun`` (``WORLD_SIZE`` set) it runs DDP.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import torch
import torch.distributed as dist
import torch.nn.functional as F
import torch.utils.data
from torch import nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from . import capture, clip_fill, gen, ggx, materials, protocols
from .evaluate import evaluate_protocols
from .export import freeze_batchnorm, unfold_model
from .model import (
    CONFIGS,
    IN_CHANNELS,
    PARAM_CHANNELS,
    Affine,
    BasicBlock,
    Conv,
    ConvBN,
    HAConv,
    NamModel,
    ReverseBlock,
    positional_encoding,
    query_dirs,
)

#: Guards the inverse param-norm sampling weights against an all-zero parameter vector.
NORM_EPS = 1e-6


#: Offset of the display-space term: keeps the gradient of ``x^(1/2.2)`` finite at black.
DISPLAY_EPS = 1e-3


def display_l1(pred_log: torch.Tensor, target_log: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """L1 between ``(clamp(R, 0, 1) + ε)^(1/2.2)`` of prediction and target: the error as a display
    shows it. Log-L1 ≈ linear L1 for dark radiance, so a dark material's colour costs it almost
    nothing; in display space the same error is ~20× larger. An offline stand-in for the paper's
    perceptual term (LPIPS weights are not reachable here)."""
    pred = torch.expm1(pred_log.clamp(min=0)).clamp(max=1)
    target = torch.expm1(target_log).clamp(0, 1)
    gamma = 1 / 2.2
    return weighted_mean(((pred + DISPLAY_EPS) ** gamma - (target + DISPLAY_EPS) ** gamma).abs(), weights)


#: Offset of the chromaticity term's denominator (linear radiance): below ~this brightness a
#: pixel's chromaticity fades to 0 in both prediction and target, so dark pixels weigh little.
CHROMA_EPS = 1e-2


def chroma_l1(pred_log: torch.Tensor, target_log: torch.Tensor) -> torch.Tensor:
    """L1 between the chromaticities ``R / (R_r + R_g + R_b + ε)`` of prediction and target. A
    model that renders every material grey at the right brightness loses only ~8% of its log-L1
    (measured on a generator batch), so colour never wins against luminance and highlights; this
    term sees nothing *but* colour (and fades out on dark pixels through ``ε``)."""
    pred = torch.expm1(pred_log.clamp(min=0))
    target = torch.expm1(target_log).clamp(min=0)
    return (chromaticity(pred) - chromaticity(target)).abs().sum(-1).mean()


def chromaticity(radiance: torch.Tensor) -> torch.Tensor:
    """``R / (R_r + R_g + R_b + CHROMA_EPS)`` over the last axis."""
    return radiance / (radiance.sum(-1, keepdim=True) + CHROMA_EPS)


def with_input_skip(state: dict[str, torch.Tensor], had: bool, wants: bool) -> dict[str, torch.Tensor]:
    """``state`` for a model whose head does (``wants``) or does not see the network input; a head
    that gains the input starts with zero weights on it, so the model computes what it did."""
    if had == wants:
        return state
    if had:
        raise SystemExit("--init-from: the model file has --input-skip; keep it")
    head = state["est.head.weight"]
    pad = head.new_zeros(head.shape[0], IN_CHANNELS, *head.shape[2:])
    return {**state, "est.head.weight": torch.cat([head, pad], dim=1)}


def bottleneck_excess(e4: torch.Tensor, limit: float) -> torch.Tensor:
    """Mean of ``relu(|e4| − limit) / limit``. ``e4`` only feeds ``atan``, which is flat beyond a
    few hundred (``atan(256) = π/2 − 0.004``), so nothing a model computes needs larger values; with
    BatchNorms frozen (fine-tuning a model file) nothing else bounds them, and one fine-tune drove
    them to 5e4 on the real photos, within 1.3× of f16's largest value (65504)."""
    return F.softshrink(e4, limit).abs().mean().float() / limit


class ActivationExcess:
    """``train --activation-limit``: the sum of :func:`bottleneck_excess` over every U-Net tensor
    that the f16 trace (``examples/activation_range``) sees — conv, BatchNorm, HA-Conv and block
    outputs — while the U-Net trains. Bounding only ``e4`` let a BatchNorm inside the deepest
    block grow to 7498 in a longer fine-tune (9× below f16's largest value), so every tensor gets
    the same bound.

    Most steps nothing exceeds the limit, so the penalty's graph is built only for the tensors
    that do: :meth:`take` reads every traced tensor's largest magnitude first (one reduction each,
    outside autograd, and one read-back for all of them). Building it for every tensor made a
    CPU training step ~40% slower, and on a GPU it launched ~700 more kernels a step. Under
    ``train --compile`` the penalty is built for every tensor instead, inside the compiled graph,
    where returning the tensors for :meth:`take` would keep each one in memory (the compiled
    U-Net's forward and backward at batch 8, 96²: 0.46 s returning them, 0.41 s with the penalty
    in the graph, 0.285 s without a penalty; eager 0.57 s)."""

    def __init__(self, unet: nn.Module, limit: float):
        self.unet = unet
        self.limit = limit
        self.traced: list[torch.Tensor] = []
        #: Penalties already computed inside a compiled graph (scalars).
        self.computed: list[torch.Tensor] = []
        kinds = (Conv, ConvBN, Affine, nn.BatchNorm2d, HAConv, BasicBlock, ReverseBlock)
        for module in unet.modules():
            if isinstance(module, kinds):
                module.register_forward_hook(self._hook)

    def _hook(self, _module: nn.Module, _inputs, output: torch.Tensor) -> None:
        # ``unet.training``, not the module's: frozen BatchNorms are in eval mode but still count.
        if self.unet.training and torch.is_grad_enabled():
            if torch.compiler.is_compiling():
                self.computed.append(bottleneck_excess(output, self.limit))
            else:
                self.traced.append(output)

    def take(self) -> torch.Tensor | None:
        """The penalty of the tensors traced since the last call (``None`` when nothing was
        traced; 0 when nothing exceeds the limit), then reset."""
        traced, self.traced = self.traced, []
        computed, self.computed = self.computed, []
        if computed:
            return torch.stack(computed).sum()
        if not traced:
            return None
        # ``aminmax`` is one pass (an inf-norm of a bf16 tensor ran 17× slower on the CPU).
        peaks = torch.stack([torch.maximum(-lo, hi).float() for lo, hi in (torch.aminmax(t.detach()) for t in traced)])
        over = (peaks > self.limit).nonzero().flatten().tolist()
        total = torch.zeros((), device=peaks.device)
        for i in over:
            total = total + bottleneck_excess(traced[i], self.limit)
        return total


def select_pixels(params: torch.Tensor, k: int, frac: float, generator: torch.Generator | None) -> torch.Tensor:
    """Pixel indices ``[B, K, n]`` drawn without replacement ∝ 1/‖params‖ (paper masking method 1)."""
    b, _, h, w = params.shape
    with torch.no_grad():
        weights = 1.0 / (torch.linalg.vector_norm(params.detach().float(), dim=1).reshape(b, h * w) + NORM_EPS)
        n = max(1, round(frac * h * w))
        rows = weights.repeat_interleave(k, dim=0)
        idx = torch.multinomial(rows.cpu(), n, replacement=False, generator=generator).to(params.device)
    return idx.reshape(b, k, n)


def select_shared_pixels(b: int, hw: int, k: int, frac: float, generator: torch.Generator | None, device):
    """Pixel indices ``[B, K, n]``, uniform without replacement, the same for every material."""
    n = max(1, round(frac * hw))
    # A permutation per exemplar (0.55 ms for 8 × 128² here; sorting random keys took 7 ms, and
    # 15 ms of host time per step beside a GPU).
    idx = torch.stack([torch.randperm(hw, generator=generator)[:n] for _ in range(k)]).to(device, non_blocking=True)
    return idx.unsqueeze(0).expand(b, k, n)


def gather_rows(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``x`` [B, P, C], ``idx`` [B, K, n] → [B, K, n, C]."""
    b, k, n = idx.shape
    flat = idx.reshape(b, k * n)
    out = torch.gather(x, 1, flat[..., None].expand(b, k * n, x.shape[-1]))
    return out.reshape(b, k, n, x.shape[-1])


#: Offset of the specular share's denominator (linear radiance): black pixels have share 0.
SHARE_EPS = 1e-4


def specular_share(radiance: torch.Tensor, diffuse: torch.Tensor, normal: torch.Tensor, wi: torch.Tensor):
    """Share ``[...]`` in [0, 1] of the GGX radiance ``[..., 3]`` that is not the Lambertian term
    ``diffuse · max(n·wi, 0)``: ~1 inside a highlight, ~0 on a matte surface or away from it."""
    lambert = diffuse * ggx.dot(normal, wi).clamp(min=0).unsqueeze(-1)
    return ((radiance - lambert).sum(-1) / (radiance.sum(-1) + SHARE_EPS)).clamp(0, 1)


def highlight_weights(share: torch.Tensor, clipped: torch.Tensor, weight: float) -> torch.Tensor:
    """``train --highlight-weight``: per-query loss weights ``1 + weight · max(share, clipped)``
    ``[B, K, n]``. A highlight covers a few percent of a glossy exemplar's pixels, and where the
    photo clipped the model has to undo the capture highlight it sees there; uniform pixel
    weights let both cost little against the matte rest of the image (issue 24's highlight test
    scores exactly these two places)."""
    return 1 + weight * torch.maximum(share, clipped.to(share.dtype))


def weighted_mean(err: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
    """Mean of ``err`` ``[B, K, n, C]`` with per-query ``weights`` ``[B, K, n]`` (None: plain mean)."""
    if weights is None:
        return err.mean()
    return (err * weights.unsqueeze(-1)).sum() / (weights.sum() * err.shape[-1])


def input_clipped(net_input: torch.Tensor) -> torch.Tensor:
    """Where the capture photo clipped ``[B, H, W]``: the network input's log RGB decoded back to
    the 8-bit photo's linear values."""
    return ggx.clipped(torch.expm1(net_input[:, :3].float()).permute(0, 2, 3, 1))


def capture_clipped(net_input: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Whether the capture photo clipped at the selected pixels ``idx`` ``[B, K, n]``."""
    clipped = input_clipped(net_input).reshape(net_input.shape[0], -1, 1)
    return gather_rows(clipped, idx)[..., 0]


def exemplar_targets(maps, light, view, idx):
    """GGX log radiance, query directions and :func:`specular_share` at the selected pixels:
    ``[B, K, n, 3]``, ``[B, K, n, 9]``, ``[B, K, n]``."""
    b = idx.shape[0]
    h, w = maps["roughness"].shape[1:3]
    pos = ggx.pixel_positions(h, w, light.dtype, light.device).reshape(1, h * w, 3).expand(b, h * w, 3)
    p = gather_rows(pos, idx)
    wi = ggx.normalize(light[:, :, None, :] - p)
    wo = ggx.normalize(view[:, :, None, :] - p)
    flat = {key: v.reshape(b, h * w, -1) for key, v in maps.items()}
    sel = {key: gather_rows(v, idx) for key, v in flat.items()}
    radiance = ggx.ggx_radiance(sel["diffuse"], sel["specular"], sel["roughness"][..., 0], sel["normal"], wi, wo)
    share = specular_share(radiance, sel["diffuse"], sel["normal"], wi)
    return ggx.to_log(radiance), query_dirs(wi, wo), share


class TrainStep(nn.Module):
    """Forward of one training step (so DDP sees a single ``forward``): input → sampled log radiance."""

    def __init__(
        self,
        model: NamModel,
        straight_through: bool = True,
        shared_geometry: bool = False,
        compile_unet: bool = False,
        fill_clipped: bool = False,
    ):
        super().__init__()
        self.model = model
        #: ``train --compile``: the U-Net through ``torch.compile``, one static graph per crop size
        #: (a bound method, so the module's state_dict keys stay as they are).
        self.estimate = torch.compile(model.estimate, dynamic=False) if compile_unet else model.estimate
        #: Unscaled gradient through the final LeakyReLU(0.001) (see model.RenderMLP); without it
        #: the output dies within a few steps. ``False`` only for before/after experiments.
        self.straight_through = straight_through
        #: Every material of the step shares the exemplar light/view ``[1, K, 3]`` and the (uniform)
        #: pixel subset, so ND_enc — 86% of the per-query multiply-adds — runs once per exemplar
        #: pixel instead of once per material.
        self.shared_geometry = shared_geometry
        #: ``train --fill-clipped``: the params of the pixels the capture clipped are filled from the
        #: others (``clip_fill``, as the runtime does) before rendering.
        self.fill_clipped = fill_clipped

    def forward(self, net_input, k, frac, sel_gen, maps, light, view):
        params = self.estimate(net_input)
        if self.fill_clipped:
            params = clip_fill.fill_clipped(params, input_clipped(net_input))
        #: The step's parameter maps, kept for the latent regression (``train --latent-weight``).
        self.last_params = params
        b, _, h, w = params.shape
        if self.shared_geometry:
            idx = select_shared_pixels(b, h * w, k, frac, sel_gen, params.device)
            light, view = light.expand(b, k, 3), view.expand(b, k, 3)
        else:
            idx = select_pixels(params, k, frac, sel_gen)
        target, dirs, share = exemplar_targets(maps, light, view, idx)
        #: The step's pixel indices ``[B, K, n]`` and specular shares, for ``--highlight-weight``.
        self.last_idx, self.last_share = idx, share
        p = gather_rows(params.permute(0, 2, 3, 1).reshape(b, -1, PARAM_CHANNELS), idx)
        if self.shared_geometry:
            nd = self.model.nd_enc(positional_encoding(dirs[0]))
            x = torch.cat([p, nd.expand(b, *nd.shape)], dim=-1)
            pred = self.model.render(x.reshape(-1, x.shape[-1]), self.straight_through)
        else:
            pred = self.model.render_log(p.reshape(-1, PARAM_CHANNELS), dirs.reshape(-1, 9), self.straight_through)
        return pred.reshape(target.shape), target


def make_batch(seeds: list[int], size: int, device) -> tuple[dict, torch.Tensor]:
    """Procedural maps and the network input of their ideal capture (28°, co-located, 8-bit)."""
    maps = gen.batch(seeds, size, device)
    photo = ggx.ldr_capture(ggx.render_capture(maps))
    return maps, ggx.network_input(photo, "ldr")


@dataclasses.dataclass(frozen=True)
class DataMix:
    """What a step's materials and their photos are drawn from (:func:`draw_batch`)."""

    #: Share of the materials drawn from the real sets (augmented), the rest procedural.
    real_frac: float = 0.0
    #: Share of the steps with phone-like captures (``capture.photograph``), the rest the ideal 28°
    #: co-located one the evaluations use (0: all ideal, 1: all phone-like).
    phone: float = 0.0
    #: Probability that a material's normals are flattened (``+z``, before its capture).
    flat_normal_frac: float = 0.0
    #: Range of a phone capture's auto-exposed median radiance (log-uniform).
    exposure: tuple[float, float] = capture.EXPOSURE_MEDIAN

    @staticmethod
    def from_args(args) -> DataMix:
        phone = args.phone_frac if args.phone else 0.0
        return DataMix(args.real_frac, phone, args.flat_normal_frac, args.exposure_median)


def draw_maps(
    seeds: list[int], size: int, bank: materials.MaterialBank | None, mix: DataMix, rng: gen.Rng
) -> dict[str, torch.Tensor]:
    """The channel-last maps ``[B, H, W, ...]`` of one step's materials: real sets from ``bank``
    (share ``mix.real_frac``) then procedural ones, normals flattened with ``mix.flat_normal_frac``."""
    n_real = sum(rng.u() < mix.real_frac for _ in seeds) if bank is not None else 0
    parts = [materials.batch(bank, seeds[:n_real], size)] if n_real else []
    if n_real < len(seeds):
        parts.append(gen.batch(seeds[n_real:], size))
    maps = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    if mix.flat_normal_frac > 0:
        maps = materials.flat_normals(maps, torch.tensor([rng.u() < mix.flat_normal_frac for _ in seeds]))
    return maps


def draw_batch(
    seeds: list[int],
    size: int,
    device,
    bank: materials.MaterialBank | None,
    mix: DataMix,
) -> tuple[dict, torch.Tensor, capture.Capture]:
    """Maps, network input and capture of one step, drawn as ``mix`` says (real sets from
    ``bank``); a phone capture draws the field of view and flash offset for the step, exposure,
    noise, clipping and JPEG per material."""
    rng = gen.Rng(seeds[0] * 31 + 7)
    maps = draw_maps(seeds, size, bank, mix, rng)
    ideal = mix.phone == 0 or (mix.phone < 1 and rng.u() >= mix.phone)
    if ideal:
        photo = ggx.ldr_capture(ggx.render_capture(maps))
        return {k: v.to(device) for k, v in maps.items()}, ggx.network_input(photo, "ldr").to(device), capture.Capture()
    cap = capture.Capture.random(rng.gen)
    maps, net_input = capture.photograph(maps, cap, rng, mix.exposure)
    return {k: v.to(device) for k, v in maps.items()}, net_input.to(device), cap


#: Offset of the crop-size stream's seed from the run's: under DDP the sizes come from a stream
#: without the rank (``draw_seeds_and_size``'s ``size_g``).
SIZE_SEED_OFFSET = 15485863
#: Multiplier of the run's ``--seed`` in its data streams' seeds (``seed * RUN_SEED_STRIDE + ...``),
#: so neighbouring run seeds draw unrelated streams.
RUN_SEED_STRIDE = 1000003
#: A DDP rank's offset in its material stream's seed: ``seed + RANK_SEED_STRIDE * rank``.
RANK_SEED_STRIDE = 7919


def draw_seeds_and_size(
    g: torch.Generator, batch: int, sizes: list[int], size: int, size_g: torch.Generator | None = None
) -> tuple[list[int], int]:
    """A step's material seeds (from ``g``) and its crop size: one of ``sizes`` (drawn from ``size_g``,
    default ``g``), else ``size``. DDP ranks pass one ``size_g`` seeded alike, so a step has one crop
    size on every rank and none waits on another's larger crop."""
    seeds = torch.randint(0, gen.HELD_OUT_SEED_BASE, (batch,), generator=g).tolist()
    if sizes:
        size = sizes[int(torch.randint(0, len(sizes), (), generator=g if size_g is None else size_g))]
    return seeds, size


def agreed_progress(progress: float, device: torch.device) -> float:
    """The largest schedule progress over the DDP ranks: time budgets (``--minutes``,
    ``--cpu-minutes``) run out on each rank's own clock, and a rank that stopped alone would leave
    the others waiting in their next gradient all-reduce."""
    value = torch.tensor(progress, dtype=torch.float64, device=device)
    dist.all_reduce(value, op=dist.ReduceOp.MAX)
    return float(value)


class CaptureStream(torch.utils.data.IterableDataset):
    """Endless training batches ``(size, maps, net_input, capture)`` drawn by ``draw_batch`` on the
    CPU, for ``--workers`` DataLoader processes that keep a GPU fed (each worker its own seeded
    stream: the batches differ from a ``--workers 0`` run's, which draws them in the step loop).
    Under DDP (``world`` > 1) each rank draws its own materials, and the crop sizes from a stream
    without the rank: a DataLoader yields its workers' batches in turn, so every rank's k-th batch
    has the same size."""

    def __init__(
        self,
        seed: int,
        batch: int,
        sizes: list[int],
        size: int,
        bank,
        mix: DataMix,
        rank: int = 0,
        world: int = 1,
    ):
        super().__init__()
        self.seed, self.batch, self.sizes, self.size = seed, batch, sizes, size
        self.bank, self.mix, self.rank, self.world = bank, mix, rank, world

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        worker = info.id if info is not None else 0
        stream = self.seed * RUN_SEED_STRIDE + 104729 * (worker + 1)
        g = torch.Generator().manual_seed(stream + RANK_SEED_STRIDE * self.rank)
        size_g = torch.Generator().manual_seed(stream + SIZE_SEED_OFFSET) if self.world > 1 else None
        while True:
            seeds, size = draw_seeds_and_size(g, self.batch, self.sizes, self.size, size_g)
            yield (size, *draw_batch(seeds, size, "cpu", self.bank, self.mix))


class StepProfiler:
    """``train --profile-steps N``: runs ``torch.profiler`` over steps ``[first, first + N)`` and
    writes the operators that took the most host time and the most device time (CUDA kernels
    when there is a GPU) to ``path``: where a step's time goes, e.g. whether a GPU step waits for
    the host to launch its kernels."""

    def __init__(self, path: Path, first: int, steps: int, cuda: bool):
        self.path, self.first, self.last, self.cuda = path, first, first + steps, cuda
        self.prof: torch.profiler.profile | None = None
        self.t0 = 0.0

    def at(self, step: int) -> None:
        """Called before each step ``step``: starts or finishes the profile."""
        if step == self.first:
            acts = [torch.profiler.ProfilerActivity.CPU]
            if self.cuda:
                acts.append(torch.profiler.ProfilerActivity.CUDA)
                torch.cuda.synchronize()
            self.prof = torch.profiler.profile(activities=acts)
            self.prof.__enter__()
            self.t0 = time.time()
        elif step == self.last and self.prof is not None:
            if self.cuda:
                torch.cuda.synchronize()
            wall = time.time() - self.t0
            self.prof.__exit__(None, None, None)
            events = self.prof.key_averages()
            steps = self.last - self.first
            kernels = sum(e.count for e in events if e.device_type == torch.autograd.DeviceType.CUDA)
            lines = [
                f"{steps} steps in {wall:.3f} s ({wall / steps * 1e3:.1f} ms/step); "
                f"{kernels / steps:.0f} device kernels per step",
                "",
                "By host time:",
                events.table(sort_by="self_cpu_time_total", row_limit=25),
            ]
            if self.cuda:
                lines += ["", "By device time:", events.table(sort_by="self_cuda_time_total", row_limit=25)]
            self.path.write_text("\n".join(lines) + "\n")
            print(f"wrote {self.path}: {lines[0]}", flush=True)
            self.prof = None


def load_decoder(path: str, into: NamModel | None) -> nn.Module:
    """The map encoder ``E`` (frozen) of a pretrained decoder (``train_py.pretrain`` checkpoint), the
    target of the latent regression; its ``nd_enc`` and ``render`` are copied ``into`` a model."""
    from .pretrain import MapEncoder, load_state

    saved = load_state(path)
    for name in ("nd_enc", "render") if into is not None else ():
        part = {k[len(name) + 1 :]: v for k, v in saved.items() if k.startswith(name + ".")}
        getattr(into, name).load_state_dict(part)
    encoder = MapEncoder()
    encoder.load_state_dict({k[4:]: v for k, v in saved.items() if k.startswith("enc.")})
    encoder.requires_grad_(False)
    return encoder.eval()


def latent_l1(params: torch.Tensor, encoder: nn.Module, maps: dict[str, torch.Tensor]) -> torch.Tensor:
    """Dense L1 between the U-Net's params ``[B, 64, H, W]`` and ``E(maps)`` at every pixel."""
    with torch.no_grad():
        target = encoder(maps).permute(0, 3, 1, 2)
    return (params.float() - target).abs().mean()


class MapProbe(nn.Module):
    """A training-only head that reads the geometry a highlight depends on back from the params:
    ``[B, 64, H, W]`` → normal (3) and roughness α (1) per pixel, a 1×1-conv MLP.

    ``train --maps-weight`` adds its dense L1 against the true maps at *every* pixel, so the latent
    has to hold the normals and roughness where the rendering loss, on a sampled share of the pixels
    and in log space, sees them only through a highlight's position. Not exported: the model file
    and the runtime do not change. Not in the paper. The normal is not normalised: through a
    normalisation, a prediction pointing away from the truth gets no gradient to turn it (a run
    whose probe started pointing down stayed there), while the raw vector's L1 pulls it straight
    to the unit target; its z output starts at 1 (a flat surface).
    """

    #: Hidden width of the probe.
    HIDDEN = 32
    #: Its learning rate over the run's: a fresh probe has to catch up with a trained latent (at
    #: the fine-tunes' 3e-4 it stayed at a constant guess for hundreds of steps).
    LR_SCALE = 10.0
    #: Initial roughness output, ``softplus(b) ≈ 0.3`` (a typical α).
    ROUGHNESS_BIAS = -1.05

    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(PARAM_CHANNELS, self.HIDDEN, 1), nn.ReLU(), nn.Conv2d(self.HIDDEN, 4, 1))
        with torch.no_grad():
            self.net[2].bias.copy_(torch.tensor([0.0, 0.0, 1.0, self.ROUGHNESS_BIAS]))

    def forward(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Normals ``[B, H, W, 3]`` and roughness ``[B, H, W]`` (> 0)."""
        out = self.net(params.float())
        return out[:, :3].permute(0, 2, 3, 1), torch.nn.functional.softplus(out[:, 3])


def maps_l1(normal: torch.Tensor, rough: torch.Tensor, maps: dict[str, torch.Tensor]) -> torch.Tensor:
    """Dense L1 of a :class:`MapProbe`'s normals and roughness against the true maps (mean over
    pixels; the normal's three components and the roughness weigh the same)."""
    err = (normal - maps["normal"]).abs().sum(-1) + (rough - maps["roughness"]).abs()
    return err.mean() / 4


def lr_at(progress: float, lr: float, lr_final: float, warmup: float = 0.02) -> float:
    """Short linear warm-up, then cosine decay from ``lr`` to ``lr_final`` over progress ∈ [0, 1]."""
    if progress < warmup:
        return lr * max(progress / warmup, 0.05)
    t = min(1.0, (progress - warmup) / (1 - warmup))
    return lr_final + 0.5 * (lr - lr_final) * (1 + math.cos(math.pi * t))


def weight_average(model: NamModel, decay: float) -> AveragedModel | None:
    """``train --weight-ema``: an exponential moving average of ``model``'s weights (Polyak
    averaging; torch's ``AveragedModel``), updated after every optimizer step; ``None`` when off."""
    if not decay:
        return None
    if not 0.0 < decay < 1.0:
        raise SystemExit(f"--weight-ema {decay}: the decay must lie in (0, 1)")
    return AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)


def save_checkpoint(
    path: Path,
    model: NamModel,
    opt,
    state: dict,
    probe: nn.Module | None = None,
    averaged: AveragedModel | None = None,
) -> None:
    tmp = path.with_suffix(".tmp")
    saved = {"config": model.config.as_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(), **state}
    if probe is not None:
        saved["probe"] = probe.state_dict()
    if averaged is not None:
        saved["averaged"] = averaged.state_dict()
    torch.save(saved, tmp)
    os.replace(tmp, path)


def _share(text: str) -> float:
    """A share of the draws: a number in [0, 1]."""
    try:
        p = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0 <= p <= 1:
        raise argparse.ArgumentTypeError(f"need a share in [0, 1], got {text!r}")
    return p


def _exposure_range(text: str) -> tuple[float, float]:
    """``LO,HI`` → ``(LO, HI)`` with 0 < LO ≤ HI ≤ 1 (a photo's median radiance)."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI (two numbers), got {text!r}") from None
    if not 0 < lo <= hi <= 1:
        raise argparse.ArgumentTypeError(f"need 0 < LO <= HI <= 1, got {text!r}")
    return lo, hi


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="small", choices=sorted(CONFIGS))
    ap.add_argument(
        "--width",
        type=int,
        default=None,
        help="U-Net width C instead of the config's (e.g. 12, a file widened by train_py.widen)",
    )
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--minutes", type=float, default=None, help="wall-clock budget; the schedule follows it")
    ap.add_argument(
        "--cpu-minutes",
        type=float,
        default=None,
        help="CPU-time budget of this process (all threads; fair A/B runs on a shared machine; under DDP each "
        "rank's own, the ranks stopping together when the first runs out)",
    )
    ap.add_argument("--out", default="runs/small")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument(
        "--workers",
        type=int,
        default=0,
        help="DataLoader processes drawing the batches (0: in the step loop; a GPU run wants ~cores-2)",
    )
    ap.add_argument("--batch", type=int, default=2, help="materials (input photos) per step")
    ap.add_argument("--outputs", type=int, default=8, help="rendered exemplars per material")
    ap.add_argument("--size", type=int, default=64, help="training resolution (the U-Net is fully convolutional)")
    ap.add_argument(
        "--sizes",
        default="",
        help="comma-separated resolutions drawn per step instead of --size; exemplars per material are "
        "scaled by (size/--size)^-2 so every step costs about the same",
    )
    ap.add_argument("--pixel-frac", type=float, default=0.6, help="fraction of pixels in the data loss")
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--lr-final", type=float, default=1e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ckpt-minutes", type=float, default=3.0)
    ap.add_argument("--val-every", type=int, default=200, help="steps between validations (0: never)")
    ap.add_argument("--val-materials", type=int, default=6)
    ap.add_argument("--log-every", type=int, default=10)
    ap.add_argument(
        "--compile",
        action="store_true",
        help="run the U-Net's training forward and backward through torch.compile (one static graph per "
        "crop size, compiled on the first step at that size: minutes on a CPU; validation stays eager)",
    )
    ap.add_argument(
        "--profile-steps",
        type=int,
        default=0,
        help="profile this many steps after 5 warm-up steps (torch.profiler) and write the busiest "
        "operators, by host and by device time, to OUT/profile.txt (0: off)",
    )
    ap.add_argument("--bf16", action="store_true", help="bfloat16 autocast for the matmuls")
    ap.add_argument(
        "--weight-ema",
        type=float,
        default=0.0,
        help="also keep an exponential moving average of the weights with this decay per step (e.g. "
        "0.998: a horizon of ~500 steps), saved in the checkpoint for `export --averaged` (0: off)",
    )
    ap.add_argument(
        "--identity-frac",
        type=float,
        default=0.0,
        help="share of exemplars rendered at the capture light/view instead of Reflect (0: paper)",
    )
    ap.add_argument(
        "--moved-frac",
        type=float,
        default=0.0,
        help="share of exemplars with the view at the camera and the light moved off it "
        "(protocols.moved_light: highlights in the frame, moved; 0: paper); drawn before --identity-frac",
    )
    ap.add_argument(
        "--hemisphere-frac",
        type=float,
        default=0.0,
        help="share of exemplars with independent uniform light and view on the hemisphere of radius 4 "
        "(protocols.hemisphere, the Hemisphere protocol's distribution; 0: paper); drawn after "
        "--moved-frac, before --identity-frac",
    )
    ap.add_argument(
        "--shared-geometry",
        action="store_true",
        help="the materials of a step share exemplar light/view and a uniform pixel subset; ND_enc "
        "runs once per exemplar pixel (~3x faster steps on CPU; drops the param-norm pixel weighting)",
    )
    ap.add_argument(
        "--display-weight",
        type=float,
        default=0.0,
        help="weight of a display-space L1 term added to the log-L1 loss (0: log-L1 only, as before)",
    )
    ap.add_argument(
        "--highlight-weight",
        type=float,
        default=0.0,
        help="queries inside a highlight (specular share of the target) or where the capture clipped "
        "weigh up to 1 + this in the log and display terms (0: uniform, the paper)",
    )
    ap.add_argument(
        "--chroma-weight",
        type=float,
        default=0.0,
        help="weight of a chromaticity L1 term (colour only; 0: off)",
    )
    ap.add_argument(
        "--init-from",
        default=None,
        help="checkpoint (.pt) or model file (.safetensors, BN folded: BNs then stay frozen) whose weights "
        "start the run (fresh schedule)",
    )
    ap.add_argument(
        "--bottleneck-limit",
        type=float,
        default=0.0,
        help="penalise |e4| above this (the U-Net bottleneck before atan, where atan is already "
        "flat) so every activation keeps f16 headroom (0: off)",
    )
    ap.add_argument(
        "--activation-limit",
        type=float,
        default=0.0,
        help="penalise every U-Net activation (conv, BatchNorm, HA-Conv and block outputs) above this "
        "in magnitude, so f16 storage keeps 65504/limit headroom (0: off)",
    )
    ap.add_argument(
        "--input-skip",
        action="store_true",
        help="the U-Net head also sees the network input (a direct colour path, not in the paper); "
        "with --init-from a model without it, the new head weights start at zero",
    )
    ap.add_argument(
        "--real-frac",
        type=_share,
        default=0.0,
        help="share of materials drawn from the real CC0 sets (materials/train, augmented) instead of "
        "the procedural generator (0: procedural only)",
    )
    ap.add_argument("--materials-root", default=str(materials.DEFAULT_ROOT), help="folder holding train/")
    ap.add_argument(
        "--phone",
        action="store_true",
        help="phone-like captures: field of view 26-50 deg, flash off the lens axis, auto-exposure, "
        "noise, clipping, 8-bit sRGB, sometimes JPEG (default: the ideal 28 deg co-located capture)",
    )
    ap.add_argument(
        "--phone-frac",
        type=_share,
        default=1.0,
        help="with --phone: share of the steps with phone-like captures, the rest the ideal one (default 1)",
    )
    ap.add_argument(
        "--exposure-median",
        type=_exposure_range,
        default=capture.EXPOSURE_MEDIAN,
        metavar="LO,HI",
        help="with --phone: the auto-exposed photo's median linear radiance, log-uniform in LO..HI "
        f"(default {capture.EXPOSURE_MEDIAN[0]},{capture.EXPOSURE_MEDIAN[1]})",
    )
    ap.add_argument(
        "--decoder",
        default=None,
        help="train_py.pretrain checkpoint: its ND_enc and M_render start the run, its map encoder E "
        "is the target of --latent-weight",
    )
    ap.add_argument(
        "--latent-weight", type=float, default=0.0, help="weight of the dense L1 to E(maps) (needs --decoder)"
    )
    ap.add_argument("--freeze-decoder", action="store_true", help="ND_enc and M_render are not trained")
    ap.add_argument(
        "--maps-weight",
        type=float,
        default=0.0,
        help="weight of a dense L1 of the normals and roughness read back from the params by a "
        "training-only probe (MapProbe; not exported, not in the paper; 0: off)",
    )
    ap.add_argument(
        "--flat-normal-frac",
        type=_share,
        default=0.0,
        help="flatten each training material's normals (n = +z, before its capture) with this "
        "probability: a prior that lets the network put a moved highlight where a flat surface has "
        "it instead of hedging over normals it cannot see (not in the paper; 0: off)",
    )
    ap.add_argument(
        "--fill-clipped",
        action="store_true",
        help="render the clipped pixels of a capture from params filled from the other pixels "
        "(clip_fill, as the runtime estimates), so the pixels around a blown-out highlight learn "
        "params that also relight it (not in the paper)",
    )
    ap.add_argument(
        "--no-straight-through",
        action="store_true",
        help="true LeakyReLU(0.001) gradient at the output (dies early; for comparisons only)",
    )
    args = ap.parse_args(argv)
    if not args.phone and (args.phone_frac != 1.0 or args.exposure_median != capture.EXPOSURE_MEDIAN):
        ap.error("--phone-frac and --exposure-median shape the phone-like captures: add --phone")
    return args


def train(args) -> dict:
    if args.threads:
        torch.set_num_threads(args.threads)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    distributed = "WORLD_SIZE" in os.environ
    device = torch.device(args.device)
    if distributed:
        dist.init_process_group("nccl" if args.device == "cuda" else "gloo")
        if args.device == "cuda":
            device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
            torch.cuda.set_device(device)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / "ckpt.pt"

    torch.manual_seed(args.seed)
    config = dataclasses.replace(CONFIGS[args.config], input_skip=args.input_skip)
    if args.width:
        config = dataclasses.replace(config, width=args.width)
    model = NamModel(config).to(device)
    probe = MapProbe().to(device) if args.maps_weight else None
    groups = [{"params": list(model.parameters()), "lr_scale": 1.0}]
    if probe is not None:
        groups.append({"params": list(probe.parameters()), "lr_scale": MapProbe.LR_SCALE})
    opt = torch.optim.Adam(groups, lr=args.lr)
    #: ``frozen_bn``: BatchNorms in eval mode throughout (a run started from a folded model file).
    state = {"step": 0, "elapsed": 0.0, "cpu": 0.0, "loss": None, "history": [], "frozen_bn": False}
    if args.resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, map_location=device, weights_only=False)
        model.load_state_dict(ckpt["model"])
        if (probe is not None) != ("probe" in ckpt):
            raise SystemExit(f"--resume {ckpt_path}: --maps-weight must be given exactly when the run had it")
        if probe is not None:
            probe.load_state_dict(ckpt["probe"])
        opt.load_state_dict(ckpt["optimizer"])
        state = {**state, **{k: ckpt[k] for k in state if k in ckpt}}
        if rank == 0:
            print(f"resumed {ckpt_path} at step {state['step']} ({state['elapsed'] / 60:.1f} min)", flush=True)
    elif args.init_from and Path(args.init_from).suffix == ".safetensors":
        init = unfold_model(args.init_from)
        if dataclasses.replace(init.config, input_skip=model.config.input_skip) != model.config:
            raise SystemExit(f"--init-from {args.init_from}: {init.config} does not match --config {args.config}")
        model.load_state_dict(with_input_skip(init.state_dict(), init.config.input_skip, model.config.input_skip))
        state["frozen_bn"] = True
        if rank == 0:
            print(f"initialised from {args.init_from} (BatchNorms frozen)", flush=True)
    elif args.init_from:
        init = torch.load(args.init_from, map_location=device, weights_only=False)
        model.load_state_dict(init["model"])
        # A run that started from a model file keeps its BatchNorms frozen in every later stage.
        state["frozen_bn"] = bool(init.get("frozen_bn", False))
        if rank == 0:
            print(f"initialised from {args.init_from}", flush=True)
    averaged = weight_average(model, args.weight_ema)
    if args.resume and ckpt_path.exists():
        if (averaged is not None) != ("averaged" in ckpt):
            raise SystemExit(f"--resume {ckpt_path}: --weight-ema must be given exactly when the run had it")
        if averaged is not None:
            averaged.load_state_dict(ckpt["averaged"])
    # A resumed run's checkpoint already holds the decoder; it only needs E.
    encoder = load_decoder(args.decoder, None if state["step"] else model).to(device) if args.decoder else None
    if args.latent_weight and encoder is None:
        raise SystemExit("--latent-weight needs --decoder")
    if args.freeze_decoder:
        model.nd_enc.requires_grad_(False)
        model.render.requires_grad_(False)
    bank = materials.MaterialBank("train", Path(args.materials_root)) if args.real_frac > 0 else None
    trainer = TrainStep(
        model,
        straight_through=not args.no_straight_through,
        shared_geometry=args.shared_geometry,
        compile_unet=args.compile,
        fill_clipped=args.fill_clipped,
    )
    step_module: nn.Module = trainer
    activations = ActivationExcess(model.est, args.activation_limit) if args.activation_limit else None
    if distributed:
        step_module = nn.parallel.DistributedDataParallel(step_module)

    data_gen = torch.Generator().manual_seed(args.seed * RUN_SEED_STRIDE + RANK_SEED_STRIDE * rank + state["step"])
    size_gen = None
    if distributed:
        size_gen = torch.Generator().manual_seed(args.seed * RUN_SEED_STRIDE + SIZE_SEED_OFFSET + state["step"])
    log = open(out / "train.log", "a") if rank == 0 else None  # noqa: SIM115 (kept open for the run)

    def emit(line: str) -> None:
        if rank == 0:
            print(line, flush=True)
            log.write(line + "\n")
            log.flush()

    emit(f"# {json.dumps(vars(args))} world={world}")
    sizes = [int(v) for v in args.sizes.split(",") if v.strip()]
    mix = DataMix.from_args(args)
    batches = None
    if args.workers:
        stream = CaptureStream(args.seed + 7919 * state["step"], args.batch, sizes, args.size, bank, mix, rank, world)
        loader = torch.utils.data.DataLoader(
            stream, batch_size=None, num_workers=args.workers, pin_memory=device.type == "cuda", prefetch_factor=4
        )
        batches = iter(loader)
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True
    start = time.time() - state["elapsed"]
    cpu_start = time.process_time() - state["cpu"]
    last_ckpt = time.time()
    #: Running mean of the loss, kept on the device: reading it back every step would make the
    #: host wait for the GPU instead of queueing the next step (read at log and checkpoint steps).
    ema = None if state["loss"] is None else torch.tensor(state["loss"], device=device)
    step = state["step"]
    #: Wall-clock time, step and time spent waiting for batches since the last log line (its
    #: s/step is the mean over those steps; only the log line reads the loss back from the GPU).
    log_t, log_step, data_s = time.time(), step, 0.0
    profiler = (
        StepProfiler(out / "profile.txt", step + 5, args.profile_steps, device.type == "cuda")
        if args.profile_steps
        else None
    )
    while True:
        if profiler is not None:
            profiler.at(step)
        elapsed = time.time() - start
        progress = step / args.steps
        if args.minutes:
            progress = max(progress, elapsed / (60 * args.minutes))
        if args.cpu_minutes:
            progress = max(progress, (time.process_time() - cpu_start) / (60 * args.cpu_minutes))
        if distributed:
            progress = agreed_progress(progress, device)
        if progress >= 1.0:
            break
        lr = lr_at(progress, args.lr, args.lr_final)
        for group in opt.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        t0 = time.time()
        if batches is not None:
            size, maps, net_input, cap = next(batches)
            maps = {k: v.to(device, non_blocking=True) for k, v in maps.items()}
            net_input = net_input.to(device, non_blocking=True)
        else:
            seeds, size = draw_seeds_and_size(data_gen, args.batch, sizes, args.size, size_gen)
            maps, net_input, cap = draw_batch(seeds, size, device, bank, mix)
        data_s += time.time() - t0
        outputs = max(1, round(args.outputs * (args.size / size) ** 2)) if sizes else args.outputs
        light, view = protocols.reflect(data_gen, 1 if args.shared_geometry else args.batch, outputs)
        light, view = protocols.mix_moved_light(data_gen, light, view, args.moved_frac, cap.camera())
        light, view = protocols.mix_hemisphere(data_gen, light, view, args.hemisphere_frac)
        light, view = protocols.mix_identity(data_gen, light, view, args.identity_frac, (cap.flash(), cap.camera()))
        model.train()
        if state["frozen_bn"]:
            freeze_batchnorm(model)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.bf16):
            pred, target = step_module(
                net_input,
                outputs,
                args.pixel_frac,
                data_gen,
                maps,
                light.to(device, non_blocking=True),
                view.to(device, non_blocking=True),
            )
        weights = None
        if args.highlight_weight:
            clipped = capture_clipped(net_input, trainer.last_idx)
            weights = highlight_weights(trainer.last_share, clipped, args.highlight_weight)
        loss = weighted_mean((pred.float() - target).abs(), weights)
        if args.display_weight:
            loss = loss + args.display_weight * display_l1(pred.float(), target, weights)
        if args.chroma_weight:
            loss = loss + args.chroma_weight * chroma_l1(pred.float(), target)
        if args.latent_weight:
            loss = loss + args.latent_weight * latent_l1(trainer.last_params, encoder, maps)
        maps_err = None
        if probe is not None:
            maps_err = maps_l1(*probe(trainer.last_params), maps)
            loss = loss + args.maps_weight * maps_err
        if args.bottleneck_limit:
            loss = loss + bottleneck_excess(model.est.last_bottleneck, args.bottleneck_limit)
        if activations is not None and (excess := activations.take()) is not None:
            loss = loss + excess
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if averaged is not None:
            averaged.update_parameters(model)
        step += 1
        ema = loss.detach() if ema is None else 0.98 * ema + 0.02 * loss.detach()
        if step % args.log_every == 0 or step == 1:
            emit(
                f"step {step:6d}  loss {float(loss.detach()):.4f}  ema {float(ema):.4f}  lr {lr:.2e}  "
                f"{(time.time() - log_t) / (step - log_step):.2f} s/step (data {data_s / (step - log_step):.2f})  "
                f"{elapsed / 60:.1f} min" + (f"  maps {float(maps_err.detach()):.4f}" if maps_err is not None else "")
            )
            log_t, log_step, data_s = time.time(), step, 0.0
        state.update(step=step, elapsed=time.time() - start, cpu=time.process_time() - cpu_start)
        if args.val_every and step % args.val_every == 0 and rank == 0:
            res = validate(model, args)
            state["history"].append({"step": step, **res})
            emit(f"val   {step:6d}  " + "  ".join(f"{k} {v:.4f}" for k, v in res.items()))
        if rank == 0 and time.time() - last_ckpt > 60 * args.ckpt_minutes:
            state["loss"] = float(ema)
            save_checkpoint(ckpt_path, model, opt, state, probe, averaged)
            last_ckpt = time.time()
    if rank == 0:
        state["minutes"] = state["elapsed"] / 60
        state["loss"] = None if ema is None else float(ema)
        save_checkpoint(ckpt_path, model, opt, state, probe, averaged)
        emit(
            f"done: {step} steps, {state['elapsed'] / 60:.1f} min ({state['cpu'] / 60:.1f} CPU-min), "
            f"ema loss {state['loss']:.4f}; wrote {ckpt_path}"
        )
        log.close()
    if distributed:
        dist.destroy_process_group()
    return state


def validate(model: NamModel, args) -> dict[str, float]:
    """Mean log-L1 on held-out procedural materials under the three protocols (small, fast)."""
    model.eval()
    seeds = [gen.HELD_OUT_SEED_BASE + 1000 + i for i in range(args.val_materials)]
    res = evaluate_protocols(model, seeds, args.size, hemisphere_k=8, reflect_k=4, device=args.device)
    return {f"{p}_logl1": v["model"]["log_l1"] for p, v in res.items()}


def main(argv=None) -> None:
    train(parse_args(argv))


if __name__ == "__main__":
    main()
