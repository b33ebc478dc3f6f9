//! `nam-cli render-ggx`: render a 4-panel GGX SVBRDF file (the analytic reference of
//! `nam-ggx`) for one light and one viewer.

use crate::args::{parse_non_negative, parse_vec3};
use crate::output::{self, OutputFormat};
use crate::progress;
use anyhow::{Context, Result, bail};
use nam_ggx::render::render_with_progress;
use nam_ggx::{DVec3, Light, RenderSettings, RgbImage, SvbrdfMaps, View};
use std::path::PathBuf;
use std::time::Instant;

/// Rough single-thread cost of one GGX pixel, for deciding whether a progress bar is worth it.
const SECONDS_PER_PIXEL_ESTIMATE: f64 = 2e-7;

/// Evaluation precision.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Precision {
    /// Single precision (fast).
    F32,
    /// Double precision (reference).
    F64,
}

/// Arguments of `render-ggx`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Coordinates: the material lies on z = 0 and spans [-1,1]² in x and y; z points up.
The capture camera sits at (0,0,4.0108) (28° field of view).

Input: one image 4·H wide, panels diffuse | specular | roughness | normal. PNG/JPEG diffuse
and specular are gamma 2.2 encoded; EXR values are linear. Normals are stored as (n+1)/2.

Output: .png = 8-bit sRGB of the clamped radiance; .exr = linear f32 radiance
R = π·f_r·cos θi (unit light; times --intensity, and d²/|light−p|² with --falloff).

Examples:
  nam-cli render-ggx assets/example_maps.png --light 1,1,4 --view 0,0,4 -o out.png
  nam-cli render-ggx maps.exr --light -2,0.5,3 --view 0,0,4.0108 --intensity 2 --falloff -o out.exr
  nam-cli render-ggx maps.png --light 1,0,1 --directional-light --view 0,0,1 --orthographic -o out.png")]
pub struct Args {
    /// 4-panel SVBRDF file (.png, .jpg or .exr).
    pub maps: PathBuf,

    /// Light position x,y,z (or direction towards the light with --directional-light); z > 0.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light: [f64; 3],

    /// Viewer position x,y,z (or direction towards the viewer with --orthographic); z > 0.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub view: [f64; 3],

    /// Light intensity multiplying the radiance.
    #[arg(long, value_name = "K", default_value_t = 1.0, value_parser = parse_non_negative,
          allow_hyphen_values = true)]
    pub intensity: f64,

    /// Apply the inverse-square falloff d²/|light − p|² (d = capture distance).
    #[arg(long)]
    pub falloff: bool,

    /// Treat --light as a direction (light at infinity).
    #[arg(long)]
    pub directional_light: bool,

    /// Treat --view as a direction (orthographic viewer).
    #[arg(long)]
    pub orthographic: bool,

    /// Evaluation precision.
    #[arg(long, value_enum, default_value_t = Precision::F32)]
    pub precision: Precision,

    /// Output image (.png: 8-bit sRGB, clamped; .exr: linear f32).
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
}

/// Runs `render-ggx`.
pub fn run(args: &Args) -> Result<()> {
    let format = output::check_output_path(&args.output)?;
    output::check_distinct(&[args.maps.as_path()], std::slice::from_ref(&args.output))?;
    let settings = settings(args)?;
    let maps = SvbrdfMaps::load(&args.maps).context("cannot load the SVBRDF maps")?;

    let start = Instant::now();
    let rows = maps.height() as u64;
    let pixels = (maps.height() * maps.width()) as f64;
    let pb = progress::bar(rows, "render-ggx", pixels * SECONDS_PER_PIXEL_ESTIMATE);
    let tick = || pb.inc(1);
    let img: RgbImage<f32> = match args.precision {
        Precision::F32 => render_with_progress::<f32>(&maps, &settings, &tick)?,
        Precision::F64 => render_with_progress::<f64>(&maps, &settings, &tick)?.cast(),
    };
    pb.finish_and_clear();
    let elapsed = start.elapsed();

    output::write_linear_rgb(&args.output, &img)?;
    let kind = match format {
        OutputFormat::Png => "8-bit sRGB PNG",
        OutputFormat::Exr => "linear f32 EXR",
    };
    eprintln!(
        "rendered {}×{} in {:.1} ms; wrote {} ({kind})",
        maps.width(),
        maps.height(),
        elapsed.as_secs_f64() * 1e3,
        args.output.display()
    );
    Ok(())
}

/// Builds and checks the light/view setup; lights and viewers must be above the surface.
fn settings(args: &Args) -> Result<RenderSettings> {
    let [lx, ly, lz] = args.light;
    let [vx, vy, vz] = args.view;
    if lz <= 0.0 {
        bail!("--light must be above the surface (z > 0), got z = {lz}");
    }
    if vz <= 0.0 {
        bail!("--view must be above the surface (z > 0), got z = {vz}");
    }
    let light = DVec3::new(lx, ly, lz);
    let view = DVec3::new(vx, vy, vz);
    let settings = RenderSettings {
        light: if args.directional_light {
            Light::Directional(light)
        } else {
            Light::Point(light)
        },
        view: if args.orthographic {
            View::Orthographic(view)
        } else {
            View::Point(view)
        },
        intensity: args.intensity,
        falloff: args.falloff,
    };
    settings.validate()?;
    Ok(settings)
}
