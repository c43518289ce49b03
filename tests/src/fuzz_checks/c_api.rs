//! Fuzz target `c_api`: arbitrary bytes read as a sequence of calls on the C
//! ABI of `guiding-capi`, made through its `extern "C"` functions exactly as
//! a C renderer would make them.
//!
//! The interpreter keeps a few handle slots (fields, distributions, a
//! recorder, a training schedule). A release clears its slot, so a handle is never used after it
//! is released or released twice: the header documents both as undefined
//! behaviour (as with `free`), which no status code can report. Everything
//! else is fair game: NULL handles and arrays, unknown codes, NaN and empty
//! bounds, NaN and out-of-range random numbers and directions, counts larger
//! than the distributions hold, arbitrary training samples and path
//! vertices, saved files with corrupted bytes, schedules with any
//! options, budgets, times and path counts driving `pg_field_train_scheduled`
//! and their early look, and efficiency trials (`PgGuideTrial`,
//! `PgWindowTrial`) fed passes of any values, seconds and arms, before and
//! after their verdicts, each checked against a Rust twin fed the same calls.
//!
//! Asserted after every call: the status is one of the `PgStatus` codes and
//! never `PG_PANIC` (a panic caught at the boundary is a library bug);
//! `pg_last_error()` is a non-empty string after a failure and `""` after a
//! success; on success the outputs are valid (finite unit directions, finite
//! densities, `> 0` for samples, selection probabilities in `[0, 1]`); a
//! scheduled update runs what the schedule's report then counts; the early
//! look is due at most three times per schedule (once per quarter of the
//! training phase); a trial's arms, verdicts and statuses are its Rust twin's.
//!
//! Inputs stay cheap: only `PG_SIZE_SMALL` models (other size codes are
//! invalid ones), batches of at most 16 samples, at most 4 steps per update,
//! at most 2 threads, at most 6 queries per call and [`MAX_OPS`] calls; a
//! valid schedule allows at most 4 epochs per update, so a scheduled update
//! runs at most 4 · 64 steps. Trial images have at most 6 × 6 pixels.

use super::{special_values, ByteReader};
use guiding::{GuideTrial, TrialArm, TrialOptions, TrialVerdict, WindowTrial};
use guiding_capi::*;
use std::ffi::{CStr, CString};
use std::ptr::{null, null_mut};
use std::sync::atomic::{AtomicU64, Ordering};

/// Calls interpreted per input at most.
pub const MAX_OPS: usize = 32;
/// Queries (and distributions) per call at most.
const MAX_N: usize = 6;
/// Handle slots of each kind.
const SLOTS: usize = 2;

/// Values at the edges of every argument's domain.
const SPECIAL: [f32; 16] = special_values(
    [0.0, -0.0, 1e-45, -1.0, 1.0, 0.5, 1.0 + 1e-3, 1e-30, 1e6],
    [2.0],
);

impl ByteReader<'_> {
    /// Mostly a plausible value in `[0, 1)`, sometimes a special value,
    /// sometimes any bit pattern.
    fn c_value(&mut self) -> f32 {
        let b = self.byte();
        match b % 8 {
            0 => self.any_f32(),
            1 | 2 => SPECIAL[usize::from(b >> 4)],
            _ => self.unit(),
        }
    }

    /// Mostly a unit direction, sometimes an arbitrary vector.
    fn c_dir3(&mut self) -> [f32; 3] {
        match self.byte() % 6 {
            0 => [self.c_value(), self.c_value(), self.c_value()],
            1 => [0.0; 3],
            _ => {
                let (u, v) = (self.unit(), self.unit());
                let z = 1.0 - 2.0 * u;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = std::f32::consts::TAU * v;
                [r * phi.cos(), r * phi.sin(), z]
            }
        }
    }

    fn c_position(&mut self) -> [f32; 3] {
        if self.byte() % 8 == 0 {
            [self.c_value(), self.c_value(), self.c_value()]
        } else {
            [
                self.unit() * 2.0 - 1.0,
                self.unit() * 2.0 - 1.0,
                self.unit() * 2.0 - 1.0,
            ]
        }
    }

    fn c_query(&mut self) -> PgQueryPoint {
        // As a C caller would: designated fields, the padding left zero.
        PgQueryPoint {
            position: self.c_position(),
            roughness: self.c_value(),
            normal: self.c_dir3(),
            wo: self.c_dir3(),
            ..PgQueryPoint::default()
        }
    }

    fn c_sample(&mut self) -> PgTrainingSample {
        PgTrainingSample {
            position: self.c_position(),
            roughness: self.c_value(),
            normal: self.c_dir3(),
            sample_pdf: self.c_value(),
            wo: self.c_dir3(),
            bsdf_pdf: self.c_value(),
            wi: self.c_dir3(),
            radiance: [self.c_value(), self.c_value(), self.c_value()],
            bsdf_cos: [self.c_value(), self.c_value(), self.c_value()],
            ..PgTrainingSample::default()
        }
    }

    fn c_vertex(&mut self) -> PgPathVertex {
        let mut v = PgPathVertex::default();
        // SAFETY: a valid pointer to a local.
        assert_ok(unsafe { pg_path_vertex_set_defaults(&mut v) }, "vertex");
        v.position = self.c_position();
        v.normal = self.c_dir3();
        v.wo = self.c_dir3();
        v.wi = self.c_dir3();
        v.sample_pdf = self.c_value();
        v.emitted = [self.c_value(), 0.0, self.c_value()];
        let b = self.byte();
        if b & 1 != 0 {
            v.roughness = self.c_value();
            v.bsdf_pdf = self.c_value();
            v.emitted_mis_weight = self.c_value();
            v.continuation_scale = self.c_value();
        }
        v.direct = [self.c_value(), self.c_value(), 0.0];
        v.bsdf_cos = [self.c_value(), self.c_value(), self.c_value()];
        v.is_delta = u32::from(b & 6 == 6);
        v
    }
}

