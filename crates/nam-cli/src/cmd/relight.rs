//! `nam-cli relight`: render a photo's (or a saved material's) neural material under new
//! lights — one frame, or a sweep written as numbered frames, a contact sheet and a GIF.

use crate::args::{parse_fov, parse_non_negative, parse_vec3};
use crate::backend::ModelArgs;
use crate::output::{check_distinct, check_output_dir, check_output_path, stage_linear_rgb};
use crate::progress;
use crate::sweep::{LightSpec, contact_sheet, encode_gif, expand, frame_path, parse_light_spec};
use anyhow::{Context, Result, bail};
use nam::geometry::{CAPTURE_FOV_DEG, Light, View, capture_distance, capture_position};
use nam::{DVec3, LogMode, NeuralMaterial, NeuralModel, Photo, Scene, relight};
use nam_model::input::LDR_CLAMP;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Relight a flash photo (PNG/JPEG sRGB, EXR linear) or a saved material (.nam).
///
/// Coordinates are the surface frame: the material spans [−1,1]² on z = 0, z up, the photo
/// was taken from (0,0,d) with a co-located flash, d = 1/tan(fov/2) (4.01 for the default
/// --fov 28). Several --light values (or
/// orbit:N[,elevation°[,distance]]) write numbered frames OUT_000.png, OUT_001.png, …
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  nam-cli relight photo.png --light 1,1,4 -o relit.png
  nam-cli relight photo.png --light orbit:24 -o frames/relit.png --gif relit.gif --sheet sheet.png
  nam-cli estimate photo.png -o photo.nam && nam-cli relight photo.nam --light 0,2,3 -o a.exr
  nam-cli relight photo.png --directional --light 0.3,0.2,1 --orthographic --view 0,0,1 -o d.png")]
