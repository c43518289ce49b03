//! Does the guide pay? An interleaved A/B trial of whole passes, guided against unguided, that
//! compares the two estimators' **efficiency** (variance × time) on the renderer's own image.
//!
//! A guide that samples better per sample can still lose at equal time: every guided vertex pays
//! for the guide's lookup, sample and densities, and on a scene that BSDF sampling and NEE
//! already handle well the saved variance is smaller than the added cost. The per-vertex
//! selection-probability fit ([`crate::GuideCache::fit_selection`]) sees only the variance of
//! one vertex's estimator, not the cost, nor how much of the pixel's variance that vertex carries.
//! This trial measures both at the level the user sees, once training has stopped:
//!
//! 1. the renderer runs `2K` passes (one sample per pixel over the whole image), alternating
//!    [`TrialArm::Guided`] and [`TrialArm::Unguided`] (its own estimator with the guide switched
//!    off: BSDF sampling and NEE), and hands each pass's pixel values and seconds to
//!    [`GuideTrial::record`]; both arms are unbiased, so every pass stays in the image;
//! 2. per arm `a`, the per-pass relative variance is estimated from its `K` passes,
//!    `V_a = (1 / 3N) Σ_p Σ_ch s²_{a,p,ch} / (m_{p,ch}² + ε)`, with `s²` the unbiased sample
//!    variance of the pixel's `K` values, `ε = 0.01` (the denominator of the relMSE the
//!    benchmark reports, so `V_a` estimates the relMSE one pass of that arm would have against
//!    the truth) and `m` the renderer's image *before* the trial (its mean so far), smoothed by
//!    a `(2r + 1)²` box filter (`r = 2`); each pixel's term `Σ_ch s² / (m² + ε)` is winsorised
//!    at the arm's 99.9th percentile ([`TRIAL_TRIM`], as the benchmark trims its relMSE). The
//!    weights must not come from the trial's own
//!    passes: with a noisy image their mean's `m²` grows with the pixel's variance
//!    (`E[m²] = μ² + σ²/2K`), every term `s²/(m² + ε)` tends to the same constant and the two
//!    arms look alike whatever their variances. The image before the trial is independent of
//!    the trial's passes, so both arms are weighted alike, and the filter takes out most of its
//!    noise;
//! 3. the efficiency cost of an arm is `V_a · t_a` with `t_a` its mean seconds per pass: the
//!    relMSE it reaches in one second is `V_a · t_a` (variance of a mean of `n = T / t_a`
//!    passes). `V_a` is estimated per band of rows too, and the paired bands give a
//!    confidence interval on the cost ratio `R = V_g t_g / (V_u t_u)` ([`crate::evidence`]).
//!    Each arm's passes alternate between two halves; once every half has 2 passes, `V_a` is
//!    the mean of its halves' estimates and the interval comes from the halves' differences
//!    per band ([`CostRatio::from_split_bands`]): the paired-band interval also counts, as if
//!    it were noise, that the guide helps more in some rows than in others, so it stops
//!    narrowing after a few passes (on the Cornell box a continuing trial's interval was
//!    [0.83, 1.27] after 121 + 242 passes, as wide as after 4 + 4); the halves' differences
//!    hold only the noise and narrow as `1/√passes`.
//!    The guide is switched off only when the whole interval lies above 1
//!    ([`TrialVerdict::keep_guide`]) and the untrimmed point estimate does too
//!    ([`TrialOptions::robust_to_trim`]); else the guide stays on.
//!
//! This is the pixel-level counterpart of Müller et al.'s "is guiding worth it" question
//! (*Practical Path Guiding*, 2017, spends a budget fraction on learning and decides nothing;
//! Open PGL leaves the choice to the user). Deviations: the arms alternate pass by pass so a
//! drift of the machine's speed falls on both; pixels with a non-finite value in any trial pass
//! are left out of both sums (and counted), so one NaN cannot decide.
//!
//! The decision is made once, from `K` passes per arm (default 4), or earlier from `k ≥ 2` each
//! when the interval already excludes 1 ([`TrialOptions::early_verdict`]): a trial pass of the
//! losing arm adds its variance to the image, so a clear case should not pay for all of them
//! (on `builtin:door` without NEE, 4 `pt` passes among 77 were about a quarter of the image's
//! relMSE). The relative standard error of each `V_a` is about `√(2 / (3N(K − 1)))` for
//! independent pixels (0.3 % at 320 × 240); heavy-tailed pixels (fireflies) widen it, through
//! the spread of the bands, and a verdict then waits (the old rule, the point estimate against
//! 1, switched guides off by a coin flip on such scenes).
//!
//! **Continuation** ([`TrialOptions::continuation`], on by default). A trial whose interval
//! still straddles 1 after `K` passes per arm does not end: the guide stays on, as the fixed
//! trial would keep it, but the passes go on alternating, the arm with the cheaper point
//! estimate running two passes for each pass of the other, and the interval is looked at again
//! each time the less-run arm reaches `2K, 4K, 8K, …` passes, until it excludes 1 (then the
//! verdict is final) or the render ends. Both arms are unbiased and the renderer's pass
//! combiner weighs every pass by its own variance, so a continuing trial costs the image only
//! the efficiency gap on the third of the passes that the worse-looking arm runs; in exchange a
//! scene whose first look straddled (fireflies, or a guide that is nearly break-even) reaches a
//! verdict once enough passes exist, instead of keeping a dearer guide for the whole render.
//! The 2 : 1 split: for `n` passes the standard error of `ln R̂` grows as
//! `√(1/n_f + 1/n_o)`, `√4.5/√4 = 1.06` times that of an even split, while the worse-looking
//! arm's share falls from 1/2 to 1/3. Looks are sequential tests of the same hypothesis, so
//! each has its own error (α-spending): look `j ≥ 1` of the continuation uses
//! `α_j = α₀ · 2^{−j}` (`α₀` the two-sided error of [`TrialOptions::z`] per look, 0.27 % at
//! `z = 3`), so all continuation looks together err at most `α₀`, and the whole trial (three
//! looks before, at 2, 3 and 4 passes per arm) at most `4 α₀` (1.1 %).
//! [`GuideTrial::restart`] drops one arm's passes when the renderer changes that estimator
//! (host-demo refits the guide-selection probabilities at the first look): the continuation
//! then measures the estimator that renders.

