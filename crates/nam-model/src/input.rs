//! The 4-channel network input of `M_est` (docs/FORMAT.md, "Network input").

use nam_weights::LogMode;

use crate::error::{Result, check_finite, check_len};
use crate::geometry::capture_half_z;
use crate::unet::check_image;

/// Largest LDR value kept before the log (FORMAT.md: `clamp(rgb, 0, 0.999999)`).
pub const LDR_CLAMP: f32 = 0.999_999;

/// Builds the CHW network input (`4 × height × width`) from a linear-RGB photo
/// (HWC, `height × width × 3`; LDR photos sRGB-decoded already):
/// channels 0..3 = `ln(1 + clamp(rgb, 0, 0.999999))` (LDR) or `ln(1 + max(rgb, 0))`
/// (HDR); channel 3 = z of the capture half vector at the pixel centre.
/// Non-finite pixels are an error.
pub fn network_input(
    photo: &[f32],
    height: usize,
    width: usize,
    mode: LogMode,
) -> Result<Vec<f32>> {
    check_image(height, width)?;
    check_len("photo", height * width * 3, photo.len())?;
    check_finite("photo", photo)?;
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
        out[3 * n + p] = capture_half_z(p / width, p % width, height, width);
    }
    Ok(out)
}
