//! The guided / unguided efficiency trial (`guiding::GuideTrial`): its variance estimate is the
//! per-pass relative variance within a standard error derived from the chi-square law of the
//! sample variance, its verdict follows variance × time, and the weighting by the image before
//! the trial is what keeps a noisy image from making the two arms look alike (a committed
//! negative control computes the defective self-weighted estimate from the same samples).

use guiding::{GuideTrial, GuidingError, TrialArm, TrialOptions, TrialVerdict};
use guiding_core::rng::Rng;
use statrs::distribution::{ContinuousCDF, Normal};

const W: usize = 64;
const H: usize = 48;
const MEAN: [f32; 3] = [0.5, 0.2, 1.0];

/// Standard normal by Box–Muller.
fn gauss(rng: &mut Rng) -> f64 {
    let u1 = f64::from(rng.next_f32()).max(1e-12);
    let u2 = f64::from(rng.next_f32());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// How an arm's pixel values scatter around the true mean `m` of their channel.
#[derive(Clone, Copy)]
enum Noise {
    /// Gaussian with standard deviation `scale · (0.5 + x / W) · m` (varies over the image, so
    /// the weighting matters).
    Gauss(f64),
    /// A firefly estimator: `m / q` with probability `q`, else 0 (heavy-tailed, as the
    /// per-pass values of a hard pixel are).
    Firefly(f64),
}

impl Noise {
    fn draw(self, p: usize, m: f64, rng: &mut Rng) -> f64 {
        match self {
            Noise::Gauss(scale) => m + scale * (0.5 + (p % W) as f64 / W as f64) * m * gauss(rng),
            Noise::Firefly(q) => {
                if f64::from(rng.next_f32()) < q {
                    m / q
                } else {
                    0.0
                }
            }
        }
    }

    /// Variance and fourth central moment of pixel `p`'s values.
    fn moments(self, p: usize, m: f64) -> (f64, f64) {
        match self {
            Noise::Gauss(scale) => {
                let sd = scale * (0.5 + (p % W) as f64 / W as f64) * m;
                (sd * sd, 3.0 * sd.powi(4))
            }
            Noise::Firefly(q) => {
                let a = m / q;
                let b = q * (1.0 - q);
                (a * a * b, a.powi(4) * b * (1.0 - 3.0 * q + 3.0 * q * q))
            }
        }
    }
}

/// Two-sided Šidák-corrected normal quantile for `tests` comparisons at family level `alpha`.
fn z_bound(alpha: f64, tests: usize) -> f64 {
    let per_test = 1.0 - (1.0 - alpha).powf(1.0 / tests as f64);
    Normal::new(0.0, 1.0)
        .expect("unit normal")
        .inverse_cdf(1.0 - per_test / 2.0)
}

/// The trial's expected `V` of an arm and its standard error: the sample variance `s²` of `K`
/// values has mean `σ²` and variance `(μ₄ − σ⁴ (K − 3) / (K − 1)) / K`. From 4 passes (even
/// `K`) the trial's `V` is the mean of its two halves' (`K / 2` passes each): the variance of
/// `s²` of `K / 2` values, halved.
fn expected(noise: Noise, k: u32, eps: f64) -> (f64, f64) {
    let (mut v, mut var) = (0.0, 0.0);
    let split = k >= 4;
    let kf = if split {
        f64::from(k / 2)
    } else {
        f64::from(k)
    };
    let halves = if split { 2.0 } else { 1.0 };
    for p in 0..W * H {
        for m in MEAN {
            let m = f64::from(m);
            let (s2, mu4) = noise.moments(p, m);
            let w = 1.0 / (m * m + eps);
            v += s2 * w;
            var += (mu4 - s2 * s2 * (kf - 3.0) / (kf - 1.0)) / kf / halves * w * w;
        }
    }
    let cells = (3 * W * H) as f64;
    (v / cells, var.sqrt() / cells)
}

/// The verdict of a finished [`run_trial`].
fn trial_verdict(
    seed: u32,
    noise: (Noise, Noise),
    seconds: (f64, f64),
    options: TrialOptions,
) -> TrialVerdict {
    let (trial, _) = run_trial(seed, noise, seconds, options);
    trial.verdict().expect("finished")
}

/// Runs a trial with passes of the arms' noise `(guided, unguided)` and pass times; returns
/// the trial and every pass's pixels per arm.
fn run_trial(
    seed: u32,
    noise: (Noise, Noise),
    seconds: (f64, f64),
    options: TrialOptions,
) -> (GuideTrial, [Vec<Vec<[f32; 3]>>; 2]) {
    let image = vec![MEAN; W * H];
    let mut trial = GuideTrial::new(W, H, &image, options).expect("valid trial");
    let mut rng = Rng::new(seed);
    let mut passes: [Vec<Vec<[f32; 3]>>; 2] = [Vec::new(), Vec::new()];
    while let Some(arm) = trial.next_arm() {
        let (noise, t, slot) = match arm {
            TrialArm::Guided => (noise.0, seconds.0, 0),
            TrialArm::Unguided => (noise.1, seconds.1, 1),
        };
        let pixels: Vec<[f32; 3]> = (0..W * H)
            .map(|p| MEAN.map(|m| noise.draw(p, f64::from(m), &mut rng) as f32))
            .collect();
        trial.record(arm, &pixels, t).expect("a valid pass");
        passes[slot].push(pixels);
    }
    (trial, passes)
}

#[test]
fn arms_alternate_guided_first_until_both_have_their_passes() {
    let image = vec![[0.0; 3]; 4];
    // Equal (zero) passes never exclude 1: the fixed trial ends at its 3 passes per arm.
    let options = TrialOptions {
        passes_per_arm: 3,
        continuation: false,
        ..TrialOptions::default()
    };
    let mut trial = GuideTrial::new(2, 2, &image, options).expect("valid trial");
    let mut order = Vec::new();
    while let Some(arm) = trial.next_arm() {
        assert!(trial.verdict().is_none());
        trial.record(arm, &image, 0.1).expect("valid pass");
        order.push(arm);
    }
    use TrialArm::{Guided as G, Unguided as U};
    assert_eq!(order, [G, U, G, U, G, U]);
    assert!(trial.verdict().is_some());
    assert!(matches!(
        trial.record(G, &image, 0.1),
        Err(GuidingError::InvalidConfig(_))
    ));
}

#[test]
fn variance_estimate_is_the_per_pass_relative_variance_and_the_verdict_follows_cost() {
    let eps = TrialOptions::default().epsilon;
    let k = TrialOptions::default().passes_per_arm;
    // Guided: half the standard deviation (a quarter of the variance) of the unguided arm.
    let (guided, unguided) = (Noise::Gauss(1.0), Noise::Gauss(2.0));
    let (vg, seg) = expected(guided, k, eps);
    let (vu, seu) = expected(unguided, k, eps);
    // Two cases of two arms, plus two cost ratios.
    let z = z_bound(1e-3, 6);
    for (seed, tg, keep) in [(11, 3.0, true), (12, 5.0, false)] {
        // All passes (the interval would end these early).
        let options = TrialOptions {
            early_verdict: false,
            ..TrialOptions::default()
        };
        let v = trial_verdict(seed, (guided, unguided), (tg, 1.0), options);
        assert!(
            (v.guided_variance - vg).abs() <= z * seg,
            "guided V {} against {vg} ± {}",
            v.guided_variance,
            z * seg
        );
        assert!(
            (v.unguided_variance - vu).abs() <= z * seu,
            "unguided V {} against {vu} ± {}",
            v.unguided_variance,
            z * seu
        );
        assert_eq!(v.guided_seconds, tg);
        assert_eq!(v.unguided_seconds, 1.0);
        // Cost ratio (V_g t_g) / (V_u t_u); its relative error by the delta method.
        let ratio = vg * tg / vu;
        let rel = ((seg / vg).powi(2) + (seu / vu).powi(2)).sqrt();
        assert!(
            (v.cost_ratio / ratio - 1.0).abs() <= z * rel,
            "cost ratio {} against {ratio}",
            v.cost_ratio
        );
        // 0.75 keeps the guide, 1.25 does not: a verdict that ignored the time (or the
        // variance) would keep it in both cases.
        assert_eq!(v.keep_guide, keep, "t_g = {tg}: ratio {}", v.cost_ratio);
        assert_eq!((v.guided_passes, v.unguided_passes), (k, k));
        // The interval is narrow here (Gaussian pixels) and excludes 1 on the right side.
        assert!(v.ratio_low <= v.cost_ratio && v.cost_ratio <= v.ratio_high);
        assert_eq!(
            v.ratio_high < 1.0,
            keep,
            "[{}, {}]",
            v.ratio_low,
            v.ratio_high
        );
        assert_eq!(v.pixels_skipped, 0);
    }
}

/// Negative control: weighting each pixel by the trial's own mean instead of the image before
/// the trial. With heavy-tailed passes (fireflies: relative variance 1 guided, 19 unguided) a
/// pixel's `m²` and `s²` come from the same rare large values, `s² / m²` is bounded whatever
/// their size, and the self-weighted ratio is pulled towards 1: it misses the true 1 / 19 by
/// many standard errors, while the trial's estimate is within its bound.
#[test]
fn weights_from_the_image_before_the_trial_see_through_noise() {
    let (eps, k) = (TrialOptions::default().epsilon, 4u32);
    let (guided, unguided) = (Noise::Firefly(0.5), Noise::Firefly(0.05));
    let (vg, seg) = expected(guided, k, eps);
    let (vu, seu) = expected(unguided, k, eps);
    let truth = vg / vu;
    let rel = ((seg / vg).powi(2) + (seu / vu).powi(2)).sqrt();
    let z = z_bound(1e-3, 1);
    // All 4 passes per arm (no early verdict: the case is clear).
    let options = TrialOptions {
        early_verdict: false,
        ..TrialOptions::default()
    };
    let (trial, passes) = run_trial(21, (guided, unguided), (1.0, 1.0), options);
    let v = trial.verdict().expect("finished");
    assert!(
        (v.cost_ratio / truth - 1.0).abs() <= z * rel,
        "ratio {} against {truth}",
        v.cost_ratio
    );
    // The defective estimate from the same samples.
    let kf = f64::from(k);
    let mut self_weighted = [0.0f64; 2];
    for cell in 0..3 * W * H {
        let (p, ch) = (cell / 3, cell % 3);
        let value = |a: usize, i: usize| f64::from(passes[a][i][p][ch]);
        let mean = (0..2)
            .flat_map(|a| (0..k as usize).map(move |i| (a, i)))
            .map(|(a, i)| value(a, i))
            .sum::<f64>()
            / (2.0 * kf);
        for (a, acc) in self_weighted.iter_mut().enumerate() {
            let m = (0..k as usize).map(|i| value(a, i)).sum::<f64>() / kf;
            let s2 = (0..k as usize)
                .map(|i| (value(a, i) - m).powi(2))
                .sum::<f64>()
                / (kf - 1.0);
            *acc += s2 / (mean * mean + eps);
        }
    }
    let defective = self_weighted[0] / self_weighted[1];
    assert!(
        (defective / truth - 1.0).abs() > 10.0 * rel,
        "the self-weighted ratio {defective} should miss {truth} by far (rel. SE {rel})"
    );
}

/// A clear case ends the trial after 2 passes per arm: cost ratio 1 / 4 keeps the guide, 4 turns
/// it off; the estimates are those of `k = 2` within their standard errors.
#[test]
fn a_clear_case_ends_the_trial_after_two_passes_per_arm() {
    let eps = TrialOptions::default().epsilon;
    let z = z_bound(1e-3, 4);
    for (seed, scales, keep) in [(31, (1.0, 2.0), true), (32, (2.0, 1.0), false)] {
        let (guided, unguided) = (Noise::Gauss(scales.0), Noise::Gauss(scales.1));
        let (trial, passes) = run_trial(
            seed,
            (guided, unguided),
            (1.0, 1.0),
            TrialOptions::default(),
        );
        let v = trial.verdict().expect("ended early");
        assert_eq!((v.guided_passes, v.unguided_passes), (2, 2));
        assert_eq!((passes[0].len(), passes[1].len()), (2, 2));
        assert!(trial.next_arm().is_none());
        assert_eq!(v.keep_guide, keep);
        let (vg, seg) = expected(guided, 2, eps);
        let (vu, seu) = expected(unguided, 2, eps);
        assert!(
            (v.guided_variance - vg).abs() <= z * seg,
            "{} against {vg}",
            v.guided_variance
        );
        assert!(
            (v.unguided_variance - vu).abs() <= z * seu,
            "{} against {vu}",
            v.unguided_variance
        );
    }
}

/// Verdicts wait for evidence: with heavy-tailed passes (fireflies of probability 0.002, as a
/// hard pixel's caustic paths) a guide whose true cost
/// ratio is 1.2 gives a point estimate above 1 (the old rule switched it off on that alone),
/// but the interval straddles 1 and the guide stays on; with Gaussian passes of the same ratio
/// the interval is narrow and the guide is switched off (the rule is not "never off").
#[test]
fn a_straddling_interval_keeps_the_guide() {
    let options = TrialOptions {
        early_verdict: false,
        continuation: false,
        ..TrialOptions::default()
    };
    let firefly = (Noise::Firefly(0.002), Noise::Firefly(0.002));
    let v = trial_verdict(41, firefly, (1.2, 1.0), options);
    assert!(v.cost_ratio > 1.0, "point estimate {}", v.cost_ratio);
    assert!(
        v.ratio_low < 1.0 && v.ratio_high > 1.0,
        "[{}, {}]",
        v.ratio_low,
        v.ratio_high
    );
    assert_eq!(v.evidence, guiding::Verdict::Undecided);
    assert!(v.keep_guide);
    let gauss = (Noise::Gauss(1.0), Noise::Gauss(1.0));
    let v = trial_verdict(42, gauss, (1.2, 1.0), options);
    assert_eq!(
        v.evidence,
        guiding::Verdict::DoesNotPay,
        "[{}, {}]",
        v.ratio_low,
        v.ratio_high
    );
    assert!(!v.keep_guide);
}

#[test]
fn non_finite_pixels_are_left_out_and_counted() {
    let image = vec![MEAN; W * H];
    // Equal arms: the fixed trial (a continuing one would go on until the render ends).
    let options = TrialOptions {
        continuation: false,
        ..TrialOptions::default()
    };
    let mut trial = GuideTrial::new(W, H, &image, options).expect("valid");
    let mut rng = Rng::new(5);
    while let Some(arm) = trial.next_arm() {
        let mut pixels: Vec<[f32; 3]> = (0..W * H)
            .map(|_| MEAN.map(|m| m * (1.0 + 0.1 * gauss(&mut rng) as f32)))
            .collect();
        if arm == TrialArm::Unguided {
            pixels[7] = [f32::NAN, 0.0, 0.0];
            pixels[9] = [0.0, f32::INFINITY, 0.0];
        }
        trial.record(arm, &pixels, 1.0).expect("valid");
    }
    let v = trial.verdict().expect("finished");
    assert_eq!(v.pixels_skipped, 2);
    assert!(v.guided_variance.is_finite() && v.unguided_variance.is_finite());
    assert!(v.cost_ratio.is_finite());
}

#[test]
fn bad_arguments_are_errors() {
    let image = vec![[0.0; 3]; 6];
    let ok = TrialOptions::default();
    assert!(GuideTrial::new(0, 0, &[], ok).is_err());
    assert!(matches!(
        GuideTrial::new(2, 2, &image, ok),
        Err(GuidingError::LengthMismatch { .. })
    ));
    for bad in [
        TrialOptions {
            passes_per_arm: 1,
            ..ok
        },
        TrialOptions { epsilon: 0.0, ..ok },
        TrialOptions {
            epsilon: f64::NAN,
            ..ok
        },
        TrialOptions { z: 0.0, ..ok },
        TrialOptions { z: f64::NAN, ..ok },
        TrialOptions { trim: -0.1, ..ok },
        TrialOptions { trim: 0.5, ..ok },
        TrialOptions {
            trim: f64::NAN,
            ..ok
        },
    ] {
        assert!(GuideTrial::new(3, 2, &image, bad).is_err());
    }
    let mut trial = GuideTrial::new(3, 2, &image, ok).expect("valid");
    assert!(trial.record(TrialArm::Guided, &image[..5], 1.0).is_err());
    for t in [f64::NAN, -1.0, f64::INFINITY] {
        assert!(trial.record(TrialArm::Guided, &image, t).is_err());
    }
    assert_eq!(
        trial.next_arm(),
        Some(TrialArm::Guided),
        "nothing was added"
    );
}

/// Continuation: a guide whose true cost ratio is 2 % from break-even straddles 1 at the first
/// look (4 passes per arm), and the continuing trial reaches the right verdict once enough
/// passes exist: 1.02 switches the guide off, 0.98 keeps it as "pays"; meanwhile the arm that
/// looks cheaper runs about two passes per pass of the other. Negative control: the same
/// passes without continuation end undecided with the guide on, so a trial that never goes
/// on fails this test.
#[test]
fn a_continuing_trial_decides_a_near_break_even_guide() {
    let gauss = (Noise::Gauss(1.0), Noise::Gauss(1.0));
    for (seed, tg, expected) in [
        (51, 1.02, guiding::Verdict::DoesNotPay),
        (52, 0.98, guiding::Verdict::Pays),
    ] {
        let options = TrialOptions {
            early_verdict: false,
            ..TrialOptions::default()
        };
        let (trial, passes) = run_trial(seed, gauss, (tg, 1.0), options);
        let first = trial.first_look().expect("first look");
        assert_eq!(
            first.evidence,
            guiding::Verdict::Undecided,
            "t_g = {tg}: the case must straddle at the first look: [{}, {}]",
            first.ratio_low,
            first.ratio_high
        );
        assert_eq!((first.guided_passes, first.unguided_passes), (4, 4));
        let v = trial.verdict().expect("the continuation decides");
        assert_eq!(
            v.evidence, expected,
            "t_g = {tg}: [{}, {}]",
            v.ratio_low, v.ratio_high
        );
        assert_eq!(v.keep_guide, expected == guiding::Verdict::Pays);
        assert!(
            v.z > first.z,
            "later looks spend less error: z {} then {}",
            first.z,
            v.z
        );
        let (favourite, other) = if tg < 1.0 {
            (passes[0].len(), passes[1].len())
        } else {
            (passes[1].len(), passes[0].len())
        };
        assert!(
            favourite >= 2 * other - 4 && favourite <= 2 * other + 1,
            "t_g = {tg}: {favourite} passes of the cheaper arm against {other}"
        );
        // The negative control: the fixed trial, same seed, ends at its first look.
        let fixed = TrialOptions {
            continuation: false,
            ..options
        };
        let v = trial_verdict(seed, gauss, (tg, 1.0), fixed);
        assert_eq!(v.evidence, guiding::Verdict::Undecided);
        assert!(v.keep_guide);
    }
}

/// The continuation's looks spend error as `α_j = α₀ 2^{−j}` (`α₀` two-sided at `z = 3`): each
/// look's quantile is the normal quantile of that error (checked against `statrs`), and the
/// errors of all looks sum to at most `α₀`.
#[test]
fn continuation_looks_spend_a_halving_error() {
    let normal = Normal::new(0.0, 1.0).expect("unit normal");
    let z0 = TrialOptions::default().z;
    let alpha0 = 2.0 * (1.0 - normal.cdf(z0));
    let mut spent = 0.0;
    let mut previous = z0;
    for j in 1..=30 {
        let z = guiding::trial::continuation_z(z0, j);
        let alpha = alpha0 * 0.5f64.powi(j as i32);
        // The lower tail, so that a tiny α is not rounded away in `1 − α/2`.
        let expected = -normal.inverse_cdf(alpha / 2.0);
        // `libm::erfc` and `statrs` are accurate to a few ulps of the tail probability: a
        // relative error δ in it moves z by about δ / z, far below 1e-9 here.
        assert!(
            (z - expected).abs() < 1e-9,
            "look {j}: z {z} against {expected}"
        );
        assert!(z > previous);
        previous = z;
        spent += 2.0 * (1.0 - normal.cdf(z));
    }
    assert!(spent <= alpha0 * (1.0 + 1e-4), "spent {spent} of {alpha0}");
    // Far looks saturate, never overflow.
    assert!(guiding::trial::continuation_z(z0, u32::MAX).is_finite());
}

/// A restart drops one arm's passes: the continuing trial runs that arm until it has 2 again,
/// and its next estimate counts only the new passes.
#[test]
fn a_restart_measures_the_new_estimator() {
    let options = TrialOptions {
        early_verdict: false,
        ..TrialOptions::default()
    };
    let image = vec![MEAN; W * H];
    let mut trial = GuideTrial::new(W, H, &image, options).expect("valid trial");
    let mut rng = Rng::new(61);
    let pass = |noise: Noise, rng: &mut Rng| -> Vec<[f32; 3]> {
        (0..W * H)
            .map(|p| MEAN.map(|m| noise.draw(p, f64::from(m), rng) as f32))
            .collect()
    };
    // Fireflies: the first look straddles.
    let firefly = Noise::Firefly(0.002);
    while trial.first_look().is_none() {
        let arm = trial.next_arm().expect("running");
        trial
            .record(arm, &pass(firefly, &mut rng), 1.0)
            .expect("valid");
    }
    assert!(trial.verdict().is_none(), "{:?}", trial.first_look());
    trial.restart(TrialArm::Guided);
    assert!(trial.latest().is_none());
    for _ in 0..2 {
        assert_eq!(trial.next_arm(), Some(TrialArm::Guided));
        trial
            .record(TrialArm::Guided, &pass(firefly, &mut rng), 2.0)
            .expect("valid");
    }
    assert!(trial.latest().is_none(), "no look since the restart");
    let latest = trial.current().expect("2 passes of each");
    assert_eq!(latest.guided_passes, 2);
    assert_eq!(latest.guided_seconds, 2.0, "only the new passes' seconds");
    assert!(latest.unguided_passes >= 4);
}

/// Fireflies do not decide a trial: two arms of the same Gaussian noise and pass time (true
/// cost ratio 1), except that the unguided arm's first two passes (one in each half) carry one
/// enormous value (1000× the mean) in one pixel of every band. The trial winsorises the largest
/// 0.1 % of each half's pixel terms, and those 16 pixels per half are fewer than the 32 it
/// trims: the interval straddles 1 around a point estimate near 1. Negative control: with
/// `trim = 0` the same passes make the guide look many times cheaper and "pay".
#[test]
fn rare_fireflies_in_one_arm_do_not_decide_the_trial() {
    const FW: usize = 512;
    const FH: usize = 128;
    let bands = guiding::evidence::band_count(FH);
    // One firefly pixel per band in each half: fewer than the half's trimmed pixels.
    assert!(bands < (guiding::TRIAL_TRIM * (FW * FH) as f64) as usize);
    let run = |trim: f64| {
        let options = TrialOptions {
            early_verdict: false,
            continuation: false,
            trim,
            ..TrialOptions::default()
        };
        let image = vec![MEAN; FW * FH];
        let mut trial = GuideTrial::new(FW, FH, &image, options).expect("valid trial");
        let mut rng = Rng::new(61);
        let mut unguided = 0;
        while let Some(arm) = trial.next_arm() {
            let mut pixels: Vec<[f32; 3]> = (0..FW * FH)
                .map(|p| MEAN.map(|m| Noise::Gauss(1.0).draw(p, f64::from(m), &mut rng) as f32))
                .collect();
            if arm == TrialArm::Unguided {
                if unguided < 2 {
                    for b in 0..bands {
                        let row = b * FH / bands;
                        pixels[row * FW + 17 + unguided] = MEAN.map(|m| 1000.0 * m);
                    }
                }
                unguided += 1;
            }
            trial.record(arm, &pixels, 1.0).expect("a valid pass");
        }
        trial.verdict().expect("finished")
    };
    let v = run(guiding::TRIAL_TRIM);
    assert_eq!(
        v.evidence,
        guiding::Verdict::Undecided,
        "{} [{}, {}]",
        v.cost_ratio,
        v.ratio_low,
        v.ratio_high
    );
    assert!((v.cost_ratio - 1.0).abs() < 0.1, "{}", v.cost_ratio);
    let control = run(0.0);
    assert_eq!(
        control.evidence,
        guiding::Verdict::Pays,
        "untrimmed: {} [{}, {}]",
        control.cost_ratio,
        control.ratio_low,
        control.ratio_high
    );
    assert!(control.cost_ratio < 0.2, "{}", control.cost_ratio);
}

/// A verdict that the trimmed pixels would overturn waits (`TrialOptions::robust_to_trim`).
/// One arm has Gaussian noise of scale 1 plus, in every pass, one value 300× the mean in one
/// pixel of each band; the other has scale 1.3 (1.69× the variance) and nothing else. Each
/// half of a 4 + 4 trial holds 64 such values, fewer than the 65 pixel terms it winsorises:
/// trimmed, the arm with events looks 0.59× as costly and the interval excludes 1; untrimmed
/// (what a render of many passes shows), it is many times dearer. With the events in the
/// guided arm the trimmed interval says "pays", with them in the unguided arm "does not pay";
/// both wait (the guide stays on). Negative control: with the rule off the trimmed interval
/// decides alone, both ways.
#[test]
fn a_verdict_that_the_trimmed_pixels_overturn_waits() {
    const FW: usize = 512;
    const FH: usize = 128;
    let bands = guiding::evidence::band_count(FH);
    // Each half's events (2 passes × bands) are all winsorised.
    assert!(2 * bands <= (guiding::TRIAL_TRIM * (FW * FH) as f64) as usize);
    let run = |events_in: TrialArm, robust_to_trim: bool| {
        let options = TrialOptions {
            early_verdict: false,
            continuation: false,
            robust_to_trim,
            ..TrialOptions::default()
        };
        let image = vec![MEAN; FW * FH];
        let mut trial = GuideTrial::new(FW, FH, &image, options).expect("valid trial");
        let mut rng = Rng::new(71);
        let mut with_events = 0;
        while let Some(arm) = trial.next_arm() {
            let scale = if arm == events_in { 1.0 } else { 1.3 };
            let mut pixels: Vec<[f32; 3]> = (0..FW * FH)
                .map(|p| MEAN.map(|m| Noise::Gauss(scale).draw(p, f64::from(m), &mut rng) as f32))
                .collect();
            if arm == events_in {
                for b in 0..bands {
                    let row = b * FH / bands;
                    pixels[row * FW + 31 + 7 * with_events] = MEAN.map(|m| 300.0 * m);
                }
                with_events += 1;
            }
            trial.record(arm, &pixels, 1.0).expect("a valid pass");
        }
        trial.verdict().expect("finished")
    };
    for (events_in, trimmed_says) in [
        (TrialArm::Guided, guiding::Verdict::Pays),
        (TrialArm::Unguided, guiding::Verdict::DoesNotPay),
    ] {
        let v = run(events_in, true);
        assert_eq!(
            v.evidence,
            guiding::Verdict::Undecided,
            "events in {events_in:?}: {} [{}, {}]",
            v.cost_ratio,
            v.ratio_low,
            v.ratio_high
        );
        assert!(v.keep_guide);
        let control = run(events_in, false);
        assert_eq!(
            control.evidence, trimmed_says,
            "events in {events_in:?}, trimmed alone: {} [{}, {}]",
            control.cost_ratio, control.ratio_low, control.ratio_high
        );
        // The same passes, the same trimmed estimate: only the rule differs.
        assert_eq!(control.cost_ratio, v.cost_ratio);
        assert_eq!(control.ratio_low, v.ratio_low);
    }
}
