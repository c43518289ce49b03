//! Emitters besides area lights: `point`, `constant` (uniform environment) and `envmap`
//! (lat-long EXR environment, importance-sampled by a piecewise-constant 2D distribution).
//!
//! Conventions follow Mitsuba 3:
//!
//! * `envmap` maps a local direction `d` to `u = atan2(d.x, −d.z) / 2π`, `v = acos(d.y) / π`;
//!   lookups are bilinear with texel centres at `u = (j + ½)/W` (wrapping) and rows at
//!   `v = i/(H − 1)` (the first and last rows sit on the poles), scaled by `scale`;
//!   `to_world` must be a rotation.
//! * Deviation: Mitsuba samples the map with a piecewise-bilinear warp; here each bilinear
//!   cell gets a constant density proportional to the mean of its four corner luminances
//!   (the exact integral of the bilinear patch) times `sin θ` at the cell centre. The density is
//!   positive wherever the map is, so NEE alone is unbiased; the pdf is exact for this sampler.
//! * `constant` is sampled uniformly over the sphere (pdf `1/4π`) like Mitsuba's.
//! * `point` is a delta light: only NEE reaches it (`pt` renders no light from it).

use crate::math::sample_uniform_sphere;
use glam::{Mat3, Vec3};
use std::f32::consts::PI;

/// Rec. 709 luminance (Mitsuba's `luminance`).
pub fn luminance(c: Vec3) -> f32 {
    0.212_671 * c.x + 0.715_160 * c.y + 0.072_169 * c.z
}

/// A piecewise-constant distribution on `nu × nv` cells of the unit square (Pharr et al.,
/// *PBRT* 3rd ed. §13.6.7: marginal over rows, conditional within each row).
#[derive(Clone, Debug)]
pub struct Distribution2D {
    nu: usize,
    nv: usize,
    /// Per row, the conditional CDF over its `nu` cells (`nu + 1` entries, first 0, last 1).
    cond: Vec<f32>,
    /// Marginal CDF over rows (`nv + 1` entries).
    marg: Vec<f32>,
    /// Probability of each cell.
    prob: Vec<f32>,
}

fn cdf_of(w: &[f64]) -> (Vec<f32>, f64) {
    let total: f64 = w.iter().sum();
    let mut c = Vec::with_capacity(w.len() + 1);
    let mut acc = 0.0f64;
    c.push(0.0);
    for &x in w {
        acc += x;
        c.push(if total > 0.0 {
            (acc / total) as f32
        } else {
            0.0
        });
    }
    if let Some(l) = c.last_mut() {
        *l = 1.0;
    }
    (c, total)
}

/// Index `k` with `cdf[k] <= u < cdf[k + 1]` (skipping empty cells) and the remapped `u`.
fn search(cdf: &[f32], u: f32) -> (usize, f32) {
    let n = cdf.len() - 1;
    let k = cdf
        .partition_point(|&c| c <= u)
        .saturating_sub(1)
        .min(n - 1);
    let w = cdf[k + 1] - cdf[k];
    let r = if w > 0.0 {
        ((u - cdf[k]) / w).clamp(0.0, 1.0 - f32::EPSILON)
    } else {
        0.5
    };
    (k, r)
}

impl Distribution2D {
    /// Builds the distribution from non-negative cell weights (row-major, `nv` rows of `nu`);
    /// `None` if every weight is zero or one is negative or not finite.
    pub fn new(weights: &[f64], nu: usize, nv: usize) -> Option<Self> {
        if nu == 0 || nv == 0 || weights.len() != nu * nv {
            return None;
        }
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return None;
        }
        let mut cond = Vec::with_capacity(nv * (nu + 1));
        let mut rows = Vec::with_capacity(nv);
        for r in weights.chunks(nu) {
            let (c, t) = cdf_of(r);
            cond.extend(c);
            rows.push(t);
        }
        let (marg, total) = cdf_of(&rows);
        if total <= 0.0 {
            return None;
        }
        let prob = weights.iter().map(|w| (w / total) as f32).collect();
        Some(Self {
            nu,
            nv,
            cond,
            marg,
            prob,
        })
    }

    /// Samples a cell and a uniform point in it: `(column, row, (fu, fv) in the cell, cell
    /// probability)`.
    pub fn sample(&self, u1: f32, u2: f32) -> (usize, usize, (f32, f32), f32) {
        let (row, fv) = search(&self.marg, u2);
        let c = &self.cond[row * (self.nu + 1)..(row + 1) * (self.nu + 1)];
        let (col, fu) = search(c, u1);
        (col, row, (fu, fv), self.prob[row * self.nu + col])
    }

    /// Probability of cell `(col, row)`.
    pub fn prob(&self, col: usize, row: usize) -> f32 {
        self.prob[row.min(self.nv - 1) * self.nu + col.min(self.nu - 1)]
    }
}

/// A lat-long environment map (see the module docs for the conventions).
#[derive(Clone, Debug)]
pub struct EnvMap {
    width: usize,
    height: usize,
    /// `height` rows of `width` linear RGB texels, already multiplied by `scale`.
    texels: Vec<Vec3>,
    dist: Distribution2D,
}

