//! DESIGN §7 stability through the facade, on the embedded default model: stiff scenes
//! (grazing, below the horizon, co-located, lights at 1e-3 and 1e4, directional), degenerate
//! photos (black, clipped white, HDR 1e6, NaN/Inf pixels, denormals, negative noise) and odd
//! sizes (1×1, 7×7, 13×13, 40×40 — none a multiple of the U-Net's 8). Every output must be
//! finite and ≥ 0, black exactly where the geometry says so, and invalid input must be an
//! error that names the problem.
//!
//! Over 600 lines on purpose: one catalogue of stiff scenes and degenerate inputs, each a short
//! test on the same loaded model, read as one list against DESIGN §7.

mod common;

use glam::{Vec2, Vec3};
use nam::geometry::{Light, View};
use nam::{
    BrdfQuery, DVec3, LogMode, NamError, NeuralBrdf, NeuralMaterial, NeuralModel, Photo, RgbImage,
    Scene, relight,
};
use std::sync::OnceLock;

/// Capture distance d = 1/tan 14° (DESIGN §3).
const D: f64 = nam::geometry::CAPTURE_DISTANCE;

fn model() -> &'static NeuralModel {
    static M: OnceLock<NeuralModel> = OnceLock::new();
    M.get_or_init(|| NeuralModel::embedded().expect("embedded model loads"))
}

