//! The evaluation protocols of the paper (§3.1 and §4), as seeded, reproducible samplers of
//! light and view positions (surface frame, material half-widths).
//!
//! The stream is nam-weights' [`SplitMix64`], uniforms are its top 53 bits, normal variates use Box–Muller
//! on two uniforms, and every draw happens in a fixed order: a definition small enough that
//! `train_py/protocols.py` (`SeededPairs`) re-implements it draw for draw, so the Rust report
//! and `train_py.evaluate` score the same light/view pairs (pinned by
//! `tests/fixtures/eval_agreement.json`).

use crate::geometry::{CAPTURE_DISTANCE, capture_position, direction};
use crate::vec3::{Vec3, Vec3d};
use glam::DVec3;
pub use nam_weights::SplitMix64;

/// Radius of the hemisphere of the Hemisphere protocol (paper §4: 4.0).
pub const HEMISPHERE_RADIUS: f64 = 4.0;

/// Standard deviation of the Gaussian offsets of the Reflect protocol (paper §3.1).
pub const REFLECT_SIGMA: f64 = 2.0;

/// Smallest light distance of the Reflect protocol: `|N(0, 2)| + 0.5`.
pub const REFLECT_MIN_LIGHT_DISTANCE: f64 = 0.5;

/// One light/view configuration (point light, perspective viewer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightView {
    /// Point-light position.
    pub light: DVec3,
    /// Viewer position.
    pub view: DVec3,
}

/// Which protocol to sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Training sampling (paper §3.1): p = U[−1,1]² + N(0, 2) per axis, view uniform on the
    /// hemisphere of radius d, light along the mirror of the view direction about z at p, at
    /// distance |N(0, 2)| + 0.5 from p — a highlight centred on p.
    Reflect,
    /// Light and view co-located at the capture position (0, 0, d).
    Identity,
    /// Light and view independently uniform (by area) on the hemisphere of radius 4.
    Hemisphere,
}

impl Protocol {
    /// Lower-case name (`reflect`, `identity`, `hemisphere`).
    pub fn name(self) -> &'static str {
        match self {
            Protocol::Reflect => "reflect",
            Protocol::Identity => "identity",
            Protocol::Hemisphere => "hemisphere",
        }
    }
}

impl std::str::FromStr for Protocol {
    type Err = crate::GgxError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "reflect" => Ok(Protocol::Reflect),
            "identity" => Ok(Protocol::Identity),
            "hemisphere" => Ok(Protocol::Hemisphere),
            _ => Err(crate::GgxError::InvalidArgument(format!(
                "unknown protocol {s:?} (expected reflect, identity or hemisphere)"
            ))),
        }
    }
}

/// A seeded sampler of light/view configurations.
#[derive(Debug, Clone)]
pub struct ProtocolSampler {
    protocol: Protocol,
    rng: SplitMix64,
}

impl ProtocolSampler {
    /// A sampler for `protocol` whose stream is fixed by `seed`.
    pub fn new(protocol: Protocol, seed: u64) -> Self {
        Self {
            protocol,
            rng: SplitMix64(seed),
        }
    }

    /// The next configuration.
    pub fn sample(&mut self) -> LightView {
        match self.protocol {
            Protocol::Identity => {
                let c = capture_position(CAPTURE_DISTANCE);
                LightView { light: c, view: c }
            }
            Protocol::Hemisphere => {
                let light = uniform_hemisphere(&mut self.rng) * HEMISPHERE_RADIUS;
                let view = uniform_hemisphere(&mut self.rng) * HEMISPHERE_RADIUS;
                LightView {
                    light: light.into(),
                    view: view.into(),
                }
            }
            Protocol::Reflect => self.sample_reflect(),
        }
    }

    /// `n` configurations.
    pub fn take(&mut self, n: usize) -> Vec<LightView> {
        (0..n).map(|_| self.sample()).collect()
    }

    fn sample_reflect(&mut self) -> LightView {
        let rng = &mut self.rng;
        let px = 2.0 * rng.uniform() - 1.0 + REFLECT_SIGMA * std_normal(rng);
        let py = 2.0 * rng.uniform() - 1.0 + REFLECT_SIGMA * std_normal(rng);
        let p = Vec3::new(px, py, 0.0);
        let view = uniform_hemisphere(rng) * CAPTURE_DISTANCE;
        // view.z > 0 (see uniform_hemisphere) and p.z = 0, so v − p is never degenerate.
        let to_view = direction(p, view);
        let to_light = Vec3::new(-to_view.x, -to_view.y, to_view.z);
        let dist = (REFLECT_SIGMA * std_normal(rng)).abs() + REFLECT_MIN_LIGHT_DISTANCE;
        LightView {
            light: (p + to_light * dist).into(),
            view: view.into(),
        }
    }
}

/// Convenience: `n` configurations of `protocol` from `seed`.
pub fn sample_protocol(protocol: Protocol, n: usize, seed: u64) -> Vec<LightView> {
    ProtocolSampler::new(protocol, seed).take(n)
}

