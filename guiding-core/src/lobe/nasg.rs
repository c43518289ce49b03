//! The normalised anisotropic spherical Gaussian (NASG) lobe.
//!
//! Huang et al. 2024, "Online Neural Path Guiding with Normalized Anisotropic
//! Spherical Gaussians", ACM TOG 43(3). A lobe has an orthonormal frame
//! `(x, y, z)` (`z` is the axis), a sharpness `λ > 0`, an anisotropy `a ≥ 0`
//! and a small constant `ε > 0`. For a unit direction `v` with local
//! coordinates `(v_x, v_y, v_z) = (v·x, v·y, v·z)`, write
//!
//! ```text
//! t = (1 + v_z) / 2 ∈ [0, 1],   cos²φ = v_x² / (v_x² + v_y²),   b(φ) = 1 + ε + a cos²φ,
//! G(v) = exp(2λ (t^b − 1)) · t^(b−1)
//! K    = ∫ G dω = 2π (1 − e^{−2λ}) / (λ √((1 + ε)(1 + ε + a)))         (NASG eq. 19)
//! p(v) = G(v) / K.
//! ```
//!
//! `K` follows from `dω = dφ · 2 dt`, the substitution `u = t^b`
//! (`∫₀¹ e^{2λ(t^b−1)} t^{b−1} 2 dt = (1 − e^{−2λ}) / (λ b)`) and
//! `∫₀^{2π} dφ / (p + q cos²φ) = 2π / √(p (p + q))` with `p = 1 + ε`, `q = a`.
//! With `a = ε = 0` the lobe is exactly the vMF lobe of concentration `κ = λ`.
//!
//! Deviations and conventions (all documented where they act):
//! - `ε` is written out: the paper's `b = 1 + a cos²φ` is the `ε → 0` limit.
//!   With `ε > 0` the factor `t^(b−1)` vanishes at the antipode (`t = 0`) for
//!   every azimuth, so `G` is continuous there (with `ε = 0` and `a > 0` the
//!   antipode value would depend on the direction of approach).
//! - At the poles of the frame (`v_x = v_y = 0`) `cos²φ` is defined as 0.
//! - A zero, infinite or NaN direction is treated as the antipode, as in
//!   [`one_minus_cos_angle`](crate::sphere::one_minus_cos_angle).
//! - `t` and `1 − t` are both computed without cancellation: `1 − t` by the
//!   stable form of `one_minus_cos_angle` on the axis side, `t` by its mirror
//!   image `1 + cos θ = sin²θ / (1 − cos θ)` on the antipode side, and
//!   `ln t = ln_1p(−(1 − t))`, clamped to `≥ ln(f32::MIN_POSITIVE)`.
//!
//! Sampling is exact (NASG appendix C, rederived from the closed form): the
//! azimuth marginal is `∝ 1 / b(φ)` with period π, inverted in closed form by
//! `φ₀ = atan(√((p + q)/p) · tan(π(w − ½))) ∈ (−π/2, π/2)` (east half) and
//! `φ₀ + π` (west half); given φ, `u = t^b` has density `∝ e^{2λ(u − 1)}` on
//! `[0, 1]`, a truncated exponential inverted like the vMF's polar angle.

