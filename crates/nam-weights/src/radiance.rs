//! The networks' output convention: `M_render` predicts `y = ln(1 + R)` per colour channel
//! (docs/FORMAT.md); this is its one inverse, used by the CPU and the GPU paths alike.

/// ln(f32::MAX), rounded down: the largest log value whose `expm1` is finite.
const LN_F32_MAX: f32 = 88.722_83;

/// Radiance `R = max(expm1(y), 0)` of a log-space network output `y` (linear radiance
/// `R = π f_r cos θi`, DESIGN §3). `y` is capped at ln(f32::MAX), so a saturated network gives
/// about f32::MAX, never +Inf; NaN gives 0.
#[inline]
pub fn radiance_from_log(y: f32) -> f32 {
    let r = if y > LN_F32_MAX { LN_F32_MAX } else { y }.exp_m1();
    if r > 0.0 { r } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::radiance_from_log;

    #[test]
    fn radiance_is_finite_and_non_negative_for_every_log_value() {
        for y in [100.0, 1e30, f32::INFINITY, f32::MAX] {
            let r = radiance_from_log(y);
            assert!(r.is_finite() && r > 1e38, "{y} -> {r}");
        }
        assert_eq!(radiance_from_log(f32::NAN), 0.0);
        assert_eq!(radiance_from_log(-5.0), 0.0);
        assert!((radiance_from_log(1.0) - (1f32.exp() - 1.0)).abs() < 1e-6);
    }
}
