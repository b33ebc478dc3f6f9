//! `nam-ggx` — two things in one crate: the analytic GGX SVBRDF reference of the nam project
//! (DESIGN.md §3, §7, §8) and nam's small imaging library. They share the radiance convention
//! and the surface frame, and both sit below every other crate, so they stay together rather
//! than split into a reference crate and an imaging crate.
//!
//! **The GGX reference** (ground truth for training, evaluation and `nam-cli render-ggx`):
//! - [`brdf`]: pointwise GGX, generic over `f32`/`f64` ([`Float`]).
//! - [`mod@render`]: a whole map for one light and viewer (rayon).
//! - [`maps`]: SVBRDF parameter maps and the 4-panel / separate-file formats.
//! - [`protocol`]: seeded Reflect / Identity / Hemisphere samplers.
//!
//! **The imaging library** (used by the facade's photos, the CLI's outputs and the
//! evaluation's images; it knows nothing about GGX):
//! - [`imageio`]: a plain RGB buffer ([`RgbImage`]) and PNG/JPEG/EXR encode/decode.
//! - [`color`]: log compression, sRGB and gamma curves, the display transform.
//!
//! **Shared by both, and by the networks:**
//! - [`geometry`]: pixel positions, the capture camera, per-pixel ωi/ωo/ωh: the one home of
//!   the surface frame, which the networks (`nam-model`) use in f32.
//! - [`vec3`], [`float`]: the small vector type and the `f32`/`f64` abstraction.
//!
//! Radiance convention everywhere: `R = π · f_r(ωi, ωo) · max(0, n·ωi)` for a unit light
//! without inverse-square falloff; frames are the surface frame (material on z = 0 spanning
//! [−1, 1]², z up). This crate knows nothing about the networks.

#![forbid(unsafe_code)]

pub mod brdf;
pub mod color;
mod error;
pub mod float;
pub mod geometry;
pub mod imageio;
pub mod maps;
pub mod protocol;
pub mod render;
pub mod vec3;

pub use brdf::{GgxPoint, eval};
pub use error::{GgxError, Result};
pub use float::Float;
pub use geometry::{CAPTURE_DISTANCE, Directions, Light, View};
/// The scene vector type: light and viewer positions and directions ([`Light`], [`View`], [`LightView`]).
pub use glam::DVec3;
pub use imageio::RgbImage;
pub use maps::{MapFiles, SvbrdfMaps};
pub use protocol::{LightView, Protocol, ProtocolSampler, SplitMix64, sample_protocol};
pub use render::{RenderSettings, render};
pub use vec3::{Vec3, Vec3d, Vec3f};
