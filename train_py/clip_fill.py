"""Latent params where the photo clipped, filled in from the pixels around them (push-pull).

A pixel the photo clipped (a channel at or above ``ggx.LDR_MAX``, pure white to an LDR model; in an
8-bit capture a channel at 255, ``ggx.clipped``) tells the network only that the radiance there was
at least 1: the U-Net's params there are a guess, and the shipped model's
guess keeps the flash highlight baked in (relit too bright under a moved light) or turns it into a
dark patch. The runtime therefore replaces the params of clipped pixels by those of the unclipped
pixels around them, the material the photo did show; unclipped pixels keep theirs exactly.

The interpolation is push-pull (Gortler et al. 1996, "The Lumigraph", §3.4), O(pixels):

* **push**: halve the image (2×2 blocks, a last odd row or column alone) until every pixel of a
  level holds a kept pixel below it; a coarse pixel is the mean of its kept children and is kept
  when it has one;
* **pull**: from the coarsest level down, a pixel that is not kept takes the bilinear upsample
  of the filled level above (child ``i`` sits at ``(i + 0.5) / 2 − 0.5`` parent pixels, clamped
  to the edge).

An image with no kept pixel is left as it is (there is nothing to fill from). The Rust runtime
(``nam_model::fill_clipped``) computes the same; ``golden.py`` stores both ends for its parity test.
Not in the paper: measured by ``train_py.highlights`` (clipped regions within 0.5–2× of the truth
in 53% of cases without it, 89% with it, for the model of 2026-12-06).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def fill_clipped(params: torch.Tensor, clipped: torch.Tensor) -> torch.Tensor:
    """Params ``[B, C, H, W]`` with the pixels where ``clipped`` ``[B, H, W]`` (bool) is true
    filled from the others (module doc); images with every pixel clipped are returned as they are."""
    keep = (~clipped).to(params.dtype)[:, None]
    keep = torch.where(keep.flatten(1).any(1).view(-1, 1, 1, 1), keep, torch.ones_like(keep))
    return _push_pull(params, keep)


def _push_pull(values: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """``values`` ``[B, C, H, W]`` filled where ``keep`` ``[B, 1, H, W]`` (0 or 1) is 0."""
    height, width = values.shape[2:]
    if bool((keep > 0).all()) or (height == 1 and width == 1):
        return values
    pad = (0, width % 2, 0, height % 2)
    total = F.avg_pool2d(F.pad(values * keep, pad), 2, divisor_override=1)
    count = F.avg_pool2d(F.pad(keep, pad), 2, divisor_override=1)
    coarse_keep = (count > 0).to(values.dtype)
    coarse = torch.where(count > 0, total / count.clamp(min=1), torch.zeros_like(total))
    filled = _upsample(_push_pull(coarse, coarse_keep), height, width)
    return torch.where(keep > 0, values, filled)


def _upsample(values: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Bilinear 2× upsample of ``[B, C, h, w]`` to ``[B, C, height, width]`` (child ``i`` at parent
    coordinate ``(i + 0.5) / 2 − 0.5``, clamped to ``[0, h − 1]``)."""

    def taps(n: int, parent: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = ((torch.arange(n, dtype=values.dtype, device=values.device) + 0.5) / 2 - 0.5).clamp(0, parent - 1)
        lo = x.floor().long()
        return lo, (lo + 1).clamp(max=parent - 1), x - lo

    r0, r1, fr = taps(height, values.shape[2])
    c0, c1, fc = taps(width, values.shape[3])
    rows = values[:, :, r0] * (1 - fr)[:, None] + values[:, :, r1] * fr[:, None]
    return rows[:, :, :, c0] * (1 - fc) + rows[:, :, :, c1] * fc
