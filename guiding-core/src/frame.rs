//! Orthonormal frames around a direction.

use crate::math::copysign;
use glam::Vec3;

/// A right-handed orthonormal frame `(x, y, z)`; `z` is the axis.
///
/// A local value only (it holds `Vec3`s); GPU-visible structs store their
/// frames as `[f32; 3]` arrays instead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// First tangent.
    pub x: Vec3,
    /// Second tangent, `z × x`.
    pub y: Vec3,
    /// The axis.
    pub z: Vec3,
}

impl Frame {
    /// Frame around a unit vector `n`, branchless and continuous except at
    /// `n.z = 0` (Duff et al. 2017, "Building an Orthonormal Basis, Revisited",
    /// JCGT 6(1)). `n` must be unit length.
    #[inline]
    #[must_use]
    pub fn from_z(n: Vec3) -> Self {
        let sign = copysign(1.0, n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let x = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let y = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { x, y, z: n }
    }

    /// Coordinates of `v` in this frame.
    #[inline]
    #[must_use]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.x), v.dot(self.y), v.dot(self.z))
    }

    /// World vector of local coordinates `l`.
    #[inline]
    #[must_use]
    pub fn to_world(&self, l: Vec3) -> Vec3 {
        self.x * l.x + self.y * l.y + self.z * l.z
    }
}

/// Whether `n` is the library's "no surface" normal: exactly zero, what a
/// renderer passes for a scattering point inside a participating medium
/// (`QueryPoint::normal`, `TrainingSample::normal`). Such a point has no
/// hemisphere and no cosine: the guide is a full-sphere distribution there,
/// and the cosine product leaves it unchanged.
#[inline]
#[must_use]
pub fn is_no_surface(n: Vec3) -> bool {
    n.x == 0.0 && n.y == 0.0 && n.z == 0.0
}

/// Unit vector along `v`, or `fallback` when `v` is zero, tiny, infinite or NaN.
///
/// The guard that keeps degenerate inputs (a zero normal, a NaN mean) from
/// turning into NaN directions.
#[inline]
#[must_use]
pub fn normalize_or(v: Vec3, fallback: Vec3) -> Vec3 {
    let len2 = v.length_squared();
    if len2 > 1e-30 && len2.is_finite() {
        v * (1.0 / crate::math::sqrt(len2))
    } else {
        fallback
    }
}
