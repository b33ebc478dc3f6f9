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
    /// An input holds NaN or infinity (outputs would be NaN).
    #[error("{what}: non-finite value at flat index {index}")]
    NonFinite {
        /// Which argument.
        what: &'static str,
        /// Flat index of the first offending value.
        index: usize,
    },
    /// A `.nam` param-map file is malformed.
    #[error("{file}: invalid param map: {reason}")]
    ParamFile {
        /// Source label.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// The requested code path needs CPU features this machine lacks.
    #[error("unsupported on this CPU: {0}")]
    Unsupported(&'static str),
    /// A light or view position at or below the surface plane z = 0.
    #[error("light and view must be above the surface (z > 0)")]
    BelowSurface,
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

pub(crate) fn check_finite(what: &'static str, v: &[f32]) -> Result<()> {
    match v.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(index) => Err(ModelError::NonFinite { what, index }),
    }
}
