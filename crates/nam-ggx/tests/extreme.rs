//! DESIGN §7 stability: the extreme grid (roughness 0 / 1e-6 / 1, cosines 0 / 1e-7 / 1e-3,
//! F0 0 and 1, normals tilted up to 89.9°, 1e6 light intensities) in f32 and f64.

use nam_ggx::brdf::{ALPHA_MIN, eval, ndf_ggx};
use nam_ggx::{GgxPoint, Vec3};

const ROUGHNESS: [f64; 7] = [0.0, 1e-6, 0.01, 0.1, 0.3, 0.7, 1.0];
const COSINES: [f64; 7] = [0.0, 1e-7, 1e-3, 0.1, 0.5, 0.9, 1.0];
const F0: [f64; 3] = [0.0, 0.04, 1.0];
const TILT_DEG: [f64; 4] = [0.0, 30.0, 80.0, 89.9];
const AZIMUTHS: [f64; 3] = [0.0, 2.0, 3.1];
/// The brightest light of the grid (HDR): intensities multiply R.
const HDR_INTENSITY: f64 = 1e6;

/// Relative tolerance between the f32 and f64 evaluation of the same f32-representable inputs
/// on the regular part of the grid (roughness ≥ 0.3, both cosines ≥ 1e-3, normals up to
/// 89.9°). Measured worst 5.7e-5 (roughness 0.3 near the highlight; 2.7e-5 from the f32
/// rounding of a 1e-3 cosine). Outside this region the error is input conditioning, not
/// arithmetic: at cosines of 1e-7 the f32 dot product itself is off by ~17%, and at the α clamp
/// the f32 NDF denominator `(1−NoH²) + NoH²α²` has a rounding error of ~1e-7 against α² = 1e-8
/// (worst measured factor 39 exactly at the mirror direction); there only finiteness and sign
/// are guaranteed (see the grid test above).
const F32_VS_F64_REL_TOL_REGULAR: f64 = 1e-4;

/// Orthonormal frame (t, b) around unit n.
fn frame(n: Vec3<f64>) -> (Vec3<f64>, Vec3<f64>) {
    let a = if n.x.abs() < 0.9 {
        Vec3::new(1.0, 0.0, 0.0)
    } else {
        Vec3::new(0.0, 1.0, 0.0)
    };
    let t = a
        .cross(n)
        .try_normalize()
        .unwrap_or_else(|| panic!("frame"));
    (t, n.cross(t))
}

/// Unit direction with `cos` to n at azimuth `phi` around it.
fn dir(n: Vec3<f64>, cos: f64, phi: f64) -> Vec3<f64> {
    let (t, b) = frame(n);
    let s = (1.0 - cos * cos).max(0.0).sqrt();
    n * cos + (t * phi.cos() + b * phi.sin()) * s
}

fn tilted(deg: f64, phi: f64) -> Vec3<f64> {
    let th = deg.to_radians();
    Vec3::new(th.sin() * phi.cos(), th.sin() * phi.sin(), th.cos())
}

/// Round a vector to f32 and back, so f32 and f64 see the same inputs.
fn r32(v: Vec3<f64>) -> Vec3<f64> {
    v.cast::<f32>().cast::<f64>()
}

struct Case {
    p: GgxPoint<f64>,
    wi: Vec3<f64>,
    wo: Vec3<f64>,
    nol: f64,
    nov: f64,
}

