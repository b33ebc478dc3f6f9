"""Analytic GGX SVBRDF renderer in torch: the training renderer of DESIGN.md §3 and §7.

Conventions (shared with the Rust crate `nam-ggx`, pinned by `tests/fixtures/ggx_golden.safetensors`):

- The material lies on z = 0 and spans [-1, 1]² in x, y. Pixel (row i, col j) of an H×W image
  sits at ``x = 2(j+0.5)/W - 1``, ``y = -2(i+0.5)/H + 1``.
- The capture camera and its co-located point light sit at (0, 0, d), ``d = 1/tan(14°)``.
- Directions are per pixel, unit length, in the surface frame (z up): ``wi = normalize(light - p)``,
  ``wo = normalize(view - p)``, ``wh = normalize(wi + wo)``.
- Radiance convention: ``R = π · f_r(wi, wo) · max(0, n·wi)`` for a unit light without inverse-square
  falloff, i.e. ``R = (ρd/π + D·G·F / (4·NoL·NoV)) · NoL · π``.
- All tensors are channel-last: colours and vectors have a trailing dimension of 3.
"""

from __future__ import annotations

import math

import torch

#: Field of view of the default capture camera (the paper's training geometry), degrees.
CAPTURE_FOV = 28.0


def capture_distance(fov_degrees: float) -> float:
    """Distance of a camera whose field of view ``fov_degrees`` is just filled by the [-1, 1]²
    surface: ``1 / tan(fov / 2)``."""
    return 1.0 / math.tan(math.radians(fov_degrees) / 2)


#: Capture distance of the 28° field-of-view camera: the [-1, 1]² surface just fills the frame.
CAPTURE_DISTANCE = capture_distance(CAPTURE_FOV)
#: Lower bound of α = roughness² (roughness ≥ 0.01), as pbrt-v4 / Mitsuba 3 clamp it.
ALPHA_MIN = 1e-4
#: Lengths below this are treated as zero when normalising (guards 0/0 for opposite wi, wo).
NORMALIZE_EPS = 1e-30
#: Largest linear value kept by the LDR input compression (FORMAT.md "Network input").
LDR_MAX = 0.999999

