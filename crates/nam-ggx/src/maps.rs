//! SVBRDF parameter maps and their file formats.
//!
//! **4-panel file** (MatFusion's layout, DESIGN §3): one image of width `W = 4·H`, panels left
//! to right `diffuse | specular | roughness | normal`, each `H×H`.
//!
//! | map | LDR file (PNG 8/16-bit, JPEG) | EXR file |
//! |---|---|---|
//! | diffuse, specular | pure gamma 2.2: linear = `v^2.2` | linear, stored as is |
//! | roughness | linear, red channel | linear, red channel |
//! | normal | `n = 2v − 1`, renormalised | `n = 2v − 1`, renormalised |
//!
//! So an EXR differs from a PNG only in the missing gamma on diffuse and specular; the
//! normal keeps its `(n+1)/2` encoding in both. The same rules apply to separate map files
//! ([`MapFiles`]), each decided by its own extension.
//!
//! Loading validates: non-empty, consistent sizes, finite values, non-negative reflectance
//! and roughness, non-zero normals. A loaded [`SvbrdfMaps`] therefore always evaluates to
//! finite radiance.

use crate::brdf::GgxPoint;
use crate::color::{gamma_decode, gamma_encode};
use crate::error::{GgxError, Result};
use crate::float::Float;
use crate::imageio::{FileKind, PngDepth, RgbImage, read_rgb, write_rgb};
use crate::vec3::Vec3;
use std::path::{Path, PathBuf};

/// Per-pixel GGX parameters of an `height`×`width` material, row-major, linear values.
#[derive(Debug, Clone, PartialEq)]
pub struct SvbrdfMaps {
    height: usize,
    width: usize,
    diffuse: Vec<[f32; 3]>,
    specular: Vec<[f32; 3]>,
    roughness: Vec<f32>,
    normal: Vec<[f32; 3]>,
}

/// Paths of the four maps stored as separate image files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MapFiles {
    /// Diffuse albedo (RGB).
    pub diffuse: PathBuf,
    /// Specular F0 (RGB).
    pub specular: PathBuf,
    /// Roughness (the red channel is used).
    pub roughness: PathBuf,
    /// Normal map, `(n+1)/2` encoded.
    pub normal: PathBuf,
}

fn check_len(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(GgxError::SizeMismatch {
            what,
            expected,
            got,
        })
    }
}

fn check_value(what: &'static str, v: f32, k: usize, width: usize) -> Result<()> {
    let (row, col) = (k / width, k % width);
    if !v.is_finite() {
        return Err(GgxError::NonFinite { what, row, col });
    }
    if v < 0.0 {
        return Err(GgxError::Negative {
            what,
            value: v,
            row,
            col,
        });
    }
    if v > 1.0 {
        return Err(GgxError::AboveOne {
            what,
            value: v,
            row,
            col,
        });
    }
    Ok(())
}

impl SvbrdfMaps {
    /// Builds maps from linear per-pixel values (row-major, `height·width` entries each).
    ///
    /// Errors on empty size, length mismatch, NaN/Inf anywhere, diffuse/specular/roughness
    /// outside [0, 1] (reflectances and roughness; above 1 an f32 render could overflow), or
    /// a zero normal. Normals are renormalised to unit length.
    pub fn new(
        height: usize,
        width: usize,
        diffuse: Vec<[f32; 3]>,
        specular: Vec<[f32; 3]>,
        roughness: Vec<f32>,
        normal: Vec<[f32; 3]>,
    ) -> Result<Self> {
        if height == 0 || width == 0 {
            return Err(GgxError::Empty {
                what: "SVBRDF maps",
            });
        }
        let n = height * width;
        check_len("diffuse map", n, diffuse.len())?;
        check_len("specular map", n, specular.len())?;
        check_len("roughness map", n, roughness.len())?;
        check_len("normal map", n, normal.len())?;
        for (k, px) in diffuse.iter().enumerate() {
            for &v in px {
                check_value("diffuse map", v, k, width)?;
            }
        }
        for (k, px) in specular.iter().enumerate() {
            for &v in px {
                check_value("specular map", v, k, width)?;
            }
        }
        for (k, &v) in roughness.iter().enumerate() {
            check_value("roughness map", v, k, width)?;
        }
        let mut unit = Vec::with_capacity(n);
        for (k, px) in normal.iter().enumerate() {
            let (row, col) = (k / width, k % width);
            if px.iter().any(|v| !v.is_finite()) {
                return Err(GgxError::NonFinite {
                    what: "normal map",
                    row,
                    col,
                });
            }
            // Normalise in f64 so tiny-but-nonzero f32 vectors do not underflow.
            let v = Vec3::from_array(px.map(f64::from));
            let u = v
                .try_normalize()
                .ok_or(GgxError::DegenerateNormal { row, col })?;
            unit.push(u.cast::<f32>().to_array());
        }
        Ok(Self {
            height,
            width,
            diffuse,
            specular,
            roughness,
            normal: unit,
        })
    }

