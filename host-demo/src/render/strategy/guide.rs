//! The guide of the `guided` integrator.
//!
//! [`build_guide`] maps the CLI's choices onto the embedding facade's
//! [`guiding::GuidingField`] (model + online trainer + EMA weights over every representation
//! and size), so the renderer uses the library exactly as a third-party renderer would. Batched queries run serially on the
//! calling render thread (the renderer already runs one thread per core; nesting the field's
//! own thread pool inside each render thread would oversubscribe).
//!
//! # Model sizes
//!
//! * [`ModelSize::Compact`] (default): a 4-level dense grid (4,
//!   8, 16, 32 cells per axis, 4 features per vertex: 166 816 parameters) and MLPs of 2 hidden
//!   layers × 32. About 25× fewer parameters than the paper grids and ~4× cheaper per query,
//!   so a 320×240 image trains and renders in about a minute on 2 cores.
//! * [`ModelSize::Small`]: the library's test presets (2-level grid, MLP 2 × 16, 608 grid
//!   parameters) — fast, used by the tests.
//! * [`ModelSize::Paper`]: the papers' sizes (4.1 M grid parameters; slow on a CPU).

use glam::Vec3;
use guiding::{GuidingConfig, GuidingField, ModelSize, Representation};
use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;

/// Human-readable description of a guide: representation, target, size and parameter count.
pub fn describe(field: &GuidingField) -> String {
    let c = field.config();
    format!(
        "{:?} {:?} {:?} ({} parameters)",
        c.representation,
        c.target,
        c.size,
        field.param_count()
    )
}

/// Builds a guide over the box `[bbox_min, bbox_max]` (the facade pads it by 1 % so surface
/// points on the box never sit exactly on the grid boundary). `selection` is the constant
/// guide-selection probability of NPM / DF (NASG learns its own).
pub fn build_guide(
    representation: Representation,
    target: Target,
    size: ModelSize,
    bbox: (Vec3, Vec3),
    selection: f32,
    config: FieldConfig,
) -> crate::Result<GuidingField> {
    let config = GuidingConfig {
        representation,
        target,
        size,
        selection_probability: selection,
        training: config,
    };
    // Degenerate (flat) scene boxes get a minimal thickness, as before the facade existed.
    let (lo, hi) = (bbox.0, bbox.1.max(bbox.0 + Vec3::splat(1e-3)));
    GuidingField::new(config, lo.to_array(), hi.to_array())
        .map_err(|e| crate::Error::Scene(format!("guiding field: {e}")))
}
