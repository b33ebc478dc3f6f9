//! `M_est`, fast path: HWC activations, convolutions as im2col + blocked GEMM
//! over bands of output rows (rayon), convs that read the same input fused
//! into one GEMM (gate, inc1a, inc2 and the 1×1 `down` as a centre tap),
//! transposed convs split into output-parity sub-convolutions.

use nam_weights::{Scope, Weights};
use rayon::prelude::*;

use crate::error::{ModelError, Result, check_finite, check_len};
use crate::render::ParamMap;
use crate::sgemm::{Mat, sgemm, sgemm_into_transposed};

/// Largest accepted image side, in pixels (guards size arithmetic).
pub const MAX_SIDE: usize = 1 << 15;

/// Output pixels per GEMM band: enough rows for the GEMM kernel, small enough
/// that the im2col band stays in cache.
const BAND_PIXELS: usize = 512;

/// Pixels per rayon task in element-wise passes.
const EW_PIXELS: usize = 1024;

/// Convolutions with fewer output channels than this run their GEMM with the
/// pixel dimension along the SIMD lanes (16 f32 per AVX-512 register).
const TRANSPOSE_BELOW: usize = 16;

pub(crate) fn pad_multiple(n: usize) -> usize {
    n.next_multiple_of(nam_weights::UNET_MULTIPLE)
}

pub(crate) fn check_image(height: usize, width: usize) -> Result<()> {
    let bad = |reason| {
        Err(ModelError::ImageSize {
            height,
            width,
            reason,
        })
    };
    if height == 0 || width == 0 {
        return bad("zero-sized");
    }
    if height > MAX_SIDE || width > MAX_SIDE {
        return bad("side larger than 32768");
    }
    Ok(())
}

/// An HWC activation: `d[(y·w + x)·c + ch]`.
#[derive(Debug, Clone)]
struct Hwc {
    h: usize,
    w: usize,
    c: usize,
    d: Vec<f32>,
}

/// A k×k convolution (or several fused along the output channels) packed as
/// the GEMM right-hand side `[k·k·cin, cout]`, row index `(ky·k + kx)·cin + ci`.
#[derive(Debug, Clone)]
struct PackedConv {
    k: usize,
    stride: usize,
    pad: usize,
    cin: usize,
    cout: usize,
    wt: Vec<f32>,
}

impl PackedConv {
    /// Fuses convs over the same input; each part is `(weight [co, cin, kp, kp], co, kp)`
    /// with `kp == k` or `kp == 1` (a 1×1 conv placed at the centre tap; valid
    /// because pad = k/2 makes the centre tap read exactly the 1×1 conv's pixel).
    fn fused(parts: &[(&[f32], usize, usize)], cin: usize, k: usize, stride: usize) -> Self {
        let cout: usize = parts.iter().map(|p| p.1).sum();
        let mut wt = vec![0.0f32; k * k * cin * cout];
        let mut col0 = 0;
        for &(w, co, kp) in parts {
            for o in 0..co {
                for i in 0..cin {
                    for ky in 0..kp {
                        for kx in 0..kp {
                            let (ty, tx) = if kp == k { (ky, kx) } else { (k / 2, k / 2) };
                            wt[((ty * k + tx) * cin + i) * cout + col0 + o] =
                                w[((o * cin + i) * kp + ky) * kp + kx];
                        }
                    }
                }
            }
            col0 += co;
        }
        Self {
            k,
            stride,
            pad: k / 2,
            cin,
            cout,
            wt,
        }
    }

    /// Replicate-padded convolution (no bias) of the first `cin` channels of
    /// `x` (`x.c` may be wider: a view of a fused GEMM's leading columns).
    fn run(&self, x: &Hwc) -> Hwc {
        self.run_with(x, &self.wt)
    }

