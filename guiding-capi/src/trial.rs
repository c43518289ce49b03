//! Efficiency trials: does the guide (`PgGuideTrial`, the Rust `guiding::GuideTrial`) or the
//! weight window (`PgWindowTrial`, the Rust `guiding::WindowTrial`) pay on this image? Both
//! compare whole passes (one sample per pixel over the image) with and without it by their
//! **efficiency**, relMSE per pass × seconds per pass, and decide when the confidence interval
//! of that cost ratio excludes 1; the Rust docs give the estimator, the looks and the
//! measurements behind them. The trial's first look also serves as the training schedule's
//! **early look** (`pg_schedule_look_due`): whether the rest of the training phase is worth
//! spending on the guide.
//!
//! Each trial is created from the renderer's image so far (its mean, RGB, `3 · width · height`
//! floats, before any trial pass) and then given each trial pass's pixel values (the same
//! layout) and wall-clock seconds. Every trial pass is an unbiased estimate and stays in the
//! image.
//!
//! ```c
//! /* After training, with a time budget: one pass at a time. */
//! pg_guide_trial_new(w, h, mean_rgb, &guide_trial);
//! pg_window_trial_new(w, h, mean_rgb, &window_trial);
//! bool keep_guide = true;
//! while (time_left) {
//!     int32_t arm; bool window, running, has;
//!     pg_guide_trial_next_arm(guide_trial, &arm);      /* PG_TRIAL_ARM_NONE once decided */
//!     pg_window_trial_next_pass_uses_window(window_trial, &window); /* the verdict's, after */
//!     bool guided = arm == PG_TRIAL_ARM_NONE ? keep_guide : arm == PG_TRIAL_ARM_GUIDED;
//!     /* render one pass (guide on or off, window on or off) into pass_rgb: `seconds` */
//!     if (arm != PG_TRIAL_ARM_NONE) {
//!         pg_guide_trial_record(guide_trial, arm, pass_rgb, seconds);
//!         PgTrialVerdict v;
//!         pg_guide_trial_verdict(guide_trial, &has, &v);
//!         if (has) keep_guide = v.keep_guide;        /* off only on evidence */
//!     }
//!     pg_window_trial_running(window_trial, &running);
//!     if (running) pg_window_trial_record(window_trial, window, pass_rgb, seconds);
//! }
//! pg_window_trial_release(window_trial);
//! pg_guide_trial_release(guide_trial);
//! ```
//!
//! The early look, in the training phase (the training loop of the crate docs), before each
//! pass:
//!
//! ```c
//! bool look = false;
//! if (!guide_pays)                      /* once per quarter of the phase, at most 3 times */
//!     pg_schedule_look_due(schedule, seconds_since_start, pass, &look);
//! if (look) {
//!     /* Pause training: guided passes read the guide as it is (its cache), record nothing
//!        and run no Adam step; unguided passes switch it off. */
//!     pg_guide_trial_new(w, h, mean_rgb, &probe);
//!     PgTrialVerdict v; bool has = false, more = false;
//!     double look_seconds = 0; uint32_t look_passes = 0;
//!     while (!has) {                                 /* at most 4 + 4 passes */
//!         pg_guide_trial_next_arm(probe, &arm);
//!         /* render one pass of `arm` into pass_rgb: `seconds` */
//!         look_seconds += seconds; look_passes++;
//!         if (pg_guide_trial_record(probe, arm, pass_rgb, seconds) != PG_OK) break;
//!         pg_guide_trial_first_look(probe, &has, &v);
//!     }
//!     if (has) pg_trial_verdict_worth_more_training(&v, &more); /* interval below 1 */
//!     bool straddles = has && v.evidence == PG_EVIDENCE_UNDECIDED && isfinite(v.ratio_high);
//!     if (more || straddles)                 /* no evidence either way: look again later */
//!         pg_schedule_resume_after_look(schedule, look_seconds, look_passes);
//!     else pg_schedule_end_training(schedule);      /* the trial after training decides */
//!     guide_pays = more;
//!     pg_guide_trial_release(probe);
//! }
//! ```
//!
//! The look never switches the guide off: a guide whose training ends there keeps what it
//! learned, and the trial after training judges it.