_FRESNEL_A = -5.55473
_FRESNEL_B = -6.98316


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Dot product over the trailing dimension (no keepdim)."""
    return (a * b).sum(dim=-1)


def normalize(v: torch.Tensor) -> torch.Tensor:
    """Unit vector along the trailing dimension; the zero vector stays zero (never NaN)."""
    length = torch.sqrt(dot(v, v)).unsqueeze(-1)
    return v / torch.clamp(length, min=NORMALIZE_EPS)


def ggx_radiance(
    diffuse: torch.Tensor,
    specular: torch.Tensor,
    roughness: torch.Tensor,
    normal: torch.Tensor,
    wi: torch.Tensor,
    wo: torch.Tensor,
) -> torch.Tensor:
    """GGX radiance ``R = π f_r(wi, wo) (n·wi)`` per point (DESIGN.md §3, guards of §7).

    Shapes: ``diffuse``, ``specular`` (linear albedo / F0), ``normal`` (unit shading normal),
    ``wi`` and ``wo`` (unit, surface frame, pointing away from the surface) are ``[..., 3]``;
    ``roughness`` is ``[...]`` (perceptual, α = roughness²). Broadcasting applies.

    Guards: α ≥ ``ALPHA_MIN``; a light or view at or below the shading horizon
    (``n·wi ≤ 0`` or ``n·wo ≤ 0``) returns exactly 0. The Smith–Schlick terms are divided
    out analytically, ``G1(x)/x = 1/(x(1-k)+k)``, so no division by a dot product remains, and
    the NDF denominator is evaluated as ``(1 - NoH²) + NoH²·α²`` which cannot cancel to 0.
    """
    n_dot_l = dot(normal, wi)
    n_dot_v = dot(normal, wo)
    visible = (n_dot_l > 0) & (n_dot_v > 0)
    n_dot_l = torch.clamp(n_dot_l, min=0.0)
    n_dot_v = torch.clamp(n_dot_v, min=0.0)

    wh = normalize(wi + wo)
    n_dot_h = torch.clamp(dot(normal, wh), 0.0, 1.0)
    v_dot_h = torch.clamp(dot(wo, wh), 0.0, 1.0)

    alpha = torch.clamp(roughness * roughness, min=ALPHA_MIN)
    alpha2 = alpha * alpha
    n_dot_h2 = n_dot_h * n_dot_h
    # NoH²(α²-1)+1 rewritten as (1-NoH²) + NoH²α²: both terms ≥ 0, the second > 0 unless NoH = 0.
    d_denom = (1.0 - n_dot_h2) + n_dot_h2 * alpha2
    ndf = alpha2 / (math.pi * d_denom * d_denom)

    k = alpha / 2.0
    # G / (4 NoL NoV) with Smith–Schlick G1(x) = x / (x(1-k)+k): the x cancel exactly.
    vis = 1.0 / (4.0 * (n_dot_l * (1.0 - k) + k) * (n_dot_v * (1.0 - k) + k))

    fresnel_w = torch.exp2((_FRESNEL_A * v_dot_h + _FRESNEL_B) * v_dot_h)
    fresnel = specular + (1.0 - specular) * fresnel_w.unsqueeze(-1)

    spec = (ndf * vis).unsqueeze(-1) * fresnel
    radiance = (diffuse / math.pi + spec) * (n_dot_l * math.pi).unsqueeze(-1)
    return torch.where(visible.unsqueeze(-1), radiance, torch.zeros_like(radiance))


def pixel_positions(
    height: int, width: int, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu"
) -> torch.Tensor:
    """Pixel-centre positions on the surface, ``[H, W, 3]`` with z = 0 (DESIGN.md §3)."""
    j = torch.arange(width, dtype=torch.float64, device=device)
    i = torch.arange(height, dtype=torch.float64, device=device)
    x = 2.0 * (j + 0.5) / width - 1.0
    y = -2.0 * (i + 0.5) / height + 1.0
    pos = torch.zeros(height, width, 3, dtype=torch.float64, device=device)
    pos[..., 0] = x[None, :]
    pos[..., 1] = y[:, None]
    return pos.to(dtype)


def directions(
    light: torch.Tensor, view: torch.Tensor, height: int, width: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-pixel ``(wi, wo, wh)``, each ``[..., H, W, 3]`` for light/view positions ``[..., 3]``."""
    pos = pixel_positions(height, width, light.dtype, light.device)
    lead = light.shape[:-1]
    pos = pos.reshape((1,) * len(lead) + pos.shape)
    wi = normalize(light[..., None, None, :] - pos)
    wo = normalize(view[..., None, None, :] - pos)
    wh = normalize(wi + wo)
    return wi, wo, wh


def capture_position(
    dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu", distance: float = CAPTURE_DISTANCE
) -> torch.Tensor:
    """Camera and co-located light of the input photo, ``(0, 0, d)``."""
    return torch.tensor([0.0, 0.0, distance], dtype=dtype, device=device)


def capture_half_z(
    height: int,
    width: int,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    distance: float = CAPTURE_DISTANCE,
) -> torch.Tensor:
    """z of the capture half vector per pixel, ``d / sqrt(x² + y² + d²)``, shape ``[H, W]``."""
    pos = pixel_positions(height, width, torch.float64, device)
    d = distance
    z = d / torch.sqrt(pos[..., 0] ** 2 + pos[..., 1] ** 2 + d * d)
    return z.to(dtype)


def decode_normal_map(stored: torch.Tensor) -> torch.Tensor:
    """Stored normal ``(n+1)/2`` in [0, 1] → unit normal ``[..., 3]`` (renormalised)."""
    return normalize(2.0 * stored - 1.0)


def encode_normal_map(normal: torch.Tensor) -> torch.Tensor:
    """Unit normal → stored ``(n+1)/2``."""
    return (normal + 1.0) * 0.5


