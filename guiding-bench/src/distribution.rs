//! One sample and one density per random pair, for every directional
//! distribution of the library: what a guided vertex asks of its guide
//! (a direction for the next ray, then the density of that direction for
//! MIS), next to the uniform sphere warp as the in-process baseline.

use crate::inputs::raw_rows;
use guiding_core::factorised::FactorisedTable;
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::nasg::{NasgLobe, NASG_EPSILON};
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::pdf1d::Interpolation;
use guiding_core::rng::Rng;
use guiding_core::sphere::{square_to_uniform_sphere, UNIFORM_SPHERE_PDF};
use std::hint::black_box;

/// Lobes of the mixtures (NPM's and NASG's `K`).
pub const LOBES: usize = 8;
/// Marginal bins of the DF tables (DF's `M`).
pub const DF_ROWS: usize = 32;
/// Conditional bins of the DF tables (DF's `N`).
pub const DF_COLUMNS: usize = 16;

/// One distribution under test.
/// The variants hold the distributions by value, as the renderer does (a case is built
/// once per run and timed in place, so their different sizes cost nothing).
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug)]
pub enum DistributionCase {
    /// `square_to_uniform_sphere` and its constant density: the baseline.
    UniformSphere,
    /// One vMF lobe, κ = 25.
    VmfLobe(VmfLobe),
    /// One NASG lobe, λ = 25, a = 4.
    NasgLobe(NasgLobe),
    /// NPM's mixture of 8 vMF lobes (random raw rows, κ ≈ 20).
    VmfMixture(VmfMixture<LOBES>),
    /// NASG's mixture of 8 lobes (random raw rows, λ ≈ 20).
    NasgMixture(NasgMixture<LOBES>),
    /// DF's 32 × 16 piecewise table from random logits.
    Factorised(FactorisedTable<DF_ROWS, DF_COLUMNS>, Interpolation),
}

impl DistributionCase {
    /// Every case, the baseline first; fixed seeds.
    #[must_use]
    pub fn all() -> Vec<Self> {
        let vmf = VmfMixture::decode(&raw_rows::<LOBES, VMF_RAW_PER_LOBE>(11, 3.0));
        let nasg = NasgMixture::decode(&raw_rows::<LOBES, NASG_RAW_PER_LOBE>(13, 3.0), 0.0);
        let mut rng = Rng::new(17);
        let marginal: [f32; DF_ROWS] = core::array::from_fn(|_| 3.0 * rng.next_f32());
        let conditional: [[f32; DF_COLUMNS]; DF_ROWS] =
            core::array::from_fn(|_| core::array::from_fn(|_| 3.0 * rng.next_f32()));
        let table =
            |i| Self::Factorised(FactorisedTable::from_logits(&marginal, &conditional, i), i);
        let axis = Vec3::new(0.3, -0.5, 0.8).normalize();
        vec![
            Self::UniformSphere,
            Self::VmfLobe(VmfLobe::new(axis, 25.0)),
            Self::NasgLobe(NasgLobe::new(axis, Vec3::X, 25.0, 4.0, NASG_EPSILON)),
            Self::VmfMixture(vmf),
            Self::NasgMixture(nasg),
            table(Interpolation::Nearest),
            table(Interpolation::Linear),
        ]
    }

    /// The name both harnesses print.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::UniformSphere => "uniform sphere (baseline)",
            Self::VmfLobe(_) => "vMF lobe",
            Self::NasgLobe(_) => "NASG lobe",
            Self::VmfMixture(_) => "vMF mixture K=8",
            Self::NasgMixture(_) => "NASG mixture K=8",
            Self::Factorised(_, Interpolation::Nearest) => "DF-N table 32x16",
            Self::Factorised(_, Interpolation::Linear) => "DF-L table 32x16",
        }
    }

    /// Whether this is the baseline the others are divided by.
    #[must_use]
    pub fn is_baseline(&self) -> bool {
        matches!(self, Self::UniformSphere)
    }

    /// For each pair of `us`: one sample, then the density of the sampled
    /// direction evaluated again (`pdf`, as MIS does); returns a sum of the
    /// results so that nothing is optimised away. One `match` per call, the
    /// loop inside each arm.
    #[inline]
    pub fn sample_then_pdf(&self, us: &[Vec2]) -> f32 {
        // One function per case, each loop optimised on its own.
        #[inline(never)]
        fn run(us: &[Vec2], f: impl Fn(Vec2) -> (Vec3, f32)) -> f32 {
            let mut acc = 0.0f32;
            for &u in us {
                let (d, p) = f(black_box(u));
                acc += d.x + p;
            }
            acc
        }
        // `d`'s sample at `u` and its density there (the distributions
        // share no trait).
        macro_rules! sampled {
            ($d:expr) => {
                |u| {
                    let s = $d.sample(u);
                    (s.direction, $d.pdf(s.direction))
                }
            };
        }
        match self {
            Self::UniformSphere => run(us, |u| (square_to_uniform_sphere(u), UNIFORM_SPHERE_PDF)),
            Self::VmfLobe(l) => run(us, sampled!(l)),
            Self::NasgLobe(l) => run(us, sampled!(l)),
            Self::VmfMixture(m) => run(us, sampled!(m)),
            Self::NasgMixture(m) => run(us, sampled!(m)),
            Self::Factorised(t, _) => run(us, sampled!(t)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inputs::unit_pairs;

    /// One baseline, names that tell the cases apart, and finite work in
    /// every case (a NaN would mean timing a degenerate path). Whether the
    /// distributions sample their own densities is the tests crate's job
    /// (chi² per family).
    #[test]
    fn cases_are_distinct_and_finite() {
        let cases = DistributionCase::all();
        assert!(cases[0].is_baseline());
        assert_eq!(cases.iter().filter(|c| c.is_baseline()).count(), 1);
        for (i, a) in cases.iter().enumerate() {
            for b in &cases[i + 1..] {
                assert_ne!(a.name(), b.name());
            }
        }
        let us = unit_pairs(9, 4096);
        for case in &cases {
            let sum = case.sample_then_pdf(&us);
            assert!(sum.is_finite() && sum > 0.0, "{}: {sum}", case.name());
        }
    }
}
