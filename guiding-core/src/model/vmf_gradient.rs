//! The NPM training loss gradient over a batch of samples, vectorised
//! across samples (`std`, CPU only): [`grad_log_pdf_vmf_batch`].
//!
//! Training NPM spent most of its time not in the network but in the
//! per-sample `∇_y ln q(ωᵢ)` of [`VmfMixture::grad_log_pdf`] (Dong et al.
//! 2023, eq. 9: `ℓ = −w ln q(ωᵢ)`): per lobe two sigmoids, two sine-cosine
//! pairs, `exp κ`, the normaliser's `expm1` and `ln`, and four more `exp`
//! through libm, all out-of-line calls that keep the loop scalar. Here the
//! same formulas run on [`GRAD_BLOCK`] samples at once, laid out
//! `[lobe][sample]` so each line of arithmetic is one 8-lane vector, with
//! the inlined `exp` / `ln_inline` / `expm1_inline` of the math shim.
//!
//! Deviation from the per-sample kernel: only rounding. `ln` and `expm1`
//! are the inlined versions (within 2 ulp of the correctly rounded value,
//! as libm's), `ln norm(κ)` is taken of the same `f32` normaliser; every
//! other operation is the per-sample one in the same order. The
//! per-sample kernel stays the reference and the SPIR-V path; the tests
//! compare both over the whole raw-output domain (clamped `κ`, saturated
//! sigmoids, non-finite outputs).

use super::npm::NPM_LOBES;
use super::npm::NPM_OUTPUTS;
use crate::lobe::vmf::VMF_KAPPA_MAX;
use crate::math::{
    exp, expm1_inline, expm1_nonpositive, ln_inline, sanitize, sigmoid, sin_cos_turns, INV_FOUR_PI,
    PI, TWO_PI,
};
#[cfg(doc)]
use crate::mixture::vmf::VmfMixture;
use crate::mixture::vmf::{VMF_LOG_KAPPA_MAX, VMF_LOG_KAPPA_MIN, VMF_RAW_LIMIT, VMF_RAW_PER_LOBE};
use glam::Vec3;

/// Samples per block: one AVX2 vector per lobe and quantity.
pub const GRAD_BLOCK: usize = 8;

/// `log_pdfs[i] = VmfMixture::grad_log_pdf(ys[i] as rows, dirs[i], dys[i])`
/// for every `i` (the gradient written row-major as `ys`), up to the
/// rounding stated in the [module docs](self), with the widest vectors this
/// CPU runs (AVX2 only widens the lanes, so every variant gives the same
/// bits).
///
/// # Panics
/// If the slices differ in length.
pub fn grad_log_pdf_vmf_batch(
    ys: &[[f32; NPM_OUTPUTS]],
    dirs: &[Vec3],
    dys: &mut [[f32; NPM_OUTPUTS]],
    log_pdfs: &mut [f32],
) {
    // Both variants check the lengths (in the portable one).
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 support was just checked.
        unsafe { grad_log_pdf_vmf_avx2(ys, dirs, dys, log_pdfs) };
        return;
    }
    grad_log_pdf_vmf_portable(ys, dirs, dys, log_pdfs);
}

/// [`grad_log_pdf_vmf_batch`] compiled for the target's baseline features
/// (public so tests check both variants).
///
/// # Panics
/// If the slices differ in length.
#[inline(always)]
pub fn grad_log_pdf_vmf_portable(
    ys: &[[f32; NPM_OUTPUTS]],
    dirs: &[Vec3],
    dys: &mut [[f32; NPM_OUTPUTS]],
    log_pdfs: &mut [f32],
) {
    assert!(
        ys.len() == dirs.len() && ys.len() == dys.len() && ys.len() == log_pdfs.len(),
        "one direction, gradient and log pdf per raw row"
    );
    let blocks = ys
        .chunks(GRAD_BLOCK)
        .zip(dirs.chunks(GRAD_BLOCK))
        .zip(dys.chunks_mut(GRAD_BLOCK))
        .zip(log_pdfs.chunks_mut(GRAD_BLOCK));
    for (((y, d), dy), lp) in blocks {
        grad_block(y, d, dy, lp);
    }
}

/// [`grad_log_pdf_vmf_portable`] compiled for AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn grad_log_pdf_vmf_avx2(
    ys: &[[f32; NPM_OUTPUTS]],
    dirs: &[Vec3],
    dys: &mut [[f32; NPM_OUTPUTS]],
    log_pdfs: &mut [f32],
) {
    grad_log_pdf_vmf_portable(ys, dirs, dys, log_pdfs);
}

