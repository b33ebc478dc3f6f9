//! Direct k×k convolution on AVX-512F/VL, the fast path of [`PackedConv::run_rows`] on CPUs that
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

/// True when this CPU runs the direct convolution (AVX-512F and VL; `std` caches the answer).
pub(super) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
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
    assert!(available(), "direct convolution without AVX-512F/VL");
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

/// Column groups of at most this many columns run on 8-lane registers.
const NARROW: usize = 8;

/// Vector lanes of a column group: 8 for a narrow one (at most [`NARROW`] columns), else 16.
fn lanes(cols: &Range<usize>) -> usize {
    if cols.len() <= NARROW { NARROW } else { LANES }
}

/// The output columns split into groups: 16-lane blocks in groups of at most [`MAX_NB`], as even
/// as possible (160 columns: 64 + 48 + 48), and a remainder of at most [`NARROW`] columns as a
/// narrow group of its own (36 columns: 32 + 4).
fn column_groups(cout: usize) -> Vec<Range<usize>> {
    let rem = cout % LANES;
    let wide = if rem > NARROW { cout } else { cout - rem };
    let blocks = wide.div_ceil(LANES);
    let n = blocks.div_ceil(MAX_NB);
    let mut groups = Vec::with_capacity(n + 1);
    let mut b0 = 0;
    for g in 0..n {
        let nb = blocks / n + usize::from(g < blocks % n);
        groups.push(b0 * LANES..((b0 + nb) * LANES).min(wide));
        b0 += nb;
    }
    if wide < cout {
        groups.push(wide..cout);
    }
    groups
}

/// Starts of the `mr`-pixel tiles covering a row of `wo ≥ mr` pixels: the last tile overlaps
/// its neighbour (the same values are written twice) instead of running a narrower tile.
fn tile_starts(wo: usize, mr: usize) -> impl Iterator<Item = usize> {
    (0..wo.div_ceil(mr)).map(move |i| (i * mr).min(wo - mr))
}

/// Columns `cols` of `wt` (`[rows, cout]`) as `[rows, cols padded to whole vectors]`.
fn pack(wt: &[f32], cout: usize, cols: Range<usize>) -> Vec<f32> {
    let ld = cols.len().next_multiple_of(lanes(&cols));
    let mut p = vec![0.0f32; wt.len() / cout * ld];
    for (dst, src) in p.chunks_exact_mut(ld).zip(wt.chunks_exact(cout)) {
        dst[..cols.len()].copy_from_slice(&src[cols.clone()]);
    }
    p
}

