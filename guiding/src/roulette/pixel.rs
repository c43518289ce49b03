//! [`pixel_estimates`]: the pixel values `Î` the weight window compares a path's expected
//! contribution with.
//!
//! ADRRS takes `Î` from an image rendered beforehand. A progressive renderer has its running
//! mean, which after a few samples per pixel is mostly noise: one firefly makes a pixel look
//! bright (its paths are then rouletted hard), a pixel whose few paths all missed the light
//! looks black (its paths are left alone, the missing-estimate rule). The estimate here is the
//! running mean's luminance box-filtered over a `(2r + 1)²` neighbourhood (clipped at the
//! image's border), the noise of one pixel's mean divided by up to `(2r + 1)²`; the bias of the
//! filter (edges blur) only moves work between neighbouring pixels, never the image's
//! expectation. Deviation from ADRRS: the filter, and the running mean instead of a
//! pre-rendered image.

use crate::GuidingError;

/// Per pixel (row-major), the luminance of the mean `sum / passes` box-filtered with radius
/// `radius`, into `out` (cleared first); every value 0 when `passes` is 0. Non-finite sums
/// count as 0, values beyond the `f32` range saturate at `±f32::MAX`.
///
/// # Errors
/// [`GuidingError::LengthMismatch`] if `sum` does not hold `width × height` pixels; `out` is
/// untouched.
pub fn pixel_estimates(
    width: u32,
    height: u32,
    sum: &[[f64; 3]],
    passes: u32,
    radius: u32,
    out: &mut Vec<f32>,
) -> Result<(), GuidingError> {
    let (w, h) = (width as usize, height as usize);
    if sum.len() != w * h {
        return Err(GuidingError::LengthMismatch {
            what: format!("{} pixel sums for a {width} x {height} image", sum.len()),
        });
    }
    out.clear();
    if passes == 0 {
        out.resize(w * h, 0.0);
        return Ok(());
    }
    let inv = 1.0 / f64::from(passes);
    let y: Vec<f64> = sum
        .iter()
        .map(|s| finite_or_zero(luminance_f64(*s) * inv))
        .collect();
    box_filter(w, h, &y, radius as usize, out);
    Ok(())
}

/// Per pixel (row-major), the variance `σ²` of one sample (one pass) of the pixel, estimated
/// from its sums `sum` and sums of squares `sum2` over `passes` passes as the luminance-weighted
/// mean of the channels' variances `Σ_c w_c (S2_c − S_c²/n)/(n − 1)` (the cross-channel
/// covariances of the luminance's variance are left out), box-filtered with radius `radius`
/// as [`pixel_estimates`], into `out`; every value 0 below 2 passes.
///
/// # Errors
/// [`GuidingError::LengthMismatch`] if `sum` or `sum2` does not hold `width × height` pixels;
/// `out` is untouched.
pub fn pixel_variances(
    width: u32,
    height: u32,
    sum: &[[f64; 3]],
    sum2: &[[f64; 3]],
    passes: u32,
    radius: u32,
    out: &mut Vec<f32>,
) -> Result<(), GuidingError> {
    let (w, h) = (width as usize, height as usize);
    if sum.len() != w * h || sum2.len() != w * h {
        return Err(GuidingError::LengthMismatch {
            what: format!(
                "{} pixel sums, {} sums of squares for a {width} x {height} image",
                sum.len(),
                sum2.len()
            ),
        });
    }
    out.clear();
    if passes < 2 {
        out.resize(w * h, 0.0);
        return Ok(());
    }
    let n = f64::from(passes);
    let v: Vec<f64> = sum
        .iter()
        .zip(sum2)
        .map(|(s, s2)| {
            let var = [0, 1, 2].map(|c| ((s2[c] - s[c] * s[c] / n) / (n - 1.0)).max(0.0));
            finite_or_zero(luminance_f64(var))
        })
        .collect();
    box_filter(w, h, &v, radius as usize, out);
    Ok(())
}

/// Rec. 709 luminance in `f64`.
fn luminance_f64(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

fn finite_or_zero(x: f64) -> f64 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}

