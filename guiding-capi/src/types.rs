//! The `repr(C)` value types of the C ABI: field arguments, training
//! samples, query points, path vertices, statistics and update reports,
//! with their conversions to the `guiding` types. Mirrors of `guiding-core`
//! structs are checked at compile time to have the same size and field
//! offsets, so slices are passed through without copies.

use bytemuck::{Pod, Zeroable};
use guiding::{FieldStats, PathVertex, QueryPoint, TrainingSample, UpdateReport};
use guiding_core::sample::REJECTION_KINDS;
use std::mem::{offset_of, size_of};

/// Directional representation code (`PG_REPRESENTATION_*`).
pub type PgRepresentation = u32;
/// Neural Parametric Mixtures (Dong et al. 2023): 8 vMF lobes.
pub const PG_REPRESENTATION_NPM: PgRepresentation = 0;
/// Normalised anisotropic spherical Gaussians (Huang et al. 2024), with a
/// learned guide-selection probability.
pub const PG_REPRESENTATION_NASG: PgRepresentation = 1;
/// Factorised piecewise-constant PDFs (DF-N, Figueiredo et al. 2025).
pub const PG_REPRESENTATION_DF_NEAREST: PgRepresentation = 2;
/// Factorised piecewise-linear PDFs (DF-L).
pub const PG_REPRESENTATION_DF_LINEAR: PgRepresentation = 3;

/// Training target code (`PG_TARGET_*`).
pub type PgTarget = u32;
/// The guide learns incident radiance `L_i(x, ω)`.
pub const PG_TARGET_RADIANCE: PgTarget = 0;
/// The guide learns the product `f(ωo, ω) L_i(x, ω) |cos θ|` (queries need
/// normal, ωo and roughness).
pub const PG_TARGET_PRODUCT: PgTarget = 1;

/// Where a field's network runs (`PG_DEVICE_*`).
pub type PgDevice = u32;
/// The CPU threads (default).
pub const PG_DEVICE_CPU: PgDevice = 0;
/// A Vulkan device: a discrete GPU first, then an integrated one, then a
/// CPU implementation (lavapipe); `GUIDING_VK_DEVICE` overrides the choice.
pub const PG_DEVICE_VULKAN: PgDevice = 1;
/// A Vulkan GPU, never a CPU implementation.
pub const PG_DEVICE_VULKAN_GPU: PgDevice = 2;

/// What a field on a device does when the device fails (`PG_DEVICE_FAILURE_*`).
pub type PgDeviceFailure = u32;
/// Every later call that needs the device returns `PG_DEVICE_UNAVAILABLE` (default).
pub const PG_DEVICE_FAILURE_ERROR: PgDeviceFailure = 0;
/// Go on on the CPU with the weights the device trained.
pub const PG_DEVICE_FALLBACK_CPU: PgDeviceFailure = 1;

/// Model size code (`PG_SIZE_*`): `guiding::ModelSize` as `u32`.
pub type PgModelSize = u32;

/// `PG_SIZE_<NAME>`, one constant per row of the size table
/// ([`guiding_core::for_each_size`]). cbindgen does not expand macros: the
/// header's `#define`s are written from `ModelSize::ALL` by its generator
/// (`tests/header.rs`).
macro_rules! size_constants {
    ([$($size:ident = $code:literal, $name:ident, $doc:literal, $shape:tt;)*]) => {
        guiding_core::__pastey::paste! {
            $(
                #[doc = $doc]
                pub const [<PG_SIZE_ $name:upper>]: PgModelSize = $code;
            )*
        }
    };
}
guiding_core::for_each_size!(size_constants);

/// Number of rejection kinds counted in `PgFieldStats.rejected_samples`.
pub const PG_REJECTION_KINDS: usize = 4;
const _: () = assert!(PG_REJECTION_KINDS == REJECTION_KINDS);

