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

use super::conv::{Hwc, PackedConv, min_len};
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

/// Bytes of one piece of a band's transformed tiles (`V` and `M`), about: they stay in L2.
const BAND_BYTES: usize = 512 * 1024;

/// Tiles per piece at least, so that each transformed weight matrix serves that many tiles.
const MIN_PIECE_TILES: usize = 32;

/// Tiles per piece for `K = kk` GEMM rows and `cout` columns ([`BAND_BYTES`], at least
/// [`MIN_PIECE_TILES`]).
fn band_tiles(kk: usize, cout: usize) -> usize {
    (BAND_BYTES / (POINTS * (kk + cout) * 4)).max(MIN_PIECE_TILES)
}

/// Floats of the transformed weights of a k×k conv with `cin` inputs and `cout` outputs that
/// [`run_rows`] holds during a call (packed: columns padded to whole vectors).
pub(super) fn weight_floats(k: usize, cin: usize, cout: usize) -> usize {
    POINTS * gemm_rows(k, cin) * cout.next_multiple_of(LANES)
}

/// Floats of one rayon task's Winograd buffers, at most, for a k×k conv with `cin` inputs and
/// `cout` outputs.
pub(super) fn scratch_floats(k: usize, cin: usize, cout: usize) -> usize {
    let kk = gemm_rows(k, cin);
    POINTS * band_tiles(kk, cout) * (kk + cout)
}

/// Whether `conv` on an `h × w` input runs here rather than on the direct tiles: a stride-1 f32 conv with an
/// odd kernel and "same" padding where the CPU has AVX-512F/VL, with enough output channels that
/// the products outweigh the transforms, and enough tiles that each transformed weight matrix
/// serves many of them (thresholds measured per shape of the U-Net: docs/perf/unet_cpu.md).
pub(super) fn applies(conv: &PackedConv, (h, w): (usize, usize)) -> bool {
    let tiles = h.div_ceil(M) * w.div_ceil(M);
    conv.k % 2 == 1
        && conv.k >= 3
        && conv.stride == 1
        && conv.pad == conv.k / 2
        && conv.winograd
        && !conv.bf16
        && conv.cout >= MIN_COUT
        && tiles >= MIN_TILES
        && TILES_PER_ROW * tiles >= gemm_rows(conv.k, conv.cin)
        && direct::available()
}

/// Output channels below which the direct tiles are faster (the output transform then costs
/// as much as the products it saves): measured at 256², 32 → 16 channels ran 1.13× faster
/// here, 16 → 8 0.75×.
const MIN_COUT: usize = 16;

/// Transformed-weight rows per tile above which the direct tiles are faster (the weight
/// transform and packing, `36·K·cout` values per call, outweigh the products saved): 128 → 448
/// channels at 32² (64 tiles, `K` = 128) still ran 1.54× faster here.
const TILES_PER_ROW: usize = 2;

/// Tiles (a 32×32 output) below which a conv stays direct: it takes microseconds either way,
/// and small images (the parity goldens) keep the direct path's rounding.
const MIN_TILES: usize = 64;

/// 3×3 blocks per side of a k×k kernel: a larger kernel runs as `blocks²` 3×3 convolutions of
/// shifted inputs (the kernel zero-padded to `3·blocks`, `lead` zero rows and columns first), whose
/// products are summed before the output transform: one GEMM with `K = blocks²·cin`.
fn blocks(k: usize) -> usize {
    k.div_ceil(3)
}

/// `K`, the rows of each point's transformed weights: every 3×3 block's input channels.
fn gemm_rows(k: usize, cin: usize) -> usize {
    blocks(k).pow(2) * cin
}

/// Zero rows (and columns) before the kernel in its `3·blocks` padding.
fn lead(k: usize) -> usize {
    (3 * blocks(k) - k) / 2
}

