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

/// Records a path of one vertex at `(position, normal, wo)` (roughness 1)
/// whose direction `wi` was sampled uniformly (both pdfs `1/4π`, unit
/// BSDF·cos), `radiance` escaping along `wi` (the embedding tests' training
/// paths).
pub fn record_uniform_vertex(
    recorder: &mut guiding::PathRecorder,
    (position, normal, wo): ([f32; 3], [f32; 3], [f32; 3]),
    wi: Vec3,
    radiance: f32,
) {
    let uniform = guiding_core::math::INV_FOUR_PI;
    recorder.start_path();
    recorder.add_vertex(guiding::PathVertex {
        position,
        normal,
        wo,
        roughness: 1.0,
        wi: wi.to_array(),
        sample_pdf: uniform,
        bsdf_pdf: uniform,
        bsdf_cos: [1.0; 3],
        ..guiding::PathVertex::default()
    });
    recorder.add_escaped_radiance([radiance; 3], 1.0);
    recorder.end_path();
}

/// A three-vertex path: diffuse (seen by the camera, with direct light), a
/// delta (mirror) vertex, and a diffuse vertex that hits an emitter (MIS
/// weight ½), has direct light and survived roulette with probability ½ (the
/// recorder tests of the Rust and the C API).
#[must_use]
pub fn mirror_path() -> [guiding::PathVertex; 3] {
    use guiding::PathVertex;
    [
        PathVertex {
            position: [0.0, 0.0, 0.0],
            normal: [0.0, 0.0, 1.0],
            wo: [0.0, 0.0, 1.0],
            emitted: [5.0; 3],
            direct: [0.1, 0.2, 0.3],
            wi: [1.0, 0.0, 0.0],
            sample_pdf: 0.5,
            bsdf_pdf: 0.4,
            bsdf_cos: [0.2, 0.3, 0.4],
            ..PathVertex::default()
        },
        PathVertex {
            position: [1.0, 0.0, 0.0],
            wi: [0.0, 1.0, 0.0],
            sample_pdf: 1.0,
            bsdf_cos: [0.9; 3],
            is_delta: true,
            ..PathVertex::default()
        },
        PathVertex {
            position: [1.0, 1.0, 0.0],
            emitted: [2.0, 4.0, 8.0],
            emitted_mis_weight: 0.5,
            direct: [0.5, 0.0, 0.25],
            wi: [0.0, 0.0, 1.0],
            sample_pdf: 2.0,
            bsdf_cos: [1.0, 0.5, 0.25],
            continuation_scale: 2.0,
            ..PathVertex::default()
        },
    ]
}

/// A query point uniform in the box `[lo, hi]`, with a uniform normal and
/// `wo` on the sphere and a uniform roughness (the embedding and device
/// tests' shading points).
pub fn random_query_in(
    rng: &mut Pcg32,
    lo: [f32; 3],
    hi: [f32; 3],
) -> guiding_core::model::QueryPoint {
    use guiding_core::sphere::square_to_uniform_sphere;
    let n = square_to_uniform_sphere(rng.next_vec2());
    let wo = square_to_uniform_sphere(rng.next_vec2());
    guiding_core::model::QueryPoint {
        position: [
            rng.uniform(lo[0], hi[0]),
            rng.uniform(lo[1], hi[1]),
            rng.uniform(lo[2], hi[2]),
        ],
        roughness: rng.next_f32(),
        normal: n.to_array(),
        wo: wo.to_array(),
        ..guiding_core::model::QueryPoint::default()
    }
}