    /// Like [`Self::run`], with `wt` (same packing as `self.wt`) as weights.
    fn run_with(&self, x: &Hwc, wt: &[f32]) -> Hwc {
        debug_assert!(self.cin <= x.c);
        debug_assert_eq!(wt.len(), self.wt.len());
        let whole = x.c == self.cin;
        let ho = (x.h + 2 * self.pad - self.k) / self.stride + 1;
        let wo = (x.w + 2 * self.pad - self.k) / self.stride + 1;
        let kk = self.k * self.k * self.cin;
        let rows = (BAND_PIXELS / wo).max(1);
        let mut out = vec![0.0f32; ho * wo * self.cout];
        out.par_chunks_mut(rows * wo * self.cout)
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new()),
                |(col, tmp): &mut (Vec<f32>, Vec<f32>), (band, dst)| {
                    let m = dst.len() / self.cout;
                    col.resize(m * kk, 0.0);
                    let p0 = band * rows * wo;
                    for p in 0..m {
                        let (oy, ox) = ((p0 + p) / wo, (p0 + p) % wo);
                        let row = &mut col[p * kk..(p + 1) * kk];
                        for ky in 0..self.k {
                            let iy = (oy * self.stride + ky)
                                .saturating_sub(self.pad)
                                .min(x.h - 1);
                            let x0 = ox * self.stride;
                            if whole
                                && self.stride == 1
                                && x0 >= self.pad
                                && x0 + self.k - self.pad <= x.w
                            {
                                // Interior, stride 1: the k taps of this row are
                                // k·cin contiguous values; one copy instead of k.
                                let src = (iy * x.w + x0 - self.pad) * x.c;
                                let t = ky * self.k * self.cin;
                                let len = self.k * self.cin;
                                row[t..t + len].copy_from_slice(&x.d[src..src + len]);
                                continue;
                            }
                            for kx in 0..self.k {
                                let ix = (x0 + kx).saturating_sub(self.pad).min(x.w - 1);
                                let src = (iy * x.w + ix) * x.c;
                                let t = (ky * self.k + kx) * self.cin;
                                row[t..t + self.cin].copy_from_slice(&x.d[src..src + self.cin]);
                            }
                        }
                    }
                    let b = Mat {
                        data: wt,
                        ld: self.cout,
                    };
                    if self.cout < TRANSPOSE_BELOW {
                        tmp.resize(m * self.cout, 0.0);
                        sgemm_into_transposed(
                            m,
                            self.cout,
                            kk,
                            Mat { data: col, ld: kk },
                            b,
                            tmp,
                            m,
                        );
                        for (p, px) in dst.chunks_exact_mut(self.cout).enumerate() {
                            for (o, v) in px.iter_mut().enumerate() {
                                *v = tmp[o * m + p];
                            }
                        }
                    } else {
                        sgemm(
                            m,
                            self.cout,
                            kk,
                            Mat { data: col, ld: kk },
                            b,
                            dst,
                            self.cout,
                            false,
                            1,
                        );
                    }
                },
            );
        Hwc {
            h: ho,
            w: wo,
            c: self.cout,
            d: out,
        }
    }
}

/// `x − μ` per channel, with μ (f64) and the InstanceNorm scale `1/√(var + eps)`
/// (biased variance in f64 from the centred values, as the reference's two passes).
fn centred_with_stats(x: &Hwc, eps: f32) -> (Hwc, Vec<f64>, Vec<f32>) {
    let c = x.c;
    let n = (x.h * x.w) as f64;
    let add = |mut a: Vec<f64>, b: Vec<f64>| {
        a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
        a
    };
    let sum =
        x.d.par_chunks(c * EW_PIXELS)
            .map(|blk| {
                let mut acc = vec![0.0f64; c];
                for px in blk.chunks_exact(c) {
                    acc.iter_mut()
                        .zip(px)
                        .for_each(|(a, &v)| *a += f64::from(v));
                }
                acc
            })
            .reduce(|| vec![0.0; c], add);
    let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
    let mean32: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
    let mut d = vec![0.0f32; x.d.len()];
    let var = d
        .par_chunks_mut(c * EW_PIXELS)
        .zip(x.d.par_chunks(c * EW_PIXELS))
        .map(|(dst, src)| {
            let mut acc = vec![0.0f64; c];
            for (o, px) in dst.chunks_exact_mut(c).zip(src.chunks_exact(c)) {
                for (ch, (o, &v)) in o.iter_mut().zip(px).enumerate() {
                    *o = v - mean32[ch];
                    acc[ch] += (f64::from(v) - mean[ch]).powi(2);
                }
            }
            acc
        })
        .reduce(|| vec![0.0; c], add);
    let inv = var
        .iter()
        .map(|q| (1.0 / (q / n + f64::from(eps)).sqrt()) as f32)
        .collect();
    (Hwc { d, ..*x }, mean, inv)
}

