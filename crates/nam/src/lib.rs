//! # nam — neural appearance models for renderers and engines
//!
//! From a single flash photo of a near-planar material, `M_est` (a U-Net) estimates a
//! 64-channel latent parameter map; `M_render`, a small per-pixel MLP, then evaluates the
//! material's reflectance for any light and view (Idema & Peers, *Neural Appearance Modeling
//! From Single Images*). This crate is the embedding API; `nam-cli` is the command line.
//!
//! ```
//! use nam::{DVec3, NeuralModel, Photo, Scene, relight};
//! use nam::geometry::{Light, View};
//! # fn main() -> Result<(), nam::NamError> {
//! let model = NeuralModel::embedded()?;                  // or NeuralModel::from_file(..)
//! // A 16×16 grey photo as linear RGB (normally: Photo::load("photo.png")?).
//! let photo = Photo::from_linear_rgb(16, 16, vec![0.3; 16 * 16 * 3])?;
//! let material = model.estimate(&photo)?;               // runs the U-Net once
//! let (light, view) = (DVec3::new(1.0, 1.0, 4.0), DVec3::new(0.0, 0.0, 4.0));
//! let scene = Scene::new(Light::Point(light), View::Point(view));
//! let image = relight(&model, &material, &scene)?;      // any number of times
//! assert_eq!((image.width(), image.height()), (16, 16));
//! assert!(image.data().iter().all(|v| v.is_finite() && *v >= 0.0));
//! # Ok(()) }
//! ```
//!
//! Conventions (DESIGN.md §3): the material lies on z = 0 spanning [−1, 1]², z up; the photo
//! is taken from (0, 0, d), d = 1/tan 14° (a 28° camera; [`Photo::with_fov`] declares
//! another, d = [`geometry::capture_distance`]`(fov)`), with a co-located flash; radiance is
//! `R = π f_r cos θi` for a unit light without inverse-square falloff.
//!
//! Renderers use [`NeuralBrdf`]: batched `eval` (f_r·cos θi or f_r), cosine `sample` and
//! `pdf`, with [`ShadingFrame`] for arbitrarily oriented surfaces.

#![forbid(unsafe_code)]

mod brdf;
mod error;
mod frame;
mod io;
mod material;
mod model;
mod photo;
mod relight;
mod sampling;

pub use brdf::{BrdfQuery, BrdfSample, GPU_MIN_QUERIES, NeuralBrdf};
pub use error::{NamError, Result};
pub use frame::ShadingFrame;
pub use io::{MAX_MATERIAL_FILE_BYTES, MAX_MODEL_FILE_BYTES, Staged, commit_all, write_atomic};
pub use material::NeuralMaterial;
#[cfg(feature = "default-model")]
pub use model::EMBEDDED_MODEL;
pub use model::{BackendKind, COST_PROBE_SIDE, EstimateCost, NeuralModel};
pub use nam_model::input::network_input;
pub use nam_model::{Precision as CpuPrecision, ProbeTime, Roi, Source};
pub use photo::{MAX_PHOTO_SIDE, Photo};
pub use relight::{Scene, relight, relight_roi};
pub use sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere};

/// The vector types of the API, from glam: `DVec3` for scene positions and directions
/// ([`Scene`], [`geometry::Light`]), `Vec3`/`Vec2` for the renderer-side BRDF queries.
pub use glam::{self, DVec3, Vec2, Vec3};
pub use nam_ggx::RgbImage;
/// Scene geometry, the one home of the surface frame (re-exported from `nam-ggx`).
pub use nam_ggx::geometry;
/// The GPU backend (re-exported from `nam-gpu`).
#[cfg(feature = "gpu")]
pub use nam_gpu;
/// Model configuration and weights (re-exported from `nam-weights`).
pub use nam_weights::{LinearLayer, LogMode, ModelConfig, RenderLayers, Weights};
/// The wgpu version the GPU backend is built against (engines pass its `Device`/`Queue`).
#[cfg(feature = "gpu")]
pub use wgpu;
