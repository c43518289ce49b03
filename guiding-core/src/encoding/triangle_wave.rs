//! Triangle-wave encoding of a scalar: tiny-cuda-nn's `TriangleWave`
//! (introduced for Neural Radiance Caching, Müller et al. 2021), which
//! Figueiredo et al. 2025 ("Neural Path Guiding with Distribution
//! Factorization") use for the conditional's input `ε1` with 12 frequencies.
//!
//! ## Formula (tiny-cuda-nn's form, followed exactly)
//!
//! For `i < n`:
//!
//! `tw_i(x) = 4 · |frac(2^{i−1} x + i/4) − ½| − 1 ∈ [−1, 1]`,
//!
//! a triangle wave of period `2^{1−i}` (`i = 0` spans `[0, 1]` with half a
//! period) shifted by a quarter period per frequency ("to help disambiguate
//! locations"). Its derivative is piecewise constant:
//! `d tw_i/dx = 2^{i+1} · sign(frac(2^{i−1} x + i/4) − ½)` (`+` at the kink,
//! as tiny-cuda-nn).
//!
//! Evaluated as `frac(frac(2^{i−1} x) + (i mod 4)/4)`: the scaling by a power
//! of two is exact, so the error does not grow with the frequency (tiny-cuda-nn
//! adds `i/4` before taking `frac`; the results agree up to rounding).
//!
//! The "paper-like" alternative `|2 frac(2^i x) − 1|` is not used: this
//! library keeps tiny-cuda-nn's encoding, which the published models were
//! trained with.

use crate::encoding::slots_inside;
use crate::math::floor;

/// Frequencies Figueiredo et al. 2025 use for `ε1`.
pub const TRIANGLE_WAVE_DF_FREQUENCIES: u32 = 12;

/// `2²⁴`: every `f32` at or above it is an even integer.
const TWO_POW_24: f32 = 16_777_216.0;
/// Largest frequency factor used: beyond `2^100` the factor stops growing
/// (exact for every `|x| ≥ 2⁻⁷⁶`, where `frac` is already 0).
const MAX_FACTOR: f32 = 1.267_650_6e30;

/// NaN → 0; clamped to `±2²⁴`. Exact for the encoding: every `|x| ≥ 2²⁴` is
/// an even integer, as is `2²⁴`, so `frac(2^{i−1} x) = 0` for both.
#[inline]
fn sanitize_input(x: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        x.clamp(-TWO_POW_24, TWO_POW_24)
    }
}

/// `frac(p·x + (i mod 4)/4) − ½`, with `p = 2^{i−1}`.
#[inline]
fn phase(p: f32, x: f32, i: u32) -> f32 {
    let y = p * x;
    let f = if y.abs() >= TWO_POW_24 {
        0.0
    } else {
        y - floor(y)
    };
    let mut g = f + 0.25 * (i & 3) as f32;
    if g >= 1.0 {
        g -= 1.0;
    }
    g - 0.5
}

/// The factor of the next frequency: `2p`, until it reaches [`MAX_FACTOR`].
#[inline]
fn next_factor(p: f32) -> f32 {
    if p < MAX_FACTOR {
        p * 2.0
    } else {
        p
    }
}

/// Writes `tw_i(x)` for `i < frequencies` (formula in the
/// [module docs](self)) to `out[out_offset ..]` and returns
/// `out_offset + frequencies`.
///
/// NaN encodes as 0; `x` is clamped to `±2²⁴` (exact, see the module docs),
/// so ±∞ and `10³⁰` are fine. Slots at or past `N` are skipped (the loop
/// stops there). Every output is in `[−1, 1]`.
pub fn triangle_wave_encode<const N: usize>(
    x: f32,
    frequencies: u32,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    let n = slots_inside::<N>(out_offset, frequencies);
    let x = sanitize_input(x);
    let mut p = 0.5f32;
    let mut i = 0u32;
    while i < n {
        out[out_offset + i as usize] = 4.0 * phase(p, x, i).abs() - 1.0;
        p = next_factor(p);
        i += 1;
    }
    out_offset.wrapping_add(frequencies as usize)
}

/// `∂loss/∂x = Σ_i d_out[d_out_offset + i] · d tw_i/dx` (derivative in the
/// [module docs](self)), the input gradient of [`triangle_wave_encode`].
///
/// Zero for NaN `x` and for `|x| > 2²⁴` (where the clamp is flat). `d_out`
/// slots at or past `N` count as zero. Finite `d_out` with moderate
/// `frequencies` (`≤ 100`) gives a finite result.
#[must_use]
pub fn triangle_wave_backward<const N: usize>(
    x: f32,
    frequencies: u32,
    d_out: &[f32; N],
    d_out_offset: usize,
) -> f32 {
    if x.is_nan() || x.abs() > TWO_POW_24 {
        return 0.0;
    }
    let mut sum = 0.0;
    let mut p = 0.5f32;
    let n = slots_inside::<N>(d_out_offset, frequencies);
    let mut i = 0u32;
    while i < n {
        let slope = if phase(p, x, i) < 0.0 {
            -4.0 * p
        } else {
            4.0 * p
        };
        sum += d_out[d_out_offset + i as usize] * slope;
        p = next_factor(p);
        i += 1;
    }
    sum
}
