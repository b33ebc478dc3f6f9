//! The convolution primitives of the fast `M_est`: HWC activations, k×k convolutions packed
//! as GEMM operands (im2col over bands of output rows), InstanceNorm statistics, concatenation
//! and the vectorisable `exp`/sigmoid of the element-wise passes.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::{amx_conv, direct, winograd};
use crate::sgemm::{Mat, sgemm, sgemm_into_transposed};

/// Output pixels per GEMM band: enough rows for the GEMM kernel, small enough
/// that the im2col band stays in cache.
pub(super) const BAND_PIXELS: usize = 512;

/// Pixels per rayon task in element-wise passes.
pub(super) const EW_PIXELS: usize = 1024;

/// Convolutions with fewer output channels than this run their GEMM with the
/// pixel dimension along the SIMD lanes (16 f32 per AVX-512 register).
pub(super) const TRANSPOSE_BELOW: usize = 16;

/// An HWC activation: `d[(y·w + x)·c + ch]`.
#[derive(Debug, Clone)]
pub(super) struct Hwc {
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) c: usize,
    pub(super) d: Vec<f32>,
}

/// A vector of `n` values that `write` writes in place, not zeroed first (zeroing an output
/// that a kernel then overwrites is a pass over memory for nothing), and what `write` returns.
/// One home for the unsafe step of every such output.
///
/// # Safety
/// `write` writes every one of the `n` values; the vector is then read as initialised.
#[allow(unsafe_code)]
pub(super) unsafe fn written<R>(
    n: usize,
    write: impl FnOnce(&mut [MaybeUninit<f32>]) -> R,
) -> (Vec<f32>, R) {
    let mut v = Vec::with_capacity(n);
    let r = write(&mut v.spare_capacity_mut()[..n]);
    // SAFETY: the caller's contract: `write` wrote the `n` values.
    unsafe { v.set_len(n) };
    (v, r)
}

/// [`written`] for two vectors of `n` values, the second only where `second` (the outputs of
/// one pass that writes both).
///
/// # Safety
/// As [`written`], for each vector.
#[allow(unsafe_code)]
pub(super) unsafe fn written_pair<R>(
    n: usize,
    second: bool,
    write: impl FnOnce(&mut [MaybeUninit<f32>], Option<&mut [MaybeUninit<f32>]>) -> R,
) -> (Vec<f32>, Option<Vec<f32>>, R) {
    let mut b = second.then(|| Vec::with_capacity(n));
    let both =
        |a: &mut [MaybeUninit<f32>]| write(a, b.as_mut().map(|b| &mut b.spare_capacity_mut()[..n]));
    // SAFETY: the caller's contract: `write` wrote the `n` values of the first vector.
    let (a, r) = unsafe { written(n, both) };
    if let Some(b) = b.as_mut() {
        // SAFETY: the caller's contract: `write` wrote the `n` values of the second.
        unsafe { b.set_len(n) };
    }
    (a, b, r)
}

/// A k×k convolution (or several fused along the output channels) packed as
/// the GEMM right-hand side `[k·k·cin, cout]`, row index `(ky·k + kx)·cin + ci`.
#[derive(Debug, Clone)]
pub(super) struct PackedConv {
    pub(super) k: usize,
    pub(super) stride: usize,
    pub(super) pad: usize,
    pub(super) cin: usize,
    pub(super) cout: usize,
    pub(super) wt: Vec<f32>,
    /// bf16 products, f32 sums ([`super::UNet::with_bf16`]; direct convolution only).
    pub(super) bf16: bool,
    /// Winograd where it pays ([`super::winograd::applies`]; cleared by
    /// [`super::UNet::without_winograd`]).
    pub(super) winograd: bool,
}

/// A conv's weights prepared for the kernel that runs it ([`PackedConv::prepare`]).
pub(super) enum Prepared<'a> {
    /// bf16 pairs for the AMX tiles.
    Amx(Vec<crate::simd::Line>),
    /// Transformed for Winograd, one GEMM operand per point.
    Winograd(Vec<direct::Gemm>),
    /// Packed as [`PackedConv::wt`]; each kernel repacks them per call (cheap beside the
    /// products).
    Packed(&'a [f32]),
}

