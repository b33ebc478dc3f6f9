//! The whole network on the GPU against the torch golden fixtures (docs/FORMAT.md,
//! `tests/fixtures/net_tiny*.safetensors`, written by `python -m train_py.golden`), in f32 and
//! f16, and a saturated network's radiance against the CPU's cap at f32::MAX. Without an
//! adapter tests print a reason and pass, except under `CI=true` (`skip_without_adapter`).

use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};

use nam_gpu::{DeviceHandles, GpuNetwork, MatmulVariant, Precision};
use nam_weights::{Tensor, TensorFile, Weights, radiance_from_log};

/// f32 GPU vs torch f32: different summation orders through ~40 layers of the U-Net
/// (InstanceNorm divides by small standard deviations), so a few 1e-5 relative to the map's
/// largest magnitude.
const ESTIMATE_F32_TOL: f32 = 2e-4;
/// f16 storage rounds every activation to 11 bits through ~40 layers, and InstanceNorm over
/// the 3x5-pixel bottleneck of the 20x36 fixture amplifies that rounding (max error).
const ESTIMATE_F16_TOL: f32 = 0.15;
/// Mean absolute error (relative to the largest |param|) for f16: rounding noise averages out.
const ESTIMATE_F16_MEAN_TOL: f32 = 1.5e-2;
/// Mean-error bound for f32 (relative to the largest |param|).
const ESTIMATE_F32_MEAN_TOL: f32 = 2e-5;
/// The render MLP folds l1·l0 in f64 and sums in a different order than torch.
const RENDER_F32_TOL: f32 = 5e-5;
/// Scale of the last render layer that drives the fixture's log outputs to ±1e3 and beyond,
/// past ln(f32::MAX) ≈ 88.7, where `expm1` alone overflows to +Inf.
const SATURATE: f32 = 1e4;
/// f16 storage of weights and activations, 9 layers.
const RENDER_F16_TOL: f32 = 1e-2;
/// Directional plan vs the general plan, f32: the same kernels on the same rows, the ND_enc
/// features computed on one row instead of each; only the upload path differs.
const DIRECTIONAL_F32_TOL: f32 = 1e-6;
/// The same in f16: the shared features are rounded to f16 on the host instead of in a kernel.
const DIRECTIONAL_F16_TOL: f32 = 2e-3;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures")
        .join(name)
}

fn gpu() -> Option<&'static Mutex<DeviceHandles>> {
    static GPU: OnceLock<Option<Mutex<DeviceHandles>>> = OnceLock::new();
    let g = GPU.get_or_init(|| nam_gpu::request_device(true).map(Mutex::new));
    if g.is_none() {
        nam_gpu::skip_without_adapter("no GPU adapter available");
    }
    g.as_ref()
}

/// The random C=4 fixture model and its golden tensors.
fn load() -> (Weights, TensorFile) {
    load_pair(
        fixture("net_tiny.safetensors"),
        "net_tiny_golden.safetensors",
    )
}

fn load_pair(model: PathBuf, golden: &str) -> (Weights, TensorFile) {
    let w = Weights::from_file(model).unwrap_or_else(|e| panic!("{e}"));
    let g = TensorFile::from_file(fixture(golden)).unwrap_or_else(|e| panic!("{e}"));
    (w, g)
}

fn tensor<'a>(g: &'a TensorFile, name: &str) -> (&'a [f32], Vec<usize>) {
    let t = g
        .tensors()
        .get(name)
        .unwrap_or_else(|| panic!("golden lacks {name}"));
    (t.data(), t.shape().to_vec())
}

/// Largest |got - want| relative to the largest |want| (at least 1).
fn rel_err(got: &[f32], want: &[f32]) -> f32 {
    assert_eq!(got.len(), want.len());
    let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
    got.iter()
        .zip(want)
        .map(|(g, w)| (g - w).abs())
        .fold(0.0, f32::max)
        / scale
}

fn network(p: Precision, weights: &Weights) -> Option<GpuNetwork> {
    let g = gpu()?.lock().unwrap_or_else(|e| e.into_inner());
    if p == Precision::F16 && !g.device.features().contains(wgpu::Features::SHADER_F16) {
        eprintln!("SKIP f16: adapter {:?} lacks SHADER_F16", g.info.name);
        return None;
    }
    Some(
        GpuNetwork::new(&g.device, &g.queue, g.info.device_type, weights, p)
            .unwrap_or_else(|e| panic!("{e}")),
    )
}

fn estimate_case(p: Precision, tol: f32, mean_tol: f32) {
    let (weights, golden) = load();
    estimate_against(&weights, &golden, p, tol, mean_tol);
}

