//! The registry of every distribution the statistical suite checks. One list,
//! so that the Šidák correction knows the total number of chi² tests in a run.

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

/// Every case of every family.
#[must_use]
pub fn all_cases() -> Vec<Case> {
    let mut cases = vmf::cases();
    cases.extend(nasg::cases());
    cases.extend(factorised::cases());
    cases
}
