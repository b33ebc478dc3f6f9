//! The surface frame of DESIGN.md §3, the one home of the scene geometry: pixel positions on
//! the material plane, the capture camera, where lights and viewers are, and per-pixel
//! ωi/ωo/ωh. The GGX reference uses it in f64, the networks (CPU fast path, the facade's GPU
//! path) in f32: every function is generic over [`Float`] and computes in the caller's
//! precision, so the f32 directions stay bit-identical to the torch exporter's.
//!
//! Frame: the material lies on z = 0 and spans [−1, 1]² in x and y (units: material
//! half-widths); z points up, away from the surface. Row i grows downwards (−y), column j
//! grows to the right (+x).

use crate::float::Float;
use crate::vec3::{Vec3, Vec3d};
use glam::DVec3;
use std::ops::RangeInclusive;

/// Field of view of the paper's capture camera (its training geometry), degrees.
pub const CAPTURE_FOV_DEG: f64 = 28.0;

/// Capture distance of the training geometry, [`capture_distance`]`(28°)` = `1/tan(14°)`
/// (material half-widths): from there a 28° camera sees exactly the [−1, 1]² material.
/// Checked against the formula in a test.
pub const CAPTURE_DISTANCE: f64 = 4.010_780_933_535_842;

/// Fields of view a photo may declare, degrees: 5° puts the camera at d = 22.9 (nearly
/// orthographic: the half-vector channel is ≥ 0.998 everywhere), 120° at d = 0.58 (the
/// corners seen 68° off the axis).
pub const FOV_RANGE_DEG: RangeInclusive<f64> = 5.0..=120.0;

/// `|v|²` below which a direction is degenerate (a light or viewer at the pixel, ωi = −ωo for
/// the half vector): [`direction`] and [`half_vector`] then give the surface normal (0, 0, 1),
/// [`Source::try_direction_from`] gives `None`.
pub const DIRECTION_GUARD: f64 = 1e-12;

/// Distance from the material's centre of a camera with field of view `fov_deg` (degrees)
/// whose frame the [−1, 1]² material exactly fills: `d = 1 / tan(fov/2)` (material
/// half-widths). `train_py/ggx.py`'s `capture_distance` is the same formula.
pub fn capture_distance(fov_deg: f64) -> f64 {
    1.0 / (fov_deg.to_radians() / 2.0).tan()
}

/// The capture position (0, 0, `distance`): where the input photo's camera and flash are.
#[inline]
pub fn capture_position(distance: f64) -> DVec3 {
    DVec3::new(0.0, 0.0, distance)
}

/// Surface position of the centre of pixel (row `i`, col `j`) of an `height`×`width` image:
/// `x = 2(j+0.5)/W − 1`, `y = −2(i+0.5)/H + 1`, `z = 0`, computed in `T`.
#[inline]
pub fn pixel_position<T: Float>(i: usize, j: usize, height: usize, width: usize) -> Vec3<T> {
    let two = T::from_f64(2.0);
    let x = two * T::from_f64(j as f64 + 0.5) / T::from_f64(width as f64) - T::ONE;
    let y = -two * T::from_f64(i as f64 + 0.5) / T::from_f64(height as f64) + T::ONE;
    Vec3::new(x, y, T::ZERO)
}

/// z of the half vector of the capture geometry (light and camera co-located at
/// (0, 0, `distance`)) at pixel (i, j): `d / sqrt(x² + y² + d²)`, computed in `T`. This is
/// input channel 3 of `M_est`.
#[inline]
pub fn capture_half_z<T: Float>(i: usize, j: usize, height: usize, width: usize, distance: T) -> T {
    let p: Vec3<T> = pixel_position(i, j, height, width);
    let d = distance;
    d / (p.x * p.x + p.y * p.y + d * d).sqrt()
}

