//! The von Mises–Fisher lobe on the unit sphere.
//!
//! Density (Dong et al. 2023, "Neural Parametric Mixtures for Path Guiding",
//! eq. 3, written in the form that never overflows):
//!
//! ```text
//! v(ω | μ, κ) = κ / (2π (1 − e^{−2κ})) · e^{κ (μ·ω − 1)}
//! ```
//!
//! Sampling inverts the CDF of `cos θ` (Jakob 2012, "Numerically stable
//! sampling of the von Mises Fisher distribution on S²"):
//! `cos θ = 1 + ln(ξ + (1 − ξ) e^{−2κ}) / κ`, evaluated here as
//! `1 − cos θ = −ln(1 − (1 − ξ)(1 − e^{−2κ})) / κ` with `ln_1p` / `expm1`, and
//! the angular distance `1 − μ·ω` is computed by
//! [`one_minus_cos_angle`] so that lobes as
//! sharp as κ = 10⁷ keep full precision. κ = 0 is the uniform sphere.

use crate::frame::{normalize_or, Frame};
use crate::lobe::DirectionSample;
use crate::math::{atan2_turns, exp, exp_nonpositive, expm1, expm1_inline, safe_sqrt};
use crate::math::{ln_1p, unit_interval, x_over_one_minus_exp_neg, INV_FOUR_PI, ONE_MINUS_EPSILON};
use crate::sphere::{one_minus_cos_angle, spherical_direction_turns};
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Largest concentration a lobe holds; larger values are clamped. At κ = 10⁷
/// the lobe is ~3·10⁻⁴ rad wide, still 5000× the angular resolution of an
/// `f32` unit vector; beyond that the density stops being meaningful in `f32`.
pub const VMF_KAPPA_MAX: f32 = 1e7;

/// Below this concentration a lobe is exactly the uniform sphere (the
/// relative deviation of the true density is below `2κ`, far under `f32`
/// resolution).
pub const VMF_KAPPA_UNIFORM: f32 = 1e-30;

/// The polar random number is used as `max(ξ, 2⁻²⁴)`: `2⁻²⁴` is the resolution
/// of an `f32` random number in `[0, 1)`, and without the cut the single value
/// `ξ = 0` would jump to the antipode, a point of density `~e^{−2κ}` (zero in
/// `f32` for κ ≳ 44), instead of the `2⁻²⁴`-quantile where its neighbours land.
/// With it, sampled densities are `≥ norm · 2⁻²⁴ · (1 − e^{−2κ})`, positive
/// and normal.
pub const VMF_TAIL_CUT: f32 = 1.0 / 16_777_216.0;

/// A von Mises–Fisher lobe with its constants precomputed (the Open PGL
/// layout: evaluating a lobe costs one `exp`).
///
/// `repr(C)`, `Pod`, 24 bytes: mean (3 × f32), κ, normaliser, `1 − e^{−2κ}`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct VmfLobe {
    /// Unit mean direction μ.
    pub mean: [f32; 3],
    /// Concentration κ ∈ `[0, VMF_KAPPA_MAX]`.
    pub kappa: f32,
    /// `κ / (2π (1 − e^{−2κ}))`, or `1/(4π)` for the uniform lobe.
    pub norm: f32,
    /// `1 − e^{−2κ}` (computed as `−expm1(−2κ)`).
    pub one_minus_e2k: f32,
}

impl VmfLobe {
    /// Lobe with mean direction `mean` (normalised here; a zero or non-finite
    /// mean becomes `+z`) and concentration `kappa` (NaN or negative becomes 0,
    /// larger than [`VMF_KAPPA_MAX`] is clamped).
    #[must_use]
    pub fn new(mean: Vec3, kappa: f32) -> Self {
        let mean = normalize_or(mean, Vec3::Z);
        let kappa = if kappa >= 0.0 {
            kappa.min(VMF_KAPPA_MAX)
        } else {
            0.0
        };
        let (norm, one_minus_e2k) = if kappa < VMF_KAPPA_UNIFORM {
            (INV_FOUR_PI, 0.0)
        } else {
            // κ / (2π(1 − e^{−2κ})) = (2κ / (1 − e^{−2κ})) / (4π).
            (
                x_over_one_minus_exp_neg(2.0 * kappa) * INV_FOUR_PI,
                -expm1(-2.0 * kappa),
            )
        };
        Self {
            mean: mean.to_array(),
            kappa,
            norm,
            one_minus_e2k,
        }
    }

    /// Mean direction as a vector.
    #[inline]
    #[must_use]
    pub fn mean(&self) -> Vec3 {
        Vec3::from_array(self.mean)
    }

    /// Unnormalised value `e^{κ (μ·ω − 1)} ∈ [0, 1]` (1 at the mean): the
    /// lobe's shape without its normaliser, so [`Self::pdf`] is
    /// `norm · eval`. (`eval` always means this unnormalised value; see the
    /// crate docs.)
    #[inline]
    #[must_use]
    pub fn eval(&self, direction: Vec3) -> f32 {
        exp(-self.kappa * one_minus_cos_angle(self.mean(), direction))
    }

