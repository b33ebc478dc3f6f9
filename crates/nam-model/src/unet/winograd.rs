//! Winograd F(4×4, 3×3) (Lavin & Gray, "Fast Algorithms for Convolutional Neural Networks",
//! 2016) for the U-Net's stride-1 3×3 convolutions on CPUs with AVX-512F/VL: a 6×6 input tile
//! gives a 4×4 output tile from 36 products per input/output channel pair instead of 144.
//!
//! Per band of output rows (one rayon task): every 6×6 tile of the replicate-padded input goes
//! through `Bᵀ·d·B` into 36 matrices `V[point][tile][cin]`; each is multiplied by its
//! transformed weights `U[point] = G·g·Gᵀ` (`[cin, cout]`, computed per call, since `run_with`
//! rescales the weights) on the direct convolution's register tiles ([`Gemm`]); `Aᵀ·M·A` turns
//! the 36 products `M[point][tile][cout]` of a tile back into its 4×4 output pixels. The
//! transforms work on whole channel vectors of a pixel (HWC). Rounding grows with the transforms'
//! coefficients (up to 8 and 1/15): `WINOGRAD_TOL` in the tests.
#![allow(unsafe_code)]
// Elsewhere only `applies()` is reachable (false): the transforms are x86-64 code.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_variables))]

use std::ops::Range;

use rayon::prelude::*;

use super::conv::{Hwc, PackedConv};
use super::direct::{self, Gemm};

/// Lanes of one AVX-512 register of f32.
const LANES: usize = 16;

/// Output tile side.
const M: usize = 4;
/// Input tile side, `M + 3 − 1`.
const A: usize = M + 2;
/// Transformed points per tile.
const POINTS: usize = A * A;

/// Input transform `Bᵀ`, for the interpolation points 0, −1, 1, 1/2, −2 and ∞: about 2.3× less
/// f32 rounding than the usual 0, ±1, ±2 (Barabasz et al., "Error analysis and improving the
/// accuracy of Winograd convolution for deep neural networks", 2020; measured here with
/// random 64-channel tiles).
const BT: [[f32; A]; A] = [
    [1.0, -1.5, -2.0, 1.5, 1.0, 0.0],
    [0.0, 1.0, -2.5, 0.5, 1.0, 0.0],
    [0.0, -1.0, 0.5, 2.5, 1.0, 0.0],
    [0.0, -2.0, -1.0, 2.0, 1.0, 0.0],
    [0.0, 0.5, -1.0, -0.5, 1.0, 0.0],
    [0.0, 1.0, -1.5, -2.0, 1.5, 1.0],
];

