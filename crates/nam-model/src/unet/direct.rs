//! Direct k×k convolution on AVX-512F/VL, the fast path of [`PackedConv::run_rows`] on CPUs that
//! have it: no im2col and no GEMM packing. Each band of output rows copies the input rows it
//! reads once into a replicate-padded buffer; a register tile of `MR` output pixels × `NB`
//! 16-lane blocks of output channels then sums every tap and input channel before it is
//! stored (weights `[tap][ci][cout padded to 16]`, repacked per call: `run_with` rescales them).
//! The same sums as the im2col path in another order: `DIRECT_TOL` in the tests. With bf16
//! operands ([`UNet::with_bf16`](super::UNet::with_bf16), CPUs with AVX-512 BF16) the input
//! band and the weights are rounded to bf16 pairs of input channels and each `vdpbf16ps` sums two
//! products into f32: twice the products per instruction.
#![allow(unsafe_code)]
// Elsewhere only `available()` is reachable (false): the kernels are x86-64 code.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

use std::ops::Range;

use rayon::prelude::*;

use super::conv::{Hwc, PackedConv, min_len};
use crate::bf16::to_bf16;

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

/// True when this CPU runs the direct convolution on bf16 operands (AVX-512 BF16 as well).
pub(super) fn available_bf16() -> bool {
    available() && crate::bf16::bf16_supported()
}

/// Output rows per band (per rayon task) for `rows` output rows of a stride-`s` conv over an
/// input `w_in` wide: about [`BAND_PIXELS`] input pixels, and at least four bands per thread
/// where there are enough rows — unless the conv runs on this thread alone
/// ([`super::conv::on_this_thread`]): then more bands would only convert more halo rows.
pub(super) fn band_rows(w_in: usize, s: usize, rows: usize) -> usize {
    let most = (BAND_PIXELS / (w_in * s)).max(1);
    let per_thread = if super::conv::alone() {
        rows
    } else {
        rows.div_ceil(4 * rayon::current_num_threads())
    };
    most.clamp(1, per_thread.max(1))
}

/// Floats of one thread's padded input band, at most, for a k×k conv over an input `w_in` wide
/// with `cin` channels (any stride: a band reads about [`BAND_PIXELS`] input pixels).
pub(super) fn scratch_floats(w_in: usize, k: usize, cin: usize) -> usize {
    ((BAND_PIXELS / w_in).max(1) + k - 1) * (w_in + k - 1) * cin
}

/// Output rows `rows` of `conv` applied to `x` with weights `wt` (packed as `conv.wt`), the
/// values of [`PackedConv::run_rows`], with f32 products (`bf16`: bf16 ones, f32 sums). Only
/// where [`available`] (`bf16`: [`available_bf16`]).
pub(super) fn run_rows(
    conv: &PackedConv,
    x: &Hwc,
    wt: &[f32],
    rows: Range<usize>,
    bf16: bool,
) -> Hwc {
    #[cfg(target_arch = "x86_64")]
    if bf16 {
        assert!(
            available_bf16(),
            "bf16 direct convolution without AVX-512 BF16"
        );
        run_rows_with::<Bf16Pair>(conv, x, wt, rows)
    } else {
        assert!(available(), "direct convolution without AVX-512F/VL");
        run_rows_with::<f32>(conv, x, wt, rows)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (conv, x, wt, rows, bf16);
        unreachable!("direct convolution only where available()")
    }
}

