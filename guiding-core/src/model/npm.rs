//! Neural Parametric Mixtures (Dong et al. 2023, "Neural Parametric Mixtures
//! for Path Guiding", SIGGRAPH 2023): a dense multi-resolution grid and a
//! small MLP map a shading point to the parameters of a mixture of
//! [`NPM_LOBES`] = 8 von Mises–Fisher lobes.
//!
//! This module also holds the pieces the three models share (the input
//! encoding, the flat-layout helpers, the seeds): [`encode_inputs`],
//! [`input_dims`], [`grid_param_count`], [`small_grid`].
//!
//! ## Formula
//!
//! ```text
//! x = [ grid(p) | SH₄(ωo) | OB₄(½nₓ+½) | OB₄(½n_y+½) | OB₄(½n_z+½) | OB₄(r) ]   (product)
//! x = [ grid(p) ]                                                       (radiance)
//! y = MLP(x) ∈ ℝ³²,   q = VmfMixture::<8>::decode(y)                   (NPM Table 1)
//! ℓ = −w ln q(ωᵢ),    w = p̂(ωᵢ) / p_s(ωᵢ)                              (NPM eq. 9)
//! ∂ℓ/∂y = −w ∇_y ln q(ωᵢ)  →  MLP backward  →  grid backward
//! ```
//!
//! `grid` is [`GridConfig::npm`] (8 levels × 4 features = 32 inputs, NPM
//! §5.1), `SH₄` the real spherical harmonics of degree 4 (16 values), `OB₄`
//! the one-blob encoding with 4 bins (NPM §5.1: "the surface normal and
//! roughness are encoded with one-blob"), `p̂` the target
//! ([`Target::Radiance`]: `L_i`, [`Target::Product`]: `f L_i |cos|`, see
//! [`kl_weight`]) and `p_s` the renderer's sampling density.
//!
//! ## Parameter layout (one flat `f32` buffer)
//!
//! ```text
//! [0, mlp_offset)                         grid (GridConfig layout, offset 0)
//! [mlp_offset, mlp_offset + MLP params)   Mlp<IN, WIDTH, 32, HIDDEN> (mlp.rs layout)
//! ```
//!
//! with `mlp_offset = grid_param_count(grid)`. The paper presets
//! ([`NpmRadiance::paper`], [`NpmProduct::paper`]) hold 4 134 012 grid
//! parameters plus 12 512 (radiance, IN = 32) or 14 560 (product, IN = 64)
//! MLP parameters (3 hidden × 64, biases included).
//!
//! ## Deviations
//!
//! - The MLP has biases and the grid is vertex-aligned (see `mlp.rs`,
//!   `encoding/grid.rs`); the one-blob kernel is the paper's Gaussian
//!   (`encoding/one_blob.rs`).
//! - The guide/BSDF selection probability is a constant of the
//!   configuration ([`NPM_DEFAULT_SELECTION_PROBABILITY`] = 0.5), as in NPM's
//!   experiments; NPM learns no selection probability.
//! - A zero normal (unknown) encodes as three one-blobs of `½`; a zero `ωo`
//!   encodes as `+z` (see `sh_encode`).

use crate::encoding::grid::{resolution_at, GRID_MAX_FEATURES, GRID_MAX_LEVELS};
use crate::encoding::GridConfig;
use crate::encoding::{grid_backward, grid_forward, grid_init, one_blob_encode4, sh_encode};
use crate::gradient::GradientSink;
use crate::lobe::DirectionSample;
use crate::loss::{kl_weight, Target};
use crate::mixture::vmf::{VmfMixture, VMF_LOG_KAPPA_MIN, VMF_RAW_PER_LOBE};
use crate::mlp::{Mlp, MlpContext};
use crate::model::{GuidingModel, QueryPoint};
use crate::rng::hash2;
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// Number of vMF lobes NPM decodes (the paper's K = 8).
pub const NPM_LOBES: usize = 8;
/// Raw network outputs of NPM: `NPM_LOBES × 4` (`[logit, ln κ, θ, φ]` per lobe).
pub const NPM_OUTPUTS: usize = NPM_LOBES * VMF_RAW_PER_LOBE;
/// Selection probability of the guide (vs. the BSDF) of the presets.
pub const NPM_DEFAULT_SELECTION_PROBABILITY: f32 = 0.5;

