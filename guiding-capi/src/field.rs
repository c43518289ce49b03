//! `PgField`: a guiding field behind a read-write lock, its arguments,
//! training calls, direct batched queries and save/load.

use crate::distributions::PgDistributions;
use crate::ptr::{self, disjoint, region, times};
use crate::status::{guard, Failure, PgStatus};
use crate::types::{
    as_query_points, as_training_samples, PgFieldArgs, PgFieldStats, PgQueryPoint,
    PgRepresentation, PgTrainingSample, PgUpdateReport, PG_DEVICE_CPU, PG_DEVICE_FAILURE_ERROR,
    PG_DEVICE_FALLBACK_CPU, PG_DEVICE_VULKAN, PG_DEVICE_VULKAN_GPU, PG_TARGET_PRODUCT,
    PG_TARGET_RADIANCE,
};
use guiding::{
    DeviceFailure, DeviceSelection, DirectionSample, GuidingConfig, GuidingError, GuidingField,
    ModelSize, PlateauConfig, Representation, Target, UpdateReport,
};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::sample::UNIT_TOLERANCE;
use std::ffi::c_char;
use std::sync::{Arc, RwLock, RwLockReadGuard, RwLockWriteGuard};

/// A guiding field (opaque). Create with `pg_field_new` or `pg_field_load`,
/// release with `pg_field_release`. Internally synchronised: queries run
/// concurrently, training calls take the field exclusively.
pub struct PgField {
    pub(crate) inner: Arc<RwLock<GuidingField>>,
}

const POISONED: &str =
    "an earlier call panicked while it was modifying this field; release the field";

/// Shared access to a field behind its lock.
pub(crate) fn read(
    lock: &RwLock<GuidingField>,
) -> Result<RwLockReadGuard<'_, GuidingField>, Failure> {
    lock.read()
        .map_err(|_| Failure::new(PgStatus::PG_POISONED, POISONED))
}

/// Exclusive access to a field behind its lock.
pub(crate) fn write(
    lock: &RwLock<GuidingField>,
) -> Result<RwLockWriteGuard<'_, GuidingField>, Failure> {
    lock.write()
        .map_err(|_| Failure::new(PgStatus::PG_POISONED, POISONED))
}

impl From<GuidingField> for PgField {
    fn from(field: GuidingField) -> Self {
        PgField {
            inner: Arc::new(RwLock::new(field)),
        }
    }
}

/// The radiance-target preset of a representation: the library's defaults
/// (`GuidingConfig::for_representation`).
fn preset(code: PgRepresentation) -> Result<GuidingConfig, Failure> {
    let rep = Representation::from_code(code)
        .ok_or_else(|| Failure::unknown_code("representation", code, "REPRESENTATION", "0 to 3"))?;
    Ok(GuidingConfig::for_representation(rep, Target::Radiance))
}

fn args_of(config: &GuidingConfig, bounds: ([f32; 3], [f32; 3])) -> PgFieldArgs {
    let t = &config.training;
    PgFieldArgs {
        representation: config.representation as u32,
        target: config.target as u32,
        size: config.size as u32,
        selection_probability: config.selection_probability,
        learning_rate: t.adam.learning_rate,
        ema_decay: t.ema_decay,
        steps_per_update: t.steps_per_update,
        seed: t.seed,
        batch_size: t.batch_size,
        threads: t.threads,
        max_buffered_samples: t.max_buffered_samples,
        max_steps: t.max_steps,
        plateau_window: t.plateau.window,
        plateau_min_relative_improvement: t.plateau.min_relative_improvement,
        bounds_min: bounds.0,
        bounds_max: bounds.1,
        device: PG_DEVICE_CPU,
        device_failure: PG_DEVICE_FAILURE_ERROR,
    }
}

/// The device and failure policy of `args` (`None`: the CPU).
fn device_of(args: &PgFieldArgs) -> Result<Option<(DeviceSelection, DeviceFailure)>, Failure> {
    let failure = match args.device_failure {
        PG_DEVICE_FAILURE_ERROR => DeviceFailure::Error,
        PG_DEVICE_FALLBACK_CPU => DeviceFailure::FallbackToCpu,
        f => {
            return Err(Failure::unknown_code(
                "device_failure",
                f,
                "DEVICE_FAILURE",
                "0 or 1",
            ))
        }
    };
    Ok(match args.device {
        PG_DEVICE_CPU => None,
        PG_DEVICE_VULKAN => Some((DeviceSelection::Auto, failure)),
        PG_DEVICE_VULKAN_GPU => Some((DeviceSelection::Gpu, failure)),
        d => return Err(Failure::unknown_code("device", d, "DEVICE", "0 to 2")),
    })
}