use crate::evidence::{band_count, band_of_row, CostRatio, Verdict};
use crate::GuidingError;

/// The default [`TrialOptions::trim`]: the largest 0.1 % of the pixels' relative-variance terms
/// of each arm and half are winsorised (set to the largest term left) before the bands are
/// averaged.
///
/// A trial estimates what the benchmark reports, relMSE trimmed of its largest 0.1 % of pixels
/// (host-demo's `compare`, as the papers report it). Untrimmed, one firefly pass decides a
/// heavy-tailed scene: on veach-mis a weight-window trial measured the window at 0.06 [0.008,
/// 0.52] of the plain estimator's cost after 160 passes while the image with the window got
/// 1.08x worse (trimmed relMSE, and 1.04x in MAPE, which no firefly sways). Deviation from the
/// benchmark: the terms are winsorised, not dropped, so every band keeps its pixel count in
/// both arms and halves and the bands stay paired. A guide whose whole gain is removing rare
/// fireflies is credited only for what the trimmed metric sees of it.
///
/// The trim is not the image's, though: a render of `T` passes shows `T / k` times the rare
/// events of `k` trial passes and its trimmed relMSE still drops only 0.1 % of the pixels, so a
/// trial of few passes hides rare large values that the image keeps. On veach-mis (30 s, 256
/// px) the weight window's trial saw the window's variance at 1.00–1.03× the plain passes' after
/// 2–4 passes per arm and at 1.105× after 748 + 578 (its roulette survivors are the rarer,
/// larger values), kept the window on 2 of 3 seeds from the early look, and the image came out
/// 1.07× worse. Trimming less at few passes lets single fireflies decide (a trim scaled by
/// `k / T` gave cost ratios of 0.006 and 182 with intervals that excluded 1,
/// `docs/bench-2026-12-08-window/`). So a verdict must hold both ways
/// ([`TrialOptions::robust_to_trim`]): the trimmed interval excludes 1 *and* the untrimmed
/// point estimate lies on the same side; a verdict that the trimmed pixels would overturn waits.
pub const TRIAL_TRIM: f64 = 0.001;

/// The two estimators a [`GuideTrial`] compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrialArm {
    /// The renderer's guided estimator (guide and BSDF in one-sample MIS).
    Guided,
    /// The same renderer with the guide switched off (BSDF sampling and NEE only).
    Unguided,
}

impl TrialArm {
    fn index(self) -> usize {
        match self {
            TrialArm::Guided => 0,
            TrialArm::Unguided => 1,
        }
    }
}

