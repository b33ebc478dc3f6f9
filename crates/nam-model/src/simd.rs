//! AVX-512 pieces and line-aligned operand buffers shared by the reduced-precision kernels
//! ([`crate::bf16`], [`crate::int8`], [`crate::amx`]).
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::{__m512, __mmask16, _mm512_mask_storeu_ps, _mm512_max_ps, _mm512_mul_ps};

/// Lanes `0..min(left, 16)` of a 16-lane vector.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn lanes(left: usize) -> __mmask16 {
    ((1u32 << left.min(16)) - 1) as __mmask16
}

/// Stores LeakyReLU(`v`) — `max(v, slope·v)`, exact for a slope in [0, 1] (1: identity) — to the
/// `mask` lanes at `dst`.
///
/// # Safety
/// AVX-512F must be available, and the `mask` lanes of `dst` writable.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn store_leaky(dst: *mut f32, mask: __mmask16, v: __m512, slope: __m512) {
    let v = _mm512_max_ps(v, _mm512_mul_ps(v, slope));
    // SAFETY: the caller guarantees the masked lanes are writable.
    unsafe { _mm512_mask_storeu_ps(dst, mask, v) }
}

/// Words (`u32`: bf16 pairs, int8 quads) per [`Line`].
pub(crate) const LINE_WORDS: usize = 16;

/// One 64-byte cache line of packed operands, aligned to a line. Packed buffers are made of
/// them so that a row whose stride is a multiple of 64 bytes never straddles two lines: an AMX
/// `tileloadd` of such rows from a plain `Vec<u32>` (16-byte aligned by the allocator) read
/// two lines per row, and the bf16 estimate took 1.4× the time (issue 22).
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
pub(crate) struct Line([u32; LINE_WORDS]);

/// The words of `v`.
pub(crate) fn words(v: &[Line]) -> &[u32] {
    // SAFETY: `Line` is `repr(C)` over `[u32; LINE_WORDS]` without padding (64 bytes, aligned
    // to 64), so `v` is `v.len() · LINE_WORDS` initialised u32s.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), v.len() * LINE_WORDS) }
}

/// The words of `v`, writable.
pub(crate) fn words_mut(v: &mut [Line]) -> &mut [u32] {
    // SAFETY: as in `words`; every bit pattern is a valid u32, so every write leaves valid
    // `Line`s.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast(), v.len() * LINE_WORDS) }
}

/// `v` refilled: its first `n` words, every one `fill` (`v` holds whole lines, the last one's
/// tail `fill` too).
pub(crate) fn filled(v: &mut Vec<Line>, n: usize, fill: u32) -> &mut [u32] {
    v.clear();
    v.resize(n.div_ceil(LINE_WORDS), Line([fill; LINE_WORDS]));
    &mut words_mut(v)[..n]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filled_buffers_start_on_a_line_and_fill_whole_lines() {
        let mut v = Vec::new();
        for n in [1, 15, 16, 17, 1000] {
            let w = filled(&mut v, n, 7);
            assert_eq!(w.len(), n);
            assert_eq!(w.as_ptr() as usize % 64, 0, "{n} words");
            w[n - 1] = 9;
            assert_eq!(v.len(), n.div_ceil(LINE_WORDS));
            let all = words(&v);
            assert_eq!(all.len(), v.len() * LINE_WORDS);
            assert!(all[n..].iter().all(|&x| x == 7) && all[n - 1] == 9);
        }
    }
}
