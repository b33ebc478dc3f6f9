//! `nam-cli relight`: estimate a photo's neural material and render it under a new light.

use crate::args::{parse_non_negative, parse_vec3};
use crate::output::{check_output_path, write_linear_rgb};
use anyhow::{Context, Result, bail};
use nam::geometry::{Light, View};
use nam::{NeuralModel, Photo, Scene, Vec3d, relight};
use std::path::PathBuf;

/// Relight a flash photo (PNG/JPEG sRGB, EXR linear) with the embedded or a given model.
///
/// Example: `nam-cli relight photo.png --light 1,1,4 --view 0,0,4 -o out.png`
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input photo, square (use --crop otherwise), taken from (0,0,d) with a co-located flash.
    pub photo: PathBuf,
    /// Point-light position x,y,z (surface frame; z > 0).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light: [f64; 3],
    /// Viewer position x,y,z (surface frame; z > 0).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, default_value = "0,0,4.010781")]
    pub view: [f64; 3],
    /// Light intensity multiplier.
    #[arg(long, value_parser = parse_non_negative, default_value = "1")]
    pub intensity: f64,
    /// Apply inverse-square falloff d²/|light − p|².
    #[arg(long)]
    pub falloff: bool,
    /// Centre-crop a non-square photo to a square.
    #[arg(long)]
    pub crop: bool,
    /// Model file (default: the embedded model).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Output image (.png sRGB 8-bit or .exr linear).
    #[arg(short, long)]
    pub output: PathBuf,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<()> {
    check_output_path(&args.output)?;
    if args.light[2] <= 0.0 || args.view[2] <= 0.0 {
        bail!("light and view must be above the surface (z > 0)");
    }
    let model = match &args.model {
        Some(p) => NeuralModel::from_file(p)?,
        None => NeuralModel::embedded()?,
    };
    let photo = if args.crop {
        Photo::load_cropped(&args.photo)
    } else {
        Photo::load(&args.photo)
    }
    .with_context(|| format!("reading {}", args.photo.display()))?;
    let material = model.estimate(&photo)?;
    let mut scene = Scene::new(
        Light::Point(Vec3d::from_array(args.light)),
        View::Point(Vec3d::from_array(args.view)),
    );
    scene.intensity = args.intensity;
    scene.falloff = args.falloff;
    let img = relight(&model, &material, &scene)?;
    write_linear_rgb(&args.output, &img)?;
    Ok(())
}