/// Options of a [`GuideTrial`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrialOptions {
    /// Passes per arm (`K` in the module docs), at least 2: the most the trial runs.
    pub passes_per_arm: u32,
    /// Early verdict: once both arms have the same number `k ≥ 2` of passes, the trial ends if
    /// the cost ratio's interval excludes 1 (every unguided pass of a scene the guide wins
    /// costs the image variance, and the other way round).
    pub early_verdict: bool,
    /// Normal quantile `z` of the cost ratio's interval ([`crate::evidence`]), > 0.
    pub z: f64,
    /// `ε` of the relative variance's denominator `m² + ε`.
    pub epsilon: f64,
    /// Radius `r` of the box filter on the image before the trial (0: none).
    pub smoothing_radius: u32,
    /// Fraction of the pixels, in `[0, 0.5)`, whose relative-variance terms are winsorised per
    /// arm and half: the largest `⌊trim · N⌋` terms count as the largest one left. Default
    /// [`TRIAL_TRIM`] (why: there).
    pub trim: f64,
    /// A verdict must not rest on the trimmed pixels: the interval's [`Verdict::Pays`] or
    /// [`Verdict::DoesNotPay`] stands only when the untrimmed point estimate of the cost ratio
    /// lies on the same side of 1, else the evidence is [`Verdict::Undecided`] (see
    /// [`TRIAL_TRIM`]). Off: the trimmed interval alone decides.
    pub robust_to_trim: bool,
    /// An interval that still straddles 1 after `K` passes per arm does not end the trial: it
    /// goes on with a 2 : 1 split of passes and α-spending looks (see the
    /// [module docs](self)). Off: the trial ends at `K` passes per arm whatever the interval.
    pub continuation: bool,
}

impl Default for TrialOptions {
    fn default() -> Self {
        Self {
            passes_per_arm: 4,
            early_verdict: true,
            z: crate::evidence::Z,
            epsilon: 0.01,
            smoothing_radius: 2,
            trim: TRIAL_TRIM,
            robust_to_trim: true,
            continuation: true,
        }
    }
}

/// What a finished [`GuideTrial`] measured and decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrialVerdict {
    /// The guide stays on: the cost ratio's interval does not lie above 1 (it pays, or the
    /// evidence does not say it does not).
    pub keep_guide: bool,
    /// What the interval says ([`crate::evidence::CostRatio::verdict`]), withheld
    /// ([`Verdict::Undecided`]) when the untrimmed point estimate lies on the other side of 1
    /// ([`TrialOptions::robust_to_trim`]).
    pub evidence: Verdict,
    /// Lower end of the cost ratio's interval (`NaN` without one).
    pub ratio_low: f64,
    /// Upper end of the cost ratio's interval (`NaN` without one).
    pub ratio_high: f64,
    /// Per-pass relative variance of the guided arm (`V_g`).
    pub guided_variance: f64,
    /// Per-pass relative variance of the unguided arm (`V_u`).
    pub unguided_variance: f64,
    /// Mean seconds per guided pass (`t_g`).
    pub guided_seconds: f64,
    /// Mean seconds per unguided pass (`t_u`).
    pub unguided_seconds: f64,
    /// `(V_g · t_g) / (V_u · t_u)`: below 1 the guide pays (`NaN` if the unguided cost is 0).
    pub cost_ratio: f64,
    /// Passes of the guided arm in this estimate (since its last [`GuideTrial::restart`]).
    pub guided_passes: u32,
    /// Passes of the unguided arm in this estimate (since its last [`GuideTrial::restart`]).
    pub unguided_passes: u32,
    /// The interval's normal quantile at this look (larger at later looks of a continuing
    /// trial: α-spending).
    pub z: f64,
    /// Pixels left out because a trial pass gave them a non-finite value.
    pub pixels_skipped: u64,
}

impl TrialVerdict {
    /// The early look's rule ([`crate::TrainingSchedule::look_due`]): more training is worth
    /// its time only for a guide whose cost ratio's whole interval already lies below 1 (it
    /// pays on evidence). The rest of the training phase is a sure cost (a third of its wall
    /// clock trains), so a straddling look does not buy it: on the suite of 2026-12-07 (15
    /// looks that straddled or lay below 1, `docs/bench-2026-12-07-look/`) every look of the
    /// door lay below 1 (upper ends 0.57–0.93) and its guide paid, while of six straddling
    /// looks that trained on (point estimates 0.89–0.99) three ended in a trial that switched
    /// the guide off. A guide stopped here keeps what it has learned and goes to the trial
    /// after training, which switches it off only on evidence; without an interval (a black
    /// image) there is no evidence either.
    #[must_use]
    pub fn worth_more_training(&self) -> bool {
        self.ratio_high < 1.0
    }

    /// What an early look with this estimate decides ([`crate::TrainingSchedule::look_due`]):
    /// training goes on with no more looks when the interval lies below 1
    /// ([`Self::worth_more_training`]), ends when it lies above 1 or there is none (a black
    /// image), and goes on to the next look when it straddles 1: a look too noisy to show
    /// either does not decide the guide's training (see [`crate::EARLY_LOOK_AT`] for the
    /// measurement).
    #[must_use]
    pub fn look_decision(&self) -> LookDecision {
        if self.worth_more_training() {
            LookDecision::TrainOn
        } else if self.ratio_low <= 1.0 && self.ratio_high.is_finite() {
            LookDecision::LookAgain
        } else {
            LookDecision::EndTraining
        }
    }
}

