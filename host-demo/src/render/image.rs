//! Rendered images (per-pixel means with the variance of each mean, accumulated pass by pass)
//! and what the render that made them measured.

use glam::Vec3;
use std::time::Duration;

/// What the driver measured over a render.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    /// Passes (samples per pixel) rendered.
    pub passes: u32,
    /// Wall time of the whole render (passes and what the strategy does between them).
    pub wall: Duration,
    /// Wall time of the passes' tracing alone.
    pub trace: Duration,
    /// Rays traced: camera and continuation rays plus shadow rays.
    pub rays: u64,
    /// Scattering points inside media (vertices with a phase function).
    pub medium_vertices: u64,
    /// The NEE stage ran (NEE on, and the scene has an emitter NEE can sample).
    pub nee: bool,
    /// What guided roulette and splitting did (`--rr guided`).
    pub roulette: Option<crate::render::roulette::RouletteStats>,
}

/// A rendered image plus per-pixel variance information for statistical tests.
#[derive(Clone, Debug)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel estimates (mean over samples), row-major.
    pub pixels: Vec<[f32; 3]>,
    /// Estimated variance of each pixel estimate (sample variance / spp), row-major.
    pub var_of_mean: Vec<[f32; 3]>,
}

impl Image {
    /// Mean RGB over all pixels.
    pub fn mean(&self) -> [f64; 3] {
        let mut m = [0.0f64; 3];
        for p in &self.pixels {
            for c in 0..3 {
                m[c] += p[c] as f64;
            }
        }
        m.map(|v| v / self.pixels.len().max(1) as f64)
    }

    /// Standard error of [`Image::mean`], from the per-pixel sample variances (pixels are
    /// independent, so `Var(mean) = sum_p Var(pixel_p) / P^2`).
    pub fn mean_std_error(&self) -> [f64; 3] {
        let mut v = [0.0f64; 3];
        for p in &self.var_of_mean {
            for c in 0..3 {
                v[c] += p[c] as f64;
            }
        }
        let n = self.var_of_mean.len().max(1) as f64;
        v.map(|x| x.sqrt() / n)
    }

    /// True if every pixel value is finite and non-negative.
    pub fn all_finite_non_negative(&self) -> bool {
        self.pixels
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0))
    }
}

/// Adds one pass's radiance of a block to the per-pixel sums (non-finite samples count as 0).
pub(crate) fn accumulate(sum: &mut [[f64; 3]], sum2: &mut [[f64; 3]], radiance: &[Vec3]) {
    for (k, l) in radiance.iter().enumerate() {
        for c in 0..3 {
            let v = if l[c].is_finite() { l[c] as f64 } else { 0.0 };
            sum[k][c] += v;
            sum2[k][c] += v * v;
        }
    }
}

/// Per-pixel mean and variance of the mean from the running sums over `passes` samples.
/// The mean of `passes` passes from their per-pixel sums (what an efficiency trial weighs
/// its passes by: the image before the trial); no passes count as one.
pub(crate) fn mean_image(sum: &[[f64; 3]], passes: u32) -> Vec<[f32; 3]> {
    let n = f64::from(passes.max(1));
    sum.iter().map(|s| s.map(|x| (x / n) as f32)).collect()
}

pub(crate) fn finish_image(
    width: u32,
    height: u32,
    passes: u32,
    sum: &[[f64; 3]],
    sum2: &[[f64; 3]],
) -> Image {
    let n = passes.max(1) as f64;
    let pixels = sum.iter().map(|s| s.map(|v| (v / n) as f32)).collect();
    let var_of_mean = sum
        .iter()
        .zip(sum2)
        .map(|(s, s2)| {
            let mut v = [0.0f32; 3];
            for c in 0..3 {
                let mean = s[c] / n;
                let var = if n > 1.0 {
                    ((s2[c] - n * mean * mean) / (n - 1.0)).max(0.0)
                } else {
                    0.0
                };
                v[c] = (var / n) as f32;
            }
            v
        })
        .collect();
    Image {
        width,
        height,
        pixels,
        var_of_mean,
    }
}
