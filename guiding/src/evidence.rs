//! Verdicts that wait for evidence: a confidence interval on the guide's cost ratio.
//!
//! Whether a guide pays is the **cost ratio** `R = (V_g · t_g) / (V_u · t_u)` of the guided and
//! the unguided estimator: per-pass relative variance times seconds per pass (below 1 the guide
//! reaches a lower relMSE per second). `V` is estimated from a few passes of heavy-tailed pixel
//! values, so a point estimate alone decides by a coin flip on scenes with fireflies (on
//! `builtin:door` at 160 px one unguided pass was estimated at 46 on one seed and 79 on the
//! other, and the old rule abandoned the guide on the first). A guide is therefore switched off
//! only when an interval excludes break-even.
//!
//! **The interval.** The image's rows are cut into `B` bands ([`BANDS`], fewer for short
//! images) and each arm's `V` is estimated per band (`V_{a,b}`, the mean of the band's
//! per-pixel relative variance terms) and over the image (`V_a`, the mean of the bands; bands
//! of equal size). The two arms are measured on the same pixels, so their band estimates are
//! paired; by the delta method `ln R − ln R̂ ≈ mean_b(r_b)` with
//! `r_b = V_{g,b} / V_g − V_{u,b} / V_u`, whose standard error is `sd_b(r_b) / √B` (batch
//! means: bands are far apart compared with the spatial correlation of pixel errors, and a
//! firefly widens the interval of the band it falls in, as it should). The seconds per pass are
//! treated as exact (their spread is a few percent; the variances' is tens). The interval is
//! `R̂ · exp(±z · se)` with `z` = [`Z`].
//!
//! **Decisions.** [`CostRatio::verdict`]: [`Verdict::Pays`] when the upper end is below 1,
//! [`Verdict::DoesNotPay`] when the lower end is above 1, [`Verdict::Undecided`] when it
//! straddles 1; callers keep the guide on while undecided. A caller that looks `k` times
//! (the trial after each pair of passes) has a family-wise error of at most `k` times the
//! per-look error (Bonferroni): `z = 3` gives 0.27 % per look two-sided; the trial looks after
//! 2, 3 and 4 passes per arm (at most 0.8 %), and a continuing trial's later looks spend
//! halving errors that add up to at most one more look's ([`crate::trial::continuation_z`]).

/// Row bands of the batch-means standard error (fewer when the image has fewer rows).
pub const BANDS: usize = 32;

/// Normal quantile of the interval: `z = 3`, 0.27 % two-sided per look.
pub const Z: f64 = 3.0;

/// Band of row `y` in an image of `height` rows cut into `bands` bands (equal to within a
/// row).
#[must_use]
pub fn band_of_row(y: usize, height: usize, bands: usize) -> usize {
    (y * bands / height.max(1)).min(bands.saturating_sub(1))
}

/// The number of bands for an image of `height` rows: [`BANDS`], or `height` when smaller.
#[must_use]
pub fn band_count(height: usize) -> usize {
    BANDS.min(height).max(1)
}

/// What the evidence says about a guide.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// The whole interval is below 1: the guide reaches a lower relMSE per second.
    Pays,
    /// The whole interval is above 1: the guide costs more than it saves.
    DoesNotPay,
    /// The interval contains 1 (or no interval could be formed): keep the guide on.
    Undecided,
}

/// The cost ratio `R` with its confidence interval (see the [module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostRatio {
    /// Point estimate `R̂ = V_g t_g / (V_u t_u)`.
    pub ratio: f64,
    /// Lower end of the interval.
    pub low: f64,
    /// Upper end of the interval.
    pub high: f64,
    /// Per-pass relative variance of the guided arm, `V_g`.
    pub guided_variance: f64,
    /// Per-pass relative variance of the unguided arm, `V_u`.
    pub unguided_variance: f64,
    /// Standard error of `ln R̂`.
    pub log_se: f64,
}

