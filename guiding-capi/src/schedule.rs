//! `PgSchedule`: the library's training schedule (`guiding::TrainingSchedule`, whose docs give
//! the rule): when a render trains its field and how many Adam steps each update runs, from
//! the times and path counts the renderer reports. `pg_field_train_scheduled` is the update
//! step of the loop (what host-demo's guided integrator runs after each traced piece);
//! `pg_schedule_look_due` and `pg_schedule_resume_after_look` are its early look (see
//! [`crate::trial`]).

use crate::field::{write, PgField};
use crate::ptr;
use crate::status::{guard, Failure, PgStatus};
use crate::types::PgUpdateReport;
use guiding::{Budget, ScheduleOptions, StepRule, TrainingSchedule};

/// How a schedule's updates choose their Adam steps (`PG_STEP_RULE_*`).
pub type PgStepRule = u32;
/// Training gets the share `PgScheduleArgs.step_value` (in `(0, 1)`, default 1/3) of the
/// training phase's wall clock, from measured step and tracing times (Rust
/// `StepRule::TimeShare`); the steps depend on timing, so two renders train differently.
pub const PG_STEP_RULE_TIME_SHARE: PgStepRule = 0;
/// Reproducible training: one update per whole pass with `clamp(ceil(e · buffered /
/// batch_size), 1, steps_per_update)` steps for `e = PgScheduleArgs.step_value` epochs
/// (`> 0`), the same on every run (Rust `StepRule::Epochs`).
pub const PG_STEP_RULE_EPOCHS: PgStepRule = 1;

/// The unit of a render's budget (`PG_BUDGET_*`).
pub type PgBudgetKind = u32;
/// Wall-clock seconds: `PgScheduleArgs.budget` finite and `≥ 0`.
pub const PG_BUDGET_SECONDS: PgBudgetKind = 0;
/// Samples (passes) per pixel: `PgScheduleArgs.budget` a whole number in `[0, 2³² − 1]`.
pub const PG_BUDGET_SPP: PgBudgetKind = 1;

/// Everything needed to create a schedule. Fill it with `pg_schedule_args_set_defaults`, then
/// set the budget (the default is `NaN` seconds, which `pg_schedule_new` refuses). The
/// options are the Rust `ScheduleOptions`; see their docs for the measurements behind the
/// defaults.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgScheduleArgs {
    /// `PG_BUDGET_*`: the unit of `budget` (default `PG_BUDGET_SECONDS`).
    pub budget_kind: PgBudgetKind,
    /// `PG_STEP_RULE_*` (default `PG_STEP_RULE_TIME_SHARE`).
    pub step_rule: PgStepRule,
    /// The render's budget in seconds or samples per pixel (must be set; default `NaN`).
    pub budget: f64,
    /// Fraction of the budget spent in the training phase, in `[0, 1]`. Default 0.2.
    pub train_fraction: f64,
    /// The training share in `(0, 1)` (`PG_STEP_RULE_TIME_SHARE`, default 1/3), or the epochs
    /// per update `> 0` (`PG_STEP_RULE_EPOCHS`).
    pub step_value: f64,
    /// Seconds of tracing between updates the schedule aims at, `> 0`. Default 0.25.
    pub update_interval: f64,
    /// Fraction of a pass traced before the first update, before anything was measured, in
    /// `(0, 1]`. Default 1/32.
    pub first_piece: f64,
    /// At most this many passes over the samples buffered since the last update per update,
    /// `> 0` (`PG_STEP_RULE_TIME_SHARE`). Default 4.
    pub max_epochs: f64,
}

/// What a schedule did so far (`pg_schedule_report`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PgScheduleReport {
    /// Tracing seconds of the training phase (`pg_schedule_record_traced`).
    pub traced_seconds: f64,
    /// Seconds of Adam steps (measured by `pg_field_train_scheduled`).
    pub trained_seconds: f64,
    /// Adam steps.
    pub steps: u64,
    /// Updates (`pg_field_train_scheduled` calls that had steps due).
    pub updates: u64,
    /// Mean seconds per step (`NaN` before any).
    pub seconds_per_step: f64,
    /// Training's share of the training phase's wall clock, `trained / (traced + trained)`
    /// (`NaN` before anything was recorded).
    pub training_share: f64,
    /// 1 once the training phase is over, else 0.
    pub training_over: u32,
    /// Padding (0).
    pub pad: u32,
}