use crate::frame::Frame;
use crate::lobe::DirectionSample;
use crate::math::{atan2, exp, exp_nonpositive, expm1, expm1_nonpositive, ln};
use crate::math::{ln_1p, ln_normal, safe_sqrt, sanitize, sin_cos, sin_cos_turns, sqrt};
use crate::math::{x_over_one_minus_exp_neg, FOUR_PI, ONE_MINUS_EPSILON};
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Smallest sharpness λ a lobe holds; smaller values (and NaN) become this.
/// The lobe is then within `2λ = 2·10⁻⁴` (relative) of its `λ → 0` limit.
pub const NASG_LAMBDA_MIN: f32 = 1e-4;
/// Largest sharpness λ a lobe holds; larger values are clamped. A lobe with
/// λ = 10⁵ and no anisotropy is ~3·10⁻³ rad wide.
pub const NASG_LAMBDA_MAX: f32 = 1e5;
/// Largest anisotropy `a`; larger values are clamped, negative values and NaN
/// become 0. With λ = `NASG_LAMBDA_MAX` the narrow direction is then
/// ~10⁻⁵ rad wide, ~100 `f32` ulps of a unit vector.
pub const NASG_A_MAX: f32 = 1e5;
/// Smallest `ε`; smaller values are clamped.
pub const NASG_EPSILON_MIN: f32 = 1e-6;
/// Largest `ε`; larger values are clamped.
pub const NASG_EPSILON_MAX: f32 = 1.0;
/// The `ε` that [`NasgMixture::decode`](crate::mixture::nasg::NasgMixture::decode)
/// uses, and the value a NaN `ε` becomes. Small enough to leave the shape
/// within 0.1% of the paper's `ε → 0` lobe away from the antipode, large
/// enough to keep `G` continuous there.
pub const NASG_EPSILON: f32 = 1e-3;
/// Probability at which the polar sampling cuts each tail of `u = t^b`
/// (`2⁻²⁴`, the resolution of an `f32` random number in `[0, 1)`): the polar
/// number is used as `1 − ξ ≤ 1 − 2⁻²⁴` and `u ≥ 2⁻²⁴` is enforced (see
/// [`NasgLobe::sample`]).
pub const NASG_TAIL_CUT: f32 = 1.0 / 16_777_216.0;
/// `ln(f32::MIN_POSITIVE)`: the floor of `ln t`, so that `0 · ln 0` never
/// happens.
const LN_MIN_POSITIVE: f32 = -87.336_54;
/// Floor of `t` in the gradient, where `1/t` and `ln t / sin θ` appear; the
/// gradient at directions closer than ~10⁻¹⁵ rad to a lobe's antipode is the
/// one at that distance (it is unbounded at the antipode itself).
const GRAD_T_MIN: f32 = 1e-30;

/// A NASG lobe with its constants precomputed.
///
/// `repr(C)`, `Pod`, 56 bytes: frame `x`, `y`, `z` (3 × 3 f32), λ, `a`, `ε`,
/// `ln(1/K)`, `1 − e^{−2λ}`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct NasgLobe {
    /// First tangent: the narrow direction (`cos²φ = 1`, `b = 1 + ε + a`).
    pub x: [f32; 3],
    /// Second tangent `z × x`: the wide direction (`b = 1 + ε`).
    pub y: [f32; 3],
    /// The axis.
    pub z: [f32; 3],
    /// Sharpness λ ∈ `[NASG_LAMBDA_MIN, NASG_LAMBDA_MAX]`.
    pub lambda: f32,
    /// Anisotropy `a` ∈ `[0, NASG_A_MAX]`.
    pub a: f32,
    /// `ε` ∈ `[NASG_EPSILON_MIN, NASG_EPSILON_MAX]`.
    pub epsilon: f32,
    /// `ln(1/K) = −ln K`, the log-normaliser.
    pub log_norm: f32,
    /// `1 − e^{−2λ}` (computed as `−expm1(−2λ)`).
    pub one_minus_e2l: f32,
}

/// Local coordinates of a direction in a lobe frame, in the forms the density,
/// the sampler's inverse and the gradient need.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Local {
    /// `t = (1 + cos θ)/2 ∈ [0, 1]`.
    pub t: f32,
    /// `1 − t = (1 − cos θ)/2 ∈ [0, 1]`, without cancellation.
    pub h: f32,
    /// `ln t ≥ ln(f32::MIN_POSITIVE)`.
    pub ln_t: f32,
    /// `cos θ = v_z`.
    pub cos_theta: f32,
    /// `sin θ = √(v_x² + v_y²)`.
    pub sin_theta: f32,
    /// `cos φ`; `0` at the poles.
    pub cos_phi: f32,
    /// `sin φ`; `1` at the poles.
    pub sin_phi: f32,
    /// `cos²φ ∈ [0, 1]`; `0` at the poles.
    pub cos2_phi: f32,
}

/// The antipode of every frame: what zero and non-finite directions map to.
const ANTIPODE: Local = Local {
    t: 0.0,
    h: 1.0,
    ln_t: LN_MIN_POSITIVE,
    cos_theta: -1.0,
    sin_theta: 0.0,
    cos_phi: 0.0,
    sin_phi: 1.0,
    cos2_phi: 0.0,
};

