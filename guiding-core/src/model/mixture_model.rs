//! The mixture models, NPM ([`super::npm`]) and NASG ([`super::nasg`]), as
//! one generic: `[grid | product inputs]` → `Mlp<IN, WIDTH, OUT, HIDDEN>` →
//! a mixture of lobes decoded from the `OUT` raw outputs. The two models
//! are [`MixtureModel`] with a different [`MixtureFamily`]: the lobe (vMF or
//! NASG), its decoder, how the selection probability is found (a constant
//! or learned) and the training loss (NPM eq. 9 or NASG eq. 18).
//!
//! ## Parameter layout (one flat `f32` buffer)
//!
//! ```text
//! [0, mlp_offset)                         grid (GridConfig layout, offset 0)
//! [mlp_offset, mlp_offset + MLP params)   Mlp<IN, WIDTH, OUT, HIDDEN> (mlp.rs layout)
//! ```

use super::npm::{
    all_finite, encode_inputs, grid_param_count, input_dims, mlp_init, network_seed, region_end,
    target_code, target_from_code,
};
use super::{Family, GuidingModel, QueryPoint, RawOutputs};
use crate::encoding::{grid_backward, grid_init, GridConfig};
use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::loss::{kl_weight, Target};
use crate::mixture::LobeMixture;
use crate::mlp::{Mlp, MlpContext};
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// What distinguishes one mixture model from the other: the decoded mixture
/// of `OUT` raw outputs, the selection probability and the loss. The
/// implementing type is the family's own setting stored in the model
/// (8 bytes: `repr(C)` of 4-byte scalars, so that [`MixtureModel`] stays
/// 64 bytes without padding).
pub trait MixtureFamily<const OUT: usize>: Copy + Pod + PartialEq + core::fmt::Debug {
    /// The family of the decoded distribution.
    const FAMILY: Family;
    /// The setting of a new model.
    const DEFAULT: Self;
    /// The learned selection probability where `params` is too short (the
    /// value of [`Self::uniform_raw`]).
    const UNFIT_SELECTION_PROBABILITY: f32;

    /// The mixture decoded at one query.
    type Decoded: LobeMixture;

    /// Raw outputs of the near-uniform mixture (lobe widths at their lower
    /// clamps), used when `params` is too short.
    fn uniform_raw() -> [f32; OUT];

    /// The mixture of raw outputs `y`.
    fn decode(y: &[f32; OUT]) -> Self::Decoded;

    /// The selection probability where it is a constant of the setting;
    /// `None` where the network learns it.
    fn constant_selection_probability(&self) -> Option<f32>;

    /// The learned selection probability of raw outputs `y` (only asked
    /// where [`Self::constant_selection_probability`] is `None`).
    fn learned_selection_probability(y: &[f32; OUT]) -> f32;

    /// One sample's loss at outputs `y` with KL weight `w`, and its
    /// gradient with respect to `y` written to `d_y`.
    fn output_gradient(
        &self,
        y: &[f32; OUT],
        sample: &TrainingSample,
        w: f32,
        d_y: &mut [f32; OUT],
    ) -> f32;

    /// `out[i] = decode(ys[i])` over a batch, lane-parallel
    /// ([`super::batched`]).
    ///
    /// # Panics
    /// If `ys` and `out` differ in length.
    #[cfg(feature = "std")]
    fn decode_batch(ys: &[[f32; OUT]], out: &mut [Self::Decoded]);

    /// [`Self::output_gradient`] of the live samples of a training chunk
    /// ([`super::batched`]). The default goes sample by sample; a family
    /// may vectorise it over the chunk.
    #[cfg(feature = "std")]
    fn output_gradients(&self, c: super::batched::ChunkOutputs<'_, OUT>) {
        for k in 0..c.ys.len() {
            let s = &c.chunk[c.live[k]];
            c.losses[k] = self.output_gradient(&c.ys[k], s, kl_weight(s, c.target), &mut c.dys[k]);
        }
    }
}

