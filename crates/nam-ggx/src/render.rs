//! Rendering a whole SVBRDF map for one light and viewer (rayon over rows).

use crate::brdf::eval;
use crate::error::{GgxError, Result};
use crate::float::Float;
use crate::geometry::{Light, Source, View, directions_at, pixel_position};
use crate::imageio::RgbImage;
use crate::maps::SvbrdfMaps;
use crate::vec3::Vec3d;
use rayon::prelude::*;

/// Largest light intensity (1 = the unit light of the training renders): with it, falloff and
/// the brightest GGX highlight every accepted scene renders finite in f32.
pub const MAX_INTENSITY: f64 = 1e6;

/// Lowest height above the surface (material half-widths) of a point light with falloff:
/// the falloff `d²/|light − p|²` then stays below 1.6e7.
pub const MIN_FALLOFF_HEIGHT: f64 = 1e-3;

/// Light, viewer and light scaling for [`render`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// The light.
    pub light: Light,
    /// The viewer.
    pub view: View,
    /// Light intensity k ≥ 0 multiplying R (1 = the unit light of the training renders).
    pub intensity: f64,
    /// Multiply by the inverse-square falloff `d²/|light − p|²` (point lights only).
    pub falloff: bool,
}

impl RenderSettings {
    /// Unit intensity, no falloff: the radiance convention of DESIGN §3.
    pub fn new(light: Light, view: View) -> Self {
        Self {
            light,
            view,
            intensity: 1.0,
            falloff: false,
        }
    }

    /// Checks what every backend can render finite: coordinates within the f32 range
    /// (|x| ≤ 3.4e38) and a height above the surface that f32 can hold (z ≤ 0, rendered
    /// black, or z ≥ 1.2e-38, f32's smallest normal number), directional vectors not
    /// degenerate (|v| ≥ 1e-6, [`DIRECTION_GUARD`](crate::geometry::DIRECTION_GUARD): shorter,
    /// the networks would light every pixel from straight above), intensity in
    /// [0, [`MAX_INTENSITY`]], and with falloff a point light at least [`MIN_FALLOFF_HEIGHT`]
    /// above the surface.
    pub fn validate(&self) -> Result<()> {
        let (light, view) = (self.light.source::<f64>(), self.view.source::<f64>());
        let f32_max = f64::from(f32::MAX);
        for (what, s) in [("light", light), ("view", view)] {
            let c = s.coordinates();
            if !c.iter().all(|x| x.is_finite() && x.abs() <= f32_max) {
                return Err(GgxError::InvalidArgument(format!(
                    "{what} coordinates {c:?} must be finite and within ±3.4e38 (f32's range)"
                )));
            }
            if c[2] > 0.0 && c[2] < f64::from(f32::MIN_POSITIVE) {
                return Err(GgxError::InvalidArgument(format!(
                    "{what} height z = {:e} is above the surface but below 1.2e-38, the smallest \
                     height the f32 networks can hold; use z ≥ 1.2e-38 (or z ≤ 0: black)",
                    c[2]
                )));
            }
        }
        let origin = Vec3d::zero();
        let degenerate = |s: Source<f64>| {
            matches!(s, Source::Distant(_)) && s.try_direction_from(origin).is_none()
        };
        if degenerate(light) || degenerate(view) {
            return Err(GgxError::InvalidArgument(
                "a light or view direction is the zero vector (or shorter than 1e-6)".into(),
            ));
        }
        if !(self.intensity >= 0.0 && self.intensity <= MAX_INTENSITY) {
            return Err(GgxError::InvalidArgument(format!(
                "light intensity must lie in [0, {MAX_INTENSITY:e}], got {:e}",
                self.intensity
            )));
        }
        if let (true, Light::Point(p)) = (self.falloff, self.light)
            && p.z > 0.0
            && p.z < MIN_FALLOFF_HEIGHT
        {
            return Err(GgxError::InvalidArgument(format!(
                "with falloff a point light must be at least {MIN_FALLOFF_HEIGHT:e} above the \
                 surface (the falloff d²/r² diverges at the pixel below it), got z = {:e}",
                p.z
            )));
        }
        Ok(())
    }

    /// The factor applied to R at surface point `p`: intensity, times falloff if enabled.
    #[inline]
    pub fn scale_at(&self, p: Vec3d) -> f64 {
        if self.falloff {
            self.intensity * self.light.falloff_at(p)
        } else {
            self.intensity
        }
    }
}

/// Renders `R` (DESIGN §3 convention, times [`RenderSettings::scale_at`]) for every pixel,
/// evaluating the BRDF in precision `T` (geometry is computed in f64, then rounded).
/// Pixels where the light or viewer sits on the pixel centre (closer than 1e-6) are 0.
pub fn render<T: Float>(maps: &SvbrdfMaps, settings: &RenderSettings) -> Result<RgbImage<T>> {
    render_with_progress(maps, settings, &|| {})
}