/// A training schedule (opaque). Not synchronised: one render loop uses it. Create with
/// `pg_schedule_new`, release with `pg_schedule_release`.
pub struct PgSchedule {
    inner: TrainingSchedule,
}

fn args_of(o: &ScheduleOptions) -> PgScheduleArgs {
    let (step_rule, step_value) = match o.steps {
        StepRule::TimeShare(s) => (PG_STEP_RULE_TIME_SHARE, s),
        StepRule::Epochs(e) => (PG_STEP_RULE_EPOCHS, e),
    };
    PgScheduleArgs {
        budget_kind: PG_BUDGET_SECONDS,
        step_rule,
        budget: f64::NAN,
        train_fraction: o.train_fraction,
        step_value,
        update_interval: o.update_interval,
        first_piece: o.first_piece,
        max_epochs: o.max_epochs,
    }
}

/// The options and budget of `args`; the ranges are checked by `TrainingSchedule::new`.
/// `value` as seconds: finite and `≥ 0`, else `PG_INVALID_ARGUMENT` naming the argument.
fn non_negative_seconds(value: f64, what: &str) -> Result<(), Failure> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(Failure::invalid(format!(
            "{what} {value} is not finite and >= 0"
        )))
    }
}

fn options_of(args: &PgScheduleArgs) -> Result<(ScheduleOptions, Budget), Failure> {
    let steps = match args.step_rule {
        PG_STEP_RULE_TIME_SHARE => StepRule::TimeShare(args.step_value),
        PG_STEP_RULE_EPOCHS => StepRule::Epochs(args.step_value),
        r => return Err(Failure::unknown_code("step_rule", r, "STEP_RULE", "0 or 1")),
    };
    let budget = match args.budget_kind {
        PG_BUDGET_SECONDS => Budget::Seconds(args.budget),
        PG_BUDGET_SPP => {
            let b = args.budget;
            if !(b >= 0.0 && b <= f64::from(u32::MAX) && b.fract() == 0.0) {
                return Err(Failure::invalid(format!(
                    "budget {b} spp is not a whole number in [0, {}]",
                    u32::MAX
                )));
            }
            Budget::Spp(b as u32)
        }
        k => return Err(Failure::unknown_code("budget_kind", k, "BUDGET", "0 or 1")),
    };
    let options = ScheduleOptions {
        train_fraction: args.train_fraction,
        steps,
        update_interval: args.update_interval,
        first_piece: args.first_piece,
        max_epochs: args.max_epochs,
    };
    Ok((options, budget))
}

/// Fills `args` with the library's defaults (Rust `ScheduleOptions::DEFAULT`: training
/// fraction 0.2, `PG_STEP_RULE_TIME_SHARE` with share 1/3, updates every 0.25 s of tracing, a
/// first piece of 1/32 pass, at most 4 epochs per update) and a budget of `NaN` seconds, which
/// the caller must set.
///
/// Returns `PG_NULL_POINTER` if `args` is NULL.
///
/// # Safety
/// `args` must be NULL or point to writable memory for a `PgScheduleArgs`.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_args_set_defaults(args: *mut PgScheduleArgs) -> PgStatus {
    guard("pg_schedule_args_set_defaults", || unsafe {
        ptr::write_whole(args, "args", || Ok(args_of(&ScheduleOptions::DEFAULT)))
    })
}

/// Creates a schedule for a render of `args.budget` (see `PgScheduleArgs`) in `*out`.
///
/// Returns `PG_INVALID_ARGUMENT` for an unknown code, a value out of its range, a time budget
/// that is not finite and `≥ 0`, or an spp budget that is not a whole number in `[0, 2³² −
/// 1]`. On failure `*out` is set to NULL.
///
/// # Safety
/// `args` must be NULL or point to a `PgScheduleArgs`; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_new(
    args: *const PgScheduleArgs,
    out: *mut *mut PgSchedule,
) -> PgStatus {
    guard("pg_schedule_new", || unsafe {
        ptr::new_handle(out, || {
            let (options, budget) = options_of(ptr::as_ref(args, "args")?)?;
            let inner = TrainingSchedule::new(options, budget)?;
            Ok(PgSchedule { inner })
        })
    })
}

/// Releases a schedule (NULL: no-op).
///
/// # Safety
/// `schedule` must be NULL or a live handle that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_release(schedule: *mut PgSchedule) {
    unsafe { ptr::release("pg_schedule_release", schedule) }
}

