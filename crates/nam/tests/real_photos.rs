//! The embedded model on the real flash photos of `../shared/real_photos` (256², LDR, taken by
//! no one here), measured per photo on its well-exposed pixels (no channel ≥ [`SATURATED`], not
//! black):
//! - *Identity* (relit under the capture's own light and view, DESIGN §7): log-L1 against the
//!   photo, chromaticity error, and colourfulness relit / in the photo.
//! - *Moving light*: how much brighter the right half gets, relative to the left, when a light
//!   at (−2, 0, 3) moves to (2, 0, 3).
//!
//! Two kinds of checks: what any plausible relight must do ([`IDENTITY_LOG_L1_MAX`],
//! [`SIDE_LIGHT_RATIO_MIN`], and a chromaticity error below a grey relight's: it keeps the
//! photo's colour), and the shipped model's measured values per photo ([`MEASURED_FILE`], within
//! [`ABS_TOL`] / [`REL_TOL`]), so that a change in the runtime or the weights that moves any of
//! them shows up. (The model shipped before the U-Net's input skip relit these photos nearly
//! grey: colourfulness ratio ≈ 0.1 for five of them, chromaticity error 0.04–0.82.)

mod common;

use nam::geometry::{CAPTURE_DISTANCE, Light, View, capture_position};
use nam::{DVec3, NeuralModel, Photo, RgbImage, Scene, relight};
use rayon::prelude::*;

/// A photo pixel with any channel at or above this (8-bit 250) is blown out: what the material
/// does there is not in the photo, so it is not compared.
const SATURATED: f32 = 0.955;
/// A photo pixel whose channels sum below this is too dark for a colour to be measured.
const DARK: f32 = 0.03;
/// Offset of the log comparison, `|ln(o + ε) − ln(p + ε)|`, in linear radiance.
const LOG_EPS: f32 = 0.01;
/// Any plausible relight reproduces the photo under its own light at least this well (Identity
/// log-L1, mean over channels and compared pixels; predicting black gives ≈ 1.5–4).
const IDENTITY_LOG_L1_MAX: f64 = 0.8;
/// Any plausible relight gets brighter on the side the light moves to: the right-over-left ratio
/// grows at least this much from the left light to the right light. A relight that ignores the
/// light (the photo itself) scores 1; a flat Lambertian surface 1.34 at these lights (`cos θi`,
/// no falloff, mean over each half of the [-1, 1]² surface); highlights and normal-mapped
/// shading add to that. Until 2026-12-04 the floor was 1.5, above the Lambertian response: a
/// flat matte material would have failed it, and rusty-can-label (1.53, then 1.49) did.
const SIDE_LIGHT_RATIO_MIN: f64 = 1.2;
/// The shipped model's values, recorded by this test (`NAM_UPDATE_MEASURED=1 cargo test --release
/// -p nam --test real_photos`) together with the model's fingerprint, so that they are computed,
/// never edited by hand: identity log-L1, chromaticity error `Σ_c |o_c/Σo − p_c/Σp|` (0: same hue
/// and saturation, 2: disjoint primaries), colourfulness ratio (mean `max_c − min_c` of the
/// chromaticity, relit / photo; 1: as colourful as the photo), side-light ratio. A different
/// embedded model fails the test until its values are recorded.
const MEASURED_FILE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../tests/fixtures/real_photos_measured.tsv"
);
/// Setting this environment variable to `1` records [`MEASURED_FILE`] instead of comparing.
const UPDATE_ENV: &str = "NAM_UPDATE_MEASURED";
/// Allowed drift of log-L1 and chromaticity error from [`MEASURED_FILE`] (f32 rounding across CPUs
/// moves them by < 1e-3).
const ABS_TOL: f64 = 0.02;
/// Allowed relative drift of the two ratios from [`MEASURED_FILE`].
const REL_TOL: f64 = 0.1;

/// What one photo's relights measure.
#[derive(Debug)]
struct Measures {
    log_l1: f64,
    chroma_err: f64,
    /// The chromaticity error of a grey relight (every pixel `r = g = b`): how colourful the
    /// photo is, and what a model that ignores colour scores.
    grey_chroma_err: f64,
    colourfulness_ratio: f64,
    side_light_ratio: f64,
}

fn relit(model: &NeuralModel, material: &nam::NeuralMaterial, light: DVec3) -> RgbImage<f32> {
    let scene = Scene::new(
        Light::Point(light),
        View::Point(capture_position(CAPTURE_DISTANCE)),
    );
    let img = relight(model, material, &scene).expect("relight");
    assert!(img.first_non_finite().is_none(), "non-finite radiance");
    assert!(img.data().iter().all(|&v| v >= -1e-3), "negative radiance");
    img
}

/// Chromaticity `rgb / Σrgb`.
fn chroma(p: &[f32]) -> [f64; 3] {
    let s = f64::from(p[0] + p[1] + p[2]).max(1e-6);
    [0, 1, 2].map(|c| f64::from(p[c]) / s)
}

