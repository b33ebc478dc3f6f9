//! The nam networks on the CPU (no GPU dependency).
//!
//! * [`UNet`] — `M_est`: network input (CHW, 4 × H × W) → [`ParamMap`] (HWC, 64 per pixel).
//! * [`RenderNet`] — `M_render`: per-pixel positional encoding → ND_enc → render
//!   MLP, fused per tile; batch queries ([`RenderNet::render_batch`]), whole
//!   images ([`RenderNet::relight`]) and the separate pieces
//!   ([`RenderNet::encode`], [`RenderNet::nd_enc`], [`RenderNet::render_from_features`]).
//!   Also [`RenderNet::relight_directional`] (same ωi, ωo everywhere: ND_enc
//!   runs once, DESIGN §9), [`RenderNet::with_bf16`] (opt-in bf16 products,
//!   f32 sums, AVX-512 BF16 or AMX; check [`bf16_supported`]) and [`RenderNet::with_int8`]
//!   (opt-in int8 products, i32 sums, AVX-512 VNNI; check [`int8_supported`]).
//! * [`PreparedMaterial`] — [`RenderNet::prepare`] computes the params' part
//!   `W_p·p` of the first render layer once per material; then
//!   [`RenderNet::relight_prepared`] relights any [`Roi`] for point or distant
//!   light and viewer ([`Source`]), and [`RenderNet::render_log_prepared`]
//!   evaluates arbitrary (texel, ωi, ωo) query batches for engines.
//! * [`Model`] — both, built from one [`nam_weights::Weights`].
//! * [`reference`](mod@reference) — readable loops with f32 or f64 accumulation, the yardstick
//!   for the fast path.
//! * [`ParamMap::to_nam_bytes`] / [`ParamMap::from_nam_bytes`] — the `.nam` file.
//! * [`input::network_input`] — photo (linear RGB, HWC) → the 4-channel CHW input;
//!   [`fill_clipped`] — the params of the pixels a photo clipped, filled from the others.
//! * [`geometry`] — pixel positions and per-pixel directions (DESIGN §3), re-exported from
//!   `nam-ggx`, the one home of the surface frame; the networks use it in f32.
//!
//! Conventions: directions are unit vectors in the surface frame (z up);
//! radiance is `R = π·f_r·cos θi` for a unit light without falloff; networks
//! work in `ln(R + 1)`. Threads: rayon's current pool (use `ThreadPool::install`).

#![deny(unsafe_code)]

mod amx;
mod bf16;
mod clip_fill;
mod dense;
pub mod encoding;
mod error;
pub mod input;
mod int8;
mod maps;
mod param_file;
mod prepared;
pub mod reference;
mod render;
mod sgemm;
mod simd;
mod unet;

pub use bf16::{bf16_kernel, bf16_supported};
pub use clip_fill::fill_clipped;
pub use error::{ModelError, Result};
pub use int8::int8_supported;
pub use maps::{ParamMap, Rgb};
pub use nam_ggx::geometry;
pub use nam_weights::radiance_from_log;
pub use prepared::{PreparedMaterial, Roi};
pub use render::{DEFAULT_TILE, Precision, ProbeTime, RenderNet, interpolation_step};
pub use unet::{BF16_PARAM_TOL, MAX_SIDE, UNet};

use nam_weights::Weights;

/// Where a light or the viewer is, in the networks' precision (f32, surface frame):
/// [`geometry::Source`].
pub type Source = geometry::Source<f32>;

/// The complete CPU model: estimator and renderer.
#[derive(Debug, Clone)]
pub struct Model {
    /// `M_est`.
    pub unet: UNet,
    /// `M_render`.
    pub render: RenderNet,
}

impl Model {
    /// Packs validated weights for the fast path.
    pub fn new(weights: &Weights) -> Result<Self> {
        Ok(Self {
            unet: UNet::new(weights)?,
            render: RenderNet::new(weights)?,
        })
    }
}

/// Row-major `c[m×n] = a[m×k] · b[k×n]` with this crate's blocked GEMM on the
/// current rayon pool (exposed for benchmarks and engines).
pub fn matmul(m: usize, n: usize, k: usize, a: &[f32], b: &[f32], c: &mut [f32]) -> Result<()> {
    error::check_len("a", m * k, a.len())?;
    error::check_len("b", k * n, b.len())?;
    error::check_len("c", m * n, c.len())?;
    sgemm::sgemm(
        m,
        n,
        k,
        sgemm::Mat { data: a, ld: k },
        sgemm::Mat { data: b, ld: n },
        c,
        n,
        false,
        rayon::current_num_threads(),
    );
    Ok(())
}

/// Multiply-add rate of this crate's GEMM on an `n×n×n` f32 product using the
/// current rayon pool, in GFLOP/s (2 flops per multiply-add); the best of `reps`.
/// Benchmarks report network throughput against it.
pub fn sgemm_gflops(n: usize, reps: usize) -> f64 {
    let a: Vec<f32> = (0..n * n).map(|i| (i % 7) as f32 * 0.1).collect();
    let b: Vec<f32> = (0..n * n).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut c = vec![0.0f32; n * n];
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t = std::time::Instant::now();
        sgemm::sgemm(
            n,
            n,
            n,
            sgemm::Mat { data: &a, ld: n },
            sgemm::Mat { data: &b, ld: n },
            &mut c,
            n,
            false,
            rayon::current_num_threads(),
        );
        best = best.min(t.elapsed().as_secs_f64());
    }
    2.0 * (n as f64).powi(3) / best / 1e9
}
