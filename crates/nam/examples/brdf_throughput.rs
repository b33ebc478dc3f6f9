//! Times [`nam::NeuralBrdf::eval`] on a batch of random queries: the Rust side of
//! `crates/nam-py/bench/eval_throughput.py`, which times the same call from Python in the same
//! run. Prints one line: `queries <N> best_seconds <s>` (best of `--reps`).
//!
//! ```text
//! cargo run --release -p nam --example brdf_throughput -- [--queries 1000000] [--reps 5] [--side 64]
//! ```

use nam::{BrdfQuery, NeuralBrdf, NeuralModel, Photo, Vec2, Vec3};
use nam_weights::SplitMix64;
use std::time::Instant;

fn arg(args: &[String], name: &str, default: usize) -> usize {
    args.windows(2)
        .find(|w| w[0] == name)
        .map(|w| w[1].parse().expect("a whole number"))
        .unwrap_or(default)
}

fn main() -> Result<(), nam::NamError> {
    let args: Vec<String> = std::env::args().collect();
    let (n, reps, side) = (
        arg(&args, "--queries", 1_000_000),
        arg(&args, "--reps", 5),
        arg(&args, "--side", 64),
    );
    let model = NeuralModel::embedded()?;
    let photo = Photo::load_resized(
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../assets/example_photo.png"
        ),
        false,
        Some(side),
    )?;
    let material = model.estimate(&photo)?;
    let brdf = NeuralBrdf::new(&model, &material)?;
    // Directions in the upper hemisphere, uv over the material: what a renderer sends.
    let mut rng = SplitMix64(7);
    let mut unit = || rng.uniform() as f32;
    let up = |u: f32, v: f32| {
        let (phi, z) = (std::f32::consts::TAU * u, 0.05 + 0.95 * v);
        let r = (1.0 - z * z).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    };
    let queries: Vec<BrdfQuery> = (0..n)
        .map(|_| {
            let uv = Vec2::new(unit(), unit());
            let wi = up(unit(), unit());
            let wo = up(unit(), unit());
            BrdfQuery { uv, wi, wo }
        })
        .collect();
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t = Instant::now();
        let out = brdf.eval(&queries)?;
        best = best.min(t.elapsed().as_secs_f64());
        assert_eq!(out.len(), n);
    }
    println!("queries {n} best_seconds {best:.6}");
    Ok(())
}
