"""nam: neural appearance models in Python, without torch.

Estimate a neural material from one flash photo, relight it under any point or directional
light and viewer, and evaluate or sample it as a BRDF in a renderer. The networks run in
Rust (the ``nam`` crates); arrays are numpy.

>>> import numpy as np, nam
>>> model = nam.Model.embedded()
>>> photo = np.full((32, 32, 3), 128, dtype=np.uint8)   # H×W×3 sRGB, e.g. from a PNG
>>> material = model.estimate(photo)
>>> material.shape
(32, 32)
>>> image = nam.relight(model, material, light=(1.0, 1.0, 4.0), view=(0.0, 0.0, 4.01))
>>> image.shape, image.dtype
((32, 32, 3), dtype('float32'))

Conventions (the project's DESIGN.md §3): positions are in the surface frame in material
half-widths — the material spans [−1, 1]² at z = 0 and the 28° capture camera sat at
(0, 0, 4.01); radiance is linear; the renderer API takes unit directions in the local
shading frame (z = normal).
"""

from ._nam import CAPTURE_FOV_DEG, Material, Model, relight

__all__ = ["CAPTURE_FOV_DEG", "Material", "Model", "relight"]