/// Writes to `*out` whether work that starts now belongs to the training phase:
/// `elapsed_seconds` since the render started below `train_fraction · budget` (time budget),
/// or the sample index `pass_index` below `round(train_fraction · spp)` (spp budget). Once it
/// has answered false (or `pg_schedule_end_training` was called) it always does. Ask it
/// before each pass; record and train only while it says true.
///
/// Returns `PG_INVALID_ARGUMENT` (and changes nothing) if `elapsed_seconds` is not finite and
/// `≥ 0`.
///
/// # Safety
/// `schedule` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_in_training_phase(
    schedule: *mut PgSchedule,
    elapsed_seconds: f64,
    pass_index: u32,
    out: *mut bool,
) -> PgStatus {
    guard("pg_schedule_in_training_phase", || {
        let s = unsafe { ptr::as_mut(schedule, "schedule") }?;
        let out = unsafe { ptr::as_mut(out, "out") }?;
        non_negative_seconds(elapsed_seconds, "elapsed_seconds")?;
        *out = s.inner.in_training_phase(elapsed_seconds, pass_index);
        Ok(())
    })
}

/// Ends the training phase now (the renderer's own verdict, e.g. the field converged): later
/// `pg_schedule_in_training_phase` calls write false and `pg_field_train_scheduled` runs no
/// steps.
///
/// # Safety
/// `schedule` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_end_training(schedule: *mut PgSchedule) -> PgStatus {
    guard("pg_schedule_end_training", || {
        unsafe { ptr::as_mut(schedule, "schedule") }?
            .inner
            .end_training();
        Ok(())
    })
}

/// Writes to `*out` whether the renderer should take its early look at the guide now, before
/// the pass `pass_index` that starts `elapsed_seconds` into the render (Rust
/// `TrainingSchedule::look_due`): the guide has had 64 Adam steps (`EARLY_LOOK_MIN_STEPS`,
/// counted by `pg_field_train_scheduled`; the look waits for them), the phase is not over, and
/// the next look's share of the training phase is behind it: a quarter (`EARLY_LOOK_AT`) for
/// the first, then each following quarter (1/2, 3/4). Writes true at most once per quarter.
///
/// The look is a short efficiency trial of the guide as it is (`PgGuideTrial` up to its first
/// look, `pg_guide_trial_first_look`; training paused, nothing recorded), whose estimate
/// decides (Rust `TrialVerdict::look_decision`): `PG_EVIDENCE_PAYS`
/// (`pg_trial_verdict_worth_more_training`): training goes on
/// (`pg_schedule_resume_after_look`) and the renderer asks no more;
/// `PG_EVIDENCE_UNDECIDED` with a finite interval: training goes on
/// (`pg_schedule_resume_after_look`) to the next look; otherwise training ends
/// (`pg_schedule_end_training`). The look never switches the guide off. A renderer without
/// such a trial need not ask.
///
/// Returns `PG_INVALID_ARGUMENT` (and changes nothing) if `elapsed_seconds` is not finite and
/// `≥ 0`.
///
/// # Safety
/// `schedule` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_look_due(
    schedule: *mut PgSchedule,
    elapsed_seconds: f64,
    pass_index: u32,
    out: *mut bool,
) -> PgStatus {
    guard("pg_schedule_look_due", || {
        let s = unsafe { ptr::as_mut(schedule, "schedule") }?;
        let out = unsafe { ptr::as_mut(out, "out") }?;
        non_negative_seconds(elapsed_seconds, "elapsed_seconds")?;
        *out = s.inner.look_due(elapsed_seconds, pass_index);
        Ok(())
    })
}

/// Training resumes after an early look that took `look_seconds` (wall clock) and
/// `look_passes` passes (Rust `TrainingSchedule::resume_after_look`): the training phase ends
/// that much later, so the look does not cost the guide its training (the seconds count
/// against a time budget, the passes against an spp budget).
///
/// Returns `PG_INVALID_ARGUMENT` (and changes nothing) if `look_seconds` is not finite and
/// `≥ 0`.
///
/// # Safety
/// `schedule` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_resume_after_look(
    schedule: *mut PgSchedule,
    look_seconds: f64,
    look_passes: u32,
) -> PgStatus {
    guard("pg_schedule_resume_after_look", || {
        let s = unsafe { ptr::as_mut(schedule, "schedule") }?;
        non_negative_seconds(look_seconds, "look_seconds")?;
        s.inner.resume_after_look(look_seconds, look_passes);
        Ok(())
    })
}

