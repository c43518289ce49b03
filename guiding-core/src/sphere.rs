//! Warps between the unit square and the unit sphere, and the stable angular
//! distance every lobe is evaluated with.

use crate::math::TWO_PI;
use crate::math::{atan2_turns, safe_sqrt, sin_cos, sin_cos_turns, sqrt, FOUR_PI, INV_FOUR_PI};
use glam::{Vec2, Vec3};

/// Density of [`square_to_uniform_sphere`] in solid angle: `1 / (4π)`.
pub const UNIFORM_SPHERE_PDF: f32 = INV_FOUR_PI;

/// Direction with polar angle θ (given as `sin θ`, `cos θ`) and azimuth φ
/// about `+z`.
#[inline]
#[must_use]
pub fn spherical_direction(sin_theta: f32, cos_theta: f32, phi: f32) -> Vec3 {
    let (s, c) = sin_cos(phi);
    Vec3::new(sin_theta * c, sin_theta * s, cos_theta)
}

/// [`spherical_direction`] with the azimuth given in turns, `φ = 2π u`: the
/// form every warp uses, evaluated by the inlined
/// [`sin_cos_turns`] (exact reduction, no
/// rounding of `2πu`, no libm call).
#[inline]
#[must_use]
pub fn spherical_direction_turns(sin_theta: f32, cos_theta: f32, u: f32) -> Vec3 {
    let (s, c) = sin_cos_turns(u);
    Vec3::new(sin_theta * c, sin_theta * s, cos_theta)
}

/// Uniform sphere warp used by the factorised PDFs (Figueiredo et al. 2025,
/// §3): `φ = 2π u.x`, `cos θ = 1 − 2 u.y`. Its Jacobian is constant, so a
/// density `p(u)` on the square is `p(u) / (4π)` in solid angle.
#[inline]
#[must_use]
pub fn square_to_uniform_sphere(u: Vec2) -> Vec3 {
    let cos_theta = 1.0 - 2.0 * u.y;
    // sin θ = sqrt((1 − cos θ)(1 + cos θ)) = 2 sqrt(u.y (1 − u.y)), no cancellation.
    let sin_theta = 2.0 * safe_sqrt(u.y * (1.0 - u.y));
    // libm's `sin_cos(2π u)` rather than `spherical_direction_turns`, on
    // purpose: the factorised densities sample `u.x` exactly onto bin edges
    // (`k / N` rounded), and the chi² suite bins their directions in f64 on a
    // grid aligned with those edges; this keeps their directions bit-identical
    // to the reference implementation (an ulp-level change of the warp moves
    // a handful of edge samples per 10⁶ into the neighbouring bin).
    spherical_direction(sin_theta, cos_theta, TWO_PI * u.x)
}

/// Inverse of [`square_to_uniform_sphere`]; `d` need not be exactly unit.
/// Returns `u ∈ [0, 1]²`.
#[inline]
#[must_use]
pub fn uniform_sphere_to_square(d: Vec3) -> Vec2 {
    let len = sqrt(d.length_squared());
    let cos_theta = (d.z / len).clamp(-1.0, 1.0);
    // φ / 2π directly (inlined, branch-free; see `atan2_turns`).
    let mut phi = atan2_turns(d.y, d.x);
    if phi < 0.0 {
        phi += 1.0;
    }
    Vec2::new(phi.clamp(0.0, 1.0), 0.5 * (1.0 - cos_theta))
}

/// Solid angle of the unit sphere.
pub const SPHERE_AREA: f32 = FOUR_PI;

/// `1 − cos∠(axis, d)` computed without cancellation near the axis.
///
/// `axis` must be unit length; `d` may deviate from unit length by rounding
/// (its norm is divided out). Near the axis the naive `1 − axis·d` loses all
/// digits (and any error in `|d|` becomes an absolute error of `|d| − 1`);
/// here, for `axis·d > 0`, `1 − cos θ = sin²θ / (1 + cos θ)` with
/// `sin θ = |axis × d| / |d|`, which keeps full relative precision down to the
/// smallest angles. This is the "stable vMF form"; the naive form is kept
/// only as a test oracle.
///
/// A zero, infinite or NaN `d` has no angle; it is treated as the antipode
/// (result `2`), the least likely direction of every lobe, so densities stay
/// finite.
#[inline]
#[must_use]
pub fn one_minus_cos_angle(axis: Vec3, d: Vec3) -> f32 {
    let len2 = d.length_squared();
    if !(len2 > 0.0 && len2 <= f32::MAX) {
        return 2.0;
    }
    let len = sqrt(len2);
    let dot = axis.dot(d);
    if dot > 0.0 {
        let cross2 = axis.cross(d).length_squared();
        // sin²θ/(1 + cos θ) = (|x|²/len²) / (1 + dot/len) = |x|² / (len (len + dot)).
        cross2 / (len * (len + dot))
    } else {
        1.0 - dot / len
    }
}
