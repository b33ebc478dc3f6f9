//! bf16 k×k convolution on AMX tiles (Xeon Sapphire Rapids and later): the bf16 path of
//! [`PackedConv::run_rows`] where the CPU has AMX-BF16 ([`UNet::with_bf16`](super::UNet::with_bf16)).
//!
//! No im2col copy: as on the direct path, a band of output rows copies the input rows it reads
//! once into a replicate-padded buffer, here of bf16 pairs of input channels (`[row][column]
//! [⌈cin/2⌉ pairs]`). For one kernel row `ky` the `k` taps of an output pixel then read
//! `k·⌈cin/2⌉` consecutive pairs, and the next pixel's start `stride·⌈cin/2⌉` pairs later, so an
//! AMX A tile (16 pixels × 16 pairs) is one strided `tileloadd` from the band: the im2col matrix
//! read in place. The weights are `[ky][kx·⌈cin/2⌉ + pair, padded to 16 pairs][cout padded to
//! 32]` with zeros in the padding, so the pairs an A tile reads past a pixel's span (its right
//! neighbours: finite values) add nothing. Each 32 × 32 block (two tiles of 16 pixels × 32 output
//! channels) sums every kernel row and pair with `tdpbf16ps` (bf16 products, f32 sums: the
//! arithmetic of the `vdpbf16ps` path in another order) and is stored once.
#![allow(unsafe_code)]
// Elsewhere only `available()` is reachable (false): the kernel is x86-64 code.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

#[cfg(target_arch = "x86_64")]
use std::mem::MaybeUninit;
use std::ops::Range;

#[cfg(target_arch = "x86_64")]
use rayon::prelude::*;

use super::conv::{Hwc, PackedConv};
#[cfg(target_arch = "x86_64")]
use super::conv::{min_len, written};
use super::direct;
use crate::amx::{self, K_PAIRS, N_BLOCK, TILE};
use crate::bf16::to_bf16;
use crate::simd::{self, LINE_WORDS, Line};

/// True when this CPU runs the bf16 convolution on AMX tiles (AMX-BF16 granted by the OS, and
/// the AVX-512 BF16 that packs the operands).
pub(super) fn available() -> bool {
    direct::available_bf16() && amx::available()
}

/// One conv's shape on the tiles; sizes in bf16 pairs (`u32`) unless said otherwise.
struct Shape {
    k: usize,
    stride: usize,
    /// Pairs per padded-input pixel, `⌈cin/2⌉`.
    cp: usize,
    /// Pairs per kernel row of the weights: `k·cp` padded to whole tiles ([`K_PAIRS`]).
    kd: usize,
    cout: usize,
    /// At most 16 output columns: blocks of 64 pixels × 16 columns ([`amx::dot_column`]), not
    /// 32 × 32 ([`amx::dot_block`]), so that fewer padding columns are summed.
    narrow: bool,
    /// Output columns of the weights: `cout` padded to whole blocks (16 when narrow, else a
    /// multiple of [`N_BLOCK`]).
    op: usize,
    /// Output pixels per row.
    wo: usize,
    /// Padded-input pixels per row, `(wo − 1)·stride + k`.
    wp: usize,
}

impl Shape {
    fn new(conv: &PackedConv, wo: usize) -> Self {
        let cp = conv.cin.div_ceil(2);
        let narrow = conv.cout <= TILE;
        Self {
            k: conv.k,
            stride: conv.stride,
            cp,
            kd: (conv.k * cp).next_multiple_of(K_PAIRS),
            cout: conv.cout,
            narrow,
            op: if narrow {
                TILE
            } else {
                conv.cout.next_multiple_of(N_BLOCK)
            },
            wo,
            wp: (wo - 1) * conv.stride + conv.k,
        }
    }

    /// `wt` (`[k·k·cin, cout]`, [`PackedConv`]'s layout) as the B operand: row `ky·kd + kx·cp +
    /// ci/2` holds input channel `ci` of tap `(ky, kx)` in the bf16 half `ci % 2`, zero elsewhere.
    fn pack(&self, wt: &[f32], cin: usize) -> Vec<Line> {
        let mut lines = Vec::new();
        let w = simd::filled(&mut lines, self.k * self.kd * self.op, 0);
        for (t, tap) in wt.chunks_exact(cin * self.cout).enumerate() {
            let (ky, kx) = (t / self.k, t % self.k);
            for (ci, row) in tap.chunks_exact(self.cout).enumerate() {
                let at = (ky * self.kd + kx * self.cp + ci / 2) * self.op;
                let shift = 16 * (ci % 2);
                for (d, &v) in w[at..at + self.cout].iter_mut().zip(row) {
                    *d |= to_bf16(v) << shift;
                }
            }
        }
        lines
    }

    /// Pairs of a band's padded input for `n_rows` output rows, with the slack its last tiles
    /// read past it: up to 16 pixels past a row narrower than a tile, and the padding of the
    /// last kernel row's span.
    fn pad_len(&self, n_rows: usize) -> usize {
        ((n_rows - 1) * self.stride + self.k) * self.wp * self.cp
            + TILE * self.stride * self.cp
            + K_PAIRS
    }