impl CostRatio {
    /// The ratio and its interval from the two arms' per-band variances (same bands, same
    /// order) and seconds per pass; `None` when there are fewer than 2 bands, the band lists
    /// differ in length, or a value is not finite and positive where it must be.
    #[must_use]
    pub fn from_bands(
        guided_bands: &[f64],
        unguided_bands: &[f64],
        guided_seconds: f64,
        unguided_seconds: f64,
        z: f64,
    ) -> Option<Self> {
        let b = usable_bands(&[guided_bands, unguided_bands])?;
        let vg = guided_bands.iter().sum::<f64>() / b as f64;
        let vu = unguided_bands.iter().sum::<f64>() / b as f64;
        Self::with_se((vg, vu), (guided_seconds, unguided_seconds), z, |vg, vu| {
            let r: Vec<f64> = guided_bands
                .iter()
                .zip(unguided_bands)
                .map(|(g, u)| g / vg - u / vu)
                .collect();
            let mean = r.iter().sum::<f64>() / b as f64;
            let var = r.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (b - 1) as f64;
            (var / b as f64).sqrt()
        })
    }

    /// The ratio and its interval from two independent halves of each arm's passes, per band:
    /// `guided[h][b]` the guided arm's `V` on band `b` from its passes of half `h` (the
    /// renderer's alternate passes), the same for `unguided`. The point estimate weighs the
    /// halves equally (`V_a = mean_b (V_{a,b}^0 + V_{a,b}^1) / 2`); the standard error of
    /// `ln R̂` comes from the halves' differences, `se² = Σ_b d_b² / (4 B²)` with
    /// `d_b = r_b^0 − r_b^1`, `r_b^h = V_{g,b}^h / V_g − V_{u,b}^h / V_u`: what the bands have in
    /// common (the guide helping more in one part of the image than in another) cancels, so
    /// unlike [`Self::from_bands`] the interval narrows as passes accumulate instead of
    /// settling at the bands' spread. `None` under the conditions of [`Self::from_bands`].
    #[must_use]
    pub fn from_split_bands(
        guided: [&[f64]; 2],
        unguided: [&[f64]; 2],
        guided_seconds: f64,
        unguided_seconds: f64,
        z: f64,
    ) -> Option<Self> {
        let b = usable_bands(&[guided[0], guided[1], unguided[0], unguided[1]])?;
        let mean_of =
            |h: [&[f64]; 2]| (0..b).map(|i| (h[0][i] + h[1][i]) / 2.0).sum::<f64>() / b as f64;
        let v = (mean_of(guided), mean_of(unguided));
        Self::with_se(v, (guided_seconds, unguided_seconds), z, |vg, vu| {
            let r = |h: usize, i: usize| guided[h][i] / vg - unguided[h][i] / vu;
            let sum_d2: f64 = (0..b).map(|i| (r(0, i) - r(1, i)).powi(2)).sum();
            (sum_d2 / 4.0).sqrt() / b as f64
        })
    }

    /// The ratio `R̂ = V_g t_g / (V_u t_u)` of `(V_g, V_u)` and `(t_g, t_u)` with the interval
    /// `R̂ · exp(±z · se)`, `se = log_se(V_g, V_u)`; `None` unless all four are finite and
    /// positive.
    fn with_se(
        (vg, vu): (f64, f64),
        (tg, tu): (f64, f64),
        z: f64,
        log_se: impl FnOnce(f64, f64) -> f64,
    ) -> Option<Self> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !(positive(vg) && positive(vu) && positive(tg) && positive(tu)) {
            return None;
        }
        let log_se = log_se(vg, vu);
        let ratio = vg * tg / (vu * tu);
        Some(Self {
            ratio,
            low: ratio * (-z * log_se).exp(),
            high: ratio * (z * log_se).exp(),
            guided_variance: vg,
            unguided_variance: vu,
            log_se,
        })
    }

    /// [`Verdict::Pays`] when `high < 1`, [`Verdict::DoesNotPay`] when `low > 1`, else
    /// [`Verdict::Undecided`].
    #[must_use]
    pub fn verdict(&self) -> Verdict {
        if self.high < 1.0 {
            Verdict::Pays
        } else if self.low > 1.0 {
            Verdict::DoesNotPay
        } else {
            Verdict::Undecided
        }
    }
}

/// The common length `B ≥ 2` of band lists whose values are all finite and non-negative.
fn usable_bands(lists: &[&[f64]]) -> Option<usize> {
    let b = lists.first()?.len();
    let finite = |x: &f64| x.is_finite() && *x >= 0.0;
    (b >= 2 && lists.iter().all(|l| l.len() == b && l.iter().all(finite))).then_some(b)
}

