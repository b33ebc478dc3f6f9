//! The error type of this crate.

/// Errors of the CPU network: bad weights, or inputs whose sizes do not fit.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Loading or validating weights failed.
    #[error(transparent)]
    Weights(#[from] nam_weights::WeightsError),
    /// An input buffer's length does not match the dimensions given with it.
    #[error("{what}: expected {expected} values, got {found}")]
    Size {
        /// Which argument.
        what: &'static str,
        /// Length implied by the other arguments.
        expected: usize,
        /// Length passed.
        found: usize,
    },
    /// An image dimension is zero or too large.
    #[error("invalid image size {height}×{width}: {reason}")]
    ImageSize {
        /// Rows.
        height: usize,
        /// Columns.
        width: usize,
        /// Why it is rejected.
        reason: &'static str,
    },
}

/// Shorthand for results of this crate.
pub type Result<T, E = ModelError> = std::result::Result<T, E>;

pub(crate) fn check_len(what: &'static str, expected: usize, found: usize) -> Result<()> {
    if expected == found {
        Ok(())
    } else {
        Err(ModelError::Size {
            what,
            expected,
            found,
        })
    }
}
