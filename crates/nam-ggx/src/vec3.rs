//! A small 3-vector generic over [`Float`]: the math type of the generic (f32/f64) kernels.
//! Scenes are given in glam's `DVec3` ([`crate::geometry::Light`], [`crate::LightView`]),
//! which converts to and from [`Vec3d`] losslessly.

use crate::float::Float;
use std::ops::{Add, Mul, Neg, Sub};

/// A 3-vector. For positions the unit is the surface half-width (the material spans
/// [−1, 1]² on z = 0); directions are unit vectors in the surface frame (z up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vec3<T> {
    /// x component.
    pub x: T,
    /// y component.
    pub y: T,
    /// z component (up, away from the surface).
    pub z: T,
}

/// Single-precision vector.
pub type Vec3f = Vec3<f32>;
/// Double-precision vector.
pub type Vec3d = Vec3<f64>;

impl<T: Float> Vec3<T> {
    /// Builds a vector from its components.
    #[inline]
    pub const fn new(x: T, y: T, z: T) -> Self {
        Self { x, y, z }
    }

    /// The origin, (0, 0, 0): the centre of the material.
    #[inline]
    pub fn zero() -> Self {
        Self::new(T::ZERO, T::ZERO, T::ZERO)
    }

    /// The surface normal of the macro surface, (0, 0, 1).
    #[inline]
    pub fn up() -> Self {
        Self::new(T::ZERO, T::ZERO, T::ONE)
    }

    /// Builds a vector from an array `[x, y, z]`.
    #[inline]
    pub fn from_array(a: [T; 3]) -> Self {
        Self::new(a[0], a[1], a[2])
    }

    /// The components as `[x, y, z]`.
    #[inline]
    pub fn to_array(self) -> [T; 3] {
        [self.x, self.y, self.z]
    }

    /// Converts the components to another float type (rounding to nearest).
    #[inline]
    pub fn cast<U: Float>(self) -> Vec3<U> {
        Vec3::new(
            U::from_f64(self.x.to_f64()),
            U::from_f64(self.y.to_f64()),
            U::from_f64(self.z.to_f64()),
        )
    }

    /// Dot product.
    #[inline]
    pub fn dot(self, o: Self) -> T {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    /// Cross product (right-handed).
    #[inline]
    pub fn cross(self, o: Self) -> Self {
        Self::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }

    /// Euclidean length.
    #[inline]
    pub fn length(self) -> T {
        self.dot(self).sqrt()
    }

    /// The unit vector along `self`, or `None` when the length is zero or not finite
    /// (so no NaN can come out of a degenerate input).
    #[inline]
    pub fn try_normalize(self) -> Option<Self> {
        let len = self.length();
        if len > T::ZERO && len.is_finite() {
            let inv = T::ONE / len;
            let n = self * inv;
            if n.x.is_finite() && n.y.is_finite() && n.z.is_finite() {
                return Some(n);
            }
        }
        None
    }

    /// True if every component is finite.
    #[inline]
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
}

impl<T: Float> Add for Vec3<T> {
    type Output = Self;
    #[inline]
    fn add(self, o: Self) -> Self {
        Self::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}

impl<T: Float> Sub for Vec3<T> {
    type Output = Self;
    #[inline]
    fn sub(self, o: Self) -> Self {
        Self::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}

impl<T: Float> Mul<T> for Vec3<T> {
    type Output = Self;
    #[inline]
    fn mul(self, s: T) -> Self {
        Self::new(self.x * s, self.y * s, self.z * s)
    }
}

impl<T: Float> Neg for Vec3<T> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        Self::new(-self.x, -self.y, -self.z)
    }
}

impl<T: Float> From<[T; 3]> for Vec3<T> {
    /// `[x, y, z]`, the networks' interchange type.
    #[inline]
    fn from(a: [T; 3]) -> Self {
        Self::from_array(a)
    }
}

impl From<glam::DVec3> for Vec3<f64> {
    #[inline]
    fn from(v: glam::DVec3) -> Self {
        Self::new(v.x, v.y, v.z)
    }
}

impl From<Vec3<f64>> for glam::DVec3 {
    #[inline]
    fn from(v: Vec3<f64>) -> Self {
        glam::DVec3::new(v.x, v.y, v.z)
    }
}
