//! Factorised directional densities (Figueiredo et al. 2025, "Neural Path
//! Guiding with Distribution Factorization", EGSR 2025, §3).
//!
//! A direction is parametrised by the unit square through the uniform sphere
//! warp of [`square_to_uniform_sphere`] (`φ = 2π ε₁`, `cos θ = 1 − 2 ε₂`,
//! constant Jacobian `1/(4π)`), and the density on the square is factorised
//! into a marginal and a conditional 1D density:
//!
//! ```text
//! p(ω) = p(ε₁) · p(ε₂ | ε₁) / (4π)
//! ```
//!
//! `p(ε₁)` is a [`Pdf1d`] with [`Boundary::Wrap`] (the azimuth is periodic),
//! `p(ε₂ | ε₁)` one with [`Boundary::Clamp`] (the polar angle is not).
//!
//! Two forms are offered:
//! - free functions over one marginal and one conditional [`Pdf1d`] — the
//!   per-query building blocks of the neural path, where the conditional
//!   network is evaluated at the sampled `ε₁` (so the conditional is
//!   continuous in `ε₁`);
//! - [`FactorisedTable`], a complete 2D distribution: `M` conditional rows,
//!   row `⌊ε₁ M⌋` used at `ε₁`, for tests, benchmarks and caching.

use crate::lobe::DirectionSample;
use crate::math::INV_FOUR_PI;
use crate::pdf1d::{bin_index, Boundary, Interpolation, Pdf1d, RunningSums};
use crate::sphere::{square_to_uniform_sphere, uniform_sphere_to_square};
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// `ln(4π)`, the log of the warp's Jacobian `dω / dε`.
pub const LN_FOUR_PI: f32 = 2.531_024_2;

/// How far inside its cell a sampled square point `ε` is kept: `2⁻²⁰`
/// (≈ 9.5 · 10⁻⁷, 16 ulps of 1).
///
/// The round trip `ε → ω = direction_from_square(ε) →
/// square_from_direction(ω)` moves `ε` by up to 2 ulps of 1 in `ε₁` and 1 ulp
/// in `ε₂` (measured over 2 · 10⁷ points concentrated at bin edges and near
/// the poles; `tests/tests/factorised.rs` checks 4 ulps), and at a pole
/// (`ε₂ ∈ {0, 1}`) the direction loses its azimuth altogether. The densities
/// are discontinuous at nearest-bin edges, at the edges of their support and
/// at the table's row edges, so a point sampled within a few ulps of such an
/// edge could come back from the round trip in a neighbouring cell of zero
/// density: `pdf(ω) = 0` for a sampled `ω`. The samplers therefore keep `ε`
/// at least this margin inside the sampled 1D piece (see
/// [`Pdf1d::sample_with_margin`]; the first and last pieces end at the poles
/// and at the azimuth seam, so those are avoided too) and, for the table,
/// inside the sampled row. Only points within the margin of an edge move, by
/// at most the margin and within their own cell, so the sampled distribution
/// changes by less than `2 · 2⁻²⁰ · max p` of probability mass per cell,
/// moved by less than 10⁻⁶ (far below what any histogram test resolves).
pub const SAMPLE_MARGIN: f32 = 1.0 / 1_048_576.0;

/// The direction of the square point `eps` (DF §3): `φ = 2π ε₁`,
/// `cos θ = 1 − 2 ε₂` about `+z`; see [`square_to_uniform_sphere`].
/// `eps` is clamped to `[0, 1]²` (NaN reads as 0), so the result is always a
/// unit vector.
#[inline]
#[must_use]
pub fn direction_from_square(eps: Vec2) -> Vec3 {
    square_to_uniform_sphere(Vec2::new(clamp01(eps.x), clamp01(eps.y)))
}

/// The square point of `direction`, the inverse of [`direction_from_square`],
/// in `[0, 1]²` (see [`uniform_sphere_to_square`]). `direction` need not be
/// unit: it is first divided by its largest component, so tiny and huge
/// vectors work too; a zero, infinite or NaN direction reads as `+z`
/// (`ε = (0, 0)`).
#[inline]
#[must_use]
pub fn square_from_direction(direction: Vec3) -> Vec2 {
    let m = direction
        .x
        .abs()
        .max(direction.y.abs())
        .max(direction.z.abs());
    // Always divided by m, also where the warp would not need it: the
    // rounding of this normalisation is part of the reference behaviour that
    // the sampler's zero-density nudges are tested against (a direction
    // sampled a few ulps off a linear knot of zero density must come back
    // off the knot).
    let d = if m > 0.0 && m <= f32::MAX && direction.is_finite() {
        direction / m
    } else {
        Vec3::Z
    };
    let e = uniform_sphere_to_square(d);
    Vec2::new(clamp01(e.x), clamp01(e.y))
}

