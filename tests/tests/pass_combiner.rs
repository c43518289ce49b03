//! Inverse-variance combination of passes (`guiding::PassCombiner`): its per-group variance
//! estimate agrees with the exact expectation within a standard error derived from the
//! quadratic form's variance, the combined image reaches the optimal `1 / Σ n/σ²` error and
//! beats the plain mean, the cross-half weighting is unbiased where a committed negative
//! control (the same weights applied to the half they were estimated on) is not, and the cap
//! at the largest group keeps one-pass groups of a heavy-tailed estimator from being weighted
//! up (a second negative control runs without the cap), and with a few heavy-tailed passes
//! only denominators from the other half tell the groups apart (a third control shows the
//! self-normalised estimates crushing the difference).

use guiding::{Combination, CombineOptions, Denominator, GuidingError, PassCombiner};
use guiding_core::rng::Rng;
use guiding_tests::chi2::sidak;
use statrs::distribution::{ContinuousCDF, Normal};

/// Family-wise significance level of each test function.
const ALPHA: f64 = 0.01;

/// Standard normal by Box–Muller.
fn gauss(rng: &mut Rng) -> f64 {
    let u1 = f64::from(rng.next_f32()).max(1e-12);
    let u2 = f64::from(rng.next_f32());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Two-sided critical |z| at level `alpha / …` after the Šidák correction for `tests` tests.
fn z_critical(tests: usize) -> f64 {
    let level = sidak(ALPHA, tests);
    Normal::new(0.0, 1.0)
        .unwrap()
        .inverse_cdf(1.0 - level / 2.0)
}

/// An unbiasedness test with its negative control (two tests, Šidák):
/// `estimate ± se` agrees with `truth` (two-sided), and the defective
/// `control ± se` falls significantly below it (one-sided).
fn assert_unbiased_and_control_low(
    what: &str,
    (estimate, se): (f64, f64),
    (control, se_control): (f64, f64),
    truth: f64,
) {
    let z = (estimate - truth) / se;
    assert!(
        z.abs() < z_critical(2),
        "{what}: {estimate} ± {se}, expected {truth} (z {z:.2})"
    );
    let z_control = (control - truth) / se_control;
    assert!(
        z_control < -z_critical_one_sided(2),
        "{what}: the control should fall below {truth}: {control} ± {se_control} \
         (z {z_control:.2})"
    );
}

/// One-sided critical z at the Šidák-corrected level.
fn z_critical_one_sided(tests: usize) -> f64 {
    let level = sidak(ALPHA, tests);
    Normal::new(0.0, 1.0).unwrap().inverse_cdf(1.0 - level)
}

/// How a pass's values scatter around the true mean `μ` of every pixel and channel.
#[derive(Clone, Copy)]
enum Noise {
    /// `μ + σ N(0, 1)`.
    Gauss(f64),
    /// `μ / q` with probability `q`, else 0 (a firefly estimator).
    Firefly(f64),
}

impl Noise {
    fn draw(self, mu: f64, rng: &mut Rng) -> f32 {
        let v = match self {
            Noise::Gauss(sigma) => mu + sigma * gauss(rng),
            Noise::Firefly(q) => {
                if f64::from(rng.next_f32()) < q {
                    mu / q
                } else {
                    0.0
                }
            }
        };
        v as f32
    }

    fn variance(self, mu: f64) -> f64 {
        match self {
            Noise::Gauss(sigma) => sigma * sigma,
            Noise::Firefly(q) => mu * mu * (1.0 / q - 1.0),
        }
    }
}

/// The passes of a render, each with its group id.
type Passes = Vec<(u32, Vec<[f32; 3]>)>;

fn pass(npix: usize, mu: f64, noise: Noise, rng: &mut Rng) -> Vec<[f32; 3]> {
    (0..npix)
        .map(|_| {
            [
                noise.draw(mu, rng),
                noise.draw(mu, rng),
                noise.draw(mu, rng),
            ]
        })
        .collect()
}

/// Renders `groups` (id, passes, noise) into a fresh combiner.
fn render(
    w: usize,
    h: usize,
    mu: f64,
    groups: &[(u32, u32, Noise)],
    options: CombineOptions,
    rng: &mut Rng,
) -> (PassCombiner, Passes) {
    let mut c = PassCombiner::new(w, h, options).unwrap();
    let mut passes = Vec::new();
    for &(id, n, noise) in groups {
        for _ in 0..n {
            let px = pass(w * h, mu, noise, rng);
            c.add_pass(id, &px).unwrap();
            passes.push((id, px));
        }
    }
    (c, passes)
}

fn image_mean(px: &[[f32; 3]]) -> f64 {
    px.iter()
        .map(|v| v.iter().map(|&x| f64::from(x)).sum::<f64>())
        .sum::<f64>()
        / (3 * px.len()) as f64
}

/// `V_g` on each half agrees with its exact expectation for Gaussian groups of a constant
/// image: with `e_i = x_i − x̄` (`x̄` the plain mean of all `N` passes, `S = Σ_j n_j σ_j²`),
/// `Cov(e_i, e_j) = a δ_ij + b` within group `g`, `a = σ_g²`, `b = S/N² − 2σ_g²/N`, so one
/// cell's `D_g = Σ_{i∈g} e_i²` has mean `n (a + b)` and variance `2 tr(C²) = 2 n (a² + 2ab + n b²)`;
/// `V_g` averages `D_g / (n (μ² + ε))` over the half's `3|H|` independent cells (the box
/// filter's `m̃` differs from `μ` by less than 0.03, a bias under 0.1 standard errors here).
/// The combined image's MSE then equals the optimum `1 / Σ n_g/σ_g²` within its chi-square
/// standard error, and its predicted gain and error bars follow.
#[test]
fn variance_estimates_and_the_combined_error_match_their_expectations() {
    let (w, h, mu) = (64usize, 48usize, 1.0f64);
    let options = CombineOptions::default();
    let groups = [(3u32, 1u32, Noise::Gauss(1.0)), (9, 20, Noise::Gauss(0.3))];
    let mut rng = Rng::new(0x5eed_c0b1);
    let (c, passes) = render(w, h, mu, &groups, options, &mut rng);
    let out = c.combine();
    assert!(!out.fell_back);
    assert_eq!(out.groups.len(), 2);

    let total: f64 = groups.iter().map(|g| f64::from(g.1)).sum();
    let s: f64 = groups
        .iter()
        .map(|g| f64::from(g.1) * g.2.variance(mu))
        .sum();
    let cells = (3 * w * h / 2) as f64;
    let denom = mu * mu + options.epsilon;
    // 4 variance z-tests, the image's MSE, and its error bars.
    let z_max = z_critical(6);
    for (gi, &(id, n, noise)) in groups.iter().enumerate() {
        let n = f64::from(n);
        let a = noise.variance(mu);
        let b = s / (total * total) - 2.0 * a / total;
        let mean_d = n * (a + b);
        let var_d = 2.0 * n * (a * a + 2.0 * a * b + n * b * b);
        let expected = mean_d / (n * denom);
        let se = var_d.sqrt() / (n * denom * cells.sqrt());
        let g = &out.groups[gi];
        assert_eq!(g.group, id);
        for half in 0..2 {
            let z = (g.relative_variance[half] - expected) / se;
            assert!(
                z.abs() < z_max,
                "group {id} half {half}: V {} expected {expected} ± {se} (z {z:.2})",
                g.relative_variance[half]
            );
        }
    }

    // The optimum and the plain mean's error.
    let optimal: f64 = 1.0
        / groups
            .iter()
            .map(|g| f64::from(g.1) / g.2.variance(mu))
            .sum::<f64>();
    let plain = s / (total * total);
    let cells_all = (3 * w * h) as f64;
    let mse = out
        .pixels
        .iter()
        .map(|v| v.iter().map(|&x| (f64::from(x) - mu).powi(2)).sum::<f64>())
        .sum::<f64>()
        / cells_all;
    // Each cell's squared error is σ_c² χ²₁: relative standard error √(2 / cells).
    let se = optimal * (2.0 / cells_all).sqrt();
    let z = (mse - optimal) / se;
    assert!(
        z.abs() < z_max,
        "combined MSE {mse} against the optimum {optimal} ± {se} (z {z:.2}); plain mean {plain}"
    );
    let z_plain = (plain - mse) / (plain * (2.0 / cells_all).sqrt());
    assert!(
        z_plain > z_max,
        "MSE {mse}, plain mean {plain} (z {z_plain:.2})"
    );
    // The predicted gain is its documented formula over the reported variances and weights.
    let mut gain = 0.0;
    for half in 0..2 {
        let (mut weighted, mut plain_v) = (0.0, 0.0);
        for g in &out.groups {
            let (n, v) = (f64::from(g.passes), g.relative_variance[half]);
            weighted += n * g.pass_weight[half] * g.pass_weight[half] * v;
            plain_v += n * v / (total * total);
        }
        gain += weighted / plain_v / 2.0;
    }
    assert!((out.predicted_gain() - gain).abs() < 1e-12 * gain);
    assert!(
        gain < 0.8,
        "predicted gain {gain} (exact {})",
        optimal / plain
    );

    // Error bars: E[var_of_mean] = N/(N−1) Σ_g a_g² E[D_g], E[D_g] = n (σ_g² (1 − 2/N) + S/N²)
    // (the deviations are taken from the plain mean); the pixel average of the estimate agrees
    // within its standard error (from the per-pixel spread of the estimate itself).
    let shares: Vec<f64> = out
        .groups
        .iter()
        .map(|g| (g.pass_weight[0] + g.pass_weight[1]) / 2.0)
        .collect();
    let expected_var: f64 = total / (total - 1.0)
        * groups
            .iter()
            .zip(&shares)
            .map(|(g, a)| {
                let n = f64::from(g.1);
                a * a * n * (g.2.variance(mu) * (1.0 - 2.0 / total) + s / (total * total))
            })
            .sum::<f64>();
    let est: Vec<f64> = out
        .var_of_mean
        .iter()
        .flat_map(|v| v.iter().map(|&x| f64::from(x)))
        .collect();
    let m = est.iter().sum::<f64>() / est.len() as f64;
    let sd = (est.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (est.len() - 1) as f64).sqrt();
    let z = (m - expected_var) / (sd / (est.len() as f64).sqrt());
    assert!(
        z.abs() < z_max,
        "mean error bar {m} against {expected_var} (z {z:.2}); true variance {optimal}"
    );
    drop(passes);
}

/// The per-pixel value of the same-half (defective) estimator: weights estimated on the half
/// a pixel lies in applied to that pixel.
fn self_weighted_mean(out: &Combination, passes: &Passes, w: usize) -> f64 {
    let npix = passes[0].1.len();
    let mut total = 0.0;
    for p in 0..npix {
        let half = (p % w + p / w) % 2;
        for (id, px) in passes {
            let g = out.groups.iter().find(|g| g.group == *id).unwrap();
            for &x in &px[p] {
                total += g.pass_weight[half] * f64::from(x);
            }
        }
    }
    total / (3 * npix) as f64
}

/// Mean and standard error over trials.
fn mean_se(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// A firefly pass weighted by its own half's variance loses energy (a half with more fireflies
/// has a larger `V` and a smaller weight): the cross-half weights keep the image's mean at `μ`
/// (z-test over 20 000 renders), while the self-weighted estimator computed from the same
/// renders is biased low at a significance the test demands. Without the cap, so that the
/// firefly pass carries a large weight.
#[test]
fn cross_half_weights_are_unbiased_and_self_weights_are_not() {
    let (w, h, mu) = (8usize, 8usize, 1.0f64);
    let options = CombineOptions {
        cap_at_largest_group: false,
        ..CombineOptions::default()
    };
    let groups = [(0u32, 1u32, Noise::Firefly(0.1)), (1, 4, Noise::Gauss(5.0))];
    let mut rng = Rng::new(0xb1a5);
    let trials = 20_000;
    let (mut cross, mut own) = (Vec::new(), Vec::new());
    let mut firefly_share = 0.0;
    for _ in 0..trials {
        let (c, passes) = render(w, h, mu, &groups, options, &mut rng);
        let out = c.combine();
        if out.fell_back {
            continue;
        }
        firefly_share += out.groups[0].share / f64::from(trials);
        cross.push(image_mean(&out.pixels));
        own.push(self_weighted_mean(&out, &passes, w));
    }
    assert!(cross.len() > trials as usize * 9 / 10);
    // The firefly pass must matter for the test to mean anything.
    assert!(firefly_share > 0.3, "firefly share {firefly_share}");
    assert_unbiased_and_control_low(
        "cross-half mean (control: self-weighted)",
        mean_se(&cross),
        mean_se(&own),
        mu,
    );
}

/// Six one-pass groups and one of 60 passes, all the same firefly estimator (`q = 0.02`):
/// the plain mean is optimal. A one-pass group without a firefly on a half reports a small `V`;
/// uncapped, it is weighted up and the MSE rises significantly above the plain mean's (paired
/// over 600 renders). The cap keeps every weight at or below the largest group's, and its MSE
/// is significantly below the uncapped one.
#[test]
fn the_cap_keeps_one_pass_groups_of_a_heavy_tailed_estimator_from_being_weighted_up() {
    let (w, h, mu) = (32usize, 24usize, 1.0f64);
    let noise = Noise::Firefly(0.02);
    let mut groups: Vec<(u32, u32, Noise)> = (0..6).map(|i| (i, 1, noise)).collect();
    groups.push((100, 60, noise));
    let capped = CombineOptions::default();
    let uncapped = CombineOptions {
        cap_at_largest_group: false,
        ..capped
    };
    let mut rng = Rng::new(0xca9);
    let sq = |px: &[[f32; 3]]| {
        px.iter()
            .map(|v| v.iter().map(|&x| (f64::from(x) - mu).powi(2)).sum::<f64>())
            .sum::<f64>()
            / (3 * px.len()) as f64
    };
    let (mut worse_uncapped, mut better_capped) = (Vec::new(), Vec::new());
    for _ in 0..600 {
        let (mut c, passes) = render(w, h, mu, &groups, uncapped, &mut rng);
        let out_uncapped = c.combine();
        // The same passes, capped.
        let mut c2 = PassCombiner::new(w, h, capped).unwrap();
        for (id, px) in &passes {
            c2.add_pass(*id, px).unwrap();
        }
        let out_capped = c2.combine();
        // The plain mean: every pass in one group.
        c = PassCombiner::new(w, h, capped).unwrap();
        for (_, px) in &passes {
            c.add_pass(0, px).unwrap();
        }
        let plain = c.combine();
        assert!(plain.fell_back);
        for g in &out_capped.groups {
            let largest = out_capped.groups.last().unwrap();
            for half in 0..2 {
                assert!(g.pass_weight[half] <= largest.pass_weight[half] * (1.0 + 1e-12));
            }
        }
        let (e_u, e_c, e_p) = (
            sq(&out_uncapped.pixels),
            sq(&out_capped.pixels),
            sq(&plain.pixels),
        );
        worse_uncapped.push(e_u - e_p);
        better_capped.push(e_u - e_c);
    }
    let z_max = z_critical_one_sided(2);
    let (m, se) = mean_se(&worse_uncapped);
    assert!(
        m / se > z_max,
        "uncapped MSE should exceed the plain mean's: {m} ± {se}"
    );
    let (m, se) = mean_se(&better_capped);
    assert!(
        m / se > z_max,
        "capped MSE should be below the uncapped: {m} ± {se}"
    );
}

#[test]
fn bad_input_is_rejected_and_degenerate_images_fall_back() {
    assert!(matches!(
        PassCombiner::new(0, 4, CombineOptions::default()),
        Err(GuidingError::InvalidConfig(_))
    ));
    for epsilon in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let options = CombineOptions {
            epsilon,
            ..CombineOptions::default()
        };
        assert!(
            matches!(
                PassCombiner::new(4, 4, options),
                Err(GuidingError::InvalidConfig(_))
            ),
            "epsilon {epsilon}"
        );
    }
    let mut c = PassCombiner::new(4, 4, CombineOptions::default()).unwrap();
    assert!(matches!(
        c.add_pass(0, &[[1.0; 3]; 15]),
        Err(GuidingError::LengthMismatch { .. })
    ));
    assert_eq!(c.passes(), 0);
    // Black passes in two groups: no usable variance, the plain mean (zero).
    c.add_pass(0, &[[0.0; 3]; 16]).unwrap();
    c.add_pass(1, &[[0.0; 3]; 16]).unwrap();
    let out = c.combine();
    assert!(out.fell_back);
    assert!(out.pixels.iter().all(|v| *v == [0.0; 3]));
    assert_eq!(out.predicted_gain(), 1.0);
    // Non-finite values count as 0: finite output, no NaN in the error bars.
    let mut c = PassCombiner::new(4, 4, CombineOptions::default()).unwrap();
    let mut rng = Rng::new(7);
    for g in 0..3u32 {
        let mut px = pass(16, 1.0, Noise::Gauss(0.5), &mut rng);
        px[3] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        c.add_pass(g, &px).unwrap();
    }
    assert_eq!((c.passes(), c.group_count()), (3, 3));
    let out = c.combine();
    assert!(out
        .pixels
        .iter()
        .chain(&out.var_of_mean)
        .all(|v| v.iter().all(|x| x.is_finite())));
    let shares: f64 = out.groups.iter().map(|g| g.share).sum();
    assert!((shares - 1.0).abs() < 1e-9, "shares sum to {shares}");
}

/// Four passes: one of a firefly estimator (`q = 0.05`), three Gaussian. With denominators from
/// the other half (independent of a pixel's values), `E[V_g] = E[D_g / n_g] · E[w]` with the same
/// `w` for both groups, so the ratio of the groups' mean `V` over renders is the ratio of
/// `E[D_g] / n_g = σ_g² (1 − 2/N) + S/N²` (z-test, delta-method standard error over 300 renders).
/// Self-normalised (the denominator from the pixel's own mean), a firefly raises its own
/// denominator and the ratio falls significantly below it: the defect the probe avoids.
#[test]
fn other_half_denominators_tell_few_heavy_tailed_passes_apart() {
    let (w, h, mu) = (32usize, 24usize, 1.0f64);
    let firefly = Noise::Firefly(0.05);
    let gauss = Noise::Gauss((firefly.variance(mu) / 4.0).sqrt());
    let groups = [(0u32, 1u32, firefly), (1, 3, gauss)];
    let total = 4.0;
    let s_all = firefly.variance(mu) + 3.0 * gauss.variance(mu);
    let e_d = |v: f64| v * (1.0 - 2.0 / total) + s_all / (total * total);
    let expected = e_d(firefly.variance(mu)) / e_d(gauss.variance(mu));
    let mut rng = Rng::new(0xde70);
    let trials = 300;
    let mut v = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    for _ in 0..trials {
        let (c, _) = render(w, h, mu, &groups, CombineOptions::default(), &mut rng);
        for (k, d) in [Denominator::OtherHalf, Denominator::SameHalf]
            .into_iter()
            .enumerate()
        {
            let out = c.combine_with(d);
            for (g, acc) in out.groups.iter().zip(&mut v[k]) {
                let r = &g.relative_variance;
                acc.push((r[0] + r[1]) / 2.0);
            }
        }
    }
    // Ratio of means and its delta-method standard error.
    let ratio = |a: &[f64], b: &[f64]| {
        let n = a.len() as f64;
        let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
        let (mut vaa, mut vbb, mut vab) = (0.0, 0.0, 0.0);
        for (x, y) in a.iter().zip(b) {
            vaa += (x - ma) * (x - ma) / (n - 1.0);
            vbb += (y - mb) * (y - mb) / (n - 1.0);
            vab += (x - ma) * (y - mb) / (n - 1.0);
        }
        let r = ma / mb;
        let var = r * r * (vaa / (ma * ma) + vbb / (mb * mb) - 2.0 * vab / (ma * mb)) / n;
        (r, var.sqrt())
    };
    assert_unbiased_and_control_low(
        "other-half ratio (control: self-normalised)",
        ratio(&v[0][0], &v[0][1]),
        ratio(&v[1][0], &v[1][1]),
        expected,
    );
}

/// The per-band variances (the evidence intervals' input) are the halves' variances cut into
/// bands of rows: with 64 rows in 32 equal bands, the mean over the bands is the two halves'
/// mean `V_g` (rounding aside), for either denominator, and every band is finite.
#[test]
fn band_variances_average_to_the_group_variance() {
    let (w, h) = (20, 64);
    let mut rng = Rng::new(77);
    let groups = [(0, 1, Noise::Gauss(0.3)), (1, 5, Noise::Gauss(0.1))];
    let (c, _) = render(w, h, 1.0, &groups, CombineOptions::default(), &mut rng);
    for denominator in [Denominator::SameHalf, Denominator::OtherHalf] {
        let whole = c.combine_with(denominator);
        let bands = c.band_variances(denominator);
        assert_eq!(bands.len(), whole.groups.len());
        for ((id, v), g) in bands.iter().zip(&whole.groups) {
            assert_eq!(*id, g.group);
            assert_eq!(v.len(), 32);
            assert!(v.iter().all(|x| x.is_finite() && *x > 0.0), "{v:?}");
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let expected = g.mean_relative_variance();
            assert!(
                (mean / expected - 1.0).abs() < 1e-12,
                "group {id}: bands {mean}, halves {expected}"
            );
        }
    }
}
