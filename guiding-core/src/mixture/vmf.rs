//! Mixtures of `K` von Mises–Fisher lobes (Neural Parametric Mixtures, Dong et
//! al. 2023), their decoder from raw network outputs, the analytic gradient of
//! `ln p(ω)` used for training (NPM eq. 9), and the product with a clamped
//! cosine used by radiance guiding.

use crate::lobe::vmf::{dlog_pdf_dkappa, VmfLobe};
use crate::lobe::DirectionSample;
use crate::math::{
    exp, exp_nonpositive, expm1_nonpositive, ln, sanitize, sigmoid, sin_cos_turns, sqrt,
    INV_FOUR_PI, PI, TWO_PI,
};
use crate::mixture::{
    log_sum_exp_parts, normalized_weights, pairwise_sum, select_lobe, softmax, weight_logits,
};
use crate::sphere::one_minus_cos_angle;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Raw network outputs per vMF lobe: `[weight logit, log κ, θ, φ]`.
pub const VMF_RAW_PER_LOBE: usize = 4;
/// Raw outputs are clamped to `±VMF_RAW_LIMIT` (NaN becomes 0) before decoding.
pub const VMF_RAW_LIMIT: f32 = 1e30;
/// Lower clamp of the raw `ln κ` output: κ ≥ e⁻¹⁰ ≈ 4.5·10⁻⁵.
pub const VMF_LOG_KAPPA_MIN: f32 = -10.0;
/// Upper clamp of the raw `ln κ` output: κ ≤ e¹⁰ ≈ 2.2·10⁴ (a lobe ~0.4° wide).
pub const VMF_LOG_KAPPA_MAX: f32 = 10.0;
/// Concentration of the vMF lobe that approximates the clamped cosine
/// `max(0, n·ω)` (the value NPM and Open PGL use).
pub const CLAMPED_COSINE_KAPPA: f32 = 2.18853;

/// A mixture of `K` vMF lobes, stored structure-of-arrays so the `K`-lobe
/// density loop vectorises.
///
/// `repr(C)`, `Pod`, `7 K` floats (224 bytes for K = 8): a decoded
/// distribution that a renderer can keep per path vertex and sample, or ask
/// the [`pdf`](Self::pdf) of several directions (MIS, NEE), without touching
/// the network again.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VmfMixture<const K: usize> {
    /// Mixture weights, `≥ 0`, summing to one.
    pub weight: [f32; K],
    /// x components of the unit mean directions.
    pub mean_x: [f32; K],
    /// y components of the unit mean directions.
    pub mean_y: [f32; K],
    /// z components of the unit mean directions.
    pub mean_z: [f32; K],
    /// Concentrations κ.
    pub kappa: [f32; K],
    /// Per-lobe normalisers `κ / (2π (1 − e^{−2κ}))`.
    pub norm: [f32; K],
    /// Per-lobe `1 − e^{−2κ}`.
    pub one_minus_e2k: [f32; K],
}

// SAFETY: `repr(C)` struct of `[f32; K]` arrays only: no padding, every bit
// pattern valid, zero is valid.
unsafe impl<const K: usize> Zeroable for VmfMixture<K> {}
// SAFETY: see above; `Copy + 'static` holds for every `K`.
unsafe impl<const K: usize> Pod for VmfMixture<K> {}

/// One lobe's decoded parameters and the activation derivatives the gradient
/// needs.
struct DecodedLobe {
    mean: Vec3,
    /// ∂μ/∂(raw θ).
    dmean_dtheta_raw: Vec3,
    /// ∂μ/∂(raw φ).
    dmean_dphi_raw: Vec3,
    kappa: f32,
    /// ∂κ/∂(raw ln κ): κ inside the clamp range, 0 outside.
    dkappa_draw: f32,
}

/// NPM Table 1 activations for one lobe: `κ = exp(clamp(r₁))`,
/// `θ = π·sigmoid(r₂)`, `φ = 2π·sigmoid(r₃)`, `μ = (sin θ cos φ, sin θ sin φ, cos θ)`.
fn decode_lobe(raw: &[f32; VMF_RAW_PER_LOBE]) -> DecodedLobe {
    let r_kappa = sanitize(raw[1], VMF_RAW_LIMIT);
    let log_kappa = r_kappa.clamp(VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX);
    let kappa = exp(log_kappa);
    let inside = r_kappa > VMF_LOG_KAPPA_MIN && r_kappa < VMF_LOG_KAPPA_MAX;
    let s_theta = sigmoid(sanitize(raw[2], VMF_RAW_LIMIT));
    let s_phi = sigmoid(sanitize(raw[3], VMF_RAW_LIMIT));
    let (sin_t, cos_t) = sin_cos_turns(0.5 * s_theta);
    let (sin_p, cos_p) = sin_cos_turns(s_phi);
    let mean = Vec3::new(sin_t * cos_p, sin_t * sin_p, cos_t);
    let dtheta = PI * s_theta * (1.0 - s_theta);
    let dphi = TWO_PI * s_phi * (1.0 - s_phi);
    DecodedLobe {
        mean,
        dmean_dtheta_raw: Vec3::new(cos_t * cos_p, cos_t * sin_p, -sin_t) * dtheta,
        dmean_dphi_raw: Vec3::new(-sin_t * sin_p, sin_t * cos_p, 0.0) * dphi,
        kappa,
        dkappa_draw: if inside { kappa } else { 0.0 },
    }
}