/// Per output column of a packed conv, its response to the constant image
/// `value[ci]` (replicate padding keeps a constant image constant): `Σ_taps,ci w·value`.
fn constant_response(conv: &PackedConv, value: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0f64; conv.cout];
    for (r, row) in conv.wt.chunks_exact(conv.cout).enumerate() {
        let v = value[r % conv.cin];
        for (o, &w) in out.iter_mut().zip(row) {
            *o += f64::from(w) * v;
        }
    }
    out
}

fn concat(a: &Hwc, b: &Hwc) -> Hwc {
    let c = a.c + b.c;
    let mut d = vec![0.0f32; a.h * a.w * c];
    d.par_chunks_mut(c)
        .zip(a.d.par_chunks(a.c).zip(b.d.par_chunks(b.c)))
        .for_each(|(o, (x, y))| {
            o[..a.c].copy_from_slice(x);
            o[a.c..].copy_from_slice(y);
        });
    Hwc {
        h: a.h,
        w: a.w,
        c,
        d,
    }
}

/// `e^x` without a libm call, so element-wise loops vectorise: Cody–Waite
/// reduction `x = n·ln2 + r`, |r| ≤ ln2/2, and the Cephes `expf` polynomial
/// (relative error < 3e-7, tested against f64). `x` is clamped to
/// [−87, 88] (results stay normal); NaN stays NaN.
#[inline(always)]
fn exp_fast(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5·2^23: round to nearest by two adds
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let t = x * std::f32::consts::LOG2_E + MAGIC;
    let n = t - MAGIC;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.987_569_1e-4;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5;
    let e = 1.0 + r + r * r * p;
    // n sits in the low mantissa bits of t: 2^n from integer ops only (no
    // float → int conversion, which would keep the loop scalar).
    let n_bits = t.to_bits().wrapping_sub(MAGIC.to_bits());
    e * f32::from_bits(n_bits.wrapping_add(127) << 23)
}

#[inline(always)]
fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + exp_fast(-v))
}

/// One HA-Conv output value: `gate·leaky(feat) + inc`, `gate` already through the sigmoid.
#[inline(always)]
fn ha_mix(gate: f32, feat: f32, inc: f32, slope: f32) -> f32 {
    let b = if feat >= 0.0 { feat } else { feat * slope };
    gate * b + inc
}

/// One HA-Conv, packed: `sigmoid(gate(x))·leaky(feat(IN(x))) + cat(inc1b(inc1a(x)), inc2(x))`.
///
/// Every conv that reads `x` is one GEMM on the centred input `x − μ` (μ: the
/// per-channel mean InstanceNorm computes anyway). InstanceNorm is then only a
/// per-input-channel scale `1/σ`, folded into the `feat` weights per call, and
/// each other conv gets back its response to the constant image μ as a bias.
/// Centring keeps the products small, so a flat channel gives `feat` = 0
/// exactly, as in the reference.
#[derive(Debug, Clone)]
struct Ha {
    cout: usize,
    stride: usize,
    /// Stride-s GEMM on `x − μ`, columns `[inc1a (s = 1 only) | gate | inc2 | feat | down?]`.
    main: PackedConv,
    /// inc1a at stride 1 on `x` itself, when s ≠ 1.
    inc1a: Option<PackedConv>,
    inc1b: PackedConv,
    has_down: bool,
}

