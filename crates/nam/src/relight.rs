//! Relighting a whole material for one light and viewer (DESIGN.md §3 geometry).

use crate::error::Result;
use crate::material::NeuralMaterial;
use crate::model::{BackendKind, NeuralModel};
use nam_ggx::geometry::{Light, View, directions_at, pixel_position};
use nam_ggx::{RenderSettings, RgbImage};

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
pub fn relight(
    model: &NeuralModel,
    material: &NeuralMaterial,
    scene: &Scene,
) -> Result<RgbImage<f32>> {
    scene.validate()?;
    material.check_model(model)?;
    let (h, w) = material.size();
    let mut img = RgbImage::zeros(w, h)?;
    if !above_surface(scene) {
        return Ok(img);
    }
    let radiance = match (model.backend(), scene.light, scene.view) {
        (BackendKind::Cpu, Light::Point(l), View::Point(v)) => {
            let to32 = |p: nam_ggx::Vec3d| [p.x as f32, p.y as f32, p.z as f32];
            model
                .cpu()
                .render
                .relight(material.params(), to32(l), to32(v))?
                .data
        }
        _ => render_with_directions(model, material, scene)?,
    };
    for (k, (dst, src)) in img
        .data_mut()
        .chunks_exact_mut(3)
        .zip(radiance.chunks_exact(3))
        .enumerate()
    {
        let scale = scene.scale_at(pixel_position(k / w, k % w, h, w)) as f32;
        for c in 0..3 {
            dst[c] = src[c] * scale;
        }
    }
    Ok(img)
}

/// Per-pixel `[ωi, ωo, ωh]` (f32, `H·W×9`) for a scene; pixels whose centre coincides with the
/// light or viewer get the co-located straight-up triple (their radiance is then scaled by 0
/// falloff or is a measure-zero point).
pub(crate) fn direction_triples(scene: &Scene, h: usize, w: usize) -> Vec<f32> {
    let mut dirs = Vec::with_capacity(h * w * 9);
    for i in 0..h {
        for j in 0..w {
            let t = directions_at(&scene.light, &scene.view, pixel_position(i, j, h, w))
                .map(|d| d.cast::<f32>().to_array9())
                .unwrap_or([0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
            dirs.extend_from_slice(&t);
        }
    }
    dirs
}

fn render_with_directions(
    model: &NeuralModel,
    material: &NeuralMaterial,
    scene: &Scene,
) -> Result<Vec<f32>> {
    let (h, w) = material.size();
    let dirs = direction_triples(scene, h, w);
    let params = &material.params().data;
    #[cfg(feature = "gpu")]
    if let Some(res) = model.with_gpu(|net| Ok(net.render(params, &dirs)?)) {
        return res;
    }
    let net = &model.cpu().render;
    let mut log = vec![0.0f32; h * w * 3];
    net.render_log_triples(params, &dirs, &mut log)?;
    Ok(log.into_iter().map(nam_model::radiance_from_log).collect())
}