/// `x` clamped to `[0, 1]`, NaN to 0.
#[inline]
fn clamp01(x: f32) -> f32 {
    if x > 0.0 {
        x.min(1.0)
    } else {
        0.0
    }
}

/// Density in solid angle, `p(ε₁) p(ε₂ | ε₁) / (4π)` at `ε =`
/// [`square_from_direction`]`(direction)`, for a marginal (wrap) and the
/// conditional evaluated at this direction's `ε₁` (clamp). The boundary
/// modes stored in the two densities are used as they are.
#[inline]
#[must_use]
pub fn pdf<const M: usize, const N: usize>(
    marginal: &Pdf1d<M>,
    conditional: &Pdf1d<N>,
    direction: Vec3,
) -> f32 {
    let eps = square_from_direction(direction);
    marginal.pdf(eps.x) * conditional.pdf(eps.y) * INV_FOUR_PI
}

/// Draws `ε₁` from the marginal with `u ∈ [0, 1)`: returns `(ε₁, p(ε₁))`,
/// `ε₁` kept [`SAMPLE_MARGIN`] inside its piece
/// ([`Pdf1d::sample_with_margin`]). The caller then evaluates the conditional
/// at `ε₁` and calls [`sample_conditional`].
#[inline]
#[must_use]
pub fn sample_marginal<const M: usize>(marginal: &Pdf1d<M>, u: f32) -> (f32, f32) {
    marginal.sample_with_margin(u, SAMPLE_MARGIN)
}

/// Draws `ε₂` from the conditional `p(· | ε₁)` with `u ∈ [0, 1)`: returns
/// `(ε₂, p(ε₂ | ε₁))`, `ε₂` kept [`SAMPLE_MARGIN`] inside its piece (so also
/// off the poles). The direction is [`direction_from_square`]`(ε₁, ε₂)` and
/// its density `p(ε₁) p(ε₂ | ε₁) / (4π)`.
#[inline]
#[must_use]
pub fn sample_conditional<const N: usize>(conditional: &Pdf1d<N>, u: f32) -> (f32, f32) {
    conditional.sample_with_margin(u, SAMPLE_MARGIN)
}

/// `ln p(ω)` of the factorised density built from raw logits — marginal with
/// [`Boundary::Wrap`], conditional with [`Boundary::Clamp`], both with
/// `interpolation` and the `N · softmax` activation — and its gradients
/// with respect to both sets of logits (the conditional logits being the
/// conditional network's output at this direction's `ε₁`).
///
/// `ln p = ln p(ε₁) + ln p(ε₂ | ε₁) − ln 4π`, each term from
/// [`Pdf1d::grad_log_pdf`] (log space, finite for any logits).
pub fn grad_log_pdf<const M: usize, const N: usize>(
    marginal_logits: &[f32; M],
    conditional_logits: &[f32; N],
    interpolation: Interpolation,
    direction: Vec3,
    grad_marginal: &mut [f32; M],
    grad_conditional: &mut [f32; N],
) -> f32 {
    let eps = square_from_direction(direction);
    let lm = Pdf1d::grad_log_pdf(
        marginal_logits,
        eps.x,
        interpolation,
        Boundary::Wrap,
        grad_marginal,
    );
    let lc = Pdf1d::grad_log_pdf(
        conditional_logits,
        eps.y,
        interpolation,
        Boundary::Clamp,
        grad_conditional,
    );
    lm + lc - LN_FOUR_PI
}

/// A complete factorised distribution on the sphere: a marginal over `ε₁`
/// with `M` bins ([`Boundary::Wrap`]) and `M` conditional rows over `ε₂`
/// with `N` bins each ([`Boundary::Clamp`]); at `ε₁` the row `⌊ε₁ M⌋` is the
/// conditional.
///
/// Deviation from the paper: the DF network's conditional is a continuous
/// function of `ε₁` (the network is queried at the sampled `ε₁`); this table
/// is its discretisation, piecewise constant in `ε₁` over the `M` marginal
/// bins. It is exact as a distribution in its own right — the density below
/// is the one sampled — and serves tests, benchmarks and caching.
///
/// `repr(C)`, `Pod`: `(M + 2) + M (N + 2)` four-byte words.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FactorisedTable<const M: usize, const N: usize> {
    /// Marginal density of `ε₁` (wrap).
    pub marginal: Pdf1d<M>,
    /// Conditional density of `ε₂` per marginal bin (clamp).
    pub conditionals: [Pdf1d<N>; M],
}