/// Uniform (by area) on the unit upper hemisphere, z ∈ (0, 1] (never on the horizon).
fn uniform_hemisphere(rng: &mut SplitMix64) -> Vec3d {
    let z = 1.0 - rng.uniform();
    let phi = 2.0 * std::f64::consts::PI * rng.uniform();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A standard normal variate by Box–Muller (one of the pair; u1 ∈ (0, 1] so ln is finite).
fn std_normal(rng: &mut SplitMix64) -> f64 {
    let u1 = 1.0 - rng.uniform();
    let u2 = rng.uniform();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_gives_the_published_sequence() {
        // The first outputs from state 0 (the reference C code of Vigna's xoshiro page).
        let mut g = SplitMix64(0);
        assert_eq!(g.next(), 0xe220_a839_7b1d_cdaf);
        assert_eq!(g.next(), 0x6e78_9e6a_a1b9_65f4);
        assert_eq!(g.next(), 0x06c4_5d18_8009_454f);
        let u = SplitMix64(0).uniform();
        assert_eq!(
            u,
            (0xe220_a839_7b1d_cdafu64 >> 11) as f64 / 9_007_199_254_740_992.0
        );
    }

    #[test]
    fn same_seed_gives_same_sequence_and_different_seed_differs() {
        for p in [Protocol::Reflect, Protocol::Hemisphere] {
            assert_eq!(sample_protocol(p, 20, 7), sample_protocol(p, 20, 7));
            assert_ne!(sample_protocol(p, 20, 7), sample_protocol(p, 20, 8));
        }
    }

    #[test]
    fn identity_is_colocated_at_capture_distance() {
        for lv in sample_protocol(Protocol::Identity, 3, 1) {
            assert_eq!(lv.light, lv.view);
            assert_eq!(lv.light, DVec3::new(0.0, 0.0, CAPTURE_DISTANCE));
        }
    }

    #[test]
    fn hemisphere_points_lie_on_radius_4_above_the_surface_with_uniform_z() {
        let n = 20_000;
        let s = sample_protocol(Protocol::Hemisphere, n, 3);
        let mut mean_z = 0.0;
        for lv in &s {
            for v in [lv.light, lv.view] {
                assert!((v.length() - HEMISPHERE_RADIUS).abs() < 1e-12);
                assert!(v.z > 0.0);
                mean_z += v.z / (2 * n) as f64;
            }
        }
        // Uniform by area ⇔ z uniform on (0, R]: mean R/2. 4σ of the sample mean ≈ 0.033.
        assert!((mean_z - 2.0).abs() < 0.033, "{mean_z}");
    }

    #[test]
    fn reflect_light_mirrors_the_view_direction_about_z_at_p() {
        for lv in sample_protocol(Protocol::Reflect, 2_000, 11) {
            // Recover p as the point on z = 0 on the line from the light along the mirrored
            // direction: the view and the mirrored light are on one line through p.
            let (l, v) = (lv.light, lv.view);
            assert!(l.z > 0.0 && v.z > 0.0);
            let mirrored = DVec3::new(l.x, l.y, -l.z);
            let t = v.z / (v.z + l.z);
            let p = v + (mirrored - v) * t;
            assert!(p.z.abs() < 1e-9);
            let dist = (l - p).length();
            assert!(dist >= REFLECT_MIN_LIGHT_DISTANCE - 1e-9, "{dist}");
            let to_v = (v - p).try_normalize().unwrap_or(DVec3::Z);
            let to_l = (l - p).try_normalize().unwrap_or(DVec3::Z);
            assert!((to_l.x + to_v.x).abs() < 1e-9 && (to_l.y + to_v.y).abs() < 1e-9);
            assert!((to_l.z - to_v.z).abs() < 1e-9);
            assert!((v.length() - CAPTURE_DISTANCE).abs() < 1e-9);
        }
    }

    #[test]
    fn reflect_p_has_the_papers_spread() {
        // p.x = U[−1, 1] + N(0, 2): variance 1/3 + 4.
        let n = 20_000;
        let mut sum = 0.0;
        let mut sum2 = 0.0;
        for lv in sample_protocol(Protocol::Reflect, n, 5) {
            let (l, v) = (lv.light, lv.view);
            let mirrored = DVec3::new(l.x, l.y, -l.z);
            let p = v + (mirrored - v) * (v.z / (v.z + l.z));
            sum += p.x;
            sum2 += p.x * p.x;
        }
        let mean = sum / n as f64;
        let var = sum2 / n as f64 - mean * mean;
        // Sample-mean 4σ ≈ 4·2.08/√n ≈ 0.06; sample-variance relative 4σ ≈ 4·√(2/n) ≈ 0.04.
        assert!(mean.abs() < 0.06, "{mean}");
        assert!((var / (1.0 / 3.0 + 4.0) - 1.0).abs() < 0.04, "{var}");
    }
}