/// Spherical-harmonics degree (bands) of `ωo` in the product inputs: 16 values.
pub const PRODUCT_SH_DEGREE: u32 = 4;
/// One-blob bins of each normal component and of the roughness.
pub const PRODUCT_ONE_BLOB_BINS: u32 = crate::encoding::one_blob::ONE_BLOB_FIXED_BINS as u32;
/// Width of the product inputs appended after the grid features:
/// `16 (SH of ωo) + 3 × 4 (normal) + 4 (roughness) = 32`.
pub const PRODUCT_INPUT_DIMS: usize = 32;

/// The `u32` code of a [`Target`] stored in the model configurations
/// (`0` radiance, `1` product).
#[inline]
#[must_use]
pub const fn target_code(target: Target) -> u32 {
    target as u32
}

/// Reads a target code: `0` is [`Target::Radiance`], every other value
/// [`Target::Product`] (so a corrupt code still names a valid target).
#[inline]
#[must_use]
pub const fn target_from_code(code: u32) -> Target {
    if code == 0 {
        Target::Radiance
    } else {
        Target::Product
    }
}

/// Input width of the networks that read `[grid | product inputs]`:
/// `grid.output_dims()` for [`Target::Radiance`], `+ PRODUCT_INPUT_DIMS` for
/// [`Target::Product`].
#[inline]
#[must_use]
pub const fn input_dims(grid: &GridConfig, target: Target) -> usize {
    match target {
        Target::Radiance => grid.output_dims(),
        Target::Product => grid.output_dims() + PRODUCT_INPUT_DIMS,
    }
}

/// [`GridConfig::param_count`] as a `const fn`, so that the model presets
/// can store their layer offsets at compile time: `Σ_l (R_l + 1)³ · F` with
/// `R_l = floor(b · s^l)` (`s^l` by successive `f32` multiplications) and the
/// grid's clamps on levels, features and resolution. Equal to
/// `grid.param_count()` for every configuration (tested); wrapping like it.
#[must_use]
pub const fn grid_param_count(grid: &GridConfig) -> usize {
    let levels = if grid.levels < GRID_MAX_LEVELS {
        grid.levels
    } else {
        GRID_MAX_LEVELS
    };
    let features = if grid.features < GRID_MAX_FEATURES {
        grid.features
    } else {
        GRID_MAX_FEATURES
    } as usize;
    let mut scale_pow = 1.0f32;
    let mut total = 0usize;
    let mut l = 0;
    while l < levels {
        let n = resolution_at(grid.base_resolution, scale_pow) as usize + 1;
        total = total.wrapping_add(n.wrapping_mul(n).wrapping_mul(n).wrapping_mul(features));
        scale_pow *= grid.per_level_scale;
        l += 1;
    }
    total
}

/// Writes the network input of `query` to `out`: the grid features of the
/// position at `0..L·F`, then, for [`Target::Product`] (`target` code ≠ 0),
/// `SH₄(ωo)`, the one-blobs of `½n + ½` (x, y, z) and of the roughness
/// (formula in the [module docs](self)). Returns the end offset. Slots past
/// `N` are skipped (a too small `N` truncates, a too large one leaves zeros),
/// and every value is finite for finite parameters, whatever the query.
pub fn encode_inputs<const N: usize>(
    params: &[f32],
    grid: &GridConfig,
    target: u32,
    query: &QueryPoint,
    out: &mut [f32; N],
) -> usize {
    let o = grid_forward(params, grid, query.position(), out, 0);
    encode_product_inputs(target, query, out, o)
}

/// [`encode_inputs`] with the grid read by
/// [`grid_forward_fast`](crate::encoding::grid::grid_forward_fast) (the same
/// bits, CPU fast path of the batched decode).
#[cfg(feature = "std")]
pub fn encode_inputs_fast<const N: usize>(
    params: &[f32],
    grid: &GridConfig,
    target: u32,
    query: &QueryPoint,
    out: &mut [f32; N],
) -> usize {
    let o = crate::encoding::grid::grid_forward_fast(params, grid, query.position(), out, 0);
    encode_product_inputs(target, query, out, o)
}

