//! Mixtures of `K` normalised anisotropic spherical Gaussians (Huang et al.
//! 2024, "Online Neural Path Guiding with Normalized Anisotropic Spherical
//! Gaussians"), their decoder from raw network outputs, the analytic gradient
//! of `ln p(ω)` used for training, and the learned BSDF/guide selection
//! probability `c`.
//!
//! Decoding is our reading of NASG Table 2; per lobe the network emits
//! [`NASG_RAW_PER_LOBE`] = 6 numbers `[weight logit, ln λ, ln a, α, β, γ]`:
//!
//! ```text
//! w = softmax(logits)                       (the mixture weight is the lobe amplitude)
//! λ = exp(clamp(r₁, NASG_LN_LAMBDA_MIN, NASG_LN_LAMBDA_MAX))   λ ∈ [1.0·10⁻⁴, 1.0·10⁴]
//! a = exp(clamp(r₂, NASG_LN_A_MIN, NASG_LN_A_MAX))             a ∈ [4.5·10⁻⁵, 2.2·10⁴]
//! α = 2π sigmoid(r₃),  β = π sigmoid(r₄),  γ = π sigmoid(r₅)   (frame of NASG eq. 13)
//! ε = NASG_EPSILON                          (a constant, not learned)
//! c = clamp(sigmoid(r_c), NASG_SELECTION_MIN, NASG_SELECTION_MAX)
//! ```
//!
//! A γ range of π suffices: `G` depends on the tangents only through
//! `cos²φ`, so it is symmetric under `x → −x` (γ → γ + π). Every raw value is
//! first passed through [`sanitize`] (`NaN → 0`, clamp to `±NASG_RAW_LIMIT`).

use crate::lobe::nasg::{
    euler_frame, local_coords, log_eval, log_g_local, log_pdf_grad, unit_direction, NasgLobe,
    NASG_EPSILON,
};
use crate::lobe::DirectionSample;
use crate::math::{exp, ln, sanitize, sigmoid, sin_cos, PI, TWO_PI};
use crate::mixture::{
    log_sum_exp_parts, normalized_weights, pairwise_sum, select_lobe, softmax, weight_logits,
};
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Raw network outputs per NASG lobe: `[weight logit, ln λ, ln a, α, β, γ]`.
pub const NASG_RAW_PER_LOBE: usize = 6;
/// Raw outputs are clamped to `±NASG_RAW_LIMIT` (NaN becomes 0) before decoding.
pub const NASG_RAW_LIMIT: f32 = 1e30;
/// Lower clamp of the raw `ln λ` output: λ ≥ e^{−9.21} ≈ 1.0·10⁻⁴ (the lobe's
/// [`NASG_LAMBDA_MIN`](crate::lobe::nasg::NASG_LAMBDA_MIN)).
pub const NASG_LN_LAMBDA_MIN: f32 = -9.21;
/// Upper clamp of the raw `ln λ` output: λ ≤ e^{9.21} ≈ 1.0·10⁴ (an isotropic
/// lobe ~0.6° wide; with `a` at its maximum the narrow direction is ~0.004°
/// wide).
pub const NASG_LN_LAMBDA_MAX: f32 = 9.21;
/// Lower clamp of the raw `ln a` output: `a ≥ e⁻¹⁰ ≈ 4.5·10⁻⁵`.
pub const NASG_LN_A_MIN: f32 = -10.0;
/// Upper clamp of the raw `ln a` output: `a ≤ e¹⁰ ≈ 2.2·10⁴`.
pub const NASG_LN_A_MAX: f32 = 10.0;
/// Smallest decoded selection probability `c`: the guide is always sampled
/// with probability ≥ 1%.
pub const NASG_SELECTION_MIN: f32 = 0.01;
/// Largest decoded selection probability `c`: the BSDF is always sampled with
/// probability ≥ 1%, so that a badly learned guide cannot make the
/// one-sample MIS estimator miss BSDF-only features.
pub const NASG_SELECTION_MAX: f32 = 0.99;
/// Selection probability of mixtures built by [`NasgMixture::from_lobes`], and
/// the value a NaN probability becomes.
pub const NASG_SELECTION_DEFAULT: f32 = 0.5;

