//! Direct k×k convolution on AVX-512F, the fast path of [`PackedConv::run_rows`] on CPUs that
//! have it: no im2col and no GEMM packing. Each band of output rows copies the input rows it
//! reads once into a replicate-padded buffer; a register tile of `MR` output pixels × `NB`
//! 16-lane blocks of output channels then sums every tap and input channel before it is
//! stored (weights `[tap][ci][cout padded to 16]`, repacked per call: `run_with` rescales them).
//! The same sums as the im2col path in another order: `DIRECT_TOL` in the tests.
#![allow(unsafe_code)]

use std::ops::Range;

use rayon::prelude::*;

use super::conv::{Hwc, PackedConv};

/// Lanes of one AVX-512 register of f32.
const LANES: usize = 16;

/// Output pixels per band (per rayon task) when the image has enough of them: the padded input
/// band (`(rows + k − 1) · (w + k − 1) · cin` floats) then stays in L2.
const BAND_PIXELS: usize = 4096;

/// Output-channel blocks per register tile at most (`MR · NB` accumulators + `NB` weights + one
/// broadcast fit in the 32 vector registers).
const MAX_NB: usize = 4;

/// True when this CPU runs the direct convolution (AVX-512F; the answer is cached by `std`).
pub(super) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Output rows per band (per rayon task) for `rows` output rows of a stride-`s` conv over an
/// input `w_in` wide: about [`BAND_PIXELS`] input pixels, and at least four bands per thread
/// where there are enough rows.
fn band_rows(w_in: usize, s: usize, rows: usize) -> usize {
    (BAND_PIXELS / (w_in * s)).clamp(1, rows.div_ceil(4 * rayon::current_num_threads()).max(1))
}

/// Floats of one thread's padded input band, at most, for a k×k conv over an input `w_in` wide
/// with `cin` channels (any stride: a band reads about [`BAND_PIXELS`] input pixels).
pub(super) fn scratch_floats(w_in: usize, k: usize, cin: usize) -> usize {
    ((BAND_PIXELS / w_in).max(1) + k - 1) * (w_in + k - 1) * cin
}

