//! The guiding models the `guided` integrator can use, behind one object-safe trait.
//!
//! [`build_guide`] maps the CLI's choices onto the embedding facade's
//! [`guiding::GuidingField`] (model + online trainer + EMA weights over every representation
//! and size), so the renderer uses the library exactly as a third-party renderer would. Batched queries run serially on the
//! calling render thread (the renderer already runs one thread per core; nesting the field's
//! own thread pool inside each render thread would oversubscribe).
//!
//! # Model sizes
//!
//! * [`ModelSize::Demo`] (default): [`guiding::ModelSize::Compact`], a 4-level dense grid (4,
//!   8, 16, 32 cells per axis, 4 features per vertex: 166 816 parameters) and MLPs of 2 hidden
//!   layers × 32. About 25× fewer parameters than the paper grids and ~4× cheaper per query,
//!   so a 320×240 image trains and renders in about a minute on 2 cores.
//! * [`ModelSize::Small`]: the library's test presets (2-level grid, MLP 2 × 16, 608 grid
//!   parameters) — fast, used by the tests.
//! * [`ModelSize::Paper`]: the papers' sizes (4.1 M grid parameters; slow on a CPU).

use glam::Vec3;
use guiding::{GuidingConfig, GuidingField, Representation};
use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;

/// Which guiding model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuideKind {
    /// Neural Parametric Mixtures (vMF mixture, constant selection probability).
    Npm,
    /// Normalised anisotropic spherical Gaussians with a learned selection probability.
    Nasg,
    /// Distribution factorisation, piecewise-constant (nearest) reconstruction.
    DfN,
    /// Distribution factorisation, piecewise-linear reconstruction.
    DfL,
}

/// Model size preset; see the [module docs](self#model-sizes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelSize {
    /// 4-level grid, MLP 2 × 32 (the default of the CLI).
    Demo,
    /// The library's test presets (tiny).
    Small,
    /// The papers' presets (4.1 M parameters).
    Paper,
}

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
    kind: GuideKind,
    target: Target,
    size: ModelSize,
    bbox: (Vec3, Vec3),
    selection: f32,
    config: FieldConfig,
) -> crate::Result<GuidingField> {
    let representation = match kind {
        GuideKind::Npm => Representation::Npm,
        GuideKind::Nasg => Representation::Nasg,
        GuideKind::DfN => Representation::DfNearest,
        GuideKind::DfL => Representation::DfLinear,
    };
    let size = match size {
        ModelSize::Demo => guiding::ModelSize::Compact,
        ModelSize::Small => guiding::ModelSize::Small,
        ModelSize::Paper => guiding::ModelSize::Paper,
    };
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
