//! Opt-in bf16 dense layers for `M_render` on CPUs with AVX-512 BF16
//! (`vdpbf16ps`: bf16 products, f32 accumulation). Weights and activations are
//! rounded to bf16 (8-bit mantissa) right before each product; sums, biases and
//! activations stay f32. About twice the f32 throughput on Zen 4, for a small
//! loss of accuracy (see the `bf16_relight_is_close_to_f32` test). On CPUs with
//! AMX-BF16 (Xeon Sapphire Rapids and later, where `vdpbf16ps` is slower than
//! f32) the same products run on the matrix unit ([`crate::amx`]).
#![allow(unsafe_code)]
// Elsewhere `bf16_supported()` is false and no layer is built: the kernels are x86-64 code.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

use crate::amx;
#[cfg(target_arch = "x86_64")]
use crate::simd::{self, Line};

/// Rows of the microkernel (activations) and columns (two 16-lane registers).
const MR: usize = 8;
const NR: usize = 32;

/// True when this CPU runs the bf16 kernel.
pub fn bf16_supported() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The instructions the bf16 paths (the dense layers and the U-Net's convolutions) run on
/// this CPU: `"AMX tiles"` or
/// `"AVX-512 BF16"` (meaningful where [`bf16_supported`]).
pub fn bf16_kernel() -> &'static str {
    if amx::available() {
        "AMX tiles"
    } else {
        "AVX-512 BF16"
    }
}

/// f32 → bf16 bits, round to nearest even (finite inputs; NaN is never passed).
#[inline(always)]
pub(crate) fn to_bf16(v: f32) -> u32 {
    let b = v.to_bits();
    (b.wrapping_add(0x7FFF + ((b >> 16) & 1))) >> 16
}

/// A dense layer `y = act(x · Wᵀ)` with W packed as bf16 pairs along k:
/// `wp[p·out_pad + o] = W[o, 2p] | W[o, 2p+1] << 16`.
#[derive(Debug, Clone)]
pub(crate) struct Bf16Dense {
    inp: usize,
    out: usize,
    out_pad: usize,
    /// On whole cache lines ([`Line`]): each row of `out_pad` pairs starts a line.
    wp: Vec<Line>,
    slope: Option<f32>,
    /// Products on AMX tiles ([`amx::matmul`]) instead of `vdpbf16ps`.
    amx: bool,
}

impl Bf16Dense {
    /// From W `[out, inp]` row-major (a LeakyReLU `slope` lies in [0, 1]); AMX tiles where the
    /// CPU has them.
    pub fn new(w: &[f32], out: usize, inp: usize, slope: Option<f32>) -> Self {
        Self::with_kernel(w, out, inp, slope, amx::available())
    }

    /// As [`Self::new`], with the kernel chosen by the caller (`amx` only where
    /// [`amx::available`]).
    fn with_kernel(w: &[f32], out: usize, inp: usize, slope: Option<f32>, amx: bool) -> Self {
        // The kernel computes LeakyReLU as max(v, slope·v).
        assert!(
            slope.is_none_or(|s| (0.0..=1.0).contains(&s)),
            "LeakyReLU slope {slope:?}"
        );
        // AMX reads whole tiles: k padded to 16 pairs, columns to 32 (= NR).
        let kp = inp.div_ceil(2).div_ceil(amx::K_PAIRS) * amx::K_PAIRS;
        let out_pad = out.div_ceil(NR.max(amx::N_BLOCK)) * NR.max(amx::N_BLOCK);
        let mut wp = Vec::new();
        let packed = simd::filled(&mut wp, kp * out_pad, 0);
        for o in 0..out {
            for i in 0..inp {
                let bits = to_bf16(w[o * inp + i]);
                packed[(i / 2) * out_pad + o] |= bits << (16 * (i % 2));
            }
        }
        Self {
            inp,
            out,
            out_pad,
            wp,
            slope,
            amx,
        }
    }

    /// Output width.
    pub fn out(&self) -> usize {
        self.out
    }

