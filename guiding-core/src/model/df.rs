//! Neural path guiding with distribution factorisation (Figueiredo et al.
//! 2025, "Neural Path Guiding with Distribution Factorization", EGSR 2025):
//! a shared grid feeds a marginal network (the density of `ε₁`, i.e. the
//! azimuth), a conditional network (the density of `ε₂` given `ε₁`, i.e. the
//! polar angle) and a neural radiance cache (Müller et al. 2021, "Real-time
//! Neural Radiance Caching for Path Tracing") whose prediction replaces the
//! noisy radiance in the training weight (DF §4, eq. 14).
//!
//! ## Formula
//!
//! ```text
//! b      = [ grid(p) | product inputs ]                    (as NPM, super::npm::encode_inputs)
//! p(ε₁)  = Pdf1d<32>( MLP_m(b) ),                  Wrap    (φ = 2π ε₁)
//! p(ε₂|ε₁) = Pdf1d<16>( MLP_c([ b | TW₁₂(ε₁) ]) ), Clamp   (cos θ = 1 − 2 ε₂)
//! q(ω)   = p(ε₁) p(ε₂|ε₁) / (4π),  ε = square_from_direction(ω)    (DF eq. 3)
//! L̂(x, ω) = softplus( MLP_r([ grid(p) | SH₄(ω) ]) ) ∈ ℝ³₊           (radiance cache)
//! ```
//!
//! `Pdf1d<N>(l)` is the `N · softmax(l)` activation with
//! [`Interpolation::Nearest`] (DF-N) or [`Interpolation::Linear`] (DF-L)
//! reconstruction, `TW₁₂` tiny-cuda-nn's triangle wave with 12 frequencies
//! (DF §5). Training, per sample (one `accumulate_gradient`, one optimiser):
//!
//! ```text
//! w  = scalar(L ⊙ f|cos|) / p_s            (Target::Product)
//! w  = scalar(L) · |n·ωᵢ| / p_s            (Target::Radiance; |n·ωᵢ| = 1 for n = 0)
//!      with L = sg(L̂(x, ωᵢ)) (DF eq. 14) or the sample's noisy radiance (ablation)
//! ℓ  = −w ln q(ωᵢ)  +  λ_c · relL2(L̂(x, ωᵢ), L_sample)     (DF eq. 12; NRC §5)
//! ```
//!
//! `∂ℓ/∂logits` of both densities come from [`factorised::grad_log_pdf`] (the
//! conditional evaluated at the sample's own `ε₁`); the cache's from
//! [`relative_l2`] through the softplus; the three networks' input
//! gradients are summed on the shared grid features and scattered into the
//! grid.
//!
//! ## Parameter layout
//!
//! ```text
//! [0, marginal_offset)                        grid (offset 0)
//! [marginal_offset, conditional_offset)       Mlp<IN_M, WIDTH, 32, HIDDEN>
//! [conditional_offset, cache_offset)          Mlp<IN_C, WIDTH, 16, HIDDEN>
//! [cache_offset, cache_offset + cache params) Mlp<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>
//! ```
//!
//! with `IN_M = input_dims(grid, target)`, `IN_C = IN_M + 12`,
//! `IN_R = grid.output_dims() + 16`. [`DfRadiance::paper`]: grid 4 134 012 +
//! marginal 12 512 + conditional 12 240 + cache 11 651 = 4 170 415;
//! [`DfProduct::paper`]: grid + 14 560 + 14 288 + 11 651 = 4 174 511.
//!
//! ## Deviations
//!
//! - Eq. 14 also divides each point's weight by `L̂_r(x)`, the cache's
//!   estimate of the reflected radiance (a per-point normalisation). We drop
//!   it: it only reweights points against each other — like NPM's
//!   unnormalised target — and would need an extra `∫` estimate per sample.
//! - The radiance target learns the cosine-weighted incident radiance
//!   `L |n·ω|` (eq. 14 with `f = 1`), not NPM's bare `L`.
//! - Network sizes (3 × 64 for both densities, 3 × 64 for the cache) are our
//!   choice; the conditional's input is `[b | TW(ε₁)]` (grid, product
//!   inputs, then ε₁). The cache has its own MLP on the shared grid (NRC
//!   uses its own encoding) and a softplus output (smooth, non-negative,
//!   never a dead unit; raw outputs clamped to ±10¹⁵ so `L̂²` stays finite).
//!   The cache term is weighted by `λ_c` = `cache_loss_weight` (default 1).
//! - [`GuidingModel::sample`] returns the density of the returned direction
//!   as [`GuidingModel::pdf`] evaluates it (the conditional network is run
//!   again at the direction's own `ε₁` unless it equals the sampled one
//!   bit for bit), so the two agree exactly for MIS, as in
//!   [`FactorisedTable::sample`](crate::factorised::FactorisedTable::sample).
//! - The selection probability is a constant of the configuration.

