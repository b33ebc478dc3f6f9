//! End-to-end tests of the embedding API on the tiny golden model and the embedded model.

use glam::{Vec2, Vec3};
use nam::geometry::{Light, View};
use nam::{
    BrdfQuery, DVec3, LogMode, NeuralBrdf, NeuralMaterial, NeuralModel, Photo, Roi, Scene,
    ShadingFrame, relight, relight_roi,
};
use nam_weights::TensorFile;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures")
        .join(name)
}

/// f32 round-off in ln_1p and the half-vector z (computed in f64 then rounded).
const INPUT_TOL: f32 = 1e-6;
/// Two CPU code paths (streamed point-light relight vs per-pixel triples) differ only in
/// f32 rounding of the directions, which the top encoding octave (2^15·π) amplifies.
const PATH_TOL: f32 = 2e-2;

fn tiny() -> NeuralModel {
    NeuralModel::from_file(fixture("net_tiny.safetensors")).expect("tiny model loads")
}

fn grey_material(model: &NeuralModel, side: usize) -> NeuralMaterial {
    let rgb: Vec<f32> = (0..side * side * 3)
        .map(|k| 0.1 + 0.5 * ((k % 7) as f32 / 7.0))
        .collect();
    let photo = Photo::from_linear_rgb(side, side, rgb).expect("valid photo");
    model.estimate(&photo).expect("estimate")
}

/// Radiance `img` equals `π · eval(query k)` at every pixel `k`, within [`PATH_TOL`].
fn assert_image_matches_queries(
    img: &nam::RgbImage<f32>,
    brdf: &NeuralBrdf<'_>,
    queries: &[BrdfQuery],
) {
    let f = brdf.eval(queries).expect("eval");
    for (k, fk) in f.iter().enumerate() {
        let r = Vec3::from_slice(&img.data()[k * 3..k * 3 + 3]);
        let want = *fk * std::f32::consts::PI;
        assert!(
            (r - want).abs().max_element() <= PATH_TOL * (1.0 + want.abs().max_element()),
            "pixel {k}: {r} vs {want}"
        );
    }
}

fn point(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

#[test]
fn network_input_matches_torch_golden() {
    let g = TensorFile::from_file(fixture("net_tiny_golden.safetensors")).expect("golden");
    let photo = &g.tensors()["photo"];
    let (h, w) = (photo.shape()[0], photo.shape()[1]);
    let want = g.get("input", &[4, h, w]).expect("input");
    let d = nam::geometry::CAPTURE_DISTANCE as f32;
    let got = nam::network_input(photo.data(), h, w, LogMode::Ldr, d).expect("input");
    let worst = got
        .iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst < INPUT_TOL, "worst |Δ| = {worst}");
}

#[test]
fn srgb8_pixels_decode_like_a_png_file() {
    // Every 8-bit value, in a 16×16×3 photo written as a PNG and loaded from it.
    let bytes: Vec<u8> = (0..16 * 16 * 3).map(|k| (k * 7 % 256) as u8).collect();
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("p.png");
    image::RgbImage::from_raw(16, 16, bytes.clone())
        .expect("image")
        .save(&path)
        .expect("png");
    let from_file = Photo::load(&path).expect("load");
    let from_pixels = Photo::from_srgb8(16, 16, &bytes).expect("pixels");
    assert_eq!(from_pixels.rgb(), from_file.rgb());
    assert!(Photo::from_srgb8(16, 15, &bytes[..16 * 15 * 3]).is_err());
}

#[test]
fn estimate_cost_forecasts_memory_and_time_on_the_cpu() {
    let model = tiny();
    let cost = model.estimate_cost(64).expect("cost");
    // At least the input and the param map; the U-Net's own working set on top.
    let io = 64 * 64 * 4 * (4 + 64);
    assert!(cost.peak_bytes > io, "{cost:?}");
    let seconds = cost.seconds.expect("CPU backend: timed");
    assert!(seconds.is_finite() && seconds > 0.0, "{cost:?}");
    // Four times the pixels: at least three more param maps and inputs.
    let big = model.estimate_cost(128).expect("cost");
    assert!(
        big.peak_bytes > cost.peak_bytes + 3 * io,
        "{big:?} vs {cost:?}"
    );
}

