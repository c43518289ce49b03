//! Batch kernels, one element per call: the bodies that a CPU loop and a
//! SPIR-V compute entry point (crate `guiding-shaders`, one invocation per
//! element) both run, so that the GPU executes exactly this code.
//!
//! Conventions (shared with the Vulkan runtime in `guiding-gpu`):
//! - every buffer is a flat slice of `f32`, `[f32; 4]` or a `#[repr(C)]`
//!   [`Pod`] struct; vectors travel as `[f32; 4]` (std430 has no packed
//!   `vec3` arrays), so a direction sample is `[x, y, z, pdf]` and a random
//!   pair is `[u₀, u₁, ·, ·]`;
//! - `i` is the element index; a call with `i` past the batch does nothing
//!   (an invocation of the last, partial workgroup);
//! - no allocation, no iterator, no `dyn`, `f32` only.
//!
//! The training step is three kernels: [`gradient_sample`] (one invocation
//! per sample, adding its gradient into one shared buffer through the
//! caller's [`GradientSink`] — on the GPU an atomic compare-and-swap float
//! add, since Vulkan guarantees no float atomics), [`max_abs_partial`]
//! (block maxima the host reads to skip a non-finite step or clip a large
//! one, as `Field` does) and [`adam_element`] (one invocation per
//! parameter). One sample per invocation keeps every invocation short:
//! lavapipe (Mesa's CPU Vulkan driver) cuts any invocation's loops after
//! 65535 iterations in total (gallivm's loop limiter), which a chunk of a
//! few dozen samples through a compact network already exceeds. The GPU
//! adds the samples in whatever order the atomics land, so its gradient
//! equals the CPU's up to the rounding of a reordered sum.

use crate::factorised::FactorisedTable;
use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::mixture::nasg::{decode_selection, NasgMixture, NASG_RAW_PER_LOBE};
use crate::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use crate::model::df::{DfVertex, VertexModel, DF_CONDITIONAL_BINS, DF_MARGINAL_BINS};
use crate::model::nasg::{NASG_LOBES, NASG_OUTPUTS, NASG_SELECTION_OUTPUT};
use crate::model::npm::{NPM_LOBES, NPM_OUTPUTS};
use crate::model::{GuidingModel, QueryPoint, RawOutputs};
use crate::optim::{adam_update_with_factors, ema_update_element, AdamConfig, AdamStepFactors};
use crate::pdf1d::Interpolation;
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Raw outputs per element of the DF decode kernels: the marginal logits,
/// then the `DF_MARGINAL_BINS` conditional rows.
pub const DF_TABLE_LOGITS: usize = DF_MARGINAL_BINS + DF_MARGINAL_BINS * DF_CONDITIONAL_BINS;

/// Push constants of the element kernels.
///
/// `repr(C)`, [`Pod`], 16 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BatchArgs {
    /// Number of elements (queries, samples or parameters).
    pub count: u32,
    /// The interpolation code of the DF decode kernels (0 nearest, 1
    /// linear); unused elsewhere.
    pub code: u32,
    /// Padding.
    pub pad: [u32; 2],
}

/// Push constants of [`adam_element`].
///
/// `repr(C)`, [`Pod`], 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct AdamArgs {
    /// Number of parameters.
    pub count: u32,
    /// Padding.
    pub pad: [u32; 3],
    /// Optimiser settings.
    pub adam: AdamConfig,
    /// Bias corrections of this step.
    pub factors: AdamStepFactors,
    /// Factor applied to every gradient element first (`1`, or
    /// `clip / max|g|` for a clipped step).
    pub gradient_scale: f32,
    /// Weight of the new parameters in the EMA ([`crate::optim::ema_weight`]).
    pub ema_alpha: f32,
}

/// `[x, y, z, pdf]` of a direction sample.
#[inline]
#[must_use]
pub fn pack_sample(s: DirectionSample) -> [f32; 4] {
    [s.direction.x, s.direction.y, s.direction.z, s.pdf]
}

