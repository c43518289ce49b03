//! The training record a renderer hands to the guiding field, and its
//! validation.

use crate::math::all_finite;
use crate::model::QueryPoint;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Largest deviation from unit length accepted for `wi` (and for a non-zero
/// `normal` / `wo`): `| |v| − 1 | ≤ 10⁻³`.
pub const UNIT_TOLERANCE: f32 = 1e-3;

/// One training sample: a path vertex, the direction the renderer sampled
/// there and the radiance that came back along it.
///
/// Directions follow the library's convention (pbrt's; see the `guiding`
/// crate's *Conventions*): `wo` points towards the previous path vertex, `wi`
/// is the sampled continuation direction, along which `radiance` arrives.
///
/// `repr(C)`, `Pod`, 96 bytes (every vector padded to four floats). Build it
/// with [`Self::new`], which zeroes the padding.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TrainingSample {
    /// World-space position of the vertex.
    pub position: [f32; 3],
    /// Surface roughness in `[0, 1]` (product models only).
    pub roughness: f32,
    /// Unit world-space shading normal (product models only). Zero: no surface, a
    /// scattering point inside a participating medium, or unknown.
    pub normal: [f32; 3],
    /// Density, in solid angle, with which the renderer actually sampled
    /// `wi` (the one-sample MIS density of BSDF and guide sampling). `> 0`.
    pub sample_pdf: f32,
    /// `wo`: unit world-space direction towards the previous vertex, the
    /// viewer (product models only; zero if unknown).
    pub wo: [f32; 3],
    /// Density of `wi` under BSDF sampling alone (NASG's MIS loss); `0` if unknown.
    pub bsdf_pdf: f32,
    /// `wi`: unit world-space sampled continuation direction (the incident
    /// direction of `radiance`).
    pub wi: [f32; 3],
    /// Padding (0).
    pub pad0: f32,
    /// Estimate of the incident radiance `L_i(x, wi)`, RGB, `≥ 0`.
    pub radiance: [f32; 3],
    /// Padding (0).
    pub pad1: f32,
    /// `f(wo, wi) |cos θ_i|`, RGB, `≥ 0` (product targets).
    pub bsdf_cos: [f32; 3],
    /// Padding (0).
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
    /// A sample at the vertex `query` (position, normal, `wo`, roughness):
    /// the renderer sampled `wi` with density `sample_pdf`, and `radiance`
    /// (`L_i(x, wi)`) came back along it; `bsdf_pdf` is the density of `wi`
    /// under BSDF sampling alone (`0` if unknown) and `bsdf_cos` is
    /// `f(wo, wi) |cos θ_i|` (product targets; zero otherwise). The padding
    /// is zero. Nothing is checked here: see [`Self::validate`].
    ///
    /// ```
    /// use guiding_core::model::QueryPoint;
    /// use guiding_core::sample::TrainingSample;
    ///
    /// let vertex = QueryPoint::new([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8], 0.5);
    /// let s = TrainingSample::new(vertex, [0.6, 0.0, 0.8], [1.0, 2.0, 3.0], 0.25, 0.3, [0.5; 3]);
    /// assert_eq!(s.validate(), Ok(()));
    /// assert_eq!((s.wi, s.sample_pdf, s.bsdf_pdf), ([0.6, 0.0, 0.8], 0.25, 0.3));
    /// assert_eq!(QueryPoint::of_sample(&s), vertex);
    /// ```
    #[inline]
    #[must_use]
    pub const fn new(
        query: QueryPoint,
        wi: [f32; 3],
        radiance: [f32; 3],
        sample_pdf: f32,
        bsdf_pdf: f32,
        bsdf_cos: [f32; 3],
    ) -> Self {
        Self {
            position: query.position,
            roughness: query.roughness,
            normal: query.normal,
            sample_pdf,
            wo: query.wo,
            bsdf_pdf,
            wi,
            pad0: 0.0,
            radiance,
            pad1: 0.0,
            bsdf_cos,
            pad2: 0.0,
        }
    }

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

#[cfg(test)]
mod tests {
    use super::TrainingSample;
    use crate::model::QueryPoint;
    use bytemuck::bytes_of;
    use core::mem::{align_of, offset_of, size_of};

    /// The constructors write the fields to their documented slots and zero
    /// the padding: the memory image, one 16-byte `vec4` slot a row.
    #[test]
    fn constructors_match_literals_with_zero_padding() {
        let q = QueryPoint::new([1.0, 2.0, 3.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8], 0.25);
        let q_image: [f32; 12] = [
            1.0, 2.0, 3.0, 0.25, // position, roughness
            0.0, 0.0, 1.0, 0.0, // normal, pad0
            0.6, 0.0, 0.8, 0.0, // wo, pad1
        ];
        assert_eq!(bytes_of(&q), bytes_of(&q_image));
        let from_vec3 = QueryPoint::from_vec3(
            glam::Vec3::new(1.0, 2.0, 3.0),
            glam::Vec3::Z,
            glam::Vec3::new(0.6, 0.0, 0.8),
            0.25,
        );
        assert_eq!(bytes_of(&from_vec3), bytes_of(&q_image));

        let s = TrainingSample::new(
            q,
            [0.0, 0.6, 0.8],
            [4.0, 5.0, 6.0],
            0.5,
            0.125,
            [0.7, 0.8, 0.9],
        );
        let s_image: [f32; 24] = [
            1.0, 2.0, 3.0, 0.25, // position, roughness
            0.0, 0.0, 1.0, 0.5, // normal, sample_pdf
            0.6, 0.0, 0.8, 0.125, // wo, bsdf_pdf
            0.0, 0.6, 0.8, 0.0, // wi, pad0
            4.0, 5.0, 6.0, 0.0, // radiance, pad1
            0.7, 0.8, 0.9, 0.0, // bsdf_cos, pad2
        ];
        assert_eq!(bytes_of(&s), bytes_of(&s_image));
        assert_eq!(QueryPoint::of_sample(&s), q);
    }

    /// `offsets_of!(T, [f₀, f₁, …])` = `[offset_of!(T, f₀), offset_of!(T, f₁), …]`.
    macro_rules! offsets_of {
        ($t:ty, [$($field:ident),+ $(,)?]) => {
            [$(offset_of!($t, $field)),+]
        };
    }

    /// The GPU / C layout: sizes, alignment and every field's offset.
    #[test]
    fn layouts_are_unchanged() {
        assert_eq!((size_of::<QueryPoint>(), align_of::<QueryPoint>()), (48, 4));
        assert_eq!(
            offsets_of!(QueryPoint, [position, roughness, normal, pad0, wo, pad1]),
            [0, 12, 16, 28, 32, 44]
        );
        assert_eq!(
            (size_of::<TrainingSample>(), align_of::<TrainingSample>()),
            (96, 4)
        );
        assert_eq!(
            offsets_of!(
                TrainingSample,
                [
                    position, roughness, normal, sample_pdf, wo, bsdf_pdf, wi, pad0, radiance,
                    pad1, bsdf_cos, pad2
                ]
            ),
            [0, 12, 16, 28, 32, 44, 48, 60, 64, 76, 80, 92]
        );
    }
}
