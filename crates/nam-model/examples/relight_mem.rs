//! Relights an N×N random param map once with random weights and prints the
//! time; run under `/usr/bin/time -v` to read the peak RSS.
//!
//! `cargo run --release -p nam-model --example relight_mem -- 2048`

use nam_model::{ParamMap, RenderNet};
use nam_weights::{ModelConfig, Weights};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(256);
    let w = Weights::random(ModelConfig::standard(8), 1)?;
    let net = RenderNet::new(&w)?;
    let data = (0..n * n * 64)
        .map(|i| ((i * 2_654_435_761usize) % 2001) as f32 / 1000.0 - 1.0)
        .collect();
    let map = ParamMap {
        height: n,
        width: n,
        channels: 64,
        data,
    };
    let t = std::time::Instant::now();
    let img = net.relight(
        &map,
        [1.5, 1.0, 3.5],
        [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE as f32],
    )?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let mean = img.data.iter().map(|&v| f64::from(v)).sum::<f64>() / img.data.len() as f64;
    println!(
        "relight {n}x{n}: {ms:.1} ms (mean radiance {mean:.4}); param map {:.1} MB, output {:.1} MB",
        (n * n * 64 * 4) as f64 / 1e6,
        (n * n * 12) as f64 / 1e6
    );
    if std::env::args().any(|a| a == "--sgemm") {
        let sg = nam_model::sgemm_gflops(1024, 5);
        // 2 · (634,470 − 16,384 folded) MAC per pixel.
        let gf = 2.0 * 618_086.0 * (n * n) as f64 / (ms / 1e3) / 1e9;
        println!(
            "relight {gf:.1} GFLOP/s; sgemm 1024³ {sg:.1} GFLOP/s; ratio {:.0}%",
            100.0 * gf / sg
        );
    }
    Ok(())
}
