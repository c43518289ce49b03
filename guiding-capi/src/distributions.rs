//! `PgDistributions`: distributions decoded by `pg_field_query`, sampled
//! and evaluated per lane without another network pass (NPM, NASG).

use crate::field::{check_unit_square, read, unit_directions};
use crate::ptr::{self, disjoint, region, times};
use crate::status::{guard, Failure, PgStatus};
use guiding::{DirectionSample, DistributionBatch, GuidingField, QueryPoint};
use guiding_core::glam::{Vec2, Vec3};
use std::sync::{Arc, RwLock};

/// Decoded distributions (opaque), one per query of the latest
/// `pg_field_query` into it. Create with `pg_distributions_new`, release
/// with `pg_distributions_release`. Holds a reference to its field, so the
/// field's memory lives as long as it does.
#[derive(Default)]
pub struct PgDistributions {
    field: Option<Arc<RwLock<GuidingField>>>,
    /// The batched decodes of the latest query, `QUERY_CHUNK` lanes each.
    batches: Vec<DistributionBatch>,
    len: usize,
}

impl PgDistributions {
    /// Empties it (drops the field reference).
    pub(crate) fn clear(&mut self) {
        self.field = None;
        self.batches.clear();
        self.len = 0;
    }

    /// Decodes `queries` with `field` into it (batched, spread over the
    /// field's threads).
    pub(crate) fn fill(
        &mut self,
        field: &Arc<RwLock<GuidingField>>,
        queries: &[QueryPoint],
    ) -> Result<(), Failure> {
        let f = read(field)?;
        self.batches = f.decode_chunks(queries);
        self.len = queries.len();
        self.field = Some(Arc::clone(field));
        Ok(())
    }

    /// Runs `body(field, batch, start)` for each decoded batch that holds
    /// some of the first `n` lanes (`start`: its first lane), with the field
    /// read-locked (`PG_SIZE_MISMATCH` if it holds fewer than `n`,
    /// `PG_STALE` if the field was updated since they were decoded, checked
    /// before anything is written).
    fn with_batches(
        &self,
        n: usize,
        mut body: impl FnMut(&GuidingField, &DistributionBatch, usize, usize) -> Result<(), Failure>,
    ) -> Result<(), Failure> {
        if n > self.len {
            return Err(Failure::new(
                PgStatus::PG_SIZE_MISMATCH,
                format!(
                    "n = {n} but the distributions hold {} (from the latest pg_field_query)",
                    self.len
                ),
            ));
        }
        let Some(field) = (n > 0).then_some(()).and(self.field.as_ref()) else {
            return Ok(());
        };
        let f = read(field)?;
        // All batches were decoded together (one field, one generation).
        if let Some(first) = self.batches.first().and_then(|b| b.get(0)) {
            f.attach(first)?;
        }
        let mut start = 0;
        for b in &self.batches {
            if start >= n {
                break;
            }
            let m = b.len().min(n - start);
            body(&f, b, start, m)?;
            start += b.len();
        }
        Ok(())
    }
}

/// Creates an empty distributions handle in `*out` (NULL on failure).
///
/// # Safety
/// `out` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_new(out: *mut *mut PgDistributions) -> PgStatus {
    guard("pg_distributions_new", || unsafe {
        ptr::new_handle(out, || Ok(PgDistributions::default()))
    })
}

/// Releases a distributions handle (NULL: no-op), and with it its
/// reference to the field.
///
/// # Safety
/// `distributions` must be NULL or a live handle from
/// `pg_distributions_new` that no other call is using.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_release(distributions: *mut PgDistributions) {
    unsafe { ptr::release("pg_distributions_release", distributions) }
}

/// Writes the number of distributions held (the `n` of the latest
/// successful `pg_field_query`, else 0) to `*out`.
///
/// # Safety
/// `distributions` NULL or a live handle; `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_len(
    distributions: *const PgDistributions,
    out: *mut usize,
) -> PgStatus {
    guard("pg_distributions_len", || unsafe {
        ptr::read_into(distributions, "distributions", out, |d| Ok(d.len))
    })
}