/// Reports that the renderer traced `paths` paths (camera samples) in `seconds` of the
/// training phase, recording included. The time share and the piece sizes are computed from
/// these reports.
///
/// Returns `PG_INVALID_ARGUMENT` (and records nothing) if `seconds` is not finite and `≥ 0`.
///
/// # Safety
/// `schedule` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_record_traced(
    schedule: *mut PgSchedule,
    seconds: f64,
    paths: u64,
) -> PgStatus {
    guard("pg_schedule_record_traced", || {
        let s = unsafe { ptr::as_mut(schedule, "schedule") }?;
        non_negative_seconds(seconds, "seconds")?;
        s.inner.record_traced(seconds, paths);
        Ok(())
    })
}

/// Writes to `*out` how many paths to trace (and record) before the next
/// `pg_field_train_scheduled`, at most `pass_paths` (the paths of one pass, `≥ 1`) and at
/// least 1: about `update_interval` seconds of tracing at the measured seconds per path, or
/// `first_piece` of a pass before anything was measured; a whole pass with
/// `PG_STEP_RULE_EPOCHS`. Trace a pass in pieces of this size, each an unbiased part of it
/// (e.g. rows spread over the image).
///
/// Returns `PG_INVALID_ARGUMENT` if `pass_paths` is 0.
///
/// # Safety
/// `schedule` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_paths_before_update(
    schedule: *const PgSchedule,
    pass_paths: u64,
    out: *mut u64,
) -> PgStatus {
    guard("pg_schedule_paths_before_update", || unsafe {
        ptr::read_into(schedule, "schedule", out, |s| {
            if pass_paths == 0 {
                return Err(Failure::invalid("pass_paths is 0 (a pass has >= 1 path)"));
            }
            Ok(s.inner.paths_before_update(pass_paths))
        })
    })
}

/// Writes what the schedule did so far to `*out`.
///
/// # Safety
/// `schedule` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_schedule_report(
    schedule: *const PgSchedule,
    out: *mut PgScheduleReport,
) -> PgStatus {
    guard("pg_schedule_report", || unsafe {
        ptr::read_into(schedule, "schedule", out, |s| {
            let r = s.inner.report();
            Ok(PgScheduleReport {
                traced_seconds: r.traced_seconds,
                trained_seconds: r.trained_seconds,
                steps: r.steps,
                updates: r.updates,
                seconds_per_step: r.seconds_per_step,
                training_share: r.training_share(),
                training_over: u32::from(s.inner.training_over()),
                pad: 0,
            })
        })
    })
}

/// The update step of a scheduled render, to call after each traced piece has been handed to
/// the field (`pg_field_add_samples` or `pg_recorder_flush_into`) and reported with
/// `pg_schedule_record_traced`: runs the Adam steps the schedule says are due for the field's
/// buffered samples and training settings (none once the training phase is over, nothing
/// buffered, or, with `PG_STEP_RULE_TIME_SHARE`, training ahead of its share), times them and
/// records them in the schedule. As Rust's `TrainingSchedule::steps_due`,
/// `GuidingField::try_update_steps` and `TrainingSchedule::record_update`. If it applied a
/// step, distributions queried before are stale. Writes what it did to `*report` unless
/// `report` is NULL (`steps` 0 and `mean_loss` NaN when no step was due). Takes the field
/// exclusively. On a field whose device failed (`PG_DEVICE_FAILURE_ERROR`) it trains nothing,
/// records nothing and returns `PG_DEVICE_UNAVAILABLE`.
///
/// # Safety
/// `field` must be NULL or a live handle; `schedule` NULL or a live handle no other call is
/// using; `report` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_train_scheduled(
    field: *mut PgField,
    schedule: *mut PgSchedule,
    report: *mut PgUpdateReport,
) -> PgStatus {
    guard("pg_field_train_scheduled", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let s = unsafe { ptr::as_mut(schedule, "schedule") }?;
        let report = unsafe { ptr::as_mut_opt(report, "report") }?;
        let mut f = write(&field.inner)?;
        let r = match s.inner.train(&mut f)? {
            Some(r) => r.into(),
            None => {
                let buffered = f.buffered_samples();
                PgUpdateReport {
                    buffered_samples: buffered as u64,
                    batch_size: f.config().training.batch_size.min(buffered) as u64,
                    converged: u32::from(f.is_converged()),
                    mean_loss: f64::NAN,
                    ..PgUpdateReport::default()
                }
            }
        };
        if let Some(out) = report {
            *out = r;
        }
        Ok(())
    })
}