use crate::encoding::triangle_wave::TRIANGLE_WAVE_DF_FREQUENCIES;
use crate::encoding::GridConfig;
use crate::encoding::{grid_backward, grid_forward, grid_init, sh_encode, triangle_wave_encode};
use crate::factorised::{self, direction_from_square, square_from_direction};
use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::loss::{relative_l2, scalar, Target};
use crate::math::{exp, ln_1p, sanitize, sigmoid, INV_FOUR_PI};
use crate::mlp::{Mlp, MlpContext};
use crate::model::npm::{
    all_finite, clean_probability, encode_inputs, grid_param_count, input_dims, mlp_init,
    network_seed, region_end, target_code, target_from_code, NPM_DEFAULT_SELECTION_PROBABILITY,
};
use crate::model::{GuidingModel, QueryPoint};
use crate::pdf1d::{Boundary, Interpolation, Pdf1d};
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Bins of the marginal density of `ε₁` (azimuth).
pub const DF_MARGINAL_BINS: usize = 32;
/// Bins of the conditional density of `ε₂` (polar angle).
pub const DF_CONDITIONAL_BINS: usize = 16;
/// Triangle-wave frequencies of `ε₁` in the conditional's input (DF: 12).
pub const DF_EPS1_FREQUENCIES: u32 = TRIANGLE_WAVE_DF_FREQUENCIES;
/// Spherical-harmonics degree of the cache's direction input (16 values).
pub const DF_CACHE_SH_DEGREE: u32 = 4;
/// Width of the cache's direction input.
pub const DF_CACHE_SH_DIMS: usize = 16;
/// Raw cache outputs are clamped to `±DF_CACHE_RAW_LIMIT` (NaN → 0) before
/// the softplus, so `L̂² ≤ 10³⁰` stays finite in the relative L2.
pub const DF_CACHE_RAW_LIMIT: f32 = 1e15;
/// Weight of the cache's relative L2 in the presets.
pub const DF_CACHE_LOSS_WEIGHT: f32 = 1.0;

/// Largest DF base input (`[grid | product inputs]`) a [`DfVertex`] holds:
/// 64, the paper product model's `IN_M`.
pub const DF_MAX_BASE: usize = 64;

/// What a DF model keeps of one shading point after the batched decode: the
/// network input `b = [grid | product inputs]` (the conditional network's
/// input starts with it) and the marginal density of `ε₁`. Sampling and pdfs
/// then run only the conditional network, once per direction.
///
/// `repr(C)`, [`Pod`], `4 · (64 + 32 + 2)` = 392 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DfVertex {
    /// `b`, zero past the model's `IN_M`.
    pub base: [f32; DF_MAX_BASE],
    /// `p(ε₁)` at this point.
    pub marginal: Pdf1d<DF_MARGINAL_BINS>,
}

// SAFETY: `repr(C)` struct of an `[f32; 64]` and a `Pod` `Pdf1d` (f32 values
// and two u32 codes, align 4): no padding, every bit pattern valid.
unsafe impl Zeroable for DfVertex {}
// SAFETY: see above.
unsafe impl Pod for DfVertex {}

impl DfVertex {
    /// All zeros (an invalid marginal; only a placeholder to overwrite).
    pub const ZERO: Self = Self {
        base: [0.0; DF_MAX_BASE],
        marginal: Pdf1d::ZERO,
    };
}

impl Default for DfVertex {
    fn default() -> Self {
        Self::ZERO
    }
}