    /// Writes every value of the `n_rows` output rows of a band (`dst`, `n_rows·wo·cout`) from
    /// its padded input `pad` ([`Self::pad_len`]) and the packed weights `w` ([`Self::pack`]):
    /// the tiles cover every pixel of every row, the blocks every column.
    ///
    /// # Safety
    /// [`available`].
    #[cfg(target_arch = "x86_64")]
    unsafe fn band(&self, pad: &[u32], w: &[u32], dst: &mut [MaybeUninit<f32>], n_rows: usize) {
        let &Self {
            k,
            stride: s,
            cp,
            kd,
            cout,
            narrow,
            op,
            wo,
            wp,
        } = self;
        // Tiles of 16 pixels along each row (the last one overlapping its neighbour; one
        // partly filled tile for a row narrower than that), taken two (narrow: four) at a time.
        let starts: Vec<usize> = if wo >= TILE {
            direct::tile_starts(wo, TILE).collect()
        } else {
            vec![0]
        };
        let mut tiles: Vec<(usize, usize)> = (0..n_rows)
            .flat_map(|r| starts.iter().map(move |&ox| (r, ox)))
            .collect();
        let (group, block_cols, sums) = if narrow {
            (4, TILE, &amx::COLUMN_SUMS)
        } else {
            (2, N_BLOCK, &amx::SUMS)
        };
        while !tiles.len().is_multiple_of(group) {
            tiles.push(tiles[tiles.len() - 1]);
        }
        // Every A tile lies inside `pad` (the last one reads farthest), every B tile inside `w`.
        let (r_last, ox_last) = tiles[tiles.len() - 1];
        let far = ((r_last * s + k - 1) * wp + (ox_last + TILE - 1) * s) * cp + kd;
        assert!(far <= pad.len() && w.len() >= k * kd * op && dst.len() >= n_rows * wo * cout);
        let (sa, sb) = (4 * s * cp, 4 * op);
        let mut c = [[0.0f32; TILE]; TILE];
        // SAFETY (all calls below): AMX by this fn's contract; the tile loads stay inside `pad`
        // and `w` by the checks above, the stores inside `dst` (a whole 16 × 16 tile only where
        // its pixels and columns exist) or `c`.
        unsafe { amx::configure() };
        for set in tiles.chunks_exact(group) {
            let a: [*const u32; 4] = std::array::from_fn(|i| {
                let (r, ox) = set[i.min(group - 1)];
                pad[(r * s * wp + ox * s) * cp..].as_ptr()
            });
            for o0 in (0..cout).step_by(block_cols) {
                unsafe { amx::zero_block() };
                for ky in 0..k {
                    for j0 in (0..kd).step_by(K_PAIRS) {
                        let off = ky * wp * cp + j0;
                        let b = w[(ky * kd + j0) * op + o0..].as_ptr();
                        let a = a.map(|p| unsafe { p.add(off) });
                        unsafe {
                            if narrow {
                                amx::dot_column(a, sa, b, sb);
                            } else {
                                amx::dot_block([a[0], a[1]], sa, [b, b.add(TILE)], sb);
                            }
                        }
                    }
                }
                for (t, &(di, dj)) in sums.iter().enumerate() {
                    let ((r, ox), o) = (set[di / TILE], o0 + dj);
                    if o >= cout {
                        continue;
                    }
                    let (pixels, cols) = ((wo - ox).min(TILE), (cout - o).min(TILE));
                    let at = (r * wo + ox) * cout + o;
                    if pixels == TILE && cols == TILE {
                        unsafe { amx::store_sum(t, dst[at..].as_mut_ptr().cast(), 4 * cout) };
                    } else {
                        unsafe { amx::store_sum(t, c.as_mut_ptr().cast(), 4 * TILE) };
                        for (i, row) in c.iter().enumerate().take(pixels) {
                            let d = &mut dst[at + i * cout..][..cols];
                            d.iter_mut().zip(row).for_each(|(d, &v)| {
                                d.write(v);
                            });
                        }
                    }
                }
            }
        }
        unsafe { amx::release() };
    }
}

/// The weights `wt` of `conv` (packed as `conv.wt`) as [`run_rows`] reads them, once for any
/// number of calls (the packing does not depend on the image).
pub(super) fn pack_weights(conv: &PackedConv, wt: &[f32]) -> Vec<Line> {
    assert_eq!(wt.len(), conv.k * conv.k * conv.cin * conv.cout);
    Shape::new(conv, 1).pack(wt, conv.cin)
}

/// Output rows `rows` of `conv` applied to `x` with weights `w` ([`pack_weights`]), the values
/// of [`PackedConv::run_rows`] with bf16 products and f32 sums. Only where [`available`].
pub(super) fn run_rows(conv: &PackedConv, x: &Hwc, w: &[Line], rows: Range<usize>) -> Hwc {
    assert!(available(), "AMX convolution without AMX-BF16");
    #[cfg(target_arch = "x86_64")]
    {
        run_rows_x86(conv, x, simd::words(w), rows)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (conv, x, w, rows);
        unreachable!("AMX convolution only where available()")
    }
}

