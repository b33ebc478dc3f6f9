//! The held-out procedural set: 4-panel SVBRDF files, their LDR flash photos and the
//! light/view pairs of each protocol (the definitions of `train_py/evaluate.py`).

use crate::error::{EvalError, Result};
use nam_ggx::color::{srgb_decode, srgb_encode};
use nam_ggx::geometry::{CAPTURE_DISTANCE, Light, View, capture_position};
use nam_ggx::{LightView, Protocol, RenderSettings, SvbrdfMaps, render, sample_protocol};
use std::path::{Path, PathBuf};

/// Base of the per-material protocol seeds (`EVAL_SEED` of `evaluate.py`).
pub const EVAL_SEED: u64 = 4242;

/// The protocols in `evaluate.py`'s order (the order enters the seeds).
pub const PROTOCOLS: [Protocol; 3] = [Protocol::Reflect, Protocol::Identity, Protocol::Hemisphere];

/// One held-out material.
#[derive(Debug, Clone)]
pub struct Material {
    /// File stem, e.g. `material_1000002000`.
    pub name: String,
    /// Generator seed (from the file name), or the index when the name has none.
    pub seed: u64,
    /// The ground-truth GGX maps (resampled to the evaluation size).
    pub maps: SvbrdfMaps,
    /// The input photo: the co-located flash render at the capture position, through an
    /// 8-bit sRGB round trip (clamp, quantise, decode), linear RGB, HWC.
    pub photo: Vec<f32>,
}

impl Material {
    /// Side length in pixels.
    pub fn side(&self) -> usize {
        self.maps.height()
    }

    /// `n` light/view pairs of `protocol` for this material: seed
    /// `EVAL_SEED + seed mod 100000 + 17·protocol index`, nam-ggx's sampler — the pairs
    /// `evaluate.py` draws (`protocols.seeded_pairs`; tests/eval_agreement.rs). The first `k`
    /// pairs of a longer list are the `k`-pair list.
    pub fn pairs(&self, protocol: Protocol, n: usize) -> Vec<LightView> {
        let index = PROTOCOLS.iter().position(|p| *p == protocol).unwrap_or(0) as u64;
        let seed = EVAL_SEED + self.seed % 100_000 + 17 * index;
        sample_protocol(protocol, n, seed)
    }
}

/// The LDR capture of `evaluate.py`: `srgb_decode(round(255·srgb_encode(R))/255)`.
pub fn ldr_capture(radiance: &[f32]) -> Vec<f32> {
    radiance
        .iter()
        .map(|&v| srgb_decode((srgb_encode(v) * 255.0).round() / 255.0))
        .collect()
}

/// The flash photo of `maps` (see [`Material::photo`]).
pub fn capture_photo(maps: &SvbrdfMaps) -> Result<Vec<f32>> {
    let cam = capture_position(CAPTURE_DISTANCE);
    let hdr = render::<f32>(
        maps,
        &RenderSettings::new(Light::Point(cam), View::Point(cam)),
    )?;
    Ok(ldr_capture(hdr.data()))
}

/// Box-downsamples maps by an integer factor (linear values averaged; normals averaged and
/// renormalised by [`SvbrdfMaps::new`]).
pub fn downsample(maps: &SvbrdfMaps, side: usize) -> Result<SvbrdfMaps> {
    let (h, w) = (maps.height(), maps.width());
    if side == 0 || h % side != 0 || w % side != 0 || h != w {
        return Err(EvalError::Option(format!(
            "cannot resample {h}×{w} maps to {side}×{side} (needs a divisor of the side)"
        )));
    }
    if side == h {
        return Ok(maps.clone());
    }
    let f = h / side;
    let n = side * side;
    let inv = 1.0 / (f * f) as f32;
    let avg3 = |src: &[[f32; 3]], i: usize, j: usize| {
        let mut s = [0.0f32; 3];
        for di in 0..f {
            for dj in 0..f {
                let v = src[(i * f + di) * w + j * f + dj];
                for c in 0..3 {
                    s[c] += v[c] * inv;
                }
            }
        }
        s
    };
    let mut diffuse = Vec::with_capacity(n);
    let mut specular = Vec::with_capacity(n);
    let mut roughness = Vec::with_capacity(n);
    let mut normal = Vec::with_capacity(n);
    for i in 0..side {
        for j in 0..side {
            diffuse.push(avg3(maps.diffuse(), i, j));
            specular.push(avg3(maps.specular(), i, j));
            normal.push(avg3(maps.normal(), i, j));
            let mut r = 0.0;
            for di in 0..f {
                for dj in 0..f {
                    r += maps.roughness()[(i * f + di) * w + j * f + dj] * inv;
                }
            }
            roughness.push(r);
        }
    }
    Ok(SvbrdfMaps::new(
        side, side, diffuse, specular, roughness, normal,
    )?)
}