use crate::ptr::{self, disjoint, region, times, triples};
use crate::status::{guard, Failure, PgStatus};
use guiding::{GuideTrial, TrialArm, TrialOptions, TrialVerdict, Verdict, WindowTrial};
use std::mem::size_of;

/// What a trial's interval says (`PG_EVIDENCE_*`, the Rust `guiding::Verdict`).
pub type PgEvidence = u32;
/// The interval contains 1, none could be formed (a black image), or the untrimmed point
/// estimate contradicts it: nothing is decided, the guide (or window) is not shown to pay nor
/// not to pay.
pub const PG_EVIDENCE_UNDECIDED: PgEvidence = 0;
/// The whole interval lies below 1, and so does the untrimmed point estimate (Rust
/// `TrialOptions::robust_to_trim`): with it, a lower relMSE per second.
pub const PG_EVIDENCE_PAYS: PgEvidence = 1;
/// The whole interval lies above 1, and so does the untrimmed point estimate: it costs more
/// time than it saves variance.
pub const PG_EVIDENCE_DOES_NOT_PAY: PgEvidence = 2;

/// An arm of a `PgGuideTrial` (`PG_TRIAL_ARM_*`, the Rust `guiding::TrialArm`).
pub type PgTrialArm = i32;
/// The renderer's guided estimator.
pub const PG_TRIAL_ARM_GUIDED: PgTrialArm = 0;
/// The same renderer with the guide switched off (BSDF sampling and NEE only).
pub const PG_TRIAL_ARM_UNGUIDED: PgTrialArm = 1;
/// No arm: the trial has its verdict and runs no more passes (`pg_guide_trial_next_arm`).
pub const PG_TRIAL_ARM_NONE: PgTrialArm = -1;

/// What a trial measured and decided at a look (the Rust `guiding::TrialVerdict`). In a
/// `PgWindowTrial`'s verdict the "guided" fields are the arm with the window and the
/// "unguided" ones the arm without it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgTrialVerdict {
    /// 1: the guide stays on (the interval does not lie above 1), else 0. Where a verdict is
    /// read back (`pg_trial_verdict_worth_more_training`, `pg_window_trial_window_pays`) any
    /// non-zero value counts as 1.
    pub keep_guide: u32,
    /// `PG_EVIDENCE_*`: what the interval says.
    pub evidence: PgEvidence,
    /// Lower end of the cost ratio's interval (`NaN` without one).
    pub ratio_low: f64,
    /// Upper end of the cost ratio's interval (`NaN` without one).
    pub ratio_high: f64,
    /// Per-pass relative variance of the guided arm (`V_g`).
    pub guided_variance: f64,
    /// Per-pass relative variance of the unguided arm (`V_u`).
    pub unguided_variance: f64,
    /// Mean seconds per guided pass (`t_g`).
    pub guided_seconds: f64,
    /// Mean seconds per unguided pass (`t_u`).
    pub unguided_seconds: f64,
    /// `(V_g · t_g) / (V_u · t_u)`: below 1 the guide pays (`NaN` if the unguided cost is 0).
    pub cost_ratio: f64,
    /// Passes of the guided arm in this estimate (since its last `pg_guide_trial_restart`).
    pub guided_passes: u32,
    /// Passes of the unguided arm in this estimate (since its last `pg_guide_trial_restart`).
    pub unguided_passes: u32,
    /// The interval's normal quantile at this look (larger at later looks: α-spending).
    pub z: f64,
    /// Pixels left out because a trial pass gave them a non-finite value.
    pub pixels_skipped: u64,
}

const _: () = assert!(size_of::<PgTrialVerdict>() == 88);

impl From<TrialVerdict> for PgTrialVerdict {
    fn from(v: TrialVerdict) -> Self {
        Self {
            keep_guide: u32::from(v.keep_guide),
            evidence: match v.evidence {
                Verdict::Undecided => PG_EVIDENCE_UNDECIDED,
                Verdict::Pays => PG_EVIDENCE_PAYS,
                Verdict::DoesNotPay => PG_EVIDENCE_DOES_NOT_PAY,
            },
            ratio_low: v.ratio_low,
            ratio_high: v.ratio_high,
            guided_variance: v.guided_variance,
            unguided_variance: v.unguided_variance,
            guided_seconds: v.guided_seconds,
            unguided_seconds: v.unguided_seconds,
            cost_ratio: v.cost_ratio,
            guided_passes: v.guided_passes,
            unguided_passes: v.unguided_passes,
            z: v.z,
            pixels_skipped: v.pixels_skipped,
        }
    }
}