fn config_of(args: &PgFieldArgs) -> Result<GuidingConfig, Failure> {
    let base = preset(args.representation)?;
    let target = match args.target {
        PG_TARGET_RADIANCE => Target::Radiance,
        PG_TARGET_PRODUCT => Target::Product,
        t => return Err(Failure::unknown_code("target", t, "TARGET", "0 or 1")),
    };
    let size = ModelSize::from_code(args.size).ok_or_else(|| {
        Failure::invalid(format!(
            "size {} is not a PG_SIZE_* code (0 to {})",
            args.size,
            ModelSize::ALL.len() - 1
        ))
    })?;
    let training = base
        .training
        .with_learning_rate(args.learning_rate)
        .with_ema_decay(args.ema_decay)
        .with_steps_per_update(args.steps_per_update)
        .with_seed(args.seed)
        .with_batch_size(args.batch_size)
        .with_threads(args.threads)
        .with_max_buffered_samples(args.max_buffered_samples)
        .with_max_steps(args.max_steps)
        .with_plateau(PlateauConfig::new(
            args.plateau_window,
            args.plateau_min_relative_improvement,
        ));
    Ok(base
        .with_target(target)
        .with_size(size)
        .with_selection_probability(args.selection_probability)
        .with_training(training))
}

/// Rejects query points with a NaN or infinite value.
pub(crate) fn check_queries(queries: &[PgQueryPoint]) -> Result<(), Failure> {
    match queries.iter().position(|q| !q.is_finite()) {
        Some(i) => Err(Failure::invalid(format!(
            "queries[{i}] has a NaN or infinite value: {:?}",
            queries[i]
        ))),
        None => Ok(()),
    }
}

/// Rejects random numbers outside `[0, 1]` (or NaN).
pub(crate) fn check_unit_square(u: &[f32]) -> Result<(), Failure> {
    match u.iter().position(|x| !(0.0..=1.0).contains(x)) {
        Some(i) => Err(Failure::invalid(format!(
            "u[{i}] = {} is not in [0, 1]",
            u[i]
        ))),
        None => Ok(()),
    }
}

/// The directions of a `3n`-float array, each finite and of unit length
/// (within `guiding_core::sample::UNIT_TOLERANCE`).
pub(crate) fn unit_directions(dirs: &[f32]) -> Result<Vec<Vec3>, Failure> {
    dirs.chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let d = Vec3::new(c[0], c[1], c[2]);
            if d.is_finite() && (d.length() - 1.0).abs() <= UNIT_TOLERANCE {
                Ok(d)
            } else {
                Err(Failure::invalid(format!(
                    "direction {i} = {d} is not a finite unit vector"
                )))
            }
        })
        .collect()
}

/// Writes `samples` into `dirs` (3 floats each) and `pdfs`.
pub(crate) fn write_samples(samples: &[DirectionSample], dirs: &mut [f32], pdfs: &mut [f32]) {
    for ((s, d), p) in samples.iter().zip(dirs.chunks_exact_mut(3)).zip(pdfs) {
        d.copy_from_slice(&s.direction.to_array());
        *p = s.pdf;
    }
}

/// Fills `args` with the defaults of a representation, the library's preset
/// (Rust `GuidingConfig::for_representation` with the radiance target, the
/// defaults host-demo renders with): target `PG_TARGET_RADIANCE`, size
/// `PG_SIZE_COMPACT`, selection probability 0.3
/// (`guiding::config::PRESET_SELECTION_PROBABILITY`), learning rate 0.03
/// (NPM: 0.005, `guiding::config::NPM_LEARNING_RATE`), batches of 8192, 64
/// steps per update (`guiding::config::PRESET_TRAINING`), EMA decay 0.95, all
/// cores, seed 0, no step limit, no plateau detection, at most 2^20 buffered
/// samples; and an empty scene box, which the caller must set.
///
/// Returns `PG_NULL_POINTER` if `args` is NULL, `PG_INVALID_ARGUMENT` (and
/// leaves `*args` unchanged) for an unknown representation.
///
/// # Safety
/// `args` must be NULL or point to writable memory for a `PgFieldArgs`.
#[no_mangle]
pub unsafe extern "C" fn pg_field_args_set_defaults(
    args: *mut PgFieldArgs,
    representation: PgRepresentation,
) -> PgStatus {
    guard("pg_field_args_set_defaults", || unsafe {
        ptr::write_whole(args, "args", || {
            Ok(args_of(&preset(representation)?, ([0.0; 3], [0.0; 3])))
        })
    })
}