/// Weight transform `G`.
const G: [[f64; 3]; A] = [
    [1.0, 0.0, 0.0],
    [-1.0 / 3.0, 1.0 / 3.0, -1.0 / 3.0],
    [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
    [-16.0 / 15.0, -8.0 / 15.0, -4.0 / 15.0],
    [1.0 / 15.0, -2.0 / 15.0, 4.0 / 15.0],
    [0.0, 0.0, 1.0],
];

/// Output transform `Aᵀ`: powers of the points.
const AT: [[f32; A]; M] = [
    [1.0, 1.0, 1.0, 1.0, 1.0, 0.0],
    [0.0, -1.0, 1.0, 0.5, -2.0, 0.0],
    [0.0, 1.0, 1.0, 0.25, 4.0, 0.0],
    [0.0, -1.0, 1.0, 0.125, -8.0, 1.0],
];

/// Bytes of one band's transformed tiles (`V` and `M`), about: they stay in L2.
const BAND_BYTES: usize = 512 * 1024;

/// Whether `conv` on `x` runs here rather than on the direct tiles: a stride-1 3×3 f32 conv
/// where the CPU has AVX-512F/VL, with enough output channels that the products outweigh the
/// transforms, and enough tiles that each transformed weight matrix serves many of them
/// (thresholds measured per shape of the U-Net: docs/perf/unet_cpu.md).
pub(super) fn applies(conv: &PackedConv, x: &Hwc) -> bool {
    let tiles = x.h.div_ceil(M) * x.w.div_ceil(M);
    conv.k == 3
        && conv.stride == 1
        && conv.pad == 1
        && !conv.bf16
        && conv.cout >= MIN_COUT
        && tiles >= TILES_PER_CIN * conv.cin
        && direct::available()
}

/// Output channels below which the direct tiles are faster (the output transform then costs
/// as much as the products it saves).
const MIN_COUT: usize = 24;

/// Tiles per input channel below which the direct tiles are faster (the weight transform and
/// packing, `36·cin·cout` values per call, outweigh the products saved).
const TILES_PER_CIN: usize = 4;

/// `U[point] = G·g·Gᵀ` of the packed weights `wt` (`[tap][ci][co]`), as `[point][ci][co]`:
/// each point is a fixed combination of the 9 taps (coefficients `G[i][ky]·G[j][kx]`, rounded
/// from f64), summed over whole `cin·cout` rows.
fn transform_weights(wt: &[f32], cin: usize, cout: usize) -> Vec<f32> {
    let n = cin * cout;
    let mut u = vec![0.0f32; POINTS * n];
    u.par_chunks_mut(n).enumerate().for_each(|(p, dst)| {
        let (i, j) = (p / A, p % A);
        for (tap, src) in wt.chunks_exact(n).enumerate() {
            let c = (G[i][tap / 3] * G[j][tap % 3]) as f32;
            if c != 0.0 {
                // SAFETY: AVX-512F, asserted by `run_rows` before any call.
                unsafe { axpy(dst, c, src) };
            }
        }
    });
    u
}

/// `dst += c·src`, vectorised for AVX-512.
///
/// # Safety
/// AVX-512F (on x86-64).
#[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx512f"))]
unsafe fn axpy(dst: &mut [f32], c: f32, src: &[f32]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d += c * s;
    }
}

/// Output rows `rows` of `conv` (stride 1, 3×3, replicate padding 1) applied to `x` with weights
/// `wt`: the values of [`PackedConv::run_rows`] within `WINOGRAD_TOL`; [`applies`] says where it is faster.
pub(super) fn run_rows(conv: &PackedConv, x: &Hwc, wt: &[f32], rows: Range<usize>) -> Hwc {
    assert!(
        direct::available(),
        "Winograd convolution without AVX-512F/VL"
    );
    assert!((conv.k, conv.stride, conv.pad) == (3, 1, 1) && conv.cin <= x.c);
    assert_eq!(wt.len(), 9 * conv.cin * conv.cout);
    let (cin, cout) = (conv.cin, conv.cout);
    let (ho, wo) = conv.out_size(x);
    assert!(rows.end <= ho && !rows.is_empty());
    let u = transform_weights(wt, cin, cout);
    let gemms: Vec<Gemm> = u
        .chunks_exact(cin * cout)
        .map(|u| Gemm::new(u, cin, cout))
        .collect();
    let tiles_x = wo.div_ceil(M);
    let tile_rows = rows.len().div_ceil(M);
    let per_tile_row = POINTS * (cin + cout) * 4 * tiles_x;
    let band = (BAND_BYTES / per_tile_row).clamp(
        1,
        tile_rows.div_ceil(4 * rayon::current_num_threads()).max(1),
    ) * M;
    let mut out = vec![0.0f32; rows.len() * wo * cout];
    out.par_chunks_mut(band * wo * cout)
        .enumerate()
        .for_each_init(Scratch::default, |s, (b, dst)| {
            let y0 = rows.start + b * band;
            let n_rows = dst.len() / (wo * cout);
            let tiles = n_rows.div_ceil(M) * tiles_x;
            s.v.resize(POINTS * tiles * cin, 0.0);
            s.m.resize(POINTS * tiles * cout, 0.0);
            #[cfg(target_arch = "x86_64")]
            for t in 0..tiles {
                let (ty, tx) = (t / tiles_x, t % tiles_x);
                // SAFETY: AVX-512F asserted above; `s.v` sized for `tiles`.
                unsafe { input_tile(x, cin, (y0 + ty * M, tx * M), &mut s.v, (t, tiles)) };
            }
            for (p, g) in gemms.iter().enumerate() {
                g.run(
                    &s.v[p * tiles * cin..(p + 1) * tiles * cin],
                    tiles,
                    &mut s.m[p * tiles * cout..(p + 1) * tiles * cout],
                );
            }
            #[cfg(target_arch = "x86_64")]
            for t in 0..tiles {
                let (ty, tx) = (t / tiles_x, t % tiles_x);
                let at = (ty * M, tx * M);
                // SAFETY: AVX-512F asserted above; `s.m` sized for `tiles`.
                unsafe { output_tile(&s.m, (t, tiles), cout, dst, at, (n_rows, wo)) };
            }
        });
    Hwc {
        h: rows.len(),
        w: wo,
        c: cout,
        d: out,
    }
}

