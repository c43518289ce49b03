//! Tests of the guided integrator. Run with `cargo test --release -p host-demo --test guided`
//! (about 20-30 s on 2 cores, half of it the door; debug builds use smaller images, except for
//! the Cornell variance case, and ignore the door).
//!
//! Unbiasedness is a z-test on the image mean: the two images are rendered with different
//! seeds (independent), so `Var(mean_a − mean_b) = se_a² + se_b²` with each standard error
//! from the per-pixel sample variances (`Image::mean_std_error`: pixels are independent, so
//! `Var(mean) = Σ_p Var(pixel_p) / P²`). By the CLT the difference is normal; 4.5σ gives a
//! two-sided false-alarm rate of 7·10⁻⁶ per channel, ~10⁻⁴ for the 12 channel comparisons.

mod common;

use common::{guide, npm_guide, training_config};
use guiding::{GuidingField, LookDecision, ModelSize, Representation};
use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;
use host_demo::render::{render, Image, IntegratorKind, RenderOptions};
use host_demo::render::{render_guided, GuidedOptions, GuidedStats, TestHooks};
use host_demo::scene::builtin::load_builtin;
use host_demo::scene::Scene;

/// Reproducible training ([`guiding::StepRule::Epochs`]): the first `train_fraction` of the
/// budget trains, `epochs` passes over each training pass's samples (capped by the field's
/// `steps_per_update`).
fn epochs(train_fraction: f64, epochs: f64) -> guiding::ScheduleOptions {
    guiding::ScheduleOptions {
        train_fraction,
        steps: guiding::StepRule::Epochs(epochs),
        ..guiding::ScheduleOptions::DEFAULT
    }
}

/// The library's time-driven schedule with another training fraction.
fn time_share(train_fraction: f64) -> guiding::ScheduleOptions {
    guiding::ScheduleOptions {
        train_fraction,
        ..guiding::ScheduleOptions::DEFAULT
    }
}

const Z: f64 = 4.5;

fn res(n: u32) -> u32 {
    if cfg!(debug_assertions) {
        (n / 4).max(8)
    } else {
        n
    }
}

fn opts(
    kind: IntegratorKind,
    spp: u32,
    w: u32,
    h: u32,
    seed: u64,
    threads: usize,
) -> RenderOptions {
    RenderOptions {
        integrator: kind,
        spp,
        max_depth: 8,
        threads,
        seed,
        width: w,
        height: h,
        ..RenderOptions::default()
    }
}

#[allow(clippy::too_many_arguments)]
fn guided(
    scene: &Scene,
    kind: Representation,
    target: Target,
    size: ModelSize,
    o: &RenderOptions,
    nee: bool,
    steps: u32,
    batch: usize,
) -> (Image, GuidedStats) {
    let config = training_config(batch, steps, o.seed as u32).with_threads(o.threads);
    let mut g = guide(kind, target, size, scene, 0.5, config);
    // Every training pass takes `steps` Adam steps (the cap): these tests are about what a
    // trained guide does, not about the step schedule; their pass counts are written for a
    // training fraction of 0.3 (not the default's).
    let gopts = GuidedOptions {
        nee,
        schedule: epochs(0.3, 1e6),
        ..GuidedOptions::default()
    };
    render_guided(scene, o, &gopts, &mut g).expect("guided render")
}

/// The small NPM radiance guide of the time-budget tests.
fn small_npm_radiance(scene: &Scene, config: FieldConfig) -> GuidingField {
    npm_guide(Target::Radiance, ModelSize::Small, scene, config)
}

/// The compact NPM radiance guide of the door and shared-scene tests.
fn compact_npm_radiance(scene: &Scene, selection: f32, config: FieldConfig) -> GuidingField {
    guide(
        Representation::Npm,
        Target::Radiance,
        ModelSize::Compact,
        scene,
        selection,
        config,
    )
}