fn run_rows_with<E: Operand>(conv: &PackedConv, x: &Hwc, wt: &[f32], rows: Range<usize>) -> Hwc {
    assert!(conv.cin <= x.c && wt.len() == conv.k * conv.k * conv.cin * conv.cout);
    let (ho, wo) = conv.out_size(x);
    assert!(rows.end <= ho);
    let (k, s, cin, cout) = (conv.k, conv.stride, conv.cin, conv.cout);
    // Operand elements per padded-input pixel.
    let ce = E::per_pixel(cin);
    let groups = column_groups(cout);
    let packed: Vec<Vec<E>> = groups
        .iter()
        .map(|g| E::pack(wt, cin, cout, g.clone()))
        .collect();
    // Padded input columns: output column ox, tap kx reads column ox·s + kx.
    let wp = (wo - 1) * s + k;
    let band = band_rows(x.w, s, rows.len());
    let mut out = vec![0.0f32; rows.len() * wo * cout];
    let first = rows.start;
    out.par_chunks_mut(band * wo * cout)
        .with_min_len(min_len())
        .enumerate()
        .for_each_init(Vec::new, |pad: &mut Vec<E>, (b, dst)| {
            let oy0 = first + b * band;
            let n_rows = dst.len() / (wo * cout);
            let in_rows = (n_rows - 1) * s + k;
            pad.resize(in_rows * wp * ce, E::default());
            for py in 0..in_rows {
                let iy = (oy0 * s + py).saturating_sub(conv.pad).min(x.h - 1);
                for px in 0..wp {
                    let ix = px.saturating_sub(conv.pad).min(x.w - 1);
                    let src = (iy * x.w + ix) * x.c;
                    let d = (py * wp + px) * ce;
                    E::put(&mut pad[d..d + ce], &x.d[src..src + cin]);
                }
            }
            let taps: Vec<usize> = (0..k * k).map(|t| ((t / k) * wp + t % k) * ce).collect();
            for r in 0..n_rows {
                let a_row = r * s * wp * ce;
                let d_row = r * wo * cout;
                for (g, w) in groups.iter().zip(&packed) {
                    let tile = Tile {
                        taps: &taps,
                        ce,
                        px_step: s * ce,
                        w,
                        cols: g.clone(),
                        cout,
                    };
                    // SAFETY: the operand's CPU features were asserted; `tile.row` checks that
                    // its reads stay inside `pad` and its writes inside this row of `dst`.
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

/// The register tiles as a pixel-major GEMM, `dst[p][..cout] = Σ_e a[p][e]·w[e][..cout]` for
/// `w` = `[cin, cout]`, packed once for many rows (the products of `winograd.rs`).
pub(super) struct Gemm {
    cin: usize,
    cout: usize,
    groups: Vec<Range<usize>>,
    packed: Vec<Vec<f32>>,
}

impl Gemm {
    /// All-zero weights of `cin` rows and `cout` columns, in the tiles' layout (fill them with
    /// [`Self::row_mut`]).
    pub(super) fn zeroed(cin: usize, cout: usize) -> Self {
        let groups = column_groups(cout);
        let packed = groups
            .iter()
            .map(|g| vec![0.0f32; cin * g.len().next_multiple_of(lanes(g))])
            .collect();
        Self {
            cin,
            cout,
            groups,
            packed,
        }
    }

    /// Row `e` of the weights, per column group: `(columns, their values)`.
    pub(super) fn row_mut(&mut self, e: usize) -> impl Iterator<Item = (Range<usize>, &mut [f32])> {
        self.groups.iter().zip(&mut self.packed).map(move |(g, p)| {
            let ld = g.len().next_multiple_of(lanes(g));
            (g.clone(), &mut p[e * ld..e * ld + g.len()])
        })
    }

    /// Writes `dst` (`n·cout`) from the `n` rows of `a` (`n·cin`). Only where [`available`].
    pub(super) fn run(&self, a: &[f32], n: usize, dst: &mut [f32]) {
        assert!(available(), "direct GEMM without AVX-512F/VL");
        assert!(n > 0 && a.len() >= n * self.cin && dst.len() >= n * self.cout);
        #[cfg(target_arch = "x86_64")]
        for (g, w) in self.groups.iter().zip(&self.packed) {
            let tile = Tile {
                taps: &[0],
                ce: self.cin,
                px_step: self.cin,
                w,
                cols: g.clone(),
                cout: self.cout,
            };
            // SAFETY: AVX-512F/VL asserted; `tile.row` checks its bounds.
            unsafe { tile.row(a, dst, n) };
        }
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
pub(super) fn tile_starts(wo: usize, mr: usize) -> impl Iterator<Item = usize> {
    (0..wo.div_ceil(mr)).map(move |i| (i * mr).min(wo - mr))
}

/// An operand of the direct convolution's products: f32, or a pair of input channels as bf16.
trait Operand: Copy + Default + Send + Sync {
    /// Elements per pixel for `cin` channels.
    fn per_pixel(cin: usize) -> usize;
    /// One pixel's channels `src` as elements.
    fn put(dst: &mut [Self], src: &[f32]);
    /// Columns `cols` of `wt` (`[taps·cin, cout]`) as `[taps·per_pixel(cin), cols padded to
    /// whole vectors]`.
    fn pack(wt: &[f32], cin: usize, cout: usize, cols: Range<usize>) -> Vec<Self>;
    /// `MR` pixels from `ox` × `NB` vectors of 16 columns ([`Tile::runs`]).
    ///
    /// # Safety
    /// The CPU features of this operand; `ox + MR ≤ wo` for the `wo` of [`Tile::row`]'s checks.
    unsafe fn tile<const MR: usize, const NB: usize>(
        t: &Tile<'_, Self>,
        a: &[Self],
        dst: &mut [f32],
        ox: usize,
    );
    /// [`Self::tile`] for a group of at most 8 columns, on 8-lane registers (on Zen 4 an 8-lane
    /// FMA costs half a 16-lane one; elsewhere the same as a half-empty 16-lane one).
    ///
    /// # Safety
    /// As [`Self::tile`].
    unsafe fn tile8<const MR: usize>(t: &Tile<'_, Self>, a: &[Self], dst: &mut [f32], ox: usize);
}

/// Two input channels `2p, 2p + 1` as bf16 (round to nearest even), low half first; an odd
/// channel count pads with 0.
#[derive(Debug, Clone, Copy, Default)]
struct Bf16Pair(u32);

impl Bf16Pair {
    fn of(v: &[f32]) -> Self {
        Self(to_bf16(v[0]) | v.get(1).map_or(0, |&h| to_bf16(h) << 16))
    }
}

/// Columns `cols` of the rows of `wt` (`cout` values each) in [`Operand::pack`]'s f32 layout:
/// each row's slice of columns, padded to whole vectors.
fn pack_f32(wt: &[f32], cout: usize, cols: Range<usize>) -> Vec<f32> {
    let ld = cols.len().next_multiple_of(lanes(&cols));
    let mut p = vec![0.0f32; wt.len() / cout * ld];
    for (dst, src) in p.chunks_exact_mut(ld).zip(wt.chunks_exact(cout)) {
        dst[..cols.len()].copy_from_slice(&src[cols.clone()]);
    }
    p
}

/// Columns `cols` of `wt` in [`Operand::pack`]'s layout, `group` rows of `wt` per element.
fn pack_with<E: Copy + Default>(
    wt: &[f32],
    (cin, cout, cols): (usize, usize, Range<usize>),
    group: usize,
    element: impl Fn(&[f32]) -> E,
) -> Vec<E> {
    let ld = cols.len().next_multiple_of(lanes(&cols));
    let per_tap = cin.div_ceil(group);
    let taps = wt.len() / (cin * cout);
    let mut p = vec![E::default(); taps * per_tap * ld];
    let mut vals = Vec::with_capacity(group);
    for t in 0..taps {
        for e in 0..per_tap {
            let row = &mut p[(t * per_tap + e) * ld..][..cols.len()];
            for (o, d) in cols.clone().zip(row) {
                vals.clear();
                let chans = e * group..((e + 1) * group).min(cin);
                vals.extend(chans.map(|ci| wt[(t * cin + ci) * cout + o]));
                *d = element(&vals);
            }
        }
    }
    p
}

/// The register tile of [`Operand::tile`] over one vector width: `MR` pixels × `NB` vectors of
/// `L` lanes (f32 accumulators), summed over every tap and operand element, then stored (the last
/// vector masked to the group's columns). `$load`, `$set1` and `$fma` build the products.
#[cfg(target_arch = "x86_64")]
macro_rules! tile_body {
    ($t:ident, $a:ident, $dst:ident, $ox:ident, $mr:expr, $nb:expr, $l:expr, $w:ty, $zero:expr,
     $load:expr, $set1:expr, $fma:expr, $store:expr) => {{
        let ld = $t.ld();
        let mut acc = [[$zero; $nb]; $mr];
        let a0 = $a.as_ptr();
        let base = $ox * $t.px_step;
        let mut wp = $t.w.as_ptr();
        for &tap in $t.taps {
            // SAFETY: pixel p reads a[base + p·px_step + tap + e] below the checked `last`.
            let at = unsafe { a0.add(base + tap) };
            for e in 0..$t.ce {
                // SAFETY: `wp` walks the taps·ce rows of `ld` elements of the group's weights.
                let wv: [$w; $nb] = std::array::from_fn(|b| unsafe { $load(wp.add(b * $l)) });
                for r in 0..$mr {
                    let av = $set1(unsafe { *at.add(r * $t.px_step + e) });
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

/// Masked stores of the first `n` lanes, as `tile_body!` calls them.
#[cfg(target_arch = "x86_64")]
mod store {
    use std::arch::x86_64::*;

    /// # Safety
    /// AVX-512F; `n ≤ 16` lanes writable at `p`.
    #[inline]
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn lanes16(p: *mut f32, n: usize, v: __m512) {
        // SAFETY: the caller's contract.
        unsafe { _mm512_mask_storeu_ps(p, crate::simd::lanes(n), v) }
    }

    /// # Safety
    /// AVX-512F/VL; `n ≤ 8` lanes writable at `p`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl")]
    pub(super) unsafe fn lanes8(p: *mut f32, n: usize, v: __m256) {
        // SAFETY: the caller's contract.
        unsafe { _mm256_mask_storeu_ps(p, ((1u32 << n) - 1) as __mmask8, v) }
    }
}

#[cfg(target_arch = "x86_64")]
impl Operand for f32 {
    fn per_pixel(cin: usize) -> usize {
        cin
    }

    fn put(dst: &mut [Self], src: &[f32]) {
        dst.copy_from_slice(src);
    }

    fn pack(wt: &[f32], _cin: usize, cout: usize, cols: Range<usize>) -> Vec<Self> {
        pack_f32(wt, cout, cols)
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile<const MR: usize, const NB: usize>(
        t: &Tile<'_, Self>,
        a: &[Self],
        dst: &mut [f32],
        ox: usize,
    ) {
        use std::arch::x86_64::*;
        tile_body!(
            t,
            a,
            dst,
            ox,
            MR,
            NB,
            16,
            __m512,
            _mm512_setzero_ps(),
            |p| _mm512_loadu_ps(p),
            _mm512_set1_ps,
            _mm512_fmadd_ps,
            |p, n, v| unsafe { store::lanes16(p, n, v) }
        )
    }

    #[target_feature(enable = "avx512f,avx512vl")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile8<const MR: usize>(t: &Tile<'_, Self>, a: &[Self], dst: &mut [f32], ox: usize) {
        use std::arch::x86_64::*;
        tile_body!(
            t,
            a,
            dst,
            ox,
            MR,
            1,
            8,
            __m256,
            _mm256_setzero_ps(),
            |p| _mm256_loadu_ps(p),
            _mm256_set1_ps,
            _mm256_fmadd_ps,
            |p, n, v| unsafe { store::lanes8(p, n, v) }
        )
    }
}

#[cfg(target_arch = "x86_64")]
impl Operand for Bf16Pair {
    fn per_pixel(cin: usize) -> usize {
        cin.div_ceil(2)
    }

    fn put(dst: &mut [Self], src: &[f32]) {
        for (d, pair) in dst.iter_mut().zip(src.chunks(2)) {
            *d = Self::of(pair);
        }
    }

    fn pack(wt: &[f32], cin: usize, cout: usize, cols: Range<usize>) -> Vec<Self> {
        pack_with(wt, (cin, cout, cols), 2, Self::of)
    }

    #[target_feature(enable = "avx512f,avx512bf16")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile<const MR: usize, const NB: usize>(
        t: &Tile<'_, Self>,
        a: &[Self],
        dst: &mut [f32],
        ox: usize,
    ) {
        use std::arch::x86_64::*;
        tile_body!(
            t,
            a,
            dst,
            ox,
            MR,
            NB,
            16,
            __m512bh,
            _mm512_setzero_ps(),
            // (`tile_body!` calls the load inside its own `unsafe` block.)
            |p: *const Bf16Pair| std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(
                p.cast()
            )),
            |v: Bf16Pair| unsafe {
                std::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32(v.0 as i32))
            },
            |a, w, acc| _mm512_dpbf16_ps(acc, a, w),
            |p, n, v| unsafe { store::lanes16(p, n, v) }
        )
    }

    #[target_feature(enable = "avx512f,avx512vl,avx512bf16")]
    #[allow(clippy::needless_range_loop)]
    unsafe fn tile8<const MR: usize>(t: &Tile<'_, Self>, a: &[Self], dst: &mut [f32], ox: usize) {
        use std::arch::x86_64::*;
        tile_body!(
            t,
            a,
            dst,
            ox,
            MR,
            1,
            8,
            __m256bh,
            _mm256_setzero_ps(),
            // (`tile_body!` calls the load inside its own `unsafe` block.)
            |p: *const Bf16Pair| std::mem::transmute::<__m256i, __m256bh>(_mm256_loadu_si256(
                p.cast()
            )),
            |v: Bf16Pair| unsafe {
                std::mem::transmute::<__m256i, __m256bh>(_mm256_set1_epi32(v.0 as i32))
            },
            |a, w, acc| _mm256_dpbf16_ps(acc, a, w),
            |p, n, v| unsafe { store::lanes8(p, n, v) }
        )
    }
}

/// One group of output columns over one output row.
struct Tile<'a, E> {
    /// Offset of each tap `(ky, kx)` in the padded input, from a pixel's first tap.
    taps: &'a [usize],
    /// Operand elements per pixel ([`Operand::per_pixel`]).
    ce: usize,
    /// Padded-input elements between two neighbouring output pixels (stride · ce).
    px_step: usize,
    /// This group's weights, `[tap][element][columns padded to whole vectors]`.
    w: &'a [E],
    cols: Range<usize>,
    cout: usize,
}

impl<E: Operand> Tile<'_, E> {
    /// Writes columns `self.cols` of the `wo` pixels of one output row (`dst`, `wo·cout`) from
    /// the padded input starting at that row's first tap (`a`).
    ///
    /// # Safety
    /// The CPU features of the operand `E` ([`available`], [`available_bf16`]).
    unsafe fn row(&self, a: &[E], dst: &mut [f32], wo: usize) {
        assert!(dst.len() >= wo * self.cout);
        let last = (wo - 1) * self.px_step + self.taps.last().copied().unwrap_or(0) + self.ce;
        assert!(a.len() >= last && self.w.len() >= self.taps.len() * self.ce * self.ld());
        // SAFETY (all calls): bounds asserted above; CPU features by this fn's contract.
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

    /// Elements per weight row of this group: its columns padded to whole vectors.
    fn ld(&self) -> usize {
        self.cols.len().next_multiple_of(lanes(&self.cols))
    }

    /// Tiles of `MR` pixels along the row ([`tile_starts`]); rows narrower than `MR` run one
    /// pixel at a time.
    ///
    /// # Safety
    /// As [`Self::row`], with its bounds checked.
    unsafe fn runs<const MR: usize, const NB: usize>(&self, a: &[E], dst: &mut [f32], wo: usize) {
        // SAFETY (both loops): every tile's pixels lie below wo, within the checked bounds.
        if wo < MR {
            (0..wo).for_each(|ox| unsafe { E::tile::<1, NB>(self, a, dst, ox) });
        } else {
            tile_starts(wo, MR).for_each(|ox| unsafe { E::tile::<MR, NB>(self, a, dst, ox) });
        }
    }

    /// [`Self::runs`] on 8-lane registers ([`Operand::tile8`]).
    ///
    /// # Safety
    /// As [`Self::row`], with its bounds checked.
    unsafe fn runs8<const MR: usize>(&self, a: &[E], dst: &mut [f32], wo: usize) {
        // SAFETY (both loops): every tile's pixels lie below wo, within the checked bounds.
        if wo < MR {
            (0..wo).for_each(|ox| unsafe { E::tile8::<1>(self, a, dst, ox) });
        } else {
            tile_starts(wo, MR).for_each(|ox| unsafe { E::tile8::<MR>(self, a, dst, ox) });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::unet::conv::fixtures::{CASES, DIRECT_TOL, case, round_bf16, worst_rel};

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
    fn direct_conv_matches_im2col_gemm_and_bf16_matches_it_on_rounded_operands() {
        if !available() {
            eprintln!("no AVX-512F/VL: direct convolution not tested");
            return;
        }
        for (n, &(k, s, cin, xc, cout, h, w)) in CASES.iter().enumerate() {
            let (conv, x) = case((k, s, cin, xc, cout), (h, w), n);
            let (ho, _) = conv.out_size(&x);
            for rows in [0..ho, ho / 3..ho, 0..ho.div_ceil(2)] {
                if rows.is_empty() {
                    continue;
                }
                let want = conv.im2col_rows(&x, &conv.wt, rows.clone());
                let got = run_rows(&conv, &x, &conv.wt, rows.clone(), false);
                let worst = worst_rel(&got, &want);
                assert!(worst < DIRECT_TOL, "case {n}, rows {rows:?}: {worst:e}");
                if available_bf16() {
                    // bf16 products of bf16-rounded operands are exact in f32: the same sums
                    // as f32 products of the rounded operands.
                    let xr = Hwc {
                        d: round_bf16(&x.d),
                        ..x.clone()
                    };
                    let want = conv.im2col_rows(&xr, &round_bf16(&conv.wt), rows.clone());
                    let got = run_rows(&conv, &x, &conv.wt, rows.clone(), true);
                    let worst = worst_rel(&got, &want);
                    assert!(
                        worst < DIRECT_TOL,
                        "bf16 case {n}, rows {rows:?}: {worst:e}"
                    );
                }
            }
        }
    }
}