/// The register tile of [`Tile::tile`] and [`Tile::tile8`] over one vector width: `MR` pixels ×
/// `NB` vectors of `L` lanes, summed over every tap and input channel, then stored (the last
/// vector masked to the group's columns).
macro_rules! tile_body {
    ($t:ident, $a:ident, $dst:ident, $ox:ident, $mr:expr, $nb:expr, $l:expr, $v:ty, $zero:ident,
     $load:ident, $set1:ident, $fma:ident, $store:expr) => {{
        let ld = $t.ld();
        let mut acc = [[$zero(); $nb]; $mr];
        let a0 = $a.as_ptr();
        let base = $ox * $t.px_step;
        let mut wp = $t.w.as_ptr();
        for &tap in $t.taps {
            // SAFETY: pixel p reads a[base + p·px_step + tap + ci] ≤ the checked `last`.
            let at = unsafe { a0.add(base + tap) };
            for ci in 0..$t.cin {
                // SAFETY: `wp` walks the taps·cin rows of `ld` floats of the group's weights.
                let wv: [$v; $nb] = std::array::from_fn(|b| unsafe { $load(wp.add(b * $l)) });
                for r in 0..$mr {
                    let av = $set1(unsafe { *at.add(r * $t.px_step + ci) });
                    for b in 0..$nb {
                        acc[r][b] = $fma(av, wv[b], acc[r][b]);
                    }
                }
                wp = unsafe { wp.add(ld) };
            }
        }
        let n = $t.cols.len();
        let store = $store;
        for r in 0..$mr {
            let d = ($ox + r) * $t.cout + $t.cols.start;
            for b in 0..$nb {
                let lanes = n.saturating_sub(b * $l).min($l);
                // SAFETY: the `lanes` stored are columns < cols.end of pixel ox + r < wo.
                store(
                    unsafe { $dst.as_mut_ptr().add(d + b * $l) },
                    lanes,
                    acc[r][b],
                );
            }
        }
    }};
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
    /// AVX-512F and VL are available ([`available`]).
    unsafe fn row(&self, a: &[f32], dst: &mut [f32], wo: usize) {
        assert!(dst.len() >= wo * self.cout);
        let last = (wo - 1) * self.px_step + self.taps.last().copied().unwrap_or(0) + self.cin;
        assert!(a.len() >= last && self.w.len() >= self.taps.len() * self.cin * self.ld());
        // SAFETY (all calls): bounds asserted above; AVX-512F/VL by this fn's contract.
        unsafe {
            match self.cols.len().div_ceil(LANES) {
                1 if self.cols.len() <= NARROW => self.runs8::<16>(a, dst, wo),
                1 => self.runs::<14, 1>(a, dst, wo),
                2 => self.runs::<12, 2>(a, dst, wo),
                3 => self.runs::<8, 3>(a, dst, wo),
                _ => self.runs::<6, 4>(a, dst, wo),
            }
        }
    }

    /// Floats per weight row of this group: its columns padded to whole vectors.
    fn ld(&self) -> usize {
        self.cols.len().next_multiple_of(lanes(&self.cols))
    }

    /// Tiles of `MR` pixels along the row ([`tile_starts`]); rows narrower than `MR` run one
    /// pixel at a time.
    ///
    /// # Safety
    /// As [`Self::row`], with its bounds checked.
    unsafe fn runs<const MR: usize, const NB: usize>(&self, a: &[f32], dst: &mut [f32], wo: usize) {
        // SAFETY (both loops): every tile's pixels lie below wo, within the checked bounds.
        if wo < MR {
            (0..wo).for_each(|ox| unsafe { self.tile::<1, NB>(a, dst, ox) });
        } else {
            tile_starts(wo, MR).for_each(|ox| unsafe { self.tile::<MR, NB>(a, dst, ox) });
        }
    }

    /// [`Self::runs`] on 8-lane registers ([`Self::tile8`]).
    ///
    /// # Safety
    /// As [`Self::row`], with its bounds checked.
    unsafe fn runs8<const MR: usize>(&self, a: &[f32], dst: &mut [f32], wo: usize) {
        // SAFETY (both loops): every tile's pixels lie below wo, within the checked bounds.
        if wo < MR {
            (0..wo).for_each(|ox| unsafe { self.tile8::<1>(a, dst, ox) });
        } else {
            tile_starts(wo, MR).for_each(|ox| unsafe { self.tile8::<MR>(a, dst, ox) });
        }
    }

    /// Pixels `ox..ox + MR` of the row, all `NB` blocks of 16 columns of this group.
    ///
    /// # Safety
    /// AVX-512F; `ox + MR ≤ wo` for the `wo` of [`Self::row`]'s checks.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile<const MR: usize, const NB: usize>(&self, a: &[f32], dst: &mut [f32], ox: usize) {
        use std::arch::x86_64::*;
        tile_body!(
            self,
            a,
            dst,
            ox,
            MR,
            NB,
            16,
            __m512,
            _mm512_setzero_ps,
            _mm512_loadu_ps,
            _mm512_set1_ps,
            _mm512_fmadd_ps,
            |p, n: usize, v| {
                // SAFETY: the caller passes n writable lanes at p.
                unsafe { _mm512_mask_storeu_ps(p, ((1u32 << n) - 1) as __mmask16, v) }
            }
        )
    }

    /// [`Self::tile`] for a group of at most 8 columns, on 8-lane registers (on Zen 4 an 8-lane
    /// FMA costs half a 16-lane one; elsewhere the same as a half-empty 16-lane one).
    ///
    /// # Safety
    /// AVX-512F and VL; `ox + MR ≤ wo` for the `wo` of [`Self::row`]'s checks.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile8<const MR: usize>(&self, a: &[f32], dst: &mut [f32], ox: usize) {
        use std::arch::x86_64::*;
        tile_body!(
            self,
            a,
            dst,
            ox,
            MR,
            1,
            8,
            __m256,
            _mm256_setzero_ps,
            _mm256_loadu_ps,
            _mm256_set1_ps,
            _mm256_fmadd_ps,
            |p, n: usize, v| {
                // SAFETY: the caller passes n writable lanes at p.
                unsafe { _mm256_mask_storeu_ps(p, ((1u32 << n) - 1) as __mmask8, v) }
            }
        )
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn tile<const MR: usize, const NB: usize>(&self, _: &[f32], _: &mut [f32], _: usize) {
        unreachable!("direct convolution only where available()")
    }

    #[cfg(not(target_arch = "x86_64"))]
    unsafe fn tile8<const MR: usize>(&self, _: &[f32], _: &mut [f32], _: usize) {
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
        assert_eq!(column_groups(28), vec![0..28]);
        assert_eq!(column_groups(36), vec![0..32, 32..36]);
        assert_eq!(column_groups(64), vec![0..64]);
        assert_eq!(column_groups(72), vec![0..64, 64..72]);
        assert_eq!(column_groups(88), vec![0..48, 48..80, 80..88]);
        assert_eq!(column_groups(160), vec![0..64, 64..112, 112..160]);
        assert_eq!(tile_starts(30, 12).collect::<Vec<_>>(), vec![0, 12, 18]);
        assert_eq!(tile_starts(24, 12).collect::<Vec<_>>(), vec![0, 12]);
    }

    #[test]
    fn direct_conv_matches_im2col_gemm() {
        if !available() {
            eprintln!("no AVX-512F/VL: direct convolution not tested");
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
            (3, 1, 8, 8, 12, 5, 40),
            (3, 2, 8, 8, 88, 9, 31),
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