fn estimate_against(weights: &Weights, golden: &TensorFile, p: Precision, tol: f32, mean_tol: f32) {
    let Some(mut net) = network(p, weights) else {
        return;
    };
    let (input, shape) = tensor(golden, "input");
    let (h, w) = (shape[1], shape[2]);
    let (want_chw, _) = tensor(golden, "params");
    // The adapter's own choice first (on lavapipe the texture convolutions), then the buffer
    // convolution kernels that every other variant runs.
    let chosen = net.context().matmul_variant();
    let variants = if chosen == MatmulVariant::Direct {
        vec![chosen]
    } else {
        vec![chosen, MatmulVariant::Direct]
    };
    for v in variants {
        net.set_matmul_variant(v).unwrap_or_else(|e| panic!("{e}"));
        let got_hwc = net.estimate(input, h, w).unwrap_or_else(|e| panic!("{e}"));
        let mut got_chw = vec![0.0; got_hwc.len()];
        for (i, x) in got_hwc.iter().enumerate() {
            let (pix, c) = (i / 64, i % 64);
            got_chw[c * h * w + pix] = *x;
        }
        let err = rel_err(&got_chw, want_chw);
        let scale = want_chw.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let mean = got_chw
            .iter()
            .zip(want_chw)
            .map(|(g, x)| (g - x).abs())
            .sum::<f32>()
            / got_chw.len() as f32;
        eprintln!("estimate {p:?} {v:?}: max |params| {scale:.3}, mean abs error {mean:.3e}");
        assert!(
            mean <= mean_tol * scale.max(1.0),
            "estimate {p:?} {v:?}: mean error {mean} > {mean_tol} x {scale}"
        );
        eprintln!("estimate {p:?} {v:?}: relative error {err:.3e} (tol {tol:.1e})");
        assert!(
            err <= tol,
            "estimate {p:?} {v:?}: relative error {err} > {tol}"
        );
    }
}

fn render_case(p: Precision, tol: f32) {
    let (weights, golden) = load();
    let Some(mut net) = network(p, &weights) else {
        return;
    };
    let (params, _) = tensor(&golden, "r_params");
    let (dirs, _) = tensor(&golden, "r_dirs");
    // The adapter's own choice first, then the buffer variants (texture and buffer render
    // plans differ, so each is checked against torch).
    let chosen = net.context().matmul_variant();
    for v in [chosen, MatmulVariant::Direct, MatmulVariant::Tiled] {
        net.set_matmul_variant(v).unwrap_or_else(|e| panic!("{e}"));
        let (log, nd) = net
            .render_log_with_nd(params, dirs)
            .unwrap_or_else(|e| panic!("{e}"));
        let radiance = net.render(params, dirs).unwrap_or_else(|e| panic!("{e}"));
        for (name, got) in [("r_nd", &nd), ("r_log", &log), ("r_radiance", &radiance)] {
            let err = rel_err(got, tensor(&golden, name).0);
            eprintln!("render {p:?} {v:?} {name}: relative error {err:.3e} (tol {tol:.1e})");
            assert!(
                err <= tol,
                "render {p:?} {v:?} {name}: relative error {err} > {tol}"
            );
        }
    }
}

#[test]
fn estimate_matches_torch_golden_on_net_tiny_f32() {
    estimate_case(Precision::F32, ESTIMATE_F32_TOL, ESTIMATE_F32_MEAN_TOL);
}

#[test]
fn estimate_matches_torch_golden_on_net_tiny_f16() {
    estimate_case(Precision::F16, ESTIMATE_F16_TOL, ESTIMATE_F16_MEAN_TOL);
}

/// The shipped model (trained weights, and the head's input skip, which the random fixture
/// lacks) against its own torch golden (`python -m train_py.golden --model ...`).
#[test]
fn estimate_matches_torch_golden_on_default_model_f32() {
    let (weights, golden) = load_pair(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors"),
        "net_default_golden.safetensors",
    );
    estimate_against(
        &weights,
        &golden,
        Precision::F32,
        ESTIMATE_F32_TOL,
        ESTIMATE_F32_MEAN_TOL,
    );
}

#[test]
fn render_matches_torch_golden_on_net_tiny_f32() {
    render_case(Precision::F32, RENDER_F32_TOL);
}

#[test]
fn render_matches_torch_golden_on_net_tiny_f16() {
    render_case(Precision::F16, RENDER_F16_TOL);
}

