//! The path recorder: the renderer records every vertex of a path as it
//! traces it, and at the end of the path the recorder propagates the
//! radiance back along it into one [`TrainingSample`] per guidable vertex
//! (the role of Open PGL's `PathSegmentStorage`). A wavefront renderer,
//! which traces a block of paths bounce by bounce, records the whole block
//! with a [`BatchRecorder`] instead: same rule, same samples.
//!
//! # Propagation
//!
//! For vertices `0 … n−1` (0 nearest the camera), with the continuation
//! weight `β_k = s_k · f_k cos θ_k / p_k` (`bsdf_cos / sample_pdf`, times
//! the Russian-roulette scale `s_k`), the path estimate of the radiance
//! leaving vertex `k` towards `k − 1` is
//!
//! `L̃_o(k) = w_k L_e(k) + D_k + β_k L̃_i(k)`, with `L̃_i(k) = L̃_o(k + 1)`
//!
//! where `L_e(k)` is the emission seen at `k` (MIS weight `w_k` against
//! next-event estimation at `k − 1`), `D_k` the already weighted next-event
//! contribution at `k`, and `L̃_i(n−1)` the MIS-weighted radiance of an
//! escaped ray ([`PathRecorder::add_escaped_radiance`]) or zero.
//! [`PathRecorder::end_path`] returns `L̃_o(0)`, the path's contribution to
//! its pixel (divided by the camera weight), so a renderer can check its own
//! estimator against it.
//!
//! The training target of vertex `k` is the incident radiance along its
//! sampled direction `ω_i`, `L_i(k) = L_e(k + 1) + D_{k+1} + β_{k+1}
//! L̃_i(k + 1)`: the emission found along `ω_i` counts **in full** (it is the
//! radiance arriving along `ω_i`, whatever NEE at `k` estimated), while
//! everything scattered further down the path keeps its MIS weights (NEE and
//! BSDF sampling there together estimate the light scattered at `k + 1`
//! without double counting). This is Open PGL's behaviour without
//! `useNEEMiWeights`. No sample is made for delta vertices (no guiding
//! there) or vertices whose path ended (`sample_pdf = 0`).
//!
//! Beside each sample the recorders keep its **MIS-weighted** incident
//! radiance `L̃_i(k)` (the emission along `ω_i` with its MIS weight against
//! NEE, plus the rest as above): what the renderer's estimator actually got
//! along `ω_i`. The guide learns the full radiance, but the variance of the
//! one-sample MIS of guide and BSDF next to NEE depends on this share
//! ([`crate::GuideCache::fit_selection`]).
//!
//! On request ([`BatchRecorder::keep_reflected`]) the recorders also keep, for every vertex
//! whose path went on (delta vertices included), its **reflected radiance**
//! `L̃_r(k) = D_k + β_k L̃_i(k)` (the path estimate of the light leaving `k` towards `k − 1`
//! without `k`'s own emission, MIS weights as in the pixel estimate): an unbiased one-sample
//! estimate of `L_r(x_k, ω_o)`, what Russian roulette and splitting weigh a path by
//! ([`crate::roulette::RadianceGrid`]). A vertex whose path ended there keeps none: its
//! continuation was not sampled (a roulette kill, a failed sample), so its `D_k` alone would
//! underestimate `L_r`.

pub mod batch;

use crate::field::GuidingField;
pub use batch::{BatchRecorder, Continuation};
use guiding_core::model::QueryPoint;
use guiding_core::sample::TrainingSample;

/// One path vertex as the renderer saw it. All vectors in world space, the
/// directions as in the [crate conventions](crate#conventions); RGB values
/// linear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathVertex {
    /// Surface position.
    pub position: [f32; 3],
    /// Unit shading normal (product models need it). Zero: a scattering point inside a
    /// participating medium (no surface), or unknown.
    pub normal: [f32; 3],
    /// `wo`: unit direction towards the previous vertex (the camera for
    /// vertex 0).
    pub wo: [f32; 3],
    /// Surface roughness in `[0, 1]` (product models).
    pub roughness: f32,
    /// Radiance emitted at this vertex towards `wo`.
    pub emitted: [f32; 3],
    /// MIS weight of `emitted` against next-event estimation at the
    /// previous vertex (1 without NEE); it weights the pixel estimate, not
    /// the previous vertex's training target (see the [module docs](self)).
    pub emitted_mis_weight: f32,
    /// Next-event estimation at this vertex, scattered towards `wo`, already
    /// weighted: `f · L_light · |cos| · w_mis / p_light`.
    pub direct: [f32; 3],
    /// `wi`: unit sampled continuation direction (ignored if `sample_pdf = 0`).
    pub wi: [f32; 3],
    /// Density with which `wi` was sampled (the one-sample MIS density of
    /// BSDF and guide); `0` if the path ends here.
    pub sample_pdf: f32,
    /// Density of `wi` under BSDF sampling alone (NASG's loss), `0` if unknown.
    pub bsdf_pdf: f32,
    /// `f(wo, wi) |cos θ_i|` (not divided by the pdf).
    pub bsdf_cos: [f32; 3],
    /// Extra factor on the continuation weight, e.g. `1 / q` after a
    /// Russian-roulette survival with probability `q`; `1` otherwise.
    pub continuation_scale: f32,
    /// Whether the BSDF at this vertex is a delta (specular) one: radiance
    /// is propagated through it but no training sample is made.
    pub is_delta: bool,
}