/// Samples the first `n` distributions, one direction each: `u` holds `2n`
/// numbers in `[0, 1]`, `dirs` receives `3n` floats (unit `wi` vectors) and
/// `pdfs` `n` densities (solid angle, `> 0`). Returns `PG_SIZE_MISMATCH` if
/// `n` exceeds the number held and `PG_STALE` if the field was updated since
/// the query (outputs untouched).
///
/// # Safety
/// `distributions` NULL or a live handle; each array NULL or of the stated
/// length.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_sample(
    distributions: *const PgDistributions,
    n: usize,
    u: *const f32,
    dirs: *mut f32,
    pdfs: *mut f32,
) -> PgStatus {
    guard("pg_distributions_sample", || {
        let d = unsafe { ptr::as_ref(distributions, "distributions") }?;
        let (n2, n3) = (times(n, 2, "u")?, times(n, 3, "dirs")?);
        disjoint(
            &[region("dirs", dirs, n3), region("pdfs", pdfs, n)],
            &[region("u", u, n2)],
        )?;
        let u = unsafe { ptr::slice(u, n2, "u") }?;
        let dirs = unsafe { ptr::slice_mut(dirs, n3, "dirs") }?;
        let pdfs = unsafe { ptr::slice_mut(pdfs, n, "pdfs") }?;
        check_unit_square(u)?;
        let mut samples = Vec::new();
        d.with_batches(n, |f, b, start, m| {
            let lanes: Vec<u32> = (0..m as u32).collect();
            let us: Vec<Vec2> = (start..start + m)
                .map(|i| Vec2::new(u[2 * i], u[2 * i + 1]))
                .collect();
            samples.resize(
                m,
                DirectionSample {
                    direction: Vec3::ZERO,
                    pdf: 0.0,
                },
            );
            f.sample_decoded(b, &lanes, &us, &mut samples)?;
            for (k, s) in samples.iter().enumerate() {
                let i = start + k;
                dirs[3 * i..3 * i + 3].copy_from_slice(&s.direction.to_array());
                pdfs[i] = s.pdf;
            }
            Ok(())
        })
    })
}

/// Density (solid angle) of `dirs[3i..3i+3]` (finite unit `wi` vectors) under
/// distribution `i`, for the first `n`, into `pdfs`. Errors as
/// `pg_distributions_sample`.
///
/// # Safety
/// `distributions` NULL or a live handle; each array NULL or of the stated
/// length.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_pdf(
    distributions: *const PgDistributions,
    n: usize,
    dirs: *const f32,
    pdfs: *mut f32,
) -> PgStatus {
    guard("pg_distributions_pdf", || {
        let d = unsafe { ptr::as_ref(distributions, "distributions") }?;
        let n3 = times(n, 3, "dirs")?;
        disjoint(&[region("pdfs", pdfs, n)], &[region("dirs", dirs, n3)])?;
        let dirs = unsafe { ptr::slice(dirs, n3, "dirs") }?;
        let pdfs = unsafe { ptr::slice_mut(pdfs, n, "pdfs") }?;
        let dirs = unit_directions(dirs)?;
        d.with_batches(n, |f, b, start, m| {
            let lanes: Vec<u32> = (0..m as u32).collect();
            f.pdf_decoded(
                b,
                &lanes,
                &dirs[start..start + m],
                &mut pdfs[start..start + m],
            )?;
            Ok(())
        })
    })
}

/// Guide-selection probability (in `[0, 1]`) of the first `n`
/// distributions, into `out`. Errors as `pg_distributions_sample`.
///
/// # Safety
/// `distributions` NULL or a live handle; `out` NULL or of length `n`.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_selection_probability(
    distributions: *const PgDistributions,
    n: usize,
    out: *mut f32,
) -> PgStatus {
    guard("pg_distributions_selection_probability", || {
        let d = unsafe { ptr::as_ref(distributions, "distributions") }?;
        let out = unsafe { ptr::slice_mut(out, n, "out") }?;
        d.with_batches(n, |_, b, start, m| {
            for (k, o) in out[start..start + m].iter_mut().enumerate() {
                *o = b.selection_probability(k);
            }
            Ok(())
        })
    })
}

impl PgDistributions {
    /// Runs `body(batch, start, m)` on each decoded batch holding some of the
    /// first `n` lanes (as `with_batches`, mutable), after the same checks:
    /// `PG_SIZE_MISMATCH` if it holds fewer than `n`, `PG_STALE` if the field
    /// was updated since the query. `body` returns whether it could multiply
    /// (vMF lanes); a `false` is `PG_INVALID_ARGUMENT` naming `what` (the
    /// first batch's, before any changed: all are of one field).
    fn multiply_batches(
        &mut self,
        n: usize,
        what: &str,
        mut body: impl FnMut(&mut DistributionBatch, usize, usize) -> bool,
    ) -> Result<(), Failure> {
        self.with_batches(n, |_, _, _, _| Ok(()))?;
        if n == 0 {
            return Ok(());
        }
        // All batches are of one field: the first refuses or none does.
        let mut start = 0;
        for b in &mut self.batches {
            if start >= n {
                break;
            }
            let m = b.len().min(n - start);
            if !body(b, start, m) {
                return Err(Failure::invalid(format!(
                    "{what} needs vMF mixtures (PG_REPRESENTATION_NPM; the lobe product: \
                     decoded on the CPU); NASG and DF have no closed-form product"
                )));
            }
            start += b.len();
        }
        Ok(())
    }
}