/// Lanes of one block: `[lobe][sample]`.
type Lanes = [[f32; GRAD_BLOCK]; NPM_LOBES];

/// `1 − cos∠(axis, d)` for a unit `d` of length `len` (precomputed), as
/// `sphere::one_minus_cos_angle`: `|axis × d|² / (len (len + dot))` where
/// the angle is acute (no cancellation), `1 − dot / len` otherwise. Not
/// the shared function itself: its early return for a degenerate `d` and
/// the out-of-line `sqrt` keep the lane loop scalar (measured: 650 against
/// 150 ns per sample); here `d` is unit by construction.
#[inline(always)]
fn one_minus_cos(a: [f32; 3], d: [f32; 3], len: f32) -> f32 {
    let dot = a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
    let cx = a[1] * d[2] - a[2] * d[1];
    let cy = a[2] * d[0] - a[0] * d[2];
    let cz = a[0] * d[1] - a[1] * d[0];
    let cross2 = cx * cx + cy * cy + cz * cz;
    let acute = cross2 / (len * (len + dot));
    let obtuse = 1.0 - dot / len;
    if dot > 0.0 {
        acute
    } else {
        obtuse
    }
}

/// `∂ ln f / ∂κ` of a vMF lobe at `1 − cos = t`, as
/// `lobe::vmf::dlog_pdf_dkappa` with the inlined `expm1`.
#[inline(always)]
fn dlog_pdf_dkappa(kappa: f32, t: f32) -> f32 {
    let k2 = kappa * kappa;
    let series = 1.0 - kappa * (1.0 / 3.0 - k2 * (1.0 / 45.0 - k2 * (2.0 / 945.0)));
    let exact = 1.0 / kappa - 2.0 / expm1_inline(2.0 * kappa);
    let norm_term = if kappa < 0.05 { series } else { exact };
    norm_term - t
}

/// Per lane `b`, `ln Σ_k exp(x[k][b] − max[b])` (summed in lobe order).
#[inline(always)]
#[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorises
fn ln_sum_exp_shifted(x: &Lanes, max: &[f32; GRAD_BLOCK]) -> [f32; GRAD_BLOCK] {
    let mut sum = [0.0f32; GRAD_BLOCK];
    for k in 0..NPM_LOBES {
        for b in 0..GRAD_BLOCK {
            sum[b] += exp(x[k][b] - max[b]);
        }
    }
    let mut ln_sum = [0.0f32; GRAD_BLOCK];
    for b in 0..GRAD_BLOCK {
        ln_sum[b] = ln_inline(sum[b]);
    }
    ln_sum
}