impl<const K: usize> VmfMixture<K> {
    /// All-zero mixture (the starting value of the constructors; written
    /// out because `Zeroable::zeroed` goes through `MaybeUninit`, which
    /// rust-gpu cannot compile).
    pub const ZERO: Self = Self {
        weight: [0.0; K],
        mean_x: [0.0; K],
        mean_y: [0.0; K],
        mean_z: [0.0; K],
        kappa: [0.0; K],
        norm: [0.0; K],
        one_minus_e2k: [0.0; K],
    };
}

impl<const K: usize> VmfMixture<K> {
    /// Mixture of the given lobes with the given weights (normalised here;
    /// negative or NaN weights count as zero, all-zero weights become uniform).
    #[must_use]
    pub fn from_lobes(lobes: &[VmfLobe; K], weights: &[f32; K]) -> Self {
        let mut m = Self::ZERO;
        m.weight = normalized_weights(weights);
        let mut k = 0;
        while k < K {
            m.set_lobe(k, &lobes[k]);
            k += 1;
        }
        m
    }

    /// Decodes raw network outputs (NPM Table 1): weights by softmax of the
    /// logits, `κ = exp(clamp(ln κ, −10, 10))`, mean from sigmoid-activated
    /// spherical angles. Any input, including NaN and ±∞, gives a valid
    /// mixture.
    ///
    /// Written lobe-parallel (one index loop per quantity over `[f32; K]`,
    /// every function inlined and branch-free: [`exp`], [`sigmoid`],
    /// [`sin_cos_turns`], [`expm1_nonpositive`]) so that a CPU evaluates
    /// the `K = 8` lobes as one SIMD vector. The values are those of
    /// [`VmfLobe::new`] of the decoded mean and κ: the mean
    /// `(sin θ cos φ, sin θ sin φ, cos θ)` renormalised, κ clamped to
    /// `[0, VMF_KAPPA_MAX]`, the normaliser `2κ / (1 − e^{−2κ}) / 4π`.
    #[must_use]
    pub fn decode(raw: &[[f32; VMF_RAW_PER_LOBE]; K]) -> Self {
        let mut m = Self::ZERO;
        softmax(&weight_logits(raw, VMF_RAW_LIMIT), &mut m.weight);
        // Transposed first, so every loop below runs over contiguous arrays.
        let (mut r_kappa, mut r_theta, mut r_phi) = ([0.0f32; K], [0.0f32; K], [0.0f32; K]);
        let mut k = 0;
        while k < K {
            r_kappa[k] = raw[k][1];
            r_theta[k] = raw[k][2];
            r_phi[k] = raw[k][3];
            k += 1;
        }
        k = 0;
        while k < K {
            let r = sanitize(r_kappa[k], VMF_RAW_LIMIT);
            m.kappa[k] = exp(r.clamp(VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX));
            // θ = π s_θ and φ = 2π s_φ, in turns: s_θ / 2 and s_φ.
            let s_theta = sigmoid(sanitize(r_theta[k], VMF_RAW_LIMIT));
            let s_phi = sigmoid(sanitize(r_phi[k], VMF_RAW_LIMIT));
            let (sin_t, cos_t) = sin_cos_turns(0.5 * s_theta);
            let (sin_p, cos_p) = sin_cos_turns(s_phi);
            let (x, y, z) = (sin_t * cos_p, sin_t * sin_p, cos_t);
            // |μ| = 1 up to rounding: renormalise as VmfLobe::new does.
            let inv = 1.0 / sqrt(x * x + y * y + z * z);
            m.mean_x[k] = x * inv;
            m.mean_y[k] = y * inv;
            m.mean_z[k] = z * inv;
            k += 1;
        }
        k = 0;
        while k < K {
            // κ ∈ [e⁻¹⁰, e¹⁰] here, far above VMF_KAPPA_UNIFORM and below
            // VMF_KAPPA_MAX: the normal branch of VmfLobe::new.
            let two_kappa = 2.0 * m.kappa[k];
            let one_minus = -expm1_nonpositive(-two_kappa);
            m.one_minus_e2k[k] = one_minus;
            m.norm[k] = two_kappa / one_minus * INV_FOUR_PI;
            k += 1;
        }
        m
    }

