//! The C ABI called from Rust through its `extern "C"` functions: NULL
//! pointers, wrong sizes, `n = 0`, NaN inputs, misaligned and overlapping
//! arrays, release(NULL), double use, stale distributions, corrupt files,
//! agreement with the Rust API (fields, schedules, efficiency trials and the
//! early look), and concurrent queries during updates.

use guiding::{
    Budget, GuideTrial, GuidingConfig, GuidingField, ModelSize, PathRecorder, PathVertex,
    Representation, ScheduleOptions, StepRule, Target, TrainingSchedule, TrialArm, TrialOptions,
    TrialVerdict, WindowTrial,
};
use guiding_capi::*;
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;
use std::ffi::{CStr, CString};
use std::path::PathBuf;
use std::ptr::{null, null_mut};

use PgStatus::*;

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];

fn last() -> String {
    // SAFETY: pg_last_error returns a valid NUL-terminated string.
    unsafe { CStr::from_ptr(pg_last_error()) }
        .to_string_lossy()
        .into_owned()
}

/// Asserts `status` is `want` and, unless OK, that the message names
/// `function` and contains `needle`.
#[track_caller]
fn expect(status: PgStatus, want: PgStatus, function: &str, needle: &str) {
    let msg = last();
    assert_eq!(status, want, "{function}: {msg}");
    if want == PG_OK {
        assert_eq!(msg, "", "{function}: message after success");
    } else {
        assert!(
            msg.starts_with(&format!("{function}: ")) && msg.contains(needle),
            "{function}: message {msg:?} lacks {needle:?}"
        );
    }
}

/// [`expect`] of `PG_OK` (and an empty message).
#[track_caller]
fn expect_ok(status: PgStatus) {
    expect(status, PG_OK, "", "");
}

fn args(representation: PgRepresentation) -> PgFieldArgs {
    let mut a = std::mem::MaybeUninit::<PgFieldArgs>::uninit();
    // SAFETY: set_defaults writes the whole struct.
    let a = unsafe {
        assert_eq!(
            pg_field_args_set_defaults(a.as_mut_ptr(), representation),
            PG_OK
        );
        a.assume_init()
    };
    PgFieldArgs {
        size: PG_SIZE_SMALL,
        batch_size: 256,
        steps_per_update: 2,
        threads: 1,
        bounds_min: LO,
        bounds_max: HI,
        ..a
    }
}

/// The Rust configuration `args(representation)` stands for: the library's
/// preset of the representation (radiance target), small, batches of 256,
/// 2 steps per update, one thread.
fn rust_config(representation: PgRepresentation) -> GuidingConfig {
    let rep = Representation::from_code(representation).unwrap();
    let base = GuidingConfig::for_representation(rep, Target::Radiance);
    base.with_size(ModelSize::Small).with_training(
        base.training
            .with_batch_size(256)
            .with_steps_per_update(2)
            .with_threads(1),
    )
}

fn new_field(a: &PgFieldArgs) -> *mut PgField {
    let mut f = null_mut();
    // SAFETY: valid pointers.
    let s = unsafe { pg_field_new(a, &mut f) };
    assert_eq!(s, PG_OK, "{}", last());
    assert!(!f.is_null());
    f
}

fn new_distributions() -> *mut PgDistributions {
    let mut d = null_mut();
    // SAFETY: valid pointer.
    assert_eq!(unsafe { pg_distributions_new(&mut d) }, PG_OK);
    d
}

/// A field of the given arguments and an empty distributions handle, both
/// released on drop (also when an assertion fails).
struct FieldAndDistributions {
    field: *mut PgField,
    d: *mut PgDistributions,
}

impl FieldAndDistributions {
    fn new(a: &PgFieldArgs) -> Self {
        Self {
            field: new_field(a),
            d: new_distributions(),
        }
    }
}

impl Drop for FieldAndDistributions {
    fn drop(&mut self) {
        // SAFETY: live handles, released once.
        unsafe {
            pg_distributions_release(self.d);
            pg_field_release(self.field);
        }
    }
}

fn random_query(rng: &mut Pcg32) -> PgQueryPoint {
    PgQueryPoint {
        position: [
            rng.uniform(LO[0], HI[0]),
            rng.uniform(LO[1], HI[1]),
            rng.uniform(LO[2], HI[2]),
        ],
        roughness: rng.next_f32(),
        normal: square_to_uniform_sphere(rng.next_vec2()).to_array(),
        wo: square_to_uniform_sphere(rng.next_vec2()).to_array(),
        ..PgQueryPoint::default()
    }
}

fn radiance(dir: Vec3) -> f32 {
    if dir.z > 0.95 {
        10.0
    } else {
        0.1
    }
}

/// Uniformly sampled one-vertex paths as training samples.
fn samples(rng: &mut Pcg32, n: usize) -> Vec<PgTrainingSample> {
    (0..n)
        .map(|_| {
            let q = random_query(rng);
            let wi = square_to_uniform_sphere(rng.next_vec2());
            PgTrainingSample {
                position: q.position,
                roughness: q.roughness,
                normal: q.normal,
                sample_pdf: INV_FOUR_PI,
                wo: q.wo,
                bsdf_pdf: INV_FOUR_PI,
                wi: wi.to_array(),
                radiance: [radiance(wi); 3],
                bsdf_cos: [1.0; 3],
                ..PgTrainingSample::default()
            }
        })
        .collect()
}

fn train(field: *mut PgField, rng: &mut Pcg32, n: usize) -> PgUpdateReport {
    let s = samples(rng, n);
    let mut report = PgUpdateReport::default();
    // SAFETY: valid pointers and lengths.
    unsafe {
        assert_eq!(pg_field_add_samples(field, s.as_ptr(), s.len()), PG_OK);
        assert_eq!(pg_field_update(field, &mut report), PG_OK);
    }
    report
}

fn stats(field: *const PgField) -> PgFieldStats {
    let mut s = PgFieldStats::default();
    // SAFETY: valid pointers.
    assert_eq!(unsafe { pg_field_stats(field, &mut s) }, PG_OK);
    s
}

/// `pg_field_sample` on these arrays; `n` may exceed them only where the
/// call must refuse it before any access.
unsafe fn field_sample(
    f: *const PgField,
    n: usize,
    q: &[PgQueryPoint],
    u: &[f32],
    d: &mut [f32],
    p: &mut [f32],
) -> PgStatus {
    // SAFETY: the caller's contract.
    unsafe { pg_field_sample(f, n, q.as_ptr(), u.as_ptr(), d.as_mut_ptr(), p.as_mut_ptr()) }
}

/// `pg_distributions_sample` on these arrays, as [`field_sample`].
unsafe fn dist_sample(
    d: *const PgDistributions,
    n: usize,
    u: &[f32],
    dirs: &mut [f32],
    pdfs: &mut [f32],
) -> PgStatus {
    // SAFETY: the caller's contract.
    unsafe { pg_distributions_sample(d, n, u.as_ptr(), dirs.as_mut_ptr(), pdfs.as_mut_ptr()) }
}

/// Asserts that the three `pg_distributions_*` readers on the first `n` of
/// `d` fail with `want` and a message containing `needle`, outputs untouched.
unsafe fn expect_readers_refuse(d: *const PgDistributions, n: usize, want: PgStatus, needle: &str) {
    let (u, unit) = (vec![0.5f32; 2 * n], [0.0f32, 0.0, 1.0].repeat(n));
    let (mut dirs, mut pdfs) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
    // SAFETY: arrays of the stated lengths; `d` is the caller's.
    unsafe {
        let sample = dist_sample(d, n, &u, &mut dirs, &mut pdfs);
        expect(sample, want, "pg_distributions_sample", needle);
        let pdf = pg_distributions_pdf(d, n, unit.as_ptr(), pdfs.as_mut_ptr());
        expect(pdf, want, "pg_distributions_pdf", needle);
        let selection = pg_distributions_selection_probability(d, n, pdfs.as_mut_ptr());
        expect(
            selection,
            want,
            "pg_distributions_selection_probability",
            needle,
        );
    }
    assert!(
        dirs.iter().chain(&pdfs).all(|&x| x == 0.0),
        "outputs untouched"
    );
}

