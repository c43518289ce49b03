//! Chi² goodness-of-fit test on the sphere (being written).

use glam::DVec3;

/// Parametrisation of the sphere by the unit square used for the chi² grid
/// and for quadrature.
#[derive(Clone, Copy, Debug)]
pub enum Warp {
    /// Mitsuba's grid: `u → φ = 2πu` about `axis`, `v → cos θ = 1 − 2v`.
    UniformSphere {
        /// Pole of the grid.
        axis: DVec3,
    },
}