/// [`encode_inputs_fast`] that also records the grid's corners in `trace`
/// for [`crate::encoding::grid_backward_traced`] (the batched gradient).
#[cfg(feature = "std")]
pub fn encode_inputs_traced<const N: usize>(
    params: &[f32],
    grid: &GridConfig,
    target: u32,
    query: &QueryPoint,
    out: &mut [f32; N],
    trace: &mut crate::encoding::GridTrace,
) -> usize {
    let o =
        crate::encoding::grid::grid_forward_traced(params, grid, query.position(), out, 0, trace);
    encode_product_inputs(target, query, out, o)
}

/// The product inputs of [`encode_inputs`] from `out[o]` on (nothing for the
/// radiance target); returns the end offset.
#[inline]
fn encode_product_inputs<const N: usize>(
    target: u32,
    query: &QueryPoint,
    out: &mut [f32; N],
    mut o: usize,
) -> usize {
    if target != 0 {
        o = sh_encode(Vec3::from_array(query.wo), PRODUCT_SH_DEGREE, out, o);
        // The normal's components mapped from [−1, 1] to [0, 1], then the
        // roughness: 4 one-blob bins each, in one vectorisable loop.
        let n = query.normal;
        let scalars = [
            0.5 * n[0] + 0.5,
            0.5 * n[1] + 0.5,
            0.5 * n[2] + 0.5,
            query.roughness,
        ];
        o = one_blob_encode4(&scalars, out, o);
    }
    o
}

/// Seed of the `k`-th network of a model (`k ≥ 1`; the grid uses `seed`
/// itself): `hash2(seed, 0x6d6c_7000 + k)`. The grid and the MLP
/// initialisers both hash `(seed, index)`; distinct seeds keep their
/// streams apart.
#[inline]
#[must_use]
pub(crate) fn network_seed(seed: u32, k: u32) -> u32 {
    hash2(seed, 0x6d6c_7000u32.wrapping_add(k))
}

/// [`Mlp::init`] that skips parameters past `params.len()` instead of
/// panicking.
pub(crate) fn mlp_init<const IN: usize, const W: usize, const OUT: usize, const H: usize>(
    params: &mut [f32],
    offset: usize,
    seed: u32,
) {
    let len = params.len();
    let mut k = 0;
    while k < Mlp::<IN, W, OUT, H>::PARAM_COUNT {
        let idx = crate::math::add_saturating(offset, k);
        if idx >= len {
            break;
        }
        params[idx] = Mlp::<IN, W, OUT, H>::init_value(k, seed);
        k += 1;
    }
}

/// `offset + count`, saturating (a corrupt 32-bit offset cannot wrap).
#[inline]
#[must_use]
pub(crate) fn region_end(offset: u32, count: usize) -> usize {
    crate::math::add_saturating(offset as usize, count)
}

/// `p` clamped to `[0, 1]`, NaN → 0.5.
#[inline]
#[must_use]
pub(crate) fn clean_probability(p: f32) -> f32 {
    if p.is_nan() {
        0.5
    } else {
        p.clamp(0.0, 1.0)
    }
}

pub(crate) use crate::math::all_finite;

/// The flat output `y` as `K` rows of `R` (row-major, `y[k R + r]`); entries
/// past `N` read as 0.
#[inline]
#[must_use]
pub(crate) fn split_rows<const K: usize, const R: usize, const N: usize>(
    y: &[f32; N],
) -> [[f32; R]; K] {
    let mut rows = [[0.0f32; R]; K];
    let mut k = 0;
    while k < K {
        let mut r = 0;
        while r < R {
            let i = k * R + r;
            if i < N {
                rows[k][r] = y[i];
            }
            r += 1;
        }
        k += 1;
    }
    rows
}

/// The inverse of [`split_rows`]: writes `rows` into `y` (entries past `N`
/// are dropped).
#[inline]
pub(crate) fn join_rows<const K: usize, const R: usize, const N: usize>(
    rows: &[[f32; R]; K],
    y: &mut [f32; N],
) {
    let mut k = 0;
    while k < K {
        let mut r = 0;
        while r < R {
            let i = k * R + r;
            if i < N {
                y[i] = rows[k][r];
            }
            r += 1;
        }
        k += 1;
    }
}