/// A mixture of `K` NASG lobes, stored structure-of-arrays, with the learned
/// probability `c` of sampling it rather than the BSDF.
///
/// `repr(C)`, `Pod`, `15 K + 1` floats (484 bytes for K = 8), no padding (all
/// fields are `f32`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NasgMixture<const K: usize> {
    /// Mixture weights, `≥ 0`, summing to one.
    pub weight: [f32; K],
    /// x components of the frame tangents `x`.
    pub x_x: [f32; K],
    /// y components of the frame tangents `x`.
    pub x_y: [f32; K],
    /// z components of the frame tangents `x`.
    pub x_z: [f32; K],
    /// x components of the frame tangents `y`.
    pub y_x: [f32; K],
    /// y components of the frame tangents `y`.
    pub y_y: [f32; K],
    /// z components of the frame tangents `y`.
    pub y_z: [f32; K],
    /// x components of the lobe axes `z`.
    pub z_x: [f32; K],
    /// y components of the lobe axes `z`.
    pub z_y: [f32; K],
    /// z components of the lobe axes `z`.
    pub z_z: [f32; K],
    /// Sharpnesses λ.
    pub lambda: [f32; K],
    /// Anisotropies `a`.
    pub a: [f32; K],
    /// Per-lobe `ε`.
    pub epsilon: [f32; K],
    /// Per-lobe log-normalisers `−ln K`.
    pub log_norm: [f32; K],
    /// Per-lobe `1 − e^{−2λ}`.
    pub one_minus_e2l: [f32; K],
    /// Probability `c ∈ [0, 1]` of sampling this mixture rather than the BSDF.
    pub selection_probability: f32,
}

// SAFETY: `repr(C)` struct of `[f32; K]` arrays and one `f32`: all fields have
// alignment 4 and sizes that are multiples of 4, so there is no padding; every
// bit pattern is valid, zero is valid.
unsafe impl<const K: usize> Zeroable for NasgMixture<K> {}
// SAFETY: see above; `Copy + 'static` holds for every `K`.
unsafe impl<const K: usize> Pod for NasgMixture<K> {}

/// One lobe's decoded parameters and the activation derivatives the gradient
/// needs.
struct DecodedLobe {
    lobe: NasgLobe,
    sin_alpha: f32,
    cos_alpha: f32,
    /// ∂λ/∂(raw ln λ): λ inside the clamp range, 0 outside.
    dlambda_draw: f32,
    /// ∂a/∂(raw ln a): `a` inside the clamp range, 0 outside.
    da_draw: f32,
    /// ∂α/∂(raw α) = 2π s (1 − s).
    dalpha_draw: f32,
    /// ∂β/∂(raw β) = π s (1 − s).
    dbeta_draw: f32,
    /// ∂γ/∂(raw γ) = π s (1 − s).
    dgamma_draw: f32,
}

/// `exp(clamp(r))` of a sanitised raw value and its derivative (0 where clamped).
#[inline]
fn clamped_exp(raw: f32, lo: f32, hi: f32) -> (f32, f32) {
    let r = sanitize(raw, NASG_RAW_LIMIT);
    let v = exp(r.clamp(lo, hi));
    (v, if r > lo && r < hi { v } else { 0.0 })
}

/// The activations of the module docs for one lobe.
fn decode_lobe(raw: &[f32; NASG_RAW_PER_LOBE]) -> DecodedLobe {
    let (lambda, dlambda_draw) = clamped_exp(raw[1], NASG_LN_LAMBDA_MIN, NASG_LN_LAMBDA_MAX);
    let (a, da_draw) = clamped_exp(raw[2], NASG_LN_A_MIN, NASG_LN_A_MAX);
    let s_alpha = sigmoid(sanitize(raw[3], NASG_RAW_LIMIT));
    let s_beta = sigmoid(sanitize(raw[4], NASG_RAW_LIMIT));
    let s_gamma = sigmoid(sanitize(raw[5], NASG_RAW_LIMIT));
    let alpha = TWO_PI * s_alpha;
    let (x, y, z) = euler_frame(alpha, PI * s_beta, PI * s_gamma);
    let (sin_alpha, cos_alpha) = sin_cos(alpha);
    DecodedLobe {
        lobe: NasgLobe::with_frame(x, y, z, lambda, a, NASG_EPSILON),
        sin_alpha,
        cos_alpha,
        dlambda_draw,
        da_draw,
        dalpha_draw: TWO_PI * s_alpha * (1.0 - s_alpha),
        dbeta_draw: PI * s_beta * (1.0 - s_beta),
        dgamma_draw: PI * s_gamma * (1.0 - s_gamma),
    }
}