/// The directional plan (ND_enc once, render MLP per row) against the general plan with the
/// same triple on every row, for every matmul variant; the batch is longer than one
/// submission so the chunking of the MLP-only plan is covered too.
fn directional_case(p: Precision, tol: f32) {
    let (weights, golden) = load();
    let Some(mut net) = network(p, &weights) else {
        return;
    };
    let (params, _) = tensor(&golden, "r_params");
    let (dirs, _) = tensor(&golden, "r_dirs");
    let rows = params.len() / 64;
    let triple: [f32; 9] = dirs[9..18].try_into().unwrap_or_else(|e| panic!("{e}"));
    let repeated: Vec<f32> = (0..rows).flat_map(|_| triple).collect();
    let chosen = net.context().matmul_variant();
    for v in [chosen, MatmulVariant::Direct, MatmulVariant::Tiled] {
        net.set_matmul_variant(v).unwrap_or_else(|e| panic!("{e}"));
        let want = net
            .render_log(params, &repeated)
            .unwrap_or_else(|e| panic!("{e}"));
        let got = net
            .render_log_directional(params, &triple)
            .unwrap_or_else(|e| panic!("{e}"));
        let err = rel_err(&got, &want);
        eprintln!("directional {p:?} {v:?}: {rows} rows, relative error {err:.3e} (tol {tol:.1e})");
        assert!(err <= tol, "directional {p:?} {v:?}: {err} > {tol}");
    }
    net.set_matmul_variant(chosen)
        .unwrap_or_else(|e| panic!("{e}"));
    // Tiled past one submission: row r repeats golden row r % rows.
    let n = nam_gpu::MAX_RENDER_ROWS as usize + 3 * rows + 5;
    let big: Vec<f32> = (0..n)
        .flat_map(|r| params[(r % rows) * 64..(r % rows + 1) * 64].iter().copied())
        .collect();
    let want = net
        .render_directional(params, &triple)
        .unwrap_or_else(|e| panic!("{e}"));
    let got = net
        .render_directional(&big, &triple)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(got.len(), 3 * n);
    let tiled: Vec<f32> = (0..n)
        .flat_map(|r| want[(r % rows) * 3..(r % rows + 1) * 3].iter().copied())
        .collect();
    let err = rel_err(&got, &tiled);
    eprintln!("directional {p:?} {chosen:?}: {n} rows in chunks, relative error {err:.3e}");
    assert!(err <= tol, "directional {p:?} chunked: {err} > {tol}");
    // Empty input gives empty output; a partial row is an error.
    assert!(
        net.render_directional(&[], &triple)
            .is_ok_and(|v| v.is_empty())
    );
    let err = net.render_directional(&params[..70], &triple);
    assert!(
        err.as_ref().is_err_and(|e| e.to_string().contains("param")),
        "{err:?}"
    );
}

#[test]
fn directional_render_matches_general_path_f32() {
    directional_case(Precision::F32, DIRECTIONAL_F32_TOL);
}

#[test]
fn directional_render_matches_general_path_f16() {
    directional_case(Precision::F16, DIRECTIONAL_F16_TOL);
}

/// A saturated network gives finite radiance on the GPU path, as on the CPU: the log values
/// read back go through the one `radiance_from_log` (capped at about f32::MAX), not +Inf.
#[test]
fn saturated_log_output_gives_finite_radiance_as_on_the_cpu() {
    let (weights, golden) = load();
    let last = format!("render.l{}.weight", weights.config().render.len() - 2);
    let mut tensors = weights.tensors().clone();
    let t = &tensors[&last];
    let hot: Vec<f32> = t.data().iter().map(|v| v * SATURATE).collect();
    let hot = Tensor::new(t.shape().to_vec(), hot).unwrap_or_else(|| panic!("{last}"));
    tensors.insert(last, hot);
    let saturated = Weights::from_tensors(weights.config().clone(), tensors, "saturated")
        .unwrap_or_else(|e| panic!("{e}"));
    let Some(mut net) = network(Precision::F32, &saturated) else {
        return;
    };
    let (params, _) = tensor(&golden, "r_params");
    let (dirs, _) = tensor(&golden, "r_dirs");
    let log = net
        .render_log(params, dirs)
        .unwrap_or_else(|e| panic!("{e}"));
    let radiance = net.render(params, dirs).unwrap_or_else(|e| panic!("{e}"));
    let capped = radiance_from_log(f32::INFINITY);
    assert!(capped.is_finite() && capped > 1e38, "{capped}");
    let mut saturated_values = 0;
    for (&y, &r) in log.iter().zip(&radiance) {
        assert!(r.is_finite() && r >= 0.0, "log {y} -> radiance {r}");
        if y > 88.8 {
            assert_eq!(r, capped, "log {y}");
            saturated_values += 1;
        }
    }
    eprintln!(
        "saturated: {saturated_values} of {} values capped",
        log.len()
    );
    assert!(
        saturated_values > 0,
        "the test needs log values past ln(f32::MAX)"
    );
}