/// This thread's `pg_last_error()` text.
fn last_error() -> String {
    let p = pg_last_error();
    assert!(!p.is_null(), "pg_last_error returned NULL");
    // SAFETY: pg_last_error returns a NUL-terminated string (checked non-NULL).
    unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

/// Checks the contract of every status and returns it.
fn check(status: PgStatus, what: &str) -> PgStatus {
    assert!(
        status as u32 <= PgStatus::PG_PANIC as u32,
        "{what}: bad code"
    );
    let message = last_error();
    assert!(
        status != PgStatus::PG_PANIC,
        "{what}: the library panicked: {message}"
    );
    if status == PgStatus::PG_OK {
        assert!(message.is_empty(), "{what}: OK with message {message:?}");
    } else {
        assert!(!message.is_empty(), "{what}: {status:?} without a message");
    }
    status
}

fn assert_ok(status: PgStatus, what: &str) {
    assert_eq!(
        check(status, what),
        PgStatus::PG_OK,
        "{what}: {}",
        last_error()
    );
}

fn is_unit(d: &[f32]) -> bool {
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.iter().all(|x| x.is_finite()) && (l - 1.0).abs() <= 1e-5
}

fn check_samples(what: &str, dirs: &[f32], pdfs: &[f32]) {
    for (d, p) in dirs.chunks_exact(3).zip(pdfs) {
        assert!(is_unit(d), "{what}: direction {d:?}");
        assert!(p.is_finite() && *p > 0.0, "{what}: sample pdf {p}");
    }
}

fn check_pdfs(what: &str, pdfs: &[f32]) {
    for p in pdfs {
        assert!(p.is_finite() && *p >= 0.0, "{what}: pdf {p}");
    }
}

fn check_probabilities(what: &str, out: &[f32]) {
    for p in out {
        assert!((0.0..=1.0).contains(p), "{what}: selection probability {p}");
    }
}

/// A pointer to `v`'s data, or NULL when `null` (the callee must refuse
/// NULL unless the count is 0).
fn ptr_or_null<T>(v: &[T], null: bool) -> *const T {
    if null {
        std::ptr::null()
    } else {
        v.as_ptr()
    }
}

fn mut_or_null<T>(v: &mut [T], null: bool) -> *mut T {
    if null {
        null_mut()
    } else {
        v.as_mut_ptr()
    }
}

/// A file path unique to this process and call.
fn temp_path() -> CString {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let path =
        std::env::temp_dir().join(format!("guiding-capi-fuzz-{}-{n}.pgf", std::process::id()));
    CString::new(path.into_os_string().into_encoded_bytes()).unwrap()
}

/// Handles held by the interpreter; released when it is dropped (also
/// when a check fails, so the fuzzer does not leak).
struct State {
    fields: [*mut PgField; SLOTS],
    dists: [*mut PgDistributions; SLOTS],
    /// Distributions held by each slot (from the latest query into it).
    held: [usize; SLOTS],
    recorder: *mut PgRecorder,
    schedule: *mut PgSchedule,
    grid: *mut PgRadianceGrid,
    /// Estimates offered to the grid since it was made (kept or refused).
    grid_offered: u64,
    /// Early looks due so far on this schedule (at most one per quarter of its training
    /// phase: 1/4, 1/2, 3/4).
    looks: u32,
    guide_trial: *mut PgGuideTrial,
    /// The Rust trial fed the calls the C one accepted (`Some` while `guide_trial` is live).
    guide_twin: Option<GuideTrial>,
    window_trial: *mut PgWindowTrial,
    /// As `guide_twin`, for `window_trial`.
    window_twin: Option<WindowTrial>,
    /// Pixels of the live trials' images (and passes).
    guide_pixels: usize,
    window_pixels: usize,
    /// Trial passes made so far (seeds each pass's noise).
    trial_passes: u64,
    path: CString,
}

impl Drop for State {
    fn drop(&mut self) {
        // SAFETY: every non-NULL slot holds a live handle, released once.
        unsafe {
            for f in self.fields {
                pg_field_release(f);
            }
            for d in self.dists {
                pg_distributions_release(d);
            }
            pg_recorder_release(self.recorder);
            pg_schedule_release(self.schedule);
            pg_radiance_grid_release(self.grid);
            pg_guide_trial_release(self.guide_trial);
            pg_window_trial_release(self.window_trial);
        }
        let path = std::path::PathBuf::from(self.path.to_str().unwrap_or_default());
        let _ = std::fs::remove_file(path);
    }
}

/// Field arguments from bytes: a representation code (4 is invalid), and
/// sometimes an invalid target or size, out-of-range training values or
/// bad bounds. The size is always `PG_SIZE_SMALL` or an invalid code.
fn field_args(r: &mut ByteReader<'_>) -> Option<PgFieldArgs> {
    let rep = u32::from(r.byte() % 5);
    let mut args = PgFieldArgs {
        representation: 0,
        target: 0,
        size: 0,
        selection_probability: 0.0,
        learning_rate: 0.0,
        ema_decay: 0.0,
        steps_per_update: 0,
        seed: 0,
        batch_size: 0,
        threads: 0,
        max_buffered_samples: 0,
        max_steps: 0,
        plateau_window: 0,
        plateau_min_relative_improvement: 0.0,
        bounds_min: [0.0; 3],
        bounds_max: [0.0; 3],
        device: 0,
        device_failure: 0,
    };
    // SAFETY: a valid pointer to a local.
    let status = check(
        unsafe { pg_field_args_set_defaults(&mut args, rep) },
        "defaults",
    );
    if rep < 4 {
        assert_eq!(status, PgStatus::PG_OK);
        assert_eq!(args.representation, rep);
        assert!(args.bounds_min == [0.0; 3] && args.bounds_max == [0.0; 3]);
    } else {
        assert_eq!(status, PgStatus::PG_INVALID_ARGUMENT);
    }
    let flags = r.byte();
    args.target = u32::from(r.byte() % 2);
    args.size = PG_SIZE_SMALL;
    args.threads = 1 + usize::from(r.byte() % 2);
    args.batch_size = 1 + usize::from(r.byte() % 16);
    args.steps_per_update = 1 + u32::from(r.byte() % 4);
    args.max_buffered_samples = 1 + usize::from(r.byte() % 64);
    args.seed = u32::from(r.byte());
    args.bounds_min = [-1.0; 3];
    args.bounds_max = [1.0; 3];
    if flags & 1 != 0 {
        // Arbitrary training values: invalid ones must be refused.
        args.selection_probability = r.c_value();
        args.learning_rate = r.c_value();
        args.ema_decay = r.c_value();
        args.plateau_window = u32::from(r.byte() % 4);
        args.plateau_min_relative_improvement = r.c_value();
        args.max_steps = u64::from(r.byte());
        let b = r.byte();
        if b & 1 != 0 {
            args.batch_size = 0;
        }
        if b & 2 != 0 {
            args.steps_per_update = 0;
        }
        if b & 4 != 0 {
            args.max_buffered_samples = 0;
        }
        if b & 8 != 0 {
            args.target = 2 + u32::from(b >> 4);
        }
    }
    if flags & 2 != 0 {
        // Bad sizes: 3.. are not size codes (Compact/Paper stay out: slow).
        args.size = 3 + u32::from(r.byte());
    }
    match (flags >> 2) % 8 {
        0 => {
            // NaN, infinite, huge or arbitrary corners.
            args.bounds_min = [r.c_value(), r.c_value(), r.c_value()];
            args.bounds_max = [r.c_value(), r.c_value(), r.c_value()];
        }
        1 => args.bounds_max = args.bounds_min, // empty
        2 => std::mem::swap(&mut args.bounds_min, &mut args.bounds_max),
        3 => {
            args.bounds_min = [-1e30; 3];
            args.bounds_max = [1e30; 3];
        }
        4 => args.bounds_max[usize::from(r.byte() % 3)] = f32::NAN,
        _ => {}
    }
    (flags & 0xe0 != 0xe0).then_some(args)
}

/// Fuzz target `c_api`: see the module documentation.
pub fn c_api(data: &[u8]) {
    let mut r = ByteReader::new(data);
    let mut s = State {
        fields: [null_mut(); SLOTS],
        dists: [null_mut(); SLOTS],
        held: [0; SLOTS],
        recorder: null_mut(),
        schedule: null_mut(),
        grid: null_mut(),
        grid_offered: 0,
        looks: 0,
        guide_trial: null_mut(),
        guide_twin: None,
        window_trial: null_mut(),
        window_twin: None,
        guide_pixels: 0,
        window_pixels: 0,
        trial_passes: 0,
        path: temp_path(),
    };
    for _ in 0..MAX_OPS {
        if r.pos >= data.len() {
            break;
        }
        let op = r.byte();
        let slot = usize::from(op >> 7);
        // Sometimes a NULL handle instead of the slot's.
        let null_handle = op & 0x40 != 0 && r.byte() % 4 == 0;
        let field = if null_handle {
            null_mut()
        } else {
            s.fields[slot]
        };
        let dist = if null_handle {
            null_mut()
        } else {
            s.dists[slot]
        };
        // SAFETY (all calls below): handles are NULL or live (slots are
        // cleared on release), arrays are locals of at least the stated
        // length or NULL.
        // The slot and NULL-handle bits do not take part in the choice.
        match (op & 0x3f) % 26 {
            0 | 1 => op_new_field(&mut r, &mut s, slot),
            2 => {
                unsafe { pg_field_release(s.fields[slot]) };
                check(PgStatus::PG_OK, "pg_field_release");
                s.fields[slot] = null_mut();
            }
            3 | 4 => op_query(&mut r, &mut s, slot, field, dist),
            5 => op_dist_sample(&mut r, &s, slot, dist),
            6 => op_dist_pdf(&mut r, &s, slot, dist),
            7 => {
                let n = usize::from(r.byte()) % (MAX_N + 2);
                let mut out = vec![-1.0; n];
                let st = check(
                    unsafe { pg_distributions_selection_probability(dist, n, out.as_mut_ptr()) },
                    "pg_distributions_selection_probability",
                );
                expect_size(st, dist, n, s.held[slot], true);
                if st == PgStatus::PG_OK {
                    check_probabilities("distributions", &out);
                }
            }
            8 => op_field_sample(&mut r, field),
            9 => op_field_pdf(&mut r, field),
            10 => {
                let n = usize::from(r.byte()) % (MAX_N + 1);
                let q: Vec<_> = (0..n).map(|_| r.c_query()).collect();
                let mut out = vec![-1.0; n];
                let st = check(
                    unsafe {
                        pg_field_selection_probability(field, n, q.as_ptr(), out.as_mut_ptr())
                    },
                    "pg_field_selection_probability",
                );
                expect_null(st, field.is_null());
                if st == PgStatus::PG_OK {
                    check_probabilities("field", &out);
                }
            }
            11 | 12 => {
                let n = usize::from(r.byte() % 9);
                let samples: Vec<_> = (0..n).map(|_| r.c_sample()).collect();
                let null = n > 0 && r.byte() % 8 == 0;
                let st = check(
                    unsafe { pg_field_add_samples(field, ptr_or_null(&samples, null), n) },
                    "pg_field_add_samples",
                );
                expect_null(st, field.is_null() || null);
            }
            13 => op_update(&mut r, field),
            14 => op_info(field),
            15 => {
                let st = check(
                    unsafe { pg_field_stop_training(field) },
                    "pg_field_stop_training",
                );
                expect_null(st, field.is_null());
            }
            16 => op_recorder(&mut r, &mut s, field, null_handle),
            17 => op_save_load(&mut r, &mut s, slot, field),
            18 => {
                // A fresh or released distributions handle.
                let new = r.byte() % 2 == 0;
                unsafe { pg_distributions_release(s.dists[slot]) };
                s.dists[slot] = null_mut();
                s.held[slot] = 0;
                if new {
                    let mut d = null_mut();
                    assert_ok(unsafe { pg_distributions_new(&mut d) }, "dist new");
                    assert!(!d.is_null());
                    s.dists[slot] = d;
                }
            }
            19 => op_schedule(&mut r, &mut s, null_handle),
            20 => op_train_scheduled(&mut r, &s, field, null_handle),
            21 => op_roulette(&mut r, &mut s, null_handle),
            22 => op_dist_product(&mut r, &s, slot, dist),
            23 => op_media_rules(&mut r),
            24 => op_trials(&mut r, &mut s, null_handle),
            _ => null_sweep(),
        }
    }
}

/// On a NULL handle or array the status must be `PG_NULL_POINTER`; else
/// it must not be.
fn expect_null(status: PgStatus, null: bool) {
    if null {
        assert_eq!(status, PgStatus::PG_NULL_POINTER, "{}", last_error());
    } else {
        assert_ne!(status, PgStatus::PG_NULL_POINTER, "{}", last_error());
    }
}

/// Distributions calls: `n` beyond what is held is `PG_SIZE_MISMATCH` when
/// every other argument is valid, and never OK.
fn expect_size(st: PgStatus, dist: *mut PgDistributions, n: usize, held: usize, valid: bool) {
    if dist.is_null() {
        assert_eq!(st, PgStatus::PG_NULL_POINTER, "{}", last_error());
    } else if n > held {
        assert_ne!(st, PgStatus::PG_OK, "n {n} > held {held}");
        if valid {
            assert_eq!(st, PgStatus::PG_SIZE_MISMATCH, "{}", last_error());
        }
    } else if valid {
        assert!(
            matches!(st, PgStatus::PG_OK | PgStatus::PG_STALE),
            "{st:?}: {}",
            last_error()
        );
    }
}

fn op_new_field(r: &mut ByteReader<'_>, s: &mut State, slot: usize) {
    let args = field_args(r);
    let null_out = r.byte() % 16 == 0;
    let mut out: *mut PgField = std::ptr::dangling_mut(); // must be overwritten
    let args_ptr = args.as_ref().map_or(null(), |a| a as *const PgFieldArgs);
    let out_ptr = if null_out {
        null_mut()
    } else {
        &mut out as *mut *mut PgField
    };
    // SAFETY: valid pointers to locals or NULL.
    let st = check(unsafe { pg_field_new(args_ptr, out_ptr) }, "pg_field_new");
    if null_out || args.is_none() {
        assert_eq!(st, PgStatus::PG_NULL_POINTER);
        if !null_out {
            assert!(out.is_null(), "out not NULL on failure");
        }
        return;
    }
    if st != PgStatus::PG_OK {
        assert!(out.is_null(), "out not NULL on failure");
        return;
    }
    assert!(!out.is_null());
    // SAFETY: the slot holds NULL or a live handle; replaced by the new one.
    unsafe { pg_field_release(s.fields[slot]) };
    s.fields[slot] = out;
    // The arguments round-trip.
    let mut got = args.unwrap();
    got.seed ^= 1;
    assert_ok(unsafe { pg_field_get_args(out, &mut got) }, "get_args");
    let a = args.unwrap();
    assert_eq!(
        (got.representation, got.target),
        (a.representation, a.target)
    );
    assert_eq!(
        (got.bounds_min, got.bounds_max),
        (a.bounds_min, a.bounds_max)
    );
}

fn op_query(
    r: &mut ByteReader<'_>,
    s: &mut State,
    slot: usize,
    field: *mut PgField,
    dist: *mut PgDistributions,
) {
    let n = usize::from(r.byte()) % (MAX_N + 1);
    let q: Vec<_> = (0..n).map(|_| r.c_query()).collect();
    let null_q = n > 0 && r.byte() % 8 == 0;
    let st = check(
        unsafe { pg_field_query(field, n, ptr_or_null(&q, null_q), dist) },
        "pg_field_query",
    );
    expect_null(st, field.is_null() || dist.is_null() || null_q);
    if dist.is_null() {
        return;
    }
    let mut len = usize::MAX;
    assert_ok(unsafe { pg_distributions_len(dist, &mut len) }, "len");
    let expected = if st == PgStatus::PG_OK { n } else { 0 };
    assert_eq!(len, expected, "held after query ({st:?})");
    s.held[slot] = len;
}

/// Random numbers: mostly in `[0, 1)`, sometimes 1, NaN or out of range.
fn random_numbers(r: &mut ByteReader<'_>, n: usize) -> (Vec<f32>, bool) {
    let bad = r.byte() % 4 == 0;
    let u: Vec<f32> = (0..n)
        .map(|_| if bad { r.c_value() } else { r.unit() })
        .collect();
    let valid = u.iter().all(|x| (0.0..=1.0).contains(x));
    (u, valid)
}

fn directions(r: &mut ByteReader<'_>, n: usize) -> (Vec<f32>, bool) {
    let d: Vec<f32> = (0..n).flat_map(|_| r.c_dir3()).collect();
    let valid = d.chunks_exact(3).all(|c| {
        let l = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        c.iter().all(|x| x.is_finite()) && (l - 1.0).abs() <= 1e-6
    });
    (d, valid)
}

/// The output arrays of a sampling call on `n` lanes, NaN until the call
/// writes them.
struct SampleOutputs {
    dirs: Vec<f32>,
    pdfs: Vec<f32>,
}

impl SampleOutputs {
    fn new(n: usize) -> Self {
        Self {
            dirs: vec![f32::NAN; 3 * n],
            pdfs: vec![f32::NAN; n],
        }
    }

    /// The call's outcome `st`: random numbers `u` outside `[0, 1]` are
    /// never accepted, and on success every lane holds a valid sample.
    fn check(&self, what: &str, st: PgStatus, u: &[f32], valid_u: bool) {
        if !valid_u {
            assert_ne!(st, PgStatus::PG_OK, "{what}: invalid u accepted: {u:?}");
        }
        if st == PgStatus::PG_OK {
            check_samples(what, &self.dirs, &self.pdfs);
        }
    }
}

fn op_dist_sample(r: &mut ByteReader<'_>, s: &State, slot: usize, dist: *mut PgDistributions) {
    let n = usize::from(r.byte()) % (MAX_N + 2);
    let (u, valid) = random_numbers(r, 2 * n);
    let null_pdfs = r.byte() % 16 == 0;
    let mut out = SampleOutputs::new(n);
    let (dirs, pdfs) = (out.dirs.as_mut_ptr(), mut_or_null(&mut out.pdfs, null_pdfs));
    let st = check(
        unsafe { pg_distributions_sample(dist, n, u.as_ptr(), dirs, pdfs) },
        "pg_distributions_sample",
    );
    let null_array = null_pdfs && n > 0;
    if null_array && !dist.is_null() {
        assert_eq!(st, PgStatus::PG_NULL_POINTER);
        return;
    }
    expect_size(st, dist, n, s.held[slot], valid);
    out.check("distributions", st, &u, valid);
}

/// `pg_distributions_apply_cosine_product` or `_apply_lobe_product` on random (sometimes
/// non-finite, zero, negative) normals, axes and concentrations: invalid ones are refused
/// with `PG_INVALID_ARGUMENT`, and after a product every lane still samples a unit direction
/// with a positive, finite density.
fn op_dist_product(r: &mut ByteReader<'_>, s: &State, slot: usize, dist: *mut PgDistributions) {
    let n = usize::from(r.byte()) % (MAX_N + 2);
    let cosine = r.byte() % 2 == 0;
    let vectors: Vec<f32> = (0..n).flat_map(|_| r.c_dir3()).collect();
    let kappas: Vec<f32> = (0..n)
        .map(|_| match r.byte() % 4 {
            0 => r.c_value(),
            1 => 0.0,
            _ => r.unit() * 1000.0,
        })
        .collect();
    let valid = vectors.iter().all(|x| x.is_finite())
        && (cosine
            || kappas.iter().zip(vectors.chunks_exact(3)).all(|(&k, a)| {
                k >= 0.0 && k.is_finite() && !(k > 0.0 && a.iter().all(|&x| x == 0.0))
            }));
    let st = if cosine {
        check(
            unsafe { pg_distributions_apply_cosine_product(dist, n, vectors.as_ptr()) },
            "pg_distributions_apply_cosine_product",
        )
    } else {
        check(
            unsafe {
                pg_distributions_apply_lobe_product(dist, n, vectors.as_ptr(), kappas.as_ptr())
            },
            "pg_distributions_apply_lobe_product",
        )
    };
    if dist.is_null() {
        assert_eq!(st, PgStatus::PG_NULL_POINTER, "{}", last_error());
        return;
    }
    if !valid {
        assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT, "{}", last_error());
        return;
    }
    if n > s.held[slot] {
        assert_eq!(st, PgStatus::PG_SIZE_MISMATCH, "{}", last_error());
        return;
    }
    // NASG and DF distributions are refused, stale ones too.
    assert!(
        matches!(
            st,
            PgStatus::PG_OK | PgStatus::PG_STALE | PgStatus::PG_INVALID_ARGUMENT
        ),
        "{st:?}: {}",
        last_error()
    );
    if st == PgStatus::PG_OK && n > 0 {
        let u: Vec<f32> = (0..2 * n).map(|_| r.unit()).collect();
        let mut out = SampleOutputs::new(n);
        let st = check(
            unsafe {
                pg_distributions_sample(
                    dist,
                    n,
                    u.as_ptr(),
                    out.dirs.as_mut_ptr(),
                    out.pdfs.as_mut_ptr(),
                )
            },
            "pg_distributions_sample",
        );
        assert_eq!(st, PgStatus::PG_OK, "{}", last_error());
        out.check("product", st, &u, true);
    }
}