impl Default for PathVertex {
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            normal: [0.0; 3],
            wo: [0.0; 3],
            roughness: 1.0,
            emitted: [0.0; 3],
            emitted_mis_weight: 1.0,
            direct: [0.0; 3],
            wi: [0.0; 3],
            sample_pdf: 0.0,
            bsdf_pdf: 0.0,
            bsdf_cos: [0.0; 3],
            continuation_scale: 1.0,
            is_delta: false,
        }
    }
}

impl PathVertex {
    /// The training sample of this vertex's continuation, with `radiance`
    /// the incident radiance estimate along `wi` (what the recorders make
    /// for a guidable vertex; see the [module docs](self)).
    #[must_use]
    pub fn training_sample(&self, radiance: [f32; 3]) -> TrainingSample {
        TrainingSample::new(
            QueryPoint::new(self.position, self.normal, self.wo, self.roughness),
            self.wi,
            radiance,
            self.sample_pdf,
            self.bsdf_pdf,
            self.bsdf_cos,
        )
    }
}

fn add(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn scale(a: [f32; 3], s: f32) -> [f32; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn mul(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] * b[0], a[1] * b[1], a[2] * b[2]]
}

/// Radiance that escaped along a path's last `wi`: in full (the last
/// vertex's training target) and MIS-weighted (the path estimate).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Escaped {
    full: [f32; 3],
    mis: [f32; 3],
}

impl Escaped {
    fn add(&mut self, radiance: [f32; 3], mis_weight: f32) {
        self.full = add(self.full, radiance);
        self.mis = add(self.mis, scale(radiance, mis_weight));
    }
}

/// The propagation rule of the [module docs](self), the one implementation
/// both recorders ([`PathRecorder`], [`BatchRecorder`]) run: walks one
/// path's vertices from its **last** vertex back to vertex 0 (`reversed`),
/// appends its training samples to `samples` in path order and returns
/// `L̃_o(0)` (the escaped radiance's MIS share for a path without vertices).
fn propagate<'a>(
    reversed: impl Iterator<Item = &'a PathVertex>,
    escaped: Escaped,
    recorded: &mut RecordedSamples,
) -> [f32; 3] {
    let RecordedSamples {
        samples,
        mis_radiance,
        reflected,
    } = recorded;
    // Incident radiance along the current vertex's `wi`: the training
    // target (emission in full) and the path estimate (MIS-weighted).
    let (mut incident, mut incident_mis) = (escaped.full, escaped.mis);
    let first_new = samples.len();
    for v in reversed {
        let continues = v.sample_pdf > 0.0;
        if continues && !v.is_delta {
            samples.push(v.training_sample(incident));
            mis_radiance.push(incident_mis);
        }
        let scattered = if continues {
            mul(
                scale(v.bsdf_cos, v.continuation_scale / v.sample_pdf),
                incident_mis,
            )
        } else {
            [0.0; 3]
        };
        let rest = add(v.direct, scattered);
        if continues {
            if let Some(out) = reflected.as_mut() {
                out.push(ReflectedSample {
                    position: v.position,
                    normal: v.normal,
                    radiance: rest,
                });
            }
        }
        incident = add(v.emitted, rest);
        incident_mis = add(scale(v.emitted, v.emitted_mis_weight), rest);
    }
    // Samples were pushed from the last vertex back; keep path order.
    samples[first_new..].reverse();
    let first_mis = mis_radiance.len() - (samples.len() - first_new);
    mis_radiance[first_mis..].reverse();
    incident_mis
}

