//! The registry of every distribution the statistical suite checks. One list,
//! so that the Šidák correction knows the total number of chi² tests in a run.

/// [`SphereDistribution`] for newtypes `$t(pub X)` over a lobe or mixture of
/// `guiding_core` (`X::sample(Vec2) -> DirectionSample`, `X::pdf(Vec3)`),
/// sampled with two random numbers.
macro_rules! sphere_distribution_of_sampler {
    ($($t:ty),*) => {$(
        impl $crate::SphereDistribution for $t {
            fn sample(&self, rng: &mut $crate::rng::Pcg32) -> (glam::Vec3, f32) {
                let s = self.0.sample(rng.next_vec2());
                (s.direction, s.pdf)
            }
            fn pdf(&self, direction: glam::Vec3) -> f32 {
                self.0.pdf(direction)
            }
        }
    )*};
}

pub mod factorised;
pub mod nasg;
pub mod vmf;

use crate::SphereDistribution;

/// One distribution to test, with the chi² grid that resolves it.
pub struct Case {
    /// Unique name, prefixed by the family (`vmf/`, `nasg/`, `df/`).
    pub name: String,
    /// The distribution.
    pub dist: Box<dyn SphereDistribution>,
    /// How the chi² grid and the quadrature parametrise the sphere for it.
    pub warp: crate::chi2::Warp,
}

/// The cases `make(name, rng)` for seeds 1 to `seeds`, named
/// `{prefix}/seed={seed}`, each with its own `Pcg32::new(seed, stream)`.
fn seeded_cases(
    prefix: &str,
    seeds: u64,
    stream: u64,
    mut make: impl FnMut(String, &mut crate::rng::Pcg32) -> Case,
) -> Vec<Case> {
    (1..=seeds)
        .map(|seed| {
            let mut rng = crate::rng::Pcg32::new(seed, stream);
            make(format!("{prefix}/seed={seed}"), &mut rng)
        })
        .collect()
}

/// Every case of every family.
#[must_use]
pub fn all_cases() -> Vec<Case> {
    let mut cases = vmf::cases();
    cases.extend(nasg::cases());
    cases.extend(factorised::cases());
    cases
}