/// Asserts that `img`'s mean agrees with `reference`'s within `Z` combined standard errors,
/// per channel.
fn assert_same_mean(label: &str, img: &Image, reference: &Image) {
    let (m, se) = (img.mean(), img.mean_std_error());
    let (rm, rse) = (reference.mean(), reference.mean_std_error());
    for c in 0..3 {
        let sigma = (se[c] * se[c] + rse[c] * rse[c]).sqrt();
        eprintln!(
            "{label} ch{c}: {:.5} against pt-nee {:.5}, sigma {:.5}, z {:.2}",
            m[c],
            rm[c],
            sigma,
            (m[c] - rm[c]) / sigma
        );
        assert!(
            (m[c] - rm[c]).abs() <= Z * sigma + 1e-6,
            "{label} channel {c}: {} against {} (sigma {sigma})",
            m[c],
            rm[c]
        );
    }
}

/// Mean over pixels and channels of the per-pixel variance of the mean.
fn mean_pixel_variance(img: &Image) -> f64 {
    let s: f64 = img
        .var_of_mean
        .iter()
        .map(|v| v.iter().map(|&c| c as f64).sum::<f64>())
        .sum();
    s / (3.0 * img.var_of_mean.len().max(1) as f64)
}

/// (a) Every guide (small presets, product target; NPM also radiance) is unbiased on the
/// Cornell box: its mean agrees with pt-nee within Z combined standard errors.
#[test]
fn guided_unbiased_cornell() {
    let scene = load_builtin("cornell-box").unwrap();
    let (w, h) = (res(48), res(48));
    let reference = render(&scene, &opts(IntegratorKind::PtNee, 64, w, h, 1, 0));
    let cases = [
        (Representation::Npm, Target::Product),
        (Representation::Npm, Target::Radiance),
        (Representation::Nasg, Target::Product),
        (Representation::DfNearest, Target::Product),
        (Representation::DfLinear, Target::Product),
    ];
    for (i, (kind, target)) in cases.into_iter().enumerate() {
        let o = opts(IntegratorKind::PtNee, 32, w, h, 100 + i as u64, 0);
        let (img, st) = guided(&scene, kind, target, ModelSize::Small, &o, true, 2, 4096);
        assert!(img.all_finite_non_negative());
        assert!(st.training_steps > 0 && st.guide_queries > 0);
        assert_same_mean(&format!("{kind:?} {target:?}"), &img, &reference);
    }
}

/// (a') Without NEE (pure one-sample MIS of guide and BSDF) the guided mean agrees as well.
#[test]
fn guided_unbiased_cornell_no_nee() {
    let scene = load_builtin("cornell-box").unwrap();
    let (w, h) = (res(32), res(32));
    let reference = render(&scene, &opts(IntegratorKind::PtNee, 64, w, h, 3, 0));
    let o = opts(IntegratorKind::Pt, 64, w, h, 4, 0);
    let (img, _) = guided(
        &scene,
        Representation::Npm,
        Target::Product,
        ModelSize::Small,
        &o,
        false,
        2,
        4096,
    );
    assert_same_mean("no-NEE", &img, &reference);
}

/// (b) The trained NPM product guide (demo size, no NEE) lowers the mean per-pixel variance
/// against pt at equal spp on the Cornell box, by a margin: ratio < 0.8 (measured ~0.6; the
/// variance estimate over 4096 pixels × 3 channels has a relative standard error of a few
/// percent, so 0.8 only fails if guiding helps by less than ~20 %). The training passes
/// (30 %, the first with an untrained guide) are part of the guided image.
///
/// Full size in debug builds too (unlike the other tests here: at 16 × 16 pixels the guide
/// has too few training samples to help, ratio 0.96), so it asserts there as well, with the
/// same numbers: ~1.5 s in release, ~25 s in debug. The door has its own test,
/// [`guided_reduces_variance_on_the_door`].
#[test]
fn guided_reduces_variance() {
    let spp = 32;
    let (w, h) = (64, 64);
    let scene = load_builtin("cornell-box").unwrap();
    let pt = render(&scene, &opts(IntegratorKind::Pt, spp, w, h, 5, 0));
    let o = opts(IntegratorKind::Pt, spp, w, h, 6, 0);
    let (g, st) = guided(
        &scene,
        Representation::Npm,
        Target::Product,
        ModelSize::Compact,
        &o,
        false,
        16,
        8192,
    );
    let (vp, vg) = (mean_pixel_variance(&pt), mean_pixel_variance(&g));
    eprintln!("{st}");
    eprintln!(
        "cornell-box {w}x{h} {spp} spp: pt mean {:?} var {vp:.3e}; guided (no NEE) mean {:?} var {vg:.3e}; ratio {:.3}",
        pt.mean(),
        g.mean(),
        vg / vp
    );
    assert!(
        vg < 0.8 * vp,
        "cornell-box: guided variance {vg} not below 0.8 x pt {vp}"
    );
}

