//! The blocks of the fast `M_est`, built on the primitives of `conv.rs`: the packed HA-Conv,
//! the BasicBlock (two HA-Convs, BatchNorm, residual) and the ReverseBlock (transposed convs
//! split into output-parity sub-convolutions).

use std::mem::MaybeUninit;

use nam_weights::Scope;
use rayon::prelude::*;

use super::conv::{
    BAND_PIXELS, EW_PIXELS, Hwc, PackedConv, centred_with_stats, constant_response, ha_mix,
    min_len, on_this_thread, sigmoid, wide, written, written_pair,
};
use crate::bf16::Bf16Dense;
use crate::error::Result;
use crate::sgemm::{Mat, sgemm};
use crate::simd::Line;

/// One HA-Conv, packed: `sigmoid(gate(x))·leaky(feat(IN(x))) + cat(inc1b(inc1a(x)), inc2(x))`.
///
/// Every conv that reads `x` is one GEMM on the centred input `x − μ` (μ: the
/// per-channel mean InstanceNorm computes anyway). InstanceNorm is then only a
/// per-input-channel scale `1/σ`, folded into the `feat` weights per call, and
/// each other conv gets back its response to the constant image μ as a bias.
/// Centring keeps the products small, so a flat channel gives `feat` = 0
/// exactly, as in the reference.
#[derive(Debug, Clone)]
pub(super) struct Ha {
    pub(super) cout: usize,
    pub(super) stride: usize,
    /// Stride-s GEMM on `x − μ`, columns `[inc1a (s = 1 only) | gate | inc2 | feat | down?]`.
    pub(super) main: PackedConv,
    /// inc1a at stride 1 on `x` itself, when s ≠ 1.
    pub(super) inc1a: Option<PackedConv>,
    pub(super) inc1b: PackedConv,
    pub(super) has_down: bool,
    /// Pixels per band of the stride-1 path ([`HA_BAND_PIXELS`]; tests make it small).
    pub(super) band_pixels: usize,
}

