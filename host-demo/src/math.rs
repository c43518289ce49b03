//! Small math helpers: RNG, orthonormal frames and sampling routines.

use glam::Vec3;
use std::f32::consts::PI;

/// The per-path PCG32 generator (one per path, keyed by seed, pixel and sample with
/// [`Rng::from_keys`], so results do not depend on the thread count): the workspace's one
/// copy, [`guiding_core::rng::Pcg32`].
pub use guiding_core::rng::Pcg32 as Rng;

/// Orthonormal frame with the shading normal as its z axis (Duff et al. 2017): the
/// workspace's one copy, [`guiding_core::frame::Frame`] (`Frame::from_z`).
pub use guiding_core::frame::Frame;

/// Cosine-weighted hemisphere sample (local frame, z up); pdf is `z / pi`.
pub fn sample_cosine_hemisphere(u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk (area preserving).
pub fn sample_concentric_disk(u1: f32, u2: f32) -> (f32, f32) {
    let (x, y) = (2.0 * u1 - 1.0, 2.0 * u2 - 1.0);
    if x == 0.0 && y == 0.0 {
        return (0.0, 0.0);
    }
    let (r, phi) = if x.abs() > y.abs() {
        (x, std::f32::consts::FRAC_PI_4 * (y / x))
    } else {
        (
            y,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (x / y),
        )
    };
    (r * phi.cos(), r * phi.sin())
}

/// Uniform direction on the unit sphere.
pub fn sample_uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Power heuristic (beta = 2) weight of strategy `a` against `b`.
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && a2.is_finite() {
        a2 / (a2 + b2)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}
