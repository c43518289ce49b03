//! Single directional lobes: von Mises–Fisher and normalised anisotropic
//! spherical Gaussians.

pub mod nasg;
pub mod vmf;

use glam::Vec3;

/// A sampled direction with the density it was drawn from (solid angle).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionSample {
    /// Unit direction.
    pub direction: Vec3,
    /// Density of `direction` in solid angle; finite and `> 0`.
    pub pdf: f32,
}
