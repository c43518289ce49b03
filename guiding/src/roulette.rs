//! Russian roulette and splitting by a weight window: the rule of adjoint-driven Russian
//! roulette and splitting (ADRRS; Vorba and Křivánek 2016, *Adjoint-Driven Russian Roulette
//! and Splitting in Light Transport Simulation*, §4–5), for a renderer that knows, at a
//! vertex, an estimate `L̂` of the radiance the path will bring back from it and, for its
//! pixel, an estimate `Î` of the pixel's value.
//!
//! A path of throughput `β` at the vertex is expected to add `β·L̂` to its pixel. ADRRS keeps
//! that contribution near the pixel's value: with `m = β·L̂ / Î` the path goes on as
//! **`m` continuations in expectation**, each of weight `β / m`: below 1, Russian roulette with
//! survival probability `m`; above 1, `⌊m⌋` continuations plus one more with probability
//! `m − ⌊m⌋`. Either way `E[k]·β/m = β`: unbiased whatever `L̂` and `Î` are (they only decide
//! where the work goes). The **weight window** leaves paths alone while `m` lies in
//! `[2/(1+s), 2s/(1+s)]` (centred on 1 in the sense of ADRRS's `C_ww = Î/L̂`, with upper over
//! lower bound `s`; the paper uses `s = 5`), so that small errors of the estimates cost nothing.
//!
//! Deviations: splitting is capped at [`WeightWindow::max_split`] continuations (`m` clamped
//! there; unbiased all the same), and where `L̂` or `Î` is not finite and positive (no estimate
//! yet, a black pixel) the rule answers `m = 1` (the path goes on untouched) instead of guessing.

use crate::GuidingError;

/// The window's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightWindow {
    /// `s > 1`: the window's upper bound over its lower bound.
    pub ratio: f32,
    /// The most continuations one vertex may spawn (`≥ 1`; 1: roulette only).
    pub max_split: u32,
}

impl Default for WeightWindow {
    /// ADRRS's `s = 5`; at most 8 continuations per vertex.
    fn default() -> Self {
        Self {
            ratio: 5.0,
            max_split: 8,
        }
    }
}

impl WeightWindow {
    /// The window's settings in their ranges, or the error naming the one that is not.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] unless `ratio > 1` is finite and `max_split ≥ 1`.
    pub fn validate(&self) -> Result<(), GuidingError> {
        if !(self.ratio.is_finite() && self.ratio > 1.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "weight window ratio {} must be finite and > 1",
                self.ratio
            )));
        }
        if self.max_split == 0 {
            return Err(GuidingError::InvalidConfig(
                "weight window max_split must be at least 1".into(),
            ));
        }
        Ok(())
    }

    /// The window `[2/(1+s), 2s/(1+s)]` on `m`.
    #[must_use]
    pub fn bounds(&self) -> (f32, f32) {
        let lower = 2.0 / (1.0 + self.ratio);
        (lower, lower * self.ratio)
    }

    /// `m`, the expected number of continuations of a path of throughput `beta` (luminance, or
    /// the largest channel, as the renderer measures it) at a vertex expected to bring back
    /// `radiance`, for a pixel estimated at `pixel`: `β·L̂/Î` outside the window (at most
    /// `max_split`), 1 inside it and where an estimate is missing. 0 for a path of zero or
    /// non-finite throughput.
    #[must_use]
    pub fn continuations(&self, beta: f32, radiance: f32, pixel: f32) -> f32 {
        if !(beta.is_finite() && beta > 0.0) {
            return 0.0;
        }
        let usable = |x: f32| x.is_finite() && x > 0.0;
        if !(usable(radiance) && usable(pixel)) {
            return 1.0;
        }
        let m = beta * radiance / pixel;
        let (lower, upper) = self.bounds();
        if !m.is_finite() {
            return self.max_split as f32;
        }
        if (lower..=upper).contains(&m) {
            1.0
        } else {
            m.min(self.max_split as f32)
        }
    }

    /// [`Self::continuations`] for every row: `out[i]` for `beta[i]`, `radiance[i]`,
    /// `pixel[i]`.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the slices differ in length; `out` is untouched.
    pub fn continuations_batch(
        &self,
        beta: &[f32],
        radiance: &[f32],
        pixel: &[f32],
        out: &mut Vec<f32>,
    ) -> Result<(), GuidingError> {
        if radiance.len() != beta.len() || pixel.len() != beta.len() {
            return Err(GuidingError::LengthMismatch {
                what: format!(
                    "{} throughputs, {} radiances, {} pixel estimates",
                    beta.len(),
                    radiance.len(),
                    pixel.len()
                ),
            });
        }
        out.clear();
        out.extend((0..beta.len()).map(|i| self.continuations(beta[i], radiance[i], pixel[i])));
        Ok(())
    }
}

