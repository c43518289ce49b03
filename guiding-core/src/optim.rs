//! Optimisers over a flat `f32` parameter buffer: Adam (Kingma & Ba 2015)
//! and an exponential moving average of the weights for inference.
//!
//! Everything is elementwise, so a GPU runs one invocation per parameter
//! ([`adam_update`], [`ema_update_element`]) and the CPU loops over slices
//! ([`adam_step`], [`ema_update`]). The moment buffers `m`, `v` and the EMA
//! buffer use the same layout as the parameters (e.g. the
//! [`crate::mlp`] layout at the same offset).
//!
//! # Non-finite gradients
//!
//! A NaN or ±∞ gradient (a poisoned training sample) must never reach the
//! weights: once one parameter is NaN, every output is. Two guards:
//! - [`all_finite`] checks a whole gradient buffer, so the caller can skip
//!   the step altogether (recommended: one non-finite component usually
//!   means the whole batch is suspect; this is what loss-scaling trainers do);
//! - [`adam_update`] itself commits an element only if its gradient **and**
//!   its new parameter, `m` and `v` are all finite, and otherwise leaves all
//!   three untouched — a skipped step for that element. This also catches a
//!   finite gradient whose square overflows (`|g| ≳ 1.8·10¹⁹`).

use bytemuck::{Pod, Zeroable};

/// Adam hyper-parameters.
///
/// `repr(C)`, [`Pod`]: five `f32`, uploadable as a uniform.
///
/// Defaults ([`AdamConfig::DEFAULT`]): learning rate 10⁻³, `β₁ = 0.9`,
/// `β₂ = 0.99`, `ε = 10⁻¹⁵`, no L2 regularisation. `β₂` and `ε` are the
/// values of Instant NGP (Müller et al. 2022, §4), the tiny-cuda-nn setting
/// this project adopts for neural path guiding (NPM, Dong et al. 2023): the shorter
/// second-moment memory (0.99 instead of Kingma & Ba's 0.999) adapts faster to
/// the non-stationary online-training targets, and the tiny `ε` keeps the
/// update scale-invariant even for parameters with very small gradients.
/// (tiny-cuda-nn's own code defaults are `β₂ = 0.999`, `ε = 10⁻⁸`.)
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct AdamConfig {
    /// Step size α.
    pub learning_rate: f32,
    /// Decay of the first-moment estimate, `β₁`.
    pub beta1: f32,
    /// Decay of the second-moment estimate, `β₂`.
    pub beta2: f32,
    /// `ε` added to `√v̂` in the denominator.
    pub epsilon: f32,
    /// L2 regularisation `λ`: `λ · θ` is added to the gradient before the
    /// moments (coupled L2, as tiny-cuda-nn's `l2_reg`; not AdamW's decoupled
    /// weight decay).
    pub l2_regularization: f32,
}

impl AdamConfig {
    /// The defaults described on [`AdamConfig`].
    pub const DEFAULT: Self = Self::new(1e-3);

    /// The defaults with the given learning rate.
    #[must_use]
    pub const fn new(learning_rate: f32) -> Self {
        Self {
            learning_rate,
            beta1: 0.9,
            beta2: 0.99,
            epsilon: 1e-15,
            l2_regularization: 0.0,
        }
    }

    /// `self` with another learning rate.
    #[must_use]
    pub const fn with_learning_rate(self, learning_rate: f32) -> Self {
        Self {
            learning_rate,
            ..self
        }
    }

    /// `self` with other moment decays.
    #[must_use]
    pub const fn with_betas(self, beta1: f32, beta2: f32) -> Self {
        Self {
            beta1,
            beta2,
            ..self
        }
    }

    /// `self` with another `ε`.
    #[must_use]
    pub const fn with_epsilon(self, epsilon: f32) -> Self {
        Self { epsilon, ..self }
    }

