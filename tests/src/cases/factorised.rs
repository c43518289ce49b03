//! Factorised piecewise densities (Figueiredo et al. 2025): complete
//! [`FactorisedTable`]s with random, peaked and spiky logits, both
//! interpolations.

use super::Case;

/// Chi² tests of the factorised family that run outside the registry (in
/// `tests/tests/factorised.rs`, with exact cell integrals): 1D (5 sizes × 4
/// configurations × 3 logit kinds) and sphere-level tables at the paper's
/// sizes (2 sizes × 2 interpolations × 2 kinds × 2 seeds).
pub const STANDALONE_CHI2_TESTS: usize = 5 * 4 * 3 + 2 * 2 * 2 * 2;
use crate::rng::Pcg32;
use crate::SphereDistribution;
use glam::{DVec3, Vec3};
use guiding_core::factorised::FactorisedTable;
use guiding_core::pdf1d::Interpolation;

/// A [`FactorisedTable`] under test (boxed: 101 × 51 tables are 22 kB).
pub struct TableDistribution<const M: usize, const N: usize> {
    /// The table.
    pub table: Box<FactorisedTable<M, N>>,
}

impl<const M: usize, const N: usize> SphereDistribution for TableDistribution<M, N> {
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
        let s = self.table.sample(rng.next_vec2());
        (s.direction, s.pdf)
    }

    fn pdf(&self, direction: Vec3) -> f32 {
        self.table.pdf(direction)
    }
}

/// Standard normal deviate (Box–Muller).
#[must_use]
pub fn normal(rng: &mut Pcg32) -> f32 {
    let u1 = 1.0 - rng.next_f64(); // (0, 1]
    let u2 = rng.next_f64();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// How the logits of a case are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogitKind {
    /// Independent normal logits, standard deviation 1.
    Random,
    /// Normal logits with a few bins raised by +10..+20 (near-delta peaks).
    Spiky,
    /// Normal logits with a few bins raised by +2..+3 (clear peaks whose
    /// kinks a cell-wise Gauss–Legendre rule still integrates well).
    Peaked,
}

/// `K` logits of the given kind.
#[must_use]
pub fn logits<const K: usize>(rng: &mut Pcg32, kind: LogitKind) -> [f32; K] {
    let mut l = [0.0; K];
    for x in &mut l {
        *x = normal(rng);
    }
    let (lo, hi) = match kind {
        LogitKind::Random => return l,
        LogitKind::Spiky => (10.0, 20.0),
        LogitKind::Peaked => (2.0, 3.0),
    };
    let spikes = 1 + (rng.next_u32() % 3) as usize;
    for _ in 0..spikes {
        let k = rng.next_u32() as usize % K;
        l[k] += rng.uniform(lo, hi);
    }
    l
}

/// A random table: marginal and every row drawn with `kind`.
#[must_use]
pub fn random_table<const M: usize, const N: usize>(
    seed: u64,
    kind: LogitKind,
    interpolation: Interpolation,
) -> Box<FactorisedTable<M, N>> {
    let mut rng = Pcg32::new(seed, 0xdf);
    let marginal = logits::<M>(&mut rng, kind);
    let mut conditional = [[0.0; N]; M];
    for row in &mut conditional {
        *row = logits::<N>(&mut rng, kind);
    }
    Box::new(FactorisedTable::from_logits(
        &marginal,
        &conditional,
        interpolation,
    ))
}

fn case<const M: usize, const N: usize>(
    seed: u64,
    kind: LogitKind,
    interpolation: Interpolation,
) -> Case {
    let name = format!(
        "df/{}/{M}x{N}/{}/seed{seed}",
        match interpolation {
            Interpolation::Nearest => "nearest",
            Interpolation::Linear => "linear",
        },
        match kind {
            LogitKind::Random => "random",
            LogitKind::Spiky => "spiky",
            LogitKind::Peaked => "peaked",
        },
    );
    Case {
        name,
        dist: Box::new(TableDistribution {
            table: random_table::<M, N>(seed, kind, interpolation),
        }),
        warp: crate::chi2::Warp::UniformSphere { axis: DVec3::Z },
    }
}

/// Every case of this family (10): for each interpolation, random and
/// peaked logits at 101 × 51 and 101 × 17, plus one more seed; near-delta
/// (`Spiky`) logits for nearest only.
///
/// The sizes are chosen for the generic runner, which integrates expected
/// counts cell by cell with Gauss–Legendre rules, exact only where the
/// density is smooth inside a cell. With `Warp::UniformSphere` about `+z`
/// the runner's `(u, v)` grid is exactly the DF square `(ε₁, ε₂)`, so with
/// `M = 101` and `N | 51` every jump of a table (nearest bin edges, the
/// conditional row edges) falls on an edge of its 101 × 51 chi² grid and of
/// its 202 × 102 normalisation grid, and nearest cells integrate exactly.
/// Linear kinks (bin centres) stay inside cells, where the rule's error is
/// below the Poisson noise only for moderate slopes — hence `Peaked`
/// (+2..+3) rather than `Spiky` (+10..+20) logits for linear tables here.
/// Unaligned sizes (32 × 16, 64 × 32) with spiky logits would be rejected
/// for quadrature error rather than sampling error; they are checked with
/// exact cell integrals by `chi2_tables` in `tests/factorised.rs`.
#[must_use]
pub fn cases() -> Vec<Case> {
    let mut cases = Vec::new();
    for interpolation in [Interpolation::Nearest, Interpolation::Linear] {
        let peaks = match interpolation {
            Interpolation::Nearest => LogitKind::Spiky,
            Interpolation::Linear => LogitKind::Peaked,
        };
        for kind in [LogitKind::Random, peaks] {
            cases.push(case::<101, 51>(1, kind, interpolation));
            cases.push(case::<101, 17>(2, kind, interpolation));
        }
        cases.push(case::<101, 17>(3, LogitKind::Peaked, interpolation));
    }
    cases
}
