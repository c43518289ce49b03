//! The wavefront path recorder: [`BatchRecorder`] records a whole block of
//! paths that a wavefront renderer traces together, bounce by bounce, each
//! path known by its slot `0 … n−1` in the block.
//!
//! # Propagation
//!
//! Exactly the rule of the [`PathRecorder`](super::PathRecorder) (see the
//! [recorder module docs](super) for the formula of `L̃_o(k)` and of the
//! training target `L_i(k)`): [`BatchRecorder::end`] runs the same code on
//! every slot, so recording paths interleaved through a `BatchRecorder`
//! gives bit for bit the samples and `L̃_o(0)` of recording each path alone
//! through a `PathRecorder`, in slot order.
//!
//! # Calls per bounce
//!
//! A slot's vertex is added when its ray hits (emission and its MIS weight
//! are known then); the fields found out later are filled in on that slot's
//! **last** vertex:
//!
//! | stage of the bounce | call |
//! |---|---|
//! | new block of paths | [`start(n)`](BatchRecorder::start) |
//! | hit: position, normal, `wo`, emission + MIS weight, `is_delta` | [`add_vertex(slot, PathVertex { … })`](BatchRecorder::add_vertex) |
//! | Russian roulette survived with probability `q` | [`scale_continuation(slot, 1 / q)`](BatchRecorder::scale_continuation) |
//! | unoccluded shadow ray (0, 1 or more per vertex) | [`add_direct(slot, rgb)`](BatchRecorder::add_direct) |
//! | continuation sampled | [`set_continuation(slot, Continuation { … })`](BatchRecorder::set_continuation) |
//! | path ends (absorbed, depth, roulette) | nothing (`sample_pdf` stays `0`) |
//! | ray left the scene | [`add_escaped_radiance(slot, rgb, mis)`](BatchRecorder::add_escaped_radiance) |
//! | block done | [`end()`](BatchRecorder::end) → `L̃_o(0)` per slot |
//!
//! `continuation_scale` multiplies the scattered radiance only, as in
//! [`PathVertex`]; a renderer whose roulette also scales its NEE at that
//! vertex passes the scaled value to `add_direct`.
//!
//! # Storage
//!
//! One flat vertex array in the order the vertices were added (bounce by
//! bounce), a `prev` index per vertex and the last vertex and escaped
//! radiance per slot; [`BatchRecorder::end`] walks each slot's chain from its
//! last vertex back. Every buffer is reused across [`BatchRecorder::start`],
//! so a renderer that keeps its recorder allocates nothing in steady state.
//!
//! # Bad input
//!
//! Nothing panics. A call for a slot outside `0 … n−1` (or after
//! [`BatchRecorder::end`]), and a per-vertex call for a slot without a
//! vertex yet, is **ignored**: it returns `false` and is counted by
//! [`BatchRecorder::ignored_calls`]. Values are not checked here, as in the
//! `PathRecorder`: a non-finite radiance propagates into the samples and
//! estimates it reaches, and [`GuidingField::add_samples`] rejects (and
//! counts) such samples; a NaN `sample_pdf` ends the path like `0`.

use super::{add, propagate, Escaped, PathVertex, RecordedSamples, ReflectedSample};
use crate::field::GuidingField;
use guiding_core::sample::TrainingSample;

/// No vertex (end of a chain, or a slot without vertices).
const NONE: u32 = u32::MAX;

/// The continuation sampled at a vertex: the [`PathVertex`] fields of the
/// same names.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Continuation {
    /// Unit sampled continuation direction.
    pub wi: [f32; 3],
    /// Density with which `wi` was sampled (the one-sample MIS density of
    /// BSDF and guide); `0` ends the path here.
    pub sample_pdf: f32,
    /// Density of `wi` under BSDF sampling alone, `0` if unknown.
    pub bsdf_pdf: f32,
    /// `f(wo, wi) |cos θ_i|` (not divided by the pdf).
    pub bsdf_cos: [f32; 3],
}