/// Relative variance of `img`: the mean over pixels and channels of
/// `Var(pixel) / (R² + ε)`, `R` the pixel of an independent `reference` render and `ε` the
/// 0.01 of relMSE ([`host_demo::render::compare::EPSILON`]). This is the relMSE of `host-demo
/// compare` with the image's own per-pixel variance estimate in place of the squared error
/// (the estimators are unbiased, so their MSE is their variance, and the reference's noise
/// stays out); the fixed weights `1 / (R² + ε)` keep bright pixels from dominating. Returns
/// (value, relative standard error), the error from the spread of the per-pixel terms over
/// the `P` independent pixels, `sd / (√P · mean)` (an overestimate: the spread also holds the
/// true variation between pixels).
fn relative_variance(img: &Image, reference: &Image) -> (f64, f64) {
    let eps = host_demo::render::compare::EPSILON;
    let terms: Vec<f64> = img
        .var_of_mean
        .iter()
        .zip(&reference.pixels)
        .map(|(v, r)| {
            (0..3)
                .map(|c| f64::from(v[c]) / (f64::from(r[c]).powi(2) + eps))
                .sum::<f64>()
                / 3.0
        })
        .collect();
    let n = terms.len() as f64;
    let mean = terms.iter().sum::<f64>() / n;
    let var = terms.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt() / (n.sqrt() * mean))
}

/// Passes of the door's training render.
const DOOR_TRAIN_SPP: u32 = 32;
/// Samples per pixel of the door's compared renders.
const DOOR_SPP: u32 = 128;
/// The door's guided relative variance must be below this fraction of `pt-nee`'s.
const DOOR_MAX_RATIO: f64 = 0.6;

