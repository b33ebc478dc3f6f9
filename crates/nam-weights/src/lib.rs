//! Loading nam model files: safetensors parsing, the typed [`ModelConfig`],
//! validation of every tensor against the architecture, and `f32` access.
//!
//! The file contract is `docs/FORMAT.md`; the architecture is DESIGN.md §4.
//!
//! ```no_run
//! use nam_weights::Weights;
//! # fn main() -> Result<(), nam_weights::WeightsError> {
//! let w = Weights::from_file("models/default.safetensors")?;
//! let c = w.config().width;
//! let stem = w.get("est.stem.weight", &[c, 4, 7, 7])?; // &[f32], row-major
//! let blk = w.scope("est.enc1.0");
//! let gate = blk.get("ha1.gate.weight", &[c, c, 3, 3])?; // "est.enc1.0.ha1.gate.weight"
//! # let _ = (stem, gate); Ok(()) }
//! ```
//!
//! * [`Weights`] — validated model: [`Weights::from_file`], [`Weights::from_bytes`]
//!   (for `include_bytes!`), [`Weights::random`] (seeded, for tests/benches),
//!   [`Weights::get`] / [`Weights::scope`] / [`Scope::get`], [`Weights::tensors`],
//!   [`Weights::to_safetensors_bytes`].
//! * [`expected_tensors`] — the complete `name → shape` list a config implies;
//!   [`ModelConfig::estimate_macs`] and [`ModelConfig::render_macs`] — the multiply-adds of
//!   `M_est` and `M_render` derived from the same layout; [`UNET_MULTIPLE`] — the padding.
//! * [`radiance_from_log`] — the networks' log-space output as radiance.
//! * [`Weights::render_layers`] — `M_render`'s linear layers and activations as every backend
//!   runs them ([`RenderLayers`], [`LinearLayer`]).
//! * [`TensorFile`] — any safetensors file (golden fixtures, `.nam` param maps)
//!   as `f32` tensors plus `__metadata__`, without model validation;
//!   [`write_safetensors`] writes one (F32). Both go through the `safetensors` crate.
//! * [`WeightsError`] — every error names the file, the tensor and expected vs found.
//!
//! Storage dtypes F32, F16, BF16 (and F64, for fixtures) are converted to `f32`.
//! Parsing never panics and never allocates more than the input's size implies.

#![forbid(unsafe_code)]

mod config;
mod error;
mod layout;
mod radiance;
mod render_layers;
mod tensor_file;
mod weights;

pub use config::{LogMode, MAX_WIDTH, ModelConfig, Slopes};
pub use error::{Result, WeightsError};
pub use layout::{DirectionWork, RenderWork, UNET_MULTIPLE, expected_tensors};
pub use radiance::radiance_from_log;
pub use render_layers::{LinearLayer, RenderLayers};
pub use tensor_file::{
    Dtype, MAX_HEADER_BYTES, StoreAs, Tensor, TensorFile, TensorView, write_safetensors,
    write_safetensors_as, write_safetensors_to,
};
pub use weights::{Scope, SplitMix64, Weights};