/// Decodes the raw selection output: `c = clamp(sigmoid(r), NASG_SELECTION_MIN,
/// NASG_SELECTION_MAX)` and `dc/dr` (`s (1 − s)` inside the clamp, 0 outside).
///
/// `c` does not enter the guide density, so [`NasgMixture::grad_log_pdf`] has
/// no term for it; a loss on the combined density
/// `c p_guide + (1 − c) p_bsdf` chains through this derivative.
#[inline]
#[must_use]
pub fn decode_selection(selection_raw: f32) -> (f32, f32) {
    let s = sigmoid(sanitize(selection_raw, NASG_RAW_LIMIT));
    let inside = s > NASG_SELECTION_MIN && s < NASG_SELECTION_MAX;
    (
        s.clamp(NASG_SELECTION_MIN, NASG_SELECTION_MAX),
        if inside { s * (1.0 - s) } else { 0.0 },
    )
}

impl<const K: usize> NasgMixture<K> {
    /// All-zero mixture (written out: `Zeroable::zeroed` goes through
    /// `MaybeUninit`, which rust-gpu cannot compile).
    pub const ZERO: Self = Self {
        weight: [0.0; K],
        x_x: [0.0; K],
        x_y: [0.0; K],
        x_z: [0.0; K],
        y_x: [0.0; K],
        y_y: [0.0; K],
        y_z: [0.0; K],
        z_x: [0.0; K],
        z_y: [0.0; K],
        z_z: [0.0; K],
        lambda: [0.0; K],
        a: [0.0; K],
        epsilon: [0.0; K],
        log_norm: [0.0; K],
        one_minus_e2l: [0.0; K],
        selection_probability: 0.0,
    };
}

impl<const K: usize> NasgMixture<K> {
    /// Mixture of the given lobes with the given weights (normalised here;
    /// negative, infinite or NaN weights count as zero, all-zero weights become
    /// uniform) and selection probability [`NASG_SELECTION_DEFAULT`].
    #[must_use]
    pub fn from_lobes(lobes: &[NasgLobe; K], weights: &[f32; K]) -> Self {
        let mut m = Self::ZERO;
        m.weight = normalized_weights(weights);
        let mut k = 0;
        while k < K {
            m.set_lobe(k, &lobes[k]);
            k += 1;
        }
        m.selection_probability = NASG_SELECTION_DEFAULT;
        m
    }

    /// The same mixture with selection probability `c` (clamped to `[0, 1]`;
    /// NaN becomes [`NASG_SELECTION_DEFAULT`]).
    #[must_use]
    pub fn with_selection_probability(mut self, c: f32) -> Self {
        self.selection_probability = if c.is_nan() {
            NASG_SELECTION_DEFAULT
        } else {
            c.clamp(0.0, 1.0)
        };
        self
    }

    /// Decodes raw network outputs (see the module docs for the activations
    /// and clamps). Any input, including NaN and ±∞, gives a valid mixture.
    #[must_use]
    pub fn decode(raw: &[[f32; NASG_RAW_PER_LOBE]; K], selection_raw: f32) -> Self {
        let mut m = Self::ZERO;
        softmax(&weight_logits(raw, NASG_RAW_LIMIT), &mut m.weight);
        let mut k = 0;
        while k < K {
            let d = decode_lobe(&raw[k]);
            m.set_lobe(k, &d.lobe);
            k += 1;
        }
        m.selection_probability = decode_selection(selection_raw).0;
        m
    }

    fn set_lobe(&mut self, k: usize, lobe: &NasgLobe) {
        self.x_x[k] = lobe.x[0];
        self.x_y[k] = lobe.x[1];
        self.x_z[k] = lobe.x[2];
        self.y_x[k] = lobe.y[0];
        self.y_y[k] = lobe.y[1];
        self.y_z[k] = lobe.y[2];
        self.z_x[k] = lobe.z[0];
        self.z_y[k] = lobe.z[1];
        self.z_z[k] = lobe.z[2];
        self.lambda[k] = lobe.lambda;
        self.a[k] = lobe.a;
        self.epsilon[k] = lobe.epsilon;
        self.log_norm[k] = lobe.log_norm;
        self.one_minus_e2l[k] = lobe.one_minus_e2l;
    }

    /// Lobe `k` as a standalone [`NasgLobe`].
    #[inline]
    #[must_use]
    pub fn lobe(&self, k: usize) -> NasgLobe {
        NasgLobe {
            x: [self.x_x[k], self.x_y[k], self.x_z[k]],
            y: [self.y_x[k], self.y_y[k], self.y_z[k]],
            z: [self.z_x[k], self.z_y[k], self.z_z[k]],
            lambda: self.lambda[k],
            a: self.a[k],
            epsilon: self.epsilon[k],
            log_norm: self.log_norm[k],
            one_minus_e2l: self.one_minus_e2l[k],
        }
    }

