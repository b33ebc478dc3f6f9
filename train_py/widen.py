"""Widen a model file's U-Net (``M_est``) to a larger width ``C`` without changing what it computes.

``python -m train_py.widen models/default.safetensors --width 12 -o runs/w12/init.safetensors``

A function-preserving widening (Net2Net, Chen et al. 2016) of the folded network: every new
channel copies an old one (``channel_map``), and wherever a layer reads copies of one channel its
weight on that channel is split among them with random shares that sum to 1, so the sum is
unchanged while the copies get different gradients and grow apart when training continues. All
per-channel operations of the U-Net (InstanceNorm, the HA gate, LeakyReLU/ReLU, folded
BatchNorm, ``atan``) act on a copy as on its original. ``ND_enc`` and ``M_render`` are copied
unchanged. The widened file is then fine-tuned with ``train --width C --init-from <it>``; it
computes the same params as the original up to float rounding (checked on a random input and
printed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from .export import load_model, save_model
from .model import IN_CHANNELS, ConvBN, HAConv, ModelConfig, NamModel, ReverseBlock, UNet

#: A widened model's params may differ from the original's by float rounding only.
WIDEN_TOL = 1e-4


def repeat_map(new: int, old: int) -> torch.Tensor:
    """New channel ``j`` → old channel ``j mod old`` (``new ≥ old``)."""
    if new < old:
        raise ValueError(f"cannot narrow {old} channels to {new}")
    return torch.arange(new) % old


def channel_map(new: int, old: int) -> torch.Tensor:
    """The map of an HA-Conv-shaped tensor: its first half (``inc1b``) and second half (``inc2``)
    are widened separately, so copies stay within their half and the concatenation still holds."""
    if new % 2 or old % 2:
        raise ValueError("HA-Conv widths must be even")
    half = repeat_map(new // 2, old // 2)
    return torch.cat([half, half + old // 2])


def concat_maps(*maps: tuple[torch.Tensor, int]) -> torch.Tensor:
    """The map of ``torch.cat`` of tensors given as ``(map, old channel count)``."""
    parts, offset = [], 0
    for g, old in maps:
        parts.append(g + offset)
        offset += old
    return torch.cat(parts)


class Widener:
    """Copies weights from a width-``old`` U-Net into a width-``new`` one, layer by layer."""

    def __init__(self, src: UNet, dst: UNet, old: int, new: int, generator: torch.Generator):
        self.src, self.dst, self.old, self.new, self.gen = src, dst, old, new, generator

    def stage(self, mult: int) -> tuple[torch.Tensor, int]:
        """``(map, old channels)`` of a tensor ``mult · C`` channels wide."""
        return channel_map(mult * self.new, mult * self.old), mult * self.old

    def shares(self, rows: int, g_in: torch.Tensor) -> torch.Tensor:
        """``[rows, len(g_in)]`` random shares in which each row's copies of an input channel split
        its weight: positive, summing to 1 over the copies (1 for an uncopied channel)."""
        u = torch.rand(rows, len(g_in), generator=self.gen, dtype=torch.float64) + 0.5
        total = torch.zeros(rows, int(g_in.max()) + 1, dtype=torch.float64).index_add_(1, g_in, u)
        return (u / total[:, g_in]).float()

    def weight(self, w: torch.Tensor, g_out: torch.Tensor, g_in: torch.Tensor, transposed: bool) -> torch.Tensor:
        """A conv weight ``[out, in, k, k]`` (transposed: ``[in, out, k, k]``) remapped and split."""
        if transposed:
            return self.weight(w.transpose(0, 1), g_out, g_in, False).transpose(0, 1).contiguous()
        picked = w[g_out][:, g_in]
        return picked * self.shares(len(g_out), g_in)[:, :, None, None]

    def conv(self, dst, src, g_out: torch.Tensor, g_in: torch.Tensor) -> None:
        transposed = isinstance(src, ConvBN) and src.kind != "conv"
        dst.weight.data.copy_(self.weight(src.weight.data, g_out, g_in, transposed))
        if getattr(src, "bias", None) is not None:
            dst.bias.data.copy_(src.bias.data[g_out])

    def affine(self, dst, src, g: torch.Tensor) -> None:
        dst.scale.data.copy_(src.scale.data[g])
        dst.shift.data.copy_(src.shift.data[g])

    def ha(self, dst: HAConv, src: HAConv, g_in: torch.Tensor, mult: int) -> None:
        g_out, _ = self.stage(mult)
        half_new = len(g_out) // 2
        self.conv(dst.gate, src.gate, g_out, g_in)
        self.conv(dst.feat, src.feat, g_out, g_in)
        self.conv(dst.inc1a, src.inc1a, g_out, g_in)
        self.conv(dst.inc1b, src.inc1b, g_out[:half_new], g_out)
        self.conv(dst.inc2, src.inc2, g_out[half_new:] - mult * self.old // 2, g_in)

    def basic(self, dst, src, g_in: torch.Tensor, mult: int) -> None:
        g_out, _ = self.stage(mult)
        self.ha(dst.ha1, src.ha1, g_in, mult)
        self.affine(dst.bn1, src.bn1, g_out)
        self.ha(dst.ha2, src.ha2, g_out, mult)
        self.affine(dst.bn2, src.bn2, g_out)
        if src.down is not None:
            self.conv(dst.down, src.down, g_out, g_in)

    def reverse(self, dst: ReverseBlock, src: ReverseBlock, g_in: torch.Tensor, mult: int) -> None:
        g_out, _ = self.stage(mult)
        self.conv(dst.up4, src.up4, g_out, g_in)
        self.conv(dst.conv, src.conv, g_out, g_out)
        self.conv(dst.up2, src.up2, g_out, g_in)

    def run(self) -> None:
        s, d = self.src, self.dst
        photo = (torch.arange(IN_CHANNELS), IN_CHANNELS)
        self.conv(d.stem, s.stem, self.stage(1)[0], photo[0])
        enc = []
        g = self.stage(1)
        for k, mult in enumerate((1, 2, 4, 8), start=1):
            first, second = getattr(d, f"enc{k}"), getattr(s, f"enc{k}")
            self.basic(first[0], second[0], g[0], mult)
            g = self.stage(mult)
            self.basic(first[1], second[1], g[0], mult)
            enc.append(g)
        # dec1 reads atan(e4); dec2..dec4 read cat([previous, skip]).
        inputs = {"dec1": g, "dec2": (8, enc[2]), "dec3": (4, enc[1]), "dec4": (2, enc[0])}
        outs = {"dec1": 8, "dec2": 4, "dec3": 2, "dec4": 1}
        prev = g
        for name, mult in outs.items():
            g_in = prev[0] if name == "dec1" else concat_maps(prev, inputs[name][1])
            first, second = getattr(d, name), getattr(s, name)
            if name == "dec4":
                self.basic(first[0], second[0], g_in, mult)
            else:
                self.reverse(first[0], second[0], g_in, mult)
            prev = self.stage(mult)
            self.basic(first[1], second[1], prev[0], mult)
        head_in = concat_maps(prev, photo) if s.input_skip else prev[0]
        self.conv(d.head, s.head, torch.arange(d.head.weight.shape[0]), head_in)


def widen(model: NamModel, width: int, seed: int = 0) -> NamModel:
    """A folded model of width ``width`` computing what the folded ``model`` does."""
    if not model.folded:
        raise ValueError("widen works on a folded model (a model file)")
    config = ModelConfig(width=width, log_mode=model.config.log_mode, input_skip=model.config.input_skip)
    wide = NamModel(config, folded=True)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        Widener(model.est, wide.est, model.config.width, width, gen).run()
        wide.nd_enc.load_state_dict(model.nd_enc.state_dict())
        wide.render.load_state_dict(model.render.state_dict())
    return wide.eval()


def params_difference(a: NamModel, b: NamModel, size: int = 64, seed: int = 1) -> float:
    """Largest |Δ| between the params of ``a`` and ``b`` on a random input, relative to the largest
    |param|."""
    x = torch.randn(1, IN_CHANNELS, size, size, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        pa, pb = a.estimate(x), b.estimate(x)
    return float((pa - pb).abs().max() / pa.abs().max())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", help="a model file (safetensors)")
    ap.add_argument("--width", type=int, required=True, help="the new U-Net width C (even, ≥ the old)")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--seed", type=int, default=0, help="seed of the random weight shares")
    args = ap.parse_args(argv)
    model = load_model(args.model)
    wide = widen(model, args.width, args.seed)
    diff = params_difference(model, wide)
    if diff > WIDEN_TOL:
        raise SystemExit(f"widening changed the params by {diff:.2e} (> {WIDEN_TOL:g}): a bug")
    save_model(dict(wide.state_dict()), wide.config, args.output, "f32")
    size = Path(args.output).stat().st_size
    print(
        f"wrote {args.output} ({size / 1e6:.2f} MB, f32, width {model.config.width} → {args.width}; "
        f"params differ by {diff:.1e} of their range)"
    )


if __name__ == "__main__":
    main()
