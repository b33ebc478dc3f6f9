//! The plain reference implementation: readable loops straight from the
//! definitions in DESIGN §4 / docs/FORMAT.md, using the file's tensors as they
//! are (no folding, no packing), CHW activations, and a choice of f32 or f64
//! accumulation for every dot product and reduction. Slow; used to check the
//! fast path and as executable documentation.

use std::cell::RefCell;

use nam_weights::{Scope, Weights, radiance_from_log};

use crate::encoding::{direction_triple, encode_f64, encode_into};
use crate::error::{Result, check_finite, check_len};
use crate::maps::ParamMap;
use crate::unet::{check_image, pad_multiple};

/// Accumulator precision of the reference path. Activations are stored as f32
/// between operations in both modes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accumulate {
    /// Sums in f32 (what a straightforward f32 implementation does).
    F32,
    /// Sums in f64 (closest to the exact result of the f32 weights).
    F64,
}

trait Acc: Copy + std::ops::AddAssign {
    const ZERO: Self;
    /// True for f64 accumulation.
    const WIDE: bool;
    fn mul(a: f32, b: f32) -> Self;
    fn of(a: f32) -> Self;
    fn get(self) -> f32;
    fn as_f64(self) -> f64;
}
impl Acc for f32 {
    const ZERO: Self = 0.0;
    const WIDE: bool = false;
    fn mul(a: f32, b: f32) -> Self {
        a * b
    }
    fn of(a: f32) -> Self {
        a
    }
    fn get(self) -> f32 {
        self
    }
    fn as_f64(self) -> f64 {
        f64::from(self)
    }
}
impl Acc for f64 {
    const ZERO: Self = 0.0;
    const WIDE: bool = true;
    fn mul(a: f32, b: f32) -> Self {
        f64::from(a) * f64::from(b)
    }
    fn of(a: f32) -> Self {
        f64::from(a)
    }
    fn get(self) -> f32 {
        self as f32
    }
    fn as_f64(self) -> f64 {
        self
    }
}

/// The largest magnitude of every intermediate activation of one reference evaluation, in
/// evaluation order, named after the weights that produce it (`est.enc1.0.ha1.gate` is the
/// gate convolution's output before the sigmoid, `render.l3` the fourth render layer before its
/// activation). Values are recorded where they are stored between operations, before any
/// activation function, so each entry bounds what an f16 activation buffer would hold.
/// A NaN counts as +∞.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ActivationRanges {
    /// `(name, max |value|)` in evaluation order.
    pub entries: Vec<(String, f32)>,
}

impl ActivationRanges {
    fn record(&mut self, name: String, values: &[f32]) {
        let m = values.iter().fold(0.0f32, |m, &v| {
            if v.is_nan() {
                f32::INFINITY
            } else {
                m.max(v.abs())
            }
        });
        self.entries.push((name, m));
    }

    /// Takes the element-wise maximum with another trace (entries matched by name; names
    /// missing here are appended).
    pub fn merge(&mut self, other: &Self) {
        for (name, m) in &other.entries {
            match self.entries.iter_mut().find(|(n, _)| n == name) {
                Some((_, v)) => *v = v.max(*m),
                None => self.entries.push((name.clone(), *m)),
            }
        }
    }

    /// The largest magnitude over all entries (0 when empty).
    pub fn max(&self) -> f32 {
        self.entries.iter().fold(0.0, |a, (_, m)| a.max(*m))
    }
}

/// A CHW activation.
#[derive(Debug, Clone)]
struct Chw {
    c: usize,
    h: usize,
    w: usize,
    d: Vec<f32>,
}

impl Chw {
    fn zeros(c: usize, h: usize, w: usize) -> Self {
        Self {
            c,
            h,
            w,
            d: vec![0.0; c * h * w],
        }
    }
    fn at(&self, c: usize, y: usize, x: usize) -> f32 {
        self.d[(c * self.h + y) * self.w + x]
    }
    fn map(mut self, f: impl Fn(f32) -> f32) -> Self {
        self.d.iter_mut().for_each(|v| *v = f(*v));
        self
    }
    fn zip(mut self, o: &Self, f: impl Fn(f32, f32) -> f32) -> Self {
        self.d
            .iter_mut()
            .zip(&o.d)
            .for_each(|(a, b)| *a = f(*a, *b));
        self
    }
    fn concat(&self, o: &Self) -> Self {
        let mut d = self.d.clone();
        d.extend_from_slice(&o.d);
        Self {
            c: self.c + o.c,
            h: self.h,
            w: self.w,
            d,
        }
    }
    /// y·scale[c] + shift[c].
    fn affine(mut self, scale: Option<&[f32]>, shift: &[f32]) -> Self {
        let hw = self.h * self.w;
        for c in 0..self.c {
            for v in &mut self.d[c * hw..(c + 1) * hw] {
                *v = scale.map_or(*v, |s| *v * s[c]) + shift[c];
            }
        }
        self
    }
}

