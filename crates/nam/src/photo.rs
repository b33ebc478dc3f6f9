//! Input photos: loading, validation and the 4-channel network input (docs/FORMAT.md).
//!
//! A photo is a square image of a near-planar material taken from the capture position
//! (0, 0, d) with a co-located flash (DESIGN.md §3), d = 1/tan(fov/2) for the camera's field
//! of view (28° unless the photo declares another, [`Photo::with_fov`]). Pixel values are
//! *linear* RGB radiance in the network's convention (a white diffuse surface facing the flash
//! reads ≈ 1).

use crate::error::{NamError, Result};
use nam_ggx::color::srgb_decode;
use nam_ggx::geometry::{CAPTURE_FOV_DEG, FOV_RANGE_DEG, capture_distance};
use nam_ggx::imageio::{FileKind, read_rgb};
use nam_model::input::network_input;
use nam_weights::LogMode;
use std::path::Path;

/// Largest accepted photo side in pixels. The U-Net's activations at C=64 take
/// ≈ 64·(1+…)·H·W floats; 4096² is where that stops fitting a typical machine.
pub const MAX_PHOTO_SIDE: usize = 4096;

/// A validated linear-RGB photo, row-major, channels interleaved, with the field of view of
/// the camera that took it.
#[derive(Debug, Clone, PartialEq)]
pub struct Photo {
    side: usize,
    rgb: Vec<f32>,
    fov_deg: f64,
}

