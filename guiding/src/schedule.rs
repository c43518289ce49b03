//! When to train and how much: a schedule driven by wall-clock time and recorded samples, not
//! by whole-image passes.
//!
//! A renderer that trains its guide between whole passes gets very different training on
//! different scenes: a 320-px pass of a simple room takes 0.1 s, a 256 × 455 pass of a
//! staircase at path depth 65 takes 3–4 s. With a per-pass rule (a capped number of Adam steps
//! after each pass) the staircase's training phase was one pass and 64 steps, 1 % of the wall
//! time, and the first update came after 3 s. This schedule instead:
//!
//! 1. **splits the render in a training phase and the rest**: the first
//!    [`ScheduleOptions::train_fraction`] of the budget (seconds for a time budget, samples per
//!    pixel for an spp budget) trains, the rest renders with the frozen guide;
//! 2. **gives training a share of the wall clock during that phase**
//!    ([`StepRule::TimeShare`]): after the renderer has traced for `T` seconds of
//!    the training phase and trained for `U`, the steps due now are
//!    `⌊(s/(1 − s) · T − U) / c⌋` with `c` the measured seconds of one Adam step (a running
//!    mean over the updates so far), so `U / (T + U) → s` whatever the pass time, the image size
//!    or the path depth. An update with fewer steps than its share leaves the rest to the next
//!    one (the account is cumulative), so no step count is lost to rounding;
//! 3. **asks for updates often**: [`TrainingSchedule::paths_before_update`] tells the renderer
//!    how many paths to trace before it next asks, `update_interval / (seconds per path)`
//!    measured on what it has traced, so a slow pass is cut into pieces (host-demo traces its
//!    training passes as subsets of rows spread over the image, each subset an unbiased part of
//!    the pass) and the first update comes within about [`ScheduleOptions::update_interval`]
//!    of the start. Before any measurement the first piece is
//!    [`ScheduleOptions::first_piece`] of a pass.
//!
//! **Why one third.** The share is the trade between a better guide (training) and more
//! samples (tracing) during the training phase. NASG (Huang et al. 2024) spends about a third
//! of its GPU frame time training; host-demo's old per-pass rule spent about 40 % of the
//! training phase on `builtin:door` at 20 s (1.5–1.8 s of training in its 4 s,
//! `docs/bench-2026-12-04-batched/`), where it was tuned, and 1 % on the staircase above.
//! Training outside the training phase is never done: the guide is frozen (and cached) for the
//! rest of the render.
//!
//! There is no constant cap on steps per update: the steps are what the time share pays for,
//! bounded only by [`ScheduleOptions::max_epochs`] passes over the samples buffered since the
//! last update (a guide is not trained a hundred times over on the few samples of a tiny
//! image), and at least one step once the buffer is half full (so no sample overflows it).
//!
//! The schedule measures nothing itself; the renderer reports what it did
//! ([`TrainingSchedule::record_traced`], [`TrainingSchedule::record_update`]), so the same
//! rule runs in host-demo, behind the C ABI, and in any renderer that reports its times.

use crate::GuidingError;
use guiding_core::field::FieldConfig;

/// How far into the training phase a renderer with an efficiency trial takes its **early
/// look** ([`TrainingSchedule::look_due`]): a quarter of the phase (5 % of the budget with the
/// default [`ScheduleOptions::train_fraction`]).
///
/// **Why.** On a scene where the guide cannot pay (the shared Cornell box, veach-mis), the
/// whole training phase is lost: a third of its wall clock trains, the guide cache is rebuilt
/// after every update and the traced passes record, so it renders about a third of the
/// passes `pt-nee` would (35 against 98 in the first 6 s of a 30-s Cornell box,
/// `docs/bench-2026-12-06-trial/`), 11 % of the render. A guide trained for a quarter of the
/// phase already shows whether it is heading anywhere: on `builtin:door` after 1.2 s of a
/// 30-s render (136 Adam steps) the trial measured 0.81 [0.68, 0.98] of the unguided cost,
/// on the Cornell box (65 steps) 1.13 [1.05, 1.21] and on veach-mis 1.14 [1.04, 1.25]
/// (`docs/bench-2026-12-07-look/`). A quarter keeps three quarters of the loss on such scenes
/// and gives a paying guide the rest of its phase.
///
/// A look whose interval straddles 1 decides nothing: training goes on to the next look, a
/// quarter of the phase later (at 1/2 and 3/4), until a look shows the guide paying
/// ([`TrainingSchedule::end_looks`]) or not, or the phase ends. One look that had to decide
/// stopped guides that pay once trained whenever it was too noisy to show it: `builtin:door`
/// at 160 px (20 s, 3 seeds, `docs/bench-2026-12-08-window/door-160/`): on 4 of 6 renders the
/// look straddled ([0.62, 1.10] … [0.82, 1.48]), training ended at pass 10–11 and the trial
/// switched the under-trained guide off; where training went on the guide measured 0.43–0.54
/// of the unguided cost.
pub const EARLY_LOOK_AT: f64 = 0.25;

