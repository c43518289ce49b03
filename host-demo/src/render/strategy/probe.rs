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
//! 2. resumes training when the guide already pays on evidence
//!    ([`guiding::TrialVerdict::worth_more_training`]: the interval lies below 1), the training
//!    phase then ending as much later as the look took
//!    ([`guiding::TrainingSchedule::resume_after_look`]);
//! 3. otherwise ends training there: the guide keeps what it has learned, the selection fit
//!    runs, and the efficiency trial after training decides whether it stays on, by its
//!    evidence rule (an interval above 1). **The probe never switches a guide off**, so a
//!    guide whose early passes looked bad is not lost by it: the trial judges it with the cost
//!    and the selection it renders with.
//!
//! The old probe compared one guided *training* pass with one unguided pass after 256 Adam
//! steps: one pass per arm gave intervals like [0.43, 2.47] (classroom), and the 256 steps
//! came at the end of the Cornell box's phase, so it never decided there. Every look pass is an
//! unbiased estimate and stays in the image (the guided ones as a pass group of their own in
//! the pass combination, the unguided ones with the other unguided passes).

use guiding::TrialVerdict;

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
    /// Training went on after the look.
    pub resumed: bool,
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
                "training probe before pass {} (after {} steps), {} + {} passes in {:.3} s: \
                 cost ratio {:.3} [{:.3}, {:.3}] ({:.4} s per guided pass, {:.4} s unguided): {}",
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
                if self.resumed {
                    "the guide pays (the interval lies below 1), training goes on"
                } else {
                    "skipped: the rest of the training phase (no evidence yet that the guide \
                     pays; the trial after training decides whether it stays on)"
                }
            ),
        }
    }
}