fn v(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

/// A textured linear-RGB photo: smooth gradients plus a checker, values in [0.02, 0.9].
fn textured(side: usize) -> Vec<f32> {
    let mut rgb = Vec::with_capacity(side * side * 3);
    for i in 0..side {
        for j in 0..side {
            let (x, y) = (j as f32 / side as f32, i as f32 / side as f32);
            let checker = if (i / 3 + j / 3).is_multiple_of(2) {
                0.3
            } else {
                0.0
            };
            rgb.push(0.02 + 0.5 * x + checker);
            rgb.push(0.1 + 0.4 * y);
            rgb.push(0.05 + 0.2 * (x * y) + checker);
        }
    }
    rgb
}

fn material(side: usize) -> NeuralMaterial {
    let photo = Photo::from_linear_rgb(side, side, textured(side)).expect("valid photo");
    model().estimate(&photo).expect("estimate")
}

/// Finite and ≥ 0 everywhere; returns the maximum.
fn assert_clean(what: &str, img: &RgbImage<f32>) -> f32 {
    let mut max = 0.0f32;
    for (k, &x) in img.data().iter().enumerate() {
        assert!(x.is_finite() && x >= 0.0, "{what}: value {k} = {x}");
        max = max.max(x);
    }
    max
}

fn assert_params_finite(what: &str, m: &NeuralMaterial) {
    let d = &m.params().data;
    assert_eq!(d.len(), m.size().0 * m.size().1 * 64, "{what}");
    assert!(d.iter().all(|x| x.is_finite()), "{what}: non-finite param");
}

/// A point at `dist` from `target` in direction (θ from the normal, azimuth 0).
fn at_angle(target: DVec3, theta_deg: f64, dist: f64) -> DVec3 {
    let t = theta_deg.to_radians();
    v(
        target.x + dist * t.sin(),
        target.y,
        target.z + dist * t.cos(),
    )
}

#[test]
fn odd_sizes_estimate_and_relight_to_finite_images() {
    for side in [1usize, 7, 13, 40] {
        let m = material(side);
        assert_eq!(m.size(), (side, side));
        assert_params_finite(&format!("{side}²"), &m);
        let scene = Scene::new(Light::Point(v(1.0, 0.5, 3.0)), View::Point(v(0.0, 0.0, D)));
        let img = relight(model(), &m, &scene).expect("relight");
        assert_eq!((img.width(), img.height()), (side, side));
        let max = assert_clean(&format!("{side}²"), &img);
        eprintln!("{side}²: max radiance {max:e}");
    }
}

#[test]
fn degenerate_photos_give_finite_params_and_images() {
    let side = 13;
    let n = side * side * 3;
    let mut denormal = textured(side);
    denormal.iter_mut().step_by(2).for_each(|x| *x = 1e-40);
    let mut negative = textured(side);
    negative.iter_mut().step_by(5).for_each(|x| *x = -3.0);
    let cases: Vec<(&str, Vec<f32>)> = vec![
        ("all black", vec![0.0; n]),
        ("all white (clipped LDR)", vec![1.0; n]),
        ("HDR 1e6", vec![1e6; n]),
        ("f32::MAX", vec![f32::MAX; n]),
        ("denormals", denormal),
        ("negative noise", negative),
    ];
    let scene = Scene::new(
        Light::Point(v(-1.0, 2.0, 2.0)),
        View::Point(v(0.5, 0.0, 5.0)),
    );
    for (what, rgb) in cases {
        let photo = Photo::from_linear_rgb(side, side, rgb).expect(what);
        let m = model().estimate(&photo).expect(what);
        assert_params_finite(what, &m);
        assert_clean(what, &relight(model(), &m, &scene).expect(what));
    }
}

#[test]
fn ldr_model_clamps_hdr_input_exactly_like_clipped_white() {
    // The default model is LDR: 1e6 and 1.0 both clamp to 0.999999 before the log, so the two
    // estimates must be bit-identical (defined behaviour, not merely finite).
    assert_eq!(model().config().log_mode, LogMode::Ldr);
    let side = 7;
    let white = Photo::from_linear_rgb(side, side, vec![1.0; side * side * 3]).expect("white");
    let hdr = Photo::from_linear_rgb(side, side, vec![1e6; side * side * 3]).expect("hdr");
    let a = model().estimate(&white).expect("white");
    let b = model().estimate(&hdr).expect("hdr");
    assert_eq!(a.params().data, b.params().data);
}

#[test]
fn hdr_log_input_up_to_1e6_keeps_the_unet_finite() {
    // The network sees ln(1+1e6) ≈ 13.8 per channel in HDR mode, 19× the LDR maximum; the
    // facade's model is LDR, so drive the CPU U-Net with an HDR-mode input directly.
    let side = 13;
    let mut rgb = textured(side);
    rgb.iter_mut().step_by(3).for_each(|x| *x *= 1e6);
    let d = nam::geometry::CAPTURE_DISTANCE as f32;
    let input = nam::network_input(&rgb, side, side, LogMode::Hdr, d).expect("finite photo");
    let max_in = input[..3 * side * side]
        .iter()
        .fold(0.0f32, |a, &b| a.max(b));
    assert!(max_in > 13.0, "{max_in}");
    let map = model()
        .cpu()
        .unet
        .estimate(&input, side, side)
        .expect("estimate");
    assert!(map.data.iter().all(|x| x.is_finite()));
}

#[test]
fn non_finite_empty_non_square_and_oversized_photos_are_errors() {
    let side = 7;
    for (k, bad) in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY]
        .into_iter()
        .enumerate()
    {
        let mut rgb = textured(side);
        let idx = (2 * side + 5) * 3 + k; // row 2, col 5, channel k
        rgb[idx] = bad;
        let err = Photo::from_linear_rgb(side, side, rgb).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, NamError::Photo(_)), "{msg}");
        assert!(
            msg.contains("row 2, col 5") && msg.contains("not finite"),
            "{msg}"
        );
    }
    let err = Photo::from_linear_rgb(0, 0, Vec::new()).unwrap_err();
    assert!(err.to_string().contains("no pixels"), "{err}");
    let err = Photo::from_linear_rgb(7, 8, vec![0.5; 8 * 7 * 3]).unwrap_err();
    assert!(err.to_string().contains("must be square"), "{err}");
    let err = Photo::from_linear_rgb(7, 7, vec![0.5; 7 * 7 * 3 - 1]).unwrap_err();
    assert!(err.to_string().contains("expected 147 RGB values"), "{err}");
    let err = Photo::from_linear_rgb(5000, 5000, Vec::new()).unwrap_err();
    assert!(err.to_string().contains("largest supported side"), "{err}");
    assert!(Photo::from_linear_rgb(4, 4, vec![0.5; 48]).is_ok());
}

#[test]
fn nan_and_inf_pixels_in_an_exr_file_are_load_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    for (name, bad) in [("nan.exr", f32::NAN), ("inf.exr", f32::INFINITY)] {
        let mut rgb = textured(5);
        rgb[(3 * 5 + 1) * 3 + 2] = bad; // row 3, col 1
        let img = RgbImage::from_vec(5, 5, rgb).expect("image");
        let path = dir.path().join(name);
        std::fs::write(&path, nam_ggx::imageio::encode_exr(&img).expect("encode")).expect("write");
        let err = Photo::load(&path).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains(name), "{msg}");
        assert!(msg.contains("row 3") && msg.contains("col 1"), "{msg}");
    }
}