fn relu(v: f32) -> f32 {
    v.max(0.0)
}
fn leaky(v: f32, s: f32) -> f32 {
    if v >= 0.0 { v } else { v * s }
}
fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}

/// Conv2d, weight `[co, ci, k, k]`, replicate padding `pad`, stride `s`, no bias.
fn conv<A: Acc>(x: &Chw, w: &[f32], co: usize, k: usize, s: usize, pad: usize) -> Chw {
    let ho = (x.h + 2 * pad - k) / s + 1;
    let wo = (x.w + 2 * pad - k) / s + 1;
    let mut out = Chw::zeros(co, ho, wo);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for o in 0..co {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = A::ZERO;
                for i in 0..x.c {
                    for ky in 0..k {
                        let iy = clamp((oy * s + ky) as isize - pad as isize, x.h);
                        for kx in 0..k {
                            let ix = clamp((ox * s + kx) as isize - pad as isize, x.w);
                            acc += A::mul(w[((o * x.c + i) * k + ky) * k + kx], x.at(i, iy, ix));
                        }
                    }
                }
                out.d[(o * ho + oy) * wo + ox] = acc.get();
            }
        }
    }
    out
}

/// ConvTranspose2d, weight `[ci, co, k, k]`, stride 2, zero padding `pad`, plus bias.
fn conv_t<A: Acc>(x: &Chw, w: &[f32], b: &[f32], co: usize, k: usize, pad: usize) -> Chw {
    let ho = (x.h - 1) * 2 + k - 2 * pad;
    let wo = (x.w - 1) * 2 + k - 2 * pad;
    let mut out = Chw::zeros(co, ho, wo);
    for o in 0..co {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = A::of(b[o]);
                for i in 0..x.c {
                    for ky in 0..k {
                        // oy = 2·iy − pad + ky
                        let ty = oy as isize + pad as isize - ky as isize;
                        if ty < 0 || ty % 2 != 0 || (ty / 2) as usize >= x.h {
                            continue;
                        }
                        for kx in 0..k {
                            let tx = ox as isize + pad as isize - kx as isize;
                            if tx < 0 || tx % 2 != 0 || (tx / 2) as usize >= x.w {
                                continue;
                            }
                            acc += A::mul(
                                w[((i * co + o) * k + ky) * k + kx],
                                x.at(i, (ty / 2) as usize, (tx / 2) as usize),
                            );
                        }
                    }
                }
                out.d[(o * ho + oy) * wo + ox] = acc.get();
            }
        }
    }
    out
}

/// InstanceNorm: per channel over H×W, biased variance, no affine.
fn instance_norm<A: Acc>(x: &Chw, eps: f32) -> Chw {
    let hw = x.h * x.w;
    let mut out = x.clone();
    for c in 0..x.c {
        let v = &x.d[c * hw..(c + 1) * hw];
        let mut s = A::ZERO;
        v.iter().for_each(|&a| s += A::of(a));
        let mean = s.as_f64() / hw as f64;
        let mut q = A::ZERO;
        v.iter().for_each(|&a| {
            let d = (f64::from(a) - mean) as f32;
            q += A::mul(d, d);
        });
        let var = q.as_f64() / hw as f64;
        let inv = 1.0 / (var + f64::from(eps)).sqrt();
        for (o, &a) in out.d[c * hw..(c + 1) * hw].iter_mut().zip(v) {
            *o = ((f64::from(a) - mean) * inv) as f32;
        }
    }
    out
}

struct Ctx {
    eps: f32,
    ha_slope: f32,
    /// Activation ranges, when tracing.
    trace: Option<RefCell<ActivationRanges>>,
}

impl Ctx {
    /// Records `x` as activation `what` of the layer at `p` (when tracing).
    fn rec(&self, p: &Scope<'_>, what: &str, x: &Chw) {
        if let Some(t) = &self.trace {
            let name = if what.is_empty() {
                p.prefix().to_string()
            } else {
                format!("{}.{what}", p.prefix())
            };
            t.borrow_mut().record(name, &x.d);
        }
    }