/// The Rust verdict of a C one (the inverse of the `From` conversion); an unknown
/// `evidence` code is refused.
fn verdict_of(v: &PgTrialVerdict) -> Result<TrialVerdict, Failure> {
    let evidence = match v.evidence {
        PG_EVIDENCE_UNDECIDED => Verdict::Undecided,
        PG_EVIDENCE_PAYS => Verdict::Pays,
        PG_EVIDENCE_DOES_NOT_PAY => Verdict::DoesNotPay,
        e => {
            return Err(Failure::unknown_code(
                "evidence",
                e,
                "EVIDENCE",
                "0, 1 or 2",
            ))
        }
    };
    Ok(TrialVerdict {
        keep_guide: v.keep_guide != 0,
        evidence,
        ratio_low: v.ratio_low,
        ratio_high: v.ratio_high,
        guided_variance: v.guided_variance,
        unguided_variance: v.unguided_variance,
        guided_seconds: v.guided_seconds,
        unguided_seconds: v.unguided_seconds,
        cost_ratio: v.cost_ratio,
        guided_passes: v.guided_passes,
        unguided_passes: v.unguided_passes,
        z: v.z,
        pixels_skipped: v.pixels_skipped,
    })
}

/// The Rust arm of `PG_TRIAL_ARM_GUIDED` or `PG_TRIAL_ARM_UNGUIDED`; any other code is refused.
fn arm_of(arm: PgTrialArm) -> Result<TrialArm, Failure> {
    match arm {
        PG_TRIAL_ARM_GUIDED => Ok(TrialArm::Guided),
        PG_TRIAL_ARM_UNGUIDED => Ok(TrialArm::Unguided),
        a => Err(Failure::invalid(format!(
            "arm {a} is not PG_TRIAL_ARM_GUIDED (0) or PG_TRIAL_ARM_UNGUIDED (1)"
        ))),
    }
}

/// The C code of a trial's next arm (`PG_TRIAL_ARM_NONE` for none).
fn arm_code(arm: Option<TrialArm>) -> PgTrialArm {
    match arm {
        Some(TrialArm::Guided) => PG_TRIAL_ARM_GUIDED,
        Some(TrialArm::Unguided) => PG_TRIAL_ARM_UNGUIDED,
        None => PG_TRIAL_ARM_NONE,
    }
}

/// The pixels of a `width × height` image and its `3 · width · height` floats at `image`
/// (NULL allowed for no pixels, which the trial then refuses).
///
/// # Safety
/// As [`ptr::slice`] for `3 · width · height` floats.
unsafe fn image_of<'a>(
    width: u32,
    height: u32,
    image: *const f32,
) -> Result<(usize, &'a [[f32; 3]]), Failure> {
    let pixels = times(width as usize, height as usize, "width x height")?;
    // SAFETY: the caller's contract.
    let image = unsafe { triples(image, pixels, "image") }?;
    Ok((pixels, image))
}

/// Writes whether `verdict` exists to `*has` and, if it does, the verdict to `*out` (left
/// untouched otherwise). Both must be non-NULL and must not overlap.
///
/// # Safety
/// As [`ptr::as_mut`] for `has` and `out`.
unsafe fn write_verdict(
    has: *mut bool,
    out: *mut PgTrialVerdict,
    verdict: Option<TrialVerdict>,
) -> Result<(), Failure> {
    disjoint(&[region("has", has, 1), region("out", out, 1)], &[])?;
    // SAFETY: the caller's contract; disjoint (checked).
    let (has, out) = unsafe { (ptr::as_mut(has, "has")?, ptr::as_mut(out, "out")?) };
    *has = verdict.is_some();
    if let Some(v) = verdict {
        *out = v.into();
    }
    Ok(())
}