/// Adam steps the guide must have had before the early look (the look waits for them): a
/// quarter of the 256 at which the learning tests (`tests/learning.rs`, 300 steps) reach their
/// thresholds; the look judges a guide's direction, not its end state.
pub const EARLY_LOOK_MIN_STEPS: u64 = 64;

/// Options of a [`TrainingSchedule`]: the library's defaults are what `host-demo bench`
/// measures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScheduleOptions {
    /// Fraction of the budget (seconds, or samples per pixel) spent in the training phase, in
    /// `[0, 1]`. 0.2: at 20 s (1 seed each) 0.15 against 0.3 gave relMSE 0.00103 / 0.00112
    /// (Cornell box), 0.00420 / 0.00475 (veach-mis) and 0.092 / 0.090 (`builtin:door`).
    pub train_fraction: f64,
    /// How many Adam steps an update runs.
    pub steps: StepRule,
    /// Seconds of tracing between updates that the schedule aims at (> 0).
    pub update_interval: f64,
    /// Fraction of a pass traced before the first update, when nothing has been measured yet,
    /// in `(0, 1]`.
    pub first_piece: f64,
    /// At most this many passes (epochs) over the samples buffered since the last update per
    /// update (> 0).
    pub max_epochs: f64,
}

/// How many Adam steps an update of a [`TrainingSchedule`] runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepRule {
    /// Training gets this share `s` of the training phase's wall clock, in `(0, 1)` (the
    /// default, 1/3; see the [module docs](self)). Steps and update times depend on measured
    /// seconds, so two renders differ in their training.
    TimeShare(f64),
    /// Reproducible training: one update per whole pass (no pieces) with
    /// `clamp(⌈e · buffered / batch_size⌉, 1, steps_per_update)` steps for `e` epochs (> 0):
    /// the same steps on every run and thread count, for tests and reproducible renders. The
    /// per-update cap is the field configuration's `steps_per_update`.
    Epochs(f64),
}

impl ScheduleOptions {
    /// The library's defaults (see each field).
    pub const DEFAULT: Self = Self {
        train_fraction: 0.2,
        steps: StepRule::TimeShare(1.0 / 3.0),
        update_interval: 0.25,
        first_piece: 1.0 / 32.0,
        max_epochs: 4.0,
    };

    /// Checks every value against its documented range.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] naming the first value out of range.
    pub fn validate(&self) -> Result<(), GuidingError> {
        let bad = |what: &str, v: f64| {
            Err(GuidingError::InvalidConfig(format!(
                "schedule: {what} {v} is out of range"
            )))
        };
        if !(0.0..=1.0).contains(&self.train_fraction) {
            return bad("train_fraction (in [0, 1])", self.train_fraction);
        }
        match self.steps {
            StepRule::TimeShare(s) if !(s > 0.0 && s < 1.0) => {
                return bad("training share (in (0, 1))", s);
            }
            StepRule::Epochs(e) if !(e.is_finite() && e > 0.0) => {
                return bad("epochs per update (> 0)", e);
            }
            _ => {}
        }
        if !(self.update_interval.is_finite() && self.update_interval > 0.0) {
            return bad("update_interval (> 0 s)", self.update_interval);
        }
        if !(self.first_piece > 0.0 && self.first_piece <= 1.0) {
            return bad("first_piece (in (0, 1])", self.first_piece);
        }
        if !(self.max_epochs.is_finite() && self.max_epochs > 0.0) {
            return bad("max_epochs (> 0)", self.max_epochs);
        }
        Ok(())
    }
}