/// `pg_hg_vmf_kappa` and `pg_guides_medium` on arbitrary values: `g` outside `(−1, 1)` or NaN,
/// negative or NaN coefficients and extents are `PG_INVALID_ARGUMENT`; otherwise `κ` is finite
/// and `≥ 0`, the depth is the product (0 if either is 0) and the verdict is `depth ≥
/// PG_MIN_GUIDED_SCATTERING_DEPTH`.
fn op_media_rules(r: &mut ByteReader<'_>) {
    let g = r.c_value();
    let mut kappa = f32::NAN;
    let st = check(unsafe { pg_hg_vmf_kappa(g, &mut kappa) }, "pg_hg_vmf_kappa");
    if g > -1.0 && g < 1.0 {
        assert_eq!(st, PgStatus::PG_OK, "{}", last_error());
        assert!(kappa.is_finite() && kappa >= 0.0, "g {g}: kappa {kappa}");
    } else {
        assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT, "g {g}");
    }
    let (sigma, extent) = (r.c_value(), r.c_value());
    let (mut depth, mut guided) = (f32::NAN, false);
    let st = check(
        unsafe { pg_guides_medium(sigma, extent, &mut depth, &mut guided) },
        "pg_guides_medium",
    );
    if sigma >= 0.0 && extent >= 0.0 {
        assert_eq!(st, PgStatus::PG_OK, "{}", last_error());
        let want = if sigma == 0.0 || extent == 0.0 {
            0.0
        } else {
            sigma * extent
        };
        assert_eq!(depth, want, "sigma {sigma} extent {extent}");
        assert_eq!(guided, depth >= PG_MIN_GUIDED_SCATTERING_DEPTH);
    } else {
        assert_eq!(
            st,
            PgStatus::PG_INVALID_ARGUMENT,
            "sigma {sigma} extent {extent}"
        );
    }
}

fn op_dist_pdf(r: &mut ByteReader<'_>, s: &State, slot: usize, dist: *mut PgDistributions) {
    let n = usize::from(r.byte()) % (MAX_N + 2);
    let (dirs, valid) = directions(r, n);
    let mut pdfs = vec![f32::NAN; n];
    let st = check(
        unsafe { pg_distributions_pdf(dist, n, dirs.as_ptr(), pdfs.as_mut_ptr()) },
        "pg_distributions_pdf",
    );
    expect_size(st, dist, n, s.held[slot], valid);
    if st == PgStatus::PG_OK {
        check_pdfs("distributions", &pdfs);
    }
}

fn op_field_sample(r: &mut ByteReader<'_>, field: *mut PgField) {
    let n = usize::from(r.byte()) % (MAX_N + 1);
    let q: Vec<_> = (0..n).map(|_| r.c_query()).collect();
    let (u, valid_u) = random_numbers(r, 2 * n);
    let mut out = SampleOutputs::new(n);
    let (dirs, pdfs) = (out.dirs.as_mut_ptr(), out.pdfs.as_mut_ptr());
    let st = check(
        unsafe { pg_field_sample(field, n, q.as_ptr(), u.as_ptr(), dirs, pdfs) },
        "pg_field_sample",
    );
    expect_null(st, field.is_null());
    out.check("field", st, &u, valid_u);
}

fn op_field_pdf(r: &mut ByteReader<'_>, field: *mut PgField) {
    let n = usize::from(r.byte()) % (MAX_N + 1);
    let q: Vec<_> = (0..n).map(|_| r.c_query()).collect();
    let (dirs, valid) = directions(r, n);
    let mut pdfs = vec![f32::NAN; n];
    let st = check(
        unsafe { pg_field_pdf(field, n, q.as_ptr(), dirs.as_ptr(), pdfs.as_mut_ptr()) },
        "pg_field_pdf",
    );
    expect_null(st, field.is_null());
    let finite_q = q.iter().all(|q| {
        [q.position, q.normal, q.wo]
            .iter()
            .flatten()
            .chain([&q.roughness])
            .all(|x| x.is_finite())
    });
    if !field.is_null() && valid && finite_q {
        assert_eq!(st, PgStatus::PG_OK, "{}", last_error());
    }
    if st == PgStatus::PG_OK {
        check_pdfs("field", &pdfs);
    }
}

fn op_update(r: &mut ByteReader<'_>, field: *mut PgField) {
    let with_report = r.byte() % 2 == 0;
    let mut report = PgUpdateReport::default();
    let report_ptr = if with_report {
        &mut report as *mut PgUpdateReport
    } else {
        null_mut()
    };
    let st = check(
        unsafe { pg_field_update(field, report_ptr) },
        "pg_field_update",
    );
    expect_null(st, field.is_null());
    if st == PgStatus::PG_OK {
        assert!(report.steps <= 4, "{report:?}");
        assert!(
            report.mean_loss.is_finite() || report.steps == 0,
            "{report:?}"
        );
    }
}

fn op_info(field: *mut PgField) {
    let mut stats = PgFieldStats::default();
    let st = check(
        unsafe { pg_field_stats(field, &mut stats) },
        "pg_field_stats",
    );
    expect_null(st, field.is_null());
    let mut converged = false;
    let st2 = check(
        unsafe { pg_field_is_converged(field, &mut converged) },
        "pg_field_is_converged",
    );
    expect_null(st2, field.is_null());
    if st == PgStatus::PG_OK {
        assert_eq!(stats.converged != 0, converged);
        assert!(stats.buffered_samples <= 64, "{stats:?}");
    }
}

