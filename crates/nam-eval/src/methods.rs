//! The evaluated methods: the baselines of `train_py/evaluate.py` (printout, diffuse fit), the
//! GGX ground truth, and the neural model on every backend / precision / specialisation.
//!
//! Each method has two timed steps: **estimate** (once per photo) and **relight** (once per
//! light/view pair). Both return linear radiance in the DESIGN §3 convention.

use crate::error::{EvalError, Result};
use crate::heldout::Material;
use nam::geometry::{CAPTURE_DISTANCE, Light, View, capture_half_z, pixel_position};
use nam::{CpuPrecision, DVec3, NeuralMaterial, NeuralModel, Photo, Scene, relight};
use nam_ggx::{LightView, SvbrdfMaps, render};
use nam_model::reference::{self, Accumulate};
use nam_model::{ParamMap, Source};
use rayon::prelude::*;
use std::path::PathBuf;

/// Which implementation runs the networks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// `nam_model::reference`: readable loops, f32 accumulation (rayon over pixels in relight).
    CpuReference,
    /// `nam_model`'s fast path (blocked GEMM, fused tiles, rayon) through the `nam` facade.
    CpuFast,
    /// `nam-gpu` (wgpu compute) through the `nam` facade.
    Gpu,
}

impl Backend {
    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Backend::CpuReference => "CPU reference",
            Backend::CpuFast => "CPU fast",
            Backend::Gpu => "GPU",
        }
    }
}

/// Arithmetic precision of the networks (weights are stored as f16 in the shipped files and
/// widened on load).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// f32 storage and arithmetic.
    F32,
    /// CPU render MLP with bf16 products and f32 sums (`RenderNet::with_bf16`, AVX-512 BF16).
    Bf16,
    /// CPU render MLP with int8 products and i32 sums (`RenderNet::with_int8`, AVX-512 VNNI).
    Int8,
    /// GPU f16 storage, f32 arithmetic (`nam_gpu::Precision::F16`, `SHADER_F16`).
    F16,
}

impl Precision {
    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
            Precision::Int8 => "int8",
            Precision::F16 => "f16",
        }
    }
}

/// A scene specialisation (DESIGN §9).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Specialisation {
    /// The general pipeline: a point light and a perspective viewer, per-pixel directions.
    General,
    /// Directional light and orthographic viewer (the facade's constant-direction plan on
    /// the CPU fast path or the GPU): ND_enc runs once per image. The protocol's point light and viewer are replaced by their
    /// directions from the material centre, so its error includes that approximation.
    Directional,
    /// The protocol's point light and viewer with ND_enc on a coarser pixel grid
    /// (`RenderNet::relight_interpolated`, CPU fast path): ωi and ωo turn at most this many
    /// millidegrees between neighbouring grid nodes.
    Interpolated(u32),
}

impl Specialisation {
    /// Short name for tables.
    pub fn name(self) -> String {
        match self {
            Specialisation::General => "—".into(),
            Specialisation::Directional => "directional (ND_enc once)".into(),
            Specialisation::Interpolated(md) => {
                format!(
                    "interpolated ND_enc (≤ {}° per node)",
                    f64::from(md) / 1000.0
                )
            }
        }
    }
}

/// One neural configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct NeuralConfig {
    /// The model file (`.safetensors`).
    pub model: PathBuf,
    /// Backend.
    pub backend: Backend,
    /// Precision.
    pub precision: Precision,
    /// Specialisation.
    pub specialisation: Specialisation,
}

/// What to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub enum MethodSpec {
    /// The LDR input photo reused for every light and view.
    Printout,
    /// Per-pixel Lambertian albedo from the photo (`photo / cos θ_capture`, n = +z), times the
    /// new `max(ωi.z, 0)`.
    DiffuseFit,
    /// The analytic GGX render of the true maps (error 0 by construction; its time is the
    /// cost of the analytic render).
    GgxTruth,
    /// The neural model.
    Neural(NeuralConfig),
}

impl MethodSpec {
    /// Backend column of the table.
    pub fn backend_name(&self) -> &'static str {
        match self {
            MethodSpec::Neural(c) => c.backend.name(),
            _ => "CPU",
        }
    }

    /// Precision column of the table.
    pub fn precision_name(&self) -> &'static str {
        match self {
            MethodSpec::Neural(c) => c.precision.name(),
            MethodSpec::GgxTruth => "f32",
            _ => "f32",
        }
    }

    /// Specialisation column of the table.
    pub fn specialisation_name(&self) -> String {
        match self {
            MethodSpec::Neural(c) => c.specialisation.name(),
            _ => "—".into(),
        }
    }

    /// Whether the method has an estimate step (the GGX truth starts from the true maps).
    pub fn has_estimate(&self) -> bool {
        !matches!(self, MethodSpec::GgxTruth)
    }
}