impl Photo {
    /// Reads a PNG/JPEG (sRGB-decoded to linear; alpha dropped) or an EXR (linear HDR).
    /// The image must be square (see [`Photo::from_linear_rgb`]); use
    /// [`Photo::load_cropped`] to accept any aspect ratio.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::load_resized(path, false, None)
    }

    /// Like [`Photo::load`], but centre-crops a non-square image to its shorter side first.
    pub fn load_cropped(path: impl AsRef<Path>) -> Result<Self> {
        Self::load_resized(path, true, None)
    }

    /// Like [`Photo::load`], optionally centre-cropped (`crop`) and resampled to
    /// `side`×`side` ([`Photo::resized`]'s filters) *before* the [`MAX_PHOTO_SIDE`] limit
    /// applies, so a photo larger than that loads when it is resized below it (files are still
    /// bounded by the decoder's `MAX_IMAGE_SIDE`, 16384).
    pub fn load_resized(path: impl AsRef<Path>, crop: bool, side: Option<usize>) -> Result<Self> {
        let path = path.as_ref();
        let (h, w, rgb) = read_linear(path)?;
        let (h, w, rgb) = if crop {
            center_crop(h, w, rgb)
        } else {
            (h, w, rgb)
        };
        let (h, w, rgb) = match side {
            Some(side) if h == w => (side, side, resample(rgb, h, side)?),
            _ => (h, w, rgb),
        };
        Self::from_linear_rgb(h, w, rgb).map_err(|e| e.in_file(path))
    }

    /// Wraps `height`×`width` linear RGB values, row-major and interleaved
    /// (`rgb.len() == height·width·3`; sizes are (height, width) throughout nam). Errors on a non-square or
    /// empty image, a side above [`MAX_PHOTO_SIDE`], or any NaN/Inf value. Negative values
    /// (noise in HDR files) are kept; the network input clamps them to 0. The field of view
    /// is the training geometry's, 28° ([`Photo::with_fov`] declares another).
    pub fn from_linear_rgb(height: usize, width: usize, rgb: Vec<f32>) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(NamError::Photo("the photo has no pixels".into()));
        }
        if width != height {
            return Err(NamError::Photo(format!(
                "the photo is {width} px wide and {height} px high but must be square: the material spans \
                 [−1,1]² seen from the capture position (crop it, e.g. `--crop` in nam-cli)"
            )));
        }
        if width > MAX_PHOTO_SIDE {
            return Err(NamError::Photo(format!(
                "the photo is {width}×{height}; the largest supported side is {MAX_PHOTO_SIDE} \
                 (resize it, e.g. `--resize 1024` in nam-cli)"
            )));
        }
        if rgb.len() != width * height * 3 {
            return Err(NamError::Photo(format!(
                "expected {} RGB values for {width}×{height}, got {}",
                width * height * 3,
                rgb.len()
            )));
        }
        if let Some(k) = rgb.iter().position(|v| !v.is_finite()) {
            let px = k / 3;
            return Err(NamError::Photo(format!(
                "pixel (row {}, col {}) is not finite ({})",
                px / width,
                px % width,
                rgb[k]
            )));
        }
        Ok(Self {
            side: width,
            rgb,
            fov_deg: CAPTURE_FOV_DEG,
        })
    }

    /// Wraps `height`×`width` 8-bit sRGB-encoded RGB values (row-major, interleaved), decoded
    /// to linear as a PNG or JPEG file's are ([`Photo::load`]); otherwise as
    /// [`Photo::from_linear_rgb`].
    pub fn from_srgb8(height: usize, width: usize, rgb: &[u8]) -> Result<Self> {
        let linear = rgb
            .iter()
            .map(|&v| srgb_decode(f32::from(v) / f32::from(u8::MAX)))
            .collect();
        Self::from_linear_rgb(height, width, linear)
    }

    /// Declares the field of view of the camera that took the (square) photo, in degrees,
    /// within [`FOV_RANGE_DEG`]: the estimator then sees camera and flash at (0, 0, d),
    /// d = [`capture_distance`]`(degrees)` (surface frame, material half-widths), instead of
    /// the training geometry's 28°. Phone photos cropped to a centre square are often 35–50°.
    pub fn with_fov(self, degrees: f64) -> Result<Self> {
        if !FOV_RANGE_DEG.contains(&degrees) {
            return Err(NamError::Photo(format!(
                "field of view {degrees}° is outside {}..={} degrees",
                FOV_RANGE_DEG.start(),
                FOV_RANGE_DEG.end()
            )));
        }
        Ok(Self {
            fov_deg: degrees,
            ..self
        })
    }

    /// Field of view of the camera that took the photo, degrees (28 unless declared).
    pub fn fov(&self) -> f64 {
        self.fov_deg
    }

    /// Distance of the capture camera and flash from the material's centre, `1/tan(fov/2)`
    /// (material half-widths): they sit at (0, 0, d).
    pub fn capture_distance(&self) -> f64 {
        capture_distance(self.fov_deg)
    }

    /// Side length in pixels (photos are square).
    pub fn side(&self) -> usize {
        self.side
    }

    /// Linear RGB values, row-major, interleaved.
    pub fn rgb(&self) -> &[f32] {
        &self.rgb
    }

    /// Fraction of pixels (0..=1) with some channel at or above `level` (linear). At
    /// [`nam_model::input::LDR_CLAMP`] these are the pixels an LDR model sees as pure white:
    /// the blown-out highlight of an over-exposed photo, where the material is not visible.
    pub fn saturated_fraction(&self, level: f32) -> f64 {
        let n = self.saturated(level).filter(|&s| s).count();
        n as f64 / (self.side * self.side) as f64
    }

    /// Per pixel (row-major), whether some channel is at or above `level` (linear); see
    /// [`Self::saturated_fraction`].
    pub fn saturated(&self, level: f32) -> impl Iterator<Item = bool> + '_ {
        self.rgb
            .chunks_exact(3)
            .map(move |px| px.iter().any(|&v| v >= level))
    }

    /// Resamples to `side`×`side` with a triangle (bilinear) filter on downscale and
    /// Catmull-Rom on upscale
    /// (in linear space, so highlights keep their energy). The field of view is kept.
    pub fn resized(&self, side: usize) -> Result<Self> {
        Ok(Self {
            fov_deg: self.fov_deg,
            ..Self::from_linear_rgb(side, side, resample(self.rgb.clone(), self.side, side)?)?
        })
    }

    /// The 4-channel network input, CHW (`[4, side, side]`): `ln(1 + clamp(rgb))` per the
    /// model's log mode and the capture half-vector z for the photo's field of view
    /// (docs/FORMAT.md); see [`nam_model::input::network_input`].
    pub fn network_input(&self, mode: LogMode) -> Result<Vec<f32>> {
        let d = self.capture_distance() as f32;
        Ok(network_input(&self.rgb, self.side, self.side, mode, d)?)
    }
}

/// A square `from`×`from` linear RGB buffer resampled to `to`×`to`: a triangle (bilinear)
/// filter on downscale, Catmull-Rom on upscale.
fn resample(rgb: Vec<f32>, from: usize, to: usize) -> Result<Vec<f32>> {
    if to == 0 || to > MAX_PHOTO_SIDE {
        return Err(NamError::Photo(format!(
            "resize target {to} is outside 1..={MAX_PHOTO_SIDE}"
        )));
    }
    let buf =
        image::ImageBuffer::<image::Rgb<f32>, Vec<f32>>::from_raw(from as u32, from as u32, rgb)
            .ok_or_else(|| NamError::Photo("internal: photo buffer size".into()))?;
    let filter = if to < from {
        image::imageops::FilterType::Triangle
    } else {
        image::imageops::FilterType::CatmullRom
    };
    Ok(image::imageops::resize(&buf, to as u32, to as u32, filter).into_raw())
}

/// Reads any supported image as linear RGB `(height, width, rgb)`: LDR files are sRGB-decoded.
fn read_linear(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let (img, kind) = read_rgb(path)?;
    let (h, w) = (img.height(), img.width());
    let mut rgb = img.into_vec();
    if kind == FileKind::Ldr {
        rgb.iter_mut().for_each(|v| *v = srgb_decode(*v));
    }
    Ok((h, w, rgb))
}