/// One vertex's reflected radiance estimate `L̃_r` (see the [module docs](self)).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReflectedSample {
    /// The vertex's position.
    pub position: [f32; 3],
    /// Its shading normal as recorded (zero if the renderer gave none).
    pub normal: [f32; 3],
    /// `L̃_r = D + β L̃_i`, RGB.
    pub radiance: [f32; 3],
}

/// The training samples of finished paths and, per sample, its MIS-weighted
/// incident radiance: what both recorders keep between flushes; and, when asked
/// for, the reflected radiance of every vertex whose path went on.
#[derive(Clone, Debug, Default)]
pub(crate) struct RecordedSamples {
    pub(crate) samples: Vec<TrainingSample>,
    pub(crate) mis_radiance: Vec<[f32; 3]>,
    /// `Some` while reflected radiance is kept.
    pub(crate) reflected: Option<Vec<ReflectedSample>>,
}

impl RecordedSamples {
    /// Hands the samples to `field` and clears both; returns how many.
    pub(crate) fn flush_into(&mut self, field: &mut GuidingField) -> usize {
        let n = self.samples.len();
        field.add_samples(&self.samples);
        self.clear();
        n
    }

    /// Whether to keep reflected radiance (off drops what was kept).
    pub(crate) fn keep_reflected(&mut self, keep: bool) {
        match (keep, &self.reflected) {
            (true, None) => self.reflected = Some(Vec::new()),
            (false, Some(_)) => self.reflected = None,
            _ => {}
        }
    }

    pub(crate) fn reflected(&self) -> &[ReflectedSample] {
        self.reflected.as_deref().unwrap_or(&[])
    }

    pub(crate) fn drain_reflected_into(&mut self, out: &mut Vec<ReflectedSample>) {
        if let Some(r) = &mut self.reflected {
            out.append(r);
        }
    }

    pub(crate) fn clear(&mut self) {
        self.samples.clear();
        self.mis_radiance.clear();
        if let Some(r) = &mut self.reflected {
            r.clear();
        }
    }
}

/// Records paths and turns them into training samples. Use one per render
/// thread; hand the samples to the field between passes with
/// [`Self::flush_into`].
#[derive(Clone, Debug, Default)]
pub struct PathRecorder {
    vertices: Vec<PathVertex>,
    escaped: Escaped,
    recorded: RecordedSamples,
}

impl PathRecorder {
    /// An empty recorder.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a new path (an unfinished previous path is discarded).
    pub fn start_path(&mut self) {
        self.vertices.clear();
        self.escaped = Escaped::default();
    }

    /// Records the next vertex of the current path.
    pub fn add_vertex(&mut self, vertex: PathVertex) {
        self.vertices.push(vertex);
    }

    /// Radiance arriving along the last vertex's `wi` from outside the scene
    /// (an environment), with its MIS weight against next-event estimation
    /// of the environment at that vertex; adds up over calls.
    pub fn add_escaped_radiance(&mut self, radiance: [f32; 3], mis_weight: f32) {
        self.escaped.add(radiance, mis_weight);
    }

    /// Vertices recorded on the current path.
    pub fn path_len(&self) -> usize {
        self.vertices.len()
    }

    /// Ends the path: propagates radiance back along it (see the [module
    /// docs](self)), appends its training samples and returns `L_o(0)`.
    pub fn end_path(&mut self) -> [f32; 3] {
        let l0 = propagate(self.vertices.iter().rev(), self.escaped, &mut self.recorded);
        self.start_path();
        l0
    }

    /// Training samples of the finished paths so far.
    pub fn samples(&self) -> &[TrainingSample] {
        &self.recorded.samples
    }

    /// The MIS-weighted incident radiance of each of [`Self::samples`] (see
    /// the [module docs](self)).
    pub fn mis_radiance(&self) -> &[[f32; 3]] {
        &self.recorded.mis_radiance
    }

    /// Hands every finished path's samples to `field` and clears them;
    /// returns how many were handed over.
    pub fn flush_into(&mut self, field: &mut GuidingField) -> usize {
        self.recorded.flush_into(field)
    }

    /// Drops the finished paths' samples.
    pub fn clear_samples(&mut self) {
        self.recorded.clear();
    }

    /// Moves the kept reflected radiance (see [`Self::keep_reflected`]) to
    /// the end of `out`.
    pub fn drain_reflected_into(&mut self, out: &mut Vec<ReflectedSample>) {
        self.recorded.drain_reflected_into(out);
    }

    /// Whether to keep each continuing vertex's reflected radiance (see the
    /// [module docs](self)), off by default; turning it off drops what was
    /// kept.
    pub fn keep_reflected(&mut self, keep: bool) {
        self.recorded.keep_reflected(keep);
    }
}