/// What an early look decides ([`TrialVerdict::look_decision`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LookDecision {
    /// The guide pays on evidence: training goes on to the end of the phase, no more looks.
    TrainOn,
    /// No evidence either way: training goes on to the next look (or the end of the phase).
    LookAgain,
    /// The guide does not pay on evidence (or nothing could be measured): training ends.
    EndTraining,
}

/// Per-arm sums of one trial: the arm's passes alternate between two halves (pass `i` of the
/// arm goes to half `i mod 2`), whose independent estimates give the split-half interval.
#[derive(Clone, Debug, Default)]
struct ArmSums {
    passes: u32,
    seconds: f64,
    halves: [HalfSums; 2],
}

/// Per-pixel sums of one half of an arm's passes.
#[derive(Clone, Debug, Default)]
struct HalfSums {
    passes: u32,
    sum: Vec<[f64; 3]>,
    sum2: Vec<[f64; 3]>,
}

impl HalfSums {
    fn new(pixels: usize) -> Self {
        Self {
            passes: 0,
            sum: vec![[0.0; 3]; pixels],
            sum2: vec![[0.0; 3]; pixels],
        }
    }
}

/// The interleaved guided / unguided trial of the [module docs](self).
#[derive(Clone, Debug)]
pub struct GuideTrial {
    options: TrialOptions,
    width: usize,
    height: usize,
    pixels: usize,
    /// `1 / (m̃² + ε)` per pixel and channel, from the smoothed image before the trial.
    weight: Vec<[f64; 3]>,
    arms: [ArmSums; 2],
    /// Pixels with a non-finite value in some trial pass.
    bad: Vec<bool>,
    /// The verdict, once the trial has ended (all passes, or an early clear case).
    decided: Option<TrialVerdict>,
    /// The estimate at `K` passes per arm (or the early verdict), once it exists.
    first_look: Option<TrialVerdict>,
    /// The estimate at the latest look (its point estimate picks the favourite arm).
    latest: Option<TrialVerdict>,
    /// Looks of the continuation made so far (`j` of the next look is this plus 1).
    continued_looks: u32,
}