// SAFETY: `repr(C)` struct of `Pdf1d`s, which are `Pod`, 4-byte aligned and
// a multiple of 4 bytes in size, so there is no padding; zero is valid.
unsafe impl<const M: usize, const N: usize> Zeroable for FactorisedTable<M, N> {}
// SAFETY: see above; `Copy + 'static` holds for every `M`, `N`.
unsafe impl<const M: usize, const N: usize> Pod for FactorisedTable<M, N> {}

/// The running sums of a [`FactorisedTable`]'s marginal and rows
/// ([`FactorisedTable::running_sums`]), kept next to a table that is sampled
/// many times.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableSums<const M: usize, const N: usize> {
    /// The marginal's.
    pub marginal: RunningSums<M>,
    /// Each row's.
    pub rows: [RunningSums<N>; M],
}

impl<const M: usize, const N: usize> TableSums<M, N> {
    /// All zeros (a placeholder to overwrite).
    pub const ZERO: Self = Self {
        marginal: RunningSums::ZERO,
        rows: [RunningSums::ZERO; M],
    };
}

impl<const M: usize, const N: usize> FactorisedTable<M, N> {
    /// All-zero table (written out: `Zeroable::zeroed` goes through
    /// `MaybeUninit`, which rust-gpu cannot compile).
    pub const ZERO: Self = Self {
        marginal: Pdf1d::ZERO,
        conditionals: [Pdf1d::ZERO; M],
    };
}

impl<const M: usize, const N: usize> FactorisedTable<M, N> {
    /// Table from raw logits: the marginal from `marginal_logits` and row `i`
    /// from `conditional_logits[i]`, each by `N · softmax` (see
    /// [`Pdf1d::from_logits`]; any input gives a valid table).
    #[must_use]
    pub fn from_logits(
        marginal_logits: &[f32; M],
        conditional_logits: &[[f32; N]; M],
        interpolation: Interpolation,
    ) -> Self {
        let mut table = Self::ZERO;
        table.marginal = Pdf1d::from_logits(marginal_logits, interpolation, Boundary::Wrap);
        let mut i = 0;
        while i < M {
            table.conditionals[i] =
                Pdf1d::from_logits(&conditional_logits[i], interpolation, Boundary::Clamp);
            i += 1;
        }
        table
    }

    /// Index of the conditional row used at `ε₁ ∈ [0, 1]`: `⌊ε₁ M⌋`, clamped
    /// to `[0, M − 1]`.
    #[inline]
    #[must_use]
    pub fn row(eps1: f32) -> usize {
        bin_index::<M>(eps1 * M as f32)
    }

    /// Density of the square point `eps ∈ [0, 1]²`: `p(ε₁) p(ε₂ | row(ε₁))`.
    #[inline]
    #[must_use]
    pub fn pdf_square(&self, eps: Vec2) -> f32 {
        let e1 = clamp01(eps.x);
        self.marginal.pdf(e1) * self.conditionals[Self::row(e1)].pdf(eps.y)
    }

