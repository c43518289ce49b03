//! Deterministic benchmark inputs: random pairs, raw network rows, query
//! points, directions and training samples, each from
//! [`guiding_core::rng::Rng`] with the caller's seed.

use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::model::QueryPoint;
use guiding_core::rng::Rng;
use guiding_core::sample::TrainingSample;
use guiding_core::sphere::square_to_uniform_sphere;

/// Elements of one timed pass: the table of random pairs, the queries of a
/// wavefront and the MLP batch are all this long.
pub const BATCH: usize = 4096;

/// The scene box of every query and training sample.
pub const SCENE_BOX: ([f32; 3], [f32; 3]) = ([-1.0; 3], [1.0; 3]);

/// `n` pairs uniform in `[0, 1)²`: the random numbers of `n` samples.
#[must_use]
pub fn unit_pairs(seed: u32, n: usize) -> Vec<Vec2> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| Vec2::new(rng.next_f32(), rng.next_f32()))
        .collect()
}

/// `n` directions uniform on the sphere.
#[must_use]
pub fn directions(seed: u32, n: usize) -> Vec<Vec3> {
    unit_pairs(seed, n)
        .into_iter()
        .map(square_to_uniform_sphere)
        .collect()
}

/// `n` points uniform in `[0, 1)³` (the encodings' unit-cube input).
#[must_use]
pub fn unit_points(seed: u32, n: usize) -> Vec<Vec3> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
        .collect()
}

/// `n` arrays uniform in `[−1, 1)` (network inputs and output gradients).
#[must_use]
pub fn symmetric_arrays<const N: usize>(seed: u32, n: usize) -> Vec<[f32; N]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| core::array::from_fn(|_| 2.0 * rng.next_f32() - 1.0))
        .collect()
}

/// Raw mixture outputs, `K` rows of `R`, uniform in `[−2, 2)`, with
/// `offset_of_1` added to column 1 (`ln κ` / `ln λ`: 3 gives lobes of
/// κ ≈ 20, as a trained guide's).
#[must_use]
pub fn raw_rows<const K: usize, const R: usize>(seed: u32, offset_of_1: f32) -> [[f32; R]; K] {
    let mut rng = Rng::new(seed);
    let mut raw = [[0.0; R]; K];
    for row in &mut raw {
        for v in row.iter_mut() {
            *v = 4.0 * (rng.next_f32() - 0.5);
        }
        if R > 1 {
            row[1] += offset_of_1;
        }
    }
    raw
}

/// A shading point uniform in [`SCENE_BOX`], with a uniform normal, an
/// outgoing direction in its hemisphere and a uniform roughness.
fn query(rng: &mut Rng) -> QueryPoint {
    let unit = |rng: &mut Rng| square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
    let n = unit(rng);
    let mut wo = unit(rng);
    if wo.dot(n) < 0.0 {
        wo = -wo;
    }
    let (lo, hi) = SCENE_BOX;
    let p: [f32; 3] = core::array::from_fn(|i| lo[i] + (hi[i] - lo[i]) * rng.next_f32());
    QueryPoint::new(p, n.to_array(), wo.to_array(), rng.next_f32())
}

/// `n` shading points (`query`).
#[must_use]
pub fn queries(seed: u32, n: usize) -> Vec<QueryPoint> {
    let mut rng = Rng::new(seed);
    (0..n).map(|_| query(&mut rng)).collect()
}

/// `n` valid training samples: uniform incident directions at `query`
/// points, with a smooth synthetic radiance `max(1 + ωᵢ·x p₀ + ωᵢ·y, 0)`
/// (position-dependent, so the grid has something to learn), a uniform
/// sampling pdf and a cosine BSDF.
#[must_use]
pub fn training_samples(seed: u32, n: usize) -> Vec<TrainingSample> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let q = query(&mut rng);
            let wi = square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
            let l = (1.0 + wi.x * q.position[0] + wi.y).max(0.0);
            let cos = wi.dot(Vec3::from_array(q.normal)).abs();
            TrainingSample::new(
                q,
                wi.to_array(),
                [l; 3],
                INV_FOUR_PI,
                cos * core::f32::consts::FRAC_1_PI,
                [0.3 * cos; 3],
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inputs are what the benchmarks claim to feed: pairs in the unit
    /// square, unit directions, queries inside the box with a unit normal
    /// and `wo` in its hemisphere, and training samples the field accepts
    /// (a rejected sample would time the rejection path instead of a step).
    #[test]
    fn inputs_are_in_their_domains() {
        for u in unit_pairs(1, 1000) {
            assert!((0.0..1.0).contains(&u.x) && (0.0..1.0).contains(&u.y));
        }
        for d in directions(2, 1000) {
            assert!((d.length() - 1.0).abs() < 1e-5);
        }
        let (lo, hi) = SCENE_BOX;
        for q in queries(3, 1000) {
            for i in 0..3 {
                assert!(q.position[i] >= lo[i] && q.position[i] < hi[i]);
            }
            let n = Vec3::from_array(q.normal);
            assert!((n.length() - 1.0).abs() < 1e-5);
            assert!(Vec3::from_array(q.wo).dot(n) >= 0.0);
        }
        for s in training_samples(4, 1000) {
            assert_eq!(s.validate(), Ok(()));
        }
    }

    /// Same seed, same inputs; another seed, other inputs.
    #[test]
    fn inputs_are_deterministic_per_seed() {
        assert_eq!(unit_pairs(5, 64), unit_pairs(5, 64));
        assert_ne!(unit_pairs(5, 64), unit_pairs(6, 64));
        assert_eq!(raw_rows::<8, 4>(7, 3.0), raw_rows::<8, 4>(7, 3.0),);
        assert_ne!(raw_rows::<8, 4>(7, 3.0), raw_rows::<8, 4>(8, 3.0));
    }
}
