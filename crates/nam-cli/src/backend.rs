//! Which model and where it runs: `--model`, `--backend auto|cpu|gpu`,
//! `--precision f32|bf16|int8|fastest|f16`.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use nam::{CpuPrecision, NeuralModel};
use std::path::PathBuf;

/// Where the networks run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// A real GPU (discrete, integrated or virtual) when one exists, else the CPU. CPU
    /// Vulkan adapters such as lavapipe are skipped: the CPU path is faster than them.
    Auto,
    /// The CPU fast path (all cores).
    Cpu,
    /// The first wgpu adapter, whatever its type (lavapipe included); an error when none.
    Gpu,
}

/// The networks' arithmetic (sums in f32, or exact i32 for int8). Named for what runs: the CPU
/// fast path has bf16 products (AVX-512 BF16) and int8 products (AVX-512 VNNI), the GPU f16
/// storage and products (SHADER_F16).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PrecisionArg {
    /// f32 throughout (every backend).
    F32,
    /// bf16 products of the CPU fast path (needs AVX-512 BF16); `--backend auto` then stays on
    /// the CPU.
    Bf16,
    /// int8 products of the CPU fast path (needs AVX-512 VNNI); `--backend auto` then stays on
    /// the CPU.
    Int8,
    /// The fastest of f32, bf16 and int8 on this CPU, measured on one tile at start-up; `--backend
    /// auto` then stays on the CPU.
    Fastest,
    /// f16 storage and products on the GPU (needs SHADER_F16).
    F16,
}

/// Model selection shared by the subcommands that run the networks.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelArgs {
    /// Model file (.safetensors, docs/FORMAT.md); default: the model embedded in this binary.
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// Where the networks run.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Arithmetic of the networks: `bf16` and `int8` run on the CPU (AVX-512 BF16 / VNNI),
    /// `fastest` times them there and keeps the fastest, `f16` runs on the GPU (SHADER_F16); a
    /// precision the backend lacks falls back to f32 with a note.
    #[arg(long, value_enum, default_value_t = PrecisionArg::F32)]
    pub precision: PrecisionArg,
}

impl ModelArgs {
    /// Loads the model and attaches the chosen backend. Prints one line to stderr saying
    /// which backend and precision run (and why, when a request could not be honoured).
    pub fn load(&self) -> Result<NeuralModel> {
        let mut model = match &self.model {
            Some(p) => NeuralModel::from_file(p)
                .with_context(|| format!("loading the model {}", p.display()))?,
            None => NeuralModel::embedded().context("loading the embedded model")?,
        };
        let gpu_allowed = match (self.backend, self.precision) {
            (Backend::Cpu, _)
            | (Backend::Auto, PrecisionArg::Bf16 | PrecisionArg::Int8 | PrecisionArg::Fastest) => {
                false
            }
            (Backend::Gpu | Backend::Auto, _) => true,
        };
        if gpu_allowed && attach_gpu(&mut model, self)? {
            return Ok(model);
        }
        let precision = match self.precision {
            PrecisionArg::F32 => "f32".to_string(),
            PrecisionArg::Bf16 => cpu_precision(&mut model, CpuPrecision::Bf16),
            PrecisionArg::Int8 => cpu_precision(&mut model, CpuPrecision::Int8),
            PrecisionArg::Fastest => {
                let times = model
                    .use_fastest_cpu_precision()
                    .context("timing the CPU precisions")?;
                let probe: Vec<String> = times
                    .iter()
                    .map(|t| format!("{} {:.2} ms", t.precision.name(), t.ms))
                    .collect();
                format!(
                    "{}, the fastest per tile: {}",
                    model.cpu_precision().name(),
                    probe.join(", ")
                )
            }
            PrecisionArg::F16 => {
                eprintln!(
                    "note: --precision f16 runs on a GPU only (the CPU has bf16 and int8: \
                     --precision bf16|int8); computing in f32"
                );
                "f32".to_string()
            }
        };
        eprintln!("backend: CPU ({precision})");
        Ok(model)
    }
}

/// Switches the CPU products to `precision`, or says why not and keeps f32.
fn cpu_precision(model: &mut NeuralModel, precision: CpuPrecision) -> String {
    let name = precision.name();
    match model.set_cpu_precision(precision) {
        Ok(()) => name.to_string(),
        Err(e) => {
            eprintln!("note: --precision {name} unavailable on this CPU ({e}); computing in f32");
            "f32".to_string()
        }
    }
}

/// Attaches a wgpu adapter per `args.backend`; `Ok(false)` when `auto` finds no real GPU.
#[cfg(feature = "gpu")]
fn attach_gpu(model: &mut NeuralModel, args: &ModelArgs) -> Result<bool> {
    use nam::nam_gpu::{Precision, request_device};
    let want_f16 = args.precision == PrecisionArg::F16;
    let Some(gpu) = request_device(want_f16) else {
        if args.backend == Backend::Gpu {
            bail!("--backend gpu: no wgpu adapter (see the message above)");
        }
        return Ok(false);
    };
    let kind = gpu.info.device_type;
    if args.backend == Backend::Auto && kind == nam::wgpu::DeviceType::Cpu {
        return Ok(false);
    }
    let f16 = want_f16
        && gpu
            .device
            .features()
            .contains(nam::wgpu::Features::SHADER_F16);
    if want_f16 && !f16 {
        eprintln!(
            "note: --precision f16 unavailable: adapter {} lacks SHADER_F16; computing in f32",
            gpu.info.name
        );
    }
    if let PrecisionArg::Bf16 | PrecisionArg::Int8 | PrecisionArg::Fastest = args.precision {
        eprintln!(
            "note: --precision {} runs on the CPU only (the GPU has f16); computing in f32",
            args.precision
                .to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_string())
        );
    }
    let precision = if f16 { Precision::F16 } else { Precision::F32 };
    model
        .attach_gpu(&gpu.device, &gpu.queue, kind, precision)
        .with_context(|| format!("setting up the networks on {}", gpu.info.name))?;
    eprintln!(
        "backend: GPU {} ({:?}, {})",
        gpu.info.name,
        gpu.info.backend,
        if f16 { "f16" } else { "f32" }
    );
    Ok(true)
}

/// Without the `gpu` feature only the CPU exists.
#[cfg(not(feature = "gpu"))]
fn attach_gpu(_model: &mut NeuralModel, args: &ModelArgs) -> Result<bool> {
    if args.backend == Backend::Gpu {
        bail!("--backend gpu: this nam-cli was built without the `gpu` feature");
    }
    Ok(false)
}
