//! `PgRecorder`: records path vertices and turns finished paths into
//! training samples (the `guiding::PathRecorder`, whose docs give the
//! radiance propagation).

use crate::field::{write, PgField};
use crate::ptr;
use crate::roulette::PgRadianceGrid;
use crate::status::{guard, PgStatus};
use crate::types::PgPathVertex;
use guiding::PathRecorder;

/// A path recorder (opaque). Not synchronised: use one per render thread.
/// Create with `pg_recorder_new`, release with `pg_recorder_release`.
#[derive(Default)]
pub struct PgRecorder {
    inner: PathRecorder,
}

/// Fills `*vertex` with the defaults: zeros, except `roughness`,
/// `emitted_mis_weight` and `continuation_scale`, which are 1.
///
/// # Safety
/// `vertex` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_path_vertex_set_defaults(vertex: *mut PgPathVertex) -> PgStatus {
    guard("pg_path_vertex_set_defaults", || {
        *unsafe { ptr::as_mut(vertex, "vertex") }? = PgPathVertex::defaults();
        Ok(())
    })
}

/// Creates an empty recorder in `*out` (NULL on failure).
///
/// # Safety
/// `out` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_new(out: *mut *mut PgRecorder) -> PgStatus {
    guard("pg_recorder_new", || unsafe {
        ptr::new_handle(out, || Ok(PgRecorder::default()))
    })
}

/// Releases a recorder (NULL: no-op); samples not flushed are lost.
///
/// # Safety
/// `recorder` must be NULL or a live handle that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_release(recorder: *mut PgRecorder) {
    unsafe { ptr::release("pg_recorder_release", recorder) }
}

/// Starts a new path (an unfinished previous path is discarded).
///
/// # Safety
/// `recorder` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_start_path(recorder: *mut PgRecorder) -> PgStatus {
    guard("pg_recorder_start_path", || {
        unsafe { ptr::as_mut(recorder, "recorder") }?
            .inner
            .start_path();
        Ok(())
    })
}

/// Records the next vertex of the current path (vertex 0 is the first hit
/// seen from the camera). Values are not checked here: a path with NaN or
/// negative values yields samples that the field rejects and counts.
///
/// # Safety
/// `recorder` NULL or a live handle; `vertex` NULL or readable.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_add_vertex(
    recorder: *mut PgRecorder,
    vertex: *const PgPathVertex,
) -> PgStatus {
    guard("pg_recorder_add_vertex", || {
        let r = unsafe { ptr::as_mut(recorder, "recorder") }?;
        let v = unsafe { ptr::as_ref(vertex, "vertex") }?;
        r.inner.add_vertex((*v).into());
        Ok(())
    })
}

/// Adds radiance `rgb[0..3]` (times `mis_weight`) arriving along the last
/// vertex's `wi` from outside the scene (an environment light); adds up
/// over calls.
///
/// # Safety
/// `recorder` NULL or a live handle; `rgb` NULL or 3 readable floats.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_add_escaped_radiance(
    recorder: *mut PgRecorder,
    rgb: *const f32,
    mis_weight: f32,
) -> PgStatus {
    guard("pg_recorder_add_escaped_radiance", || {
        let r = unsafe { ptr::as_mut(recorder, "recorder") }?;
        let rgb = unsafe { ptr::slice(rgb, 3, "rgb") }?;
        r.inner
            .add_escaped_radiance([rgb[0], rgb[1], rgb[2]], mis_weight);
        Ok(())
    })
}

