//! Frequency (positional) encoding of NeRF (Mildenhall et al. 2020, §5.1),
//! tiny-cuda-nn's `Frequency` encoding, used for the radiance cache inputs.
//!
//! ## Formula
//!
//! For every input component `x_d` (`d < D`) and frequency `i < n`:
//!
//! `out[2(d·n + i)]     = sin(2^i π x_d)`,
//! `out[2(d·n + i) + 1] = cos(2^i π x_d)`,
//!
//! component-major, then frequency, then (sin, cos) — tiny-cuda-nn's order.
//!
//! The argument is reduced exactly in half-turns before any rounding:
//! `y_0 = |x| mod 2` folded to `(−1, 1]`, `y_{i+1} = 2 y_i` folded again (all
//! exact in `f32`), then `sin(π y_i)` (negated for `x < 0`) and `cos(π y_i)`.
//! So the absolute error stays ~2·10⁻⁷ at every frequency instead of growing
//! like `2^i |x| ulp(π)` as with a naive `sin(2^i π x)`. Deviation from
//! tiny-cuda-nn: only this (more accurate) evaluation.

use crate::encoding::write_clamped;
use crate::math::{floor, sin_cos, PI};

/// `2²⁴`: every `f32` at or above it is an even integer.
const TWO_POW_24: f32 = 16_777_216.0;

/// Width of [`frequency_encode`]: `2 · D · frequencies` (wrapping).
#[inline]
#[must_use]
pub const fn frequency_width(components: usize, frequencies: u32) -> usize {
    components
        .wrapping_mul(frequencies as usize)
        .wrapping_mul(2)
}

/// `2^0 x` in half-turns, reduced to `(−1, 1]` exactly: `sin(π y) = sin(π x)`,
/// `cos(π y) = cos(π x)`. NaN → 0; `|x| ≥ 2²⁴` (an even integer, ±∞
/// included) → 0, which is exact.
#[inline]
fn reduce(x: f32) -> f32 {
    let a = x.abs();
    if a.is_nan() || a >= TWO_POW_24 {
        return 0.0;
    }
    let h = 0.5 * a;
    // h ≥ 0: h − ⌊h⌋ is exact (Sterbenz for h ≥ 1, trivially for h < 1).
    let mut y = 2.0 * (h - floor(h));
    if y > 1.0 {
        y -= 2.0;
    }
    if x < 0.0 {
        -y
    } else {
        y
    }
}

/// Writes the `2 · D · frequencies` sin/cos features of `input` (formula and
/// order in the [module docs](self)) to `out[out_offset ..]` and returns
/// `out_offset + 2·D·frequencies`.
///
/// NaN components encode as 0; `|x| ≥ 2²⁴` (±∞ included) encodes as 0 too,
/// which is exact for finite values (they are even integers). Slots at or
/// past `N` are skipped (the loops stop there). Every output is in `[−1, 1]`.
pub fn frequency_encode<const D: usize, const N: usize>(
    input: &[f32; D],
    frequencies: u32,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    let end = out_offset.wrapping_add(frequency_width(D, frequencies));
    if out_offset >= N {
        return end;
    }
    let mut o = out_offset;
    let mut d = 0;
    while d < D {
        let mut y = reduce(input[d]);
        let mut i = 0u32;
        while i < frequencies {
            if o >= N {
                return end;
            }
            let (s, c) = sin_cos(PI * y);
            write_clamped(out, o, s);
            write_clamped(out, o + 1, c);
            o += 2;
            // Next octave: double and fold back into [−1, 1] (exact).
            y *= 2.0;
            if y > 1.0 {
                y -= 2.0;
            } else if y < -1.0 {
                y += 2.0;
            }
            i += 1;
        }
        d += 1;
    }
    end
}