#[test]
fn material_round_trips_through_nam_file_and_rejects_other_models() {
    let model = tiny();
    let m = grey_material(&model, 12);
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("m.nam");
    m.save_exact(&path).expect("save");
    let back = NeuralMaterial::load(&path).expect("load");
    assert_eq!(back, m);
    // The default save stores f16 params: the same material within f16 rounding.
    assert_eq!(
        std::fs::read(&path).expect("read"),
        m.to_bytes_exact().expect("bytes")
    );
    m.save(&path).expect("save f16");
    // Streamed to the file, the same bytes as serialised in memory.
    assert_eq!(
        std::fs::read(&path).expect("read"),
        m.to_bytes().expect("bytes")
    );
    let half = NeuralMaterial::load(&path).expect("load f16");
    let (a, b) = (&half.params().data, &m.params().data);
    assert!(
        a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= y.abs() * 4.9e-4 + 6e-8)
    );
    back.check_model(&model).expect("same model");
    let other = NeuralModel::from_weights(
        nam_weights::Weights::random(model.config().clone(), 7).expect("random"),
    )
    .expect("other model");
    let err = back.check_model(&other).unwrap_err().to_string();
    assert!(err.contains("not by this model"), "{err}");
    // No temporary files are left next to the output.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .expect("ls")
        .map(|e| e.expect("entry").file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("m.nam")]);
}

#[test]
fn corrupt_nam_file_is_a_clear_error() {
    let model = tiny();
    let bytes = grey_material(&model, 8).to_bytes().unwrap();
    for cut in [0, 7, 8, 100, bytes.len() - 1] {
        let err = NeuralMaterial::from_bytes(&bytes[..cut], "cut.nam").unwrap_err();
        assert!(err.to_string().contains("cut.nam"), "{err}");
    }
    let err = NeuralMaterial::from_bytes(
        &std::fs::read(fixture("net_tiny.safetensors")).expect("read"),
        "model.safetensors",
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("not a .nam file") || err.to_string().contains("params"),
        "{err}"
    );
}

#[test]
fn point_light_relight_matches_per_query_evaluation() {
    let model = tiny();
    let m = grey_material(&model, 10);
    let scene = Scene::new(
        Light::Point(point(1.0, -0.5, 3.0)),
        View::Point(point(-0.3, 0.2, 4.0)),
    );
    let img = relight(&model, &m, &scene).expect("relight");
    let brdf = NeuralBrdf::new(&model, &m).expect("bind");
    let (h, w) = m.size();
    let queries: Vec<BrdfQuery> = (0..h * w)
        .map(|k| {
            let p = nam::geometry::pixel_position(k / w, k % w, h, w);
            let d = nam::geometry::directions_at(&scene.light, &scene.view, p)
                .expect("dirs")
                .cast::<f32>();
            BrdfQuery {
                uv: Vec2::new(
                    ((k % w) as f32 + 0.5) / w as f32,
                    ((k / w) as f32 + 0.5) / h as f32,
                ),
                wi: Vec3::from_array(d.wi.to_array()),
                wo: Vec3::from_array(d.wo.to_array()),
            }
        })
        .collect();
    assert_image_matches_queries(&img, &brdf, &queries);
}

