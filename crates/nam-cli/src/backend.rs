//! Which model and where it runs: `--model`, `--backend auto|cpu|gpu`, `--f16`.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use nam::NeuralModel;
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

/// Model selection shared by the subcommands that run the networks.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelArgs {
    /// Model file (.safetensors, docs/FORMAT.md); default: the model embedded in this binary.
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// Where the networks run.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Reduced precision with f32 accumulation: f16 storage on the GPU (needs SHADER_F16),
    /// bf16 products on the CPU (needs AVX-512 BF16). Falls back to f32 with a note.
    #[arg(long)]
    pub f16: bool,
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
        if self.backend != Backend::Cpu && attach_gpu(&mut model, self)? {
            return Ok(model);
        }
        let precision = if self.f16 {
            match model.enable_cpu_bf16() {
                Ok(()) => "bf16",
                Err(e) => {
                    eprintln!("note: --f16 ignored on this CPU ({e}); computing in f32");
                    "f32"
                }
            }
        } else {
            "f32"
        };
        eprintln!("backend: CPU ({precision})");
        Ok(model)
    }
}

/// Attaches a wgpu adapter per `args.backend`; `Ok(false)` when `auto` finds no real GPU.
#[cfg(feature = "gpu")]
fn attach_gpu(model: &mut NeuralModel, args: &ModelArgs) -> Result<bool> {
    use nam::nam_gpu::{Precision, request_device};
    let Some(gpu) = request_device(args.f16) else {
        if args.backend == Backend::Gpu {
            bail!("--backend gpu: no wgpu adapter (see the message above)");
        }
        return Ok(false);
    };
    let kind = gpu.info.device_type;
    if args.backend == Backend::Auto && kind == nam::wgpu::DeviceType::Cpu {
        return Ok(false);
    }
    let f16 = args.f16
        && gpu
            .device
            .features()
            .contains(nam::wgpu::Features::SHADER_F16);
    if args.f16 && !f16 {
        eprintln!(
            "note: --f16 ignored: adapter {} lacks SHADER_F16",
            gpu.info.name
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