/// `rule` of the Rust verdict of `*verdict`, into `*out`.
///
/// # Safety
/// `verdict` NULL or readable; `out` NULL or writable.
unsafe fn verdict_rule(
    verdict: *const PgTrialVerdict,
    out: *mut bool,
    rule: impl FnOnce(&TrialVerdict) -> bool,
) -> Result<(), Failure> {
    disjoint(&[region("out", out, 1)], &[region("verdict", verdict, 1)])?;
    // SAFETY: the caller's contract; disjoint (checked).
    let (v, out) = unsafe { (ptr::as_ref(verdict, "verdict")?, ptr::as_mut(out, "out")?) };
    *out = rule(&verdict_of(v)?);
    Ok(())
}

/// A guide trial (opaque): guided against unguided passes. Not synchronised: the render
/// loop uses it (any thread, one call at a time). Create with `pg_guide_trial_new`, release
/// with `pg_guide_trial_release`.
pub struct PgGuideTrial {
    inner: GuideTrial,
    /// Pixels of each pass (`width · height`).
    pixels: usize,
}

/// Creates a guide trial with the library's default options (Rust `TrialOptions::default()`:
/// 4 passes per arm, an early verdict from 2 + 2 passes when the interval already excludes 1,
/// `z = 3`, and the continuation of an undecided trial) in `*out` (NULL on failure). `image`
/// is the renderer's image before the trial, `3 · width · height` floats (RGB, row-major; its
/// mean so far, which must not include a trial pass); non-finite values count as 0. It weighs
/// the pixels' relative variances.
///
/// Returns `PG_INVALID_ARGUMENT` for an image without pixels or whose size overflows.
///
/// # Safety
/// `image` NULL or `3 · width · height` readable floats; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_new(
    width: u32,
    height: u32,
    image: *const f32,
    out: *mut *mut PgGuideTrial,
) -> PgStatus {
    guard("pg_guide_trial_new", || unsafe {
        ptr::new_handle(out, || {
            let (pixels, image) = image_of(width, height, image)?;
            let inner = GuideTrial::new(
                width as usize,
                height as usize,
                image,
                TrialOptions::default(),
            )?;
            Ok(PgGuideTrial { inner, pixels })
        })
    })
}

/// Releases a guide trial (NULL: no-op).
///
/// # Safety
/// `trial` must be NULL or a live handle that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_release(trial: *mut PgGuideTrial) {
    unsafe { ptr::release("pg_guide_trial_release", trial) }
}

/// Writes to `*out` the arm the next pass should run (`PG_TRIAL_ARM_GUIDED` or
/// `PG_TRIAL_ARM_UNGUIDED`), or `PG_TRIAL_ARM_NONE` once the trial has its verdict. Before the
/// first look the arms alternate, guided first; a continuing trial gives the arm with the
/// cheaper-looking estimate two passes for each pass of the other (Rust
/// `GuideTrial::next_arm`).
///
/// # Safety
/// `trial` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_next_arm(
    trial: *const PgGuideTrial,
    out: *mut PgTrialArm,
) -> PgStatus {
    guard("pg_guide_trial_next_arm", || unsafe {
        ptr::read_into(trial, "trial", out, |t| Ok(arm_code(t.inner.next_arm())))
    })
}

/// Adds one pass of `arm` (the one `pg_guide_trial_next_arm` said): its pixel values,
/// `3 · width · height` floats in the layout of the trial's image (a pixel with a non-finite
/// value is left out of the trial and counted), and the wall-clock seconds it took.
///
/// Returns `PG_INVALID_ARGUMENT` (and adds nothing) for an `arm` that is not
/// `PG_TRIAL_ARM_GUIDED` or `PG_TRIAL_ARM_UNGUIDED`, `seconds` not finite and `≥ 0`, a trial
/// with its verdict, or an arm that already has its passes before the first look.
///
/// # Safety
/// `trial` NULL or a live handle no other call is using; `pixels` NULL or
/// `3 · width · height` readable floats.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_record(
    trial: *mut PgGuideTrial,
    arm: PgTrialArm,
    pixels: *const f32,
    seconds: f64,
) -> PgStatus {
    guard("pg_guide_trial_record", || {
        let t = unsafe { ptr::as_mut(trial, "trial") }?;
        let pixels = unsafe { triples(pixels, t.pixels, "pixels") }?;
        t.inner.record(arm_of(arm)?, pixels, seconds)?;
        Ok(())
    })
}