/// The direction of a packed `[x, y, z, ·]`.
#[inline]
#[must_use]
pub fn unpack_direction(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Network outputs of query `i`: `out[i·R .. (i+1)·R]` with `R =
/// M::RAW_OUTPUTS` ([`RawOutputs::write_raw`]).
#[inline]
pub fn infer_element<M: RawOutputs>(
    model: &M,
    params: &[f32],
    queries: &[QueryPoint],
    out: &mut [f32],
    i: usize,
) {
    if i < queries.len() {
        model.write_raw(params, &queries[i], out, i * M::RAW_OUTPUTS);
    }
}

/// `out[i] = [ω, pdf]` of [`GuidingModel::sample`] at query `i` with the
/// random pair `u[i]`.
#[inline]
pub fn sample_element<M: GuidingModel>(
    model: &M,
    params: &[f32],
    queries: &[QueryPoint],
    u: &[[f32; 4]],
    out: &mut [[f32; 4]],
    i: usize,
) {
    if i < queries.len() && i < u.len() && i < out.len() {
        let r = u[i];
        out[i] = pack_sample(model.sample(params, &queries[i], Vec2::new(r[0], r[1])));
    }
}

/// `out[i]` = [`GuidingModel::pdf`] of direction `directions[i]` at query `i`.
#[inline]
pub fn pdf_element<M: GuidingModel>(
    model: &M,
    params: &[f32],
    queries: &[QueryPoint],
    directions: &[[f32; 4]],
    out: &mut [f32],
    i: usize,
) {
    if i < queries.len() && i < directions.len() && i < out.len() {
        out[i] = model.pdf(params, &queries[i], unpack_direction(directions[i]));
    }
}

/// `out[i]` = [`GuidingModel::selection_probability`] at query `i`.
#[inline]
pub fn selection_element<M: GuidingModel>(
    model: &M,
    params: &[f32],
    queries: &[QueryPoint],
    out: &mut [f32],
    i: usize,
) {
    if i < queries.len() && i < out.len() {
        out[i] = model.selection_probability(params, &queries[i]);
    }
}

/// Training loss of sample `i` into `losses[i]`, its parameter gradient
/// added into `grad` ([`GuidingModel::accumulate_gradient`]); the sum over
/// the batch divided by `count` is the step's gradient. Samples past
/// `count` (or the buffers) do nothing.
#[inline]
pub fn gradient_sample<M: GuidingModel, G: GradientSink + ?Sized>(
    model: &M,
    params: &[f32],
    samples: &[TrainingSample],
    count: usize,
    grad: &mut G,
    losses: &mut [f32],
    i: usize,
) {
    if i < count && i < samples.len() && i < losses.len() {
        losses[i] = model.accumulate_gradient(params, &samples[i], grad);
    }
}

/// Elements per block of [`max_abs_partial`].
pub const MAX_ABS_BLOCK: usize = 256;

/// `out[b] = max |g|` over block `b` (`MAX_ABS_BLOCK` elements) of `g`, or
/// `+∞` when the block holds a non-finite value: the host reads these
/// `⌈P / 256⌉` values to skip (non-finite) or clip the step, as `Field` does.
#[inline]
pub fn max_abs_partial(g: &[f32], count: usize, out: &mut [f32], b: usize) {
    if b >= out.len() {
        return;
    }
    let n = if count < g.len() { count } else { g.len() };
    let mut max = 0.0f32;
    let mut j = b * MAX_ABS_BLOCK;
    let end = j + MAX_ABS_BLOCK;
    while j < end && j < n {
        let x = g[j];
        if !x.is_finite() {
            max = f32::INFINITY;
        } else if x.abs() > max {
            max = x.abs();
        }
        j += 1;
    }
    out[b] = max;
}

/// One parameter's Adam update ([`adam_update_with_factors`] on
/// `gradient_scale · grad[j]`), then its EMA ([`ema_update_element`]) and
/// `grad[j] = 0`. Returns whether Adam updated the element.
#[inline]
pub fn adam_element(
    params: &mut [f32],
    grad: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    ema: &mut [f32],
    args: &AdamArgs,
    j: usize,
) -> bool {
    let n = args.count as usize;
    if j >= n || j >= params.len() || j >= grad.len() || j >= m.len() || j >= v.len() {
        return false;
    }
    let g = grad[j] * args.gradient_scale;
    let mut p = params[j];
    let mut mj = m[j];
    let mut vj = v[j];
    let updated = adam_update_with_factors(&mut p, &mut mj, &mut vj, g, &args.adam, &args.factors);
    params[j] = p;
    m[j] = mj;
    v[j] = vj;
    if j < ema.len() {
        let mut e = ema[j];
        ema_update_element(&mut e, p, args.ema_alpha);
        ema[j] = e;
    }
    grad[j] = 0.0;
    updated
}

/// `raw[i]`, or 0 for a missing slot.
#[inline]
fn raw_at(raw: &[f32], i: usize) -> f32 {
    if i < raw.len() {
        raw[i]
    } else {
        0.0
    }
}

/// The row `raw[base .. base + R]`; missing slots read as 0.
#[inline]
fn raw_row<const R: usize>(raw: &[f32], base: usize) -> [f32; R] {
    let mut row = [0.0f32; R];
    let mut r = 0;
    while r < R {
        row[r] = raw_at(raw, base + r);
        r += 1;
    }
    row
}

/// `K` consecutive rows of `R` raw outputs from `raw[base]` ([`raw_row`]).
#[inline]
fn raw_rows<const K: usize, const R: usize>(raw: &[f32], base: usize) -> [[f32; R]; K] {
    let mut rows = [[0.0f32; R]; K];
    let mut k = 0;
    while k < K {
        rows[k] = raw_row::<R>(raw, base + k * R);
        k += 1;
    }
    rows
}

/// The NPM mixture of the raw outputs `raw[base .. base + 32]` (8 rows of
/// `[w, ln κ, θ, φ]`, [`VmfMixture::decode`]); missing slots read as 0.
#[must_use]
pub fn vmf_mixture_from_raw(raw: &[f32], base: usize) -> VmfMixture<NPM_LOBES> {
    VmfMixture::decode(&raw_rows::<NPM_LOBES, VMF_RAW_PER_LOBE>(raw, base))
}

/// The NASG mixture (with its selection probability) of the raw outputs
/// `raw[base .. base + 49]` ([`NasgMixture::decode`]); missing slots read
/// as 0.
#[must_use]
pub fn nasg_mixture_from_raw(raw: &[f32], base: usize) -> NasgMixture<NASG_LOBES> {
    let rows = raw_rows::<NASG_LOBES, NASG_RAW_PER_LOBE>(raw, base);
    NasgMixture::decode(&rows, raw_at(raw, base + NASG_SELECTION_OUTPUT))
}

/// The DF table of the logits `raw[base .. base + DF_TABLE_LOGITS]`
/// ([`FactorisedTable::from_logits`]); missing slots read as 0.
#[must_use]
pub fn df_table_from_raw(
    raw: &[f32],
    base: usize,
    interpolation: Interpolation,
) -> FactorisedTable<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS> {
    let marginal = raw_row::<DF_MARGINAL_BINS>(raw, base);
    let conditional =
        raw_rows::<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS>(raw, base + DF_MARGINAL_BINS);
    FactorisedTable::from_logits(&marginal, &conditional, interpolation)
}

/// A directional distribution decoded from one row of raw network outputs:
/// what the decode kernels ([`decode_sample_element`],
/// [`decode_pdf_element`]) and the lane kernels ([`lane_sample_element`],
/// [`lane_pdf_element`]) sample and evaluate, one implementation per
/// representation, so that each kernel exists once.
pub trait RawRowDistribution: Sized {
    /// Raw outputs per row.
    const STRIDE: usize;
    /// The distribution of `raw[base .. base + STRIDE]` (missing slots read
    /// as 0). `code` is the dispatch's variant code ([`BatchArgs::code`]):
    /// DF's interpolation ([`Interpolation::from_code`]); the mixtures ignore
    /// it.
    fn from_raw_row(raw: &[f32], base: usize, code: u32) -> Self;
    /// This distribution times the clamped cosine around `normal`,
    /// renormalised (NPM §4.2). The default returns it unchanged: NASG and
    /// DF have no closed-form product, and their callers never ask for one.
    #[inline]
    #[must_use]
    fn with_clamped_cosine(self, normal: Vec3) -> Self {
        let _ = normal;
        self
    }
    /// A direction and its density from `u ∈ [0,1)²`.
    fn sample_direction(&self, u: Vec2) -> DirectionSample;
    /// The density of `direction` (unit length).
    fn density(&self, direction: Vec3) -> f32;
}

/// [`RawRowDistribution::sample_direction`] and
/// [`RawRowDistribution::density`] of a type whose inherent `sample` and
/// `pdf` are exactly those.
macro_rules! sample_and_pdf_by_inherent_methods {
    () => {
        #[inline]
        fn sample_direction(&self, u: Vec2) -> DirectionSample {
            self.sample(u)
        }
        #[inline]
        fn density(&self, direction: Vec3) -> f32 {
            self.pdf(direction)
        }
    };
}

impl RawRowDistribution for VmfMixture<NPM_LOBES> {
    const STRIDE: usize = NPM_OUTPUTS;
    #[inline]
    fn from_raw_row(raw: &[f32], base: usize, _code: u32) -> Self {
        vmf_mixture_from_raw(raw, base)
    }
    #[inline]
    fn with_clamped_cosine(self, normal: Vec3) -> Self {
        self.product_with_clamped_cosine(normal)
    }
    sample_and_pdf_by_inherent_methods!();
}

impl RawRowDistribution for NasgMixture<NASG_LOBES> {
    const STRIDE: usize = NASG_OUTPUTS;
    #[inline]
    fn from_raw_row(raw: &[f32], base: usize, _code: u32) -> Self {
        nasg_mixture_from_raw(raw, base)
    }
    sample_and_pdf_by_inherent_methods!();
}

impl RawRowDistribution for FactorisedTable<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS> {
    const STRIDE: usize = DF_TABLE_LOGITS;
    #[inline]
    fn from_raw_row(raw: &[f32], base: usize, code: u32) -> Self {
        df_table_from_raw(raw, base, Interpolation::from_code(code))
    }
    sample_and_pdf_by_inherent_methods!();
}

/// Decode kernel: `out[i] = [ω, pdf]` sampled with `u[i]` from the
/// distribution `D` of raw row `i` ([`RawRowDistribution::from_raw_row`]
/// with the dispatch's `code`).
#[inline]
pub fn decode_sample_element<D: RawRowDistribution>(
    raw: &[f32],
    code: u32,
    u: &[[f32; 4]],
    out: &mut [[f32; 4]],
    i: usize,
) {
    if i < u.len() && i < out.len() {
        let r = u[i];
        let d = D::from_raw_row(raw, i * D::STRIDE, code);
        out[i] = pack_sample(d.sample_direction(Vec2::new(r[0], r[1])));
    }
}

/// Decode kernel: `out[i]` = density of `directions[i]` under the
/// distribution `D` of raw row `i`.
#[inline]
pub fn decode_pdf_element<D: RawRowDistribution>(
    raw: &[f32],
    code: u32,
    directions: &[[f32; 4]],
    out: &mut [f32],
    i: usize,
) {
    if i < directions.len() && i < out.len() {
        let d = D::from_raw_row(raw, i * D::STRIDE, code);
        out[i] = d.density(unpack_direction(directions[i]));
    }
}

/// The first raw output of lane `i` of a lane kernel with `stride` outputs
/// per row: `lanes[i] · stride`, or `raw.len()` (every slot then reads as
/// 0) when `i` is past `lanes` or the row past `raw`.
#[inline]
fn lane_base(raw: &[f32], lanes: &[u32], stride: usize, i: usize) -> usize {
    if i < lanes.len() && (lanes[i] as usize) < raw.len() / stride {
        lanes[i] as usize * stride
    } else {
        raw.len()
    }
}

/// The distribution of lane `i` of a lane kernel: raw row `lanes[i]`,
/// multiplied by the clamped cosine of `normals[i]`'s `xyz` where its `w` is
/// `> 0` ([`RawRowDistribution::with_clamped_cosine`]: what
/// `DistributionBatch::apply_cosine_product` does on the CPU).
#[inline]
fn lane_distribution<D: RawRowDistribution>(
    raw: &[f32],
    lanes: &[u32],
    normals: &[[f32; 4]],
    i: usize,
) -> D {
    let d = D::from_raw_row(raw, lane_base(raw, lanes, D::STRIDE, i), 0);
    if i < normals.len() && normals[i][3] > 0.0 {
        let n = normals[i];
        d.with_clamped_cosine(Vec3::new(n[0], n[1], n[2]))
    } else {
        d
    }
}

/// Lane kernel: `out[i] = [ω, pdf]` sampled with `u[i]` from the
/// distribution `D` of raw row `lanes[i]` (the raw outputs of a whole
/// wavefront stay on the device; a call samples some of its lanes), with
/// the cosine product where `normals[i].w > 0` (see [`lane_pdf_element`]).
#[inline]
pub fn lane_sample_element<D: RawRowDistribution>(
    raw: &[f32],
    lanes: &[u32],
    normals: &[[f32; 4]],
    u: &[[f32; 4]],
    out: &mut [[f32; 4]],
    i: usize,
) {
    if i < u.len() && i < out.len() {
        let r = u[i];
        let d = lane_distribution::<D>(raw, lanes, normals, i);
        out[i] = pack_sample(d.sample_direction(Vec2::new(r[0], r[1])));
    }
}

/// Lane kernel: `out[i]` = density of `directions[i]` under the
/// distribution `D` of raw row `lanes[i]`, times the clamped cosine of
/// `normals[i].xyz` (renormalised, as the CPU's cosine product) where
/// `normals[i].w > 0`.
#[inline]
pub fn lane_pdf_element<D: RawRowDistribution>(
    raw: &[f32],
    lanes: &[u32],
    normals: &[[f32; 4]],
    directions: &[[f32; 4]],
    out: &mut [f32],
    i: usize,
) {
    if i < directions.len() && i < out.len() {
        let d = lane_distribution::<D>(raw, lanes, normals, i);
        out[i] = d.density(unpack_direction(directions[i]));
    }
}

/// Kernel: `out[i]` = the learned guide-selection probability of the NASG
/// raw row `i`: [`decode_selection`] of its selection output alone (what
/// [`nasg_mixture_from_raw`] stores, without decoding the lobes); a missing
/// slot reads as 0.
#[inline]
pub fn nasg_selection_element(raw: &[f32], out: &mut [f32], i: usize) {
    if i < out.len() {
        let s = i * NASG_OUTPUTS + NASG_SELECTION_OUTPUT;
        out[i] = decode_selection(raw_at(raw, s)).0;
    }
}

/// DF vertex kernel: `out[i]` = the [`DfVertex`] of `queries[i]` (grid,
/// product inputs and the marginal network, once per shading point).
#[inline]
pub fn vertex_element<M: VertexModel>(
    model: &M,
    params: &[f32],
    queries: &[QueryPoint],
    out: &mut [DfVertex],
    i: usize,
) {
    if i < queries.len() && i < out.len() {
        out[i] = model.vertex(params, &queries[i]);
    }
}

/// DF vertex lane kernel: `out[i] = [ω, pdf]` sampled with `u[i]` at the
/// resident vertex `vertices[lanes[i]]` (the conditional network once, or
/// twice where `ε₁` rounds into another bin); `[0, 0, 1, 0]` for a lane
/// past `vertices`.
#[inline]
pub fn vertex_sample_element<M: VertexModel>(
    model: &M,
    params: &[f32],
    vertices: &[DfVertex],
    lanes: &[u32],
    u: &[[f32; 4]],
    out: &mut [[f32; 4]],
    i: usize,
) {
    if i < lanes.len() && i < u.len() && i < out.len() {
        let l = lanes[i] as usize;
        out[i] = if l < vertices.len() {
            let r = u[i];
            pack_sample(model.sample_vertex(params, &vertices[l], Vec2::new(r[0], r[1])))
        } else {
            [0.0, 0.0, 1.0, 0.0]
        };
    }
}

/// DF vertex lane kernel: `out[i]` = the density of `directions[i]` at the
/// resident vertex `vertices[lanes[i]]` (one conditional pass); 0 for a lane
/// past `vertices`.
#[inline]
pub fn vertex_pdf_element<M: VertexModel>(
    model: &M,
    params: &[f32],
    vertices: &[DfVertex],
    lanes: &[u32],
    directions: &[[f32; 4]],
    out: &mut [f32],
    i: usize,
) {
    if i < lanes.len() && i < directions.len() && i < out.len() {
        let l = lanes[i] as usize;
        out[i] = if l < vertices.len() {
            model.pdf_vertex(params, &vertices[l], unpack_direction(directions[i]))
        } else {
            0.0
        };
    }
}
