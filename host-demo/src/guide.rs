//! The guiding models the `guided` integrator can use, behind one object-safe trait.
//!
//! [`Guide`] wraps a [`guiding_core::field::Field`] (model + online trainer + EMA weights)
//! so the renderer is not generic over the model type. Batched queries run serially on the
//! calling render thread (the renderer already runs one thread per core; nesting the field's
//! own thread pool inside each render thread would oversubscribe), evaluating the field's EMA
//! parameters exactly as `Field::sample_batch` / `pdf_batch` do with one thread.
//!
//! # Model sizes
//!
//! * [`ModelSize::Demo`] (default): a 4-level dense grid (4, 8, 16, 32 cells per axis, 4
//!   features per vertex: 16 outputs, 166 816 parameters) and MLPs of 2 hidden layers × 32.
//!   About 25× fewer parameters than the paper grids and ~4× cheaper per query, so a
//!   320×240 image trains and renders in about a minute on 2 cores.
//! * [`ModelSize::Small`]: the library's test presets (2-level grid, MLP 2 × 16, 608 grid
//!   parameters) — fast, used by the tests.
//! * [`ModelSize::Paper`]: the papers' sizes (4.1 M grid parameters; slow on a CPU).

use glam::{Vec2, Vec3};
use guiding_core::encoding::GridConfig;
use guiding_core::field::{Field, FieldConfig, UpdateReport};
use guiding_core::lobe::DirectionSample;
use guiding_core::loss::Target;
use guiding_core::model::df::{Df, DfProduct, DfRadiance, DfSmallProduct, DfSmallRadiance};
use guiding_core::model::nasg::{
    Nasg, NasgProduct, NasgRadiance, NasgSmallProduct, NasgSmallRadiance,
};
use guiding_core::model::npm::{Npm, NpmProduct, NpmRadiance, NpmSmallProduct, NpmSmallRadiance};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;
use guiding_core::sample::TrainingSample;

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

/// The demo grid: 4 levels (4, 8, 16, 32 cells per axis), 4 features each.
pub const fn demo_grid(bbox_min: [f32; 3], bbox_max: [f32; 3]) -> GridConfig {
    GridConfig::new(bbox_min, bbox_max, 4, 4, 2.0, 4)
}

/// Demo NPM, radiance target (IN = 16 grid features).
pub type NpmDemoRadiance = Npm<16, 32, 2>;
/// Demo NPM, product target (IN = 16 + 32 product inputs).
pub type NpmDemoProduct = Npm<48, 32, 2>;
/// Demo NASG, radiance target.
pub type NasgDemoRadiance = Nasg<16, 32, 2>;
/// Demo NASG, product target.
pub type NasgDemoProduct = Nasg<48, 32, 2>;
/// Demo DF, radiance target (`IN_C = IN_M + 12`, cache input `16 + 16`).
pub type DfDemoRadiance = Df<16, 28, 32, 32, 2, 32, 2>;
/// Demo DF, product target.
pub type DfDemoProduct = Df<48, 60, 32, 32, 2, 32, 2>;

const B0: [f32; 3] = [0.0; 3];
const B1: [f32; 3] = [1.0; 3];
const _: () = assert!(NpmDemoRadiance::new(demo_grid(B0, B1), Target::Radiance).is_consistent());
const _: () = assert!(NpmDemoProduct::new(demo_grid(B0, B1), Target::Product).is_consistent());
const _: () = assert!(NasgDemoRadiance::new(demo_grid(B0, B1), Target::Radiance).is_consistent());
const _: () = assert!(NasgDemoProduct::new(demo_grid(B0, B1), Target::Product).is_consistent());
const _: () =
    assert!(
        DfDemoRadiance::new(demo_grid(B0, B1), Target::Radiance, Interpolation::Linear)
            .is_consistent()
    );
const _: () =
    assert!(
        DfDemoProduct::new(demo_grid(B0, B1), Target::Product, Interpolation::Linear)
            .is_consistent()
    );

/// A trained-online guiding distribution, object-safe so the renderer stays non-generic.
pub trait Guide: Sync {
    /// Human-readable model description (kind, target, size, parameter count).
    fn describe(&self) -> String;
    /// Whether the model learns its selection probability (NASG).
    fn learned_selection(&self) -> bool;
    /// Learned selection probability for every query.
    fn selection_batch(&self, queries: &[QueryPoint], out: &mut [f32]);
    /// Samples one direction per query (`u[i]` uniform in `[0,1)²`).
    fn sample_batch(&self, queries: &[QueryPoint], u: &[Vec2], out: &mut [DirectionSample]);
    /// Density of `dirs[i]` at `queries[i]`.
    fn pdf_batch(&self, queries: &[QueryPoint], dirs: &[Vec3], out: &mut [f32]);
    /// Hands training samples to the field.
    fn add_samples(&mut self, samples: &[TrainingSample]);
    /// Runs the configured number of training steps on the buffered samples.
    fn update(&mut self) -> UpdateReport;
    /// Stops training for good.
    fn stop_training(&mut self);
    /// Applied training steps so far.
    fn steps(&self) -> u64;
    /// Rejected training samples so far (all kinds).
    fn rejected(&self) -> u64;
    /// Samples handed over after training stopped.
    fn ignored(&self) -> u64;
    /// Valid samples dropped because the buffer was full.
    fn overflowed(&self) -> u64;
}

struct FieldGuide<M: GuidingModel> {
    field: Field<M>,
    name: String,
    learned_selection: bool,
}