/// `d / |d|` and `true`, or `(0, false)` for a zero, infinite or NaN `d`.
///
/// Scales by the largest component first, so directions with only subnormal
/// or only huge (`> 10¹⁹`) components are still normalised.
#[inline]
pub(crate) fn unit_direction(d: Vec3) -> (Vec3, bool) {
    // `f32::max` ignores NaN, so NaN components are rejected separately.
    let m = d.x.abs().max(d.y.abs()).max(d.z.abs());
    if !(m > 0.0 && d.is_finite()) {
        return (Vec3::ZERO, false);
    }
    let s = Vec3::new(d.x / m, d.y / m, d.z / m);
    // |s|² ∈ [1, 3]; NaN cannot appear (every component is finite).
    (s * (1.0 / sqrt(s.length_squared())), true)
}

/// Local coordinates of the unit direction `u` in the frame `(x, y, z)`
/// (`valid == false`: the antipode convention).
#[inline]
pub(crate) fn local_coords(x: Vec3, y: Vec3, z: Vec3, u: Vec3, valid: bool) -> Local {
    if !valid {
        return ANTIPODE;
    }
    let vx = u.dot(x);
    let vy = u.dot(y);
    let vz = u.dot(z);
    // Azimuth from the scaled tangential components (no under/overflow).
    let m = vx.abs().max(vy.abs());
    let (cos_phi, sin_phi, cos2_phi, sin_theta) = if m > 0.0 {
        let ex = vx / m;
        let ey = vy / m;
        let r2 = ex * ex + ey * ey; // ∈ [1, 2]
        let r = sqrt(r2);
        (ex / r, ey / r, (ex * ex / r2).min(1.0), m * r)
    } else {
        (0.0, 1.0, 0.0, 0.0)
    };
    let sin2 = sin_theta * sin_theta;
    let (t, h, ln_t) = if vz > 0.0 {
        // 1 − cos θ = sin²θ / (1 + cos θ): full relative precision near the axis.
        let h = (0.5 * sin2 / (1.0 + vz)).min(1.0);
        (1.0 - h, h, ln_1p(-h))
    } else {
        // 1 + cos θ = sin²θ / (1 − cos θ): full relative precision near the antipode.
        let t = (0.5 * sin2 / (1.0 - vz)).min(1.0);
        (t, 1.0 - t, ln(t.max(f32::MIN_POSITIVE)))
    };
    Local {
        t,
        h,
        ln_t,
        cos_theta: vz.clamp(-1.0, 1.0),
        sin_theta,
        cos_phi,
        sin_phi,
        cos2_phi,
    }
}

/// `ln G = 2λ (t^b − 1) + (b − 1) ln t` with `b − 1 = ε + a cos²φ`, evaluated as
/// `2λ expm1(b ln t) + (b − 1) ln t` (exact near the axis, where `t^b → 1`).
/// Finite for `ln t ≥ ln(f32::MIN_POSITIVE)` and parameters in the lobe's range.
#[inline]
pub(crate) fn log_eval(lambda: f32, a: f32, epsilon: f32, ln_t: f32, cos2_phi: f32) -> f32 {
    let b_minus_1 = epsilon + a * cos2_phi;
    2.0 * lambda * expm1((1.0 + b_minus_1) * ln_t) + b_minus_1 * ln_t
}

