//! The error type of this crate.

use std::path::PathBuf;

/// Everything that can go wrong while reading, validating or querying weights.
///
/// Every variant names the source (`file`: a path, or the label given to
/// [`crate::TensorFile::from_bytes`]) and, where one is involved, the tensor.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The path that was opened.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The safetensors container is malformed (length prefix, JSON header, offsets).
    #[error("{file}: malformed safetensors: {reason}")]
    Format {
        /// Source label.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// A tensor is stored with a dtype this reader does not convert.
    #[error("{file}: tensor `{tensor}` has dtype {dtype}; expected F32, F16, BF16 or F64")]
    UnsupportedDtype {
        /// Source label.
        file: String,
        /// Tensor name.
        tensor: String,
        /// The dtype string found in the header.
        dtype: String,
    },
    /// `__metadata__["config"]` is missing, not JSON, or describes an unsupported architecture.
    #[error("{file}: invalid model config: {reason}")]
    Config {
        /// Source label.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// A tensor that the config's architecture needs is absent.
    #[error("{file}: missing tensor `{tensor}` (expected shape {expected:?})")]
    MissingTensor {
        /// Source label.
        file: String,
        /// Tensor name.
        tensor: String,
        /// Shape the architecture requires.
        expected: Vec<usize>,
    },
    /// The file holds a tensor the config's architecture does not have.
    #[error("{file}: unexpected tensor `{tensor}` with shape {found:?}")]
    UnexpectedTensor {
        /// Source label.
        file: String,
        /// Tensor name.
        tensor: String,
        /// Its shape in the file.
        found: Vec<usize>,
    },
    /// A tensor exists but its shape differs from the expected one.
    #[error("{file}: tensor `{tensor}` has shape {found:?}, expected {expected:?}")]
    ShapeMismatch {
        /// Source label.
        file: String,
        /// Tensor name.
        tensor: String,
        /// Shape the caller or architecture requires.
        expected: Vec<usize>,
        /// Shape stored in the file.
        found: Vec<usize>,
    },
    /// The `safetensors` crate refused to serialise (a header over its 100 MB limit).
    #[error("cannot write safetensors: {0}")]
    Serialize(String),
    /// A tensor holds NaN or infinite values.
    #[error("{file}: tensor `{tensor}` contains a non-finite value at flat index {index}")]
    NonFinite {
        /// Source label.
        file: String,
        /// Tensor name.
        tensor: String,
        /// Flat (row-major) index of the first offending element.
        index: usize,
    },
}

/// Shorthand for results of this crate.
pub type Result<T, E = WeightsError> = std::result::Result<T, E>;
