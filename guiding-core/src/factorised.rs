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
use crate::pdf1d::{Boundary, Interpolation, Pdf1d};
use crate::sphere::{square_to_uniform_sphere, uniform_sphere_to_square};
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// `ln(4π)`, the log of the warp's Jacobian `dω / dε`.
pub const LN_FOUR_PI: f32 = 2.531_024_2;

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

/// Draws `ε₁` from the marginal with `u ∈ [0, 1)`: returns `(ε₁, p(ε₁))`
/// ([`Pdf1d::sample`]). The caller then evaluates the conditional at `ε₁`
/// and calls [`sample_conditional`].
#[inline]
#[must_use]
pub fn sample_marginal<const M: usize>(marginal: &Pdf1d<M>, u: f32) -> (f32, f32) {
    marginal.sample(u)
}

/// Draws `ε₂` from the conditional `p(· | ε₁)` with `u ∈ [0, 1)`: returns
/// `(ε₂, p(ε₂ | ε₁))`. The direction is [`direction_from_square`]`(ε₁, ε₂)`
/// and its density `p(ε₁) p(ε₂ | ε₁) / (4π)`.
#[inline]
#[must_use]
pub fn sample_conditional<const N: usize>(conditional: &Pdf1d<N>, u: f32) -> (f32, f32) {
    conditional.sample(u)
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
        let mut table = Self::zeroed();
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
        let s = eps1 * M as f32;
        if s > 0.0 {
            let i = s as u32 as usize;
            if i < M {
                i
            } else {
                M - 1
            }
        } else {
            0
        }
    }

    /// Density of the square point `eps ∈ [0, 1]²`: `p(ε₁) p(ε₂ | row(ε₁))`.
    #[inline]
    #[must_use]
    pub fn pdf_square(&self, eps: Vec2) -> f32 {
        let e1 = clamp01(eps.x);
        self.marginal.pdf(e1) * self.conditionals[Self::row(e1)].pdf(eps.y)
    }

    /// Density in solid angle, `p(ε₁) p(ε₂ | ε₁) / (4π)`.
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        // `pdf_square` on a point already in [0, 1]².
        let eps = square_from_direction(direction);
        let p1 = self.marginal.pdf_in_unit_interval(eps.x);
        let p2 = self.conditionals[Self::row(eps.x)].pdf_in_unit_interval(eps.y);
        p1 * p2 * INV_FOUR_PI
    }

    /// Alias of [`Self::pdf`]: the distribution is normalised.
    #[inline]
    #[must_use]
    pub fn eval(&self, direction: Vec3) -> f32 {
        self.pdf(direction)
    }

    /// Draws a direction from `u ∈ [0, 1)²`: `u.x → ε₁` through the marginal,
    /// `u.y → ε₂` through the conditional row of `ε₁`.
    ///
    /// The returned pdf is [`Self::pdf`] of the returned direction (as in
    /// [`VmfMixture::sample`](crate::mixture::vmf::VmfMixture::sample)), so it
    /// agrees exactly with the density used for MIS. It equals
    /// `p(ε₁) p(ε₂ | ε₁) / (4π)` of the sampled `ε` except where the rounding
    /// of the warp round trip (~10⁻⁷) carries `ε` across a bin edge of a
    /// nearest density or across a row edge. In the rare case that this
    /// lands on zero density while the sampled `ε` has positive density, the
    /// latter is returned (still finite and `> 0`).
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let (e1, p1) = self.marginal.sample(u.x);
        let (e2, p2) = self.conditionals[Self::row(e1)].sample(u.y);
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