/// Every stiff scene of the issue: finite ≥ 0 output, and black exactly where the light or the
/// viewer is on or below the surface plane.
#[test]
fn stiff_scenes_relight_to_finite_images_and_black_below_the_horizon() {
    let m = material(13);
    let cam = v(0.0, 0.0, D);
    let centre = v(0.0, 0.0, 0.0);
    // A pixel centre of a 13×13 image: (row 6, col 6) is the origin; (row 0, col 0) a corner.
    let corner = v(2.0 * 0.5 / 13.0 - 1.0, 1.0 - 2.0 * 0.5 / 13.0, 0.0);
    let lit: Vec<(&str, Light, View)> = vec![
        ("capture geometry", Light::Point(cam), View::Point(cam)),
        (
            "co-located off-axis",
            Light::Point(v(0.3, -0.2, 2.0)),
            View::Point(v(0.3, -0.2, 2.0)),
        ),
        (
            "grazing point light θ = 89.99°",
            Light::Point(at_angle(centre, 89.99, 10.0)),
            View::Point(cam),
        ),
        (
            "grazing view θ = 89.999°",
            Light::Point(cam),
            View::Point(at_angle(centre, 89.999, 10.0)),
        ),
        (
            "both grazing, opposite sides",
            Light::Point(at_angle(centre, 89.99, 10.0)),
            View::Point(at_angle(centre, -89.99, 10.0)),
        ),
        (
            "light 1e-3 above the centre pixel",
            Light::Point(v(0.0, 0.0, 1e-3)),
            View::Point(cam),
        ),
        (
            "light 1e-3 above a corner pixel",
            Light::Point(v(corner.x, corner.y, 1e-3)),
            View::Point(cam),
        ),
        (
            "view 1e-3 above the centre",
            Light::Point(cam),
            View::Point(v(0.0, 0.0, 1e-3)),
        ),
        (
            "light at 1e4",
            Light::Point(at_angle(centre, 30.0, 1e4)),
            View::Point(cam),
        ),
        (
            "light and view at 1e4",
            Light::Point(v(0.0, 1e4, 1e4)),
            View::Point(v(1e4, 0.0, 1e4)),
        ),
        (
            "directional + orthographic",
            Light::Directional(v(1.0, 1.0, 1.0)),
            View::Orthographic(v(0.0, 0.0, 1.0)),
        ),
        (
            "directional grazing",
            Light::Directional(v(1.0, 0.0, 1e-7)),
            View::Orthographic(v(-0.3, 0.1, 1.0)),
        ),
        (
            "directional mirror pair",
            Light::Directional(v(0.5, 0.0, 1.0)),
            View::Orthographic(v(-0.5, 0.0, 1.0)),
        ),
        (
            "directional + point view",
            Light::Directional(v(0.0, 0.0, 3.0)),
            View::Point(cam),
        ),
        (
            "point light + orthographic view",
            Light::Point(v(2.0, 2.0, 1.0)),
            View::Orthographic(v(0.0, 0.0, 1.0)),
        ),
    ];
    for (what, light, view) in lit {
        for (falloff, intensity) in [(false, 1.0), (true, 1.0), (true, 1e6), (false, 0.0)] {
            let scene = Scene {
                light,
                view,
                intensity,
                falloff,
            };
            let img = relight(model(), &m, &scene).unwrap_or_else(|e| panic!("{what}: {e}"));
            let max = assert_clean(what, &img);
            if intensity == 0.0 {
                assert_eq!(max, 0.0, "{what}: zero intensity");
            }
        }
    }

    let below: Vec<(&str, Light, View)> = vec![
        (
            "light below",
            Light::Point(v(0.0, 0.0, -D)),
            View::Point(cam),
        ),
        (
            "light on the plane",
            Light::Point(v(3.0, 0.0, 0.0)),
            View::Point(cam),
        ),
        (
            "light exactly on a pixel centre",
            Light::Point(corner),
            View::Point(cam),
        ),
        (
            "view below",
            Light::Point(cam),
            View::Point(v(0.0, 0.0, -1.0)),
        ),
        (
            "view on the plane",
            Light::Point(cam),
            View::Point(v(0.0, 5.0, 0.0)),
        ),
        (
            "view exactly on the centre pixel",
            Light::Point(cam),
            View::Point(centre),
        ),
        (
            "directional light below",
            Light::Directional(v(1.0, 0.0, -1e-9)),
            View::Orthographic(v(0.0, 0.0, 1.0)),
        ),
        (
            "directional light horizontal",
            Light::Directional(v(1.0, 0.0, 0.0)),
            View::Point(cam),
        ),
        (
            "orthographic view below",
            Light::Point(cam),
            View::Orthographic(v(0.0, 0.0, -1.0)),
        ),
    ];
    for (what, light, view) in below {
        let scene = Scene {
            light,
            view,
            intensity: 1e6,
            falloff: true,
        };
        let img = relight(model(), &m, &scene).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert!(img.data().iter().all(|&x| x == 0.0), "{what}: not black");
    }
}

