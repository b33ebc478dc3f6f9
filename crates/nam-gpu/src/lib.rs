//! wgpu compute backend of nam: the estimator U-Net `M_est` and the per-pixel `M_render`
//! (positional encoding, ND_enc, render MLP) as WGSL compute shaders (`shaders/`).
//!
//! The `wgpu::Device` and `Queue` are passed in; [`GpuNetwork`] uploads the weights once,
//! builds pipelines lazily (validation failures become [`GpuError`]s through error scopes)
//! and caches per-size execution plans. Storage is f32 or f16 ([`Precision`]); arithmetic
//! and accumulation are f32 in both.
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let weights = nam_weights::Weights::from_file("models/default.safetensors")?;
//! let Some(gpu) = nam_gpu::request_device(false) else { return Ok(()) };
//! let mut net = nam_gpu::GpuNetwork::new(
//!     &gpu.device, &gpu.queue, gpu.info.device_type, &weights, nam_gpu::Precision::F32)?;
//! let (h, w) = (4, 4);
//! let params = net.estimate(&vec![0.0; 4 * h * w], h, w)?; // [h, w, 64]
//! let dirs = vec![0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]; // ωi, ωo, ωh
//! let radiance = net.render(&params[..64], &dirs)?; // [1, 3]
//! # let _ = radiance; Ok(()) }
//! ```

#![forbid(unsafe_code)]

mod context;
mod device;
mod error;
mod network;
mod ops;
mod params;
pub mod probe;
pub mod shaders;
mod weights;

#[cfg(test)]
mod kernel_tests;

pub use context::{GpuContext, MatmulVariant};
pub use device::{DeviceHandles, request_device, skip_without_adapter};
pub use error::{GpuError, Result};
pub use nam_weights::UNET_MULTIPLE;
pub use network::{GpuNetwork, MAX_RENDER_ROWS};
pub use shaders::Precision;