impl GuideTrial {
    /// A trial over images of `width × height` pixels (row-major), weighted by `image`: the
    /// renderer's estimate of the image before the trial (its mean so far), which must not
    /// include any trial pass. Non-finite values in it count as 0.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for no pixels, fewer than 2 passes per arm or an
    /// `epsilon` that is not finite and positive; [`GuidingError::LengthMismatch`] if `image`
    /// does not have `width × height` pixels.
    pub fn new(
        width: usize,
        height: usize,
        image: &[[f32; 3]],
        options: TrialOptions,
    ) -> Result<Self, GuidingError> {
        let pixels = width.saturating_mul(height);
        if image.len() != pixels {
            return Err(GuidingError::LengthMismatch {
                what: format!(
                    "a trial of {width} x {height} pixels weighted by an image of {}",
                    image.len()
                ),
            });
        }
        if pixels == 0 || options.passes_per_arm < 2 {
            return Err(GuidingError::InvalidConfig(format!(
                "a guide trial needs pixels and at least 2 passes per arm (got {pixels} pixels, \
                 {} passes)",
                options.passes_per_arm
            )));
        }
        if !(options.z.is_finite() && options.z > 0.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "the trial's interval quantile z must be finite and positive, got {}",
                options.z
            )));
        }
        if !(options.epsilon.is_finite() && options.epsilon > 0.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "the trial's epsilon must be finite and positive, got {}",
                options.epsilon
            )));
        }
        if !(0.0..0.5).contains(&options.trim) {
            return Err(GuidingError::InvalidConfig(format!(
                "the trial's trim fraction must lie in [0, 0.5), got {}",
                options.trim
            )));
        }
        let arm = || ArmSums {
            passes: 0,
            seconds: 0.0,
            halves: [HalfSums::new(pixels), HalfSums::new(pixels)],
        };
        let smooth = box_filter(width, height, image, options.smoothing_radius as usize);
        let weight = smooth
            .iter()
            .map(|m| m.map(|x| 1.0 / (x * x + options.epsilon)))
            .collect();
        Ok(Self {
            options,
            width,
            height,
            pixels,
            weight,
            arms: [arm(), arm()],
            bad: vec![false; pixels],
            decided: None,
            first_look: None,
            latest: None,
            continued_looks: 0,
        })
    }

    /// The arm the next pass should run, or `None` once the trial has ended (a verdict). Before
    /// the first look the arms alternate (guided first); a continuing trial gives the arm with
    /// the cheaper point estimate at the latest look two passes for each pass of the other (an
    /// arm with fewer than 2 passes since a [`GuideTrial::restart`] runs first, and without a
    /// look since the restart the guide counts as the cheaper, as an undecided trial keeps it).
    pub fn next_arm(&self) -> Option<TrialArm> {
        let (g, u) = (self.arms[0].passes, self.arms[1].passes);
        if self.decided.is_some() {
            return None;
        }
        if self.first_look.is_none() {
            return Some(if g <= u {
                TrialArm::Guided
            } else {
                TrialArm::Unguided
            });
        }
        if g < 2 {
            return Some(TrialArm::Guided);
        }
        if u < 2 {
            return Some(TrialArm::Unguided);
        }
        // No look since a restart, or a NaN ratio (no cost): the guide, as an undecided trial
        // keeps it.
        let guide_looks_dearer = self.latest.is_some_and(|v| v.cost_ratio > 1.0);
        let (favourite, other) = if !guide_looks_dearer {
            (TrialArm::Guided, TrialArm::Unguided)
        } else {
            (TrialArm::Unguided, TrialArm::Guided)
        };
        let (f, o) = (
            self.arms[favourite.index()].passes,
            self.arms[other.index()].passes,
        );
        Some(if 2 * o < f { other } else { favourite })
    }

    /// Drops the passes of `arm` (its sums, count and seconds) once the renderer has changed
    /// that estimator, so that the continuing trial measures the one that now renders. Only
    /// while the trial runs; the first look and the looks already made stand.
    pub fn restart(&mut self, arm: TrialArm) {
        if self.decided.is_none() {
            let a = &mut self.arms[arm.index()];
            a.passes = 0;
            a.seconds = 0.0;
            for h in &mut a.halves {
                h.passes = 0;
                h.sum.fill([0.0; 3]);
                h.sum2.fill([0.0; 3]);
            }
            self.latest = None;
        }
    }

    /// Adds one pass of `arm`: its pixel values (RGB, the same pixel order every pass) and the
    /// seconds it took.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the image has another size;
    /// [`GuidingError::InvalidConfig`] if the seconds are not finite and non-negative or the
    /// arm already has its passes. Nothing is added then.
    pub fn record(
        &mut self,
        arm: TrialArm,
        pixels: &[[f32; 3]],
        seconds: f64,
    ) -> Result<(), GuidingError> {
        if pixels.len() != self.pixels {
            return Err(GuidingError::LengthMismatch {
                what: format!(
                    "a trial pass of {} pixels for a trial of {}",
                    pixels.len(),
                    self.pixels
                ),
            });
        }
        if !(seconds.is_finite() && seconds >= 0.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "a trial pass took {seconds} s"
            )));
        }
        if self.next_arm().is_none() {
            return Err(GuidingError::InvalidConfig(
                "the trial has ended: no more passes".into(),
            ));
        }
        let a = &mut self.arms[arm.index()];
        if self.first_look.is_none() && a.passes >= self.options.passes_per_arm {
            return Err(GuidingError::InvalidConfig(format!(
                "the {arm:?} arm already has its {} passes",
                a.passes
            )));
        }
        let half = &mut a.halves[(a.passes % 2) as usize];
        a.passes += 1;
        a.seconds += seconds;
        half.passes += 1;
        for (p, v) in pixels.iter().enumerate() {
            if !v.iter().all(|x| x.is_finite()) {
                self.bad[p] = true;
                continue;
            }
            for (ch, &x) in v.iter().enumerate() {
                let x = f64::from(x);
                half.sum[p][ch] += x;
                half.sum2[p][ch] += x * x;
            }
        }
        self.look();
        Ok(())
    }

    /// At a look, estimates and decides (see the [module docs](self)). Only at looks: an
    /// estimate reads every pixel of both arms, and a continuing trial of short passes (1 300
    /// passes of 15 ms on veach-mis) would spend seconds re-estimating after each.
    fn look(&mut self) {
        let (g, u) = (self.arms[0].passes, self.arms[1].passes);
        if g < 2 || u < 2 {
            return;
        }
        let k = self.options.passes_per_arm;
        if self.first_look.is_none() {
            if g != u {
                return;
            }
            let v = self.estimate(self.options.z);
            self.latest = Some(v);
            let clear = self.options.early_verdict && v.evidence != Verdict::Undecided;
            if clear || g >= k {
                self.first_look = Some(v);
                if v.evidence != Verdict::Undecided || !self.options.continuation {
                    self.decided = Some(v);
                }
            }
            return;
        }
        let j = self.continued_looks + 1;
        let due = u64::from(k) << j.min(32);
        if u64::from(g.min(u)) >= due {
            let v = self.estimate(continuation_z(self.options.z, j));
            self.latest = Some(v);
            self.continued_looks = j;
            if v.evidence != Verdict::Undecided {
                self.decided = Some(v);
            }
        }
    }

    /// The estimate at the first look: `K` passes per arm, or the early verdict; `None` before.
    pub fn first_look(&self) -> Option<TrialVerdict> {
        self.first_look
    }

    /// The estimate at the latest look (`None` before the first, and after a
    /// [`GuideTrial::restart`] until the next). Not a verdict: see [`GuideTrial::verdict`].
    pub fn latest(&self) -> Option<TrialVerdict> {
        self.latest
    }

    /// An estimate from all passes so far, at the quantile of the next look (`None` while an
    /// arm has fewer than 2 passes): what a render that ends before the next look reports. It
    /// reads every pixel of both arms; the trial itself estimates only at its looks.
    pub fn current(&self) -> Option<TrialVerdict> {
        let (g, u) = (self.arms[0].passes, self.arms[1].passes);
        if g < 2 || u < 2 {
            return None;
        }
        let z = if self.first_look.is_none() {
            self.options.z
        } else {
            continuation_z(self.options.z, self.continued_looks + 1)
        };
        Some(self.estimate(z))
    }

    /// The verdict once the trial has ended, else `None`.
    pub fn verdict(&self) -> Option<TrialVerdict> {
        self.decided
    }

    /// The verdict from the arms' passes (at least 2 each) at quantile `z`: per band of rows
    /// and arm the mean of `s² · w` over the band's cells (each pixel's term winsorised, see
    /// [`TrialOptions::trim`]) and the arms' `V` the mean over the bands. Once each half of each
    /// arm has 2 passes, per half too, and the interval is the split-half one
    /// ([`CostRatio::from_split_bands`], `V` the mean of the halves'); before, the paired
    /// bands' ([`CostRatio::from_bands`], `V` from all of the arm's passes).
    fn estimate(&self, z: f64) -> TrialVerdict {
        let bands = band_count(self.height);
        let split = self
            .arms
            .iter()
            .all(|a| a.halves.iter().all(|h| h.passes >= 2));
        let used: Vec<usize> = (0..self.pixels).filter(|&p| !self.bad[p]).collect();
        let mut cells = vec![0u64; bands];
        let band: Vec<usize> = used
            .iter()
            .map(|&p| band_of_row(p / self.width.max(1), self.height, bands))
            .collect();
        for &b in &band {
            cells[b] += 3;
        }
        // var[a][0]: all of the arm's passes (before the split); var[a][1 + h]: half h.
        let mut var = [
            [0, 1, 2].map(|_| vec![0.0f64; bands]),
            [0, 1, 2].map(|_| vec![0.0f64; bands]),
        ];
        let sets: &[usize] = if split { &[1, 2] } else { &[0] };
        // The same sums without the winsorisation (for `robust_to_trim`).
        let mut raw = var.clone();
        let mut terms = vec![0.0f64; used.len()];
        for (a, arm) in self.arms.iter().enumerate() {
            let [h0, h1] = &arm.halves;
            for &set in sets {
                // The pixel's `Σ_ch s² · w` from the passes of `set`.
                let variance = |p: usize, ch: usize| {
                    let (s0, q0, k0) = (h0.sum[p][ch], h0.sum2[p][ch], f64::from(h0.passes));
                    let (s1, q1, k1) = (h1.sum[p][ch], h1.sum2[p][ch], f64::from(h1.passes));
                    match set {
                        0 => sample_variance(s0 + s1, q0 + q1, k0 + k1),
                        1 => sample_variance(s0, q0, k0),
                        _ => sample_variance(s1, q1, k1),
                    }
                };
                for (t, &p) in terms.iter_mut().zip(&used) {
                    let w = &self.weight[p];
                    *t = (0..3).map(|ch| variance(p, ch) * w[ch]).sum();
                }
                let cap = winsor_cap(&terms, self.options.trim);
                for (t, &b) in terms.iter().zip(&band) {
                    var[a][set][b] += t.min(cap);
                    raw[a][set][b] += t;
                }
            }
        }
        // Bands whose every pixel was left out carry no evidence.
        let kept: Vec<usize> = (0..bands).filter(|&b| cells[b] > 0).collect();
        let bands_of = |sums: &[[Vec<f64>; 3]; 2], a: usize, set: usize| -> Vec<f64> {
            kept.iter()
                .map(|&b| sums[a][set][b] / cells[b] as f64)
                .collect()
        };
        let per_band = |a: usize, set: usize| bands_of(&var, a, set);
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (tg, tu) = (
            self.arms[0].seconds / f64::from(self.arms[0].passes),
            self.arms[1].seconds / f64::from(self.arms[1].passes),
        );
        let (vg, vu, interval) = if split {
            let (g0, g1, u0, u1) = (
                per_band(0, 1),
                per_band(0, 2),
                per_band(1, 1),
                per_band(1, 2),
            );
            let halves = |x: &[f64], y: &[f64]| (mean(x) + mean(y)) / 2.0;
            (
                halves(&g0, &g1),
                halves(&u0, &u1),
                CostRatio::from_split_bands([&g0, &g1], [&u0, &u1], tg, tu, z),
            )
        } else {
            let (gb, ub) = (per_band(0, 0), per_band(1, 0));
            (
                mean(&gb),
                mean(&ub),
                CostRatio::from_bands(&gb, &ub, tg, tu, z),
            )
        };
        let (cg, cu) = (vg * tg, vu * tu);
        let cost_ratio = if cu > 0.0 { cg / cu } else { f64::NAN };
        // The untrimmed point estimate, `V` formed as the trimmed one's.
        let untrimmed_v = |a: usize| {
            if split {
                (mean(&bands_of(&raw, a, 1)) + mean(&bands_of(&raw, a, 2))) / 2.0
            } else {
                mean(&bands_of(&raw, a, 0))
            }
        };
        let untrimmed = untrimmed_v(0) * tg / (untrimmed_v(1) * tu);
        let trimmed_alone = !self.options.robust_to_trim;
        let evidence = match interval.map_or(Verdict::Undecided, |c| c.verdict()) {
            Verdict::Pays if !(trimmed_alone || untrimmed < 1.0) => Verdict::Undecided,
            Verdict::DoesNotPay if !(trimmed_alone || untrimmed > 1.0) => Verdict::Undecided,
            e => e,
        };
        TrialVerdict {
            keep_guide: evidence != Verdict::DoesNotPay,
            evidence,
            ratio_low: interval.map_or(f64::NAN, |c| c.low),
            ratio_high: interval.map_or(f64::NAN, |c| c.high),
            guided_variance: vg,
            unguided_variance: vu,
            guided_seconds: tg,
            unguided_seconds: tu,
            cost_ratio,
            guided_passes: self.arms[0].passes,
            unguided_passes: self.arms[1].passes,
            z,
            pixels_skipped: (self.pixels - used.len()) as u64,
        }
    }
}

