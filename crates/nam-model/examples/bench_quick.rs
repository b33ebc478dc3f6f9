//! Quick best-of-N timings without criterion (same work as benches/cpu.rs), for
//! side-by-side runs with `python -m train_py.bench_torch` on a busy machine.
//!
//! Set NAM_SKIP_RELIGHT=1 to time only the estimator.
//!
//! `RAYON_NUM_THREADS=2 cargo run --release -p nam-model --example bench_quick -- [reps] [tile]`

use std::time::Instant;

use nam_model::{ParamMap, RenderNet, UNet};
use nam_weights::{ModelConfig, Weights};

fn best_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let reps: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(3);
    let tile: usize = args
        .next()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(nam_model::DEFAULT_TILE);
    let sg = nam_model::sgemm_gflops(1024, 5);
    println!(
        "sgemm_1024: {:.2} ms ({sg:.1} GFLOP/s)",
        2.0 * 1024f64.powi(3) / sg / 1e6
    );
    let w = Weights::random(ModelConfig::standard(8), 1)?;
    let net = RenderNet::new(&w)?.with_tile(tile);
    let s = 256;
    let data = (0..s * s * 64)
        .map(|i| ((i * 2_654_435_761usize) % 2001) as f32 / 1000.0 - 1.0)
        .collect();
    let map = ParamMap {
        height: s,
        width: s,
        channels: 64,
        data,
    };
    let view = [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE];
    let skip_relight = std::env::var_os("NAM_SKIP_RELIGHT").is_some();
    let ms = if skip_relight {
        f64::NAN
    } else {
        best_ms(reps, || {
            let _ = net.relight(&map, [1.5, 1.0, 3.5], view);
        })
    };
    let gf = 2.0 * 618_086.0 * (s * s) as f64 / ms / 1e6;
    println!(
        "relight_{s} (tile {tile}): {ms:.1} ms ({gf:.1} GFLOP/s, {:.0}% of sgemm)",
        100.0 * gf / sg
    );
    if !skip_relight {
        let wi = nam_model::geometry::direction([0.0; 3], [1.5, 1.0, 3.5]);
        let dms = best_ms(reps, || {
            let _ = net.relight_directional(&map, wi, [0.0, 0.0, 1.0]);
        });
        println!(
            "relight_directional_{s} (ND_enc once): {dms:.1} ms ({:.1}× faster)",
            ms / dms
        );
        if nam_model::bf16_supported() {
            let bf = net.clone().with_bf16()?;
            let bms = best_ms(reps, || {
                let _ = bf.relight(&map, [1.5, 1.0, 3.5], view);
            });
            let bgf = 2.0 * 618_086.0 * (s * s) as f64 / bms / 1e6;
            println!(
                "relight_bf16_{s}: {bms:.1} ms ({bgf:.1} GFLOP/s, {:.2}× the f32 path)",
                ms / bms
            );
        }
    }
    let input: Vec<f32> = (0..4 * s * s)
        .map(|i| ((i * 37) % 101) as f32 / 101.0)
        .collect();
    for width in [8usize, 16] {
        let unet = UNet::new(&Weights::random(ModelConfig::standard(width), 2)?)?;
        let ms = best_ms(reps, || {
            let _ = unet.estimate(&input, s, s);
        });
        println!("estimate_{s}_c{width}: {ms:.1} ms");
    }
    Ok(())
}
