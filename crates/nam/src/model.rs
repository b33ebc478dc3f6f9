//! [`NeuralModel`]: validated weights plus the networks on the CPU and, optionally, a GPU.

use crate::error::{NamError, Result};
use crate::material::NeuralMaterial;
use crate::photo::Photo;
use nam_model::input::LDR_CLAMP;
use nam_model::{Model, ParamMap, Precision as CpuPrecision, ProbeTime, UNet};
use nam_weights::{LogMode, ModelConfig, Weights};
use sha2::{Digest, Sha256};
use std::path::Path;

/// The shipped default model (f16, BatchNorm folded), embedded at build time.
#[cfg(feature = "default-model")]
pub const EMBEDDED_MODEL: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../models/default.safetensors"
));

/// Which backend runs the networks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BackendKind {
    /// `nam-model`'s fast CPU path (rayon's current pool).
    Cpu,
    /// `nam-gpu` on the device given to [`NeuralModel::attach_gpu`].
    Gpu,
}

/// What estimating a photo will cost, forecast before running it
/// ([`NeuralModel::estimate_cost`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimateCost {
    /// Heap bytes held at the peak: the network input, the U-Net's working set and the param
    /// map it returns (on a GPU: the input and the map; device memory is not counted).
    pub peak_bytes: u64,
    /// Seconds on this machine: a [`COST_PROBE_SIDE`]² estimate timed now, scaled by the pixel
    /// count (the U-Net's work is linear in it). `None` on a GPU.
    pub seconds: Option<f64>,
}

/// Side of the estimate [`NeuralModel::estimate_cost`] times (≈ 30 ms for C = 8 on 2 cores).
pub const COST_PROBE_SIDE: usize = 128;

/// A loaded neural appearance model: `M_est` and `M_render`.
///
/// Load it once, estimate materials from photos ([`NeuralModel::estimate`]) and relight or
/// evaluate them ([`crate::relight`], [`crate::NeuralBrdf`]).
///
/// ```
/// # fn main() -> Result<(), nam::NamError> {
/// let model = nam::NeuralModel::embedded()?;
/// assert_eq!(model.config().param_channels, 64);
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct NeuralModel {
    weights: Weights,
    cpu: Model,
    fingerprint: String,
    /// Bound (radians) of the CPU relight's interpolated ND_enc, when enabled.
    nd_interpolation: Option<f32>,
    #[cfg(feature = "gpu")]
    gpu: Option<std::sync::Mutex<nam_gpu::GpuNetwork>>,
}

impl NeuralModel {
    /// The model embedded in this build (`models/default.safetensors`).
    #[cfg(feature = "default-model")]
    pub fn embedded() -> Result<Self> {
        Self::from_bytes(EMBEDDED_MODEL, "embedded default model")
    }