impl PackedConv {
    /// Fuses convs over the same input; each part is `(weight [co, cin, kp, kp], co, kp)`
    /// with `kp == k` or `kp == 1` (a 1×1 conv placed at the centre tap; valid
    /// because pad = k/2 makes the centre tap read exactly the 1×1 conv's pixel).
    pub(super) fn fused(
        parts: &[(&[f32], usize, usize)],
        cin: usize,
        k: usize,
        stride: usize,
    ) -> Self {
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
            bf16: false,
            winograd: true,
        }
    }

    /// Replicate-padded convolution (no bias) of the first `cin` channels of
    /// `x` (`x.c` may be wider: a view of a fused GEMM's leading columns).
    pub(super) fn run(&self, x: &Hwc) -> Hwc {
        self.run_with(x, &self.wt)
    }

    /// Like [`Self::run`], with `wt` (same packing as `self.wt`) as weights.
    pub(super) fn run_with(&self, x: &Hwc, wt: &[f32]) -> Hwc {
        self.run_rows(x, wt, 0..self.out_size(x).0)
    }

    /// Output `(height, width)` of this conv on `x`.
    pub(super) fn out_size(&self, x: &Hwc) -> (usize, usize) {
        (
            (x.h + 2 * self.pad - self.k) / self.stride + 1,
            (x.w + 2 * self.pad - self.k) / self.stride + 1,
        )
    }

    /// Output rows `rows` of [`Self::run_with`] (an `Hwc` of `rows.len()` rows): the same
    /// values, computed without the rest of the output. bf16 products on AMX tiles where the CPU
    /// has them ([`amx_conv`]). Otherwise, where the CPU has AVX-512F/VL: Winograd
    /// F(4×4, 3×3) for the stride-1 f32 convs wide and large enough to gain from it
    /// ([`winograd::applies`]), else a direct convolution (faster than im2col at every width
    /// here, 4 outputs included: docs/perf/unet_cpu.md); elsewhere im2col + GEMM.
    pub(super) fn run_rows(&self, x: &Hwc, wt: &[f32], rows: std::ops::Range<usize>) -> Hwc {
        self.run_prepared(x, &self.prepare((x.h, x.w), wt), rows)
    }

    /// The weights `wt` as the kernel that runs this conv on inputs of `size` (height, width)
    /// reads them, for any number of [`Self::run_prepared`] calls: packed once for AMX,
    /// transformed once for Winograd, else as they are.
    pub(super) fn prepare<'a>(&self, size: (usize, usize), wt: &'a [f32]) -> Prepared<'a> {
        if self.bf16 && amx_conv::available() {
            Prepared::Amx(amx_conv::pack_weights(self, wt))
        } else if winograd::applies(self, size) {
            Prepared::Winograd(winograd::transform_weights(self, wt))
        } else {
            Prepared::Packed(wt)
        }
    }

    /// [`Self::run_rows`] with weights from [`Self::prepare`] (for inputs of about `x`'s size:
    /// the size only chooses the faster kernel).
    pub(super) fn run_prepared(
        &self,
        x: &Hwc,
        wt: &Prepared<'_>,
        rows: std::ops::Range<usize>,
    ) -> Hwc {
        match *wt {
            Prepared::Amx(ref w) => amx_conv::run_rows(self, x, w, rows),
            Prepared::Winograd(ref gemms) => winograd::run_rows(self, x, gemms, rows),
            Prepared::Packed(wt) if direct::available() => {
                direct::run_rows(self, x, wt, rows, self.bf16)
            }
            Prepared::Packed(wt) => self.im2col_rows(x, wt, rows),
        }
    }

    /// [`Self::run_rows`] as im2col over bands of output rows + GEMM.
    pub(super) fn im2col_rows(&self, x: &Hwc, wt: &[f32], rows: std::ops::Range<usize>) -> Hwc {
        debug_assert!(self.cin <= x.c);
        debug_assert_eq!(wt.len(), self.wt.len());
        let whole = x.c == self.cin;
        let (ho, wo) = self.out_size(x);
        debug_assert!(rows.end <= ho);
        let first = rows.start * wo;
        let ho = rows.len();
        let kk = self.k * self.k * self.cin;
        let rows = (BAND_PIXELS / wo).max(1);
        let mut out = vec![0.0f32; ho * wo * self.cout];
        out.par_chunks_mut(rows * wo * self.cout)
            .with_min_len(min_len())
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new()),
                |(col, tmp): &mut (Vec<f32>, Vec<f32>), (band, dst)| {
                    let m = dst.len() / self.cout;
                    col.resize(m * kk, 0.0);
                    let p0 = first + band * rows * wo;
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

std::thread_local! {
    /// Set while [`on_this_thread`] runs: the parallel loops of the convolutions and
    /// element-wise passes then run on the calling thread ([`min_len`]).
    static ON_THIS_THREAD: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// The `with_min_len` of every parallel loop of the U-Net: 1 (rayon splits as it likes), or
/// inside [`on_this_thread`] all of the loop (one job, on the calling thread).
pub(super) fn min_len() -> usize {
    if alone() { usize::MAX } else { 1 }
}

/// True inside [`on_this_thread`]: the U-Net's parallel loops run on the calling thread alone.
pub(super) fn alone() -> bool {
    ON_THIS_THREAD.get()
}

/// Runs `f` with the U-Net's parallel loops on the calling thread: for work that is already one
/// of several parallel tasks (the bands of an HA-Conv), so that a thread never waits inside one
/// task for another's help and meanwhile starts a further task, holding both tasks' buffers.
pub(super) fn on_this_thread<R>(f: impl FnOnce() -> R) -> R {
    /// Restores the flag when `f` returns or unwinds.
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            ON_THIS_THREAD.set(self.0);
        }
    }
    let _restore = Restore(ON_THIS_THREAD.replace(true));
    f()
}