/// Ends the current path: propagates radiance back along it, keeps one
/// training sample per non-delta vertex that continued (`sample_pdf > 0`),
/// and writes the radiance leaving vertex 0 towards the camera to
/// `out_rgb[0..3]` unless `out_rgb` is NULL.
///
/// # Safety
/// `recorder` NULL or a live handle; `out_rgb` NULL or 3 writable floats.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_end_path(
    recorder: *mut PgRecorder,
    out_rgb: *mut f32,
) -> PgStatus {
    guard("pg_recorder_end_path", || {
        let r = unsafe { ptr::as_mut(recorder, "recorder") }?;
        let out = if out_rgb.is_null() {
            None
        } else {
            Some(unsafe { ptr::slice_mut(out_rgb, 3, "out_rgb") }?)
        };
        let l = r.inner.end_path();
        if let Some(out) = out {
            out.copy_from_slice(&l);
        }
        Ok(())
    })
}

/// Writes the number of training samples of finished paths waiting to be
/// flushed to `*out`.
///
/// # Safety
/// `recorder` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_sample_count(
    recorder: *const PgRecorder,
    out: *mut usize,
) -> PgStatus {
    guard("pg_recorder_sample_count", || unsafe {
        ptr::read_into(recorder, "recorder", out, |r| Ok(r.inner.samples().len()))
    })
}

/// Drops the samples of the finished paths without training on them.
///
/// # Safety
/// `recorder` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_clear_samples(recorder: *mut PgRecorder) -> PgStatus {
    guard("pg_recorder_clear_samples", || {
        unsafe { ptr::as_mut(recorder, "recorder") }?
            .inner
            .clear_samples();
        Ok(())
    })
}

/// Hands the samples of every finished path to `field` (as
/// `pg_field_add_samples`) and clears them; writes how many were handed
/// over to `*out_count` unless it is NULL. Takes the field exclusively.
///
/// # Safety
/// `recorder` NULL or a live handle; `field` NULL or a live handle;
/// `out_count` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_flush_into(
    recorder: *mut PgRecorder,
    field: *mut PgField,
    out_count: *mut usize,
) -> PgStatus {
    guard("pg_recorder_flush_into", || {
        let r = unsafe { ptr::as_mut(recorder, "recorder") }?;
        let field = unsafe { ptr::as_ref(field, "field") }?;
        let out = unsafe { ptr::as_mut_opt(out_count, "out_count") }?;
        let n = r.inner.flush_into(&mut *write(&field.inner)?);
        if let Some(out) = out {
            *out = n;
        }
        Ok(())
    })
}

/// Whether the recorder keeps, for every vertex whose path went on, its reflected radiance
/// `L̃_r = D + β L̃_i` (the path estimate of the light it reflects towards the previous vertex,
/// see `guiding::recorder`), for `pg_recorder_flush_reflected_into`; off by default, and
/// turning it off drops what was kept.
///
/// # Safety
/// `recorder` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_keep_reflected(
    recorder: *mut PgRecorder,
    keep: bool,
) -> PgStatus {
    guard("pg_recorder_keep_reflected", || {
        unsafe { ptr::as_mut(recorder, "recorder") }?
            .inner
            .keep_reflected(keep);
        Ok(())
    })
}

/// Adds the reflected radiance the finished paths kept to `grid` and clears it; writes how
/// many estimates the grid kept to `*out_count` unless it is NULL. The training samples stay.
///
/// # Safety
/// `recorder` NULL or a live handle; `grid` NULL or a live handle; `out_count` NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn pg_recorder_flush_reflected_into(
    recorder: *mut PgRecorder,
    grid: *const PgRadianceGrid,
    out_count: *mut u64,
) -> PgStatus {
    guard("pg_recorder_flush_reflected_into", || {
        let r = unsafe { ptr::as_mut(recorder, "recorder") }?;
        let g = unsafe { ptr::as_ref(grid, "grid") }?;
        let out = unsafe { ptr::as_mut_opt(out_count, "out_count") }?;
        let mut samples = Vec::new();
        r.inner.drain_reflected_into(&mut samples);
        let kept = {
            let mut inner = g.write();
            samples
                .iter()
                .filter(|s| inner.add(s.position, s.normal, s.radiance))
                .count()
        };
        if let Some(o) = out {
            *o = kept as u64;
        }
        Ok(())
    })
}