/// One rayon task's buffers: the transformed input `V` and the products `M`.
#[derive(Default)]
struct Scratch {
    v: Vec<f32>,
    m: Vec<f32>,
}

/// `Σ_k c[k]·v[k]` over 16-lane vectors, the zero coefficients skipped (with `c` a constant
/// row of the transforms, the loop unrolls to just its non-zero terms).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn combine(c: &[f32; A], v: &[std::arch::x86_64::__m512; A]) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    // SAFETY: only reached from the `avx512f` transforms below.
    unsafe {
        let mut acc = _mm512_setzero_ps();
        for k in 0..A {
            acc = match c[k] {
                0.0 => acc,
                1.0 => _mm512_add_ps(acc, v[k]),
                -1.0 => _mm512_sub_ps(acc, v[k]),
                ck => _mm512_fmadd_ps(_mm512_set1_ps(ck), v[k], acc),
            };
        }
        acc
    }
}

/// `V[point][t]` of the tile whose output starts at `(oy, ox)`: `Bᵀ·d·B` of the 6×6 input pixels
/// from `(oy − 1, ox − 1)`, replicate-padded (rows and columns clamped to `x`), 16 channels at a
/// time (masked loads and stores for the last block).
///
/// # Safety
/// AVX-512F; `v` holds `POINTS · tiles · cin` values and `t < tiles`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::needless_range_loop)]
unsafe fn input_tile(
    x: &Hwc,
    cin: usize,
    (oy, ox): (usize, usize),
    v: &mut [f32],
    (t, tiles): (usize, usize),
) {
    use std::arch::x86_64::*;
    let rows: [usize; A] = std::array::from_fn(|a| (oy + a).saturating_sub(1).min(x.h - 1) * x.w);
    let cols: [usize; A] = std::array::from_fn(|b| (ox + b).saturating_sub(1).min(x.w - 1));
    let src = x.d.as_ptr();
    let dst = v.as_mut_ptr();
    for c0 in (0..cin).step_by(LANES) {
        let k = crate::simd::lanes(cin - c0);
        // tmp[a][j] = Σ_b d[a][b]·Bᵀ[j][b].
        let mut tmp = [[_mm512_setzero_ps(); A]; A];
        for (a, row) in tmp.iter_mut().enumerate() {
            // SAFETY: masked loads of the first `cin − c0` channels of clamped pixels of `x`.
            let d: [__m512; A] = std::array::from_fn(|b| unsafe {
                _mm512_maskz_loadu_ps(k, src.add((rows[a] + cols[b]) * x.c + c0))
            });
            for (j, bt) in BT.iter().enumerate() {
                row[j] = combine(bt, &d);
            }
        }
        // V[i][j] = Σ_a Bᵀ[i][a]·tmp[a][j].
        for j in 0..A {
            let col: [__m512; A] = std::array::from_fn(|a| tmp[a][j]);
            for (i, bt) in BT.iter().enumerate() {
                let p = i * A + j;
                // SAFETY: point p of tile t, channels c0.. masked to cin: inside `v`.
                unsafe {
                    _mm512_mask_storeu_ps(dst.add((p * tiles + t) * cin + c0), k, combine(bt, &col))
                };
            }
        }
    }
}