/// Everything needed to create a field. Fill it with
/// `pg_field_args_set_defaults`, then set at least the scene bounds (the
/// defaults are an empty box, which `pg_field_new` refuses). The defaults
/// are the library's presets (Rust `GuidingConfig::for_representation`).
/// Training values not listed here (Adam β₁/β₂/ε, gradient chunks and clip)
/// keep the preset values.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgFieldArgs {
    /// `PG_REPRESENTATION_*`.
    pub representation: PgRepresentation,
    /// `PG_TARGET_*` (default `PG_TARGET_RADIANCE`).
    pub target: PgTarget,
    /// `PG_SIZE_*` (default `PG_SIZE_COMPACT`).
    pub size: PgModelSize,
    /// Probability of sampling the guide rather than the BSDF, in `[0, 1]`
    /// (NPM and DF; NASG learns its own). Default 0.3.
    pub selection_probability: f32,
    /// Adam learning rate, `> 0`. Default 0.03 (NPM: 0.005).
    pub learning_rate: f32,
    /// Decay of the weight average used for queries, in `[0, 1)`. Default 0.95.
    pub ema_decay: f32,
    /// Adam steps per `pg_field_update`, `≥ 1`, and the most steps of a
    /// `PG_STEP_RULE_EPOCHS` update in `pg_field_train_scheduled`. Default 64.
    pub steps_per_update: u32,
    /// Seed of the minibatch shuffles. Default 0.
    pub seed: u32,
    /// Samples per minibatch, `≥ 1`. Default 8192. Feed about
    /// `steps_per_update × batch_size` samples per update.
    pub batch_size: usize,
    /// Worker threads of updates and batched queries; 0 = all cores
    /// (default). Set 1 when the renderer calls queries from its own
    /// thread pool.
    pub threads: usize,
    /// Samples buffered at most between updates (more are dropped and
    /// counted). Default 2²⁰.
    pub max_buffered_samples: usize,
    /// Training stops after this many steps; `UINT64_MAX` = no limit (default).
    pub max_steps: u64,
    /// Updates without improvement after which training counts as converged;
    /// 0 = never (default).
    pub plateau_window: u32,
    /// Relative loss improvement that counts as progress, `≥ 0`. Default 0.
    pub plateau_min_relative_improvement: f32,
    /// Scene bounding box, lower corner (must be set).
    pub bounds_min: [f32; 3],
    /// Scene bounding box, upper corner, `> bounds_min` on every axis (must be set).
    pub bounds_max: [f32; 3],
    /// `PG_DEVICE_*`: where the network's inference and training run
    /// (default `PG_DEVICE_CPU`). `pg_field_new` returns
    /// `PG_DEVICE_UNAVAILABLE` when the device cannot be used.
    pub device: PgDevice,
    /// `PG_DEVICE_FAILURE_*`: what a field on a device does when the device
    /// fails mid-render (default `PG_DEVICE_FAILURE_ERROR`).
    pub device_failure: PgDeviceFailure,
}

/// One training sample, identical in layout to `guiding_core`'s
/// `TrainingSample` (96 bytes, every vector padded to four floats).
/// Directions as in the header's Conventions (world space, unit, pointing
/// away from the surface).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PgTrainingSample {
    /// World-space position of the vertex.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product targets).
    pub roughness: f32,
    /// Unit shading normal (product targets). Zero: no surface (a scattering point inside
    /// a participating medium; the guide covers the whole sphere) or unknown.
    pub normal: [f32; 3],
    /// Density (solid angle) with which `wi` was sampled, `> 0`.
    pub sample_pdf: f32,
    /// `wo`: unit direction towards the previous vertex, the viewer (product
    /// targets; zero if unknown).
    pub wo: [f32; 3],
    /// Density of `wi` under BSDF sampling alone (NASG), `0` if unknown.
    pub bsdf_pdf: f32,
    /// `wi`: unit sampled continuation direction (the incident direction of
    /// `radiance`).
    pub wi: [f32; 3],
    /// Padding (0).
    pub pad0: f32,
    /// Incident radiance estimate along `wi`, RGB, `≥ 0`.
    pub radiance: [f32; 3],
    /// Padding (0).
    pub pad1: f32,
    /// `f(wo, wi) |cos θ_i|`, RGB, `≥ 0` (product targets).
    pub bsdf_cos: [f32; 3],
    /// Padding (0).
    pub pad2: f32,
}

macro_rules! same_layout {
    ($a:ty, $b:ty, $size:expr, [$($f:ident),*]) => {
        const _: () = assert!(size_of::<$a>() == $size && size_of::<$b>() == $size);
        const _: () = assert!(std::mem::align_of::<$a>() == std::mem::align_of::<$b>());
        $(const _: () = assert!(offset_of!($a, $f) == offset_of!($b, $f));)*
    };
}

