//! The single math shim of `guiding-core`.
//!
//! Every transcendental function the kernels use goes through this module, so
//! that one file decides where the math comes from: [`libm`] on the CPU (exact,
//! portable, `no_std`), and later `spirv-std` intrinsics when the crate is
//! compiled to SPIR-V. Kernels never call `f32::exp` & co. directly.
//!
//! Only `f32` is offered: GPU kernels must not touch `f64`.

/// π.
pub const PI: f32 = core::f32::consts::PI;
/// 2π.
pub const TWO_PI: f32 = 2.0 * core::f32::consts::PI;
/// 4π, the solid angle of the sphere.
pub const FOUR_PI: f32 = 4.0 * core::f32::consts::PI;
/// 1 / (2π).
pub const INV_TWO_PI: f32 = 0.5 * core::f32::consts::FRAC_1_PI;
/// 1 / (4π), the density of the uniform sphere.
pub const INV_FOUR_PI: f32 = 0.25 * core::f32::consts::FRAC_1_PI;
/// The largest `f32` below one, the upper end of `[0, 1)` random numbers.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON * 0.5;

/// `e^x`.
#[inline]
#[must_use]
pub fn exp(x: f32) -> f32 {
    libm::expf(x)
}

/// `e^x - 1`, accurate for small `|x|`.
#[inline]
#[must_use]
pub fn expm1(x: f32) -> f32 {
    libm::expm1f(x)
}

/// Natural logarithm.
#[inline]
#[must_use]
pub fn ln(x: f32) -> f32 {
    libm::logf(x)
}

/// `ln(1 + x)`, accurate for small `|x|`.
#[inline]
#[must_use]
pub fn ln_1p(x: f32) -> f32 {
    libm::log1pf(x)
}

/// Square root.
#[inline]
#[must_use]
pub fn sqrt(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// Square root of `max(x, 0)`: never NaN for a slightly negative rounding result.
#[inline]
#[must_use]
pub fn safe_sqrt(x: f32) -> f32 {
    libm::sqrtf(x.max(0.0))
}

/// `(sin x, cos x)`.
#[inline]
#[must_use]
pub fn sin_cos(x: f32) -> (f32, f32) {
    libm::sincosf(x)
}

/// Four-quadrant arctangent of `y / x`, in `[-π, π]`.
#[inline]
#[must_use]
pub fn atan2(y: f32, x: f32) -> f32 {
    libm::atan2f(y, x)
}

/// Arctangent, in `[-π/2, π/2]`.
#[inline]
#[must_use]
pub fn atan(x: f32) -> f32 {
    libm::atanf(x)
}

/// Tangent.
#[inline]
#[must_use]
pub fn tan(x: f32) -> f32 {
    libm::tanf(x)
}

/// `|x|` with the sign of `s`.
#[inline]
#[must_use]
pub fn copysign(x: f32, s: f32) -> f32 {
    libm::copysignf(x, s)
}

/// Logistic sigmoid `1 / (1 + e^{-x})`, finite for every finite or infinite `x`.
#[inline]
#[must_use]
pub fn sigmoid(x: f32) -> f32 {
    // Branch on the sign so that `exp` only ever sees a non-positive argument.
    let e = exp(-x.abs());
    if x >= 0.0 {
        1.0 / (1.0 + e)
    } else {
        e / (1.0 + e)
    }
}

/// Replaces NaN by `0` and clamps to `[-limit, limit]`.
///
/// Used on raw network outputs before any activation, so that a corrupt
/// output can never produce a NaN distribution.
#[inline]
#[must_use]
pub fn sanitize(x: f32, limit: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        x.clamp(-limit, limit)
    }
}

/// `x / (1 - e^{-x})`, the ratio behind the vMF/NASG normalisers
/// (`κ / (1 - e^{-2κ})`); equals `1` at `x = 0` and is accurate for every `x ≥ 0`.
#[inline]
#[must_use]
pub fn x_over_one_minus_exp_neg(x: f32) -> f32 {
    if x < 1e-30 {
        // Series: 1 + x/2 + x²/12 + …; at this size only the constant survives.
        1.0
    } else {
        x / -expm1(-x)
    }
}