/// Records a block of paths traced together (a wavefront) and turns them
/// into training samples; see the [module docs](self) for the calls per
/// bounce. Use one per render thread; hand the samples to the field between
/// passes with [`Self::flush_into`].
///
/// ```
/// use guiding::{BatchRecorder, Continuation, PathRecorder, PathVertex};
///
/// let mut rec = BatchRecorder::new();
/// rec.start(2);
/// // Bounce 0: slot 0 hits a diffuse surface, slot 1 a light (and stops).
/// rec.add_vertex(0, PathVertex { wo: [0.0, 0.0, 1.0], ..PathVertex::default() });
/// rec.add_vertex(1, PathVertex { emitted: [1.0; 3], ..PathVertex::default() });
/// rec.add_direct(0, [0.25; 3]); // slot 0's shadow ray reached a light
/// let wi = [0.0, 0.0, 1.0];
/// rec.set_continuation(0, Continuation { wi, sample_pdf: 0.5, bsdf_cos: [0.25; 3], ..Continuation::default() });
/// // Bounce 1: slot 0 leaves the scene; an environment of radiance 2 with MIS weight ½.
/// rec.add_escaped_radiance(0, [2.0; 3], 0.5);
/// assert!(!rec.add_direct(7, [1.0; 3])); // no slot 7: ignored
///
/// // L̃_o(0) per slot: 0.25 + 0.25 / 0.5 · (½ · 2) for slot 0, the light for slot 1.
/// assert_eq!(rec.end(), &[[0.75; 3], [1.0; 3]]);
/// // One sample (slot 0's vertex), whose target is the escaped radiance in full.
/// assert_eq!(rec.len(), 1);
/// assert_eq!(rec.samples()[0].radiance, [2.0; 3]);
/// assert_eq!(rec.ignored_calls(), 1);
///
/// // The same path through a PathRecorder gives the same sample.
/// let mut one = PathRecorder::new();
/// one.start_path();
/// one.add_vertex(PathVertex {
///     wo: [0.0, 0.0, 1.0],
///     direct: [0.25; 3],
///     wi,
///     sample_pdf: 0.5,
///     bsdf_cos: [0.25; 3],
///     ..PathVertex::default()
/// });
/// one.add_escaped_radiance([2.0; 3], 0.5);
/// assert_eq!(one.end_path(), [0.75; 3]);
/// assert_eq!(one.samples(), rec.samples());
/// ```
#[derive(Clone, Debug, Default)]
pub struct BatchRecorder {
    /// Every vertex of the current block, in the order added.
    vertices: Vec<PathVertex>,
    /// Per vertex: the previous vertex of its path (`NONE` for vertex 0).
    prev: Vec<u32>,
    /// Per slot: its last vertex (`NONE` while it has none).
    last: Vec<u32>,
    /// Per slot: radiance that escaped along its last vertex's `wi`.
    escaped: Vec<Escaped>,
    /// Per slot: `L̃_o(0)` of the block [`Self::end`] finished last.
    estimates: Vec<[f32; 3]>,
    recorded: RecordedSamples,
    ignored: u64,
}

/// One slot's vertices, from its last back to vertex 0.
struct Chain<'a> {
    vertices: &'a [PathVertex],
    prev: &'a [u32],
    at: u32,
}

impl<'a> Iterator for Chain<'a> {
    type Item = &'a PathVertex;

    fn next(&mut self) -> Option<&'a PathVertex> {
        let i = self.at as usize;
        let v = self.vertices.get(i)?;
        self.at = self.prev.get(i).copied().unwrap_or(NONE);
        Some(v)
    }
}

impl BatchRecorder {
    /// An empty recorder (no block started: every call is ignored until
    /// [`Self::start`]).
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a block of `paths` empty paths, slots `0 … paths−1`. An
    /// unfinished previous block is discarded, as are the estimates of the
    /// last [`Self::end`]; the training samples are kept.
    pub fn start(&mut self, paths: usize) {
        self.vertices.clear();
        self.prev.clear();
        self.last.clear();
        self.last.resize(paths, NONE);
        self.escaped.clear();
        self.escaped.resize(paths, Escaped::default());
        self.estimates.clear();
    }

    /// Slots of the current block (`0` after [`Self::end`]).
    pub fn paths(&self) -> usize {
        self.last.len()
    }

    /// Vertices recorded in the current block, all slots together.
    pub fn vertex_count(&self) -> usize {
        self.vertices.len()
    }

    /// Appends the next vertex of path `slot`; the fields known only later
    /// (`direct`, the continuation, `continuation_scale`) may be left at
    /// their defaults and filled in by the calls below. `false` (ignored) if
    /// `slot` is not in the block.
    pub fn add_vertex(&mut self, slot: u32, vertex: PathVertex) -> bool {
        let index = self.vertices.len();
        match self.last.get_mut(slot as usize) {
            Some(last) if index < NONE as usize => {
                self.prev.push(*last);
                *last = index as u32;
                self.vertices.push(vertex);
                true
            }
            _ => self.ignore(),
        }
    }

    /// The last vertex of path `slot`, as recorded so far.
    pub fn last_vertex(&self, slot: u32) -> Option<&PathVertex> {
        let last = *self.last.get(slot as usize)?;
        self.vertices.get(last as usize)
    }

    /// Adds next-event estimation (already weighted, as
    /// [`PathVertex::direct`]) to the last vertex of path `slot`; adds up
    /// over calls. `false` (ignored) if the slot has no vertex.
    pub fn add_direct(&mut self, slot: u32, direct: [f32; 3]) -> bool {
        self.with_last(slot, |v| v.direct = add(v.direct, direct))
    }

    /// Sets the continuation of the last vertex of path `slot` (a vertex
    /// without one ends its path). `false` (ignored) if the slot has no
    /// vertex.
    pub fn set_continuation(&mut self, slot: u32, continuation: Continuation) -> bool {
        self.with_last(slot, |v| {
            v.wi = continuation.wi;
            v.sample_pdf = continuation.sample_pdf;
            v.bsdf_pdf = continuation.bsdf_pdf;
            v.bsdf_cos = continuation.bsdf_cos;
        })
    }