fn op_recorder(r: &mut ByteReader<'_>, s: &mut State, field: *mut PgField, null_handle: bool) {
    let rec = if null_handle { null_mut() } else { s.recorder };
    let null = rec.is_null();
    match r.byte() % 8 {
        0 => {
            unsafe { pg_recorder_release(s.recorder) };
            s.recorder = null_mut();
            if r.byte() % 2 == 0 {
                let mut out = null_mut();
                assert_ok(unsafe { pg_recorder_new(&mut out) }, "recorder new");
                assert!(!out.is_null());
                s.recorder = out;
            }
        }
        1 => expect_null(
            check(unsafe { pg_recorder_start_path(rec) }, "start_path"),
            null,
        ),
        2 | 3 => {
            let v = r.c_vertex();
            expect_null(
                check(unsafe { pg_recorder_add_vertex(rec, &v) }, "add_vertex"),
                null,
            );
        }
        4 => {
            let rgb = [r.c_value(), r.c_value(), r.c_value()];
            let w = r.c_value();
            expect_null(
                check(
                    unsafe { pg_recorder_add_escaped_radiance(rec, rgb.as_ptr(), w) },
                    "escaped",
                ),
                null,
            );
        }
        5 => {
            let mut rgb = [f32::NAN; 3];
            let out = if r.byte() % 2 == 0 {
                null_mut()
            } else {
                rgb.as_mut_ptr()
            };
            expect_null(
                check(unsafe { pg_recorder_end_path(rec, out) }, "end_path"),
                null,
            );
        }
        6 => {
            let mut count = usize::MAX;
            let st = check(
                unsafe { pg_recorder_sample_count(rec, &mut count) },
                "count",
            );
            expect_null(st, null);
            if r.byte() % 2 == 0 {
                let st = check(unsafe { pg_recorder_clear_samples(rec) }, "clear");
                expect_null(st, null);
            }
        }
        _ => {
            let mut count = usize::MAX;
            let st = check(
                unsafe { pg_recorder_flush_into(rec, field, &mut count) },
                "flush_into",
            );
            expect_null(st, null || field.is_null());
        }
    }
}

fn op_save_load(r: &mut ByteReader<'_>, s: &mut State, slot: usize, field: *mut PgField) {
    let st = check(
        unsafe { pg_field_save(field, s.path.as_ptr()) },
        "pg_field_save",
    );
    expect_null(st, field.is_null());
    let path = std::path::PathBuf::from(s.path.to_str().unwrap());
    if st == PgStatus::PG_OK {
        // Corrupt it: overwrite bytes, truncate or append.
        let mut bytes = std::fs::read(&path).unwrap();
        let mode = r.byte();
        for _ in 0..mode % 4 {
            let len = bytes.len().max(1);
            let at = (r.u32() as usize) % len;
            match r.byte() % 4 {
                0 => bytes.truncate(at),
                1 => bytes.push(r.byte()),
                _ => {
                    if let Some(b) = bytes.get_mut(at) {
                        *b ^= r.byte() | 1;
                    }
                }
            }
        }
        std::fs::write(&path, &bytes).unwrap();
    } else if r.byte() % 2 == 0 {
        // Arbitrary bytes in place of a field file.
        let len = usize::from(r.byte());
        let bytes: Vec<u8> = (0..len).map(|_| r.byte()).collect();
        std::fs::write(&path, bytes).unwrap();
    }
    let mut out: *mut PgField = null_mut();
    let st = check(
        unsafe { pg_field_load(s.path.as_ptr(), &mut out) },
        "pg_field_load",
    );
    assert!(
        matches!(st, PgStatus::PG_OK | PgStatus::PG_IO | PgStatus::PG_FORMAT),
        "load: {st:?} {}",
        last_error()
    );
    if st == PgStatus::PG_OK {
        assert!(!out.is_null());
        unsafe { pg_field_release(s.fields[slot]) };
        s.fields[slot] = out;
    } else {
        assert!(out.is_null());
    }
    let _ = std::fs::remove_file(&path);
}

/// Every function with NULL handles (and NULL outputs): `PG_NULL_POINTER`.
fn null_sweep() {
    let nul = PgStatus::PG_NULL_POINTER;
    let path = c"/nonexistent/x";
    let mut f: *mut PgField = std::ptr::dangling_mut();
    let mut n = 0usize;
    let mut b = false;
    let u = [0.5f32; 2];
    let mut o = [0.0f32; 3];
    let q = [PgQueryPoint::default()];
    let sample = PgTrainingSample::default();
    let v = PgPathVertex::default();
    let mut sched: *mut PgSchedule = std::ptr::dangling_mut();
    let sa = schedule_defaults();
    let mut report = PgScheduleReport::default();
    let mut up = PgUpdateReport::default();
    let mut paths = 0u64;
    let mut grid: *mut PgRadianceGrid = std::ptr::dangling_mut();
    let mut window = PgWeightWindow {
        ratio: 5.0,
        max_split: 8,
        min_survival: 0.05,
    };
    let mut decision = PgDecision::default();
    let mut grid_stats = PgRadianceGridStats::default();
    let one = [0.5f32];
    let room = [0u32];
    let mut guide_trial: *mut PgGuideTrial = std::ptr::dangling_mut();
    let mut window_trial: *mut PgWindowTrial = std::ptr::dangling_mut();
    let mut arm = 0;
    let mut verdict = PgTrialVerdict::from(TrialVerdict {
        keep_guide: true,
        evidence: guiding::Verdict::Undecided,
        ratio_low: 0.5,
        ratio_high: 2.0,
        guided_variance: 1.0,
        unguided_variance: 1.0,
        guided_seconds: 1.0,
        unguided_seconds: 1.0,
        cost_ratio: 1.0,
        guided_passes: 4,
        unguided_passes: 4,
        z: 3.0,
        pixels_skipped: 0,
    });
    unsafe {
        let calls: [(PgStatus, &str); 81] = [
            (
                pg_guide_trial_new(1, 1, null(), &mut guide_trial),
                "guide trial image",
            ),
            (
                pg_guide_trial_new(1, 1, o.as_ptr(), null_mut()),
                "guide trial out",
            ),
            (pg_guide_trial_next_arm(null(), &mut arm), "next arm"),
            (pg_guide_trial_next_arm(null(), null_mut()), "next arm out"),
            (
                pg_guide_trial_record(null_mut(), 0, o.as_ptr(), 1.0),
                "guide record",
            ),
            (
                pg_guide_trial_record(null_mut(), 5, null(), f64::NAN),
                "guide record pixels",
            ),
            (pg_guide_trial_restart(null_mut(), 0), "restart"),
            (
                pg_guide_trial_verdict(null(), &mut b, &mut verdict),
                "guide verdict",
            ),
            (
                pg_guide_trial_first_look(null(), &mut b, &mut verdict),
                "first look",
            ),
            (
                pg_trial_verdict_worth_more_training(null(), &mut b),
                "worth more training",
            ),
            (
                pg_trial_verdict_worth_more_training(&verdict, null_mut()),
                "worth more training out",
            ),
            (
                pg_window_trial_new(1, 1, null(), &mut window_trial),
                "window trial image",
            ),
            (
                pg_window_trial_next_pass_uses_window(null(), &mut b),
                "uses window",
            ),
            (pg_window_trial_running(null(), &mut b), "running"),
            (
                pg_window_trial_record(null_mut(), true, o.as_ptr(), 1.0),
                "window record",
            ),
            (
                pg_window_trial_verdict(null(), &mut b, &mut verdict),
                "window verdict",
            ),
            (pg_window_trial_window_pays(null(), &mut b), "window pays"),
            (pg_schedule_look_due(null_mut(), 0.0, 0, &mut b), "look due"),
            (
                pg_schedule_resume_after_look(null_mut(), f64::NAN, 1),
                "resume after look",
            ),
            (pg_weight_window_set_defaults(null_mut()), "window defaults"),
            (
                pg_weight_window_decide(
                    null(),
                    1,
                    o.as_ptr(),
                    o.as_ptr(),
                    one.as_ptr(),
                    one.as_ptr(),
                    room.as_ptr(),
                    &mut decision,
                ),
                "decide",
            ),
            (
                pg_weight_window_decide(
                    &window,
                    1,
                    o.as_ptr(),
                    o.as_ptr(),
                    one.as_ptr(),
                    null(),
                    room.as_ptr(),
                    &mut decision,
                ),
                "decide u",
            ),
            (
                pg_weight_window_decide(
                    &window,
                    1,
                    o.as_ptr(),
                    o.as_ptr(),
                    one.as_ptr(),
                    one.as_ptr(),
                    room.as_ptr(),
                    null_mut(),
                ),
                "decide out",
            ),
            (
                pg_radiance_grid_args_set_defaults(null_mut()),
                "grid defaults",
            ),
            (pg_radiance_grid_new(null(), &mut grid), "grid new"),
            (
                pg_radiance_grid_add(null(), 0, null(), null(), null(), null_mut()),
                "grid add",
            ),
            (
                pg_radiance_grid_estimate(null(), 1, o.as_ptr(), o.as_ptr(), null_mut()),
                "grid estimate",
            ),
            (
                pg_radiance_grid_stats(null(), &mut grid_stats),
                "grid stats",
            ),
            (pg_pixel_estimates(1, 1, null(), 1, 0, null_mut()), "pixels"),
            (
                pg_recorder_keep_reflected(null_mut(), true),
                "keep reflected",
            ),
            (
                pg_recorder_flush_reflected_into(null_mut(), null(), null_mut()),
                "flush reflected",
            ),
            (
                pg_weight_window_set_defaults(null_mut()),
                "window defaults 2",
            ),
            (pg_radiance_grid_new(null(), null_mut()), "grid new out"),
            (pg_field_args_set_defaults(null_mut(), 0), "defaults"),
            (pg_field_new(null(), &mut f), "new"),
            (pg_field_new(null(), null_mut()), "new out"),
            (pg_field_get_args(null(), null_mut()), "get_args"),
            (pg_field_add_samples(null_mut(), &sample, 1), "add"),
            (pg_field_update(null_mut(), null_mut()), "update"),
            (pg_field_is_converged(null(), &mut b), "converged"),
            (pg_field_stop_training(null_mut()), "stop"),
            (pg_field_stats(null(), null_mut()), "stats"),
            (pg_field_save(null(), path.as_ptr()), "save"),
            (pg_field_load(null(), &mut f), "load"),
            (pg_field_load(path.as_ptr(), null_mut()), "load out"),
            (pg_field_query(null(), 1, q.as_ptr(), null_mut()), "query"),
            (
                pg_field_sample(
                    null(),
                    1,
                    q.as_ptr(),
                    u.as_ptr(),
                    o.as_mut_ptr(),
                    null_mut(),
                ),
                "sample",
            ),
            (pg_field_pdf(null(), 0, null(), null(), null_mut()), "pdf"),
            (
                pg_field_selection_probability(null(), 0, null(), null_mut()),
                "selection",
            ),
            (pg_distributions_new(null_mut()), "dist new"),
            (pg_distributions_len(null(), &mut n), "len"),
            (
                pg_distributions_apply_cosine_product(null_mut(), 0, null()),
                "cosine product",
            ),
            (
                pg_distributions_apply_lobe_product(null_mut(), 0, null(), null()),
                "lobe product",
            ),
            (pg_hg_vmf_kappa(0.5, null_mut()), "hg kappa"),
            (
                pg_guides_medium(1.0, 1.0, null_mut(), null_mut()),
                "guides medium",
            ),
            (
                pg_distributions_sample(null(), 0, null(), null_mut(), null_mut()),
                "dist sample",
            ),
            (
                pg_distributions_pdf(null(), 0, null(), null_mut()),
                "dist pdf",
            ),
            (
                pg_distributions_selection_probability(null(), 0, null_mut()),
                "dist sel",
            ),
            (pg_path_vertex_set_defaults(null_mut()), "vertex"),
            (pg_recorder_new(null_mut()), "rec new"),
            (pg_recorder_start_path(null_mut()), "start"),
            (pg_recorder_add_vertex(null_mut(), &v), "add vertex"),
            (
                pg_recorder_add_escaped_radiance(null_mut(), o.as_ptr(), 1.0),
                "escaped",
            ),
            (pg_recorder_end_path(null_mut(), null_mut()), "end"),
            (pg_recorder_sample_count(null(), &mut n), "count"),
            (pg_recorder_clear_samples(null_mut()), "clear"),
            (
                pg_recorder_flush_into(null_mut(), null_mut(), null_mut()),
                "flush",
            ),
            (
                pg_field_sample(null(), 0, null(), null(), null_mut(), null_mut()),
                "s0",
            ),
            (pg_field_query(null(), 0, null(), null_mut()), "q0"),
            (pg_schedule_args_set_defaults(null_mut()), "sched defaults"),
            (pg_schedule_new(null(), &mut sched), "sched new"),
            (pg_schedule_new(&sa, null_mut()), "sched new out"),
            (
                pg_schedule_in_training_phase(null_mut(), 0.0, 0, &mut b),
                "phase",
            ),
            (
                pg_schedule_in_training_phase(null_mut(), f64::NAN, 0, null_mut()),
                "phase NaN",
            ),
            (pg_schedule_end_training(null_mut()), "end training"),
            (pg_schedule_record_traced(null_mut(), -1.0, 1), "traced"),
            (
                pg_schedule_paths_before_update(null(), 0, &mut paths),
                "paths",
            ),
            (pg_schedule_report(null(), &mut report), "report"),
            (
                pg_field_train_scheduled(null_mut(), null_mut(), &mut up),
                "train",
            ),
            (
                pg_field_train_scheduled(null_mut(), null_mut(), null_mut()),
                "train no report",
            ),
            (pg_schedule_report(null(), null_mut()), "report out"),
        ];
        assert!(f.is_null(), "new/load leave *out NULL on failure");
        assert!(grid.is_null(), "pg_radiance_grid_new leaves *out NULL");
        assert_eq!(pg_weight_window_set_defaults(&mut window), PgStatus::PG_OK);
        assert_eq!(window.max_split, 8);
        assert!(
            sched.is_null(),
            "pg_schedule_new leaves *out NULL on failure"
        );
        assert!(guide_trial.is_null() && window_trial.is_null());
        assert_eq!(verdict.ratio_high, 2.0, "outputs untouched");
        for (st, what) in calls {
            // Only the last call's message is kept: check the code here.
            assert_eq!(st, nul, "{what}");
        }
        // A NULL release is a no-op; the message is then "".
        pg_field_release(null_mut());
        pg_distributions_release(null_mut());
        pg_recorder_release(null_mut());
        pg_schedule_release(null_mut());
        pg_radiance_grid_release(null_mut());
        pg_guide_trial_release(null_mut());
        pg_window_trial_release(null_mut());
        check(PgStatus::PG_OK, "release NULL");
    }
}