/// The `(2r + 1)²` box mean of `values` (a `w × h` image, row-major; clipped at the border,
/// divided by the pixels inside) into `out` (resized to `w·h`): separable, through prefix sums,
/// rows then columns.
fn box_filter(w: usize, h: usize, values: &[f64], r: usize, out: &mut Vec<f32>) {
    let mut rows = vec![0.0f64; w * h];
    let mut prefix = vec![0.0f64; w.max(h) + 1];
    for row in 0..h {
        for x in 0..w {
            prefix[x + 1] = prefix[x] + values[row * w + x];
        }
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), x.saturating_add(r + 1).min(w));
            rows[row * w + x] = (prefix[b] - prefix[a]) / (b - a) as f64;
        }
    }
    out.clear();
    out.resize(w * h, 0.0);
    for x in 0..w {
        for row in 0..h {
            prefix[row + 1] = prefix[row] + rows[row * w + x];
        }
        for row in 0..h {
            let (a, b) = (row.saturating_sub(r), row.saturating_add(r + 1).min(h));
            // Saturated to the f32 range: sums beyond it give f32::MAX, not infinity.
            let mean = (prefix[b] - prefix[a]) / (b - a) as f64;
            out[row * w + x] = mean.clamp(-f64::from(f32::MAX), f64::from(f32::MAX)) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter written out on a 3 × 2 image with radius 1: each value the mean of the
    /// pixels' means within one pixel (clipped), in luminance.
    #[test]
    fn box_filtered_means_written_out() {
        // Grey pixels, luminance = value; sums of 2 passes.
        let means = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
        let sum: Vec<[f64; 3]> = means.iter().map(|&m| [2.0 * f64::from(m); 3]).collect();
        let mut out = Vec::new();
        pixel_estimates(3, 2, &sum, 2, 1, &mut out).unwrap();
        let expect = [
            (1.0 + 2.0 + 4.0 + 5.0) / 4.0,
            (1.0 + 2.0 + 3.0 + 4.0 + 5.0 + 6.0) / 6.0,
            (2.0 + 3.0 + 5.0 + 6.0) / 4.0,
        ];
        for x in 0..3 {
            for row in 0..2 {
                assert!((out[row * 3 + x] - expect[x]).abs() < 1e-6, "{out:?}");
            }
        }
        pixel_estimates(3, 2, &sum, 2, 0, &mut out).unwrap();
        for (o, m) in out.iter().zip(means) {
            assert!((o - m).abs() < 1e-6);
        }
        // Variances: two passes of 1 and 3 (grey): σ² = (10 − 16/2)/1 = 2 per pixel.
        let (s1, s2) = ([[4.0; 3]; 6], [[10.0; 3]; 6]);
        pixel_variances(3, 2, &s1, &s2, 2, 1, &mut out).unwrap();
        assert!(out.iter().all(|v| (v - 2.0).abs() < 1e-6), "{out:?}");
        pixel_variances(3, 2, &s1, &s2, 1, 1, &mut out).unwrap();
        assert!(out.iter().all(|&v| v == 0.0));
        assert!(pixel_variances(3, 2, &s1, &s2[..5], 2, 1, &mut out).is_err());
        // Colour goes through the luminance.
        pixel_estimates(1, 1, &[[1.0, 0.0, 0.0]], 1, 2, &mut out).unwrap();
        assert!((out[0] - 0.2126).abs() < 1e-6);
    }

    #[test]
    fn no_passes_and_bad_input() {
        let mut out = vec![7.0];
        pixel_estimates(2, 1, &[[1.0; 3]; 2], 0, 1, &mut out).unwrap();
        assert_eq!(out, [0.0, 0.0]);
        assert!(pixel_estimates(2, 2, &[[1.0; 3]; 2], 1, 1, &mut out).is_err());
        assert_eq!(out, [0.0, 0.0]);
        // Sums beyond the f32 range saturate (found by the c_api fuzz target: infinities).
        pixel_estimates(2, 1, &[[1e39; 3], [-1e39; 3]], 1, 0, &mut out).unwrap();
        assert_eq!(out, [f32::MAX, -f32::MAX]);
        pixel_variances(1, 1, &[[0.0; 3]], &[[1e300; 3]], 2, 0, &mut out).unwrap();
        assert_eq!(out, [f32::MAX]);
        pixel_estimates(2, 1, &[[f64::NAN; 3], [2.0; 3]], 1, 0, &mut out).unwrap();
        assert_eq!(out[0], 0.0);
        assert!((out[1] - 2.0).abs() < 1e-6);
    }
}
