//! Participating media (Mitsuba's `homogeneous`, and `heterogeneous` with a density grid,
//! [`crate::scene::grid`]) and their phase functions (`isotropic`, `hg`).
//!
//! # Free-flight sampling
//!
//! A heterogeneous medium (grey extinction times the grid's density) uses delta tracking
//! against the majorant `σt · max d` for free flights and ratio tracking for shadow rays,
//! restricted to the grid's box ([`Medium::free_flight`], [`Medium::transmittance_along`]).
//! Along a ray inside a homogeneous medium with extinction `σt` (RGB) the distance to the next collision
//! is sampled with one-sample spectral MIS (the balance heuristic over the colour channels, as
//! Mitsuba 3's `volpathmis` and pbrt-v4's chromatic media do): a channel `c` is picked
//! uniformly, `t = −ln(1 − u) / σt_c`, and the sample's density is the channels' mean,
//!
//! ```text
//! p(t) = ⅓ Σ_c σt_c e^{−σt_c t}              (a collision at t < t_max)
//! P(pass) = ⅓ Σ_c e^{−σt_c t_max}             (no collision before the surface at t_max)
//! ```
//!
//! with weights `σs ⊙ e^{−σt t} / p(t)` (scattering; `σs = albedo ⊙ σt`) and
//! `e^{−σt t_max} / P(pass)`, both exactly the albedo and 1 for a grey medium. Deviation from
//! Mitsuba 3's `volpath`: it samples one channel per path and divides by that channel's density
//! alone (same expectation, more variance in chromatic media). Every collision of a homogeneous
//! medium is real (the majorant is `σt`), so there are no null collisions.
//!
//! Shadow rays take the transmittance `e^{−σt d}` in closed form (ratio tracking with the
//! homogeneous majorant `σt` has exactly this expectation; its estimate is 0 or 1).
//!
//! # Phase functions
//!
//! Henyey–Greenstein (1941) with Mitsuba 3's convention: `ω_o` points back along the incoming
//! ray, `ω_i` is the scattered direction, and
//!
//! ```text
//! p(ω_o, ω_i) = (1 − g²) / (4π (1 + g² + 2g (ω_o·ω_i))^{3/2})
//! ```
//!
//! so `g > 0` scatters forward (`ω_i ≈ −ω_o`); `g = 0` is `isotropic`, `1 / 4π`. Sampled
//! exactly by inverting its CDF in the cosine (the sample's weight is 1).

use crate::math::Rng;
use crate::scene::grid::{DensityGrid, MAX_TRACKING_STEPS};
use glam::Vec3;
use std::f32::consts::PI;
use std::sync::Arc;

/// Index of "no medium" (vacuum) wherever a medium index is stored.
pub const NO_MEDIUM: u32 = u32::MAX;

/// A medium: extinction and scattering coefficients (per unit length, RGB, `scale` applied),
/// a Henyey–Greenstein phase function, and for a heterogeneous medium a density grid that
/// multiplies both.
#[derive(Clone, Debug, PartialEq)]
pub struct Medium {
    /// Extinction `σt = σa + σs`, each channel ≥ 0 (grey with a density grid).
    pub sigma_t: Vec3,
    /// Scattering `σs = albedo ⊙ σt`, each channel in `[0, σt]`.
    pub sigma_s: Vec3,
    /// Henyey–Greenstein asymmetry in `(−1, 1)` (0: isotropic).
    pub g: f32,
    /// Heterogeneous: `σt(x) = σt · d(x)`, `σs(x) = σs · d(x)` with the grid's density `d`
    /// (Mitsuba's `heterogeneous` with a `gridvolume`); free flights by delta tracking and
    /// transmittance by ratio tracking against the majorant `σt · max d` (Woodcock et al.
    /// 1965; Novák et al. 2014).
    pub density: Option<Arc<DensityGrid>>,
}

/// Which media lie on either side of a shape that bounds media (Mitsuba's `interior` and
/// `exterior`; [`NO_MEDIUM`] where one is not given).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MediumInterface {
    /// The medium behind the surface (against its geometric normal).
    pub interior: u32,
    /// The medium in front of it (along its geometric normal).
    pub exterior: u32,
}

impl MediumInterface {
    /// The medium a ray with direction `d` enters when it crosses the surface with geometric
    /// normal `ng` (Mitsuba's `target_medium`: exterior where `d · ng > 0`).
    #[inline]
    pub fn target(&self, d: Vec3, ng: Vec3) -> u32 {
        if d.dot(ng) > 0.0 {
            self.exterior
        } else {
            self.interior
        }
    }
}