/// `v / |v|`, or `None` when `|v|²` is NaN or below [`DIRECTION_GUARD`]. A `|v|²` that
/// overflows for finite `v` (a light at ~1e20 in f32) is rescaled by the largest component
/// first: the direction is the same, and the usual path stays bit-identical to torch.
#[inline]
fn try_unit<T: Float>(v: Vec3<T>) -> Option<Vec3<T>> {
    let mut v = v;
    let mut n2 = v.dot(v);
    if !n2.is_finite() && v.is_finite() {
        let m = v.x.abs().max(v.y.abs()).max(v.z.abs());
        v = Vec3::new(v.x / m, v.y / m, v.z / m);
        n2 = v.dot(v);
    }
    if !(n2 >= T::from_f64(DIRECTION_GUARD) && n2.is_finite()) {
        return None;
    }
    // Divide (not multiply by a reciprocal): correctly rounded like torch's `v / norm`, which
    // matters because the encoding scales ωh by up to 2^15·π.
    let n = n2.sqrt();
    Some(Vec3::new(v.x / n, v.y / n, v.z / n))
}

/// `normalize(to − from)`; a degenerate difference (see [`DIRECTION_GUARD`]) gives the
/// surface normal (0, 0, 1).
#[inline]
pub fn direction<T: Float>(from: Vec3<T>, to: Vec3<T>) -> Vec3<T> {
    try_unit(to - from).unwrap_or_else(Vec3::up)
}

/// `v / |v|` for a direction given as `[x, y, z]` (the networks' interchange type: a
/// directional light's ωi, an orthographic ωo), by the rules of [`direction`].
#[inline]
pub fn unit_direction<T: Float>(v: [T; 3]) -> [T; 3] {
    direction(Vec3::zero(), Vec3::from_array(v)).to_array()
}

/// The half vector `normalize(ωi + ωo)`, or the normal (0, 0, 1) when `|ωi + ωo|²` is below
/// [`DIRECTION_GUARD`] (ωi ≈ −ωo: then n·ωi and n·ωo cannot both be positive, so every BRDF
/// is 0 there anyway).
#[inline]
pub fn half_vector<T: Float>(wi: Vec3<T>, wo: Vec3<T>) -> Vec3<T> {
    try_unit(wi + wo).unwrap_or_else(Vec3::up)
}

/// Where a light or the viewer is, as the networks see a scene: a point (directions differ
/// per pixel) or infinitely far (one direction everywhere). Coordinates are `[x, y, z]` in the
/// surface frame, the networks' interchange type. [`Light`] and [`View`] convert to it
/// ([`Light::source`], [`View::source`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Source<T> {
    /// A point at this surface-frame position: a point light, or a perspective (pinhole)
    /// viewer.
    Point([T; 3]),
    /// Infinitely far along this direction (from the surface towards it; any length,
    /// normalised where used): a directional light, or an orthographic viewer.
    Distant([T; 3]),
}

impl<T: Float> Source<T> {
    /// Unit direction from surface point `p` towards the source, or `None` when degenerate
    /// (a point source at `p`, a zero or non-finite vector; see [`DIRECTION_GUARD`]).
    #[inline]
    pub fn try_direction_from(&self, p: Vec3<T>) -> Option<Vec3<T>> {
        match *self {
            Self::Point(q) => try_unit(Vec3::from_array(q) - p),
            Self::Distant(d) => try_unit(Vec3::from_array(d)),
        }
    }

    /// [`Self::try_direction_from`], with the surface normal (0, 0, 1) where degenerate (the
    /// networks' convention).
    #[inline]
    pub fn direction_from(&self, p: Vec3<T>) -> Vec3<T> {
        self.try_direction_from(p).unwrap_or_else(Vec3::up)
    }

    /// The position or direction, `[x, y, z]`.
    #[inline]
    pub fn coordinates(&self) -> [T; 3] {
        let (Self::Point(v) | Self::Distant(v)) = *self;
        v
    }

    /// Converts to another float type (rounding to nearest; beyond the f32 range → ±inf).
    #[inline]
    pub fn cast<U: Float>(&self) -> Source<U> {
        let c = |v: [T; 3]| Vec3::from_array(v).cast::<U>().to_array();
        match *self {
            Self::Point(v) => Source::Point(c(v)),
            Self::Distant(v) => Source::Distant(c(v)),
        }
    }
}