impl<M: GuidingModel + Sync + Send> Guide for FieldGuide<M> {
    fn describe(&self) -> String {
        format!(
            "{} ({} parameters)",
            self.name,
            self.field.model().param_count()
        )
    }
    fn learned_selection(&self) -> bool {
        self.learned_selection
    }
    fn selection_batch(&self, queries: &[QueryPoint], out: &mut [f32]) {
        let (m, p) = (self.field.model(), self.field.ema_params());
        for (o, q) in out.iter_mut().zip(queries) {
            *o = m.selection_probability(p, q);
        }
    }
    fn sample_batch(&self, queries: &[QueryPoint], u: &[Vec2], out: &mut [DirectionSample]) {
        let (m, p) = (self.field.model(), self.field.ema_params());
        for ((o, q), u) in out.iter_mut().zip(queries).zip(u) {
            *o = m.sample(p, q, *u);
        }
    }
    fn pdf_batch(&self, queries: &[QueryPoint], dirs: &[Vec3], out: &mut [f32]) {
        let (m, p) = (self.field.model(), self.field.ema_params());
        for ((o, q), d) in out.iter_mut().zip(queries).zip(dirs) {
            *o = m.pdf(p, q, *d);
        }
    }
    fn add_samples(&mut self, samples: &[TrainingSample]) {
        self.field.add_samples(samples);
    }
    fn update(&mut self) -> UpdateReport {
        self.field.update()
    }
    fn stop_training(&mut self) {
        self.field.stop_training();
    }
    fn steps(&self) -> u64 {
        self.field.steps()
    }
    fn rejected(&self) -> u64 {
        self.field.rejected().iter().sum()
    }
    fn ignored(&self) -> u64 {
        self.field.ignored()
    }
    fn overflowed(&self) -> u64 {
        self.field.overflowed()
    }
}

fn wrap<M: GuidingModel + Sync + Send + 'static>(
    model: M,
    config: FieldConfig,
    name: String,
    learned_selection: bool,
) -> crate::Result<Box<dyn Guide + Send>> {
    let field = Field::new(model, config)
        .map_err(|e| crate::Error::Scene(format!("guiding field: {e}")))?;
    Ok(Box::new(FieldGuide {
        field,
        name,
        learned_selection,
    }))
}

/// Builds a guide over the box `[bbox_min, bbox_max]` (padded by 1 % so surface points on the
/// box never sit exactly on the grid boundary). `selection` is the constant guide-selection
/// probability of NPM / DF (NASG learns its own).
pub fn build_guide(
    kind: GuideKind,
    target: Target,
    size: ModelSize,
    bbox: (Vec3, Vec3),
    selection: f32,
    config: FieldConfig,
) -> crate::Result<Box<dyn Guide + Send>> {
    let pad = (bbox.1 - bbox.0).max(Vec3::splat(1e-3)) * 0.01;
    let (lo, hi) = ((bbox.0 - pad).to_array(), (bbox.1 + pad).to_array());
    if !(lo.iter().chain(&hi).all(|v| v.is_finite())) {
        return Err(crate::Error::Scene("scene bounds are not finite".into()));
    }
    let name = format!("{kind:?} {target:?} {size:?}");
    let interp = if kind == GuideKind::DfL {
        Interpolation::Linear
    } else {
        Interpolation::Nearest
    };
    let c = selection;
    use ModelSize::*;
    use Target::*;
    match (kind, size, target) {
        (GuideKind::Npm, Demo, Radiance) => wrap(
            NpmDemoRadiance::new(demo_grid(lo, hi), Radiance).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Npm, Demo, Product) => wrap(
            NpmDemoProduct::new(demo_grid(lo, hi), Product).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Npm, Small, Radiance) => wrap(
            NpmSmallRadiance::small(lo, hi).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Npm, Small, Product) => wrap(
            NpmSmallProduct::small(lo, hi).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Npm, Paper, Radiance) => wrap(
            NpmRadiance::paper(lo, hi).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Npm, Paper, Product) => wrap(
            NpmProduct::paper(lo, hi).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (GuideKind::Nasg, Demo, Radiance) => wrap(
            NasgDemoRadiance::new(demo_grid(lo, hi), Radiance),
            config,
            name,
            true,
        ),
        (GuideKind::Nasg, Demo, Product) => wrap(
            NasgDemoProduct::new(demo_grid(lo, hi), Product),
            config,
            name,
            true,
        ),
        (GuideKind::Nasg, Small, Radiance) => {
            wrap(NasgSmallRadiance::small(lo, hi), config, name, true)
        }
        (GuideKind::Nasg, Small, Product) => {
            wrap(NasgSmallProduct::small(lo, hi), config, name, true)
        }
        (GuideKind::Nasg, Paper, Radiance) => wrap(NasgRadiance::paper(lo, hi), config, name, true),
        (GuideKind::Nasg, Paper, Product) => wrap(NasgProduct::paper(lo, hi), config, name, true),
        (_, Demo, Radiance) => wrap(
            DfDemoRadiance::new(demo_grid(lo, hi), Radiance, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (_, Demo, Product) => wrap(
            DfDemoProduct::new(demo_grid(lo, hi), Product, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (_, Small, Radiance) => wrap(
            DfSmallRadiance::small(lo, hi, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (_, Small, Product) => wrap(
            DfSmallProduct::small(lo, hi, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (_, Paper, Radiance) => wrap(
            DfRadiance::paper(lo, hi, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
        (_, Paper, Product) => wrap(
            DfProduct::paper(lo, hi, interp).with_selection_probability(c),
            config,
            name,
            false,
        ),
    }
}