    /// `self` with another L2 regularisation.
    #[must_use]
    pub const fn with_l2_regularization(self, l2_regularization: f32) -> Self {
        Self {
            l2_regularization,
            ..self
        }
    }
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// `base^exp` by square-and-multiply (`⌊log₂ exp⌋ + 1` squarings, no
/// transcendental call, no `f64`). Squaring doubles a relative error, so the
/// result is within a relative `~exp · u` (`u = 2⁻²⁴`) of the exact power of
/// the `f32` base — like `exp(exp · ln base)`; for Adam's bias corrections
/// `1 − βᵗ` that is an absolute error `t βᵗ u ≤ u / (e (1 − β))`, i.e.
/// `≤ 37 u` for `β = 0.99`.
#[inline]
#[must_use]
pub fn powi(base: f32, exp: u32) -> f32 {
    let mut result = 1.0;
    let mut b = base;
    let mut e = exp;
    while e > 0 {
        if e & 1 == 1 {
            result *= b;
        }
        b *= b;
        e >>= 1;
    }
    result
}

/// The per-step factors of Adam's bias correction, computed once per step
/// and shared by every element: `1 − β₁ᵗ` and `1 − β₂ᵗ`.
///
/// `repr(C)`, [`Pod`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct AdamStepFactors {
    /// `1 − β₁ᵗ`.
    pub bias_correction1: f32,
    /// `1 − β₂ᵗ`.
    pub bias_correction2: f32,
}

impl AdamStepFactors {
    /// Factors of the 1-based step `step` (0 is treated as 1).
    #[must_use]
    pub fn new(step: u32, cfg: &AdamConfig) -> Self {
        let t = if step == 0 { 1 } else { step };
        Self {
            bias_correction1: 1.0 - powi(cfg.beta1, t),
            bias_correction2: 1.0 - powi(cfg.beta2, t),
        }
    }
}

/// One Adam update of one element with precomputed [`AdamStepFactors`]
/// (Kingma & Ba 2015, *Adam: A Method for Stochastic Optimization*,
/// Algorithm 1):
///
/// ```text
/// g  = grad + λ θ
/// m ← β₁ m + (1 − β₁) g
/// v ← β₂ v + (1 − β₂) g²
/// θ ← θ − α · (m / (1 − β₁ᵗ)) / (√(v / (1 − β₂ᵗ)) + ε)
/// ```
///
/// Nothing is written unless `grad` and the new `θ`, `m`, `v` are all finite
/// (see the [module docs](self)); returns whether the element was updated.
#[inline]
pub fn adam_update_with_factors(
    param: &mut f32,
    m: &mut f32,
    v: &mut f32,
    grad: f32,
    cfg: &AdamConfig,
    factors: &AdamStepFactors,
) -> bool {
    if !grad.is_finite() {
        return false;
    }
    let g = grad + cfg.l2_regularization * *param;
    let m_new = cfg.beta1 * *m + (1.0 - cfg.beta1) * g;
    let v_new = cfg.beta2 * *v + (1.0 - cfg.beta2) * (g * g);
    let m_hat = m_new / factors.bias_correction1;
    let v_hat = v_new / factors.bias_correction2;
    let p_new = *param - cfg.learning_rate * m_hat / (crate::math::sqrt(v_hat) + cfg.epsilon);
    if p_new.is_finite() && m_new.is_finite() && v_new.is_finite() {
        *param = p_new;
        *m = m_new;
        *v = v_new;
        true
    } else {
        false
    }
}

/// One Adam update of one element at the 1-based step `step` (0 is treated
/// as 1): [`adam_update_with_factors`] with [`AdamStepFactors::new`]. The
/// per-element kernel for a GPU (one invocation per parameter); a CPU loop
/// should use [`adam_step`], which computes the factors once.
///
/// Returns whether the element was updated (`false`: non-finite gradient or
/// result, nothing written).
#[inline]
pub fn adam_update(
    param: &mut f32,
    m: &mut f32,
    v: &mut f32,
    grad: f32,
    step: u32,
    cfg: &AdamConfig,
) -> bool {
    adam_update_with_factors(param, m, v, grad, cfg, &AdamStepFactors::new(step, cfg))
}

