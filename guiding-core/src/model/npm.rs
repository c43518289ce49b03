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
//! [`kl_weight`](crate::loss::kl_weight)) and `p_s` the renderer's sampling density.
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

use super::mixture_model::{MixtureFamily, MixtureModel};
use crate::encoding::grid::{resolution_at, GRID_MAX_FEATURES, GRID_MAX_LEVELS};
use crate::encoding::GridConfig;
use crate::encoding::{grid_forward, one_blob_encode4, sh_encode};
use crate::loss::Target;
use crate::mixture::vmf::{VmfMixture, VMF_LOG_KAPPA_MIN, VMF_RAW_PER_LOBE};
use crate::mlp::Mlp;
use crate::model::QueryPoint;
use crate::rng::hash2;
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

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

/// The product inputs of [`encode_inputs`] from `out[o]` on (nothing for the
/// radiance target); returns the end offset. [`encode_inputs`] is
/// [`grid_forward`] followed by this; the batched CPU decoders follow
/// [`grid_forward_fast`](crate::encoding::grid::grid_forward_fast) or
/// [`grid_forward_traced`](crate::encoding::grid::grid_forward_traced) (the
/// same bits) by it.
#[inline]
pub fn encode_product_inputs<const N: usize>(
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
    let mut i = 0;
    while i < K * R && i < N {
        rows[i / R][i % R] = y[i];
        i += 1;
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
    let mut i = 0;
    while i < K * R && i < N {
        y[i] = rows[i / R][i % R];
        i += 1;
    }
}

/// [`join_rows`] into a new array.
#[inline]
#[must_use]
pub(crate) fn flat_rows<const K: usize, const R: usize, const N: usize>(
    rows: &[[f32; R]; K],
) -> [f32; N] {
    let mut y = [0.0; N];
    join_rows(rows, &mut y);
    y
}

/// A Neural Parametric Mixtures model: `[grid | product inputs]` →
/// `Mlp<IN, WIDTH, 32, HIDDEN>` → [`VmfMixture<8>`] (formula, layout and
/// deviations in the [module docs](self)): the [`MixtureModel`] of the
/// vMF family ([`NpmFamily`]).
///
/// `IN` must equal [`input_dims`]`(grid, target)` (32 for the paper's
/// radiance model, 64 for its product model); see
/// [`MixtureModel::is_consistent`].
pub type Npm<const IN: usize, const WIDTH: usize, const HIDDEN: usize> =
    MixtureModel<NpmFamily, IN, WIDTH, HIDDEN, NPM_OUTPUTS>;

/// NPM's setting in a [`Npm`] model: the constant probability of sampling
/// the guide rather than the BSDF (NPM learns none).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct NpmFamily {
    /// Constant probability of sampling the guide rather than the BSDF
    /// (clamped to `[0, 1]` when read; NaN reads as 0.5).
    pub selection_probability: f32,
    /// Padding.
    pub pad: u32,
}

pub use super::sizes::npm::*;
pub use super::sizes::small_grid;

/// The paper's NPM for radiance guiding: IN = 32, 3 hidden layers × 64.
pub type NpmRadiance = NpmPaperRadiance;
/// The paper's NPM for product guiding: IN = 64, 3 hidden layers × 64.
pub type NpmProduct = NpmPaperProduct;

const _: () = assert!(core::mem::size_of::<NpmRadiance>() == 64);

impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Npm<IN, WIDTH, HIDDEN> {
    /// The same model with a different constant selection probability.
    #[must_use]
    pub const fn with_selection_probability(self, p: f32) -> Self {
        self.with_family(NpmFamily::new(p))
    }
}

impl NpmFamily {
    /// The setting with selection probability `p`.
    #[must_use]
    pub const fn new(p: f32) -> Self {
        Self {
            selection_probability: p,
            pad: 0,
        }
    }
}

impl MixtureFamily<NPM_OUTPUTS> for NpmFamily {
    const FAMILY: super::Family = super::Family::Npm;
    const DEFAULT: Self = Self::new(NPM_DEFAULT_SELECTION_PROBABILITY);
    const UNFIT_SELECTION_PROBABILITY: f32 = NPM_DEFAULT_SELECTION_PROBABILITY; // never asked

    type Decoded = VmfMixture<NPM_LOBES>;

    /// `ln κ` at its lower clamp, everything else 0.
    fn uniform_raw() -> [f32; NPM_OUTPUTS] {
        flat_rows(&[[0.0, VMF_LOG_KAPPA_MIN, 0.0, 0.0]; NPM_LOBES])
    }

    /// [`VmfMixture::decode`] of the rows `[logit, ln κ, θ, φ]` of `y`.
    fn decode(y: &[f32; NPM_OUTPUTS]) -> VmfMixture<NPM_LOBES> {
        VmfMixture::decode(&split_rows(y))
    }

    fn constant_selection_probability(&self) -> Option<f32> {
        Some(clean_probability(self.selection_probability))
    }

    /// The constant (never asked: NPM learns none).
    fn learned_selection_probability(_y: &[f32; NPM_OUTPUTS]) -> f32 {
        NPM_DEFAULT_SELECTION_PROBABILITY
    }

    /// `ℓ = −w ln q(ωᵢ)` (NPM eq. 9), `∂ℓ/∂y = −w ∇ ln q`
    /// ([`VmfMixture::grad_log_pdf`]).
    fn output_gradient(
        &self,
        y: &[f32; NPM_OUTPUTS],
        sample: &TrainingSample,
        w: f32,
        d_y: &mut [f32; NPM_OUTPUTS],
    ) -> f32 {
        let raw: [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] = split_rows(y);
        let mut g = [[0.0f32; VMF_RAW_PER_LOBE]; NPM_LOBES];
        let log_q = VmfMixture::grad_log_pdf(&raw, sample.wi(), &mut g);
        let loss = -w * log_q;
        join_rows(&g, d_y);
        let mut i = 0;
        while i < NPM_OUTPUTS {
            d_y[i] *= -w;
            i += 1;
        }
        loss
    }

    /// [`super::batched::decode_vmf_batch`].
    #[cfg(feature = "std")]
    fn decode_batch(ys: &[[f32; NPM_OUTPUTS]], out: &mut [VmfMixture<NPM_LOBES>]) {
        super::batched::decode_vmf_batch(ys, out);
    }

    /// NPM eq. 9 as [`Self::output_gradient`], the gradient of `ln q`
    /// vectorised over the chunk
    /// ([`super::vmf_gradient::grad_log_pdf_vmf_batch`]).
    #[cfg(feature = "std")]
    fn output_gradients(&self, c: super::batched::ChunkOutputs<'_, NPM_OUTPUTS>) {
        use super::batched::TRAIN_CHUNK;
        let m = c.ys.len();
        let mut dirs = [Vec3::Z; TRAIN_CHUNK];
        let mut log_q = [0.0f32; TRAIN_CHUNK];
        for (k, d) in dirs[..m].iter_mut().enumerate() {
            *d = c.sample(k).wi();
        }
        super::vmf_gradient::grad_log_pdf_vmf_batch(c.ys, &dirs[..m], c.dys, &mut log_q[..m]);
        for (k, &log_q) in log_q[..m].iter().enumerate() {
            let w = crate::loss::kl_weight(c.sample(k), c.target);
            for d in c.dys[k].iter_mut() {
                *d *= -w;
            }
            c.losses[k] = -w * log_q;
        }
    }
}
