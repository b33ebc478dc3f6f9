//! `nam-cli report`: error against run time on the held-out procedural set (DESIGN.md §8) —
//! every available configuration plus the printout, diffuse-fit and GGX baselines, as a
//! Markdown table and a PNG scatter plot in one folder.

use crate::progress;
use anyhow::{Context, Result, bail};
use nam_eval::heldout;
use nam_eval::report::{self, ReportMeta, ReportOptions};
use nam_eval::runner::{self, PairCounts};
use std::path::PathBuf;
use std::time::Instant;

/// Measure error (log-L1, log-RMSE, FLIP, SSIM) against time (ms per estimate, ms per relit
/// megapixel) for every model, backend, precision and specialisation available here, next to
/// the printout, diffuse-fit and GGX baselines; write report.md and error_vs_time.png.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  nam-cli report -o docs/report
  nam-cli report -o /tmp/r --materials 2 --size 16 --hemisphere 8 --no-gpu")]
pub struct Args {
    /// Output folder (created if missing): report.md and error_vs_time.png.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Folder of held-out 4-panel SVBRDF PNGs (material_*.png).
    #[arg(long, default_value = "assets/heldout")]
    pub heldout: PathBuf,
    /// Number of held-out materials.
    #[arg(long, default_value_t = 8)]
    pub materials: usize,
    /// Image side in pixels (the files' side or a divisor of it).
    #[arg(long, default_value_t = 64)]
    pub size: usize,
    /// Reflect pairs per material.
    #[arg(long, default_value_t = 8)]
    pub reflect: usize,
    /// Identity pairs per material.
    #[arg(long, default_value_t = 1)]
    pub identity: usize,
    /// Hemisphere pairs per material.
    #[arg(long, default_value_t = 128)]
    pub hemisphere: usize,
    /// Model files (comma-separated), one block of rows each.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "models/default.safetensors,models/tiny.safetensors"
    )]
    pub models: Vec<PathBuf>,
    /// Materials for the slow rows (CPU reference, GPU).
    #[arg(long, default_value_t = 1)]
    pub subset_materials: usize,
    /// Reflect,Identity,Hemisphere pairs per material for the slow rows (a prefix of the
    /// full rows' pairs).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 1, 4])]
    pub subset_pairs: Vec<usize>,
    /// FLIP viewing condition in pixels per degree.
    #[arg(long, default_value_t = nam_eval::flip::DEFAULT_PIXELS_PER_DEGREE)]
    pub ppd: f64,
    /// Leave out the GPU rows (otherwise they run on the default wgpu adapter, if any).
    #[arg(long)]
    pub no_gpu: bool,
}

pub fn run(args: &Args) -> Result<()> {
    if args.materials == 0 || args.size == 0 {
        bail!("--materials and --size must be at least 1");
    }
    if !(args.ppd.is_finite() && args.ppd > 0.0) {
        bail!("--ppd must be a positive number, got {}", args.ppd);
    }
    for m in &args.models {
        if !m.is_file() {
            bail!("model file {} not found", m.display());
        }
    }
    let [sr, si, sh] = args.subset_pairs[..] else {
        bail!("--subset-pairs takes three numbers R,I,H");
    };
    let opts = ReportOptions {
        models: args.models.clone(),
        materials: args.materials,
        pairs: PairCounts {
            reflect: args.reflect,
            identity: args.identity,
            hemisphere: args.hemisphere,
        },
        subset_materials: args.subset_materials,
        subset_pairs: PairCounts {
            reflect: sr,
            identity: si,
            hemisphere: sh,
        },
        gpu: !args.no_gpu,
    };
    let t0 = Instant::now();
    let materials = heldout::load(&args.heldout, args.materials, args.size)
        .with_context(|| format!("loading the held-out set {}", args.heldout.display()))?;
    let gpu = if args.no_gpu {
        None
    } else {
        nam_eval::methods::request_gpu()
    };
    let gpu_name = gpu.as_ref().map(nam_eval::methods::describe_gpu);
    let entries = report::entries(&opts);
    let total = runner::total_steps(&materials, &entries);
    let bar = progress::bar(total, "report: relights", 10.0);
    let res = runner::run(&materials, &entries, gpu.as_ref(), args.ppd, &mut |k| {
        bar.inc(k)
    })
    .context("running the evaluation")?;
    bar.finish_and_clear();
    let command = std::iter::once("nam-cli".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    let meta = ReportMeta {
        command,
        threads: nam_eval::cpu_threads(),
        gpu: gpu_name,
        heldout: format!(
            "{}, {}",
            args.heldout.display(),
            materials
                .first()
                .zip(materials.last())
                .map(|(a, b)| format!("{}..{}", a.name, b.name))
                .unwrap_or_default()
        ),
    };
    let (md, png) = report::write(&args.output, &res, &meta)
        .with_context(|| format!("writing the report to {}", args.output.display()))?;
    for sk in &res.skipped {
        eprintln!("skipped {}: {}", sk.entry.label, sk.reason);
    }
    println!(
        "wrote {} and {} ({} rows, {:.1} s)",
        md.display(),
        png.display(),
        res.results.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
