//! Guiding models: encodings → MLP → directional distribution, as per-query
//! kernels over one flat parameter buffer (shared by the CPU runtime, the GPU
//! build, the optimiser and the save file).
//!
//! A model is a small `Copy` value holding its configuration (grid box, layer
//! offsets, target); parameters live outside it, in `params: &[f32]`, and
//! gradients are accumulated into a buffer of the same layout.

#[cfg(feature = "std")]
pub mod batched;
pub mod df;
#[cfg(feature = "std")]
pub mod mixture_batch;
pub mod mixture_model;
pub mod nasg;
pub mod npm;
pub mod sizes;
pub mod table;
#[cfg(feature = "std")]
pub mod vmf_gradient;

use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Where and how the renderer asks for a guiding distribution.
///
/// Directions follow the library's convention (pbrt's; see the `guiding`
/// crate's *Conventions*): `wo` points from the shading point towards the
/// previous path vertex, and the distribution returned for the query is one
/// over the sampled directions `wi`.
///
/// `repr(C)`, `Pod`, 48 bytes. Build it with [`Self::new`] (or
/// [`Self::from_vec3`]), which zeroes the padding.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct QueryPoint {
    /// World-space position of the shading point.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product models only).
    pub roughness: f32,
    /// Unit world-space shading normal (product models only). Zero: no surface, a
    /// scattering point inside a participating medium (the guide covers the whole sphere;
    /// no cosine product), or unknown.
    pub normal: [f32; 3],
    /// Padding (0).
    pub pad0: f32,
    /// `wo`: unit world-space direction towards the previous vertex, the
    /// viewer (product models only; zero if unknown).
    pub wo: [f32; 3],
    /// Padding (0).
    pub pad1: f32,
}

impl QueryPoint {
    /// A query at `position` with shading `normal`, outgoing direction `wo`
    /// (towards the previous vertex) and `roughness`; the padding is zero.
    /// Radiance models read only `position`.
    ///
    /// ```
    /// use guiding_core::model::QueryPoint;
    ///
    /// const Q: QueryPoint = QueryPoint::new([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8], 0.5);
    /// assert_eq!(Q.wo, [0.0, 0.6, 0.8]);
    /// assert_eq!((Q.pad0, Q.pad1), (0.0, 0.0));
    /// ```
    #[inline]
    #[must_use]
    pub const fn new(position: [f32; 3], normal: [f32; 3], wo: [f32; 3], roughness: f32) -> Self {
        Self {
            position,
            roughness,
            normal,
            pad0: 0.0,
            wo,
            pad1: 0.0,
        }
    }

    /// [`Self::new`] from vectors.
    ///
    /// ```
    /// use guiding_core::glam::Vec3;
    /// use guiding_core::model::QueryPoint;
    ///
    /// let q = QueryPoint::from_vec3(Vec3::new(0.1, 0.2, 0.3), Vec3::Z, Vec3::new(0.0, 0.6, 0.8), 0.5);
    /// assert_eq!(q, QueryPoint::new([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8], 0.5));
    /// ```
    #[inline]
    #[must_use]
    pub const fn from_vec3(position: Vec3, normal: Vec3, wo: Vec3, roughness: f32) -> Self {
        Self::new(
            position.to_array(),
            normal.to_array(),
            wo.to_array(),
            roughness,
        )
    }

    /// The query of a training sample (same position, normal, `wo`, roughness).
    #[must_use]
    pub const fn of_sample(s: &TrainingSample) -> Self {
        Self::new(s.position, s.normal, s.wo, s.roughness)
    }

    /// Position as a vector.
    #[inline]
    #[must_use]
    pub fn position(&self) -> Vec3 {
        Vec3::from_array(self.position)
    }
}

