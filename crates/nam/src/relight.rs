//! Relighting a whole material for one light and viewer (DESIGN.md §3 geometry).

use crate::error::{NamError, Result};
use crate::material::NeuralMaterial;
use crate::model::NeuralModel;
#[cfg(feature = "gpu")]
use nam_ggx::Vec3;
#[cfg(feature = "gpu")]
use nam_ggx::geometry::Directions;
use nam_ggx::geometry::{Light, View, pixel_position};
use nam_ggx::{RenderSettings, RgbImage};
use nam_model::{Roi, Source};

/// Light, viewer, intensity and falloff of a relight: the same type the GGX reference uses,
/// so a neural render and its ground truth are always set up identically.
pub type Scene = RenderSettings;

/// Whether the light and the viewer are above the surface plane z = 0. Every pixel lies on
/// that plane, so for point and directional lights alike the answer is the same at all pixels.
fn above_surface(scene: &Scene) -> bool {
    let lz = match scene.light {
        Light::Point(p) | Light::Directional(p) => p.z,
    };
    let vz = match scene.view {
        View::Point(p) | View::Orthographic(p) => p.z,
    };
    lz > 0.0 && vz > 0.0
}

/// Renders `material` as seen under `scene`: linear radiance `R = π f_r cos θi` times the
/// scene's intensity (and `d²/|light − p|²` when `scene.falloff`), `H×W` RGB.
///
/// A light or viewer on or below the surface plane gives a black image (the network knows
/// no horizon; the GGX reference is exactly 0 there, DESIGN §7).
///
/// The cheapest exact pipeline is picked (DESIGN §9), on the CPU and on an attached GPU
/// alike: with a directional light *and* an orthographic view the positional encoding and
/// ND_enc run once for the whole image and each pixel runs only the render MLP (≥ 5× faster);
/// on the CPU memory beyond the output stays bounded by the tile scratch. With
/// [`NeuralModel::set_nd_interpolation`] the CPU also interpolates ND_enc between grid nodes
/// for point lights (an approximation the caller opts into).
pub fn relight(
    model: &NeuralModel,
    material: &NeuralMaterial,
    scene: &Scene,
) -> Result<RgbImage<f32>> {
    let (h, w) = material.size();
    relight_roi(model, material, scene, Roi::full(h, w))
}

/// Like [`relight`], but evaluates only the pixels of `roi` (a `roi.height × roi.width`
/// image, row-major); pixels outside it cost nothing. The values equal the same pixels of
/// [`relight`].
pub fn relight_roi(
    model: &NeuralModel,
    material: &NeuralMaterial,
    scene: &Scene,
    roi: Roi,
) -> Result<RgbImage<f32>> {
    scene.validate()?;
    material.check_model(model)?;
    let (h, w) = material.size();
    if roi.height == 0 || roi.width == 0 || roi.row + roi.height > h || roi.col + roi.width > w {
        return Err(NamError::Query(format!(
            "region {}×{} at ({}, {}) is empty or outside the {h}×{w} material",
            roi.height, roi.width, roi.row, roi.col
        )));
    }
    let mut img = RgbImage::zeros(roi.height, roi.width)?;
    // One route for both backends: the scene in the networks' f32 (`validate` checked that
    // it fits), whose per-pixel directions both compute with `Directions::at`.
    let (light, view): (Source, Source) = (scene.light.source(), scene.view.source());
    if !above_surface(scene) {
        return Ok(img);
    }
    let radiance = match render_gpu(model, material, light, view, roi) {
        Some(gpu) => gpu?,
        None => {
            let net = &model.cpu().render;
            match (model.nd_interpolation(), light, view) {
                (Some(angle), Source::Point(l), Source::Point(v)) if roi == Roi::full(h, w) => {
                    net.relight_interpolated(material.params(), l, v, angle)?
                        .data
                }
                _ => {
                    net.relight_sources(material.params(), light, view, roi)?
                        .data
                }
            }
        }
    };
    for (k, (dst, src)) in img
        .data_mut()
        .chunks_exact_mut(3)
        .zip(radiance.chunks_exact(3))
        .enumerate()
    {
        let (i, j) = (roi.row + k / roi.width, roi.col + k % roi.width);
        let scale = scene.scale_at(pixel_position(i, j, h, w)) as f32;
        for c in 0..3 {
            // The network's radiance is capped at f32::MAX; so is its product with the
            // scene's (bounded) scale, so an accepted scene never gives +Inf.
            dst[c] = (src[c] * scale).min(f32::MAX);
        }
    }
    Ok(img)
}

/// Per-pixel `[ωi, ωo, ωh]` (f32, 9 per pixel of `roi`): the directions the CPU path
/// computes per tile, [`Directions::at`] (degenerate ones are the normal (0, 0, 1)).
#[cfg(feature = "gpu")]
fn direction_triples(light: &Source, view: &Source, h: usize, w: usize, roi: Roi) -> Vec<f32> {
    let mut dirs = Vec::with_capacity(roi.height * roi.width * 9);
    for i in roi.row..roi.row + roi.height {
        for j in roi.col..roi.col + roi.width {
            let p = pixel_position(i, j, h, w);
            dirs.extend_from_slice(&Directions::at(light, view, p).to_array9());
        }
    }
    dirs
}

/// The GPU path, when a GPU is attached: the ROI's params uploaded with per-pixel
/// directions, or, for a directional light and an orthographic view, with the one triple
/// every pixel shares (ND_enc then runs once).
#[cfg(feature = "gpu")]
fn render_gpu(
    model: &NeuralModel,
    material: &NeuralMaterial,
    light: Source,
    view: Source,
    roi: Roi,
) -> Option<Result<Vec<f32>>> {
    let (h, w) = material.size();
    let p = material.params();
    let c = p.channels;
    let params: Vec<f32> = (roi.row..roi.row + roi.height)
        .flat_map(|i| {
            let start = (i * w + roi.col) * c;
            p.data[start..start + roi.width * c].iter().copied()
        })
        .collect();
    if let (Source::Distant(_), Source::Distant(_)) = (light, view) {
        // The same directions at every surface point.
        let triple = Directions::at(&light, &view, Vec3::zero()).to_array9();
        return model.with_gpu(|net| Ok(net.render_directional(&params, &triple)?));
    }
    let dirs = direction_triples(&light, &view, h, w, roi);
    model.with_gpu(|net| Ok(net.render(&params, &dirs)?))
}

/// Without the `gpu` feature there is only the CPU.
#[cfg(not(feature = "gpu"))]
fn render_gpu(
    _: &NeuralModel,
    _: &NeuralMaterial,
    _: Source,
    _: Source,
    _: Roi,
) -> Option<Result<Vec<f32>>> {
    None
}
