//! AVX-512 pieces shared by the reduced-precision kernels ([`crate::bf16`], [`crate::int8`]).
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
