//! The facade crate's error type.

use std::path::{Path, PathBuf};

/// Everything that can go wrong in `nam`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NamError {
    /// Reading or decoding an image, or a GGX reference problem.
    #[error(transparent)]
    Image(#[from] nam_ggx::GgxError),
    /// A model or param-map file is unreadable, corrupt or of the wrong architecture.
    #[error(transparent)]
    Weights(#[from] nam_weights::WeightsError),
    /// The CPU network rejected its input.
    #[error(transparent)]
    Model(#[from] nam_model::ModelError),
    /// The GPU backend failed.
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] nam_gpu::GpuError),
    /// An input photo is unusable (size, shape, non-finite values).
    #[error("photo: {0}")]
    Photo(String),
    /// A light/view/query is unusable (below the surface, non-finite, degenerate).
    #[error("{0}")]
    Query(String),
    /// A param map does not belong to this model or is malformed.
    #[error("param map: {0}")]
    Params(String),
    /// A content error inside a named file.
    #[error("{path}: {inner}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What was wrong with its content.
        inner: Box<NamError>,
    },
    /// OS-level I/O on a named file.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
}

impl NamError {
    /// Attaches the file a content error came from (errors that already name one are kept).
    pub(crate) fn in_file(self, path: &Path) -> Self {
        match self {
            e @ (NamError::Image(_)
            | NamError::Weights(_)
            | NamError::InFile { .. }
            | NamError::Io { .. }) => e,
            inner => NamError::InFile {
                path: path.to_path_buf(),
                inner: Box::new(inner),
            },
        }
    }
}

/// `Result` with [`NamError`].
pub type Result<T, E = NamError> = std::result::Result<T, E>;
