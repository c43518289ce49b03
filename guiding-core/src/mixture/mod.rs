//! Mixtures of `K` lobes with softmax weights, decoded from raw network outputs.

pub mod nasg;
pub mod vmf;

use crate::lobe::DirectionSample;
use crate::math::{exp, sanitize, ONE_MINUS_EPSILON};
use glam::{Vec2, Vec3};
use nasg::NasgMixture;
use vmf::VmfMixture;

/// A decoded mixture of lobes, as the generic model kernels
/// ([`crate::model::mixture_model`]) sample and evaluate it.
pub trait LobeMixture: Copy {
    /// Draws a direction from `u ∈ [0, 1)²` with the mixture density there.
    fn sample(&self, u: Vec2) -> DirectionSample;
    /// Density of `direction` in solid angle.
    fn pdf(&self, direction: Vec3) -> f32;
}

/// [`LobeMixture`] for mixture types that have inherent `sample` and `pdf`
/// of that signature (generic over the lobe count `K`).
macro_rules! lobe_mixture_by_inherent_methods {
    ($($mixture:ident),*) => {$(
        impl<const K: usize> LobeMixture for $mixture<K> {
            #[inline]
            fn sample(&self, u: Vec2) -> DirectionSample {
                Self::sample(self, u)
            }

            #[inline]
            fn pdf(&self, direction: Vec3) -> f32 {
                Self::pdf(self, direction)
            }
        }
    )*};
}
lobe_mixture_by_inherent_methods!(VmfMixture, NasgMixture);

/// The weight logits (column 0) of raw rows of `R` outputs per lobe, each
/// passed through [`sanitize`] with `limit`.
#[inline]
#[must_use]
pub(crate) fn weight_logits<const K: usize, const R: usize>(
    raw: &[[f32; R]; K],
    limit: f32,
) -> [f32; K] {
    let mut logits = [0.0; K];
    let mut k = 0;
    while k < K {
        logits[k] = sanitize(raw[k][0], limit);
        k += 1;
    }
    logits
}

pub use crate::math::log_sum_exp_parts;

/// Weights normalised to sum to one: negative, infinite or NaN weights count
/// as zero, and all-zero weights become uniform (`1 / K`).
#[inline]
#[must_use]
pub fn normalized_weights<const K: usize>(weights: &[f32; K]) -> [f32; K] {
    let mut out = [0.0f32; K];
    let mut sum = 0.0;
    let mut k = 0;
    while k < K {
        let w = if weights[k] > 0.0 && weights[k] <= f32::MAX {
            weights[k]
        } else {
            0.0
        };
        out[k] = w;
        sum += w;
        k += 1;
    }
    k = 0;
    while k < K {
        out[k] = if sum > 0.0 && sum <= f32::MAX {
            out[k] / sum
        } else {
            1.0 / K as f32
        };
        k += 1;
    }
    out
}

/// [`select_component`] of a mixture's lobe by `u.x` (lobe 0 if every
/// weight is zero, which the decoders never produce), with `u.x` rescaled
/// for reuse by the lobe's own sampling.
#[inline]
#[must_use]
pub fn select_lobe<const K: usize>(weights: &[f32; K], u: Vec2) -> (usize, Vec2) {
    let (k, u_lobe) = match select_component(weights, u.x) {
        Some(sel) => sel,
        None => (0, u.x),
    };
    (k, Vec2::new(u_lobe, u.y))
}

/// Numerically stable softmax of `logits` into `weights` (the largest logit is
/// subtracted first, so ±10³⁰ inputs are fine).
#[inline]
pub fn softmax<const K: usize>(logits: &[f32; K], weights: &mut [f32; K]) {
    let max = crate::math::max_entry(logits);
    let mut sum = 0.0;
    let mut k = 0;
    while k < K {
        let w = exp(logits[k] - max);
        weights[k] = w;
        sum += w;
        k += 1;
    }
    // sum ≥ 1 (the maximum contributes e^0).
    let inv = 1.0 / sum;
    k = 0;
    while k < K {
        weights[k] *= inv;
        k += 1;
    }
}

/// `Σ terms`, summed pairwise in place (`terms` is clobbered): a tree of
/// depth `⌈log₂ K⌉` instead of a chain of `K − 1` dependent additions, and
/// for `K = 8` two vector additions and a horizontal one. `0` for `K = 0`.
#[inline]
pub fn pairwise_sum<const K: usize>(terms: &mut [f32; K]) -> f32 {
    if K == 0 {
        return 0.0;
    }
    let mut n = K;
    while n > 1 {
        // Fold the upper part [half, n) onto [0, n − half).
        let half = n.div_ceil(2);
        let mut i = 0;
        while i < n - half {
            terms[i] += terms[i + half];
            i += 1;
        }
        n = half;
    }
    terms[0]
}

/// Picks a component with probability `weights[k]` from `u ∈ [0, 1)` and
/// returns it with `u` rescaled to `[0, 1)` within that component, so the same
/// random number can be reused for the component's own sampling.
///
/// Components of weight zero are never chosen, also when rounding leaves `u`
/// beyond the last partial sum. Returns `None` only if every weight is zero.
///
/// Branch-free in the common case: the partial sums `end_k` of the positive
/// weights are formed first, and the chosen component is the number of them
/// that `u` is not below (the first `k` with `u < end_k`, which has a
/// positive weight since the sums are non-decreasing) — a count LLVM
/// vectorises, instead of a scan whose data-dependent exit the branch
/// predictor misses about once per sample.
#[inline]
#[must_use]
pub fn select_component<const K: usize>(weights: &[f32; K], u: f32) -> Option<(usize, f32)> {
    let mut ends = [0.0f32; K];
    let mut acc = 0.0f32;
    let mut k = 0;
    while k < K {
        // Non-positive and NaN weights add nothing.
        let w = weights[k];
        acc += if w > 0.0 { w } else { 0.0 };
        ends[k] = acc;
        k += 1;
    }
    // Counted at max(u, 0), so that a negative u (out of contract) still
    // lands on the first non-empty component, not on leading empty ones.
    let u_count = u.max(0.0);
    let mut chosen = 0;
    k = 0;
    while k < K {
        chosen += usize::from(u_count >= ends[k]);
        k += 1;
    }
    // A NaN `u` takes the fallback, like every `u` beyond the last sum.
    if chosen < K && !u.is_nan() {
        let start = if chosen > 0 { ends[chosen - 1] } else { 0.0 };
        let rescaled = ((u - start) / weights[chosen]).clamp(0.0, ONE_MINUS_EPSILON);
        return Some((chosen, rescaled));
    }
    select_last_component(weights, &ends, u)
}

/// The rare end of [`select_component`], kept out of line so that the common
/// path inlines: rounding left `u` beyond the last partial sum (or `u` is
/// NaN), and the last non-empty component takes it.
#[cold]
#[inline(never)]
fn select_last_component<const K: usize>(
    weights: &[f32; K],
    ends: &[f32; K],
    u: f32,
) -> Option<(usize, f32)> {
    let mut k = K;
    while k > 0 {
        k -= 1;
        if weights[k] > 0.0 {
            let start = if k > 0 { ends[k - 1] } else { 0.0 };
            return Some((k, ((u - start) / weights[k]).clamp(0.0, ONE_MINUS_EPSILON)));
        }
    }
    None
}
