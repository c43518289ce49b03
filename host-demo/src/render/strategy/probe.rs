//! The training probe: an early "is the guide learning anything useful?" that can end
//! training before the efficiency trial.
//!
//! The efficiency trial ([`GuidedOptions::efficiency_trial`](super::guided::GuidedOptions))
//! judges the trained guide with its real cost, but only after the whole training phase has
//! been paid for. With the trial on (a time budget and NEE), the probe
//! 1. renders the first training pass with the guide off (BSDF sampling and NEE: `pt-nee`'s
//!    estimator; its paths are recorded and trained on like any other, so training loses
//!    nothing, and an untrained guide would only have made that pass noisier);
//! 2. waits for evidence of training: [`MIN_STEPS`] Adam steps (the learning tests'
//!    `tests/learning.rs` train 300 steps to reach their KL thresholds; 256 is that scale), and
//!    then one whole guided training pass traced with the guide they produced;
//! 3. compares that pass's per-pass relative variance with the unguided pass's, band by band
//!    ([`guiding::PassCombiner::band_variances`], denominators from the other checkerboard
//!    half), as a cost ratio with a confidence interval ([`guiding::CostRatio`]) **at the cost
//!    the guide will have after training**: the unguided pass's seconds plus the guided pass's
//!    guide queries (wall seconds: thread-seconds over the threads). What a training pass pays
//!    besides (recording its paths, the network for the cache's misses) goes away once
//!    training stops and would count against the guide: the door room's guided training passes
//!    were 1.33x slower than the unguided one and 1.2x better per pass, and the old probe,
//!    which compared the training passes' own times, abandoned a guide that rendered 0.68x
//!    `pt-nee` when left on;
//! 4. ends training, with the guide off for the rest of the render, only when the whole
//!    interval lies above 1; otherwise training goes on and the trial judges the real costs
//!    later. The probe decides once.
//!
//! Every probe pass is an unbiased estimate and stays in the image.

use guiding::{CostRatio, Verdict};

/// Adam steps the guide must have had before the probe judges it (see the module docs).
pub const MIN_STEPS: u64 = 256;

/// Whether the probe may pick the pass about to start, with `steps` Adam steps behind it, as
/// the guided pass it judges: the guide has had [`MIN_STEPS`] steps and no pass was picked yet.
/// The verdict comes before the next training pass, once the picked one is in the image.
pub fn picks_pass(steps: u64, picked: Option<(u32, u64)>) -> bool {
    picked.is_none() && steps >= MIN_STEPS
}

/// What the probe measured and decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeVerdict {
    /// The pass before which the probe ran (training ended there if abandoned).
    pub at_pass: u32,
    /// The guided training pass that was compared (traced after [`MIN_STEPS`]).
    pub guided_pass: u32,
    /// Adam steps before that pass.
    pub steps: u64,
    /// Tracing seconds of the unguided first pass.
    pub unguided_seconds: f64,
    /// The guided pass's cost after training: `unguided_seconds` plus its guide queries.
    pub guided_seconds: f64,
    /// The cost ratio and its interval.
    pub ratio: CostRatio,
    /// The interval lay above 1: training ended and the guide is off.
    pub abandoned: bool,
}

