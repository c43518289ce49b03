//! Path guiding for renderers: the embedding API.
//!
//! [`GuidingField`] is one non-generic type over every representation and
//! size of `guiding-core` (NPM vMF mixtures, NASG mixtures, factorised
//! DF-N / DF-L PDFs), built from a [`GuidingConfig`] preset and the scene
//! bounds. A renderer:
//!
//! 1. per shading vertex, asks [`GuidingField::distribution`] (or the
//!    batched [`GuidingField::query`]) and samples / evaluates it with
//!    one-sample MIS against its BSDF;
//! 2. records each path with a [`PathRecorder`], which turns it into
//!    training samples (a wavefront renderer records a whole block of
//!    paths, bounce by bounce, with a [`BatchRecorder`]: same samples);
//! 3. between passes, hands the samples over ([`PathRecorder::flush_into`])
//!    and calls [`GuidingField::update`] until [`GuidingField::is_converged`]
//!    (or its own budget) says stop;
//! 4. optionally [saves](GuidingField::save) the trained field and
//!    [loads](GuidingField::load) it in a later run.
//!
//! The same field runs on a Vulkan device after
//! [`GuidingField::use_device`]: the same calls, the network's inference,
//! the wavefront's samples and pdfs and the arithmetic of the training steps
//! there, one training loop for both backends, and a device failure that is
//! an error (or a fallback to the CPU with the device's weights,
//! [`DeviceFailure`]); see [`device`].
//!
//! ```
//! use guiding::{GuidingConfig, GuidingField, ModelSize, PathRecorder, PathVertex, QueryPoint};
//! use glam::{Vec2, Vec3};
//!
//! let config = GuidingConfig::npm_radiance().with_size(ModelSize::Small);
//! let mut field = GuidingField::new(config, [-1.0; 3], [1.0; 3])?;
//! let mut recorder = PathRecorder::new();
//! // A one-vertex path that saw a light of radiance 2 along +z.
//! recorder.start_path();
//! recorder.add_vertex(PathVertex {
//!     normal: [0.0, 0.0, 1.0],
//!     wo: [0.0, 0.0, 1.0],
//!     wi: [0.0, 0.0, 1.0],
//!     sample_pdf: 0.25 / std::f32::consts::PI,
//!     bsdf_cos: [0.3; 3],
//!     ..PathVertex::default()
//! });
//! recorder.add_escaped_radiance([2.0; 3], 1.0);
//! recorder.end_path();
//! recorder.flush_into(&mut field);
//! field.update();
//!
//! // position, normal, wo, roughness (a radiance model reads only the position).
//! let query = QueryPoint::new([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 1.0);
//! let dist = field.distribution(&query);
//! let s = dist.sample(Vec2::new(0.3, 0.7));
//! assert!((s.direction.length() - 1.0).abs() < 1e-5 && s.pdf > 0.0);
//! assert!((dist.pdf(s.direction) / s.pdf - 1.0).abs() < 1e-3);
//! # Ok::<(), guiding::GuidingError>(())
//! ```
//!
//! # Conventions
//!
//! This is the one statement of the library's direction convention; the
//! field docs of [`QueryPoint`], [`TrainingSample`], [`PathVertex`], the
//! distributions and the C header refer to it. It is pbrt's:
//!
//! - **`wo`** is the direction from the shading point towards the previous
//!   path vertex: the viewer (the camera for the first hit). Light leaves
//!   the point along it.
//! - **`wi`** is the sampled incident / continuation direction: the path
//!   goes on along it, and the radiance `L_i(x, wi)` that a training sample
//!   carries arrives from it. Every direction a distribution samples
//!   ([`Distribution::sample`], [`DistributionBatch`],
//!   [`GuidingField::sample_decoded`]) or takes the density of
//!   ([`Distribution::pdf`], [`GuidingField::pdf_decoded`]) is such a `wi`.
//! - Both are **unit vectors in world space pointing away from the
//!   surface**; the library never flips them (nor the normal) into a
//!   hemisphere. Zero is accepted for `wo` (and the `normal`) where it is
//!   unknown.
//! - `bsdf_cos` is `f(wo, wi) |cos θ_i|` with `θ_i` the angle between `wi`
//!   and the shading normal. Densities are in solid angle, over `wi`.
//!
//! A renderer with Mitsuba's naming, where `wi` points towards the viewer
//! and `wo` is the sampled direction, passes its `wi` as our `wo` and its
//! `wo` as our `wi`.
//!
//! Values: `pdf` is always a normalised density; the normalised
//! distributions have no `eval` (in `guiding-core`, `eval` is the
//! unnormalised value of a single lobe).

pub mod batch;
pub mod cache;
pub mod combine;
pub mod config;
pub mod device;
pub mod error;
pub mod evidence;
pub mod field;
pub mod file;
pub mod media;
mod models;
pub mod recorder;
pub mod roulette;
pub mod schedule;
pub mod trial;

pub use batch::DistributionBatch;
pub use cache::{
    CacheLookup, CacheOptions, GuideCache, ProductLobe, SelectionFit, SelectionReport, VmfTable,
};
pub use combine::{Combination, CombineOptions, Denominator, GroupWeight, PassCombiner};
pub use config::{GuidingConfig, ModelSize, Representation, Target, UnknownName};
pub use device::{DeviceFailure, DeviceSelection, GpuContext};
pub use error::GuidingError;
pub use evidence::{CostRatio, Verdict};
pub use field::{DecodedDistribution, Distribution, FieldStats, GuidingField, ModelExport};
pub use guiding_core::field::{FieldConfig, FieldState, PlateauConfig, UpdateReport};
pub use guiding_core::lobe::DirectionSample;
pub use guiding_core::model::QueryPoint;
pub use guiding_core::optim::AdamConfig;
pub use guiding_core::sample::{Rejection, TrainingSample};
pub use recorder::{BatchRecorder, Continuation, PathRecorder, PathVertex, ReflectedSample};
pub use roulette::{
    continuation_count, pixel_estimates, pixel_variances, Decision, GridOptions, GridStats,
    RadianceGrid, WeightWindow, WindowTrial,
};
pub use schedule::{
    Budget, ScheduleOptions, ScheduleReport, StepRule, TrainingSchedule, EARLY_LOOK_AT,
    EARLY_LOOK_MIN_STEPS,
};
pub use trial::{GuideTrial, LookDecision, TrialArm, TrialOptions, TrialVerdict, TRIAL_TRIM};

/// The code examples of the embedding guide, `docs/manual/embedding.md` (the
/// embedding API and the `guiding-core` kernels), compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../../docs/manual/embedding.md")]
pub struct EmbeddingGuideDoctests;