/// The outcome of sampling a free flight along a ray segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FreeFlight {
    /// Distance of the collision; `None` if the ray reaches the end of the segment.
    pub t: Option<f32>,
    /// The path throughput's factor: `σs e^{−σt t} / p(t)` at a collision, `e^{−σt t_max} /
    /// P(pass)` otherwise (zero when passing has probability 0, e.g. an unbounded ray in a
    /// medium that absorbs every channel).
    pub weight: Vec3,
}

/// `e^{−σ t}` per channel, with `e^{−0·∞} = 1` (a channel without extinction transmits
/// everything, even along an unbounded ray).
#[inline]
fn attenuation(sigma: Vec3, t: f32) -> Vec3 {
    let one = |s: f32| if s > 0.0 { (-s * t).exp() } else { 1.0 };
    Vec3::new(one(sigma.x), one(sigma.y), one(sigma.z))
}

impl Medium {
    /// The largest scattering coefficient over the medium and its colour channels:
    /// `max σs`, times the grid's largest density for a heterogeneous medium.
    pub fn max_scattering(&self) -> f32 {
        let d = self.density.as_ref().map_or(1.0, |g| g.max);
        self.sigma_s.max_element() * d
    }

    /// A medium from Mitsuba 3's parameters: `sigma_t`, `albedo` and `scale` (`σt = scale ·
    /// sigma_t`, `σs = albedo ⊙ σt`). Errors name the bad value.
    pub fn new(sigma_t: Vec3, albedo: Vec3, scale: f32, g: f32) -> Result<Self, String> {
        if !(sigma_t.is_finite() && sigma_t.min_element() >= 0.0) {
            return Err(format!("sigma_t {sigma_t} must be finite and >= 0"));
        }
        if !(albedo.is_finite() && albedo.min_element() >= 0.0 && albedo.max_element() <= 1.0) {
            return Err(format!("albedo {albedo} must be in [0, 1]"));
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(format!("scale {scale} must be finite and >= 0"));
        }
        if !(g > -1.0 && g < 1.0) {
            return Err(format!("the phase function's g = {g} must be in (-1, 1)"));
        }
        let sigma_t = sigma_t * scale;
        if !sigma_t.is_finite() {
            return Err(format!("sigma_t times scale ({sigma_t}) overflows"));
        }
        Ok(Medium {
            sigma_t,
            sigma_s: albedo * sigma_t,
            g,
            density: None,
        })
    }

    /// The heterogeneous medium of `grid`: its coefficients scale the grid's density. The
    /// extinction must be grey (delta tracking with one majorant; a chromatic extinction
    /// would need spectral tracking, which is not implemented).
    pub fn with_density(self, grid: DensityGrid) -> Result<Self, String> {
        let s = self.sigma_t;
        if s.x != s.y || s.y != s.z {
            return Err(format!(
                "a heterogeneous medium needs a grey sigma_t (got {s}); give the colour in albedo"
            ));
        }
        if !(s.x * grid.max).is_finite() {
            return Err("sigma_t times the grid's largest density overflows".into());
        }
        Ok(Medium {
            density: Some(Arc::new(grid)),
            ..self
        })
    }

    /// The free flight of the ray `o + t d` over `[0, t_max]` (see [`FreeFlight`]): the
    /// closed form of [`Medium::sample_free_flight`] for a homogeneous medium, delta tracking
    /// through the grid's box for a heterogeneous one (weight: the albedo at a real
    /// collision, 1 when the ray passes).
    pub fn free_flight(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Rng) -> FreeFlight {
        let Some(grid) = &self.density else {
            return self.sample_free_flight(t_max, rng.next_f32(), rng.next_f32());
        };
        let pass = FreeFlight {
            t: None,
            weight: Vec3::ONE,
        };
        let majorant = self.sigma_t.x * grid.max;
        let Some((t0, t1)) = grid.clip(o, d, t_max).filter(|_| majorant > 0.0) else {
            return pass;
        };
        let mut t = t0;
        for _ in 0..MAX_TRACKING_STEPS {
            t -= (1.0 - rng.next_f32()).max(f32::MIN_POSITIVE).ln() / majorant;
            if t >= t1 {
                return pass;
            }
            // A real collision with probability σt(x) / majorant = d(x) / max d.
            if rng.next_f32() * grid.max < grid.eval(o + d * t) {
                let albedo = self.sigma_s / self.sigma_t.x;
                return FreeFlight {
                    t: Some(t),
                    weight: albedo,
                };
            }
        }
        FreeFlight {
            t: None,
            weight: Vec3::ZERO,
        }
    }