    /// Reads and validates a model file (`.safetensors`, docs/FORMAT.md).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::io::read(path, crate::io::MAX_MODEL_FILE_BYTES, "a model file")?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses and validates a model held in memory; `label` names it in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        let weights = Weights::from_bytes(bytes, label)?;
        let fingerprint = hex_sha256(bytes);
        Self::build(weights, fingerprint)
    }

    /// Wraps already validated weights (e.g. [`Weights::random`] in tests).
    pub fn from_weights(weights: Weights) -> Result<Self> {
        let fingerprint = hex_sha256(&weights.to_safetensors_bytes()?);
        Self::build(weights, fingerprint)
    }

    fn build(weights: Weights, fingerprint: String) -> Result<Self> {
        let cpu = Model::new(&weights)?;
        Ok(Self {
            weights,
            cpu,
            fingerprint,
            nd_interpolation: None,
            #[cfg(feature = "gpu")]
            gpu: None,
        })
    }

    /// The architecture (width, log mode, layer sizes).
    pub fn config(&self) -> &ModelConfig {
        self.weights.config()
    }

    /// The validated weights (f32).
    pub fn weights(&self) -> &Weights {
        &self.weights
    }

    /// SHA-256 of the model file (hex); param maps record it so a material is never rendered
    /// with a model that did not estimate it.
    pub fn fingerprint(&self) -> &str {
        &self.fingerprint
    }

    /// The CPU networks (always available; engines use them for per-query evaluation).
    pub fn cpu(&self) -> &Model {
        &self.cpu
    }

    /// Number of stored parameters (weights), all layers.
    pub fn parameter_count(&self) -> usize {
        self.weights
            .tensors()
            .values()
            .map(|t| t.data().len())
            .sum()
    }

    /// Lets [`crate::relight`] on the CPU evaluate ND_enc only on a grid of pixels whose light
    /// and view directions turn at most `max_angle_deg` degrees between neighbouring nodes,
    /// interpolating its features in between (`RenderNet::relight_interpolated`; point lights
    /// and perspective viewers, whole images): 4–7× faster at 256² for 0.5–2°, an
    /// approximation whose error against the exact path the report (`nam-cli report`) lists
    /// per bound. `None`, the default, keeps the exact per-pixel pipeline. Errors on a bound
    /// that is not a positive finite angle below 90°, leaving the setting unchanged.
    pub fn set_nd_interpolation(&mut self, max_angle_deg: Option<f64>) -> Result<()> {
        if let Some(a) = max_angle_deg
            && !(a.is_finite() && a > 0.0 && a < 90.0)
        {
            return Err(crate::NamError::Query(format!(
                "ND_enc interpolation bound {a}° is not an angle in (0°, 90°)"
            )));
        }
        self.nd_interpolation = max_angle_deg.map(|a| a.to_radians() as f32);
        Ok(())
    }

    /// The ND_enc interpolation bound in radians, when enabled ([`Self::set_nd_interpolation`]).
    pub fn nd_interpolation(&self) -> Option<f32> {
        self.nd_interpolation
    }

    /// Switches the products of the CPU renderer (ND_enc and the render layers after the first;
    /// sums stay f32, or exact i32 for int8) to `precision`: bf16 (≈2× faster where the CPU has
    /// AVX-512 BF16 or AMX; log-space differences of order 1e-3), int8 (AVX-512 VNNI) or back to
    /// f32. The CPU estimate follows ([`unet_for`]): bf16 products in its convolutions for bf16,
    /// f32 for f32 and int8 (the U-Net has no int8 path). Errors,
    /// leaving the model unchanged, when the CPU lacks the instructions; the report
    /// (`nam-cli report`) gives each precision's error, estimate included.
    pub fn set_cpu_precision(&mut self, precision: CpuPrecision) -> Result<()> {
        let render = self.cpu.render.clone().with_precision(precision)?;
        self.cpu.unet = unet_for(self.cpu.unet.clone(), precision)?;
        self.cpu.render = render;
        Ok(())
    }

    /// Switches the CPU renderer to the fastest precision this CPU runs (and the estimate to the
    /// faster of f32 and bf16, timed on a small photo), chosen by timing one tile of the general
    /// path in each ([`RenderNet::fastest`](nam_model::RenderNet::fastest),
    /// a few milliseconds); returns the probe times. f32 stays when it is the fastest.
    pub fn use_fastest_cpu_precision(&mut self) -> Result<Vec<ProbeTime>> {
        let (net, times) = self.cpu.render.clone().fastest()?;
        self.cpu.unet = fastest_unet(self.cpu.unet.clone(), self.config().in_channels)?;
        self.cpu.render = net;
        Ok(times)
    }

    /// The products the CPU renderer computes in ([`Self::set_cpu_precision`]).
    pub fn cpu_precision(&self) -> CpuPrecision {
        self.cpu.render.precision()
    }

    /// Runs estimation, image relighting and large [`NeuralBrdf::eval`](crate::NeuralBrdf::eval)
    /// batches on the caller's wgpu device from now on.
    /// Weights are uploaded once here; pipelines are built lazily on first use.
    /// `adapter_type` (`adapter.get_info().device_type`) selects kernel variants. Request
    /// `Features::SHADER_F16` for `Precision::F16`, and on CPU adapters (lavapipe)
    /// `Features::SUBGROUP`, which enables the texture matmul (≈25× the buffer kernel there).
    #[cfg(feature = "gpu")]
    pub fn attach_gpu(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_type: wgpu::DeviceType,
        precision: nam_gpu::Precision,
    ) -> Result<()> {
        let net = nam_gpu::GpuNetwork::new(device, queue, adapter_type, &self.weights, precision)?;
        self.gpu = Some(std::sync::Mutex::new(net));
        Ok(())
    }

    /// The backend [`NeuralModel::estimate`] and [`crate::relight`] use.
    pub fn backend(&self) -> BackendKind {
        #[cfg(feature = "gpu")]
        if self.gpu.is_some() {
            return BackendKind::Gpu;
        }
        BackendKind::Cpu
    }

    /// Runs `f` on the attached GPU network, if any.
    #[cfg(feature = "gpu")]
    pub(crate) fn with_gpu<T>(
        &self,
        f: impl FnOnce(&mut nam_gpu::GpuNetwork) -> Result<T>,
    ) -> Option<Result<T>> {
        let gpu = self.gpu.as_ref()?;
        // A poisoned lock means an earlier call panicked mid-dispatch; the network's buffers
        // hold no state across calls, so reusing it is safe.
        let mut net = gpu
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        Some(f(&mut net))
    }

    /// Forecasts the memory and time of [`Self::estimate`] on a `side × side` photo; on the
    /// CPU it runs one small estimate to time this machine.
    pub fn estimate_cost(&self, side: usize) -> Result<EstimateCost> {
        let cfg = self.config();
        let pixels = (side * side) as u64;
        let io_bytes = 4 * pixels * (cfg.in_channels + cfg.param_channels) as u64;
        if self.backend() == BackendKind::Gpu {
            return Ok(EstimateCost {
                peak_bytes: io_bytes,
                seconds: None,
            });
        }
        let unet = &self.cpu.unet;
        let n = COST_PROBE_SIDE;
        let probe = vec![0.5f32; cfg.in_channels * n * n];
        // The first run warms the thread pool and caches; the second is timed.
        unet.estimate(&probe, n, n)?;
        let started = std::time::Instant::now();
        unet.estimate(&probe, n, n)?;
        let probe_seconds = started.elapsed().as_secs_f64();
        let padded = |s: usize| s.next_multiple_of(nam_weights::UNET_MULTIPLE) as f64;
        Ok(EstimateCost {
            peak_bytes: 4 * pixels * cfg.in_channels as u64 + unet.peak_bytes(side, side),
            seconds: Some(probe_seconds * (padded(side) / padded(n)).powi(2)),
        })
    }

    /// Estimates the neural material of a photo (runs `M_est` once), taken with the photo's
    /// field of view ([`Photo::with_fov`]; 28°, the training geometry, unless declared).
    ///
    /// For an LDR model the params of the pixels the photo clipped (a channel at or above
    /// [`LDR_CLAMP`], pure white to the network, which then sees only that the radiance was at
    /// least 1) are then replaced by an interpolation of the other pixels' params
    /// ([`nam_model::fill_clipped`]): the network's own guess there keeps the flash highlight
    /// baked in (relit more than 2× too bright under a moved light in 30 of the highlight test's
    /// 64 cases, `train_py.highlights`). [`Self::estimate_with`] can keep that guess. HDR
    /// models see the true radiance and are never filled.
    pub fn estimate(&self, photo: &Photo) -> Result<NeuralMaterial> {
        self.estimate_with(photo, true)
    }

    /// As [`Self::estimate`]; `fill_clipped: false` keeps the network's own params where the
    /// photo clipped.
    pub fn estimate_with(&self, photo: &Photo, fill_clipped: bool) -> Result<NeuralMaterial> {
        let mut map = self.network_params(photo)?;
        if fill_clipped && self.config().log_mode == LogMode::Ldr {
            let clipped: Vec<bool> = photo.saturated(LDR_CLAMP).collect();
            nam_model::fill_clipped(&mut map, &clipped)?;
        }
        NeuralMaterial::new(map, self.fingerprint.clone())
    }

    /// The U-Net's param map of `photo`, on the GPU when one is attached.
    fn network_params(&self, photo: &Photo) -> Result<ParamMap> {
        let side = photo.side();
        let input = photo.network_input(self.config().log_mode)?;
        #[cfg(feature = "gpu")]
        if let Some(res) = self.with_gpu(|net| Ok(net.estimate(&input, side, side)?)) {
            return Ok(ParamMap {
                height: side,
                width: side,
                channels: self.config().param_channels,
                data: res?,
            });
        }
        Ok(self.cpu.unet.estimate(&input, side, side)?)
    }
}