/// Creates a field from `args` (see `PgFieldArgs`) and stores it in `*out`.
///
/// Returns `PG_INVALID_ARGUMENT` for an unknown code, a value out of its
/// range, or bounds that are not finite with `min < max` on every axis.
/// On failure `*out` is set to NULL.
///
/// # Safety
/// `args` must be NULL or point to a `PgFieldArgs`; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_new(
    args: *const PgFieldArgs,
    out: *mut *mut PgField,
) -> PgStatus {
    guard("pg_field_new", || unsafe {
        ptr::new_handle(out, || {
            let args = ptr::as_ref(args, "args")?;
            let config = config_of(args)?;
            let device = device_of(args)?;
            let mut field = GuidingField::new(config, args.bounds_min, args.bounds_max)?;
            if let Some((selection, on_failure)) = device {
                field.use_device(selection, on_failure)?;
            }
            Ok(field.into())
        })
    })
}

/// Releases a field (NULL: no-op). `PgDistributions` filled from it stay
/// usable: they keep the field's memory alive until they are released or
/// refilled.
///
/// # Safety
/// `field` must be NULL or a handle from `pg_field_new`/`pg_field_load` not
/// yet released, and no other call may be using it.
#[no_mangle]
pub unsafe extern "C" fn pg_field_release(field: *mut PgField) {
    unsafe { ptr::release("pg_field_release", field) }
}

/// Writes the arguments the field was created with (its configuration and
/// scene bounds) to `*out`, e.g. after `pg_field_load`.
///
/// # Safety
/// `field` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_get_args(
    field: *const PgField,
    out: *mut PgFieldArgs,
) -> PgStatus {
    guard("pg_field_get_args", || unsafe {
        ptr::read_into(field, "field", out, |field| {
            let f = read(&field.inner)?;
            Ok(args_of(f.config(), f.bounds()))
        })
    })
}

/// Validates and buffers `n` training samples for the next update (the
/// array may be NULL when `n` is 0). Invalid samples (NaN/infinite values,
/// negative radiance, `sample_pdf ≤ 0`, non-unit directions) are dropped and
/// counted in `PgFieldStats.rejected_samples`; they are not an error. Takes
/// the field exclusively.
///
/// # Safety
/// `field` must be NULL or a live handle; `samples` NULL or `n` readable
/// samples.
#[no_mangle]
pub unsafe extern "C" fn pg_field_add_samples(
    field: *mut PgField,
    samples: *const PgTrainingSample,
    n: usize,
) -> PgStatus {
    guard("pg_field_add_samples", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let samples = unsafe { ptr::slice(samples, n, "samples") }?;
        write(&field.inner)?.add_samples(as_training_samples(samples));
        Ok(())
    })
}

/// The body of `pg_field_update*`: runs `train` on the field taken
/// exclusively and writes its report to `*report` unless that is NULL.
///
/// # Safety
/// `field` NULL or a live handle; `report` NULL or writable.
unsafe fn update(
    field: *const PgField,
    report: *mut PgUpdateReport,
    train: impl FnOnce(&mut GuidingField) -> Result<UpdateReport, GuidingError>,
) -> Result<(), Failure> {
    let field = unsafe { ptr::as_ref(field, "field") }?;
    let report = unsafe { ptr::as_mut_opt(report, "report") }?;
    let r = train(&mut *write(&field.inner)?)?;
    if let Some(out) = report {
        *out = r.into();
    }
    Ok(())
}