/// The 4×4 output pixels `Aᵀ·M·A` of tile `t`, those inside the band (`n_rows × wo`), written to
/// `dst` from `(y, x)`, 16 channels at a time.
///
/// # Safety
/// AVX-512F; `m` holds `POINTS · tiles · cout` values, `t < tiles`, `dst` `n_rows · wo · cout`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::needless_range_loop)]
unsafe fn output_tile(
    m: &[f32],
    (t, tiles): (usize, usize),
    cout: usize,
    dst: &mut [f32],
    (y, x): (usize, usize),
    (n_rows, wo): (usize, usize),
) {
    use std::arch::x86_64::*;
    let (ni, nj) = (M.min(n_rows - y), M.min(wo - x));
    let src = m.as_ptr();
    let out = dst.as_mut_ptr();
    for c0 in (0..cout).step_by(LANES) {
        let k = crate::simd::lanes(cout - c0);
        // tmp[a][j] = Σ_b M[a][b]·Aᵀ[j][b].
        let mut tmp = [[_mm512_setzero_ps(); M]; A];
        for (a, row) in tmp.iter_mut().enumerate() {
            // SAFETY: point a·A + b of tile t, channels masked to cout: inside `m`.
            let mv: [__m512; A] = std::array::from_fn(|b| unsafe {
                _mm512_maskz_loadu_ps(k, src.add(((a * A + b) * tiles + t) * cout + c0))
            });
            for (j, at) in AT.iter().enumerate() {
                row[j] = combine(at, &mv);
            }
        }
        // Y[i][j] = Σ_a Aᵀ[i][a]·tmp[a][j], inside the band only.
        for j in 0..nj {
            let col: [__m512; A] = std::array::from_fn(|a| tmp[a][j]);
            for (i, at) in AT.iter().enumerate().take(ni) {
                let o = ((y + i) * wo + x + j) * cout + c0;
                // SAFETY: pixel (y + i, x + j) lies in the band; channels masked to cout.
                unsafe { _mm512_mask_storeu_ps(out.add(o), k, combine(at, &col)) };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// F(4×4, 3×3) in f32 against the im2col path, relative to the output's magnitude (or 1):
    /// the transforms' coefficients (up to 8 and 1/15) amplify rounding (2.2e-5 at worst in
    /// these cases; the direct path's `DIRECT_TOL` is 2e-5).
    const WINOGRAD_TOL: f32 = 5e-5;

    fn det(i: usize, salt: usize) -> f32 {
        ((i * 7919 + salt * 104_729) % 2003) as f32 / 2003.0 - 0.5
    }

    #[test]
    fn winograd_matches_im2col_gemm() {
        if !direct::available() {
            eprintln!("no AVX-512F/VL: Winograd not tested");
            return;
        }
        // (cin, x.c, cout, h, w): partial tiles in both directions, a view of wider channels,
        // images smaller than a tile, every column-group shape.
        let cases = [
            (8, 8, 28, 19, 23),
            (8, 36, 4, 9, 5),
            (16, 16, 72, 16, 18),
            (64, 64, 224, 8, 8),
            (24, 24, 160, 6, 13),
            (8, 8, 17, 1, 1),
            (12, 12, 12, 3, 2),
            (32, 32, 112, 33, 31),
        ];
        for (n, &(cin, xc, cout, h, w)) in cases.iter().enumerate() {
            let wt: Vec<f32> = (0..9 * cin * cout).map(|i| det(i, n)).collect();
            let conv = PackedConv {
                k: 3,
                stride: 1,
                pad: 1,
                cin,
                cout,
                wt,
                bf16: false,
            };
            let x = Hwc {
                h,
                w,
                c: xc,
                d: (0..h * w * xc).map(|i| 3.0 * det(i, n + 17)).collect(),
            };
            for rows in [0..h, h / 3..h, 0..h.div_ceil(2)] {
                if rows.is_empty() {
                    continue;
                }
                let want = conv.im2col_rows(&x, &conv.wt, rows.clone());
                let got = run_rows(&conv, &x, &conv.wt, rows.clone());
                assert_eq!((got.h, got.w, got.c), (want.h, want.w, want.c));
                let worst = want
                    .d
                    .iter()
                    .zip(&got.d)
                    .map(|(a, b)| (a - b).abs() / a.abs().max(1.0))
                    .fold(0.0f32, f32::max);
                assert!(worst < WINOGRAD_TOL, "case {n}, rows {rows:?}: {worst:e}");
            }
        }
    }
}