    fn ha<A: Acc>(&self, x: &Chw, p: &Scope<'_>, co: usize, s: usize) -> Result<Chw> {
        let ci = x.c;
        let g = p.get("gate.weight", &[co, ci, 3, 3])?;
        let f = p.get("feat.weight", &[co, ci, 3, 3])?;
        let i1a = p.get("inc1a.weight", &[co, ci, 3, 3])?;
        let i1b = p.get("inc1b.weight", &[co / 2, co, 3, 3])?;
        let i2 = p.get("inc2.weight", &[co / 2, ci, 3, 3])?;
        let a = conv::<A>(x, g, co, 3, s, 1);
        self.rec(p, "gate", &a);
        let a = a.map(sigmoid);
        let norm = instance_norm::<A>(x, self.eps);
        self.rec(p, "norm", &norm);
        let b = conv::<A>(&norm, f, co, 3, s, 1);
        self.rec(p, "feat", &b);
        let b = b.map(|v| leaky(v, self.ha_slope));
        let c1a = conv::<A>(x, i1a, co, 3, 1, 1);
        self.rec(p, "inc1a", &c1a);
        let c1 = conv::<A>(&c1a, i1b, co / 2, 3, s, 1);
        self.rec(p, "inc1b", &c1);
        let c2 = conv::<A>(x, i2, co / 2, 3, s, 1);
        self.rec(p, "inc2", &c2);
        let out = a.zip(&b, |a, b| a * b).zip(&c1.concat(&c2), |ab, c| ab + c);
        self.rec(p, "out", &out);
        Ok(out)
    }

    fn basic<A: Acc>(&self, x: &Chw, p: &Scope<'_>, co: usize, s: usize) -> Result<Chw> {
        let y = self.ha::<A>(x, &p.scope("ha1"), co, s)?;
        let y = y.affine(Some(p.get("bn1.scale", &[co])?), p.get("bn1.shift", &[co])?);
        self.rec(p, "bn1", &y);
        let y = y.map(relu);
        let y = self.ha::<A>(&y, &p.scope("ha2"), co, 1)?;
        let y = y.affine(Some(p.get("bn2.scale", &[co])?), p.get("bn2.shift", &[co])?);
        self.rec(p, "bn2", &y);
        let id = if x.c != co || s != 1 {
            let d = conv::<A>(x, p.get("down.weight", &[co, x.c, 1, 1])?, co, 1, s, 0)
                .affine(None, p.get("down.bias", &[co])?);
            self.rec(p, "down", &d);
            d
        } else {
            x.clone()
        };
        let out = y.zip(&id, |a, b| relu(a + b));
        self.rec(p, "", &out);
        Ok(out)
    }

    fn reverse<A: Acc>(&self, x: &Chw, p: &Scope<'_>, co: usize) -> Result<Chw> {
        let ci = x.c;
        let up4 = conv_t::<A>(
            x,
            p.get("up4.weight", &[ci, co, 4, 4])?,
            p.get("up4.bias", &[co])?,
            co,
            4,
            1,
        );
        self.rec(p, "up4", &up4);
        let up4 = up4.map(relu);
        let y = conv::<A>(&up4, p.get("conv.weight", &[co, co, 3, 3])?, co, 3, 1, 1)
            .affine(None, p.get("conv.bias", &[co])?);
        self.rec(p, "conv", &y);
        let up2 = conv_t::<A>(
            x,
            p.get("up2.weight", &[ci, co, 2, 2])?,
            p.get("up2.bias", &[co])?,
            co,
            2,
            0,
        );
        self.rec(p, "up2", &up2);
        let out = y.zip(&up2, |a, b| relu(a + b));
        self.rec(p, "", &out);
        Ok(out)
    }
}

/// Reference `M_est`: network input (CHW, `in_channels × height × width`) →
/// param map (HWC). Any size: replicate-padded bottom/right to a multiple of 8
/// and cropped back.
pub fn estimate(
    weights: &Weights,
    input: &[f32],
    height: usize,
    width: usize,
    acc: Accumulate,
) -> Result<ParamMap> {
    let (map, _) = match acc {
        Accumulate::F32 => estimate_impl::<f32>(weights, input, height, width, false),
        Accumulate::F64 => estimate_impl::<f64>(weights, input, height, width, false),
    }?;
    Ok(map)
}