impl std::fmt::Display for CostRatio {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "cost ratio {:.3} [{:.3}, {:.3}] (V guided {:.3e}, unguided {:.3e})",
            self.ratio, self.low, self.high, self.guided_variance, self.unguided_variance
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in `(0, 1)` from a 64-bit LCG (Knuth's MMIX constants) seeded `state`.
    fn lcg_uniform(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
    }

    #[test]
    fn bands_cover_every_row_evenly() {
        let h = 100;
        let b = band_count(h);
        let mut counts = vec![0; b];
        for y in 0..h {
            counts[band_of_row(y, h, b)] += 1;
        }
        assert!(counts.iter().all(|&c| c == 3 || c == 4), "{counts:?}");
        assert_eq!(band_count(5), 5);
        assert_eq!(band_count(0), 1);
    }

    /// Equal bands give a zero-width interval; a spread gives a wider one; the verdicts follow.
    #[test]
    fn interval_and_verdicts() {
        let g = [1.0; 8];
        let u = [2.0; 8];
        let c = CostRatio::from_bands(&g, &u, 1.0, 1.0, Z).unwrap();
        assert!((c.ratio - 0.5).abs() < 1e-12 && c.log_se == 0.0);
        assert_eq!(c.verdict(), Verdict::Pays);
        let c = CostRatio::from_bands(&g, &u, 3.0, 1.0, Z).unwrap();
        assert_eq!(c.verdict(), Verdict::DoesNotPay);
        // A firefly in one guided band: R̂ = 1.5 but the interval straddles 1.
        let mut g = [1.0; 8];
        g[3] = 9.0;
        let c = CostRatio::from_bands(&g, &[1.0; 8], 1.0, 1.0, Z).unwrap();
        assert!((c.ratio - 2.0).abs() < 1e-12);
        assert!(c.low < 1.0 && c.high > 1.0, "{c}");
        assert_eq!(c.verdict(), Verdict::Undecided);
    }

    /// The interval's coverage: for bands drawn with a known ratio, `z = 3` covers the truth
    /// in about 99.7 % of draws (checked at 98 %, 3 standard errors of the binomial below).
    #[test]
    fn the_interval_covers_the_true_ratio() {
        let mut uniform = lcg_uniform(0x853c_49e6_748f_ea9b);
        let trials = 2000;
        let (mut covered, mut covered_narrow) = (0, 0);
        for _ in 0..trials {
            // Band variances: each the mean of 20 exponential pixel terms around a
            // band-dependent level; guided = 0.8 × unguided.
            let mut band = |b: usize, scale: f64| {
                let level = scale * (1.0 + (b % 5) as f64);
                (0..20).map(|_| -level * uniform().ln()).sum::<f64>() / 20.0
            };
            let g: Vec<f64> = (0..32).map(|b| band(b, 0.8)).collect();
            let u: Vec<f64> = (0..32).map(|b| band(b, 1.0)).collect();
            let c = CostRatio::from_bands(&g, &u, 1.0, 1.0, Z).unwrap();
            covered += usize::from(c.low <= 0.8 && 0.8 <= c.high);
            // Negative control: an interval a sixth as wide (z = 0.5, 38 % nominal) must be
            // caught by the same check.
            let n = CostRatio::from_bands(&g, &u, 1.0, 1.0, 0.5).unwrap();
            covered_narrow += usize::from(n.low <= 0.8 && 0.8 <= n.high);
        }
        let narrow = covered_narrow as f64 / f64::from(trials);
        assert!(
            narrow < 0.98,
            "the check cannot fail: narrow coverage {narrow}"
        );
        let rate = covered as f64 / f64::from(trials);
        assert!(rate > 0.98, "coverage {rate}");
        assert!(
            rate < 1.0,
            "an interval that always covers is too wide: {rate}"
        );
    }

    /// Bands whose true ratio differs (the guide helps more in some rows than in others): the
    /// split-half interval covers the ratio of the means at about its nominal rate and narrows
    /// as passes accumulate (16 times the passes: about a quarter of the width), while the
    /// band interval of [`CostRatio::from_bands`] on the same draws settles at the bands'
    /// spread (the defect this estimator removes; its width barely changes). Negative control:
    /// a split interval a sixth as wide fails the coverage check.
    #[test]
    fn the_split_interval_narrows_with_passes_over_uneven_bands() {
        let mut uniform = lcg_uniform(0x2545_f491_4f6c_dd1d);
        let bands = 32;
        let level_u = |b: usize| 1.0 + (b % 5) as f64;
        // Guided: 0.4x to 1.3x of the unguided level depending on the band.
        let level_g = |b: usize| level_u(b) * (0.4 + 0.3 * (b % 4) as f64);
        let truth = (0..bands).map(level_g).sum::<f64>() / (0..bands).map(level_u).sum::<f64>();
        let trials = 1000;
        let mut width = |cells: usize, covered: &mut [usize; 3]| -> [f64; 2] {
            let mut w = [0.0; 2];
            for _ in 0..trials {
                // A half's band estimate: the mean of `cells` exponential terms (more passes,
                // more terms: the noise falls as 1/sqrt(cells)).
                let mut draw = |level: f64| {
                    (0..cells).map(|_| -level * uniform().ln()).sum::<f64>() / cells as f64
                };
                let g: [Vec<f64>; 2] =
                    [0, 1].map(|_| (0..bands).map(|b| draw(level_g(b))).collect());
                let u: [Vec<f64>; 2] =
                    [0, 1].map(|_| (0..bands).map(|b| draw(level_u(b))).collect());
                let split =
                    CostRatio::from_split_bands([&g[0], &g[1]], [&u[0], &u[1]], 1.0, 1.0, Z)
                        .unwrap();
                let narrow =
                    CostRatio::from_split_bands([&g[0], &g[1]], [&u[0], &u[1]], 1.0, 1.0, 0.5)
                        .unwrap();
                let pooled = |h: &[Vec<f64>; 2]| -> Vec<f64> {
                    (0..bands).map(|b| (h[0][b] + h[1][b]) / 2.0).collect()
                };
                let band = CostRatio::from_bands(&pooled(&g), &pooled(&u), 1.0, 1.0, Z).unwrap();
                let covers = |c: &CostRatio| usize::from(c.low <= truth && truth <= c.high);
                covered[0] += covers(&split);
                covered[1] += covers(&narrow);
                covered[2] += covers(&band);
                w[0] += (split.high / split.low).ln() / f64::from(trials);
                w[1] += (band.high / band.low).ln() / f64::from(trials);
            }
            w
        };
        let mut few = [0; 3];
        let w_few = width(10, &mut few);
        let mut many = [0; 3];
        let w_many = width(160, &mut many);
        for covered in [few, many] {
            let rate = covered[0] as f64 / f64::from(trials);
            // 99.7 % nominal; 3 binomial standard errors below is 98.8 % at 1000 draws.
            assert!(rate > 0.985, "split coverage {rate}");
            let narrow = covered[1] as f64 / f64::from(trials);
            assert!(
                narrow < 0.985,
                "the check cannot fail: narrow coverage {narrow}"
            );
        }
        // sqrt(16) = 4 times narrower, within 20 %.
        let shrink = w_few[0] / w_many[0];
        assert!(
            (3.2..4.8).contains(&shrink),
            "split width {w_few:?} -> {w_many:?}"
        );
        // The band interval keeps the bands' spread: it shrinks far less.
        let band_shrink = w_few[1] / w_many[1];
        assert!(band_shrink < 2.0, "band width {w_few:?} -> {w_many:?}");
        assert!(w_many[1] > 3.0 * w_many[0], "{w_many:?}");
    }

    #[test]
    fn unusable_inputs_give_none() {
        assert!(CostRatio::from_bands(&[1.0], &[1.0], 1.0, 1.0, Z).is_none());
        assert!(CostRatio::from_bands(&[1.0, 1.0], &[1.0], 1.0, 1.0, Z).is_none());
        assert!(CostRatio::from_bands(&[0.0, 0.0], &[1.0, 1.0], 1.0, 1.0, Z).is_none());
        assert!(CostRatio::from_bands(&[1.0, f64::NAN], &[1.0, 1.0], 1.0, 1.0, Z).is_none());
        assert!(CostRatio::from_bands(&[1.0, 1.0], &[1.0, 1.0], 0.0, 1.0, Z).is_none());
        let (one, two) = ([1.0, 1.0], [1.0, 1.0, 1.0]);
        assert!(CostRatio::from_split_bands([&one, &two], [&one, &one], 1.0, 1.0, Z).is_none());
        assert!(
            CostRatio::from_split_bands([&one, &one], [&one, &[0.0, 0.0]], 1.0, 1.0, Z)
                .is_some_and(|c| c.ratio.is_finite())
        );
        assert!(
            CostRatio::from_split_bands([&[0.0; 2], &[0.0; 2]], [&one, &one], 1.0, 1.0, Z)
                .is_none()
        );
        assert!(
            CostRatio::from_split_bands([&one, &[1.0, f64::NAN]], [&one, &one], 1.0, 1.0, Z)
                .is_none()
        );
    }
}
