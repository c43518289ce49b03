//! Online neural path guiding with normalised anisotropic spherical
//! Gaussians (Huang et al. 2024, "Online Neural Path Guiding with Normalized
//! Anisotropic Spherical Gaussians", ACM TOG 43(3)): the NPM input encoding
//! and an MLP map a shading point to a mixture of [`NASG_LOBES`] = 8 NASG
//! lobes plus the learned probability `c` of sampling the guide rather than
//! the BSDF.
//!
//! ## Formula
//!
//! ```text
//! x = [ grid(p) | product inputs ]             (as NPM, see super::npm::encode_inputs)
//! y = MLP(x) ∈ ℝ⁴⁹,  (q, c) = NasgMixture::<8>::decode(y[0..48], y[48])   (NASG Table 2)
//! ℓ = −w [ (1 − e) ln(c q(ωᵢ) + (1 − c) p_bsdf(ωᵢ)) + e ln q(ωᵢ) ]      (NASG eq. 18)
//! ∂ℓ/∂y[0..48] = ∂ℓ/∂ln q · ∇ ln q,   ∂ℓ/∂y[48] = ∂ℓ/∂c · dc/dr
//! ```
//!
//! with `w` = [`kl_weight`] (NASG eq. 17), `e` = [`NASG_MIS_BLEND`] = 0.2,
//! `p_bsdf` = the sample's `bsdf_pdf` ([`nasg_mis_loss`] evaluates the blend
//! in log space), `∇ ln q` from [`NasgMixture::grad_log_pdf`] and `dc/dr`
//! from [`decode_selection`].
//!
//! ## Parameter layout
//!
//! ```text
//! [0, mlp_offset)                         grid (GridConfig layout, offset 0)
//! [mlp_offset, mlp_offset + MLP params)   Mlp<IN, WIDTH, 49, HIDDEN>
//! ```
//!
//! [`NasgProduct::paper`]: NPM's grid (4 134 012 parameters) + a 4 × 128 MLP
//! with IN = 64 (64 177 parameters); [`NasgRadiance::paper`] the same with
//! IN = 32 (60 081).
//!
//! ## Deviations
//!
//! - The encoding is NPM's dense grid (+ NPM's product inputs), not the
//!   paper's hash grid; the MLP has biases.
//! - NASG trains the full product; the radiance target is offered as well
//!   (its guide is then a radiance distribution, `c` still blends with the
//!   BSDF).
//! - `c` is clamped to `[0.01, 0.99]` by the decoder (see
//!   `mixture/nasg.rs`).
//! - A sample with `bsdf_pdf = 0` (unknown) makes `p_mis = c q`; its loss then
//!   pushes `c` up. Renderers should fill `bsdf_pdf`.

use crate::encoding::{grid_backward, grid_init, GridConfig};
use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::loss::{kl_weight, nasg_mis_loss, Target};
use crate::mixture::nasg::{
    decode_selection, NasgMixture, NASG_LN_A_MIN, NASG_LN_LAMBDA_MIN, NASG_RAW_PER_LOBE,
    NASG_SELECTION_DEFAULT,
};
use crate::mlp::{Mlp, MlpContext};
use crate::model::npm::{
    all_finite, encode_inputs, grid_param_count, input_dims, join_rows, mlp_init, network_seed,
    region_end, split_rows, target_code, target_from_code,
};
use crate::model::{GuidingModel, QueryPoint};
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Number of NASG lobes (the paper's K = 8).
pub const NASG_LOBES: usize = 8;
/// Raw network outputs: `8 × 6` lobe parameters, then the selection logit.
pub const NASG_OUTPUTS: usize = NASG_LOBES * NASG_RAW_PER_LOBE + 1;
/// Index of the selection logit in the raw outputs.
pub const NASG_SELECTION_OUTPUT: usize = NASG_LOBES * NASG_RAW_PER_LOBE;
/// The blend `e` of NASG eq. 18 (paper: 0.2).
pub const NASG_MIS_BLEND: f32 = 0.2;

/// A NASG guiding model: `[grid | product inputs]` →
/// `Mlp<IN, WIDTH, 49, HIDDEN>` → [`NasgMixture<8>`] with learned selection
/// probability (formula, layout and deviations in the [module docs](self)).
///
/// `IN` must equal [`input_dims`]`(grid, target)` (checked by
/// [`Self::is_consistent`], and at compile time for the presets).
///
/// `repr(C)`, [`Pod`], 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nasg<const IN: usize, const WIDTH: usize, const HIDDEN: usize> {
    /// The grid; its `offset` is 0.
    pub grid: GridConfig,
    /// Offset of the MLP in the flat buffer: `grid_param_count(grid)`.
    pub mlp_offset: u32,
    /// [`Target`] code (see [`target_code`]).
    pub target: u32,
    /// The blend `e` of NASG eq. 18 ([`NASG_MIS_BLEND`]).
    pub mis_blend: f32,
    /// Padding.
    pub pad: u32,
}