/// `pg_schedule_args_set_defaults`, checked against the library's defaults.
fn schedule_defaults() -> PgScheduleArgs {
    let mut a = std::mem::MaybeUninit::<PgScheduleArgs>::uninit();
    // SAFETY: set_defaults writes the whole struct.
    let a = unsafe {
        assert_ok(
            pg_schedule_args_set_defaults(a.as_mut_ptr()),
            "schedule defaults",
        );
        a.assume_init()
    };
    let d = guiding::ScheduleOptions::DEFAULT;
    assert_eq!(
        (a.train_fraction, a.first_piece, a.max_epochs),
        (d.train_fraction, d.first_piece, d.max_epochs)
    );
    assert!(a.budget.is_nan());
    a
}

/// Schedule arguments from bytes: valid ones mostly, sometimes unknown
/// codes and any values. `max_epochs` is 1 to 4 or an invalid value (NaN,
/// 0, negative, ∞), so a scheduled update stays cheap.
fn schedule_args(r: &mut ByteReader<'_>) -> PgScheduleArgs {
    let mut a = schedule_defaults();
    let flags = r.byte();
    a.budget_kind = u32::from(flags & 1);
    a.step_rule = u32::from((flags >> 1) & 1);
    a.budget = if a.budget_kind == PG_BUDGET_SPP {
        f64::from(r.byte() % 32)
    } else {
        f64::from(r.unit()) * 4.0
    };
    a.train_fraction = f64::from(r.unit());
    a.step_value = if a.step_rule == PG_STEP_RULE_EPOCHS {
        f64::from(1 + r.byte() % 4)
    } else {
        0.05 + 0.9 * f64::from(r.unit())
    };
    a.max_epochs = f64::from(1 + r.byte() % 4);
    if flags & 4 != 0 {
        // Any value where any value is allowed to be tried.
        a.budget = f64::from(r.c_value()) * 64.0;
        a.train_fraction = f64::from(r.c_value());
        a.step_value = f64::from(r.c_value());
        a.update_interval = f64::from(r.c_value());
        a.first_piece = f64::from(r.c_value());
    }
    if flags & 8 != 0 {
        a.max_epochs = [f64::NAN, 0.0, -1.0, f64::INFINITY][usize::from(r.byte() % 4)];
    }
    if flags & 16 != 0 {
        a.budget_kind = 2 + u32::from(r.byte());
    }
    if flags & 32 != 0 {
        a.step_rule = 2 + u32::from(r.byte());
    }
    a
}

/// Whether `pg_schedule_new` must accept `a` (the documented ranges).
fn schedule_args_valid(a: &PgScheduleArgs) -> bool {
    let budget = match a.budget_kind {
        PG_BUDGET_SECONDS => a.budget.is_finite() && a.budget >= 0.0,
        PG_BUDGET_SPP => {
            a.budget >= 0.0 && a.budget <= f64::from(u32::MAX) && a.budget.fract() == 0.0
        }
        _ => false,
    };
    let steps = match a.step_rule {
        PG_STEP_RULE_TIME_SHARE => a.step_value > 0.0 && a.step_value < 1.0,
        PG_STEP_RULE_EPOCHS => a.step_value.is_finite() && a.step_value > 0.0,
        _ => false,
    };
    budget
        && steps
        && (0.0..=1.0).contains(&a.train_fraction)
        && a.update_interval.is_finite()
        && a.update_interval > 0.0
        && a.first_piece > 0.0
        && a.first_piece <= 1.0
        && a.max_epochs.is_finite()
        && a.max_epochs > 0.0
}

/// The schedule's report, checked: counts and seconds add up.
fn schedule_report(schedule: *mut PgSchedule) -> Option<PgScheduleReport> {
    if schedule.is_null() {
        return None;
    }
    let mut r = PgScheduleReport::default();
    assert_ok(unsafe { pg_schedule_report(schedule, &mut r) }, "report");
    assert!(r.traced_seconds >= 0.0 && r.trained_seconds >= 0.0, "{r:?}");
    assert!(r.training_over <= 1 && r.pad == 0, "{r:?}");
    if r.steps == 0 || r.trained_seconds == 0.0 {
        assert!(r.seconds_per_step.is_nan(), "{r:?}");
    } else {
        assert!(r.seconds_per_step > 0.0, "{r:?}");
    }
    let share = r.training_share;
    assert!(share.is_nan() || (0.0..=1.0).contains(&share), "{r:?}");
    Some(r)
}

fn op_schedule(r: &mut ByteReader<'_>, s: &mut State, null_handle: bool) {
    let sched = if null_handle { null_mut() } else { s.schedule };
    let null = sched.is_null();
    // SAFETY (all calls): the handle is NULL or live (the slot is cleared on
    // release), outputs are locals or NULL.
    match r.byte() % 10 {
        0 | 1 => {
            let a = schedule_args(r);
            let null_out = r.byte() % 16 == 0;
            let mut out: *mut PgSchedule = std::ptr::dangling_mut();
            let out_ptr = if null_out {
                null_mut()
            } else {
                &mut out as *mut *mut PgSchedule
            };
            let st = check(unsafe { pg_schedule_new(&a, out_ptr) }, "pg_schedule_new");
            if null_out {
                assert_eq!(st, PgStatus::PG_NULL_POINTER);
                return;
            }
            let valid = schedule_args_valid(&a);
            assert_eq!(st == PgStatus::PG_OK, valid, "{a:?}: {}", last_error());
            if st == PgStatus::PG_OK {
                assert!(!out.is_null());
                unsafe { pg_schedule_release(s.schedule) };
                s.schedule = out;
                s.looks = 0;
                let rep = schedule_report(out).unwrap();
                assert_eq!((rep.steps, rep.updates, rep.training_over), (0, 0, 0));
            } else {
                assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT);
                assert!(out.is_null(), "out not NULL on failure");
            }
        }
        2 => {
            unsafe { pg_schedule_release(s.schedule) };
            check(PgStatus::PG_OK, "pg_schedule_release");
            s.schedule = null_mut();
        }
        3 => {
            let elapsed = f64::from(r.c_value()) * 4.0;
            let pass = u32::from(r.byte());
            let mut flag = false;
            let out = if r.byte() % 16 == 0 {
                null_mut()
            } else {
                &mut flag as *mut bool
            };
            let st = check(
                unsafe { pg_schedule_in_training_phase(sched, elapsed, pass, out) },
                "pg_schedule_in_training_phase",
            );
            expect_null(st, null || out.is_null());
            if !null && !out.is_null() {
                let valid = elapsed.is_finite() && elapsed >= 0.0;
                assert_eq!(st == PgStatus::PG_OK, valid, "elapsed {elapsed}");
            }
            if st == PgStatus::PG_OK {
                let over = schedule_report(sched).unwrap().training_over == 1;
                assert_eq!(flag, !over);
            }
        }
        4 => {
            let st = check(
                unsafe { pg_schedule_end_training(sched) },
                "pg_schedule_end_training",
            );
            expect_null(st, null);
            if st == PgStatus::PG_OK {
                assert_eq!(schedule_report(sched).unwrap().training_over, 1);
            }
        }
        5 => {
            let seconds = f64::from(r.c_value());
            let paths = u64::from(r.u32());
            let before = schedule_report(sched);
            let st = check(
                unsafe { pg_schedule_record_traced(sched, seconds, paths) },
                "pg_schedule_record_traced",
            );
            expect_null(st, null);
            if let Some(before) = before {
                let valid = seconds.is_finite() && seconds >= 0.0;
                assert_eq!(st == PgStatus::PG_OK, valid, "seconds {seconds}");
                let after = schedule_report(sched).unwrap();
                let want = if valid {
                    before.traced_seconds + seconds
                } else {
                    before.traced_seconds
                };
                assert_eq!(after.traced_seconds, want);
            }
        }
        6 => {
            let pass_paths = u64::from(r.u32() >> (r.byte() % 32));
            let mut out = 0u64;
            let out_ptr = if r.byte() % 16 == 0 {
                null_mut()
            } else {
                &mut out as *mut u64
            };
            let st = check(
                unsafe { pg_schedule_paths_before_update(sched, pass_paths, out_ptr) },
                "pg_schedule_paths_before_update",
            );
            expect_null(st, null || out_ptr.is_null());
            if !null && !out_ptr.is_null() {
                assert_eq!(st == PgStatus::PG_OK, pass_paths > 0);
            }
            if st == PgStatus::PG_OK {
                assert!((1..=pass_paths).contains(&out), "{out} of {pass_paths}");
            }
        }
        8 => {
            // The early look: due at most three times (once per quarter), never once the
            // phase is over or before EARLY_LOOK_MIN_STEPS steps.
            let elapsed = f64::from(r.c_value()) * 4.0;
            let pass = u32::from(r.byte());
            let mut due = false;
            let out = if r.byte() % 16 == 15 {
                null_mut()
            } else {
                &mut due as *mut bool
            };
            let before = schedule_report(sched);
            let st = check(
                unsafe { pg_schedule_look_due(sched, elapsed, pass, out) },
                "pg_schedule_look_due",
            );
            expect_null(st, null || out.is_null());
            if !null && !out.is_null() {
                let valid = elapsed.is_finite() && elapsed >= 0.0;
                assert_eq!(st == PgStatus::PG_OK, valid, "elapsed {elapsed}");
            }
            if st == PgStatus::PG_OK && due {
                let before = before.unwrap();
                assert!(s.looks < 3, "a fourth look was due");
                assert_eq!(before.training_over, 0, "a look after the phase");
                assert!(before.steps >= guiding::EARLY_LOOK_MIN_STEPS, "{before:?}");
                s.looks += 1;
            }
        }
        9 => {
            let seconds = f64::from(r.c_value()) * 4.0;
            let passes = u32::from(r.byte());
            let st = check(
                unsafe { pg_schedule_resume_after_look(sched, seconds, passes) },
                "pg_schedule_resume_after_look",
            );
            expect_null(st, null);
            if !null {
                let valid = seconds.is_finite() && seconds >= 0.0;
                assert_eq!(st == PgStatus::PG_OK, valid, "seconds {seconds}");
            }
        }
        _ => {
            let mut rep = PgScheduleReport::default();
            let st = check(
                unsafe { pg_schedule_report(sched, &mut rep) },
                "pg_schedule_report",
            );
            expect_null(st, null);
            let _ = schedule_report(sched);
        }
    }
}

