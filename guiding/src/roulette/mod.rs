//! Russian roulette and splitting by a weight window: the rule of adjoint-driven Russian
//! roulette and splitting (ADRRS; Vorba and Křivánek 2016, *Adjoint-Driven Russian Roulette
//! and Splitting in Light Transport Simulation*, §4–5), for a renderer that knows, at a
//! vertex, an estimate `L̂` of the radiance the path will bring back from it (the reflected
//! radiance `L_r(x, ω_o)`, learned by a [`RadianceGrid`]) and, for its pixel, an estimate `Î`
//! of the pixel's value ([`pixel_estimates`]).
//!
//! A path of throughput `β` at the vertex is expected to add `β·L̂` to its pixel. ADRRS keeps
//! that contribution near the pixel's value: with `m = Y(β ⊙ L̂) / Î` (`Y` the luminance) the
//! path goes on as **`m` continuations in expectation**. Below 1, Russian roulette: it survives
//! with probability `m` and its throughput is divided by `m`. Above 1, splitting: `k = ⌊m⌋ +
//! [u < m − ⌊m⌋]` continuations, each with throughput `β / k`. Both keep every estimate
//! unbiased whatever `L̂` and `Î` are (they only decide where the work goes): roulette because
//! `E[survive]/m = 1`, splitting because the mean of `k ≥ 1` independent continuations is an
//! unbiased estimate for any `k`. The **weight window** leaves paths alone while `m` lies in
//! `[2/(1+s), 2s/(1+s)]` (centred on 1 in the sense of ADRRS's `C_ww = Î/L̂`, with upper over
//! lower bound `s`; the paper uses `s = 5`), so that small errors of the estimates cost
//! nothing. The decision is made at a vertex before its next-event estimation and its
//! direction sampling, so the `k` continuations differ in both.
//!
//! Deviations from the paper:
//! - splitting weights each continuation `1/k` instead of ADRRS's `1/m` (also unbiased, as
//!   above, and the `k` copies then add up to exactly the path's weight);
//! - splitting is capped: at most [`WeightWindow::max_split`] continuations per vertex, and the
//!   renderer passes how many more a path may still spawn ([`WeightWindow::decide`]'s `room`),
//!   so one camera path never becomes more than `1 + room` paths. Capping `k` keeps the `1/k`
//!   weights unbiased;
//! - the survival probability is at least [`WeightWindow::min_survival`]: a survivor's weight
//!   grows at most `1/min_survival`-fold at a vertex, which bounds the firefly that a wrong
//!   estimate (a cell's mean that missed a caustic) can make;
//! - where `L̂` or `Î` is missing (no estimate yet, a black pixel) the path goes on untouched
//!   (`m = 1`) instead of guessing.
//!
//! The efficiency-aware alternative after EARS (Rath et al. 2022), which chooses `m` from the
//! subpath's second moment and variance against the pixel's variance
//! ([`WeightWindow::efficiency_continuations`]), is here too; measured, it did not beat the
//! window (`docs/bench-2026-12-07-roulette`). Neither rule weighs what the pixel's variance
//! already is against what a vertex saves well enough to be right on every scene, so a
//! renderer with a time budget asks its image whether the window pays ([`WindowTrial`]).

pub mod grid;
pub mod pixel;
pub mod trial;

pub use grid::{GridOptions, GridStats, RadianceGrid};
pub use pixel::{pixel_estimates, pixel_variances};
pub use trial::WindowTrial;

use crate::GuidingError;

/// Rec. 709 luminance of linear RGB.
#[inline]
#[must_use]
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// The window's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightWindow {
    /// `s > 1`: the window's upper bound over its lower bound.
    pub ratio: f32,
    /// The most continuations one vertex may spawn (`≥ 1`; 1: roulette only).
    pub max_split: u32,
    /// The least survival probability of roulette, in `(0, 1]`.
    pub min_survival: f32,
}

impl Default for WeightWindow {
    /// ADRRS's `s = 5`; at most 8 continuations per vertex; survival at least 0.05 (a
    /// survivor's weight grows at most 20-fold per vertex).
    fn default() -> Self {
        Self {
            ratio: 5.0,
            max_split: 8,
            min_survival: 0.05,
        }
    }
}

/// What the window decided for one path at one vertex.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Decision {
    /// Continuations to trace from the vertex (0: the path ends here).
    pub count: u32,
    /// The factor on each continuation's throughput: `1/m` after a roulette survival, `1/k`
    /// for `k` split continuations, 1 otherwise.
    pub weight: f32,
}

