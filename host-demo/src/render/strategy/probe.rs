//! The training probe: an early "does the guide pay?" that can end training after a few
//! passes.
//!
//! The efficiency trial ([`GuidedOptions::efficiency_trial`](super::guided::GuidedOptions))
//! judges the trained guide, but only after the whole training phase has been paid for. On
//! the Cornell box (diffuse, one area light) that phase was ~17 % of a 20-s budget at about a
//! quarter of `pt-nee`'s pass rate, for a guide the trial then switched off: the render
//! ended at 1.2x `pt-nee`'s relMSE with the trial's verdict right; veach-mis at 1.1x.
//!
//! With the trial on (a time budget and NEE), the probe therefore
//! 1. renders the first training pass with the guide off (BSDF sampling and NEE: `pt-nee`'s
//!    estimator; its paths are recorded and trained on like any other, so training loses
//!    nothing, and an untrained guide would only have made that pass noisier);
//! 2. after [`PROBE_GUIDED_PASSES`] guided training passes, compares the best of their
//!    efficiencies `V_k · t_k` (relMSE per pass from the [`guiding::PassCombiner`]'s
//!    variance estimates, tracing seconds of the pass, recording included for both) with the
//!    unguided first pass's `V_0 · t_0`. The denominators of the relative variances come from
//!    the other half of the checkerboard ([`guiding::Denominator::OtherHalf`]): with 4 passes,
//!    self-normalised estimates made every pass look alike on `builtin:door` (6.1 unguided
//!    against 6.0 guided, where the trial, weighted by an independent image, then measured 25–31
//!    against 9.2–10.5);
//! 3. if even the best guided pass costs more than the unguided one ([`ABANDON_RATIO`]),
//!    training ends there and the guide stays off for the rest of the render (no cache, no
//!    selection fit, no trial).
//!
//! The comparison favours the guide: the guide of pass `k` has had `k` updates and improves
//! with more; the minimum over the passes is biased low. Only a guide that is clearly worse
//! per second is abandoned, and a guide that does pass the probe still faces the trial.
//! Every probe pass is an unbiased estimate and stays in the image.

/// Guided training passes the probe waits for (after the unguided first one).
pub const PROBE_GUIDED_PASSES: u32 = 3;

/// The probe abandons the guide when its best training pass costs more than this many times
/// the unguided pass (relMSE per pass × seconds per pass): no guided pass has yet beaten the
/// unguided one per second. The rest of the training phase costs Adam steps on top of the
/// passes (on the Cornell box about twice a pass's tracing), which only a guide already better
/// per second can hope to repay. Measured at 20 s, 320 px (`docs/bench-2026-12-03-weights/`):
/// `builtin:door` 0.66–0.71 (the trial then measured 0.41–0.43), the Cornell box 1.08–1.09
/// (trial 1.04–1.07, guide off), veach-mis 0.51–1.18 (trial 0.48–3.5, a scene of fireflies).
pub const ABANDON_RATIO: f64 = 1.0;

/// What the probe measured and decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeVerdict {
    /// The pass before which the probe ran (training ended there if abandoned).
    pub at_pass: u32,
    /// relMSE per pass of the unguided first pass.
    pub unguided_variance: f64,
    /// Tracing seconds of the unguided first pass.
    pub unguided_seconds: f64,
    /// relMSE per pass of the most efficient guided training pass.
    pub guided_variance: f64,
    /// Tracing seconds of that pass.
    pub guided_seconds: f64,
    /// `guided_variance · guided_seconds / (unguided_variance · unguided_seconds)`.
    pub cost_ratio: f64,
    /// The ratio was above the threshold: training ended and the guide is off.
    pub abandoned: bool,
}

/// The probe's verdict from the unguided pass's `(V, t)` and the guided training passes'
/// (`threshold`: [`ABANDON_RATIO`] unless a test forces a verdict); `None` when some value is
/// not finite and positive (a black image: no verdict, the guide stays on).
pub fn decide(
    at_pass: u32,
    unguided: (f64, f64),
    guided: &[(f64, f64)],
    threshold: f64,
) -> Option<ProbeVerdict> {
    let ok = |(v, t): (f64, f64)| v.is_finite() && v > 0.0 && t.is_finite() && t > 0.0;
    if guided.is_empty() || !ok(unguided) || !guided.iter().all(|&g| ok(g)) {
        return None;
    }
    let (guided_variance, guided_seconds) = guided
        .iter()
        .copied()
        .min_by(|a, b| (a.0 * a.1).total_cmp(&(b.0 * b.1)))?;
    let cost_ratio = guided_variance * guided_seconds / (unguided.0 * unguided.1);
    Some(ProbeVerdict {
        at_pass,
        unguided_variance: unguided.0,
        unguided_seconds: unguided.1,
        guided_variance,
        guided_seconds,
        cost_ratio,
        abandoned: cost_ratio > threshold,
    })
}

/// What the probe of a guided render did.
#[derive(Clone, Copy, Debug, Default)]
pub struct ProbeStats {
    /// The verdict, `None` if training ended before the probe's pass or a value was unusable.
    pub verdict: Option<ProbeVerdict>,
    /// Passes rendered with the guide off: the first training pass, and every pass after an
    /// abandonment.
    pub passes_guide_off: u32,
}

impl std::fmt::Display for ProbeStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.verdict {
            None => write!(
                f,
                "training probe: first training pass unguided; no verdict (training ended \
                 before it, or a black image)"
            ),
            Some(v) => {
                write!(
                f,
                "training probe before pass {}: relMSE per pass x seconds per pass: best guided \
                 training pass {:.3e} x {:.4} s, unguided first pass {:.3e} x {:.4} s, ratio \
                 {:.3}: {}",
                v.at_pass,
                v.guided_variance,
                v.guided_seconds,
                v.unguided_variance,
                v.unguided_seconds,
                v.cost_ratio,
                if v.abandoned {
                    format!(
                        "skipped: training ended, the guide is off ({} passes without it)",
                        self.passes_guide_off
                    )
                } else {
                    format!("training goes on ({} passes without the guide)", self.passes_guide_off)
                }
            )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_guided_pass_is_compared() {
        let v = decide(
            4,
            (1.0, 1.0),
            &[(3.0, 1.0), (1.2, 1.1), (2.0, 1.0)],
            ABANDON_RATIO,
        )
        .unwrap();
        assert_eq!((v.guided_variance, v.guided_seconds), (1.2, 1.1));
        assert!((v.cost_ratio - 1.32).abs() < 1e-12);
        assert!(v.abandoned);
        let v = decide(4, (1.0, 1.0), &[(0.8, 1.2)], ABANDON_RATIO).unwrap();
        assert!(!v.abandoned);
    }

    #[test]
    fn unusable_values_give_no_verdict() {
        assert!(decide(4, (0.0, 1.0), &[(1.0, 1.0)], ABANDON_RATIO).is_none());
        assert!(decide(4, (1.0, 1.0), &[(f64::NAN, 1.0)], ABANDON_RATIO).is_none());
        assert!(decide(4, (1.0, 1.0), &[], ABANDON_RATIO).is_none());
    }
}