impl Ha {
    fn new(
        p: &Scope<'_>,
        cin: usize,
        cout: usize,
        stride: usize,
        down: Option<&[f32]>,
    ) -> Result<Self> {
        let g = p.get("gate.weight", &[cout, cin, 3, 3])?;
        let f = p.get("feat.weight", &[cout, cin, 3, 3])?;
        let i1a = p.get("inc1a.weight", &[cout, cin, 3, 3])?;
        let i1b = p.get("inc1b.weight", &[cout / 2, cout, 3, 3])?;
        let i2 = p.get("inc2.weight", &[cout / 2, cin, 3, 3])?;
        let mut parts: Vec<(&[f32], usize, usize)> = Vec::new();
        if stride == 1 {
            parts.push((i1a, cout, 3));
        }
        parts.push((g, cout, 3));
        parts.push((i2, cout / 2, 3));
        parts.push((f, cout, 3));
        if let Some(d) = down {
            parts.push((d, cout, 1));
        }
        Ok(Self {
            cout,
            stride,
            main: PackedConv::fused(&parts, cin, 3, stride),
            inc1a: (stride != 1).then(|| PackedConv::fused(&[(i1a, cout, 3)], cin, 3, 1)),
            inc1b: PackedConv::fused(&[(i1b, cout / 2, 3)], cout, 3, stride),
            has_down: down.is_some(),
        })
    }

    /// Returns (HA output, down-conv output without its bias if fused).
    /// `post(p, out)` finishes output pixel `p` in place (the block's
    /// BatchNorm, residual and ReLU), while the pixel is still in cache.
    fn run(
        &self,
        x: &Hwc,
        eps: f32,
        slope: f32,
        post: impl Fn(usize, &mut [f32]) + Sync,
    ) -> (Hwc, Option<Hwc>) {
        let (co, half) = (self.cout, self.cout / 2);
        let off = if self.stride == 1 { co } else { 0 };
        let feat0 = off + co + half;
        let (xc, mean, inv) = centred_with_stats(x, eps);
        // Columns other than feat: response to μ (feat sees x − μ only).
        let mut bias = constant_response(&self.main, &mean);
        bias[feat0..feat0 + co].fill(0.0);
        let mut wt = self.main.wt.clone();
        let cols = self.main.cout;
        for (r, row) in wt.chunks_exact_mut(cols).enumerate() {
            let s = inv[r % self.main.cin];
            row[feat0..feat0 + co].iter_mut().for_each(|w| *w *= s);
        }
        let main = self.main.run_with(&xc, &wt);
        let (c1b, c1b_bias) = match &self.inc1a {
            Some(c) => (self.inc1b.run(&c.run(x)), vec![0.0; half]),
            // inc1a without its bias sits in columns 0..co of `main` (read as a
            // view); inc1b of that constant bias image is again a constant.
            None => (
                self.inc1b.run(&main),
                constant_response(&self.inc1b, &bias[..co]),
            ),
        };
        let f32s = |v: &[f64]| -> Vec<f32> { v.iter().map(|&b| b as f32).collect() };
        let (bias, c1b_bias) = (f32s(&bias), f32s(&c1b_bias));
        let (h, w) = (main.h, main.w);
        let mut out = vec![0.0f32; h * w * co];
        const P: usize = EW_PIXELS;
        let (gate_b, inc2_b) = bias[off..feat0].split_at(co);
        out.par_chunks_mut(co * P)
            .zip(main.d.par_chunks(main.c * P))
            .zip(c1b.d.par_chunks(half * P))
            .enumerate()
            .for_each(|(chunk, ((o, m), c1))| {
                // gate + bias, then the sigmoid over the whole contiguous block
                // (a flat loop vectorises; a per-pixel one over `co` does not).
                for (o, m) in o.chunks_exact_mut(co).zip(m.chunks_exact(main.c)) {
                    for ((o, &g), &b) in o.iter_mut().zip(&m[off..off + co]).zip(gate_b) {
                        *o = g + b;
                    }
                }
                o.iter_mut().for_each(|v| *v = sigmoid(*v));
                let px = o
                    .chunks_exact_mut(co)
                    .zip(m.chunks_exact(main.c))
                    .zip(c1.chunks_exact(half));
                for (i, ((o, m), c1)) in px.enumerate() {
                    // Channels < half add inc1b, the rest inc2 (columns after the gate).
                    let (inc2, feat) = m[off + co..feat0 + co].split_at(half);
                    let (o_lo, o_hi) = o.split_at_mut(half);
                    let (f_lo, f_hi) = feat.split_at(half);
                    for k in 0..half {
                        o_lo[k] = ha_mix(o_lo[k], f_lo[k], c1[k] + c1b_bias[k], slope);
                        o_hi[k] = ha_mix(o_hi[k], f_hi[k], inc2[k] + inc2_b[k], slope);
                    }
                    post(chunk * P + i, o);
                }
            });
        let down = self.has_down.then(|| {
            let s = feat0 + co;
            let b = &bias[s..s + co];
            let mut d = vec![0.0f32; h * w * co];
            d.par_chunks_mut(co * P)
                .zip(main.d.par_chunks(main.c * P))
                .for_each(|(o, m)| {
                    for (o, m) in o.chunks_exact_mut(co).zip(m.chunks_exact(main.c)) {
                        for ((o, &v), &b) in o.iter_mut().zip(&m[s..s + co]).zip(b) {
                            *o = v + b;
                        }
                    }
                });
            Hwc { h, w, c: co, d }
        });
        (
            Hwc {
                h,
                w,
                c: co,
                d: out,
            },
            down,
        )
    }
}

