//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong while evaluating.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EvalError {
    /// Image sizes that do not fit together (or an empty image).
    #[error("image size: {0}")]
    Size(String),
    /// The held-out set could not be read or is unusable.
    #[error("held-out set {path}: {reason}")]
    HeldOut {
        /// The folder or file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A file could not be written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
    /// The plot could not be encoded.
    #[error("plot: {0}")]
    Plot(String),
    /// An invalid option value.
    #[error("invalid option: {0}")]
    Option(String),
    /// From the GGX reference.
    #[error(transparent)]
    Ggx(#[from] nam_ggx::GgxError),
    /// From the networks or the facade.
    #[error(transparent)]
    Nam(#[from] nam::NamError),
    /// From the CPU networks.
    #[error(transparent)]
    Model(#[from] nam_model::ModelError),
}

/// `Result` with [`EvalError`].
pub type Result<T, E = EvalError> = std::result::Result<T, E>;