    /// Density `v(ω | μ, κ) = norm · eval(ω)` in solid angle (integrates to 1
    /// over the sphere).
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        self.norm * self.eval(direction)
    }

    /// `1 − cos θ` of the sample with CDF value `u_theta ∈ [0, 1)` (clamped
    /// there, NaN read as 0, so any input gives `t ∈ [0, 2]`).
    #[inline]
    fn sample_one_minus_cos(&self, u_theta: f32) -> f32 {
        let u_theta = unit_interval(u_theta);
        if self.kappa < VMF_KAPPA_UNIFORM {
            return 2.0 * (1.0 - u_theta);
        }
        // 1 − cos θ = −ln(1 − (1 − ξ)(1 − e^{−2κ})) / κ, ξ cut at VMF_TAIL_CUT
        // and the result capped at the antipode.
        let xi = u_theta.max(VMF_TAIL_CUT);
        // × (1/κ) rather than / κ: the reciprocal is formed in parallel with
        // the logarithm, leaving a multiplication on the dependency chain.
        let t = -ln_1p(-(1.0 - xi) * self.one_minus_e2k) * (1.0 / self.kappa);
        t.min(2.0)
    }

    /// Draws a direction from `u ∈ [0, 1)²`: `u.x` picks the azimuth, `u.y`
    /// the polar angle (`u.y → 1` is the mean). `u` outside `[0, 1)²` is
    /// clamped (NaN reads as 0), so every input gives a unit direction.
    #[inline]
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let (direction, t) = self.sample_with_one_minus_cos(u);
        DirectionSample {
            direction,
            pdf: self.norm * exp_nonpositive(-self.kappa * t),
        }
    }

    /// [`Self::sample`] without the density: the direction only (mixtures
    /// evaluate their own density afterwards).
    #[inline]
    #[must_use]
    pub fn sample_direction(&self, u: Vec2) -> Vec3 {
        self.sample_with_one_minus_cos(u).0
    }

    #[inline]
    fn sample_with_one_minus_cos(&self, u: Vec2) -> (Vec3, f32) {
        let t = self.sample_one_minus_cos(u.y);
        let sin_theta = safe_sqrt(t * (2.0 - t));
        let local = spherical_direction_turns(sin_theta, 1.0 - t, unit_interval(u.x));
        (Frame::from_z(self.mean()).to_world(local), t)
    }

    /// Inverse of [`Self::sample`]: the `u` that maps to `direction`. A zero
    /// or non-finite `direction` has no preimage and gives `(0, 0)`.
    #[must_use]
    pub fn invert(&self, direction: Vec3) -> Vec2 {
        let len2 = direction.length_squared();
        if !(len2 > 0.0 && len2 <= f32::MAX) {
            return Vec2::ZERO;
        }
        let mean = self.mean();
        let local = Frame::from_z(mean).to_local(direction);
        // φ / 2π.
        let mut phi = atan2_turns(local.y, local.x);
        if phi < 0.0 {
            phi += 1.0;
        }
        let t = one_minus_cos_angle(mean, direction);
        let one_minus_u = if self.kappa < VMF_KAPPA_UNIFORM {
            0.5 * t
        } else {
            -expm1_inline(-self.kappa * t) / self.one_minus_e2k
        };
        Vec2::new(
            phi.clamp(0.0, ONE_MINUS_EPSILON),
            (1.0 - one_minus_u).clamp(0.0, ONE_MINUS_EPSILON),
        )
    }
}

/// The unit axis and concentration of a lobe product `e^{κ (a·ω − 1)}` given as `axis`
/// (any length; `+z` if it vanishes) and `kappa`, or `None` when it is no product: `κ ≤ 0`,
/// a non-finite `κ` or a non-finite axis leave a distribution as it is. The one rule of
/// [`crate::model::batched::lobe_product_batch`] and its callers.
#[inline]
#[must_use]
pub fn product_lobe(axis: Vec3, kappa: f32) -> Option<(Vec3, f32)> {
    (kappa > 0.0 && kappa.is_finite() && axis.is_finite())
        .then(|| (crate::frame::normalize_or(axis, Vec3::Z), kappa))
}

/// The concentration `κ` of the vMF lobe whose mean cosine `coth κ − 1/κ` equals `|g|`, the
/// mean cosine of a Henyey–Greenstein phase function: Banerjee et al. (2005)'s approximation
/// `κ ≈ r (3 − r²) / (1 − r²)`, `r = |g|` (within 4 % of the exact inverse over `r ≤ 0.99`),
/// the vMF fit of an HG lobe that Open PGL multiplies its guide by in media. The lobe's
/// axis is the forward direction for `g > 0`, the backward one for `g < 0`. `|g|` is clamped
/// to 0.999 (κ ≈ 1000); NaN reads as 0 (isotropic: `κ = 0`).
#[must_use]
pub fn hg_vmf_kappa(g: f32) -> f32 {
    let r = if g.is_nan() { 0.0 } else { g.abs().min(0.999) };
    r * (3.0 - r * r) / (1.0 - r * r)
}

/// `d ln v / dκ` at fixed direction, for the density of [`VmfLobe`]:
/// `1/κ − 2/(e^{2κ} − 1) − (1 − μ·ω)`. The first two terms equal
/// `1 + 1/κ − coth κ = 1 − κ/3 + κ³/45 − 2κ⁵/945 + …` and cancel badly for small
/// κ, so below κ = 0.05 the series is used (truncation error < 10⁻⁹).
#[inline]
#[must_use]
pub fn dlog_pdf_dkappa(kappa: f32, one_minus_cos: f32) -> f32 {
    let norm_term = if kappa < 0.05 {
        let k2 = kappa * kappa;
        1.0 - kappa * (1.0 / 3.0 - k2 * (1.0 / 45.0 - k2 * (2.0 / 945.0)))
    } else {
        1.0 / kappa - 2.0 / expm1(2.0 * kappa)
    };
    norm_term - one_minus_cos
}
