//! Per-sample training losses: the Monte Carlo KL-divergence gradient shared
//! by all guiding models, NASG's MIS blend, and the relative L2 of the
//! radiance cache.
//!
//! All models minimise `KL(p̂ ‖ q)` between the (unnormalised) target `p̂`
//! and the guide `q`. Its gradient is `−∫ p̂ ∇ ln q dω`, estimated from the
//! renderer's own samples `ωᵢ ~ p_s` as `−(p̂(ωᵢ) / p_s(ωᵢ)) ∇ ln q(ωᵢ)`
//! (NPM, Dong et al. 2023, eq. 9; DF, Figueiredo et al. 2025, eq. 12;
//! NASG, Huang et al. 2024, eq. 17). The weight `p̂ / p_s` is [`kl_weight`].

use crate::math::{exp, ln, sigmoid};
use crate::sample::TrainingSample;

/// What the guide is trained to be proportional to.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// Incident radiance `L_i(x, ω)` (the guide is later multiplied by the
    /// BSDF, e.g. [`crate::mixture::vmf::VmfMixture::product_with_clamped_cosine`]).
    Radiance = 0,
    /// The full product `f(ωo, ω) L_i(x, ω) |cos θ|`.
    Product = 1,
}

/// Scalar value of an RGB quantity used as a training target: the channel
/// mean (so that a grey value `v` counts as `v`).
#[inline]
#[must_use]
pub fn scalar(rgb: [f32; 3]) -> f32 {
    (rgb[0] + rgb[1] + rgb[2]) * (1.0 / 3.0)
}

/// Target value `p̂(ωᵢ)` of a sample: `L_i` for [`Target::Radiance`],
/// `f L_i |cos|` (per channel, then [`scalar`]) for [`Target::Product`].
#[inline]
#[must_use]
pub fn target_value(sample: &TrainingSample, target: Target) -> f32 {
    let l = sample.radiance;
    match target {
        Target::Radiance => scalar(l),
        Target::Product => {
            let f = sample.bsdf_cos;
            scalar([l[0] * f[0], l[1] * f[1], l[2] * f[2]])
        }
    }
}

/// Monte Carlo weight `p̂(ωᵢ) / p_s(ωᵢ)` of the KL gradient; `0` for a sample
/// that fails [`TrainingSample::validate`] or whose weight overflows, so a bad
/// sample can never contribute.
#[inline]
#[must_use]
pub fn kl_weight(sample: &TrainingSample, target: Target) -> f32 {
    if sample.validate().is_err() {
        return 0.0;
    }
    let w = target_value(sample, target) / sample.sample_pdf;
    if w.is_finite() {
        w
    } else {
        0.0
    }
}

/// NASG's blended loss for one sample (Huang et al. 2024, eq. 18):
/// `ℓ = −w [(1 − e) ln p_mis + e ln q]` with the MIS density
/// `p_mis = c q + (1 − c) p_bsdf` of the learned selection probability `c`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NasgLossTerms {
    /// The loss value `ℓ`.
    pub loss: f32,
    /// `∂ℓ/∂ ln q`: multiply the guide's `∇ ln q` by this.
    pub dloss_dlog_guide: f32,
    /// `∂ℓ/∂c`.
    pub dloss_dselection: f32,
}

/// [`NasgLossTerms`] from the weight `w`, `ln q(ωᵢ)`, the selection
/// probability `c ∈ (0, 1)`, `p_bsdf(ωᵢ) ≥ 0` and the blend `e` (paper: 0.2).
///
/// Evaluated in log space: `∂ ln p_mis / ∂ ln q = c q / p_mis
/// = sigmoid(ln(c q) − ln((1 − c) p_bsdf))`, finite when `q` underflows. If
/// both `q` and `p_bsdf` are zero the sample carries no information and every
/// term is zero.
#[must_use]
pub fn nasg_mis_loss(w: f32, log_guide: f32, c: f32, bsdf_pdf: f32, e: f32) -> NasgLossTerms {
    let log_cq = ln(c) + log_guide;
    let log_b = if bsdf_pdf > 0.0 {
        ln(1.0 - c) + ln(bsdf_pdf)
    } else {
        f32::NEG_INFINITY
    };
    // ln p_mis = logaddexp(ln cq, ln (1−c)b).
    let hi = log_cq.max(log_b);
    let lo = log_cq.min(log_b);
    if hi.is_nan() || hi == f32::NEG_INFINITY {
        // Both densities are zero: the sample carries no information.
        return NasgLossTerms {
            loss: 0.0,
            dloss_dlog_guide: 0.0,
            dloss_dselection: 0.0,
        };
    }
    let log_mis = hi + ln(1.0 + exp(lo - hi));
    let guide_share = sigmoid(log_cq - log_b);
    // ∂ ln p_mis / ∂c = (q − p_bsdf) / p_mis.
    let q_over_mis = exp(log_guide - log_mis);
    let b_over_mis = if bsdf_pdf > 0.0 {
        exp(ln(bsdf_pdf) - log_mis)
    } else {
        0.0
    };
    NasgLossTerms {
        loss: -w * ((1.0 - e) * log_mis + e * log_guide),
        dloss_dlog_guide: -w * ((1.0 - e) * guide_share + e),
        dloss_dselection: -w * (1.0 - e) * (q_over_mis - b_over_mis),
    }
}

/// Relative L2 loss of a radiance prediction (neural radiance caching,
/// Müller et al. 2021, §5): `ℓ = mean_c (pred − target)² / (sg(pred)² + 0.01)`
/// where `sg` stops the gradient. Returns `ℓ` and `∂ℓ/∂pred`.
#[must_use]
pub fn relative_l2(pred: [f32; 3], target: [f32; 3]) -> (f32, [f32; 3]) {
    let mut loss = 0.0;
    let mut grad = [0.0; 3];
    let mut c = 0;
    while c < 3 {
        let denom = pred[c] * pred[c] + 0.01;
        let diff = pred[c] - target[c];
        loss += diff * diff / denom;
        grad[c] = 2.0 * diff / denom * (1.0 / 3.0);
        c += 1;
    }
    (loss * (1.0 / 3.0), grad)
}
