//! Scene geometry of DESIGN.md §3: pixel positions on the material plane, the capture
//! camera, and per-pixel light/view/half directions.
//!
//! Frame: the material lies on z = 0 and spans [−1, 1]² in x and y (units: material
//! half-widths); z points up, away from the surface. Row i grows downwards (−y), column j
//! grows to the right (+x).

use crate::float::Float;
use crate::vec3::{Vec3, Vec3d};

/// Field of view of the capture camera, degrees.
pub const CAPTURE_FOV_DEG: f64 = 28.0;

/// Capture distance `d = 1/tan(14°)` (material half-widths): from there a 28° camera sees
/// exactly the [−1, 1]² material. Checked against the formula in a test.
pub const CAPTURE_DISTANCE: f64 = 4.010_780_933_535_842;

/// Surface position of the centre of pixel (row `i`, col `j`) of an `height`×`width` image:
/// `x = 2(j+0.5)/W − 1`, `y = −2(i+0.5)/H + 1`, `z = 0`.
#[inline]
pub fn pixel_position(i: usize, j: usize, height: usize, width: usize) -> Vec3d {
    let x = 2.0 * (j as f64 + 0.5) / width as f64 - 1.0;
    let y = -2.0 * (i as f64 + 0.5) / height as f64 + 1.0;
    Vec3::new(x, y, 0.0)
}

/// Where the light comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// A point light at this position (surface frame, material half-widths).
    Point(Vec3d),
    /// A directional light; the vector points *towards* the light (need not be unit).
    Directional(Vec3d),
}

/// Where the surface is seen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum View {
    /// A perspective (pinhole) viewer at this position (surface frame, material half-widths).
    Point(Vec3d),
    /// An orthographic viewer; the vector points *towards* the viewer (need not be unit).
    Orthographic(Vec3d),
}

impl Light {
    /// Unit direction from surface point `p` towards the light, or `None` if degenerate
    /// (light exactly at `p`, zero or non-finite vector).
    #[inline]
    pub fn direction_from(&self, p: Vec3d) -> Option<Vec3d> {
        match *self {
            Light::Point(pos) => (pos - p).try_normalize(),
            Light::Directional(dir) => dir.try_normalize(),
        }
    }

    /// Inverse-square falloff relative to the capture distance, `d² / |light − p|²`
    /// (1 for a point light at distance d; always 1 for a directional light).
    /// Returns 0 if the light is exactly at `p`.
    #[inline]
    pub fn falloff_at(&self, p: Vec3d) -> f64 {
        match *self {
            Light::Point(pos) => {
                let r = pos - p;
                let r2 = r.dot(r);
                if r2 > 0.0 {
                    CAPTURE_DISTANCE * CAPTURE_DISTANCE / r2
                } else {
                    0.0
                }
            }
            Light::Directional(_) => 1.0,
        }
    }
}

impl View {
    /// Unit direction from surface point `p` towards the viewer, or `None` if degenerate.
    #[inline]
    pub fn direction_from(&self, p: Vec3d) -> Option<Vec3d> {
        match *self {
            View::Point(pos) => (pos - p).try_normalize(),
            View::Orthographic(dir) => dir.try_normalize(),
        }
    }
}

/// The unit directions at one surface point, surface frame (z up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Directions<T> {
    /// Towards the light.
    pub wi: Vec3<T>,
    /// Towards the viewer.
    pub wo: Vec3<T>,
    /// Half vector `normalize(ωi + ωo)` ((0, 0, 1) if ωi = −ωo).
    pub wh: Vec3<T>,
}

impl<T: Float> Directions<T> {
    /// Builds the triple from ωi and ωo (assumed unit).
    #[inline]
    pub fn new(wi: Vec3<T>, wo: Vec3<T>) -> Self {
        Self {
            wi,
            wo,
            wh: crate::brdf::half_vector(wi, wo),
        }
    }

    /// Converts to another float type.
    #[inline]
    pub fn cast<U: Float>(&self) -> Directions<U> {
        Directions {
            wi: self.wi.cast(),
            wo: self.wo.cast(),
            wh: self.wh.cast(),
        }
    }

    /// The 9 values `[ωi, ωo, ωh]` in the order the network's positional encoding uses.
    #[inline]
    pub fn to_array9(&self) -> [T; 9] {
        [
            self.wi.x, self.wi.y, self.wi.z, self.wo.x, self.wo.y, self.wo.z, self.wh.x, self.wh.y,
            self.wh.z,
        ]
    }
}

