//! The value types of the fast path: a latent [`ParamMap`] and an [`Rgb`] radiance image.

/// A latent parameter map: `data[(row·width + col)·channels + k]` (HWC).
#[derive(Debug, Clone, PartialEq)]
pub struct ParamMap {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Channels per pixel (the config's `param_channels`, 64).
    pub channels: usize,
    /// `height · width · channels` values, pixel-major.
    pub data: Vec<f32>,
}

/// An RGB image, HWC, linear radiance `R = π f_r cos θi` (DESIGN §3).
#[derive(Debug, Clone, PartialEq)]
pub struct Rgb {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// `height · width · 3` values.
    pub data: Vec<f32>,
}