#[derive(Debug, Clone)]
struct Basic {
    ha1: Ha,
    ha2: Ha,
    bn1: (Vec<f32>, Vec<f32>),
    bn2: (Vec<f32>, Vec<f32>),
    down_bias: Option<Vec<f32>>,
}

impl Basic {
    fn new(p: &Scope<'_>, cin: usize, cout: usize, stride: usize) -> Result<Self> {
        let down = if cin != cout || stride != 1 {
            Some((
                p.get("down.weight", &[cout, cin, 1, 1])?,
                p.get("down.bias", &[cout])?.to_vec(),
            ))
        } else {
            None
        };
        let bn = |n: &str| -> Result<(Vec<f32>, Vec<f32>)> {
            Ok((
                p.get(&format!("{n}.scale"), &[cout])?.to_vec(),
                p.get(&format!("{n}.shift"), &[cout])?.to_vec(),
            ))
        };
        Ok(Self {
            ha1: Ha::new(
                &p.scope("ha1"),
                cin,
                cout,
                stride,
                down.as_ref().map(|d| d.0),
            )?,
            ha2: Ha::new(&p.scope("ha2"), cout, cout, 1, None)?,
            bn1: bn("bn1")?,
            bn2: bn("bn2")?,
            down_bias: down.map(|d| d.1),
        })
    }

    fn run(&self, x: &Hwc, eps: f32, slope: f32) -> Hwc {
        let (s1, t1) = &self.bn1;
        let (y, down) = self.ha1.run(x, eps, slope, |_, px| {
            for ((v, s), t) in px.iter_mut().zip(s1).zip(t1) {
                *v = (*v * s + t).max(0.0);
            }
        });
        let co = y.c;
        let (s2, t2) = &self.bn2;
        // Identity branch: the fused 1×1 `down` conv plus its bias, or x itself.
        let zero = vec![0.0f32; co];
        let (id, bias) = match (&down, &self.down_bias) {
            (Some(d), Some(b)) => (&d.d, b),
            _ => (&x.d, &zero),
        };
        let (y, _) = self.ha2.run(&y, eps, slope, |p, px| {
            let id = &id[p * co..(p + 1) * co];
            for (k, v) in px.iter_mut().enumerate() {
                *v = (*v * s2[k] + t2[k] + id[k] + bias[k]).max(0.0);
            }
        });
        y
    }
}

/// ReverseBlock, packed: `up4` as four output-parity 2×2 sub-convolutions
/// (zero outside the input), `up2` as one GEMM to `[2·2·cout]` then scattered.
#[derive(Debug, Clone)]
#[allow(clippy::needless_range_loop)]
struct Reverse {
    cin: usize,
    cout: usize,
    /// Per parity (py, px): `[2·2·cin, cout]`, row `(ty·2 + tx)·cin + ci`.
    up4: [Vec<f32>; 4],
    up4_b: Vec<f32>,
    conv: PackedConv,
    conv_b: Vec<f32>,
    /// `[cin, 4·cout]`, column `(py·2 + px)·cout + co`.
    up2: Vec<f32>,
    up2_b: Vec<f32>,
}

