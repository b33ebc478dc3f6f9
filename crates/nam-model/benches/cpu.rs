//! CPU benchmarks: relight 256² (M_render over 65,536 pixels), estimate 256²
//! (C = 8 and 16, random weights), and this machine's sgemm rate (1024³) in the
//! same run, so network throughput can be reported as a fraction of it.
//!
//! `cargo bench -p nam-model --bench cpu` (threads: rayon default = all cores;
//! set RAYON_NUM_THREADS=2 to match train_py/bench_torch.py).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nam_model::{ParamMap, RenderNet, UNet, matmul};
use nam_weights::{ModelConfig, Weights};

/// Multiply-adds per pixel of M_render after folding render.l0·l1 (DESIGN §4
/// counts 634,470 unfolded; folding 96·128 + 128·128 into 96·128 saves 16,384).
const RENDER_MACS_PER_PIXEL: f64 = 634_470.0 - 16_384.0;

fn param_map(h: usize, w: usize) -> ParamMap {
    let data = (0..h * w * 64)
        .map(|i| ((i * 2_654_435_761usize) % 2001) as f32 / 1000.0 - 1.0)
        .collect();
    ParamMap {
        height: h,
        width: w,
        channels: 64,
        data,
    }
}

fn benches(c: &mut Criterion) {
    let n = 1024;
    let a: Vec<f32> = (0..n * n).map(|i| (i % 7) as f32 * 0.1).collect();
    let b: Vec<f32> = (0..n * n).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut out = vec![0.0f32; n * n];
    let mut g = c.benchmark_group("cpu");
    g.sample_size(10);
    g.bench_function("sgemm_1024", |bch| {
        bch.iter(|| matmul(n, n, n, black_box(&a), black_box(&b), &mut out))
    });

    let w = Weights::random(ModelConfig::standard(8), 1).expect("standard config is valid");
    let net = RenderNet::new(&w).expect("random weights are complete");
    let map = param_map(256, 256);
    let light = [1.5, 1.0, 3.5];
    let view = [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE];
    g.bench_function("relight_256", |bch| {
        bch.iter(|| net.relight(black_box(&map), light, view))
    });

    let wi = nam_model::geometry::direction([0.0; 3], light);
    g.bench_function("relight_directional_256", |bch| {
        bch.iter(|| net.relight_directional(black_box(&map), wi, [0.0, 0.0, 1.0]))
    });

    if nam_model::bf16_supported() {
        let bf = net.clone().with_bf16().expect("supported");
        g.bench_function("relight_bf16_256", |bch| {
            bch.iter(|| bf.relight(black_box(&map), light, view))
        });
    }

    for width in [8usize, 16] {
        let w = Weights::random(ModelConfig::standard(width), 2).expect("valid");
        let unet = UNet::new(&w).expect("complete");
        let input: Vec<f32> = (0..4 * 256 * 256)
            .map(|i| ((i * 37) % 101) as f32 / 101.0)
            .collect();
        g.bench_function(format!("estimate_256_c{width}"), |bch| {
            bch.iter(|| unet.estimate(black_box(&input), 256, 256))
        });
    }
    g.finish();
    println!(
        "relight_256 = {:.1} GFLOP per frame (2·{RENDER_MACS_PER_PIXEL} MAC/px × 65536); sgemm_1024 = 2.147 GFLOP",
        2.0 * RENDER_MACS_PER_PIXEL * 65536.0 / 1e9
    );
}

criterion_group!(cpu, benches);
criterion_main!(cpu);
