//! CPU benchmarks: relight 256² (M_render over 65,536 pixels), estimate 256²
//! (C = 8 and 16, random weights), and this machine's sgemm rate (1024³) in the
//! same run, so network throughput can be reported as a fraction of it.
//!
//! The `specialisations` group times the DESIGN §9 fast paths against the
//! general per-pixel relight in the same run (`cargo bench -p nam-model
//! --bench cpu -- specialisations`).
//!
//! `cargo bench -p nam-model --bench cpu` (threads: rayon default = all cores;
//! set RAYON_NUM_THREADS=2 to match train_py/bench_torch.py).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nam_model::{ParamMap, RenderNet, Roi, Source, UNet, matmul};
use nam_weights::{ModelConfig, Weights};

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
    let view = [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE as f32];
    g.bench_function("relight_256", |bch| {
        bch.iter(|| net.relight(black_box(&map), light, view))
    });

    let wi = nam_model::geometry::unit_direction(light);
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
        let direct = unet.clone().without_winograd();
        g.bench_function(format!("estimate_direct_256_c{width}"), |bch| {
            bch.iter(|| direct.estimate(black_box(&input), 256, 256))
        });
        if nam_model::bf16_supported() {
            let bf = unet.clone().with_bf16().expect("supported");
            g.bench_function(format!("estimate_bf16_256_c{width}"), |bch| {
                bch.iter(|| bf.estimate(black_box(&input), 256, 256))
            });
        }
    }
    g.finish();
    // Folded l0·l1: DESIGN §4's 634,470 unfolded minus 128·128.
    let macs = net.macs_per_output(false, false);
    println!(
        "relight_256 = {:.1} GFLOP per frame (2·{macs} MAC/px × 65536); sgemm_1024 = 2.147 GFLOP",
        2.0 * macs as f64 * 65536.0 / 1e9
    );
}

/// DESIGN §9 specialisations against the general per-pixel path, same run:
/// general point relight, one-shot directional + orthographic, `prepare`
/// (`W_p·p` once), prepared point and directional relights, a 64² ROI, a
/// batch of 4,096 (texel, ωi, ωo) queries, and the general path without the
/// `render.l0·l1` fold.
fn specialisations(c: &mut Criterion) {
    let w = Weights::random(ModelConfig::standard(8), 1).expect("standard config is valid");
    let net = RenderNet::new(&w).expect("random weights are complete");
    let unfolded = RenderNet::new_unfolded(&w).expect("complete");
    let map = param_map(256, 256);
    let prep = net.prepare(&map).expect("valid map");
    let light = [1.5, 1.0, 3.5];
    let view = [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE as f32];
    let (l, v) = (Source::Point(light), Source::Point(view));
    let wi = nam_model::geometry::unit_direction(light);
    let (dl, dv) = (Source::Distant(wi), Source::Distant([0.0, 0.0, 1.0]));
    let full = Roi::full(256, 256);
    let mut g = c.benchmark_group("specialisations");
    g.sample_size(10);
    g.bench_function("general_point_256", |b| {
        b.iter(|| net.relight(black_box(&map), light, view))
    });
    g.bench_function("general_point_256_unfolded", |b| {
        b.iter(|| unfolded.relight(black_box(&map), light, view))
    });
    g.bench_function("directional_ortho_256", |b| {
        b.iter(|| net.relight_directional(black_box(&map), wi, [0.0, 0.0, 1.0]))
    });
    g.bench_function("directional_ortho_256_unfolded", |b| {
        b.iter(|| unfolded.relight_directional(black_box(&map), wi, [0.0, 0.0, 1.0]))
    });
    g.bench_function("prepare_256", |b| b.iter(|| net.prepare(black_box(&map))));
    g.bench_function("prepared_point_256", |b| {
        b.iter(|| net.relight_prepared(black_box(&prep), l, v, full))
    });
    g.bench_function("prepared_directional_256", |b| {
        b.iter(|| net.relight_prepared(black_box(&prep), dl, dv, full))
    });
    let roi = Roi {
        row: 96,
        col: 96,
        height: 64,
        width: 64,
    };
    g.bench_function("prepared_point_roi_64", |b| {
        b.iter(|| net.relight_prepared(black_box(&prep), l, v, roi))
    });
    let n = 4096;
    let texels: Vec<usize> = (0..n).map(|q| (q * 7919) % (256 * 256)).collect();
    let qwi: Vec<[f32; 3]> = (0..n)
        .map(|q| nam_model::geometry::unit_direction([(q % 61) as f32 / 30.0 - 1.0, 0.4, 1.0]))
        .collect();
    let qwo: Vec<[f32; 3]> = (0..n)
        .map(|q| nam_model::geometry::unit_direction([0.2, (q % 53) as f32 / 26.0 - 1.0, 1.0]))
        .collect();
    let mut out = vec![0.0f32; n * 3];
    g.bench_function("prepared_queries_4096", |b| {
        b.iter(|| net.render_log_prepared(black_box(&prep), &texels, &qwi, &qwo, &mut out))
    });
    g.finish();
}

criterion_group!(cpu, benches, specialisations);
criterion_main!(cpu);
