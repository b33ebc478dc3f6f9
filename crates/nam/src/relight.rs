//! Relighting a whole material for one light and viewer (DESIGN.md §3 geometry).

use crate::error::{NamError, Result};
use crate::material::NeuralMaterial;
use crate::model::NeuralModel;
use nam_ggx::geometry::{Light, View, pixel_position};
use nam_ggx::{RenderSettings, RgbImage, Vec3d};
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
/// on the CPU memory beyond the output stays bounded by the tile scratch.
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
    let mut img = RgbImage::zeros(roi.width, roi.height)?;
    let (light, view) = (light_source(scene), view_source(scene));
    let (Source::Point(l) | Source::Distant(l), Source::Point(v) | Source::Distant(v)) =
        (light, view);
    if !l.iter().chain(&v).all(|x| x.is_finite()) {
        return Err(NamError::Query(format!(
            "light and view coordinates must fit in f32 (|x| < 3.4e38), got {:?} and {:?}",
            scene.light, scene.view
        )));
    }
    if !above_surface(scene) {
        return Ok(img);
    }
    let radiance = match render_gpu(model, material, scene, roi) {
        Some(gpu) => gpu?,
        None => {
            let net = &model.cpu().render;
            net.relight_sources(material.params(), light, view, roi)?
                .data
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
            dst[c] = src[c] * scale;
        }
    }
    Ok(img)
}

fn to32(p: Vec3d) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

fn light_source(scene: &Scene) -> Source {
    match scene.light {
        Light::Point(p) => Source::Point(to32(p)),
        Light::Directional(d) => Source::Distant(to32(d)),
    }
}

fn view_source(scene: &Scene) -> Source {
    match scene.view {
        View::Point(p) => Source::Point(to32(p)),
        View::Orthographic(d) => Source::Distant(to32(d)),
    }
}

#[cfg(feature = "gpu")]
/// Per-pixel `[ωi, ωo, ωh]` (f32, 9 per pixel of `roi`) for a scene; pixels whose centre
/// coincides with the light or viewer get the co-located straight-up triple (their radiance
/// is then scaled by 0 falloff or is a measure-zero point).
fn direction_triples(scene: &Scene, h: usize, w: usize, roi: Roi) -> Vec<f32> {
    let mut dirs = Vec::with_capacity(roi.height * roi.width * 9);
    for i in roi.row..roi.row + roi.height {
        for j in roi.col..roi.col + roi.width {
            let t = nam_ggx::geometry::directions_at(
                &scene.light,
                &scene.view,
                pixel_position(i, j, h, w),
            )
            .map(|d| d.cast::<f32>().to_array9())
            .unwrap_or([0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
            dirs.extend_from_slice(&t);
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
    scene: &Scene,
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
    if let (Light::Directional(_), View::Orthographic(_)) = (scene.light, scene.view) {
        let triple = direction_triples(
            scene,
            h,
            w,
            Roi {
                height: 1,
                width: 1,
                ..roi
            },
        );
        let triple: [f32; 9] = triple.try_into().ok()?;
        return model.with_gpu(|net| Ok(net.render_directional(&params, &triple)?));
    }
    let dirs = direction_triples(scene, h, w, roi);
    model.with_gpu(|net| Ok(net.render(&params, &dirs)?))
}

/// Without the `gpu` feature there is only the CPU.
#[cfg(not(feature = "gpu"))]
fn render_gpu(_: &NeuralModel, _: &NeuralMaterial, _: &Scene, _: Roi) -> Option<Result<Vec<f32>>> {
    None
}
