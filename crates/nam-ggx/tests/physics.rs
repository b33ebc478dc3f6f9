//! Physical sanity of the GGX reference: Helmholtz reciprocity and energy conservation of the
//! specular lobe (white furnace), pbrt-style.

use nam_ggx::brdf::{alpha_from_roughness, brdf_value, eval_specular};
use nam_ggx::{GgxPoint, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// f64 reciprocity: the formula is symmetric, only the rounding of `wo·h` vs `wi·h` and of the
/// product order differ (a few ulps, amplified by D's peak).
const RECIPROCITY_REL_TOL_F64: f64 = 1e-11;
/// f32 reciprocity: the same in single precision, on configurations away from the α clamp.
const RECIPROCITY_REL_TOL_F32: f64 = 1e-4;
/// Quadrature error allowance of the stratified 512² importance-sampled albedo estimate: the
/// horizon cut makes the error ∝ 1/m; the measured 256²→512² change is ≤ 5.2e-4, so the 512²
/// error is ≈ 5e-4. (Measured worst albedo over the grid: 0.99999999 at roughness 0.)
const FURNACE_TOL: f64 = 2e-3;

fn random_unit_above(rng: &mut Pcg64, n: Vec3<f64>) -> Vec3<f64> {
    loop {
        let v = Vec3::new(
            rng.random::<f64>() * 2.0 - 1.0,
            rng.random::<f64>() * 2.0 - 1.0,
            rng.random::<f64>() * 2.0 - 1.0,
        );
        let len = v.length();
        if len > 0.1 && len <= 1.0 {
            let u = v * (1.0 / len);
            if n.dot(u) > 0.01 {
                return u;
            }
        }
    }
}

fn random_point(rng: &mut Pcg64) -> GgxPoint<f64> {
    let tilt = rng.random::<f64>() * 1.2;
    let phi = rng.random::<f64>() * std::f64::consts::TAU;
    GgxPoint {
        diffuse: [rng.random(), rng.random(), rng.random()],
        specular: [rng.random(), rng.random(), rng.random()],
        roughness: 0.05 + rng.random::<f64>() * 0.95,
        normal: Vec3::new(tilt.sin() * phi.cos(), tilt.sin() * phi.sin(), tilt.cos()),
    }
}

#[test]
fn brdf_is_reciprocal_in_f64_and_f32_for_tilted_normals() {
    let mut rng = Pcg64::seed_from_u64(42);
    for _ in 0..5_000 {
        let p = random_point(&mut rng);
        let wi = random_unit_above(&mut rng, p.normal);
        let wo = random_unit_above(&mut rng, p.normal);
        let a = brdf_value(&p, wi, wo);
        let b = brdf_value(&p, wo, wi);
        let p32 = p.cast::<f32>();
        let a32 = brdf_value(&p32, wi.cast(), wo.cast());
        let b32 = brdf_value(&p32, wo.cast(), wi.cast());
        for c in 0..3 {
            assert!(a[c] > 0.0);
            assert!(
                (a[c] - b[c]).abs() <= RECIPROCITY_REL_TOL_F64 * a[c],
                "{} vs {} for {p:?}",
                a[c],
                b[c]
            );
            let rel32 = f64::from((a32[c] - b32[c]).abs() / a32[c]);
            assert!(
                rel32 <= RECIPROCITY_REL_TOL_F32,
                "f32 rel {rel32:e} for {p:?}"
            );
        }
    }
}

/// Directional albedo `∫ f_spec(ωi, ωo) cos θi dωi` of the specular lobe for a view with
/// `cos θo = nov`, by importance sampling the GGX NDF on an `m×m` stratified grid.
/// The integrand goes through [`eval_specular`], so it checks the shipped formula.
fn specular_albedo(roughness: f64, nov: f64, m: usize) -> f64 {
    let n = Vec3::up();
    let wo = Vec3::new((1.0 - nov * nov).sqrt(), 0.0, nov);
    let p = GgxPoint {
        diffuse: [0.0; 3],
        specular: [1.0; 3],
        roughness,
        normal: n,
    };
    let alpha = alpha_from_roughness(roughness);
    let mut sum = 0.0;
    for a in 0..m {
        for b in 0..m {
            let u1 = (a as f64 + 0.5) / m as f64;
            let u2 = (b as f64 + 0.5) / m as f64;
            // GGX NDF sampling: tan²θh = α² u1 / (1 − u1), pdf_h = D(h)·cosθh.
            let tan2 = alpha * alpha * u1 / (1.0 - u1);
            let cos_h = 1.0 / (1.0 + tan2).sqrt();
            let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
            let phi = std::f64::consts::TAU * u2;
            let h = Vec3::new(sin_h * phi.cos(), sin_h * phi.sin(), cos_h);
            let voh = wo.dot(h);
            if voh <= 0.0 {
                continue;
            }
            let wi = h * (2.0 * voh) - wo;
            if wi.z <= 0.0 {
                continue;
            }
            let d = nam_ggx::brdf::ndf_ggx(cos_h, alpha);
            let pdf_wi = d * cos_h / (4.0 * voh);
            // R = π f cos θi, so f cos θi = R / π.
            let r = eval_specular(&p, wi, wo)[0];
            sum += r / std::f64::consts::PI / pdf_wi;
        }
    }
    sum / (m * m) as f64
}

#[test]
fn white_furnace_specular_albedo_never_exceeds_one_for_f0_one() {
    let mut worst = 0.0_f64;
    for roughness in [0.0, 0.01, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.85, 1.0] {
        for nov in [1e-3, 0.05, 0.2, 0.5, 0.8, 1.0] {
            let albedo = specular_albedo(roughness, nov, 512);
            worst = worst.max(albedo);
            assert!(
                albedo <= 1.0 + FURNACE_TOL,
                "roughness {roughness}, cos θo {nov}: albedo {albedo}"
            );
            assert!(albedo > 0.0);
        }
    }
    println!("worst specular albedo {worst}");
}

#[test]
fn white_furnace_smooth_lobe_at_normal_incidence_keeps_nearly_all_energy() {
    // With F = 1 and Smith–Schlick G ≈ 1 away from grazing, a smooth lobe reflects almost
    // everything: a wrong D normalisation (e.g. a missing π) would show here.
    for roughness in [0.01, 0.1, 0.2] {
        let albedo = specular_albedo(roughness, 1.0, 512);
        assert!(
            albedo > 0.97 && albedo <= 1.0 + FURNACE_TOL,
            "{roughness}: {albedo}"
        );
    }
}

#[test]
fn furnace_estimate_is_converged_at_512_squared() {
    for (roughness, nov) in [(0.3, 0.5), (1.0, 0.05), (0.05, 1.0)] {
        let a = specular_albedo(roughness, nov, 256);
        let b = specular_albedo(roughness, nov, 512);
        assert!(
            (a - b).abs() < FURNACE_TOL / 2.0,
            "{roughness} {nov}: {a} {b}"
        );
    }
}
