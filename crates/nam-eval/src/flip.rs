//! LDR-FLIP (Andersson et al., "FLIP: A Difference Evaluator for Alternating Images", HPG
//! 2020), ported to Rust from the paper's definitions and the reference Python
//! implementation's constants.
//!
//! This is our own port, not NVIDIA's code: it follows the published pipeline step by step
//! (below). `tests/flip_golden.rs` compares it with NVIDIA's `flip-evaluator` 1.7 on seeded
//! image pairs (tests/fixtures/flip_golden.safetensors, `python -m train_py.flip_golden`;
//! linear RGB, LDR, 67 ppd): means agree within 1e-4 and per-pixel maps within 5e-4 (the
//! reference computes in f32). The unit tests below also pin closed-form values (a flat
//! white/black pair gives ΔE_c of the colour pipeline alone) and the expected orderings.
//!
//! Inputs are **linear** RGB images. FLIP takes sRGB-encoded LDR images and decodes them to
//! linear first, so the encode/decode pair cancels and we only clamp to [0, 1].
//!
//! Colour pipeline: linear RGB → XYZ → YCxCz (opponent space, D65 white of the sRGB
//! primaries); per-channel contrast-sensitivity filters (sums of Gaussians in visual degrees,
//! `pixels_per_degree` pixels per degree, replicate padding); back to linear RGB, clamp to
//! [0, 1]; → CIELAB; Hunt adjustment (`a, b *= 0.01·L`); HyAB distance
//! `|ΔL| + ‖Δ(a, b)‖`; `^0.7`; remapped piecewise-linearly by the distance between Hunt-adjusted
//! green and blue (`p_c = 0.4`, `p_t = 0.95`) to ΔE_c ∈ [0, 1].
//!
//! Feature pipeline: normalised luminance `(Y_YCxCz + 16)/116` of the unfiltered images; edge
//! (first Gaussian derivative) and point (second derivative) detectors with σ = ½·0.082°,
//! positive and negative weights each normalised to ±1; ΔE_f = `(max(|Δ‖edge‖|, |Δ‖point‖|)/√2)^0.5`.
//!
//! Per pixel `ΔE = ΔE_c^(1 − ΔE_f)`; the score is the mean over pixels.

use crate::error::Result;
use crate::pair::check_pair;
use std::f64::consts::PI;

/// FLIP's default viewing condition: a 0.7 m wide 3840-pixel monitor seen from 0.7 m
/// (≈ 67 pixels per degree).
pub const DEFAULT_PIXELS_PER_DEGREE: f64 = 67.0;

/// linear sRGB → XYZ (D65), FLIP's rational coefficients.
const RGB_TO_XYZ: [[f64; 3]; 3] = [
    [
        10_135_552.0 / 24_577_794.0,
        8_788_810.0 / 24_577_794.0,
        4_435_075.0 / 24_577_794.0,
    ],
    [
        2_613_072.0 / 12_288_897.0,
        8_788_810.0 / 12_288_897.0,
        887_015.0 / 12_288_897.0,
    ],
    [
        1_425_312.0 / 73_733_382.0,
        8_788_810.0 / 73_733_382.0,
        70_074_185.0 / 73_733_382.0,
    ],
];

/// Contrast-sensitivity filters `(a, b)` per YCxCz channel:
/// `g(x) = Σ a·sqrt(π/b)·exp(−π² x²/b)`, x in degrees.
const CSF: [&[(f64, f64)]; 3] = [
    &[(1.0, 0.0047)],
    &[(1.0, 0.0053)],
    &[(34.1, 0.04), (13.5, 0.025)],
];
/// Largest `b` of [`CSF`] (with FLIP's `b2 = 1e-5` terms of zero weight): sets the radius.
const CSF_MAX_B: f64 = 0.04;
/// Colour-error exponent `q_c`.
const QC: f64 = 0.7;
/// Feature-error exponent `q_f`.
const QF: f64 = 0.5;
/// Remapping knee: fraction of the maximum error.
const PC: f64 = 0.4;
/// Remapped value at the knee.
const PT: f64 = 0.95;
/// Feature detector width in degrees (σ = w/2).
const FEATURE_WIDTH_DEG: f64 = 0.082;