    /// Multiplies the `continuation_scale` of the last vertex of path `slot`
    /// by `factor` (`1 / q` after surviving Russian roulette with
    /// probability `q`), before or after [`Self::set_continuation`].
    /// `false` (ignored) if the slot has no vertex.
    pub fn scale_continuation(&mut self, slot: u32, factor: f32) -> bool {
        self.with_last(slot, |v| v.continuation_scale *= factor)
    }

    /// Radiance arriving along the last vertex's `wi` of path `slot` from
    /// outside the scene, with its MIS weight, as
    /// [`PathRecorder::add_escaped_radiance`](super::PathRecorder::add_escaped_radiance)
    /// (for a slot without vertices it is what the camera saw). Adds up over
    /// calls. `false` (ignored) if `slot` is not in the block.
    pub fn add_escaped_radiance(&mut self, slot: u32, radiance: [f32; 3], mis_weight: f32) -> bool {
        match self.escaped.get_mut(slot as usize) {
            Some(e) => {
                e.add(radiance, mis_weight);
                true
            }
            None => self.ignore(),
        }
    }

    /// Ends the block: propagates every path back along its vertices, in
    /// slot order, appends their training samples (slot 0's in path order,
    /// then slot 1's, …) and returns `L̃_o(0)` per slot (also kept in
    /// [`Self::estimates`] until the next [`Self::start`]). The block is
    /// then empty ([`Self::paths`] is 0).
    pub fn end(&mut self) -> &[[f32; 3]] {
        self.estimates.clear();
        for (&at, &escaped) in self.last.iter().zip(&self.escaped) {
            let chain = Chain {
                vertices: &self.vertices,
                prev: &self.prev,
                at,
            };
            self.estimates
                .push(propagate(chain, escaped, &mut self.recorded));
        }
        self.vertices.clear();
        self.prev.clear();
        self.last.clear();
        self.escaped.clear();
        &self.estimates
    }

    /// `L̃_o(0)` per slot of the block [`Self::end`] finished last.
    pub fn estimates(&self) -> &[[f32; 3]] {
        &self.estimates
    }

    /// Training samples of the finished blocks so far.
    pub fn samples(&self) -> &[TrainingSample] {
        &self.recorded.samples
    }

    /// Number of training samples of the finished blocks.
    pub fn len(&self) -> usize {
        self.recorded.samples.len()
    }

    /// Whether there are no training samples.
    pub fn is_empty(&self) -> bool {
        self.recorded.samples.is_empty()
    }

    /// The MIS-weighted incident radiance of each of [`Self::samples`] (see
    /// [`crate::recorder`]).
    pub fn mis_radiance(&self) -> &[[f32; 3]] {
        &self.recorded.mis_radiance
    }

    /// Removes the training samples and yields them (the buffer keeps its
    /// capacity); their MIS-weighted radiances are dropped.
    pub fn drain_samples(&mut self) -> std::vec::Drain<'_, TrainingSample> {
        self.recorded.mis_radiance.clear();
        self.recorded.samples.drain(..)
    }

    /// Moves the training samples and their MIS-weighted incident radiances
    /// to the ends of `samples` and `mis_radiance`.
    pub fn drain_into(
        &mut self,
        samples: &mut Vec<TrainingSample>,
        mis_radiance: &mut Vec<[f32; 3]>,
    ) {
        samples.append(&mut self.recorded.samples);
        mis_radiance.append(&mut self.recorded.mis_radiance);
    }

    /// Whether to keep each continuing vertex's reflected radiance
    /// ([`Self::reflected`], see [`crate::recorder`]); off by default. Turning
    /// it off drops what was kept.
    pub fn keep_reflected(&mut self, keep: bool) {
        self.recorded.keep_reflected(keep);
    }

    /// The reflected radiance of every continuing vertex of the finished blocks
    /// (in the order of [`Self::end`]'s propagation: slot by slot, each path
    /// from its last vertex back); empty unless [`Self::keep_reflected`].
    pub fn reflected(&self) -> &[ReflectedSample] {
        self.recorded.reflected()
    }

    /// Moves the kept reflected radiance to the end of `out`.
    pub fn drain_reflected_into(&mut self, out: &mut Vec<ReflectedSample>) {
        self.recorded.drain_reflected_into(out);
    }

    /// Hands every finished block's samples to `field` and clears them;
    /// returns how many were handed over.
    pub fn flush_into(&mut self, field: &mut GuidingField) -> usize {
        self.recorded.flush_into(field)
    }

    /// Drops the finished blocks' samples.
    pub fn clear_samples(&mut self) {
        self.recorded.clear();
    }

    /// Calls ignored so far (slot out of range, or no vertex to fill in).
    pub fn ignored_calls(&self) -> u64 {
        self.ignored
    }

    fn ignore(&mut self) -> bool {
        self.ignored += 1;
        false
    }

    fn with_last(&mut self, slot: u32, f: impl FnOnce(&mut PathVertex)) -> bool {
        let last = self.last.get(slot as usize).copied().unwrap_or(NONE);
        match self.vertices.get_mut(last as usize) {
            Some(v) => {
                f(v);
                true
            }
            None => self.ignore(),
        }
    }
}