/// The centred square of side `min(h, w)`: `(side, side, rgb)`.
fn center_crop(h: usize, w: usize, rgb: Vec<f32>) -> (usize, usize, Vec<f32>) {
    if w == h {
        return (h, w, rgb);
    }
    let s = w.min(h);
    let (x0, y0) = ((w - s) / 2, (h - s) / 2);
    let mut out = Vec::with_capacity(s * s * 3);
    for i in y0..y0 + s {
        out.extend_from_slice(&rgb[(i * w + x0) * 3..(i * w + x0 + s) * 3]);
    }
    (s, s, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_square_photo_is_rejected_and_crop_makes_it_square() {
        let err = Photo::from_linear_rgb(2, 4, vec![0.5; 24]).unwrap_err();
        assert!(
            err.to_string()
                .contains("4 px wide and 2 px high but must be square"),
            "{err}"
        );
        let (h, w, rgb) = center_crop(2, 4, (0..24).map(|v| v as f32).collect());
        assert_eq!((h, w), (2, 2));
        // Columns 1..3 of both rows.
        assert_eq!(rgb[0], 3.0);
        assert_eq!(rgb[6], 15.0);
    }

    #[test]
    fn nan_pixel_is_rejected_with_its_position() {
        let mut rgb = vec![0.2; 3 * 9];
        rgb[3 * 5 + 1] = f32::NAN;
        let err = Photo::from_linear_rgb(3, 3, rgb).unwrap_err();
        assert!(err.to_string().contains("row 1, col 2"), "{err}");
    }

    #[test]
    fn huge_photo_is_rejected_before_touching_pixels() {
        let err =
            Photo::from_linear_rgb(MAX_PHOTO_SIDE + 1, MAX_PHOTO_SIDE + 1, Vec::new()).unwrap_err();
        assert!(err.to_string().contains("largest supported side"), "{err}");
    }

    #[test]
    fn saturated_fraction_counts_pixels_with_any_channel_at_the_level() {
        let p = Photo::from_linear_rgb(
            2,
            2,
            vec![1.0, 0.2, 0.2, 0.5, 0.5, 0.5, 0.1, 3.0, 0.1, 0.999, 0.0, 0.0],
        )
        .expect("valid");
        assert_eq!(p.saturated_fraction(nam_model::input::LDR_CLAMP), 0.5);
        assert_eq!(p.saturated_fraction(10.0), 0.0);
    }

    #[test]
    fn ldr_input_clamps_and_hdr_input_keeps_large_values() {
        let p = Photo::from_linear_rgb(1, 1, vec![1e6, -3.0, 0.5]).expect("valid");
        let ldr = p.network_input(LogMode::Ldr).expect("input");
        assert!((ldr[0] - nam_model::input::LDR_CLAMP.ln_1p()).abs() < 1e-7);
        assert_eq!(ldr[1], 0.0);
        let hdr = p.network_input(LogMode::Hdr).expect("input");
        assert!((hdr[0] - 1e6f32.ln_1p()).abs() < 1e-5);
        // A 1×1 photo's only pixel is the centre: half vector straight up.
        assert!((hdr[3] - 1.0).abs() < 1e-7);
    }

    #[test]
    fn fov_moves_the_capture_camera_and_survives_a_resize() {
        let p = Photo::from_linear_rgb(4, 4, vec![0.5; 48]).expect("valid");
        assert_eq!(p.fov(), CAPTURE_FOV_DEG);
        assert_eq!(p.capture_distance(), capture_distance(CAPTURE_FOV_DEG));
        let wide = p
            .clone()
            .with_fov(45.0)
            .expect("in range")
            .resized(2)
            .expect("resize");
        assert_eq!(wide.fov(), 45.0);
        let d = wide.capture_distance();
        assert!((d - (1.0 + 2f64.sqrt())).abs() < 1e-12, "{d}");
        // Pixel (0, 0) of a 2×2 photo is at (−0.5, 0.5).
        let z = wide.network_input(LogMode::Ldr).expect("input")[3 * 4];
        let want = d / (0.5 + d * d).sqrt();
        assert!((f64::from(z) - want).abs() < 1e-6, "{z} vs {want}");
    }

    #[test]
    fn fov_outside_the_range_is_an_error_naming_it() {
        let p = Photo::from_linear_rgb(1, 1, vec![0.5; 3]).expect("valid");
        for bad in [0.0, 4.9, 120.1, 500.0, f64::NAN, f64::INFINITY] {
            let err = p.clone().with_fov(bad).unwrap_err().to_string();
            assert!(err.contains("5..=120 degrees"), "{bad}: {err}");
        }
        assert!(p.clone().with_fov(5.0).is_ok() && p.with_fov(120.0).is_ok());
    }
}