fn colourfulness(c: [f64; 3]) -> f64 {
    c.iter().copied().fold(f64::MIN, f64::max) - c.iter().copied().fold(f64::MAX, f64::min)
}

/// Mean radiance of the right half over that of the left half (columns: +x to the right).
fn right_over_left(img: &RgbImage<f32>) -> f64 {
    let (w, h) = (img.width(), img.height());
    let (mut left, mut right) = (0.0f64, 0.0f64);
    for i in 0..h {
        for j in 0..w {
            let s: f32 = img.pixel(i, j).iter().sum();
            if j < w / 2 {
                left += f64::from(s);
            } else {
                right += f64::from(s);
            }
        }
    }
    right / left.max(1e-12)
}

fn measure(model: &NeuralModel, photo: &Photo) -> Measures {
    let material = model.estimate(photo).expect("estimate");
    let identity = relit(model, &material, capture_position(CAPTURE_DISTANCE));
    let (mut l1, mut chroma_err, mut grey_err, mut n) = (0.0, 0.0, 0.0, 0usize);
    let (mut col_photo, mut col_out) = (0.0, 0.0);
    for (p, o) in photo
        .rgb()
        .chunks_exact(3)
        .zip(identity.data().chunks_exact(3))
    {
        if p.iter().any(|&v| v >= SATURATED) || p.iter().sum::<f32>() < DARK {
            continue;
        }
        let o: Vec<f32> = o.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        for c in 0..3 {
            l1 += f64::from(((o[c] + LOG_EPS).ln() - (p[c] + LOG_EPS).ln()).abs()) / 3.0;
        }
        let (cp, co) = (chroma(p), chroma(&o));
        chroma_err += (0..3).map(|c| (cp[c] - co[c]).abs()).sum::<f64>();
        grey_err += cp.iter().map(|v| (v - 1.0 / 3.0).abs()).sum::<f64>();
        col_photo += colourfulness(cp);
        col_out += colourfulness(co);
        n += 1;
    }
    assert!(n > 1000, "only {n} well-exposed pixels to compare");
    let n = n as f64;
    let right = relit(model, &material, DVec3::new(2.0, 0.0, 3.0));
    let left = relit(model, &material, DVec3::new(-2.0, 0.0, 3.0));
    Measures {
        log_l1: l1 / n,
        chroma_err: chroma_err / n,
        grey_chroma_err: grey_err / n,
        colourfulness_ratio: col_out / col_photo.max(1e-9),
        side_light_ratio: right_over_left(&right) / right_over_left(&left),
    }
}

#[test]
fn the_embedded_model_relights_every_real_photo_as_measured() {
    let Some(photos) = common::real_photos() else {
        return;
    };
    let model = NeuralModel::embedded().expect("embedded model");
    let t0 = std::time::Instant::now();
    let measured: Vec<(String, Measures)> = photos
        .par_iter()
        .map(|(name, photo)| (name.clone(), measure(&model, photo)))
        .collect();
    eprintln!(
        "photo                       identity log-L1  chroma err  (grey)  colourfulness  side ratio"
    );
    for (name, m) in &measured {
        eprintln!(
            "{name:<28}{:>15.4}{:>12.4}{:>8.4}{:>15.2}{:>12.2}",
            m.log_l1, m.chroma_err, m.grey_chroma_err, m.colourfulness_ratio, m.side_light_ratio
        );
    }
    eprintln!(
        "({} photos, {:.1} s)",
        measured.len(),
        t0.elapsed().as_secs_f64()
    );
    for (name, m) in &measured {
        assert!(
            m.log_l1 <= IDENTITY_LOG_L1_MAX,
            "{name}: identity log-L1 {:.4} > {IDENTITY_LOG_L1_MAX}",
            m.log_l1
        );
        assert!(
            m.side_light_ratio >= SIDE_LIGHT_RATIO_MIN,
            "{name}: moving the light from left to right changes right/left by only {:.2}×",
            m.side_light_ratio
        );
        assert!(
            m.chroma_err < m.grey_chroma_err,
            "{name}: chromaticity error {:.4} is no better than a grey relight's {:.4}",
            m.chroma_err,
            m.grey_chroma_err
        );
    }
    if std::env::var(UPDATE_ENV).as_deref() == Ok("1") {
        record(model.fingerprint(), &measured);
        return;
    }
    let recorded = read_recorded(model.fingerprint());
    for (name, m) in &measured {
        let Some((_, want)) = recorded.iter().find(|(n, _)| n == name) else {
            panic!("{name}: no recorded values in {MEASURED_FILE}; rerun with {UPDATE_ENV}=1");
        };
        let got = m.values();
        let labels = [
            "identity log-L1",
            "chroma error",
            "colourfulness",
            "side ratio",
        ];
        for k in 0..4 {
            let tol = if k < 2 { ABS_TOL } else { REL_TOL * want[k] };
            assert!(
                (got[k] - want[k]).abs() <= tol,
                "{name}: {} {:.4}, measured {:.4} for the shipped model (tolerance {tol:.4})",
                labels[k],
                got[k],
                want[k]
            );
        }
    }
}