impl Ha {
    pub(super) fn new(
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
            band_pixels: HA_BAND_PIXELS,
        })
    }

    /// Its convolutions, for [`super::UNet::with_bf16`].
    pub(super) fn convs_mut(&mut self) -> Vec<&mut PackedConv> {
        let mut v = vec![&mut self.main, &mut self.inc1b];
        v.extend(self.inc1a.as_mut());
        v
    }

    /// Returns (HA output, down-conv output without its bias if fused).
    /// `post(p, out)` finishes output pixel `p` in place (the block's
    /// BatchNorm, residual and ReLU), while the pixel is still in cache.
    pub(super) fn run(
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
        let f32s = |v: &[f64]| -> Vec<f32> { v.iter().map(|&b| b as f32).collect() };
        let (h, w) = self.main.out_size(x);
        // At stride 2 allocated once the centred copy is gone, so the two are not held together.
        // Not zeroed: the mix writes every value (`Mix::run`).
        let n = h * w * co;
        let mix = Mix {
            cols,
            co,
            off,
            bias: f32s(&bias),
            slope,
        };
        let (out, down, ()) = match &self.inc1a {
            // Stride 2 (the first block of a level): the output has a quarter of the input's
            // pixels, so it runs in one piece.
            Some(c) => {
                let main = self.main.run_with(&xc, &wt);
                drop(xc);
                let c1b = self.inc1b.run(&c.run(x));
                let c1b_bias = vec![0.0; half];
                let fill = |o: &mut [MaybeUninit<f32>], d: Option<&mut [MaybeUninit<f32>]>| {
                    mix.run(&main.d, &c1b.d, &c1b_bias, 0, o, d, &post);
                };
                // SAFETY: `Mix::run` writes every value of its output and of `down`.
                #[allow(unsafe_code)]
                unsafe {
                    written_pair(n, self.has_down, fill)
                }
            }
            // Stride 1: the fused GEMM and inc1b run over bands of output rows, the bands in
            // parallel, so their 7·C/2 + C/2 columns are never held for the whole image and are
            // read back from cache. inc1b (3×3) reads inc1a one row beyond the band: those halo
            // rows are computed too, and inc1b's replicate padding at a band edge only touches
            // halo outputs, which are dropped.
            None => {
                // inc1a without its bias sits in columns 0..co of `main` (read as a view);
                // inc1b of that constant bias image is again a constant.
                let c1b_bias = f32s(&constant_response(&self.inc1b, &bias[..co]));
                // At least two bands per thread where the image has the rows (each band runs on
                // one thread), at most `band_pixels` pixels each.
                let threads = rayon::current_num_threads();
                let band = (self.band_pixels / w).clamp(1, h.div_ceil(2 * threads).max(1));
                let main_wt = self.main.prepare((h, w), &wt);
                // inc1b reads a band's GEMM output: `band` rows and the halo.
                let inc1b_wt = self.inc1b.prepare(((band + 2).min(h), w), &self.inc1b.wt);
                // One band on one thread: the fused GEMM of its rows (and a halo row either
                // side), inc1b, the mix, while its GEMM output is still in cache.
                let run_band =
                    |y0: usize, o: &mut [MaybeUninit<f32>], d: Option<&mut [MaybeUninit<f32>]>| {
                        on_this_thread(|| {
                            let y1 = (y0 + band).min(h);
                            let (a, b) = (y0.saturating_sub(1), (y1 + 1).min(h));
                            let main = self.main.run_prepared(&xc, &main_wt, a..b);
                            let c1b = self.inc1b.run_prepared(&main, &inc1b_wt, 0..main.h);
                            let rows = (y0 - a) * w..(y1 - a) * w;
                            mix.run(
                                &main.d[rows.start * cols..rows.end * cols],
                                &c1b.d[rows.start * half..rows.end * half],
                                &c1b_bias,
                                y0 * w,
                                o,
                                d,
                                &post,
                            );
                        })
                    };
                let chunk = band * w * co;
                let fill = |o: &mut [MaybeUninit<f32>], d: Option<&mut [MaybeUninit<f32>]>| match d
                {
                    Some(d) => o
                        .par_chunks_mut(chunk)
                        .zip(d.par_chunks_mut(chunk))
                        .enumerate()
                        .for_each(|(i, (o, d))| run_band(i * band, o, Some(d))),
                    None => o
                        .par_chunks_mut(chunk)
                        .enumerate()
                        .for_each(|(i, o)| run_band(i * band, o, None)),
                };
                // SAFETY: the bands cover the `n` values, and `Mix::run` writes every value of
                // its band's output and `down`.
                #[allow(unsafe_code)]
                unsafe {
                    written_pair(n, self.has_down, fill)
                }
            }
        };
        let hwc = |d| Hwc { h, w, c: co, d };
        (hwc(out), down.map(hwc))
    }
}

/// Pixels per band of a stride-1 HA-Conv: its GEMM output (0.9 MB at C = 8, 1.8 MB at C = 16)
/// stays in a core's L2 until inc1b and the mix have read it. Bands run in parallel; the halo
/// rows cost 2 GEMM rows a band (measured: 8192 pixels beat 4096, 16384 and one band for the
/// whole image, docs/perf/unet_cpu.md).
pub(super) const HA_BAND_PIXELS: usize = 1 << 13;

/// The element-wise end of an HA-Conv over a run of pixels: gate, InstanceNorm'd feat, inc
/// branches and the fused `down`, from the fused GEMM's columns.
struct Mix {
    /// Columns of the fused GEMM: `[inc1a (s = 1 only) | gate | inc2 | feat | down?]`.
    cols: usize,
    co: usize,
    /// Column of the gate (`co` at stride 1, after inc1a; else 0).
    off: usize,
    /// Per column: the response to the mean image (0 for feat).
    bias: Vec<f32>,
    slope: f32,
}

