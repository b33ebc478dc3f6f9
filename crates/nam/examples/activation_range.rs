//! Measures the largest |activation| of every layer of `M_est` and `M_render` on the real photos
//! at full resolution (the f16 overflow analysis of docs/perf/f16_activation_range.md), with the
//! f64-accumulated reference network, and prints a Markdown table.
//!
//! ```text
//! cargo run --release -p nam --example activation_range -- ../shared/real_photos/*.png
//! ```
//!
//! The U-Net rows group a block's intermediates (gate/feat/inc convs, InstanceNorm, BN, down,
//! up-convs, output) and name the largest; the render rows are single layers. The render MLP is
//! traced on every 16th pixel in each direction under four light/view pairs.

use nam::geometry::{CAPTURE_DISTANCE, direction, pixel_position};
use nam::{NeuralModel, Photo};
use nam_ggx::Vec3;
use nam_model::reference::{self, Accumulate, ActivationRanges};
use rayon::prelude::*;

const F16_MAX: f32 = 65504.0;
const D: f32 = CAPTURE_DISTANCE as f32;

/// `max |a − b| / max |b|`.
fn normwise(a: &[f32], b: &[f32]) -> f64 {
    let scale = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| f64::from((x - y).abs()) / f64::from(scale))
        .fold(0.0, f64::max)
}

/// Activation ranges, and the U-Net's f32 errors against the f64-accumulated reference:
/// (fast path, plain f32 reference).
fn trace(model: &NeuralModel, photo: &Photo) -> (ActivationRanges, f64, f64) {
    let w = model.weights();
    let side = photo.side();
    let input = photo
        .network_input(model.config().log_mode)
        .expect("photos are validated on load");
    let (map, mut ranges) = reference::estimate_traced(w, &input, side, side, Accumulate::F64)
        .unwrap_or_else(|e| panic!("{e}"));
    let fast = model
        .cpu()
        .unet
        .estimate(&input, side, side)
        .unwrap_or_else(|e| panic!("{e}"));
    let plain = reference::estimate(w, &input, side, side, Accumulate::F32)
        .unwrap_or_else(|e| panic!("{e}"));
    let errors = (
        normwise(&fast.data, &map.data),
        normwise(&plain.data, &map.data),
    );
    let c = map.channels;
    let scenes = [
        ([0.0, 0.0, D], [0.0, 0.0, D]),
        ([1.0, 1.0, 4.0], [0.0, 0.0, D]),
        ([9.96, 0.0, 0.87], [0.0, 0.0, D]),
        ([-2.0, 0.5, 3.0], [1.0, -1.0, 2.0]),
    ];
    for (light, view) in scenes {
        for i in (0..side).step_by(16) {
            for j in (0..side).step_by(16) {
                let p = pixel_position(i, j, side, side);
                let wi = direction(p, Vec3::from_array(light)).to_array();
                let wo = direction(p, Vec3::from_array(view)).to_array();
                let k = i * side + j;
                let (_, r) = reference::render_traced(
                    w,
                    &map.data[k * c..(k + 1) * c],
                    wi,
                    wo,
                    Accumulate::F64,
                )
                .unwrap_or_else(|e| panic!("{e}"));
                ranges.merge(&r);
            }
        }
    }
    (ranges, errors.0, errors.1)
}

/// The table row of an entry: U-Net blocks (`est.enc1.0.ha1.gate` → `est.enc1.0`), the
/// single tensors `est.input`/`stem`/`head`, and render layers as they are.
fn group(name: &str) -> String {
    let parts: Vec<&str> = name.split('.').collect();
    if parts[0] == "est" && parts.len() >= 3 {
        parts[..3].join(".")
    } else {
        name.to_string()
    }
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: activation_range PHOTO.png...");
        std::process::exit(2);
    }
    let model = NeuralModel::embedded().unwrap_or_else(|e| panic!("{e}"));
    let t0 = std::time::Instant::now();
    let per_photo: Vec<(String, usize, (ActivationRanges, f64, f64))> = paths
        .par_iter()
        .map(|p| {
            let photo = Photo::load(p).unwrap_or_else(|e| panic!("{e}"));
            let name = std::path::Path::new(p)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            (name, photo.side(), trace(&model, &photo))
        })
        .collect();
    let mut all = ActivationRanges::default();
    println!(
        "| photo | side | max \\|activation\\| | where | U-Net f32 fast vs f64 | U-Net plain f32 vs f64 |"
    );
    println!("|---|---:|---:|---|---:|---:|");
    for (name, side, (r, fast, plain)) in &per_photo {
        let (n, m) =
            r.entries.iter().fold(
                ("", 0.0f32),
                |a, (n, m)| if *m > a.1 { (n.as_str(), *m) } else { a },
            );
        println!("| {name} | {side} | {m:.2} | `{n}` | {fast:.2e} | {plain:.2e} |");
        all.merge(r);
    }
    println!();
    println!(
        "| layer | max \\|activation\\| | largest intermediate | f16 headroom (65504 / max) |"
    );
    println!("|---|---:|---|---:|");
    let mut rows: Vec<(String, f32, String)> = Vec::new();
    for (name, m) in &all.entries {
        let g = group(name);
        match rows.iter_mut().find(|r| r.0 == g) {
            Some(r) if *m > r.1 => {
                r.1 = *m;
                r.2 = name.clone();
            }
            Some(_) => {}
            None => rows.push((g, *m, name.clone())),
        }
    }
    for (g, m, n) in &rows {
        let short = n
            .strip_prefix(&format!("{g}."))
            .unwrap_or(if n == g { "(output)" } else { n });
        println!("| `{g}` | {m:.3} | {short} | {:.0}× |", F16_MAX / m);
    }
    eprintln!(
        "{} photos, {} traced tensors, overall max {:.3} ({:.0}× below f16 max), {:.1} s",
        per_photo.len(),
        all.entries.len(),
        all.max(),
        F16_MAX / all.max(),
        t0.elapsed().as_secs_f64()
    );
}