#[test]
fn light_or_view_below_the_surface_renders_black_and_eval_is_zero() {
    let model = tiny();
    let m = grey_material(&model, 8);
    for (l, v) in [
        (point(0.0, 0.0, -1.0), point(0.0, 0.0, 4.0)),
        (point(0.0, 1.0, 4.0), point(0.0, 0.0, 0.0)),
    ] {
        let img =
            relight(&model, &m, &Scene::new(Light::Point(l), View::Point(v))).expect("relight");
        assert!(img.data().iter().all(|&x| x == 0.0));
    }
    let brdf = NeuralBrdf::new(&model, &m).expect("bind");
    let q = |wi: Vec3, wo: Vec3| BrdfQuery {
        uv: Vec2::splat(0.5),
        wi,
        wo,
    };
    let f = brdf
        .eval(&[
            q(Vec3::new(0.0, 0.6, -0.8), Vec3::Z),
            q(Vec3::Z, Vec3::new(1.0, 0.0, 0.0)),
        ])
        .expect("eval");
    assert_eq!(f, vec![Vec3::ZERO, Vec3::ZERO]);
    assert!(brdf.eval(&[q(Vec3::ZERO, Vec3::Z)]).is_err());
    assert!(
        brdf.eval(&[BrdfQuery {
            uv: Vec2::new(f32::NAN, 0.0),
            wi: Vec3::Z,
            wo: Vec3::Z
        }])
        .is_err()
    );
}

#[test]
fn world_space_eval_on_tilted_frame_equals_local_eval_and_sample_weight_is_f_over_pdf() {
    let model = tiny();
    let m = grey_material(&model, 8);
    let brdf = NeuralBrdf::new(&model, &m).expect("bind");
    let frame = ShadingFrame::from_normal(Vec3::new(0.3, -0.4, 0.8)).expect("frame");
    let (wi_l, wo_l) = (
        Vec3::new(0.2, 0.1, 0.97).normalize(),
        Vec3::new(-0.4, 0.3, 0.87).normalize(),
    );
    let uv = Vec2::new(0.3, 0.7);
    let world = brdf
        .eval_world(&frame, uv, frame.to_world(wi_l), frame.to_world(wo_l))
        .expect("world");
    let local = brdf
        .eval(&[BrdfQuery {
            uv,
            wi: wi_l,
            wo: wo_l,
        }])
        .expect("local")[0];
    assert!((world - local).abs().max_element() < PATH_TOL * (1.0 + local.max_element()));

    let s = brdf
        .sample(&[
            (uv, wo_l, Vec2::new(0.25, 0.6)),
            (uv, -wo_l, Vec2::new(0.5, 0.5)),
        ])
        .expect("sample");
    let s0 = s[0].expect("wo above horizon");
    assert!(s[1].is_none(), "wo below the horizon has no sample");
    let f = brdf
        .eval(&[BrdfQuery {
            uv,
            wi: s0.wi,
            wo: wo_l,
        }])
        .expect("eval")[0];
    assert!((s0.weight * s0.pdf - f).abs().max_element() < 1e-5 * (1.0 + f.max_element()));
    assert!((brdf.pdf(wo_l, s0.wi) - s0.pdf).abs() < 1e-6);
}

#[test]
fn embedded_model_estimates_and_relights_the_bundled_photo_to_finite_values() {
    let model = NeuralModel::embedded().expect("embedded model");
    let photo = Photo::load(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/example_photo.png"),
    )
    .expect("bundled photo")
    .resized(64)
    .expect("resize");
    let m = model.estimate(&photo).expect("estimate");
    let scene = Scene::new(
        Light::Point(point(1.0, 1.0, 3.5)),
        View::Point(nam::geometry::capture_position(
            nam::geometry::CAPTURE_DISTANCE,
        )),
    );
    let img = relight(&model, &m, &scene).expect("relight");
    assert!(img.data().iter().all(|v| v.is_finite() && *v >= 0.0));
}

/// The same network on the same directions, summed in another order (f32).
const SAME_PATH_TOL: f32 = 1e-4;

/// Every pixel of `part` equals the pixel of `full` it stands for, within [`SAME_PATH_TOL`].
fn assert_roi_matches(part: &nam::RgbImage<f32>, full: &nam::RgbImage<f32>, roi: Roi) {
    for i in 0..roi.height {
        for j in 0..roi.width {
            let (a, b) = (part.pixel(i, j), full.pixel(roi.row + i, roi.col + j));
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= SAME_PATH_TOL * (1.0 + b[c].abs()),
                    "pixel ({i}, {j}) of {roi:?}: {a:?} vs {b:?}"
                );
            }
        }
    }
}