/// `ln G` at the local coordinates `(v_x, v_y, v_z)` of a unit direction
/// (`(0, 0, 0)`: the antipode convention), in one branch-free pass with
/// inlined math only, so that the `K`-lobe loop of
/// [`NasgMixture::pdf`](crate::mixture::nasg::NasgMixture::pdf) vectorises;
/// also the density of [`NasgLobe::pdf`], so that a mixture and its lobes
/// agree to the last bit per term.
///
/// The same quantities as [`local_coords`] + [`log_eval`], formed without
/// their branches:
/// - `cos²φ = v_x² / (v_x² + v_y²)` (`0` at the poles), with `v_x, v_y`
///   scaled by `2⁶⁰` first when `v_x² + v_y² < 10⁻³⁰` (within 10⁻¹⁵ rad of
///   a pole), so that the azimuth survives where the squares underflow;
/// - `q = ½ sin²θ / (1 + |cos θ|)`: `1 − t` on the axis side (`v_z > 0`),
///   `t` on the antipode side, each without cancellation;
/// - `ln t = ln(1 − q)` (its rounding error recovered exactly and added as
///   `e / (1 − q)`, i.e. `ln_1p(−q)`) or `ln max(q, f32::MIN_POSITIVE)`, by a
///   single logarithm of the selected argument;
/// - `ln G = 2λ expm1(b ln t) + (b − 1) ln t`.
#[inline(always)]
pub(crate) fn log_g_local(vx: f32, vy: f32, vz: f32, lambda: f32, a: f32, epsilon: f32) -> f32 {
    let sin2 = vx * vx + vy * vy;
    // cos²φ; rescued from underflow near the poles by an exact power-of-two
    // scale (2⁶⁰), and 0 at the poles themselves.
    let tiny = sin2 < 1e-30;
    let scale = if tiny { 1.152_921_5e18 } else { 1.0 };
    let sx = vx * scale;
    let sy = vy * scale;
    let sx2 = sx * sx;
    let s2 = sx2 + sy * sy;
    let cos2_phi = if s2 > 0.0 { (sx2 / s2).min(1.0) } else { 0.0 };
    let front = vz > 0.0;
    let q = (0.5 * sin2 / (1.0 + vz.abs())).min(1.0);
    // Axis side: ln(1 − q) = ln u + e/u with u = fl(1 − q) and its rounding
    // error e = (1 − u) − q (exact, Fast2Sum); antipode side: ln q.
    let one_minus_q = 1.0 - q;
    let u = if front {
        one_minus_q
    } else {
        q.max(f32::MIN_POSITIVE)
    };
    #[cfg(not(target_arch = "spirv"))]
    let ln_t = {
        let err = if front { (1.0 - one_minus_q) - q } else { 0.0 };
        // u ∈ [MIN_POSITIVE, 1] is normal: the raw logarithm needs no selects.
        ln_normal(u, err / u)
    };
    // SPIR-V compilers may fold the compensation `(1 − (1 − q)) − q` to 0
    // (see `math::ln_1p_series`): the axis side there is `ln_1p(−q)` by a
    // series that nothing can cancel.
    #[cfg(target_arch = "spirv")]
    let ln_t = if front {
        crate::math::ln_1p_series(-q)
    } else {
        ln_normal(u, 0.0)
    };
    let b_minus_1 = epsilon + a * cos2_phi;
    2.0 * lambda * expm1_nonpositive((1.0 + b_minus_1) * ln_t) + b_minus_1 * ln_t
}

/// `−ln K = ln(2λ / (1 − e^{−2λ})) − ln 4π + ½ ln(1 + ε) + ½ ln(1 + ε + a)`
/// (NASG eq. 19 with ε), accurate for every λ > 0 (the ratio is evaluated by
/// [`x_over_one_minus_exp_neg`]).
#[inline]
pub(crate) fn log_norm(lambda: f32, a: f32, epsilon: f32) -> f32 {
    ln(x_over_one_minus_exp_neg(2.0 * lambda)) - ln(FOUR_PI)
        + 0.5 * (ln_1p(epsilon) + ln_1p(epsilon + a))
}

/// The frame of NASG eq. 13: `R = R_z(α) R_y(β) R_z(γ)`, returns
/// `(R e_x, R e_y, R e_z)`. With `β = 0` the axis is exactly `+z`.
#[inline]
pub(crate) fn euler_frame(alpha: f32, beta: f32, gamma: f32) -> (Vec3, Vec3, Vec3) {
    let (sa, ca) = sin_cos(alpha);
    let (sb, cb) = sin_cos(beta);
    let (sg, cg) = sin_cos(gamma);
    let x = Vec3::new(ca * cb * cg - sa * sg, sa * cb * cg + ca * sg, -sb * cg);
    let y = Vec3::new(-ca * cb * sg - sa * cg, -sa * cb * sg + ca * cg, sb * sg);
    let z = Vec3::new(ca * sb, sa * sb, cb);
    (x, y, z)
}

/// `x` clamped to `[0, ONE_MINUS_EPSILON]`, NaN becomes 0.
#[inline]
fn unit_interval(x: f32) -> f32 {
    if x >= 0.0 {
        x.min(ONE_MINUS_EPSILON)
    } else {
        0.0
    }
}

/// The stretch `√((1 + ε + a)/(1 + ε))` of the azimuth CDF.
#[inline]
fn phi_stretch(a: f32, epsilon: f32) -> f32 {
    sqrt(1.0 + a / (1.0 + epsilon))
}

