//! Materials: Lambertian diffuse and GGX rough conductor (Mitsuba 3 semantics).
//!
//! All functions work in the local shading frame (z = shading normal). Both BSDFs are
//! one-sided like Mitsuba's: if either direction is below the surface the value is zero.

use crate::math::sample_cosine_hemisphere;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// A material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Lambertian reflector with RGB albedo.
    Diffuse {
        /// Albedo.
        reflectance: Vec3,
    },
    /// Isotropic GGX microfacet conductor with complex RGB index of refraction `eta + i k`.
    RoughConductor {
        /// GGX roughness alpha.
        alpha: f32,
        /// Real part of the IOR.
        eta: Vec3,
        /// Imaginary part (absorption).
        k: Vec3,
    },
}

/// Result of sampling a BSDF.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled outgoing direction (local frame).
    pub wo: Vec3,
    /// `f * cos(wo) / pdf`.
    pub weight: Vec3,
    /// Solid-angle pdf of `wo`.
    pub pdf: f32,
}

/// Unpolarised Fresnel reflectance of a conductor, per channel (same formula as Mitsuba 3).
pub fn fresnel_conductor(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    let c = cos_i.clamp(0.0, 1.0);
    let f = |eta: f32, k: f32| -> f32 {
        let cos2 = c * c;
        let sin2 = 1.0 - cos2;
        let (eta2, k2) = (eta * eta, k * k);
        let t0 = eta2 - k2 - sin2;
        let a2pb2 = (t0 * t0 + 4.0 * eta2 * k2).max(0.0).sqrt();
        let a = (0.5 * (a2pb2 + t0)).max(0.0).sqrt();
        let t1 = a2pb2 + cos2;
        let t2 = 2.0 * c * a;
        let rs = (t1 - t2) / (t1 + t2);
        let t3 = cos2 * a2pb2 + sin2 * sin2;
        let t4 = t2 * sin2;
        let rp = rs * (t3 - t4) / (t3 + t4);
        let r = 0.5 * (rp + rs);
        if r.is_finite() {
            r.clamp(0.0, 1.0)
        } else {
            1.0
        }
    };
    Vec3::new(f(eta.x, k.x), f(eta.y, k.y), f(eta.z, k.z))
}

/// GGX normal distribution D(m).
pub fn ggx_d(m: Vec3, alpha: f32) -> f32 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let d = m.z * m.z * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