#[test]
fn roi_relight_equals_the_same_pixels_of_the_full_relight_and_rejects_bad_regions() {
    let model = tiny();
    let m = grey_material(&model, 11);
    let scene = Scene::new(
        Light::Point(point(0.7, 0.4, 2.5)),
        View::Point(point(0.0, -0.5, 4.0)),
    );
    let full = relight(&model, &m, &scene).expect("relight");
    let roi = Roi {
        row: 3,
        col: 2,
        height: 5,
        width: 7,
    };
    let part = relight_roi(&model, &m, &scene, roi).expect("roi");
    assert_eq!((part.height(), part.width()), (5, 7));
    assert_roi_matches(&part, &full, roi);
    for bad in [
        Roi {
            row: 0,
            col: 0,
            height: 0,
            width: 3,
        },
        Roi {
            row: 9,
            col: 0,
            height: 3,
            width: 3,
        },
        Roi {
            row: 0,
            col: 5,
            height: 1,
            width: 7,
        },
    ] {
        assert!(
            relight_roi(&model, &m, &scene, bad).is_err(),
            "{bad:?} accepted"
        );
    }
}

#[test]
fn directional_orthographic_relight_equals_per_query_evaluation() {
    // The specialised path (ND_enc once) against the general per-query BRDF evaluation; the
    // directions are re-normalised in f32 on one side, hence PATH_TOL.
    let model = tiny();
    let m = grey_material(&model, 9);
    let (wi, wo) = (
        Vec3::new(0.4, -0.3, 0.87).normalize(),
        Vec3::new(-0.2, 0.1, 0.97).normalize(),
    );
    let scene = Scene::new(
        Light::Directional(wi.as_dvec3()),
        View::Orthographic(wo.as_dvec3()),
    );
    let img = relight(&model, &m, &scene).expect("relight");
    let brdf = NeuralBrdf::new(&model, &m).expect("bind");
    let (h, w) = m.size();
    let queries: Vec<BrdfQuery> = (0..h * w)
        .map(|k| BrdfQuery {
            uv: Vec2::new(
                ((k % w) as f32 + 0.5) / w as f32,
                ((k / w) as f32 + 0.5) / h as f32,
            ),
            wi,
            wo,
        })
        .collect();
    assert_image_matches_queries(&img, &brdf, &queries);
}

#[test]
fn coordinates_beyond_f32_are_errors_and_tiny_directions_still_evaluate() {
    let model = tiny();
    let m = grey_material(&model, 6);
    let scene = Scene::new(
        Light::Point(point(1e39, 0.0, 1.0)),
        View::Point(point(0.0, 0.0, 4.0)),
    );
    let err = relight(&model, &m, &scene).expect_err("1e39 does not fit in f32");
    assert!(
        err.to_string().contains("within ±3.4e38 (f32's range)"),
        "{err}"
    );
    let brdf = NeuralBrdf::new(&model, &m).expect("bind");
    let q = |wi: Vec3| BrdfQuery {
        uv: Vec2::new(0.5, 0.5),
        wi,
        wo: Vec3::new(0.1, 0.2, 0.9),
    };
    let tiny_dir = brdf
        .eval(&[q(Vec3::new(0.0, 0.0, 1e-30))])
        .expect("tiny wi");
    let unit_dir = brdf.eval(&[q(Vec3::Z)]).expect("unit wi");
    assert_eq!(tiny_dir, unit_dir);
}

/// GPU (f32) against CPU image relights, per pixel: different summation orders and the
/// directions rounded to f32 in another order, amplified by the top encoding octave.
#[cfg(feature = "gpu")]
const GPU_TOL: f32 = 2e-2;

