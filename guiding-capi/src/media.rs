//! Participating media: the phase function's lobe for the product at a scattering point
//! (`pg_hg_vmf_kappa`, used with `pg_distributions_apply_lobe_product`) and the library's
//! rule for which media to guide (`pg_guides_medium`, Rust `guiding::media`).
//!
//! ```c
//! /* once per medium: guide its scattering points? */
//! float depth; bool guided;
//! pg_guides_medium(max_sigma_s, diagonal_of_its_region, &depth, &guided);
//! /* at the medium vertices of a batch, after pg_field_query (NPM) */
//! pg_hg_vmf_kappa(g, &kappa);                 /* axis: -wo for g > 0, wo for g < 0 */
//! pg_distributions_apply_lobe_product(dists, n, axes, kappas);
//! ```

use crate::ptr;
use crate::status::{guard, Failure, PgStatus};

/// The concentration `κ` of the vMF lobe fitted to a Henyey–Greenstein phase
/// function of asymmetry `g ∈ (−1, 1)` (equal mean cosine `|g|`, Rust
/// `guiding_core::lobe::vmf::hg_vmf_kappa`; `0` for `g = 0`), into `*out`:
/// the `κ` of `pg_distributions_apply_lobe_product` at a medium vertex.
/// `PG_INVALID_ARGUMENT` for `g` outside `(−1, 1)` or NaN.
///
/// # Safety
/// `out` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_hg_vmf_kappa(g: f32, out: *mut f32) -> PgStatus {
    guard("pg_hg_vmf_kappa", || {
        if !(g > -1.0 && g < 1.0) {
            return Err(Failure::invalid(format!(
                "g = {g} is not in (-1, 1) (a Henyey-Greenstein asymmetry)"
            )));
        }
        let out = unsafe { ptr::as_mut(out, "out") }?;
        *out = guiding_core::lobe::vmf::hg_vmf_kappa(g);
        Ok(())
    })
}

/// The library's thin-medium rule (Rust `guiding::media`, whose docs give the reasoning): a
/// medium whose largest scattering coefficient is `max_scattering` (over its volume and
/// colour channels) over a region of diagonal `extent` (the box of the shapes it fills, or
/// the scene's box for a medium around the camera; `INFINITY` for one without bounds) has
/// the scattering optical depth `τ_s = max_scattering · extent`, written to `*depth` (may
/// be NULL), and is worth guiding when `τ_s ≥ 0.05` (`PG_MIN_GUIDED_SCATTERING_DEPTH`),
/// written to `*guided`. `PG_INVALID_ARGUMENT` for a negative or NaN input.
///
/// # Safety
/// `depth` NULL or writable; `guided` NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn pg_guides_medium(
    max_scattering: f32,
    extent: f32,
    depth: *mut f32,
    guided: *mut bool,
) -> PgStatus {
    guard("pg_guides_medium", || {
        let guided = unsafe { ptr::as_mut(guided, "guided") }?;
        let tau = guiding::media::scattering_depth(max_scattering, extent).ok_or_else(|| {
            Failure::invalid(format!(
                "max_scattering = {max_scattering} and extent = {extent} must be >= 0 (not NaN)"
            ))
        })?;
        if !depth.is_null() {
            // SAFETY: non-NULL and writable by the contract.
            unsafe { *depth = tau };
        }
        *guided = guiding::media::guides_medium(max_scattering, extent);
        Ok(())
    })
}

/// The scattering optical depth below which `pg_guides_medium` says a medium is not worth
/// guiding (Rust `guiding::media::MIN_GUIDED_SCATTERING_DEPTH`; a literal for cbindgen,
/// equal to it by a test).
pub const PG_MIN_GUIDED_SCATTERING_DEPTH: f32 = 0.05;

#[cfg(test)]
mod tests {
    #[test]
    fn the_c_threshold_is_the_library_threshold() {
        assert_eq!(
            super::PG_MIN_GUIDED_SCATTERING_DEPTH,
            guiding::media::MIN_GUIDED_SCATTERING_DEPTH
        );
    }
}