impl NasgLobe {
    /// Lobe with frame `(x, y, z)` (assumed orthonormal, right-handed) and the
    /// parameters clamped to their ranges: λ to
    /// `[NASG_LAMBDA_MIN, NASG_LAMBDA_MAX]` (NaN → `NASG_LAMBDA_MIN`), `a` to
    /// `[0, NASG_A_MAX]` (NaN → 0), `ε` to `[NASG_EPSILON_MIN, NASG_EPSILON_MAX]`
    /// (NaN → [`NASG_EPSILON`]).
    pub(crate) fn with_frame(x: Vec3, y: Vec3, z: Vec3, lambda: f32, a: f32, epsilon: f32) -> Self {
        let lambda = if lambda >= NASG_LAMBDA_MIN {
            lambda.min(NASG_LAMBDA_MAX)
        } else {
            NASG_LAMBDA_MIN
        };
        let a = if a >= 0.0 { a.min(NASG_A_MAX) } else { 0.0 };
        let epsilon = if epsilon.is_nan() {
            NASG_EPSILON
        } else {
            epsilon.clamp(NASG_EPSILON_MIN, NASG_EPSILON_MAX)
        };
        Self {
            x: x.to_array(),
            y: y.to_array(),
            z: z.to_array(),
            lambda,
            a,
            epsilon,
            log_norm: log_norm(lambda, a, epsilon),
            one_minus_e2l: -expm1(-2.0 * lambda),
        }
    }

    /// Lobe around `z_axis` (normalised here; zero or non-finite becomes `+z`)
    /// whose narrow tangent `x` is `x_hint` made orthogonal to the axis by
    /// Gram–Schmidt (twice, so that a hint nearly parallel to the axis still
    /// gives an orthogonal frame). A zero or non-finite hint, or one within
    /// ~10⁻⁵ rad of `±z`, falls back to [`Frame::from_z`]. `y = z × x`. Parameters are clamped as
    /// documented on the `NASG_*` constants.
    #[must_use]
    pub fn new(z_axis: Vec3, x_hint: Vec3, lambda: f32, a: f32, epsilon: f32) -> Self {
        let (z, z_ok) = unit_direction(z_axis);
        let z = if z_ok { z } else { Vec3::Z };
        let (hint, _) = unit_direction(x_hint);
        let x1 = hint - z * hint.dot(z);
        // The first pass leaves an absolute error of ~10⁻⁷; with |x1| > 10⁻⁵ the
        // second pass makes x orthogonal to z to f32 precision. Hints closer
        // than that to ±z do not define a tangent.
        let x = if x1.length_squared() > 1e-10 {
            let x2 = x1 - z * x1.dot(z);
            let (x2, ok) = unit_direction(x2);
            if ok {
                x2
            } else {
                Frame::from_z(z).x
            }
        } else {
            Frame::from_z(z).x
        };
        let y = z.cross(x);
        Self::with_frame(x, y, z, lambda, a, epsilon)
    }

    /// Lobe with the frame of NASG eq. 13, `R = R_z(α) R_y(β) R_z(γ)`,
    /// `(x, y, z) = (R e_x, R e_y, R e_z)`: the axis has polar angle β and
    /// azimuth α, and γ turns the tangents about it. NaN angles become 0,
    /// infinite ones ±10³⁰. Parameters are clamped as documented on the
    /// `NASG_*` constants.
    #[must_use]
    pub fn from_euler(
        alpha: f32,
        beta: f32,
        gamma: f32,
        lambda: f32,
        a: f32,
        epsilon: f32,
    ) -> Self {
        let (x, y, z) = euler_frame(
            sanitize(alpha, 1e30),
            sanitize(beta, 1e30),
            sanitize(gamma, 1e30),
        );
        Self::with_frame(x, y, z, lambda, a, epsilon)
    }

    /// The lobe frame.
    #[inline]
    #[must_use]
    pub fn frame(&self) -> Frame {
        Frame {
            x: Vec3::from_array(self.x),
            y: Vec3::from_array(self.y),
            z: Vec3::from_array(self.z),
        }
    }

    /// Local coordinates of `direction` (any vector).
    #[inline]
    pub(crate) fn local(&self, direction: Vec3) -> Local {
        let (u, valid) = unit_direction(direction);
        local_coords(
            Vec3::from_array(self.x),
            Vec3::from_array(self.y),
            Vec3::from_array(self.z),
            u,
            valid,
        )
    }

    /// Normaliser `K = ∫ G dω` (NASG eq. 19 with ε).
    #[inline]
    #[must_use]
    pub fn normalization(&self) -> f32 {
        exp(-self.log_norm)
    }