    /// A material with the same parameters at every pixel (validated like [`Self::new`]).
    pub fn uniform(height: usize, width: usize, p: &GgxPoint<f32>) -> Result<Self> {
        let n = height * width;
        Self::new(
            height,
            width,
            vec![p.diffuse; n],
            vec![p.specular; n],
            vec![p.roughness; n],
            vec![p.normal.to_array(); n],
        )
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Linear diffuse albedo per pixel, row-major.
    pub fn diffuse(&self) -> &[[f32; 3]] {
        &self.diffuse
    }

    /// Linear specular F0 per pixel, row-major.
    pub fn specular(&self) -> &[[f32; 3]] {
        &self.specular
    }

    /// Roughness per pixel, row-major.
    pub fn roughness(&self) -> &[f32] {
        &self.roughness
    }

    /// Unit shading normal per pixel (surface frame), row-major.
    pub fn normal(&self) -> &[[f32; 3]] {
        &self.normal
    }

    /// The GGX parameters of pixel index `k = i·width + j` (panics if out of range).
    #[inline]
    pub fn point<T: Float>(&self, k: usize) -> GgxPoint<T> {
        let c = |a: [f32; 3]| a.map(|v| T::from_f64(f64::from(v)));
        GgxPoint {
            diffuse: c(self.diffuse[k]),
            specular: c(self.specular[k]),
            roughness: T::from_f64(f64::from(self.roughness[k])),
            normal: Vec3::from_array(c(self.normal[k])),
        }
    }

    /// Decodes a 4-panel image whose values are as stored in a file of kind `kind`
    /// (see the module docs for the per-kind encoding).
    pub fn from_panels(img: &RgbImage<f32>, kind: FileKind) -> Result<Self> {
        let (w4, h) = (img.width(), img.height());
        if w4 != 4 * h {
            return Err(GgxError::PanelLayout {
                width: w4,
                height: h,
            });
        }
        let w = h;
        let n = h * w;
        let mut diffuse = Vec::with_capacity(n);
        let mut specular = Vec::with_capacity(n);
        let mut roughness = Vec::with_capacity(n);
        let mut normal = Vec::with_capacity(n);
        for i in 0..h {
            for j in 0..w {
                diffuse.push(decode_color(img.pixel(i, j), kind));
                specular.push(decode_color(img.pixel(i, w + j), kind));
                roughness.push(img.pixel(i, 2 * w + j)[0]);
                normal.push(img.pixel(i, 3 * w + j).map(|v| 2.0 * v - 1.0));
            }
        }
        Self::new(h, w, diffuse, specular, roughness, normal)
    }

    /// Encodes into a 4-panel image with the value encoding of `kind` (PNG: gamma on
    /// diffuse/specular, then the caller's PNG encoder clamps to [0, 1]).
    pub fn to_panels(&self, kind: FileKind) -> RgbImage<f32> {
        let (h, w) = (self.height, self.width);
        let mut data = vec![0.0_f32; h * 4 * w * 3];
        for i in 0..h {
            for j in 0..w {
                let k = i * w + j;
                let r = self.roughness[k];
                let panels = [
                    encode_color(self.diffuse[k], kind),
                    encode_color(self.specular[k], kind),
                    [r, r, r],
                    self.normal[k].map(|v| 0.5 * v + 0.5),
                ];
                for (p, v) in panels.iter().enumerate() {
                    let o = (i * 4 * w + p * w + j) * 3;
                    data[o..o + 3].copy_from_slice(v);
                }
            }
        }
        RgbImage::from_parts(h, 4 * w, data)
    }

    /// Loads a 4-panel SVBRDF file (`.png`, `.jpg`, `.jpeg` or `.exr`).
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (img, kind) = read_rgb(path)?;
        Self::from_panels(&img, kind).map_err(|e| e.in_file(path))
    }

