//! Opt-in int8 dense layers for `M_render` on CPUs with AVX-512 VNNI
//! (`vpdpbusd`: u8 × s8 products summed four at a time into i32).
//!
//! Quantisation (symmetric, scales in f32):
//! * weights per output channel `o`: `w_q = round(W[o, i] / s_o)`, `s_o = max_i |W[o, i]| / 127`;
//! * activations per row `r`, at run time: `x_q = round(x / t_r)`, `t_r = max_i |x[r, i]| / 127`,
//!   stored as `x_q + 128` (u8, what `vpdpbusd` multiplies) — the offset is taken back out
//!   exactly with the precomputed column sums: `Σ (x_q + 128)·w_q − 128·Σ w_q = Σ x_q·w_q`.
//!
//! `y[r, o] = act(t_r · s_o · Σ_i x_q·w_q)`: integer sums are exact, so the kernel and the scalar
//! reference ([`Int8Dense::forward_reference`]) agree bit for bit; the error against f32 is the
//! rounding of both operands to 8 bits (see the tests and the report's int8 row).
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use crate::simd::{self, Line};

/// Rows of the microkernel (activations) and columns (two 16-lane registers).
const MR: usize = 8;
const NR: usize = 32;
/// k values per packed `u32` (one `vpdpbusd` lane).
const QUAD: usize = 4;
/// Largest quantised magnitude (symmetric range `[-127, 127]`).
const QMAX: f32 = 127.0;
/// The u8 offset of a quantised activation.
const OFFSET: i32 = 128;

/// True when this CPU runs the int8 kernel (AVX-512 VNNI).
pub fn int8_supported() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A dense layer `y = act(x · Wᵀ)` with W quantised per output channel and packed four k
/// values per `u32`: `wq[p·out_pad + o]` holds `W_q[o, 4p..4p+4]` (byte j = k index 4p + j).
#[derive(Debug, Clone)]
pub(crate) struct Int8Dense {
    inp: usize,
    out: usize,
    out_pad: usize,
    /// On whole cache lines ([`Line`]): each row of `out_pad` quads starts a line.
    wq: Vec<Line>,
    /// `s_o` per output column (`out_pad`, zero in the padding).
    scale: Vec<f32>,
    /// `128 · Σ_i W_q[o, i]` per output column (`out_pad`).
    offset_sum: Vec<i32>,
    slope: Option<f32>,
}

impl Int8Dense {
    /// From W `[out, inp]` row-major; a LeakyReLU `slope` lies in [0, 1] (the kernel computes
    /// it as `max(v, slope·v)`).
    pub fn new(w: &[f32], out: usize, inp: usize, slope: Option<f32>) -> Self {
        assert!(
            slope.is_none_or(|s| (0.0..=1.0).contains(&s)),
            "LeakyReLU slope {slope:?}"
        );
        let quads = inp.div_ceil(QUAD);
        let out_pad = out.div_ceil(NR) * NR;
        let mut wq = Vec::new();
        let packed = simd::filled(&mut wq, quads * out_pad, 0);
        let mut scale = vec![0.0f32; out_pad];
        let mut offset_sum = vec![0i32; out_pad];
        for o in 0..out {
            let row = &w[o * inp..(o + 1) * inp];
            let s = row.iter().fold(0.0f32, |m, v| m.max(v.abs())) / QMAX;
            scale[o] = s;
            let inv = if s > 0.0 { 1.0 / s } else { 0.0 };
            for (i, &v) in row.iter().enumerate() {
                let q = (v * inv).round().clamp(-QMAX, QMAX) as i8;
                offset_sum[o] += OFFSET * i32::from(q);
                packed[(i / QUAD) * out_pad + o] |= u32::from(q as u8) << (8 * (i % QUAD));
            }
        }
        Self {
            inp,
            out,
            out_pad,
            wq,
            scale,
            offset_sum,
            slope,
        }
    }

    /// Output width.
    pub fn out(&self) -> usize {
        self.out
    }