/// [`estimate`], also returning the range of every intermediate activation (for the f16
/// safety analysis: which layers an f16 activation buffer could overflow in).
pub fn estimate_traced(
    weights: &Weights,
    input: &[f32],
    height: usize,
    width: usize,
    acc: Accumulate,
) -> Result<(ParamMap, ActivationRanges)> {
    match acc {
        Accumulate::F32 => estimate_impl::<f32>(weights, input, height, width, true),
        Accumulate::F64 => estimate_impl::<f64>(weights, input, height, width, true),
    }
}

fn estimate_impl<A: Acc>(
    weights: &Weights,
    input: &[f32],
    height: usize,
    width: usize,
    traced: bool,
) -> Result<(ParamMap, ActivationRanges)> {
    let cfg = weights.config();
    check_image(height, width)?;
    check_len(
        "network input",
        cfg.in_channels * height * width,
        input.len(),
    )?;
    check_finite("network input", input)?;
    let (hp, wp) = (pad_multiple(height), pad_multiple(width));
    let mut x = Chw::zeros(cfg.in_channels, hp, wp);
    for c in 0..cfg.in_channels {
        for y in 0..hp {
            for xx in 0..wp {
                x.d[(c * hp + y) * wp + xx] =
                    input[(c * height + y.min(height - 1)) * width + xx.min(width - 1)];
            }
        }
    }
    let ctx = Ctx {
        eps: cfg.norm_eps,
        ha_slope: cfg.slopes.ha,
        trace: traced.then(|| RefCell::new(ActivationRanges::default())),
    };
    let est = weights.scope("est");
    ctx.rec(&est, "input", &x);
    let photo = x;
    let c = cfg.width;
    let x = conv::<A>(
        &photo,
        est.get("stem.weight", &[c, cfg.in_channels, 7, 7])?,
        c,
        7,
        1,
        3,
    );
    ctx.rec(&est, "stem", &x);
    let mut skips = Vec::new();
    let mut x = x;
    for (k, w) in [c, 2 * c, 4 * c, 8 * c].into_iter().enumerate() {
        let s = if k == 0 { 1 } else { 2 };
        x = ctx.basic::<A>(&x, &est.scope(&format!("enc{}.0", k + 1)), w, s)?;
        x = ctx.basic::<A>(&x, &est.scope(&format!("enc{}.1", k + 1)), w, 1)?;
        skips.push(x.clone());
    }
    let x = x.map(f32::atan);
    let x = ctx.reverse::<A>(&x, &est.scope("dec1.0"), 8 * c)?;
    let x = ctx.basic::<A>(&x, &est.scope("dec1.1"), 8 * c, 1)?;
    let x = ctx.reverse::<A>(&x.concat(&skips[2]), &est.scope("dec2.0"), 4 * c)?;
    let x = ctx.basic::<A>(&x, &est.scope("dec2.1"), 4 * c, 1)?;
    let x = ctx.reverse::<A>(&x.concat(&skips[1]), &est.scope("dec3.0"), 2 * c)?;
    let x = ctx.basic::<A>(&x, &est.scope("dec3.1"), 2 * c, 1)?;
    let x = ctx.basic::<A>(&x.concat(&skips[0]), &est.scope("dec4.0"), c, 1)?;
    let x = ctx.basic::<A>(&x, &est.scope("dec4.1"), c, 1)?;
    let pc = cfg.param_channels;
    let x = if cfg.input_skip { x.concat(&photo) } else { x };
    let head = est.get("head.weight", &[pc, cfg.head_in_channels(), 7, 7])?;
    let x = conv::<A>(&x, head, pc, 7, 1, 3);
    ctx.rec(&est, "head", &x);
    let mut data = Vec::with_capacity(height * width * pc);
    for y in 0..height {
        for xx in 0..width {
            for k in 0..pc {
                data.push(x.at(k, y, xx));
            }
        }
    }
    let map = ParamMap {
        height,
        width,
        channels: pc,
        data,
    };
    Ok((map, ctx.trace.map(RefCell::into_inner).unwrap_or_default()))
}

/// Reference positional encoding: f64 `sin(2^k·π·c)` rounded to f32.
pub fn encode(wi: [f32; 3], wo: [f32; 3], octaves: usize) -> Vec<f32> {
    encode_f64(&direction_triple(wi, wo), octaves)
        .into_iter()
        .map(|v| v as f32)
        .collect()
}