/// Smith G1 for GGX (one-sided, ignores the microfacet side test like Mitsuba does for wi/wo > 0).
pub fn ggx_g1(v: Vec3, m: Vec3, alpha: f32) -> f32 {
    if v.dot(m) * v.z <= 0.0 {
        return 0.0;
    }
    let z2 = v.z * v.z;
    let tan2 = ((1.0 - z2) / z2).max(0.0);
    2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

/// Samples a visible normal of the GGX distribution (Heitz 2018, "Sampling the GGX
/// Distribution of Visible Normals"). `wi` must be in the upper hemisphere.
pub fn sample_ggx_vndf(wi: Vec3, alpha: f32, u1: f32, u2: f32) -> Vec3 {
    let vh = Vec3::new(alpha * wi.x, alpha * wi.y, wi.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    let p1 = r * phi.cos();
    let mut p2 = r * phi.sin();
    let s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

impl Material {
    /// Evaluates `f(wi, wo) * cos(wo)` and the solid-angle pdf of sampling `wo` given `wi`.
    pub fn eval(&self, wi: Vec3, wo: Vec3) -> (Vec3, f32) {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        match *self {
            Material::Diffuse { reflectance } => {
                (reflectance * (FRAC_1_PI * wo.z), FRAC_1_PI * wo.z)
            }
            Material::RoughConductor { alpha, eta, k } => {
                let m = (wi + wo).normalize();
                let d = ggx_d(m, alpha);
                let g1i = ggx_g1(wi, m, alpha);
                let g = g1i * ggx_g1(wo, m, alpha);
                let f = fresnel_conductor(wi.dot(m), eta, k);
                let value = f * (d * g / (4.0 * wi.z));
                let pdf = g1i * wi.dot(m).max(0.0) * d / wi.z / (4.0 * wo.dot(m));
                (value, pdf)
            }
        }
    }

    /// Samples an outgoing direction. Returns `None` when the sample is absorbed or invalid.
    pub fn sample(&self, wi: Vec3, u1: f32, u2: f32) -> Option<BsdfSample> {
        if wi.z <= 0.0 {
            return None;
        }
        match *self {
            Material::Diffuse { reflectance } => {
                let wo = sample_cosine_hemisphere(u1, u2);
                if wo.z <= 0.0 {
                    return None;
                }
                Some(BsdfSample {
                    wo,
                    weight: reflectance,
                    pdf: wo.z * FRAC_1_PI,
                })
            }
            Material::RoughConductor { alpha, eta, k } => {
                let m = sample_ggx_vndf(wi, alpha, u1, u2);
                let wo = 2.0 * wi.dot(m) * m - wi;
                if wo.z <= 0.0 {
                    return None;
                }
                let g1i = ggx_g1(wi, m, alpha);
                if g1i <= 0.0 {
                    return None;
                }
                let d = ggx_d(m, alpha);
                let pdf = g1i * wi.dot(m).max(0.0) * d / wi.z / (4.0 * wo.dot(m));
                // f cos / pdf = F G1(wi) G1(wo) / G1(wi) = F G1(wo) (separable Smith G).
                let weight = fresnel_conductor(wi.dot(m), eta, k) * ggx_g1(wo, m, alpha);
                if pdf.is_nan() || pdf <= 0.0 || !weight.is_finite() {
                    return None;
                }
                Some(BsdfSample { wo, weight, pdf })
            }
        }
    }

    /// True for the Lambertian BSDF.
    pub fn is_diffuse(&self) -> bool {
        matches!(self, Material::Diffuse { .. })
    }

    /// True if the material reflects nothing (e.g. the black "Null" BSDF of area lights).
    pub fn is_black(&self) -> bool {
        match *self {
            Material::Diffuse { reflectance } => reflectance.max_element() <= 0.0,
            Material::RoughConductor { .. } => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// Sampling weight must equal eval/pdf (consistency between `sample` and `eval`).
    #[test]
    fn sample_matches_eval() {
        let mats = [
            Material::Diffuse {
                reflectance: Vec3::new(0.5, 0.6, 0.7),
            },
            Material::RoughConductor {
                alpha: 0.3,
                eta: Vec3::new(0.2, 0.92, 1.1),
                k: Vec3::new(3.9, 2.45, 2.14),
            },
        ];
        let mut rng = Rng::new(1, 2, 3);
        let wi = Vec3::new(0.3, -0.2, 0.8).normalize();
        for m in mats {
            for _ in 0..1000 {
                let Some(s) = m.sample(wi, rng.next_f32(), rng.next_f32()) else {
                    continue;
                };
                let (f, pdf) = m.eval(wi, s.wo);
                assert!(
                    (pdf - s.pdf).abs() <= 1e-3 * pdf.max(1.0),
                    "{pdf} {}",
                    s.pdf
                );
                let w = f / pdf;
                assert!((w - s.weight).abs().max_element() < 1e-3 * w.max_element().max(1.0));
            }
        }
    }

    /// The VNDF pdf integrated over the upper hemisphere equals the fraction of samples that
    /// `sample` accepts (reflections below the horizon are rejected).
    #[test]
    fn ggx_pdf_normalised() {
        let m = Material::RoughConductor {
            alpha: 0.4,
            eta: Vec3::ZERO,
            k: Vec3::ONE,
        };
        let wi = Vec3::new(0.5, 0.0, 0.8).normalize();
        let mut rng = Rng::new(7, 0, 0);
        let n = 400_000;
        let mut acc = 0.0f64;
        let mut accepted = 0usize;
        for _ in 0..n {
            let wo = crate::math::sample_uniform_sphere(rng.next_f32(), rng.next_f32());
            acc += m.eval(wi, wo).1 as f64 * 4.0 * std::f64::consts::PI;
            accepted += m.sample(wi, rng.next_f32(), rng.next_f32()).is_some() as usize;
        }
        let integral = acc / n as f64;
        let frac = accepted as f64 / n as f64;
        assert!((integral - frac).abs() < 0.02, "{integral} vs {frac}");
    }
}