// SAFETY: `repr(C)` struct of a `Pod` `GridConfig` (48 bytes, align 4) and
// four 4-byte scalars: no padding, every bit pattern valid, zero valid.
unsafe impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Zeroable
    for Nasg<IN, WIDTH, HIDDEN>
{
}
// SAFETY: see above.
unsafe impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Pod
    for Nasg<IN, WIDTH, HIDDEN>
{
}

pub use super::sizes::nasg::*;

/// The paper's NASG model (product target): IN = 64, 4 hidden layers × 128.
pub type NasgProduct = NasgPaperProduct;
/// NASG with a radiance target: IN = 32, 4 hidden layers × 128.
pub type NasgRadiance = NasgPaperRadiance;

const _: () = assert!(core::mem::size_of::<NasgProduct>() == 64);

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Nasg<IN, WIDTH, HIDDEN> {
    /// Parameters of the MLP, `Mlp<IN, WIDTH, 49, HIDDEN>::PARAM_COUNT`.
    pub const MLP_PARAMS: usize = Mlp::<IN, WIDTH, NASG_OUTPUTS, HIDDEN>::PARAM_COUNT;

    /// Model with `grid` (moved to offset 0) followed by the MLP, for
    /// `target`, `e` = [`NASG_MIS_BLEND`].
    #[must_use]
    pub const fn new(grid: GridConfig, target: Target) -> Self {
        let grid = grid.with_offset(0);
        Self {
            grid,
            mlp_offset: grid_param_count(&grid) as u32,
            target: target_code(target),
            mis_blend: NASG_MIS_BLEND,
            pad: 0,
        }
    }

    /// The same model with another blend `e` of eq. 18 (clamped to `[0, 1]`
    /// when used; NaN reads as [`NASG_MIS_BLEND`]).
    #[must_use]
    pub const fn with_mis_blend(mut self, e: f32) -> Self {
        self.mis_blend = e;
        self
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

    #[inline]
    pub(crate) fn fits(&self, params: &[f32]) -> bool {
        params.len() >= region_end(self.mlp_offset, Self::MLP_PARAMS)
    }

    /// `e` as used: clamped to `[0, 1]`, NaN → [`NASG_MIS_BLEND`].
    #[inline]
    pub(crate) fn blend(&self) -> f32 {
        if self.mis_blend.is_nan() {
            NASG_MIS_BLEND
        } else {
            self.mis_blend.clamp(0.0, 1.0)
        }
    }

    /// Raw network outputs; for a too short `params`, those of a
    /// near-uniform mixture (λ and `a` at their lower clamps, `c = ½`).
    fn raw(&self, params: &[f32], query: &QueryPoint) -> [f32; NASG_OUTPUTS] {
        let mut y = [0.0f32; NASG_OUTPUTS];
        if !self.fits(params) {
            let mut k = 0;
            while k < NASG_LOBES {
                y[k * NASG_RAW_PER_LOBE + 1] = NASG_LN_LAMBDA_MIN;
                y[k * NASG_RAW_PER_LOBE + 2] = NASG_LN_A_MIN;
                k += 1;
            }
            return y;
        }
        let mut input = [0.0f32; IN];
        encode_inputs(params, &self.grid, self.target, query, &mut input);
        Mlp::<IN, WIDTH, NASG_OUTPUTS, HIDDEN>::infer(params, self.mlp_offset as usize, &input)
    }

    /// The NASG mixture at `query` with its learned selection probability
    /// (for renderers that keep the decoded distribution). A too short
    /// `params` gives a near-uniform mixture with `c = ½`.
    #[must_use]
    pub fn decode(&self, params: &[f32], query: &QueryPoint) -> NasgMixture<NASG_LOBES> {
        let y = self.raw(params, query);
        NasgMixture::decode(&split_rows(&y), y[NASG_SELECTION_OUTPUT])
    }
}

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> GuidingModel
    for Nasg<IN, WIDTH, HIDDEN>
{
    const FAMILY: super::Family = super::Family::Nasg;

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

    /// Grid: [`grid_init`] with `seed`; MLP: [`Mlp::init`] with a derived
    /// seed (the small output-layer scale starts every lobe broad and `c`
    /// near ½). Parameters past `params.len()` are skipped.
    fn init(&self, params: &mut [f32], seed: u32) {
        grid_init(params, &self.grid, seed);
        mlp_init::<IN, WIDTH, NASG_OUTPUTS, HIDDEN>(
            params,
            self.mlp_offset as usize,
            network_seed(seed, 1),
        );
    }

    /// [`NasgMixture::sample`] of [`Self::decode`].
    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample {
        self.decode(params, query).sample(u)
    }

    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32 {
        self.decode(params, query).pdf(direction)
    }

    /// Learned per query (the network's last output).
    fn constant_selection_probability(&self) -> Option<f32> {
        None
    }

    /// The learned `c` ([`decode_selection`] of the last output); ½ for a too
    /// short `params`.
    fn selection_probability(&self, params: &[f32], query: &QueryPoint) -> f32 {
        if !self.fits(params) {
            return NASG_SELECTION_DEFAULT;
        }
        decode_selection(self.raw(params, query)[NASG_SELECTION_OUTPUT]).0
    }

    /// NASG eq. 18 ([`nasg_mis_loss`]) with `w` = [`kl_weight`]; the lobe
    /// outputs get `∂ℓ/∂ln q · ∇ ln q` ([`NasgMixture::grad_log_pdf`]), the
    /// selection output `∂ℓ/∂c · dc/dr` ([`decode_selection`]); then MLP and
    /// grid backward. Adds nothing and returns 0 for an invalid sample, a
    /// zero weight, a too short `params`/`grad`, or a non-finite loss,
    /// network output or output gradient.
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
        let mut ctx = MlpContext::<WIDTH, HIDDEN>::ZERO;
        let y = Mlp::<IN, WIDTH, NASG_OUTPUTS, HIDDEN>::forward(params, offset, &input, &mut ctx);
        let raw: [[f32; NASG_RAW_PER_LOBE]; NASG_LOBES] = split_rows(&y);
        let mut g = [[0.0f32; NASG_RAW_PER_LOBE]; NASG_LOBES];
        let log_q = NasgMixture::grad_log_pdf(&raw, sample.wi(), &mut g);
        let (c, dc_dr) = decode_selection(y[NASG_SELECTION_OUTPUT]);
        let terms = nasg_mis_loss(w, log_q, c, sample.bsdf_pdf, self.blend());
        let mut d_y = [0.0f32; NASG_OUTPUTS];
        join_rows(&g, &mut d_y);
        let mut i = 0;
        while i < NASG_SELECTION_OUTPUT {
            d_y[i] *= terms.dloss_dlog_guide;
            i += 1;
        }
        d_y[NASG_SELECTION_OUTPUT] = terms.dloss_dselection * dc_dr;
        if !(terms.loss.is_finite() && all_finite(&y) && all_finite(&d_y)) {
            return 0.0;
        }
        let mut d_input = [0.0f32; IN];
        Mlp::<IN, WIDTH, NASG_OUTPUTS, HIDDEN>::backward(
            params,
            offset,
            &input,
            &ctx,
            &d_y,
            grad,
            &mut d_input,
        );
        grid_backward(&self.grid, sample.position(), &d_input, 0, grad);
        terms.loss
    }
}

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> super::RawOutputs
    for Nasg<IN, WIDTH, HIDDEN>
{
    const RAW_OUTPUTS: usize = NASG_OUTPUTS;

    /// The network outputs of [`Self::decode`]: 8 rows of 6 lobe values,
    /// then the selection logit.
    fn write_raw(&self, params: &[f32], query: &QueryPoint, out: &mut [f32], base: usize) {
        let y = self.raw(params, query);
        let mut k = 0;
        while k < NASG_OUTPUTS {
            let i = crate::math::add_saturating(base, k);
            if i < out.len() {
                out[i] = y[k];
            }
            k += 1;
        }
    }
}