/// Multiplies the first `n` distributions by the clamped cosine of their
/// normals (`normals`: `3n` finite floats; NPM §4.2, Open PGL's
/// `ApplyCosineProduct`, Rust `DistributionBatch::apply_cosine_product`):
/// a radiance guide then samples `∝ L_i · cos`. A zero normal ("no surface",
/// a scattering point in a medium) leaves its distribution as it is; others
/// are normalised. Later `pg_distributions_sample` / `_pdf` use the product
/// (exact densities of what they sample); a second call multiplies again.
/// `PG_INVALID_ARGUMENT` for NASG and DF distributions (no closed form) and
/// non-finite normals; `PG_SIZE_MISMATCH`, `PG_STALE` as
/// `pg_distributions_sample` (nothing changed then).
///
/// # Safety
/// `distributions` NULL or a live handle no other call is using; `normals`
/// NULL or of length `3n`.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_apply_cosine_product(
    distributions: *mut PgDistributions,
    n: usize,
    normals: *const f32,
) -> PgStatus {
    guard("pg_distributions_apply_cosine_product", || {
        let d = unsafe { ptr::as_mut(distributions, "distributions") }?;
        let n3 = times(n, 3, "normals")?;
        let normals = unsafe { ptr::slice(normals, n3, "normals") }?;
        let normals = finite_vectors(normals, "normals")?;
        d.multiply_batches(n, "the cosine product", |b, start, m| {
            b.apply_cosine_product(&normals[start..start + m])
        })
    })
}

/// Multiplies the first `n` distributions by vMF lobes
/// `e^{κᵢ (aᵢ·ω − 1)}` (`axes`: `3n` floats, each axis finite and non-zero
/// where `κᵢ > 0`, normalised; `kappas`: `n` finite values `≥ 0`, `0`
/// leaving the distribution as it is), in closed form (Rust
/// `DistributionBatch::apply_lobe_product`): at a scattering point in a
/// medium, the product of a radiance guide with the vMF fit of the phase
/// function (`pg_hg_vmf_kappa`, its axis the forward direction `−wo` for
/// `g > 0`, `wo` for `g < 0`), as Open PGL guides in volumes. Later samples
/// and pdfs use the product; a second call multiplies again. Errors as
/// `pg_distributions_apply_cosine_product`.
///
/// # Safety
/// `distributions` NULL or a live handle no other call is using; each array
/// NULL or of the stated length.
#[no_mangle]
pub unsafe extern "C" fn pg_distributions_apply_lobe_product(
    distributions: *mut PgDistributions,
    n: usize,
    axes: *const f32,
    kappas: *const f32,
) -> PgStatus {
    guard("pg_distributions_apply_lobe_product", || {
        let d = unsafe { ptr::as_mut(distributions, "distributions") }?;
        let n3 = times(n, 3, "axes")?;
        let axes = unsafe { ptr::slice(axes, n3, "axes") }?;
        let kappas = unsafe { ptr::slice(kappas, n, "kappas") }?;
        let axes = finite_vectors(axes, "axes")?;
        for (i, (&k, a)) in kappas.iter().zip(&axes).enumerate() {
            if !(k >= 0.0 && k.is_finite()) {
                return Err(Failure::invalid(format!(
                    "kappas[{i}] = {k} is not a finite value >= 0"
                )));
            }
            if k > 0.0 && guiding_core::frame::is_no_surface(*a) {
                return Err(Failure::invalid(format!(
                    "axes[{i}] is zero where kappas[{i}] = {k} > 0"
                )));
            }
        }
        d.multiply_batches(n, "the lobe product", |b, start, m| {
            let lanes: Vec<u32> = (0..m as u32).collect();
            b.apply_lobe_product(&lanes, &axes[start..start + m], &kappas[start..start + m])
        })
    })
}

/// The vectors of a `3n`-float array, each finite (any length).
fn finite_vectors(v: &[f32], what: &str) -> Result<Vec<Vec3>, Failure> {
    v.chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let x = Vec3::new(c[0], c[1], c[2]);
            if x.is_finite() {
                Ok(x)
            } else {
                Err(Failure::invalid(format!(
                    "{what}[{i}] = {x} has a NaN or infinite value"
                )))
            }
        })
        .collect()
}
