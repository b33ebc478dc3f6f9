//! Directional + orthographic relight of a 256² material, one-shot
//! ([`RenderNet::relight_directional`]) and from a prepared (cached) material
//! ([`RenderNet::relight_prepared`]): best wall time and CPU time (all threads,
//! from `/proc/self/task/*/schedstat`, Linux) of 5 interleaved rounds after a
//! warm-up round. On a
//! shared machine the CPU time shows what a run costs when it gets the cores.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p nam-model --example directional_cpu_time`

use std::time::Instant;

use nam_model::{ParamMap, RenderNet, Roi, Source};
use nam_weights::{ModelConfig, Weights};

/// CPU time of every thread of this process so far, ns (0 where unavailable).
fn cpu_ns() -> u64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    tasks
        .filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

/// (wall ms, CPU ms) of one run.
fn timed(f: &mut dyn FnMut()) -> (f64, f64) {
    let (t, c) = (Instant::now(), cpu_ns());
    f();
    let wall = t.elapsed().as_secs_f64() * 1e3;
    (wall, cpu_ns().saturating_sub(c) as f64 / 1e6)
}

/// Best (wall ms, CPU ms) of each of two workloads over `rounds` interleaved
/// rounds after one warm-up round (interleaving shares the load drift).
fn best_pair(rounds: usize, a: &mut dyn FnMut(), b: &mut dyn FnMut()) -> [(f64, f64); 2] {
    let mut best = [(f64::INFINITY, f64::INFINITY); 2];
    for r in 0..=rounds {
        let runs = [timed(a), timed(b)];
        if r > 0 {
            for (b, (w, c)) in best.iter_mut().zip(runs) {
                *b = (b.0.min(w), b.1.min(c));
            }
        }
    }
    best
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let w = Weights::random(ModelConfig::standard(8), 1)?;
    let net = RenderNet::new(&w)?;
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
    let prep = net.prepare(&map)?;
    let wi = nam_model::geometry::unit_direction([1.5, 1.0, 3.5]);
    let wo = [0.0, 0.0, 1.0];
    let [(one_wall, one_cpu), (prep_wall, prep_cpu)] = best_pair(
        5,
        &mut || {
            std::hint::black_box(net.relight_directional(&map, wi, wo).expect("valid"));
        },
        &mut || {
            let (l, v) = (Source::Distant(wi), Source::Distant(wo));
            let img = net.relight_prepared(&prep, l, v, Roi::full(s, s));
            std::hint::black_box(img.expect("valid"));
        },
    );
    println!(
        "directional {s}²: one-shot wall {one_wall:.1} ms, cpu {one_cpu:.1} ms | prepared wall {prep_wall:.1} ms, cpu {prep_cpu:.1} ms ({:.2}× by wall)",
        one_wall / prep_wall
    );
    Ok(())
}