/// [`adam_update`] over whole slices (`params[i]` with `grads[i]`, `m[i]`,
/// `v[i]`); returns how many elements were skipped for a non-finite gradient
/// or result (0 normally).
///
/// # Panics
/// If `grads`, `m` or `v` is shorter than `params`.
pub fn adam_step(
    params: &mut [f32],
    grads: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    step: u32,
    cfg: &AdamConfig,
) -> usize {
    let factors = AdamStepFactors::new(step, cfg);
    let n = params.len();
    let mut skipped = 0;
    let mut i = 0;
    while i < n {
        if !adam_update_with_factors(
            &mut params[i],
            &mut m[i],
            &mut v[i],
            grads[i],
            cfg,
            &factors,
        ) {
            skipped += 1;
        }
        i += 1;
    }
    skipped
}

/// Whether every element of `values` is finite (no NaN, no ±∞). Use it on
/// a gradient buffer to skip a whole poisoned step.
#[must_use]
pub fn all_finite(values: &[f32]) -> bool {
    let mut ok = true;
    let mut i = 0;
    while i < values.len() {
        // No early exit: a branch-free AND vectorises on the CPU.
        ok &= values[i].is_finite();
        i += 1;
    }
    ok
}

/// Weight of the new value in the debiased EMA at the 1-based step `step`
/// (0 is treated as 1): `α_t = (1 − d) / (1 − dᵗ)`; `α₁ = 1`, `α_t → 1 − d`.
#[inline]
#[must_use]
pub fn ema_weight(decay: f32, step: u32) -> f32 {
    let t = if step == 0 { 1 } else { step };
    let denom = 1.0 - powi(decay, t);
    if denom > 0.0 {
        (1.0 - decay) / denom
    } else {
        // decay = 1 (or above): the first value is kept forever.
        if t == 1 {
            1.0
        } else {
            0.0
        }
    }
}

/// One element of [`ema_update`]: `ema ← (1 − α) ema + α θ` with `α` from
/// [`ema_weight`]; for `α ≥ 1` (the first step) exactly `ema ← θ`, whatever
/// the buffer held before (even NaN).
#[inline]
pub fn ema_update_element(ema: &mut f32, param: f32, alpha: f32) {
    *ema = if alpha >= 1.0 {
        param
    } else {
        (1.0 - alpha) * *ema + alpha * param
    };
}

/// Exponential moving average of the weights for inference (the runtime
/// renders with the average of the trained weights, decay `d = 0.95` in the
/// NPM setting), in the **debiased** form, one buffer:
///
/// ```text
/// ema_t = (1 − α_t) ema_{t−1} + α_t θ_t,   α_t = (1 − d) / (1 − dᵗ)
/// ```
///
/// which equals (up to rounding) the normalised weighted average
/// `Σ_{s≤t} d^{t−s} (1 − d) θ_s / (1 − dᵗ)` of all parameter iterates, i.e.
/// tiny-cuda-nn's two-buffer form (`S_t = d S_{t−1} + (1 − d) θ_t`, read out
/// as `S_t / (1 − dᵗ)`) without the second buffer. Why debiased: the plain
/// form `ema ← d·ema + (1 − d)θ` starts from whatever the buffer held (zeros,
/// or the random initial weights) and is pulled towards it for the first
/// `~1/(1 − d)` steps; debiased, step 1 simply copies `θ₁` (`α₁ = 1`), so the
/// buffer needs no initialisation and the average is usable from the first
/// step. `step` is the 1-based count of EMA updates (0 is treated as 1).
///
/// # Panics
/// If `params` is shorter than `ema`.
pub fn ema_update(ema: &mut [f32], params: &[f32], decay: f32, step: u32) {
    let alpha = ema_weight(decay, step);
    let mut i = 0;
    while i < ema.len() {
        ema_update_element(&mut ema[i], params[i], alpha);
        i += 1;
    }
}