/// A Neural Parametric Mixtures model: `[grid | product inputs]` →
/// `Mlp<IN, WIDTH, 32, HIDDEN>` → [`VmfMixture<8>`] (formula, layout and
/// deviations in the [module docs](self)).
///
/// `IN` must equal [`input_dims`]`(grid, target)` (32 for the paper's
/// radiance model, 64 for its product model); [`Self::is_consistent`] checks
/// it and the presets are checked at compile time. An inconsistent
/// configuration still never panics or produces NaN (the encoding is
/// truncated or zero-padded), it is merely not the model described here.
///
/// `repr(C)`, [`Pod`], 64 bytes: the plain data a GPU kernel reads from a
/// uniform buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Npm<const IN: usize, const WIDTH: usize, const HIDDEN: usize> {
    /// The grid; its `offset` is 0 (the grid leads the flat buffer).
    pub grid: GridConfig,
    /// Offset of the MLP in the flat buffer: `grid_param_count(grid)`.
    pub mlp_offset: u32,
    /// [`Target`] code (see [`target_code`]).
    pub target: u32,
    /// Constant probability of sampling the guide rather than the BSDF
    /// (clamped to `[0, 1]` when read; NaN reads as 0.5).
    pub selection_probability: f32,
    /// Padding.
    pub pad: u32,
}

// SAFETY: `repr(C)` struct of a `Pod` `GridConfig` (48 bytes, align 4) and
// four 4-byte scalars: no padding, every bit pattern valid, zero valid. The
// const parameters do not affect the layout.
unsafe impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Zeroable
    for Npm<IN, WIDTH, HIDDEN>
{
}
// SAFETY: see above; `Copy + 'static` holds for every parameter.
unsafe impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Pod
    for Npm<IN, WIDTH, HIDDEN>
{
}

pub use super::sizes::npm::*;
pub use super::sizes::small_grid;

/// The paper's NPM for radiance guiding: IN = 32, 3 hidden layers × 64.
pub type NpmRadiance = NpmPaperRadiance;
/// The paper's NPM for product guiding: IN = 64, 3 hidden layers × 64.
pub type NpmProduct = NpmPaperProduct;