/// Where the radiance in the guide's training weight comes from.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DfWeightSource {
    /// The radiance cache's prediction `L̂(x, ωᵢ)`, stop-gradient (DF eq. 14).
    Cache = 0,
    /// The sample's noisy radiance estimate (ablation, tests).
    Sample = 1,
}

impl DfWeightSource {
    /// The `u32` code stored in the configuration.
    #[inline]
    #[must_use]
    pub const fn code(self) -> u32 {
        self as u32
    }

    /// Reads a code: `0` is [`DfWeightSource::Cache`], every other value
    /// [`DfWeightSource::Sample`].
    #[inline]
    #[must_use]
    pub const fn from_code(code: u32) -> Self {
        if code == 0 {
            Self::Cache
        } else {
            Self::Sample
        }
    }
}

/// Softplus `ln(1 + eʳ)` of the clamped raw output, and its derivative
/// `sigmoid(r)` (0 where clamped).
#[inline]
pub(crate) fn softplus(raw: f32) -> (f32, f32) {
    let r = sanitize(raw, DF_CACHE_RAW_LIMIT);
    let v = r.max(0.0) + ln_1p(exp(-r.abs()));
    let inside = raw > -DF_CACHE_RAW_LIMIT && raw < DF_CACHE_RAW_LIMIT;
    (v, if inside { sigmoid(r) } else { 0.0 })
}

/// The guide's training weight `w` of the [module docs](self) for the
/// radiance `l` (the cache's or the sample's); 0 if not finite.
#[inline]
#[must_use]
pub fn guide_weight(l: [f32; 3], sample: &TrainingSample, target: Target) -> f32 {
    let v = match target {
        Target::Product => {
            let f = sample.bsdf_cos;
            scalar([l[0] * f[0], l[1] * f[1], l[2] * f[2]])
        }
        Target::Radiance => {
            let n = Vec3::from_array(sample.normal);
            let cos = if n == Vec3::ZERO {
                1.0
            } else {
                n.dot(sample.wi()).abs()
            };
            scalar(l) * cos
        }
    };
    let w = v / sample.sample_pdf;
    if w.is_finite() {
        w
    } else {
        0.0
    }
}

/// A distribution-factorisation guiding model with a radiance cache
/// (formula, layout and deviations in the [module docs](self)).
///
/// Const parameters: the input widths of the marginal (`IN_M`), conditional
/// (`IN_C = IN_M + 12`) and cache (`IN_R = L·F + 16`) networks, the width and
/// depth of the two density networks, and of the cache network.
/// [`Self::is_consistent`] checks the widths and offsets (at compile time
/// for the presets).
///
/// `repr(C)`, [`Pod`], 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Df<
    const IN_M: usize,
    const IN_C: usize,
    const IN_R: usize,
    const WIDTH: usize,
    const HIDDEN: usize,
    const CACHE_WIDTH: usize,
    const CACHE_HIDDEN: usize,
> {
    /// The shared grid; its `offset` is 0.
    pub grid: GridConfig,
    /// Offset of the marginal MLP: `grid_param_count(grid)`.
    pub marginal_offset: u32,
    /// Offset of the conditional MLP.
    pub conditional_offset: u32,
    /// Offset of the radiance-cache MLP.
    pub cache_offset: u32,
    /// [`Target`] code (see [`target_code`]).
    pub target: u32,
    /// [`Interpolation`] code of both densities (0: DF-N, 1: DF-L).
    pub interpolation: u32,
    /// [`DfWeightSource`] code.
    pub weight_source: u32,
    /// Constant probability of sampling the guide rather than the BSDF.
    pub selection_probability: f32,
    /// Weight `λ_c` of the cache's relative L2 in the loss (non-finite or
    /// negative values read as 1).
    pub cache_loss_weight: f32,
}

// SAFETY: `repr(C)` struct of a `Pod` `GridConfig` (48 bytes, align 4) and
// eight 4-byte scalars: no padding, every bit pattern valid, zero valid.
unsafe impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > Zeroable for Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
}
// SAFETY: see above.
unsafe impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > Pod for Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
}

pub use super::sizes::df::*;