/// Where the light comes from (glam's `DVec3`, surface frame, material half-widths).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// A point light at this position.
    Point(DVec3),
    /// A directional light; the vector points *towards* the light (need not be unit).
    Directional(DVec3),
}

/// Where the surface is seen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum View {
    /// A perspective (pinhole) viewer at this position (surface frame, material half-widths).
    Point(DVec3),
    /// An orthographic viewer; the vector points *towards* the viewer (need not be unit).
    Orthographic(DVec3),
}

impl Light {
    /// The light as a [`Source`] in precision `T`.
    #[inline]
    pub fn source<T: Float>(&self) -> Source<T> {
        match *self {
            Light::Point(p) => Source::Point(p.to_array()),
            Light::Directional(d) => Source::Distant(d.to_array()),
        }
        .cast()
    }

    /// Unit direction from surface point `p` towards the light, or `None` if degenerate
    /// (light at `p`, zero or non-finite vector; see [`DIRECTION_GUARD`]).
    #[inline]
    pub fn direction_from(&self, p: Vec3d) -> Option<Vec3d> {
        self.source().try_direction_from(p)
    }

    /// Inverse-square falloff relative to the training geometry's capture distance,
    /// `d² / |light − p|²` with d = [`CAPTURE_DISTANCE`] (1 for a point light at that
    /// distance: the unit light of the training renders; always 1 for a directional light).
    /// Returns 0 if the light is exactly at `p`.
    #[inline]
    pub fn falloff_at(&self, p: Vec3d) -> f64 {
        match *self {
            Light::Point(pos) => {
                let r = Vec3d::from(pos) - p;
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
    /// The viewer as a [`Source`] in precision `T`.
    #[inline]
    pub fn source<T: Float>(&self) -> Source<T> {
        match *self {
            View::Point(p) => Source::Point(p.to_array()),
            View::Orthographic(d) => Source::Distant(d.to_array()),
        }
        .cast()
    }

    /// Unit direction from surface point `p` towards the viewer, or `None` if degenerate.
    #[inline]
    pub fn direction_from(&self, p: Vec3d) -> Option<Vec3d> {
        self.source().try_direction_from(p)
    }
}

/// The unit directions at one surface point, surface frame (z up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Directions<T> {
    /// Towards the light.
    pub wi: Vec3<T>,
    /// Towards the viewer.
    pub wo: Vec3<T>,
    /// Half vector [`half_vector`]`(ωi, ωo)`.
    pub wh: Vec3<T>,
}

impl<T: Float> Directions<T> {
    /// Builds the triple from ωi and ωo (assumed unit).
    #[inline]
    pub fn new(wi: Vec3<T>, wo: Vec3<T>) -> Self {
        Self {
            wi,
            wo,
            wh: half_vector(wi, wo),
        }
    }

    /// The networks' directions at surface point `p` for a light and a viewer, computed in
    /// `T`: degenerate directions are the normal (0, 0, 1) ([`Source::direction_from`]).
    #[inline]
    pub fn at(light: &Source<T>, view: &Source<T>, p: Vec3<T>) -> Self {
        Self::new(light.direction_from(p), view.direction_from(p))
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
/// when the light or the viewer sits at `p` (the GGX reference renders such a pixel black).
#[inline]
pub fn directions_at(light: &Light, view: &View, p: Vec3d) -> Option<Directions<f64>> {
    let wi = light.direction_from(p)?;
    let wo = view.direction_from(p)?;
    Some(Directions::new(wi, wo))
}

/// Per-pixel `(ωi, ωo)` for a point light at `light` and a pinhole viewer at `view` (surface
/// frame), row-major over the `height`×`width` image, computed in `T` like the networks'.
pub fn pixel_directions<T: Float>(
    height: usize,
    width: usize,
    light: [T; 3],
    view: [T; 3],
) -> (Vec<[T; 3]>, Vec<[T; 3]>) {
    let (light, view) = (Source::Point(light), Source::Point(view));
    (0..height * width)
        .map(|k| {
            let d = Directions::at(
                &light,
                &view,
                pixel_position(k / width, k % width, height, width),
            );
            (d.wi.to_array(), d.wo.to_array())
        })
        .unzip()
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
        assert!((capture_distance(CAPTURE_FOV_DEG) - CAPTURE_DISTANCE).abs() < TIGHT);
        // The f32 networks use the same constant rounded once (the literal they used before).
        assert_eq!(capture_distance(CAPTURE_FOV_DEG) as f32, 4.010_781_f32);
        assert_eq!(CAPTURE_DISTANCE as f32, 4.010_781_f32);
    }

    #[test]
    fn capture_distance_of_45_and_90_degrees() {
        assert!((capture_distance(90.0) - 1.0).abs() < TIGHT);
        assert!((capture_distance(45.0) - (1.0 + 2f64.sqrt())).abs() < TIGHT);
        let ends = [FOV_RANGE_DEG.start(), FOV_RANGE_DEG.end()].map(|&f| capture_distance(f));
        assert!((ends[0] - 22.903_765).abs() < 1e-6 && (ends[1] - 0.577_350).abs() < 1e-6);
    }

    #[test]
    fn pixel_centres_span_the_unit_square_symmetrically() {
        let (h, w) = (5, 7);
        let a: Vec3d = pixel_position(0, 0, h, w);
        let b: Vec3d = pixel_position(h - 1, w - 1, h, w);
        assert!((a.x + b.x).abs() < TIGHT && (a.y + b.y).abs() < TIGHT);
        assert!((a.x - (1.0 / 7.0 - 1.0)).abs() < TIGHT);
        assert!(
            (a.y - (1.0 - 1.0 / 5.0)).abs() < TIGHT,
            "row 0 is at the top (+y)"
        );
        let c: Vec3d = pixel_position(2, 3, h, w);
        assert!(c.x.abs() < TIGHT && c.y.abs() < TIGHT);
    }

    #[test]
    fn f32_pixel_positions_round_the_formula_in_f32() {
        for (i, j, h, w) in [(0, 0, 3, 3), (5, 250, 256, 256), (4095, 17, 4096, 4096)] {
            let p: Vec3<f32> = pixel_position(i, j, h, w);
            let x = 2.0 * (j as f32 + 0.5) / w as f32 - 1.0;
            let y = -2.0 * (i as f32 + 0.5) / h as f32 + 1.0;
            assert_eq!(p.to_array(), [x, y, 0.0]);
        }
    }

    #[test]
    fn capture_half_z_matches_colocated_half_vector() {
        let (h, w) = (6, 9);
        for d in [CAPTURE_DISTANCE, capture_distance(45.0)] {
            let cam = capture_position(d);
            for i in 0..h {
                for j in 0..w {
                    let p = pixel_position(i, j, h, w);
                    let dirs = directions_at(&Light::Point(cam), &View::Point(cam), p);
                    let Some(dirs) = dirs else {
                        panic!("capture geometry is never degenerate")
                    };
                    assert!((dirs.wh.z - capture_half_z(i, j, h, w, d)).abs() < TIGHT);
                }
            }
        }
    }

    #[test]
    fn directional_light_gives_the_same_direction_everywhere() {
        let light = Light::Directional(DVec3::new(1.0, 0.0, 1.0));
        let a = light.direction_from(pixel_position(0, 0, 4, 4));
        let b = light.direction_from(pixel_position(3, 3, 4, 4));
        assert_eq!(a, b);
        assert_eq!(light.falloff_at(Vec3::new(0.3, 0.1, 0.0)), 1.0);
    }

    #[test]
    fn falloff_is_one_at_capture_distance_and_quarter_at_double() {
        let p = Vec3::new(0.0, 0.0, 0.0);
        let l1 = Light::Point(capture_position(CAPTURE_DISTANCE));
        let l2 = Light::Point(capture_position(CAPTURE_DISTANCE) * 2.0);
        assert!((l1.falloff_at(p) - 1.0).abs() < TIGHT);
        assert!((l2.falloff_at(p) - 0.25).abs() < TIGHT);
        assert_eq!(Light::Point(p.into()).falloff_at(p), 0.0);
    }

    #[test]
    fn far_lights_keep_their_direction_when_the_squared_length_overflows() {
        let d = direction(Vec3::zero(), Vec3::new(1e20f32, 0.0, 1.0));
        assert!((d.x - 1.0).abs() < 1e-6 && d.z > 0.0 && d.z < 1e-6, "{d:?}");
        let d = direction(Vec3::zero(), Vec3::new(3e38f32, -3e38, 3e38));
        let r = 1.0 / 3f32.sqrt();
        assert!((d.x - r).abs() < 1e-6 && (d.y + r).abs() < 1e-6, "{d:?}");
    }

    /// The f64 reference once normalised with `len > 0` and a reciprocal; it now follows the
    /// networks' tested f32 rules: division, [`DIRECTION_GUARD`], rescaling on overflow.
    #[test]
    fn f64_directions_follow_the_f32_network_rules() {
        let p = Vec3::new(0.25, -0.5, 0.0);
        // An f64 |v|² overflows beyond ~1.3e154: the direction is kept, as in f32.
        let far = Light::Point(DVec3::new(1e200, 0.0, 1e200)).direction_from(p);
        let r = 1.0 / 2f64.sqrt();
        assert!(far.is_some_and(|d| (d.x - r).abs() < TIGHT && (d.z - r).abs() < TIGHT));
        // Closer than 1e-6 to the pixel is degenerate in both precisions.
        let near = Source::Point([0.25, -0.5, 1e-7]);
        assert_eq!(near.try_direction_from(p), None);
        assert_eq!(near.cast::<f32>().direction_from(p.cast()), Vec3::up());
        assert_eq!(
            Light::Directional(DVec3::new(1e-7, 0.0, 0.0)).direction_from(p),
            None
        );
        // Division, not a reciprocal: 5/√27 rounds like torch's `v / norm` (5·(1/√27) does
        // not: it is one ulp above).
        let n = 27f64.sqrt();
        let d = direction(Vec3::zero(), Vec3::new(1.0, 1.0, 5.0));
        assert_eq!(d.to_array(), [1.0 / n, 1.0 / n, 5.0 / n]);
        assert_ne!(d.z, 5.0 * (1.0 / n));
        // Both precisions round the same formula: the f64 direction rounded to f32 is within
        // an ulp of the f32 one.
        let (lf, pf) = ([0.3f32, 0.7, 2.5], Vec3::new(-0.9f32, 0.1, 0.0));
        let d32 = Source::Point(lf).direction_from(pf);
        let d64 = Source::Point(lf)
            .cast::<f64>()
            .direction_from(pf.cast())
            .cast::<f32>();
        for (a, b) in d32.to_array().into_iter().zip(d64.to_array()) {
            assert!((a - b).abs() <= f32::EPSILON, "{d32:?} {d64:?}");
        }
    }

    #[test]
    fn degenerate_half_vector_is_the_normal() {
        let wi = Vec3::new(1.0f32, 0.0, 0.0);
        assert_eq!(half_vector(wi, -wi), Vec3::up());
        assert_eq!(Directions::new(wi, -wi).wh, Vec3::up());
    }

    #[test]
    fn pixel_directions_agree_with_directions_at() {
        let (h, w) = (3, 4);
        let (l, v) = ([0.4, 0.2, 2.0], [0.0, 0.0, CAPTURE_DISTANCE]);
        let (wi, wo) = pixel_directions(h, w, l, v);
        for k in 0..h * w {
            let p = pixel_position(k / w, k % w, h, w);
            let want = directions_at(
                &Light::Point(DVec3::from_array(l)),
                &View::Point(DVec3::from_array(v)),
                p,
            );
            let Some(want) = want else {
                panic!("not degenerate")
            };
            assert_eq!((wi[k], wo[k]), (want.wi.to_array(), want.wo.to_array()));
        }
    }
}
