//! The direction-sampling seam of the wavefront: how a vertex picks its continuation and what
//! density NEE's MIS weight compares against.
//!
//! The [driver](crate::render::wavefront) writes intersection, emission, NEE, the shadow rays,
//! the continuation and the pass loop once. Per bounce it hands the strategy the batch of
//! surviving [`Vertices`]:
//!
//! 1. [`VertexStrategy::prepare`]: anything done once per vertex (the guided strategy decodes
//!    the guide for the whole batch with one call);
//! 2. [`VertexStrategy::light_pdfs`]: the strategy's sampling density of each NEE light
//!    direction (the power heuristic's partner);
//! 3. [`VertexStrategy::sample`]: one continuation per vertex, with its weight and density.
//!
//! [`bsdf::BsdfSampling`] is `pt` and `pt-nee`; [`guided::Guided`] is path guiding (a one-sample
//! MIS of guide and BSDF) with online training between pieces of passes
//! ([`Strategy::end_chunk`]).

use crate::math::Rng;
use crate::render::queues::{Continuations, LightSamples, Vertices};
use crate::render::schedule::Pass;
use crate::scene::bsdf::Material;
use crate::scene::Scene;
use guiding_core::sample::TrainingSample;

pub mod bsdf;
pub mod guide;
pub mod guided;
pub mod probe;

/// The training samples of a pass (block order), with the MIS-weighted incident radiance of
/// each ([`guiding::BatchRecorder::mis_radiance`]).
#[derive(Clone, Debug, Default)]
pub struct PassSamples {
    /// The samples.
    pub samples: Vec<TrainingSample>,
    /// Per sample: the incident radiance with the emission MIS-weighted against NEE.
    pub mis_radiance: Vec<[f32; 3]>,
}

/// A strategy's own combination of a render's passes: per pixel (row-major) the value and the
/// variance of that estimate.
pub type CombinedImage = (Vec<[f32; 3]>, Vec<[f32; 3]>);

/// One pass's image, for a strategy that asked for it ([`Strategy::wants_pass_image`]).
#[derive(Clone, Copy, Debug)]
pub struct PassImage<'a> {
    /// Image size; pixels are row-major.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// This pass's pixel values (one sample per pixel).
    pub pixels: &'a [[f32; 3]],
    /// Per pixel, the sums of the `passes_before` earlier passes.
    pub sum_before: &'a [[f64; 3]],
    /// Passes before this one.
    pub passes_before: u32,
    /// Wall seconds of this pass's tracing.
    pub seconds: f64,
}

/// One direction-sampling strategy of a render, shared by the render threads.
pub trait Strategy: Sync {
    /// Per-thread state.
    type Worker<'a>: VertexStrategy
    where
        Self: 'a;
    /// What a worker reports when its thread ends a pass (counters, a device error).
    type Report: Send;
    /// What ends a render early.
    type Error;

    /// A worker for one render thread.
    fn worker(&self) -> Self::Worker<'_>;

    /// A thread's worker at the end of a pass.
    fn report(&self, worker: Self::Worker<'_>) -> Self::Report;

    /// Called before pass `pass`; returns whether its paths are recorded for training.
    fn begin_pass(&mut self, pass: &Pass) -> bool;

    /// Whether the estimator of the passes from this one on is settled, asked after
    /// [`Strategy::begin_pass`]: training is over and a trial of the strategy's own (the
    /// guide's efficiency trial) has had its first look, so it is either decided or goes on
    /// between two arms it found alike (their cost ratio's interval straddles 1). Another trial
    /// (the weight window's) starts only then: one that ran beside the guide's first passes
    /// would weigh the window on a mix of guided and unguided passes whose efficiencies may
    /// differ by 2x, not on the estimator that renders the rest. The default: always settled.
    fn estimator_settled(&self) -> bool {
        true
    }

    /// Whether the strategy trains something of its own from the passes it records (a guide):
    /// then the guided roulette's grid learns from exactly those passes (see
    /// [`crate::render::roulette`]), whose paths are recorded anyway, and stops when the
    /// strategy's training stops. The default: no training of its own.
    fn trains_from_recorded_passes(&self) -> bool {
        false
    }

    /// Whether the strategy wants the image of pass `pass` (its pixel values alone, not the
    /// running mean) through [`Strategy::observe_pass_image`]; asked after
    /// [`Strategy::begin_pass`].
    fn wants_pass_image(&self, _pass: &Pass) -> bool {
        false
    }

    /// The image of a pass it asked for ([`Strategy::wants_pass_image`]); called after the
    /// pass's last [`Strategy::end_chunk`].
    fn observe_pass_image(&mut self, _pass: &Pass, _image: &PassImage<'_>) {}

    /// At the end of the render: the strategy's own combination of the passes it observed
    /// (pixel values and the variance of each, row-major), replacing the plain mean; `None`
    /// (the default) keeps the plain mean.
    fn combined_image(&mut self) -> Option<CombinedImage> {
        None
    }

    /// Paths to trace in a recorded pass before the next [`Strategy::end_chunk`] (the
    /// driver rounds up to whole rows), given the paths of a whole pass; the default is the
    /// whole pass.
    fn paths_before_update(&self, pass_paths: u64) -> u64 {
        pass_paths
    }

    /// Called after each piece of a pass (a whole pass unless the strategy asked for pieces,
    /// [`Strategy::paths_before_update`]) with the threads' reports, the piece's training
    /// samples (row order, so deterministic) and what was traced. An error ends the render.
    fn end_chunk(
        &mut self,
        pass: &Pass,
        recorded: bool,
        reports: Vec<Self::Report>,
        samples: PassSamples,
        traced: Traced,
    ) -> Result<(), Self::Error>;
}

/// What the driver traced in a piece of a pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Traced {
    /// Wall seconds of the piece's tracing (recording included).
    pub seconds: f64,
    /// Paths (pixels) traced.
    pub paths: u64,
}

/// The per-thread, per-bounce half of a [`Strategy`].
pub trait VertexStrategy {
    /// Called once per bounce before NEE and sampling; may draw from the paths' random
    /// streams `rng[slot]`.
    fn prepare(&mut self, scene: &Scene, verts: &Vertices, rng: &mut [Rng]);

    /// Fills `lights.sampling_pdf` with this strategy's density of each light direction.
    fn light_pdfs(&mut self, verts: &Vertices, lights: &mut LightSamples);

    /// Whether vertices of material `mat` make training samples (the strategy guides them);
    /// `medium` is the medium of a scattering point (its phase function is `mat`), else
    /// [`crate::scene::medium::NO_MEDIUM`].
    fn trains(&self, mat: &Material, medium: u32) -> bool;

    /// Samples one continuation per vertex into `out` (already reset to ended paths), drawing
    /// from the path's random stream `rng[slot]`.
    fn sample(&mut self, verts: &Vertices, rng: &mut [Rng], out: &mut Continuations);
}