    /// An unbiased estimate of the transmittance of the ray `o + t d` over `[0, dist]`:
    /// `e^{−σt dist}` for a homogeneous medium, ratio tracking through the grid's box for a
    /// heterogeneous one (the product of `1 − d(x_i)/max d` over tentative collisions drawn at
    /// the majorant's rate; each factor in `[0, 1]`).
    pub fn transmittance_along(&self, o: Vec3, d: Vec3, dist: f32, rng: &mut Rng) -> Vec3 {
        let Some(grid) = &self.density else {
            return self.transmittance(dist);
        };
        let majorant = self.sigma_t.x * grid.max;
        let Some((t0, t1)) = grid.clip(o, d, dist).filter(|_| majorant > 0.0) else {
            return Vec3::ONE;
        };
        let (mut t, mut tr) = (t0, 1.0f32);
        for _ in 0..MAX_TRACKING_STEPS {
            t -= (1.0 - rng.next_f32()).max(f32::MIN_POSITIVE).ln() / majorant;
            if t >= t1 {
                return Vec3::splat(tr);
            }
            tr *= 1.0 - (grid.eval(o + d * t) / grid.max).min(1.0);
            if tr <= 0.0 {
                break;
            }
        }
        Vec3::ZERO
    }

    /// Transmittance `e^{−σt d}` over a distance `d ≥ 0` (`∞` allowed).
    #[inline]
    pub fn transmittance(&self, d: f32) -> Vec3 {
        attenuation(self.sigma_t, d)
    }

    /// Samples the distance to the next collision along a segment of length `t_max` (`∞`
    /// for an unbounded ray) from two uniform numbers: `u_channel` picks the channel, `u`
    /// the distance (see the module docs).
    pub fn sample_free_flight(&self, t_max: f32, u_channel: f32, u: f32) -> FreeFlight {
        let c = ((u_channel * 3.0) as usize).min(2);
        let sigma_c = self.sigma_t[c];
        let t = if sigma_c > 0.0 {
            -(1.0 - u).max(f32::MIN_POSITIVE).ln() / sigma_c
        } else {
            f32::INFINITY
        };
        if t < t_max {
            let tr = attenuation(self.sigma_t, t);
            let pdf = (self.sigma_t * tr).element_sum() / 3.0;
            let weight = if pdf > 0.0 && pdf.is_finite() {
                self.sigma_s * tr / pdf
            } else {
                Vec3::ZERO
            };
            return FreeFlight { t: Some(t), weight };
        }
        let tr = attenuation(self.sigma_t, t_max);
        let pass = tr.element_sum() / 3.0;
        let weight = if pass > 0.0 { tr / pass } else { Vec3::ZERO };
        FreeFlight { t: None, weight }
    }
}

/// The Henyey–Greenstein density for `cos = ω_o · ω_i` (Mitsuba's convention, see the
/// module docs), per steradian.
#[inline]
pub fn hg_pdf(cos: f32, g: f32) -> f32 {
    let denom = 1.0 + g * g + 2.0 * g * cos.clamp(-1.0, 1.0);
    (1.0 - g * g) / (4.0 * PI * denom * denom.max(0.0).sqrt())
}