/// `U[point] = G·g·Gᵀ` of every 3×3 block `g` of the packed weights `wt` (`[tap][ci][co]`, k×k
/// taps), as one GEMM operand per point (rows `[block][ci]`, `K = blocks²·cin` of them): each
/// point of a block is a fixed combination of its taps (coefficients `G[i][r]·G[j][s]`, rounded
/// from f64), summed over the `cout` weights of a row straight into the packed layout. Row by
/// row for every point of a thread's share, so each tap row is read from L1.
fn transform(wt: &[f32], k: usize, cin: usize, cout: usize) -> Vec<Gemm> {
    let (nb, lead) = (blocks(k), lead(k));
    let kk = gemm_rows(k, cin);
    let mut gemms: Vec<Gemm> = (0..POINTS).map(|_| Gemm::zeroed(kk, cout)).collect();
    let share = POINTS.div_ceil(rayon::current_num_threads());
    gemms
        .par_chunks_mut(share)
        .with_min_len(min_len())
        .enumerate()
        .for_each(|(c, chunk)| {
            for e in 0..kk {
                let (blk, ci) = (e / cin, e % cin);
                for (q, gemm) in chunk.iter_mut().enumerate() {
                    let p = c * share + q;
                    let (i, j) = (p / A, p % A);
                    for (cols, dst) in gemm.row_mut(e) {
                        for (r, s) in (0..9).map(|t| (t / 3, t % 3)) {
                            let ky = (3 * (blk / nb) + r).checked_sub(lead).filter(|&v| v < k);
                            let kx = (3 * (blk % nb) + s).checked_sub(lead).filter(|&v| v < k);
                            let (Some(ky), Some(kx)) = (ky, kx) else {
                                continue;
                            };
                            let c = (G[i][r] * G[j][s]) as f32;
                            if c != 0.0 {
                                let row = ((ky * k + kx) * cin + ci) * cout;
                                // SAFETY: AVX-512F, asserted by `run_rows` before any call.
                                unsafe { axpy(dst, c, &wt[row + cols.start..row + cols.end]) };
                            }
                        }
                    }
                }
            }
        });
    gemms
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

/// The weights `wt` of `conv` (packed as `conv.wt`) transformed for [`run_rows`]: one GEMM
/// operand per point, computed once for any number of calls with the same weights.
pub(super) fn transform_weights(conv: &PackedConv, wt: &[f32]) -> Vec<Gemm> {
    let (k, cin, cout) = (conv.k, conv.cin, conv.cout);
    assert_eq!(wt.len(), k * k * cin * cout);
    transform(wt, k, cin, cout)
}

/// Output rows `rows` of `conv` (stride 1, odd k×k, replicate padding k/2) applied to `x` with
/// the transformed weights `gemms` ([`transform_weights`]): the values of
/// [`PackedConv::run_rows`] within `WINOGRAD_TOL`; [`applies`] says where it is faster.
pub(super) fn run_rows(conv: &PackedConv, x: &Hwc, gemms: &[Gemm], rows: Range<usize>) -> Hwc {
    assert!(
        direct::available(),
        "Winograd convolution without AVX-512F/VL"
    );
    let (k, cin, cout) = (conv.k, conv.cin, conv.cout);
    assert!(k % 2 == 1 && conv.stride == 1 && conv.pad == k / 2 && cin <= x.c);
    assert_eq!(gemms.len(), POINTS);
    let (ho, wo) = conv.out_size(x);
    assert!(rows.end <= ho && !rows.is_empty());
    let nb = blocks(k);
    let kk = gemm_rows(k, cin);
    // Input offset of block (by, bx)'s tile from its output tile, per side.
    let shift = |b: usize| (3 * b) as isize - (conv.pad + lead(k)) as isize;
    let tiles_x = wo.div_ceil(M);
    // A band is `band` output rows (one rayon task), worked in pieces of at most `piece` tiles
    // along a row of tiles, so that a piece's `V` and `M` stay near [`BAND_BYTES`].
    let piece = band_tiles(kk, cout);
    let rows_of_tiles = (piece / tiles_x).clamp(
        1,
        rows.len()
            .div_ceil(M)
            .div_ceil(4 * rayon::current_num_threads())
            .max(1),
    );
    let band = rows_of_tiles * M;
    let mut out = vec![0.0f32; rows.len() * wo * cout];
    out.par_chunks_mut(band * wo * cout)
        .with_min_len(min_len())
        .enumerate()
        .for_each_init(Scratch::default, |s, (b, dst)| {
            let y0 = rows.start + b * band;
            let n_rows = dst.len() / (wo * cout);
            let ty = n_rows.div_ceil(M);
            // Tiles per row of a piece: `piece` tiles spread over the band's rows of tiles.
            let per_row = piece.div_ceil(ty).max(1);
            for tx in (0..tiles_x).step_by(per_row) {
                let tw = per_row.min(tiles_x - tx);
                let tiles = ty * tw;
                // The tile at (i, j) of this piece: output pixel (i·M, (tx + j)·M) of the band.
                let at = |t: usize| (t / tw * M, (tx + t % tw) * M);
                s.v.resize(POINTS * tiles * kk, 0.0);
                s.m.resize(POINTS * tiles * cout, 0.0);
                #[cfg(target_arch = "x86_64")]
                for t in 0..tiles {
                    let (oy, ox) = at(t);
                    for blk in 0..nb * nb {
                        let origin = (
                            (y0 + oy) as isize + shift(blk / nb),
                            ox as isize + shift(blk % nb),
                        );
                        // SAFETY: AVX-512F asserted above; `input_tile` checks its bounds.
                        unsafe {
                            input_tile(x, cin, origin, &mut s.v, (t, tiles), (kk, blk * cin));
                        }
                    }
                }
                for (p, g) in gemms.iter().enumerate() {
                    g.run(
                        &s.v[p * tiles * kk..(p + 1) * tiles * kk],
                        tiles,
                        &mut s.m[p * tiles * cout..(p + 1) * tiles * cout],
                    );
                }
                #[cfg(target_arch = "x86_64")]
                for t in 0..tiles {
                    // SAFETY: AVX-512F asserted above; `output_tile` checks its bounds.
                    unsafe { output_tile(&s.m, (t, tiles), cout, dst, at(t), (n_rows, wo)) };
                }
            }
        });
    Hwc {
        h: rows.len(),
        w: wo,
        c: cout,
        d: out,
    }
}

/// One rayon task's buffers for a piece: the transformed input `V` and the products `M`.
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

/// `V[point][t][c0..c0 + cin]` (rows of `ld` values): `Bᵀ·d·B` of the 6×6 input pixels from
/// `(iy, ix)` (may lie outside `x`: rows and columns are clamped, i.e. replicate padding), 16
/// channels at a time (masked loads and stores for the last block).
///
/// # Safety
/// AVX-512F (the bounds are checked).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::needless_range_loop)]
unsafe fn input_tile(
    x: &Hwc,
    cin: usize,
    (iy, ix): (isize, isize),
    v: &mut [f32],
    (t, tiles): (usize, usize),
    (ld, c_at): (usize, usize),
) {
    use std::arch::x86_64::*;
    assert!(t < tiles && c_at + cin <= ld && v.len() >= POINTS * tiles * ld && x.h * x.w > 0);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let rows: [usize; A] = std::array::from_fn(|a| clamp(iy + a as isize, x.h) * x.w);
    let cols: [usize; A] = std::array::from_fn(|b| clamp(ix + b as isize, x.w));
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
                    _mm512_mask_storeu_ps(
                        dst.add((p * tiles + t) * ld + c_at + c0),
                        k,
                        combine(bt, &col),
                    )
                };
            }
        }
    }
}

