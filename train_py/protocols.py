"""Light/view sampling protocols (paper §3.1 and §4, DESIGN.md §6 and §8).

All functions return light and view positions ``[B, K, 3]`` in surface units.
"""

from __future__ import annotations

import math

import torch

from .ggx import CAPTURE_DISTANCE
from .ggx import normalize as _normalize

#: Hemisphere radius of the evaluation protocol (paper §4).
HEMISPHERE_RADIUS = 4.0
#: Standard deviation of the Gaussian perturbation of the highlight point and of the light distance.
REFLECT_SIGMA = 2.0
#: Smallest light distance from the highlight point of the Reflect protocol.
REFLECT_MIN_DIST = 0.5


def uniform_hemisphere(gen: torch.Generator, shape: tuple[int, ...], dtype=torch.float32) -> torch.Tensor:
    """Directions uniform in solid angle over the upper hemisphere, ``[*shape, 3]``."""
    z = torch.rand(shape, generator=gen, dtype=dtype)
    phi = 2 * torch.pi * torch.rand(shape, generator=gen, dtype=dtype)
    r = torch.sqrt(torch.clamp(1 - z * z, min=0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


def reflect(gen: torch.Generator, batch: int, k: int, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Reflect sampling: a highlight centred on a perturbed surface point (paper §3.1).

    ``p = U[-1,1]² + N(0, 2)``; view uniform on the hemisphere of radius d; light on the mirror
    direction of ``view - p`` about the surface normal at ``p``, at distance ``|N(0, 2)| + 0.5``.
    """
    shape = (batch, k)
    p = 2 * torch.rand(*shape, 2, generator=gen, dtype=dtype) - 1
    p = p + REFLECT_SIGMA * torch.randn(*shape, 2, generator=gen, dtype=dtype)
    p = torch.cat([p, torch.zeros(*shape, 1, dtype=dtype)], dim=-1)
    view = CAPTURE_DISTANCE * uniform_hemisphere(gen, shape, dtype)
    to_view = _normalize(view - p)
    mirrored = to_view * torch.tensor([-1.0, -1.0, 1.0], dtype=dtype)
    dist = REFLECT_SIGMA * torch.randn(*shape, 1, generator=gen, dtype=dtype).abs() + REFLECT_MIN_DIST
    light = p + mirrored * dist
    return light, view


def identity(batch: int, k: int = 1, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Co-located light and view at the capture position (re-creates the input photo)."""
    cam = torch.tensor([0.0, 0.0, CAPTURE_DISTANCE], dtype=dtype).expand(batch, k, 3).clone()
    return cam, cam.clone()


def hemisphere(gen: torch.Generator, batch: int, k: int, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Independent uniform light and view positions on the hemisphere of radius 4 (paper §4)."""
    light = HEMISPHERE_RADIUS * uniform_hemisphere(gen, (batch, k), dtype)
    view = HEMISPHERE_RADIUS * uniform_hemisphere(gen, (batch, k), dtype)
    return light, view


def _replace_share(
    gen: torch.Generator,
    light: torch.Tensor,
    view: torch.Tensor,
    frac: float,
    other_light: torch.Tensor,
    other_view: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each exemplar ``[B, K]`` of ``light``/``view`` swapped for ``other_*`` (broadcast to it) with
    probability ``frac``: the one draw the ``mix_*`` functions share (the mask is drawn after
    ``other_*``)."""
    mask = torch.rand(*light.shape[:2], 1, generator=gen) < frac
    return torch.where(mask, other_light, light), torch.where(mask, other_view, view)


def mix_identity(
    gen: torch.Generator,
    light: torch.Tensor,
    view: torch.Tensor,
    frac: float,
    capture: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Replaces each exemplar ``[B, K]`` by the Identity (capture) light and view with probability
    ``frac``. Reflect targets are mostly dark, so a short run learns the input photo's colour only
    slowly; a share of capture-geometry exemplars teaches it directly (opt-in, not in the paper).
    ``capture``: the capture's (flash, camera) positions ``[3]``; default both at ``(0, 0, d)``."""
    if frac <= 0:
        return light, view
    cam = torch.tensor([0.0, 0.0, CAPTURE_DISTANCE], dtype=light.dtype)
    flash, camera = capture if capture is not None else (cam, cam)
    return _replace_share(gen, light, view, frac, flash.to(light).expand_as(light), camera.to(view).expand_as(view))


def mix_hemisphere(
    gen: torch.Generator, light: torch.Tensor, view: torch.Tensor, frac: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Replaces each exemplar ``[B, K]`` by an independent uniform light and view (:func:`hemisphere`,
    the Hemisphere protocol's distribution: any relight a user may ask for, most with no highlight
    in the frame) with probability ``frac``. Reflect aims every light at a mirror point, so its
    off-specular queries come only from mirror points far outside the frame (opt-in, not in the
    paper)."""
    if frac <= 0:
        return light, view
    return _replace_share(gen, light, view, frac, *hemisphere(gen, *light.shape[:2], light.dtype))


#: Radius range (surface units, in the plane parallel to the surface) of the light's move away
#: from the camera in the moved-light protocol: from just off the lens to a wide side light.
MOVED_LIGHT_RADIUS = (0.2, 3.0)
#: Standard deviation of the moved light's height change (surface units).
MOVED_LIGHT_SIGMA_Z = 0.5


def moved_light(
    gen: torch.Generator, batch: int, k: int, camera: torch.Tensor, dtype=torch.float32
) -> tuple[torch.Tensor, torch.Tensor]:
    """The relight a user asks for first: the view stays at the capture camera ``[3]`` and the light
    moves off it (radius uniform in ``MOVED_LIGHT_RADIUS`` at a uniform angle, height jittered by
    ``N(0, MOVED_LIGHT_SIGMA_Z)``, kept ≥ 0.5 above the surface). The highlight of a glossy material
    then lies in the frame for ~75% of them, moved from where the photo has it; Reflect puts it in the frame for only
    ~15% of its exemplars (its centre ``U[-1,1]² + N(0, 2)`` mostly falls outside). Not in the paper."""
    u = torch.rand(batch, k, 2, generator=gen, dtype=dtype)
    lo, hi = MOVED_LIGHT_RADIUS
    r = lo + (hi - lo) * u[..., 0]
    phi = 2 * torch.pi * u[..., 1]
    dz = MOVED_LIGHT_SIGMA_Z * torch.randn(batch, k, generator=gen, dtype=dtype)
    cam = camera.to(dtype)
    light = torch.stack([cam[0] + r * torch.cos(phi), cam[1] + r * torch.sin(phi), (cam[2] + dz).clamp(min=0.5)], -1)
    return light, cam.expand(batch, k, 3).clone()


def mix_moved_light(
    gen: torch.Generator, light: torch.Tensor, view: torch.Tensor, frac: float, camera: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Replaces each exemplar ``[B, K]`` by a :func:`moved_light` one with probability ``frac``."""
    if frac <= 0:
        return light, view
    return _replace_share(gen, light, view, frac, *moved_light(gen, *light.shape[:2], camera, light.dtype))


PROTOCOLS = ("reflect", "identity", "hemisphere")

_MASK64 = (1 << 64) - 1


class SplitMix64:
    """nam-weights' ``SplitMix64`` (``crates/nam-weights/src/weights.rs``, nam-ggx's protocol stream), bit for bit."""

    def __init__(self, seed: int):
        self.state = seed & _MASK64

    def next_u64(self) -> int:
        self.state = (self.state + 0x9E3779B97F4A7C15) & _MASK64
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
        return z ^ (z >> 31)

    def uniform(self) -> float:
        """Uniform on [0, 1): the top 53 bits times 2⁻⁵³."""
        return (self.next_u64() >> 11) * 2.0**-53

    def normal(self) -> float:
        """Box–Muller, one of the pair (``u1 ∈ (0, 1]`` keeps the log finite)."""
        u1 = 1.0 - self.uniform()
        u2 = self.uniform()
        return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)

    def hemisphere(self) -> tuple[float, float, float]:
        """Uniform by area on the unit upper hemisphere, ``z ∈ (0, 1]``."""
        z = 1.0 - self.uniform()
        phi = 2.0 * math.pi * self.uniform()
        r = math.sqrt(max(1.0 - z * z, 0.0))
        return (r * math.cos(phi), r * math.sin(phi), z)


def seeded_pairs(name: str, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` light and view positions ``[1, n, 3]`` (float64) of protocol ``name``: the evaluation's
    pairs, drawn exactly as nam-ggx's ``ProtocolSampler`` draws them (same stream, same order), so
    ``train_py.evaluate`` and ``nam-cli report`` score the same images."""
    rng = SplitMix64(seed)
    lights, views = [], []
    for _ in range(n):
        if name == "identity":
            light = view = (0.0, 0.0, CAPTURE_DISTANCE)
        elif name == "hemisphere":
            light = tuple(HEMISPHERE_RADIUS * c for c in rng.hemisphere())
            view = tuple(HEMISPHERE_RADIUS * c for c in rng.hemisphere())
        elif name == "reflect":
            px = 2.0 * rng.uniform() - 1.0 + REFLECT_SIGMA * rng.normal()
            py = 2.0 * rng.uniform() - 1.0 + REFLECT_SIGMA * rng.normal()
            view = tuple(CAPTURE_DISTANCE * c for c in rng.hemisphere())
            d = (view[0] - px, view[1] - py, view[2])
            norm = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
            to_light = (-d[0] / norm, -d[1] / norm, d[2] / norm)
            dist = abs(REFLECT_SIGMA * rng.normal()) + REFLECT_MIN_DIST
            light = (px + to_light[0] * dist, py + to_light[1] * dist, to_light[2] * dist)
        else:
            raise ValueError(f"unknown protocol {name!r}")
        lights.append(light)
        views.append(view)
    as_tensor = lambda v: torch.tensor(v, dtype=torch.float64).reshape(1, n, 3)  # noqa: E731
    return as_tensor(lights), as_tensor(views)


def sample(name: str, gen: torch.Generator, batch: int, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    if name == "reflect":
        return reflect(gen, batch, k)
    if name == "identity":
        return identity(batch, 1)
    if name == "hemisphere":
        return hemisphere(gen, batch, k)
    raise ValueError(f"unknown protocol {name!r}")