fn op_train_scheduled(r: &mut ByteReader<'_>, s: &State, field: *mut PgField, null_handle: bool) {
    let sched = if null_handle { null_mut() } else { s.schedule };
    let with_report = r.byte() % 4 != 0;
    let mut report = PgUpdateReport::default();
    let report_ptr = if with_report {
        &mut report as *mut PgUpdateReport
    } else {
        null_mut()
    };
    let before = schedule_report(sched);
    let st = check(
        unsafe { pg_field_train_scheduled(field, sched, report_ptr) },
        "pg_field_train_scheduled",
    );
    expect_null(st, field.is_null() || sched.is_null());
    if st != PgStatus::PG_OK {
        return;
    }
    let (before, after) = (before.unwrap(), schedule_report(sched).unwrap());
    // Whatever ran was recorded; at most 4 epochs of at most 64 samples.
    assert!(after.steps - before.steps <= 4 * 64, "{after:?}");
    assert!(after.updates - before.updates <= 1);
    if with_report {
        assert_eq!(
            u64::from(report.steps),
            after.steps - before.steps,
            "{report:?}"
        );
        assert!(report.buffered_samples <= 64, "{report:?}");
        assert!(
            report.mean_loss.is_finite() || report.steps == 0,
            "{report:?}"
        );
    }
}

