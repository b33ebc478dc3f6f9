//! The CPU renderer's reduced-precision products (`NeuralModel::set_cpu_precision`, issue 22):
//! each stays close to f32 on the embedded model and the bundled photo, f32 comes back bit for
//! bit, unsupported precisions are errors that change nothing, and `use_fastest_cpu_precision`
//! keeps the precision its probe measured fastest.

use nam::geometry::{Light, View};
use nam::{CpuPrecision, DVec3, NeuralModel, Photo, Scene, relight};
use std::path::PathBuf;

/// Mean `|ln(1 + R) − ln(1 + R_f32)|` over pixels and channels of the bundled photo relit at 64²
/// under a moved light, per precision. bf16: 8-bit mantissas, f32 sums (measured 2.6e-4 on
/// this photo); int8: 8-bit operands per channel / per row, exact sums (measured 3.3e-3). The
/// embedded model's own Hemisphere log-L1 against the GGX truth is ~0.03.
const BF16_MEAN_LOG_TOL: f32 = 5e-3;
const INT8_MEAN_LOG_TOL: f32 = 1e-2;

fn scene_and_photo() -> (Scene, Photo) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/example_photo.png");
    let photo = Photo::load_resized(path, false, Some(64)).expect("bundled photo");
    let scene = Scene::new(
        Light::Point(DVec3::new(1.2, 0.5, 3.8)),
        View::Point(DVec3::new(0.0, 0.0, 4.01)),
    );
    (scene, photo)
}

fn mean_log_difference(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x.ln_1p() - y.ln_1p()).abs())
        .sum::<f32>()
        / a.len() as f32
}

#[test]
fn reduced_precisions_stay_close_to_f32_and_f32_comes_back_exactly() {
    let (scene, photo) = scene_and_photo();
    let mut model = NeuralModel::embedded().expect("embedded model");
    assert_eq!(model.cpu_precision(), CpuPrecision::F32);
    let material = model.estimate(&photo).expect("estimate");
    let exact = relight(&model, &material, &scene)
        .expect("f32 relight")
        .into_vec();
    let supported = nam_model::RenderNet::supported_precisions();
    for (precision, tol) in [
        (CpuPrecision::Bf16, BF16_MEAN_LOG_TOL),
        (CpuPrecision::Int8, INT8_MEAN_LOG_TOL),
    ] {
        if !supported.contains(&precision) {
            assert!(model.set_cpu_precision(precision).is_err());
            assert_eq!(
                model.cpu_precision(),
                CpuPrecision::F32,
                "a refusal changes nothing"
            );
            eprintln!(
                "skipped {}: this CPU lacks the instructions",
                precision.name()
            );
            continue;
        }
        model.set_cpu_precision(precision).expect("supported");
        assert_eq!(model.cpu_precision(), precision);
        let got = relight(&model, &material, &scene)
            .expect("relight")
            .into_vec();
        assert!(got.iter().all(|v| v.is_finite() && *v >= 0.0));
        let mean = mean_log_difference(&got, &exact);
        println!("{} vs f32: mean |Δ ln(1+R)| {mean:e}", precision.name());
        assert!(mean < tol, "{}: {mean:e}", precision.name());
        assert!(mean > 0.0, "{} must actually run", precision.name());
        model.set_cpu_precision(CpuPrecision::F32).expect("f32");
        let back = relight(&model, &material, &scene)
            .expect("relight")
            .into_vec();
        assert_eq!(
            back,
            exact,
            "f32 after {} is the f32 path",
            precision.name()
        );
    }
}

/// Mean `|ln(1 + R) − ln(1 + R_f32)|` as above when the estimate runs in bf16 too (measured
/// 3.0e-4 on this photo, the relight in bf16 as well; 2.6e-4 with the f32 estimate).
const BF16_END_TO_END_MEAN_LOG_TOL: f32 = 5e-3;

#[test]
fn the_estimate_follows_bf16_and_comes_back_to_f32_exactly() {
    if !nam_model::bf16_supported() {
        eprintln!("skipped: this CPU lacks AVX-512 BF16");
        return;
    }
    let (scene, photo) = scene_and_photo();
    let mut model = NeuralModel::embedded().expect("embedded model");
    let exact_material = model.estimate(&photo).expect("estimate");
    let exact = relight(&model, &exact_material, &scene)
        .expect("f32 relight")
        .into_vec();
    model.set_cpu_precision(CpuPrecision::Bf16).expect("bf16");
    assert!(model.cpu().unet.is_bf16());
    let material = model.estimate(&photo).expect("bf16 estimate");
    assert_ne!(material.params().data, exact_material.params().data);
    let got = relight(&model, &material, &scene)
        .expect("relight")
        .into_vec();
    assert!(got.iter().all(|v| v.is_finite() && *v >= 0.0));
    let mean = mean_log_difference(&got, &exact);
    println!("bf16 estimate + relight vs f32: mean |Δ ln(1+R)| {mean:e}");
    assert!(mean < BF16_END_TO_END_MEAN_LOG_TOL, "{mean:e}");
    model.set_cpu_precision(CpuPrecision::F32).expect("f32");
    assert!(!model.cpu().unet.is_bf16());
    let back = model.estimate(&photo).expect("estimate");
    assert_eq!(back.params().data, exact_material.params().data);
}

#[test]
fn fastest_keeps_the_precision_its_probe_timed_fastest() {
    let mut model = NeuralModel::embedded().expect("embedded model");
    let times = model.use_fastest_cpu_precision().expect("probe");
    let supported = nam_model::RenderNet::supported_precisions();
    assert_eq!(
        times.iter().map(|t| t.precision).collect::<Vec<_>>(),
        supported,
        "one probe per supported precision"
    );
    assert!(
        times.iter().all(|t| t.ms.is_finite() && t.ms > 0.0),
        "{times:?}"
    );
    let best = times
        .iter()
        .min_by(|a, b| a.ms.total_cmp(&b.ms))
        .expect("f32 at least");
    assert_eq!(model.cpu_precision(), best.precision, "{times:?}");
}