same_layout!(
    PgTrainingSample,
    TrainingSample,
    96,
    [
        position, roughness, normal, sample_pdf, wo, bsdf_pdf, wi, pad0, radiance, pad1, bsdf_cos,
        pad2
    ]
);

/// A shading point to query, identical in layout to `guiding_core`'s
/// `QueryPoint` (48 bytes). Directions as in the header's Conventions.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PgQueryPoint {
    /// World-space position.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product targets).
    pub roughness: f32,
    /// Unit shading normal (product targets). Zero: no surface (a scattering point inside
    /// a participating medium; the guide covers the whole sphere) or unknown.
    pub normal: [f32; 3],
    /// Padding (0).
    pub pad0: f32,
    /// `wo`: unit direction towards the previous vertex, the viewer (product
    /// targets; zero if unknown).
    pub wo: [f32; 3],
    /// Padding (0).
    pub pad1: f32,
}

same_layout!(
    PgQueryPoint,
    QueryPoint,
    48,
    [position, roughness, normal, pad0, wo, pad1]
);

impl PgQueryPoint {
    /// Whether every value is finite.
    pub(crate) fn is_finite(&self) -> bool {
        let v = [
            self.position[0],
            self.position[1],
            self.position[2],
            self.roughness,
            self.normal[0],
            self.normal[1],
            self.normal[2],
            self.wo[0],
            self.wo[1],
            self.wo[2],
        ];
        v.iter().all(|x| x.is_finite())
    }
}

/// One path vertex as the renderer saw it (see `pg_recorder_add_vertex`).
/// Initialise with `pg_path_vertex_set_defaults`: zero is not the default
/// for `roughness`, `emitted_mis_weight` and `continuation_scale` (1).
/// Directions as in the header's Conventions. 112 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PgPathVertex {
    /// Surface position.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product targets). Default 1.
    pub roughness: f32,
    /// Unit shading normal (zero if unknown; product targets need it).
    pub normal: [f32; 3],
    /// Density with which `wi` was sampled (the one-sample MIS density of
    /// BSDF and guide); 0 if the path ends here.
    pub sample_pdf: f32,
    /// `wo`: unit direction towards the previous vertex (the camera for
    /// vertex 0).
    pub wo: [f32; 3],
    /// Density of `wi` under BSDF sampling alone (NASG), 0 if unknown.
    pub bsdf_pdf: f32,
    /// `wi`: unit sampled continuation direction (ignored if `sample_pdf` is 0).
    pub wi: [f32; 3],
    /// MIS weight of `emitted` against next-event estimation at the
    /// previous vertex. Default 1.
    pub emitted_mis_weight: f32,
    /// Radiance emitted at this vertex towards `wo`, RGB.
    pub emitted: [f32; 3],
    /// Extra factor on the continuation weight, e.g. `1/q` after Russian
    /// roulette survival with probability `q`. Default 1.
    pub continuation_scale: f32,
    /// Next-event estimation at this vertex scattered towards `wo`, already
    /// MIS-weighted: `f · L_light · |cos| · w / p_light`, RGB.
    pub direct: [f32; 3],
    /// Non-zero if the BSDF here is a delta (specular) one: radiance is
    /// propagated through the vertex but no training sample is made.
    pub is_delta: u32,
    /// `f(wo, wi) |cos θ_i|` (not divided by the pdf), RGB.
    pub bsdf_cos: [f32; 3],
    /// Padding (0).
    pub pad: f32,
}

const _: () = assert!(size_of::<PgPathVertex>() == 112);

impl PgPathVertex {
    /// The defaults of the Rust `PathVertex` (zeros, roughness, MIS weight
    /// and continuation scale 1).
    pub(crate) fn defaults() -> Self {
        PathVertex::default().into()
    }
}

impl From<PathVertex> for PgPathVertex {
    /// `is_delta` becomes 0 or 1.
    fn from(v: PathVertex) -> Self {
        Self {
            position: v.position,
            roughness: v.roughness,
            normal: v.normal,
            sample_pdf: v.sample_pdf,
            wo: v.wo,
            bsdf_pdf: v.bsdf_pdf,
            wi: v.wi,
            emitted_mis_weight: v.emitted_mis_weight,
            emitted: v.emitted,
            continuation_scale: v.continuation_scale,
            direct: v.direct,
            is_delta: u32::from(v.is_delta),
            bsdf_cos: v.bsdf_cos,
            pad: 0.0,
        }
    }
}