/// (b') A trained guide lowers the variance against unguided path tracing at equal spp on
/// `builtin:door`, whose camera room is lit only through the opening of a door: the relative
/// variance ([`relative_variance`]) of a guided render with a trained, frozen guide is below
/// [`DOOR_MAX_RATIO`] × `pt-nee`'s, 80 × 60 pixels, [`DOOR_SPP`] spp each, NEE in both.
///
/// Settings: the guide (NPM demo size, radiance target with the cosine product, selection
/// probability 0.3) trains on its own render first ([`DOOR_TRAIN_SPP`] passes at 80 × 60,
/// every pass training, 4 epochs per pass capped at 16 Adam steps of 8192 samples: ~500
/// steps) and is then frozen (`train_fraction = 0`), so the ratio is about what a trained
/// guide does per sample, not about its training passes. Relative variance rather than the
/// mean pixel variance of the Cornell case: on the slit door ~70 % of the mean pixel variance
/// sits in the one pixel column that sees the bright far room through the slit, and it comes
/// from the pixel footprint (part wall, part far room), which no guide can change (that ratio
/// is printed too: ~1.0).
///
/// Measured on Veach's door (door ajar by 20°, [`door_ratio_over_seeds`], 8 seed sets:
/// training, guided, `pt-nee` and reference seeds all changed): ratio 0.413, sd 0.036
/// (0.38–0.47); this test's seeds give 0.395 ± 0.031 (each relative variance has a relative
/// standard error of 4–8 %, which matches the spread over seeds). `DOOR_MAX_RATIO = 0.6` is
/// 5 standard deviations above the mean over seeds, and fails a guide that gains less than
/// 40 % per sample. Checked: with the training render removed (an untrained guide) the ratio
/// is 1.46 ± 0.19 and the test fails.
///
/// Tried on the earlier slit door and dropped (ratio ≥ 0.9, or noisier): the product target, selection
/// probability 0.5 / 0.2, NASG, DF-N / DF-L, the small and paper sizes, 1 or 16 Adam steps per
/// pass, learning rate 3·10⁻³ / 5·10⁻³, NEE off against `pt` (mean 0.78 but standard error
/// 0.12), online training with `train_fraction` 0.3–0.5 (1.1–1.4: the untrained passes cost
/// more than the guide saves), max depth 3–4.
///
/// Release builds only (ignored in debug builds, where the unoptimised host crate takes
/// ~130 s for it against 7–12 s in release); CI runs the tests in release.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only: ~130 s unoptimised, 7-12 s in release (CI runs release)"
)]
fn guided_reduces_variance_on_the_door() {
    let (ratio, se) = door_ratio(0);
    assert!(
        ratio < DOOR_MAX_RATIO,
        "door: guided relative variance {ratio:.3} (+- {se:.3}) x pt-nee's, not below {DOOR_MAX_RATIO}"
    );
}

/// The door case of [`guided_reduces_variance_on_the_door`] with seeds offset by `seed`:
/// (relative variance of the guided render / `pt-nee`'s, its standard error).
fn door_ratio(seed: u64) -> (f64, f64) {
    let scene = load_builtin("door").unwrap();
    let (w, h) = (80, 60);
    let config = training_config(8192, 16, 6 + seed as u32);
    let mut g = compact_npm_radiance(&scene, 0.3, config);
    let train = GuidedOptions {
        nee: true,
        schedule: epochs(1.0, 1.0),
        ..GuidedOptions::default()
    };
    let o = opts(IntegratorKind::PtNee, DOOR_TRAIN_SPP, w, h, 1000 + seed, 0);
    let (_, st) = render_guided(&scene, &o, &train, &mut g).expect("guided render");
    eprintln!("training render:\n{st}");
    assert_eq!(st.training_passes, DOOR_TRAIN_SPP);
    let frozen = GuidedOptions {
        schedule: epochs(0.0, 1.0),
        ..train
    };
    let o = opts(IntegratorKind::PtNee, DOOR_SPP, w, h, 6 + 10 * seed, 0);
    let (guided, st) = render_guided(&scene, &o, &frozen, &mut g).expect("guided render");
    assert_eq!(st.samples_recorded, 0);
    let pt_nee = render(
        &scene,
        &opts(IntegratorKind::PtNee, DOOR_SPP, w, h, 5 + 10 * seed, 0),
    );
    let reference = render(
        &scene,
        &opts(IntegratorKind::PtNee, 16, w, h, 7 + 10 * seed, 0),
    );
    let ((vg, eg), (vp, ep)) = (
        relative_variance(&guided, &reference),
        relative_variance(&pt_nee, &reference),
    );
    let ratio = vg / vp;
    let se = ratio * (eg * eg + ep * ep).sqrt();
    eprintln!(
        "door {w}x{h} {DOOR_SPP} spp: relative variance pt-nee {vp:.3e} (rse {ep:.3}), \
         guided {vg:.3e} (rse {eg:.3}); ratio {ratio:.3} +- {se:.3}; mean pixel variance \
         ratio {:.3}",
        mean_pixel_variance(&guided) / mean_pixel_variance(&pt_nee)
    );
    (ratio, se)
}