impl Default for ScheduleOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The budget of a render, as the schedule sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// Wall-clock seconds.
    Seconds(f64),
    /// Samples (passes) per pixel.
    Spp(u32),
}

/// The time- and sample-driven training schedule of the [module docs](self).
#[derive(Clone, Debug)]
pub struct TrainingSchedule {
    options: ScheduleOptions,
    budget: Budget,
    /// Tracing seconds and paths reported in the training phase.
    traced_seconds: f64,
    traced_paths: u64,
    /// Training seconds and steps reported.
    trained_seconds: f64,
    steps: u64,
    updates: u64,
    over: bool,
    /// Training-phase progress at which the next early look is due (`≥ 1`: none).
    next_look: f64,
    /// Seconds and passes of an early look after which training resumed: the training phase
    /// ends that much later, so the look does not cost the guide its training.
    paused_seconds: f64,
    paused_passes: u32,
}

impl TrainingSchedule {
    /// A schedule for a render of `budget`.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for options out of range or a budget that is not finite
    /// and non-negative.
    pub fn new(options: ScheduleOptions, budget: Budget) -> Result<Self, GuidingError> {
        options.validate()?;
        if let Budget::Seconds(s) = budget {
            if !(s.is_finite() && s >= 0.0) {
                return Err(GuidingError::InvalidConfig(format!(
                    "schedule: a time budget must be finite and non-negative, got {s} s"
                )));
            }
        }
        Ok(Self {
            options,
            budget,
            traced_seconds: 0.0,
            traced_paths: 0,
            trained_seconds: 0.0,
            steps: 0,
            updates: 0,
            over: false,
            next_look: EARLY_LOOK_AT,
            paused_seconds: 0.0,
            paused_passes: 0,
        })
    }

    /// The options.
    pub fn options(&self) -> &ScheduleOptions {
        &self.options
    }

    /// Whether work that starts now belongs to the training phase: `elapsed` seconds since the
    /// render started below `train_fraction · budget` (time budget), or sample index `pass`
    /// below `round(train_fraction · spp)` (spp budget). Once it has answered `false` (or
    /// [`Self::end_training`] was called) it always does.
    pub fn in_training_phase(&mut self, elapsed: f64, pass: u32) -> bool {
        if self.over {
            return false;
        }
        let on = self.phase_progress(elapsed, pass) < 1.0;
        if !on {
            self.over = true;
        }
        on
    }

    /// How much of the training phase work starting now has behind it: `elapsed` over the
    /// phase's seconds, or `pass` over its passes (1 or more: the phase is over; an empty
    /// phase counts as over). Seconds and passes of an early look after which training
    /// resumed do not count.
    fn phase_progress(&self, elapsed: f64, pass: u32) -> f64 {
        let (done, phase) = match self.budget {
            Budget::Seconds(b) => (
                elapsed - self.paused_seconds,
                self.options.train_fraction * b,
            ),
            Budget::Spp(spp) => (
                f64::from(pass.saturating_sub(self.paused_passes)),
                (self.options.train_fraction * f64::from(spp))
                    .round()
                    .min(f64::from(spp)),
            ),
        };
        if phase > 0.0 {
            done / phase
        } else {
            1.0
        }
    }

    /// Whether the renderer should take an early look now, before the pass `pass` that starts
    /// `elapsed` seconds into the render: the guide has had [`EARLY_LOOK_MIN_STEPS`] Adam
    /// steps, the phase is not over, and the next look's share of the training phase is behind
    /// it: [`EARLY_LOOK_AT`] for the first, then each following quarter (1/2, 3/4). Answers
    /// `true` at most once per quarter, and never after [`Self::end_looks`].
    ///
    /// The look (host-demo's, `--training-probe`) is a short efficiency trial
    /// ([`crate::GuideTrial`], its first look only) of the guide as it is, read from the
    /// guide cache without recording. Its interval decides: below 1
    /// ([`crate::TrialVerdict::worth_more_training`]) training goes on with no more looks
    /// ([`Self::resume_after_look`], [`Self::end_looks`]); above 1 training ends
    /// ([`Self::end_training`]); straddling 1, training goes on to the next look
    /// ([`Self::resume_after_look`]) and, after the last, to the end of the phase. Whether the
    /// guide stays on is left to the trial after training: a look never switches a guide off.
    pub fn look_due(&mut self, elapsed: f64, pass: u32) -> bool {
        if self.over || self.next_look >= 1.0 || self.steps < EARLY_LOOK_MIN_STEPS {
            return false;
        }
        let progress = self.phase_progress(elapsed, pass);
        if !(self.next_look..1.0).contains(&progress) {
            return false;
        }
        // The next quarter after this one (a late look, waiting for its steps, skips those
        // it passed).
        self.next_look = ((progress / EARLY_LOOK_AT).floor() + 1.0) * EARLY_LOOK_AT;
        true
    }