    /// `y[m×out] (ld ldy) = act(x[m×inp] (ld ldx) · Wᵀ)` on the VNNI kernel; `packed` is
    /// scratch (the quantised rows, then their scales as f32 bits).
    pub fn forward(
        &self,
        m: usize,
        x: &[f32],
        ldx: usize,
        y: &mut [f32],
        ldy: usize,
        packed: &mut Vec<Line>,
    ) {
        let m_pad = m.div_ceil(MR) * MR;
        self.quantise_rows((m, m_pad), x, ldx, packed, cfg!(target_arch = "x86_64"));
        assert!(y.len() >= m.saturating_sub(1) * ldy + self.out && ldy >= self.out);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: callers construct the int8 path only when `int8_supported()`; `packed` holds
        // m_pad·quads values then m_pad scales, `wq` quads·out_pad (see `quantise_rows`, `new`).
        unsafe {
            self.kernel(m, m_pad, simd::words(packed), y, ldy);
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.products_reference(m, simd::words(packed), y, ldy);
    }

    /// The same arithmetic in scalar code (quantisation, products, scaling, activation): what
    /// [`Self::forward`] must equal bit for bit.
    #[cfg(test)]
    pub fn forward_reference(
        &self,
        m: usize,
        x: &[f32],
        ldx: usize,
        y: &mut [f32],
        ldy: usize,
        packed: &mut Vec<Line>,
    ) {
        self.quantise_rows((m, m.div_ceil(MR) * MR), x, ldx, packed, false);
        self.products_reference(m, simd::words(packed), y, ldy);
    }

    /// Packs `m` rows as u8 quads (`x_q + 128`), `m_pad` rows of `quads` values, padding rows
    /// and k at the offset (they add `128·w`, and the padded weights are zero), then the
    /// `m_pad` row scales `t_r` as f32 bits; with AVX-512 (`vector`) or in scalar code, the
    /// same values.
    fn quantise_rows(
        &self,
        (m, m_pad): (usize, usize),
        x: &[f32],
        ldx: usize,
        packed: &mut Vec<Line>,
        vector: bool,
    ) {
        let quads = self.inp.div_ceil(QUAD);
        let fill = u32::from_ne_bytes([OFFSET as u8; 4]);
        let packed = simd::filled(packed, m_pad * quads + m_pad, fill);
        let (rows, scales) = packed.split_at_mut(m_pad * quads);
        for r in 0..m {
            let row = &x[r * ldx..r * ldx + self.inp];
            let dst = &mut rows[r * quads..(r + 1) * quads];
            let t = match vector {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `vector` is set only where `int8_supported()` (AVX-512F).
                true => unsafe { quantise_row_avx512(row, dst) },
                _ => quantise_row(row, dst),
            };
            scales[r] = t.to_bits();
        }
    }

    /// `y = act(t_r · s_o · (Σ packed·w_q − 128·Σ w_q))` for one output value.
    #[inline(always)]
    fn finish(&self, sum: i32, t: f32, o: usize) -> f32 {
        let v = (sum - self.offset_sum[o]) as f32 * (t * self.scale[o]);
        match self.slope {
            Some(s) if v < 0.0 => v * s,
            _ => v,
        }
    }

    #[cfg_attr(target_arch = "x86_64", allow(dead_code))]
    fn products_reference(&self, m: usize, packed: &[u32], y: &mut [f32], ldy: usize) {
        let quads = self.inp.div_ceil(QUAD);
        let m_pad = m.div_ceil(MR) * MR;
        for r in 0..m {
            let t = f32::from_bits(packed[m_pad * quads + r]);
            for o in 0..self.out {
                let mut sum = 0i32;
                for p in 0..quads {
                    let (a, w) = (
                        packed[r * quads + p],
                        simd::words(&self.wq)[p * self.out_pad + o],
                    );
                    for j in 0..QUAD {
                        let av = i32::from((a >> (8 * j)) as u8);
                        let wv = i32::from((w >> (8 * j)) as u8 as i8);
                        sum += av * wv;
                    }
                }
                y[r * ldy + o] = self.finish(sum, t, o);
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vnni")]
    #[allow(clippy::needless_range_loop)]
    fn kernel(&self, m: usize, m_pad: usize, a: &[u32], y: &mut [f32], ldy: usize) {
        use std::arch::x86_64::*;
        let quads = self.inp.div_ceil(QUAD);
        let scales = &a[m_pad * quads..];
        for j0 in (0..self.out_pad).step_by(NR) {
            for i0 in (0..m_pad).step_by(MR) {
                let mut acc = [[_mm512_setzero_si512(); 2]; MR];
                let rows: [&[u32]; MR] =
                    std::array::from_fn(|r| &a[(i0 + r) * quads..(i0 + r + 1) * quads]);
                for p in 0..quads {
                    let wrow =
                        &simd::words(&self.wq)[p * self.out_pad + j0..p * self.out_pad + j0 + NR];
                    // SAFETY: `wrow` has NR = 32 u32 values = two 512-bit vectors.
                    let (b0, b1) = unsafe {
                        (
                            _mm512_loadu_si512(wrow.as_ptr().cast()),
                            _mm512_loadu_si512(wrow.as_ptr().add(16).cast()),
                        )
                    };
                    for r in 0..MR {
                        let av = _mm512_set1_epi32(rows[r][p] as i32);
                        acc[r][0] = _mm512_dpbusd_epi32(acc[r][0], av, b0);
                        acc[r][1] = _mm512_dpbusd_epi32(acc[r][1], av, b1);
                    }
                }
                let cols = (self.out - j0.min(self.out)).min(NR);
                let slope = _mm512_set1_ps(self.slope.unwrap_or(1.0));
                for r in 0..MR.min(m.saturating_sub(i0)) {
                    let t = _mm512_set1_ps(f32::from_bits(scales[i0 + r]));
                    for (h, acc) in acc[r].iter().enumerate() {
                        let c0 = j0 + 16 * h;
                        let mask = simd::lanes(cols.saturating_sub(16 * h));
                        if mask == 0 {
                            continue;
                        }
                        // SAFETY: `offset_sum` and `scale` hold out_pad ≥ c0 + 16 values; the
                        // store is masked to the `cols` real columns of row i0 + r.
                        unsafe {
                            let off = _mm512_loadu_si512(self.offset_sum.as_ptr().add(c0).cast());
                            let s = _mm512_loadu_ps(self.scale.as_ptr().add(c0));
                            let v = _mm512_mul_ps(
                                _mm512_cvtepi32_ps(_mm512_sub_epi32(*acc, off)),
                                _mm512_mul_ps(t, s),
                            );
                            let dst = y.as_mut_ptr().add((i0 + r) * ldy + c0);
                            simd::store_leaky(dst, mask, v, slope);
                        }
                    }
                }
            }
        }
    }
}

/// The row scale `t = max |x| / 127` and its reciprocal (0 for an all-zero row).
#[inline(always)]
fn row_scale(max_abs: f32) -> (f32, f32) {
    let t = max_abs / QMAX;
    (t, if t > 0.0 { 1.0 / t } else { 0.0 })
}

/// One row quantised into `dst` (`⌈len/4⌉` quads of `x_q + 128`); returns its scale `t`.
fn quantise_row(row: &[f32], dst: &mut [u32]) -> f32 {
    let (t, inv) = row_scale(row.iter().fold(0.0f32, |a, v| a.max(v.abs())));
    for (d, chunk) in dst.iter_mut().zip(row.chunks(QUAD)) {
        let mut bytes = [OFFSET as u8; 4];
        for (b, &v) in bytes.iter_mut().zip(chunk) {
            // |v·inv| ≤ 127, so v·inv + 128.5 lies in [1.5, 255.5]: truncation rounds.
            *b = (v * inv + (OFFSET as f32 + 0.5)) as u8;
        }
        *d = u32::from_le_bytes(bytes);
    }
    t
}

/// [`quantise_row`] sixteen values at a time, bit for bit the same: max |x| is exact in any
/// order, and the products and sums round as the scalar ones do (no fused multiply-add).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn quantise_row_avx512(row: &[f32], dst: &mut [u32]) -> f32 {
    use std::arch::x86_64::*;
    let n = row.len();
    let lanes = |i: usize, end: usize| simd::lanes(end.saturating_sub(i));
    let mut vmax = _mm512_setzero_ps();
    for i in (0..n).step_by(16) {
        // SAFETY: the mask covers only lanes below `n`.
        let v = unsafe { _mm512_maskz_loadu_ps(lanes(i, n), row.as_ptr().add(i)) };
        vmax = _mm512_max_ps(vmax, _mm512_abs_ps(v));
    }
    let (t, inv) = row_scale(_mm512_reduce_max_ps(vmax));
    let (vinv, half) = (_mm512_set1_ps(inv), _mm512_set1_ps(OFFSET as f32 + 0.5));
    let bytes = dst.len() * QUAD;
    let out = dst.as_mut_ptr().cast::<i8>();
    for i in (0..bytes).step_by(16) {
        // SAFETY: loads are masked to lanes below `n` (the others read as 0 → 128, the k
        // padding) and start inside `row` (i < n + 3); stores are masked to bytes below
        // `bytes` = dst's length in bytes.
        unsafe {
            let v = _mm512_maskz_loadu_ps(lanes(i, n), row.as_ptr().wrapping_add(i));
            let q = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(v, vinv), half));
            _mm512_mask_cvtusepi32_storeu_epi8(out.add(i), lanes(i, bytes), q);
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// ND_enc's layers and the render tail; row counts that do not fill a block; k not a
    /// multiple of 4; an all-zero row; a padded output stride.
    const SHAPES: [(usize, usize, usize, Option<f32>); 4] = [
        (297, 594, 37, Some(0.01)),
        (594, 32, 9, None),
        (128, 3, 70, None),
        (5, 40, 3, Some(0.2)),
    ];

    fn layer_and_input(
        inp: usize,
        out: usize,
        m: usize,
        slope: Option<f32>,
    ) -> (Int8Dense, Vec<f32>) {
        let w = values(out * inp, inp as u64);
        let mut x = values(m * inp, 7 + m as u64);
        x[..inp].iter_mut().for_each(|v| *v = 0.0);
        (Int8Dense::new(&w, out, inp, slope), x)
    }

    #[test]
    fn vnni_kernel_equals_the_scalar_reference_bit_for_bit() {
        if !int8_supported() {
            eprintln!(
                "skipped: this CPU has no AVX-512 VNNI (the scalar reference is tested below)"
            );
            return;
        }
        for (inp, out, m, slope) in SHAPES {
            let (layer, x) = layer_and_input(inp, out, m, slope);
            let ldy = out + 3;
            let mut fast = vec![f32::NAN; m * ldy];
            let mut reference = vec![f32::NAN; m * ldy];
            layer.forward(m, &x, inp, &mut fast, ldy, &mut Vec::new());
            layer.forward_reference(m, &x, inp, &mut reference, ldy, &mut Vec::new());
            for r in 0..m {
                for o in 0..ldy {
                    let (a, b) = (fast[r * ldy + o], reference[r * ldy + o]);
                    // Bit-identical values; the padding between rows is never written.
                    assert!(
                        a.to_bits() == b.to_bits(),
                        "{inp}→{out} row {r} col {o}: {a} vs {b}"
                    );
                    assert_eq!(o >= out, a.is_nan());
                }
            }
        }
    }

    /// Largest error of a quantised dot product relative to `Σ|x|·|w|`: both operands are
    /// rounded to 1/254 of their range, so each product is off by at most ~1/127 of the
    /// larger operand's range.
    const QUANT_TOL: f32 = 2.0 / QMAX;

    #[test]
    fn reference_is_the_f32_layer_within_the_quantisation_step() {
        for (inp, out, m, slope) in SHAPES {
            let (layer, x) = layer_and_input(inp, out, m, slope);
            let w = values(out * inp, inp as u64);
            let mut y = vec![0.0f32; m * out];
            layer.forward_reference(m, &x, inp, &mut y, out, &mut Vec::new());
            let xmax: Vec<f32> = (0..m)
                .map(|r| {
                    x[r * inp..(r + 1) * inp]
                        .iter()
                        .fold(0.0f32, |a, v| a.max(v.abs()))
                })
                .collect();
            let wmax: Vec<f32> = (0..out)
                .map(|o| {
                    w[o * inp..(o + 1) * inp]
                        .iter()
                        .fold(0.0f32, |a, v| a.max(v.abs()))
                })
                .collect();
            let mut mean_rel = 0.0f32;
            for r in 0..m {
                for o in 0..out {
                    let row = &w[o * inp..(o + 1) * inp];
                    let exact: f32 = (0..inp).map(|i| x[r * inp + i] * row[i]).sum();
                    let exact = match slope {
                        Some(s) if exact < 0.0 => exact * s,
                        _ => exact,
                    };
                    let bound = QUANT_TOL * xmax[r] * wmax[o] * inp as f32;
                    let got = y[r * out + o];
                    assert!(
                        (got - exact).abs() <= bound,
                        "{inp}→{out} row {r} col {o}: {got} vs {exact} (bound {bound})"
                    );
                    if xmax[r] == 0.0 {
                        assert_eq!(got, 0.0);
                    }
                    mean_rel +=
                        (got - exact).abs() / (xmax[r] * wmax[o] * (inp as f32).sqrt() + 1e-12);
                }
            }
            // Quantisation is much better than the bound on average (errors cancel in the sum).
            let mean_rel = mean_rel / (m * out) as f32;
            assert!(
                mean_rel < 0.01,
                "{inp}→{out}: mean relative error {mean_rel}"
            );
        }
    }
}