/// The tiny model with the default adapter attached (f32); `None`, with a printed reason,
/// when there is no adapter (a failure under `CI=true`). The model keeps its own handles to the device.
#[cfg(feature = "gpu")]
fn tiny_on_gpu() -> Option<NeuralModel> {
    let Some(gpu) = nam::nam_gpu::request_device(false) else {
        nam::nam_gpu::skip_without_adapter("no wgpu adapter");
        return None;
    };
    let mut model = tiny();
    model
        .attach_gpu(
            &gpu.device,
            &gpu.queue,
            gpu.info.device_type,
            nam::nam_gpu::Precision::F32,
        )
        .expect("attach");
    Some(model)
}

#[cfg(feature = "gpu")]
#[test]
fn gpu_relight_matches_the_cpu_for_directional_point_and_mixed_scenes() {
    let Some(model) = tiny_on_gpu() else { return };
    let cpu = tiny();
    let m = grey_material(&cpu, 11);
    let scenes = [
        Scene::new(
            Light::Directional(point(0.4, -0.3, 0.87)),
            View::Orthographic(point(-0.2, 0.1, 0.97)),
        ),
        Scene::new(
            Light::Point(point(0.5, 0.2, 1.5)),
            View::Point(point(0.0, 0.0, 4.0)),
        ),
        Scene::new(
            Light::Directional(point(0.1, 0.6, 0.5)),
            View::Point(point(0.3, 0.0, 2.0)),
        ),
    ];
    let roi = Roi {
        row: 2,
        col: 3,
        height: 5,
        width: 7,
    };
    for scene in &scenes {
        for r in [Roi::full(11, 11), roi] {
            let want = relight_roi(&cpu, &m, scene, r).expect("cpu relight");
            let got = relight_roi(&model, &m, scene, r).expect("gpu relight");
            let err = got
                .data()
                .iter()
                .zip(want.data())
                .map(|(g, w)| (g - w).abs() / (1.0 + w.abs()))
                .fold(0.0f32, f32::max);
            assert!(
                err <= GPU_TOL,
                "{scene:?} {r:?}: GPU vs CPU {err} > {GPU_TOL}"
            );
            assert!(want.data().iter().any(|&v| v > 0.0), "{scene:?}: all black");
        }
    }
}

#[cfg(feature = "gpu")]
#[test]
fn large_eval_batches_run_on_an_attached_gpu_with_the_cpu_values() {
    let Some(model) = tiny_on_gpu() else { return };
    let cpu = tiny();
    let m = grey_material(&cpu, 9);
    // Deterministic queries over the hemisphere, every 17th one below the horizon.
    let n = nam::GPU_MIN_QUERIES + 123;
    let queries: Vec<BrdfQuery> = (0..n)
        .map(|k| {
            let t = k as f32 * 0.37;
            let below = if k % 17 == 0 { -1.0 } else { 1.0 };
            BrdfQuery {
                uv: Vec2::new((k % 13) as f32 / 13.0, (k % 7) as f32 / 7.0),
                wi: Vec3::new(
                    0.6 * t.sin(),
                    0.5 * t.cos(),
                    below * (0.3 + (t * 0.5).cos().abs()),
                ),
                wo: Vec3::new(-0.4 * (t * 1.3).cos(), 0.3 * (t * 0.7).sin(), 1.0),
            }
        })
        .collect();
    let want = NeuralBrdf::new(&cpu, &m)
        .expect("bind")
        .eval(&queries)
        .expect("cpu");
    let on_gpu = NeuralBrdf::new(&model, &m).expect("bind");
    let got = on_gpu.eval(&queries).expect("gpu");
    let err = got
        .iter()
        .zip(&want)
        .map(|(g, w)| ((*g - *w).abs() / (1.0 + w.abs())).max_element())
        .fold(0.0f32, f32::max);
    eprintln!("GPU vs CPU eval over {n} queries: max relative difference {err:.2e}");
    assert!(err <= GPU_TOL, "GPU vs CPU eval: {err} > {GPU_TOL}");
    assert!(want.iter().any(|v| v.max_element() > 0.0));
    for k in (0..n).step_by(17) {
        assert_eq!(got[k], Vec3::ZERO, "query {k} is below the horizon");
    }
    // A small batch stays on the CPU: bit-identical.
    let small = &queries[..100];
    assert_eq!(on_gpu.eval(small).expect("small"), want[..100].to_vec());
}