/// Output rows `rows` of `conv` applied to `x` with weights `wt` (packed as `conv.wt`), the
/// values of [`PackedConv::run_rows`]. Only where [`available`].
pub(super) fn run_rows(conv: &PackedConv, x: &Hwc, wt: &[f32], rows: Range<usize>) -> Hwc {
    assert!(available(), "direct convolution without AVX-512F");
    assert!(conv.cin <= x.c && wt.len() == conv.k * conv.k * conv.cin * conv.cout);
    let (ho, wo) = conv.out_size(x);
    assert!(rows.end <= ho);
    let (k, s, cin, cout) = (conv.k, conv.stride, conv.cin, conv.cout);
    let groups = column_groups(cout);
    let packed: Vec<Vec<f32>> = groups.iter().map(|g| pack(wt, cout, g.clone())).collect();
    // Padded input columns: output column ox, tap kx reads column ox·s + kx.
    let wp = (wo - 1) * s + k;
    let band = band_rows(x.w, s, rows.len());
    let mut out = vec![0.0f32; rows.len() * wo * cout];
    let first = rows.start;
    out.par_chunks_mut(band * wo * cout)
        .enumerate()
        .for_each_init(Vec::new, |pad: &mut Vec<f32>, (b, dst)| {
            let oy0 = first + b * band;
            let n_rows = dst.len() / (wo * cout);
            let in_rows = (n_rows - 1) * s + k;
            pad.resize(in_rows * wp * cin, 0.0);
            for py in 0..in_rows {
                let iy = (oy0 * s + py).saturating_sub(conv.pad).min(x.h - 1);
                for px in 0..wp {
                    let ix = px.saturating_sub(conv.pad).min(x.w - 1);
                    let src = (iy * x.w + ix) * x.c;
                    let d = (py * wp + px) * cin;
                    pad[d..d + cin].copy_from_slice(&x.d[src..src + cin]);
                }
            }
            let taps: Vec<usize> = (0..k * k).map(|t| ((t / k) * wp + t % k) * cin).collect();
            for r in 0..n_rows {
                let a_row = r * s * wp * cin;
                let d_row = r * wo * cout;
                for (g, w) in groups.iter().zip(&packed) {
                    let tile = Tile {
                        taps: &taps,
                        cin,
                        px_step: s * cin,
                        w,
                        cols: g.clone(),
                        cout,
                    };
                    // SAFETY: `available()` was asserted; `tile.run` reads `pad` at
                    // a_row + (ox·s)·cin + taps + ci < in_rows·wp·cin for ox < wo, and writes
                    // `dst` row r, columns of `g`, pixels < wo.
                    unsafe { tile.row(&pad[a_row..], &mut dst[d_row..d_row + wo * cout], wo) };
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

/// The output columns split into groups of at most [`MAX_NB`] 16-lane blocks, as even as
/// possible (72 columns: 48 + 32, not 64 + 16).
fn column_groups(cout: usize) -> Vec<Range<usize>> {
    let blocks = cout.div_ceil(LANES);
    let n = blocks.div_ceil(MAX_NB);
    let mut groups = Vec::with_capacity(n);
    let mut b0 = 0;
    for g in 0..n {
        let nb = blocks / n + usize::from(g < blocks % n);
        groups.push(b0 * LANES..((b0 + nb) * LANES).min(cout));
        b0 += nb;
    }
    groups
}

/// Columns `cols` of `wt` (`[rows, cout]`) as `[rows, cols padded to 16]`.
fn pack(wt: &[f32], cout: usize, cols: Range<usize>) -> Vec<f32> {
    let ld = cols.len().next_multiple_of(LANES);
    let mut p = vec![0.0f32; wt.len() / cout * ld];
    for (dst, src) in p.chunks_exact_mut(ld).zip(wt.chunks_exact(cout)) {
        dst[..cols.len()].copy_from_slice(&src[cols.clone()]);
    }
    p
}

/// One group of output columns over one output row.
struct Tile<'a> {
    /// Offset of each tap `(ky, kx)` in the padded input, from a pixel's first tap.
    taps: &'a [usize],
    cin: usize,
    /// Padded-input floats between two neighbouring output pixels (stride · cin).
    px_step: usize,
    /// This group's weights, `[tap][ci][16·NB]`.
    w: &'a [f32],
    cols: Range<usize>,
    cout: usize,
}

impl Tile<'_> {
    /// Writes columns `self.cols` of the `wo` pixels of one output row (`dst`, `wo·cout`) from
    /// the padded input starting at that row's first tap (`a`).
    ///
    /// # Safety
    /// AVX-512F is available.
    unsafe fn row(&self, a: &[f32], dst: &mut [f32], wo: usize) {
        assert!(dst.len() >= wo * self.cout);
        let last = (wo - 1) * self.px_step + self.taps.last().copied().unwrap_or(0) + self.cin;
        assert!(a.len() >= last && self.w.len() >= self.taps.len() * self.cin * self.ld());
        // SAFETY (all calls): bounds asserted above; AVX-512F by this fn's contract.
        unsafe {
            match self.cols.len().div_ceil(LANES) {
                1 => self.runs::<14, 1>(a, dst, wo),
                2 => self.runs::<12, 2>(a, dst, wo),
                3 => self.runs::<8, 3>(a, dst, wo),
                _ => self.runs::<6, 4>(a, dst, wo),
            }
        }
    }

    fn ld(&self) -> usize {
        self.cols.len().next_multiple_of(LANES)
    }

    /// Tiles of `MR` pixels along the row; the last one overlaps its neighbour (the same
    /// values are written twice) instead of running a narrower tile. Rows narrower than `MR`
    /// run one pixel at a time.
    ///
    /// # Safety
    /// As [`Self::row`], with its bounds checked.
    unsafe fn runs<const MR: usize, const NB: usize>(&self, a: &[f32], dst: &mut [f32], wo: usize) {
        if wo < MR {
            for ox in 0..wo {
                // SAFETY: pixel ox < wo, within the checked bounds.
                unsafe { self.tile::<1, NB>(a, dst, ox) };
            }
            return;
        }
        let mut ox = 0;
        loop {
            let o = ox.min(wo - MR);
            // SAFETY: pixels o..o + MR ≤ wo, within the checked bounds.
            unsafe { self.tile::<MR, NB>(a, dst, o) };
            if o + MR == wo {
                break;
            }
            ox += MR;
        }
    }

    /// Pixels `ox..ox + MR` of the row, all `NB` blocks of this group.
    ///
    /// # Safety
    /// AVX-512F; `ox + MR ≤ wo` for the `wo` of [`Self::row`]'s checks.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile<const MR: usize, const NB: usize>(&self, a: &[f32], dst: &mut [f32], ox: usize) {
        use std::arch::x86_64::*;
        let ld = self.ld();
        let mut acc = [[_mm512_setzero_ps(); NB]; MR];
        let a0 = a.as_ptr();
        let base = ox * self.px_step;
        let mut wp = self.w.as_ptr();
        for &t in self.taps {
            // SAFETY: pixel p reads a[base + p·px_step + t + ci] ≤ the checked `last`.
            let at = unsafe { a0.add(base + t) };
            for ci in 0..self.cin {
                // SAFETY: `wp` walks the taps·cin rows of `ld` floats of `self.w`.
                let wv: [__m512; NB] =
                    std::array::from_fn(|b| unsafe { _mm512_loadu_ps(wp.add(b * LANES)) });
                for r in 0..MR {
                    let av = _mm512_set1_ps(unsafe { *at.add(r * self.px_step + ci) });
                    for b in 0..NB {
                        acc[r][b] = _mm512_fmadd_ps(av, wv[b], acc[r][b]);
                    }
                }
                wp = unsafe { wp.add(ld) };
            }
        }
        let n = self.cols.len();
        for r in 0..MR {
            let d = (ox + r) * self.cout + self.cols.start;
            for b in 0..NB {
                let mask = ((1u32 << n.saturating_sub(b * LANES).min(LANES)) - 1) as __mmask16;
                // SAFETY: the masked lanes are columns < cols.end of pixel ox + r < wo.
                unsafe {
                    _mm512_mask_storeu_ps(dst.as_mut_ptr().add(d + b * LANES), mask, acc[r][b])
                };
            }
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn tile<const MR: usize, const NB: usize>(&self, _: &[f32], _: &mut [f32], _: usize) {
        unreachable!("direct convolution only where available()")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The direct path sums the same products as im2col + GEMM in another order: f32
    /// rounding, relative to the magnitude of the output (or 1).
    const DIRECT_TOL: f32 = 2e-5;

    fn det(i: usize, salt: usize) -> f32 {
        ((i * 7919 + salt * 104_729) % 2003) as f32 / 2003.0 - 0.5
    }

    #[test]
    fn column_groups_cover_every_column_in_even_groups() {
        assert_eq!(column_groups(4), vec![0..4]);
        assert_eq!(column_groups(64), vec![0..64]);
        assert_eq!(column_groups(72), vec![0..48, 48..72]);
        assert_eq!(column_groups(160), vec![0..64, 64..112, 112..160]);
    }

    #[test]
    fn direct_conv_matches_im2col_gemm() {
        if !available() {
            eprintln!("no AVX-512F: direct convolution not tested");
            return;
        }
        // (k, stride, cin, x.c, cout, h, w): 3×3 and 7×7, stride 1 and 2, a view of wider
        // channels, rows narrower than the tile, every column-group shape.
        let cases = [
            (3, 1, 8, 8, 36, 19, 23),
            (3, 1, 4, 36, 4, 9, 5),
            (3, 2, 16, 16, 72, 16, 18),
            (3, 2, 5, 5, 24, 7, 3),
            (7, 1, 13, 13, 64, 12, 30),
            (7, 1, 5, 5, 8, 11, 2),
            (3, 1, 24, 24, 160, 6, 13),
            (3, 1, 3, 3, 17, 1, 1),
        ];
        for (n, &(k, s, cin, xc, cout, h, w)) in cases.iter().enumerate() {
            let wt: Vec<f32> = (0..k * k * cin * cout).map(|i| det(i, n)).collect();
            let conv = PackedConv {
                k,
                stride: s,
                pad: k / 2,
                cin,
                cout,
                wt,
            };
            let x = Hwc {
                h,
                w,
                c: xc,
                d: (0..h * w * xc).map(|i| 3.0 * det(i, n + 17)).collect(),
            };
            let (ho, _) = conv.out_size(&x);
            for rows in [0..ho, ho / 3..ho, 0..ho.div_ceil(2)] {
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
                assert!(worst < DIRECT_TOL, "case {n}, rows {rows:?}: {worst:e}");
            }
        }
    }
}