/// DF for radiance guiding on NPM's grid: density networks 3 × 64, cache
/// 3 × 64.
pub type DfRadiance = DfPaperRadiance;
/// DF for product guiding on NPM's grid + product inputs.
pub type DfProduct = DfPaperProduct;

const _: () = assert!(core::mem::size_of::<DfProduct>() == 80);

impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
    /// Parameters of the marginal MLP.
    pub const MARGINAL_PARAMS: usize = Mlp::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>::PARAM_COUNT;
    /// Parameters of the conditional MLP.
    pub const CONDITIONAL_PARAMS: usize =
        Mlp::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::PARAM_COUNT;
    /// Parameters of the radiance-cache MLP.
    pub const CACHE_PARAMS: usize = Mlp::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>::PARAM_COUNT;

    /// Model with `grid` (moved to offset 0), then the marginal, conditional
    /// and cache MLPs; weight source [`DfWeightSource::Cache`], selection
    /// probability 0.5, `λ_c = 1`.
    #[must_use]
    pub const fn new(grid: GridConfig, target: Target, interpolation: Interpolation) -> Self {
        let grid = grid.with_offset(0);
        let marginal = grid_param_count(&grid);
        let conditional = marginal + Self::MARGINAL_PARAMS;
        let cache = conditional + Self::CONDITIONAL_PARAMS;
        Self {
            grid,
            marginal_offset: marginal as u32,
            conditional_offset: conditional as u32,
            cache_offset: cache as u32,
            target: target_code(target),
            interpolation: interpolation as u32,
            weight_source: DfWeightSource::Cache.code(),
            selection_probability: NPM_DEFAULT_SELECTION_PROBABILITY,
            cache_loss_weight: DF_CACHE_LOSS_WEIGHT,
        }
    }

    /// The same model with another source of the training weight's radiance.
    #[must_use]
    pub const fn with_weight_source(mut self, source: DfWeightSource) -> Self {
        self.weight_source = source.code();
        self
    }

    with_fields! {
        /// The same model with another constant selection probability.
        with_selection_probability(selection_probability: f32);
        /// The same model with another weight `λ_c` of the cache loss.
        with_cache_loss_weight(cache_loss_weight: f32);
    }

    /// Whether the const widths match the grid and target
    /// (`IN_M = input_dims`, `IN_C = IN_M + 12`, `IN_R = L·F + 16`) and the
    /// networks follow each other after the grid.
    #[must_use]
    pub const fn is_consistent(&self) -> bool {
        let m = grid_param_count(&self.grid) + self.grid.offset as usize;
        IN_M == input_dims(&self.grid, target_from_code(self.target))
            && IN_C == IN_M + DF_EPS1_FREQUENCIES as usize
            && IN_R == self.grid.output_dims() + DF_CACHE_SH_DIMS
            && self.marginal_offset as usize == m
            && self.conditional_offset as usize == m + Self::MARGINAL_PARAMS
            && self.cache_offset as usize == m + Self::MARGINAL_PARAMS + Self::CONDITIONAL_PARAMS
    }

    /// The training target.
    #[inline]
    #[must_use]
    pub const fn target(&self) -> Target {
        target_from_code(self.target)
    }

    /// The interpolation of both densities.
    #[inline]
    #[must_use]
    pub const fn interpolation(&self) -> Interpolation {
        if self.interpolation == 0 {
            Interpolation::Nearest
        } else {
            Interpolation::Linear
        }
    }

    /// The source of the training weight's radiance.
    #[inline]
    #[must_use]
    pub const fn weight_source(&self) -> DfWeightSource {
        DfWeightSource::from_code(self.weight_source)
    }

    /// `λ_c` as used.
    #[inline]
    pub(crate) fn cache_weight(&self) -> f32 {
        let c = self.cache_loss_weight;
        if c.is_finite() && c >= 0.0 {
            c
        } else {
            DF_CACHE_LOSS_WEIGHT
        }
    }

    /// End of each network's region; the model needs the largest.
    #[inline]
    fn ends(&self) -> (usize, usize, usize) {
        (
            region_end(self.marginal_offset, Self::MARGINAL_PARAMS),
            region_end(self.conditional_offset, Self::CONDITIONAL_PARAMS),
            region_end(self.cache_offset, Self::CACHE_PARAMS),
        )
    }

    #[inline]
    pub(crate) fn fits(&self, params: &[f32]) -> bool {
        params.len() >= self.param_count()
    }

    /// `b = [grid | product inputs]` of `query`.
    #[inline]
    pub(crate) fn base_input(&self, params: &[f32], query: &QueryPoint) -> [f32; IN_M] {
        let mut b = [0.0f32; IN_M];
        encode_inputs(params, &self.grid, self.target, query, &mut b);
        b
    }

    /// `[b | TW₁₂(ε₁)]`.
    #[inline]
    pub(crate) fn conditional_input(base: &[f32; IN_M], eps1: f32) -> [f32; IN_C] {
        let mut x = [0.0f32; IN_C];
        let mut i = 0;
        while i < IN_M && i < IN_C {
            x[i] = base[i];
            i += 1;
        }
        triangle_wave_encode(eps1, DF_EPS1_FREQUENCIES, &mut x, IN_M);
        x
    }

    /// `[grid features of b | SH₄(ω)]`.
    #[inline]
    pub(crate) fn cache_input(&self, base: &[f32; IN_M], direction: Vec3) -> [f32; IN_R] {
        let g = self.grid.output_dims();
        let mut x = [0.0f32; IN_R];
        let mut i = 0;
        while i < g && i < IN_M && i < IN_R {
            x[i] = base[i];
            i += 1;
        }
        sh_encode(direction, DF_CACHE_SH_DEGREE, &mut x, g);
        x
    }

    pub(crate) fn marginal_from(
        &self,
        params: &[f32],
        base: &[f32; IN_M],
    ) -> Pdf1d<DF_MARGINAL_BINS> {
        let logits = Mlp::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>::infer(
            params,
            self.marginal_offset as usize,
            base,
        );
        Pdf1d::from_logits(&logits, self.interpolation(), Boundary::Wrap)
    }

    pub(crate) fn conditional_from(
        &self,
        params: &[f32],
        base: &[f32; IN_M],
        eps1: f32,
    ) -> Pdf1d<DF_CONDITIONAL_BINS> {
        let x = Self::conditional_input(base, eps1);
        let logits = Mlp::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::infer(
            params,
            self.conditional_offset as usize,
            &x,
        );
        Pdf1d::from_logits(&logits, self.interpolation(), Boundary::Clamp)
    }

    /// The base input held by `v` (its first `IN_M` values).
    #[inline]
    pub(crate) fn base_of(v: &DfVertex) -> [f32; IN_M] {
        let mut b = [0.0f32; IN_M];
        let mut i = 0;
        while i < IN_M && i < DF_MAX_BASE {
            b[i] = v.base[i];
            i += 1;
        }
        b
    }

    /// The uniform marginal of a too short `params` (as [`Self::marginal`]).
    pub(crate) fn uniform_marginal(&self) -> Pdf1d<DF_MARGINAL_BINS> {
        Pdf1d::from_logits(
            &[0.0; DF_MARGINAL_BINS],
            self.interpolation(),
            Boundary::Wrap,
        )
    }

    /// The conditional density `p(ε₂ | ε₁)` at the vertex `v` (one
    /// per-query conditional pass).
    pub(crate) fn conditional_at(
        &self,
        params: &[f32],
        v: &DfVertex,
        eps1: f32,
    ) -> Pdf1d<DF_CONDITIONAL_BINS> {
        self.conditional_from(params, &Self::base_of(v), eps1)
    }

    /// The second half of a sample: `ε₂`, the direction, and its density as
    /// [`VertexModel::pdf_vertex`] evaluates it.
    pub(crate) fn finish_sample(
        &self,
        params: &[f32],
        v: &DfVertex,
        e1: f32,
        p1: f32,
        conditional: &Pdf1d<DF_CONDITIONAL_BINS>,
        uy: f32,
    ) -> DirectionSample {
        let (e2, p2) = factorised::sample_conditional(conditional, uy);
        let direction = direction_from_square(Vec2::new(e1, e2));
        let eps = square_from_direction(direction);
        let p_cond = if eps.x == e1 {
            conditional.pdf(eps.y)
        } else {
            self.conditional_at(params, v, eps.x).pdf(eps.y)
        };
        let mut pdf = v.marginal.pdf(eps.x) * p_cond * INV_FOUR_PI;
        if pdf <= 0.0 || pdf.is_nan() {
            pdf = p1 * p2 * INV_FOUR_PI;
        }
        DirectionSample { direction, pdf }
    }

    /// The marginal density of `ε₁` at `query` (uniform for a too short
    /// `params`).
    #[must_use]
    pub fn marginal(&self, params: &[f32], query: &QueryPoint) -> Pdf1d<DF_MARGINAL_BINS> {
        if !self.fits(params) {
            return Pdf1d::from_logits(
                &[0.0; DF_MARGINAL_BINS],
                self.interpolation(),
                Boundary::Wrap,
            );
        }
        self.marginal_from(params, &self.base_input(params, query))
    }

    /// The conditional density of `ε₂` given `ε₁` at `query` (uniform for a
    /// too short `params`).
    #[must_use]
    pub fn conditional(
        &self,
        params: &[f32],
        query: &QueryPoint,
        eps1: f32,
    ) -> Pdf1d<DF_CONDITIONAL_BINS> {
        if !self.fits(params) {
            return Pdf1d::from_logits(
                &[0.0; DF_CONDITIONAL_BINS],
                self.interpolation(),
                Boundary::Clamp,
            );
        }
        self.conditional_from(params, &self.base_input(params, query), eps1)
    }

    /// The radiance cache's prediction `L̂(x, ω)` (RGB, `≥ 0`, finite); zero
    /// for a too short `params`.
    #[must_use]
    pub fn radiance(&self, params: &[f32], position: Vec3, direction: Vec3) -> [f32; 3] {
        if !self.fits(params) {
            return [0.0; 3];
        }
        let mut base = [0.0f32; IN_M];
        grid_forward(params, &self.grid, position, &mut base, 0);
        let x = self.cache_input(&base, direction);
        let raw = Mlp::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>::infer(
            params,
            self.cache_offset as usize,
            &x,
        );
        [softplus(raw[0]).0, softplus(raw[1]).0, softplus(raw[2]).0]
    }
}

impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > GuidingModel for Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
    const FAMILY: super::Family = super::Family::Df;

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

    /// The end of the last network (the cache, for the presets).
    fn param_count(&self) -> usize {
        let (m, c, r) = self.ends();
        m.max(c).max(r)
    }

    /// Grid: [`grid_init`] with `seed`; the three MLPs: [`Mlp::init`] with
    /// distinct seeds derived from `seed`. Parameters past `params.len()` are
    /// skipped.
    fn init(&self, params: &mut [f32], seed: u32) {
        grid_init(params, &self.grid, seed);
        mlp_init::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>(
            params,
            self.marginal_offset as usize,
            network_seed(seed, 1),
        );
        mlp_init::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>(
            params,
            self.conditional_offset as usize,
            network_seed(seed, 2),
        );
        mlp_init::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>(
            params,
            self.cache_offset as usize,
            network_seed(seed, 3),
        );
    }

    /// `u.x → ε₁` through the marginal, the conditional network at `ε₁`,
    /// `u.y → ε₂` (each kept [`factorised::SAMPLE_MARGIN`] inside its piece,
    /// so the warp's rounding cannot carry `ω` into a neighbouring bin of zero
    /// density), `ω = direction_from_square(ε)`. The pdf is that of
    /// [`Self::pdf`] at `ω` (see the module docs); should it be zero or NaN
    /// where the sampled `ε` has positive density, `p(ε₁) p(ε₂|ε₁) / 4π` of
    /// the sampled `ε` is returned.
    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample {
        if !self.fits(params) {
            return DirectionSample {
                direction: direction_from_square(u),
                pdf: INV_FOUR_PI,
            };
        }
        let base = self.base_input(params, query);
        let marginal = self.marginal_from(params, &base);
        let (e1, p1) = factorised::sample_marginal(&marginal, u.x);
        let conditional = self.conditional_from(params, &base, e1);
        let (e2, p2) = factorised::sample_conditional(&conditional, u.y);
        let direction = direction_from_square(Vec2::new(e1, e2));
        let eps = square_from_direction(direction);
        let p_cond = if eps.x == e1 {
            conditional.pdf(eps.y)
        } else {
            self.conditional_from(params, &base, eps.x).pdf(eps.y)
        };
        let mut pdf = marginal.pdf(eps.x) * p_cond * INV_FOUR_PI;
        if pdf <= 0.0 || pdf.is_nan() {
            pdf = p1 * p2 * INV_FOUR_PI;
        }
        DirectionSample { direction, pdf }
    }

    /// `p(ε₁) p(ε₂|ε₁) / (4π)` at `ε = square_from_direction(direction)`, the
    /// conditional network evaluated at this `ε₁` ([`factorised::pdf`]).
    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32 {
        if !self.fits(params) {
            return INV_FOUR_PI;
        }
        let base = self.base_input(params, query);
        let marginal = self.marginal_from(params, &base);
        let eps = square_from_direction(direction);
        let conditional = self.conditional_from(params, &base, eps.x);
        factorised::pdf(&marginal, &conditional, direction)
    }

    fn constant_selection_probability(&self) -> Option<f32> {
        Some(clean_probability(self.selection_probability))
    }

    /// The configuration's constant.
    fn selection_probability(&self, _params: &[f32], _query: &QueryPoint) -> f32 {
        clean_probability(self.selection_probability)
    }

    /// The loss of the [module docs](self): `−w ln q(ωᵢ)` (skipped when
    /// `w = 0`) plus `λ_c` times the cache's relative L2 against the
    /// sample's radiance; gradients of all three networks and the shared
    /// grid. Adds nothing and returns 0 for an invalid sample, a too short
    /// `params`/`grad`, or a non-finite loss, network output or output
    /// gradient.
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
        let query = QueryPoint::of_sample(sample);
        let wi = sample.wi();
        let base = self.base_input(params, &query);

        // Radiance cache: forward, relative L2, output gradient.
        let x_r = self.cache_input(&base, wi);
        let off_r = self.cache_offset as usize;
        let mut ctx_r = MlpContext::<CACHE_WIDTH, CACHE_HIDDEN>::ZERO;
        let raw_r =
            Mlp::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>::forward(params, off_r, &x_r, &mut ctx_r);
        let mut pred = [0.0f32; 3];
        let mut dpred = [0.0f32; 3];
        let mut c = 0;
        while c < 3 {
            let (v, d) = softplus(raw_r[c]);
            pred[c] = v;
            dpred[c] = d;
            c += 1;
        }
        let lambda_c = self.cache_weight();
        let (loss_r, dl_dpred) = relative_l2(pred, sample.radiance);
        let mut d_r = [0.0f32; 3];
        c = 0;
        while c < 3 {
            d_r[c] = lambda_c * dl_dpred[c] * dpred[c];
            c += 1;
        }
        let mut loss = lambda_c * loss_r;
        let mut outputs_finite = all_finite(&raw_r);

        // Guide: weight from the cache (stop-gradient) or the sample.
        let l = match self.weight_source() {
            DfWeightSource::Cache => pred,
            DfWeightSource::Sample => sample.radiance,
        };
        let w = guide_weight(l, sample, self.target());
        let off_m = self.marginal_offset as usize;
        let off_c = self.conditional_offset as usize;
        let mut ctx_m = MlpContext::<WIDTH, HIDDEN>::ZERO;
        let mut ctx_c = MlpContext::<WIDTH, HIDDEN>::ZERO;
        let mut d_m = [0.0f32; DF_MARGINAL_BINS];
        let mut d_c = [0.0f32; DF_CONDITIONAL_BINS];
        let eps1 = square_from_direction(wi).x;
        let x_c = Self::conditional_input(&base, eps1);
        if w != 0.0 {
            let logits_m = Mlp::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>::forward(
                params, off_m, &base, &mut ctx_m,
            );
            let logits_c = Mlp::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::forward(
                params, off_c, &x_c, &mut ctx_c,
            );
            outputs_finite = outputs_finite && all_finite(&logits_m) && all_finite(&logits_c);
            let log_q = factorised::grad_log_pdf(
                &logits_m,
                &logits_c,
                self.interpolation(),
                wi,
                &mut d_m,
                &mut d_c,
            );
            loss += -w * log_q;
            let mut i = 0;
            while i < DF_MARGINAL_BINS {
                d_m[i] *= -w;
                i += 1;
            }
            i = 0;
            while i < DF_CONDITIONAL_BINS {
                d_c[i] *= -w;
                i += 1;
            }
        }
        if !(outputs_finite
            && loss.is_finite()
            && all_finite(&d_r)
            && all_finite(&d_m)
            && all_finite(&d_c))
        {
            return 0.0;
        }

        // Backward: the three networks, then the grid with the summed
        // gradients of the shared grid features.
        let mut d_base = [0.0f32; IN_M];
        if w != 0.0 {
            Mlp::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>::backward(
                params,
                off_m,
                &base,
                &ctx_m,
                &d_m,
                grad,
                &mut d_base,
            );
            let mut d_x_c = [0.0f32; IN_C];
            Mlp::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::backward(
                params, off_c, &x_c, &ctx_c, &d_c, grad, &mut d_x_c,
            );
            let mut i = 0;
            while i < IN_M && i < IN_C {
                d_base[i] += d_x_c[i];
                i += 1;
            }
        }
        let mut d_x_r = [0.0f32; IN_R];
        Mlp::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>::backward(
            params, off_r, &x_r, &ctx_r, &d_r, grad, &mut d_x_r,
        );
        let g = self.grid.output_dims();
        let mut i = 0;
        while i < g && i < IN_M && i < IN_R {
            d_base[i] += d_x_r[i];
            i += 1;
        }
        grid_backward(&self.grid, sample.position(), &d_base, 0, grad);
        loss
    }
}