/// Samples the Henyey–Greenstein phase function in a frame whose `z` axis is `ω_o` (the
/// direction back along the incoming ray): returns the scattered direction `ω_i` in that
/// frame, from two uniform numbers. Its density is [`hg_pdf`]`(ω_i.z, g)`.
pub fn hg_sample(g: f32, u1: f32, u2: f32) -> Vec3 {
    // The cosine μ of the angle to the forward direction −z, by inverting the CDF of
    // p(μ) ∝ (1 + g² − 2gμ)^{−3/2} (uniform for g = 0).
    let mu = if g.abs() < 1e-3 {
        1.0 - 2.0 * u1
    } else {
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        (1.0 + g * g - s * s) / (2.0 * g)
    }
    .clamp(-1.0, 1.0);
    let sin = (1.0 - mu * mu).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(sin * phi.cos(), sin * phi.sin(), -mu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn hg_integrates_to_one_and_is_isotropic_at_zero() {
        for g in [-0.9f32, -0.3, 0.0, 0.5, 0.95] {
            // ∫ p dω = 2π ∫ p(μ) dμ, midpoint rule on a fine grid (the g = 0.95 peak is
            // 1/(4π(1−g)²·…) wide enough at 200k cells).
            let n = 200_000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let mu = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
                sum += f64::from(hg_pdf(mu as f32, g)) * 2.0 / n as f64;
            }
            let total = 2.0 * std::f64::consts::PI * sum;
            assert!((total - 1.0).abs() < 2e-3, "g {g}: {total}");
        }
        assert!((hg_pdf(0.3, 0.0) - 1.0 / (4.0 * PI)).abs() < 1e-7);
        // Forward scattering: the peak is at ω_i = −ω_o (cos = −1).
        assert!(hg_pdf(-1.0, 0.7) > hg_pdf(1.0, 0.7) * 100.0);
    }

    #[test]
    fn hg_sample_is_unit_and_forward_for_positive_g() {
        let mut rng = Rng::from_keys(1, 2, 3);
        let (mut mean_z, n) = (0.0f64, 100_000);
        for _ in 0..n {
            let w = hg_sample(0.6, rng.next_f32(), rng.next_f32());
            assert!((w.length() - 1.0).abs() < 1e-5);
            mean_z += f64::from(w.z);
        }
        // E[ω_o · ω_i] = −g for HG: the mean cosine to the forward direction is g.
        let mean = mean_z / f64::from(n);
        // Standard error of the mean of a variable in [−1, 1]: below 1/√n.
        assert!((mean + 0.6).abs() < 4.0 / (n as f64).sqrt(), "{mean}");
    }

    /// The free-flight weights are unbiased: `E[weight · 1(collision before t)]` integrates
    /// `σs e^{−σt s}` over `[0, t]`, and `E[weight · 1(pass)] = e^{−σt t_max}`, per channel.
    #[test]
    fn free_flight_weights_have_the_analytic_expectations() {
        let m = Medium::new(Vec3::new(0.5, 1.5, 3.0), Vec3::new(0.9, 0.5, 0.2), 1.0, 0.0)
            .unwrap_or_else(|e| panic!("{e}"));
        let (t_max, split) = (1.2f32, 0.4f32);
        let n = 400_000;
        let mut rng = Rng::from_keys(7, 0, 0);
        let (mut early, mut pass) = (Vec3::ZERO.as_dvec3(), Vec3::ZERO.as_dvec3());
        let (mut early2, mut pass2) = (early, pass);
        for _ in 0..n {
            let f = m.sample_free_flight(t_max, rng.next_f32(), rng.next_f32());
            let w = f.weight.as_dvec3();
            match f.t {
                Some(t) if t < split => {
                    early += w;
                    early2 += w * w;
                }
                Some(_) => {}
                None => {
                    pass += w;
                    pass2 += w * w;
                }
            }
        }
        let nf = f64::from(n);
        for c in 0..3 {
            let (st, ss) = (f64::from(m.sigma_t[c]), f64::from(m.sigma_s[c]));
            let want_early = ss / st * (1.0 - (-st * f64::from(split)).exp());
            let want_pass = (-st * f64::from(t_max)).exp();
            for (sum, sum2, want, what) in [
                (early[c], early2[c], want_early, "collision"),
                (pass[c], pass2[c], want_pass, "pass"),
            ] {
                let mean = sum / nf;
                let se = ((sum2 / nf - mean * mean).max(0.0) / nf).sqrt();
                // 6 standard errors over 6 tests: a false alarm has probability < 1e-8.
                assert!(
                    (mean - want).abs() < 6.0 * se + 1e-6,
                    "channel {c} {what}: {mean} against {want} (se {se})"
                );
            }
        }
    }

    #[test]
    fn grey_media_weigh_by_the_albedo_and_channels_without_extinction_pass() {
        let m = Medium::new(Vec3::splat(2.0), Vec3::splat(0.7), 0.5, 0.3)
            .unwrap_or_else(|e| panic!("{e}"));
        let f = m.sample_free_flight(f32::INFINITY, 0.5, 0.5);
        assert!(f.t.is_some());
        assert!((f.weight - Vec3::splat(0.7)).abs().max_element() < 1e-6);
        let f = m.sample_free_flight(0.01, 0.5, 0.5);
        assert_eq!(f.t, None);
        assert!((f.weight - Vec3::ONE).abs().max_element() < 1e-6);
        // Only red attenuates: an unbounded ray passes in green and blue.
        let m = Medium::new(Vec3::new(1.0, 0.0, 0.0), Vec3::ONE, 1.0, 0.0)
            .unwrap_or_else(|e| panic!("{e}"));
        let f = m.sample_free_flight(f32::INFINITY, 0.9, 0.5);
        assert_eq!(f.t, None);
        assert_eq!(f.weight, Vec3::new(0.0, 1.5, 1.5));
        assert!(f.weight.is_finite());
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(Medium::new(Vec3::splat(-1.0), Vec3::ONE, 1.0, 0.0).is_err());
        assert!(Medium::new(Vec3::ONE, Vec3::splat(1.5), 1.0, 0.0).is_err());
        assert!(Medium::new(Vec3::ONE, Vec3::ONE, f32::NAN, 0.0).is_err());
        assert!(Medium::new(Vec3::ONE, Vec3::ONE, 1.0, 1.0).is_err());
        assert!(Medium::new(Vec3::splat(f32::MAX), Vec3::ONE, 10.0, 0.0).is_err());
    }
}
