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

    with_fields! {
        /// `self` with another learning rate.
        with_learning_rate(learning_rate: f32);
        /// `self` with other moment decays.
        with_betas(beta1: f32, beta2: f32);
        /// `self` with another `ε`.
        with_epsilon(epsilon: f32);
        /// `self` with another L2 regularisation.
        with_l2_regularization(l2_regularization: f32);
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

/// The skip / clip decision of a training step, shared by every backend
/// (the CPU field and the Vulkan runtime): `None` skips the step (its mean
/// gradient or loss is not finite: nothing may reach Adam, the moments or
/// the EMA); otherwise the factor the mean gradient is scaled by, `1` or,
/// when its largest magnitude `max_abs` exceeds `clip`, `clip / max_abs`
/// (direction kept; see `guiding_core::field`'s training docs for why).
#[inline]
#[must_use]
pub fn step_clip_factor(finite: bool, max_abs: f32, clip: f32) -> Option<f32> {
    if !finite || !max_abs.is_finite() {
        return None;
    }
    if max_abs > clip {
        Some(clip / max_abs)
    } else {
        Some(1.0)
    }
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
    // One bounds check up front, so the loop below vectorises.
    let params = &params[..ema.len()];
    let mut i = 0;
    while i < ema.len() {
        ema_update_element(&mut ema[i], params[i], alpha);
        i += 1;
    }
}

/// Elements per block of [`adam_ema_step`]: the five buffers of one block
/// (80 KiB) stay in L2 from Adam to the EMA to the zeroing.
#[cfg(feature = "std")]
const FUSED_BLOCK: usize = 4096;

/// Lanes of one [`adam_lanes`] call (a multiple of every x86 vector width).
#[cfg(feature = "std")]
const FUSED_LANES: usize = 16;

/// [`adam_update_with_factors`] on `FUSED_LANES` elements at once, written
/// so that the compiler vectorises it: finiteness as `|x| < ∞` (false for
/// NaN), the commit as a bit mask. Returns the number of skipped elements.
#[cfg(feature = "std")]
#[inline(always)]
fn adam_lanes(
    p: &mut [f32; FUSED_LANES],
    g: &[f32; FUSED_LANES],
    m: &mut [f32; FUSED_LANES],
    v: &mut [f32; FUSED_LANES],
    cfg: &AdamConfig,
    f: &AdamStepFactors,
) -> u32 {
    let mut skipped = 0u32;
    for l in 0..FUSED_LANES {
        let grad = g[l];
        let gl = grad + cfg.l2_regularization * p[l];
        let m_new = cfg.beta1 * m[l] + (1.0 - cfg.beta1) * gl;
        let v_new = cfg.beta2 * v[l] + (1.0 - cfg.beta2) * (gl * gl);
        let m_hat = m_new / f.bias_correction1;
        let v_hat = v_new / f.bias_correction2;
        let p_new = p[l] - cfg.learning_rate * m_hat / (v_hat.sqrt() + cfg.epsilon);
        let ok = (grad.abs() < f32::INFINITY)
            & (p_new.abs() < f32::INFINITY)
            & (m_new.abs() < f32::INFINITY)
            & (v_new.abs() < f32::INFINITY);
        let keep = u32::from(ok).wrapping_neg();
        let pick =
            |new: f32, old: f32| f32::from_bits((new.to_bits() & keep) | (old.to_bits() & !keep));
        p[l] = pick(p_new, p[l]);
        m[l] = pick(m_new, m[l]);
        v[l] = pick(v_new, v[l]);
        skipped += 1 - u32::from(ok);
    }
    skipped
}

/// One whole optimiser step of the CPU runtime, fused: [`adam_step`] on
/// `params`, `m`, `v` with `grads`, then [`ema_update`] of `ema` towards the
/// new `params` with `ema_decay`, then `grads` zeroed — the three passes done
/// block by block, so each block is read from memory once. Returns how many
/// elements Adam skipped (as [`adam_step`]).
///
/// Every result is bit for bit that of [`adam_update_with_factors`] and
/// [`ema_update_element`]: the same operations in the same order (Rust never
/// contracts them into fused multiply-adds), with the element's commit
/// written as a bit mask instead of a branch and `f32::sqrt` (correctly
/// rounded, as `libm::sqrtf`), so that the loop vectorises.
///
/// # Panics
/// If `grads`, `m`, `v` or `ema` is shorter than `params`.
#[cfg(feature = "std")]
#[allow(clippy::too_many_arguments)] // the optimiser's five buffers and its settings
pub fn adam_ema_step(
    params: &mut [f32],
    grads: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    ema: &mut [f32],
    step: u32,
    cfg: &AdamConfig,
    ema_decay: f32,
) -> usize {
    let n = params.len();
    let (grads, m, v, ema) = (&mut grads[..n], &mut m[..n], &mut v[..n], &mut ema[..n]);
    let f = AdamStepFactors::new(step, cfg);
    let mut skipped = 0usize;
    let mut start = 0;
    while start < n {
        let end = (start + FUSED_BLOCK).min(n);
        let p = &mut params[start..end];
        let g = &mut grads[start..end];
        let mb = &mut m[start..end];
        let vb = &mut v[start..end];
        let lanes = p.len() / FUSED_LANES * FUSED_LANES;
        let mut k = 0;
        while k < lanes {
            let r = k..k + FUSED_LANES;
            skipped += adam_lanes(
                (&mut p[r.clone()])
                    .try_into()
                    .unwrap_or_else(|_| unreachable!()),
                (&g[r.clone()])
                    .try_into()
                    .unwrap_or_else(|_| unreachable!()),
                (&mut mb[r.clone()])
                    .try_into()
                    .unwrap_or_else(|_| unreachable!()),
                (&mut vb[r]).try_into().unwrap_or_else(|_| unreachable!()),
                cfg,
                &f,
            ) as usize;
            k += FUSED_LANES;
        }
        for i in lanes..p.len() {
            skipped += usize::from(!adam_update_with_factors(
                &mut p[i], &mut mb[i], &mut vb[i], g[i], cfg, &f,
            ));
        }
        ema_update(&mut ema[start..end], p, ema_decay, step);
        g.fill(0.0);
        start = end;
    }
    skipped
}
