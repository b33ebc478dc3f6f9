//! The U-Net estimate on the first adapter with each convolution path, against the CPU fast
//! path in the same run: on CPU adapters (lavapipe) the texture convolutions
//! (`shaders/conv_tex.wgsl`) and the buffer ones (`conv2d.wgsl`, `conv_transpose.wgsl`).
//!
//! `cargo run --release -p nam-gpu --example estimate_variants -- [side 128] [width 8]`
//! (random weights; each time is the second of two runs).

use std::time::Instant;

use nam_gpu::{GpuNetwork, MatmulVariant, Precision};
use nam_weights::{ModelConfig, Weights};

fn arg(i: usize, default: usize) -> usize {
    std::env::args()
        .nth(i)
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Wall time of the second of two calls, in milliseconds.
fn second_run_ms<T>(mut f: impl FnMut() -> T) -> f64 {
    std::hint::black_box(f());
    let t = Instant::now();
    std::hint::black_box(f());
    t.elapsed().as_secs_f64() * 1e3
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (side, width) = (arg(1, 128), arg(2, 8));
    let gpu = nam_gpu::request_device(true).ok_or("no GPU adapter")?;
    let weights = Weights::random(ModelConfig::standard(width), 7)?;
    let cpu = nam_model::Model::new(&weights)?;
    let mut net = GpuNetwork::new(
        &gpu.device,
        &gpu.queue,
        gpu.info.device_type,
        &weights,
        Precision::F32,
    )?;
    let input: Vec<f32> = (0..4 * side * side)
        .map(|i| (i * 13 % 97) as f32 / 97.0)
        .collect();
    println!("adapter: {} ({:?})", gpu.info.name, gpu.info.device_type);
    let chosen = net.context().matmul_variant();
    let mut variants = vec![chosen];
    if chosen == MatmulVariant::Texture {
        variants.push(MatmulVariant::Direct);
    }
    for v in variants {
        net.set_matmul_variant(v)?;
        let gpu_ms = second_run_ms(|| net.estimate(&input, side, side).map(|p| p.len()));
        let cpu_ms = second_run_ms(|| cpu.unet.estimate(&input, side, side).map(|m| m.data.len()));
        println!(
            "estimate {side}² C={width}, {v:?} kernels: gpu {gpu_ms:.1} ms | cpu fast path {cpu_ms:.1} ms | gpu/cpu speed {:.3}",
            cpu_ms / gpu_ms
        );
    }
    Ok(())
}
