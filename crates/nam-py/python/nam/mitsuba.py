"""A Mitsuba 3 BSDF that wears a neural material: ``{"type": "nam", "material": ...}``.

    import mitsuba as mi
    mi.set_variant("scalar_rgb")          # or "llvm_ad_rgb"
    import nam.mitsuba                    # registers "nam" for the active variant
    bsdf = {"type": "nam", "material": "photo.nam"}         # or a photo to estimate
    bsdf = {"type": "nam", "material": "photo.png", "model": "other.safetensors"}

Properties: ``material`` — a ``.nam`` file (``nam-cli estimate``) or a square flash photo
(PNG/JPEG sRGB, EXR linear) estimated on load; ``model`` — the model file (default: the one
built into the package).

The BSDF evaluates the Rust networks through numpy (``nam.Material.eval``/``sample``/``pdf``)
with the surface point's ``uv`` and the local-frame directions; sampling is the facade's
cosine-weighted hemisphere sampling. One-sided: zero below the surface. In the JIT variants
(``llvm_ad_*``) every call must see evaluated arrays, so :func:`register` switches Dr.Jit's
symbolic loops and calls off (wavefront mode). On Debian 12 the LLVM backend needs a newer
libLLVM than the system's 15 (``apt-get install libllvm19`` and
``DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1``).

Light units: a Mitsuba point light of intensity ``I`` equals ``nam.relight(..., falloff=True)``
with ``intensity = I / (π·d²)``, d = 1/tan(14°) ≈ 4.0107 (the capture distance); a directional
light of irradiance ``E`` equals ``intensity = E / π``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import Material, Model

#: The flags of the neural BSDF: it reflects, diffusely and glossily, on its front side.
FLAGS = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide


def _scalar() -> bool:
    return mi.variant().startswith("scalar")


def _rows(x, k: int) -> np.ndarray:
    """A Dr.Jit vector (one, or a wavefront of N) as an ``N×k`` float32 array."""
    a = np.asarray(x, dtype=np.float32)
    return np.ascontiguousarray(a.reshape(1, k) if a.ndim == 1 else a.T)


def _uv(si) -> np.ndarray:
    """Mitsuba's ``uv`` (v = 0 at the bottom of a rectangle) as nam's (v = 0 at the top row)."""
    uv = _rows(si.uv, 2)
    uv[:, 1] = 1.0 - uv[:, 1]
    return uv


def _usable(uv: np.ndarray, *dirs: np.ndarray) -> np.ndarray:
    """Rows a wavefront may hold that the BRDF refuses (inactive lanes: zero or non-finite
    directions, NaN uv) are set to a harmless query in place; returns the mask of real rows,
    whose results are kept (the others are zeroed)."""
    ok = np.isfinite(uv).all(axis=1)
    for d in dirs:
        ok &= np.isfinite(d).all(axis=1) & (np.abs(d).sum(axis=1) > 0)
    uv[~ok] = 0.5
    for d in dirs:
        d[~ok] = (0.0, 0.0, 1.0)
    return ok


def _color(rgb: np.ndarray):
    return mi.Color3f(*(float(c) for c in rgb[0])) if _scalar() else mi.Color3f(np.ascontiguousarray(rgb.T))


def _vector(xyz: np.ndarray):
    return mi.Vector3f(*(float(c) for c in xyz[0])) if _scalar() else mi.Vector3f(np.ascontiguousarray(xyz.T))


def _float(v: np.ndarray):
    return mi.Float(float(v[0])) if _scalar() else mi.Float(np.ascontiguousarray(v))


def _load(material: str, model: str | None) -> Material:
    m = Model.load(model) if model else Model.embedded()
    if material.lower().endswith(".nam"):
        return Material.load(material, model=m)
    return m.estimate_file(material)


class NeuralBSDF(mi.BSDF):
    """The ``"nam"`` BSDF (see the module docs)."""

    def __init__(self, props: mi.Properties):
        mi.BSDF.__init__(self, props)
        model = props["model"] if props.has_property("model") else None
        self.material = _load(str(props["material"]), None if model is None else str(model))
        self.m_flags = FLAGS
        self.m_components = [FLAGS]

    def eval(self, ctx, si, wo, active=True):
        uv, to_light, to_view = _uv(si), _rows(wo, 3), _rows(si.wi, 3)
        ok = _usable(uv, to_light, to_view)
        f = self.material.eval(uv, to_light, to_view) * ok[:, None]
        return dr.select(active, _color(f), 0.0)

    def pdf(self, ctx, si, wo, active=True):
        uv, to_light, to_view = _uv(si), _rows(wo, 3), _rows(si.wi, 3)
        ok = _usable(uv, to_light, to_view)
        p = self.material.pdf(uv, to_light, to_view) * ok
        return dr.select(active, _float(p), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        uv, to_view, u = _uv(si), _rows(si.wi, 3), _rows(sample2, 2)
        ok = _usable(uv, to_view)
        wi, weight, pdf = self.material.sample(uv, to_view, np.nan_to_num(u))
        weight *= ok[:, None]
        pdf *= ok
        bs = mi.BSDFSample3f()
        bs.wo = _vector(wi)
        bs.pdf = dr.select(active, _float(pdf), 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
        bs.sampled_component = mi.UInt32(0)
        return bs, dr.select(active & (bs.pdf > 0), _color(weight), 0.0)

    def traverse(self, callback):
        pass

    def to_string(self):
        h, w = self.material.shape
        return f"NeuralBSDF[{h}×{w} neural material]"


def register() -> None:
    """Registers ``"nam"`` for the active variant (importing this module does it once). In JIT
    variants it also switches Dr.Jit to wavefront mode, which the numpy round trip needs."""
    if not _scalar():
        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        dr.set_flag(dr.JitFlag.SymbolicCalls, False)
    mi.register_bsdf("nam", NeuralBSDF)


register()