    /// No more early looks in this render (a look showed the guide paying).
    pub fn end_looks(&mut self) {
        self.next_look = f64::INFINITY;
    }

    /// Training resumes after an early look of `seconds` (wall clock) and `passes` passes: the
    /// training phase ends that much later. Non-finite or negative seconds count as 0.
    pub fn resume_after_look(&mut self, seconds: f64, passes: u32) {
        if seconds.is_finite() && seconds > 0.0 {
            self.paused_seconds += seconds;
        }
        self.paused_passes = self.paused_passes.saturating_add(passes);
    }

    /// Ends the training phase now (the loss converged, or the renderer's own verdict).
    pub fn end_training(&mut self) {
        self.over = true;
    }

    /// Whether the training phase is over.
    pub fn training_over(&self) -> bool {
        self.over
    }

    /// The renderer traced `paths` paths (camera samples) in `seconds` of the training phase,
    /// recording included. Non-finite or negative seconds count as 0.
    pub fn record_traced(&mut self, seconds: f64, paths: u64) {
        if seconds.is_finite() && seconds > 0.0 {
            self.traced_seconds += seconds;
        }
        self.traced_paths = self.traced_paths.saturating_add(paths);
    }

    /// The renderer ran `steps` Adam steps in `seconds`.
    pub fn record_update(&mut self, steps: u32, seconds: f64) {
        if seconds.is_finite() && seconds > 0.0 {
            self.trained_seconds += seconds;
        }
        self.steps += u64::from(steps);
        self.updates += 1;
    }

    /// Measured seconds per Adam step (`None` before the first update with steps).
    pub fn seconds_per_step(&self) -> Option<f64> {
        (self.steps > 0 && self.trained_seconds > 0.0)
            .then(|| self.trained_seconds / self.steps as f64)
    }

    /// Measured tracing seconds per path in the training phase (`None` before a report).
    pub fn seconds_per_path(&self) -> Option<f64> {
        (self.traced_paths > 0 && self.traced_seconds > 0.0)
            .then(|| self.traced_seconds / self.traced_paths as f64)
    }

    /// Adam steps due now (0: keep tracing), given `buffered` samples waiting in the field and
    /// its training configuration (minibatch size, buffer capacity, and for
    /// [`StepRule::Epochs`] the per-update cap). With [`StepRule::TimeShare`] the first update
    /// runs one step, before any step has been timed (its time calibrates `c`).
    pub fn steps_due(&self, buffered: usize, config: &FieldConfig) -> u32 {
        if self.over || buffered == 0 {
            return 0;
        }
        let share = match self.options.steps {
            StepRule::Epochs(e) => return config.proportional_steps(buffered, e),
            StepRule::TimeShare(s) => s,
        };
        let batch = config.batch_size.max(1) as f64;
        let allowance = share / (1.0 - share) * self.traced_seconds - self.trained_seconds;
        let by_time = match self.seconds_per_step() {
            Some(c) => (allowance / c).floor().max(0.0),
            None => 1.0,
        };
        let by_samples = (self.options.max_epochs * buffered as f64 / batch).ceil();
        let mut steps = by_time.min(by_samples).min(f64::from(u32::MAX));
        if steps < 1.0 && 2 * buffered >= config.max_buffered_samples {
            steps = 1.0;
        }
        steps as u32
    }

