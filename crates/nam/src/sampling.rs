//! Importance sampling of incident directions for path tracers.
//!
//! The paper's Mitsuba integration (§5) samples the neural BRDF with plain diffuse (cosine)
//! sampling, not adapted to the material. We do the same: Malley's method on pbrt's concentric
//! disk mapping, so the pdf is `cos θi / π` over solid angle in the surface frame.

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// Maps `u ∈ [0,1)²` to the unit disk with Shirley–Chiu's concentric mapping (area preserving,
/// low distortion).
fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// A cosine-distributed direction in the surface frame (z up) for `u ∈ [0,1)²`.
/// Always returns `z ≥ 0`; `z` is 0 only on the measure-zero disk boundary.
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u.clamp(Vec2::ZERO, Vec2::ONE));
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Solid-angle pdf of [`sample_cosine_hemisphere`]: `max(cos θ, 0) / π`.
pub fn cosine_hemisphere_pdf(wi_local: Vec3) -> f32 {
    wi_local.z.max(0.0) / PI
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Monte Carlo error of a 64×64 stratified estimate of a smooth integrand.
    const MC_TOL: f32 = 2e-3;

    #[test]
    fn cosine_samples_lie_on_upper_hemisphere_and_integrate_cos_to_pi() {
        // E[cos θ / pdf] over the hemisphere = ∫cos dω = π.
        let n = 64;
        let mut sum = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                let w = sample_cosine_hemisphere(u);
                assert!((w.length() - 1.0).abs() < 1e-5 && w.z >= 0.0);
                sum += f64::from(w.z / cosine_hemisphere_pdf(w));
            }
        }
        let est = (sum / f64::from(n * n)) as f32;
        assert!((est - PI).abs() < MC_TOL * PI, "∫cos dω estimated as {est}");
    }

    #[test]
    fn pdf_is_zero_below_horizon() {
        assert_eq!(cosine_hemisphere_pdf(Vec3::new(0.0, 0.6, -0.8)), 0.0);
    }
}