fn mat_mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

fn invert3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let [[a, b, c], [d, e, f], [g, h, i]] = *m;
    let det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    [
        [
            (e * i - f * h) / det,
            (c * h - b * i) / det,
            (b * f - c * e) / det,
        ],
        [
            (f * g - d * i) / det,
            (a * i - c * g) / det,
            (c * d - a * f) / det,
        ],
        [
            (d * h - e * g) / det,
            (b * g - a * h) / det,
            (a * e - b * d) / det,
        ],
    ]
}

fn white() -> [f64; 3] {
    mat_mul(&RGB_TO_XYZ, [1.0; 3])
}

fn xyz_to_ycxcz(xyz: [f64; 3], wp: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = [xyz[0] / wp[0], xyz[1] / wp[1], xyz[2] / wp[2]];
    [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
}

fn ycxcz_to_xyz(c: [f64; 3], wp: [f64; 3]) -> [f64; 3] {
    let y = (c[0] + 16.0) / 116.0;
    let x = c[1] / 500.0 + y;
    let z = y - c[2] / 200.0;
    [x * wp[0], y * wp[1], z * wp[2]]
}

fn xyz_to_lab(xyz: [f64; 3], wp: [f64; 3]) -> [f64; 3] {
    let delta: f64 = 6.0 / 29.0;
    let f = |t: f64| {
        if t > delta.powi(3) {
            t.cbrt()
        } else {
            t / (3.0 * delta * delta) + 4.0 / 29.0
        }
    };
    let [fx, fy, fz] = [f(xyz[0] / wp[0]), f(xyz[1] / wp[1]), f(xyz[2] / wp[2])];
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

fn hunt(lab: [f64; 3]) -> [f64; 3] {
    [lab[0], 0.01 * lab[0] * lab[1], 0.01 * lab[0] * lab[2]]
}

fn hyab(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).abs() + ((a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn hunt_lab_of_linear(rgb: [f64; 3]) -> [f64; 3] {
    hunt(xyz_to_lab(mat_mul(&RGB_TO_XYZ, rgb), white()))
}

/// `q_c`-powered HyAB distance between Hunt-adjusted pure green and pure blue: the largest
/// colour error, which the remapping sends to 1.
fn cmax() -> f64 {
    hyab(
        hunt_lab_of_linear([0.0, 1.0, 0.0]),
        hunt_lab_of_linear([0.0, 0.0, 1.0]),
    )
    .powf(QC)
}

/// Separable replicate-padded correlation with `kx` along rows and `ky` along columns
/// (both of odd length, centred).
fn filter_sep(src: &[f64], h: usize, w: usize, kx: &[f64], ky: &[f64]) -> Vec<f64> {
    let (rx, ry) = (kx.len() / 2, ky.len() / 2);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0.0; h * w];
    for i in 0..h {
        for j in 0..w {
            let mut s = 0.0;
            for (t, k) in kx.iter().enumerate() {
                s += k * src[i * w + clamp(j as isize + t as isize - rx as isize, w)];
            }
            tmp[i * w + j] = s;
        }
    }
    let mut out = vec![0.0; h * w];
    for i in 0..h {
        for j in 0..w {
            let mut s = 0.0;
            for (t, k) in ky.iter().enumerate() {
                s += k * tmp[clamp(i as isize + t as isize - ry as isize, h) * w + j];
            }
            out[i * w + j] = s;
        }
    }
    out
}

/// The filters of one viewing condition.
#[derive(Debug, Clone)]
struct Kernels {
    /// Per YCxCz channel: `(weight, 1-D Gaussian)` terms; the 2-D filter is
    /// `Σ weight · g ⊗ g`, normalised to sum 1.
    csf: [Vec<(f64, Vec<f64>)>; 3],
    /// Edge detector along x (the y factor is `smooth`).
    edge: Vec<f64>,
    /// Point detector along x.
    point: Vec<f64>,
    /// Normalised Gaussian across the derivative direction.
    smooth: Vec<f64>,
}

impl Kernels {
    fn new(ppd: f64) -> Self {
        let r = (3.0 * (CSF_MAX_B / (2.0 * PI * PI)).sqrt() * ppd).ceil() as isize;
        let csf = [0, 1, 2].map(|c| {
            let terms: Vec<(f64, Vec<f64>)> = CSF[c]
                .iter()
                .map(|&(a, b)| {
                    let g: Vec<f64> = (-r..=r)
                        .map(|x| {
                            let d = x as f64 / ppd;
                            (-PI * PI * d * d / b).exp()
                        })
                        .collect();
                    (a * (PI / b).sqrt(), g)
                })
                .collect();
            let total: f64 = terms
                .iter()
                .map(|(wt, g)| wt * g.iter().sum::<f64>().powi(2))
                .sum();
            terms
                .into_iter()
                .map(|(wt, g)| (wt / total, g))
                .collect::<Vec<_>>()
        });
        let sd = 0.5 * FEATURE_WIDTH_DEG * ppd;
        let fr = (3.0 * sd).ceil() as isize;
        let xs: Vec<f64> = (-fr..=fr).map(|x| x as f64).collect();
        let gauss: Vec<f64> = xs
            .iter()
            .map(|x| (-x * x / (2.0 * sd * sd)).exp())
            .collect();
        let gsum: f64 = gauss.iter().sum();
        let normalise_signed = |f: Vec<f64>| {
            let pos: f64 = f.iter().filter(|v| **v > 0.0).sum();
            let neg: f64 = -f.iter().filter(|v| **v < 0.0).sum::<f64>();
            f.into_iter()
                .map(|v| if v > 0.0 { v / pos } else { v / neg })
                .collect::<Vec<_>>()
        };
        let edge = normalise_signed(xs.iter().zip(&gauss).map(|(x, g)| -x * g).collect());
        let point = normalise_signed(
            xs.iter()
                .zip(&gauss)
                .map(|(x, g)| (x * x / (sd * sd) - 1.0) * g)
                .collect(),
        );
        let smooth = gauss.iter().map(|g| g / gsum).collect();
        Self {
            csf,
            edge,
            point,
            smooth,
        }
    }
}

/// The per-pixel quantities FLIP compares, for one image: Hunt-adjusted CIELAB of the
/// CSF-filtered image, and edge and point feature magnitudes. Build it once for a ground
/// truth and compare many predictions against it.
#[derive(Debug, Clone)]
pub struct FlipImage {
    height: usize,
    width: usize,
    ppd: f64,
    lab: Vec<[f64; 3]>,
    edge: Vec<f64>,
    point: Vec<f64>,
}

impl FlipImage {
    /// Analyses a linear RGB image (HWC, `3·height·width` values; clamped to [0, 1]).
    pub fn new(rgb: &[f32], height: usize, width: usize, pixels_per_degree: f64) -> Result<Self> {
        check_pair(rgb, rgb, height, width)?;
        let k = Kernels::new(pixels_per_degree);
        let n = height * width;
        let wp = white();
        let ycc: Vec<[f64; 3]> = (0..n)
            .map(|p| {
                let c = [0, 1, 2].map(|ch| f64::from(rgb[3 * p + ch].clamp(0.0, 1.0)));
                xyz_to_ycxcz(mat_mul(&RGB_TO_XYZ, c), wp)
            })
            .collect();
        let mut filtered = vec![[0.0; 3]; n];
        for (c, terms) in k.csf.iter().enumerate() {
            let plane: Vec<f64> = ycc.iter().map(|v| v[c]).collect();
            for (wt, g) in terms {
                let f = filter_sep(&plane, height, width, g, g);
                for (dst, v) in filtered.iter_mut().zip(f) {
                    dst[c] += wt * v;
                }
            }
        }
        let to_rgb = invert3(&RGB_TO_XYZ);
        let lab = filtered
            .iter()
            .map(|&c| {
                let rgb = mat_mul(&to_rgb, ycxcz_to_xyz(c, wp)).map(|v| v.clamp(0.0, 1.0));
                hunt_lab_of_linear(rgb)
            })
            .collect();
        let lum: Vec<f64> = ycc.iter().map(|v| (v[0] + 16.0) / 116.0).collect();
        let magnitude = |d: &[f64]| {
            let gx = filter_sep(&lum, height, width, d, &k.smooth);
            let gy = filter_sep(&lum, height, width, &k.smooth, d);
            gx.iter()
                .zip(&gy)
                .map(|(a, b)| (a * a + b * b).sqrt())
                .collect::<Vec<_>>()
        };
        Ok(Self {
            height,
            width,
            ppd: pixels_per_degree,
            lab,
            edge: magnitude(&k.edge),
            point: magnitude(&k.point),
        })
    }

    /// The viewing condition it was analysed for.
    pub fn pixels_per_degree(&self) -> f64 {
        self.ppd
    }

    /// Per-pixel FLIP error of `test` against `self` (the reference), row-major, in [0, 1].
    pub fn error_map(&self, test: &FlipImage) -> Result<Vec<f64>> {
        if (self.height, self.width) != (test.height, test.width) || self.ppd != test.ppd {
            return Err(crate::error::EvalError::Size(format!(
                "FLIP images differ: {}×{} at {} ppd vs {}×{} at {} ppd",
                self.height, self.width, self.ppd, test.height, test.width, test.ppd
            )));
        }
        let cmax = cmax();
        let knee = PC * cmax;
        Ok((0..self.lab.len())
            .map(|p| {
                let e = hyab(self.lab[p], test.lab[p]).powf(QC);
                let dc = if e < knee {
                    PT / knee * e
                } else {
                    PT + (e - knee) / (cmax - knee) * (1.0 - PT)
                };
                let df = ((self.edge[p] - test.edge[p])
                    .abs()
                    .max((self.point[p] - test.point[p]).abs())
                    / std::f64::consts::SQRT_2)
                    .powf(QF);
                dc.powf(1.0 - df)
            })
            .collect())
    }

    /// Mean FLIP error of `test` against `self`.
    pub fn mean_error(&self, test: &FlipImage) -> Result<f64> {
        let m = self.error_map(test)?;
        Ok(m.iter().sum::<f64>() / m.len() as f64)
    }
}

/// Mean LDR-FLIP of linear image `pred` against reference `gt` (see the module docs).
pub fn flip_linear(
    pred: &[f32],
    gt: &[f32],
    height: usize,
    width: usize,
    pixels_per_degree: f64,
) -> Result<f64> {
    check_pair(pred, gt, height, width)?;
    let r = FlipImage::new(gt, height, width, pixels_per_degree)?;
    let t = FlipImage::new(pred, height, width, pixels_per_degree)?;
    r.mean_error(&t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(h: usize, w: usize, v: [f32; 3]) -> Vec<f32> {
        (0..h * w).flat_map(|_| v).collect()
    }

    fn flip(a: &[f32], b: &[f32], h: usize, w: usize) -> f64 {
        flip_linear(a, b, h, w, DEFAULT_PIXELS_PER_DEGREE).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn identical_images_have_zero_flip() {
        let (h, w) = (16, 16);
        let a: Vec<f32> = (0..3 * h * w).map(|k| (k % 17) as f32 / 16.0).collect();
        assert_eq!(flip(&a, &a, h, w), 0.0);
    }

    #[test]
    fn flat_white_against_flat_black_matches_the_closed_form() {
        // Flat images: the CSF keeps them flat, features are 0, so ΔE = ΔE_c. White vs black
        // is HyAB = 100 (L 100 vs 0, a = b = 0); 100^0.7 lies above the knee 0.4·cmax.
        let (h, w) = (8, 8);
        let white_img = flat(h, w, [1.0; 3]);
        let black = flat(h, w, [0.0; 3]);
        let cm = cmax();
        let e = 100f64.powf(QC);
        let want = PT + (e - PC * cm) / (cm - PC * cm) * (1.0 - PT);
        let got = flip(&black, &white_img, h, w);
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        // The hand value with rounded Lab coordinates of green and blue: ≈ 0.967.
        assert!((got - 0.967).abs() < 2e-3, "{got}");
    }

    #[test]
    fn green_against_blue_is_the_maximum_error() {
        let (h, w) = (6, 6);
        let got = flip(
            &flat(h, w, [0.0, 0.0, 1.0]),
            &flat(h, w, [0.0, 1.0, 0.0]),
            h,
            w,
        );
        assert!((got - 1.0).abs() < 1e-9, "{got}");
    }

    #[test]
    fn flip_grows_with_the_size_of_a_perturbation() {
        let (h, w) = (24, 24);
        let base: Vec<f32> = (0..h * w)
            .flat_map(|p| {
                let v = 0.2 + 0.6 * ((p % w) as f32 / w as f32);
                [v, 0.8 * v, 0.5 * v]
            })
            .collect();
        let scaled = |s: f32| base.iter().map(|v| v * s).collect::<Vec<_>>();
        let small = flip(&scaled(0.95), &base, h, w);
        let large = flip(&scaled(0.6), &base, h, w);
        assert!(
            0.0 < small && small < large && large < 1.0,
            "{small} {large}"
        );
    }

    #[test]
    fn an_edge_costs_more_than_its_colour_error_alone() {
        // A sharp vertical edge missing from the test image: the feature term lowers the
        // exponent 1 − ΔE_f near the edge, raising ΔE_c^(1−ΔE_f) there.
        let (h, w) = (20, 20);
        let edge: Vec<f32> = (0..h * w)
            .flat_map(|p| if p % w < w / 2 { [0.2; 3] } else { [0.6; 3] })
            .collect();
        let mean = flat(h, w, [0.4; 3]);
        let r = FlipImage::new(&edge, h, w, DEFAULT_PIXELS_PER_DEGREE)
            .unwrap_or_else(|e| panic!("{e}"));
        let t = FlipImage::new(&mean, h, w, DEFAULT_PIXELS_PER_DEGREE)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(r.edge.iter().cloned().fold(0.0, f64::max) > 0.1);
        assert!(t.edge.iter().all(|v| v.abs() < 1e-12));
        let m = r.error_map(&t).unwrap_or_else(|e| panic!("{e}"));
        assert!(m.iter().all(|v| (0.0..=1.0).contains(v)));
        let centre = m[(h / 2) * w + w / 2];
        assert!(centre > 0.0);
    }

    #[test]
    fn feature_kernels_are_normalised() {
        let k = Kernels::new(DEFAULT_PIXELS_PER_DEGREE);
        for d in [&k.edge, &k.point] {
            let pos: f64 = d.iter().filter(|v| **v > 0.0).sum();
            let neg: f64 = d.iter().filter(|v| **v < 0.0).sum();
            assert!((pos - 1.0).abs() < 1e-12 && (neg + 1.0).abs() < 1e-12);
        }
        assert!((k.smooth.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        for terms in &k.csf {
            let total: f64 = terms
                .iter()
                .map(|(wt, g)| wt * g.iter().sum::<f64>().powi(2))
                .sum();
            assert!((total - 1.0).abs() < 1e-12);
        }
        // Radius ⌈3·sqrt(0.04/(2π²))·67⌉ = 10 for the CSF, ⌈3·0.041·67⌉ = 9 for features.
        assert_eq!(k.csf[0][0].1.len(), 21);
        assert_eq!(k.edge.len(), 19);
    }

    #[test]
    fn colour_transforms_round_trip() {
        let wp = white();
        for c in [[0.2, 0.5, 0.9], [1.0, 0.0, 0.3], [0.0; 3]] {
            let back = mat_mul(
                &invert3(&RGB_TO_XYZ),
                ycxcz_to_xyz(xyz_to_ycxcz(mat_mul(&RGB_TO_XYZ, c), wp), wp),
            );
            for i in 0..3 {
                assert!((back[i] - c[i]).abs() < 1e-12);
            }
        }
        assert!((wp[1] - 1.0).abs() < 1e-12);
    }
}
