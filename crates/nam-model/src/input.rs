//! The 4-channel network input of `M_est` (docs/FORMAT.md, "Network input").

use nam_weights::LogMode;

use crate::error::{ModelError, Result, check_finite, check_len};
use crate::geometry::capture_half_z;
use crate::unet::check_image;

/// Largest LDR value kept before the log (FORMAT.md: `clamp(rgb, 0, 0.999999)`).
pub const LDR_CLAMP: f32 = 0.999_999;

/// Builds the CHW network input (`4 × height × width`) from a linear-RGB photo
/// (HWC, `height × width × 3`; LDR photos sRGB-decoded already) taken from
/// (0, 0, `capture_distance`) with a co-located flash (surface frame, material
/// half-widths; the training geometry is
/// [`CAPTURE_DISTANCE`](crate::geometry::CAPTURE_DISTANCE), other cameras
/// [`capture_distance`](crate::geometry::capture_distance)`(fov)`):
/// channels 0..3 = `ln(1 + clamp(rgb, 0, 0.999999))` (LDR) or `ln(1 + max(rgb, 0))`
/// (HDR); channel 3 = z of the capture half vector at the pixel centre,
/// `d / sqrt(x² + y² + d²)`. Non-finite pixels or distance, or a distance ≤ 0,
/// are an error.
pub fn network_input(
    photo: &[f32],
    height: usize,
    width: usize,
    mode: LogMode,
    capture_distance: f32,
) -> Result<Vec<f32>> {
    check_image(height, width)?;
    check_len("photo", height * width * 3, photo.len())?;
    check_finite("photo", photo)?;
    // The capture camera and flash sit at (0, 0, d): above the surface like any light.
    check_finite("capture distance", &[capture_distance])?;
    if capture_distance <= 0.0 {
        return Err(ModelError::BelowSurface);
    }
    let n = height * width;
    let mut out = vec![0.0f32; 4 * n];
    for p in 0..n {
        for c in 0..3 {
            let v = photo[p * 3 + c];
            let v = match mode {
                LogMode::Ldr => v.clamp(0.0, LDR_CLAMP),
                LogMode::Hdr => v.max(0.0),
            };
            out[c * n + p] = v.ln_1p();
        }
        out[3 * n + p] = capture_half_z(p / width, p % width, height, width, capture_distance);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CAPTURE_DISTANCE, capture_distance};

    /// f32 rounding of the squares, the sum, the square root and the division.
    const HALF_Z_TOL: f32 = 1e-6;

    fn half_z_channel(side: usize, distance: f32) -> Vec<f32> {
        let photo = vec![0.5; side * side * 3];
        let input = network_input(&photo, side, side, LogMode::Ldr, distance)
            .unwrap_or_else(|e| panic!("{e}"));
        input[3 * side * side..].to_vec()
    }

    #[test]
    fn half_z_channel_at_fov_45_is_the_formula_at_corner_and_centre() {
        let side = 5;
        let d = capture_distance(45.0);
        let z = half_z_channel(side, d as f32);
        // Corner pixel (0, 0) is at (−0.8, 0.8); the centre pixel (2, 2) at the origin.
        let corner = d / (0.8f64 * 0.8 + 0.8 * 0.8 + d * d).sqrt();
        assert!(
            (z[0] - corner as f32).abs() < HALF_Z_TOL,
            "{} vs {corner}",
            z[0]
        );
        assert_eq!(z[2 * side + 2], 1.0);
        // A wider camera sees the corner more obliquely than the training geometry's.
        let z28 = half_z_channel(side, CAPTURE_DISTANCE as f32);
        assert!(z[0] < z28[0] - 0.05, "{} vs {}", z[0], z28[0]);
    }

    #[test]
    fn capture_distance_must_be_finite_and_positive() {
        let photo = [0.5; 3];
        for d in [0.0, -1.0] {
            let r = network_input(&photo, 1, 1, LogMode::Hdr, d);
            assert!(matches!(r, Err(ModelError::BelowSurface)), "{d}: {r:?}");
        }
        for d in [f32::NAN, f32::INFINITY] {
            let r = network_input(&photo, 1, 1, LogMode::Hdr, d);
            assert!(matches!(r, Err(ModelError::NonFinite { .. })), "{d}: {r:?}");
        }
    }
}
