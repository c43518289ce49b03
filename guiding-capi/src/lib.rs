//! C ABI of the [`guiding`] crate, for renderers written in C or C++ (or
//! anything with a C FFI). The header `include/guiding.h` is generated from
//! these declarations by cbindgen (`cbindgen.toml`) and committed; a test
//! fails when it is out of date. `examples/toy_renderer.c` is a complete
//! C99 program using it, and `docs/manual/embedding.md` ("Embedding in your renderer") maps Open PGL's calls to ours.
//!
//! The calls of a C renderer, written here in Rust (the same sequence as
//! `examples/toy_renderer.c`): a field over the scene box, one query, one
//! guided direction with its density, the handles released.
//!
//! ```
//! use guiding_capi::*;
//! use std::mem::MaybeUninit;
//! use std::ptr;
//!
//! unsafe {
//!     let mut args = MaybeUninit::<PgFieldArgs>::uninit();
//!     assert_eq!(pg_field_args_set_defaults(args.as_mut_ptr(), PG_REPRESENTATION_NPM), PgStatus::PG_OK);
//!     let mut args = args.assume_init();
//!     args.bounds_min = [-1.0; 3];
//!     args.bounds_max = [1.0; 3];
//!     let mut field = ptr::null_mut();
//!     assert_eq!(pg_field_new(&args, &mut field), PgStatus::PG_OK);
//!
//!     let query = PgQueryPoint { position: [0.1, 0.2, 0.3], normal: [0.0, 0.0, 1.0],
//!         wo: [0.0, 0.0, 1.0], roughness: 1.0, pad0: 0.0, pad1: 0.0 };
//!     let (u, mut dir, mut pdf) = ([0.3f32, 0.7], [0.0f32; 3], 0.0f32);
//!     assert_eq!(pg_field_sample(field, 1, &query, u.as_ptr(), dir.as_mut_ptr(), &mut pdf), PgStatus::PG_OK);
//!     let mut again = 0.0f32;
//!     assert_eq!(pg_field_pdf(field, 1, &query, dir.as_ptr(), &mut again), PgStatus::PG_OK);
//!     assert!(pdf > 0.0 && (again / pdf - 1.0).abs() < 1e-3);
//!     pg_field_release(field);
//! }
//! ```
//!
//! # Conventions
//!
//! - Every `pg_*` function except [`pg_version`], [`pg_last_error`] and the
//!   `*_release` functions returns a [`PgStatus`]. On anything but
//!   `PG_OK`, [`pg_last_error`] returns a message naming the function and
//!   what to change, valid until the next `pg_*` call on the same thread
//!   (each call clears it; after a success it is `""`).
//! - A pointer argument must not be NULL unless its documentation says "may
//!   be NULL" (optional outputs); a NULL one returns `PG_NULL_POINTER`. An
//!   array of `n` elements may be NULL when `n` is 0. Arrays must be aligned
//!   for their element type, and outputs must not overlap each other or the
//!   inputs (`PG_INVALID_ARGUMENT`).
//! - No Rust panic crosses the boundary: each entry point catches it and
//!   returns `PG_PANIC`.
//!
//! # The training loop
//!
//! A render trains its field as the library's schedule says (`PgSchedule`,
//! the Rust `guiding::TrainingSchedule`, whose docs give the rule): the
//! first `train_fraction` of the budget (seconds or samples per pixel) is
//! the training phase, in which Adam steps get a share of the wall clock
//! (`PG_STEP_RULE_TIME_SHARE`, 1/3) or a fixed number of epochs over what
//! each pass recorded (`PG_STEP_RULE_EPOCHS`, reproducible).
//!
//! ```c
//! for (pass = 0; ; pass++) {
//!     bool training;
//!     pg_schedule_in_training_phase(schedule, seconds_since_start, pass, &training);
//!     if (!training) break;            /* render the rest with the frozen guide */
//!     for (done = 0; done < pass_paths; done += piece) {
//!         pg_schedule_paths_before_update(schedule, pass_paths, &piece);
//!         piece = min(piece, pass_paths - done);
//!         /* trace `piece` paths (an unbiased part of the pass), recording them */
//!         pg_recorder_flush_into(recorder, field, NULL);
//!         pg_schedule_record_traced(schedule, seconds_traced, piece);
//!         pg_field_train_scheduled(field, schedule, &report); /* steps due, or none */
//!     }
//! }
//! pg_schedule_report(schedule, &stats);
//! ```
//!
//! `pg_field_update` (a fixed `steps_per_update` steps) and
//! `pg_field_update_proportional` remain for renderers with their own rule.
//!
//! With a time budget the renderer can also ask its image whether the guide
//! pays (`PgGuideTrial`, after training), whether training is worth going on
//! (the schedule's early look, `pg_schedule_look_due`) and whether the weight
//! window pays (`PgWindowTrial`): see [`trial`].
//!
//! # Ownership
//!
//! - Each handle written to an `out` pointer (`PgField`, `PgDistributions`,
//!   `PgRecorder`, `PgSchedule`, `PgRadianceGrid`, `PgGuideTrial`,
//!   `PgWindowTrial`) belongs to the caller, who releases it exactly once with
//!   its `*_release` function (NULL is a no-op). On failure the `out`
//!   pointer is set to NULL. Using a handle after releasing it is undefined
//!   behaviour, as with `free`.
//! - A `PgDistributions` keeps its field alive: releasing the field first is
//!   allowed, the distributions stay usable until released or refilled.
//! - All other memory (arrays, strings, structs) stays the caller's; no
//!   pointer is kept after a call returns.
//!
//! # Threading
//!
//! - `PgField` is internally synchronised by a read-write lock: queries
//!   (`pg_field_query`, `_sample`, `_pdf`, `_selection_probability`,
//!   `_stats`, `_save`, …) may run from many threads at once;
//!   `pg_field_add_samples`, `pg_field_update`, `pg_field_train_scheduled`,
//!   `pg_field_stop_training` and `pg_recorder_flush_into` take the field exclusively (they wait for
//!   running queries and block new ones until they are done).
//! - The reading `pg_distributions_*` functions may run from many threads on
//!   one `PgDistributions`; `pg_field_query` into it must not overlap any
//!   other use of it (use one per thread).
//! - `PgRecorder` is not synchronised: one per render thread.
//! - `PgSchedule`, `PgGuideTrial` and `PgWindowTrial` are not synchronised: the
//!   render loop uses them (any thread, one call at a time).
//! - `PgRadianceGrid` is internally synchronised: `pg_radiance_grid_estimate`
//!   and `_stats` may run from many threads at once; `pg_radiance_grid_add`
//!   and `pg_recorder_flush_reflected_into` take it exclusively.
//! - A `*_release` must not overlap any other use of its handle.
//! - The field's own worker threads (`PgFieldArgs.threads`, 0 = all cores)
//!   run updates and batched queries; set `threads = 1` when the renderer
//!   calls queries from its own thread pool.
//! - Distributions decoded before an update that applied a step are stale:
//!   the `pg_distributions_*` functions return `PG_STALE`; query again.