/// [`door_ratio`] over 8 seed sets: the measurement behind [`DOOR_MAX_RATIO`] (re-run it when
/// the door or the guide changes).
#[test]
#[ignore = "a measurement, run by hand: ~100 s"]
fn door_ratio_over_seeds() {
    let r: Vec<f64> = (0..8).map(|s| door_ratio(s).0).collect();
    let n = r.len() as f64;
    let m = r.iter().sum::<f64>() / n;
    let sd = (r.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    eprintln!("door ratio over {n} seed sets: {r:.3?}; mean {m:.3}, sd {sd:.3}");
}

/// (c) Training really stops after the training fraction: no samples recorded, no steps
/// taken, and the guide queries of the remaining passes are inference only.
#[test]
fn training_stops_after_fraction() {
    let scene = load_builtin("cornell-box").unwrap();
    let o = opts(IntegratorKind::PtNee, 10, res(24), res(24), 9, 0);
    let (_, st) = guided(
        &scene,
        Representation::Npm,
        Target::Product,
        ModelSize::Small,
        &o,
        true,
        3,
        1024,
    );
    eprintln!("{st}");
    assert_eq!(st.training_passes, 3);
    assert_eq!(st.samples_recorded_after_training, 0);
    assert_eq!(st.training_steps_after_training, 0);
    assert_eq!(st.training_steps, 3 * 3);
    assert!(st.samples_recorded > 0);
    assert!(st.guide_queries > st.guide_queries_training);
}

/// (d) A guided render (training included) is bit-identical with 1 and 2 threads.
#[test]
fn guided_deterministic_across_threads() {
    let scene = load_builtin("cornell-box").unwrap();
    let (w, h) = (res(24), res(24));
    let run = |threads| {
        let o = opts(IntegratorKind::PtNee, 6, w, h, 11, threads);
        guided(
            &scene,
            Representation::Nasg,
            Target::Product,
            ModelSize::Small,
            &o,
            true,
            2,
            1024,
        )
        .0
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.pixels, b.pixels);
}

/// The Cornell box at 32 × 32 (less in debug builds) and its 256 spp `pt-nee` reference
/// (seed 1): the setting of (e) to (g).
fn cornell_with_reference() -> (Scene, u32, u32, Image) {
    let scene = load_builtin("cornell-box").unwrap();
    let (w, h) = (res(32), res(32));
    let reference = render(&scene, &opts(IntegratorKind::PtNee, 256, w, h, 1, 0));
    (scene, w, h, reference)
}

/// (e) The efficiency trial of a time-budget render: after training and one warm-up pass it
/// alternates guided and unguided passes, 4 each (2 or 3 when the case is clear after that
/// many: the early verdict is checked whenever both arms have `k ≥ 2` passes); an interval
/// that still straddles 1 continues the trial (the guide on), and once a verdict is "does not
/// pay" every later pass runs with the guide off (each counted in the trial's statistics). The
/// image, whichever the verdict, stays unbiased (z-test against pt-nee as in (a)). An
/// spp-budget render never runs it.
#[test]
fn efficiency_trial_decides_once_and_keeps_the_image_unbiased() {
    let (scene, w, h, reference) = cornell_with_reference();
    let config = FieldConfig::DEFAULT.with_threads(2).with_seed(3);
    let small_npm = || small_npm_radiance(&scene, config);
    let mut g = small_npm();
    let o = RenderOptions {
        time_budget: Some(std::time::Duration::from_secs(3)),
        ..opts(IntegratorKind::PtNee, 1, w, h, 5, 2)
    };
    // The training probe (tested in (g)) would often end training on this scene before the
    // trial.
    let gopts = GuidedOptions {
        schedule: time_share(0.3),
        training_probe: false,
        ..GuidedOptions::default()
    };
    let (img, st) = render_guided(&scene, &o, &gopts, &mut g).expect("guided render");
    eprintln!("{st}");
    let trial = st.trial.as_ref().expect("the trial ran");
    let after_trial_start = st.passes - st.training_passes - 1;
    match (trial.verdict, trial.first_look) {
        (Some(v), None) => {
            // Decided at the first look: 4 passes per arm, or 2 or 3 in a clear case.
            assert!((2..=4).contains(&v.guided_passes));
            assert_eq!(v.guided_passes, v.unguided_passes);
            assert_eq!(trial.passes, 2 * v.guided_passes);
        }
        (verdict, Some(first)) => {
            // The first look straddled: the trial went on (a verdict, if any, came later).
            assert_eq!((first.guided_passes, first.unguided_passes), (4, 4));
            assert!(first.ratio_low <= 1.0 && first.ratio_high >= 1.0);
            assert!(trial.passes > 8);
            assert!(verdict.is_some() || trial.passes == after_trial_start);
        }
        (None, None) => panic!("3 s of a 32 x 32 image reach the trial's first look"),
    }
    let expected_off = match trial.verdict {
        Some(v) if !v.keep_guide => after_trial_start - trial.passes,
        _ => 0,
    };
    assert_eq!(trial.passes_guide_off, expected_off);
    // The verdict, or the estimate of a trial still running (none only when the render ended
    // within 2 passes of the guided arm's restart).
    match trial.verdict.or(trial.latest) {
        Some(v) => {
            assert!(v.guided_seconds > 0.0 && v.unguided_seconds > 0.0);
            assert!(v.cost_ratio.is_finite());
            assert!(v.ratio_low <= v.cost_ratio && v.cost_ratio <= v.ratio_high);
        }
        None => assert!(trial.restarted),
    }
    assert_same_mean("trial", &img, &reference);
    // The same render with an spp budget: no trial.
    let mut g = small_npm();
    let o = opts(IntegratorKind::PtNee, 16, w, h, 5, 2);
    let (_, st) = render_guided(&scene, &o, &gopts, &mut g).expect("guided render");
    assert!(st.trial.is_none());
}

/// (f) The inverse-variance combination of passes: with it (the default) a guided render's
/// stats report a group per training pass plus the steady groups, with shares summing to 1,
/// and the weighted image stays unbiased (z-test against pt-nee as in (a)); without it no
/// combination runs and the image is the plain mean of the same passes.
#[test]
fn pass_weights_keep_the_image_unbiased() {
    let (scene, w, h, reference) = cornell_with_reference();
    let config = FieldConfig::DEFAULT.with_threads(2).with_seed(4);
    let o = opts(IntegratorKind::PtNee, 64, w, h, 9, 2);
    let run = |weight_passes: bool| {
        let mut g = small_npm_radiance(&scene, config);
        let gopts = GuidedOptions {
            schedule: time_share(0.3),
            weight_passes,
            ..GuidedOptions::default()
        };
        render_guided(&scene, &o, &gopts, &mut g).expect("guided render")
    };
    let (img, st) = run(true);
    eprintln!("{st}");
    let weights = st.pass_weights.as_ref().expect("the combination ran");
    let training_groups = weights
        .groups
        .iter()
        .filter(|g| g.group < host_demo::render::strategy::guided::GROUP_UNGUIDED)
        .count();
    assert_eq!(training_groups as u32, st.training_passes);
    let passes: u32 = weights.groups.iter().map(|g| g.passes).sum();
    assert_eq!(passes, st.passes);
    let shares: f64 = weights.groups.iter().map(|g| g.share).sum();
    assert!((shares - 1.0).abs() < 1e-9, "shares sum to {shares}");
    assert!(weights.predicted_gain.is_finite() && weights.predicted_gain > 0.0);
    assert!(img.all_finite_non_negative());
    assert_same_mean("weighted passes", &img, &reference);
    let (plain, st) = run(false);
    assert!(st.pass_weights.is_none());
    assert_same_mean("plain mean", &plain, &reference);
}

/// (g) The training probe: a quarter of the way into the training phase, once the guide has
/// had `guiding::EARLY_LOOK_MIN_STEPS` Adam steps, training pauses for an early look (guided
/// passes from the guide cache against unguided ones, nothing recorded). Forced to end
/// training, the look's pass is where training stopped, the guide keeps the steps it had and
/// goes on to the efficiency trial (the probe never switches it off); forced to go on,
/// training resumes after the look and its phase ends as much later. Every image stays
/// unbiased (z-test against pt-nee as in (a)); with the probe off there is no look.
#[test]
fn training_probe_decides_how_long_to_train_and_keeps_the_image_unbiased() {
    let (scene, w, h, reference) = cornell_with_reference();
    // 64 steps per training pass (the epoch rule, capped), so the look's 64 steps are there
    // after the first training pass however loaded the machine is.
    let config = FieldConfig::DEFAULT
        .with_threads(2)
        .with_seed(5)
        .with_batch_size(1024)
        .with_steps_per_update(64);
    let o = RenderOptions {
        time_budget: Some(std::time::Duration::from_secs(3)),
        ..opts(IntegratorKind::PtNee, 1, w, h, 11, 2)
    };
    let run_with =
        |training_probe: bool, probe_force: Option<LookDecision>, weight_passes: bool| {
            let mut g = small_npm_radiance(&scene, config);
            let gopts = GuidedOptions {
                schedule: epochs(0.5, 1e6),
                training_probe,
                weight_passes,
                test_hooks: TestHooks {
                    probe_force,
                    ..TestHooks::default()
                },
                ..GuidedOptions::default()
            };
            render_guided(&scene, &o, &gopts, &mut g).expect("guided render")
        };
    let run = |training_probe, probe_force| run_with(training_probe, probe_force, true);
    let (img, st) = run(true, Some(LookDecision::EndTraining));
    eprintln!("{st}");
    let probe = st.probe.expect("the look ran");
    let v = probe.verdict.expect("the look's estimate");
    assert!(probe.steps >= guiding::EARLY_LOOK_MIN_STEPS && !probe.resumed());
    assert_eq!(probe.looks, 1);
    assert!(probe.at_pass >= 1 && probe.passes >= 4, "{probe:?}");
    assert_eq!(probe.passes, v.guided_passes + v.unguided_passes);
    assert!(v.cost_ratio.is_finite() && v.cost_ratio > 0.0);
    // Training ended at the look, with the steps the guide had there.
    assert_eq!(st.training_passes, probe.at_pass);
    assert_eq!(st.training_steps, probe.steps);
    assert_eq!(st.samples_recorded_after_training, 0);
    // The guide went on to the trial: the look does not switch it off.
    assert!(st.trial.is_some());
    assert_same_mean("look ended training", &img, &reference);

    let (img, st) = run(true, Some(LookDecision::TrainOn));
    eprintln!("{st}");
    let probe = st.probe.expect("the look ran");
    assert!(probe.resumed() && probe.verdict.is_some());
    // One look: the guide paid, no more looks; training resumed after the look's passes,
    // which recorded nothing.
    assert_eq!(probe.looks, 1, "{st}");
    assert!(st.training_passes > probe.at_pass, "{st}");
    assert!(st.training_steps > probe.steps);
    assert_eq!(st.samples_recorded_after_training, 0);
    assert_same_mean("look resumed training", &img, &reference);

    // No evidence either way at every look: training goes on to a look at each later quarter
    // of the phase (1/2, 3/4; the third may not fit a loaded machine's phase), then to its end.
    let (img, st) = run(true, Some(LookDecision::LookAgain));
    eprintln!("{st}");
    let probe = st.probe.expect("the looks ran");
    assert!(probe.resumed() && probe.verdict.is_some());
    assert!((2..=3).contains(&probe.looks), "{st}");
    // Training went on after the last look (its pass index also counts the earlier looks'
    // passes, so compare steps).
    assert!(st.training_steps > probe.steps, "{st}");
    assert_eq!(st.samples_recorded_after_training, 0);
    assert_same_mean("looks again", &img, &reference);

    let (_, st) = run(false, None);
    assert!(st.probe.is_none());

    // Without pass weights the look still gets its passes' images and decides.
    let (_, st) = run_with(true, Some(LookDecision::EndTraining), false);
    let probe = st.probe.expect("the look ran");
    assert!(probe.verdict.is_some() && st.pass_weights.is_none(), "{st}");
    assert_eq!(st.training_passes, probe.at_pass);
}

/// (h) A guide that truly does not pay is switched off: on the shared Cornell box (diffuse
/// walls, one area light; BSDF sampling and NEE already sample it well) an NPM guide selected
/// with probability 0.9 costs about twice `pt-nee` per second (measured 2.0, interval
/// [1.8, 2.2], at 128 px and 8 s; with the default per-cell fit it is 1.2 [1.08, 1.36], also
/// off): the trial's interval lies above 1 and the guide is off for every pass after it. The
/// same rule keeps a guide whose interval straddles 1 (`tests/guide_trial.rs`) and one whose
/// early passes looked bad ((g): the training probe's early look only decides how long to
/// train, never whether the guide stays on).
#[test]
fn a_guide_that_does_not_pay_on_the_cornell_box_is_switched_off() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/scenes/cornell-box/scene.xml"
    );
    if !std::path::Path::new(path).exists() {
        eprintln!("skipped: {path} not found");
        return;
    }
    let scene = host_demo::load_scene(path).expect("the shared Cornell box loads");
    let config = FieldConfig::DEFAULT.with_threads(2).with_seed(8);
    let mut g = compact_npm_radiance(&scene, 0.9, config);
    let o = RenderOptions {
        time_budget: Some(std::time::Duration::from_secs(8)),
        ..opts(IntegratorKind::PtNee, 1, 128, 128, 3, 2)
    };
    let gopts = GuidedOptions {
        selection_probability: 0.9,
        fit_selection: false,
        ..GuidedOptions::default()
    };
    let (_, st) = render_guided(&scene, &o, &gopts, &mut g).expect("guided render");
    eprintln!("{st}");
    let trial = st.trial.as_ref().expect("the trial ran");
    let v = trial.verdict.expect("8 s finish the trial");
    assert_eq!(v.evidence, guiding::Verdict::DoesNotPay, "{v:?}");
    assert!(!v.keep_guide && v.ratio_low > 1.0);
    assert!(trial.passes_guide_off > 0);
}