/// Runs `f` compiled for AVX-512 (512-bit vectors) where the CPU has AVX-512F/VL/BW/DQ and FMA,
/// else as it is: the element-wise passes are plain loops, which the default x86-64 target
/// vectorises 4 lanes wide. The same values either way (Rust never contracts a multiply and an
/// add into an FMA, nor reorders float sums). Call it inside each parallel task: the closure is
/// inlined into the AVX-512 function and compiled there.
#[inline(always)]
pub(super) fn wide<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if direct::available()
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512dq")
        && std::arch::is_x86_feature_detected!("fma")
    {
        #[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq,avx2,fma")]
        #[inline]
        fn run<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        // SAFETY: the features were checked just above (AVX-512F implies AVX2).
        #[allow(unsafe_code)]
        return unsafe { run(f) };
    }
    f()
}

/// `x − μ` per channel, with μ (f64) and the InstanceNorm scale `1/√(var + eps)`
/// (biased variance in f64 from the centred values, as the reference's two passes).
pub(super) fn centred_with_stats(x: &Hwc, eps: f32) -> (Hwc, Vec<f64>, Vec<f32>) {
    let c = x.c;
    let n = (x.h * x.w) as f64;
    let add = |mut a: Vec<f64>, b: Vec<f64>| {
        a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
        a
    };
    let sum =
        x.d.par_chunks(c * EW_PIXELS)
            .with_min_len(min_len())
            .map(|blk| {
                wide(
                    #[inline(always)]
                    || block_sums(Group::of(c), blk, c),
                )
            })
            .reduce(|| vec![0.0; c], add);
    let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
    let mean32: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
    let fill = |d: &mut [MaybeUninit<f32>]| {
        d.par_chunks_mut(c * EW_PIXELS)
            .with_min_len(min_len())
            .zip(x.d.par_chunks(c * EW_PIXELS))
            .map(|(dst, src)| {
                wide(
                    #[inline(always)]
                    || {
                        let mut acc = vec![0.0f64; c];
                        block_centre(Group::of(c), src, dst, (&mean32, &mean), &mut acc);
                        acc
                    },
                )
            })
            .reduce(|| vec![0.0; c], add)
    };
    // SAFETY: the blocks cover the values, and `block_centre` writes each of its block's.
    #[allow(unsafe_code)]
    let (d, var) = unsafe { written(x.d.len(), fill) };
    let inv = var
        .iter()
        .map(|q| (1.0 / (q / n + f64::from(eps)).sqrt()) as f32)
        .collect();
    (Hwc { d, ..*x }, mean, inv)
}

