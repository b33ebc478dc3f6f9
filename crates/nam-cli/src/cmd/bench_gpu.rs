//! `nam-cli bench --gpu`: the image relights of the facade on a wgpu adapter, the general
//! plan (positional encoding, ND_enc and render MLP per pixel) against the directional plan
//! (ND_enc once, render MLP per pixel), and the U-Net estimate, each also timed on the CPU in
//! the same rounds.

use super::timing::{Case, Row, measure};
use anyhow::{Context, Result, bail};
use nam::geometry::{CAPTURE_DISTANCE, Light, View, capture_position};
use nam::{DVec3, NeuralMaterial, NeuralModel, Scene, relight};
use nam_model::ParamMap;
use std::fmt::Write as _;

/// Times the GPU and CPU relights of `map` (square) and estimates of `input` (the network
/// input `[4, s, s]` of the same size) and returns the Markdown table.
pub fn run(model: &NeuralModel, map: ParamMap, input: &[f32], rep: usize) -> Result<String> {
    let Some(gpu) = nam::nam_gpu::request_device(false) else {
        bail!("--gpu: no wgpu adapter (see the message above)");
    };
    // Two copies with the same fingerprint, one with the GPU attached.
    let on_cpu = NeuralModel::from_weights(model.weights().clone())?;
    let mut on_gpu = NeuralModel::from_weights(model.weights().clone())?;
    on_gpu
        .attach_gpu(
            &gpu.device,
            &gpu.queue,
            gpu.info.device_type,
            nam::nam_gpu::Precision::F32,
        )
        .with_context(|| format!("setting up the networks on {}", gpu.info.name))?;
    // The CPU table's counts (folded l0·l1), so rates compare across tables.
    let net = &model.cpu().render;
    let general_macs = net.macs_per_output(false, false) as u64;
    let directional_macs = net.macs_per_output(false, true) as u64;
    // The U-Net alone on the device, as the facade's `estimate` runs it on an attached GPU.
    let mut unet = nam::nam_gpu::GpuNetwork::new(
        &gpu.device,
        &gpu.queue,
        gpu.info.device_type,
        model.weights(),
        nam::nam_gpu::Precision::F32,
    )?;
    let peak = fma_peak(unet.context())?;
    let s = map.height;
    let n = s * map.width;
    let estimate_flops = 2.0 * model.config().estimate_macs(s, s) as f64;
    let material = NeuralMaterial::new(map, on_cpu.fingerprint().to_string())?;
    let point = Scene::new(
        Light::Point(DVec3::from_array([1.5, 1.0, 3.5])),
        View::Point(capture_position(CAPTURE_DISTANCE)),
    );
    let directional = Scene::new(
        Light::Directional(DVec3::from_array([1.5, 1.0, 3.5])),
        View::Orthographic(DVec3::from_array([0.0, 0.0, 1.0])),
    );
    let fl = |macs: u64| 2.0 * macs as f64 * n as f64;
    let m = &material;
    let (gf, df) = (fl(general_macs), fl(directional_macs));
    let cases = vec![
        case("GPU general point relight", &on_gpu, m, point, gf),
        case(
            "GPU directional + orthographic",
            &on_gpu,
            m,
            directional,
            df,
        ),
        case("CPU general point relight", &on_cpu, m, point, gf),
        case(
            "CPU directional + orthographic",
            &on_cpu,
            m,
            directional,
            df,
        ),
        (
            "GPU estimate (M_est)".to_string(),
            n,
            estimate_flops,
            Box::new(|| {
                unet.estimate(input, s, s)?;
                Ok(())
            }),
        ),
        (
            "CPU estimate (M_est)".to_string(),
            n,
            estimate_flops,
            Box::new(|| {
                model.cpu().unet.estimate(input, s, s)?;
                Ok(())
            }),
        ),
    ];
    let rows = measure(cases, rep)?;
    Ok(table(&rows, &gpu.info, peak, s, rep))
}

/// GFLOP/s of `shaders/fma_peak.wgsl` on the device: a small probe first, then one sized to
/// run ~0.1 s (llvmpipe and a data-centre GPU differ by ~1000x).
fn fma_peak(ctx: &nam::nam_gpu::GpuContext) -> Result<f64> {
    use nam::nam_gpu::probe::fma_peak_gflops;
    const ITERS: u32 = 1024;
    let small = fma_peak_gflops(ctx, 64, ITERS, 1)?;
    let flops_per_group = 256.0 * f64::from(ITERS) * 64.0;
    let groups = (0.1 * small * 1e9 / flops_per_group).clamp(64.0, 65_535.0) as u32;
    Ok(fma_peak_gflops(ctx, groups, ITERS, 3)?)
}

/// Relighting `material` under `scene` with `model`'s backend, as a timed case.
fn case<'a>(
    name: &str,
    model: &'a NeuralModel,
    material: &'a NeuralMaterial,
    scene: Scene,
    flops: f64,
) -> Case<'a> {
    let (h, w) = material.size();
    (
        name.to_string(),
        h * w,
        flops,
        Box::new(move || {
            relight(model, material, &scene)?;
            Ok(())
        }),
    )
}

/// Rows 0–1 are GPU relights, 2–3 the same paths on the CPU, 4–5 the estimate on GPU and CPU;
/// FLOPs count the render network with l0·l1 folded, as the CPU table does.
fn table(rows: &[Row], info: &nam::wgpu::AdapterInfo, peak: f64, s: usize, rep: usize) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "GPU: {} ({:?}, {:?}), f32, size {s}², best of {rep} interleaved rounds after a warm-up round; FMA peak (shaders/fma_peak.wgsl) {peak:.1} GFLOP/s\n",
        info.name, info.backend, info.device_type
    );
    let _ = writeln!(
        t,
        "| path | pixels | ms | GFLOP/s | × general (same backend) | GPU/CPU speed |"
    );
    let _ = writeln!(t, "|---|---:|---:|---:|---:|---:|");
    for (k, r) in rows.iter().enumerate() {
        let (same_backend, cpu) = if k < 4 {
            (
                format!("{:.2}", rows[k - k % 2].ms / r.ms),
                (k < 2).then(|| &rows[k + 2]),
            )
        } else {
            ("—".to_string(), (k == 4).then(|| &rows[5]))
        };
        let gpu_over_cpu = cpu.map_or("—".to_string(), |c| format!("{:.2}", c.ms / r.ms));
        let _ = writeln!(
            t,
            "| {} {s}² | {} | {:.2} | {:.1} | {same_backend} | {gpu_over_cpu} |",
            r.name,
            r.items,
            r.ms,
            r.flops / r.ms / 1e6,
        );
    }
    t
}
