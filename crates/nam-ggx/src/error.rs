//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in `nam-ggx`. File errors carry the path.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GgxError {
    /// Reading or writing a file failed at the OS level.
    // Not a `#[source]`: the message already contains it, so `{:#}` chains don't repeat it.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
    /// A file exists but could not be decoded (truncated, corrupt, unsupported channels).
    #[error("{path}: cannot decode image: {reason}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// The decoder's message.
        reason: String,
    },
    /// An image could not be encoded.
    #[error("{path}: cannot encode image: {reason}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// The encoder's message.
        reason: String,
    },
    /// The file extension names no supported format.
    #[error("{path}: unsupported image format (expected .png, .jpg/.jpeg or .exr)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// A content error inside a named file.
    #[error("{path}: {inner}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What was wrong with its content.
        inner: Box<GgxError>,
    },
    /// A 4-panel SVBRDF image whose width is not 4× its height.
    #[error(
        "4-panel SVBRDF image must be 4·H wide (diffuse | specular | roughness | normal), got {width}×{height} (W×H)"
    )]
    PanelLayout {
        /// Image width in pixels.
        width: usize,
        /// Image height in pixels.
        height: usize,
    },
    /// An image or map with zero pixels.
    #[error("{what} is empty (0 pixels)")]
    Empty {
        /// Which map or image.
        what: &'static str,
    },
    /// Buffer length or map size disagrees with the declared size.
    #[error("{what}: expected {expected} values, got {got}")]
    SizeMismatch {
        /// Which map or buffer.
        what: &'static str,
        /// Expected number of values.
        expected: usize,
        /// Actual number of values.
        got: usize,
    },
    /// Separate map files with different pixel sizes.
    #[error("{what} is {got_h}×{got_w} (H×W), but the diffuse map is {want_h}×{want_w}")]
    MapSize {
        /// Which map.
        what: &'static str,
        /// Its height.
        got_h: usize,
        /// Its width.
        got_w: usize,
        /// The expected height.
        want_h: usize,
        /// The expected width.
        want_w: usize,
    },
    /// NaN or ±∞ in a map.
    #[error("{what} has a non-finite value (NaN or Inf) at row {row}, col {col}")]
    NonFinite {
        /// Which map.
        what: &'static str,
        /// Pixel row.
        row: usize,
        /// Pixel column.
        col: usize,
    },
    /// A negative reflectance or roughness.
    #[error("{what} has a negative value {value} at row {row}, col {col}")]
    Negative {
        /// Which map.
        what: &'static str,
        /// The value.
        value: f32,
        /// Pixel row.
        row: usize,
        /// Pixel column.
        col: usize,
    },
    /// A reflectance or roughness above 1 (maps hold values in [0, 1]).
    #[error(
        "{what} has the value {value:e} at row {row}, col {col}, above 1 (reflectances and roughness lie in [0, 1])"
    )]
    AboveOne {
        /// Which map.
        what: &'static str,
        /// The value.
        value: f32,
        /// Pixel row.
        row: usize,
        /// Pixel column.
        col: usize,
    },
    /// A normal-map texel that decodes to the zero vector.
    #[error("normal map has a zero-length normal at row {row}, col {col}")]
    DegenerateNormal {
        /// Pixel row.
        row: usize,
        /// Pixel column.
        col: usize,
    },
    /// An argument outside its documented domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl GgxError {
    /// Attaches a file path to a content error.
    pub(crate) fn in_file(self, path: &std::path::Path) -> Self {
        match self {
            e @ (GgxError::Io { .. }
            | GgxError::Decode { .. }
            | GgxError::Encode { .. }
            | GgxError::UnsupportedFormat { .. }
            | GgxError::InFile { .. }) => e,
            e => GgxError::InFile {
                path: path.to_path_buf(),
                inner: Box::new(e),
            },
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = GgxError> = std::result::Result<T, E>;