/// The per-vertex split of a DF model (the CPU's batched decode and the
/// device's kernels): [`DfVertex`] once per shading point, then one
/// conditional pass per sampled or evaluated direction.
pub trait VertexModel: GuidingModel {
    /// What DF keeps of one shading point ([`DfVertex`]): the base input
    /// `b` (zero past `IN_M`; `IN_M ≤ DF_MAX_BASE` for every model type)
    /// and the marginal `p(ε₁)`; uniform for a too short `params`. The
    /// per-query form of the CPU's batched decode, and the device's
    /// per-vertex kernel.
    fn vertex(&self, params: &[f32], query: &QueryPoint) -> DfVertex;
    /// [`GuidingModel::sample`] from a decoded vertex: the same draw and
    /// pdf, without the grid and marginal passes.
    fn sample_vertex(&self, params: &[f32], v: &DfVertex, u: Vec2) -> DirectionSample;
    /// [`GuidingModel::pdf`] from a decoded vertex (one conditional pass).
    fn pdf_vertex(&self, params: &[f32], v: &DfVertex, direction: Vec3) -> f32;
}

impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > VertexModel for Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
    fn vertex(&self, params: &[f32], query: &QueryPoint) -> DfVertex {
        let mut v = DfVertex::ZERO;
        if !self.fits(params) {
            v.marginal = self.uniform_marginal();
            return v;
        }
        let b = self.base_input(params, query);
        let mut i = 0;
        while i < IN_M && i < DF_MAX_BASE {
            v.base[i] = b[i];
            i += 1;
        }
        v.marginal = self.marginal_from(params, &b);
        v
    }

    fn sample_vertex(&self, params: &[f32], v: &DfVertex, u: Vec2) -> DirectionSample {
        if !self.fits(params) {
            return DirectionSample {
                direction: direction_from_square(u),
                pdf: INV_FOUR_PI,
            };
        }
        let (e1, p1) = factorised::sample_marginal(&v.marginal, u.x);
        let conditional = self.conditional_at(params, v, e1);
        self.finish_sample(params, v, e1, p1, &conditional, u.y)
    }

    fn pdf_vertex(&self, params: &[f32], v: &DfVertex, direction: Vec3) -> f32 {
        if !self.fits(params) {
            return INV_FOUR_PI;
        }
        let eps = square_from_direction(direction);
        let conditional = self.conditional_at(params, v, eps.x);
        factorised::pdf(&v.marginal, &conditional, direction)
    }
}
