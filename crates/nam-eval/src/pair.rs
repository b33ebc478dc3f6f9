//! The shape check every image metric makes: two linear RGB images (HWC, `3·height·width`
//! values each) of the same non-empty size. Its own module so that [`crate::metrics`] and
//! [`crate::flip`] share it without depending on each other.

use crate::error::{EvalError, Result};

/// Checks that two images have `3·height·width` values each.
pub(crate) fn check_pair(pred: &[f32], gt: &[f32], height: usize, width: usize) -> Result<()> {
    let n = 3 * height * width;
    if height == 0 || width == 0 {
        return Err(EvalError::Size("empty image".into()));
    }
    if pred.len() != n || gt.len() != n {
        return Err(EvalError::Size(format!(
            "expected {n} values for {height}×{width} RGB, got {} and {}",
            pred.len(),
            gt.len()
        )));
    }
    Ok(())
}