fn hex_sha256(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

// The model check lives here, beside the model it reads, so that `material.rs` (the value
// type and its file) does not depend on `model.rs`, which estimates materials.
impl NeuralMaterial {
    /// Errors unless `model` is the model that estimated this material.
    pub fn check_model(&self, model: &NeuralModel) -> Result<()> {
        if self.params().channels != model.config().param_channels {
            return Err(NamError::Params(format!(
                "the material has {} channels per pixel, the model expects {}",
                self.params().channels,
                model.config().param_channels
            )));
        }
        if self.model_fingerprint() != model.fingerprint() {
            return Err(NamError::Params(format!(
                "the material was estimated by model {}…, not by this model {}… \
                 (latent parameters only make sense to the model that produced them)",
                short(self.model_fingerprint()),
                short(model.fingerprint())
            )));
        }
        Ok(())
    }
}

/// The first 12 hex digits of a fingerprint, enough to tell models apart in a message.
fn short(fp: &str) -> &str {
    &fp[..fp.len().min(12)]
}

/// The CPU U-Net for the CPU products `precision`: bf16 for bf16, f32 otherwise (the U-Net has
/// no int8 path).
fn unet_for(unet: UNet, precision: CpuPrecision) -> Result<UNet> {
    Ok(match precision {
        CpuPrecision::Bf16 => unet.with_bf16()?,
        CpuPrecision::F32 | CpuPrecision::Int8 => unet.with_f32(),
    })
}

/// Side of the synthetic photo [`fastest_unet`] times each precision on.
const UNET_PROBE_SIDE: usize = 64;

/// The faster of the f32 and (where the CPU has AVX-512 BF16) bf16 U-Net, by timing one
/// [`UNET_PROBE_SIDE`]² estimate of each after a warm-up run: `vdpbf16ps` is fast on AMD Zen 4
/// and slower than f32 on some Intel Xeons, so this is measured, not assumed.
fn fastest_unet(unet: UNet, in_channels: usize) -> Result<UNet> {
    let f32_net = unet.with_f32();
    if !nam_model::bf16_supported() {
        return Ok(f32_net);
    }
    let bf16_net = f32_net.clone().with_bf16()?;
    let n = UNET_PROBE_SIDE;
    let probe: Vec<f32> = (0..in_channels * n * n)
        .map(|i| (i % 97) as f32 / 97.0)
        .collect();
    let time = |net: &UNet| -> Result<f64> {
        net.estimate(&probe, n, n)?;
        let started = std::time::Instant::now();
        net.estimate(&probe, n, n)?;
        Ok(started.elapsed().as_secs_f64())
    };
    let (t32, t16) = (time(&f32_net)?, time(&bf16_net)?);
    Ok(if t16 < t32 { bf16_net } else { f32_net })
}
