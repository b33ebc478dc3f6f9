//! LDR-FLIP port vs NVIDIA's reference (`flip-evaluator` 1.7, PyPI) on seeded image pairs
//! (tests/fixtures/flip_golden.safetensors, written by `python -m train_py.flip_golden`).
//!
//! Convention (matched in the generator): linear RGB inputs in [0, 1] (`inputsRGB=False`),
//! LDR, 67 pixels per degree.

use nam_eval::flip::{DEFAULT_PIXELS_PER_DEGREE, FlipImage};
use nam_weights::TensorFile;
use std::path::Path;

const H: usize = 32;
const W: usize = 48;
/// Mean FLIP of a pair vs the reference's mean. The reference computes in f32, the port in
/// f64; the worst pair (a shifted gradient) differs by 1.8e-5, the others by ≤ 3e-7.
const MEAN_TOL: f64 = 1e-4;
/// Largest per-pixel difference of the error maps (worst seen 9.4e-5, shifted gradient; the
/// others ≤ 4e-6).
const MAP_TOL: f64 = 5e-4;

/// (pair, reference tensor, test tensor).
const PAIRS: [(&str, &str, &str); 5] = [
    ("gradient_noise", "gradient", "gradient_noise_test"),
    ("gradient_shift", "gradient", "gradient_shift_test"),
    ("gradient_colour", "gradient", "gradient_colour_test"),
    ("edges_blur", "edges", "edges_blur_test"),
    ("identical", "edges", "edges"),
];

#[test]
fn flip_port_matches_flip_evaluator() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/flip_golden.safetensors");
    let g = TensorFile::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut failures = Vec::new();
    for (name, r, t) in PAIRS {
        let image = |k: &str| {
            let data = g.get(k, &[H, W, 3]).unwrap_or_else(|e| panic!("{e}"));
            FlipImage::new(data, H, W, DEFAULT_PIXELS_PER_DEGREE).unwrap_or_else(|e| panic!("{e}"))
        };
        let (reference, test) = (image(r), image(t));
        let ours = reference.error_map(&test).unwrap_or_else(|e| panic!("{e}"));
        let want = g
            .get(&format!("{name}_map"), &[H, W])
            .unwrap_or_else(|e| panic!("{e}"));
        let want_mean = f64::from(
            g.get(&format!("{name}_mean"), &[1])
                .unwrap_or_else(|e| panic!("{e}"))[0],
        );
        let mean = ours.iter().sum::<f64>() / ours.len() as f64;
        let (mut worst, mut at) = (0.0f64, 0);
        for (p, (a, b)) in ours.iter().zip(want).enumerate() {
            let d = (a - f64::from(*b)).abs();
            if d > worst {
                (worst, at) = (d, p);
            }
        }
        println!(
            "{name}: mean {mean:.6} vs {want_mean:.6} (diff {:.2e}); map max diff {worst:.2e} at ({}, {}): {:.5} vs {:.5}",
            (mean - want_mean).abs(),
            at / W,
            at % W,
            ours[at],
            want[at]
        );
        if (mean - want_mean).abs() > MEAN_TOL || worst > MAP_TOL {
            failures.push(name);
        }
    }
    assert!(
        failures.is_empty(),
        "FLIP port disagrees with flip-evaluator on {failures:?}"
    );
}