#[test]
fn near_light_falloff_is_large_but_finite_and_far_light_is_tiny() {
    let m = material(13);
    let cam = v(0.0, 0.0, D);
    let near = Scene {
        light: Light::Point(v(0.0, 0.0, 1e-3)),
        view: View::Point(cam),
        intensity: 1.0,
        falloff: true,
    };
    let far = Scene {
        light: Light::Point(v(0.0, 0.0, 1e4)),
        ..near
    };
    let unscaled = Scene {
        falloff: false,
        ..far
    };
    let a = relight(model(), &m, &near).expect("near");
    let b = relight(model(), &m, &far).expect("far");
    let c = relight(model(), &m, &unscaled).expect("unscaled");
    assert_clean("near", &a);
    assert_clean("far", &b);
    // Centre pixel (row 6, col 6) at the origin: falloff d²/1e-6 ≈ 1.6e7 for the near light.
    let k = (6 * 13 + 6) * 3;
    assert!(a.data()[k] > 1e5, "near light centre {}", a.data()[k]);
    // Far light: d²/1e8 ≈ 1.6e-7 times the unscaled value, exactly the falloff (same directions).
    for ch in 0..3 {
        let (x, y) = (b.data()[k + ch], c.data()[k + ch]);
        let want = y * (D * D / 1e8) as f32;
        assert!(
            (x - want).abs() <= 1e-6 * want.abs() + 1e-30,
            "{x} vs {want}"
        );
    }
}

#[test]
fn distant_point_light_converges_to_the_directional_light() {
    // A point light at 1e7 along (0.3, 0, 1) is within 1e-7 rad of the directional light at
    // every pixel, i.e. within f32 rounding of the directions; the two relights may differ
    // only by that rounding as amplified by the top encoding octave (2^15·π).
    let m = material(13);
    let dir = v(0.3, 0.0, 1.0);
    let len = (0.09f64 + 1.0).sqrt();
    let far = v(0.3 / len * 1e7, 0.0, 1.0 / len * 1e7);
    let view = View::Orthographic(v(0.0, 0.0, 1.0));
    let a = relight(model(), &m, &Scene::new(Light::Point(far), view)).expect("point");
    let b = relight(model(), &m, &Scene::new(Light::Directional(dir), view)).expect("directional");
    let mean_b = b.data().iter().map(|&x| f64::from(x)).sum::<f64>() / b.data().len() as f64;
    let worst = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&x, &y)| f64::from((x - y).abs()))
        .fold(0.0, f64::max);
    // Same tolerance the facade tests use between the two CPU direction paths.
    assert!(
        worst <= 2e-2 * mean_b.max(1e-3),
        "worst |Δ| {worst}, mean {mean_b}"
    );
}

#[test]
fn invalid_scenes_are_errors_that_say_why() {
    let m = material(7);
    let cam = v(0.0, 0.0, D);
    let bad: Vec<(&str, Scene, &str)> = vec![
        (
            "NaN light",
            Scene::new(Light::Point(v(f64::NAN, 0.0, 1.0)), View::Point(cam)),
            "finite",
        ),
        (
            "inf view",
            Scene::new(Light::Point(cam), View::Point(v(0.0, f64::INFINITY, 1.0))),
            "finite",
        ),
        (
            "zero directional light",
            Scene::new(Light::Directional(v(0.0, 0.0, 0.0)), View::Point(cam)),
            "zero vector",
        ),
        (
            "zero orthographic view",
            Scene::new(Light::Point(cam), View::Orthographic(v(0.0, 0.0, 0.0))),
            "zero vector",
        ),
        (
            "negative intensity",
            Scene {
                intensity: -1.0,
                ..Scene::new(Light::Point(cam), View::Point(cam))
            },
            "intensity",
        ),
        (
            "NaN intensity",
            Scene {
                intensity: f64::NAN,
                ..Scene::new(Light::Point(cam), View::Point(cam))
            },
            "intensity",
        ),
    ];
    for (what, scene, needle) in bad {
        let err = relight(model(), &m, &scene).unwrap_err().to_string();
        assert!(err.contains(needle), "{what}: {err}");
    }
}

fn q(wi: Vec3, wo: Vec3) -> BrdfQuery {
    BrdfQuery {
        uv: Vec2::new(0.3, 0.6),
        wi,
        wo,
    }
}