    fn set_lobe(&mut self, k: usize, lobe: &VmfLobe) {
        self.mean_x[k] = lobe.mean[0];
        self.mean_y[k] = lobe.mean[1];
        self.mean_z[k] = lobe.mean[2];
        self.kappa[k] = lobe.kappa;
        self.norm[k] = lobe.norm;
        self.one_minus_e2k[k] = lobe.one_minus_e2k;
    }

    /// Lobe `k` as a standalone [`VmfLobe`].
    #[inline]
    #[must_use]
    pub fn lobe(&self, k: usize) -> VmfLobe {
        VmfLobe {
            mean: [self.mean_x[k], self.mean_y[k], self.mean_z[k]],
            kappa: self.kappa[k],
            norm: self.norm[k],
            one_minus_e2k: self.one_minus_e2k[k],
        }
    }

    /// Density `Σ_k w_k v(ω | μ_k, κ_k)` in solid angle. The mixture is
    /// normalised (weights summing to one over normalised lobes) and has no
    /// unnormalised `eval`: `Σ_k w_k eval_k(ω)` would weigh the lobes' shapes
    /// without their normalisers, which is no quantity of the mixture (see
    /// the crate docs). Per-lobe values: [`Self::lobe`], then
    /// [`VmfLobe::eval`].
    #[inline]
    #[must_use]
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let len2 = direction.length_squared();
        if !(len2 > 0.0 && len2 <= f32::MAX) {
            // No angle to speak of: the antipode convention of `one_minus_cos_angle`.
            let mut p = 0.0;
            let mut k = 0;
            while k < K {
                p += self.weight[k] * self.norm[k] * exp(-2.0 * self.kappa[k]);
                k += 1;
            }
            return p;
        }
        self.pdf_unit(direction * (1.0 / sqrt(len2)))
    }

    /// [`Self::pdf`] of a direction known to be unit up to rounding.
    ///
    /// Per lobe, `1 − μ·ω = |ω − μ|² / 2` (half the squared chord). Like the
    /// cross-product form of `one_minus_cos_angle` this keeps full relative
    /// precision near the axis (the difference of two nearby unit vectors is
    /// exact, and a norm off by `1 + η` scales the result by about `1 + η`),
    /// but it is cheaper and needs neither a division nor a select per lobe.
    /// The per-lobe terms go to an array first (no floating-point reduction in
    /// the loop, which LLVM then vectorises) and are summed pairwise.
    #[inline]
    fn pdf_unit(&self, u: Vec3) -> f32 {
        let mut terms = [0.0f32; K];
        let mut k = 0;
        while k < K {
            let dx = u.x - self.mean_x[k];
            let dy = u.y - self.mean_y[k];
            let dz = u.z - self.mean_z[k];
            let half_chord2 = 0.5 * (dx * dx + dy * dy + dz * dz);
            terms[k] =
                self.weight[k] * self.norm[k] * exp_nonpositive(-self.kappa[k] * half_chord2);
            k += 1;
        }
        pairwise_sum(&mut terms)
    }

    /// The direction [`Self::sample`] draws from `u`, without its density
    /// (the batched CPU path evaluates the densities of many samples at once,
    /// [`crate::model::mixture_batch`]).
    #[inline]
    #[must_use]
    pub fn sample_direction(&self, u: Vec2) -> Vec3 {
        let (k, u_lobe) = select_lobe(&self.weight, u);
        self.lobe(k).sample_direction(u_lobe)
    }

    /// Draws a direction: `u.x` selects the lobe by the weights and is then
    /// rescaled and reused as the lobe's azimuth number; `u.y` is the lobe's
    /// polar number. The returned pdf is the full mixture density.
    #[inline]
    #[must_use]
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        let direction = self.sample_direction(u);
        // The sampled direction is unit up to rounding (~10⁻⁷), so the
        // normalisation of `pdf` is skipped: the density differs from
        // `pdf(direction)` by a relative ~10⁻⁷ κt, far below 10⁻⁴ wherever
        // the lobe's term is not negligible.
        DirectionSample {
            direction,
            pdf: self.pdf_unit(direction),
        }
    }

    /// Product with the clamped cosine `max(0, n·ω)` approximated by the vMF
    /// lobe `e^{κ_c (n·ω − 1)}`, κ_c = [`CLAMPED_COSINE_KAPPA`] (NPM §4.2,
    /// Open PGL's radiance → product conversion), normalised again.
    ///
    /// Closed form: `e^{κ_k(μ_k·ω−1)} e^{κ_c(n·ω−1)} = e^{κ'−κ_k−κ_c} e^{κ'(μ'·ω−1)}`
    /// with `κ' μ' = κ_k μ_k + κ_c n`, so lobe k keeps weight
    /// `∝ w_k · norm(κ_k) / norm(κ') · e^{κ'−κ_k−κ_c}` (the exponent is ≤ 0 by
    /// the triangle inequality; evaluated in log space).
    ///
    /// Approximation, not an identity: the vMF cosine is positive below the
    /// horizon, so the product keeps a little mass there.
    ///
    /// A zero `normal` is the library's "no surface" (a scattering point in a
    /// participating medium): there is no cosine, and the mixture comes back
    /// unchanged. A non-finite one reads as `+z`.
    #[must_use]
    pub fn product_with_clamped_cosine(&self, normal: Vec3) -> Self {
        if crate::frame::is_no_surface(normal) {
            return *self;
        }
        let n = crate::frame::normalize_or(normal, Vec3::Z);
        self.product_with_lobe(n, CLAMPED_COSINE_KAPPA)
    }

    /// Product with the (unnormalised) vMF lobe `e^{κ_c (n·ω − 1)}` around the unit `n`,
    /// `κ_c ≥ 0`, normalised again: the closed form of
    /// [`Self::product_with_clamped_cosine`] with any `κ_c` (e.g. a phase function's lobe,
    /// [`crate::lobe::vmf::hg_vmf_kappa`]). `κ_c = 0` returns the mixture unchanged (up to
    /// rounding).
    #[must_use]
    pub fn product_with_lobe(&self, n: Vec3, kc: f32) -> Self {
        let mut out = Self::ZERO;
        let mut log_w = [f32::MIN; K];
        let mut max_log = f32::MIN;
        let mut k = 0;
        while k < K {
            let lobe = self.lobe(k);
            let axis = lobe.mean() * lobe.kappa + n * kc;
            let kappa_p = sqrt(axis.length_squared());
            let product = VmfLobe::new(axis, kappa_p);
            out.set_lobe(k, &product);
            if self.weight[k] > 0.0 {
                log_w[k] = ln(self.weight[k]) + ln(lobe.norm) - ln(product.norm)
                    + (product.kappa - lobe.kappa - kc);
                max_log = max_log.max(log_w[k]);
            }
            k += 1;
        }
        let mut sum = 0.0;
        k = 0;
        while k < K {
            let w = if self.weight[k] > 0.0 {
                exp(log_w[k] - max_log)
            } else {
                0.0
            };
            out.weight[k] = w;
            sum += w;
            k += 1;
        }
        k = 0;
        while k < K {
            out.weight[k] /= sum;
            k += 1;
        }
        out
    }

    /// `ln p(ω)` of the mixture decoded from `raw`, and its gradient with
    /// respect to every raw output, through the activations of
    /// [`Self::decode`] — the term NPM eq. 9 weights per training sample.
    ///
    /// Evaluated in log space (log-softmax, log-sum-exp), so it stays finite
    /// where every lobe's density underflows. Clamped `ln κ` outputs get a zero
    /// gradient, as the clamp's derivative is zero there.
    pub fn grad_log_pdf(
        raw: &[[f32; VMF_RAW_PER_LOBE]; K],
        direction: Vec3,
        grad: &mut [[f32; VMF_RAW_PER_LOBE]; K],
    ) -> f32 {
        let direction = crate::frame::normalize_or(direction, Vec3::Z);
        let logits = weight_logits(raw, VMF_RAW_LIMIT);
        let (max_logit, log_sum) = log_sum_exp_parts(&logits);

        // log(w_k f_k) per lobe.
        let mut log_terms = [0.0; K];
        let mut k = 0;
        while k < K {
            let d = decode_lobe(&raw[k]);
            let lobe = VmfLobe::new(d.mean, d.kappa);
            let t = one_minus_cos_angle(lobe.mean(), direction);
            let log_w = logits[k] - max_logit - log_sum;
            log_terms[k] = log_w + ln(lobe.norm) - lobe.kappa * t;
            k += 1;
        }
        let (max_term, ln_total) = log_sum_exp_parts(&log_terms);
        let log_pdf = max_term + ln_total;

        k = 0;
        while k < K {
            let d = decode_lobe(&raw[k]);
            let t = one_minus_cos_angle(d.mean, direction);
            // Responsibility r_k = w_k f_k / p and weight w_k.
            let resp = exp(log_terms[k] - log_pdf);
            let w = exp(logits[k] - max_logit - log_sum);
            grad[k][0] = resp - w;
            grad[k][1] = resp * dlog_pdf_dkappa(d.kappa, t) * d.dkappa_draw;
            // ∂ ln f_k / ∂μ = κ ω (the density depends on μ through κ μ·ω).
            grad[k][2] = resp * d.kappa * direction.dot(d.dmean_dtheta_raw);
            grad[k][3] = resp * d.kappa * direction.dot(d.dmean_dphi_raw);
            k += 1;
        }
        log_pdf
    }
}