    /// `ln G(direction)`, finite (≥ about `−2λ − 87 (ε + a)`).
    #[inline]
    #[must_use]
    pub fn log_eval(&self, direction: Vec3) -> f32 {
        let (u, _) = unit_direction(direction);
        // An invalid direction is (0, 0, 0): the antipode.
        log_g_local(
            u.dot(Vec3::from_array(self.x)),
            u.dot(Vec3::from_array(self.y)),
            u.dot(Vec3::from_array(self.z)),
            self.lambda,
            self.a,
            self.epsilon,
        )
    }

    /// Unnormalised value `G(direction) ∈ [0, 1]` (1 on the axis): the lobe's
    /// shape without its normaliser `K`, so [`Self::pdf`] is `eval / K`.
    /// (`eval` always means this unnormalised value; see the crate docs.)
    #[inline]
    #[must_use]
    pub fn eval(&self, direction: Vec3) -> f32 {
        exp(self.log_eval(direction))
    }

    /// `ln p(direction) = ln G − ln K`.
    #[inline]
    #[must_use]
    pub fn log_pdf(&self, direction: Vec3) -> f32 {
        self.log_eval(direction) + self.log_norm
    }

    /// Density `G / K` in solid angle (integrates to 1 over the sphere);
    /// finite and `≥ 0` for every input.
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        exp(self.log_pdf(direction))
    }

    /// Samples from the azimuth number `w` of the chosen half (`west`: the
    /// half `φ ∈ [π/2, 3π/2)`) and the polar number `xi`.
    fn sample_half(&self, w: f32, west: bool, xi: f32) -> DirectionSample {
        let (lambda, a, epsilon) = (self.lambda, self.a, self.epsilon);
        // Azimuth: tan φ₀ = c tan ψ, ψ = π(w − ½), taken as the direction
        // (cos ψ, c sin ψ) so that no tangent is ever evaluated. ψ in turns
        // is ½(w − ½) (the scaling by ½ is exact).
        let c = phi_stretch(a, epsilon);
        let (s_psi, c_psi) = sin_cos_turns(0.5 * (unit_interval(w) - 0.5));
        let c_psi = c_psi.max(0.0);
        let y_psi = c * s_psi;
        // ≥ 1 up to rounding (c ≥ 1), never 0.
        let inv_n = 1.0 / sqrt(c_psi * c_psi + y_psi * y_psi);
        let mut cos_phi = c_psi * inv_n;
        let mut sin_phi = y_psi * inv_n;
        let cos2_phi = (cos_phi * cos_phi).min(1.0);
        if west {
            cos_phi = -cos_phi;
            sin_phi = -sin_phi;
        }
        let b_minus_1 = epsilon + a * cos2_phi;
        let b = 1.0 + b_minus_1;
        // u = t^b: 1 − u = −ln(1 − (1 − ξ)(1 − e^{−2λ})) / (2λ), with both tails
        // cut at NASG_TAIL_CUT = 2⁻²⁴ (ONE_MINUS_EPSILON = 1 − 2⁻²⁴). The
        // divisions by 2λ and b are multiplications by reciprocals formed off
        // the dependency chain of the two logarithms.
        let one_minus_xi = (1.0 - unit_interval(xi)).min(ONE_MINUS_EPSILON);
        let one_minus_u =
            (-ln_1p(-one_minus_xi * self.one_minus_e2l) * (0.5 / lambda)).min(ONE_MINUS_EPSILON);
        let ln_t = ln_1p(-one_minus_u) * (1.0 / b);
        let h = -expm1_nonpositive(ln_t);
        let t = exp_nonpositive(ln_t);
        // sin θ = √((1 − cos θ)(1 + cos θ)) = 2 √(h t); cos θ = t − h.
        let sin_theta = 2.0 * safe_sqrt(h * t);
        let local = Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, t - h);
        // ln G = 2λ (t^b − 1) + (b − 1) ln t with t^b = u exactly: the
        // sampled 1 − u stands in for −expm1(b ln t).
        let log_g = -2.0 * lambda * one_minus_u + b_minus_1 * ln_t;
        DirectionSample {
            direction: self.frame().to_world(local),
            pdf: exp(log_g + self.log_norm),
        }
    }

    /// Draws a direction from `u ∈ [0, 1)²` by exact inversion (NASG appendix
    /// C). `u.x` picks the half of the azimuth range and the azimuth within
    /// it: `u.x < ½` is the east half (`w = 2 u.x`, `φ ∈ [−π/2, π/2)`), else
    /// the west half (`w = 2 u.x − 1`, `φ ∈ [π/2, 3π/2)`), with
    /// `tan(φ mod π) = √((1 + ε + a)/(1 + ε)) tan(π (w − ½))`; so φ increases
    /// continuously with `u.x` and the only seam is `u.x = 0 ≡ 1` at
    /// `φ = −π/2`. `u.y` is the polar number (`u.y → 1` is the axis).
    ///
    /// The returned pdf is computed from the sampled `(t, b)` and agrees with
    /// [`Self::pdf`] of the returned direction up to the rounding of that
    /// direction. Both tails of the polar distribution are cut at probability
    /// [`NASG_TAIL_CUT`] `= 2⁻²⁴`, the resolution of an `f32` random number:
    /// `u.y < 2⁻²⁴` is used as `2⁻²⁴` (otherwise `u.y = 0`, which a 24-bit
    /// generator returns once in 1.7·10⁷ draws, would land at the very end of
    /// the tail, where the density is ~`e^{−2λ}`), and `u = t^b ≥ 2⁻²⁴` is
    /// enforced against rounding. Hence `2λ (1 − u) ≤ 24 ln 2`,
    /// `ln G ≥ −48 ln 2 ≈ −33.3`, and the returned pdf is always a normal
    /// positive `f32` (`≥ e^{−36}`). Out-of-range or NaN `u` is clamped to
    /// `[0, 1)`.
    #[inline]
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let ux = unit_interval(u.x);
        if ux < 0.5 {
            self.sample_half(2.0 * ux, false, u.y)
        } else {
            self.sample_half(2.0 * ux - 1.0, true, u.y)
        }
    }

    /// Like [`Self::sample`], with the half chosen by its own number: `u.x` is
    /// the azimuth number `w` within the half, `u.y` the polar number, and
    /// `u.z < ½` (or NaN) picks the east half.
    #[inline]
    #[must_use]
    pub fn sample3(&self, u: Vec3) -> DirectionSample {
        self.sample_half(u.x, u.z >= 0.5, u.y)
    }

    /// Inverse of [`Self::sample`]: the `u ∈ [0, 1)²` that maps to `direction`
    /// (any vector; see the module conventions for degenerate ones). Exact up
    /// to rounding except on the seam `φ = −π/2` (where `u.x` may come out as
    /// 0 or as the largest value below 1), where `u.y` rounds to 1, and in the
    /// cut tail `u.y < 2⁻²⁴` (which `sample` never produces).
    #[must_use]
    pub fn invert(&self, direction: Vec3) -> Vec2 {
        let l = self.local(direction);
        let c = phi_stretch(self.a, self.epsilon);
        // East half: φ ∈ [−π/2, π/2), i.e. cos φ > 0 or φ = −π/2.
        let east = l.cos_phi > 0.0 || (l.cos_phi == 0.0 && l.sin_phi < 0.0);
        let (cx, sy) = if east {
            (l.cos_phi, l.sin_phi)
        } else {
            (-l.cos_phi, -l.sin_phi)
        };
        // ψ = atan(tan φ₀ / c) = atan2(sin φ₀, c cos φ₀), cos φ₀ ≥ 0.
        let psi = atan2(sy, c * cx);
        let w = (psi * core::f32::consts::FRAC_1_PI + 0.5).clamp(0.0, 1.0);
        let ux = if east { 0.5 * w } else { 0.5 + 0.5 * w };
        // 1 − u = 1 − t^b, 1 − ξ = (1 − e^{−2λ(1 − u)}) / (1 − e^{−2λ}).
        let b = 1.0 + self.epsilon + self.a * l.cos2_phi;
        let one_minus_u = -expm1(b * l.ln_t);
        let one_minus_xi = -expm1(-2.0 * self.lambda * one_minus_u) / self.one_minus_e2l;
        Vec2::new(unit_interval(ux), unit_interval(1.0 - one_minus_xi))
    }
}