/// The `material_*.png` files of `dir`, sorted by name.
pub fn list(dir: &Path) -> Result<Vec<PathBuf>> {
    let err = |reason: String| EvalError::HeldOut {
        path: dir.to_path_buf(),
        reason,
    };
    let entries = std::fs::read_dir(dir).map_err(|e| err(e.to_string()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|x| x == "png")
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("material_"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(err("no material_*.png files".into()));
    }
    Ok(files)
}

/// Loads the first `count` materials of `dir` at `side`×`side` (box-downsampled from the
/// files when smaller) and renders their photos.
pub fn load(dir: &Path, count: usize, side: usize) -> Result<Vec<Material>> {
    let files = list(dir)?;
    if count == 0 || count > files.len() {
        return Err(EvalError::HeldOut {
            path: dir.to_path_buf(),
            reason: format!("asked for {count} materials, {} available", files.len()),
        });
    }
    files[..count]
        .iter()
        .enumerate()
        .map(|(k, path)| {
            let maps = downsample(&SvbrdfMaps::load(path)?, side)?;
            let name = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("material")
                .to_string();
            let seed = name
                .rsplit('_')
                .next()
                .and_then(|s| s.parse().ok())
                .unwrap_or(k as u64);
            let photo = capture_photo(&maps)?;
            Ok(Material {
                name,
                seed,
                maps,
                photo,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nam_ggx::GgxPoint;
    use nam_ggx::Vec3d;

    #[test]
    fn ldr_capture_quantises_to_8_bit_srgb_and_clamps() {
        let out = ldr_capture(&[0.0, 2.0, 0.5, -1.0]);
        assert_eq!(out[0], 0.0);
        assert_eq!(out[1], 1.0);
        assert_eq!(out[3], 0.0);
        let code = srgb_encode(out[2]) * 255.0;
        assert!((code - code.round()).abs() < 1e-3, "{code}");
        assert!((out[2] - 0.5).abs() < 0.005);
    }

    #[test]
    fn downsampling_a_uniform_material_keeps_it() {
        let p = GgxPoint {
            diffuse: [0.3, 0.2, 0.1],
            specular: [0.04; 3],
            roughness: 0.4,
            normal: Vec3d::up().cast(),
        };
        let m = SvbrdfMaps::uniform(8, 8, &p).unwrap_or_else(|e| panic!("{e}"));
        let d = downsample(&m, 2).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((d.height(), d.width()), (2, 2));
        assert!((d.diffuse()[3][0] - 0.3).abs() < 1e-6);
        assert!((d.roughness()[0] - 0.4).abs() < 1e-6);
        assert!(downsample(&m, 3).is_err());
    }

    #[test]
    fn pair_lists_are_prefixes_of_longer_ones() {
        let p = GgxPoint {
            diffuse: [0.5; 3],
            specular: [0.04; 3],
            roughness: 0.5,
            normal: Vec3d::up().cast(),
        };
        let maps = SvbrdfMaps::uniform(4, 4, &p).unwrap_or_else(|e| panic!("{e}"));
        let m = Material {
            name: "x".into(),
            seed: 1_000_002_003,
            photo: capture_photo(&maps).unwrap_or_else(|e| panic!("{e}")),
            maps,
        };
        let long = m.pairs(Protocol::Hemisphere, 10);
        assert_eq!(m.pairs(Protocol::Hemisphere, 4), long[..4].to_vec());
        assert_ne!(m.pairs(Protocol::Reflect, 4), long[..4].to_vec());
    }
}