/// A GPU device shared by the GPU configurations.
#[cfg(feature = "gpu")]
pub type GpuDevice = nam::nam_gpu::DeviceHandles;

/// A GPU device (this build has no GPU support: the `gpu` feature is off).
#[cfg(not(feature = "gpu"))]
#[derive(Debug)]
pub struct GpuDevice {
    _none: (),
}

/// The default wgpu adapter's device (with `SHADER_F16` when offered), or `None` (reason on
/// stderr) when there is none or the build lacks the `gpu` feature.
pub fn request_gpu() -> Option<GpuDevice> {
    #[cfg(feature = "gpu")]
    {
        nam::nam_gpu::request_device(true)
    }
    #[cfg(not(feature = "gpu"))]
    {
        eprintln!("nam-eval: built without the gpu feature; no GPU rows");
        None
    }
}

/// Adapter name and backend, flagged when it is a CPU emulation (lavapipe/llvmpipe).
pub fn describe_gpu(dev: &GpuDevice) -> String {
    #[cfg(feature = "gpu")]
    {
        let emulated = if dev.info.device_type == wgpu::DeviceType::Cpu {
            ", CPU-emulated: lavapipe timings"
        } else {
            ""
        };
        format!("{} ({:?}{emulated})", dev.info.name, dev.info.backend)
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = dev;
        "none".into()
    }
}

#[cfg(feature = "gpu")]
fn attach_gpu(
    model: &mut NeuralModel,
    precision: Precision,
    gpu: Option<&GpuDevice>,
) -> Result<()> {
    let dev = gpu.ok_or_else(|| EvalError::Option("no GPU adapter".into()))?;
    let p = if precision == Precision::F16 {
        if !dev.device.features().contains(wgpu::Features::SHADER_F16) {
            return Err(EvalError::Option(format!(
                "adapter {:?} has no SHADER_F16",
                dev.info.name
            )));
        }
        nam::nam_gpu::Precision::F16
    } else {
        nam::nam_gpu::Precision::F32
    };
    model.attach_gpu(&dev.device, &dev.queue, dev.info.device_type, p)?;
    Ok(())
}

#[cfg(not(feature = "gpu"))]
fn attach_gpu(_: &mut NeuralModel, _: Precision, _: Option<&GpuDevice>) -> Result<()> {
    Err(EvalError::Option("built without the gpu feature".into()))
}

/// A method ready to run (model loaded, GPU attached).
#[derive(Debug)]
pub struct Prepared {
    spec: MethodSpec,
    model: Option<NeuralModel>,
    width: usize,
}

/// What an estimate produced.
#[derive(Debug)]
pub enum Estimate {
    /// The photo (printout).
    Photo(Vec<f32>),
    /// Lambertian albedo per pixel (diffuse fit).
    Albedo(Vec<f32>),
    /// The true maps (GGX).
    Maps(SvbrdfMaps),
    /// A neural material from the facade (CPU fast / GPU).
    Neural(NeuralMaterial),
    /// A param map from the reference U-Net.
    Reference(ParamMap),
}

impl Prepared {
    /// Loads the model and sets up the backend. `Err` with a reason when the configuration
    /// is unavailable here (e.g. no AVX-512 BF16, no GPU, no f16 shader support).
    pub fn new(spec: &MethodSpec, gpu: Option<&GpuDevice>) -> Result<Self> {
        let MethodSpec::Neural(cfg) = spec else {
            return Ok(Self {
                spec: spec.clone(),
                model: None,
                width: 0,
            });
        };
        let mut model = NeuralModel::from_file(&cfg.model)?;
        match (cfg.backend, cfg.precision) {
            (Backend::CpuReference | Backend::CpuFast, Precision::F32) => {}
            // The facade's CPU estimate and relight follow the precision (`set_cpu_precision`):
            // the row's error is the reduced estimate's and relight's together.
            (Backend::CpuFast, Precision::Bf16) => model.set_cpu_precision(CpuPrecision::Bf16)?,
            (Backend::CpuFast, Precision::Int8) => model.set_cpu_precision(CpuPrecision::Int8)?,
            (Backend::Gpu, Precision::F32 | Precision::F16) => {
                attach_gpu(&mut model, cfg.precision, gpu)?;
            }
            (b, p) => {
                return Err(EvalError::Option(format!(
                    "{} has no {} path",
                    b.name(),
                    p.name()
                )));
            }
        }
        if matches!(cfg.specialisation, Specialisation::Interpolated(_))
            && cfg.backend != Backend::CpuFast
        {
            return Err(EvalError::Option(
                "the interpolated specialisation runs on the CPU fast path".into(),
            ));
        }
        if cfg.specialisation == Specialisation::Directional && cfg.backend == Backend::CpuReference
        {
            return Err(EvalError::Option(
                "the directional specialisation runs on the CPU fast path and the GPU".into(),
            ));
        }
        let width = model.config().width;
        Ok(Self {
            spec: spec.clone(),
            model: Some(model),
            width,
        })
    }

