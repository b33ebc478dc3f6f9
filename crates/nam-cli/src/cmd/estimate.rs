//! `nam-cli estimate`: run the estimator once and save the material (.nam), so later
//! `relight` calls skip the U-Net.

use crate::backend::ModelArgs;
use crate::cmd::relight::{PhotoArgs, load_material};
use anyhow::{Result, bail};
use std::path::PathBuf;
use std::time::Instant;

/// Estimate a photo's neural material and save it as a .nam file (docs/FORMAT.md).
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:
  nam-cli estimate photo.png -o photo.nam
  nam-cli relight photo.nam --light orbit:12 -o frames/photo.png")]
pub struct Args {
    /// Square flash photo (.png/.jpg sRGB, .exr linear), taken from (0,0,d) with a co-located
    /// flash, d = 1/tan(fov/2) (4.01 for the default --fov 28).
    pub photo: PathBuf,
    #[command(flatten)]
    pub photo_args: PhotoArgs,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Output material file (.nam: safetensors with the param map and the model's SHA-256).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Store the params as f32 (twice the file; relighting it is then bit-identical to
    /// relighting the photo) instead of f16 (relights within a log-L1 of ~1e-5).
    #[arg(long)]
    pub exact: bool,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<()> {
    if !args
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nam"))
    {
        bail!("{}: the output must end in .nam", args.output.display());
    }
    crate::output::check_output_dir(&args.output)?;
    let inputs: Vec<&std::path::Path> = std::iter::once(args.photo.as_path())
        .chain(args.model.model.as_deref())
        .collect();
    crate::output::check_distinct(&inputs, std::slice::from_ref(&args.output))?;
    if args
        .photo
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nam"))
    {
        bail!(
            "{}: already a material; estimate takes a photo",
            args.photo.display()
        );
    }
    let model = args.model.load()?;
    let started = Instant::now();
    let material = load_material(&model, &args.photo, &args.photo_args)?;
    let (h, w) = material.size();
    if args.exact {
        material.save_exact(&args.output)?;
    } else {
        material.save(&args.output)?;
    }
    eprintln!(
        "estimated {h}×{w}×{} params in {:.0} ms → {}",
        material.params().channels,
        started.elapsed().as_secs_f64() * 1e3,
        args.output.display()
    );
    Ok(())
}