#[test]
fn brdf_eval_is_zero_below_the_horizon_and_finite_at_grazing_angles() {
    let m = material(7);
    let brdf = NeuralBrdf::new(model(), &m).expect("bind");
    let up = Vec3::Z;
    let graze = |z: f32| Vec3::new(1.0, 0.0, z);
    let queries = [
        q(up, up),                                  // co-located, normal incidence
        q(graze(1e-7), up),                         // grazing light
        q(up, graze(1e-7)),                         // grazing view
        q(graze(1e-7), Vec3::new(-1.0, 0.0, 1e-7)), // both grazing, mirror pair
        q(graze(1e-7), graze(1e-7)),                // both grazing, co-located
        q(Vec3::new(0.0, 0.0, 1e-15), up),          // tiny but normalisable
        q(Vec3::new(3.0, 4.0, 1e4), up * 1e-20),    // non-unit inputs are normalised
    ];
    let f = brdf.eval(&queries).expect("eval");
    let fr = brdf.eval_fr(&queries).expect("eval_fr");
    for (k, (a, b)) in f.iter().zip(&fr).enumerate() {
        assert!(a.is_finite() && a.min_element() >= 0.0, "eval {k}: {a}");
        assert!(b.is_finite() && b.min_element() >= 0.0, "eval_fr {k}: {b}");
    }
    // cos θi = 1e-7 is below eval_fr's 1e-6 guard: f_r is defined as 0 there, not R/1e-7.
    assert_eq!(fr[1], Vec3::ZERO);

    let below = [
        q(Vec3::new(0.0, 0.0, -1.0), up),
        q(up, Vec3::new(0.3, 0.0, -1e-6)),
        q(Vec3::X, up), // exactly on the horizon
        q(up, Vec3::new(0.0, -1.0, 0.0)),
        q(Vec3::new(0.6, 0.0, 0.8), Vec3::new(-0.6, 0.0, -0.8)), // ωi = −ωo: no half vector
    ];
    for (k, (a, b)) in brdf
        .eval(&below)
        .expect("eval")
        .into_iter()
        .zip(brdf.eval_fr(&below).expect("eval_fr"))
        .enumerate()
    {
        assert_eq!(a, Vec3::ZERO, "below {k}");
        assert_eq!(b, Vec3::ZERO, "below {k}");
    }
}

#[test]
fn brdf_rejects_degenerate_queries_and_wraps_extreme_uvs() {
    let m = material(7);
    let brdf = NeuralBrdf::new(model(), &m).expect("bind");
    let up = Vec3::Z;
    for (what, query) in [
        ("zero wi", q(Vec3::ZERO, up)),
        ("NaN wo", q(up, Vec3::new(f32::NAN, 0.0, 1.0))),
        ("inf wi", q(Vec3::new(0.0, f32::INFINITY, 1.0), up)),
        (
            "NaN uv",
            BrdfQuery {
                uv: Vec2::new(f32::NAN, 0.5),
                wi: up,
                wo: up,
            },
        ),
    ] {
        let err = brdf.eval(&[query]).unwrap_err();
        assert!(matches!(err, NamError::Query(_)), "{what}: {err}");
    }
    // Texture coordinates tile: huge, negative and just-below-integer values pick a texel.
    let uvs = [1e30, -1e30, -1e-30, 0.999_999_9, 7.25, -3.75];
    let queries: Vec<BrdfQuery> = uvs
        .iter()
        .map(|&u| BrdfQuery {
            uv: Vec2::new(u, -u),
            wi: Vec3::new(0.2, 0.1, 1.0),
            wo: up,
        })
        .collect();
    for (k, f) in brdf.eval(&queries).expect("eval").into_iter().enumerate() {
        assert!(
            f.is_finite() && f.min_element() >= 0.0,
            "uv {}: {f}",
            uvs[k]
        );
    }
    // 7.25 and -3.75 wrap to 0.25 — the same texel in a 7-wide map. One batch,
    // so both rows go through the same GEMM path (batch size can change the
    // summation order by an ulp).
    let wrapped = BrdfQuery {
        uv: Vec2::new(0.25, 0.75),
        ..queries[4]
    };
    let f = brdf.eval(&[queries[4], wrapped]).expect("eval");
    assert_eq!(f[0], f[1]);
}

