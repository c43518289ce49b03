//! Mixtures of `K` lobes with softmax weights, decoded from raw network outputs.

pub mod nasg;
pub mod vmf;

use crate::math::{exp, ONE_MINUS_EPSILON};

/// Numerically stable softmax of `logits` into `weights` (the largest logit is
/// subtracted first, so ±10³⁰ inputs are fine).
#[inline]
pub fn softmax<const K: usize>(logits: &[f32; K], weights: &mut [f32; K]) {
    let mut max = f32::MIN;
    let mut k = 0;
    while k < K {
        max = max.max(logits[k]);
        k += 1;
    }
    let mut sum = 0.0;
    k = 0;
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

/// Picks a component with probability `weights[k]` from `u ∈ [0, 1)` and
/// returns it with `u` rescaled to `[0, 1)` within that component, so the same
/// random number can be reused for the component's own sampling.
///
/// Components of weight zero are never chosen, also when rounding leaves `u`
/// beyond the last partial sum. Returns `None` only if every weight is zero.
#[inline]
#[must_use]
pub fn select_component<const K: usize>(weights: &[f32; K], u: f32) -> Option<(usize, f32)> {
    let mut start = 0.0;
    let mut last: Option<(usize, f32)> = None;
    let mut k = 0;
    while k < K {
        let w = weights[k];
        if w > 0.0 {
            let end = start + w;
            if u < end {
                let rescaled = ((u - start) / w).clamp(0.0, ONE_MINUS_EPSILON);
                return Some((k, rescaled));
            }
            last = Some((k, start));
            start = end;
        }
        k += 1;
    }
    // Rounding: the partial sums ended below u; the last non-empty component takes it.
    if let Some((k, s)) = last {
        return Some((k, ((u - s) / weights[k]).clamp(0.0, ONE_MINUS_EPSILON)));
    }
    None
}
