//! Positional encoding of the direction triple (docs/FORMAT.md).
//!
//! `c = [ωi, ωo, ωh]` (9 values); `enc[0..9] = c`; for octave k and value j:
//! `enc[9 + 18k + 2j] = sin(2^k·π·c_j)`, `enc[9 + 18k + 2j + 1] = cos(2^k·π·c_j)`.
//!
//! Arguments reach `2^15·π ≈ 1e5`, where an f32 product `2^k·π·c` would already
//! be off by ~0.01 rad. Instead `u = 2^(k+1)·c` (exact: a power-of-two scale) is
//! split into quarter turns `q = round(u)` and a remainder `r = u − q ∈ [−½, ½]`
//! (exact by Sterbenz), so `2^k·π·c = (π/2)(q + r)` and only `(π/2)·r ∈ [−π/4, π/4]`
//! goes through the polynomial. Accuracy: ~1e-7 absolute for every octave.

use crate::geometry::Directions;
use nam_ggx::Vec3;

/// Number of direction values encoded (ωi, ωo, ωh).
pub const DIR_VALUES: usize = 9;

/// Encoded length for `octaves` octaves: `9 + 18·octaves`.
pub const fn encoded_len(octaves: usize) -> usize {
    DIR_VALUES * (1 + 2 * octaves)
}

/// The 9 direction values `[ωi, ωo, ωh]` with ωh = normalize(ωi + ωo) (guarded,
/// [`geometry::half_vector`](crate::geometry::half_vector)).
pub fn direction_triple(wi: [f32; 3], wo: [f32; 3]) -> [f32; 9] {
    Directions::new(Vec3::from_array(wi), Vec3::from_array(wo)).to_array9()
}

/// `(sin, cos)` of `(π/2)·u` for `|u| < 2^22`, with exact quarter-turn reduction.
#[inline(always)]
pub fn sincos_quarter_turns(u: f32) -> (f32, f32) {
    // Round to nearest via the 1.5·2^23 trick (exact for |u| < 2^22): unlike
    // `f32::round` it compiles to two adds on any x86-64, so loops vectorise.
    const MAGIC: f32 = 12_582_912.0;
    let q = (u + MAGIC) - MAGIC;
    let r = (u - q) * std::f32::consts::FRAC_PI_2;
    let r2 = r * r;
    // Taylor to x^9 / x^10 on [−π/4, π/4]: truncation < 3e-9.
    let s = r
        * (1.0
            + r2 * (-1.0 / 6.0
                + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + r2 * (-0.5
            + r2 * (1.0 / 24.0
                + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40_320.0 + r2 * (-1.0 / 3_628_800.0)))));
    // Quarter turn q mod 4, branch-free (bit selects keep it exact and vectorisable):
    // odd q swaps (s, c) → (c, −s); q ≡ 2, 3 negates both.
    let qi = q as i32;
    let swap = 0u32.wrapping_sub((qi & 1) as u32);
    let neg = ((qi & 2) as u32) << 30;
    let s1 = (s.to_bits() & !swap) | (c.to_bits() & swap);
    let c1 = (c.to_bits() & !swap) | ((-s).to_bits() & swap);
    (f32::from_bits(s1 ^ neg), f32::from_bits(c1 ^ neg))
}

/// Maximum octaves [`encode_into`] handles with its stack buffer.
pub const MAX_OCTAVES: usize = 30;

/// Writes the encoding of one direction triple into `out` (length `encoded_len(octaves)`,
/// `octaves ≤ MAX_OCTAVES`).
#[inline]
pub fn encode_into(c: &[f32; 9], octaves: usize, out: &mut [f32]) {
    out[..DIR_VALUES].copy_from_slice(c);
    // Flat index i = 9k + j maps to out[9 + 2i] (sin) and out[9 + 2i + 1] (cos).
    let n = DIR_VALUES * octaves.min(MAX_OCTAVES);
    let mut u = [0.0f32; DIR_VALUES * MAX_OCTAVES];
    let mut scale = 2.0f32; // 2^(k+1)
    for k in u[..n].chunks_exact_mut(DIR_VALUES) {
        for (v, &cj) in k.iter_mut().zip(c) {
            *v = scale * cj;
        }
        scale *= 2.0;
    }
    for (pair, &ui) in out[DIR_VALUES..DIR_VALUES + 2 * n]
        .chunks_exact_mut(2)
        .zip(&u[..n])
    {
        let (s, co) = sincos_quarter_turns(ui);
        pair[0] = s;
        pair[1] = co;
    }
}

/// Reference encoding in f64 (`sin(2^k·π·c)` with f64 argument; error ~1e-11).
pub fn encode_f64(c: &[f32; 9], octaves: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(encoded_len(octaves));
    out.extend(c.iter().map(|&v| f64::from(v)));
    for k in 0..octaves {
        let s = (1u64 << k) as f64 * std::f64::consts::PI;
        for &v in c {
            let a = s * f64::from(v);
            out.push(a.sin());
            out.push(a.cos());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Largest |fast − f64| allowed: polynomial truncation (3e-9) plus the f32
    /// rounding of (π/2)·r and of the result (~1e-7).
    const ENCODING_ABS_TOL: f64 = 2.5e-7;

    #[test]
    fn encoding_is_accurate_at_every_octave_including_2_pow_15_pi() {
        let mut worst = 0.0f64;
        let mut out = vec![0.0f32; encoded_len(16)];
        for i in 0..2000 {
            // Values over [-1, 1], including ones near multiples of 1/2^k.
            let t = (i as f32 / 999.5) - 1.0;
            let c = [
                t,
                -t,
                0.5 * t,
                t * t,
                1.0 - t.abs(),
                0.3,
                -0.999_999_9,
                1.0,
                0.0,
            ];
            encode_into(&c, 16, &mut out);
            let want = encode_f64(&c, 16);
            for (a, b) in out.iter().zip(&want) {
                worst = worst.max((f64::from(*a) - b).abs());
            }
        }
        assert!(worst < ENCODING_ABS_TOL, "worst {worst:e}");
    }

    #[test]
    fn naive_f32_argument_would_fail_the_tolerance() {
        // Proves the test above can fail: sin(f32(2^15·π·c)) is off by ~1e-2.
        let c = 0.123_456_7f32;
        let naive = (32768.0f32 * std::f32::consts::PI * c).sin();
        let exact = (32768.0 * std::f64::consts::PI * f64::from(c)).sin();
        assert!((f64::from(naive) - exact).abs() > ENCODING_ABS_TOL);
        let (s, _) = sincos_quarter_turns(65536.0 * c);
        assert!((f64::from(s) - exact).abs() < ENCODING_ABS_TOL);
    }

    #[test]
    fn opposite_directions_get_the_normal_as_half_vector() {
        let t = direction_triple([0.6, 0.0, 0.8], [-0.6, 0.0, -0.8]);
        assert_eq!(&t[6..9], &[0.0, 0.0, 1.0]);
        assert!(t.iter().all(|v| v.is_finite()));
    }
}
