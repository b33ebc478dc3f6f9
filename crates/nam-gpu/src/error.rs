//! The error type of this crate.

/// Everything that can go wrong on the GPU path.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// The model file was rejected (missing tensor, wrong shape, bad config).
    #[error("weights: {0}")]
    Weights(#[from] nam_weights::WeightsError),
    /// The device was created without a feature this request needs.
    #[error("the device lacks {feature} (needed for {needed_for})")]
    MissingFeature {
        /// The wgpu feature name.
        feature: &'static str,
        /// What asked for it.
        needed_for: &'static str,
    },
    /// Shader module or pipeline creation failed validation on this device.
    #[error("pipeline `{kernel}` failed: {message}")]
    Pipeline {
        /// Kernel family and entry point.
        kernel: String,
        /// The validation message of wgpu.
        message: String,
    },
    /// A submission, allocation or bind-group creation was rejected by the device.
    #[error("GPU error during {during}: {message}")]
    Device {
        /// The operation that failed.
        during: &'static str,
        /// The message of wgpu.
        message: String,
    },
    /// Mapping a buffer for readback failed.
    #[error("readback failed: {0}")]
    Readback(String),
    /// A caller-provided slice has the wrong length.
    #[error("{what}: expected {expected} values, got {got}")]
    InputLength {
        /// Which argument.
        what: &'static str,
        /// Expected element count.
        expected: usize,
        /// Given element count.
        got: usize,
    },
    /// A size the kernels cannot handle (zero, or too large for the device limits).
    #[error("{what}: {reason}")]
    Size {
        /// Which size.
        what: &'static str,
        /// Why it is rejected.
        reason: String,
    },
    /// The model's architecture is outside what this backend implements.
    #[error("unsupported model: {0}")]
    Unsupported(String),
}

/// `Result` with [`GpuError`].
pub type Result<T, E = GpuError> = std::result::Result<T, E>;