impl Measures {
    /// The recorded quantities, in [`MEASURED_FILE`]'s column order.
    fn values(&self) -> [f64; 4] {
        [
            self.log_l1,
            self.chroma_err,
            self.colourfulness_ratio,
            self.side_light_ratio,
        ]
    }
}

/// Writes [`MEASURED_FILE`] (first line `model<TAB>fingerprint`, then one row per photo).
fn record(fingerprint: &str, measured: &[(String, Measures)]) {
    let mut text = format!("model\t{fingerprint}\n");
    for (name, m) in measured {
        let v = m.values();
        text += &format!(
            "{name}\t{:.4}\t{:.4}\t{:.3}\t{:.3}\n",
            v[0], v[1], v[2], v[3]
        );
    }
    std::fs::write(MEASURED_FILE, text).expect("write the measured values");
    eprintln!("recorded {MEASURED_FILE}");
}

/// The rows of [`MEASURED_FILE`]; panics with what to do when it belongs to another model.
fn read_recorded(fingerprint: &str) -> Vec<(String, [f64; 4])> {
    let text = std::fs::read_to_string(MEASURED_FILE)
        .unwrap_or_else(|e| panic!("{MEASURED_FILE}: {e}; run with {UPDATE_ENV}=1"));
    let mut lines = text.lines();
    let recorded_for = lines.next().and_then(|l| l.strip_prefix("model\t"));
    assert_eq!(
        recorded_for,
        Some(fingerprint),
        "{MEASURED_FILE} holds another model's values; rerun with {UPDATE_ENV}=1 to record this one's"
    );
    lines
        .map(|line| {
            let cols: Vec<&str> = line.split('\t').collect();
            assert_eq!(cols.len(), 5, "malformed row {line:?} in {MEASURED_FILE}");
            let v = |k: usize| cols[k].parse::<f64>().expect("a number");
            (cols[0].to_string(), [v(1), v(2), v(3), v(4)])
        })
        .collect()
}

/// Mean `|ln(1 + R) − ln(1 + R_f32)|` of a real photo estimated and relit in bf16 (`--precision
/// bf16`, an opt-in approximation) against f32, light at (2, 0, 3), the capture camera. Measured
/// 2026-12-04 on an Intel Xeon with AMX: 1.2e-4 – 1.0e-3 (nailed-tiles the largest).
const BF16_REAL_MEAN_LOG_TOL: f64 = 5e-3;
/// Share of a photo's pixels whose bf16 relight differs from f32 by more than
/// [`BF16_OUTLIER_LOG`] in `ln(1 + R)` in any channel. Measured 2026-12-04: 0 on seven photos,
/// 0.06% on fancy-wood-pattern, where the network is ill-conditioned (its bf16 params differ
/// from f32 by up to 0.5 in a few places; docs/perf/unet_cpu.md).
const BF16_REAL_OUTLIER_SHARE: f64 = 0.005;
const BF16_OUTLIER_LOG: f32 = 0.05;

#[test]
fn bf16_estimate_and_relight_stay_close_to_f32_on_every_real_photo() {
    let Some(photos) = common::real_photos() else {
        return;
    };
    if !nam_model::bf16_supported() {
        eprintln!("skipped: this CPU lacks AVX-512 BF16");
        return;
    }
    let f32_model = NeuralModel::embedded().expect("embedded model");
    let mut bf16_model = NeuralModel::embedded().expect("embedded model");
    bf16_model
        .set_cpu_precision(nam::CpuPrecision::Bf16)
        .expect("bf16");
    let light = DVec3::new(2.0, 0.0, 3.0);
    for (name, photo) in &photos {
        let run = |m: &NeuralModel| relit(m, &m.estimate(photo).expect("estimate"), light);
        let (exact, got) = (run(&f32_model), run(&bf16_model));
        let d: Vec<f32> = exact
            .data()
            .iter()
            .zip(got.data())
            .map(|(a, b)| (a.ln_1p() - b.ln_1p()).abs())
            .collect();
        let mean = d.iter().map(|&v| f64::from(v)).sum::<f64>() / d.len() as f64;
        let outliers = d
            .chunks_exact(3)
            .filter(|px| px.iter().any(|&v| v > BF16_OUTLIER_LOG))
            .count() as f64
            / (d.len() / 3) as f64;
        eprintln!(
            "{name:<28} bf16 vs f32: mean |Δ ln(1+R)| {mean:.2e}, pixels off by > {BF16_OUTLIER_LOG}: {:.3}%",
            100.0 * outliers
        );
        assert!(mean > 0.0, "{name}: the bf16 path must actually run");
        assert!(mean < BF16_REAL_MEAN_LOG_TOL, "{name}: {mean:e}");
        assert!(outliers < BF16_REAL_OUTLIER_SHARE, "{name}: {outliers}");
    }
}