    /// The probability `c` of sampling this mixture rather than the BSDF.
    #[inline]
    #[must_use]
    pub fn selection_probability(&self) -> f32 {
        self.selection_probability
    }

    /// `ln(G_k / K_k)` of lobe `k` at the unit direction `u` (`(0, 0, 0)`: the
    /// antipode convention).
    #[inline(always)]
    fn log_lobe_pdf(&self, k: usize, u: Vec3) -> f32 {
        let vx = u.x * self.x_x[k] + u.y * self.x_y[k] + u.z * self.x_z[k];
        let vy = u.x * self.y_x[k] + u.y * self.y_y[k] + u.z * self.y_z[k];
        let vz = u.x * self.z_x[k] + u.y * self.z_y[k] + u.z * self.z_z[k];
        log_g_local(vx, vy, vz, self.lambda[k], self.a[k], self.epsilon[k]) + self.log_norm[k]
    }

    /// Density `Σ_k w_k G_k(ω) / K_k` in solid angle; finite and `≥ 0` for
    /// every input (degenerate directions as in [`NasgLobe::pdf`]). The
    /// mixture is normalised and has no unnormalised `eval`: `Σ_k w_k G_k(ω)`
    /// would drop the lobes' normalisers `K_k`, which is no quantity of the
    /// mixture (see the crate docs). Per-lobe values: [`Self::lobe`], then
    /// [`NasgLobe::eval`].
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let (u, _) = unit_direction(direction);
        // An invalid direction is (0, 0, 0), which every lobe reads as its
        // antipode.
        self.pdf_unit(u)
    }

    /// [`Self::pdf`] of a direction known to be unit up to rounding.
    ///
    /// The `K`-lobe loop is branch-free and calls inlined math only
    /// ([`log_g_local`]), and writes per-lobe terms to an array that is summed
    /// pairwise afterwards, so LLVM vectorises it; zero weights give exactly
    /// zero terms.
    #[inline]
    fn pdf_unit(&self, u: Vec3) -> f32 {
        let mut terms = [0.0f32; K];
        let mut k = 0;
        while k < K {
            terms[k] = self.lobe_term(k, u);
            k += 1;
        }
        pairwise_sum(&mut terms)
    }

    /// The term `w_k G_k(u) / K_k` of lobe `k` (exactly 0 for a zero weight).
    #[inline(always)]
    fn lobe_term(&self, k: usize, u: Vec3) -> f32 {
        let w = self.weight[k];
        let p = w * exp(self.log_lobe_pdf(k, u));
        if w > 0.0 {
            p
        } else {
            0.0
        }
    }

    /// `ln p(ω)` by log-sum-exp: finite also where every lobe's density
    /// underflows (`f32::MIN` only for a mixture without positive weights,
    /// which this module never builds).
    #[must_use]
    pub fn log_pdf(&self, direction: Vec3) -> f32 {
        let (u, _) = unit_direction(direction);
        let mut terms = [f32::MIN; K];
        let mut max = f32::MIN;
        let mut k = 0;
        while k < K {
            if self.weight[k] > 0.0 {
                terms[k] = ln(self.weight[k]) + self.log_lobe_pdf(k, u);
                max = max.max(terms[k]);
            }
            k += 1;
        }
        let mut sum = 0.0;
        k = 0;
        while k < K {
            if self.weight[k] > 0.0 {
                sum += exp(terms[k] - max);
            }
            k += 1;
        }
        if sum > 0.0 {
            max + ln(sum)
        } else {
            f32::MIN
        }
    }

    /// The direction [`Self::sample`] draws from `u`, without its density
    /// (the batched CPU path evaluates the densities of many samples at once,
    /// [`crate::model::mixture_batch`]).
    #[inline]
    #[must_use]
    pub fn sample_direction(&self, u: Vec2) -> Vec3 {
        let (k, u_lobe) = select_lobe(&self.weight, u);
        self.lobe(k).sample(u_lobe).direction
    }

    /// Draws a direction: `u.x` selects the lobe by the weights and is then
    /// rescaled and reused as the lobe's azimuth number (half and azimuth, see
    /// [`NasgLobe::sample`]); `u.y` is the lobe's polar number. The returned
    /// pdf is the full mixture density of the returned direction.
    #[inline]
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let direction = self.sample_direction(u);
        // The sampled direction is unit up to rounding (~10⁻⁷): the
        // normalisation of `pdf` is skipped (a relative change of ~10⁻⁷ times
        // the exponent, far below 10⁻⁴ wherever a term is not negligible).
        DirectionSample {
            direction,
            pdf: self.pdf_unit(direction),
        }
    }

    /// `ln p(ω)` of the mixture decoded from `raw` (the selection output does
    /// not enter it; see [`decode_selection`]), and its gradient with respect
    /// to every raw output through the activations of [`Self::decode`].
    ///
    /// With responsibilities `r_k = w_k p_k / p`:
    /// - logit: `r_k − w_k`;
    /// - `ln λ`: `r_k λ (1/λ − 2/(e^{2λ} − 1) − 2 (1 − t^b))` (series for
    ///   small λ, as [`dlog_pdf_dkappa`](crate::lobe::vmf::dlog_pdf_dkappa));
    /// - `ln a`: `r_k a ((2λ t^b + 1) ln t cos²φ + 1/(2 (1 + ε + a)))`;
    /// - α, β, γ: `r_k ∂ln G/∂angle · dangle/draw`, where turning the frame by
    ///   an angle about the world axis `n` (`e_z` for α, `R_z(α) e_y` for β,
    ///   the lobe axis for γ) changes the local coordinates of ω by
    ///   `ω_local × n_local`; the pole factors are combined analytically (see
    ///   the lobe module), so the result is finite on the lobe axis.
    ///
    /// Evaluated in log space (log-softmax, log-sum-exp), so it stays finite
    /// where every lobe's density underflows. Clamped `ln λ`, `ln a` outputs
    /// get a zero gradient, as the clamp's derivative is zero there. Every
    /// output is finite for every input.
    pub fn grad_log_pdf(
        raw: &[[f32; NASG_RAW_PER_LOBE]; K],
        direction: Vec3,
        grad: &mut [[f32; NASG_RAW_PER_LOBE]; K],
    ) -> f32 {
        let (u, valid) = unit_direction(direction);
        let logits = weight_logits(raw, NASG_RAW_LIMIT);
        let (max_logit, log_sum) = log_sum_exp_parts(&logits);

        // ln(w_k p_k) per lobe.
        let mut log_terms = [0.0; K];
        let mut k = 0;
        while k < K {
            let lobe = decode_lobe(&raw[k]).lobe;
            let l = local_coords(
                Vec3::from_array(lobe.x),
                Vec3::from_array(lobe.y),
                Vec3::from_array(lobe.z),
                u,
                valid,
            );
            let log_w = logits[k] - max_logit - log_sum;
            log_terms[k] = log_w
                + log_eval(lobe.lambda, lobe.a, lobe.epsilon, l.ln_t, l.cos2_phi)
                + lobe.log_norm;
            k += 1;
        }
        let (max_term, ln_total) = log_sum_exp_parts(&log_terms);
        let log_pdf = max_term + ln_total;

        k = 0;
        while k < K {
            let d = decode_lobe(&raw[k]);
            let (x, y, z) = (
                Vec3::from_array(d.lobe.x),
                Vec3::from_array(d.lobe.y),
                Vec3::from_array(d.lobe.z),
            );
            let l = local_coords(x, y, z, u, valid);
            let g = log_pdf_grad(d.lobe.lambda, d.lobe.a, d.lobe.epsilon, &l);
            let resp = exp(log_terms[k] - log_pdf);
            let w = exp(logits[k] - max_logit - log_sum);
            grad[k][0] = resp - w;
            grad[k][1] = resp * g.d_lambda * d.dlambda_draw;
            grad[k][2] = resp * g.d_a * d.da_draw;
            // α turns the frame about world e_z; its local coordinates are the
            // z components of the frame vectors.
            let n_alpha = Vec3::new(x.z, y.z, z.z);
            // β turns it about R_z(α) e_y = (−sin α, cos α, 0).
            let n_beta_world = Vec3::new(-d.sin_alpha, d.cos_alpha, 0.0);
            let n_beta = Vec3::new(
                n_beta_world.dot(x),
                n_beta_world.dot(y),
                n_beta_world.dot(z),
            );
            grad[k][3] = resp * g.d_rotation(n_alpha) * d.dalpha_draw;
            grad[k][4] = resp * g.d_rotation(n_beta) * d.dbeta_draw;
            // γ turns it about its own axis: local (0, 0, 1).
            grad[k][5] = resp * g.d_rotation(Vec3::Z) * d.dgamma_draw;
            k += 1;
        }
        log_pdf
    }
}