/// Channels summed together in registers by [`block_sums`] and [`block_centre`]: 8, 4 or 2
/// where `c` is a multiple, else 1.
#[derive(Clone, Copy)]
enum Group {
    Of8,
    Of4,
    Of2,
    Of1,
}

impl Group {
    /// The widest group that divides `c`.
    fn of(c: usize) -> Self {
        match c {
            _ if c.is_multiple_of(8) => Self::Of8,
            _ if c.is_multiple_of(4) => Self::Of4,
            _ if c.is_multiple_of(2) => Self::Of2,
            _ => Self::Of1,
        }
    }
}

/// Per channel, the f64 sum over the pixels of `blk` (`c` channels each), in pixel order.
#[inline(always)]
fn block_sums(g: Group, blk: &[f32], c: usize) -> Vec<f64> {
    #[inline(always)]
    fn run<const G: usize>(blk: &[f32], c: usize) -> Vec<f64> {
        let mut out = vec![0.0f64; c];
        for g0 in (0..c).step_by(G) {
            // One group's sums stay in registers across the pixels.
            let mut acc = [0.0f64; G];
            for px in blk.chunks_exact(c) {
                for (a, &v) in acc.iter_mut().zip(&px[g0..g0 + G]) {
                    *a += f64::from(v);
                }
            }
            out[g0..g0 + G].copy_from_slice(&acc);
        }
        out
    }
    match g {
        Group::Of8 => run::<8>(blk, c),
        Group::Of4 => run::<4>(blk, c),
        Group::Of2 => run::<2>(blk, c),
        Group::Of1 => run::<1>(blk, c),
    }
}

/// Writes `src − μ` (`mean`: μ as f32 and f64) into `dst` and adds each channel's
/// `Σ (src − μ)²` (f64, in pixel order) to `acc`.
#[inline(always)]
fn block_centre(
    g: Group,
    src: &[f32],
    dst: &mut [MaybeUninit<f32>],
    mean: (&[f32], &[f64]),
    acc: &mut [f64],
) {
    #[inline(always)]
    fn run<const G: usize>(
        src: &[f32],
        dst: &mut [MaybeUninit<f32>],
        (mean32, mean): (&[f32], &[f64]),
        out: &mut [f64],
    ) {
        let c = out.len();
        for g0 in (0..c).step_by(G) {
            let r = g0..g0 + G;
            let m32: [f32; G] = mean32[r.clone()].try_into().expect("G means");
            let m: [f64; G] = mean[r.clone()].try_into().expect("G means");
            let mut acc = [0.0f64; G];
            for (o, px) in dst.chunks_exact_mut(c).zip(src.chunks_exact(c)) {
                // Whole groups as arrays, so the loop runs in vector registers.
                let v: [f32; G] = px[r.clone()].try_into().expect("G values");
                let o: &mut [MaybeUninit<f32>; G] =
                    (&mut o[r.clone()]).try_into().expect("G values");
                *o = std::array::from_fn(|j| MaybeUninit::new(v[j] - m32[j]));
                for j in 0..G {
                    acc[j] += (f64::from(v[j]) - m[j]).powi(2);
                }
            }
            out[r].copy_from_slice(&acc);
        }
    }
    match g {
        Group::Of8 => run::<8>(src, dst, mean, acc),
        Group::Of4 => run::<4>(src, dst, mean, acc),
        Group::Of2 => run::<2>(src, dst, mean, acc),
        Group::Of1 => run::<1>(src, dst, mean, acc),
    }
}

/// Per output column of a packed conv, its response to the constant image
/// `value[ci]` (replicate padding keeps a constant image constant): `Σ_taps,ci w·value`.
pub(super) fn constant_response(conv: &PackedConv, value: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0f64; conv.cout];
    for (r, row) in conv.wt.chunks_exact(conv.cout).enumerate() {
        let v = value[r % conv.cin];
        for (o, &w) in out.iter_mut().zip(row) {
            *o += f64::from(w) * v;
        }
    }
    out
}