#[test]
fn sampling_and_pdf_are_defined_for_extreme_random_numbers_and_directions() {
    let m = material(7);
    let brdf = NeuralBrdf::new(model(), &m).expect("bind");
    let uv = Vec2::splat(0.5);
    let up = Vec3::Z;
    let us = [
        Vec2::ZERO,
        Vec2::ONE,
        Vec2::new(0.5, 0.5), // the disk centre
        Vec2::new(1.0, 0.0),
        Vec2::new(0.999_999_9, 0.000_000_1),
        Vec2::new(f32::NAN, 0.5),
        Vec2::new(-5.0, 7.0),
    ];
    let req: Vec<_> = us.iter().map(|&u| (uv, up, u)).collect();
    for (k, s) in brdf.sample(&req).expect("sample").into_iter().enumerate() {
        // A sample on the disk rim has cos θi = 0 and pdf 0: it is None, never a 0/0.
        if let Some(s) = s {
            assert!(s.wi.is_finite() && s.wi.z > 0.0, "u {}: {:?}", us[k], s);
            assert!(s.pdf.is_finite() && s.pdf > 0.0, "u {}: {:?}", us[k], s);
            assert!(
                s.weight.is_finite() && s.weight.min_element() >= 0.0,
                "u {}: {:?}",
                us[k],
                s
            );
        }
    }
    // Viewer below or on the horizon: no sample, pdf 0.
    for wo in [Vec3::new(0.0, 0.0, -1.0), Vec3::X] {
        let s = brdf.sample(&[(uv, wo, Vec2::splat(0.3))]).expect("sample");
        assert!(s[0].is_none(), "{wo}");
        assert_eq!(brdf.pdf(wo, up), 0.0);
    }
    assert_eq!(brdf.pdf(up, Vec3::new(0.0, 0.0, -1.0)), 0.0);
    assert_eq!(brdf.pdf(up, Vec3::new(f32::NAN, 0.0, 1.0)), 0.0);
    assert_eq!(brdf.pdf(up, Vec3::ZERO), 0.0);
    assert!((brdf.pdf(up, up) - std::f32::consts::FRAC_1_PI).abs() < 1e-7);
}

// ---------------------------------------------------------------------------------------------
// f16 headroom and f32-vs-f64 accuracy on the real photos (../shared/real_photos).

/// f16's largest finite value.
const F16_MAX: f32 = 65504.0;
/// Headroom demanded of every activation: `max |activation| · F16_HEADROOM < F16_MAX`.
/// (Measured worst at 24²: 183.5, 357× below; at 256² see docs/perf/f16_activation_range.md.
/// A fine-tune with frozen BatchNorms once drove the bottleneck to 5.2e4 at 256², and this
/// test caught it; `train --bottleneck-limit` keeps it down.)
const F16_HEADROOM: f32 = 16.0;
/// Side the real photos are resampled to for the (slow, per-layer traced) reference U-Net in
/// CI; the full-resolution table comes from `cargo run --release -p nam --example
/// activation_range`.
const TRACE_SIDE: usize = 24;
/// Worst f32 fast path vs f64-accumulated reference, param maps: `max |Δ| / max |ref|`.
/// Measured with the shipped model 4.8e-3 at 24² on the black photo (real photos ≤ 7.6e-4;
/// the model before the input skip: 6.5e-4 on clipped white): InstanceNorm of near-constant
/// channels divides f32 rounding by a tiny standard deviation, and a black photo makes every
/// colour channel constant. End to end that is 2.6e-2 of a near-black image (below
/// [`END_TO_END_F32_VS_F64_TOL`]). At 256² see docs/perf/f16_activation_range.md.
const UNET_F32_VS_F64_TOL: f64 = 1e-2;
/// Worst f32 fast path vs f64 reference of the render MLP alone (same params), radiance:
/// `|Δ| / max(|ref|, 1e-2)`. Measured 5.2e-5.
const RENDER_F32_VS_F64_TOL: f64 = 5e-4;
/// The same measure for the whole pipeline (fast U-Net then fast render vs both references):
/// the render MLP amplifies the U-Net's param differences ~100×. Measured 4.1e-2 at 24²
/// with the model before the input skip (clipped white); now 2.6e-2 (black; real photos ≤ 4.0e-3).
const END_TO_END_F32_VS_F64_TOL: f64 = 0.25;

/// The light/view pairs the render MLP is traced under (positions, surface frame).
fn trace_scenes() -> [([f32; 3], [f32; 3]); 4] {
    let d = D as f32;
    [
        ([0.0, 0.0, d], [0.0, 0.0, d]),       // capture: co-located flash
        ([1.0, 1.0, 4.0], [0.0, 0.0, d]),     // the README's relight
        ([9.96, 0.0, 0.87], [0.0, 0.0, d]),   // grazing light, θ ≈ 85°
        ([-2.0, 0.5, 3.0], [1.0, -1.0, 2.0]), // both off-axis
    ]
}