    /// Runs the Adam steps due now on `field` ([`Self::steps_due`] of its buffered samples)
    /// and records their time ([`Self::record_update`]); `None` when none are due. The one
    /// training call of host-demo, the C ABI (`pg_field_train_scheduled`) and the Python
    /// bindings.
    ///
    /// # Errors
    /// As [`crate::GuidingField::try_update_steps`]; nothing is recorded then.
    pub fn train(
        &mut self,
        field: &mut crate::GuidingField,
    ) -> Result<Option<guiding_core::field::UpdateReport>, GuidingError> {
        let due = self.steps_due(field.buffered_samples(), &field.config().training);
        if due == 0 {
            return Ok(None);
        }
        let start = std::time::Instant::now();
        let report = field.try_update_steps(due)?;
        self.record_update(report.steps, start.elapsed().as_secs_f64());
        Ok(Some(report))
    }

    /// How many paths to trace before asking [`Self::steps_due`] again, at most `pass_paths`
    /// (one pass): `update_interval / seconds_per_path`, or `first_piece · pass_paths` before
    /// anything was measured; at least 1.
    pub fn paths_before_update(&self, pass_paths: u64) -> u64 {
        if matches!(self.options.steps, StepRule::Epochs(_)) {
            return pass_paths.max(1);
        }
        let paths = match self.seconds_per_path() {
            Some(t) => (self.options.update_interval / t).ceil(),
            None => (self.options.first_piece * pass_paths as f64).ceil(),
        };
        (paths.min(pass_paths as f64) as u64).max(1)
    }

    /// What the schedule did so far.
    pub fn report(&self) -> ScheduleReport {
        ScheduleReport {
            traced_seconds: self.traced_seconds,
            trained_seconds: self.trained_seconds,
            steps: self.steps,
            updates: self.updates,
            seconds_per_step: self.seconds_per_step().unwrap_or(f64::NAN),
        }
    }
}

/// What a [`TrainingSchedule`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScheduleReport {
    /// Tracing seconds of the training phase.
    pub traced_seconds: f64,
    /// Seconds of Adam steps.
    pub trained_seconds: f64,
    /// Adam steps.
    pub steps: u64,
    /// Updates (calls that ran steps).
    pub updates: u64,
    /// Mean seconds per step (`NaN` before any).
    pub seconds_per_step: f64,
}