pub struct Args {
    /// Input: a square flash photo (.png/.jpg sRGB, .exr linear) or a material saved by
    /// `nam-cli estimate` (.nam; skips the estimator).
    pub input: PathBuf,
    /// Light position x,y,z (z > 0); repeat for a sweep, or orbit:N[,elevation°[,distance]]
    /// (default elevation 45°, distance d: the capture camera's).
    #[arg(long, required = true, value_parser = parse_light_spec, allow_hyphen_values = true)]
    pub light: Vec<LightSpec>,
    /// Treat --light values as directions towards a distant light (normalised).
    #[arg(long)]
    pub directional: bool,
    /// Viewer position x,y,z (z > 0) [default: the capture camera, 0,0,d]
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub view: Option<[f64; 3]>,
    /// Treat --view as the direction of an orthographic viewer.
    #[arg(long)]
    pub orthographic: bool,
    /// Light intensity multiplier.
    #[arg(long, value_parser = parse_non_negative, default_value = "1")]
    pub intensity: f64,
    /// Apply inverse-square falloff d²/|light − p|² (point lights).
    #[arg(long)]
    pub falloff: bool,
    #[command(flatten)]
    pub photo: PhotoArgs,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Output image (.png sRGB 8-bit or .exr linear); numbered per frame for sweeps.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write all frames as one contact-sheet image (.png or .exr).
    #[arg(long, value_name = "FILE")]
    pub sheet: Option<PathBuf>,
    /// Also write all frames as a looping animated GIF.
    #[arg(long, value_name = "FILE")]
    pub gif: Option<PathBuf>,
    /// GIF frame delay in milliseconds.
    #[arg(long, default_value_t = 80)]
    pub gif_delay: u32,
    /// Faster, approximate point-light relights on the CPU: ND_enc only on a grid of pixels
    /// whose light and view directions differ by at most DEG degrees, interpolated in between
    /// (4–7× faster at 256² for 0.5–2°; errors per bound in docs/report/report.md); 0: exact.
    /// CPU only: an attached GPU renders exactly.
    #[arg(long, value_name = "DEG", value_parser = parse_non_negative)]
    pub interpolate: Option<f64>,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<()> {
    check_output_path(&args.output)?;
    if let Some(sheet) = &args.sheet {
        check_output_path(sheet)?;
    }
    if let Some(gif) = &args.gif {
        check_gif_path(gif)?;
    }
    let lights = expand(&args.light, capture_distance(args.photo.fov))?;
    let scenes: Vec<Scene> = lights
        .iter()
        .map(|&l| scene(args, l))
        .collect::<Result<_>>()?;
    let mut outputs: Vec<PathBuf> = (0..scenes.len())
        .map(|k| frame_path(&args.output, k, scenes.len()))
        .collect();
    outputs.extend(args.sheet.iter().chain(&args.gif).cloned());
    let inputs: Vec<&Path> = std::iter::once(args.input.as_path())
        .chain(args.model.model.as_deref())
        .collect();
    check_distinct(&inputs, &outputs)?;
    let mut model = args.model.load()?;
    model.set_nd_interpolation(args.interpolate.filter(|&a| a > 0.0))?;
    let material = load_material(&model, &args.input, &args.photo)?;

    let (h, _) = material.size();
    let started = Instant::now();
    let bar = progress::bar(
        scenes.len() as u64,
        "relighting",
        scenes.len() as f64 * seconds_per_frame(h),
    );
    // Every output is staged next to its destination and moved into place only when all of
    // them are written: a run that fails (disk full at frame 2, a bad --sheet) leaves none.
    let mut staged = Vec::with_capacity(outputs.len());
    let mut frames = Vec::with_capacity(scenes.len());
    for (k, scene) in scenes.iter().enumerate() {
        let img = relight(&model, &material, scene)?;
        staged.push(stage_linear_rgb(&outputs[k], &img)?);
        if args.sheet.is_some() || args.gif.is_some() {
            frames.push(img);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let Some(sheet) = &args.sheet {
        staged.push(stage_linear_rgb(sheet, &contact_sheet(&frames)?)?);
    }
    if let Some(gif) = &args.gif {
        staged.push(nam::Staged::write(
            gif,
            &encode_gif(&frames, args.gif_delay)?,
        )?);
    }
    nam::commit_all(staged)?;
    if scenes.len() > 1 {
        eprintln!(
            "wrote {} frames in {:.1} s: {} … {}",
            scenes.len(),
            started.elapsed().as_secs_f64(),
            frame_path(&args.output, 0, scenes.len()).display(),
            frame_path(&args.output, scenes.len() - 1, scenes.len()).display()
        );
    }
    Ok(())
}

/// The scene of one frame of this run.
fn scene(args: &Args, light: [f64; 3]) -> Result<Scene> {
    let view = match args.view {
        Some(view) => view,
        None => capture_position(capture_distance(args.photo.fov)).to_array(),
    };
    make_scene(
        (light, args.directional),
        (view, args.orthographic),
        (args.intensity, args.falloff),
    )
}

/// A scene from a light (position, or direction when `.1`) and a viewer (position, or
/// orthographic direction when `.1`), surface frame; lights and viewers on or below the
/// surface are errors here (the library would render them black). `(intensity, falloff)`:
/// see [`Scene`].
pub fn make_scene(
    (light, directional): ([f64; 3], bool),
    (view, orthographic): ([f64; 3], bool),
    (intensity, falloff): (f64, bool),
) -> Result<Scene> {
    if light[2] <= 0.0 {
        bail!(
            "light {light:?} is not above the surface: z must be > 0 (the material lies on z = 0)"
        );
    }
    if view[2] <= 0.0 {
        bail!("view {view:?} is not above the surface: z must be > 0 (the material lies on z = 0)");
    }
    let (l, v) = (DVec3::from_array(light), DVec3::from_array(view));
    let mut scene = Scene::new(
        if directional {
            Light::Directional(l)
        } else {
            Light::Point(l)
        },
        if orthographic {
            View::Orthographic(v)
        } else {
            View::Point(v)
        },
    );
    scene.intensity = intensity;
    scene.falloff = falloff;
    scene.validate()?;
    Ok(scene)
}

/// How a photo is brought to the network's square input.
#[derive(Debug, Clone, clap::Args)]
pub struct PhotoArgs {
    /// Centre-crop a non-square photo to a square (otherwise non-square photos are an error).
    #[arg(long)]
    pub crop: bool,
    /// Resample the (square or cropped) photo to N×N pixels in linear light before
    /// estimating, e.g. to relight a large photo faster (at most 4096).
    #[arg(long, value_name = "N")]
    pub resize: Option<usize>,
    /// The field of view of the camera that took the photo, in degrees (28: the paper's
    /// training geometry; phone photos cropped to a centre square are often 35–50)
    ///
    /// Accepted: 5 to 120. It places the camera and its flash at (0,0,d), d = 1/tan(fov/2),
    /// for the estimator, and, in relight, for the default --view and orbit distance (with a
    /// saved material, only for those).
    #[arg(long, value_name = "DEGREES", value_parser = parse_fov, default_value_t = CAPTURE_FOV_DEG)]
    pub fov: f64,
    /// Keep the network's own params where the photo clipped (a channel at 1.0) instead of
    /// filling them from the pixels around (the default: the network's guess there keeps the
    /// flash highlight baked in, too bright under a moved light).
    #[arg(long)]
    pub keep_clipped: bool,
}

impl PhotoArgs {
    /// Estimates `photo`'s material, filling the clipped pixels' params unless `--keep-clipped`.
    pub fn estimate(&self, model: &NeuralModel, photo: &Photo) -> Result<NeuralMaterial> {
        Ok(model.estimate_with(photo, !self.keep_clipped)?)
    }
}

/// Share of saturated pixels above which `relight`/`estimate` print a note: more than the
/// flash highlight of a typical capture (training captures: median 3.9%, the bundled example
/// photo 3.5%; the real photos of ../shared have 0–23%).
const SATURATED_NOTE_ABOVE: f64 = 0.05;

/// A photo is estimated (U-Net); a `.nam` file is loaded and checked against the model.
pub fn load_material(model: &NeuralModel, input: &Path, how: &PhotoArgs) -> Result<NeuralMaterial> {
    let is_nam = input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nam"));
    if is_nam {
        if how.crop || how.resize.is_some() || how.keep_clipped {
            bail!("--crop, --resize and --keep-clipped apply to photos, not to a saved material");
        }
        let material = NeuralMaterial::load(input)?;
        material.check_model(model).with_context(|| {
            format!(
                "{} was estimated by another model; pass that model with --model",
                input.display()
            )
        })?;
        return Ok(material);
    }
    let photo = load_photo(model, input, how)?;
    crate::forecast::note_estimate_cost(model, photo.side())?;
    how.estimate(model, &photo)
}

/// Reads a photo as `how` says (crop, resize, field of view), printing notes on what the
/// estimator will make of it: an alpha channel, an EXIF rotation, many saturated pixels.
pub fn load_photo(model: &NeuralModel, input: &Path, how: &PhotoArgs) -> Result<Photo> {
    if has_alpha(input) {
        eprintln!(
            "note: {} has an alpha channel; it is ignored (the photo's RGB is used as is)",
            input.display()
        );
    }
    if let Some(turn) = exif_orientation(input) {
        eprintln!(
            "note: {} is stored sideways or mirrored; applied its EXIF orientation ({turn})",
            input.display()
        );
    }
    let photo = Photo::load_resized(input, how.crop, how.resize)
        .with_context(|| format!("reading {}", input.display()))?
        .with_fov(how.fov)?;
    if model.config().log_mode == LogMode::Ldr {
        let blown = photo.saturated_fraction(LDR_CLAMP);
        if blown > SATURATED_NOTE_ABOVE {
            eprintln!(
                "note: {:.1}% of the pixels of {} are saturated (a channel at 1.0, pure white to \
                 this LDR model); what lies under a blown-out highlight is not in the photo: its \
                 params are filled from the pixels around it (a darker exposure helps)",
                100.0 * blown,
                input.display()
            );
        }
    }
    Ok(photo)
}

/// Whether an image file declares an alpha channel (read from its header only; `false`
/// when the header cannot be read: decoding reports that error properly).
fn has_alpha(path: &Path) -> bool {
    use image::ImageDecoder;
    image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .ok()
        .and_then(|r| r.into_decoder().ok())
        .is_some_and(|d| d.color_type().has_alpha())
}

/// The EXIF orientation the loader applies, in words (read from the header only, like
/// [`has_alpha`]; `None` without one).
fn exif_orientation(path: &Path) -> Option<&'static str> {
    use image::ImageDecoder;
    let mut decoder = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .ok()
        .and_then(|r| r.into_decoder().ok())?;
    nam_ggx::imageio::describe_orientation(decoder.orientation().ok()?)
}

fn check_gif_path(path: &Path) -> Result<()> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gif"))
    {
        bail!("{}: --gif output must end in .gif", path.display());
    }
    check_output_dir(path)
}

/// Rough CPU cost of one relit frame, to decide whether a progress bar is worth showing.
fn seconds_per_frame(side: usize) -> f64 {
    (side * side) as f64 / (256.0 * 256.0) * 0.4
}