impl EnvMap {
    /// Builds the map from RGB texels (row-major, top row = `v = 0` = `+y`). Errors name what is
    /// wrong (size below 2 × 3, a negative or non-finite texel, an all-black map).
    pub fn new(width: usize, height: usize, rgb: &[[f32; 3]], scale: f32) -> Result<Self, String> {
        if width < 2 || height < 3 || rgb.len() != width * height {
            return Err(format!(
                "environment map must be at least 2x3 texels (is {width}x{height})"
            ));
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(format!("scale {scale} must be finite and non-negative"));
        }
        if let Some(i) = rgb
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite() && *c >= 0.0))
        {
            return Err(format!(
                "texel ({}, {}) is negative or not finite: {:?}",
                i % width,
                i / width,
                rgb[i]
            ));
        }
        let texels: Vec<Vec3> = rgb.iter().map(|p| Vec3::from(*p) * scale).collect();
        let (nu, nv) = (width, height - 1);
        let mut w = vec![0.0f64; nu * nv];
        for iy in 0..nv {
            let sin_t = ((iy as f64 + 0.5) / nv as f64 * std::f64::consts::PI).sin();
            for ix in 0..nu {
                let jx = (ix + 1) % width;
                let l = [
                    texels[iy * width + ix],
                    texels[iy * width + jx],
                    texels[(iy + 1) * width + ix],
                    texels[(iy + 1) * width + jx],
                ]
                .iter()
                .map(|&c| f64::from(luminance(c)).max(0.0))
                .sum::<f64>();
                w[iy * nu + ix] = 0.25 * l * sin_t;
            }
        }
        let dist = Distribution2D::new(&w, nu, nv)
            .ok_or_else(|| "environment map is black (nothing to sample)".to_string())?;
        Ok(Self {
            width,
            height,
            texels,
            dist,
        })
    }

    /// `(u', y)`: the half-texel-shifted column coordinate in `[0, W)` and the row coordinate
    /// in `[0, H − 1]` of a local direction.
    fn coords(&self, d: Vec3) -> (f32, f32) {
        let u = d.x.atan2(-d.z) * (0.5 / PI);
        let v = d.y.clamp(-1.0, 1.0).acos() / PI;
        let mut us = u - 0.5 / self.width as f32;
        us -= us.floor();
        (us * self.width as f32, v * (self.height - 1) as f32)
    }

    /// Bilinear radiance towards local direction `d` (unit).
    pub fn eval(&self, d: Vec3) -> Vec3 {
        let (x, y) = self.coords(d);
        let ix = (x as usize).min(self.width - 1);
        let iy = (y as usize).min(self.height - 2);
        let (wx, wy) = (
            (x - ix as f32).clamp(0.0, 1.0),
            (y - iy as f32).clamp(0.0, 1.0),
        );
        let jx = (ix + 1) % self.width;
        let t = |r: usize, c: usize| self.texels[r * self.width + c];
        let top = t(iy, ix) * (1.0 - wx) + t(iy, jx) * wx;
        let bot = t(iy + 1, ix) * (1.0 - wx) + t(iy + 1, jx) * wx;
        top * (1.0 - wy) + bot * wy
    }

    /// Samples a local direction; returns it with its solid-angle pdf.
    pub fn sample(&self, u1: f32, u2: f32) -> Option<(Vec3, f32)> {
        let (col, row, (fu, fv), p) = self.dist.sample(u1, u2);
        let us = (col as f32 + fu) / self.width as f32;
        let v = (row as f32 + fv) / (self.height - 1) as f32;
        let u = us + 0.5 / self.width as f32;
        let (theta, phi) = (v * PI, u * 2.0 * PI);
        let sin_t = theta.sin();
        if sin_t <= 0.0 || p <= 0.0 {
            return None;
        }
        let d = Vec3::new(phi.sin() * sin_t, theta.cos(), -phi.cos() * sin_t);
        let pdf_uv = p * (self.width * (self.height - 1)) as f32;
        Some((d, pdf_uv / (2.0 * PI * PI * sin_t)))
    }

    /// Solid-angle pdf of [`EnvMap::sample`] for the local direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        let (x, y) = self.coords(d);
        let p = self.dist.prob(x as usize, y as usize);
        let sin_t = (d.x * d.x + d.z * d.z).sqrt();
        if sin_t <= 1e-7 {
            return 0.0;
        }
        p * (self.width * (self.height - 1)) as f32 / (2.0 * PI * PI * sin_t)
    }
}

/// The environment: what a ray that leaves the scene sees.
#[derive(Clone, Debug)]
pub enum Environment {
    /// Uniform radiance (Mitsuba `constant`).
    Constant(Vec3),
    /// Lat-long map with its world-to-local rotation (Mitsuba `envmap`).
    Map {
        /// The map.
        map: Box<EnvMap>,
        /// Local-to-world rotation.
        to_world: Mat3,
    },
}