/// The value the largest `⌊trim · n⌋` of `terms` are winsorised to: the largest term left
/// (`+∞` when nothing is trimmed). One selection, `O(n)`, on a copy.
fn winsor_cap(terms: &[f64], trim: f64) -> f64 {
    let n = terms.len();
    let cut = (trim * n as f64).floor() as usize;
    if cut == 0 || cut >= n {
        return f64::INFINITY;
    }
    let mut sorted = terms.to_vec();
    let (_, cap, _) = sorted.select_nth_unstable_by(n - cut - 1, f64::total_cmp);
    *cap
}

/// The unbiased sample variance of `k ≥ 2` values from their sum `s` and sum of squares `q`
/// (rounding can make it a hair negative: clamped at 0).
fn sample_variance(s: f64, q: f64, k: f64) -> f64 {
    ((q - s * s / k) / (k - 1.0)).max(0.0)
}

/// The normal quantile of look `j ≥ 1` of a continuing trial: two-sided error
/// `α_j = α₀ · 2^{−j}`, `α₀ = 2 Q(z₀)` the error of the first looks' quantile `z₀`
/// (`Q` the standard normal's upper tail). Never below `z₀`.
#[must_use]
pub fn continuation_z(z0: f64, j: u32) -> f64 {
    let alpha = 2.0 * normal_upper_tail(z0) * 0.5f64.powi(j.min(1000) as i32);
    normal_upper_quantile(alpha / 2.0).max(z0)
}