/// For output parity p, the two input offsets and the kernel taps they use
/// (ConvTranspose2d k4 s2 p1: `o = 2i − 1 + k`).
const UP4_TAPS: [[(isize, usize); 2]; 2] = [[(-1, 3), (0, 1)], [(0, 2), (1, 0)]];

impl Reverse {
    fn new(p: &Scope<'_>, cin: usize, cout: usize) -> Result<Self> {
        let w4 = p.get("up4.weight", &[cin, cout, 4, 4])?;
        let w2 = p.get("up2.weight", &[cin, cout, 2, 2])?;
        let up4 = std::array::from_fn(|par| {
            let (py, px) = (par / 2, par % 2);
            let mut wt = vec![0.0f32; 4 * cin * cout];
            for ty in 0..2 {
                for tx in 0..2 {
                    let ky = UP4_TAPS[py][ty].1;
                    let kx = UP4_TAPS[px][tx].1;
                    for i in 0..cin {
                        for o in 0..cout {
                            wt[((ty * 2 + tx) * cin + i) * cout + o] =
                                w4[((i * cout + o) * 4 + ky) * 4 + kx];
                        }
                    }
                }
            }
            wt
        });
        let mut up2 = vec![0.0f32; cin * 4 * cout];
        for i in 0..cin {
            for o in 0..cout {
                for t in 0..4 {
                    up2[i * 4 * cout + t * cout + o] = w2[(i * cout + o) * 4 + t];
                }
            }
        }
        Ok(Self {
            cin,
            cout,
            up4,
            up4_b: p.get("up4.bias", &[cout])?.to_vec(),
            conv: PackedConv::fused(
                &[(p.get("conv.weight", &[cout, cout, 3, 3])?, cout, 3)],
                cout,
                3,
                1,
            ),
            conv_b: p.get("conv.bias", &[cout])?.to_vec(),
            up2,
            up2_b: p.get("up2.bias", &[cout])?.to_vec(),
        })
    }

    #[allow(clippy::needless_range_loop)]
    fn run(&self, x: &Hwc) -> Hwc {
        let (h, w, ci, co) = (x.h, x.w, self.cin, self.cout);
        let (ho, wo) = (2 * h, 2 * w);
        // up4 → relu, written to the parity positions.
        let mut y = vec![0.0f32; ho * wo * co];
        let kk = 4 * ci;
        let rows = (BAND_PIXELS / w).max(1);
        for par in 0..4 {
            let (py, px) = (par / 2, par % 2);
            let mut sub = vec![0.0f32; h * w * co];
            sub.par_chunks_mut(rows * w * co).enumerate().for_each_init(
                Vec::new,
                |col: &mut Vec<f32>, (band, dst)| {
                    let m = dst.len() / co;
                    col.clear();
                    col.resize(m * kk, 0.0);
                    let p0 = band * rows * w;
                    for p in 0..m {
                        let (iy, ix) = ((p0 + p) / w, (p0 + p) % w);
                        for ty in 0..2 {
                            let sy = iy as isize + UP4_TAPS[py][ty].0;
                            if sy < 0 || sy >= h as isize {
                                continue;
                            }
                            for tx in 0..2 {
                                let sx = ix as isize + UP4_TAPS[px][tx].0;
                                if sx < 0 || sx >= w as isize {
                                    continue;
                                }
                                let src = (sy as usize * w + sx as usize) * ci;
                                let t = p * kk + (ty * 2 + tx) * ci;
                                col[t..t + ci].copy_from_slice(&x.d[src..src + ci]);
                            }
                        }
                    }
                    sgemm(
                        m,
                        co,
                        kk,
                        Mat { data: col, ld: kk },
                        Mat {
                            data: &self.up4[par],
                            ld: co,
                        },
                        dst,
                        co,
                        false,
                        1,
                    );
                },
            );
            // Output rows of parity py take input row oy / 2, pixels of parity px.
            y.par_chunks_mut(wo * co)
                .skip(py)
                .step_by(2)
                .zip(sub.par_chunks(w * co))
                .for_each(|(row, src)| {
                    for (ix, v) in src.chunks_exact(co).enumerate() {
                        let o = &mut row[(2 * ix + px) * co..(2 * ix + px + 1) * co];
                        for ((o, &v), &b) in o.iter_mut().zip(v).zip(&self.up4_b) {
                            *o = (v + b).max(0.0);
                        }
                    }
                });
        }
        let mut y = self.conv.run(&Hwc {
            h: ho,
            w: wo,
            c: co,
            d: y,
        });
        // up2: [h·w, 4·co], scattered and added with both biases, then relu.
        let mut u = vec![0.0f32; h * w * 4 * co];
        u.par_chunks_mut(BAND_PIXELS * 4 * co)
            .enumerate()
            .for_each(|(band, dst)| {
                let m = dst.len() / (4 * co);
                let p0 = band * BAND_PIXELS;
                sgemm(
                    m,
                    4 * co,
                    ci,
                    Mat {
                        data: &x.d[p0 * ci..(p0 + m) * ci],
                        ld: ci,
                    },
                    Mat {
                        data: &self.up2,
                        ld: 4 * co,
                    },
                    dst,
                    4 * co,
                    false,
                    1,
                );
            });
        y.d.par_chunks_mut(wo * co)
            .enumerate()
            .for_each(|(oy, row)| {
                let (iy, py) = (oy / 2, oy % 2);
                for ox in 0..wo {
                    let (ix, px) = (ox / 2, ox % 2);
                    let src = ((iy * w + ix) * 4 + py * 2 + px) * co;
                    for k in 0..co {
                        let v = &mut row[ox * co + k];
                        *v = (*v + self.conv_b[k] + u[src + k] + self.up2_b[k]).max(0.0);
                    }
                }
            });
        y
    }
}