/// A guide whose device fails ends the render with the device's error (never a render with
/// untrained CPU weights); with `FallbackToCpu` the render completes on the CPU. Skipped
/// without a Vulkan device or SPIR-V, unless `GUIDING_REQUIRE_VULKAN=1`.
#[test]
fn a_device_failure_ends_the_render_with_its_error() {
    let Some(ctx) = common::vulkan_context() else {
        return;
    };
    let scene = load_builtin("cornell-box").expect("builtin");
    let o = opts(IntegratorKind::PtNee, 4, 16, 16, 3, 2);
    let config = FieldConfig::DEFAULT.with_batch_size(256).with_threads(2);
    for policy in [
        guiding::DeviceFailure::Error,
        guiding::DeviceFailure::FallbackToCpu,
    ] {
        let mut g = small_npm_radiance(&scene, config);
        g.use_device_context(ctx.clone(), policy).expect("device");
        g.fail_device_for_tests("injected");
        let result = render_guided(&scene, &o, &GuidedOptions::default(), &mut g);
        match policy {
            guiding::DeviceFailure::Error => match result {
                Err(guiding::GuidingError::Device(m)) => assert!(m.contains("injected"), "{m}"),
                other => panic!("expected the device's error, got {:?}", other.map(|r| r.1)),
            },
            guiding::DeviceFailure::FallbackToCpu => {
                let (img, st) = result.expect("the fallback renders on the CPU");
                assert!(img.mean().iter().all(|m| m.is_finite() && *m > 0.0));
                assert!(
                    st.training_steps > 0,
                    "trained on the CPU after the fallback"
                );
                assert!(g.device_name().is_none());
            }
        }
    }
}
