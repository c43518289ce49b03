//! von Mises–Fisher cases: single lobes across the range of κ, random K = 8
//! mixtures (built from lobes and decoded from raw network outputs), and
//! their products with the clamped cosine.
//!
//! Grids: broad lobes (κ ≤ 10) use Mitsuba's uniform grid; sharper lobes use
//! a [`Warp::ZoomedCap`] around their mean with `s0 = 1/κ`, so the lobe's core
//! (`1 − cos θ ≲ 1/κ`) spans many rows. Mixtures (κ ≤ ~10³) use a uniform grid
//! whose poles are kept away from every lobe with κ > 10 ([`axis_avoiding`]),
//! where the thin polar cells would be narrower than such a lobe is
//! smooth.

use super::{seeded_cases, Case};
use crate::chi2::{axis_avoiding, Warp};
use crate::rng::Pcg32;
use glam::{DVec3, Vec3};
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::sphere::square_to_uniform_sphere;

/// Lobes per mixture in the cases.
pub const K: usize = 8;

/// A single vMF lobe.
pub struct LobeDist(pub VmfLobe);

/// A K-lobe vMF mixture.
pub struct MixtureDist(pub VmfMixture<K>);

sphere_distribution_of_sampler!(LobeDist, MixtureDist);

/// Uniformly distributed unit vector.
#[must_use]
pub fn random_direction(rng: &mut Pcg32) -> Vec3 {
    square_to_uniform_sphere(rng.next_vec2())
}

/// Random mixture built with [`VmfMixture::from_lobes`]: κ log-uniform in
/// `[10⁻², 10³]`, uniform means, weights uniform in `(0, 1]` (normalised by
/// the constructor).
#[must_use]
pub fn random_mixture(rng: &mut Pcg32) -> VmfMixture<K> {
    let lobes: [VmfLobe; K] = core::array::from_fn(|_| {
        let mean = random_direction(rng);
        let log10_kappa = rng.uniform(-2.0, 3.0);
        VmfLobe::new(mean, 10f32.powf(log10_kappa))
    });
    let weights: [f32; K] = core::array::from_fn(|_| 1.0 - rng.next_f32());
    VmfMixture::from_lobes(&lobes, &weights)
}

/// Random raw network output whose decoded mixture has κ log-uniform in
/// `[10⁻², 10³]`: logits in `[−2, 2]`, `ln κ` in `[ln 10⁻², ln 10³]`, raw
/// angles in `[−3, 3]` (before the sigmoids).
#[must_use]
pub fn random_raw(rng: &mut Pcg32) -> [[f32; VMF_RAW_PER_LOBE]; K] {
    core::array::from_fn(|_| {
        [
            rng.uniform(-2.0, 2.0),
            rng.uniform(
                -2.0 * core::f32::consts::LN_10,
                3.0 * core::f32::consts::LN_10,
            ),
            rng.uniform(-3.0, 3.0),
            rng.uniform(-3.0, 3.0),
        ]
    })
}

/// Uniform grid whose poles avoid the lobes of `m` with κ > 10.
#[must_use]
pub fn mixture_warp(m: &VmfMixture<K>) -> Warp {
    let sharp: Vec<DVec3> = (0..K)
        .filter(|&k| m.kappa[k] > 10.0 && m.weight[k] > 0.0)
        .map(|k| m.lobe(k).mean().as_dvec3())
        .collect();
    Warp::uniform_about(axis_avoiding(&sharp))
}

/// The grid for a single lobe: uniform for κ < 100, zoomed onto the lobe
/// (`s0 = 1/κ`) from κ = 100 on.
#[must_use]
pub fn lobe_warp(lobe: &VmfLobe) -> Warp {
    if lobe.kappa < 100.0 {
        Warp::uniform()
    } else {
        Warp::zoomed_about(lobe.mean().as_dvec3(), 1.0 / f64::from(lobe.kappa))
    }
}

fn lobe_case(name: String, lobe: VmfLobe) -> Case {
    Case {
        name,
        warp: lobe_warp(&lobe),
        dist: Box::new(LobeDist(lobe)),
    }
}

fn mixture_case(name: String, m: VmfMixture<K>) -> Case {
    Case {
        name,
        warp: mixture_warp(&m),
        dist: Box::new(MixtureDist(m)),
    }
}

/// Every case of this family.
#[must_use]
pub fn cases() -> Vec<Case> {
    let mut cases = Vec::new();
    let mut rng = Pcg32::new(0x5f3d_0001, 0);
    for (label, kappa) in [
        ("0", 0.0),
        ("1e-3", 1e-3),
        ("0.1", 0.1),
        ("1", 1.0),
        ("10", 10.0),
        ("100", 100.0),
        ("1e3", 1e3),
        ("1e4", 1e4),
    ] {
        let mean = random_direction(&mut rng);
        cases.push(lobe_case(
            format!("vmf/lobe/kappa={label}/random-mean"),
            VmfLobe::new(mean, kappa),
        ));
    }
    // Means exactly at the poles: the frame construction's special points
    // (and, for κ = 10, the pole of the uniform grid).
    for (label, mean, kappa) in [
        ("kappa=1e3/mean=+z", Vec3::Z, 1e3),
        ("kappa=1e3/mean=-z", -Vec3::Z, 1e3),
        ("kappa=10/mean=+z", Vec3::Z, 10.0),
        ("kappa=10/mean=-z", -Vec3::Z, 10.0),
    ] {
        cases.push(lobe_case(
            format!("vmf/lobe/{label}"),
            VmfLobe::new(mean, kappa),
        ));
    }

    cases.extend(seeded_cases("vmf/mixture/from-lobes", 3, 1, |name, rng| {
        mixture_case(name, random_mixture(rng))
    }));
    cases.extend(seeded_cases("vmf/mixture/decoded", 3, 2, |name, rng| {
        mixture_case(name, VmfMixture::decode(&random_raw(rng)))
    }));
    cases.extend(seeded_cases("vmf/product-cosine", 2, 3, |name, rng| {
        let m = random_mixture(rng);
        let normal = random_direction(rng);
        mixture_case(name, m.product_with_clamped_cosine(normal))
    }));
    cases
}
