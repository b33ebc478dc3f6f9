//! The whole network on the device: `estimate` (U-Net) and `render` (ND_enc + render MLP).
//!
//! This file holds the [`GpuNetwork`] itself (uploaded weights, plan caches), its
//! construction and its multiply-add counts; `estimate.rs` records the U-Net plan and
//! `render.rs` the render plans.

use std::collections::HashMap;

use nam_weights::{DirectionWork, ModelConfig, RenderWork, Weights};

use crate::context::{GpuContext, MatmulVariant};
use crate::error::{GpuError, Result};
use crate::shaders::Precision;
use crate::weights::{self, RenderWeights, UnetWeights};

mod estimate;
mod render;

use estimate::EstimatePlan;
use render::{RenderKind, RenderPlan};

/// Most rows of one render submission. Bounds the [rows, 594] activation buffers
/// (~39 MB in f32) well inside the default 128 MiB storage binding; larger batches are tiled.
pub const MAX_RENDER_ROWS: u32 = 16_384;

/// Plans kept per cache (estimate: per padded image size; render: per row count and kind)
/// before the cache is cleared.
const MAX_CACHED_PLANS: usize = 4;

/// The neural material network on a wgpu device: weights uploaded once, pipelines built
/// lazily, per-size execution plans cached.
///
/// Conventions (docs/FORMAT.md): the estimator input is CHW `[in_channels, H, W]` (log RGB +
/// half-vector z); params come back HWC `[H, W, 64]`; render queries are rows of 64 params and
/// 9 direction values `[ωi, ωo, ωh]` (unit vectors, surface frame, z up); radiance is
/// `R = π f_r cosθi` per RGB channel (linear, unit light, no falloff).
#[derive(Debug)]
pub struct GpuNetwork {
    ctx: GpuContext,
    precision: Precision,
    /// The architecture: the multiply-add counts derive from it.
    config: ModelConfig,
    unet: UnetWeights,
    render: RenderWeights,
    estimate_plans: HashMap<(u32, u32), EstimatePlan>,
    render_plans: HashMap<(u32, RenderKind), RenderPlan>,
}

fn to_u32(v: u64, what: &'static str) -> Result<u32> {
    u32::try_from(v).map_err(|_| GpuError::Size {
        what,
        reason: format!("{v} does not fit in 32 bits"),
    })
}

impl GpuNetwork {
    /// Uploads `weights` to the caller's device. `Precision::F16` needs `SHADER_F16`.
    /// `adapter_type` (from `Adapter::get_info().device_type`) selects kernel variants.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_type: wgpu::DeviceType,
        weights: &Weights,
        precision: Precision,
    ) -> Result<Self> {
        let ctx = GpuContext::new(device, queue, adapter_type)?;
        ctx.check_precision(precision)?;
        let unet = weights::upload_unet(&ctx, weights, precision)?;
        let render = weights::upload_render(&ctx, weights, precision)?;
        Ok(Self {
            ctx,
            precision,
            config: weights.config().clone(),
            unet,
            render,
            estimate_plans: HashMap::new(),
            render_plans: HashMap::new(),
        })
    }

    /// The device context (pipelines, queue).
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Switches the kernel variant of the render MLP's matmuls and the U-Net's convolutions
    /// (for comparisons and tests; all compute the same products). `Texture` needs the layer
    /// and convolution textures, uploaded by [`GpuNetwork::new`] only when the context chose
    /// that variant; the others run the U-Net on the buffer convolution kernels.
    pub fn set_matmul_variant(&mut self, variant: MatmulVariant) -> Result<()> {
        let r = &self.render;
        let textures =
            r.nd.iter().chain(&r.mlp).all(|l| l.tex.is_some()) && self.unet.has_conv_textures();
        if variant == MatmulVariant::Texture && !textures {
            return Err(GpuError::Unsupported(
                "texture kernels: this network was built without weight textures".into(),
            ));
        }
        self.ctx.set_matmul_variant(variant);
        self.render_plans.clear();
        self.estimate_plans.clear();
        Ok(())
    }

    /// Multiply-adds of one `estimate` on an `h x w` image (after padding to multiples of
    /// [`UNET_MULTIPLE`](crate::UNET_MULTIPLE)), counting every convolution tap as the CPU and torch do
    /// ([`ModelConfig::estimate_macs`]).
    pub fn estimate_macs(&self, h: usize, w: usize) -> u64 {
        self.config.estimate_macs(h, w)
    }

    /// Multiply-adds of `M_render` per query as stored in the file (l0 and l1 unfolded),
    /// the convention of DESIGN §4 (634,470 for the standard widths).
    pub fn render_macs_per_query(&self) -> u64 {
        self.config.render_macs(RenderWork {
            folded: false,
            prepared: false,
            directions: DirectionWork::PerOutput,
        })
    }

    /// Storage precision of this network.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Multiply-adds per row of [`GpuNetwork::render_directional`]: the render MLP as
    /// uploaded (l0·l1 folded), the shared ND_enc features still multiplied per row, the
    /// one-off ND_enc row not counted.
    pub fn render_directional_macs_per_query(&self) -> u64 {
        self.config.render_macs(RenderWork {
            folded: true,
            prepared: false,
            directions: DirectionWork::FeaturesShared,
        })
    }
}