impl From<PgPathVertex> for PathVertex {
    /// Any non-zero `is_delta` is a delta vertex.
    fn from(v: PgPathVertex) -> Self {
        Self {
            position: v.position,
            normal: v.normal,
            wo: v.wo,
            roughness: v.roughness,
            emitted: v.emitted,
            emitted_mis_weight: v.emitted_mis_weight,
            direct: v.direct,
            wi: v.wi,
            sample_pdf: v.sample_pdf,
            bsdf_pdf: v.bsdf_pdf,
            bsdf_cos: v.bsdf_cos,
            continuation_scale: v.continuation_scale,
            is_delta: v.is_delta != 0,
        }
    }
}

/// Training counters of a field (`pg_field_stats`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PgFieldStats {
    /// Adam steps applied.
    pub steps: u64,
    /// Steps skipped for a non-finite gradient.
    pub skipped_steps: u64,
    /// Training samples accepted into the buffer.
    pub accepted_samples: u64,
    /// Rejected samples per kind: `[0]` a NaN or infinite value, `[1]`
    /// negative radiance or BSDF value, `[2]` `sample_pdf ≤ 0` (or negative
    /// `bsdf_pdf`), `[3]` a non-unit direction.
    pub rejected_samples: [u64; PG_REJECTION_KINDS],
    /// Samples dropped because training had stopped.
    pub ignored_samples: u64,
    /// Valid samples dropped because the buffer was full.
    pub overflowed_samples: u64,
    /// Samples waiting for the next update.
    pub buffered_samples: u64,
    /// Updates so far that changed the parameters (distributions decoded at
    /// an older generation are stale).
    pub generation: u64,
    /// Parameters of the model.
    pub param_count: u64,
    /// 1 once training is over, else 0.
    pub converged: u32,
    /// Padding (0).
    pub pad: u32,
}

impl From<FieldStats> for PgFieldStats {
    fn from(s: FieldStats) -> Self {
        Self {
            steps: s.steps,
            skipped_steps: s.skipped_steps,
            accepted_samples: s.accepted_samples,
            rejected_samples: s.rejected_samples,
            ignored_samples: s.ignored_samples,
            overflowed_samples: s.overflowed_samples,
            buffered_samples: s.buffered_samples,
            generation: s.generation,
            param_count: s.param_count,
            converged: s.converged,
            pad: 0,
        }
    }
}

/// What one `pg_field_update` did.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PgUpdateReport {
    /// Adam steps applied (0: nothing changed, distributions stay valid).
    pub steps: u32,
    /// Steps skipped because the gradient or loss was not finite.
    pub skipped_steps: u32,
    /// Applied steps whose gradient was clipped.
    pub clipped_steps: u32,
    /// 1 if training is over (after this update or before it), else 0.
    pub converged: u32,
    /// Valid samples in the buffer when the update started.
    pub buffered_samples: u64,
    /// Samples per minibatch used.
    pub batch_size: u64,
    /// Parameter elements left untouched inside applied steps because their
    /// update would not have been finite.
    pub element_skips: u64,
    /// Mean minibatch loss over the applied steps (NaN if none).
    pub mean_loss: f64,
}

impl From<UpdateReport> for PgUpdateReport {
    fn from(r: UpdateReport) -> Self {
        Self {
            steps: r.steps,
            skipped_steps: r.skipped_steps,
            clipped_steps: r.clipped_steps,
            converged: u32::from(r.converged),
            buffered_samples: r.buffered_samples as u64,
            batch_size: r.batch_size as u64,
            element_skips: r.element_skips,
            mean_loss: r.mean_loss,
        }
    }
}

/// The query points as `guiding-core`'s type (same layout, no copy).
pub(crate) fn as_query_points(q: &[PgQueryPoint]) -> &[QueryPoint] {
    bytemuck::cast_slice(q)
}

/// The training samples as `guiding-core`'s type (same layout, no copy).
pub(crate) fn as_training_samples(s: &[PgTrainingSample]) -> &[TrainingSample] {
    bytemuck::cast_slice(s)
}
