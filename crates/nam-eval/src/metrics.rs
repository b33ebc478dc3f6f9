//! Image error metrics of the evaluation (DESIGN.md §8), on linear radiance images
//! (`R = π f_r cos θi`, HWC RGB, `3·height·width` values).
//!
//! The definitions are those of `train_py/evaluate.py`, so the Rust and Python tables can be
//! compared:
//!
//! - **log-L1**: mean over pixels and channels of `|ln(1+R̂) − ln(1+R)|` (DESIGN §3 log space).
//! - **log-RMSE**: `sqrt(mean((ln(1+R̂) − ln(1+R))²))`, same log space.
//! - **SSIM**: on display images `clamp(R, 0, 1)^(1/2.2)`, **per colour channel** (each channel
//!   a grey image), 11×11 Gaussian window with σ = 1.5 (normalised to sum 1), "valid" windows
//!   only (no padding), `C1 = 0.01²`, `C2 = 0.03²`, then the mean over channels and windows.
//! - **FLIP**: see [`crate::flip`].
//!
//! Negative radiance (none of the evaluated methods produces it) is clamped to 0 before the log.

use crate::error::{EvalError, Result};
use crate::pair::check_pair;

/// SSIM stabiliser for the means (`(K1·L)²`, K1 = 0.01, L = 1).
pub const SSIM_C1: f64 = 0.01 * 0.01;
/// SSIM stabiliser for the variances (`(K2·L)²`, K2 = 0.03, L = 1).
pub const SSIM_C2: f64 = 0.03 * 0.03;
/// SSIM window side (pixels).
pub const SSIM_WINDOW: usize = 11;
/// SSIM Gaussian standard deviation (pixels).
pub const SSIM_SIGMA: f64 = 1.5;

/// The metrics of one predicted image against its ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Scores {
    /// Mean absolute log-space error (lower is better).
    pub log_l1: f64,
    /// Root-mean-square log-space error (lower is better).
    pub log_rmse: f64,
    /// Mean LDR-FLIP error in [0, 1] (lower is better).
    pub flip: f64,
    /// Mean SSIM of display images (1 = identical).
    pub ssim: f64,
}

impl Scores {
    /// `self + other · weight`, field by field (for running means).
    pub fn add_scaled(&mut self, other: &Scores, weight: f64) {
        self.log_l1 += other.log_l1 * weight;
        self.log_rmse += other.log_rmse * weight;
        self.flip += other.flip * weight;
        self.ssim += other.ssim * weight;
    }

    /// Whether every field is finite.
    pub fn is_finite(&self) -> bool {
        [self.log_l1, self.log_rmse, self.flip, self.ssim]
            .iter()
            .all(|v| v.is_finite())
    }
}

#[inline]
fn log1(v: f32) -> f64 {
    f64::from(v.max(0.0)).ln_1p()
}

/// Mean `|ln(1+R̂) − ln(1+R)|` over pixels and channels.
pub fn log_l1(pred: &[f32], gt: &[f32], height: usize, width: usize) -> Result<f64> {
    check_pair(pred, gt, height, width)?;
    let s: f64 = pred
        .iter()
        .zip(gt)
        .map(|(&p, &g)| (log1(p) - log1(g)).abs())
        .sum();
    Ok(s / pred.len() as f64)
}

/// `sqrt(mean((ln(1+R̂) − ln(1+R))²))` over pixels and channels.
pub fn log_rmse(pred: &[f32], gt: &[f32], height: usize, width: usize) -> Result<f64> {
    check_pair(pred, gt, height, width)?;
    let s: f64 = pred
        .iter()
        .zip(gt)
        .map(|(&p, &g)| {
            let d = log1(p) - log1(g);
            d * d
        })
        .sum();
    Ok((s / pred.len() as f64).sqrt())
}

/// The display transform of the SSIM: `clamp(R, 0, 1)^(1/2.2)`.
#[inline]
pub fn display(v: f32) -> f64 {
    f64::from(v.clamp(0.0, 1.0)).powf(1.0 / 2.2)
}