/// Runs one training iteration on the buffered samples (`steps_per_update`
/// Adam steps), then clears the buffer. Does nothing once converged. A
/// render that should train as the library's schedule does calls
/// `pg_field_train_scheduled` instead (see `PgSchedule`). If it
/// applied a step, distributions queried before are stale. Writes what it
/// did to `*report` unless `report` is NULL. Takes the field exclusively:
/// waits for running queries and blocks new ones until done. On a field
/// whose device failed (`PG_DEVICE_FAILURE_ERROR`) it trains nothing and
/// returns `PG_DEVICE_UNAVAILABLE`.
///
/// # Safety
/// `field` must be NULL or a live handle; `report` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_update(
    field: *mut PgField,
    report: *mut PgUpdateReport,
) -> PgStatus {
    guard("pg_field_update", || unsafe {
        update(field, report, GuidingField::try_update)
    })
}

/// `pg_field_update` with as many Adam steps as `epochs` passes over the
/// buffered samples take, capped at `steps_per_update`: `clamp(ceil(epochs ·
/// buffered / batch_size), 1, steps_per_update)` (a non-finite or negative
/// `epochs` reads as 1), training proportional to what the render pass
/// produced. Otherwise as `pg_field_update`.
///
/// # Safety
/// `field` must be NULL or a live handle; `report` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_update_proportional(
    field: *mut PgField,
    epochs: f32,
    report: *mut PgUpdateReport,
) -> PgStatus {
    guard("pg_field_update_proportional", || unsafe {
        update(field, report, |f| f.try_update_proportional(epochs))
    })
}

/// Writes to `*out` whether training is over (stopped, plateaued or at its
/// step limit).
///
/// # Safety
/// `field` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_is_converged(field: *const PgField, out: *mut bool) -> PgStatus {
    guard("pg_field_is_converged", || unsafe {
        ptr::read_into(field, "field", out, |f| Ok(read(&f.inner)?.is_converged()))
    })
}

/// Stops training for good and frees the training memory; the field keeps
/// answering queries, later samples are ignored (counted) and updates do
/// nothing.
///
/// # Safety
/// `field` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_field_stop_training(field: *mut PgField) -> PgStatus {
    guard("pg_field_stop_training", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        write(&field.inner)?.stop_training();
        Ok(())
    })
}

/// Writes the field's training counters to `*out`.
///
/// # Safety
/// `field` must be NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_stats(field: *const PgField, out: *mut PgFieldStats) -> PgStatus {
    guard("pg_field_stats", || unsafe {
        ptr::read_into(field, "field", out, |f| Ok(read(&f.inner)?.stats().into()))
    })
}

/// Saves the field (configuration, bounds, parameters and training state)
/// to the file `path`, atomically (temporary file in the same directory,
/// then rename). Returns `PG_IO` if it cannot be written.
///
/// # Safety
/// `field` must be NULL or a live handle; `path` NULL or a NUL-terminated
/// string.
#[no_mangle]
pub unsafe extern "C" fn pg_field_save(field: *const PgField, path: *const c_char) -> PgStatus {
    guard("pg_field_save", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let path = unsafe { ptr::path(path, "path") }?;
        read(&field.inner)?.save(path)?;
        Ok(())
    })
}

/// Loads a field saved by `pg_field_save` into `*out`; it answers queries
/// exactly as the saved one did and can go on training. Returns `PG_IO` if
/// the file cannot be read and `PG_FORMAT` if it is not a valid field file
/// (corrupt, truncated, another format version). On failure `*out` is NULL.
///
/// # Safety
/// `path` must be NULL or a NUL-terminated string; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_field_load(path: *const c_char, out: *mut *mut PgField) -> PgStatus {
    guard("pg_field_load", || unsafe {
        ptr::new_handle(out, || {
            Ok(GuidingField::load(ptr::path(path, "path")?)?.into())
        })
    })
}

/// Decodes the distribution at each of the `n` query points into `out`
/// (replacing its contents; the queries may be NULL when `n` is 0), spread
/// over the field's threads. The distributions stay valid until the field's
/// next update that applies a step; `out` keeps the field alive.
///
/// Returns `PG_INVALID_ARGUMENT` if a query has a NaN or infinite value; on
/// any failure `out` is left empty.
///
/// # Safety
/// `field` must be NULL or a live handle, `queries` NULL or `n` readable
/// points, `out` NULL or a live `PgDistributions` no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_field_query(
    field: *const PgField,
    n: usize,
    queries: *const PgQueryPoint,
    out: *mut PgDistributions,
) -> PgStatus {
    guard("pg_field_query", || {
        let out = unsafe { ptr::as_mut(out, "out") }?;
        out.clear();
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let queries = unsafe { ptr::slice(queries, n, "queries") }?;
        check_queries(queries)?;
        out.fill(&field.inner, as_query_points(queries))
    })
}