/// A mixture model: `[grid | product inputs]` → `Mlp<IN, WIDTH, OUT,
/// HIDDEN>` → `F::Decoded` (layout in the [module docs](self)).
///
/// `IN` must equal [`input_dims`]`(grid, target)`; [`Self::is_consistent`]
/// checks it and the presets are checked at compile time. An inconsistent
/// configuration still never panics or produces NaN (the encoding is
/// truncated or zero-padded), it is merely not the model described here.
///
/// `repr(C)`, [`Pod`], 64 bytes: the plain data a GPU kernel reads from a
/// storage buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MixtureModel<
    F,
    const IN: usize,
    const WIDTH: usize,
    const HIDDEN: usize,
    const OUT: usize,
> {
    /// The grid; its `offset` is 0 (the grid leads the flat buffer).
    pub grid: GridConfig,
    /// Offset of the MLP in the flat buffer: `grid_param_count(grid)`.
    pub mlp_offset: u32,
    /// [`Target`] code (see [`target_code`]).
    pub target: u32,
    /// The family's setting (NPM: the constant selection probability; NASG:
    /// the blend `e` of its loss).
    pub family: F,
}

// SAFETY: `repr(C)` struct of a `Pod` `GridConfig` (48 bytes, align 4), two
// `u32` and a `Pod` `F` of 4-byte scalars (see `MixtureFamily`): no padding,
// every bit pattern valid, zero valid. The const parameters do not affect
// the layout.
unsafe impl<F: Pod, const IN: usize, const W: usize, const H: usize, const OUT: usize> Zeroable
    for MixtureModel<F, IN, W, H, OUT>
{
}
// SAFETY: see above; `Copy + 'static` holds for every parameter.
unsafe impl<F: Pod, const IN: usize, const W: usize, const H: usize, const OUT: usize> Pod
    for MixtureModel<F, IN, W, H, OUT>
{
}

impl<F: MixtureFamily<OUT>, const IN: usize, const W: usize, const H: usize, const OUT: usize>
    MixtureModel<F, IN, W, H, OUT>
{
    /// Parameters of the MLP, `Mlp<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT`.
    pub const MLP_PARAMS: usize = Mlp::<IN, W, OUT, H>::PARAM_COUNT;

    /// Model with `grid` (moved to offset 0) followed by the MLP, for
    /// `target`, with the family's default setting. See
    /// [`Self::is_consistent`] for the required `IN`.
    #[must_use]
    pub const fn new(grid: GridConfig, target: Target) -> Self {
        let grid = grid.with_offset(0);
        Self {
            grid,
            mlp_offset: grid_param_count(&grid) as u32,
            target: target_code(target),
            family: F::DEFAULT,
        }
    }

    /// The same model with another family setting.
    #[must_use]
    pub const fn with_family(self, family: F) -> Self {
        Self {
            grid: self.grid,
            mlp_offset: self.mlp_offset,
            target: self.target,
            family,
        }
    }

    /// Whether `IN` equals [`input_dims`]`(grid, target)` and the MLP follows
    /// the grid.
    #[must_use]
    pub const fn is_consistent(&self) -> bool {
        IN == input_dims(&self.grid, target_from_code(self.target))
            && self.mlp_offset as usize == grid_param_count(&self.grid) + self.grid.offset as usize
    }

    /// The training target.
    #[inline]
    #[must_use]
    pub const fn target(&self) -> Target {
        target_from_code(self.target)
    }

    /// Whether `params` holds the whole model (the MLP is read unchecked).
    #[inline]
    pub(crate) fn fits(&self, params: &[f32]) -> bool {
        params.len() >= region_end(self.mlp_offset, Self::MLP_PARAMS)
    }

    /// Raw network outputs for `query`; when `params` is too short, those of
    /// a near-uniform mixture ([`MixtureFamily::uniform_raw`]).
    fn raw(&self, params: &[f32], query: &QueryPoint) -> [f32; OUT] {
        if !self.fits(params) {
            return F::uniform_raw();
        }
        let mut input = [0.0f32; IN];
        encode_inputs(params, &self.grid, self.target, query, &mut input);
        Mlp::<IN, W, OUT, H>::infer(params, self.mlp_offset as usize, &input)
    }

    /// The mixture at `query`, for renderers that keep the decoded
    /// distribution per path vertex (MIS, NEE, the cosine product) instead
    /// of calling the network again. A too short `params` gives a
    /// near-uniform mixture.
    #[must_use]
    pub fn decode(&self, params: &[f32], query: &QueryPoint) -> F::Decoded {
        F::decode(&self.raw(params, query))
    }
}