#[test]
fn version_and_last_error() {
    // SAFETY: static NUL-terminated string.
    let v = unsafe { CStr::from_ptr(pg_version()) };
    assert_eq!(v.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
    // SAFETY: NULL is checked.
    expect(
        unsafe { pg_field_update(null_mut(), null_mut()) },
        PG_NULL_POINTER,
        "pg_field_update",
        "field is NULL",
    );
    // The message is per thread.
    let other = std::thread::spawn(last).join().unwrap();
    assert_eq!(other, "");
    assert!(last().contains("field is NULL"));
    // A success clears it.
    let mut d = null_mut();
    // SAFETY: valid pointer.
    expect(
        unsafe { pg_distributions_new(&mut d) },
        PG_OK,
        "pg_distributions_new",
        "",
    );
    // SAFETY: live handle.
    unsafe { pg_distributions_release(d) };
}

/// Calls `$f(...)` and asserts `PG_NULL_POINTER` with the message
/// "`$f`: `$arg` is NULL".
macro_rules! refuses_null {
    ($arg:literal, $f:ident($($a:expr),* $(,)?)) => {{
        let status = $f($($a),*);
        let msg = last();
        assert_eq!(status, PG_NULL_POINTER, "{} with NULL {}: {msg}", stringify!($f), $arg);
        assert_eq!(msg, format!("{}: {} is NULL", stringify!($f), $arg));
    }};
}

#[test]
fn every_null_pointer_is_refused_and_releases_accept_null() {
    let a = args(PG_REPRESENTATION_NPM);
    let handles = FieldAndDistributions::new(&a);
    let (field, d) = (handles.field, handles.d);
    let mut rec = null_mut();
    let path = CString::new("unused.guide").unwrap();
    let (mut out_f, mut flag, mut len) = (null_mut(), false, 0usize);
    let (mut st, mut rep) = (PgFieldStats::default(), a);
    let q = [PgQueryPoint::default()];
    let (u, dir) = ([0.5f32; 2], [0.0f32, 0.0, 1.0]);
    let (mut o3, mut o1) = ([0.0f32; 3], [0.0f32; 1]);
    let (o3p, o1p, qp, up) = (o3.as_mut_ptr(), o1.as_mut_ptr(), q.as_ptr(), u.as_ptr());
    let v = PgPathVertex::default();
    // SAFETY: every non-NULL pointer is valid; NULL ones are the point.
    unsafe {
        assert_eq!(pg_recorder_new(&mut rec), PG_OK);
        refuses_null!("args", pg_field_args_set_defaults(null_mut(), 0));
        refuses_null!("args", pg_field_new(null(), &mut out_f));
        refuses_null!("out", pg_field_new(&a, null_mut()));
        refuses_null!("field", pg_field_get_args(null(), &mut rep));
        refuses_null!("out", pg_field_get_args(field, null_mut()));
        refuses_null!("field", pg_field_add_samples(null_mut(), null(), 0));
        refuses_null!("samples", pg_field_add_samples(field, null(), 1));
        refuses_null!("field", pg_field_update(null_mut(), null_mut()));
        refuses_null!("field", pg_field_is_converged(null(), &mut flag));
        refuses_null!("out", pg_field_is_converged(field, null_mut()));
        refuses_null!("field", pg_field_stop_training(null_mut()));
        refuses_null!("field", pg_field_stats(null(), &mut st));
        refuses_null!("out", pg_field_stats(field, null_mut()));
        refuses_null!("field", pg_field_save(null(), path.as_ptr()));
        refuses_null!("path", pg_field_save(field, null()));
        refuses_null!("path", pg_field_load(null(), &mut out_f));
        refuses_null!("out", pg_field_load(path.as_ptr(), null_mut()));
        refuses_null!("field", pg_field_query(null(), 1, qp, d));
        refuses_null!("queries", pg_field_query(field, 1, null(), d));
        refuses_null!("out", pg_field_query(field, 1, qp, null_mut()));
        refuses_null!("field", pg_field_sample(null(), 1, qp, up, o3p, o1p));
        refuses_null!("queries", pg_field_sample(field, 1, null(), up, o3p, o1p));
        refuses_null!("u", pg_field_sample(field, 1, qp, null(), o3p, o1p));
        refuses_null!("dirs", pg_field_sample(field, 1, qp, up, null_mut(), o1p));
        refuses_null!("pdfs", pg_field_sample(field, 1, qp, up, o3p, null_mut()));
        refuses_null!("field", pg_field_pdf(null(), 1, qp, dir.as_ptr(), o1p));
        refuses_null!("queries", pg_field_pdf(field, 1, null(), dir.as_ptr(), o1p));
        refuses_null!("dirs", pg_field_pdf(field, 1, qp, null(), o1p));
        refuses_null!("pdfs", pg_field_pdf(field, 1, qp, dir.as_ptr(), null_mut()));
        refuses_null!("field", pg_field_selection_probability(null(), 1, qp, o1p));
        refuses_null!(
            "queries",
            pg_field_selection_probability(field, 1, null(), o1p)
        );
        refuses_null!(
            "out",
            pg_field_selection_probability(field, 1, qp, null_mut())
        );
        refuses_null!("out", pg_distributions_new(null_mut()));
        refuses_null!("distributions", pg_distributions_len(null(), &mut len));
        refuses_null!("out", pg_distributions_len(d, null_mut()));
        refuses_null!(
            "distributions",
            pg_distributions_sample(null(), 0, null(), null_mut(), null_mut())
        );
        refuses_null!("u", pg_distributions_sample(d, 1, null(), o3p, o1p));
        refuses_null!("dirs", pg_distributions_sample(d, 1, up, null_mut(), o1p));
        refuses_null!("pdfs", pg_distributions_sample(d, 1, up, o3p, null_mut()));
        refuses_null!(
            "distributions",
            pg_distributions_pdf(null(), 1, dir.as_ptr(), o1p)
        );
        refuses_null!("dirs", pg_distributions_pdf(d, 1, null(), o1p));
        refuses_null!("pdfs", pg_distributions_pdf(d, 1, dir.as_ptr(), null_mut()));
        refuses_null!(
            "distributions",
            pg_distributions_selection_probability(null(), 1, o1p)
        );
        refuses_null!(
            "out",
            pg_distributions_selection_probability(d, 1, null_mut())
        );
        refuses_null!("vertex", pg_path_vertex_set_defaults(null_mut()));
        refuses_null!("out", pg_recorder_new(null_mut()));
        refuses_null!("recorder", pg_recorder_start_path(null_mut()));
        refuses_null!("recorder", pg_recorder_add_vertex(null_mut(), &v));
        refuses_null!("vertex", pg_recorder_add_vertex(rec, null()));
        refuses_null!(
            "recorder",
            pg_recorder_add_escaped_radiance(null_mut(), o3p, 1.0)
        );
        refuses_null!("rgb", pg_recorder_add_escaped_radiance(rec, null(), 1.0));
        refuses_null!("recorder", pg_recorder_end_path(null_mut(), o3p));
        refuses_null!("recorder", pg_recorder_sample_count(null(), &mut len));
        refuses_null!("out", pg_recorder_sample_count(rec, null_mut()));
        refuses_null!("recorder", pg_recorder_clear_samples(null_mut()));
        refuses_null!(
            "recorder",
            pg_recorder_flush_into(null_mut(), field, null_mut())
        );
        refuses_null!("field", pg_recorder_flush_into(rec, null_mut(), null_mut()));
        // Failed constructors leave NULL in their out pointer.
        assert!(out_f.is_null());
        // The optional outputs may be NULL.
        assert_eq!(pg_field_update(field, null_mut()), PG_OK);
        assert_eq!(pg_recorder_end_path(rec, null_mut()), PG_OK);
        assert_eq!(pg_recorder_flush_into(rec, field, null_mut()), PG_OK);
        // Releasing NULL is a no-op.
        pg_field_release(null_mut());
        pg_distributions_release(null_mut());
        pg_recorder_release(null_mut());
        pg_recorder_release(rec);
    }
}

#[test]
fn zero_counts_accept_null_arrays() {
    let handles = FieldAndDistributions::new(&args(PG_REPRESENTATION_NPM));
    let (field, d) = (handles.field, handles.d);
    let mut len = 7;
    // SAFETY: n = 0 with NULL arrays is allowed.
    unsafe {
        expect_ok(pg_field_add_samples(field, null(), 0));
        expect_ok(pg_field_query(field, 0, null(), d));
        assert_eq!(pg_distributions_len(d, &mut len), PG_OK);
        assert_eq!(len, 0);
        expect_ok(pg_field_sample(
            field,
            0,
            null(),
            null(),
            null_mut(),
            null_mut(),
        ));
        expect_ok(pg_field_pdf(field, 0, null(), null(), null_mut()));
        expect_ok(pg_field_selection_probability(field, 0, null(), null_mut()));
        expect_ok(pg_distributions_sample(
            d,
            0,
            null(),
            null_mut(),
            null_mut(),
        ));
        expect_ok(pg_distributions_pdf(d, 0, null(), null_mut()));
        expect_ok(pg_distributions_selection_probability(d, 0, null_mut()));
        // Nothing was buffered, nothing trained: no step, no new generation.
        let mut report = PgUpdateReport::default();
        assert_eq!(pg_field_update(field, &mut report), PG_OK);
        assert_eq!(report.steps, 0);
        assert_eq!(stats(field).generation, 0);
    }
}

#[test]
fn counts_beyond_a_handle_or_memory_are_refused() {
    let handles = FieldAndDistributions::new(&args(PG_REPRESENTATION_NPM));
    let (field, d) = (handles.field, handles.d);
    let mut rng = Pcg32::new(1, 1);
    let q: Vec<_> = (0..4).map(|_| random_query(&mut rng)).collect();
    let (u, mut dirs, mut pdfs) = ([0.5f32; 10], [0.0f32; 15], [0.0f32; 5]);
    // SAFETY: arrays hold at least n elements where a call may read them.
    unsafe {
        // A fresh handle holds nothing.
        expect_readers_refuse(d, 1, PG_SIZE_MISMATCH, "n = 1 but the distributions hold 0");
        assert_eq!(pg_field_query(field, 4, q.as_ptr(), d), PG_OK);
        expect_readers_refuse(d, 5, PG_SIZE_MISMATCH, "n = 5 but the distributions hold 4");
        // Fewer than held is fine.
        assert_eq!(dist_sample(d, 3, &u, &mut dirs, &mut pdfs), PG_OK);
        assert!(pdfs[..3].iter().all(|&p| p > 0.0) && pdfs[3] == 0.0);
        // Counts whose byte size overflows are refused before any access.
        for n in [usize::MAX, usize::MAX / 2, usize::MAX / 8] {
            expect(
                field_sample(field, n, &q, &u, &mut dirs, &mut pdfs),
                PG_INVALID_ARGUMENT,
                "pg_field_sample",
                "",
            );
            expect(
                pg_field_add_samples(field, samples(&mut rng, 1).as_ptr(), n),
                PG_INVALID_ARGUMENT,
                "pg_field_add_samples",
                "do not fit in memory",
            );
        }
    }
}

#[test]
fn invalid_arguments_are_refused_with_messages() {
    let a = args(PG_REPRESENTATION_NPM);
    // SAFETY: valid pointers throughout.
    unsafe {
        // An unknown representation leaves the struct as it was.
        let mut b = a;
        expect(
            pg_field_args_set_defaults(&mut b, 4),
            PG_INVALID_ARGUMENT,
            "pg_field_args_set_defaults",
            "representation 4",
        );
        assert_eq!(b, a);
        let bad: Vec<(PgFieldArgs, &str)> = vec![
            (
                PgFieldArgs {
                    representation: 9,
                    ..a
                },
                "representation 9",
            ),
            (PgFieldArgs { target: 2, ..a }, "target 2"),
            (PgFieldArgs { size: 3, ..a }, "size 3"),
            (
                PgFieldArgs {
                    selection_probability: 1.5,
                    ..a
                },
                "selection_probability",
            ),
            (
                PgFieldArgs {
                    selection_probability: f32::NAN,
                    ..a
                },
                "selection_probability",
            ),
            (
                PgFieldArgs {
                    learning_rate: f32::NAN,
                    ..a
                },
                "learning",
            ),
            (PgFieldArgs { batch_size: 0, ..a }, "batch"),
            (
                PgFieldArgs {
                    steps_per_update: 0,
                    ..a
                },
                "steps",
            ),
            (
                PgFieldArgs {
                    ema_decay: 1.0,
                    ..a
                },
                "ema",
            ),
            (
                PgFieldArgs {
                    bounds_min: [0.0; 3],
                    bounds_max: [0.0; 3],
                    ..a
                },
                "bounds",
            ),
            (
                PgFieldArgs {
                    bounds_min: [f32::NAN, 0.0, 0.0],
                    ..a
                },
                "bounds",
            ),
            (
                PgFieldArgs {
                    bounds_max: [f32::INFINITY; 3],
                    ..a
                },
                "bounds",
            ),
            (PgFieldArgs { device: 3, ..a }, "device 3"),
            (
                PgFieldArgs {
                    device_failure: 2,
                    ..a
                },
                "device_failure 2",
            ),
        ];
        for (b, needle) in bad {
            let mut f = std::ptr::NonNull::<PgField>::dangling().as_ptr(); // not NULL: must be reset
            let s = pg_field_new(&b, &mut f);
            let msg = last();
            assert_eq!(s, PG_INVALID_ARGUMENT, "{b:?}: {msg}");
            assert!(
                msg.to_lowercase().contains(needle),
                "{needle:?} not in {msg:?}"
            );
            assert!(f.is_null());
        }
        // The defaults with bounds unset are refused (empty box).
        let mut fresh = a;
        assert_eq!(
            pg_field_args_set_defaults(&mut fresh, PG_REPRESENTATION_NASG),
            PG_OK
        );
        let mut f = null_mut();
        expect(
            pg_field_new(&fresh, &mut f),
            PG_INVALID_ARGUMENT,
            "pg_field_new",
            "invalid scene bounds",
        );

        let handles = FieldAndDistributions::new(&a);
        let (field, d) = (handles.field, handles.d);
        let mut rng = Pcg32::new(2, 2);
        let mut q: Vec<_> = (0..3).map(|_| random_query(&mut rng)).collect();
        let (mut u, mut dirs, mut pdfs) = ([0.5f32; 6], [0.0f32; 9], [0.0f32; 3]);
        // Non-finite queries: any field of any query.
        q[2].position[1] = f32::NAN;
        expect(
            pg_field_query(field, 3, q.as_ptr(), d),
            PG_INVALID_ARGUMENT,
            "pg_field_query",
            "queries[2]",
        );
        let mut len = 9;
        assert_eq!(pg_distributions_len(d, &mut len), PG_OK);
        assert_eq!(len, 0, "a failed query leaves the distributions empty");
        q[2].position[1] = 0.0;
        q[0].wo[2] = f32::INFINITY;
        expect(
            field_sample(field, 3, &q, &u, &mut dirs, &mut pdfs),
            PG_INVALID_ARGUMENT,
            "pg_field_sample",
            "queries[0]",
        );
        q[0].wo[2] = 1.0;
        // Random numbers outside [0, 1] or NaN.
        for bad in [f32::NAN, -0.1, 1.5] {
            u[3] = bad;
            expect(
                field_sample(field, 3, &q, &u, &mut dirs, &mut pdfs),
                PG_INVALID_ARGUMENT,
                "pg_field_sample",
                "u[3]",
            );
        }
        u[3] = 1.0; // the closed end is accepted
        assert_eq!(
            field_sample(field, 3, &q, &u, &mut dirs, &mut pdfs),
            PG_OK,
            "{}",
            last()
        );
        // Directions that are not finite unit vectors.
        assert_eq!(pg_field_query(field, 3, q.as_ptr(), d), PG_OK);
        for bad in [[0.0, 0.0, 0.0], [0.0, 0.0, 1.1], [f32::NAN, 0.0, 1.0]] {
            dirs[3..6].copy_from_slice(&bad);
            expect(
                pg_field_pdf(field, 3, q.as_ptr(), dirs.as_ptr(), pdfs.as_mut_ptr()),
                PG_INVALID_ARGUMENT,
                "pg_field_pdf",
                "direction 1",
            );
            expect(
                pg_distributions_pdf(d, 3, dirs.as_ptr(), pdfs.as_mut_ptr()),
                PG_INVALID_ARGUMENT,
                "pg_distributions_pdf",
                "direction 1",
            );
        }
        // Misaligned arrays.
        let mut raw = [0.0f32; 8];
        let misaligned = raw.as_mut_ptr().cast::<u8>().add(1).cast::<f32>();
        expect(
            pg_distributions_selection_probability(d, 1, misaligned),
            PG_INVALID_ARGUMENT,
            "pg_distributions_selection_probability",
            "not aligned",
        );
        // Overlapping outputs, and an output overlapping an input.
        let mut buf = [0.0f32; 12];
        let p = buf.as_mut_ptr();
        expect(
            pg_distributions_sample(d, 3, u.as_ptr(), p, p.add(8)),
            PG_INVALID_ARGUMENT,
            "pg_distributions_sample",
            "overlaps",
        );
        expect(
            pg_distributions_pdf(d, 3, p, p.add(8)),
            PG_INVALID_ARGUMENT,
            "pg_distributions_pdf",
            "overlaps",
        );
        assert_eq!(
            pg_distributions_sample(d, 3, u.as_ptr(), p, p.add(9)),
            PG_OK
        );
        // Paths: empty, and a directory that does not exist.
        let nowhere = c"/nonexistent/dir/field.guide";
        for (path, want, needle) in [
            (c"", PG_INVALID_ARGUMENT, "empty"),
            (nowhere, PG_IO, "nonexistent"),
        ] {
            expect(
                pg_field_save(field, path.as_ptr()),
                want,
                "pg_field_save",
                needle,
            );
        }
        let mut loaded = std::ptr::NonNull::<PgField>::dangling().as_ptr();
        expect(
            pg_field_load(nowhere.as_ptr(), &mut loaded),
            PG_IO,
            "pg_field_load",
            "",
        );
        assert!(loaded.is_null());
    }
}

#[test]
fn invalid_training_samples_are_counted_not_errors() {
    let field = new_field(&args(PG_REPRESENTATION_NPM));
    let mut rng = Pcg32::new(3, 3);
    let mut s = samples(&mut rng, 8);
    s[0].radiance[1] = f32::NAN; // non-finite
    s[1].position[0] = f32::INFINITY; // non-finite
    s[2].radiance[0] = -1.0; // negative
    s[3].sample_pdf = 0.0; // non-positive pdf
    s[4].wi = [0.0, 0.0, 2.0]; // non-unit
                               // SAFETY: valid arrays.
    unsafe {
        expect_ok(pg_field_add_samples(field, s.as_ptr(), s.len()));
    }
    let st = stats(field);
    assert_eq!(st.rejected_samples, [2, 1, 1, 1]);
    assert_eq!(st.accepted_samples, 3);
    assert_eq!(st.buffered_samples, 3);
    // A recorded path with a NaN vertex yields a rejected sample.
    // SAFETY: valid handles and pointers.
    unsafe {
        let mut rec = null_mut();
        assert_eq!(pg_recorder_new(&mut rec), PG_OK);
        let mut v = PgPathVertex::default();
        assert_eq!(pg_path_vertex_set_defaults(&mut v), PG_OK);
        v.wi = [0.0, 0.0, 1.0];
        v.sample_pdf = f32::NAN;
        v.bsdf_cos = [1.0; 3];
        assert_eq!(pg_recorder_start_path(rec), PG_OK);
        assert_eq!(pg_recorder_add_vertex(rec, &v), PG_OK);
        // NaN > 0 is false: the path ends at this vertex, no sample.
        let mut l = [9.0f32; 3];
        assert_eq!(pg_recorder_end_path(rec, l.as_mut_ptr()), PG_OK);
        assert_eq!(l, [0.0; 3]);
        v.sample_pdf = 1.0;
        v.bsdf_cos = [f32::NAN, 1.0, 1.0];
        assert_eq!(pg_recorder_start_path(rec), PG_OK);
        assert_eq!(pg_recorder_add_vertex(rec, &v), PG_OK);
        assert_eq!(
            pg_recorder_add_escaped_radiance(rec, [1.0f32; 3].as_ptr(), 1.0),
            PG_OK
        );
        assert_eq!(pg_recorder_end_path(rec, l.as_mut_ptr()), PG_OK);
        assert!(l[0].is_nan());
        let mut handed = 0;
        assert_eq!(pg_recorder_flush_into(rec, field, &mut handed), PG_OK);
        assert_eq!(handed, 1);
        assert_eq!(stats(field).rejected_samples, [3, 1, 1, 1]);
        // An update on the valid samples never writes NaN: queries stay finite.
        let mut report = PgUpdateReport::default();
        assert_eq!(pg_field_update(field, &mut report), PG_OK);
        assert_eq!((report.steps, report.skipped_steps), (2, 0));
        let q = [random_query(&mut rng)];
        let (u, mut dir, mut pdf) = ([0.3f32, 0.6], [0.0f32; 3], [0.0f32]);
        assert_eq!(field_sample(field, 1, &q, &u, &mut dir, &mut pdf), PG_OK);
        assert!(pdf[0].is_finite() && pdf[0] > 0.0);
        pg_recorder_release(rec);
        pg_field_release(field);
    }
}

#[test]
fn c_results_equal_the_rust_api_for_every_representation() {
    for rep in [
        PG_REPRESENTATION_NPM,
        PG_REPRESENTATION_NASG,
        PG_REPRESENTATION_DF_NEAREST,
        PG_REPRESENTATION_DF_LINEAR,
    ] {
        let a = args(rep);
        let field = new_field(&a);
        let mut rust = GuidingField::new(rust_config(rep), LO, HI).unwrap();
        // The arguments come back as given, and mean the Rust config.
        let mut back = args(PG_REPRESENTATION_NPM);
        // SAFETY: valid pointers.
        assert_eq!(unsafe { pg_field_get_args(field, &mut back) }, PG_OK);
        assert_eq!(back, a);
        // Train both on the same samples.
        let mut rng = Pcg32::new(4, u64::from(rep));
        for _ in 0..2 {
            let s = samples(&mut rng, 300);
            // SAFETY: valid array.
            assert_eq!(
                unsafe { pg_field_add_samples(field, s.as_ptr(), s.len()) },
                PG_OK
            );
            let core: Vec<guiding::TrainingSample> = s.iter().map(|x| bytemuck::cast(*x)).collect();
            rust.add_samples(&core);
            // SAFETY: live handle.
            assert_eq!(unsafe { pg_field_update(field, null_mut()) }, PG_OK);
            rust.update();
        }
        let n = 64;
        let q: Vec<_> = (0..n).map(|_| random_query(&mut rng)).collect();
        let u: Vec<f32> = (0..2 * n).map(|_| rng.next_f32()).collect();
        let (mut dirs, mut pdfs) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
        let (mut d_dirs, mut d_pdfs, mut d_eval) =
            (vec![0.0f32; 3 * n], vec![0.0f32; n], vec![0.0f32; n]);
        let (mut sel, mut d_sel, mut f_eval) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
        let d = new_distributions();
        // SAFETY: arrays of the stated lengths.
        unsafe {
            assert_eq!(field_sample(field, n, &q, &u, &mut dirs, &mut pdfs), PG_OK);
            assert_eq!(
                pg_field_pdf(field, n, q.as_ptr(), dirs.as_ptr(), f_eval.as_mut_ptr()),
                PG_OK
            );
            assert_eq!(
                pg_field_selection_probability(field, n, q.as_ptr(), sel.as_mut_ptr()),
                PG_OK
            );
            assert_eq!(pg_field_query(field, n, q.as_ptr(), d), PG_OK);
            assert_eq!(dist_sample(d, n, &u, &mut d_dirs, &mut d_pdfs), PG_OK);
            assert_eq!(
                pg_distributions_pdf(d, n, dirs.as_ptr(), d_eval.as_mut_ptr()),
                PG_OK
            );
            assert_eq!(
                pg_distributions_selection_probability(d, n, d_sel.as_mut_ptr()),
                PG_OK
            );
            pg_distributions_release(d);
            pg_field_release(field);
        }
        assert_eq!(dirs, d_dirs, "rep {rep}");
        assert_eq!(pdfs, d_pdfs, "rep {rep}");
        assert_eq!(sel, d_sel, "rep {rep}");
        assert_eq!(f_eval, d_eval, "rep {rep}");
        for i in 0..n {
            let dist = rust.distribution(&bytemuck::cast(q[i]));
            let s = dist.sample(Vec2::new(u[2 * i], u[2 * i + 1]));
            assert_eq!(
                s.direction.to_array(),
                dirs[3 * i..3 * i + 3],
                "rep {rep} lane {i}"
            );
            assert_eq!(s.pdf, pdfs[i], "rep {rep} lane {i}");
            assert_eq!(dist.pdf(s.direction), f_eval[i], "rep {rep} lane {i}");
            assert_eq!(dist.selection_probability(), sel[i], "rep {rep} lane {i}");
            assert!((0.0..=1.0).contains(&sel[i]));
            assert!((f_eval[i] / pdfs[i] - 1.0).abs() < 1e-3);
        }
    }
}

#[test]
fn recorder_matches_the_rust_path_recorder() {
    // The embedding test's path, without direct light at its last vertex.
    let mut vertices = guiding_tests::mirror_path();
    vertices[2].direct = [0.0; 3];
    let mut rust = PathRecorder::new();
    rust.start_path();
    for v in vertices {
        rust.add_vertex(v);
    }
    rust.add_escaped_radiance([3.0; 3], 0.5);
    let want = rust.end_path();

    let mut rust_field = GuidingField::new(rust_config(PG_REPRESENTATION_NPM), LO, HI).unwrap();
    rust.flush_into(&mut rust_field);
    let field = new_field(&args(PG_REPRESENTATION_NPM));
    // SAFETY: valid handles and pointers.
    unsafe {
        let mut rec = null_mut();
        assert_eq!(pg_recorder_new(&mut rec), PG_OK);
        // Defaults mirror the Rust ones.
        let mut def = PgPathVertex {
            roughness: 7.0,
            ..PgPathVertex::default()
        };
        assert_eq!(pg_path_vertex_set_defaults(&mut def), PG_OK);
        let rd = PathVertex::default();
        assert_eq!(
            (
                def.roughness,
                def.emitted_mis_weight,
                def.continuation_scale,
                def.is_delta
            ),
            (
                rd.roughness,
                rd.emitted_mis_weight,
                rd.continuation_scale,
                0
            )
        );
        // Twice: the second time without start_path after end_path (a
        // finished path leaves the recorder empty) and with a discarded
        // unfinished path before it.
        for round in 0..2 {
            if round == 0 {
                assert_eq!(pg_recorder_start_path(rec), PG_OK);
            } else {
                assert_eq!(pg_recorder_add_vertex(rec, &def), PG_OK);
                assert_eq!(pg_recorder_start_path(rec), PG_OK);
            }
            for v in &vertices {
                let c = PgPathVertex {
                    is_delta: u32::from(v.is_delta) * 5, // any non-zero
                    ..PgPathVertex::from(*v)
                };
                assert_eq!(pg_recorder_add_vertex(rec, &c), PG_OK);
            }
            // Escaped radiance adds up over calls.
            assert_eq!(
                pg_recorder_add_escaped_radiance(rec, [1.0f32; 3].as_ptr(), 0.5),
                PG_OK
            );
            assert_eq!(
                pg_recorder_add_escaped_radiance(rec, [2.0f32; 3].as_ptr(), 0.5),
                PG_OK
            );
            let mut got = [0.0f32; 3];
            assert_eq!(pg_recorder_end_path(rec, got.as_mut_ptr()), PG_OK);
            assert_eq!(got, want);
        }
        let mut count = 0;
        assert_eq!(pg_recorder_sample_count(rec, &mut count), PG_OK);
        assert_eq!(
            count, 4,
            "two samples per path (the delta vertex makes none)"
        );
        // A path ended twice: the second end has no vertices.
        let mut l = [1.0f32; 3];
        assert_eq!(pg_recorder_end_path(rec, l.as_mut_ptr()), PG_OK);
        assert_eq!(l, [0.0; 3]);
        let mut handed = 0;
        assert_eq!(pg_recorder_flush_into(rec, field, &mut handed), PG_OK);
        assert_eq!(handed, 4);
        // Flushing again hands over nothing.
        assert_eq!(pg_recorder_flush_into(rec, field, &mut handed), PG_OK);
        assert_eq!(handed, 0);
        // Clearing drops recorded samples.
        assert_eq!(pg_recorder_start_path(rec), PG_OK);
        assert_eq!(
            pg_recorder_add_vertex(
                rec,
                &PgPathVertex {
                    wi: [0.0, 0.0, 1.0],
                    sample_pdf: 1.0,
                    ..def
                }
            ),
            PG_OK
        );
        assert_eq!(pg_recorder_end_path(rec, null_mut()), PG_OK);
        assert_eq!(pg_recorder_clear_samples(rec), PG_OK);
        assert_eq!(pg_recorder_sample_count(rec, &mut count), PG_OK);
        assert_eq!(count, 0);
        pg_recorder_release(rec);
    }
    // The field got the same samples as the Rust one (twice).
    let s = stats(field);
    assert_eq!(s.accepted_samples, 2 * rust_field.stats().accepted_samples);
    // Training on them gives the same parameters as the Rust field trained
    // on the same samples twice.
    let mut twice = PathRecorder::new();
    for _ in 0..2 {
        twice.start_path();
        for v in vertices {
            twice.add_vertex(v);
        }
        twice.add_escaped_radiance([3.0; 3], 0.5);
        twice.end_path();
    }
    let mut rust_field = GuidingField::new(rust_config(PG_REPRESENTATION_NPM), LO, HI).unwrap();
    twice.flush_into(&mut rust_field);
    rust_field.update();
    // SAFETY: live handle.
    unsafe {
        assert_eq!(pg_field_update(field, null_mut()), PG_OK);
    }
    let q = PgQueryPoint {
        position: [0.5, 0.5, 0.5],
        ..PgQueryPoint::default()
    };
    let (u, mut dir, mut pdf) = ([0.2f32, 0.9], [0.0f32; 3], [0.0f32]);
    // SAFETY: arrays of length 1.
    unsafe {
        assert_eq!(
            pg_field_sample(field, 1, &q, u.as_ptr(), dir.as_mut_ptr(), pdf.as_mut_ptr()),
            PG_OK
        );
        pg_field_release(field);
    }
    let s = rust_field
        .distribution(&bytemuck::cast(q))
        .sample(Vec2::new(0.2, 0.9));
    assert_eq!((s.direction.to_array(), s.pdf), (dir, pdf[0]));
}

#[test]
fn stale_distributions_training_stop_and_field_lifetime() {
    let a = args(PG_REPRESENTATION_DF_LINEAR);
    let field = new_field(&a);
    let other = new_field(&a);
    let d = new_distributions();
    let mut rng = Pcg32::new(5, 5);
    let q: Vec<_> = (0..8).map(|_| random_query(&mut rng)).collect();
    let (u, mut dirs, mut pdfs) = ([0.4f32; 16], [0.0f32; 24], [0.0f32; 8]);
    // SAFETY: arrays of the stated lengths, live handles.
    unsafe {
        assert_eq!(pg_field_query(field, 8, q.as_ptr(), d), PG_OK);
        // An update without samples applies no step: still valid.
        let mut report = PgUpdateReport::default();
        assert_eq!(pg_field_update(field, &mut report), PG_OK);
        assert_eq!(report.steps, 0);
        assert_eq!(dist_sample(d, 8, &u, &mut dirs, &mut pdfs), PG_OK);
        // An update that applies steps makes them stale: every reader says so.
        assert_eq!(train(field, &mut rng, 200).steps, 2);
        expect_readers_refuse(d, 8, PG_STALE, "stale");
        // n = 0 on stale distributions is still fine (nothing is read).
        assert_eq!(
            pg_distributions_sample(d, 0, null(), null_mut(), null_mut()),
            PG_OK
        );
        // Re-querying (the same handle, twice, then from another field)
        // replaces the contents.
        assert_eq!(pg_field_query(field, 8, q.as_ptr(), d), PG_OK);
        assert_eq!(pg_field_query(field, 3, q.as_ptr(), d), PG_OK);
        let mut len = 0;
        assert_eq!(pg_distributions_len(d, &mut len), PG_OK);
        assert_eq!(len, 3);
        assert_eq!(dist_sample(d, 3, &u, &mut dirs, &mut pdfs), PG_OK);
        assert_eq!(pg_field_query(other, 8, q.as_ptr(), d), PG_OK);
        assert_eq!(dist_sample(d, 8, &u, &mut dirs, &mut pdfs), PG_OK);
        // Releasing the field first: the distributions keep it alive.
        let before = pdfs;
        pg_field_release(other);
        assert_eq!(dist_sample(d, 8, &u, &mut dirs, &mut pdfs), PG_OK);
        assert_eq!(pdfs, before);
        // Stopping training: samples are ignored (counted), updates do
        // nothing, queries go on.
        let mut conv = false;
        assert_eq!(pg_field_is_converged(field, &mut conv), PG_OK);
        assert!(!conv);
        assert_eq!(pg_field_stop_training(field), PG_OK);
        assert_eq!(
            pg_field_stop_training(field),
            PG_OK,
            "stopping twice is fine"
        );
        assert_eq!(pg_field_is_converged(field, &mut conv), PG_OK);
        assert!(conv);
        let gen = stats(field).generation;
        let report = train(field, &mut rng, 100);
        assert_eq!((report.steps, report.converged), (0, 1));
        let s = stats(field);
        assert_eq!(
            (s.ignored_samples, s.generation, s.converged),
            (100, gen, 1)
        );
        assert_eq!(pg_field_query(field, 8, q.as_ptr(), d), PG_OK);
        assert_eq!(dist_sample(d, 8, &u, &mut dirs, &mut pdfs), PG_OK);
        pg_field_release(field);
        pg_distributions_release(d);
    }
}

#[test]
fn save_load_round_trip_and_corrupt_files() {
    let dir =
        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("capi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("field.guide");
    let cpath = CString::new(path.to_str().unwrap()).unwrap();
    let mut a = args(PG_REPRESENTATION_NASG);
    a.target = PG_TARGET_PRODUCT;
    let field = new_field(&a);
    let mut rng = Pcg32::new(6, 6);
    train(field, &mut rng, 300);
    let n = 32;
    let q: Vec<_> = (0..n).map(|_| random_query(&mut rng)).collect();
    let u: Vec<f32> = (0..2 * n).map(|_| rng.next_f32()).collect();
    let sample = |f: *const PgField| {
        let (mut dirs, mut pdfs) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
        // SAFETY: arrays of the stated lengths.
        let s = unsafe { field_sample(f, n, &q, &u, &mut dirs, &mut pdfs) };
        assert_eq!(s, PG_OK);
        (dirs, pdfs)
    };
    // SAFETY: live handles, NUL-terminated path.
    unsafe {
        expect_ok(pg_field_save(field, cpath.as_ptr()));
        let mut loaded = null_mut();
        expect_ok(pg_field_load(cpath.as_ptr(), &mut loaded));
        assert_eq!(sample(field), sample(loaded));
        let mut back = a;
        assert_eq!(pg_field_get_args(loaded, &mut back), PG_OK);
        assert_eq!(back, a);
        assert_eq!(stats(loaded).steps, stats(field).steps);
        pg_field_release(loaded);
        // Corrupt copies: a flipped byte, a truncation, garbage, empty.
        let bytes = std::fs::read(&path).unwrap();
        let mut flipped = bytes.clone();
        flipped[bytes.len() / 2] ^= 0x40;
        let cases: [(&str, Vec<u8>); 4] = [
            ("checksum", flipped),
            ("", bytes[..bytes.len() - 7].to_vec()),
            ("magic", b"this is not a guiding field at all".to_vec()),
            ("too short", Vec::new()),
        ];
        for (needle, content) in cases {
            std::fs::write(&path, &content).unwrap();
            let mut f = std::ptr::NonNull::<PgField>::dangling().as_ptr();
            expect(
                pg_field_load(cpath.as_ptr(), &mut f),
                PG_FORMAT,
                "pg_field_load",
                needle,
            );
            assert!(f.is_null());
        }
        pg_field_release(field);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A raw pointer that may cross threads (the C ABI's contract allows
/// concurrent use of a field and of distributions' readers).
struct Shared<T>(*mut T);
impl<T> Clone for Shared<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Shared<T> {}
// SAFETY: the pointees are internally synchronised (documented contract).
unsafe impl<T> Send for Shared<T> {}
// SAFETY: as above.
unsafe impl<T> Sync for Shared<T> {}

#[test]
fn queries_from_many_threads_during_updates() {
    let field = Shared(new_field(&args(PG_REPRESENTATION_NPM)));
    let d = Shared(new_distributions());
    let mut rng = Pcg32::new(7, 7);
    let q: Vec<_> = (0..64).map(|_| random_query(&mut rng)).collect();
    let u: Vec<f32> = (0..128).map(|_| rng.next_f32()).collect();
    // SAFETY: live handles.
    assert_eq!(
        unsafe { pg_field_query(field.0, 64, q.as_ptr(), d.0) },
        PG_OK
    );
    let training: Vec<Vec<PgTrainingSample>> = (0..4).map(|_| samples(&mut rng, 256)).collect();
    let (mut ok, mut stale) = (0, 0);
    std::thread::scope(|s| {
        let readers: Vec<_> = (0..3)
            .map(|_| {
                let (q, u) = (&q, &u);
                s.spawn(move || {
                    let (field, d) = (field, d);
                    let (mut dirs, mut pdfs) = (vec![0.0f32; 192], vec![0.0f32; 64]);
                    let mut counts = (0, 0);
                    for _ in 0..20 {
                        // SAFETY: live handles, arrays of the stated lengths.
                        unsafe {
                            let s = field_sample(field.0, 64, q, u, &mut dirs, &mut pdfs);
                            assert_eq!(s, PG_OK, "{}", last());
                            assert!(pdfs.iter().all(|p| p.is_finite() && *p > 0.0));
                            match dist_sample(d.0, 64, u, &mut dirs, &mut pdfs) {
                                PG_OK => counts.0 += 1,
                                PG_STALE => counts.1 += 1,
                                other => panic!("{other:?}: {}", last()),
                            }
                        }
                    }
                    counts
                })
            })
            .collect();
        for t in &training {
            // SAFETY: live handle, valid array.
            unsafe {
                assert_eq!(pg_field_add_samples(field.0, t.as_ptr(), t.len()), PG_OK);
                assert_eq!(pg_field_update(field.0, null_mut()), PG_OK);
            }
        }
        for r in readers {
            let (a, b) = r.join().unwrap();
            ok += a;
            stale += b;
        }
    });
    assert_eq!(ok + stale, 60);
    assert_eq!(stats(field.0).generation, 4);
    // After the updates the old distributions are stale for sure.
    let (mut dirs, mut pdfs) = (vec![0.0f32; 192], vec![0.0f32; 64]);
    // SAFETY: live handles.
    unsafe {
        assert_eq!(dist_sample(d.0, 64, &u, &mut dirs, &mut pdfs), PG_STALE);
        pg_distributions_release(d.0);
        pg_field_release(field.0);
    }
}

/// `pg_field_update_proportional`: as many steps as `epochs` passes over the
/// buffer take (batch 256 here), capped at `steps_per_update` (2), and
/// NULL is refused.
#[test]
fn proportional_update_takes_steps_by_buffer_size() {
    let mut rng = Pcg32::new(31, 2);
    let field = new_field(&args(PG_REPRESENTATION_NPM));
    for (n, epochs, expected) in [(100usize, 1.0f32, 1u32), (300, 1.0, 2), (100, 3.0, 2)] {
        let s = samples(&mut rng, n);
        let mut report = PgUpdateReport::default();
        // SAFETY: valid pointers and lengths.
        unsafe {
            assert_eq!(pg_field_add_samples(field, s.as_ptr(), s.len()), PG_OK);
            assert_eq!(
                pg_field_update_proportional(field, epochs, &mut report),
                PG_OK
            );
        }
        assert_eq!(report.steps, expected, "{n} samples, {epochs} epochs");
    }
    // SAFETY: NULL is checked; the field is live until released.
    unsafe {
        assert_eq!(
            pg_field_update_proportional(null_mut(), 1.0, null_mut()),
            PG_NULL_POINTER
        );
        pg_field_release(field);
    }
}

/// `args.device` picks the backend: the defaults are the CPU; a Vulkan
/// device gives a field that trains and answers there (`PG_OK`), or, where
/// there is no device or no SPIR-V in this build, `PG_DEVICE_UNAVAILABLE`
/// with the reason and a NULL field; never a CPU field in its place.
#[test]
fn the_device_is_chosen_by_args_or_unavailable_with_a_reason() {
    let a = args(PG_REPRESENTATION_NPM);
    assert_eq!(a.device, PG_DEVICE_CPU);
    assert_eq!(a.device_failure, PG_DEVICE_FAILURE_ERROR);
    let b = PgFieldArgs {
        device: PG_DEVICE_VULKAN,
        ..a
    };
    let mut f = std::ptr::NonNull::<PgField>::dangling().as_ptr();
    // SAFETY: valid pointers.
    let s = unsafe { pg_field_new(&b, &mut f) };
    let msg = last();
    let available = guiding_gpu::shader_module()
        .and_then(|_| guiding_gpu::GpuContext::new(guiding_gpu::DeviceSelection::Auto))
        .is_ok();
    if available {
        assert_eq!(s, PG_OK, "{msg}");
        assert!(!f.is_null());
        // It trains on the device through the same calls.
        let mut rng = Pcg32::new(5, 5);
        let batch = samples(&mut rng, 512);
        let mut report = std::mem::MaybeUninit::<PgUpdateReport>::uninit();
        // SAFETY: valid pointers.
        unsafe {
            expect(
                pg_field_add_samples(f, batch.as_ptr(), batch.len()),
                PG_OK,
                "pg_field_add_samples",
                "",
            );
            expect(
                pg_field_update(f, report.as_mut_ptr()),
                PG_OK,
                "pg_field_update",
                "",
            );
            assert_eq!(report.assume_init().steps, 2);
            pg_field_release(f);
        }
    } else {
        assert!(
            std::env::var("GUIDING_REQUIRE_VULKAN").map_or(true, |v| v != "1"),
            "GUIDING_REQUIRE_VULKAN=1 but no device"
        );
        assert_eq!(s, PG_DEVICE_UNAVAILABLE, "{msg}");
        assert!(f.is_null());
        assert!(msg.starts_with("pg_field_new: Vulkan device:"), "{msg}");
    }
}

/// `pg_field_args_set_defaults` is the library's preset of each
/// representation (`GuidingConfig::for_representation`): NPM's learning rate
/// is `NPM_LEARNING_RATE`, the others' `PRESET_TRAINING`'s; the selection
/// probability and the steps per update are the presets'.
#[test]
fn field_defaults_are_the_library_presets() {
    use guiding::config::{NPM_LEARNING_RATE, PRESET_SELECTION_PROBABILITY, PRESET_TRAINING};
    for rep in Representation::ALL {
        let mut a = std::mem::MaybeUninit::<PgFieldArgs>::uninit();
        // SAFETY: set_defaults writes the whole struct.
        let a = unsafe {
            assert_eq!(
                pg_field_args_set_defaults(a.as_mut_ptr(), rep as u32),
                PG_OK
            );
            a.assume_init()
        };
        let c = GuidingConfig::for_representation(rep, Target::Radiance);
        let t = &c.training;
        assert_eq!(
            (a.representation, a.target, a.size),
            (rep as u32, PG_TARGET_RADIANCE, c.size as u32),
            "{rep:?}"
        );
        assert_eq!(a.selection_probability, c.selection_probability, "{rep:?}");
        assert_eq!(a.selection_probability, PRESET_SELECTION_PROBABILITY);
        assert_eq!(a.learning_rate, t.adam.learning_rate, "{rep:?}");
        let lr = if rep == Representation::Npm {
            NPM_LEARNING_RATE
        } else {
            PRESET_TRAINING.adam.learning_rate
        };
        assert_eq!(a.learning_rate, lr, "{rep:?}");
        assert_eq!(a.steps_per_update, t.steps_per_update, "{rep:?}");
        assert_eq!(a.steps_per_update, PRESET_TRAINING.steps_per_update);
        assert_eq!(
            (a.batch_size, a.ema_decay, a.threads, a.seed),
            (t.batch_size, t.ema_decay, t.threads, t.seed),
            "{rep:?}"
        );
        assert_eq!(
            (a.max_buffered_samples, a.max_steps),
            (t.max_buffered_samples, t.max_steps)
        );
        assert_eq!(
            (a.device, a.device_failure),
            (PG_DEVICE_CPU, PG_DEVICE_FAILURE_ERROR)
        );
    }
}

fn schedule_args() -> PgScheduleArgs {
    let mut a = std::mem::MaybeUninit::<PgScheduleArgs>::uninit();
    // SAFETY: set_defaults writes the whole struct.
    unsafe {
        assert_eq!(pg_schedule_args_set_defaults(a.as_mut_ptr()), PG_OK);
        a.assume_init()
    }
}

fn new_schedule(a: &PgScheduleArgs) -> *mut PgSchedule {
    let mut s = null_mut();
    // SAFETY: valid pointers.
    let status = unsafe { pg_schedule_new(a, &mut s) };
    assert_eq!(status, PG_OK, "{}", last());
    assert!(!s.is_null());
    s
}

fn schedule_report(s: *const PgSchedule) -> PgScheduleReport {
    let mut r = PgScheduleReport::default();
    // SAFETY: valid pointers.
    assert_eq!(unsafe { pg_schedule_report(s, &mut r) }, PG_OK);
    r
}

/// The defaults are the library's `ScheduleOptions::DEFAULT`, with a budget
/// that must be set (NaN seconds, refused).
#[test]
fn schedule_defaults_are_the_library_defaults() {
    let a = schedule_args();
    let d = ScheduleOptions::DEFAULT;
    let StepRule::TimeShare(share) = d.steps else {
        panic!("the library's default rule changed: {:?}", d.steps)
    };
    assert_eq!(
        (a.step_rule, a.step_value),
        (PG_STEP_RULE_TIME_SHARE, share)
    );
    assert_eq!(
        (
            a.train_fraction,
            a.update_interval,
            a.first_piece,
            a.max_epochs
        ),
        (
            d.train_fraction,
            d.update_interval,
            d.first_piece,
            d.max_epochs
        )
    );
    assert_eq!(a.budget_kind, PG_BUDGET_SECONDS);
    assert!(a.budget.is_nan());
    let mut s = std::ptr::NonNull::<PgSchedule>::dangling().as_ptr();
    // SAFETY: valid pointers.
    expect(
        unsafe { pg_schedule_new(&a, &mut s) },
        PG_INVALID_ARGUMENT,
        "pg_schedule_new",
        "time budget",
    );
    assert!(s.is_null());
}

#[test]
fn schedule_calls_refuse_null_pointers() {
    let a = PgScheduleArgs {
        budget: 10.0,
        ..schedule_args()
    };
    let field = new_field(&args(PG_REPRESENTATION_NPM));
    let s = new_schedule(&a);
    let (mut out_s, mut flag, mut n) = (null_mut(), false, 0u64);
    let mut rep = PgScheduleReport::default();
    let mut up = PgUpdateReport::default();
    // SAFETY: every non-NULL pointer is valid; NULL ones are the point.
    unsafe {
        refuses_null!("args", pg_schedule_args_set_defaults(null_mut()));
        refuses_null!("args", pg_schedule_new(null(), &mut out_s));
        refuses_null!("out", pg_schedule_new(&a, null_mut()));
        refuses_null!(
            "schedule",
            pg_schedule_in_training_phase(null_mut(), 0.0, 0, &mut flag)
        );
        refuses_null!("out", pg_schedule_in_training_phase(s, 0.0, 0, null_mut()));
        refuses_null!("schedule", pg_schedule_end_training(null_mut()));
        refuses_null!("schedule", pg_schedule_record_traced(null_mut(), 1.0, 1));
        refuses_null!(
            "schedule",
            pg_schedule_paths_before_update(null(), 1, &mut n)
        );
        refuses_null!("out", pg_schedule_paths_before_update(s, 1, null_mut()));
        refuses_null!("schedule", pg_schedule_report(null(), &mut rep));
        refuses_null!("out", pg_schedule_report(s, null_mut()));
        refuses_null!("field", pg_field_train_scheduled(null_mut(), s, &mut up));
        refuses_null!(
            "schedule",
            pg_field_train_scheduled(field, null_mut(), &mut up)
        );
        // A failed constructor leaves NULL; the report is optional; NULL
        // releases are no-ops.
        assert!(out_s.is_null());
        expect(
            pg_field_train_scheduled(field, s, null_mut()),
            PG_OK,
            "pg_field_train_scheduled",
            "",
        );
        pg_schedule_release(null_mut());
        assert_eq!(last(), "");
        // Nothing above changed the schedule.
        let r = schedule_report(s);
        assert_eq!((r.steps, r.updates, r.traced_seconds), (0, 0, 0.0));
        pg_schedule_release(s);
        pg_field_release(field);
    }
}

#[test]
fn schedule_arguments_out_of_range_are_refused() {
    let a = PgScheduleArgs {
        budget: 10.0,
        ..schedule_args()
    };
    let epochs = PgScheduleArgs {
        step_rule: PG_STEP_RULE_EPOCHS,
        step_value: 1.0,
        ..a
    };
    let spp = PgScheduleArgs {
        budget_kind: PG_BUDGET_SPP,
        budget: 16.0,
        ..a
    };
    let bad: Vec<(PgScheduleArgs, &str)> = vec![
        (PgScheduleArgs { step_rule: 2, ..a }, "step_rule 2"),
        (
            PgScheduleArgs {
                budget_kind: 2,
                ..a
            },
            "budget_kind 2",
        ),
        (
            PgScheduleArgs {
                train_fraction: 1.5,
                ..a
            },
            "train_fraction",
        ),
        (
            PgScheduleArgs {
                train_fraction: f64::NAN,
                ..a
            },
            "train_fraction",
        ),
        (
            PgScheduleArgs {
                step_value: 1.0,
                ..a
            },
            "training share",
        ),
        (
            PgScheduleArgs {
                step_value: 0.0,
                ..a
            },
            "training share",
        ),
        (
            PgScheduleArgs {
                step_value: 0.0,
                ..epochs
            },
            "epochs",
        ),
        (
            PgScheduleArgs {
                step_value: f64::INFINITY,
                ..epochs
            },
            "epochs",
        ),
        (
            PgScheduleArgs {
                update_interval: 0.0,
                ..a
            },
            "update_interval",
        ),
        (
            PgScheduleArgs {
                first_piece: 0.0,
                ..a
            },
            "first_piece",
        ),
        (
            PgScheduleArgs {
                first_piece: 1.5,
                ..a
            },
            "first_piece",
        ),
        (
            PgScheduleArgs {
                max_epochs: f64::INFINITY,
                ..a
            },
            "max_epochs",
        ),
        (PgScheduleArgs { budget: -1.0, ..a }, "time budget"),
        (
            PgScheduleArgs {
                budget: f64::INFINITY,
                ..a
            },
            "time budget",
        ),
        (PgScheduleArgs { budget: 1.5, ..spp }, "1.5 spp"),
        (
            PgScheduleArgs {
                budget: -1.0,
                ..spp
            },
            "-1 spp",
        ),
        (
            PgScheduleArgs {
                budget: f64::NAN,
                ..spp
            },
            "nan spp",
        ),
        (
            PgScheduleArgs {
                budget: 4294967296.0,
                ..spp
            },
            "4294967296 spp",
        ),
    ];
    for (b, needle) in bad {
        let mut s = std::ptr::NonNull::<PgSchedule>::dangling().as_ptr(); // must be reset
                                                                          // SAFETY: valid pointers.
        let status = unsafe { pg_schedule_new(&b, &mut s) };
        let msg = last();
        assert_eq!(status, PG_INVALID_ARGUMENT, "{b:?}: {msg}");
        assert!(
            msg.starts_with("pg_schedule_new: ") && msg.to_lowercase().contains(needle),
            "{needle:?} not in {msg:?}"
        );
        assert!(s.is_null());
    }
    // The edges of the ranges are accepted.
    for good in [
        PgScheduleArgs {
            train_fraction: 0.0,
            budget: 0.0,
            first_piece: 1.0,
            ..a
        },
        PgScheduleArgs {
            train_fraction: 1.0,
            budget: 4294967295.0,
            ..spp
        },
        PgScheduleArgs {
            step_value: 1e-9,
            ..epochs
        },
    ] {
        let s = new_schedule(&good);
        // SAFETY: a live handle.
        unsafe { pg_schedule_release(s) };
    }
    // Per-call values: non-finite or negative times, a pass of 0 paths. They
    // change nothing.
    let s = new_schedule(&a);
    let (mut flag, mut n) = (true, 7u64);
    // SAFETY: valid pointers.
    unsafe {
        for bad in [f64::NAN, -1.0, f64::INFINITY] {
            expect(
                pg_schedule_in_training_phase(s, bad, 0, &mut flag),
                PG_INVALID_ARGUMENT,
                "pg_schedule_in_training_phase",
                "elapsed_seconds",
            );
            expect(
                pg_schedule_record_traced(s, bad, 10),
                PG_INVALID_ARGUMENT,
                "pg_schedule_record_traced",
                "seconds",
            );
        }
        expect(
            pg_schedule_paths_before_update(s, 0, &mut n),
            PG_INVALID_ARGUMENT,
            "pg_schedule_paths_before_update",
            "pass_paths is 0",
        );
        assert_eq!(n, 7, "out untouched on failure");
        let r = schedule_report(s);
        assert_eq!((r.traced_seconds, r.training_over), (0.0, 0));
        expect_ok(pg_schedule_in_training_phase(s, 1.0, 0, &mut flag));
        assert!(flag, "1 s of 10 at a training fraction of 0.2");
        // Misaligned args.
        let mut raw = [0u64; 16];
        let misaligned = raw
            .as_mut_ptr()
            .cast::<u8>()
            .add(1)
            .cast::<PgScheduleArgs>();
        expect(
            pg_schedule_args_set_defaults(misaligned),
            PG_INVALID_ARGUMENT,
            "pg_schedule_args_set_defaults",
            "misaligned",
        );
        pg_schedule_release(s);
    }
}

/// A scheduled training loop made of C ABI calls (`PG_STEP_RULE_EPOCHS`,
/// deterministic) runs the steps of the Rust `TrainingSchedule` driving a
/// `GuidingField` as host-demo does, on the same samples: the same steps and
/// losses per update, the same report, the same field afterwards.
#[test]
fn scheduled_c_loop_equals_the_rust_schedule() {
    let epochs = 2.0;
    let (spp, fraction) = (10u32, 0.5);
    let a = PgFieldArgs {
        steps_per_update: 8,
        ..args(PG_REPRESENTATION_NPM)
    };
    let config = rust_config(PG_REPRESENTATION_NPM);
    let config = config.with_training(config.training.with_steps_per_update(8));
    let sa = PgScheduleArgs {
        step_rule: PG_STEP_RULE_EPOCHS,
        step_value: epochs,
        budget_kind: PG_BUDGET_SPP,
        budget: f64::from(spp),
        train_fraction: fraction,
        ..schedule_args()
    };
    let options = ScheduleOptions {
        steps: StepRule::Epochs(epochs),
        train_fraction: fraction,
        ..ScheduleOptions::DEFAULT
    };
    let field = new_field(&a);
    let sched = new_schedule(&sa);
    let mut rust = GuidingField::new(config, LO, HI).unwrap();
    let mut rust_sched = TrainingSchedule::new(options, Budget::Spp(spp)).unwrap();
    // Samples per pass: steps clamp(ceil(2 n / 256), 1, 8) = 1, 3, 6, 8, 8.
    let per_pass = [100usize, 300, 700, 2000, 900, 50, 50];
    let mut rng = Pcg32::new(41, 1);
    let mut steps = Vec::new();
    for (pass, &n) in per_pass.iter().enumerate() {
        let pass = pass as u32;
        let elapsed = 0.1 * f64::from(pass);
        let mut training = false;
        // SAFETY: live handles, valid pointers.
        unsafe {
            assert_eq!(
                pg_schedule_in_training_phase(sched, elapsed, pass, &mut training),
                PG_OK
            );
        }
        assert_eq!(training, rust_sched.in_training_phase(elapsed, pass));
        if !training {
            continue;
        }
        let mut piece = 0u64;
        // SAFETY: as above.
        unsafe {
            assert_eq!(
                pg_schedule_paths_before_update(sched, n as u64, &mut piece),
                PG_OK
            );
        }
        assert_eq!(piece, n as u64, "the epoch rule traces whole passes");
        assert_eq!(piece, rust_sched.paths_before_update(n as u64));
        let s = samples(&mut rng, n);
        let seconds = 1e-3 * n as f64;
        let mut report = PgUpdateReport::default();
        // SAFETY: as above.
        unsafe {
            assert_eq!(pg_field_add_samples(field, s.as_ptr(), n), PG_OK);
            assert_eq!(pg_schedule_record_traced(sched, seconds, n as u64), PG_OK);
            expect(
                pg_field_train_scheduled(field, sched, &mut report),
                PG_OK,
                "pg_field_train_scheduled",
                "",
            );
        }
        // The Rust loop of host-demo's end_chunk.
        let core: Vec<guiding::TrainingSample> = s.iter().map(|x| bytemuck::cast(*x)).collect();
        rust_sched.record_traced(seconds, n as u64);
        rust.add_samples(&core);
        let due = rust_sched.steps_due(rust.buffered_samples(), &rust.config().training);
        assert!(due > 0);
        let r = rust.try_update_steps(due).unwrap();
        rust_sched.record_update(r.steps, 1e-3);
        assert_eq!(report.steps, r.steps, "pass {pass}");
        assert_eq!(report.buffered_samples, n as u64);
        assert_eq!(
            report.mean_loss.to_bits(),
            r.mean_loss.to_bits(),
            "pass {pass}"
        );
        steps.push(report.steps);
    }
    assert_eq!(
        steps,
        [1, 3, 6, 8, 8],
        "round(0.5 × 10) = 5 training passes"
    );
    // After the training phase: samples are taken, no step is due.
    let s = samples(&mut rng, 500);
    let mut report = PgUpdateReport::default();
    // SAFETY: live handles, valid pointers.
    unsafe {
        assert_eq!(pg_field_add_samples(field, s.as_ptr(), s.len()), PG_OK);
        assert_eq!(pg_field_train_scheduled(field, sched, &mut report), PG_OK);
    }
    assert_eq!(report.steps, 0);
    assert_eq!((report.buffered_samples, report.batch_size), (500, 256));
    assert!(report.mean_loss.is_nan());
    // The reports agree (but for the seconds, measured on the C side).
    let (c, r) = (schedule_report(sched), rust_sched.report());
    assert_eq!((c.steps, c.updates), (r.steps, r.updates));
    assert_eq!((c.steps, c.updates), (26, 5));
    assert_eq!(c.traced_seconds, r.traced_seconds);
    assert_eq!(c.training_over, 1);
    assert!(c.trained_seconds > 0.0);
    assert_eq!(c.seconds_per_step, c.trained_seconds / 26.0);
    let share = c.trained_seconds / (c.traced_seconds + c.trained_seconds);
    assert_eq!(c.training_share, share);
    assert_eq!(stats(field).steps, rust.stats().steps);
    // The same field: identical samples.
    let q: Vec<_> = (0..16).map(|_| random_query(&mut rng)).collect();
    let u: Vec<f32> = (0..32).map(|_| rng.next_f32()).collect();
    let (mut dirs, mut pdfs) = ([0.0f32; 48], [0.0f32; 16]);
    // SAFETY: arrays of the stated lengths.
    unsafe {
        assert_eq!(field_sample(field, 16, &q, &u, &mut dirs, &mut pdfs), PG_OK);
        pg_schedule_release(sched);
        pg_field_release(field);
    }
    for i in 0..16 {
        let s = rust
            .distribution(&bytemuck::cast(q[i]))
            .sample(Vec2::new(u[2 * i], u[2 * i + 1]));
        assert_eq!(s.direction.to_array(), dirs[3 * i..3 * i + 3]);
        assert_eq!(s.pdf, pdfs[i]);
    }
}

/// The default time-share rule through the C ABI: pieces of 1/32 pass before
/// anything is measured, then by the measured time per path; one calibrating
/// step first; nothing due without samples or ahead of the share; the
/// report's fields; `pg_schedule_end_training`.
#[test]
fn time_share_schedule_and_its_report() {
    let field = new_field(&args(PG_REPRESENTATION_NASG));
    let s = new_schedule(&PgScheduleArgs {
        budget: 100.0,
        ..schedule_args()
    });
    let r0 = schedule_report(s);
    assert_eq!(
        (r0.traced_seconds, r0.trained_seconds, r0.steps, r0.updates),
        (0.0, 0.0, 0, 0)
    );
    assert!(r0.seconds_per_step.is_nan() && r0.training_share.is_nan());
    assert_eq!((r0.training_over, r0.pad), (0, 0));
    let mut rng = Pcg32::new(42, 1);
    let (mut piece, mut flag) = (0u64, false);
    let mut report = PgUpdateReport::default();
    // SAFETY: live handles, valid pointers.
    unsafe {
        assert_eq!(pg_schedule_in_training_phase(s, 0.0, 0, &mut flag), PG_OK);
        assert!(flag);
        assert_eq!(
            pg_schedule_paths_before_update(s, 64_000, &mut piece),
            PG_OK
        );
        assert_eq!(piece, 2000, "1/32 of a pass");
        // Nothing buffered: nothing due.
        assert_eq!(pg_field_train_scheduled(field, s, &mut report), PG_OK);
        assert_eq!((report.steps, report.buffered_samples), (0, 0));
        assert_eq!(schedule_report(s).updates, 0);
        // The first update calibrates: one step.
        let batch = samples(&mut rng, 300);
        assert_eq!(pg_field_add_samples(field, batch.as_ptr(), 300), PG_OK);
        assert_eq!(pg_schedule_record_traced(s, 1e-9, 1000), PG_OK);
        assert_eq!(pg_field_train_scheduled(field, s, &mut report), PG_OK);
        assert_eq!((report.steps, report.buffered_samples), (1, 300));
        assert!(report.mean_loss.is_finite());
        let r = schedule_report(s);
        assert_eq!((r.steps, r.updates, r.traced_seconds), (1, 1, 1e-9));
        assert!(r.trained_seconds > 0.0 && r.seconds_per_step == r.trained_seconds);
        assert_eq!(
            r.training_share,
            r.trained_seconds / (1e-9 + r.trained_seconds)
        );
        // Training is ahead of its share (a step took longer than half a
        // nanosecond): nothing due, the samples stay buffered.
        let batch = samples(&mut rng, 10);
        assert_eq!(pg_field_add_samples(field, batch.as_ptr(), 10), PG_OK);
        assert_eq!(pg_field_train_scheduled(field, s, &mut report), PG_OK);
        assert_eq!((report.steps, report.buffered_samples), (0, 10));
        assert_eq!(schedule_report(s).updates, 1);
        // 10⁻¹² s per path: a whole pass before the next update.
        assert_eq!(
            pg_schedule_paths_before_update(s, 64_000, &mut piece),
            PG_OK
        );
        assert_eq!(piece, 64_000);
        // Much tracing later: steps are due, at most 4 epochs of the buffer
        // (10 samples, batch 256: 1 step).
        assert_eq!(pg_schedule_record_traced(s, 100.0, 10), PG_OK);
        assert_eq!(pg_field_train_scheduled(field, s, &mut report), PG_OK);
        assert_eq!((report.steps, report.buffered_samples), (1, 10));
        // ~0.099 s per path: 0.25 s of tracing is 3 paths.
        assert_eq!(
            pg_schedule_paths_before_update(s, 64_000, &mut piece),
            PG_OK
        );
        assert_eq!(piece, 3);
        // The renderer ends training: nothing more is due, the phase is over.
        assert_eq!(pg_schedule_end_training(s), PG_OK);
        let batch = samples(&mut rng, 100);
        assert_eq!(pg_field_add_samples(field, batch.as_ptr(), 100), PG_OK);
        assert_eq!(pg_schedule_record_traced(s, 100.0, 10), PG_OK);
        assert_eq!(pg_field_train_scheduled(field, s, &mut report), PG_OK);
        assert_eq!(report.steps, 0);
        assert_eq!(pg_schedule_in_training_phase(s, 0.0, 0, &mut flag), PG_OK);
        assert!(!flag);
        let r = schedule_report(s);
        assert_eq!((r.steps, r.updates, r.training_over), (2, 2, 1));
        assert_eq!(r.traced_seconds, 1e-9 + 100.0 + 100.0);
        assert_eq!(stats(field).steps, 2);
        pg_schedule_release(s);
        pg_field_release(field);
    }
}

/// A time budget's training phase ends by the clock, an spp budget's by the
/// pass index (`round(train_fraction · spp)` passes).
#[test]
fn schedule_phases_of_time_and_spp_budgets() {
    let mut flag = false;
    let time = new_schedule(&PgScheduleArgs {
        budget: 10.0,
        ..schedule_args()
    });
    let spp = new_schedule(&PgScheduleArgs {
        budget_kind: PG_BUDGET_SPP,
        budget: 10.0,
        ..schedule_args()
    });
    // SAFETY: live handles, valid pointers.
    unsafe {
        assert_eq!(
            pg_schedule_in_training_phase(time, 1.9, 50, &mut flag),
            PG_OK
        );
        assert!(flag);
        assert_eq!(
            pg_schedule_in_training_phase(time, 2.0, 51, &mut flag),
            PG_OK
        );
        assert!(!flag);
        assert_eq!(
            pg_schedule_in_training_phase(time, 0.0, 0, &mut flag),
            PG_OK
        );
        assert!(!flag, "once over, always over");
        for pass in 0..2 {
            assert_eq!(
                pg_schedule_in_training_phase(spp, 1e6, pass, &mut flag),
                PG_OK
            );
            assert!(flag, "pass {pass}");
        }
        assert_eq!(pg_schedule_in_training_phase(spp, 0.0, 2, &mut flag), PG_OK);
        assert!(!flag);
        assert_eq!(schedule_report(spp).training_over, 1);
        pg_schedule_release(time);
        pg_schedule_release(spp);
    }
}

/// `pg_distributions_apply_cosine_product` and `_apply_lobe_product` give, lane by lane and
/// across decode chunks, what `DistributionBatch::apply_cosine_product` and
/// `apply_lobe_product` give in Rust; a zero normal or `κ = 0` leaves a lane as it is;
/// `pg_hg_vmf_kappa` is `hg_vmf_kappa`.
#[test]
fn products_in_c_equal_the_rust_batch_products() {
    let a = args(PG_REPRESENTATION_NPM);
    let h = FieldAndDistributions::new(&a);
    let mut rust = GuidingField::new(rust_config(PG_REPRESENTATION_NPM), LO, HI).unwrap();
    let mut rng = Pcg32::new(11, 3);
    let s = samples(&mut rng, 300);
    // SAFETY: valid array and handle.
    unsafe {
        expect_ok(pg_field_add_samples(h.field, s.as_ptr(), s.len()));
        expect_ok(pg_field_update(h.field, null_mut()));
    }
    let core: Vec<guiding::TrainingSample> = s.iter().map(|x| bytemuck::cast(*x)).collect();
    rust.add_samples(&core);
    rust.update();
    // More than one decode chunk (guiding::QUERY_CHUNK = 1024 lanes).
    let n = 1500;
    let q: Vec<PgQueryPoint> = (0..n).map(|_| random_query(&mut rng)).collect();
    let rq: Vec<guiding::QueryPoint> = q.iter().map(|x| bytemuck::cast(*x)).collect();
    let u: Vec<f32> = (0..2 * n).map(|_| rng.next_f32()).collect();
    let us: Vec<Vec2> = u.chunks_exact(2).map(|c| Vec2::new(c[0], c[1])).collect();
    // Every third normal zero ("no surface"), every fifth kappa 0.
    let normals: Vec<Vec3> = (0..n)
        .map(|i| {
            if i % 3 == 0 {
                Vec3::ZERO
            } else {
                square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32())) * 2.0
            }
        })
        .collect();
    let axes: Vec<Vec3> = (0..n)
        .map(|_| square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32())))
        .collect();
    let kappas: Vec<f32> = (0..n)
        .map(|i| {
            if i % 5 == 0 {
                0.0
            } else {
                guiding_core::lobe::vmf::hg_vmf_kappa(rng.uniform(-0.95, 0.95))
            }
        })
        .collect();
    let flat = |v: &[Vec3]| v.iter().flat_map(|x| x.to_array()).collect::<Vec<f32>>();
    let lanes: Vec<u32> = (0..n as u32).collect();
    for product in ["cosine", "lobe"] {
        let mut batch = guiding::DistributionBatch::new();
        rust.decode_batch(&rq, &mut batch);
        let mut plain = vec![0.0f32; n];
        let plain_dirs: Vec<Vec3> = (0..n).map(|i| axes[(i + 1) % n]).collect();
        rust.pdf_decoded(&batch, &lanes, &plain_dirs, &mut plain)
            .unwrap();
        let applied = match product {
            "cosine" => batch.apply_cosine_product(&normals),
            _ => batch.apply_lobe_product(&lanes, &axes, &kappas),
        };
        assert!(applied);
        let mut want = vec![
            guiding::DirectionSample {
                direction: Vec3::ZERO,
                pdf: 0.0
            };
            n
        ];
        rust.sample_decoded(&batch, &lanes, &us, &mut want).unwrap();
        let mut want_eval = vec![0.0f32; n];
        rust.pdf_decoded(&batch, &lanes, &plain_dirs, &mut want_eval)
            .unwrap();
        let (mut dirs, mut pdfs, mut eval) =
            (vec![0.0f32; 3 * n], vec![0.0f32; n], vec![0.0f32; n]);
        // SAFETY: arrays of the stated lengths, live handles.
        unsafe {
            expect_ok(pg_field_query(h.field, n, q.as_ptr(), h.d));
            let status = match product {
                "cosine" => pg_distributions_apply_cosine_product(h.d, n, flat(&normals).as_ptr()),
                _ => pg_distributions_apply_lobe_product(
                    h.d,
                    n,
                    flat(&axes).as_ptr(),
                    kappas.as_ptr(),
                ),
            };
            expect_ok(status);
            expect_ok(dist_sample(h.d, n, &u, &mut dirs, &mut pdfs));
            expect_ok(pg_distributions_pdf(
                h.d,
                n,
                flat(&plain_dirs).as_ptr(),
                eval.as_mut_ptr(),
            ));
        }
        let mut unchanged = 0;
        for i in 0..n {
            assert_eq!(
                dirs[3 * i..3 * i + 3],
                want[i].direction.to_array(),
                "{product} {i}"
            );
            assert_eq!(pdfs[i], want[i].pdf, "{product} {i}");
            assert_eq!(eval[i], want_eval[i], "{product} {i}");
            let identity = match product {
                "cosine" => normals[i] == Vec3::ZERO,
                _ => kappas[i] == 0.0,
            };
            if identity {
                assert_eq!(eval[i], plain[i], "{product} lane {i} should be unchanged");
                unchanged += 1;
            }
        }
        assert!(unchanged > n / 6, "{product}: {unchanged} identity lanes");
        // The product changed the other lanes.
        let changed = (0..n).filter(|&i| eval[i] != plain[i]).count();
        assert!(changed > n / 2, "{product}: only {changed} lanes changed");
    }
    for g in [-0.9f32, -0.3, 0.0, 0.5, 0.99] {
        let mut k = -1.0f32;
        // SAFETY: valid pointer.
        expect_ok(unsafe { pg_hg_vmf_kappa(g, &mut k) });
        assert_eq!(k, guiding_core::lobe::vmf::hg_vmf_kappa(g));
    }
}

/// The products refuse what they cannot do, with messages, and change nothing then: NASG,
/// bad normals, axes and concentrations, stale distributions, too many lanes, NULLs.
#[test]
fn products_refuse_bad_arguments() {
    let mut rng = Pcg32::new(12, 1);
    let q: Vec<PgQueryPoint> = (0..4).map(|_| random_query(&mut rng)).collect();
    let good3 = [
        0.0f32, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0,
    ];
    let good_k = [1.0f32, 2.0, 0.0, 5.0];
    let (c, l) = (
        "pg_distributions_apply_cosine_product",
        "pg_distributions_apply_lobe_product",
    );
    // SAFETY: arrays of the stated lengths (or NULL on purpose), live handles.
    unsafe {
        let nasg = FieldAndDistributions::new(&args(PG_REPRESENTATION_NASG));
        expect_ok(pg_field_query(nasg.field, 4, q.as_ptr(), nasg.d));
        let mut before = [0.0f32; 4];
        expect_ok(pg_distributions_pdf(
            nasg.d,
            4,
            good3.as_ptr(),
            before.as_mut_ptr(),
        ));
        expect(
            pg_distributions_apply_cosine_product(nasg.d, 4, good3.as_ptr()),
            PG_INVALID_ARGUMENT,
            c,
            "vMF",
        );
        expect(
            pg_distributions_apply_lobe_product(nasg.d, 4, good3.as_ptr(), good_k.as_ptr()),
            PG_INVALID_ARGUMENT,
            l,
            "vMF",
        );
        let mut after = [0.0f32; 4];
        expect_ok(pg_distributions_pdf(
            nasg.d,
            4,
            good3.as_ptr(),
            after.as_mut_ptr(),
        ));
        assert_eq!(before, after);

        let h = FieldAndDistributions::new(&args(PG_REPRESENTATION_NPM));
        expect_ok(pg_field_query(h.field, 4, q.as_ptr(), h.d));
        let mut before = [0.0f32; 4];
        expect_ok(pg_distributions_pdf(
            h.d,
            4,
            good3.as_ptr(),
            before.as_mut_ptr(),
        ));
        let mut nan3 = good3;
        nan3[4] = f32::NAN;
        expect(
            pg_distributions_apply_cosine_product(h.d, 4, nan3.as_ptr()),
            PG_INVALID_ARGUMENT,
            c,
            "normals[1]",
        );
        expect(
            pg_distributions_apply_lobe_product(h.d, 4, nan3.as_ptr(), good_k.as_ptr()),
            PG_INVALID_ARGUMENT,
            l,
            "axes[1]",
        );
        for (bad, needle) in [
            (-1.0f32, "kappas[3]"),
            (f32::INFINITY, "kappas[3]"),
            (f32::NAN, "kappas[3]"),
        ] {
            let k = [1.0, 2.0, 0.0, bad];
            expect(
                pg_distributions_apply_lobe_product(h.d, 4, good3.as_ptr(), k.as_ptr()),
                PG_INVALID_ARGUMENT,
                l,
                needle,
            );
        }
        // A zero axis with κ > 0 (lane 3's axis is (0, 0, -1): make lane 0's zero).
        let mut zero_axis = good3;
        zero_axis[2] = 0.0;
        expect(
            pg_distributions_apply_lobe_product(h.d, 4, zero_axis.as_ptr(), good_k.as_ptr()),
            PG_INVALID_ARGUMENT,
            l,
            "axes[0] is zero",
        );
        expect(
            pg_distributions_apply_cosine_product(h.d, 5, null()),
            PG_NULL_POINTER,
            c,
            "normals",
        );
        let five = [0.0f32; 15];
        expect(
            pg_distributions_apply_cosine_product(h.d, 5, five.as_ptr()),
            PG_SIZE_MISMATCH,
            c,
            "n = 5",
        );
        expect(
            pg_distributions_apply_lobe_product(h.d, 4, good3.as_ptr(), null()),
            PG_NULL_POINTER,
            l,
            "kappas",
        );
        expect(
            pg_distributions_apply_lobe_product(null_mut(), 0, null(), null()),
            PG_NULL_POINTER,
            l,
            "distributions",
        );
        expect_ok(pg_distributions_apply_lobe_product(h.d, 0, null(), null()));
        let mut after = [0.0f32; 4];
        expect_ok(pg_distributions_pdf(
            h.d,
            4,
            good3.as_ptr(),
            after.as_mut_ptr(),
        ));
        assert_eq!(before, after, "a refused product changed the distributions");
        // Stale after an update.
        let s = samples(&mut rng, 300);
        expect_ok(pg_field_add_samples(h.field, s.as_ptr(), s.len()));
        expect_ok(pg_field_update(h.field, null_mut()));
        expect(
            pg_distributions_apply_cosine_product(h.d, 4, good3.as_ptr()),
            PG_STALE,
            c,
            "",
        );
        let mut k = 0.0f32;
        for g in [1.0f32, -1.0, f32::NAN, 2.0] {
            expect(
                pg_hg_vmf_kappa(g, &mut k),
                PG_INVALID_ARGUMENT,
                "pg_hg_vmf_kappa",
                "(-1, 1)",
            );
        }
        expect(
            pg_hg_vmf_kappa(0.5, null_mut()),
            PG_NULL_POINTER,
            "pg_hg_vmf_kappa",
            "out",
        );
    }
}

/// `pg_guides_medium` is the library's thin-medium rule (`guiding::media`): the depth
/// `σ_s,max · d` and its verdict against `PG_MIN_GUIDED_SCATTERING_DEPTH`, `depth` optional;
/// negative or NaN inputs and a NULL `guided` are refused.
#[test]
fn the_thin_medium_rule_in_c_is_the_library_rule() {
    for (sigma, extent) in [
        (0.108f32, 9.786f32),
        (0.002, 9.786),
        (0.05, 1.0),
        (0.049_999, 1.0),
        (0.0, f32::INFINITY),
        (1e-3, f32::INFINITY),
    ] {
        let (mut depth, mut guided) = (f32::NAN, false);
        // SAFETY: valid pointers.
        expect_ok(unsafe { pg_guides_medium(sigma, extent, &mut depth, &mut guided) });
        assert_eq!(Some(depth), guiding::media::scattering_depth(sigma, extent));
        assert_eq!(guided, guiding::media::guides_medium(sigma, extent));
        let mut again = !guided;
        // SAFETY: `depth` may be NULL.
        expect_ok(unsafe { pg_guides_medium(sigma, extent, null_mut(), &mut again) });
        assert_eq!(again, guided);
    }
    assert_eq!(
        PG_MIN_GUIDED_SCATTERING_DEPTH,
        guiding::media::MIN_GUIDED_SCATTERING_DEPTH
    );
    let mut guided = false;
    for (sigma, extent) in [
        (-1.0f32, 1.0f32),
        (1.0, -0.5),
        (f32::NAN, 1.0),
        (1.0, f32::NAN),
    ] {
        // SAFETY: valid pointers.
        let st = unsafe { pg_guides_medium(sigma, extent, null_mut(), &mut guided) };
        expect(st, PG_INVALID_ARGUMENT, "pg_guides_medium", ">= 0");
    }
    // SAFETY: NULL on purpose.
    let st = unsafe { pg_guides_medium(1.0, 1.0, null_mut(), null_mut()) };
    expect(st, PG_NULL_POINTER, "pg_guides_medium", "guided");
}

// ---------------------------------------------------------------------------
// Efficiency trials and the early look.

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

/// The image before a trial: values in `[0.5, 1.5)` per pixel and channel.
fn trial_image(pixels: usize, rng: &mut Lcg) -> Vec<[f32; 3]> {
    (0..pixels)
        .map(|_| {
            [
                0.5 + rng.uniform(),
                0.5 + rng.uniform(),
                0.5 + rng.uniform(),
            ]
        })
        .collect()
}

/// One pass: `base` plus uniform noise of standard deviation `sd` per pixel and channel.
fn noisy_pass(base: &[[f32; 3]], sd: f32, rng: &mut Lcg) -> Vec<[f32; 3]> {
    let half_width = sd * 3f32.sqrt();
    base.iter()
        .map(|b| b.map(|x| x + half_width * (2.0 * rng.uniform() - 1.0)))
        .collect()
}

fn floats(image: &[[f32; 3]]) -> *const f32 {
    image.as_ptr().cast()
}

/// A verdict no trial writes: an output left untouched still holds it.
const UNTOUCHED: PgTrialVerdict = PgTrialVerdict {
    keep_guide: 7,
    evidence: 7,
    ratio_low: -7.0,
    ratio_high: -7.0,
    guided_variance: -7.0,
    unguided_variance: -7.0,
    guided_seconds: -7.0,
    unguided_seconds: -7.0,
    cost_ratio: -7.0,
    guided_passes: 7,
    unguided_passes: 7,
    z: -7.0,
    pixels_skipped: 7,
};

fn evidence_code(v: guiding::Verdict) -> PgEvidence {
    match v {
        guiding::Verdict::Undecided => PG_EVIDENCE_UNDECIDED,
        guiding::Verdict::Pays => PG_EVIDENCE_PAYS,
        guiding::Verdict::DoesNotPay => PG_EVIDENCE_DOES_NOT_PAY,
    }
}

/// The C verdict is the Rust one, field for field (floats to the bit).
#[track_caller]
fn assert_same_verdict(c: Option<PgTrialVerdict>, r: Option<TrialVerdict>) {
    let (Some(c), Some(r)) = (c, r) else {
        assert_eq!(c.is_some(), r.is_some(), "C {c:?}, Rust {r:?}");
        return;
    };
    assert_eq!(
        (c.keep_guide, c.evidence),
        (u32::from(r.keep_guide), evidence_code(r.evidence)),
        "C {c:?}, Rust {r:?}"
    );
    let bits = |x: [f64; 8]| x.map(f64::to_bits);
    assert_eq!(
        bits([
            c.ratio_low,
            c.ratio_high,
            c.guided_variance,
            c.unguided_variance,
            c.guided_seconds,
            c.unguided_seconds,
            c.cost_ratio,
            c.z
        ]),
        bits([
            r.ratio_low,
            r.ratio_high,
            r.guided_variance,
            r.unguided_variance,
            r.guided_seconds,
            r.unguided_seconds,
            r.cost_ratio,
            r.z
        ]),
        "C {c:?}, Rust {r:?}"
    );
    assert_eq!(
        (c.guided_passes, c.unguided_passes, c.pixels_skipped),
        (r.guided_passes, r.unguided_passes, r.pixels_skipped)
    );
}

/// A `PgTrialVerdict` getter (`pg_guide_trial_verdict`, `_first_look`, `pg_window_trial_verdict`)
/// called with an output holding [`UNTOUCHED`]: `None` when it says there is none (and then
/// left the output alone).
#[track_caller]
fn c_verdict<T>(
    get: unsafe extern "C" fn(*const T, *mut bool, *mut PgTrialVerdict) -> PgStatus,
    trial: *const T,
) -> Option<PgTrialVerdict> {
    let (mut has, mut v) = (true, UNTOUCHED);
    // SAFETY: a live handle, valid outputs.
    expect_ok(unsafe { get(trial, &mut has, &mut v) });
    if !has {
        assert_eq!(v, UNTOUCHED, "the output is left alone without a verdict");
    }
    has.then_some(v)
}

fn c_worth_more_training(v: &PgTrialVerdict) -> bool {
    let mut out = false;
    // SAFETY: valid pointers.
    expect_ok(unsafe { pg_trial_verdict_worth_more_training(v, &mut out) });
    out
}

fn c_window_pays(v: &PgTrialVerdict) -> bool {
    let mut out = false;
    // SAFETY: valid pointers.
    expect_ok(unsafe { pg_window_trial_window_pays(v, &mut out) });
    out
}

fn c_next_arm(t: *const PgGuideTrial) -> PgTrialArm {
    let mut arm = 99;
    // SAFETY: a live handle, a valid output.
    expect_ok(unsafe { pg_guide_trial_next_arm(t, &mut arm) });
    arm
}

fn arm_code(arm: Option<TrialArm>) -> PgTrialArm {
    match arm {
        Some(TrialArm::Guided) => PG_TRIAL_ARM_GUIDED,
        Some(TrialArm::Unguided) => PG_TRIAL_ARM_UNGUIDED,
        None => PG_TRIAL_ARM_NONE,
    }
}

fn new_guide_trial(width: u32, height: u32, image: &[[f32; 3]]) -> *mut PgGuideTrial {
    let mut t = null_mut();
    // SAFETY: `image` has width × height pixels.
    expect_ok(unsafe { pg_guide_trial_new(width, height, floats(image), &mut t) });
    assert!(!t.is_null());
    t
}

fn new_window_trial(width: u32, height: u32, image: &[[f32; 3]]) -> *mut PgWindowTrial {
    let mut t = null_mut();
    // SAFETY: as above.
    expect_ok(unsafe { pg_window_trial_new(width, height, floats(image), &mut t) });
    assert!(!t.is_null());
    t
}

/// What [`guide_trials_side_by_side`] runs: the noise and seconds per pass of each arm
/// (guided, unguided), the most passes, and after which pass the unguided arm restarts.
struct TrialRun {
    sd: [f32; 2],
    seconds: [f64; 2],
    max_passes: usize,
    restart_after: Option<usize>,
}

/// Runs a C `PgGuideTrial` and a Rust `GuideTrial` on the same synthetic passes (48 × 40
/// pixels), checking after every pass that they ask for the same arm and have the same first
/// look and verdict; returns the Rust trial and the passes run.
fn guide_trials_side_by_side(run: &TrialRun) -> (GuideTrial, usize) {
    let (w, h) = (48u32, 40u32);
    let mut rng = Lcg(17);
    let base = trial_image((w * h) as usize, &mut rng);
    let c = new_guide_trial(w, h, &base);
    let mut rust = GuideTrial::new(w as usize, h as usize, &base, TrialOptions::default()).unwrap();
    let mut passes = 0;
    loop {
        let arm = rust.next_arm();
        assert_eq!(c_next_arm(c), arm_code(arm), "pass {passes}");
        let Some(arm) = arm else { break };
        if passes == run.max_passes {
            break;
        }
        let i = usize::from(arm == TrialArm::Unguided);
        let pass = noisy_pass(&base, run.sd[i], &mut rng);
        // SAFETY: a live handle, a pass of the trial's size.
        expect_ok(unsafe {
            pg_guide_trial_record(c, arm_code(Some(arm)), floats(&pass), run.seconds[i])
        });
        rust.record(arm, &pass, run.seconds[i]).unwrap();
        passes += 1;
        assert_same_verdict(c_verdict(pg_guide_trial_verdict, c), rust.verdict());
        assert_same_verdict(c_verdict(pg_guide_trial_first_look, c), rust.first_look());
        if run.restart_after == Some(passes) {
            // SAFETY: a live handle.
            expect_ok(unsafe { pg_guide_trial_restart(c, PG_TRIAL_ARM_UNGUIDED) });
            rust.restart(TrialArm::Unguided);
        }
        if let Some(v) = c_verdict(pg_guide_trial_first_look, c) {
            assert_eq!(
                c_worth_more_training(&v),
                rust.first_look().unwrap().worth_more_training()
            );
        }
    }
    if rust.verdict().is_some() {
        // The trial has ended: no more passes, whatever the arm.
        let pass = noisy_pass(&base, 0.1, &mut rng);
        for arm in [PG_TRIAL_ARM_GUIDED, PG_TRIAL_ARM_UNGUIDED] {
            // SAFETY: as above.
            let st = unsafe { pg_guide_trial_record(c, arm, floats(&pass), 1.0) };
            expect(st, PG_INVALID_ARGUMENT, "pg_guide_trial_record", "ended");
        }
        assert_same_verdict(c_verdict(pg_guide_trial_verdict, c), rust.verdict());
    }
    // SAFETY: a live handle, released once.
    unsafe { pg_guide_trial_release(c) };
    (rust, passes)
}

/// The C guide trial is the Rust `GuideTrial`: the same arms pass by pass and the same first
/// looks and verdicts, field for field, on synthetic images where one arm has 4× the
/// per-pixel variance at equal time (a clear verdict, either way), twice the seconds at equal
/// variance, and equal arms (no verdict: the continuation's 2 : 1 order, a restart).
#[test]
fn guide_trial_in_c_equals_the_rust_guide_trial() {
    let dear = guide_trials_side_by_side(&TrialRun {
        sd: [0.2, 0.1],
        seconds: [0.5, 0.5],
        max_passes: 64,
        restart_after: None,
    });
    let v = dear.0.verdict().expect("a clear case decides");
    assert_eq!(v.evidence, guiding::Verdict::DoesNotPay, "{v:?}");
    assert!(!v.keep_guide && v.ratio_low > 1.0 && dear.1 <= 8, "{v:?}");

    let cheap = guide_trials_side_by_side(&TrialRun {
        sd: [0.1, 0.2],
        seconds: [0.5, 0.5],
        max_passes: 64,
        restart_after: None,
    });
    let v = cheap.0.verdict().expect("a clear case decides");
    assert_eq!(v.evidence, guiding::Verdict::Pays, "{v:?}");
    assert!(v.keep_guide && v.worth_more_training(), "{v:?}");

    let slow = guide_trials_side_by_side(&TrialRun {
        sd: [0.1, 0.1],
        seconds: [2.0, 1.0],
        max_passes: 64,
        restart_after: None,
    });
    let v = slow.0.verdict().expect("a clear case decides");
    assert!(!v.keep_guide && (v.cost_ratio - 2.0).abs() < 0.3, "{v:?}");

    let even = guide_trials_side_by_side(&TrialRun {
        sd: [0.1, 0.1],
        seconds: [1.0, 1.0],
        max_passes: 40,
        restart_after: Some(20),
    });
    assert_eq!(even.1, 40);
    let first = even.0.first_look().expect("4 + 4 passes looked");
    assert_eq!(first.evidence, guiding::Verdict::Undecided, "{first:?}");
}

/// The C window trial is the Rust `WindowTrial`: the same ABBA order and continuation, the
/// same verdicts field for field, and `pg_window_trial_window_pays` is
/// `WindowTrial::window_pays`; a pass of the other arm than the order's and a pass after the
/// verdict are refused.
#[test]
fn window_trial_in_c_equals_the_rust_window_trial() {
    for (sd_on, sd_off, max_passes) in [(0.2f32, 0.1f32, 64), (0.1, 0.2, 64), (0.1, 0.1, 24)] {
        let (w, h) = (40u32, 32u32);
        let mut rng = Lcg(5);
        let base = trial_image((w * h) as usize, &mut rng);
        let c = new_window_trial(w, h, &base);
        let mut rust =
            WindowTrial::new(w as usize, h as usize, &base, TrialOptions::default()).unwrap();
        for pass in 0..max_passes {
            let (mut on, mut running) = (false, false);
            // SAFETY: a live handle, valid outputs.
            unsafe {
                expect_ok(pg_window_trial_next_pass_uses_window(c, &mut on));
                expect_ok(pg_window_trial_running(c, &mut running));
            }
            assert_eq!(on, rust.next_pass_uses_window(), "pass {pass}");
            assert_eq!(running, rust.running(), "pass {pass}");
            if !running {
                break;
            }
            let p = noisy_pass(&base, if on { sd_on } else { sd_off }, &mut rng);
            // SAFETY: a live handle, a pass of the trial's size.
            let wrong = unsafe { pg_window_trial_record(c, !on, floats(&p), 1.0) };
            expect(wrong, PG_INVALID_ARGUMENT, "pg_window_trial_record", "runs");
            // SAFETY: as above.
            expect_ok(unsafe { pg_window_trial_record(c, on, floats(&p), 1.0) });
            rust.record(on, &p, 1.0).unwrap();
            assert_same_verdict(c_verdict(pg_window_trial_verdict, c), rust.verdict());
        }
        if sd_on == sd_off {
            assert!(
                rust.running(),
                "equal arms: no verdict in {max_passes} passes"
            );
        } else {
            let v = c_verdict(pg_window_trial_verdict, c).expect("a clear case decides");
            let r = rust.verdict().unwrap();
            assert_eq!(c_window_pays(&v), WindowTrial::window_pays(&r));
            assert_eq!(c_window_pays(&v), sd_on < sd_off, "{v:?}");
            let mut on = !c_window_pays(&v);
            // SAFETY: as above.
            unsafe {
                expect_ok(pg_window_trial_next_pass_uses_window(c, &mut on));
                assert_eq!(on, c_window_pays(&v), "the verdict's choice from now on");
                let st = pg_window_trial_record(c, on, floats(&base), 1.0);
                expect(st, PG_INVALID_ARGUMENT, "pg_window_trial_record", "verdict");
            }
        }
        // SAFETY: a live handle, released once.
        unsafe { pg_window_trial_release(c) };
    }
}

/// Bad input to the trial calls returns an error status and changes nothing: NULL handles,
/// images and outputs, images without pixels or too large to address, misaligned or
/// overlapping arrays, non-finite or negative seconds, unknown arm and evidence codes.
#[test]
fn trial_calls_refuse_bad_input() {
    let (w, h) = (8u32, 6u32);
    let mut rng = Lcg(3);
    let image = trial_image(48, &mut rng);
    let g = new_guide_trial(w, h, &image);
    let win = new_window_trial(w, h, &image);
    let (mut out_g, mut out_w) = (null_mut(), null_mut());
    let (mut arm, mut flag, mut v) = (0, false, UNTOUCHED);
    // SAFETY: every non-NULL pointer is valid; NULL ones are the point.
    unsafe {
        refuses_null!("out", pg_guide_trial_new(w, h, floats(&image), null_mut()));
        refuses_null!("image", pg_guide_trial_new(w, h, null(), &mut out_g));
        refuses_null!("trial", pg_guide_trial_next_arm(null(), &mut arm));
        refuses_null!("out", pg_guide_trial_next_arm(g, null_mut()));
        refuses_null!(
            "trial",
            pg_guide_trial_record(null_mut(), 0, floats(&image), 1.0)
        );
        refuses_null!("pixels", pg_guide_trial_record(g, 0, null(), 1.0));
        refuses_null!("trial", pg_guide_trial_restart(null_mut(), 0));
        refuses_null!("trial", pg_guide_trial_verdict(null(), &mut flag, &mut v));
        refuses_null!("has", pg_guide_trial_verdict(g, null_mut(), &mut v));
        refuses_null!("out", pg_guide_trial_verdict(g, &mut flag, null_mut()));
        refuses_null!(
            "trial",
            pg_guide_trial_first_look(null(), &mut flag, &mut v)
        );
        refuses_null!("has", pg_guide_trial_first_look(g, null_mut(), &mut v));
        refuses_null!("out", pg_guide_trial_first_look(g, &mut flag, null_mut()));
        refuses_null!(
            "verdict",
            pg_trial_verdict_worth_more_training(null(), &mut flag)
        );
        refuses_null!(
            "out",
            pg_trial_verdict_worth_more_training(&UNTOUCHED, null_mut())
        );
        refuses_null!("out", pg_window_trial_new(w, h, floats(&image), null_mut()));
        refuses_null!("image", pg_window_trial_new(w, h, null(), &mut out_w));
        refuses_null!(
            "trial",
            pg_window_trial_next_pass_uses_window(null(), &mut flag)
        );
        refuses_null!(
            "out",
            pg_window_trial_next_pass_uses_window(win, null_mut())
        );
        refuses_null!("trial", pg_window_trial_running(null(), &mut flag));
        refuses_null!("out", pg_window_trial_running(win, null_mut()));
        refuses_null!(
            "trial",
            pg_window_trial_record(null_mut(), true, floats(&image), 1.0)
        );
        refuses_null!("pixels", pg_window_trial_record(win, true, null(), 1.0));
        refuses_null!("trial", pg_window_trial_verdict(null(), &mut flag, &mut v));
        refuses_null!("has", pg_window_trial_verdict(win, null_mut(), &mut v));
        refuses_null!("out", pg_window_trial_verdict(win, &mut flag, null_mut()));
        refuses_null!("verdict", pg_window_trial_window_pays(null(), &mut flag));
        refuses_null!("out", pg_window_trial_window_pays(&UNTOUCHED, null_mut()));
        assert!(out_g.is_null() && out_w.is_null());
        assert_eq!(v, UNTOUCHED);
        pg_guide_trial_release(null_mut());
        pg_window_trial_release(null_mut());
        assert_eq!(last(), "");

        // No pixels, or more than memory holds: refused, `*out` NULL.
        for (ww, hh, needle) in [
            (0, 6, "pixels"),
            (8, 0, "pixels"),
            (u32::MAX, u32::MAX, "overflow"),
        ] {
            let mut t = std::ptr::NonNull::<PgGuideTrial>::dangling().as_ptr();
            let st = pg_guide_trial_new(ww, hh, floats(&image), &mut t);
            expect(st, PG_INVALID_ARGUMENT, "pg_guide_trial_new", needle);
            assert!(t.is_null());
            let mut t = std::ptr::NonNull::<PgWindowTrial>::dangling().as_ptr();
            let st = pg_window_trial_new(ww, hh, floats(&image), &mut t);
            expect(st, PG_INVALID_ARGUMENT, "pg_window_trial_new", needle);
            assert!(t.is_null());
        }
        // A misaligned pass.
        let bytes = vec![0u32; 3 * 48 + 1];
        let misaligned = bytes.as_ptr().cast::<u8>().wrapping_add(1).cast::<f32>();
        let st = pg_guide_trial_record(g, 0, misaligned, 1.0);
        expect(st, PG_INVALID_ARGUMENT, "pg_guide_trial_record", "aligned");
        let st = pg_window_trial_record(win, true, misaligned, 1.0);
        expect(st, PG_INVALID_ARGUMENT, "pg_window_trial_record", "aligned");

        // Seconds that are not finite and >= 0, unknown arms: nothing is added.
        for seconds in [f64::NAN, -1.0, f64::INFINITY, f64::NEG_INFINITY] {
            let st = pg_guide_trial_record(g, PG_TRIAL_ARM_GUIDED, floats(&image), seconds);
            expect(st, PG_INVALID_ARGUMENT, "pg_guide_trial_record", "took");
            let st = pg_window_trial_record(win, true, floats(&image), seconds);
            expect(st, PG_INVALID_ARGUMENT, "pg_window_trial_record", "took");
        }
        for bad in [PG_TRIAL_ARM_NONE, 2, i32::MIN, i32::MAX] {
            let st = pg_guide_trial_record(g, bad, floats(&image), 1.0);
            expect(
                st,
                PG_INVALID_ARGUMENT,
                "pg_guide_trial_record",
                "PG_TRIAL_ARM",
            );
            let st = pg_guide_trial_restart(g, bad);
            expect(
                st,
                PG_INVALID_ARGUMENT,
                "pg_guide_trial_restart",
                "PG_TRIAL_ARM",
            );
        }
        assert_eq!(c_next_arm(g), PG_TRIAL_ARM_GUIDED, "nothing was recorded");
        let mut on = false;
        expect_ok(pg_window_trial_next_pass_uses_window(win, &mut on));
        assert!(
            on,
            "nothing was recorded: the ABBA order starts with the window"
        );
        // The guided arm has its 4 passes before the first look: a fifth is refused.
        for _ in 0..4 {
            expect_ok(pg_guide_trial_record(
                g,
                PG_TRIAL_ARM_GUIDED,
                floats(&image),
                1.0,
            ));
        }
        let st = pg_guide_trial_record(g, PG_TRIAL_ARM_GUIDED, floats(&image), 1.0);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_guide_trial_record",
            "already has",
        );
        assert_eq!(c_next_arm(g), PG_TRIAL_ARM_UNGUIDED);

        // Overlapping outputs; an output inside the verdict read.
        let mut buffer = UNTOUCHED;
        let inside = (&mut buffer as *mut PgTrialVerdict).cast::<bool>();
        let st = pg_guide_trial_verdict(g, inside, &mut buffer);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_guide_trial_verdict",
            "overlaps",
        );
        let st = pg_window_trial_verdict(win, inside, &mut buffer);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_window_trial_verdict",
            "overlaps",
        );
        let st = pg_trial_verdict_worth_more_training(&buffer, inside);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_trial_verdict_worth_more_training",
            "overlaps",
        );
        let st = pg_window_trial_window_pays(&buffer, inside);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_window_trial_window_pays",
            "overlaps",
        );
        assert_eq!(buffer, UNTOUCHED);

        // Unknown evidence codes; any non-NaN verdict of a known code is read.
        let bad = PgTrialVerdict {
            evidence: 3,
            ..UNTOUCHED
        };
        let st = pg_trial_verdict_worth_more_training(&bad, &mut flag);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_trial_verdict_worth_more_training",
            "PG_EVIDENCE_",
        );
        let st = pg_window_trial_window_pays(&bad, &mut flag);
        expect(
            st,
            PG_INVALID_ARGUMENT,
            "pg_window_trial_window_pays",
            "PG_EVIDENCE_",
        );
        let pays = PgTrialVerdict {
            evidence: PG_EVIDENCE_PAYS,
            ratio_high: 0.9,
            ..UNTOUCHED
        };
        assert!(c_worth_more_training(&pays) && c_window_pays(&pays));
        let straddles = PgTrialVerdict {
            evidence: PG_EVIDENCE_UNDECIDED,
            ratio_high: 1.1,
            ..pays
        };
        assert!(!c_worth_more_training(&straddles) && !c_window_pays(&straddles));
        let no_interval = PgTrialVerdict {
            ratio_high: f64::NAN,
            ..straddles
        };
        assert!(!c_worth_more_training(&no_interval));

        pg_window_trial_release(win);
        pg_guide_trial_release(g);
    }
}