/// The 4×4 output pixels `Aᵀ·M·A` of tile `t`, those inside the band (`n_rows × wo`), written to
/// `dst` from `(y, x)`, 16 channels at a time.
///
/// # Safety
/// AVX-512F (the bounds are checked).
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
    assert!(t < tiles && m.len() >= POINTS * tiles * cout && dst.len() >= n_rows * wo * cout);
    assert!(y < n_rows && x < wo);
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
    use crate::unet::conv::fixtures::{case, worst_rel};

    /// F(4×4, 3×3) in f32 against the im2col path, relative to the output's magnitude (or 1):
    /// the transforms' coefficients (up to 8 and 1/15) amplify rounding (2.2e-5 at worst in
    /// these cases; the direct path's `DIRECT_TOL` is 2e-5).
    const WINOGRAD_TOL: f32 = 5e-5;

    #[test]
    fn winograd_matches_im2col_gemm() {
        if !direct::available() {
            eprintln!("no AVX-512F/VL: Winograd not tested");
            return;
        }
        // (k, cin, x.c, cout, h, w): partial tiles in both directions, a view of wider channels,
        // images smaller than a tile, every column-group shape; 7×7 as 3×3 blocks.
        let cases = [
            (3, 8, 8, 28, 19, 23),
            (3, 8, 36, 4, 9, 5),
            (3, 16, 16, 72, 16, 18),
            (3, 64, 64, 224, 8, 8),
            (3, 24, 24, 160, 6, 13),
            (3, 8, 8, 17, 1, 1),
            (3, 12, 12, 12, 3, 2),
            (3, 32, 32, 112, 33, 31),
            (7, 12, 12, 64, 21, 18),
            (7, 4, 4, 8, 3, 9),
            (5, 6, 6, 20, 7, 10),
        ];
        for (n, &(k, cin, xc, cout, h, w)) in cases.iter().enumerate() {
            let (conv, x) = case((k, 1, cin, xc, cout), (h, w), n);
            for rows in [0..h, h / 3..h, 0..h.div_ceil(2)] {
                if rows.is_empty() {
                    continue;
                }
                let want = conv.im2col_rows(&x, &conv.wt, rows.clone());
                let got = run_rows(&conv, &x, &transform_weights(&conv, &conv.wt), rows.clone());
                let worst = worst_rel(&got, &want);
                assert!(worst < WINOGRAD_TOL, "case {n}, rows {rows:?}: {worst:e}");
            }
        }
    }
}
