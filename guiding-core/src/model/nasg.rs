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
//! with `w` = [`kl_weight`](crate::loss::kl_weight) (NASG eq. 17), `e` = [`NASG_MIS_BLEND`] = 0.2,
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

use super::mixture_model::{MixtureFamily, MixtureModel};
use crate::loss::nasg_mis_loss;
use crate::mixture::nasg::{
    decode_selection, NasgMixture, NASG_LN_A_MIN, NASG_LN_LAMBDA_MIN, NASG_RAW_PER_LOBE,
    NASG_SELECTION_DEFAULT,
};
use crate::model::npm::{flat_rows, join_rows, split_rows};
use crate::sample::TrainingSample;
use bytemuck::{Pod, Zeroable};

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
/// probability (formula, layout and deviations in the [module docs](self)):
/// the [`MixtureModel`] of the NASG family ([`NasgFamily`]).
///
/// `IN` must equal [`input_dims`](super::npm::input_dims)`(grid, target)`
/// (see [`MixtureModel::is_consistent`]).
pub type Nasg<const IN: usize, const WIDTH: usize, const HIDDEN: usize> =
    MixtureModel<NasgFamily, IN, WIDTH, HIDDEN, NASG_OUTPUTS>;

/// NASG's setting in a [`Nasg`] model: the blend `e` of its loss.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct NasgFamily {
    /// The blend `e` of NASG eq. 18 ([`NASG_MIS_BLEND`]).
    pub mis_blend: f32,
    /// Padding.
    pub pad: u32,
}

pub use super::sizes::nasg::*;

/// The paper's NASG model (product target): IN = 64, 4 hidden layers × 128.
pub type NasgProduct = NasgPaperProduct;
/// NASG with a radiance target: IN = 32, 4 hidden layers × 128.
pub type NasgRadiance = NasgPaperRadiance;

const _: () = assert!(core::mem::size_of::<NasgProduct>() == 64);
impl<const IN: usize, const WIDTH: usize, const HIDDEN: usize> Nasg<IN, WIDTH, HIDDEN> {
    /// The same model with another blend `e` of eq. 18 (clamped to `[0, 1]`
    /// when used; NaN reads as [`NASG_MIS_BLEND`]).
    #[must_use]
    pub const fn with_mis_blend(self, e: f32) -> Self {
        self.with_family(NasgFamily {
            mis_blend: e,
            pad: 0,
        })
    }
}

impl NasgFamily {
    /// The setting with blend `e`.
    #[must_use]
    pub const fn new(e: f32) -> Self {
        Self {
            mis_blend: e,
            pad: 0,
        }
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
}

impl MixtureFamily<NASG_OUTPUTS> for NasgFamily {
    const FAMILY: super::Family = super::Family::Nasg;
    const DEFAULT: Self = Self::new(NASG_MIS_BLEND);
    const UNFIT_SELECTION_PROBABILITY: f32 = NASG_SELECTION_DEFAULT;

    type Decoded = NasgMixture<NASG_LOBES>;

    /// λ and `a` at their lower clamps, everything else 0 (so `c = ½`).
    fn uniform_raw() -> [f32; NASG_OUTPUTS] {
        flat_rows(&[[0.0, NASG_LN_LAMBDA_MIN, NASG_LN_A_MIN, 0.0, 0.0, 0.0]; NASG_LOBES])
    }

    /// [`NasgMixture::decode`] of the 8 rows of 6 lobe values of `y` and its
    /// selection logit.
    fn decode(y: &[f32; NASG_OUTPUTS]) -> NasgMixture<NASG_LOBES> {
        NasgMixture::decode(&split_rows(y), y[NASG_SELECTION_OUTPUT])
    }

    /// Learned per query (the network's last output).
    fn constant_selection_probability(&self) -> Option<f32> {
        None
    }

    /// The learned `c` ([`decode_selection`] of the last output).
    fn learned_selection_probability(y: &[f32; NASG_OUTPUTS]) -> f32 {
        decode_selection(y[NASG_SELECTION_OUTPUT]).0
    }

    /// NASG eq. 18 ([`nasg_mis_loss`]): the lobe outputs get
    /// `∂ℓ/∂ln q · ∇ ln q` ([`NasgMixture::grad_log_pdf`]), the selection
    /// output `∂ℓ/∂c · dc/dr` ([`decode_selection`]).
    fn output_gradient(
        &self,
        y: &[f32; NASG_OUTPUTS],
        sample: &TrainingSample,
        w: f32,
        d_y: &mut [f32; NASG_OUTPUTS],
    ) -> f32 {
        let raw: [[f32; NASG_RAW_PER_LOBE]; NASG_LOBES] = split_rows(y);
        let mut g = [[0.0f32; NASG_RAW_PER_LOBE]; NASG_LOBES];
        let log_q = NasgMixture::grad_log_pdf(&raw, sample.wi(), &mut g);
        let (c, dc_dr) = decode_selection(y[NASG_SELECTION_OUTPUT]);
        let terms = nasg_mis_loss(w, log_q, c, sample.bsdf_pdf, self.blend());
        join_rows(&g, d_y);
        let mut i = 0;
        while i < NASG_SELECTION_OUTPUT {
            d_y[i] *= terms.dloss_dlog_guide;
            i += 1;
        }
        d_y[NASG_SELECTION_OUTPUT] = terms.dloss_dselection * dc_dr;
        terms.loss
    }

    /// [`super::batched::decode_nasg_batch`].
    #[cfg(feature = "std")]
    fn decode_batch(ys: &[[f32; NASG_OUTPUTS]], out: &mut [NasgMixture<NASG_LOBES>]) {
        super::batched::decode_nasg_batch(ys, out);
    }
}