/// Partial derivatives of `ln p` of one lobe at one direction, with respect to
/// the lobe parameters; the frame enters through [`LogPdfGrad::d_rotation`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct LogPdfGrad {
    /// `∂ ln p / ∂λ = 1/λ − 2/(e^{2λ} − 1) − 2 (1 − t^b)`.
    pub d_lambda: f32,
    /// `∂ ln p / ∂a = (2λ t^b + 1) ln t · cos²φ + 1/(2 (1 + ε + a))`.
    pub d_a: f32,
    /// `(∂ ln G / ∂v_z) · sin θ`.
    dz_sin: f32,
    /// `∂ ln G / ∂cos²φ = a (2λ t^b + 1) ln t`, times `2 cos φ sin φ`.
    dc2_sc: f32,
    /// The same with `ln t` replaced by `cos θ · ln t / sin θ`.
    dc2_sc_pole: f32,
    cos_phi: f32,
    sin_phi: f32,
}

impl LogPdfGrad {
    /// `∂ ln p / ∂θ` when the frame turns by angle θ about an axis with local
    /// coordinates `n = (n·x, n·y, n·z)`: a fixed direction then moves in the
    /// frame as `dv/dθ = v × n`, so `dv_z = sin θ (cos φ n_y − sin φ n_x)` and
    /// `d cos²φ = 2 cos φ sin φ (n_z − cos θ (cos φ n_x + sin φ n_y) / sin θ)`.
    #[inline]
    pub fn d_rotation(&self, n: Vec3) -> f32 {
        self.dz_sin * (self.cos_phi * n.y - self.sin_phi * n.x) + self.dc2_sc * n.z
            - self.dc2_sc_pole * (self.cos_phi * n.x + self.sin_phi * n.y)
    }
}

