//! Local shading frames: world directions ↔ the material's surface frame.
//!
//! The network (and `nam-ggx`) work in the *surface frame*: the material lies in the xy plane
//! and z is the macro normal. A renderer that puts a neural material on arbitrary geometry
//! rotates world directions into that frame first. We build the frame exactly as the paper's
//! Mitsuba integration does (§5): from the shading normal `n` and the reference axis
//! `r = (1, 0, 0)` by Gram–Schmidt, `u = normalize(n × r)`, `v = n × u`; when `n` is parallel to
//! `r` the reference falls back to `(0, 1, 0)` so the frame is always defined.

use glam::Vec3;

/// An orthonormal frame `(u, v, n)`; `n` is the surface normal (the frame's z axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadingFrame {
    /// First tangent, `normalize(n × r)`.
    pub u: Vec3,
    /// Second tangent, `n × u`.
    pub v: Vec3,
    /// Unit normal.
    pub n: Vec3,
}

/// |n·r| above which the reference axis (1,0,0) is too close to the normal to use.
const PARALLEL_COS: f32 = 0.9999;

impl ShadingFrame {
    /// The surface frame itself: world = local (`u = x`, `v = y`, `n = z`).
    pub const IDENTITY: Self = Self {
        u: Vec3::X,
        v: Vec3::Y,
        n: Vec3::Z,
    };

    /// Builds the frame of a shading normal (need not be normalised; zero or non-finite
    /// normals give `None`).
    pub fn from_normal(normal: Vec3) -> Option<Self> {
        let n = normal.try_normalize()?;
        let r = if n.x.abs() < PARALLEL_COS {
            Vec3::X
        } else {
            Vec3::Y
        };
        let u = n.cross(r).try_normalize()?;
        let v = n.cross(u);
        Some(Self { u, v, n })
    }

    /// World direction → surface frame (z along the normal).
    pub fn to_local(&self, w: Vec3) -> Vec3 {
        Vec3::new(w.dot(self.u), w.dot(self.v), w.dot(self.n))
    }

    /// Surface-frame direction → world.
    pub fn to_world(&self, l: Vec3) -> Vec3 {
        self.u * l.x + self.v * l.y + self.n * l.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ORTHO_TOL: f32 = 1e-5; // f32 round-off of two cross products

    #[test]
    fn frame_is_orthonormal_and_round_trips_for_many_normals() {
        for i in 0..200 {
            let t = i as f32 * 0.37;
            let nrm = Vec3::new(t.sin(), (1.7 * t).cos(), 0.2 + (0.3 * t).sin().abs());
            let f = ShadingFrame::from_normal(nrm).expect("non-zero normal");
            assert!((f.u.length() - 1.0).abs() < ORTHO_TOL);
            assert!((f.v.length() - 1.0).abs() < ORTHO_TOL);
            assert!(f.u.dot(f.v).abs() < ORTHO_TOL && f.u.dot(f.n).abs() < ORTHO_TOL);
            let w = Vec3::new(0.3, -0.5, 0.8).normalize();
            assert!((f.to_world(f.to_local(w)) - w).length() < ORTHO_TOL);
            assert!((f.to_local(f.n) - Vec3::Z).length() < ORTHO_TOL);
        }
    }

    #[test]
    fn frame_of_normal_along_reference_axis_is_defined() {
        let f = ShadingFrame::from_normal(Vec3::X).expect("fallback axis");
        assert!((f.to_local(Vec3::X) - Vec3::Z).length() < ORTHO_TOL);
        assert!(ShadingFrame::from_normal(Vec3::ZERO).is_none());
        assert!(ShadingFrame::from_normal(Vec3::new(f32::NAN, 0.0, 1.0)).is_none());
    }
}