impl Mix {
    /// Writes the HA output (then `post(first + i, px)`) and `down` for the pixels of `main`
    /// (`cols` values each) and `c1b` (inc1b without its bias, `co/2` each).
    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        main: &[f32],
        c1b: &[f32],
        c1b_bias: &[f32],
        first: usize,
        out: &mut [MaybeUninit<f32>],
        down: Option<&mut [MaybeUninit<f32>]>,
        post: &(impl Fn(usize, &mut [f32]) + Sync),
    ) {
        let (co, cols, off) = (self.co, self.cols, self.off);
        // Every output pixel has its GEMM row: the chunks below pair up and write every value.
        assert_eq!(
            out.len() / co,
            main.len() / cols,
            "one GEMM row per output pixel"
        );
        let half = co / 2;
        let feat0 = off + co + half;
        const P: usize = EW_PIXELS;
        out.par_chunks_mut(co * P)
            .with_min_len(min_len())
            .zip(main.par_chunks(cols * P))
            .zip(c1b.par_chunks(half * P))
            .enumerate()
            .for_each(|(chunk, ((o, m), c1))| {
                let at = first + chunk * P;
                // The common widths as constants, so the per-pixel loops unroll into whole
                // vectors (`CO = 0`: any width).
                wide(
                    #[inline(always)]
                    || match co {
                        8 => self.pixels::<8>(co, at, o, m, c1, c1b_bias, post),
                        16 => self.pixels::<16>(co, at, o, m, c1, c1b_bias, post),
                        32 => self.pixels::<32>(co, at, o, m, c1, c1b_bias, post),
                        64 => self.pixels::<64>(co, at, o, m, c1, c1b_bias, post),
                        _ => self.pixels::<0>(co, at, o, m, c1, c1b_bias, post),
                    },
                )
            });
        if let Some(d) = down {
            let s = feat0 + co;
            let b = &self.bias[s..s + co];
            d.par_chunks_mut(co * P)
                .with_min_len(min_len())
                .zip(main.par_chunks(cols * P))
                .for_each(|(o, m)| {
                    wide(
                        #[inline(always)]
                        || {
                            for (o, m) in o.chunks_exact_mut(co).zip(m.chunks_exact(cols)) {
                                for ((o, &v), &b) in o.iter_mut().zip(&m[s..s + co]).zip(b) {
                                    o.write(v + b);
                                }
                            }
                        },
                    )
                });
        }
    }

    /// [`Self::run`] for one block of pixels, the first of them pixel `first`: `co` output
    /// channels (`CO` when it is not 0, a constant the loops unroll to).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn pixels<const CO: usize>(
        &self,
        co: usize,
        first: usize,
        o: &mut [MaybeUninit<f32>],
        m: &[f32],
        c1: &[f32],
        c1b_bias: &[f32],
        post: &(impl Fn(usize, &mut [f32]) + Sync),
    ) {
        let co = if CO > 0 { CO } else { co };
        let (cols, off, slope) = (self.cols, self.off, self.slope);
        let half = co / 2;
        let feat0 = off + co + half;
        let (gate_b, inc2_b) = self.bias[off..feat0].split_at(co);
        // gate + bias, then the sigmoid over the whole contiguous block
        // (a flat loop vectorises; a per-pixel one over `co` does not).
        assert_eq!(
            o.len() / co,
            m.len() / cols,
            "one GEMM row per output pixel"
        );
        for (o, m) in o.chunks_exact_mut(co).zip(m.chunks_exact(cols)) {
            for ((o, &g), &b) in o.iter_mut().zip(&m[off..off + co]).zip(gate_b) {
                o.write(g + b);
            }
        }
        // SAFETY: the loop above wrote every value of `o` (whole pixels: `o` and `m` hold
        // the same number).
        #[allow(unsafe_code)]
        let o = unsafe { &mut *(std::ptr::from_mut(o) as *mut [f32]) };
        o.iter_mut().for_each(|v| *v = sigmoid(*v));
        let px = o
            .chunks_exact_mut(co)
            .zip(m.chunks_exact(cols))
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
            post(first + i, o);
        }
    }
}

#[derive(Debug, Clone)]
pub(super) struct Basic {
    pub(super) ha1: Ha,
    pub(super) ha2: Ha,
    pub(super) bn1: (Vec<f32>, Vec<f32>),
    pub(super) bn2: (Vec<f32>, Vec<f32>),
    pub(super) down_bias: Option<Vec<f32>>,
}