/// How many continuations to spawn for an expected `m` and a uniform `u ∈ [0, 1)`:
/// `⌊m⌋ + [u < m − ⌊m⌋]`, so that `E[k] = m`; each carries `β / m`.
#[must_use]
pub fn continuation_count(m: f32, u: f32) -> u32 {
    if !(m.is_finite() && m > 0.0) {
        return 0;
    }
    let whole = m.floor();
    (whole as u32).saturating_add(u32::from(u < m - whole))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule written out: `m = β·L̂/Î` outside `[2/(1+s), 2s/(1+s)]`, 1 inside.
    #[test]
    fn the_window_rule_written_out() {
        let w = WeightWindow::default();
        let (lo, hi) = w.bounds();
        assert!((lo - 2.0 / 6.0).abs() < 1e-7 && (hi - 10.0 / 6.0).abs() < 1e-6);
        // β·L̂/Î = 0.5 · 0.2 / 1 = 0.1 < 1/3: roulette, survival 0.1.
        assert!((w.continuations(0.5, 0.2, 1.0) - 0.1).abs() < 1e-7);
        // 2 · 3 / 2 = 3 > 5/3: three continuations.
        assert!((w.continuations(2.0, 3.0, 2.0) - 3.0).abs() < 1e-6);
        // 1 · 1.2 / 1 inside the window: untouched.
        assert_eq!(w.continuations(1.0, 1.2, 1.0), 1.0);
        assert_eq!(w.continuations(1.0, 0.34, 1.0), 1.0);
        // Capped at max_split.
        assert_eq!(w.continuations(100.0, 1.0, 1.0), 8.0);
        assert_eq!(w.continuations(f32::MAX, f32::MAX, 1e-30), 8.0);
    }

    #[test]
    fn missing_estimates_leave_the_path_alone_and_dead_paths_stay_dead() {
        let w = WeightWindow::default();
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(w.continuations(0.5, bad, 1.0), 1.0);
            assert_eq!(w.continuations(0.5, 1.0, bad), 1.0);
            assert_eq!(w.continuations(bad, 1.0, 1.0), 0.0);
        }
    }

    /// The mean count over `n` stratified uniforms (exact up to one stratum, `1/n`).
    fn mean_count(count: impl Fn(f32, f32) -> u32, m: f32, n: u32) -> f64 {
        (0..n)
            .map(|i| f64::from(count(m, (i as f32 + 0.5) / n as f32)))
            .sum::<f64>()
            / f64::from(n)
    }

    /// `E[k] = m` over the uniform `u` (the count is `⌊m⌋ + 1` on a share `m − ⌊m⌋` of
    /// `[0, 1)`), so `E[k]·β/m = β`; a count without the fraction (`⌊m⌋`) fails the same check.
    #[test]
    fn the_expected_count_is_m() {
        let n = 1 << 16;
        let tolerance = 1.0 / f64::from(n) + 1e-6;
        let floor_only = |m: f32, _u: f32| m.floor() as u32;
        for m in [0.01f32, 0.3, 0.999, 1.0, 1.5, 2.75, 7.99, 8.0] {
            let mean = mean_count(continuation_count, m, n);
            assert!((mean - f64::from(m)).abs() <= tolerance, "m {m}: {mean}");
            if m.fract() > 0.0 {
                let wrong = mean_count(floor_only, m, n);
                assert!((wrong - f64::from(m)).abs() > tolerance, "m {m}: {wrong}");
            }
        }
        assert_eq!(continuation_count(0.0, 0.0), 0);
        assert_eq!(continuation_count(f32::NAN, 0.0), 0);
    }

    #[test]
    fn batches_match_rows_and_bad_settings_are_refused() {
        let w = WeightWindow::default();
        let (beta, radiance, pixel) = ([0.5, 2.0, 1.0], [0.2, 3.0, 1.2], [1.0, 2.0, 1.0]);
        let mut out = Vec::new();
        w.continuations_batch(&beta, &radiance, &pixel, &mut out)
            .unwrap();
        for i in 0..3 {
            assert_eq!(out[i], w.continuations(beta[i], radiance[i], pixel[i]));
        }
        assert!(w
            .continuations_batch(&beta, &radiance[..2], &pixel, &mut out)
            .is_err());
        assert_eq!(out.len(), 3);
        for bad in [
            WeightWindow { ratio: 1.0, ..w },
            WeightWindow {
                ratio: f32::NAN,
                ..w
            },
            WeightWindow { max_split: 0, ..w },
        ] {
            assert!(bad.validate().is_err());
        }
        assert!(w.validate().is_ok());
    }
}
