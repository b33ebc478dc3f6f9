"""Type stubs of the extension module ``nam._nam`` (see the docstrings there for units)."""

from collections.abc import Sequence
from os import PathLike
from typing import Any

import numpy as np
import numpy.typing as npt

#: Field of view of the training captures, degrees (camera and flash at (0, 0, 4.01)).
CAPTURE_FOV_DEG: float

F32 = npt.NDArray[np.float32]

class Model:
    """``M_est`` (photo → latent map) and ``M_render`` (latent, directions → radiance)."""

    @staticmethod
    def embedded() -> Model:
        """The model built into the package."""

    @staticmethod
    def load(path: str | PathLike[str]) -> Model:
        """A model file (``.safetensors``); ``OSError`` if unreadable, ``ValueError`` if invalid."""

    def info(self) -> dict[str, Any]:
        """``width``, ``parameters``, ``dtype``, ``sha256``, ``param_channels``, ``input_skip``."""

    def estimate(
        self, photo: npt.NDArray[np.uint8] | F32, fov: float = 28.0, keep_clipped: bool = False
    ) -> Material:
        """Material of a square ``H×W×3`` photo: uint8 sRGB-encoded or float32 linear; ``fov`` in degrees.
        The params of the pixels the photo clipped are filled from the pixels around them unless
        ``keep_clipped``."""

    def estimate_file(
        self,
        path: str | PathLike[str],
        fov: float = 28.0,
        crop: bool = False,
        resize: int | None = None,
        keep_clipped: bool = False,
    ) -> Material:
        """Material of a photo file (PNG/JPEG sRGB, EXR linear), as ``nam-cli estimate`` reads it."""

class Material:
    """One 64-d latent vector per pixel, bound to its model. Directions are unit vectors in
    the local shading frame (z = normal); ``uv`` in [0, 1]² covers the material once."""

    @staticmethod
    def load(path: str | PathLike[str], model: Model | None = None) -> Material:
        """A ``.nam`` file; ``model`` must be the one that estimated it (default: embedded)."""

    def save(self, path: str | PathLike[str], exact: bool = False) -> None:
        """Writes a ``.nam`` file (f16 params, or f32 with ``exact``)."""

    @property
    def params(self) -> F32:
        """``H×W×64`` float32, a read-only view of the material's memory."""

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)`` in pixels."""

    @property
    def model(self) -> Model:
        """The model this material belongs to."""

    def eval(self, uv: npt.ArrayLike, wi: npt.ArrayLike, wo: npt.ArrayLike) -> F32:
        """``f_r·cos θi`` (``N×3``) for ``uv`` ``N×2``, ``wi``/``wo`` ``N×3``; 0 below the horizon."""

    def eval_fr(self, uv: npt.ArrayLike, wi: npt.ArrayLike, wo: npt.ArrayLike) -> F32:
        """``f_r`` (``N×3``)."""

    def sample(self, uv: npt.ArrayLike, wo: npt.ArrayLike, u: npt.ArrayLike) -> tuple[F32, F32, F32]:
        """Cosine-weighted ``(wi N×3, weight N×3, pdf N)`` for random numbers ``u`` in [0, 1)²."""

    def pdf(self, uv: npt.ArrayLike, wi: npt.ArrayLike, wo: npt.ArrayLike) -> F32:
        """Solid-angle pdf (``N``) of :meth:`sample`; 0 below the horizon."""

def relight(
    model: Model,
    material: Material,
    light: Sequence[float],
    view: Sequence[float],
    directional: bool = False,
    orthographic: bool = False,
    intensity: float = 1.0,
    falloff: bool = False,
) -> F32:
    """Linear radiance ``H×W×3`` under one light and viewer (surface frame, material half-widths)."""
