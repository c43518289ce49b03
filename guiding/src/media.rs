//! Which participating media a renderer guides: the thin-medium rule.
//!
//! A scattering point inside a medium is guided like a surface vertex (a query with a zero
//! normal, see [`crate::DistributionBatch::apply_lobe_product`]), at a surface vertex's cost:
//! the decode or cache lookup, the guide's density for every MIS weight, a training sample.
//! What it can buy is bounded by how much light scatters in the medium at all. A ray that
//! crosses a medium of scattering optical depth
//!
//! ```text
//! τ_s = σ_s,max · d
//! ```
//!
//! (`σ_s,max` the largest scattering coefficient over the medium and its colour channels, `d`
//! the diagonal of the region it fills: the box of the shapes it is the interior of, or the
//! scene's box for a medium around the camera or outside a shape) scatters in it with
//! probability at most `1 − e^{−τ_s}`. Below [`MIN_GUIDED_SCATTERING_DEPTH`] = 0.05 fewer
//! than one path in twenty that crosses the medium has a vertex in it, and those vertices
//! carry at most that share of the light through it: their guiding cannot lower the image's
//! variance by more than a few per cent, while the guide's queries, pdfs and training samples
//! are paid at every one of them, and their full-sphere samples share the grid cells with the
//! surfaces'. [`guides_medium`] says no; the renderer samples the phase function there, does
//! not train on those vertices, and reports it (host-demo: `stages.media` in `--stats`).
//!
//! The threshold is a bound on the share of the light, not a constant fitted to a scene:
//! `docs/bench-2026-12-07-media` measures guided renders with and without guided media on the
//! fog-filled room at four densities (τ_s from 0.02 to 1.06) and on the lamp in smoke.

/// The scattering optical depth below which a medium is not guided (see the
/// [module docs](self)): a ray crossing it scatters there with probability below
/// `1 − e^{−0.05}` ≈ 4.9 %.
pub const MIN_GUIDED_SCATTERING_DEPTH: f32 = 0.05;

/// The scattering optical depth `τ_s = σ_s,max · d` of a medium whose largest scattering
/// coefficient is `max_scattering` over a region of diagonal `extent` (both `≥ 0`; an
/// infinite extent, a medium without bounds, gives an infinite depth unless it does not
/// scatter). `None` for a negative or NaN input.
#[must_use]
pub fn scattering_depth(max_scattering: f32, extent: f32) -> Option<f32> {
    if !(max_scattering >= 0.0 && extent >= 0.0) {
        return None;
    }
    if max_scattering == 0.0 || extent == 0.0 {
        return Some(0.0);
    }
    Some(max_scattering * extent)
}

/// Whether a medium's scattering points are worth guiding: its [`scattering_depth`] is at
/// least [`MIN_GUIDED_SCATTERING_DEPTH`] (`false` for a negative or NaN input).
#[must_use]
pub fn guides_medium(max_scattering: f32, extent: f32) -> bool {
    scattering_depth(max_scattering, extent).is_some_and(|t| t >= MIN_GUIDED_SCATTERING_DEPTH)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rule_is_the_depth_against_the_threshold() {
        // The fog room of the bench: σs = 0.108 over the scene's 9.8 diagonal.
        assert!(guides_medium(0.108, 9.8));
        assert!(!guides_medium(0.002, 9.8));
        // At the threshold exactly, and just below it.
        assert!(guides_medium(0.05, 1.0));
        assert!(!guides_medium(0.049_999, 1.0));
        assert_eq!(scattering_depth(0.0, f32::INFINITY), Some(0.0));
        assert_eq!(scattering_depth(1e-3, f32::INFINITY), Some(f32::INFINITY));
        assert!(guides_medium(1e-3, f32::INFINITY));
        for bad in [(-1.0, 1.0), (1.0, -1.0), (f32::NAN, 1.0), (1.0, f32::NAN)] {
            assert_eq!(scattering_depth(bad.0, bad.1), None);
            assert!(!guides_medium(bad.0, bad.1));
        }
    }
}
