"""The networks of DESIGN.md §4: ``M_est`` (HA U-Net), ``ND_enc`` and the per-pixel ``M_render``.

One set of classes serves training and inference. With ``folded=False`` every BatchNorm is a
real ``nn.BatchNorm2d`` (training); with ``folded=True`` the BatchNorms are replaced by what
export writes (docs/FORMAT.md): an affine ``scale``/``shift`` after HA convolutions and a bias
on plain convolutions. Module names are chosen so that the folded ``state_dict`` *is* the
tensor list of FORMAT.md (``est.stem.weight``, ``est.enc1.0.ha1.gate.weight``, ...).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from . import ggx
from .clip_fill import fill_clipped
from .ggx import normalize

NORM_EPS = 1e-5
HA_SLOPE = 0.1
ND_SLOPE = 0.01
RENDER_HIDDEN_SLOPE = 0.01
RENDER_OUT_SLOPE = 0.001
PE_OCTAVES = 16
PARAM_CHANNELS = 64
#: Network input channels: log RGB + the capture half vector's z.
IN_CHANNELS = 4
ND_DIMS = (297, 594, 594, 32)
RENDER_DIMS = (96, 128, 128, 128, 128, 128, 64, 3)
#: The U-Net downsamples three times: inputs are padded to a multiple of this.
SIZE_MULTIPLE = 8


@dataclass
class ModelConfig:
    """Architecture switches recorded in the safetensors ``config`` metadata."""

    width: int = 8
    log_mode: str = "ldr"
    #: The head sees ``[decoder output, network input]`` (C + 4 channels) instead of the decoder
    #: output alone: a direct path for the photo's per-pixel colour (not in the paper, see
    #: ``UNet``). Absent from older files' config = ``False``.
    input_skip: bool = False

    def to_json_dict(self, dtype: str, bn_folded: bool = True) -> dict:
        return {
            "format": "nam-model",
            "version": 1,
            "width": self.width,
            "in_channels": IN_CHANNELS,
            "input_skip": self.input_skip,
            "param_channels": PARAM_CHANNELS,
            "log_mode": self.log_mode,
            "pe_octaves": PE_OCTAVES,
            "nd_enc": list(ND_DIMS),
            "render": list(RENDER_DIMS),
            "slopes": {
                "ha": HA_SLOPE,
                "nd_enc": ND_SLOPE,
                "render_hidden": RENDER_HIDDEN_SLOPE,
                "render_out": RENDER_OUT_SLOPE,
            },
            "norm_eps": NORM_EPS,
            "bn_folded": bn_folded,
            "dtype": dtype,
        }

    @staticmethod
    def from_json_dict(cfg: dict) -> ModelConfig:
        if cfg.get("format") != "nam-model" or cfg.get("version") != 1:
            raise ValueError(f"not a nam-model v1 config: {cfg.get('format')!r} v{cfg.get('version')!r}")
        if tuple(cfg["nd_enc"]) != ND_DIMS or tuple(cfg["render"]) != RENDER_DIMS:
            raise ValueError("unsupported nd_enc/render dimensions")
        return ModelConfig(
            width=int(cfg["width"]), log_mode=str(cfg["log_mode"]), input_skip=bool(cfg.get("input_skip", False))
        )

    def as_dict(self) -> dict:
        return asdict(self)


#: Named configurations for ``train.py --config``.
CONFIGS = {
    "tiny": ModelConfig(width=4),
    "small": ModelConfig(width=8),
    "medium": ModelConfig(width=16),
    "large": ModelConfig(width=32),
    "paper": ModelConfig(width=64),
}


def replicate_pad(x: torch.Tensor, pad: tuple[int, int, int, int]) -> torch.Tensor:
    """``F.pad(x, pad, mode="replicate")`` for ``[B, C, H, W]`` (pad = left, right, top, bottom).

    Under ``torch.compile`` the edges are concatenated instead: Inductor's
    ``replication_pad2d_backward`` asserts contiguous strides and fails on the channels-last
    gradients the convolutions return (torch 2.15, CPU). The values are the same either way."""
    if not torch.compiler.is_compiling():
        return F.pad(x, pad, mode="replicate")
    return replicate_pad_by_cat(x, pad)


def replicate_pad_by_cat(x: torch.Tensor, pad: tuple[int, int, int, int]) -> torch.Tensor:
    """:func:`replicate_pad` as concatenated, expanded edge columns and rows (what it runs compiled)."""
    left, right, top, bottom = pad
    x = torch.cat([x[..., :1].expand(*x.shape[:-1], left), x, x[..., -1:].expand(*x.shape[:-1], right)], dim=-1)
    rows = x.shape[:-2]
    width = x.shape[-1]
    top_rows = x[..., :1, :].expand(*rows, top, width)
    bottom_rows = x[..., -1:, :].expand(*rows, bottom, width)
    return torch.cat([top_rows, x, bottom_rows], dim=-2)


def conv3x3(x: torch.Tensor, weight: torch.Tensor, stride: int, bias: torch.Tensor | None = None) -> torch.Tensor:
    """3×3 convolution with replicate padding 1."""
    return F.conv2d(replicate_pad(x, (1, 1, 1, 1)), weight, bias, stride=stride)


def instance_norm(x: torch.Tensor) -> torch.Tensor:
    """Non-affine InstanceNorm (biased variance, eps 1e-5); unlike ``F.instance_norm`` it accepts 1×1
    maps (→ 0), which the deepest stage sees for 8×8 inputs."""
    mean = x.mean(dim=(-2, -1), keepdim=True)
    var = (x - mean).square().mean(dim=(-2, -1), keepdim=True)
    return (x - mean) * torch.rsqrt(var + NORM_EPS)


class Conv(nn.Module):
    """A bias-free conv (k×k, replicate pad k//2) with its weight as ``weight``."""

    def __init__(self, cin: int, cout: int, k: int, stride: int = 1):
        super().__init__()
        self.stride = stride
        self.pad = k // 2
        self.weight = nn.Parameter(torch.empty(cout, cin, k, k))
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.pad:
            x = replicate_pad(x, (self.pad,) * 4)
        return F.conv2d(x, self.weight, stride=self.stride)


class ConvBN(nn.Module):
    """Conv (or transposed conv) followed by BatchNorm; folded form = conv with ``bias``.

    Unfolded state: ``weight``, ``bn.*``. Folded state: ``weight``, ``bias``.
    ``kind``: ``"conv"`` (replicate pad k//2), ``"convT4"`` (k4 s2 p1) or ``"convT2"`` (k2 s2).
    """

    def __init__(self, cin: int, cout: int, k: int, stride: int, kind: str, folded: bool):
        super().__init__()
        self.kind = kind
        self.stride = stride
        self.k = k
        shape = (cout, cin, k, k) if kind == "conv" else (cin, cout, k, k)
        self.weight = nn.Parameter(torch.empty(shape))
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))
        if folded:
            self.bias = nn.Parameter(torch.zeros(cout))
            self.bn = None
        else:
            self.register_parameter("bias", None)
            self.bn = nn.BatchNorm2d(cout, eps=NORM_EPS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.kind == "conv":
            p = self.k // 2
            if p:
                x = replicate_pad(x, (p,) * 4)
            y = F.conv2d(x, self.weight, self.bias, stride=self.stride)
        elif self.kind == "convT4":
            y = F.conv_transpose2d(x, self.weight, self.bias, stride=2, padding=1)
        elif self.kind == "convT2":
            y = F.conv_transpose2d(x, self.weight, self.bias, stride=2)
        else:
            raise ValueError(self.kind)
        return y if self.bn is None else self.bn(y)


class Affine(nn.Module):
    """Folded BatchNorm after an HA convolution: ``y = x·scale + shift`` per channel."""

    def __init__(self, channels: int):
        super().__init__()
        self.scale = nn.Parameter(torch.ones(channels))
        self.shift = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale[None, :, None, None] + self.shift[None, :, None, None]


def make_bn(channels: int, folded: bool) -> nn.Module:
    return Affine(channels) if folded else nn.BatchNorm2d(channels, eps=NORM_EPS)


class HAConv(nn.Module):
    """Highlight-aware conv: ``sigmoid(gate(x)) * leaky(feat(IN(x))) + cat(inc1b(inc1a(x)), inc2(x))``."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.stride = stride
        self.gate = Conv(cin, cout, 3, stride)
        self.feat = Conv(cin, cout, 3, stride)
        self.inc1a = Conv(cin, cout, 3, 1)
        self.inc1b = Conv(cout, cout // 2, 3, stride)
        self.inc2 = Conv(cin, cout // 2, 3, stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a = torch.sigmoid(self.gate(x))
        b = F.leaky_relu(self.feat(instance_norm(x)), HA_SLOPE)
        c = torch.cat([self.inc1b(self.inc1a(x)), self.inc2(x)], dim=1)
        return a * b + c


class BasicBlock(nn.Module):
    """``y = relu(bn1(ha1(x))); y = bn2(ha2(y)); relu(y + id)``, id = ``down(x)`` on shape change."""

    def __init__(self, cin: int, cout: int, stride: int, folded: bool):
        super().__init__()
        self.ha1 = HAConv(cin, cout, stride)
        self.bn1 = make_bn(cout, folded)
        self.ha2 = HAConv(cout, cout, 1)
        self.bn2 = make_bn(cout, folded)
        if cin != cout or stride != 1:
            self.down = ConvBN(cin, cout, 1, stride, "conv", folded)
        else:
            self.down = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.ha1(x)))
        y = self.bn2(self.ha2(y))
        identity = x if self.down is None else self.down(x)
        return F.relu(y + identity)


class ReverseBlock(nn.Module):
    """``y = relu(up4(x)); y = conv(y); relu(y + up2(x))`` — plain convs with BN, ×2 upsampling."""

    def __init__(self, cin: int, cout: int, folded: bool):
        super().__init__()
        self.up4 = ConvBN(cin, cout, 4, 2, "convT4", folded)
        self.conv = ConvBN(cout, cout, 3, 1, "conv", folded)
        self.up2 = ConvBN(cin, cout, 2, 2, "convT2", folded)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.up4(x))
        y = self.conv(y)
        return F.relu(y + self.up2(x))


class UNet(nn.Module):
    """``M_est``: input ``[B, 4, H, W]`` (any H, W) → params ``[B, 64, H, W]``."""

    def __init__(self, width: int, folded: bool, input_skip: bool = False):
        super().__init__()
        c = width
        self.input_skip = input_skip
        self.stem = Conv(IN_CHANNELS, c, 7)
        widths = [c, 2 * c, 4 * c, 8 * c]
        cin = c
        for k, (w, s) in enumerate(zip(widths, [1, 2, 2, 2], strict=True), start=1):
            setattr(self, f"enc{k}", nn.Sequential(BasicBlock(cin, w, s, folded), BasicBlock(w, w, 1, folded)))
            cin = w
        self.dec1 = nn.Sequential(ReverseBlock(8 * c, 8 * c, folded), BasicBlock(8 * c, 8 * c, 1, folded))
        self.dec2 = nn.Sequential(ReverseBlock(12 * c, 4 * c, folded), BasicBlock(4 * c, 4 * c, 1, folded))
        self.dec3 = nn.Sequential(ReverseBlock(6 * c, 2 * c, folded), BasicBlock(2 * c, 2 * c, 1, folded))
        self.dec4 = nn.Sequential(BasicBlock(3 * c, c, 1, folded), BasicBlock(c, c, 1, folded))
        self.head = Conv(c + (IN_CHANNELS if input_skip else 0), PARAM_CHANNELS, 7)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        height, width = x.shape[-2:]
        pad_h = (-height) % SIZE_MULTIPLE
        pad_w = (-width) % SIZE_MULTIPLE
        if pad_h or pad_w:
            x = replicate_pad(x, (0, pad_w, 0, pad_h))
        photo = x
        x = self.stem(x)
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        #: The bottleneck before ``atan``, kept while training for ``train --bottleneck-limit``.
        self.last_bottleneck = e4 if self.training else None
        x = torch.atan(e4)
        x = self.dec1(x)
        x = self.dec2(torch.cat([x, e3], dim=1))
        x = self.dec3(torch.cat([x, e2], dim=1))
        x = self.dec4(torch.cat([x, e1], dim=1))
        x = self.head(self.head_input(x, photo))
        return x[..., :height, :width]

    def head_input(self, decoded: torch.Tensor, photo: torch.Tensor) -> torch.Tensor:
        """What the head convolves: the decoder output, then the (padded) input with the skip."""
        return torch.cat([decoded, photo], dim=1) if self.input_skip else decoded


def positional_encoding(dirs: torch.Tensor, octaves: int = PE_OCTAVES) -> torch.Tensor:
    """``[N, 9]`` directions → ``[N, 9 + 18·octaves]`` (FORMAT.md order, exact range reduction).

    ``sin(2^k π c)`` is evaluated as ``sin(2π t)`` with ``t = frac(2^(k-1) c)`` folded to
    [-1/2, 1/2): scaling by a power of two and taking the fraction are exact in binary floating
    point, so even ``2^15 π c`` keeps full accuracy.
    """
    scales = torch.pow(2.0, torch.arange(octaves, dtype=dirs.dtype, device=dirs.device) - 1.0)
    scaled = dirs.unsqueeze(-2) * scales[:, None]  # [N, octaves, 9]
    t = scaled - torch.floor(scaled)
    t = torch.where(t >= 0.5, t - 1.0, t)
    angle = (2.0 * math.pi) * t
    sc = torch.stack([torch.sin(angle), torch.cos(angle)], dim=-1)  # [N, octaves, 9, 2]
    return torch.cat([dirs, sc.reshape(*dirs.shape[:-1], octaves * 18)], dim=-1)


class NDEnc(nn.Module):
    """ND_enc: 297 → 594 → leaky → 594 → leaky → 32 (no bias)."""

    def __init__(self):
        super().__init__()
        self.l0 = nn.Linear(ND_DIMS[0], ND_DIMS[1], bias=False)
        self.l1 = nn.Linear(ND_DIMS[1], ND_DIMS[2], bias=False)
        self.l2 = nn.Linear(ND_DIMS[2], ND_DIMS[3], bias=False)
        init_linear(self.l0, self.l1, self.l2)

    def forward(self, encoded: torch.Tensor) -> torch.Tensor:
        x = F.leaky_relu(self.l0(encoded), ND_SLOPE)
        x = F.leaky_relu(self.l1(x), ND_SLOPE)
        return self.l2(x)


class _LeakyStraightThrough(torch.autograd.Function):
    """``leaky_relu(z, slope)`` forward, identity backward (training only, see ``RenderMLP``)."""

    @staticmethod
    def forward(ctx, z: torch.Tensor, slope: float) -> torch.Tensor:
        return F.leaky_relu(z, slope)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        return grad, None


class RenderMLP(nn.Module):
    """Render MLP on ``cat([params(64), nd(32)])`` → log radiance (3); l0 has no activation.

    ``straight_through=True`` (training) keeps the forward value but passes the gradient of the
    final LeakyReLU(0.001) through unscaled. With the true 0.001 slope a negative output gets a
    1000× smaller gradient, and since most Reflect exemplar pixels are dark (target ≈ 0) every
    output goes negative within a few steps and then barely trains ("dead" output: the model
    predicts ≈ 0 / a direction-only average and ignores the params). For targets ≥ 0 (log radiance
    always is) the straight-through gradient is exactly the gradient of ``|z - t|``, an upper bound
    of the true loss ``|leaky(z) - t|``; inference is unchanged.
    """

    def __init__(self):
        super().__init__()
        dims = RENDER_DIMS
        for i in range(len(dims) - 1):
            setattr(self, f"l{i}", nn.Linear(dims[i], dims[i + 1], bias=False))
        init_linear(*(getattr(self, f"l{i}") for i in range(len(dims) - 1)))

    def forward(self, x: torch.Tensor, straight_through: bool = False) -> torch.Tensor:
        x = self.l0(x)
        for i in range(1, 6):
            x = F.leaky_relu(getattr(self, f"l{i}")(x), RENDER_HIDDEN_SLOPE)
        z = self.l6(x)
        if straight_through:
            return _LeakyStraightThrough.apply(z, RENDER_OUT_SLOPE)
        return F.leaky_relu(z, RENDER_OUT_SLOPE)


def init_linear(*layers: nn.Linear) -> None:
    """He initialisation for LeakyReLU MLPs: PyTorch's default shrinks each of the 7 layers by √3."""
    for layer in layers:
        nn.init.kaiming_uniform_(layer.weight, a=ND_SLOPE, nonlinearity="leaky_relu")


def query_dirs(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """``[..., 9]`` = ``[wi, wo, normalize(wi + wo)]`` for unit ``wi``, ``wo`` ``[..., 3]``."""
    # Same normalisation as ggx.directions: octave 15 of the encoding turns a 1-ulp difference in
    # wh into ~1e-3 in the output, so every path must compute wh identically.
    return torch.cat([wi, wo, normalize(wi + wo)], dim=-1)


class NamModel(nn.Module):
    """Both stages: ``est`` (U-Net), ``nd_enc`` and ``render`` (per-pixel MLP)."""

    def __init__(self, config: ModelConfig, folded: bool = False):
        super().__init__()
        self.config = config
        self.folded = folded
        self.est = UNet(config.width, folded, config.input_skip)
        self.nd_enc = NDEnc()
        self.render = RenderMLP()

    def estimate(self, net_input: torch.Tensor) -> torch.Tensor:
        """``[B, 4, H, W]`` network input → params ``[B, 64, H, W]``."""
        return self.est(net_input)

    def estimate_photo(
        self, photo: torch.Tensor, distance: float = ggx.CAPTURE_DISTANCE, fill: bool = True
    ) -> torch.Tensor:
        """Params ``[B, 64, H, W]`` of linear photos ``[B, H, W, 3]`` taken from ``(0, 0, distance)``,
        as the runtime estimates them: network input, U-Net, then (``fill``, LDR models: their input
        saturates where the photo clipped) the clipped pixels' params filled from the pixels around
        them (``clip_fill``)."""
        params = self.estimate(ggx.network_input(photo, self.config.log_mode, distance))
        if fill and self.config.log_mode == "ldr":
            # Where the LDR input saturates (for an 8-bit photo: ggx.clipped), as the runtime does.
            params = fill_clipped(params, (photo >= ggx.LDR_MAX).any(-1))
        return params

    def render_log(self, params: torch.Tensor, dirs: torch.Tensor, straight_through: bool = False) -> torch.Tensor:
        """Per-query log radiance: params ``[N, 64]``, dirs ``[N, 9]`` → ``[N, 3]``.

        ``straight_through``: training gradient of the final activation, see ``RenderMLP``."""
        nd = self.nd_enc(positional_encoding(dirs))
        return self.render(torch.cat([params, nd], dim=-1), straight_through)

    def relight_log(self, params: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, chunk: int = 16384) -> torch.Tensor:
        """Whole-image relight: params ``[B, 64, H, W]``, wi/wo ``[B, H, W, 3]`` → log ``[B, H, W, 3]``."""
        batch, _, height, width = params.shape
        p = params.permute(0, 2, 3, 1).reshape(-1, PARAM_CHANNELS)
        d = query_dirs(wi, wo).expand(batch, height, width, 9).reshape(-1, 9)
        out = [self.render_log(p[i : i + chunk], d[i : i + chunk]) for i in range(0, p.shape[0], chunk)]
        return torch.cat(out, dim=0).reshape(batch, height, width, 3)