    /// Saves as a 4-panel file: `.png` (16-bit, gamma 2.2 on diffuse/specular, values clamped
    /// to [0, 1]) or `.exr` (f32, linear). Not atomic.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let kind = FileKind::of(path)?;
        write_file(path, &self.to_panels(kind), kind, PngDepth::Sixteen)
    }

    /// Saves as a 4-panel PNG with the given sample depth.
    pub fn save_png(&self, path: impl AsRef<Path>, depth: PngDepth) -> Result<()> {
        let path = path.as_ref();
        write_file(path, &self.to_panels(FileKind::Ldr), FileKind::Ldr, depth)
    }

    /// Loads four separate map files of equal size (each decoded by its own extension).
    pub fn load_separate(files: &MapFiles) -> Result<Self> {
        let load = |p: &Path| read_rgb(p);
        let (d, dk) = load(&files.diffuse)?;
        let (s, sk) = load(&files.specular)?;
        let (r, _) = load(&files.roughness)?;
        let (nm, _) = load(&files.normal)?;
        let (h, w) = (d.height(), d.width());
        for (what, img, path) in [
            ("specular map", &s, &files.specular),
            ("roughness map", &r, &files.roughness),
            ("normal map", &nm, &files.normal),
        ] {
            if img.height() != h || img.width() != w {
                return Err(GgxError::MapSize {
                    what,
                    got_h: img.height(),
                    got_w: img.width(),
                    want_h: h,
                    want_w: w,
                }
                .in_file(path));
            }
        }
        let n = h * w;
        let px = |img: &RgbImage<f32>, k: usize| img.pixel(k / w, k % w);
        let diffuse = (0..n).map(|k| decode_color(px(&d, k), dk)).collect();
        let specular = (0..n).map(|k| decode_color(px(&s, k), sk)).collect();
        let roughness = (0..n).map(|k| px(&r, k)[0]).collect();
        let normal = (0..n).map(|k| px(&nm, k).map(|v| 2.0 * v - 1.0)).collect();
        Self::new(h, w, diffuse, specular, roughness, normal)
    }

    /// Saves four separate map files (encodings by each extension; PNGs are 16-bit).
    pub fn save_separate(&self, files: &MapFiles) -> Result<()> {
        let (h, w) = (self.height, self.width);
        let to_img = |f: &dyn Fn(usize) -> [f32; 3]| {
            let data = (0..h * w).flat_map(f).collect();
            RgbImage::from_vec(h, w, data)
        };
        let kd = FileKind::of(&files.diffuse)?;
        let ks = FileKind::of(&files.specular)?;
        let kr = FileKind::of(&files.roughness)?;
        let kn = FileKind::of(&files.normal)?;
        let d = to_img(&|k| encode_color(self.diffuse[k], kd))?;
        let s = to_img(&|k| encode_color(self.specular[k], ks))?;
        let r = to_img(&|k| [self.roughness[k]; 3])?;
        let nm = to_img(&|k| self.normal[k].map(|v| 0.5 * v + 0.5))?;
        write_file(&files.diffuse, &d, kd, PngDepth::Sixteen)?;
        write_file(&files.specular, &s, ks, PngDepth::Sixteen)?;
        write_file(&files.roughness, &r, kr, PngDepth::Sixteen)?;
        write_file(&files.normal, &nm, kn, PngDepth::Sixteen)
    }
}

fn decode_color(v: [f32; 3], kind: FileKind) -> [f32; 3] {
    match kind {
        FileKind::Ldr => v.map(gamma_decode),
        FileKind::Exr => v,
    }
}

fn encode_color(v: [f32; 3], kind: FileKind) -> [f32; 3] {
    match kind {
        FileKind::Ldr => v.map(gamma_encode),
        FileKind::Exr => v,
    }
}

fn write_file(path: &Path, img: &RgbImage<f32>, kind: FileKind, depth: PngDepth) -> Result<()> {
    debug_assert_eq!(FileKind::of(path).ok(), Some(kind));
    write_rgb(path, img, depth)
}