impl Basic {
    pub(super) fn new(p: &Scope<'_>, cin: usize, cout: usize, stride: usize) -> Result<Self> {
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

    /// Its convolutions, for [`super::UNet::with_bf16`].
    pub(super) fn convs_mut(&mut self) -> Vec<&mut PackedConv> {
        let mut v = self.ha1.convs_mut();
        v.extend(self.ha2.convs_mut());
        v
    }

    pub(super) fn run(&self, x: &Hwc, eps: f32, slope: f32) -> Hwc {
        let (s1, t1) = &self.bn1;
        // The post closures are inlined into the mix, which runs compiled for AVX-512 where
        // the CPU has it (`conv::wide`).
        let (y, down) = self.ha1.run(
            x,
            eps,
            slope,
            #[inline(always)]
            |_, px| {
                for ((v, s), t) in px.iter_mut().zip(s1).zip(t1) {
                    *v = (*v * s + t).max(0.0);
                }
            },
        );
        let co = y.c;
        let (s2, t2) = &self.bn2;
        // Identity branch: the fused 1×1 `down` conv plus its bias, or x itself.
        let zero = vec![0.0f32; co];
        let (id, bias) = match (&down, &self.down_bias) {
            (Some(d), Some(b)) => (&d.d, b),
            _ => (&x.d, &zero),
        };
        let (y, _) = self.ha2.run(
            &y,
            eps,
            slope,
            #[inline(always)]
            |p, px| {
                let id = &id[p * co..(p + 1) * co];
                let terms = s2.iter().zip(t2).zip(id).zip(bias);
                for (v, (((s, t), i), b)) in px.iter_mut().zip(terms) {
                    *v = (*v * s + t + i + b).max(0.0);
                }
            },
        );
        y
    }
}

/// ReverseBlock, packed: `up4` as four output-parity 2×2 sub-convolutions
/// (zero outside the input), `up2` as one GEMM to `[2·2·cout]` then scattered.
#[derive(Debug, Clone)]
#[allow(clippy::needless_range_loop)]
pub(super) struct Reverse {
    pub(super) cin: usize,
    pub(super) cout: usize,
    /// Per parity (py, px): `[2·2·cin, cout]`, row `(ty·2 + tx)·cin + ci`.
    pub(super) up4: [Vec<f32>; 4],
    pub(super) up4_b: Vec<f32>,
    pub(super) conv: PackedConv,
    pub(super) conv_b: Vec<f32>,
    /// `[cin, 4·cout]`, column `(py·2 + px)·cout + co`.
    pub(super) up2: Vec<f32>,
    pub(super) up2_b: Vec<f32>,
    /// `up4` and `up2` with bf16 products and f32 sums ([`Self::set_bf16`]).
    bf16: Option<Box<ReverseBf16>>,
}

/// The GEMMs of a [`Reverse`] as bf16 dense layers (AMX tiles where the CPU has them).
#[derive(Debug, Clone)]
struct ReverseBf16 {
    up4: [Bf16Dense; 4],
    up2: Bf16Dense,
}

/// For output parity p, the two input offsets and the kernel taps they use
/// (ConvTranspose2d k4 s2 p1: `o = 2i − 1 + k`).
pub(super) const UP4_TAPS: [[(isize, usize); 2]; 2] = [[(-1, 3), (0, 1)], [(0, 2), (1, 0)]];

impl Reverse {
    pub(super) fn new(p: &Scope<'_>, cin: usize, cout: usize) -> Result<Self> {
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
            bf16: None,
        })
    }

    /// bf16 products and f32 sums in `up4` and `up2` (`on`), or f32 again; its 3×3 conv follows
    /// its own flag. Only where [`crate::bf16_supported`].
    pub(super) fn set_bf16(&mut self, on: bool) {
        // Bf16Dense takes W as [out, inp]: the transpose of the GEMMs' [inp, out].
        let dense = |wt: &[f32], inp: usize, out: usize| {
            let t: Vec<f32> = (0..out * inp)
                .map(|i| wt[(i % inp) * out + i / inp])
                .collect();
            Bf16Dense::new(&t, out, inp, None)
        };
        let (ci, co) = (self.cin, self.cout);
        self.bf16 = on.then(|| {
            Box::new(ReverseBf16 {
                up4: std::array::from_fn(|p| dense(&self.up4[p], 4 * ci, co)),
                up2: dense(&self.up2, ci, 4 * co),
            })
        });
    }

    #[allow(clippy::needless_range_loop)]
    pub(super) fn run(&self, x: &Hwc) -> Hwc {
        let (h, w, ci, co) = (x.h, x.w, self.cin, self.cout);
        let (ho, wo) = (2 * h, 2 * w);
        // up4 → relu, written to the parity positions.
        let kk = 4 * ci;
        let rows = (BAND_PIXELS / w).max(1);
        let fill = |y: &mut [MaybeUninit<f32>]| {
            for par in 0..4 {
                let (py, px) = (par / 2, par % 2);
                let mut sub = vec![0.0f32; h * w * co];
                sub.par_chunks_mut(rows * w * co)
                    .with_min_len(min_len())
                    .enumerate()
                    .for_each_init(
                        || (Vec::new(), Vec::new()),
                        |(col, pairs): &mut (Vec<f32>, Vec<Line>), (band, dst)| {
                            let m = dst.len() / co;
                            // Not zeroed first: every tap is written below, the ones outside the
                            // image as zeros.
                            col.resize(m * kk, 0.0);
                            let p0 = band * rows * w;
                            for p in 0..m {
                                let (iy, ix) = ((p0 + p) / w, (p0 + p) % w);
                                for ty in 0..2 {
                                    let sy = iy as isize + UP4_TAPS[py][ty].0;
                                    for tx in 0..2 {
                                        let sx = ix as isize + UP4_TAPS[px][tx].0;
                                        let t = p * kk + (ty * 2 + tx) * ci;
                                        let tap = &mut col[t..t + ci];
                                        if (0..h as isize).contains(&sy)
                                            && (0..w as isize).contains(&sx)
                                        {
                                            let src = (sy as usize * w + sx as usize) * ci;
                                            tap.copy_from_slice(&x.d[src..src + ci]);
                                        } else {
                                            tap.fill(0.0);
                                        }
                                    }
                                }
                            }
                            if let Some(b) = &self.bf16 {
                                b.up4[par].forward(m, col, kk, dst, co, pairs);
                                return;
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
                    .with_min_len(min_len())
                    .skip(py)
                    .step_by(2)
                    .zip(sub.par_chunks(w * co))
                    .for_each(|(row, src)| {
                        wide(
                            #[inline(always)]
                            || {
                                for (ix, v) in src.chunks_exact(co).enumerate() {
                                    let o = &mut row[(2 * ix + px) * co..(2 * ix + px + 1) * co];
                                    for ((o, &v), &b) in o.iter_mut().zip(v).zip(&self.up4_b) {
                                        o.write((v + b).max(0.0));
                                    }
                                }
                            },
                        )
                    });
            }
        };
        // SAFETY: parity (py, px) writes every output pixel (oy, ox) with oy ≡ py and ox ≡ px
        // (mod 2): the four write each value once.
        #[allow(unsafe_code)]
        let (y, ()) = unsafe { written(ho * wo * co, fill) };
        let mut y = self.conv.run(&Hwc {
            h: ho,
            w: wo,
            c: co,
            d: y,
        });
        // up2: [h·w, 4·co], scattered and added with both biases, then relu.
        let mut u = vec![0.0f32; h * w * 4 * co];
        u.par_chunks_mut(BAND_PIXELS * 4 * co)
            .with_min_len(min_len())
            .enumerate()
            .for_each_init(Vec::new, |pairs, (band, dst)| {
                let m = dst.len() / (4 * co);
                let p0 = band * BAND_PIXELS;
                let a = &x.d[p0 * ci..(p0 + m) * ci];
                if let Some(b) = &self.bf16 {
                    b.up2.forward(m, a, ci, dst, 4 * co, pairs);
                    return;
                }
                sgemm(
                    m,
                    4 * co,
                    ci,
                    Mat { data: a, ld: ci },
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
            .with_min_len(min_len())
            .enumerate()
            .for_each(|(oy, row)| {
                wide(
                    #[inline(always)]
                    || {
                        let (iy, py) = (oy / 2, oy % 2);
                        for (ox, o) in row.chunks_exact_mut(co).enumerate() {
                            let (ix, px) = (ox / 2, ox % 2);
                            let src = ((iy * w + ix) * 4 + py * 2 + px) * co;
                            let terms = self.conv_b.iter().zip(&u[src..src + co]).zip(&self.up2_b);
                            for (v, ((c, u), b)) in o.iter_mut().zip(terms) {
                                *v = (*v + c + u + b).max(0.0);
                            }
                        }
                    },
                )
            });
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nam_weights::{ModelConfig, Weights};

    /// Band edges change only which rows one GEMM call covers, so the summation order of a
    /// product may differ (the GEMM kernel depends on the call's size): f32 rounding.
    const BAND_TOL: f32 = 1e-5;

    #[test]
    fn banded_ha_conv_matches_one_band_at_band_edges_and_image_borders() {
        let weights = Weights::random(ModelConfig::standard(8), 11).unwrap();
        let est = weights.scope("est");
        // dec4.0: 24 → 8 channels with the fused 1×1 down; dec4.1: 8 → 8 without.
        for (scope, cin, cout) in [("dec4.0", 24, 8), ("dec4.1", 8, 8)] {
            let block = Basic::new(&est.scope(scope), cin, cout, 1).unwrap();
            let (h, w) = (37, 23);
            let x = Hwc {
                h,
                w,
                c: cin,
                d: (0..h * w * cin)
                    .map(|i| ((i * 7919 % 1009) as f32 / 1009.0 - 0.3) * 2.0)
                    .collect(),
            };
            let post = |p: usize, px: &mut [f32]| px.iter_mut().for_each(|v| *v += p as f32 * 1e-3);
            let (whole, whole_down) = block.ha1.run(&x, 1e-5, 0.01, post);
            for rows in [1, 2, 5, 36] {
                let mut ha = block.ha1.clone();
                ha.band_pixels = rows * w;
                let (banded, banded_down) = ha.run(&x, 1e-5, 0.01, post);
                let worst = whole
                    .d
                    .iter()
                    .zip(&banded.d)
                    .map(|(a, b)| (a - b).abs() / a.abs().max(1.0))
                    .fold(0.0f32, f32::max);
                assert!(worst < BAND_TOL, "{scope}, {rows} rows a band: {worst:e}");
                assert_eq!(whole_down.is_some(), banded_down.is_some());
                if let (Some(a), Some(b)) = (&whole_down, &banded_down) {
                    assert!(
                        a.d.iter()
                            .zip(&b.d)
                            .all(|(a, b)| (a - b).abs() <= BAND_TOL * a.abs().max(1.0))
                    );
                }
            }
        }
    }

    #[test]
    fn mix_with_a_constant_width_equals_the_any_width_loop() {
        // A stride-1 HA-Conv's columns: [inc1a | gate | inc2 | feat], co = 16.
        let (co, half) = (16, 8);
        let cols = 3 * co + half;
        let mix = Mix {
            cols,
            co,
            off: co,
            bias: (0..cols).map(|i| (i as f32 * 0.37).sin()).collect(),
            slope: 0.01,
        };
        let n = 37;
        let m: Vec<f32> = (0..n * cols)
            .map(|i| (i as f32 * 0.11).cos() * 3.0)
            .collect();
        let c1: Vec<f32> = (0..n * half).map(|i| (i as f32 * 0.23).sin()).collect();
        let c1b_bias: Vec<f32> = (0..half).map(|i| i as f32 * 0.1 - 0.4).collect();
        let post =
            |p: usize, px: &mut [f32]| px.iter_mut().for_each(|v| *v = (*v + p as f32).max(0.0));
        let run = |constant: bool| {
            let mut o = vec![MaybeUninit::new(f32::NAN); n * co];
            if constant {
                mix.pixels::<16>(co, 5, &mut o, &m, &c1, &c1b_bias, &post);
            } else {
                mix.pixels::<0>(co, 5, &mut o, &m, &c1, &c1b_bias, &post);
            }
            // SAFETY: initialised (NaN, then the mix's values).
            #[allow(unsafe_code)]
            o.into_iter()
                .map(|v| unsafe { v.assume_init() })
                .collect::<Vec<f32>>()
        };
        let (a, b) = (run(true), run(false));
        assert!(a.iter().any(|&v| v > 0.0) && a.iter().all(|v| v.is_finite()));
        assert_eq!(a, b);
    }
}
