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

/// `e^x`, within 2 ulp of the correctly rounded result (checked against `f64`
/// in the tests), `0` below `−87.34` (where `e^x` is no longer a normal `f32`),
/// `+∞` above `88.72`, NaN for NaN.
///
/// Deviation from "libm on the CPU": this one function is our own, because the
/// mixtures evaluate one `exp` per lobe and libm's `expf` is an out-of-line
/// call with branches that stops the `K`-lobe loop from vectorising. It is the
/// classic Cephes `expf`: `x = n ln 2 + r` with `|r| ≤ ln 2 / 2` (Cody–Waite
/// split of ln 2), a degree-6 polynomial for `e^r`, and `2^n` built from the
/// exponent bits — branch-free, so LLVM turns the lobe loop into SIMD.
#[inline]
#[must_use]
pub fn exp(x: f32) -> f32 {
    const LOG2_E: f32 = core::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const MAX_ARG: f32 = 88.722_83;
    const MIN_ARG: f32 = -87.336_55;
    // Round-to-nearest of x·log2(e) by the 1.5·2²³ trick (exact for |n| < 2²²).
    const ROUND: f32 = 12_582_912.0;
    let xc = x.clamp(MIN_ARG, MAX_ARG);
    let shifted = xc * LOG2_E + ROUND;
    let n = shifted - ROUND;
    let r = xc - n * LN2_HI - n * LN2_LO;
    let p = 1.987_569_2e-4;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5;
    let er = p * r * r + r + 1.0;
    // n is also held, as an integer, in the low mantissa bits of `shifted`:
    // reading it from there avoids a float → int conversion (which does not
    // vectorise well with Rust's saturating `as`).
    // 2^n is applied as 2^(n/2) · 2^(n − n/2) so that both factors stay normal
    // over the whole range n ∈ [−126, 128].
    let n_int = shifted.to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    let n_half = n_int >> 1;
    let scale_a = f32::from_bits(((n_half + 127) as u32) << 23);
    let scale_b = f32::from_bits(((n_int - n_half + 127) as u32) << 23);
    let y = er * scale_a * scale_b;
    let y = if x < MIN_ARG { 0.0 } else { y };
    let y = if x > MAX_ARG { f32::INFINITY } else { y };
    // NaN in, NaN out (the clamps above would otherwise hide it).
    if x.is_nan() {
        x
    } else {
        y
    }
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
    // Bit operations instead of libm's out-of-line call: exact, and inlined.
    f32::from_bits((x.to_bits() & 0x7fff_ffff) | (s.to_bits() & 0x8000_0000))
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

/// Largest integer `≤ x` (libm `floorf`; a native instruction on the GPU).
/// NaN and ±∞ are returned unchanged.
#[inline]
#[must_use]
pub fn floor(x: f32) -> f32 {
    libm::floorf(x)
}
