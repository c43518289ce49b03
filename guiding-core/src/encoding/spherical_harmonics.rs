//! Real orthonormal spherical harmonics of a direction: tiny-cuda-nn's
//! `SphericalHarmonics` encoding, which Neural Parametric Mixtures (Dong et
//! al. 2023, §5.1) use for the outgoing direction `ωo`.
//!
//! ## Formula
//!
//! For bands `l < degree` and `−l ≤ m ≤ l`, output `l² + l + m` is
//!
//! `Y_l^m(ω) = √2 K_l^m P_l^m(cos θ) cos(mφ)` (m > 0),
//! `K_l^0 P_l^0(cos θ)` (m = 0),
//! `√2 K_l^|m| P_l^|m|(cos θ) sin(|m|φ)` (m < 0),
//! `K_l^m = √((2l + 1)(l − m)! / (4π (l + m)!))`,
//!
//! with the Condon–Shortley phase `(−1)^m` inside `P_l^m` (Sloan, "Stupid
//! Spherical Harmonics Tricks", 2008), written as polynomials in
//! `(x, y, z)` — e.g. `Y_0^0 = 1/(2√π)`, `Y_1^{−1} = −√3 y/(2√π)`,
//! `Y_1^0 = √3 z/(2√π)`, `Y_1^1 = −√3 x/(2√π)`. Orthonormal:
//! `∫_{S²} Y_i Y_j dω = δ_ij`.
//!
//! `degree` counts bands, as in tiny-cuda-nn: `degree ∈ 1..=4` gives
//! 1, 4, 9, 16 outputs (`degree²`).
//!
//! ## Deviations from tiny-cuda-nn
//!
//! - The input is a direction in world space, not tiny-cuda-nn's `[0, 1]³`
//!   remapping (`d = 2·in − 1`); it is normalised here (any non-zero finite
//!   vector is accepted).
//! - Degrees above 4 are clamped to 4 (tiny-cuda-nn goes to 8).

use crate::encoding::write_clamped;
use glam::Vec3;

/// Largest supported degree (number of bands): 16 outputs.
pub const SH_MAX_DEGREE: u32 = 4;

/// Number of outputs of [`sh_encode`] for `degree` (clamped to
/// [`SH_MAX_DEGREE`]): `degree²`.
#[inline]
#[must_use]
pub const fn sh_width(degree: u32) -> usize {
    let d = if degree < SH_MAX_DEGREE {
        degree
    } else {
        SH_MAX_DEGREE
    };
    (d * d) as usize
}

/// Unit vector along `d`, or `+z` when `d` has no direction (zero, NaN or
/// an infinite component). The largest component is divided out first, so
/// tiny and huge finite vectors normalise without underflow or overflow.
#[inline]
fn unit_direction(d: Vec3) -> Vec3 {
    let m = d.x.abs().max(d.y.abs()).max(d.z.abs());
    if !(m > 0.0 && m <= f32::MAX) || d.x.is_nan() || d.y.is_nan() || d.z.is_nan() {
        return Vec3::Z;
    }
    // Divide (not multiply by 1/m, which overflows for subnormal m): every
    // component lands in [−1, 1] and the largest is ±1.
    let s = d / m;
    s * (1.0 / crate::math::sqrt(s.length_squared()))
}

/// Writes the first `degree²` real spherical harmonics of `dir` (formula and
/// ordering in the [module docs](self)) to `out[out_offset ..]` and returns
/// `out_offset + degree²`.
///
/// `dir` need not be unit length; a zero, NaN or infinite `dir` encodes as
/// `+z`. `degree` is clamped to `0..=4` (0 writes nothing). Slots at or past
/// `N` are skipped. Every output is finite: by the addition theorem
/// `Σ_m (Y_l^m)² = (2l + 1)/(4π)`, so `|Y_l^m| ≤ √(7/(4π)) < 0.75`.
pub fn sh_encode<const N: usize>(
    dir: Vec3,
    degree: u32,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    let width = sh_width(degree);
    if out_offset >= N {
        return out_offset.wrapping_add(width);
    }
    let d = unit_direction(dir);
    let (x, y, z) = (d.x, d.y, d.z);
    let o = out_offset;
    if width >= 1 {
        write_clamped(out, o, 0.282_094_8); // 1/(2√π)
    }
    if width >= 4 {
        write_clamped(out, o.wrapping_add(1), -0.488_602_52 * y); // −√3 y/(2√π)
        write_clamped(out, o.wrapping_add(2), 0.488_602_52 * z); // √3 z/(2√π)
        write_clamped(out, o.wrapping_add(3), -0.488_602_52 * x); // −√3 x/(2√π)
    }
    if width >= 9 {
        let (x2, y2, z2) = (x * x, y * y, z * z);
        write_clamped(out, o.wrapping_add(4), 1.092_548_5 * x * y); // √15 xy/(2√π)
        write_clamped(out, o.wrapping_add(5), -1.092_548_5 * y * z); // −√15 yz/(2√π)
                                                                     // √5 (3z² − 1)/(4√π)
        write_clamped(out, o.wrapping_add(6), 0.946_174_7 * z2 - 0.315_391_57);
        write_clamped(out, o.wrapping_add(7), -1.092_548_5 * x * z); // −√15 xz/(2√π)
                                                                     // √15 (x² − y²)/(4√π)
        write_clamped(out, o.wrapping_add(8), 0.546_274_24 * (x2 - y2));
        if width >= 16 {
            // √70 y (3x² − y²)/(8√π), with the Condon–Shortley sign.
            write_clamped(out, o.wrapping_add(9), 0.590_043_6 * y * (-3.0 * x2 + y2));
            // √105 xyz/(2√π)
            write_clamped(out, o.wrapping_add(10), 2.890_611_4 * x * y * z);
            // √42 y (1 − 5z²)/(8√π)
            write_clamped(out, o.wrapping_add(11), 0.457_045_8 * y * (1.0 - 5.0 * z2));
            // √7 z (5z² − 3)/(4√π)
            write_clamped(out, o.wrapping_add(12), 0.373_176_34 * z * (5.0 * z2 - 3.0));
            // √42 x (1 − 5z²)/(8√π)
            write_clamped(out, o.wrapping_add(13), 0.457_045_8 * x * (1.0 - 5.0 * z2));
            // √105 z (x² − y²)/(4√π)
            write_clamped(out, o.wrapping_add(14), 1.445_305_7 * z * (x2 - y2));
            // √70 x (3y² − x²)/(8√π)
            write_clamped(out, o.wrapping_add(15), 0.590_043_6 * x * (-x2 + 3.0 * y2));
        }
    }
    o.wrapping_add(width)
}