/// The early look through the C ABI is the Rust schedule's: `pg_schedule_look_due` answers as
/// `TrainingSchedule::look_due` (not before 64 Adam steps and a quarter of the phase, once per quarter),
/// a look trial's first look decides with `pg_trial_verdict_worth_more_training`, and
/// `pg_schedule_resume_after_look` moves the end of the phase as the Rust one does (or
/// `pg_schedule_end_training` ends it). Bad times are refused and change nothing.
#[test]
fn early_look_in_c_equals_the_rust_schedule() {
    // 40 spp, a fifth trains: 8 training passes, the look due from pass 2 once 64 steps ran
    // (32 per pass: ceil(16 epochs × 512 samples / 256) clamped to 32 steps per update).
    let (spp, epochs) = (40u32, 16.0);
    let sa = PgScheduleArgs {
        step_rule: PG_STEP_RULE_EPOCHS,
        step_value: epochs,
        budget_kind: PG_BUDGET_SPP,
        budget: f64::from(spp),
        ..schedule_args()
    };
    let options = ScheduleOptions {
        steps: StepRule::Epochs(epochs),
        ..ScheduleOptions::DEFAULT
    };
    // (guided noise, unguided noise): a guide that pays resumes training, one that does not
    // ends it.
    for (sd, resumes) in [([0.1f32, 0.2f32], true), ([0.2, 0.1], false)] {
        let field = new_field(&PgFieldArgs {
            steps_per_update: 32,
            ..args(PG_REPRESENTATION_NPM)
        });
        let sched = new_schedule(&sa);
        let mut rust = TrainingSchedule::new(options, Budget::Spp(spp)).unwrap();
        let mut rng = Pcg32::new(7, 3);
        let (mut looks, mut training_passes, mut pass) = (0, 0, 0u32);
        let mut paid = false;
        while pass < 24 {
            let elapsed = 0.1 * f64::from(pass);
            let (mut due, mut training) = (false, false);
            // SAFETY: live handles, valid pointers.
            unsafe {
                for bad in [f64::NAN, -1.0, f64::INFINITY] {
                    let st = pg_schedule_look_due(sched, bad, pass, &mut due);
                    expect(
                        st,
                        PG_INVALID_ARGUMENT,
                        "pg_schedule_look_due",
                        "elapsed_seconds",
                    );
                }
                // A renderer whose look showed the guide paying asks no more.
                if !paid {
                    expect_ok(pg_schedule_look_due(sched, elapsed, pass, &mut due));
                }
            }
            if !paid {
                assert_eq!(due, rust.look_due(elapsed, pass), "pass {pass}");
            }
            if due {
                looks += 1;
                assert!(schedule_report(sched).steps >= 64);
                let (look_passes, look_seconds, more) = early_look(sd);
                assert_eq!(more, resumes, "{sd:?}");
                paid = more;
                // SAFETY: a live handle.
                unsafe {
                    for bad in [f64::NAN, -0.5, f64::INFINITY] {
                        let st = pg_schedule_resume_after_look(sched, bad, 4);
                        expect(
                            st,
                            PG_INVALID_ARGUMENT,
                            "pg_schedule_resume_after_look",
                            "look_seconds",
                        );
                    }
                    if more {
                        expect_ok(pg_schedule_resume_after_look(
                            sched,
                            look_seconds,
                            look_passes,
                        ));
                        rust.resume_after_look(look_seconds, look_passes);
                    } else {
                        expect_ok(pg_schedule_end_training(sched));
                        rust.end_training();
                    }
                }
                // The look's passes were passes of the render.
                pass += look_passes;
                continue;
            }
            // SAFETY: as above.
            unsafe {
                expect_ok(pg_schedule_in_training_phase(
                    sched,
                    elapsed,
                    pass,
                    &mut training,
                ));
            }
            assert_eq!(
                training,
                rust.in_training_phase(elapsed, pass),
                "pass {pass}"
            );
            pass += 1;
            if !training {
                continue;
            }
            training_passes += 1;
            let s = samples(&mut rng, 512);
            let mut report = PgUpdateReport::default();
            // SAFETY: as above.
            unsafe {
                expect_ok(pg_field_add_samples(field, s.as_ptr(), s.len()));
                expect_ok(pg_schedule_record_traced(sched, 0.01, 512));
                expect_ok(pg_field_train_scheduled(field, sched, &mut report));
            }
            rust.record_traced(0.01, 512);
            rust.record_update(report.steps, 1e-3);
            assert_eq!(report.steps, 32);
        }
        assert_eq!(looks, 1, "one look decided (below or above 1)");
        let r = schedule_report(sched);
        assert_eq!((r.steps, r.training_over), (rust.report().steps, 1));
        // Resumed: the phase ends as many passes later as the look took, so the guide still
        // trains its 8 passes; ended at the look: only the 2 passes before it trained.
        assert_eq!(training_passes, if resumes { 8 } else { 2 }, "{sd:?}");
        assert_eq!(r.steps, 32 * training_passes);
        // SAFETY: live handles, released once.
        unsafe {
            pg_schedule_release(sched);
            pg_field_release(field);
        }
    }
}