impl ScheduleReport {
    /// Training's share of the training phase's wall clock, `U / (T + U)` (`NaN` before any).
    pub fn training_share(&self) -> f64 {
        self.trained_seconds / (self.traced_seconds + self.trained_seconds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule(budget: Budget) -> TrainingSchedule {
        TrainingSchedule::new(ScheduleOptions::DEFAULT, budget).unwrap()
    }

    /// Batch 8192, buffer of 2^20, 64 steps per update at most (for [`StepRule::Epochs`]).
    const CONFIG: FieldConfig = FieldConfig::DEFAULT
        .with_batch_size(8192)
        .with_steps_per_update(64);

    /// A simulated render: passes of `pass_seconds` traced in pieces of the size the schedule
    /// asks for, steps of `step_seconds`; returns (training share, seconds to the first update).
    fn simulate(pass_seconds: f64, step_seconds: f64) -> (f64, f64) {
        let budget = 30.0;
        let pass_paths = 100_000u64;
        let mut s = schedule(Budget::Seconds(budget));
        let (mut clock, mut first_update) = (0.0, f64::NAN);
        let mut buffered = 0usize;
        while s.in_training_phase(clock, 0) {
            let paths = s.paths_before_update(pass_paths);
            let t = pass_seconds * paths as f64 / pass_paths as f64;
            s.record_traced(t, paths);
            clock += t;
            buffered += (t * 2e6) as usize; // ~2 M guidable vertices per second of tracing
            let steps = s.steps_due(buffered, &CONFIG);
            if steps > 0 {
                clock += f64::from(steps) * step_seconds;
                s.record_update(steps, f64::from(steps) * step_seconds);
                buffered = 0;
                if first_update.is_nan() {
                    first_update = clock;
                }
            }
        }
        (s.report().training_share(), first_update)
    }

    /// The share holds for fast and slow passes alike (the old per-pass rule gave the slow
    /// scene 1 % of the wall time), and the first update comes within about a second.
    #[test]
    fn share_and_first_update_do_not_depend_on_the_pass_time() {
        for pass_seconds in [0.05, 0.5, 4.0, 20.0] {
            let (share, first) = simulate(pass_seconds, 0.004);
            assert!(
                (share - 1.0 / 3.0).abs() < 0.02,
                "pass {pass_seconds} s: share {share}"
            );
            assert!(
                first < 1.0,
                "pass {pass_seconds} s: first update at {first} s"
            );
        }
    }

    /// The epoch bound: few samples and cheap steps do not give hundreds of steps.
    #[test]
    fn steps_are_bounded_by_epochs_over_the_buffer() {
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_traced(1.0, 1000);
        s.record_update(1, 1e-4);
        // allowance 0.5 s / 1e-4 s = 5000 steps by time; 4 epochs of 8192 samples = 4.
        assert_eq!(s.steps_due(8192, &CONFIG), 4);
        // Nothing buffered: nothing due.
        assert_eq!(s.steps_due(0, &CONFIG), 0);
    }

    /// The account is cumulative: an update that took longer than its allowance delays the
    /// next one; a half-full buffer forces a step.
    #[test]
    fn the_time_account_carries_over() {
        let mut s = schedule(Budget::Seconds(10.0));
        assert_eq!(s.steps_due(100, &CONFIG), 1, "the first update calibrates");
        s.record_traced(0.1, 100);
        s.record_update(1, 0.2); // took 0.2 s where 0.05 s was due
        s.record_traced(0.1, 100);
        assert_eq!(s.steps_due(100_000, &CONFIG), 0);
        assert_eq!(s.steps_due(600_000, &CONFIG), 1, "half-full buffer");
        s.record_traced(0.5, 100); // traced 0.7 s: 0.35 s due, 0.2 s spent: 0.15 s = 0 steps
        assert_eq!(s.steps_due(100_000, &CONFIG), 0);
        s.record_traced(0.3, 100); // 1.0 s: 0.5 - 0.2 = 0.3 s = 1 step of 0.2 s
        assert_eq!(s.steps_due(100_000, &CONFIG), 1);
    }

    /// Reproducible training: whole passes, steps from the samples alone, capped.
    #[test]
    fn the_epoch_rule_ignores_time() {
        let o = ScheduleOptions {
            steps: StepRule::Epochs(2.0),
            ..ScheduleOptions::DEFAULT
        };
        let mut s = TrainingSchedule::new(o, Budget::Spp(16)).unwrap();
        assert_eq!(s.paths_before_update(5000), 5000);
        s.record_traced(123.0, 5000);
        s.record_update(3, 1e3);
        assert_eq!(s.steps_due(8192 * 3, &CONFIG), 6);
        assert_eq!(s.steps_due(10, &CONFIG), 1);
        assert_eq!(
            s.steps_due(8192 * 100, &CONFIG),
            64,
            "the configuration's cap"
        );
    }

    #[test]
    fn phases_of_time_and_spp_budgets() {
        let mut s = schedule(Budget::Seconds(10.0));
        assert!(s.in_training_phase(1.9, 50));
        assert!(!s.in_training_phase(2.0, 51));
        assert!(!s.in_training_phase(0.0, 0), "once over, always over");
        assert_eq!(s.steps_due(1000, &CONFIG), 0);
        let mut s = schedule(Budget::Spp(10));
        assert!((0..2).all(|p| s.in_training_phase(100.0, p)));
        assert!(!s.in_training_phase(0.0, 2));
        let mut s = schedule(Budget::Spp(10));
        s.end_training();
        assert!(!s.in_training_phase(0.0, 0));
    }

    #[test]
    fn pieces_follow_the_measured_path_time() {
        let mut s = schedule(Budget::Seconds(10.0));
        assert_eq!(
            s.paths_before_update(64_000),
            2000,
            "first piece: 1/32 of a pass"
        );
        s.record_traced(0.5, 1000); // 0.5 ms per path: 0.25 s is 500 paths
        assert_eq!(s.paths_before_update(64_000), 500);
        assert_eq!(s.paths_before_update(100), 100, "at most a pass");
        assert_eq!(s.paths_before_update(0), 1);
    }

    #[test]
    fn bad_options_are_refused() {
        let o = ScheduleOptions::DEFAULT;
        for bad in [
            ScheduleOptions {
                steps: StepRule::TimeShare(1.0),
                ..o
            },
            ScheduleOptions {
                steps: StepRule::Epochs(0.0),
                ..o
            },
            ScheduleOptions {
                train_fraction: f64::NAN,
                ..o
            },
            ScheduleOptions {
                update_interval: 0.0,
                ..o
            },
            ScheduleOptions {
                first_piece: 0.0,
                ..o
            },
            ScheduleOptions {
                max_epochs: f64::INFINITY,
                ..o
            },
        ] {
            assert!(
                TrainingSchedule::new(bad, Budget::Spp(1)).is_err(),
                "{bad:?}"
            );
        }
        assert!(TrainingSchedule::new(o, Budget::Seconds(f64::NAN)).is_err());
    }

    /// The early look is due once per quarter of the phase (1/4, 1/2, 3/4) with 64 steps
    /// behind it, not after the phase nor after `end_looks`; training resumed after a look ends
    /// the phase as much later. Each rule broken (a look before its quarter, before the steps,
    /// twice in a quarter, after `end_looks`, or a phase not extended) fails.
    #[test]
    fn the_early_look_is_due_once_per_quarter_and_a_resumed_phase_ends_later() {
        // 10 s budget: a 2-s training phase, the first look from 0.5 s.
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(EARLY_LOOK_MIN_STEPS as u32, 0.1);
        assert!(!s.look_due(0.49, 3), "before a quarter of the phase");
        assert!(s.look_due(0.5, 4));
        assert!(!s.look_due(0.6, 5), "due once per quarter");
        s.resume_after_look(0.3, 4);
        // The look's 0.3 s do not count: the half is at 1.3 s, three quarters at 1.8 s.
        assert!(!s.look_due(1.29, 6), "before the half");
        assert!(
            s.look_due(1.3, 7),
            "a straddling look: the next one at the half"
        );
        assert!(!s.look_due(1.35, 8), "due once per quarter");
        assert!(s.look_due(1.8, 9), "three quarters");
        assert!(!s.look_due(2.25, 10), "no look in the last quarter");
        assert!(s.in_training_phase(2.2, 9), "the phase ends 0.3 s later");
        assert!(!s.in_training_phase(2.4, 10));

        // A look that shows the guide paying ends the looks.
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(100, 0.1);
        assert!(s.look_due(0.5, 4));
        s.end_looks();
        assert!(!s.look_due(1.0, 6), "after end_looks");
        assert!(!s.look_due(1.5, 8), "after end_looks");
        // A late first look (its steps came late) is followed by the next quarter after it.
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(100, 0.1);
        assert!(s.look_due(1.1, 6), "past the half");
        assert!(
            !s.look_due(1.4, 7),
            "the next look at three quarters, not at the half"
        );
        assert!(s.look_due(1.5, 8));

        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(EARLY_LOOK_MIN_STEPS as u32 - 1, 0.1);
        assert!(!s.look_due(1.0, 4), "before the minimum of steps");
        s.record_update(1, 0.01);
        assert!(
            s.look_due(1.9, 8),
            "the steps came late: the look waits for them"
        );
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(100, 0.1);
        assert!(!s.look_due(2.0, 9), "never once the phase is over");
        let mut s = schedule(Budget::Seconds(10.0));
        s.record_update(100, 0.1);
        s.end_training();
        assert!(!s.look_due(1.0, 5), "nor after end_training");

        // 40 spp: 8 training passes, the look from pass 2; a 4-pass look moves the end to 12.
        let mut s = schedule(Budget::Spp(40));
        s.record_update(100, 0.1);
        assert!(!s.look_due(0.0, 1));
        assert!(s.look_due(0.0, 2));
        s.resume_after_look(f64::NAN, 4);
        assert!(s.in_training_phase(0.0, 11));
        assert!(!s.in_training_phase(0.0, 12));
        // No training phase: never due.
        let mut s = TrainingSchedule::new(
            ScheduleOptions {
                train_fraction: 0.0,
                ..ScheduleOptions::DEFAULT
            },
            Budget::Seconds(10.0),
        )
        .unwrap();
        s.record_update(100, 0.1);
        assert!(!s.look_due(0.0, 0));
    }
}
