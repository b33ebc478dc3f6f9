//! Log compression (DESIGN §3), transfer curves and the display transform.
//!
//! All functions are total: NaN inputs give a defined, finite (or +∞ for +∞ input) output,
//! never NaN, because Rust's `max`/`min` return the non-NaN operand.

use crate::float::Float;

/// Upper clamp of linear LDR values before log compression, `ln(1 + 0.999999)`: keeps the
/// LDR log range strictly below ln 2 like the original code.
pub const LDR_CLAMP_MAX: f64 = 0.999_999;

/// Exponent of the pure-gamma encoding of the 4-panel SVBRDF files and of the display
/// transform.
pub const GAMMA: f64 = 2.2;

/// HDR log compression `ln(1 + max(R, 0))`.
#[inline]
pub fn log_hdr<T: Float>(r: T) -> T {
    r.max(T::ZERO).ln_1p()
}

/// LDR log compression `ln(1 + clamp(R, 0, 0.999999))` (R linear, already sRGB-decoded).
#[inline]
pub fn log_ldr<T: Float>(r: T) -> T {
    r.max(T::ZERO).min(T::from_f64(LDR_CLAMP_MAX)).ln_1p()
}

/// Inverse of the log compression: `max(expm1(y), 0)`.
#[inline]
pub fn log_inverse<T: Float>(y: T) -> T {
    y.exp_m1().max(T::ZERO)
}

/// Display transform of log data: `(e^y − 1)^(1/2.2)`, i.e. `log_inverse` then gamma 2.2.
/// For figures only.
#[inline]
pub fn display<T: Float>(y: T) -> T {
    gamma_encode(log_inverse(y))
}

/// Pure gamma-2.2 decode `v^2.2` (negative and NaN inputs give 0).
#[inline]
pub fn gamma_decode<T: Float>(v: T) -> T {
    v.max(T::ZERO).powf(T::from_f64(GAMMA))
}

/// Pure gamma-2.2 encode `v^(1/2.2)` (negative and NaN inputs give 0; no upper clamp).
#[inline]
pub fn gamma_encode<T: Float>(v: T) -> T {
    v.max(T::ZERO).powf(T::from_f64(1.0 / GAMMA))
}

/// sRGB encode (IEC 61966-2-1 piecewise curve) of a linear value; input clamped to [0, 1].
#[inline]
pub fn srgb_encode<T: Float>(linear: T) -> T {
    let v = linear.max(T::ZERO).min(T::ONE);
    if v <= T::from_f64(0.003_130_8) {
        v * T::from_f64(12.92)
    } else {
        T::from_f64(1.055) * v.powf(T::from_f64(1.0 / 2.4)) - T::from_f64(0.055)
    }
}

/// sRGB decode (IEC 61966-2-1 piecewise curve) to a linear value; input clamped to [0, 1].
#[inline]
pub fn srgb_decode<T: Float>(encoded: T) -> T {
    let v = encoded.max(T::ZERO).min(T::ONE);
    if v <= T::from_f64(0.040_45) {
        v / T::from_f64(12.92)
    } else {
        ((v + T::from_f64(0.055)) / T::from_f64(1.055)).powf(T::from_f64(2.4))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f64 round trip through pow/ln_1p/exp_m1: a few ulps.
    const ROUND_TRIP: f64 = 1e-12;

    #[test]
    fn hdr_log_round_trips_including_huge_values() {
        for r in [0.0_f64, 1e-9, 0.5, 1.0, 37.0, 1e6, 1e12] {
            let back = log_inverse(log_hdr(r));
            assert!((back - r).abs() <= ROUND_TRIP * r.max(1.0), "{r} -> {back}");
        }
    }

    #[test]
    fn ldr_log_clamps_to_just_below_ln2() {
        assert_eq!(log_ldr(5.0_f64), LDR_CLAMP_MAX.ln_1p());
        assert!(log_ldr(5.0_f64) < std::f64::consts::LN_2);
        assert_eq!(log_ldr(-1.0_f64), 0.0);
    }

    #[test]
    fn log_helpers_never_return_nan() {
        for v in [f64::NAN, f64::NEG_INFINITY, -1.0, -1e300] {
            assert!(!log_hdr(v).is_nan());
            assert!(!log_ldr(v).is_nan());
            assert!(!log_inverse(v).is_nan());
            assert!(!display(v).is_nan());
            assert!(!srgb_encode(v).is_nan() && !srgb_decode(v).is_nan());
        }
        assert_eq!(log_inverse(-5.0_f64), 0.0);
    }

    #[test]
    fn srgb_curve_is_continuous_and_round_trips() {
        // The two branches meet at 0.0031308 (to the curve's published 4-digit precision).
        let lo = 0.003_130_8_f64 * 12.92;
        let hi = 1.055 * 0.003_130_8_f64.powf(1.0 / 2.4) - 0.055;
        assert!((lo - hi).abs() < 1e-7);
        for i in 0..=100 {
            let v = i as f64 / 100.0;
            assert!((srgb_decode(srgb_encode(v)) - v).abs() < ROUND_TRIP);
        }
        assert!((srgb_encode(0.5_f64) - 0.735_356_983_052_449_4).abs() < ROUND_TRIP);
    }

    #[test]
    fn display_of_log_one_plus_x_is_x_to_one_over_2_2() {
        let x = 0.3_f64;
        assert!((display(x.ln_1p()) - x.powf(1.0 / 2.2)).abs() < ROUND_TRIP);
        assert!((gamma_decode(gamma_encode(x)) - x).abs() < ROUND_TRIP);
    }
}