def render_maps(maps: dict[str, torch.Tensor], light: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
    """Render channel-last SVBRDF maps under point light/view positions.

    ``maps``: ``diffuse``, ``specular`` ``[B, H, W, 3]`` (linear), ``roughness`` ``[B, H, W]``,
    ``normal`` ``[B, H, W, 3]`` (unit). ``light``, ``view``: ``[B, K, 3]``.
    Returns radiance ``[B, K, H, W, 3]``.
    """
    height, width = maps["roughness"].shape[-2:]
    wi, wo, _ = directions(light, view, height, width)
    unsq = {k: v.unsqueeze(1) for k, v in maps.items()}
    return ggx_radiance(unsq["diffuse"], unsq["specular"], unsq["roughness"], unsq["normal"], wi, wo)


def render_capture(maps: dict[str, torch.Tensor]) -> torch.Tensor:
    """HDR radiance of the input photo (light = view = (0, 0, d)), ``[B, H, W, 3]``."""
    batch = maps["roughness"].shape[0]
    cam = capture_position(maps["roughness"].dtype, maps["roughness"].device).expand(batch, 1, 3)
    return render_maps(maps, cam, cam)[:, 0]


def to_log(radiance: torch.Tensor) -> torch.Tensor:
    """Log compression ``ln(R + 1)`` (DESIGN.md §3)."""
    return torch.log1p(radiance)


def from_log(y: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_log` for network outputs: ``max(expm1(y), 0)``."""
    return torch.clamp(torch.expm1(y), min=0.0)


def display(y_log: torch.Tensor) -> torch.Tensor:
    """Display transform of log data for figures: ``(e^y - 1)^(1/2.2)`` clamped to [0, 1]."""
    return torch.clamp(from_log(y_log), 0.0, 1.0) ** (1.0 / 2.2)


def srgb_encode(linear: torch.Tensor) -> torch.Tensor:
    """Linear [0, 1] → piecewise sRGB [0, 1] (clamps first)."""
    x = torch.clamp(linear, 0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * torch.pow(x.clamp(min=1e-12), 1.0 / 2.4) - 0.055)


def srgb_decode(encoded: torch.Tensor) -> torch.Tensor:
    """Piecewise sRGB [0, 1] → linear [0, 1]."""
    x = torch.clamp(encoded, 0.0, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, torch.pow((x + 0.055) / 1.055, 2.4))


#: An 8-bit sRGB capture value at or above this (any channel) counts as clipped.
CLIP_LEVEL = 254.5 / 255


def clipped(photo: torch.Tensor) -> torch.Tensor:
    """Where a linear photo ``[..., 3]`` (an 8-bit capture decoded) clipped in any channel: ``[...]``."""
    return (srgb_encode(photo) >= CLIP_LEVEL).any(-1)


def ldr_capture(radiance: torch.Tensor) -> torch.Tensor:
    """What an 8-bit sRGB PNG keeps of an HDR render: clamp, quantise, decode back to linear."""
    return srgb_decode(torch.round(srgb_encode(radiance) * 255.0) / 255.0)


def network_input(photo: torch.Tensor, log_mode: str = "ldr", distance: float = CAPTURE_DISTANCE) -> torch.Tensor:
    """Network input ``[B, 4, H, W]`` from a linear photo ``[B, H, W, 3]`` (FORMAT.md).

    ch 0..3: ``ln(1 + clamp(rgb, 0, 0.999999))`` (``ldr``) or ``ln(1 + max(rgb, 0))`` (``hdr``);
    ch 3: z of the capture half vector of a camera at ``(0, 0, distance)``.
    """
    if log_mode == "ldr":
        rgb = torch.log1p(torch.clamp(photo, 0.0, LDR_MAX))
    elif log_mode == "hdr":
        rgb = torch.log1p(torch.clamp(photo, min=0.0))
    else:
        raise ValueError(f"log_mode must be 'ldr' or 'hdr', got {log_mode!r}")
    batch, height, width, _ = photo.shape
    hz = capture_half_z(height, width, photo.dtype, photo.device, distance).expand(batch, 1, height, width)
    return torch.cat([rgb.permute(0, 3, 1, 2), hz], dim=1)