/// [`grad_log_pdf_vmf_batch`] of up to [`GRAD_BLOCK`] samples; unused
/// lanes compute a zero row towards `+z` and are dropped.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorises
fn grad_block(
    ys: &[[f32; NPM_OUTPUTS]],
    dirs: &[Vec3],
    dys: &mut [[f32; NPM_OUTPUTS]],
    log_pdfs: &mut [f32],
) {
    const B: usize = GRAD_BLOCK;
    const K: usize = NPM_LOBES;
    let n = ys.len().min(B);
    let mut raw = [[[0.0f32; B]; K]; VMF_RAW_PER_LOBE];
    let mut d = [[0.0f32; B], [0.0f32; B], [1.0f32; B]];
    let mut len = [1.0f32; B];
    for b in 0..n {
        for k in 0..K {
            for r in 0..VMF_RAW_PER_LOBE {
                raw[r][k][b] = ys[b][k * VMF_RAW_PER_LOBE + r];
            }
        }
        let u = crate::frame::normalize_or(dirs[b], Vec3::Z);
        d[0][b] = u.x;
        d[1][b] = u.y;
        d[2][b] = u.z;
        // one_minus_cos_angle's length of the (already unit) direction.
        len[b] = u.length_squared().sqrt();
    }

    // Log-softmax of the weight logits (max and sum in lobe order).
    let mut logit: Lanes = [[0.0; B]; K];
    let mut max_logit = [f32::MIN; B];
    for k in 0..K {
        for b in 0..B {
            logit[k][b] = sanitize(raw[0][k][b], VMF_RAW_LIMIT);
            max_logit[b] = max_logit[b].max(logit[k][b]);
        }
    }
    let log_sum = ln_sum_exp_shifted(&logit, &max_logit);

    // Per lobe: κ, the mean and its derivatives, ln(w_k f_k(ω)).
    let mut kappa: Lanes = [[0.0; B]; K];
    let mut dkappa_draw: Lanes = [[0.0; B]; K];
    let mut t_raw: Lanes = [[0.0; B]; K];
    let mut d_theta: Lanes = [[0.0; B]; K];
    let mut d_phi: Lanes = [[0.0; B]; K];
    let mut log_term: Lanes = [[0.0; B]; K];
    let mut max_term = [f32::MIN; B];
    for k in 0..K {
        for b in 0..B {
            let r_kappa = sanitize(raw[1][k][b], VMF_RAW_LIMIT);
            let kap = exp(r_kappa.clamp(VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX));
            let inside = r_kappa > VMF_LOG_KAPPA_MIN && r_kappa < VMF_LOG_KAPPA_MAX;
            let s_theta = sigmoid(sanitize(raw[2][k][b], VMF_RAW_LIMIT));
            let s_phi = sigmoid(sanitize(raw[3][k][b], VMF_RAW_LIMIT));
            let (sin_t, cos_t) = sin_cos_turns(0.5 * s_theta);
            let (sin_p, cos_p) = sin_cos_turns(s_phi);
            let mean = [sin_t * cos_p, sin_t * sin_p, cos_t];
            let dir = [d[0][b], d[1][b], d[2][b]];
            // VmfLobe::new: the mean normalised, κ clamped (a no-op for
            // κ ∈ [e⁻¹⁰, e¹⁰]), the normaliser 2κ / (1 − e^{−2κ}) / 4π.
            let len2 = mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2];
            let inv = 1.0 / len2.sqrt();
            let unit = if len2 > 1e-30 && len2 <= f32::MAX {
                [mean[0] * inv, mean[1] * inv, mean[2] * inv]
            } else {
                [0.0, 0.0, 1.0]
            };
            let lobe_kappa = kap.min(VMF_KAPPA_MAX);
            let two_kappa = 2.0 * lobe_kappa;
            let norm = two_kappa / -expm1_nonpositive(-two_kappa) * INV_FOUR_PI;
            let t = one_minus_cos(unit, dir, len[b]);
            let log_w = logit[k][b] - max_logit[b] - log_sum[b];
            log_term[k][b] = log_w + ln_inline(norm) - lobe_kappa * t;
            max_term[b] = max_term[b].max(log_term[k][b]);

            kappa[k][b] = kap;
            dkappa_draw[k][b] = if inside { kap } else { 0.0 };
            t_raw[k][b] = one_minus_cos(mean, dir, len[b]);
            let dtheta = PI * s_theta * (1.0 - s_theta);
            let dphi = TWO_PI * s_phi * (1.0 - s_phi);
            // ω · ∂μ/∂θ_raw and ω · ∂μ/∂φ_raw.
            d_theta[k][b] = dir[0] * (cos_t * cos_p * dtheta)
                + dir[1] * (cos_t * sin_p * dtheta)
                + dir[2] * (-sin_t * dtheta);
            d_phi[k][b] =
                dir[0] * (-sin_t * sin_p * dphi) + dir[1] * (sin_t * cos_p * dphi) + dir[2] * 0.0;
        }
    }
    let ln_total = ln_sum_exp_shifted(&log_term, &max_term);
    let mut log_pdf = [0.0f32; B];
    for b in 0..B {
        log_pdf[b] = max_term[b] + ln_total[b];
    }

    // Responsibilities r_k = w_k f_k / q and weights w_k.
    let mut g: [Lanes; VMF_RAW_PER_LOBE] = [[[0.0; B]; K]; VMF_RAW_PER_LOBE];
    for k in 0..K {
        for b in 0..B {
            let resp = exp(log_term[k][b] - log_pdf[b]);
            let w = exp(logit[k][b] - max_logit[b] - log_sum[b]);
            let kap = kappa[k][b];
            g[0][k][b] = resp - w;
            g[1][k][b] = resp * dlog_pdf_dkappa(kap, t_raw[k][b]) * dkappa_draw[k][b];
            g[2][k][b] = resp * kap * d_theta[k][b];
            g[3][k][b] = resp * kap * d_phi[k][b];
        }
    }
    for b in 0..n {
        for k in 0..K {
            for r in 0..VMF_RAW_PER_LOBE {
                dys[b][k * VMF_RAW_PER_LOBE + r] = g[r][k][b];
            }
        }
        log_pdfs[b] = log_pdf[b];
    }
}