/// `M_est` on the CPU, packed for the fast path.
#[derive(Debug, Clone)]
pub struct UNet {
    in_channels: usize,
    /// The head sees `[decoder output, network input]` (`ModelConfig::input_skip`).
    input_skip: bool,
    params: usize,
    eps: f32,
    slope: f32,
    stem: PackedConv,
    enc: Vec<Basic>,
    dec1: (Reverse, Basic),
    dec2: (Reverse, Basic),
    dec3: (Reverse, Basic),
    dec4: (Basic, Basic),
    head: PackedConv,
}

impl UNet {
    /// Packs the `est.*` tensors of validated weights.
    pub fn new(weights: &Weights) -> Result<Self> {
        let cfg = weights.config();
        let c = cfg.width;
        let est = weights.scope("est");
        let mut enc = Vec::new();
        let mut prev = c;
        for (k, w) in [c, 2 * c, 4 * c, 8 * c].into_iter().enumerate() {
            let s = if k == 0 { 1 } else { 2 };
            enc.push(Basic::new(
                &est.scope(&format!("enc{}.0", k + 1)),
                prev,
                w,
                s,
            )?);
            enc.push(Basic::new(&est.scope(&format!("enc{}.1", k + 1)), w, w, 1)?);
            prev = w;
        }
        Ok(Self {
            in_channels: cfg.in_channels,
            input_skip: cfg.input_skip,
            params: cfg.param_channels,
            eps: cfg.norm_eps,
            slope: cfg.slopes.ha,
            stem: PackedConv::fused(
                &[(est.get("stem.weight", &[c, cfg.in_channels, 7, 7])?, c, 7)],
                cfg.in_channels,
                7,
                1,
            ),
            enc,
            dec1: (
                Reverse::new(&est.scope("dec1.0"), 8 * c, 8 * c)?,
                Basic::new(&est.scope("dec1.1"), 8 * c, 8 * c, 1)?,
            ),
            dec2: (
                Reverse::new(&est.scope("dec2.0"), 12 * c, 4 * c)?,
                Basic::new(&est.scope("dec2.1"), 4 * c, 4 * c, 1)?,
            ),
            dec3: (
                Reverse::new(&est.scope("dec3.0"), 6 * c, 2 * c)?,
                Basic::new(&est.scope("dec3.1"), 2 * c, 2 * c, 1)?,
            ),
            dec4: (
                Basic::new(&est.scope("dec4.0"), 3 * c, c, 1)?,
                Basic::new(&est.scope("dec4.1"), c, c, 1)?,
            ),
            head: PackedConv::fused(
                &[(
                    est.get(
                        "head.weight",
                        &[cfg.param_channels, cfg.head_in_channels(), 7, 7],
                    )?,
                    cfg.param_channels,
                    7,
                )],
                cfg.head_in_channels(),
                7,
                1,
            ),
        })
    }

