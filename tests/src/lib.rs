//! Statistical test helpers shared by every distribution, model and
//! integrator test: chi² goodness of fit on the sphere, quadrature of ∫pdf,
//! finite-difference gradient checks, a deterministic RNG, and the registry
//! of every distribution case the suite tests.
//!
//! Test helpers live here, never in the library crates.

pub mod cases;
pub mod fuzz_checks;
pub mod rng;

use glam::Vec3;
use rng::Pcg32;

/// A directional distribution under test.
pub trait SphereDistribution {
    /// Draws one direction with the density `sample` reports for it; it may
    /// consume as many random numbers from `rng` as it needs.
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32);
    /// Density of `direction` in solid angle.
    fn pdf(&self, direction: Vec3) -> f32;
}

pub mod chi2;
pub mod gradcheck;
pub mod oracles;
pub mod quadrature;

/// Every chi² test one run of the suite performs: the registry's cases plus
/// the standalone ones. The Šidák correction divides α among all of them.
#[must_use]
pub fn total_chi2_tests() -> usize {
    cases::all_cases().len() + cases::factorised::STANDALONE_CHI2_TESTS
}