/// `Q(z) = P(N(0, 1) > z) = erfc(z / √2) / 2`.
fn normal_upper_tail(z: f64) -> f64 {
    0.5 * libm::erfc(z / std::f64::consts::SQRT_2)
}

/// The `z` with `Q(z) = p` for `p` in `(0, 1/2]`, by bisection on `[0, 40]` (`Q` decreases;
/// 64 halvings reach the rounding of `f64`). Smaller `p` (down to 0) gives 40.
fn normal_upper_quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if normal_upper_tail(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The mean of each pixel's `(2r + 1)²` neighbourhood (clipped at the borders), per channel;
/// non-finite values count as 0. Separable: rows, then columns.
fn box_filter(width: usize, height: usize, image: &[[f32; 3]], r: usize) -> Vec<[f64; 3]> {
    let value = |v: f32| if v.is_finite() { f64::from(v) } else { 0.0 };
    let src: Vec<[f64; 3]> = image.iter().map(|p| p.map(value)).collect();
    if r == 0 {
        return src;
    }
    // One 1-D pass over `n` samples at `at(i)`, written to `out(i)`.
    let pass_1d =
        |n: usize, get: &dyn Fn(usize) -> [f64; 3], set: &mut dyn FnMut(usize, [f64; 3])| {
            for i in 0..n {
                let (lo, hi) = (i.saturating_sub(r), (i + r).min(n - 1));
                let mut acc = [0.0; 3];
                for j in lo..=hi {
                    let v = get(j);
                    for ch in 0..3 {
                        acc[ch] += v[ch];
                    }
                }
                let count = (hi - lo + 1) as f64;
                set(i, acc.map(|a| a / count));
            }
        };
    let mut rows = vec![[0.0; 3]; src.len()];
    for y in 0..height {
        let base = y * width;
        pass_1d(width, &|x| src[base + x], &mut |x, v| rows[base + x] = v);
    }
    let mut out = vec![[0.0; 3]; src.len()];
    for x in 0..width {
        pass_1d(height, &|y| rows[y * width + x], &mut |y, v| {
            out[y * width + x] = v
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{box_filter, TrialVerdict, Verdict};

    /// The early look trains on only when the whole interval lies below 1: a straddling
    /// interval (even with its point estimate below 1), one above 1, or none (a black image)
    /// stop training (the guide keeps what it learned).
    #[test]
    fn more_training_is_worth_it_only_when_the_interval_lies_below_one() {
        let v = |cost_ratio: f64, low: f64, high: f64| TrialVerdict {
            keep_guide: true,
            evidence: Verdict::Undecided,
            ratio_low: low,
            ratio_high: high,
            guided_variance: 1.0,
            unguided_variance: 1.0,
            guided_seconds: 1.0,
            unguided_seconds: 1.0,
            cost_ratio,
            guided_passes: 2,
            unguided_passes: 2,
            z: 3.0,
            pixels_skipped: 0,
        };
        assert!(v(0.7, 0.58, 0.85).worth_more_training());
        assert!(v(0.5, 0.4, 0.999).worth_more_training());
        assert!(!v(0.89, 0.71, 1.11).worth_more_training(), "straddles");
        assert!(!v(0.99, 0.85, 1.0).worth_more_training(), "reaches 1");
        assert!(!v(1.3, 1.2, 1.4).worth_more_training());
        assert!(!v(f64::NAN, f64::NAN, f64::NAN).worth_more_training());
        // The look's decision: below 1 trains on, straddling looks again, above 1 (or no
        // interval) ends training.
        use super::LookDecision::*;
        assert_eq!(v(0.7, 0.58, 0.85).look_decision(), TrainOn);
        assert_eq!(v(0.89, 0.71, 1.11).look_decision(), LookAgain);
        assert_eq!(v(0.99, 0.85, 1.0).look_decision(), LookAgain, "reaches 1");
        assert_eq!(v(1.1, 1.0, 1.2).look_decision(), LookAgain, "starts at 1");
        assert_eq!(v(1.3, 1.2, 1.4).look_decision(), EndTraining);
        assert_eq!(v(f64::NAN, f64::NAN, f64::NAN).look_decision(), EndTraining);
        assert_eq!(
            v(1.0, 0.5, f64::INFINITY).look_decision(),
            EndTraining,
            "no finite interval"
        );
    }

    #[test]
    fn box_filter_keeps_constants_and_averages_an_impulse() {
        let (w, h) = (7, 6);
        let flat = vec![[0.25, 1.0, 3.0]; w * h];
        for v in box_filter(w, h, &flat, 2) {
            assert_eq!(v, [0.25, 1.0, 3.0]);
        }
        let mut impulse = vec![[0.0; 3]; w * h];
        impulse[3 * w + 3] = [25.0, f32::NAN, 0.0];
        let out = box_filter(w, h, &impulse, 2);
        // Interior pixel (3, 3): its 5 x 5 neighbourhood holds the impulse once.
        assert_eq!(out[3 * w + 3], [1.0, 0.0, 0.0]);
        // Corner (0, 0): a 3 x 3 clipped neighbourhood that misses (3, 3).
        assert_eq!(out[0], [0.0; 3]);
        // (1, 1): clipped to 4 x 4 = 16 pixels, which include (3, 3).
        assert_eq!(out[w + 1], [25.0 / 16.0, 0.0, 0.0]);
    }
}