#![deny(unsafe_op_in_unsafe_fn)]

// The header lists items in this module order; blank lines keep rustfmt
// from sorting the declarations.
pub mod status;

pub mod types;

pub mod field;

pub mod distributions;

pub mod recorder;

pub mod schedule;

pub mod roulette;

pub mod trial;

pub mod media;

mod ptr;

pub use distributions::*;
pub use field::*;
pub use media::*;
pub use recorder::*;
pub use roulette::*;
pub use schedule::*;
pub use status::PgStatus;
pub use trial::*;
pub use types::*;

use std::ffi::c_char;

// The threading rules of the header rest on these.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    const fn send<T: Send>() {}
    send_sync::<PgField>();
    send_sync::<PgDistributions>();
    send::<PgRecorder>();
    send::<PgSchedule>();
    send_sync::<PgRadianceGrid>();
    send::<PgGuideTrial>();
    send::<PgWindowTrial>();
};

/// The library version, `"MAJOR.MINOR.PATCH"` (static storage, never freed).
#[no_mangle]
pub extern "C" fn pg_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// This thread's message for the last failed `pg_*` call: NUL-terminated,
/// never NULL, `""` after a success, valid until the next `pg_*` call on
/// this thread (copy it to keep it).
#[no_mangle]
pub extern "C" fn pg_last_error() -> *const c_char {
    status::last_error_ptr()
}
