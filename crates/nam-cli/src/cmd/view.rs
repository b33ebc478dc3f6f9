//! `nam-cli view`: an interactive relighting viewer served to a local browser (`viewer/`).

use crate::backend::ModelArgs;
use crate::cmd::relight::{PhotoArgs, load_material, load_photo};
use crate::viewer::{self, Source, ViewerConfig};
use anyhow::{Result, bail};
use nam::NeuralModel;
use std::path::{Path, PathBuf};

/// Serve an interactive viewer on 127.0.0.1: drag the light over the material, drop a photo.
///
/// The page (embedded in this binary, nothing fetched from the internet) shows the photo and
/// the relit material side by side. Frames are rendered by this process on the CPU (or an
/// attached GPU), or in the browser with the project's WGSL shaders when it exposes WebGPU.
/// Only this machine can connect, and the API answers only requests carrying the random
/// token printed in the URL.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  nam-cli view assets/example_photo.png --open
  nam-cli view photo.nam --port 8080
  nam-cli view                      (starts empty: drop a photo on the page)")]
pub struct Args {
    /// A flash photo (.png/.jpg/.exr) or a saved material (.nam); none: drop one on the page.
    pub input: Option<PathBuf>,
    /// TCP port on 127.0.0.1 (0: any free port).
    #[arg(long, default_value_t = 0)]
    pub port: u16,
    /// Open the URL in the default browser (xdg-open / open / start).
    #[arg(long)]
    pub open: bool,
    /// Photos (given here or dropped on the page) larger than N×N are resampled to N×N, so
    /// that frames stay interactive (a 256² point-light frame takes ~0.3 s on 2 CPU cores, a
    /// directional one ~0.03 s; time grows with the pixel count).
    #[arg(long, value_name = "N", default_value_t = viewer::DEFAULT_MAX_SIDE)]
    pub max_side: usize,
    #[command(flatten)]
    pub photo: PhotoArgs,
    #[command(flatten)]
    pub model: ModelArgs,
}

/// Runs the subcommand: loads the model (and the input), binds, prints the URL, serves until
/// interrupted.
pub fn run(args: &Args) -> Result<()> {
    if !(viewer::MIN_SIDE..=nam::MAX_PHOTO_SIDE).contains(&args.max_side) {
        bail!(
            "--max-side {} must be between {} and {}",
            args.max_side,
            viewer::MIN_SIDE,
            nam::MAX_PHOTO_SIDE
        );
    }
    let model = args.model.load()?;
    let source = match &args.input {
        None => None,
        Some(path) => Some(load_source(&model, path, args)?),
    };
    let config = ViewerConfig {
        port: args.port,
        max_side: args.max_side,
        keep_clipped: args.photo.keep_clipped,
    };
    let server = viewer::Server::bind(model, source, &config)?;
    let url = server.url();
    println!("nam viewer: {url}");
    eprintln!("(serving on 127.0.0.1 only; Ctrl-C stops it)");
    if args.open {
        open_browser(&url);
    }
    server.serve()
}

/// The material to view: a `.nam` as saved, a photo (fitted to `--max-side`) estimated.
fn load_source(model: &NeuralModel, path: &Path, args: &Args) -> Result<Source> {
    let name = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into(),
    );
    let is_nam = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nam"));
    let (material, photo) = if is_nam {
        (load_material(model, path, &args.photo)?, None)
    } else {
        let mut photo = load_photo(model, path, &args.photo)?;
        if args.photo.resize.is_none() {
            photo = viewer::fit(photo, args.max_side)?;
        }
        (args.photo.estimate(model, &photo)?, Some(photo))
    };
    Ok(Source::new(name, material, photo, args.photo.fov))
}

/// Asks the desktop to open `url`; a failure is a note, not an error (the URL is printed).
fn open_browser(url: &str) {
    let opener = if cfg!(target_os = "macos") {
        "open"
    } else if cfg!(target_os = "windows") {
        "explorer"
    } else {
        "xdg-open"
    };
    if let Err(e) = std::process::Command::new(opener)
        .arg(url)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        eprintln!("note: could not run {opener} ({e}); open the URL above by hand");
    }
}