/// The directional family a model decodes to: the model table's family
/// column ([`for_each_model!`](crate::for_each_model)), known from the type
/// ([`GuidingModel::FAMILY`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Family {
    /// Neural Parametric Mixtures: a vMF mixture, constant selection probability.
    Npm,
    /// NASG mixtures with a learned selection probability.
    Nasg,
    /// Distribution factorisation (DF-N / DF-L): a conditional network per
    /// direction, so no raw outputs per query.
    Df,
}

impl Family {
    /// Raw network outputs per query ([`RawOutputs::RAW_OUTPUTS`]); 0 for DF.
    #[must_use]
    pub const fn raw_outputs(self) -> usize {
        match self {
            Self::Npm => npm::NPM_OUTPUTS,
            Self::Nasg => nasg::NASG_OUTPUTS,
            Self::Df => 0,
        }
    }
}

/// The per-query kernels every guiding model provides. Generic code (the CPU
/// runtime, shader entry points) is written against this trait; there is no
/// `dyn` use of it.
pub trait GuidingModel: Copy {
    /// The family of the decoded distribution.
    const FAMILY: Family;

    /// Number of `f32` parameters (the length of the flat buffer).
    fn param_count(&self) -> usize;

    /// Deterministic initialisation of `params` (length `param_count()`) from `seed`.
    fn init(&self, params: &mut [f32], seed: u32);

    /// Draws a direction for `query` from `u ∈ [0, 1)²`, with its density.
    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample;

    /// Density of `direction` for `query`.
    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32;

    /// Probability of sampling the guide rather than the BSDF at `query`
    /// (a learned value for NASG; a constant for the other models).
    fn selection_probability(&self, params: &[f32], query: &QueryPoint) -> f32;

    /// The selection probability where it does not depend on the query (NPM
    /// and DF: a constant of the model); `None` where it is learned (NASG).
    fn constant_selection_probability(&self) -> Option<f32>;

    /// Adds the gradient of one sample's training loss (with respect to every
    /// parameter) into `grad` (length `param_count()`) and returns the loss.
    /// A sample that fails [`TrainingSample::validate`] adds nothing and
    /// returns `0`.
    fn accumulate_gradient<G: GradientSink + ?Sized>(
        &self,
        params: &[f32],
        sample: &TrainingSample,
        grad: &mut G,
    ) -> f32;

    /// Adds the gradients of every sample of `samples` into `grad`, each
    /// gradient element summed over the samples in their order, and returns
    /// the summed loss (in `f64`). The default calls
    /// [`Self::accumulate_gradient`] per sample; NPM and NASG override it
    /// with the batched network kernels (`std`, [`batched`]), which round
    /// differently within the bound stated in [`crate::mlp`].
    fn accumulate_gradient_batch(
        &self,
        params: &[f32],
        samples: &[TrainingSample],
        grad: &mut [f32],
    ) -> f64 {
        let mut loss = 0.0f64;
        let mut i = 0;
        while i < samples.len() {
            loss += self.accumulate_gradient(params, &samples[i], grad) as f64;
            i += 1;
        }
        loss
    }
}

/// Models whose network output at a query is a fixed-size vector that fully
/// describes the distribution there (NPM: 8 vMF lobes × 4; NASG: 8 lobes × 6
/// plus the selection logit). A GPU runs the network ([`Self::write_raw`])
/// and the renderer decodes the outputs where it samples
/// ([`crate::batch::vmf_mixture_from_raw`],
/// [`crate::batch::nasg_mixture_from_raw`]). DF is not one of them: its
/// conditional network depends on the direction.
pub trait RawOutputs: GuidingModel {
    /// Number of `f32` outputs per query.
    const RAW_OUTPUTS: usize;

    /// Writes the network outputs at `query` to `out[base .. base +
    /// RAW_OUTPUTS]` (slots past `out.len()` are skipped). A too short
    /// `params` writes the outputs of the near-uniform distribution.
    fn write_raw(&self, params: &[f32], query: &QueryPoint, out: &mut [f32], base: usize);
}
