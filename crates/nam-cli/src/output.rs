//! Writing result images: format by extension, atomic replacement.
//!
//! - `.png`: 8-bit, sRGB-encoded (IEC 61966-2-1) after clamping linear values to [0, 1].
//! - `.exr`: linear f32 RGB, values as computed (HDR preserved).
//!
//! Files are written to a temporary file in the destination directory and renamed over the
//! destination only when complete, so a failed or interrupted run never leaves a partial file.

use anyhow::{Context, Result, bail};
use nam_ggx::RgbImage;
use nam_ggx::color::srgb_encode;
use nam_ggx::imageio::{PngDepth, encode_exr, encode_png};
use std::path::{Path, PathBuf};

/// Output image format, chosen by the file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputFormat {
    /// 8-bit sRGB PNG (clamped).
    Png,
    /// Linear f32 OpenEXR.
    Exr,
}

impl OutputFormat {
    /// The format named by `path`'s extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("png") => Ok(Self::Png),
            Some("exr") => Ok(Self::Exr),
            _ => bail!(
                "{}: output must end in .png (8-bit sRGB) or .exr (linear f32)",
                path.display()
            ),
        }
    }
}

/// Checks, before any expensive work, that `path` has a supported extension and that its
/// directory exists. Returns the format.
pub fn check_output_path(path: &Path) -> Result<OutputFormat> {
    let format = OutputFormat::from_path(path)?;
    check_output_dir(path)?;
    Ok(format)
}

/// Checks that the directory `path` would be written into exists.
pub fn check_output_dir(path: &Path) -> Result<()> {
    let dir = parent_dir(path);
    if !dir.is_dir() {
        bail!(
            "{}: output directory {} does not exist",
            path.display(),
            dir.display()
        );
    }
    Ok(())
}

/// Where a path points, for comparing files: the canonical path of an existing file, else the
/// canonical directory joined with the file name (the directory is checked to exist first).
fn identity(path: &Path) -> PathBuf {
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    let dir = parent_dir(path);
    let dir = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    path.file_name().map_or(dir.clone(), |name| dir.join(name))
}

/// Refuses, before any work, a run whose outputs would overwrite one of its inputs or each
/// other (canonical paths compared: `./p.png`, `p.png` and a symlink to it are one file).
pub fn check_distinct(inputs: &[&Path], outputs: &[PathBuf]) -> Result<()> {
    let inputs: Vec<(PathBuf, &Path)> = inputs.iter().map(|p| (identity(p), *p)).collect();
    let mut seen: Vec<(PathBuf, &Path)> = Vec::with_capacity(outputs.len());
    for out in outputs {
        let id = identity(out);
        if let Some((_, input)) = inputs.iter().find(|(i, _)| *i == id) {
            bail!(
                "{}: this output is the input {}; choose another output name (nothing was written)",
                out.display(),
                input.display()
            );
        }
        if let Some((_, other)) = seen.iter().find(|(s, _)| *s == id) {
            bail!(
                "{}: two outputs of this run are the same file ({} and {}); choose distinct names",
                out.display(),
                other.display(),
                out.display()
            );
        }
        seen.push((id, out));
    }
    Ok(())
}

/// Writes a linear RGB image (the renderer's radiance) to `path` atomically, encoded per
/// [`OutputFormat`].
pub fn write_linear_rgb(path: &Path, img: &RgbImage<f32>) -> Result<()> {
    write_atomic(path, &encode_linear_rgb(path, img)?)
}

/// Like [`write_linear_rgb`], but staged: moved into place by [`nam::commit_all`] with the
/// other outputs of the run, or removed if the run fails.
pub fn stage_linear_rgb(path: &Path, img: &RgbImage<f32>) -> Result<nam::Staged> {
    Ok(nam::Staged::write(path, &encode_linear_rgb(path, img)?)?)
}

fn encode_linear_rgb(path: &Path, img: &RgbImage<f32>) -> Result<Vec<u8>> {
    match OutputFormat::from_path(path)? {
        OutputFormat::Png => encode_png(&img.map(srgb_encode), PngDepth::Eight),
        OutputFormat::Exr => encode_exr(img),
    }
    .with_context(|| format!("encoding {}", path.display()))
}

/// Writes `bytes` to `path` atomically (see [`nam::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    Ok(nam::write_atomic(path, bytes)?)
}

fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}
