//! Russian roulette and splitting by the library's weight window (`guiding::roulette`, whose
//! docs give the rule, ADRRS of Vorba and Křivánek 2016, and its deviations): the window's
//! decision per path vertex (`pg_weight_window_decide`), the radiance grid that learns the
//! reflected radiance `L̂` it weighs a path by (`PgRadianceGrid`, fed by a recorder with
//! `pg_recorder_keep_reflected`), and the filtered pixel estimates `Î`
//! (`pg_pixel_estimates`).
//!
//! ```c
//! /* training phase: record paths, keep their reflected radiance, feed the grid */
//! pg_recorder_keep_reflected(recorder, true);
//! ... pg_recorder_end_path(recorder, NULL);
//! pg_recorder_flush_reflected_into(recorder, grid, NULL);
//! /* every pass: the pixels' estimates from the running sums */
//! pg_pixel_estimates(w, h, sums, passes, 2, pixel_estimate);
//! /* at a vertex, before NEE and direction sampling */
//! pg_radiance_grid_estimate(grid, 1, p, n, l_hat);
//! pg_weight_window_decide(&window, 1, beta, l_hat, &pixel_estimate[pix], &u, &room, &d);
//! /* d.count continuations, each with throughput beta * d.weight */
//! ```

use crate::field::check_unit_square;
use crate::ptr::{self, disjoint, region, times, triples};
use crate::status::{guard, Failure, PgStatus};
use guiding::{GridOptions, RadianceGrid, WeightWindow};
use std::sync::{PoisonError, RwLock};

/// The weight window's settings (`guiding::WeightWindow`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgWeightWindow {
    /// `s > 1`: the window's upper bound over its lower bound (5).
    pub ratio: f32,
    /// The most continuations one vertex may spawn, `≥ 1` (8).
    pub max_split: u32,
    /// The least survival probability of roulette, in `(0, 1]` (0.05).
    pub min_survival: f32,
}

impl From<PgWeightWindow> for WeightWindow {
    fn from(w: PgWeightWindow) -> Self {
        Self {
            ratio: w.ratio,
            max_split: w.max_split,
            min_survival: w.min_survival,
        }
    }
}

/// What the window decided for one path at one vertex (`guiding::Decision`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PgDecision {
    /// Continuations to trace from the vertex (0: the path ends here).
    pub count: u32,
    /// The factor on each continuation's throughput.
    pub weight: f32,
}

/// Options of a `PgRadianceGrid` (`guiding::GridOptions`) and the box it covers.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgRadianceGridArgs {
    /// The scene's bounding box (finite, `min ≤ max`); positions outside fall into the
    /// nearest cell.
    pub bounds_min: [f32; 3],
    /// See `bounds_min`.
    pub bounds_max: [f32; 3],
    /// Fine cells along the longest side, `≥ 1` (32).
    pub resolution: u32,
    /// Coarse cells along the longest side, `≥ 1` (8).
    pub coarse_resolution: u32,
    /// Estimates a cell's own mean needs to weigh as much as its parent's, `≥ 1` (16).
    pub prior_weight: u32,
}

/// What a `PgRadianceGrid` holds (`guiding::GridStats`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PgRadianceGridStats {
    /// Estimates added.
    pub samples: u64,
    /// Estimates refused (a non-finite position, a negative or non-finite radiance).
    pub rejected: u64,
    /// Fine cells with at least `prior_weight` estimates.
    pub fine_cells: u64,
    /// Coarse cells with at least `prior_weight` estimates.
    pub coarse_cells: u64,
}

/// A radiance grid (opaque), internally synchronised: estimates may run from many threads at
/// once; adding takes it exclusively. Create with `pg_radiance_grid_new`, release with
/// `pg_radiance_grid_release`.
pub struct PgRadianceGrid {
    pub(crate) inner: RwLock<RadianceGrid>,
}

impl PgRadianceGrid {
    pub(crate) fn write(&self) -> std::sync::RwLockWriteGuard<'_, RadianceGrid> {
        self.inner.write().unwrap_or_else(PoisonError::into_inner)
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, RadianceGrid> {
        self.inner.read().unwrap_or_else(PoisonError::into_inner)
    }
}

/// Fills `*window` with the library's defaults (`ratio` 5, `max_split` 8, `min_survival`
/// 0.05).
///
/// # Safety
/// `window` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_weight_window_set_defaults(window: *mut PgWeightWindow) -> PgStatus {
    guard("pg_weight_window_set_defaults", || unsafe {
        ptr::write_whole(window, "window", || {
            let d = WeightWindow::default();
            Ok(PgWeightWindow {
                ratio: d.ratio,
                max_split: d.max_split,
                min_survival: d.min_survival,
            })
        })
    })
}