impl WeightWindow {
    /// The window's settings in their ranges, or the error naming the one that is not.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] unless `ratio > 1` is finite, `max_split ≥ 1` and
    /// `min_survival ∈ (0, 1]`.
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
        if !(self.min_survival > 0.0 && self.min_survival <= 1.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "weight window min_survival {} must lie in (0, 1]",
                self.min_survival
            )));
        }
        Ok(())
    }

    /// The window `[2/(1+s), 2s/(1+s)]` on `m`.
    #[must_use]
    pub fn bounds(&self) -> (f32, f32) {
        let lower = 2.0 / (1.0 + self.ratio);
        (lower, lower * self.ratio)
    }

    /// `m`, the expected number of continuations of a path of throughput `beta` at a vertex
    /// expected to reflect `radiance` towards it, for a pixel estimated at `pixel`
    /// (luminance): `Y(β ⊙ L̂)/Î` outside the window, clamped to
    /// `[min_survival, max_split]`; 1 inside it, and where an estimate is missing (`radiance`
    /// with a negative or non-finite channel, `pixel` not finite and positive). 0 for a path
    /// whose throughput has no finite positive luminance.
    #[must_use]
    pub fn continuations(&self, beta: [f32; 3], radiance: [f32; 3], pixel: f32) -> f32 {
        let y_beta = luminance(beta);
        if !(y_beta.is_finite() && y_beta > 0.0) {
            return 0.0;
        }
        let radiance_ok = (0..3).all(|c| radiance[c].is_finite() && radiance[c] >= 0.0);
        if !(radiance_ok && pixel.is_finite() && pixel > 0.0) {
            return 1.0;
        }
        let weighted = [
            beta[0] * radiance[0],
            beta[1] * radiance[1],
            beta[2] * radiance[2],
        ];
        self.windowed(luminance(weighted) / pixel)
    }

    /// A raw expected count `m ≥ 0` through the window: 1 inside `[2/(1+s), 2s/(1+s)]`, else
    /// clamped to `[min_survival, max_split]` (`max_split` for a non-finite `m`).
    fn windowed(&self, m: f32) -> f32 {
        let (lower, upper) = self.bounds();
        if !m.is_finite() {
            return self.max_split as f32;
        }
        if (lower..=upper).contains(&m) {
            1.0
        } else {
            m.clamp(self.min_survival, self.max_split as f32)
        }
    }

    /// The efficiency-aware `m` (after EARS, Rath et al. 2022, without its cost term), through
    /// the window as [`Self::continuations`]. With `L̂` and `M` the mean and second moment of
    /// the reflected radiance at the vertex (RGB, [`RadianceGrid::estimate`] and
    /// [`RadianceGrid::second_moment`]), `V = M − L̂²` its variance and `σ²` the variance of one
    /// sample of the pixel (luminance-weighted, [`pixel_variances`]):
    ///
    /// - splitting, `m_s = √(Y(β² ⊙ V) / σ²)` when `m_s ≥ 1`;
    /// - else roulette, `m_r = √(Y(β² ⊙ M) / σ²)` when `m_r < 1`;
    /// - else 1.
    ///
    /// Minimising variance × cost of the pixel, `(A + B/q)(C + q·C_x)`, over the factor `q`
    /// applied to the subpath from the vertex gives `q* = √(B/A) · √(C/C_x)`. Roulette with
    /// survival `q` turns the subpath's `β²V` into `β²M/q − β²L̂²` (`B = β²M`); `k` split
    /// copies turn it into `β²V/k` (`B = β²V`): the mean a subpath carries is not noise, and
    /// splitting does not reduce it. EARS takes `B = β²M` for both, which splits paths whose
    /// subpath is large but precise (on the Cornell box: 0.69× the passes of `pt-nee` for the
    /// same image). Deviations: the rest of the pixel `A` is taken as `σ²` (as EARS) and the
    /// cost ratio `C / C_x ≥ 1` as 1 (less splitting than the optimum, never more). Where the
    /// pixel is already precise paths are split rather than killed; where it is noisy,
    /// roulette removes what its variance hardly changes. Missing estimates (a negative or
    /// non-finite mean or moment, `σ²` not finite and positive) leave the path alone; a dead
    /// path (no finite positive luminance of `β`) gets 0.
    #[must_use]
    pub fn efficiency_continuations(
        &self,
        beta: [f32; 3],
        mean: [f32; 3],
        second_moment: [f32; 3],
        pixel_variance: f32,
    ) -> f32 {
        let y_beta = luminance(beta);
        if !(y_beta.is_finite() && y_beta > 0.0) {
            return 0.0;
        }
        let valid = |x: [f32; 3]| (0..3).all(|c| x[c].is_finite() && x[c] >= 0.0);
        let usable = valid(mean)
            && valid(second_moment)
            && pixel_variance.is_finite()
            && pixel_variance > 0.0;
        if !usable {
            return 1.0;
        }
        let factor = |moment: [f32; 3]| {
            let weighted = [0, 1, 2].map(|c| beta[c] * beta[c] * moment[c]);
            (luminance(weighted) / pixel_variance).sqrt()
        };
        let variance = [0, 1, 2].map(|c| (second_moment[c] - mean[c] * mean[c]).max(0.0));
        let split = factor(variance);
        if split >= 1.0 || !split.is_finite() {
            return self.windowed(split);
        }
        let survive = factor(second_moment);
        if survive < 1.0 {
            self.windowed(survive)
        } else {
            1.0
        }
    }

    /// The decision for one path: `m` from [`Self::continuations`], then roulette (`m < 1`:
    /// one continuation of weight `1/m` if `u < m`, else none) or splitting (`m ≥ 1`:
    /// `k = min(⌊m⌋ + [u < m − ⌊m⌋], 1 + room)` continuations of weight `1/k`), `u` uniform in
    /// `[0, 1)`, `room` how many more continuations the path may still spawn.
    #[must_use]
    pub fn decide(
        &self,
        beta: [f32; 3],
        radiance: [f32; 3],
        pixel: f32,
        u: f32,
        room: u32,
    ) -> Decision {
        self.decide_expected(self.continuations(beta, radiance, pixel), u, room)
    }

    /// [`Self::decide`] with the efficiency-aware `m` ([`Self::efficiency_continuations`]).
    #[must_use]
    pub fn decide_efficiency(
        &self,
        beta: [f32; 3],
        mean: [f32; 3],
        second_moment: [f32; 3],
        pixel_variance: f32,
        u: f32,
        room: u32,
    ) -> Decision {
        let m = self.efficiency_continuations(beta, mean, second_moment, pixel_variance);
        self.decide_expected(m, u, room)
    }

    /// The decision for an expected count `m` (from [`Self::continuations`] or
    /// [`Self::efficiency_continuations`]): roulette below 1, splitting from 1 on.
    #[must_use]
    pub fn decide_expected(&self, m: f32, u: f32, room: u32) -> Decision {
        if m < 1.0 {
            return if u < m {
                Decision {
                    count: 1,
                    weight: 1.0 / m,
                }
            } else {
                Decision::default()
            };
        }
        let k = continuation_count(m, u).clamp(1, room.saturating_add(1));
        Decision {
            count: k,
            weight: 1.0 / k as f32,
        }
    }

    /// [`Self::decide`] for every row.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the slices differ in length; `out` is untouched.
    pub fn decide_batch(
        &self,
        beta: &[[f32; 3]],
        radiance: &[[f32; 3]],
        pixel: &[f32],
        u: &[f32],
        room: &[u32],
        out: &mut Vec<Decision>,
    ) -> Result<(), GuidingError> {
        let n = beta.len();
        if [radiance.len(), pixel.len(), u.len(), room.len()]
            .iter()
            .any(|&l| l != n)
        {
            return Err(GuidingError::LengthMismatch {
                what: format!(
                    "{n} throughputs, {} radiances, {} pixel estimates, {} uniforms, {} rooms",
                    radiance.len(),
                    pixel.len(),
                    u.len(),
                    room.len()
                ),
            });
        }
        out.clear();
        out.extend((0..n).map(|i| self.decide(beta[i], radiance[i], pixel[i], u[i], room[i])));
        Ok(())
    }
}