/// Rec. 709 luminance (the library's, written out).
fn luminance(c: &[f32]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// Roulette and splitting: `pg_weight_window_decide` with any settings, throughputs,
/// estimates, pixels, `u` and room; the radiance grid's new (any box and options), add,
/// estimate, stats and release; a recorder's reflected radiance into it; pixel estimates of
/// small images with any sums.
fn op_roulette(r: &mut ByteReader<'_>, s: &mut State, null_handle: bool) {
    let grid = if null_handle { null_mut() } else { s.grid };
    match r.byte() % 6 {
        0 => {
            let mut w = PgWeightWindow {
                ratio: 0.0,
                max_split: 0,
                min_survival: 0.0,
            };
            assert_ok(unsafe { pg_weight_window_set_defaults(&mut w) }, "window");
            if r.byte() % 2 == 0 {
                w.ratio = r.c_value() * 10.0;
                w.max_split = u32::from(r.byte() % 12);
                w.min_survival = r.c_value();
            }
            let valid = w.ratio.is_finite()
                && w.ratio > 1.0
                && w.max_split >= 1
                && w.min_survival > 0.0
                && w.min_survival <= 1.0;
            let n = usize::from(r.byte()) % (MAX_N + 1);
            let beta: Vec<f32> = (0..3 * n).map(|_| r.c_value() * 4.0).collect();
            let radiance: Vec<f32> = (0..3 * n).map(|_| r.c_value() * 4.0).collect();
            let pixel: Vec<f32> = (0..n).map(|_| r.c_value()).collect();
            let (u, valid_u) = random_numbers(r, n);
            let room: Vec<u32> = (0..n).map(|_| u32::from(r.byte()) % 20).collect();
            let mut out = vec![PgDecision::default(); n];
            let st = check(
                unsafe {
                    pg_weight_window_decide(
                        &w,
                        n,
                        beta.as_ptr(),
                        radiance.as_ptr(),
                        pixel.as_ptr(),
                        u.as_ptr(),
                        room.as_ptr(),
                        out.as_mut_ptr(),
                    )
                },
                "pg_weight_window_decide",
            );
            let u_ok = u.iter().all(|x| (0.0..=1.0).contains(x));
            assert_eq!(
                st == PgStatus::PG_OK,
                valid && u_ok,
                "{st:?} {w:?} {u:?} {valid_u}"
            );
            if st != PgStatus::PG_OK {
                return;
            }
            for (i, d) in out.iter().enumerate() {
                let y = luminance(&beta[3 * i..3 * i + 3]);
                if !(y.is_finite() && y > 0.0) {
                    assert_eq!(d.count, 0, "dead path {i}: {d:?}");
                    continue;
                }
                match d.count {
                    0 => {}
                    1 => assert!(
                        d.weight.is_finite()
                            && d.weight >= 1.0
                            && d.weight <= 1.0 / w.min_survival * 1.0001
                            || d.weight == 1.0,
                        "{d:?} {w:?}"
                    ),
                    k => {
                        assert!(
                            k <= w.max_split && k <= room[i] + 1,
                            "{d:?} room {}",
                            room[i]
                        );
                        assert_eq!(d.weight, 1.0 / k as f32, "{d:?}");
                    }
                }
            }
        }
        1 => {
            // A fresh or released grid, over any box with any options.
            unsafe { pg_radiance_grid_release(s.grid) };
            s.grid = null_mut();
            s.grid_offered = 0;
            if r.byte() % 4 == 0 {
                return;
            }
            let mut a = PgRadianceGridArgs {
                bounds_min: [0.0; 3],
                bounds_max: [0.0; 3],
                resolution: 0,
                coarse_resolution: 0,
                prior_weight: 0,
            };
            assert_ok(
                unsafe { pg_radiance_grid_args_set_defaults(&mut a) },
                "grid args",
            );
            a.bounds_min = r.c_position();
            a.bounds_max = r.c_position();
            if r.byte() % 2 == 0 {
                a.resolution = u32::from(r.byte() % 40);
                a.coarse_resolution = u32::from(r.byte() % 10);
                a.prior_weight = u32::from(r.byte() % 20);
            }
            let valid = (0..3).all(|k| {
                a.bounds_min[k].is_finite()
                    && a.bounds_max[k].is_finite()
                    && a.bounds_min[k] <= a.bounds_max[k]
            }) && a.resolution > 0
                && a.coarse_resolution > 0
                && a.prior_weight > 0;
            let mut g = std::ptr::dangling_mut();
            let st = check(
                unsafe { pg_radiance_grid_new(&a, &mut g) },
                "pg_radiance_grid_new",
            );
            assert_eq!(st == PgStatus::PG_OK, valid, "{st:?} {a:?}");
            assert_eq!(g.is_null(), !valid);
            s.grid = g;
        }
        2 => {
            let n = usize::from(r.byte()) % (MAX_N + 1);
            let pos: Vec<f32> = (0..n).flat_map(|_| r.c_position()).collect();
            let nrm: Vec<f32> = (0..n).flat_map(|_| r.c_dir3()).collect();
            let rad: Vec<f32> = (0..3 * n).map(|_| r.c_value()).collect();
            let mut kept = u64::MAX;
            let st = check(
                unsafe {
                    pg_radiance_grid_add(
                        grid,
                        n,
                        pos.as_ptr(),
                        nrm.as_ptr(),
                        rad.as_ptr(),
                        &mut kept,
                    )
                },
                "pg_radiance_grid_add",
            );
            expect_null(st, grid.is_null());
            if st == PgStatus::PG_OK {
                let good = (0..n)
                    .filter(|&i| {
                        pos[3 * i..3 * i + 3].iter().all(|x| x.is_finite())
                            && rad[3 * i..3 * i + 3]
                                .iter()
                                .all(|x| x.is_finite() && *x >= 0.0)
                    })
                    .count();
                assert_eq!(kept, good as u64);
                s.grid_offered += n as u64;
            }
        }
        3 => {
            let n = usize::from(r.byte()) % (MAX_N + 1);
            let pos: Vec<f32> = (0..n).flat_map(|_| r.c_position()).collect();
            let nrm: Vec<f32> = (0..n).flat_map(|_| r.c_dir3()).collect();
            let mut out = vec![f32::NAN; 3 * n];
            let st = check(
                unsafe {
                    pg_radiance_grid_estimate(grid, n, pos.as_ptr(), nrm.as_ptr(), out.as_mut_ptr())
                },
                "pg_radiance_grid_estimate",
            );
            expect_null(st, grid.is_null());
            if st == PgStatus::PG_OK {
                for e in out.chunks_exact(3) {
                    assert!(
                        e == [-1.0; 3] || e.iter().all(|x| x.is_finite() && *x >= 0.0),
                        "{e:?}"
                    );
                }
            }
            let mut stats = PgRadianceGridStats::default();
            let st = check(
                unsafe { pg_radiance_grid_stats(grid, &mut stats) },
                "grid stats",
            );
            expect_null(st, grid.is_null());
            if st == PgStatus::PG_OK {
                assert_eq!(stats.samples + stats.rejected, s.grid_offered, "{stats:?}");
            }
        }
        4 => {
            // The recorder's reflected radiance into the grid.
            let rec = if null_handle { null_mut() } else { s.recorder };
            let keep = r.byte() % 4 != 0;
            let st = check(
                unsafe { pg_recorder_keep_reflected(rec, keep) },
                "keep_reflected",
            );
            expect_null(st, rec.is_null());
            let mut count = u64::MAX;
            let st = check(
                unsafe { pg_recorder_flush_reflected_into(rec, grid, &mut count) },
                "flush_reflected_into",
            );
            expect_null(st, rec.is_null() || grid.is_null());
            if st == PgStatus::PG_OK {
                // The grid counts what it kept and refused alike; re-read its total.
                let mut stats = PgRadianceGridStats::default();
                assert_ok(unsafe { pg_radiance_grid_stats(grid, &mut stats) }, "stats");
                assert!(stats.samples + stats.rejected >= s.grid_offered + count);
                s.grid_offered = stats.samples + stats.rejected;
            }
        }
        _ => {
            let (w, h) = (u32::from(r.byte() % 5), u32::from(r.byte() % 5));
            let n = (w * h) as usize;
            let sum: Vec<f64> = (0..3 * n).map(|_| f64::from(r.c_value()) * 8.0).collect();
            let passes = u32::from(r.byte() % 4);
            let radius = if r.byte() % 8 == 0 {
                u32::MAX
            } else {
                u32::from(r.byte() % 4)
            };
            let mut out = vec![f32::NAN; n];
            let st = check(
                unsafe { pg_pixel_estimates(w, h, sum.as_ptr(), passes, radius, out.as_mut_ptr()) },
                "pg_pixel_estimates",
            );
            assert_eq!(st, PgStatus::PG_OK);
            assert!(out.iter().all(|x| x.is_finite()), "{out:?}");
            if passes == 0 {
                assert!(out.iter().all(|&x| x == 0.0));
            }
        }
    }
}

/// A deterministic LCG (Knuth's MMIX constants) for the trials' synthetic images.
struct Lcg(u64);

impl Lcg {
    /// Uniform in `(0, 1)`.
    fn uniform(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((self.0 >> 40) as f32 + 0.5) / (1u64 << 24) as f32
    }
}

/// A trial image of `pixels` pixels: `mean` plus uniform noise of standard deviation `sd`
/// per channel (an LCG seeded by `seed`), sometimes with a few arbitrary values (NaN,
/// infinities, negative, huge).
fn trial_image(
    r: &mut ByteReader<'_>,
    pixels: usize,
    mean: f32,
    sd: f32,
    seed: u64,
) -> Vec<[f32; 3]> {
    let mut lcg = Lcg(seed);
    let half_width = sd * 3f32.sqrt();
    let mut image: Vec<[f32; 3]> = (0..pixels)
        .map(|_| [(); 3].map(|()| mean + half_width * (2.0 * lcg.uniform() - 1.0)))
        .collect();
    if pixels > 0 && r.byte() % 4 == 3 {
        for _ in 0..=r.byte() % 3 {
            let p = usize::from(r.byte()) % pixels;
            image[p][usize::from(r.byte() % 3)] = r.c_value() * 1e3;
        }
    }
    image
}

/// Seconds of a trial pass: mostly 0.05 to 0.75, sometimes NaN, infinite, negative, zero or
/// huge.
fn trial_seconds(r: &mut ByteReader<'_>) -> f64 {
    let b = r.byte();
    if b % 16 == 15 {
        [
            f64::NAN,
            -1.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -0.0,
            0.0,
            1e300,
            f64::MIN_POSITIVE,
        ][usize::from(b >> 5)]
    } else {
        0.05 * f64::from(1 + b % 15)
    }
}

fn arm_code(arm: Option<TrialArm>) -> PgTrialArm {
    match arm {
        Some(TrialArm::Guided) => PG_TRIAL_ARM_GUIDED,
        Some(TrialArm::Unguided) => PG_TRIAL_ARM_UNGUIDED,
        None => PG_TRIAL_ARM_NONE,
    }
}

fn arm_of(code: PgTrialArm) -> Option<TrialArm> {
    match code {
        PG_TRIAL_ARM_GUIDED => Some(TrialArm::Guided),
        PG_TRIAL_ARM_UNGUIDED => Some(TrialArm::Unguided),
        _ => None,
    }
}

/// Whether the C verdict is the Rust one, field for field (floats to the bit).
fn same_verdict(c: &PgTrialVerdict, r: &TrialVerdict) -> bool {
    let w = PgTrialVerdict::from(*r);
    let floats = |v: &PgTrialVerdict| {
        [
            v.ratio_low,
            v.ratio_high,
            v.guided_variance,
            v.unguided_variance,
            v.guided_seconds,
            v.unguided_seconds,
            v.cost_ratio,
            v.z,
        ]
        .map(f64::to_bits)
    };
    let ints = |v: &PgTrialVerdict| {
        (
            v.keep_guide,
            v.evidence,
            v.guided_passes,
            v.unguided_passes,
            v.pixels_skipped,
        )
    };
    let code = match r.evidence {
        guiding::Verdict::Undecided => PG_EVIDENCE_UNDECIDED,
        guiding::Verdict::Pays => PG_EVIDENCE_PAYS,
        guiding::Verdict::DoesNotPay => PG_EVIDENCE_DOES_NOT_PAY,
    };
    floats(c) == floats(&w)
        && ints(c) == ints(&w)
        && c.evidence == code
        && c.keep_guide == u32::from(r.keep_guide)
}

/// A verdict getter of a trial (`pg_guide_trial_verdict`, `_first_look`,
/// `pg_window_trial_verdict`), checked: `None` when it says there is none, and then its
/// output is untouched.
fn c_verdict<T>(
    get: unsafe extern "C" fn(*const T, *mut bool, *mut PgTrialVerdict) -> PgStatus,
    trial: *const T,
    what: &str,
) -> Option<PgTrialVerdict> {
    let mut has = true;
    let mut v = std::mem::MaybeUninit::<PgTrialVerdict>::zeroed();
    // SAFETY: a live handle; valid outputs.
    assert_ok(unsafe { get(trial, &mut has, v.as_mut_ptr()) }, what);
    // SAFETY: zeroed, then written whole or not at all: all-zero is a valid verdict.
    let v = unsafe { v.assume_init() };
    if !has {
        assert_eq!(v.evidence, 0, "{what}: output written without a verdict");
        assert_eq!(v.z.to_bits(), 0, "{what}: output written without a verdict");
    }
    has.then_some(v)
}

/// The C rules on `v` (`pg_trial_verdict_worth_more_training`, `pg_window_trial_window_pays`)
/// are the Rust ones on the same fields; an unknown evidence code is refused by both.
fn check_verdict_rules(v: &PgTrialVerdict) {
    let (mut worth, mut pays) = (false, false);
    let st_worth = check(
        unsafe { pg_trial_verdict_worth_more_training(v, &mut worth) },
        "pg_trial_verdict_worth_more_training",
    );
    let st_pays = check(
        unsafe { pg_window_trial_window_pays(v, &mut pays) },
        "pg_window_trial_window_pays",
    );
    let evidence = match v.evidence {
        PG_EVIDENCE_UNDECIDED => guiding::Verdict::Undecided,
        PG_EVIDENCE_PAYS => guiding::Verdict::Pays,
        PG_EVIDENCE_DOES_NOT_PAY => guiding::Verdict::DoesNotPay,
        _ => {
            assert_eq!(st_worth, PgStatus::PG_INVALID_ARGUMENT, "{v:?}");
            assert_eq!(st_pays, PgStatus::PG_INVALID_ARGUMENT, "{v:?}");
            return;
        }
    };
    assert_eq!((st_worth, st_pays), (PgStatus::PG_OK, PgStatus::PG_OK));
    let rust = TrialVerdict {
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
    };
    assert_eq!(worth, rust.worth_more_training(), "{v:?}");
    assert_eq!(pays, WindowTrial::window_pays(&rust), "{v:?}");
}

/// The live trials answer as their Rust twins: next arm, window order, running, verdicts
/// and first looks (and the rules on them).
fn check_trials(s: &State) {
    if let Some(twin) = &s.guide_twin {
        let t = s.guide_trial;
        let mut arm = 99;
        assert_ok(unsafe { pg_guide_trial_next_arm(t, &mut arm) }, "next arm");
        assert_eq!(arm, arm_code(twin.next_arm()));
        let verdicts = [
            (
                c_verdict(pg_guide_trial_verdict, t, "verdict"),
                twin.verdict(),
                "verdict",
            ),
            (
                c_verdict(pg_guide_trial_first_look, t, "first look"),
                twin.first_look(),
                "first look",
            ),
        ];
        for (got, want, what) in verdicts {
            assert_eq!(got.is_some(), want.is_some(), "{what}: {got:?} {want:?}");
            if let (Some(c), Some(r)) = (got, want) {
                assert!(same_verdict(&c, &r), "{what}: {c:?} {r:?}");
                check_verdict_rules(&c);
            }
        }
    }
    if let Some(twin) = &s.window_twin {
        let t = s.window_trial;
        let (mut on, mut running) = (false, false);
        assert_ok(
            unsafe { pg_window_trial_next_pass_uses_window(t, &mut on) },
            "uses window",
        );
        assert_ok(
            unsafe { pg_window_trial_running(t, &mut running) },
            "running",
        );
        assert_eq!(
            (on, running),
            (twin.next_pass_uses_window(), twin.running())
        );
        let got = c_verdict(pg_window_trial_verdict, t, "window verdict");
        let want = twin.verdict();
        assert_eq!(got.is_some(), want.is_some(), "{got:?} {want:?}");
        assert_eq!(running, want.is_none());
        if let (Some(c), Some(r)) = (got, want) {
            assert!(same_verdict(&c, &r), "{c:?} {r:?}");
            check_verdict_rules(&c);
        }
    }
}

/// Efficiency trials: `PgGuideTrial` and `PgWindowTrial` new (images of up to 6 × 6 pixels,
/// none, or NULL; any values), release, record (the arm the trial asks for, the other one or
/// an unknown code; passes of any noise, some values arbitrary, NULL pixels; seconds of any
/// value; before and after a verdict), restart, verdicts and first looks (NULL and
/// overlapping outputs), and the verdict rules on arbitrary verdicts. Each live C trial has a
/// Rust twin fed the same calls: the statuses, arms and verdicts must agree.
fn op_trials(r: &mut ByteReader<'_>, s: &mut State, null_handle: bool) {
    let guide = if null_handle {
        null_mut()
    } else {
        s.guide_trial
    };
    let window = if null_handle {
        null_mut()
    } else {
        s.window_trial
    };
    // SAFETY (all calls): handles are NULL or live (slots are cleared on release), arrays are
    // locals of the trial's size or NULL, outputs are locals or NULL.
    match r.byte() % 8 {
        b @ (0 | 1) => op_new_trial(r, s, b == 1),
        2 => {
            if r.byte() % 2 == 0 {
                unsafe { pg_guide_trial_release(s.guide_trial) };
                s.guide_trial = null_mut();
                s.guide_twin = None;
            } else {
                unsafe { pg_window_trial_release(s.window_trial) };
                s.window_trial = null_mut();
                s.window_twin = None;
            }
            check(PgStatus::PG_OK, "trial release");
        }
        3 => {
            let next = s.guide_twin.as_ref().and_then(GuideTrial::next_arm);
            let b = r.byte();
            let code = match b % 8 {
                6 => arm_code(Some(match next {
                    Some(TrialArm::Guided) => TrialArm::Unguided,
                    _ => TrialArm::Guided,
                })),
                7 => [PG_TRIAL_ARM_NONE, 2, i32::MIN, i32::MAX][usize::from(b >> 6)],
                _ => arm_code(Some(next.unwrap_or(TrialArm::Guided))),
            };
            let pixels = if s.guide_twin.is_some() {
                s.guide_pixels
            } else {
                0
            };
            let (pass, null_pixels, seconds) = trial_pass(r, s, pixels);
            let st = check(
                unsafe {
                    pg_guide_trial_record(
                        guide,
                        code,
                        ptr_or_null(&pass, null_pixels).cast(),
                        seconds,
                    )
                },
                "pg_guide_trial_record",
            );
            expect_null(st, guide.is_null() || null_pixels);
            if guide.is_null() || null_pixels {
                return check_trials(s);
            }
            let twin = s.guide_twin.as_mut().unwrap();
            let want = arm_of(code).is_some_and(|arm| twin.record(arm, &pass, seconds).is_ok());
            assert_eq!(
                st == PgStatus::PG_OK,
                want,
                "{st:?} arm {code}, {seconds} s"
            );
            if !want {
                assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT);
            }
        }
        4 => {
            let next = s
                .window_twin
                .as_ref()
                .is_some_and(WindowTrial::next_pass_uses_window);
            let with_window = next != (r.byte() % 8 == 7);
            let pixels = if s.window_twin.is_some() {
                s.window_pixels
            } else {
                0
            };
            let (pass, null_pixels, seconds) = trial_pass(r, s, pixels);
            let st = check(
                unsafe {
                    pg_window_trial_record(
                        window,
                        with_window,
                        ptr_or_null(&pass, null_pixels).cast(),
                        seconds,
                    )
                },
                "pg_window_trial_record",
            );
            expect_null(st, window.is_null() || null_pixels);
            if window.is_null() || null_pixels {
                return check_trials(s);
            }
            let twin = s.window_twin.as_mut().unwrap();
            let want = twin.record(with_window, &pass, seconds).is_ok();
            assert_eq!(
                st == PgStatus::PG_OK,
                want,
                "{st:?} window {with_window}, {seconds} s"
            );
            if !want {
                assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT);
            }
        }
        5 => {
            let code = [
                PG_TRIAL_ARM_GUIDED,
                PG_TRIAL_ARM_UNGUIDED,
                2,
                PG_TRIAL_ARM_NONE,
            ][usize::from(r.byte() % 4)];
            let st = check(
                unsafe { pg_guide_trial_restart(guide, code) },
                "pg_guide_trial_restart",
            );
            expect_null(st, guide.is_null());
            if guide.is_null() {
                return check_trials(s);
            }
            match arm_of(code) {
                Some(arm) => {
                    assert_eq!(st, PgStatus::PG_OK);
                    s.guide_twin.as_mut().unwrap().restart(arm);
                }
                None => assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT),
            }
        }
        6 => {
            // Verdict getters with NULL or overlapping outputs: refused, nothing written.
            let b = r.byte();
            let mut buffer = PgTrialVerdict::from(TrialVerdict {
                keep_guide: false,
                evidence: guiding::Verdict::DoesNotPay,
                ratio_low: 1.5,
                ratio_high: 2.5,
                guided_variance: 1.0,
                unguided_variance: 1.0,
                guided_seconds: 1.0,
                unguided_seconds: 1.0,
                cost_ratio: 2.0,
                guided_passes: 2,
                unguided_passes: 2,
                z: 3.0,
                pixels_skipped: 0,
            });
            let before = buffer;
            let mut has = false;
            let buffer_ptr = &mut buffer as *mut PgTrialVerdict;
            let (has_ptr, out_ptr, want) = match b % 4 {
                0 => (null_mut(), buffer_ptr, PgStatus::PG_NULL_POINTER),
                1 => (&mut has as *mut bool, null_mut(), PgStatus::PG_NULL_POINTER),
                _ => (
                    buffer_ptr
                        .cast::<bool>()
                        .wrapping_add(usize::from(b >> 2) % 88),
                    buffer_ptr,
                    PgStatus::PG_INVALID_ARGUMENT,
                ),
            };
            let sts = [
                check(
                    unsafe { pg_guide_trial_verdict(guide, has_ptr, out_ptr) },
                    "pg_guide_trial_verdict",
                ),
                check(
                    unsafe { pg_guide_trial_first_look(guide, has_ptr, out_ptr) },
                    "pg_guide_trial_first_look",
                ),
                check(
                    unsafe { pg_window_trial_verdict(window, has_ptr, out_ptr) },
                    "pg_window_trial_verdict",
                ),
            ];
            for (st, handle) in
                sts.into_iter()
                    .zip([guide.is_null(), guide.is_null(), window.is_null()])
            {
                let want = if handle {
                    PgStatus::PG_NULL_POINTER
                } else {
                    want
                };
                assert_eq!(st, want, "{}", last_error());
            }
            // The rules with NULL or overlapping arguments.
            let inside = buffer_ptr
                .cast::<bool>()
                .wrapping_add(usize::from(b >> 2) % 88);
            for (verdict, out, want) in [
                (null(), &mut has as *mut bool, PgStatus::PG_NULL_POINTER),
                (
                    buffer_ptr.cast_const(),
                    null_mut(),
                    PgStatus::PG_NULL_POINTER,
                ),
                (
                    buffer_ptr.cast_const(),
                    inside,
                    PgStatus::PG_INVALID_ARGUMENT,
                ),
            ] {
                let st = check(
                    unsafe { pg_trial_verdict_worth_more_training(verdict, out) },
                    "pg_trial_verdict_worth_more_training",
                );
                assert_eq!(st, want, "{}", last_error());
                let st = check(
                    unsafe { pg_window_trial_window_pays(verdict, out) },
                    "pg_window_trial_window_pays",
                );
                assert_eq!(st, want, "{}", last_error());
            }
            assert_eq!(buffer, before, "outputs untouched");
        }
        _ => {
            // The rules on any verdict: any evidence code (3 is unknown), any interval.
            let v = PgTrialVerdict {
                keep_guide: u32::from(r.byte()),
                evidence: u32::from(r.byte() % 4),
                ratio_low: f64::from(r.c_value()) * 2.0,
                ratio_high: f64::from(r.c_value()) * 2.0,
                guided_variance: f64::from(r.c_value()),
                unguided_variance: f64::from(r.c_value()),
                guided_seconds: 1.0,
                unguided_seconds: 1.0,
                cost_ratio: f64::from(r.c_value()) * 2.0,
                guided_passes: u32::from(r.byte()),
                unguided_passes: u32::from(r.byte()),
                z: 3.0,
                pixels_skipped: u64::from(r.byte()),
            };
            check_verdict_rules(&v);
        }
    }
    check_trials(s);
}