#[test]
fn nd_interpolation_is_opt_in_bounded_and_leaves_rois_and_directional_scenes_exact() {
    let mut model = tiny();
    let m = grey_material(&model, 24);
    let scene = Scene::new(
        Light::Point(point(0.7, 0.4, 2.5)),
        View::Point(point(0.0, -0.5, 4.0)),
    );
    let exact = relight(&model, &m, &scene).expect("relight");
    assert_eq!(model.nd_interpolation(), None, "off by default");
    for bad in [0.0, -1.0, 90.0, f64::NAN, f64::INFINITY] {
        assert!(model.set_nd_interpolation(Some(bad)).is_err(), "{bad}");
        assert_eq!(
            model.nd_interpolation(),
            None,
            "a rejected bound changes nothing"
        );
    }
    // 20°: a grid step of 10 pixels of 2/24 units at light height 2.5.
    model.set_nd_interpolation(Some(20.0)).expect("valid bound");
    let approx = relight(&model, &m, &scene).expect("relight");
    let net = &model.cpu().render;
    let (l, v) = ([0.7, 0.4, 2.5], [0.0, -0.5, 4.0]);
    let direct = net
        .relight_interpolated(m.params(), l, v, 20f32.to_radians())
        .expect("interpolated");
    assert_eq!(
        approx.data(),
        &direct.data[..],
        "the facade runs the interpolated path"
    );
    assert_ne!(approx.data(), exact.data(), "and it is an approximation");
    // A region of interest stays on the exact per-pixel path.
    let roi = Roi {
        row: 2,
        col: 3,
        height: 4,
        width: 5,
    };
    let part = relight_roi(&model, &m, &scene, roi).expect("roi");
    assert_roi_matches(&part, &exact, roi);
    model.set_nd_interpolation(None).expect("off again");
    assert_eq!(
        relight(&model, &m, &scene).expect("relight").data(),
        exact.data()
    );
}

/// A 16² photo of a grey material with a clipped 4×5 blob (value 1.0 in every channel).
fn photo_with_clipped_blob() -> (Photo, Vec<bool>) {
    let side = 16;
    let clipped: Vec<bool> = (0..side * side)
        .map(|p| (5..9).contains(&(p / side)) && (6..11).contains(&(p % side)))
        .collect();
    let rgb = clipped
        .iter()
        .enumerate()
        .flat_map(|(p, &c)| {
            let v = if c {
                1.0
            } else {
                0.2 + 0.3 * ((p % 5) as f32 / 5.0)
            };
            [v, 0.9 * v, 0.8 * v]
        })
        .collect();
    (
        Photo::from_linear_rgb(side, side, rgb).expect("photo"),
        clipped,
    )
}

#[test]
fn estimate_fills_only_the_clipped_pixels_and_estimate_with_false_keeps_them() {
    let model = tiny();
    let (photo, clipped) = photo_with_clipped_blob();
    let filled = model.estimate(&photo).expect("estimate");
    let raw = model.estimate_with(&photo, false).expect("raw");
    let c = filled.params().channels;
    for (p, &is_clipped) in clipped.iter().enumerate() {
        let (a, b) = (
            &filled.params().data[p * c..(p + 1) * c],
            &raw.params().data[p * c..(p + 1) * c],
        );
        assert_eq!(a == b, !is_clipped, "pixel {p}");
        assert!(a.iter().all(|v| v.is_finite()), "pixel {p}");
    }
    // An all-white photo has nothing to fill from: the network's own params stay.
    let white = Photo::from_linear_rgb(8, 8, vec![1.0; 8 * 8 * 3]).expect("white");
    assert_eq!(
        model.estimate(&white).expect("white").params(),
        model
            .estimate_with(&white, false)
            .expect("white raw")
            .params()
    );
}