    /// The specification.
    pub fn spec(&self) -> &MethodSpec {
        &self.spec
    }

    /// U-Net width `C` of the model (0 for non-neural methods).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Estimates from the material's photo (the GGX truth takes the true maps).
    pub fn estimate(&self, m: &Material) -> Result<Estimate> {
        let side = m.side();
        match (&self.spec, &self.model) {
            (MethodSpec::Printout, _) => Ok(Estimate::Photo(m.photo.clone())),
            (MethodSpec::DiffuseFit, _) => {
                let mut albedo = m.photo.clone();
                for (p, px) in albedo.chunks_exact_mut(3).enumerate() {
                    let c = capture_half_z(p / side, p % side, side, side, CAPTURE_DISTANCE) as f32;
                    for v in px {
                        *v /= c;
                    }
                }
                Ok(Estimate::Albedo(albedo))
            }
            (MethodSpec::GgxTruth, _) => Ok(Estimate::Maps(m.maps.clone())),
            (MethodSpec::Neural(cfg), Some(model)) => {
                let photo = Photo::from_linear_rgb(side, side, m.photo.clone())?;
                if cfg.backend == Backend::CpuReference {
                    let input = photo.network_input(model.config().log_mode)?;
                    let map =
                        reference::estimate(model.weights(), &input, side, side, Accumulate::F32)?;
                    Ok(Estimate::Reference(map))
                } else {
                    Ok(Estimate::Neural(model.estimate(&photo)?))
                }
            }
            (MethodSpec::Neural(_), None) => Err(EvalError::Option("model not loaded".into())),
        }
    }

    /// Relights an estimate for one light/view pair: linear RGB, HWC.
    pub fn relight(&self, est: &Estimate, side: usize, lv: &LightView) -> Result<Vec<f32>> {
        let scene = Scene::new(Light::Point(lv.light), View::Point(lv.view));
        let to32 = |v: DVec3| v.as_vec3().to_array();
        match est {
            Estimate::Photo(p) => Ok(p.clone()),
            Estimate::Albedo(a) => {
                let light = Source::Point(to32(lv.light));
                let mut out = a.clone();
                for (p, px) in out.chunks_exact_mut(3).enumerate() {
                    let wi = light.direction_from(pixel_position(p / side, p % side, side, side));
                    let cos = wi.z.max(0.0);
                    for v in px {
                        *v *= cos;
                    }
                }
                Ok(out)
            }
            Estimate::Maps(maps) => Ok(render::<f32>(maps, &scene)?.into_vec()),
            Estimate::Neural(mat) => {
                let model = self
                    .model
                    .as_ref()
                    .ok_or_else(|| EvalError::Option("model not loaded".into()))?;
                let directional = matches!(
                    &self.spec,
                    MethodSpec::Neural(c) if c.specialisation == Specialisation::Directional
                );
                let net = &model.cpu().render;
                if let MethodSpec::Neural(NeuralConfig {
                    specialisation: Specialisation::Interpolated(md),
                    ..
                }) = &self.spec
                {
                    // The facade's CPU network, in the row's precision.
                    let angle = (*md as f32 / 1000.0).to_radians();
                    let rgb = net.relight_interpolated(
                        mat.params(),
                        to32(lv.light),
                        to32(lv.view),
                        angle,
                    )?;
                    return Ok(rgb.data);
                }
                if directional {
                    // The point light and viewer seen from the origin, as a directional light
                    // and an orthographic view: the facade's constant-direction plan.
                    let wi = lv.light.try_normalize().unwrap_or(DVec3::Z);
                    let wo = lv.view.try_normalize().unwrap_or(DVec3::Z);
                    let far = Scene::new(Light::Directional(wi), View::Orthographic(wo));
                    Ok(relight(model, mat, &far)?.into_vec())
                } else {
                    Ok(relight(model, mat, &scene)?.into_vec())
                }
            }
            Estimate::Reference(map) => {
                let model = self
                    .model
                    .as_ref()
                    .ok_or_else(|| EvalError::Option("model not loaded".into()))?;
                let (l, v) = (Source::Point(to32(lv.light)), Source::Point(to32(lv.view)));
                let c = map.channels;
                let px: Result<Vec<[f32; 3]>> = (0..side * side)
                    .into_par_iter()
                    .map(|p| {
                        let pos = pixel_position(p / side, p % side, side, side);
                        let t = reference::render(
                            model.weights(),
                            &map.data[p * c..(p + 1) * c],
                            l.direction_from(pos).to_array(),
                            v.direction_from(pos).to_array(),
                            Accumulate::F32,
                        )?;
                        Ok(t.radiance)
                    })
                    .collect();
                Ok(px?.into_iter().flatten().collect())
            }
        }
    }
}