/// The normalised 1-D Gaussian of the SSIM window (its outer product is the 2-D window).
pub fn gaussian_1d(size: usize, sigma: f64) -> Vec<f64> {
    let c = (size / 2) as f64;
    let g: Vec<f64> = (0..size)
        .map(|i| {
            let x = i as f64 - c;
            (-(x * x) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let s: f64 = g.iter().sum();
    g.into_iter().map(|v| v / s).collect()
}

/// Separable "valid" correlation of an `h×w` plane with `k ⊗ k`: `(h−n+1)×(w−n+1)` values.
fn filter_valid(src: &[f64], h: usize, w: usize, k: &[f64]) -> Vec<f64> {
    let n = k.len();
    let (oh, ow) = (h + 1 - n, w + 1 - n);
    let mut tmp = vec![0.0; h * ow];
    for i in 0..h {
        let row = &src[i * w..(i + 1) * w];
        for j in 0..ow {
            tmp[i * ow + j] = k.iter().zip(&row[j..j + n]).map(|(a, b)| a * b).sum();
        }
    }
    let mut out = vec![0.0; oh * ow];
    for i in 0..oh {
        for j in 0..ow {
            out[i * ow + j] = (0..n).map(|t| k[t] * tmp[(i + t) * ow + j]).sum();
        }
    }
    out
}

/// Mean SSIM of the display images of `pred` and `gt` (see the module docs). Needs images of
/// at least 11×11 pixels.
pub fn ssim(pred: &[f32], gt: &[f32], height: usize, width: usize) -> Result<f64> {
    check_pair(pred, gt, height, width)?;
    if height < SSIM_WINDOW || width < SSIM_WINDOW {
        return Err(EvalError::Size(format!(
            "SSIM needs at least {SSIM_WINDOW}×{SSIM_WINDOW} pixels, got {height}×{width}"
        )));
    }
    let k = gaussian_1d(SSIM_WINDOW, SSIM_SIGMA);
    let n = height * width;
    let mut total = 0.0;
    let mut count = 0usize;
    for c in 0..3 {
        let x: Vec<f64> = (0..n).map(|p| display(pred[3 * p + c])).collect();
        let y: Vec<f64> = (0..n).map(|p| display(gt[3 * p + c])).collect();
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(a, b)| a * b).collect();
        let [mx, my, sxx, syy, sxy] =
            [&x, &y, &xx, &yy, &xy].map(|p| filter_valid(p, height, width, &k));
        for q in 0..mx.len() {
            let (a, b) = (mx[q], my[q]);
            let vx = sxx[q] - a * a;
            let vy = syy[q] - b * b;
            let cov = sxy[q] - a * b;
            total += ((2.0 * a * b + SSIM_C1) * (2.0 * cov + SSIM_C2))
                / ((a * a + b * b + SSIM_C1) * (vx + vy + SSIM_C2));
            count += 1;
        }
    }
    Ok(total / count as f64)
}

/// All four metrics of `pred` against `gt` (FLIP at `pixels_per_degree`).
pub fn score(
    pred: &[f32],
    gt: &[f32],
    height: usize,
    width: usize,
    pixels_per_degree: f64,
) -> Result<Scores> {
    Ok(Scores {
        log_l1: log_l1(pred, gt, height, width)?,
        log_rmse: log_rmse(pred, gt, height, width)?,
        flip: crate::flip::flip_linear(pred, gt, height, width, pixels_per_degree)?,
        ssim: ssim(pred, gt, height, width)?,
    })
}

/// [`score`] with the ground truth's FLIP analysis computed once by the caller (the runner
/// compares many predictions against one ground truth).
pub fn score_with(
    pred: &[f32],
    gt: &[f32],
    height: usize,
    width: usize,
    gt_flip: &crate::flip::FlipImage,
) -> Result<Scores> {
    let test = crate::flip::FlipImage::new(pred, height, width, gt_flip.pixels_per_degree())?;
    Ok(Scores {
        log_l1: log_l1(pred, gt, height, width)?,
        log_rmse: log_rmse(pred, gt, height, width)?,
        flip: gt_flip.mean_error(&test)?,
        ssim: ssim(pred, gt, height, width)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sums of a few thousand f64 terms: far below this.
    const EXACT: f64 = 1e-12;

    fn ramp(h: usize, w: usize, scale: f32) -> Vec<f32> {
        (0..3 * h * w)
            .map(|k| scale * ((k * 37 % 101) as f32 / 100.0))
            .collect()
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        let a = ramp(16, 20, 0.9);
        let s = ssim(&a, &a, 16, 20).unwrap_or_else(|e| panic!("{e}"));
        assert!((s - 1.0).abs() < EXACT, "{s}");
    }

    #[test]
    fn ssim_of_constant_images_matches_the_closed_form() {
        // Constant images: variances and covariance are 0, so SSIM = (2ab + C1)/(a² + b² + C1).
        let (h, w) = (12, 12);
        let a = vec![0.25f32; 3 * h * w];
        let b = vec![0.64f32; 3 * h * w];
        let (x, y) = (display(0.25), display(0.64));
        let want = (2.0 * x * y + SSIM_C1) / (x * x + y * y + SSIM_C1);
        let got = ssim(&a, &b, h, w).unwrap_or_else(|e| panic!("{e}"));
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        assert!(got < 0.98);
    }

    #[test]
    fn ssim_drops_when_structure_is_destroyed() {
        let (h, w) = (24, 24);
        let a = ramp(h, w, 0.8);
        let mut b = a.clone();
        b.reverse();
        let same = ssim(&a, &a, h, w).unwrap_or_else(|e| panic!("{e}"));
        let other = ssim(&b, &a, h, w).unwrap_or_else(|e| panic!("{e}"));
        assert!(other < 0.5 * same, "{other}");
    }

    #[test]
    fn ssim_rejects_images_smaller_than_the_window() {
        let a = vec![0.5f32; 3 * 10 * 10];
        assert!(ssim(&a, &a, 10, 10).is_err());
    }

    #[test]
    fn log_l1_is_symmetric_zero_on_identity_and_matches_a_hand_value() {
        let (h, w) = (3, 5);
        let a = ramp(h, w, 2.0);
        let b = ramp(h, w, 0.5);
        let ab = log_l1(&a, &b, h, w).unwrap_or_else(|e| panic!("{e}"));
        let ba = log_l1(&b, &a, h, w).unwrap_or_else(|e| panic!("{e}"));
        assert!((ab - ba).abs() < EXACT);
        assert_eq!(log_l1(&a, &a, h, w).unwrap_or_else(|e| panic!("{e}")), 0.0);
        // One pixel e−1 against 0: |ln(e) − ln(1)| = 1 over 3 channels → mean 1.
        let e1 = (std::f32::consts::E - 1.0, 0.0f32);
        let got = log_l1(&[e1.0; 3], &[e1.1; 3], 1, 1).unwrap_or_else(|e| panic!("{e}"));
        assert!((got - 1.0).abs() < 1e-6, "{got}");
    }

    #[test]
    fn log_rmse_bounds_log_l1_and_matches_a_hand_value() {
        let (h, w) = (4, 4);
        let a = ramp(h, w, 3.0);
        let b = ramp(h, w, 0.1);
        let l1 = log_l1(&a, &b, h, w).unwrap_or_else(|e| panic!("{e}"));
        let rmse = log_rmse(&a, &b, h, w).unwrap_or_else(|e| panic!("{e}"));
        assert!(rmse >= l1 - EXACT, "RMSE {rmse} < L1 {l1}");
        // Channels with log errors 0, 0, 3·ln 2... : pixel (1, 0, 7) vs (0, 0, 0).
        let got = log_rmse(&[1.0, 0.0, 7.0], &[0.0; 3], 1, 1).unwrap_or_else(|e| panic!("{e}"));
        let want = ((2f64.ln().powi(2) + 8f64.ln().powi(2)) / 3.0).sqrt();
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }

    #[test]
    fn mismatched_sizes_are_errors() {
        let a = vec![0.0f32; 12];
        let b = vec![0.0f32; 9];
        assert!(log_l1(&a, &b, 2, 2).is_err());
        assert!(log_rmse(&a, &a, 0, 4).is_err());
    }

    #[test]
    fn gaussian_window_is_normalised_and_symmetric() {
        let g = gaussian_1d(SSIM_WINDOW, SSIM_SIGMA);
        assert!((g.iter().sum::<f64>() - 1.0).abs() < EXACT);
        for i in 0..SSIM_WINDOW {
            assert!((g[i] - g[SSIM_WINDOW - 1 - i]).abs() < EXACT);
        }
        assert!(g[5] > g[4] && g[4] > g[0]);
    }
}
