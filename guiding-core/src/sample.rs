//! The training record a renderer hands to the guiding field, and its
//! validation.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Largest deviation from unit length accepted for `wi` (and for a non-zero
/// `normal` / `wo`): `| |v| − 1 | ≤ 10⁻³`.
pub const UNIT_TOLERANCE: f32 = 1e-3;

/// One training sample: a path vertex, the direction the renderer sampled
/// there and the radiance that came back along it.
///
/// `repr(C)`, `Pod`, 96 bytes (every vector padded to four floats).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TrainingSample {
    /// World-space position of the vertex.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product models only).
    pub roughness: f32,
    /// Unit shading normal (product models only; zero if unknown).
    pub normal: [f32; 3],
    /// Density, in solid angle, with which the renderer actually sampled
    /// `wi` (the one-sample MIS density of BSDF and guide sampling). `> 0`.
    pub sample_pdf: f32,
    /// Unit outgoing direction (towards the previous vertex; product models only).
    pub wo: [f32; 3],
    /// Density of `wi` under BSDF sampling alone (NASG's MIS loss); `0` if unknown.
    pub bsdf_pdf: f32,
    /// Unit sampled incident direction.
    pub wi: [f32; 3],
    /// Padding.
    pub pad0: f32,
    /// Estimate of the incident radiance `L_i(x, wi)`, RGB, `≥ 0`.
    pub radiance: [f32; 3],
    /// Padding.
    pub pad1: f32,
    /// `f(wo, wi) |cos θ_i|`, RGB, `≥ 0` (product targets).
    pub bsdf_cos: [f32; 3],
    /// Padding.
    pub pad2: f32,
}

/// Why a training sample was rejected. Codes are stable (`u32`), so GPU
/// kernels can count them in a buffer.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// A field is NaN or infinite.
    NonFinite = 1,
    /// Negative radiance or BSDF value.
    Negative = 2,
    /// `sample_pdf ≤ 0` (or a negative `bsdf_pdf`).
    NonPositivePdf = 3,
    /// `wi` (or a non-zero `normal`/`wo`) is not unit length.
    NonUnitDirection = 4,
}

/// Number of distinct [`Rejection`] codes (`1..=REJECTION_KINDS`).
pub const REJECTION_KINDS: usize = 4;

fn all_finite<const N: usize>(v: &[f32; N]) -> bool {
    let mut i = 0;
    while i < N {
        if !v[i].is_finite() {
            return false;
        }
        i += 1;
    }
    true
}

fn all_non_negative(v: &[f32; 3]) -> bool {
    v[0] >= 0.0 && v[1] >= 0.0 && v[2] >= 0.0
}

fn is_unit(v: &[f32; 3]) -> bool {
    let len = Vec3::from_array(*v).length();
    (len - 1.0).abs() <= UNIT_TOLERANCE
}

fn is_unit_or_zero(v: &[f32; 3]) -> bool {
    (v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0) || is_unit(v)
}

impl TrainingSample {
    /// Checks that the sample can be trained on. Samples with non-finite or
    /// negative values, a non-positive pdf or non-unit directions are never
    /// trained on; callers count the rejections.
    pub fn validate(&self) -> Result<(), Rejection> {
        let scalars = [self.roughness, self.sample_pdf, self.bsdf_pdf];
        if !(all_finite(&self.position)
            && all_finite(&self.normal)
            && all_finite(&self.wo)
            && all_finite(&self.wi)
            && all_finite(&self.radiance)
            && all_finite(&self.bsdf_cos)
            && all_finite(&scalars))
        {
            return Err(Rejection::NonFinite);
        }
        if !(all_non_negative(&self.radiance) && all_non_negative(&self.bsdf_cos)) {
            return Err(Rejection::Negative);
        }
        if !(self.sample_pdf > 0.0 && self.bsdf_pdf >= 0.0) {
            return Err(Rejection::NonPositivePdf);
        }
        if !(is_unit(&self.wi) && is_unit_or_zero(&self.normal) && is_unit_or_zero(&self.wo)) {
            return Err(Rejection::NonUnitDirection);
        }
        Ok(())
    }

    /// Incident direction as a vector.
    #[inline]
    #[must_use]
    pub fn wi(&self) -> Vec3 {
        Vec3::from_array(self.wi)
    }

    /// Position as a vector.
    #[inline]
    #[must_use]
    pub fn position(&self) -> Vec3 {
        Vec3::from_array(self.position)
    }
}