    /// Runs `M_est` on the network input (CHW, `in_channels × height × width`,
    /// docs/FORMAT.md) and returns the param map (HWC). Any size: the input is
    /// replicate-padded bottom/right to a multiple of 8 and the output cropped.
    pub fn estimate(&self, input: &[f32], height: usize, width: usize) -> Result<ParamMap> {
        check_image(height, width)?;
        let ci = self.in_channels;
        check_len("network input", ci * height * width, input.len())?;
        check_finite("network input", input)?;
        let (hp, wp) = (pad_multiple(height), pad_multiple(width));
        let mut d = vec![0.0f32; hp * wp * ci];
        for y in 0..hp {
            for x in 0..wp {
                for c in 0..ci {
                    d[(y * wp + x) * ci + c] =
                        input[(c * height + y.min(height - 1)) * width + x.min(width - 1)];
                }
            }
        }
        let (eps, sl) = (self.eps, self.slope);
        let photo = Hwc {
            h: hp,
            w: wp,
            c: ci,
            d,
        };
        let stem = self.stem.run(&photo);
        // Encoder outputs e1..e4; e1..e3 are the decoder's skips.
        let mut skips: Vec<Hwc> = Vec::with_capacity(4);
        for pair in self.enc.chunks_exact(2) {
            let input = skips.last().unwrap_or(&stem);
            let y = pair[1].run(&pair[0].run(input, eps, sl), eps, sl);
            skips.push(y);
        }
        let mut x = skips.pop().expect("four encoder levels");
        x.d.iter_mut().for_each(|v| *v = v.atan());
        let x = self.dec1.1.run(&self.dec1.0.run(&x), eps, sl);
        let x = self
            .dec2
            .1
            .run(&self.dec2.0.run(&concat(&x, &skips[2])), eps, sl);
        let x = self
            .dec3
            .1
            .run(&self.dec3.0.run(&concat(&x, &skips[1])), eps, sl);
        let x = self
            .dec4
            .1
            .run(&self.dec4.0.run(&concat(&x, &skips[0]), eps, sl), eps, sl);
        let out = if self.input_skip {
            self.head.run(&concat(&x, &photo))
        } else {
            self.head.run(&x)
        };
        let pc = self.params;
        let data = if (height, width) == (hp, wp) {
            out.d
        } else {
            let mut data = Vec::with_capacity(height * width * pc);
            for y in 0..height {
                data.extend_from_slice(&out.d[y * wp * pc..(y * wp + width) * pc]);
            }
            data
        };
        Ok(ParamMap {
            height,
            width,
            channels: pc,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative error bound of [`exp_fast`] (the polynomial's, plus f32 rounding).
    const EXP_REL_TOL: f64 = 3e-7;

    #[test]
    fn exp_fast_matches_f64_exp_over_its_range_and_clamps_beyond() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -87.0 + 175.0 * i as f32 / 200_000.0;
            let want = f64::from(x).exp();
            worst = worst.max((f64::from(exp_fast(x)) - want).abs() / want);
        }
        assert!(worst < EXP_REL_TOL, "worst relative error {worst:e}");
        assert_eq!(exp_fast(-1e30), exp_fast(-87.0));
        assert_eq!(exp_fast(1e30), exp_fast(88.0));
        assert!(exp_fast(88.0).is_finite() && exp_fast(-87.0) > 0.0);
        assert!(exp_fast(f32::NAN).is_nan());
        assert_eq!(sigmoid(0.0), 0.5);
        assert!(sigmoid(-200.0) < 1e-37 && sigmoid(200.0) == 1.0);
    }
}