/// The probe's verdict from the per-band variances of the unguided first pass and of the
/// guided training pass and their seconds per pass; `None` when no interval can be formed
/// (a black image: no verdict, the guide stays on). `force` (tests only) overrides the
/// evidence: `Some(true)` abandons, `Some(false)` keeps.
pub fn decide(
    at_pass: u32,
    guided_pass: u32,
    steps: u64,
    unguided_bands: &[f64],
    guided_bands: &[f64],
    (unguided_seconds, guided_seconds): (f64, f64),
    force: Option<bool>,
) -> Option<ProbeVerdict> {
    let ratio = CostRatio::from_bands(
        guided_bands,
        unguided_bands,
        guided_seconds,
        unguided_seconds,
        guiding::evidence::Z,
    )?;
    Some(ProbeVerdict {
        at_pass,
        guided_pass,
        steps,
        unguided_seconds,
        guided_seconds,
        ratio,
        abandoned: force.unwrap_or(ratio.verdict() == Verdict::DoesNotPay),
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
            Some(v) => write!(
                f,
                "training probe before pass {}: guided training pass {} (after {} steps) \
                 against the unguided first pass, {:.4} s per pass after training against \
                 {:.4} s: {}: {}",
                v.at_pass,
                v.guided_pass,
                v.steps,
                v.guided_seconds,
                v.unguided_seconds,
                v.ratio,
                if v.abandoned {
                    format!(
                        "skipped: the guide does not pay, training ended, the guide is off ({} \
                         passes without it)",
                        self.passes_guide_off
                    )
                } else {
                    format!(
                        "no evidence against the guide, training goes on ({} passes without \
                         the guide)",
                        self.passes_guide_off
                    )
                }
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_an_interval_above_one_abandons() {
        let u = [1.0, 1.2, 0.8, 1.0];
        // Clearly worse in every band: abandoned.
        let v = decide(9, 7, 300, &u, &[2.0, 2.5, 1.5, 2.1], (0.1, 0.1), None).unwrap();
        assert!(v.ratio.low > 1.0 && v.abandoned);
        // Worse on average, but one band carries it: the interval straddles 1, kept.
        let v = decide(9, 7, 300, &u, &[0.9, 1.0, 0.7, 6.0], (0.1, 0.1), None).unwrap();
        assert!(v.ratio.ratio > 1.0 && v.ratio.low < 1.0 && !v.abandoned);
        // Better: kept.
        let v = decide(9, 7, 300, &u, &[0.5, 0.6, 0.4, 0.5], (0.1, 0.1), None).unwrap();
        assert!(!v.abandoned);
        // Forced by a test.
        let v = decide(9, 7, 300, &u, &[0.5, 0.6, 0.4, 0.5], (0.1, 0.1), Some(true)).unwrap();
        assert!(v.abandoned);
    }

    /// A guide whose early passes look bad but which pays once trained is kept: the probe
    /// judges only the pass after [`MIN_STEPS`]. The old rule (judge the first guided passes)
    /// abandons the same guide: the negative control.
    #[test]
    fn early_bad_passes_are_not_judged() {
        let unguided = [1.0, 1.1, 0.9, 1.0, 1.05, 0.95];
        // Guided training passes: (steps before the pass, per-band variances). Three times
        // worse for the first passes (an untrained guide), half as noisy once trained.
        let passes: Vec<(u64, [f64; 6])> = vec![
            (0, [0.0; 6]), // the unguided first pass
            (40, [3.0, 3.3, 2.7, 3.0, 3.1, 2.9]),
            (90, [3.1, 3.0, 2.8, 3.2, 3.0, 3.0]),
            (150, [2.5, 2.6, 2.4, 2.5, 2.7, 2.3]),
            (260, [0.5, 0.55, 0.45, 0.5, 0.52, 0.48]),
            (380, [0.45, 0.5, 0.4, 0.46, 0.5, 0.44]),
        ];
        // The rule of `Guided::begin_pass`: pick, then judge before the next pass.
        let run = |min_steps: u64| {
            let mut picked: Option<(u32, u64)> = None;
            for (at, &(steps, _)) in passes.iter().enumerate().skip(1) {
                if let Some((p, s)) = picked {
                    let v = decide(
                        at as u32,
                        p,
                        s,
                        &unguided,
                        &passes[p as usize].1,
                        (0.1, 0.1),
                        None,
                    );
                    return v.expect("a verdict");
                }
                if picked.is_none() && steps >= min_steps {
                    picked = Some((at as u32, steps));
                }
            }
            unreachable!("the passes reach a verdict")
        };
        let v = run(MIN_STEPS);
        assert!(picks_pass(MIN_STEPS, None) && !picks_pass(MIN_STEPS - 1, None));
        assert!(!picks_pass(10 * MIN_STEPS, Some((4, 260))));
        assert_eq!((v.guided_pass, v.at_pass), (4, 5));
        assert!(!v.abandoned && v.ratio.high < 1.0, "{v:?}");
        // Judging the first guided pass, as the old probe did: abandoned.
        let old = run(0);
        assert_eq!(old.guided_pass, 1);
        assert!(old.abandoned, "{old:?}");
    }

    /// The guide's cost after training counts: equal variances, but a guide whose queries take
    /// half the unguided pass again does not pay.
    #[test]
    fn the_cost_after_training_counts() {
        let u = [1.0, 1.2, 0.8, 1.0];
        let v = decide(9, 7, 300, &u, &u, (0.1, 0.15), None).unwrap();
        assert!((v.ratio.ratio - 1.5).abs() < 1e-12 && v.abandoned, "{v:?}");
        let v = decide(9, 7, 300, &u, &u, (0.1, 0.1), None).unwrap();
        assert!(!v.abandoned);
    }

    #[test]
    fn unusable_values_give_no_verdict() {
        assert!(decide(4, 2, 300, &[0.0, 0.0], &[1.0, 1.0], (1.0, 1.0), None).is_none());
        assert!(decide(4, 2, 300, &[1.0, 1.0], &[f64::NAN, 1.0], (1.0, 1.0), None).is_none());
        assert!(decide(4, 2, 300, &[1.0], &[1.0], (1.0, 1.0), None).is_none());
    }
}