#[cfg(target_arch = "x86_64")]
fn run_rows_x86(conv: &PackedConv, x: &Hwc, w: &[u32], rows: Range<usize>) -> Hwc {
    let (k, s, cin, cout) = (conv.k, conv.stride, conv.cin, conv.cout);
    assert!(cin <= x.c);
    let (ho, wo) = conv.out_size(x);
    assert!(rows.end <= ho);
    let shape = Shape::new(conv, wo);
    let band = direct::band_rows(x.w, s, rows.len());
    let n = rows.len() * wo * cout;
    let first = rows.start;
    let fill = |out: &mut [MaybeUninit<f32>]| {
        out.par_chunks_mut(band * wo * cout)
            .with_min_len(min_len())
            .enumerate()
            .for_each_init(Vec::new, |lines: &mut Vec<Line>, (b, dst)| {
                let oy0 = first + b * band;
                let n_rows = dst.len() / (wo * cout);
                // Pairs written by earlier bands of this thread stay: finite values, read only
                // against zero weights or into discarded sums. Whole lines: where `cp` is a
                // multiple of 16 pairs, every tile row read from the band starts a line.
                lines.resize(shape.pad_len(n_rows).div_ceil(LINE_WORDS), Line::default());
                let pad = simd::words_mut(lines);
                let (cp, wp, p) = (shape.cp, shape.wp, conv.pad);
                // Input columns of a padded row: [p, p + inner) read x columns 0.., the rest repeat
                // the first or the last.
                let inner = x.w.min(wp - p);
                let row_len = wp * cp;
                for py in 0..(n_rows - 1) * s + k {
                    let iy = (oy0 * s + py).saturating_sub(p).min(x.h - 1);
                    let at = py * row_len;
                    if py > 0 && iy == (oy0 * s + py - 1).saturating_sub(p).min(x.h - 1) {
                        // The same input row as the last one (the top or bottom padding).
                        pad.copy_within(at - row_len..at, at);
                        continue;
                    }
                    let (src, dst) = (&x.d[iy * x.w * x.c..], &mut pad[at..at + row_len]);
                    // SAFETY (both): AVX-512 BF16 (`available`); each destination holds the pairs
                    // of its source values.
                    if x.c == cin && cin.is_multiple_of(2) {
                        // Whole pixels of pairs: the row's inner columns convert as one run.
                        unsafe {
                            crate::bf16::pack_row_avx512(
                                &src[..inner * cin],
                                &mut dst[p * cp..(p + inner) * cp],
                            );
                        }
                    } else {
                        let d = &mut dst[p * cp..(p + inner) * cp];
                        unsafe { crate::bf16::pack_pixels_avx512(src, x.c, cin, d) };
                    }
                    for px in (0..p).chain(p + inner..wp) {
                        let from = px.saturating_sub(p).min(x.w - 1) + p;
                        dst.copy_within(from * cp..(from + 1) * cp, px * cp);
                    }
                }
                // SAFETY: AMX (`available`, asserted by the caller).
                unsafe { shape.band(pad, w, dst, n_rows) };
            });
    };
    // SAFETY: the bands cover the `n` values, and `Shape::band` writes each of its band's.
    let (out, ()) = unsafe { written(n, fill) };
    Hwc {
        h: rows.len(),
        w: wo,
        c: cout,
        d: out,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::unet::conv::fixtures::{CASES, DIRECT_TOL, case, round_bf16, worst_rel};

    #[test]
    fn amx_conv_matches_im2col_gemm_on_bf16_rounded_operands() {
        if !available() {
            eprintln!("no AMX-BF16: the AMX convolution not tested");
            return;
        }
        // The kernel cases, and: rows that end in an overlapping tile, an odd number of tiles,
        // output channels short of a block.
        let more = [(3, 1, 64, 64, 224, 16, 16), (7, 1, 12, 12, 64, 3, 33)];
        for (n, &(k, s, cin, xc, cout, h, w)) in CASES.iter().chain(&more).enumerate() {
            let (conv, x) = case((k, s, cin, xc, cout), (h, w), n);
            let (ho, _) = conv.out_size(&x);
            let xr = Hwc {
                d: round_bf16(&x.d),
                ..x.clone()
            };
            for rows in [0..ho, ho / 3..ho, 0..ho.div_ceil(2)] {
                if rows.is_empty() {
                    continue;
                }
                // bf16 products of bf16-rounded operands are exact in f32: the same sums as f32
                // products of the rounded operands.
                let want = conv.im2col_rows(&xr, &round_bf16(&conv.wt), rows.clone());
                let got = run_rows(&conv, &x, &pack_weights(&conv, &conv.wt), rows.clone());
                let worst = worst_rel(&got, &want);
                assert!(worst < DIRECT_TOL, "case {n}, rows {rows:?}: {worst:e}");
            }
        }
    }
}