pub(super) fn concat(a: &Hwc, b: &Hwc) -> Hwc {
    let c = a.c + b.c;
    let mut d = vec![0.0f32; a.h * a.w * c];
    d.par_chunks_mut(c * EW_PIXELS)
        .with_min_len(min_len())
        .zip(
            a.d.par_chunks(a.c * EW_PIXELS)
                .zip(b.d.par_chunks(b.c * EW_PIXELS)),
        )
        .for_each(|(o, (x, y))| {
            wide(
                #[inline(always)]
                || {
                    let px = o
                        .chunks_exact_mut(c)
                        .zip(x.chunks_exact(a.c).zip(y.chunks_exact(b.c)));
                    for (o, (x, y)) in px {
                        o[..a.c].copy_from_slice(x);
                        o[a.c..].copy_from_slice(y);
                    }
                },
            )
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
pub(super) fn exp_fast(x: f32) -> f32 {
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
pub(super) fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + exp_fast(-v))
}

/// One HA-Conv output value: `gate·leaky(feat) + inc`, `gate` already through the sigmoid.
#[inline(always)]
pub(super) fn ha_mix(gate: f32, feat: f32, inc: f32, slope: f32) -> f32 {
    let b = if feat >= 0.0 { feat } else { feat * slope };
    gate * b + inc
}

/// Deterministic convolutions and inputs for the kernel tests (`direct.rs`, `winograd.rs`).
#[cfg(test)]
pub(super) mod fixtures {
    use super::{Hwc, PackedConv};

    /// The direct and AMX paths sum the same products as im2col + GEMM in another order: f32
    /// rounding, relative to the magnitude of the output (or 1).
    pub(in super::super) const DIRECT_TOL: f32 = 2e-5;

    fn det(i: usize, salt: usize) -> f32 {
        ((i * 7919 + salt * 104_729) % 2003) as f32 / 2003.0 - 0.5
    }

    /// A k×k conv (`cin → cout`, stride `s`, padding k/2; weights in [−0.5, 0.5)) and an
    /// `h × w` input with `xc ≥ cin` channels (values in [−1.5, 1.5)), both from `salt`.
    pub(in super::super) fn case(
        (k, s, cin, xc, cout): (usize, usize, usize, usize, usize),
        (h, w): (usize, usize),
        salt: usize,
    ) -> (PackedConv, Hwc) {
        let conv = PackedConv {
            k,
            stride: s,
            pad: k / 2,
            cin,
            cout,
            wt: (0..k * k * cin * cout).map(|i| det(i, salt)).collect(),
            bf16: false,
            winograd: true,
        };
        let d = (0..h * w * xc).map(|i| 3.0 * det(i, salt + 17)).collect();
        (conv, Hwc { h, w, c: xc, d })
    }

    /// Kernel test shapes `(k, stride, cin, x.c, cout, h, w)`: 3×3 and 7×7, stride 1 and 2, odd
    /// channel counts, a view of wider channels, rows narrower than a register tile, every
    /// column-group shape of the direct tiles.
    pub(in super::super) const CASES: [(usize, usize, usize, usize, usize, usize, usize); 10] = [
        (3, 1, 8, 8, 36, 19, 23),
        (3, 1, 4, 36, 4, 9, 5),
        (3, 2, 16, 16, 72, 16, 18),
        (3, 2, 5, 5, 24, 7, 3),
        (7, 1, 13, 13, 64, 12, 30),
        (7, 1, 5, 5, 8, 11, 2),
        (3, 1, 24, 24, 160, 6, 13),
        (3, 1, 3, 3, 17, 1, 1),
        (3, 1, 8, 8, 12, 5, 40),
        (3, 2, 8, 8, 88, 9, 31),
    ];

    /// `v` rounded to bf16 (as f32): the operands whose bf16 products are exact in f32.
    pub(in super::super) fn round_bf16(v: &[f32]) -> Vec<f32> {
        v.iter()
            .map(|&v| f32::from_bits(crate::bf16::to_bf16(v) << 16))
            .collect()
    }

    /// Largest `|got − want|` relative to the magnitude of `want` (or 1).
    pub(in super::super) fn worst_rel(got: &Hwc, want: &Hwc) -> f32 {
        assert_eq!((got.h, got.w, got.c), (want.h, want.w, want.c));
        want.d
            .iter()
            .zip(&got.d)
            .map(|(a, b)| (a - b).abs() / a.abs().max(1.0))
            .fold(0.0f32, f32::max)
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