/// An early look through the C ABI: a `PgGuideTrial` (on a 32 × 24 image, arms of noise
/// `sd`, equal seconds) up to its first look, checked against the Rust `GuideTrial`; returns
/// its passes, its seconds and whether `pg_trial_verdict_worth_more_training` says train on.
fn early_look(sd: [f32; 2]) -> (u32, f64, bool) {
    let (w, h) = (32u32, 24u32);
    let mut rng = Lcg(11);
    let base = trial_image((w * h) as usize, &mut rng);
    let probe = new_guide_trial(w, h, &base);
    let mut rust = GuideTrial::new(w as usize, h as usize, &base, TrialOptions::default()).unwrap();
    let (mut passes, mut seconds) = (0u32, 0.0);
    let look = loop {
        if let Some(v) = c_verdict(pg_guide_trial_first_look, probe) {
            break v;
        }
        let arm = c_next_arm(probe);
        assert_eq!(arm, arm_code(rust.next_arm()));
        let i = usize::try_from(arm).expect("no verdict before the first look");
        let pass = noisy_pass(&base, sd[i], &mut rng);
        // SAFETY: a live handle, a pass of the trial's size.
        expect_ok(unsafe { pg_guide_trial_record(probe, arm, floats(&pass), 0.25) });
        rust.record([TrialArm::Guided, TrialArm::Unguided][i], &pass, 0.25)
            .unwrap();
        passes += 1;
        seconds += 0.25;
        assert!(passes <= 8, "the first look comes by 4 + 4 passes");
    };
    assert_same_verdict(Some(look), rust.first_look());
    let more = c_worth_more_training(&look);
    assert_eq!(more, rust.first_look().unwrap().worth_more_training());
    // SAFETY: a live handle, released once.
    unsafe { pg_guide_trial_release(probe) };
    (passes, seconds, more)
}