/// Drops the passes of `arm` once the renderer has changed that estimator (e.g. refitted the
/// guide's selection probabilities after the first look), so that the continuing trial
/// measures the one that now renders (Rust `GuideTrial::restart`). Does nothing once the
/// trial has its verdict; the looks made stand.
///
/// Returns `PG_INVALID_ARGUMENT` for an `arm` that is not `PG_TRIAL_ARM_GUIDED` or
/// `PG_TRIAL_ARM_UNGUIDED`.
///
/// # Safety
/// `trial` NULL or a live handle no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_restart(
    trial: *mut PgGuideTrial,
    arm: PgTrialArm,
) -> PgStatus {
    guard("pg_guide_trial_restart", || {
        let t = unsafe { ptr::as_mut(trial, "trial") }?;
        t.inner.restart(arm_of(arm)?);
        Ok(())
    })
}

/// Writes to `*has` whether the trial has its verdict (it has ended: all passes, or a clear
/// case early) and, if so, the verdict to `*out`, which is left untouched otherwise. The
/// guide stays on unless `keep_guide` is 0 (the interval lies above 1).
///
/// # Safety
/// `trial` NULL or a live handle; `has` and `out` NULL or writable, not overlapping.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_verdict(
    trial: *const PgGuideTrial,
    has: *mut bool,
    out: *mut PgTrialVerdict,
) -> PgStatus {
    guard("pg_guide_trial_verdict", || {
        let t = unsafe { ptr::as_ref(trial, "trial") }?;
        unsafe { write_verdict(has, out, t.inner.verdict()) }
    })
}

/// Writes to `*has` whether the trial has made its first look (4 passes per arm, or 2 + 2
/// when the interval already excludes 1) and, if so, that look's estimate to `*out`, which
/// is left untouched otherwise: the estimate of the early look
/// (`pg_trial_verdict_worth_more_training`), whether or not the trial continues after it.
///
/// # Safety
/// `trial` NULL or a live handle; `has` and `out` NULL or writable, not overlapping.
#[no_mangle]
pub unsafe extern "C" fn pg_guide_trial_first_look(
    trial: *const PgGuideTrial,
    has: *mut bool,
    out: *mut PgTrialVerdict,
) -> PgStatus {
    guard("pg_guide_trial_first_look", || {
        let t = unsafe { ptr::as_ref(trial, "trial") }?;
        unsafe { write_verdict(has, out, t.inner.first_look()) }
    })
}

/// The early look's rule (Rust `TrialVerdict::worth_more_training`), into `*out`: more
/// training is worth its time only for a guide whose cost ratio's whole interval lies below 1
/// (`ratio_high < 1`: it pays on evidence). False for an interval that straddles 1 or lies
/// above it, and without one (a black image): then end training
/// (`pg_schedule_end_training`) and let the trial after training decide whether the guide
/// stays on.
///
/// Returns `PG_INVALID_ARGUMENT` for an unknown `evidence` code.
///
/// # Safety
/// `verdict` NULL or readable; `out` NULL or writable, not inside `*verdict`.
#[no_mangle]
pub unsafe extern "C" fn pg_trial_verdict_worth_more_training(
    verdict: *const PgTrialVerdict,
    out: *mut bool,
) -> PgStatus {
    guard("pg_trial_verdict_worth_more_training", || unsafe {
        verdict_rule(verdict, out, TrialVerdict::worth_more_training)
    })
}

/// A weight-window trial (opaque): passes with the window against passes without it (Rust
/// `guiding::WindowTrial`). Not synchronised: the render loop uses it (any thread, one call
/// at a time). Create with `pg_window_trial_new`, release with `pg_window_trial_release`.
pub struct PgWindowTrial {
    inner: WindowTrial,
    /// Pixels of each pass (`width · height`).
    pixels: usize,
}

/// Creates a weight-window trial with the library's default options (as
/// `pg_guide_trial_new`) in `*out` (NULL on failure), from the image before the trial
/// (`3 · width · height` floats, RGB, row-major). Start it once the radiance grid has learned;
/// the grid must not learn from the trial's passes.
///
/// Returns `PG_INVALID_ARGUMENT` for an image without pixels or whose size overflows.
///
/// # Safety
/// `image` NULL or `3 · width · height` readable floats; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_new(
    width: u32,
    height: u32,
    image: *const f32,
    out: *mut *mut PgWindowTrial,
) -> PgStatus {
    guard("pg_window_trial_new", || unsafe {
        ptr::new_handle(out, || {
            let (pixels, image) = image_of(width, height, image)?;
            let inner = WindowTrial::new(
                width as usize,
                height as usize,
                image,
                TrialOptions::default(),
            )?;
            Ok(PgWindowTrial { inner, pixels })
        })
    })
}