/// How many continuations to spawn for an expected `m` and a uniform `u ∈ [0, 1)`:
/// `⌊m⌋ + [u < m − ⌊m⌋]`, so that `E[k] = m`.
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

    const GREY: fn(f32) -> [f32; 3] = |x| [x; 3];

    /// The rule written out: `m = Y(β⊙L̂)/Î` outside `[2/(1+s), 2s/(1+s)]`, 1 inside, clamped
    /// to `[min_survival, max_split]`.
    #[test]
    fn the_window_rule_written_out() {
        let w = WeightWindow::default();
        let (lo, hi) = w.bounds();
        assert!((lo - 2.0 / 6.0).abs() < 1e-7 && (hi - 10.0 / 6.0).abs() < 1e-6);
        // Y(0.5 · 0.2) / 1 = 0.1 < 1/3: roulette, survival 0.1.
        assert!((w.continuations(GREY(0.5), GREY(0.2), 1.0) - 0.1).abs() < 1e-6);
        // 2 · 3 / 2 = 3 > 5/3: three continuations.
        assert!((w.continuations(GREY(2.0), GREY(3.0), 2.0) - 3.0).abs() < 1e-5);
        // Colour: β = (1, 0, 0), L̂ = (0, 1, 0): nothing comes back, survival floor.
        assert_eq!(w.continuations([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], 1.0), 0.05);
        // β = (4, 0, 0), L̂ = (1, 0, 0), Î = 0.2126: m = 4.
        let m = w.continuations([4.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.2126);
        assert!((m - 4.0).abs() < 1e-5, "{m}");
        // Inside the window: untouched.
        assert_eq!(w.continuations(GREY(1.0), GREY(1.2), 1.0), 1.0);
        assert_eq!(w.continuations(GREY(1.0), GREY(0.34), 1.0), 1.0);
        // Capped at max_split, floored at min_survival.
        assert_eq!(w.continuations(GREY(100.0), GREY(1.0), 1.0), 8.0);
        assert_eq!(w.continuations(GREY(1e30), GREY(1e30), 1e-30), 8.0);
        assert_eq!(w.continuations(GREY(1e-3), GREY(1.0), 1.0), 0.05);
    }

    /// The efficiency-aware rule written out: splitting by the subpath's variance
    /// `m_s = √(Y(β² ⊙ V)/σ²)`, else roulette by its second moment `m_r = √(Y(β² ⊙ M)/σ²)`,
    /// through the same window.
    #[test]
    fn the_efficiency_rule_written_out() {
        let w = WeightWindow::default();
        // L̂ = 1, M = 5: V = 4, √(2² · 4 / 1) = 4: four continuations.
        let m = w.efficiency_continuations(GREY(2.0), GREY(1.0), GREY(5.0), 1.0);
        assert!((m - 4.0).abs() < 1e-5, "{m}");
        // L̂ = 2, M = 4: a precise subpath (V = 0) is not split, though √(2² · 4 / 1) = 4
        // (EARS's second moment for both would split it four ways), nor killed (m_r = 4).
        let m = w.efficiency_continuations(GREY(2.0), GREY(2.0), GREY(4.0), 1.0);
        assert_eq!(m, 1.0);
        // √(1 · 1 / 100) = 0.1: roulette (V = 0, m_s = 0).
        let m = w.efficiency_continuations(GREY(1.0), GREY(1.0), GREY(1.0), 100.0);
        assert!((m - 0.1).abs() < 1e-6, "{m}");
        // m_s = √(1 · 1.44 / 1) = 1.2: inside the window.
        let m = w.efficiency_continuations(GREY(1.0), GREY(0.0), GREY(1.44), 1.0);
        assert_eq!(m, 1.0);
        // m_r = √(0.25 / 1) = 0.5: inside the window too.
        let m = w.efficiency_continuations(GREY(0.5), GREY(1.0), GREY(1.0), 1.0);
        assert_eq!(m, 1.0);
        // Missing estimates, a dead path.
        let one = GREY(1.0);
        assert_eq!(w.efficiency_continuations(one, one, one, 0.0), 1.0);
        assert_eq!(w.efficiency_continuations(one, one, [-1.0; 3], 1.0), 1.0);
        assert_eq!(
            w.efficiency_continuations(one, [f32::NAN; 3], one, 1.0),
            1.0
        );
        assert_eq!(w.efficiency_continuations(GREY(0.0), one, one, 1.0), 0.0);
        let d = w.decide_efficiency(GREY(2.0), GREY(1.0), GREY(5.0), 1.0, 0.5, 8);
        assert_eq!((d.count, d.weight), (4, 0.25));
    }

    #[test]
    fn missing_estimates_leave_the_path_alone_and_dead_paths_stay_dead() {
        let w = WeightWindow::default();
        for bad in [-1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(w.continuations(GREY(0.5), [0.0, bad, 0.0], 1.0), 1.0);
            assert_eq!(w.continuations(GREY(0.5), GREY(1.0), bad), 1.0);
            assert_eq!(w.continuations(GREY(bad), GREY(1.0), 1.0), 0.0);
        }
        assert_eq!(w.continuations(GREY(0.5), GREY(1.0), 0.0), 1.0);
        assert_eq!(w.continuations(GREY(0.0), GREY(1.0), 1.0), 0.0);
        assert_eq!(w.decide(GREY(0.0), GREY(1.0), 1.0, 0.0, 8).count, 0);
    }

    /// The decision written out: roulette survives with probability `m` at weight `1/m`,
    /// splitting gives `k` continuations at `1/k`, and `room` caps `k`.
    #[test]
    fn decisions_written_out() {
        let w = WeightWindow::default();
        // m = 0.1: survives below u = 0.1 with weight 10.
        let d = w.decide(GREY(0.5), GREY(0.2), 1.0, 0.05, 0);
        assert_eq!(d.count, 1);
        assert!((d.weight - 10.0).abs() < 1e-4);
        assert_eq!(w.decide(GREY(0.5), GREY(0.2), 1.0, 0.2, 0).count, 0);
        // m = 2.5: 3 continuations below u = 0.5, 2 above, each 1/k.
        let d = w.decide(GREY(2.5), GREY(1.0), 1.0, 0.25, 8);
        assert_eq!((d.count, d.weight), (3, 1.0 / 3.0));
        let d = w.decide(GREY(2.5), GREY(1.0), 1.0, 0.75, 8);
        assert_eq!((d.count, d.weight), (2, 0.5));
        // No room left: one continuation at full weight.
        let d = w.decide(GREY(2.5), GREY(1.0), 1.0, 0.25, 0);
        assert_eq!((d.count, d.weight), (1, 1.0));
        let d = w.decide(GREY(2.5), GREY(1.0), 1.0, 0.25, 1);
        assert_eq!((d.count, d.weight), (2, 0.5));
        // In the window: one at weight 1.
        let d = w.decide(GREY(1.0), GREY(1.0), 1.0, 0.9, 8);
        assert_eq!((d.count, d.weight), (1, 1.0));
    }

    /// The mean count over `n` stratified uniforms (exact up to one stratum, `1/n`).
    fn mean_count(count: impl Fn(f32, f32) -> u32, m: f32, n: u32) -> f64 {
        (0..n)
            .map(|i| f64::from(count(m, (i as f32 + 0.5) / n as f32)))
            .sum::<f64>()
            / f64::from(n)
    }

    /// `E[k] = m` over the uniform `u` (the count is `⌊m⌋ + 1` on a share `m − ⌊m⌋` of
    /// `[0, 1)`); a count without the fraction (`⌊m⌋`) fails the same check.
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

    /// `E[count · weight] = 1` over `u` for every kind of decision (roulette, splitting,
    /// capped splitting, inside the window): the expected total weight of the continuations
    /// is the path's. Weights of `1` for the split copies (not divided by `k`) fail it.
    #[test]
    fn the_expected_total_weight_is_one() {
        let w = WeightWindow::default();
        let n = 1 << 16;
        let total = |beta: f32, room: u32, divide: bool| {
            (0..n)
                .map(|i| {
                    let u = (i as f32 + 0.5) / n as f32;
                    let d = w.decide(GREY(beta), GREY(1.0), 1.0, u, room);
                    let weight = if divide || d.count <= 1 {
                        d.weight
                    } else {
                        1.0
                    };
                    f64::from(d.count) * f64::from(weight)
                })
                .sum::<f64>()
                / f64::from(n)
        };
        for (beta, room) in [(0.01, 8), (0.2, 8), (1.0, 8), (2.5, 8), (7.3, 3), (30.0, 8)] {
            let t = total(beta, room, true);
            assert!((t - 1.0).abs() < 1e-3, "β {beta}, room {room}: {t}");
        }
        assert!(total(2.5, 8, false) > 2.0);
    }

    #[test]
    fn batches_match_rows_and_bad_settings_are_refused() {
        let w = WeightWindow::default();
        let beta = [GREY(0.5), GREY(2.0), GREY(1.0)];
        let radiance = [GREY(0.2), GREY(3.0), GREY(1.2)];
        let (pixel, u, room) = ([1.0, 2.0, 1.0], [0.05, 0.5, 0.9], [0, 8, 8]);
        let mut out = Vec::new();
        w.decide_batch(&beta, &radiance, &pixel, &u, &room, &mut out)
            .unwrap();
        for i in 0..3 {
            assert_eq!(
                out[i],
                w.decide(beta[i], radiance[i], pixel[i], u[i], room[i])
            );
        }
        assert!(w
            .decide_batch(&beta, &radiance[..2], &pixel, &u, &room, &mut out)
            .is_err());
        assert_eq!(out.len(), 3);
        for bad in [
            WeightWindow { ratio: 1.0, ..w },
            WeightWindow {
                ratio: f32::NAN,
                ..w
            },
            WeightWindow { max_split: 0, ..w },
            WeightWindow {
                min_survival: 0.0,
                ..w
            },
            WeightWindow {
                min_survival: 1.5,
                ..w
            },
        ] {
            assert!(bad.validate().is_err());
        }
        assert!(w.validate().is_ok());
    }
}