/// Samples one direction per query: `u` holds `2n` numbers in `[0, 1]`,
/// `dirs` receives `3n` floats (unit `wi` vectors), `pdfs` `n` densities (solid
/// angle, `> 0`). Same results as `pg_field_query` then
/// `pg_distributions_sample`, without keeping the distributions. Outputs
/// must not overlap each other or the inputs.
///
/// # Safety
/// `field` NULL or a live handle; each array NULL or of the stated length.
#[no_mangle]
pub unsafe extern "C" fn pg_field_sample(
    field: *const PgField,
    n: usize,
    queries: *const PgQueryPoint,
    u: *const f32,
    dirs: *mut f32,
    pdfs: *mut f32,
) -> PgStatus {
    guard("pg_field_sample", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let (n2, n3) = (times(n, 2, "u")?, times(n, 3, "dirs")?);
        disjoint(
            &[region("dirs", dirs, n3), region("pdfs", pdfs, n)],
            &[region("queries", queries, n), region("u", u, n2)],
        )?;
        let queries = unsafe { ptr::slice(queries, n, "queries") }?;
        let u = unsafe { ptr::slice(u, n2, "u") }?;
        let dirs = unsafe { ptr::slice_mut(dirs, n3, "dirs") }?;
        let pdfs = unsafe { ptr::slice_mut(pdfs, n, "pdfs") }?;
        check_queries(queries)?;
        check_unit_square(u)?;
        let u: Vec<Vec2> = u.chunks_exact(2).map(|c| Vec2::new(c[0], c[1])).collect();
        let mut samples = vec![
            DirectionSample {
                direction: Vec3::Z,
                pdf: 0.0
            };
            n
        ];
        read(&field.inner)?.sample_batch(as_query_points(queries), &u, &mut samples)?;
        write_samples(&samples, dirs, pdfs);
        Ok(())
    })
}

/// Density (solid angle) of `dirs[3i..3i+3]` (finite unit `wi` vectors) under
/// the guide at query `i`, for `n` queries, into `pdfs`.
///
/// # Safety
/// `field` NULL or a live handle; each array NULL or of the stated length.
#[no_mangle]
pub unsafe extern "C" fn pg_field_pdf(
    field: *const PgField,
    n: usize,
    queries: *const PgQueryPoint,
    dirs: *const f32,
    pdfs: *mut f32,
) -> PgStatus {
    guard("pg_field_pdf", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let n3 = times(n, 3, "dirs")?;
        disjoint(
            &[region("pdfs", pdfs, n)],
            &[region("queries", queries, n), region("dirs", dirs, n3)],
        )?;
        let queries = unsafe { ptr::slice(queries, n, "queries") }?;
        let dirs = unsafe { ptr::slice(dirs, n3, "dirs") }?;
        let pdfs = unsafe { ptr::slice_mut(pdfs, n, "pdfs") }?;
        check_queries(queries)?;
        let dirs = unit_directions(dirs)?;
        read(&field.inner)?.pdf_batch(as_query_points(queries), &dirs, pdfs)?;
        Ok(())
    })
}

/// Guide-selection probability (in `[0, 1]`) at each of `n` queries, into
/// `out`: sample the guide with this probability and the BSDF otherwise
/// (one-sample MIS).
///
/// # Safety
/// `field` NULL or a live handle; each array NULL or of length `n`.
#[no_mangle]
pub unsafe extern "C" fn pg_field_selection_probability(
    field: *const PgField,
    n: usize,
    queries: *const PgQueryPoint,
    out: *mut f32,
) -> PgStatus {
    guard("pg_field_selection_probability", || {
        let field = unsafe { ptr::as_ref(field, "field") }?;
        disjoint(&[region("out", out, n)], &[region("queries", queries, n)])?;
        let queries = unsafe { ptr::slice(queries, n, "queries") }?;
        let out = unsafe { ptr::slice_mut(out, n, "out") }?;
        check_queries(queries)?;
        read(&field.inner)?.selection_probability_batch(as_query_points(queries), out)?;
        Ok(())
    })
}
