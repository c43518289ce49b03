//! The training probe: an early look at the guide that decides whether the rest of the
//! training phase is worth spending on it.
//!
//! On a scene where the guide cannot pay, the whole training phase is lost (a third of its
//! wall clock trains, the cache is rebuilt after each update, the passes record): about 11 %
//! of a 30-s render of the shared Cornell box. The efficiency trial after training switches
//! such a guide off, but only once the phase has been paid for. With the trial on (a time
//! budget and NEE) the probe, once the library's schedule says the look is due
//! ([`guiding::TrainingSchedule::look_due`]: a quarter of the training phase and
//! [`guiding::EARLY_LOOK_MIN_STEPS`] Adam steps behind it),
//! 1. pauses training and runs a short efficiency trial of the guide as it is
//!    ([`guiding::GuideTrial`], its first look only: 2 passes per arm when the interval already
//!    excludes 1, else 4): guided passes **at the cost the guide will have after training**
//!    (read from the guide cache, nothing recorded, no Adam step between them) against passes
//!    with the guide off (`pt-nee`'s estimator), on the render's own image;
//! 2. decides by the look's interval ([`guiding::TrialVerdict::look_decision`]): below 1 (the
//!    guide pays on evidence) training resumes with no more looks; straddling 1 (no evidence
//!    either way) training resumes to the next look, a quarter of the phase later (at most
//!    three looks, at 1/4, 1/2 and 3/4); above 1 training ends. A resumed phase ends as much
//!    later as the look took ([`guiding::TrainingSchedule::resume_after_look`]);
//! 3. a guide whose training ended keeps what it has learned, the selection fit runs, and the
//!    efficiency trial after training decides whether it stays on, by its evidence rule (an
//!    interval above 1). **The probe never switches a guide off**, so a guide whose early
//!    passes looked bad is not lost by it: the trial judges it with the cost and the selection
//!    it renders with.
//!
//! Until 2026-12-08 there was one look, and a straddling one ended training: on
//! `builtin:door` at 160 px it stopped guides that pay once trained on 4 of 6 renders (see
//! [`guiding::EARLY_LOOK_AT`]).
//!
//! The old probe compared one guided *training* pass with one unguided pass after 256 Adam
//! steps: one pass per arm gave intervals like [0.43, 2.47] (classroom), and the 256 steps
//! came at the end of the Cornell box's phase, so it never decided there. Every look pass is an
//! unbiased estimate and stays in the image (the guided ones as a pass group of their own in
//! the pass combination, the unguided ones with the other unguided passes).

use guiding::{LookDecision, TrialVerdict};

/// What the probe of a guided render did.
#[derive(Clone, Copy, Debug, Default)]
pub struct ProbeStats {
    /// The pass before which the look started.
    pub at_pass: u32,
    /// Adam steps the guide had at the look.
    pub steps: u64,
    /// The look's passes (both arms).
    pub passes: u32,
    /// Wall seconds of the look's passes.
    pub seconds: f64,
    /// The look's estimate (`None`: the render ended before it, or a black image).
    pub verdict: Option<TrialVerdict>,
    /// What the look decided (`None` before its first look).
    pub decision: Option<LookDecision>,
    /// Looks taken so far, this one included (one per quarter of the training phase while
    /// each straddles 1; the fields above are the latest's).
    pub looks: u32,
}

impl ProbeStats {
    /// Training went on after the look (it paid on evidence, or had no evidence either way).
    pub fn resumed(&self) -> bool {
        matches!(
            self.decision,
            Some(LookDecision::TrainOn | LookDecision::LookAgain)
        )
    }
}

impl std::fmt::Display for ProbeStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.verdict {
            None => write!(
                f,
                "training probe before pass {} (after {} steps): no estimate ({} passes; the \
                 render ended first, or a black image)",
                self.at_pass, self.steps, self.passes
            ),
            Some(v) => write!(
                f,
                "training probe, look {} before pass {} (after {} steps), {} + {} passes in \
                 {:.3} s: cost ratio {:.3} [{:.3}, {:.3}] ({:.4} s per guided pass, {:.4} s \
                 unguided): {}",
                self.looks,
                self.at_pass,
                self.steps,
                v.guided_passes,
                v.unguided_passes,
                self.seconds,
                v.cost_ratio,
                v.ratio_low,
                v.ratio_high,
                v.guided_seconds,
                v.unguided_seconds,
                match self.decision {
                    Some(LookDecision::TrainOn) => {
                        "the guide pays (the interval lies below 1), training goes on"
                    }
                    Some(LookDecision::LookAgain) => {
                        "no evidence either way (the interval straddles 1), training goes on to \
                         the next look"
                    }
                    _ => {
                        "skipped: the rest of the training phase (the interval lies above 1; the \
                         trial after training decides whether the guide stays on)"
                    }
                }
            ),
        }
    }
}