fn grid() -> Vec<Case> {
    let mut out = Vec::new();
    for &tilt in &TILT_DEG {
        for &tphi in &AZIMUTHS {
            let n = r32(tilted(tilt, tphi));
            for &r in &ROUGHNESS {
                for &f0 in &F0 {
                    for &nol in &COSINES {
                        for &nov in &COSINES {
                            for &phi in &AZIMUTHS {
                                let p = GgxPoint {
                                    diffuse: [0.5, 0.0, 1.0],
                                    specular: [f0; 3],
                                    roughness: f64::from(r as f32),
                                    normal: n,
                                };
                                let wi = r32(dir(n, nol, 0.0));
                                // phi = π-ish puts wo near the mirror of wi: the highlight.
                                let wo = r32(dir(n, nov, phi));
                                out.push(Case {
                                    p,
                                    wi,
                                    wo,
                                    nol,
                                    nov,
                                });
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

#[test]
fn extreme_grid_is_finite_nonnegative_in_f32_and_f64_even_at_1e6_intensity() {
    let cases = grid();
    let mut max_r = 0.0_f64;
    for c in &cases {
        let r64 = eval(&c.p, c.wi, c.wo);
        let r32 = eval(&c.p.cast::<f32>(), c.wi.cast(), c.wo.cast());
        for ch in 0..3 {
            let a = r64[ch] * HDR_INTENSITY;
            let b = r32[ch] * HDR_INTENSITY as f32;
            assert!(a.is_finite() && a >= 0.0, "f64 {a} for {:?}", c.p);
            assert!(b.is_finite() && b >= 0.0, "f32 {b} for {:?}", c.p);
            max_r = max_r.max(a);
        }
    }
    // The analytic bound 1/(8α³)·π-ish: nothing may exceed ~1e12 per unit light.
    assert!(max_r < 1e12 * HDR_INTENSITY, "{max_r}");
    println!("{} cases, max R·1e6 = {max_r:e}", cases.len());
}

#[test]
fn zero_cosine_gives_exactly_zero_for_every_roughness_and_tilt() {
    let mut n = 0;
    for c in grid().iter().filter(|c| c.nol == 0.0 || c.nov == 0.0) {
        // The f32-rounded directions may sit a hair above the horizon; rebuild exactly
        // grazing ones by projecting out the normal component.
        let proj = |w: Vec3<f64>, cos: f64| {
            if cos == 0.0 {
                let q = w - c.p.normal * c.p.normal.dot(w);
                q.try_normalize().unwrap_or(q)
            } else {
                w
            }
        };
        let (wi, wo) = (proj(c.wi, c.nol), proj(c.wo, c.nov));
        let ndot = |w: Vec3<f64>| c.p.normal.dot(w);
        if ndot(wi) > 0.0 && ndot(wo) > 0.0 {
            continue; // projection rounding left both a hair above the horizon
        }
        assert_eq!(eval(&c.p, wi, wo), [0.0; 3], "{:?}", c.p);
        n += 1;
    }
    assert!(n > 1000, "{n}");
}

#[test]
fn below_horizon_light_or_view_gives_exactly_zero_with_tilted_normals() {
    for &tilt in &TILT_DEG {
        let n = tilted(tilt, 1.0);
        let p = GgxPoint {
            diffuse: [1.0; 3],
            specular: [1.0; 3],
            roughness: 0.0,
            normal: n,
        };
        let above = dir(n, 0.5, 0.0);
        let below = dir(n, -1e-7, 1.0);
        assert_eq!(eval(&p, below, above), [0.0; 3]);
        assert_eq!(eval(&p, above, below), [0.0; 3]);
        assert_eq!(eval(&p.cast::<f32>(), below.cast(), above.cast()), [0.0; 3]);
    }
}

#[test]
fn roughness_below_the_clamp_renders_like_roughness_0_01() {
    let n = Vec3::up();
    let wi = dir(n, 0.8, 0.0);
    let wo = dir(n, 0.8, std::f64::consts::PI);
    let at = |r: f64| {
        eval(
            &GgxPoint {
                diffuse: [0.0; 3],
                specular: [1.0; 3],
                roughness: r,
                normal: n,
            },
            wi,
            wo,
        )
    };
    assert_eq!(at(0.0), at(ALPHA_MIN.sqrt()));
    assert_eq!(at(1e-6), at(ALPHA_MIN.sqrt()));
    assert!(
        at(0.0)[0] > 1e6,
        "mirror highlight at the clamp is huge but finite"
    );
}

#[test]
fn ndf_integrates_to_one_over_projected_microfacet_area() {
    // ∫ D(h) (n·h) dω_h = 1, by midpoint quadrature in t = cos²θ (smooth enough for α ≥ 0.1).
    /// Quadrature error of 20k midpoint cells on the peaked integrand.
    const NDF_NORM_TOL: f64 = 1e-3;
    for alpha in [0.1_f64, 0.3, 0.6, 1.0] {
        let m = 20_000;
        let mut sum = 0.0;
        for k in 0..m {
            // dω = 2π sinθ dθ; with u = cosθ: ∫ D(u) u 2π du over u ∈ [0, 1].
            let u = (k as f64 + 0.5) / m as f64;
            sum += ndf_ggx(u, alpha) * u * 2.0 * std::f64::consts::PI / m as f64;
        }
        assert!((sum - 1.0).abs() < NDF_NORM_TOL, "alpha {alpha}: {sum}");
    }
}

#[test]
fn f32_matches_f64_within_1e_4_relative_for_roughness_from_0_3_and_cosines_from_1e_3() {
    let mut worst_regular = 0.0_f64;
    let mut worst_ratio = 1.0_f64;
    let mut regular = 0;
    for c in grid() {
        let a = eval(&c.p, c.wi, c.wo);
        let b = eval(&c.p.cast::<f32>(), c.wi.cast(), c.wo.cast());
        let is_regular = c.p.roughness >= 0.3 - 1e-6 && c.nol >= 1e-3 && c.nov >= 1e-3;
        for ch in 0..3 {
            let (x, y) = (a[ch], f64::from(b[ch]));
            if is_regular {
                let rel = (y - x).abs() / x;
                worst_regular = worst_regular.max(rel);
                assert!(
                    rel <= F32_VS_F64_REL_TOL_REGULAR,
                    "rel {rel:e}: {:?} wi {:?} wo {:?}",
                    c.p,
                    c.wi,
                    c.wo
                );
                regular += 1;
            } else if x > 0.0 && y > 0.0 {
                worst_ratio = worst_ratio.max((y / x).max(x / y));
            }
        }
    }
    assert!(regular > 1000, "{regular}");
    println!("f32 vs f64: worst regular rel {worst_regular:e}, worst singular ratio {worst_ratio}");
}