    /// `y[m×out] (ld ldy) = act(x[m×inp] (ld ldx) · Wᵀ)`; `pairs` is scratch.
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        m: usize,
        x: &[f32],
        ldx: usize,
        y: &mut [f32],
        ldy: usize,
        pairs: &mut Vec<Line>,
    ) {
        let kp = self.inp.div_ceil(2);
        // Row stride of the packed pairs and padded row count of each kernel.
        let (stride, m_pad) = if self.amx {
            (
                kp.div_ceil(amx::K_PAIRS) * amx::K_PAIRS,
                m.div_ceil(amx::M_BLOCK) * amx::M_BLOCK,
            )
        } else {
            (kp, m.div_ceil(MR) * MR)
        };
        let pairs = simd::filled(pairs, m_pad * stride, 0);
        for r in 0..m {
            let row = &x[r * ldx..r * ldx + self.inp];
            let dst = &mut pairs[r * stride..r * stride + kp];
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the bf16 path exists only where `bf16_supported()` (AVX-512 BF16/BW/VL);
            // `dst` holds ⌈inp/2⌉ pairs.
            unsafe {
                pack_row_avx512(row, dst);
            }
            #[cfg(not(target_arch = "x86_64"))]
            for (p, d) in dst.iter_mut().enumerate() {
                let lo = to_bf16(row[2 * p]);
                let hi = row.get(2 * p + 1).map_or(0, |&v| to_bf16(v));
                *d = lo | (hi << 16);
            }
        }
        assert!(y.len() >= m.saturating_sub(1) * ldy + self.out && ldy >= self.out);
        #[cfg(target_arch = "x86_64")]
        if self.amx {
            let slope = self.slope;
            // SAFETY: `amx` is set only when `amx::available()`; `pairs` holds
            // m_pad·stride values and `wp` stride·out_pad (padded in `with_kernel`).
            unsafe {
                amx::matmul(
                    m,
                    stride,
                    pairs,
                    self.out,
                    self.out_pad,
                    simd::words(&self.wp),
                    y,
                    ldy,
                    |v| match slope {
                        Some(s) if v < 0.0 => v * s,
                        _ => v,
                    },
                );
            }
        } else {
            // SAFETY: callers construct the bf16 path only when `bf16_supported()`;
            // all indices below stay inside `pairs` (m_pad·kp) and `wp` (kp·out_pad).
            unsafe {
                self.kernel(m, m_pad, kp, pairs, y, ldy);
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512bf16")]
    #[allow(clippy::needless_range_loop)]
    fn kernel(&self, m: usize, m_pad: usize, kp: usize, a: &[u32], y: &mut [f32], ldy: usize) {
        use std::arch::x86_64::*;
        for j0 in (0..self.out_pad).step_by(NR) {
            for i0 in (0..m_pad).step_by(MR) {
                let mut acc = [[_mm512_setzero_ps(); 2]; MR];
                let rows: [&[u32]; MR] =
                    std::array::from_fn(|r| &a[(i0 + r) * kp..(i0 + r + 1) * kp]);
                for p in 0..kp {
                    let wrow =
                        &simd::words(&self.wp)[p * self.out_pad + j0..p * self.out_pad + j0 + NR];
                    // SAFETY: `wrow` has NR = 32 u32 values = two 512-bit vectors.
                    let (b0, b1) = unsafe {
                        (
                            _mm512_loadu_si512(wrow.as_ptr().cast()),
                            _mm512_loadu_si512(wrow.as_ptr().add(16).cast()),
                        )
                    };
                    let (b0, b1): (__m512bh, __m512bh) = (
                        unsafe { std::mem::transmute::<__m512i, __m512bh>(b0) },
                        unsafe { std::mem::transmute::<__m512i, __m512bh>(b1) },
                    );
                    for r in 0..MR {
                        let av = _mm512_set1_epi32(rows[r][p] as i32);
                        let av: __m512bh = unsafe { std::mem::transmute::<__m512i, __m512bh>(av) };
                        acc[r][0] = _mm512_dpbf16_ps(acc[r][0], av, b0);
                        acc[r][1] = _mm512_dpbf16_ps(acc[r][1], av, b1);
                    }
                }
                let cols = (self.out - j0.min(self.out)).min(NR);
                let slope = _mm512_set1_ps(self.slope.unwrap_or(1.0));
                for r in 0..MR.min(m.saturating_sub(i0)) {
                    for (h, &v) in acc[r].iter().enumerate() {
                        let mask = simd::lanes(cols.saturating_sub(16 * h));
                        if mask == 0 {
                            continue;
                        }
                        // SAFETY: masked to the `cols` real columns of row i0 + r.
                        unsafe {
                            let dst = y.as_mut_ptr().add((i0 + r) * ldy + j0 + 16 * h);
                            simd::store_leaky(dst, mask, v, slope);
                        }
                    }
                }
            }
        }
    }
}

/// One activation row as bf16 pairs (`dst[p] = bf16(x[2p]) | bf16(x[2p+1]) << 16`, the odd
/// tail padded with 0): in memory the row's bf16 values in order, sixteen per conversion
/// (`vcvtneps2bf16`, round to nearest even as [`to_bf16`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
#[inline]
pub(crate) fn pack_row_avx512(row: &[f32], dst: &mut [u32]) {
    use std::arch::x86_64::*;
    let n = row.len();
    let out = dst.as_mut_ptr().cast::<i16>();
    for i in (0..n).step_by(16) {
        let mask = simd::lanes(n - i);
        // SAFETY: loads and stores are masked to the row's `n` values; `dst` holds ⌈n/2⌉ u32
        // = at least n bf16, and its padding half stays 0.
        unsafe {
            let v = _mm512_maskz_loadu_ps(mask, row.as_ptr().add(i));
            let b: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(v));
            _mm256_mask_storeu_epi16(out.add(i), mask, b);
        }
    }
}

/// [`pack_row_avx512`] for each of the pixels of `dst` (`cp` pairs each): pixel `i` reads the
/// `2·cp` or `2·cp − 1` values from `src[i·stride]`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
pub(crate) fn pack_pixels_avx512(src: &[f32], stride: usize, cin: usize, dst: &mut [u32]) {
    let cp = cin.div_ceil(2);
    for (i, d) in dst.chunks_exact_mut(cp).enumerate() {
        pack_row_avx512(&src[i * stride..i * stride + cin], d);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative difference allowed between the AMX and `vdpbf16ps` kernels: the
    /// same bf16 products, f32 sums in another order (297 terms).
    const KERNEL_TOL: f32 = 1e-5;

    /// Deterministic values in [-1, 1).
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    #[test]
    fn vector_packing_rounds_as_the_scalar_conversion() {
        if !bf16_supported() {
            eprintln!("skipped: this CPU has no AVX-512 BF16");
            return;
        }
        // Odd and even lengths, below and above one vector; ties and large/small magnitudes.
        for n in [1, 15, 16, 17, 297, 594] {
            let mut row = values(n, n as u64);
            row.iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v *= 10f32.powi(i as i32 % 9 - 4));
            row[0] = f32::from_bits(0x3F80_8000); // halfway between two bf16: ties to even
            let mut got = vec![0u32; n.div_ceil(2)];
            // SAFETY: bf16_supported() checked above.
            unsafe { pack_row_avx512(&row, &mut got) };
            let want: Vec<u32> = (0..n.div_ceil(2))
                .map(|p| to_bf16(row[2 * p]) | row.get(2 * p + 1).map_or(0, |&v| to_bf16(v)) << 16)
                .collect();
            assert_eq!(got, want, "n = {n}");
        }
    }

    #[test]
    fn amx_kernel_matches_the_avx512_bf16_kernel() {
        if !(bf16_supported() && amx::available()) {
            eprintln!("skipped: this CPU has no AMX-BF16 (or the OS did not grant the tile state)");
            return;
        }
        // ND_enc's first layer and the render output layer; row counts that do
        // not fill a 32-row block; a padded output stride.
        for (inp, out, m, slope) in [
            (297, 594, 37, Some(0.01)),
            (64, 3, 70, None),
            (128, 128, 5, Some(0.01)),
        ] {
            let w = values(out * inp, inp as u64);
            let x = values(m * inp, 7 + m as u64);
            let ldy = out + 3;
            let run = |amx: bool| {
                let layer = Bf16Dense::with_kernel(&w, out, inp, slope, amx);
                let mut y = vec![f32::NAN; m * ldy];
                layer.forward(m, &x, inp, &mut y, ldy, &mut Vec::new());
                y
            };
            let (tiles, vectors) = (run(true), run(false));
            let scale = vectors
                .iter()
                .fold(0.0f32, |a, v| if v.is_nan() { a } else { a.max(v.abs()) });
            for r in 0..m {
                for o in 0..out {
                    let (a, b) = (tiles[r * ldy + o], vectors[r * ldy + o]);
                    assert!(
                        (a - b).abs() <= KERNEL_TOL * scale,
                        "{inp}→{out} row {r} col {o}: {a} vs {b}"
                    );
                }
                // The padding between rows is never written.
                assert!(
                    tiles[r * ldy + out..(r + 1) * ldy]
                        .iter()
                        .all(|v| v.is_nan())
                );
            }
        }
    }
}