/// [`render`], calling `row_done` once after each finished image row (from worker threads).
pub fn render_with_progress<T: Float>(
    maps: &SvbrdfMaps,
    settings: &RenderSettings,
    row_done: &(dyn Fn() + Sync),
) -> Result<RgbImage<T>> {
    settings.validate()?;
    let (h, w) = (maps.height(), maps.width());
    let mut img = RgbImage::<T>::zeros(h, w)?;
    img.data_mut()
        .par_chunks_mut(w * 3)
        .enumerate()
        .for_each(|(i, row)| {
            for j in 0..w {
                let p = pixel_position(i, j, h, w);
                let Some(dirs) = directions_at(&settings.light, &settings.view, p) else {
                    continue;
                };
                let d = dirs.cast::<T>();
                let r = eval(&maps.point::<T>(i * w + j), d.wi, d.wo);
                let s = T::from_f64(settings.scale_at(p));
                for c in 0..3 {
                    row[j * 3 + c] = r[c] * s;
                }
            }
            row_done();
        });
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::GgxPoint;
    use crate::geometry::{CAPTURE_DISTANCE, capture_position};
    use crate::vec3::Vec3;
    use glam::DVec3;

    fn grey(roughness: f32) -> SvbrdfMaps {
        let p = GgxPoint {
            diffuse: [0.5; 3],
            specular: [0.04; 3],
            roughness,
            normal: Vec3::up(),
        };
        SvbrdfMaps::uniform(16, 16, &p).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn colocated_flash_highlight_peaks_at_the_centre() {
        let maps = grey(0.2);
        let cam = capture_position(CAPTURE_DISTANCE);
        let s = RenderSettings::new(Light::Point(cam), View::Point(cam));
        let img = render::<f64>(&maps, &s).unwrap_or_else(|e| panic!("{e}"));
        let centre = img.pixel(7, 7)[0];
        let corner = img.pixel(0, 0)[0];
        assert!(centre > 2.0 * corner, "centre {centre} corner {corner}");
    }

    #[test]
    fn falloff_and_intensity_scale_the_image() {
        let maps = grey(0.5);
        let cam = capture_position(CAPTURE_DISTANCE);
        let far = cam * 2.0;
        let base = RenderSettings::new(Light::Point(far), View::Point(cam));
        let scaled = RenderSettings {
            intensity: 3.0,
            falloff: true,
            ..base
        };
        let a = render::<f64>(&maps, &base).unwrap_or_else(|e| panic!("{e}"));
        let b = render::<f64>(&maps, &scaled).unwrap_or_else(|e| panic!("{e}"));
        // At the centre pixel-ish the falloff is ≈ 1/4: 3/4 of the unscaled value.
        let (x, y) = (a.pixel(8, 8)[1], b.pixel(8, 8)[1]);
        let p = pixel_position(8, 8, 16, 16);
        let want = 3.0 * Light::Point(far).falloff_at(p) * x;
        assert!((y - want).abs() < 1e-12 * want, "{y} vs {want}");
        assert!((y / x - 0.75).abs() < 0.01);
    }

    #[test]
    fn invalid_settings_are_rejected() {
        let maps = grey(0.5);
        let cam = capture_position(CAPTURE_DISTANCE);
        let bad = [
            RenderSettings {
                intensity: f64::NAN,
                ..RenderSettings::new(Light::Point(cam), View::Point(cam))
            },
            RenderSettings {
                intensity: -1.0,
                ..RenderSettings::new(Light::Point(cam), View::Point(cam))
            },
            RenderSettings::new(
                Light::Directional(DVec3::new(0.0, 0.0, 0.0)),
                View::Point(cam),
            ),
            RenderSettings::new(
                Light::Point(cam),
                View::Point(DVec3::new(f64::INFINITY, 0., 1.)),
            ),
        ];
        for s in bad {
            assert!(
                matches!(render::<f32>(&maps, &s), Err(GgxError::InvalidArgument(_))),
                "{s:?}"
            );
        }
    }

    /// The networks would light every pixel from straight above with a directional vector
    /// shorter than 1e-6 (their degenerate-direction rule); the reference rejects it instead.
    #[test]
    fn directional_vectors_shorter_than_the_guard_are_rejected() {
        let cam = capture_position(CAPTURE_DISTANCE);
        let tiny = RenderSettings::new(
            Light::Directional(DVec3::new(1e-7, 0.0, 1e-7)),
            View::Point(cam),
        );
        assert!(matches!(tiny.validate(), Err(GgxError::InvalidArgument(_))));
        let short_but_fine = RenderSettings::new(
            Light::Point(cam),
            View::Orthographic(DVec3::new(0.0, 0.0, 1e-5)),
        );
        assert!(short_but_fine.validate().is_ok());
    }
}
