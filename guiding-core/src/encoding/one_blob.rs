//! One-blob encoding of a scalar (Müller et al. 2019, "Neural Importance
//! Sampling", §4.3), which Neural Parametric Mixtures (Dong et al. 2023) use
//! for the surface normal (per component) and the roughness.
//!
//! ## Formula
//!
//! The unit interval is cut into `k` bins with centres `c_i = (i + ½)/k`; a
//! Gaussian kernel of standard deviation `σ = 1/k` placed at `x` is evaluated
//! at the bin centres:
//!
//! `b_i(x) = exp(−(x − c_i)² / (2σ²)) = exp(−((i + ½) − k·x)² / 2)`, `i < k`.
//!
//! The kernel is not normalised (its peak is 1, reached when `x` sits on a
//! bin centre), and the bins do not wrap around.
//!
//! ## Deviation
//!
//! tiny-cuda-nn's `OneBlob` integrates a quartic kernel over each bin with
//! periodic wrap-around; this follows the paper's text (a Gaussian with
//! `σ = 1/k`, "discretised into the bins" = sampled at the bin centres).

use crate::encoding::{clamp_unit, slots_inside, write_clamped};
use crate::math::exp;

/// Bins NPM uses per encoded scalar.
pub const ONE_BLOB_DEFAULT_BINS: u32 = 4;

/// Writes the `bins` one-blob values of `x` (formula in the
/// [module docs](self)) to `out[out_offset ..]` and returns
/// `out_offset + bins`.
///
/// `x` is clamped to `[0, 1]` (±∞ to the ends) and NaN encodes as `0.5`. For
/// a value `v ∈ [−1, 1]` (a normal component) pass `0.5·v + 0.5`. Slots at or
/// past `N` are skipped (the loop stops there, so a huge `bins` is harmless).
/// Every output is in `[0, 1]`.
pub fn one_blob_encode<const N: usize>(
    x: f32,
    bins: u32,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    let n = slots_inside::<N>(out_offset, bins);
    let kx = bins as f32 * clamp_unit(x);
    let mut i = 0u32;
    while i < n {
        let d = (i as f32 + 0.5) - kx;
        out[out_offset + i as usize] = exp(-0.5 * d * d);
        i += 1;
    }
    out_offset.wrapping_add(bins as usize)
}

/// Bins of [`one_blob_encode4`].
pub const ONE_BLOB_FIXED_BINS: usize = 4;

/// [`one_blob_encode`] with 4 bins of each of the `S` values `xs`, written
/// to `out[out_offset ..]` scalar after scalar (the layout of `S`
/// consecutive calls), bit for bit those calls' values; returns
/// `out_offset + 4·S`.
///
/// All `4·S` kernels are evaluated in one branch-free loop over an array,
/// which the CPU compiler vectorises (the per-value loop of
/// [`one_blob_encode`], with its early exit at `N`, stays scalar). Slots at
/// or past `N` are skipped.
pub fn one_blob_encode4<const S: usize, const N: usize>(
    xs: &[f32; S],
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    const B: usize = ONE_BLOB_FIXED_BINS;
    let mut kx = [0.0f32; S];
    let mut s = 0;
    while s < S {
        kx[s] = B as f32 * clamp_unit(xs[s]);
        s += 1;
    }
    // One lane per (value, bin); 16 values fit the largest array we use.
    let mut values = [[0.0f32; B]; S];
    s = 0;
    while s < S {
        let mut i = 0;
        while i < B {
            let d = (i as f32 + 0.5) - kx[s];
            values[s][i] = exp(-0.5 * d * d);
            i += 1;
        }
        s += 1;
    }
    s = 0;
    while s < S {
        let mut i = 0;
        while i < B {
            write_clamped(out, out_offset.wrapping_add(s * B + i), values[s][i]);
            i += 1;
        }
        s += 1;
    }
    out_offset.wrapping_add(S * B)
}
