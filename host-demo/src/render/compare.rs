//! Image error metrics of `host-demo compare IMAGE.exr REFERENCE.exr`.
//!
//! Per channel `c` of pixel `p`, with image `I` and reference `R`:
//!
//! * **relMSE** (Müller et al. 2019 and the NPM / NASG / DF papers): the pixel error is the
//!   channel mean of `(I − R)² / (R² + ε)`, `ε = 0.01`; the highest `⌊0.001·P⌋` pixel errors
//!   (0.1 % of the `P` pixels) are dropped and the rest averaged ("trimmed"). The untrimmed
//!   mean is reported too.
//! * **MAPE** (NASG, Huang et al. 2024): the mean over pixels and channels of
//!   `|I − R| / (R + ε)`, `ε = 0.01`, untrimmed.
//!
//! Deviation: the denominators use `|R|` so that a (non-physical) negative reference value
//! cannot make an error negative; for the non-negative images a renderer writes this is the
//! papers' formula.

use crate::error::{Error, Result};
use crate::scene::load::exr::RgbImage;

/// The `ε` of both metrics.
pub const EPSILON: f64 = 0.01;
/// Fraction of the highest per-pixel relMSE values dropped.
pub const TRIM_FRACTION: f64 = 0.001;

/// Result of [`compare`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Metrics {
    /// Trimmed relMSE (the papers' number).
    pub relmse: f64,
    /// relMSE over all pixels.
    pub relmse_untrimmed: f64,
    /// Mean absolute percentage error (as a fraction, not ×100).
    pub mape: f64,
    /// Pixels compared.
    pub pixels: usize,
    /// Pixels dropped by the trimming.
    pub trimmed: usize,
}

/// Compares `image` against `reference` (same size; every value finite).
pub fn compare(image: &RgbImage, reference: &RgbImage) -> Result<Metrics> {
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(Error::Image(format!(
            "image is {}x{} but the reference is {}x{}",
            image.width, image.height, reference.width, reference.height
        )));
    }
    let n = image.pixels.len();
    if n == 0 || n != reference.pixels.len() {
        return Err(Error::Image("the images have no pixels".into()));
    }
    for (what, img) in [("image", image), ("reference", reference)] {
        if let Some(i) = img
            .pixels
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(Error::Image(format!(
                "{what} pixel ({}, {}) is not finite: {:?}",
                i % img.width,
                i / img.width,
                img.pixels[i]
            )));
        }
    }
    let mut rel = Vec::with_capacity(n);
    let mut ape = 0.0f64;
    for (i, r) in image.pixels.iter().zip(&reference.pixels) {
        let mut e = 0.0f64;
        for c in 0..3 {
            let (iv, rv) = (f64::from(i[c]), f64::from(r[c]));
            let d = iv - rv;
            e += d * d / (rv * rv + EPSILON);
            ape += d.abs() / (rv.abs() + EPSILON);
        }
        rel.push(e / 3.0);
    }
    let untrimmed = rel.iter().sum::<f64>() / n as f64;
    let trimmed = (TRIM_FRACTION * n as f64).floor() as usize;
    rel.sort_by(f64::total_cmp);
    let kept = &rel[..n - trimmed];
    Ok(Metrics {
        relmse: kept.iter().sum::<f64>() / kept.len() as f64,
        relmse_untrimmed: untrimmed,
        mape: ape / (3 * n) as f64,
        pixels: n,
        trimmed,
    })
}
