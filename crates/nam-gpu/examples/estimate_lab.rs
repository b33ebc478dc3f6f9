use nam_gpu::{GpuNetwork, MatmulVariant, Precision};
use nam_weights::{ModelConfig, Weights};
use std::time::Instant;
fn main() {
    let side: usize = std::env::args()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(128);
    let width: usize = std::env::args()
        .nth(2)
        .and_then(|v| v.parse().ok())
        .unwrap_or(8);
    let old = std::env::args().nth(3).is_some();
    let gpu = nam_gpu::request_device(true).unwrap();
    let weights = Weights::random(ModelConfig::standard(width), 7).unwrap();
    let cpu = nam_model::Model::new(&weights).unwrap();
    let mut net = GpuNetwork::new(
        &gpu.device,
        &gpu.queue,
        gpu.info.device_type,
        &weights,
        Precision::F32,
    )
    .unwrap();
    let n = side * side;
    let input: Vec<f32> = (0..4 * n).map(|i| (i * 13 % 97) as f32 / 97.0).collect();
    let mut variants = vec![MatmulVariant::Texture];
    if old {
        variants.push(MatmulVariant::Direct);
    }
    for v in variants {
        net.set_matmul_variant(v).unwrap();
        net.estimate(&input, side, side).unwrap();
        let t = Instant::now();
        net.estimate(&input, side, side).unwrap();
        let tg = t.elapsed().as_secs_f64();
        cpu.unet.estimate(&input, side, side).unwrap();
        let t = Instant::now();
        cpu.unet.estimate(&input, side, side).unwrap();
        let tc = t.elapsed().as_secs_f64();
        println!(
            "{v:?} {side}² C={width}: gpu {:.1} ms cpu {:.1} ms ratio {:.3}",
            tg * 1e3,
            tc * 1e3,
            tc / tg
        );
    }
}