fn dense<A: Acc>(w: &[f32], out: usize, x: &[f32]) -> Vec<f32> {
    let inp = x.len();
    (0..out)
        .map(|o| {
            let mut s = A::ZERO;
            for i in 0..inp {
                s += A::mul(w[o * inp + i], x[i]);
            }
            s.get()
        })
        .collect()
}

/// Intermediate values of one reference `M_render` evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderTrace {
    /// Positional encoding (297).
    pub encoded: Vec<f32>,
    /// ND_enc output (32).
    pub nd: Vec<f32>,
    /// Network output, log space (3).
    pub log: [f32; 3],
    /// Radiance `max(expm1(log), 0)`.
    pub radiance: [f32; 3],
}

/// Reference `M_render` for one query (`params`: 64 values; ωi, ωo unit vectors
/// in the surface frame), using `render.l0` and `render.l1` unfolded. With
/// [`Accumulate::F64`] the encoding is computed in f64; with [`Accumulate::F32`]
/// it is the fast path's range-reduced f32 encoding.
pub fn render(
    weights: &Weights,
    params: &[f32],
    wi: [f32; 3],
    wo: [f32; 3],
    acc: Accumulate,
) -> Result<RenderTrace> {
    let mut ranges = ActivationRanges::default();
    match acc {
        Accumulate::F32 => render_impl::<f32>(weights, params, wi, wo, &mut ranges),
        Accumulate::F64 => render_impl::<f64>(weights, params, wi, wo, &mut ranges),
    }
}

/// [`render`], also returning the range of every layer's output before its activation
/// (`render.input` is the params ‖ ND_enc vector, `nd_enc.l0` … `render.l6`).
pub fn render_traced(
    weights: &Weights,
    params: &[f32],
    wi: [f32; 3],
    wo: [f32; 3],
    acc: Accumulate,
) -> Result<(RenderTrace, ActivationRanges)> {
    let mut ranges = ActivationRanges::default();
    let t = match acc {
        Accumulate::F32 => render_impl::<f32>(weights, params, wi, wo, &mut ranges),
        Accumulate::F64 => render_impl::<f64>(weights, params, wi, wo, &mut ranges),
    }?;
    Ok((t, ranges))
}

fn render_impl<A: Acc>(
    weights: &Weights,
    params: &[f32],
    wi: [f32; 3],
    wo: [f32; 3],
    ranges: &mut ActivationRanges,
) -> Result<RenderTrace> {
    let cfg = weights.config();
    check_len("params", cfg.param_channels, params.len())?;
    let encoded = if A::WIDE {
        encode(wi, wo, cfg.pe_octaves)
    } else {
        let mut e = vec![0.0; cfg.encoding_len()];
        encode_into(&direction_triple(wi, wo), cfg.pe_octaves, &mut e);
        e
    };
    let nd_w = &cfg.nd_enc;
    let mut h = encoded.clone();
    ranges.record("nd_enc.input".into(), &h);
    for i in 0..nd_w.len() - 1 {
        let w = weights.get(&format!("nd_enc.l{i}.weight"), &[nd_w[i + 1], nd_w[i]])?;
        h = dense::<A>(w, nd_w[i + 1], &h);
        ranges.record(format!("nd_enc.l{i}"), &h);
        if i + 2 < nd_w.len() {
            h.iter_mut().for_each(|v| *v = leaky(*v, cfg.slopes.nd_enc));
        }
    }
    let nd = h;
    let r = &cfg.render;
    let mut h: Vec<f32> = params.iter().chain(&nd).copied().collect();
    ranges.record("render.input".into(), &h);
    let layers = r.len() - 1;
    for i in 0..layers {
        let w = weights.get(&format!("render.l{i}.weight"), &[r[i + 1], r[i]])?;
        h = dense::<A>(w, r[i + 1], &h);
        ranges.record(format!("render.l{i}"), &h);
        let slope = if i == 0 {
            None
        } else if i + 1 == layers {
            Some(cfg.slopes.render_out)
        } else {
            Some(cfg.slopes.render_hidden)
        };
        if let Some(s) = slope {
            h.iter_mut().for_each(|v| *v = leaky(*v, s));
        }
    }
    let log = [h[0], h[1], h[2]];
    let radiance = log.map(radiance_from_log);
    Ok(RenderTrace {
        encoded,
        nd,
        log,
        radiance,
    })
}