impl<F: MixtureFamily<OUT>, const IN: usize, const W: usize, const H: usize, const OUT: usize>
    GuidingModel for MixtureModel<F, IN, W, H, OUT>
{
    const FAMILY: Family = F::FAMILY;

    /// The batched kernels of [`super::batched`].
    #[cfg(feature = "std")]
    fn accumulate_gradient_batch(
        &self,
        params: &[f32],
        samples: &[TrainingSample],
        grad: &mut [f32],
    ) -> f64 {
        self.gradient_batch(params, samples, grad)
    }

    /// `mlp_offset + MLP_PARAMS`.
    fn param_count(&self) -> usize {
        region_end(self.mlp_offset, Self::MLP_PARAMS)
    }

    /// Grid: [`grid_init`] with `seed` (`U(−10⁻⁴, 10⁻⁴)`); MLP:
    /// [`Mlp::init`] with a seed derived from `seed` (the small output-layer
    /// scale starts every lobe broad). Parameters past `params.len()` are
    /// skipped.
    fn init(&self, params: &mut [f32], seed: u32) {
        grid_init(params, &self.grid, seed);
        mlp_init::<IN, W, OUT, H>(params, self.mlp_offset as usize, network_seed(seed, 1));
    }

    /// [`LobeMixture::sample`] of [`Self::decode`]: the pdf is the mixture
    /// density of the returned direction.
    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample {
        self.decode(params, query).sample(u)
    }

    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32 {
        self.decode(params, query).pdf(direction)
    }

    fn constant_selection_probability(&self) -> Option<f32> {
        self.family.constant_selection_probability()
    }

    /// The setting's constant, or the learned value at `query`.
    fn selection_probability(&self, params: &[f32], query: &QueryPoint) -> f32 {
        match self.family.constant_selection_probability() {
            Some(c) => c,
            None if !self.fits(params) => F::UNFIT_SELECTION_PROBABILITY,
            None => F::learned_selection_probability(&self.raw(params, query)),
        }
    }

    /// The family's loss ([`MixtureFamily::output_gradient`]) with `w` =
    /// [`kl_weight`], its output gradient pushed through the MLP and into the
    /// 8 corners of each grid level. Adds nothing and returns 0 for an
    /// invalid sample, a zero weight, a too short `params`/`grad`, or a
    /// non-finite loss, network output or output gradient (a finite output
    /// implies finite hidden activations, so the backward pass sees no NaN).
    fn accumulate_gradient<G: GradientSink + ?Sized>(
        &self,
        params: &[f32],
        sample: &TrainingSample,
        grad: &mut G,
    ) -> f32 {
        let count = self.param_count();
        if sample.validate().is_err() || params.len() < count || grad.len() < count {
            return 0.0;
        }
        let w = kl_weight(sample, self.target());
        if w == 0.0 {
            return 0.0;
        }
        let query = QueryPoint::of_sample(sample);
        let mut input = [0.0f32; IN];
        encode_inputs(params, &self.grid, self.target, &query, &mut input);
        let offset = self.mlp_offset as usize;
        let mut ctx = MlpContext::<W, H>::ZERO;
        let y = Mlp::<IN, W, OUT, H>::forward(params, offset, &input, &mut ctx);
        let mut d_y = [0.0f32; OUT];
        let loss = self.family.output_gradient(&y, sample, w, &mut d_y);
        if !(loss.is_finite() && all_finite(&y) && all_finite(&d_y)) {
            return 0.0;
        }
        let mut d_input = [0.0f32; IN];
        Mlp::<IN, W, OUT, H>::backward(params, offset, &input, &ctx, &d_y, grad, &mut d_input);
        grid_backward(&self.grid, sample.position(), &d_input, 0, grad);
        loss
    }
}

impl<F: MixtureFamily<OUT>, const IN: usize, const W: usize, const H: usize, const OUT: usize>
    RawOutputs for MixtureModel<F, IN, W, H, OUT>
{
    const RAW_OUTPUTS: usize = OUT;

    /// The network outputs [`Self::decode`] reads, in order.
    fn write_raw(&self, params: &[f32], query: &QueryPoint, out: &mut [f32], base: usize) {
        let y = self.raw(params, query);
        let mut k = 0;
        while k < OUT {
            let i = crate::math::add_saturating(base, k);
            if i < out.len() {
                out[i] = y[k];
            }
            k += 1;
        }
    }
}