/// Directions at surface point `p` for this light and viewer (computed in f64), or `None`
/// when the light or the viewer sits exactly at `p`.
#[inline]
pub fn directions_at(light: &Light, view: &View, p: Vec3d) -> Option<Directions<f64>> {
    let wi = light.direction_from(p)?;
    let wo = view.direction_from(p)?;
    Some(Directions::new(wi, wo))
}

/// Directions for every pixel of an `height`×`width` image, row-major. A pixel whose centre
/// coincides with the point light or the viewer gets `None`.
pub fn direction_map(
    light: &Light,
    view: &View,
    height: usize,
    width: usize,
) -> Vec<Option<Directions<f64>>> {
    let mut out = Vec::with_capacity(height * width);
    for i in 0..height {
        for j in 0..width {
            out.push(directions_at(
                light,
                view,
                pixel_position(i, j, height, width),
            ));
        }
    }
    out
}

/// z of the half vector of the capture geometry (light and camera co-located at (0, 0, d))
/// at pixel (i, j): `d / sqrt(x² + y² + d²)`. This is input channel 3 of `M_est`.
#[inline]
pub fn capture_half_z(i: usize, j: usize, height: usize, width: usize) -> f64 {
    let p = pixel_position(i, j, height, width);
    let d = CAPTURE_DISTANCE;
    d / (p.x * p.x + p.y * p.y + d * d).sqrt()
}

/// The capture position (0, 0, d): where the input photo's camera and flash are.
#[inline]
pub fn capture_position() -> Vec3d {
    Vec3::new(0.0, 0.0, CAPTURE_DISTANCE)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f64 rounding of tan and a division.
    const TIGHT: f64 = 1e-14;

    #[test]
    fn capture_distance_is_one_over_tan_14_degrees() {
        let d = 1.0 / (CAPTURE_FOV_DEG / 2.0).to_radians().tan();
        assert!((d - CAPTURE_DISTANCE).abs() < TIGHT, "{d}");
    }

    #[test]
    fn pixel_centres_span_the_unit_square_symmetrically() {
        let (h, w) = (5, 7);
        let a = pixel_position(0, 0, h, w);
        let b = pixel_position(h - 1, w - 1, h, w);
        assert!((a.x + b.x).abs() < TIGHT && (a.y + b.y).abs() < TIGHT);
        assert!((a.x - (1.0 / 7.0 - 1.0)).abs() < TIGHT);
        assert!(
            (a.y - (1.0 - 1.0 / 5.0)).abs() < TIGHT,
            "row 0 is at the top (+y)"
        );
        let c = pixel_position(2, 3, h, w);
        assert!(c.x.abs() < TIGHT && c.y.abs() < TIGHT);
    }

    #[test]
    fn capture_half_z_matches_colocated_half_vector() {
        let (h, w) = (6, 9);
        let cam = capture_position();
        for i in 0..h {
            for j in 0..w {
                let p = pixel_position(i, j, h, w);
                let dirs = directions_at(&Light::Point(cam), &View::Point(cam), p);
                let Some(dirs) = dirs else {
                    panic!("capture geometry is never degenerate")
                };
                assert!((dirs.wh.z - capture_half_z(i, j, h, w)).abs() < TIGHT);
            }
        }
    }

    #[test]
    fn directional_light_gives_the_same_direction_everywhere() {
        let light = Light::Directional(Vec3::new(1.0, 0.0, 1.0));
        let a = light.direction_from(pixel_position(0, 0, 4, 4));
        let b = light.direction_from(pixel_position(3, 3, 4, 4));
        assert_eq!(a, b);
        assert_eq!(light.falloff_at(Vec3::new(0.3, 0.1, 0.0)), 1.0);
    }

    #[test]
    fn falloff_is_one_at_capture_distance_and_quarter_at_double() {
        let p = Vec3::new(0.0, 0.0, 0.0);
        let l1 = Light::Point(capture_position());
        let l2 = Light::Point(capture_position() * 2.0);
        assert!((l1.falloff_at(p) - 1.0).abs() < TIGHT);
        assert!((l2.falloff_at(p) - 0.25).abs() < TIGHT);
        assert_eq!(Light::Point(p).falloff_at(p), 0.0);
    }
}