/// Releases a weight-window trial (NULL: no-op).
///
/// # Safety
/// `trial` must be NULL or a live handle that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_release(trial: *mut PgWindowTrial) {
    unsafe { ptr::release("pg_window_trial_release", trial) }
}

/// Writes to `*out` whether the next pass runs with the weight window: the ABBA order (with,
/// without, without, with, …) until the first look, the cheaper-looking arm in two passes of
/// three while the trial continues, then the verdict's choice
/// (`pg_window_trial_window_pays`) for the rest of the render.
///
/// # Safety
/// `trial` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_next_pass_uses_window(
    trial: *const PgWindowTrial,
    out: *mut bool,
) -> PgStatus {
    guard("pg_window_trial_next_pass_uses_window", || unsafe {
        ptr::read_into(trial, "trial", out, |t| Ok(t.inner.next_pass_uses_window()))
    })
}

/// Writes to `*out` whether the trial still runs (it has no verdict: the next pass is a trial
/// pass, to record).
///
/// # Safety
/// `trial` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_running(
    trial: *const PgWindowTrial,
    out: *mut bool,
) -> PgStatus {
    guard("pg_window_trial_running", || unsafe {
        ptr::read_into(trial, "trial", out, |t| Ok(t.inner.running()))
    })
}

/// Adds one trial pass: whether it ran with the window (what
/// `pg_window_trial_next_pass_uses_window` said), its pixel values (`3 · width · height`
/// floats in the layout of the trial's image) and the wall-clock seconds it took.
///
/// Returns `PG_INVALID_ARGUMENT` (and adds nothing) once the trial has its verdict, for a pass
/// of the other arm than the order's, or for `seconds` not finite and `≥ 0`.
///
/// # Safety
/// `trial` NULL or a live handle no other call is using; `pixels` NULL or
/// `3 · width · height` readable floats.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_record(
    trial: *mut PgWindowTrial,
    with_window: bool,
    pixels: *const f32,
    seconds: f64,
) -> PgStatus {
    guard("pg_window_trial_record", || {
        let t = unsafe { ptr::as_mut(trial, "trial") }?;
        let pixels = unsafe { triples(pixels, t.pixels, "pixels") }?;
        t.inner.record(with_window, pixels, seconds)?;
        Ok(())
    })
}

/// Writes to `*has` whether the trial has its verdict and, if so, the verdict to `*out`
/// (untouched otherwise): its "guided" fields are the arm with the window, its "unguided"
/// fields the arm without. Whether it keeps the window: `pg_window_trial_window_pays` (its
/// `keep_guide` is the guide's rule, not the window's).
///
/// # Safety
/// `trial` NULL or a live handle; `has` and `out` NULL or writable, not overlapping.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_verdict(
    trial: *const PgWindowTrial,
    has: *mut bool,
    out: *mut PgTrialVerdict,
) -> PgStatus {
    guard("pg_window_trial_verdict", || {
        let t = unsafe { ptr::as_ref(trial, "trial") }?;
        unsafe { write_verdict(has, out, t.inner.verdict()) }
    })
}

/// Whether a window trial's verdict keeps the window (Rust `WindowTrial::window_pays`), into
/// `*out`: its whole interval lies below 1 (`evidence` is `PG_EVIDENCE_PAYS`).
///
/// Returns `PG_INVALID_ARGUMENT` for an unknown `evidence` code.
///
/// # Safety
/// `verdict` NULL or readable; `out` NULL or writable, not inside `*verdict`.
#[no_mangle]
pub unsafe extern "C" fn pg_window_trial_window_pays(
    verdict: *const PgTrialVerdict,
    out: *mut bool,
) -> PgStatus {
    guard("pg_window_trial_window_pays", || unsafe {
        verdict_rule(verdict, out, WindowTrial::window_pays)
    })
}