/// `1 + 1/λ − coth λ`, the λ-derivative of `−ln K` (see
/// [`dlog_pdf_dkappa`](crate::lobe::vmf::dlog_pdf_dkappa), the same function).
#[inline]
fn dlog_norm_dlambda(lambda: f32) -> f32 {
    crate::lobe::vmf::dlog_pdf_dkappa(lambda, 0.0)
}

/// The gradient of `ln p` of lobe `(λ, a, ε)` at the local coordinates `l`.
///
/// The frame terms are combined analytically so that they stay finite at the
/// poles of the frame: near the axis `∂ ln G/∂b = (2λ t^b + 1) ln t → 0` like
/// θ², and `ln t / sin θ = sin θ · [ln(1 − h)/h] / (4 t)` (`sin²θ = 4 t h`,
/// `h = 1 − t`). At the antipode the gradient is genuinely unbounded; there
/// `t` is floored at `GRAD_T_MIN`, which keeps every term below ~10³².
#[inline]
pub(crate) fn log_pdf_grad(lambda: f32, a: f32, epsilon: f32, l: &Local) -> LogPdfGrad {
    let b_minus_1 = epsilon + a * l.cos2_phi;
    let b = 1.0 + b_minus_1;
    let ln_tb = b * l.ln_t;
    let tb = exp(ln_tb);
    let one_minus_tb = -expm1(ln_tb);
    let dlng_db_over_ln_t = 2.0 * lambda * tb + 1.0;
    let t_safe = l.t.max(GRAD_T_MIN);
    // sin θ / t ≤ 2/√t, finite.
    let sin_over_t = l.sin_theta / t_safe;
    // ∂ ln G/∂v_z = λ b t^{b−1} + (b − 1)/(2t), times sin θ.
    let dz_sin = lambda * b * exp(b_minus_1 * l.ln_t) * l.sin_theta + 0.5 * b_minus_1 * sin_over_t;
    // ln t / h → −1 on the axis.
    let ln_t_over_h = if l.h > 0.0 { l.ln_t / l.h } else { -1.0 };
    let ln_t_over_sin = 0.25 * sin_over_t * ln_t_over_h;
    let two_cs = 2.0 * l.cos_phi * l.sin_phi;
    let dc2 = a * dlng_db_over_ln_t * two_cs;
    LogPdfGrad {
        d_lambda: dlog_norm_dlambda(lambda) - 2.0 * one_minus_tb,
        d_a: dlng_db_over_ln_t * l.ln_t * l.cos2_phi + 0.5 / (1.0 + epsilon + a),
        dz_sin,
        dc2_sc: dc2 * l.ln_t,
        dc2_sc_pole: dc2 * l.cos_theta * ln_t_over_sin,
        cos_phi: l.cos_phi,
        sin_phi: l.sin_phi,
    }
}