/// The window's decision for `n` path vertices: path `i` has throughput
/// `beta[3i..3i+3]` (RGB), the vertex reflects `radiance[3i..3i+3]` towards it (an estimate
/// such as `pg_radiance_grid_estimate`'s; a negative or non-finite channel means none), its
/// pixel is estimated at `pixel[i]` (luminance; `≤ 0` or non-finite means none), `u[i]` is a
/// uniform number in `[0, 1]` and `room[i]` how many more continuations the path may spawn.
/// Writes `out[i]`: `m = Y(β ⊙ L̂) / Î` outside the window `[2/(1+s), 2s/(1+s)]` (1 inside it
/// and where an estimate is missing) clamped to `[min_survival, max_split]`; below 1 one
/// continuation of weight `1/m` if `u < m`, else none; from 1 on
/// `k = min(⌊m⌋ + [u < m − ⌊m⌋], 1 + room)` continuations of weight `1/k`.
///
/// Returns `PG_INVALID_ARGUMENT` (outputs untouched) for window settings out of range or a
/// `u` outside `[0, 1]`.
///
/// # Safety
/// `window` NULL or readable; each array NULL or of the stated length.
#[no_mangle]
pub unsafe extern "C" fn pg_weight_window_decide(
    window: *const PgWeightWindow,
    n: usize,
    beta: *const f32,
    radiance: *const f32,
    pixel: *const f32,
    u: *const f32,
    room: *const u32,
    out: *mut PgDecision,
) -> PgStatus {
    guard("pg_weight_window_decide", || {
        let window: WeightWindow = (*unsafe { ptr::as_ref(window, "window") }?).into();
        window.validate()?;
        let n3 = times(n, 3, "beta")?;
        disjoint(
            &[region("out", out, n)],
            &[
                region("beta", beta, n3),
                region("radiance", radiance, n3),
                region("pixel", pixel, n),
                region("u", u, n),
                region("room", room, n),
            ],
        )?;
        let beta = unsafe { triples(beta, n, "beta") }?;
        let radiance = unsafe { triples(radiance, n, "radiance") }?;
        let pixel = unsafe { ptr::slice(pixel, n, "pixel") }?;
        let u = unsafe { ptr::slice(u, n, "u") }?;
        let room = unsafe { ptr::slice(room, n, "room") }?;
        let out = unsafe { ptr::slice_mut(out, n, "out") }?;
        check_unit_square(u)?;
        for (i, o) in out.iter_mut().enumerate() {
            let d = window.decide(beta[i], radiance[i], pixel[i], u[i], room[i]);
            *o = PgDecision {
                count: d.count,
                weight: d.weight,
            };
        }
        Ok(())
    })
}

fn options_of(args: &PgRadianceGridArgs) -> GridOptions {
    GridOptions {
        resolution: args.resolution,
        coarse_resolution: args.coarse_resolution,
        prior_weight: args.prior_weight,
    }
}

/// Fills `*args` with the library's defaults (32 fine and 8 coarse cells along the longest
/// side, prior weight 16) and a box of NaN, which the caller must set.
///
/// # Safety
/// `args` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_args_set_defaults(
    args: *mut PgRadianceGridArgs,
) -> PgStatus {
    guard("pg_radiance_grid_args_set_defaults", || unsafe {
        ptr::write_whole(args, "args", || {
            let d = GridOptions::default();
            Ok(PgRadianceGridArgs {
                bounds_min: [f32::NAN; 3],
                bounds_max: [f32::NAN; 3],
                resolution: d.resolution,
                coarse_resolution: d.coarse_resolution,
                prior_weight: d.prior_weight,
            })
        })
    })
}

/// Creates an empty radiance grid over `args`' box in `*out` (NULL on failure).
///
/// Returns `PG_INVALID_ARGUMENT` for a box that is not finite with `min ≤ max`, or an option
/// of 0.
///
/// # Safety
/// `args` NULL or readable; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_new(
    args: *const PgRadianceGridArgs,
    out: *mut *mut PgRadianceGrid,
) -> PgStatus {
    guard("pg_radiance_grid_new", || unsafe {
        ptr::new_handle(out, || {
            let a = ptr::as_ref(args, "args")?;
            let grid = RadianceGrid::new(a.bounds_min, a.bounds_max, options_of(a))?;
            Ok(PgRadianceGrid {
                inner: RwLock::new(grid),
            })
        })
    })
}

/// Releases a radiance grid (NULL: no-op).
///
/// # Safety
/// `grid` must be NULL or a live handle that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_release(grid: *mut PgRadianceGrid) {
    unsafe { ptr::release("pg_radiance_grid_release", grid) }
}