const _: () = assert!(core::mem::size_of::<NpmRadiance>() == 64);

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Npm<IN, WIDTH, HIDDEN> {
    /// Parameters of the MLP, `Mlp<IN, WIDTH, 32, HIDDEN>::PARAM_COUNT`.
    pub const MLP_PARAMS: usize = Mlp::<IN, WIDTH, NPM_OUTPUTS, HIDDEN>::PARAM_COUNT;

    /// Model with `grid` (moved to offset 0) followed by the MLP, for
    /// `target`, selection probability [`NPM_DEFAULT_SELECTION_PROBABILITY`].
    /// See [`Self::is_consistent`] for the required `IN`.
    #[must_use]
    pub const fn new(grid: GridConfig, target: Target) -> Self {
        let grid = grid.with_offset(0);
        Self {
            grid,
            mlp_offset: grid_param_count(&grid) as u32,
            target: target_code(target),
            selection_probability: NPM_DEFAULT_SELECTION_PROBABILITY,
            pad: 0,
        }
    }

    /// The same model with a different constant selection probability.
    #[must_use]
    pub const fn with_selection_probability(mut self, p: f32) -> Self {
        self.selection_probability = p;
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

    /// Whether `params` holds the whole model (the MLP is read unchecked).
    #[inline]
    pub(crate) fn fits(&self, params: &[f32]) -> bool {
        params.len() >= region_end(self.mlp_offset, Self::MLP_PARAMS)
    }

    /// Raw network outputs for `query`; when `params` is too short, the
    /// outputs of a near-uniform mixture (`ln κ` at its lower clamp).
    fn raw(&self, params: &[f32], query: &QueryPoint) -> [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] {
        if !self.fits(params) {
            return [[0.0, VMF_LOG_KAPPA_MIN, 0.0, 0.0]; NPM_LOBES];
        }
        let mut input = [0.0f32; IN];
        encode_inputs(params, &self.grid, self.target, query, &mut input);
        let y =
            Mlp::<IN, WIDTH, NPM_OUTPUTS, HIDDEN>::infer(params, self.mlp_offset as usize, &input);
        split_rows(&y)
    }

    /// The vMF mixture at `query`, for renderers that keep the decoded
    /// distribution per path vertex (MIS, NEE, the cosine product) instead
    /// of calling the network again. A too short `params` gives a
    /// near-uniform mixture.
    #[must_use]
    pub fn decode(&self, params: &[f32], query: &QueryPoint) -> VmfMixture<NPM_LOBES> {
        VmfMixture::decode(&self.raw(params, query))
    }
}

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> GuidingModel
    for Npm<IN, WIDTH, HIDDEN>
{
    const FAMILY: super::Family = super::Family::Npm;

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
    /// [`Mlp::init`] with a seed derived from `seed`. Parameters past
    /// `params.len()` are skipped.
    fn init(&self, params: &mut [f32], seed: u32) {
        grid_init(params, &self.grid, seed);
        mlp_init::<IN, WIDTH, NPM_OUTPUTS, HIDDEN>(
            params,
            self.mlp_offset as usize,
            network_seed(seed, 1),
        );
    }

    /// [`VmfMixture::sample`] of [`Self::decode`]: the pdf is the mixture
    /// density of the returned direction.
    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample {
        self.decode(params, query).sample(u)
    }

    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32 {
        self.decode(params, query).pdf(direction)
    }

    fn constant_selection_probability(&self) -> Option<f32> {
        Some(clean_probability(self.selection_probability))
    }

    /// The configuration's constant (NPM learns none).
    fn selection_probability(&self, _params: &[f32], _query: &QueryPoint) -> f32 {
        clean_probability(self.selection_probability)
    }

    /// `ℓ = −w ln q(ωᵢ)` with `w` = [`kl_weight`] (NPM eq. 9); the gradient
    /// `−w ∇ ln q` ([`VmfMixture::grad_log_pdf`]) is pushed through the MLP
    /// and into the 8 corners of each grid level. Adds nothing and returns 0
    /// for an invalid sample, a zero weight, a too short `params`/`grad`, or
    /// a non-finite loss, network output or output gradient (a finite output
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
        let mut ctx = MlpContext::<WIDTH, HIDDEN>::ZERO;
        let y = Mlp::<IN, WIDTH, NPM_OUTPUTS, HIDDEN>::forward(params, offset, &input, &mut ctx);
        let raw: [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] = split_rows(&y);
        let mut g = [[0.0f32; VMF_RAW_PER_LOBE]; NPM_LOBES];
        let log_q = VmfMixture::grad_log_pdf(&raw, sample.wi(), &mut g);
        let loss = -w * log_q;
        let mut d_y = [0.0f32; NPM_OUTPUTS];
        join_rows(&g, &mut d_y);
        let mut i = 0;
        while i < NPM_OUTPUTS {
            d_y[i] *= -w;
            i += 1;
        }
        if !(loss.is_finite() && all_finite(&y) && all_finite(&d_y)) {
            return 0.0;
        }
        let mut d_input = [0.0f32; IN];
        Mlp::<IN, WIDTH, NPM_OUTPUTS, HIDDEN>::backward(
            params,
            offset,
            &input,
            &ctx,
            &d_y,
            grad,
            &mut d_input,
        );
        grid_backward(&self.grid, sample.position(), &d_input, 0, grad);
        loss
    }
}

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> super::RawOutputs
    for Npm<IN, WIDTH, HIDDEN>
{
    const RAW_OUTPUTS: usize = NPM_OUTPUTS;

    /// The rows of [`Self::decode`]'s input, flattened row-major
    /// (`out[base + 4k + r]`).
    fn write_raw(&self, params: &[f32], query: &QueryPoint, out: &mut [f32], base: usize) {
        let rows = self.raw(params, query);
        let mut k = 0;
        while k < NPM_LOBES {
            let mut r = 0;
            while r < VMF_RAW_PER_LOBE {
                let i = crate::math::add_saturating(base, k * VMF_RAW_PER_LOBE + r);
                if i < out.len() {
                    out[i] = rows[k][r];
                }
                r += 1;
            }
            k += 1;
        }
    }
}