impl Environment {
    /// Radiance arriving from world direction `d` (unit, pointing away from the scene).
    pub fn eval(&self, d: Vec3) -> Vec3 {
        match self {
            Environment::Constant(l) => *l,
            Environment::Map { map, to_world } => map.eval(to_world.transpose() * d),
        }
    }

    /// Solid-angle pdf of [`Environment::sample`] (without the emitter selection).
    pub fn pdf(&self, d: Vec3) -> f32 {
        match self {
            Environment::Constant(_) => 1.0 / (4.0 * PI),
            Environment::Map { map, to_world } => map.pdf(to_world.transpose() * d),
        }
    }

    /// Samples a world direction: `(direction, radiance, pdf)`.
    pub fn sample(&self, u1: f32, u2: f32) -> Option<(Vec3, Vec3, f32)> {
        match self {
            Environment::Constant(l) => Some((sample_uniform_sphere(u1, u2), *l, 1.0 / (4.0 * PI))),
            Environment::Map { map, to_world } => {
                let (d, pdf) = map.sample(u1, u2)?;
                Some(((*to_world * d).normalize(), map.eval(d), pdf))
            }
        }
    }
}

/// An isotropic point light (Mitsuba `point`).
#[derive(Clone, Copy, Debug)]
pub struct PointLight {
    /// Position.
    pub position: Vec3,
    /// Radiant intensity (W/sr per channel).
    pub intensity: Vec3,
}

/// An NEE sample towards an emitter, seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct EmitterSample {
    /// Unit direction from the shading point towards the emitter.
    pub wo: Vec3,
    /// Distance to the sampled point (`∞` for the environment).
    pub dist: f32,
    /// Sampled point (area and point lights).
    pub p: Vec3,
    /// Emitting normal at `p` (area lights; zero otherwise).
    pub n: Vec3,
    /// Incident radiance along `wo` (area, environment) or `I / dist²` (point light).
    pub radiance: Vec3,
    /// Solid-angle pdf including the emitter selection; for a delta (point) light the
    /// selection probability alone.
    pub pdf: f32,
    /// Delta light: no MIS (the BSDF can never hit it).
    pub delta: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn test_map() -> EnvMap {
        let (w, h) = (8, 5);
        let rgb: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x == 2 && y == 1 {
                    [50.0, 40.0, 30.0]
                } else {
                    [0.2 + 0.1 * y as f32, 0.3, 0.1 * x as f32]
                }
            })
            .collect();
        EnvMap::new(w, h, &rgb, 2.0).expect("valid map")
    }

    /// The sampled pdf matches `pdf()`, the pdf integrates to 1 over the sphere, and the
    /// importance-sampled estimate of ∫L dω agrees with a uniform-sphere estimate.
    #[test]
    fn envmap_sampling_is_consistent() {
        let m = test_map();
        let mut rng = Rng::from_keys(3, 1, 4);
        let n = 200_000;
        let (mut int_pdf, mut is_est, mut uni_est) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..n {
            let (d, p) = m.sample(rng.next_f32(), rng.next_f32()).expect("sample");
            assert!((d.length() - 1.0).abs() < 1e-4);
            let q = m.pdf(d);
            assert!((p - q).abs() <= 2e-3 * p, "{p} vs {q} at {d}");
            is_est += f64::from(luminance(m.eval(d)) / p);
            let du = sample_uniform_sphere(rng.next_f32(), rng.next_f32());
            int_pdf += f64::from(m.pdf(du)) * 4.0 * std::f64::consts::PI;
            uni_est += f64::from(luminance(m.eval(du))) * 4.0 * std::f64::consts::PI;
        }
        let (int_pdf, is_est, uni_est) =
            (int_pdf / n as f64, is_est / n as f64, uni_est / n as f64);
        assert!((int_pdf - 1.0).abs() < 0.03, "∫pdf = {int_pdf}");
        assert!(
            (is_est - uni_est).abs() < 0.05 * uni_est,
            "{is_est} vs {uni_est}"
        );
    }

    /// Texel centres and poles land where Mitsuba puts them.
    #[test]
    fn envmap_lookup_conventions() {
        let m = test_map();
        // Texel (2, 1): u = 2.5/8, v = 1/4 → θ = π/4, φ = 2π·2.5/8.
        let (theta, phi) = (PI / 4.0, 2.0 * PI * 2.5 / 8.0);
        let d = Vec3::new(
            phi.sin() * theta.sin(),
            theta.cos(),
            -phi.cos() * theta.sin(),
        );
        assert!(
            (m.eval(d) - Vec3::new(100.0, 80.0, 60.0))
                .abs()
                .max_element()
                < 1e-2
        );
        // +y is the pole row 0: [0.2, 0.3, 0.1 x] · scale 2 there, so green is 0.6 exactly.
        let top = m.eval(Vec3::Y);
        assert!((top.y - 0.6).abs() < 1e-5, "{top}");
        assert!(EnvMap::new(1, 3, &[[1.0; 3]; 3], 1.0).is_err());
        assert!(EnvMap::new(2, 3, &[[0.0; 3]; 6], 1.0).is_err());
        assert!(EnvMap::new(2, 3, &[[f32::NAN; 3]; 6], 1.0).is_err());
    }
}