/// Adds `n` estimates of reflected radiance: `radiance[3i..3i+3]` (RGB) leaving
/// `positions[3i..3i+3]` (shading normal `normals[3i..3i+3]`, zeros if unknown). Estimates
/// with a non-finite position or a negative or non-finite radiance are refused and counted;
/// writes how many were kept to `*kept` unless it is NULL.
///
/// # Safety
/// `grid` NULL or a live handle; each array NULL or of the stated length; `kept` NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_add(
    grid: *const PgRadianceGrid,
    n: usize,
    positions: *const f32,
    normals: *const f32,
    radiance: *const f32,
    kept: *mut u64,
) -> PgStatus {
    guard("pg_radiance_grid_add", || {
        let g = unsafe { ptr::as_ref(grid, "grid") }?;
        let positions = unsafe { triples(positions, n, "positions") }?;
        let normals = unsafe { triples(normals, n, "normals") }?;
        let radiance = unsafe { triples(radiance, n, "radiance") }?;
        let kept = unsafe { ptr::as_mut_opt(kept, "kept") }?;
        let mut inner = g.write();
        let count = (0..n)
            .filter(|&i| inner.add(positions[i], normals[i], radiance[i]))
            .count();
        if let Some(k) = kept {
            *k = count as u64;
        }
        Ok(())
    })
}

/// The grid's reflected radiance at `n` points (`positions[3i..3i+3]`, shading normals
/// `normals[3i..3i+3]`) into `out[3i..3i+3]` (RGB): the fine cell's mean shrunk towards the
/// coarse cell's, shrunk towards the global mean; `-1, -1, -1` where there is none (an empty
/// grid, a non-finite position), which `pg_weight_window_decide` reads as missing.
///
/// # Safety
/// `grid` NULL or a live handle; each array NULL or of the stated length.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_estimate(
    grid: *const PgRadianceGrid,
    n: usize,
    positions: *const f32,
    normals: *const f32,
    out: *mut f32,
) -> PgStatus {
    guard("pg_radiance_grid_estimate", || {
        let g = unsafe { ptr::as_ref(grid, "grid") }?;
        let n3 = times(n, 3, "positions")?;
        let (p, nrm) = (
            region("positions", positions, n3),
            region("normals", normals, n3),
        );
        disjoint(&[region("out", out, n3)], &[p, nrm])?;
        let positions = unsafe { triples(positions, n, "positions") }?;
        let normals = unsafe { triples(normals, n, "normals") }?;
        let out = unsafe { ptr::slice_mut(out.cast::<[f32; 3]>(), n, "out") }?;
        let mut estimates = Vec::with_capacity(n);
        g.read()
            .estimate_batch(positions, normals, &mut estimates)?;
        out.copy_from_slice(&estimates);
        Ok(())
    })
}

/// What the grid holds, into `*out`.
///
/// # Safety
/// `grid` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_radiance_grid_stats(
    grid: *const PgRadianceGrid,
    out: *mut PgRadianceGridStats,
) -> PgStatus {
    guard("pg_radiance_grid_stats", || {
        let g = unsafe { ptr::as_ref(grid, "grid") }?;
        let s = g.read().stats();
        unsafe {
            ptr::write_whole(out, "out", || {
                Ok(PgRadianceGridStats {
                    samples: s.samples,
                    rejected: s.rejected,
                    fine_cells: s.fine_cells,
                    coarse_cells: s.coarse_cells,
                })
            })
        }
    })
}

/// The pixel estimates `Î` of a `width × height` image (row-major) from its running sums
/// `sum[3p..3p+3]` (RGB, double) over `passes` passes: the luminance of the mean,
/// box-filtered over `(2·radius + 1)²` pixels (clipped at the border), into `out[p]`; all 0
/// when `passes` is 0. Returns `PG_INVALID_ARGUMENT` if `width × height` overflows.
///
/// # Safety
/// `sum` NULL or of `3 · width · height` doubles; `out` NULL or of `width · height` floats.
#[no_mangle]
pub unsafe extern "C" fn pg_pixel_estimates(
    width: u32,
    height: u32,
    sum: *const f64,
    passes: u32,
    radius: u32,
    out: *mut f32,
) -> PgStatus {
    guard("pg_pixel_estimates", || {
        let pixels = times(width as usize, height as usize, "width x height")?;
        let n3 = times(pixels, 3, "sum")?;
        disjoint(&[region("out", out, pixels)], &[region("sum", sum, n3)])?;
        let sum = unsafe { ptr::slice(sum, n3, "sum") }?;
        let out = unsafe { ptr::slice_mut(out, pixels, "out") }?;
        let rgb: Vec<[f64; 3]> = sum.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let mut estimates = Vec::with_capacity(pixels);
        guiding::pixel_estimates(width, height, &rgb, passes, radius, &mut estimates)
            .map_err(Failure::from)?;
        out.copy_from_slice(&estimates);
        Ok(())
    })
}