/// `pg_guide_trial_new` or (`window`) `pg_window_trial_new` on an image of up to 6 × 6 pixels
/// (none is refused), any values, or NULL, into a NULL or valid `out`; a new trial replaces
/// the slot's, with its Rust twin made from the same image.
fn op_new_trial(r: &mut ByteReader<'_>, s: &mut State, window: bool) {
    let (w, h) = (u32::from(r.byte() % 7), u32::from(r.byte() % 7));
    let pixels = (w * h) as usize;
    let seed = u64::from(r.u32());
    let image = trial_image(r, pixels, 1.0, 0.3, seed);
    let flags = r.byte();
    let null_image = pixels > 0 && flags % 16 == 15;
    let null_out = flags >> 4 == 15;
    let image_ptr = ptr_or_null(&image, null_image).cast::<f32>();
    let (w_us, h_us, options) = (w as usize, h as usize, TrialOptions::default());
    // SAFETY: `image` has w × h pixels (or is NULL); `out` is a local or NULL.
    let (st, out_null) = if window {
        let mut out: *mut PgWindowTrial = std::ptr::dangling_mut();
        let out_ptr = if null_out {
            null_mut()
        } else {
            &mut out as *mut _
        };
        let st = check(
            unsafe { pg_window_trial_new(w, h, image_ptr, out_ptr) },
            "pg_window_trial_new",
        );
        if st == PgStatus::PG_OK {
            let twin = WindowTrial::new(w_us, h_us, &image, options).expect("C made it");
            unsafe { pg_window_trial_release(s.window_trial) };
            (s.window_trial, s.window_twin, s.window_pixels) = (out, Some(twin), pixels);
        }
        (st, out.is_null())
    } else {
        let mut out: *mut PgGuideTrial = std::ptr::dangling_mut();
        let out_ptr = if null_out {
            null_mut()
        } else {
            &mut out as *mut _
        };
        let st = check(
            unsafe { pg_guide_trial_new(w, h, image_ptr, out_ptr) },
            "pg_guide_trial_new",
        );
        if st == PgStatus::PG_OK {
            let twin = GuideTrial::new(w_us, h_us, &image, options).expect("C made it");
            unsafe { pg_guide_trial_release(s.guide_trial) };
            (s.guide_trial, s.guide_twin, s.guide_pixels) = (out, Some(twin), pixels);
        }
        (st, out.is_null())
    };
    expect_null(st, null_out || null_image);
    if null_out || null_image {
        return;
    }
    // No pixels is the only invalid image (any values are taken).
    assert_eq!(st == PgStatus::PG_OK, pixels > 0, "{w} x {h}: {st:?}");
    assert_eq!(out_null, pixels == 0, "*out is NULL exactly on failure");
    if pixels == 0 {
        assert_eq!(st, PgStatus::PG_INVALID_ARGUMENT);
    }
}

/// A trial pass of `pixels` pixels from bytes: noise of standard deviation 0 to 0.35 around 1
/// (each pass its own seed), some values arbitrary; whether to pass NULL instead; its seconds.
fn trial_pass(r: &mut ByteReader<'_>, s: &mut State, pixels: usize) -> (Vec<[f32; 3]>, bool, f64) {
    let sd = 0.05 * f32::from(r.byte() % 8);
    s.trial_passes += 1;
    let seed = u64::from(r.byte()) ^ (s.trial_passes << 8);
    let pass = trial_image(r, pixels, 1.0, sd, seed);
    let null_pixels = pixels > 0 && r.byte() % 16 == 15;
    (pass, null_pixels, trial_seconds(r))
}