    /// Density in solid angle, `p(ε₁) p(ε₂ | ε₁) / (4π)`. The table is
    /// normalised, so this is its only value: there is no unnormalised `eval`
    /// (see the crate docs).
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        self.pdf_at_square(square_from_direction(direction))
    }

    /// [`Self::pdf`] of the direction whose square point is `eps` (as
    /// [`square_from_direction`] returns it, in `[0, 1]²`).
    #[inline]
    #[must_use]
    pub fn pdf_at_square(&self, eps: Vec2) -> f32 {
        let p1 = self.marginal.pdf_in_unit_interval(eps.x);
        let p2 = self.conditionals[Self::row(eps.x)].pdf_in_unit_interval(eps.y);
        p1 * p2 * INV_FOUR_PI
    }

    /// Draws a direction from `u ∈ [0, 1)²`: `u.x → ε₁` through the marginal,
    /// `u.y → ε₂` through the conditional row of `ε₁`.
    ///
    /// `ε` is kept [`SAMPLE_MARGIN`] inside its cell: inside the sampled
    /// pieces of both 1D densities ([`sample_marginal`],
    /// [`sample_conditional`]) and, for `ε₁`, inside its row
    /// `[r/M, (r + 1)/M]` (a linear marginal's pieces straddle row edges).
    /// The warp round trip (≤ 2 ulps) then never leaves the cell.
    ///
    /// The returned pdf is [`Self::pdf`] of the returned direction (as in
    /// [`VmfMixture::sample`](crate::mixture::vmf::VmfMixture::sample)), so it
    /// agrees exactly with the density used for MIS; for nearest
    /// interpolation it equals `p(ε₁) p(ε₂ | ε₁) / (4π)` of the sampled `ε`,
    /// for linear up to the slope times the round trip's ~10⁻⁷. Should the
    /// product underflow to zero while the sampled `ε` has positive density,
    /// the latter is returned (still finite and `> 0`).
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let (e1, p1) = self.sample_first(u.x);
        self.sample_second(e1, p1, u.y)
    }

    /// The first half of [`Self::sample`]: `ε₁` and its marginal density
    /// from `ux` (a batch can fetch the row of `ε₁` before the second half).
    #[inline]
    #[must_use]
    pub fn sample_first(&self, ux: f32) -> (f32, f32) {
        sample_marginal(&self.marginal, ux)
    }

    /// [`Self::sample_first`] from the table's [`Self::running_sums`] (the
    /// same bits, without the pass over the marginal's pieces).
    #[inline]
    #[must_use]
    pub fn sample_first_with(&self, sums: &TableSums<M, N>, ux: f32) -> (f32, f32) {
        self.marginal
            .sample_with_sums(&sums.marginal, ux, SAMPLE_MARGIN)
    }

    /// The second half of [`Self::sample`] from [`Self::sample_first`]'s
    /// `(ε₁, p(ε₁))` and `uy`.
    #[must_use]
    pub fn sample_second(&self, e1: f32, p1: f32, uy: f32) -> DirectionSample {
        let (e1, p1, r) = self.keep_in_row(e1, p1);
        let (e2, p2) = sample_conditional(&self.conditionals[r], uy);
        self.finish_sample(e1, p1, e2, p2)
    }

    /// [`Self::sample_second`] from the table's [`Self::running_sums`] (the
    /// same bits).
    #[must_use]
    pub fn sample_second_with(
        &self,
        sums: &TableSums<M, N>,
        e1: f32,
        p1: f32,
        uy: f32,
    ) -> DirectionSample {
        let (e1, p1, r) = self.keep_in_row(e1, p1);
        let (e2, p2) = self.conditionals[r].sample_with_sums(&sums.rows[r], uy, SAMPLE_MARGIN);
        self.finish_sample(e1, p1, e2, p2)
    }

    /// The running sums of the marginal and of every row, for
    /// [`Self::sample_first_with`] / [`Self::sample_second_with`].
    #[must_use]
    pub fn running_sums(&self) -> TableSums<M, N> {
        let mut sums = TableSums {
            marginal: self.marginal.running_sums(),
            rows: [RunningSums::ZERO; M],
        };
        let mut i = 0;
        while i < M {
            sums.rows[i] = self.conditionals[i].running_sums();
            i += 1;
        }
        sums
    }

    /// `ε₁` kept [`SAMPLE_MARGIN`] inside its row (see [`Self::sample`]), its
    /// density, and the row.
    #[inline]
    fn keep_in_row(&self, e1: f32, p1: f32) -> (f32, f32, usize) {
        let r = Self::row(e1);
        let m = SAMPLE_MARGIN.min(0.25 / M as f32);
        let (lo, hi) = (r as f32 / M as f32 + m, (r + 1) as f32 / M as f32 - m);
        if e1 >= lo && e1 <= hi {
            (e1, p1, r)
        } else {
            // Within the margin of a row edge (only where a linear piece
            // straddles it): moved inside the row, within the same piece.
            let e1 = e1.clamp(lo, hi);
            (e1, self.marginal.pdf_in_unit_interval(e1), r)
        }
    }

    /// The direction of `(ε₁, ε₂)` and its density as [`Self::pdf`]
    /// evaluates it (the sampled one where that underflows).
    #[inline]
    fn finish_sample(&self, e1: f32, p1: f32, e2: f32, p2: f32) -> DirectionSample {
        let direction = direction_from_square(Vec2::new(e1, e2));
        let mut pdf = self.pdf(direction);
        if pdf <= 0.0 || pdf.is_nan() {
            pdf = p1 * p2 * INV_FOUR_PI;
        }
        DirectionSample { direction, pdf }
    }

    /// Inverse of [`Self::sample`]: `u.x` is the marginal CDF at `ε₁`, `u.y`
    /// the CDF of row `⌊ε₁ M⌋` at `ε₂`, with `ε =`
    /// [`square_from_direction`]`(direction)`; `u ∈ [0, 1)²`.
    #[must_use]
    pub fn invert(&self, direction: Vec3) -> Vec2 {
        let eps = square_from_direction(direction);
        Vec2::new(
            self.marginal.invert(eps.x),
            self.conditionals[Self::row(eps.x)].invert(eps.y),
        )
    }
}