fn unit(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Per-photo result of the traced reference run and the f32-vs-f64 comparisons.
struct Traced {
    ranges: nam_model::reference::ActivationRanges,
    /// U-Net, fast f32 vs f64 reference: `max |Δ| / max |ref|` over the param map.
    unet_rel: f64,
    /// Render MLP alone (both on the reference params), log space: `max |Δ|`.
    render_log_abs: f64,
    /// Render MLP alone, radiance: `max |Δ| / max(|ref|, 1e-2)`.
    render_rel: f64,
    /// The whole pipeline (fast U-Net + fast render vs both references), radiance, same measure.
    end_to_end_rel: f64,
    render_values: usize,
}

fn rel(a: f32, b: f32) -> f64 {
    f64::from((a - b).abs()) / f64::from(b.abs()).max(1e-2)
}

/// Runs the traced f64-accumulated reference U-Net and render MLP on a photo, and the f32 fast
/// path on the same input, returning ranges and the worst f32-vs-f64 errors.
fn trace(photo: &Photo, pixel_step: usize) -> Traced {
    use nam_model::reference::{self, Accumulate};
    let w = model().weights();
    let side = photo.side();
    let input = photo
        .network_input(model().config().log_mode)
        .expect("finite photo");
    let (reference_map, mut ranges) =
        reference::estimate_traced(w, &input, side, side, Accumulate::F64).expect("reference");
    let fast = model()
        .cpu()
        .unet
        .estimate(&input, side, side)
        .expect("fast");
    let scale = reference_map
        .data
        .iter()
        .fold(0.0f32, |m, x| m.max(x.abs()));
    let unet_rel = fast
        .data
        .iter()
        .zip(&reference_map.data)
        .map(|(a, b)| f64::from((a - b).abs()) / f64::from(scale))
        .fold(0.0, f64::max);

    let c = reference_map.channels;
    let net = &model().cpu().render;
    let (mut render_log_abs, mut render_rel, mut end_to_end_rel) = (0.0f64, 0.0f64, 0.0f64);
    let mut render_values = 0;
    for (light, view) in trace_scenes() {
        for i in (0..side).step_by(pixel_step) {
            for j in (0..side).step_by(pixel_step) {
                let p = nam_model::geometry::pixel_position::<f32>(i, j, side, side).to_array();
                let wi = unit([light[0] - p[0], light[1] - p[1], light[2]]);
                let wo = unit([view[0] - p[0], view[1] - p[1], view[2]]);
                let k = i * side + j;
                let ref_params = &reference_map.data[k * c..(k + 1) * c];
                let (t, r) = reference::render_traced(w, ref_params, wi, wo, Accumulate::F64)
                    .expect("reference render");
                ranges.merge(&r);
                let (mut same, mut log, mut whole) = ([0.0f32; 3], [0.0f32; 3], [0.0f32; 3]);
                net.render_batch(ref_params, &[wi], &[wo], &mut same)
                    .expect("fast render");
                net.render_log_batch(ref_params, &[wi], &[wo], &mut log)
                    .expect("fast render");
                net.render_batch(&fast.data[k * c..(k + 1) * c], &[wi], &[wo], &mut whole)
                    .expect("fast render");
                for ch in 0..3 {
                    render_log_abs = render_log_abs.max(f64::from((log[ch] - t.log[ch]).abs()));
                    render_rel = render_rel.max(rel(same[ch], t.radiance[ch]));
                    end_to_end_rel = end_to_end_rel.max(rel(whole[ch], t.radiance[ch]));
                    render_values += 1;
                }
            }
        }
    }
    Traced {
        ranges,
        unet_rel,
        render_log_abs,
        render_rel,
        end_to_end_rel,
        render_values,
    }
}

#[test]
fn f16_has_headroom_over_every_activation_and_f32_matches_f64_on_real_photos() {
    use rayon::prelude::*;
    let Some(photos) = common::real_photos() else {
        return;
    };
    let t0 = std::time::Instant::now();
    let mut inputs: Vec<(String, Photo)> = photos
        .iter()
        .map(|(n, p)| (n.clone(), p.resized(TRACE_SIDE).expect("resize")))
        .collect();
    // Stiff photos too: clipped white, black, and a hard checkerboard (max local contrast).
    let s = TRACE_SIDE;
    let checker: Vec<f32> = (0..s * s * 3)
        .map(|k| {
            if ((k / 3) % s / 2 + (k / 3) / s / 2).is_multiple_of(2) {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    for (name, rgb) in [
        ("white", vec![1.0; s * s * 3]),
        ("black", vec![0.0; s * s * 3]),
        ("checker", checker),
    ] {
        inputs.push((
            name.into(),
            Photo::from_linear_rgb(s, s, rgb).expect("photo"),
        ));
    }
    let results: Vec<(String, Traced)> = inputs
        .par_iter()
        .map(|(n, p)| (n.clone(), trace(p, TRACE_SIDE / 4)))
        .collect();
    let mut all = nam_model::reference::ActivationRanges::default();
    let mut worst = [0.0f64; 4];
    let mut values = 0usize;
    for (name, t) in &results {
        eprintln!(
            "{name}: max |activation| {:.1}; f32 vs f64: U-Net {:.2e}, render log |Δ| {:.2e}, \
             render rel {:.2e}, end-to-end rel {:.2e}",
            t.ranges.max(),
            t.unet_rel,
            t.render_log_abs,
            t.render_rel,
            t.end_to_end_rel
        );
        all.merge(&t.ranges);
        let r = [t.unet_rel, t.render_log_abs, t.render_rel, t.end_to_end_rel];
        for (w, x) in worst.iter_mut().zip(r) {
            *w = w.max(x);
        }
        values += t.render_values;
    }
    let (worst_name, worst_act) =
        all.entries.iter().fold(
            ("", 0.0f32),
            |a, (n, m)| if *m > a.1 { (n.as_str(), *m) } else { a },
        );
    eprintln!(
        "f16 headroom: worst activation {worst_act:.1} at {worst_name} over {} traced tensors, \
         {} inputs at {TRACE_SIDE}²: f16 max / worst = {:.0}× ({:.1} s)",
        all.entries.len(),
        results.len(),
        F16_MAX / worst_act,
        t0.elapsed().as_secs_f64()
    );
    eprintln!(
        "f32 fast path vs f64 reference: U-Net max|Δ|/max|ref| {:.2e}; render MLP log |Δ| {:.2e}, \
         rel {:.2e}; end to end rel {:.2e} ({values} radiance values)",
        worst[0], worst[1], worst[2], worst[3]
    );
    assert!(all.entries.len() > 100, "{}", all.entries.len());
    assert!(
        worst_act * F16_HEADROOM < F16_MAX,
        "{worst_name} reaches {worst_act}: less than {F16_HEADROOM}× below the f16 maximum"
    );
    assert!(
        worst[0] <= UNET_F32_VS_F64_TOL,
        "U-Net f32 vs f64: {:e}",
        worst[0]
    );
    assert!(
        worst[2] <= RENDER_F32_VS_F64_TOL,
        "render f32 vs f64: {:e}",
        worst[2]
    );
    assert!(
        worst[3] <= END_TO_END_F32_VS_F64_TOL,
        "end to end f32 vs f64: {:e}",
        worst[3]
    );
}

/// The render MLP's activations depend on the param magnitudes, which grow with the photo's
/// resolution: trace it on the full-resolution (256²) param maps of the real photos, from the
/// fast U-Net, at a 4×4 grid of pixels under each traced light/view pair.
#[test]
fn f16_has_headroom_over_the_render_mlp_at_full_resolution() {
    use nam_model::reference::{self, Accumulate, ActivationRanges};
    use rayon::prelude::*;
    let Some(photos) = common::real_photos() else {
        return;
    };
    let t0 = std::time::Instant::now();
    let w = model().weights();
    let traced: Vec<(String, usize, ActivationRanges)> = photos
        .par_iter()
        .map(|(name, photo)| {
            let m = model().estimate(photo).expect("estimate");
            let (side, c) = (photo.side(), m.params().channels);
            let mut ranges = ActivationRanges::default();
            for (light, view) in trace_scenes() {
                for i in (side / 8..side).step_by(side / 4) {
                    for j in (side / 8..side).step_by(side / 4) {
                        let p =
                            nam_model::geometry::pixel_position::<f32>(i, j, side, side).to_array();
                        let wi = unit([light[0] - p[0], light[1] - p[1], light[2]]);
                        let wo = unit([view[0] - p[0], view[1] - p[1], view[2]]);
                        let k = i * side + j;
                        let params = &m.params().data[k * c..(k + 1) * c];
                        let (_, r) = reference::render_traced(w, params, wi, wo, Accumulate::F64)
                            .expect("reference render");
                        ranges.merge(&r);
                    }
                }
            }
            (name.clone(), side, ranges)
        })
        .collect();
    let mut all = ActivationRanges::default();
    for (name, side, r) in &traced {
        eprintln!(
            "{name} ({side}²): render MLP max |activation| {:.1}",
            r.max()
        );
        all.merge(r);
    }
    for (n, m) in &all.entries {
        eprintln!("  {n}: {m:.2}");
    }
    let worst = all.max();
    eprintln!(
        "f16 headroom of the render MLP at full resolution: worst {worst:.1}, f16 max / worst = \
         {:.0}× ({:.1} s)",
        F16_MAX / worst,
        t0.elapsed().as_secs_f64()
    );
    assert!(all.entries.iter().any(|(n, _)| n == "render.l6"));
    assert!(
        worst * F16_HEADROOM < F16_MAX,
        "render MLP reaches {worst}: less than {F16_HEADROOM}× below the f16 maximum"
    );
}
