//! Tests of the guided integrator. Run with `cargo test --release -p host-demo --test guided`
//! (about 10-20 s on 2 cores; debug builds use smaller images).
//!
//! Unbiasedness is a z-test on the image mean: the two images are rendered with different
//! seeds (independent), so `Var(mean_a − mean_b) = se_a² + se_b²` with each standard error
//! from the per-pixel sample variances (`Image::mean_std_error`: pixels are independent, so
//! `Var(mean) = Σ_p Var(pixel_p) / P²`). By the CLT the difference is normal; 4.5σ gives a
//! two-sided false-alarm rate of 7·10⁻⁶ per channel, ~10⁻⁴ for the 12 channel comparisons.

use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;
use host_demo::render::strategy::guide::{build_guide, GuideKind, ModelSize};
use host_demo::render::{render, Image, IntegratorKind, RenderOptions};
use host_demo::render::{render_guided, GuidedOptions, GuidedStats};
use host_demo::scene::builtin::load_builtin;
use host_demo::scene::Scene;

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
    kind: GuideKind,
    target: Target,
    size: ModelSize,
    o: &RenderOptions,
    nee: bool,
    steps: u32,
    batch: usize,
) -> (Image, GuidedStats) {
    let config = FieldConfig::DEFAULT
        .with_batch_size(batch)
        .with_steps_per_update(steps)
        .with_learning_rate(1e-2)
        .with_threads(o.threads)
        .with_seed(o.seed as u32);
    let mut g = build_guide(kind, target, size, scene.bounds(), 0.5, config).expect("guide");
    // Every training pass takes `steps` Adam steps (the cap): these tests are about what a
    // trained guide does, not about the step schedule.
    let gopts = GuidedOptions {
        nee,
        train_epochs: f32::MAX,
        ..GuidedOptions::default()
    };
    render_guided(scene, o, &gopts, &mut g)
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
    let (rm, rse) = (reference.mean(), reference.mean_std_error());
    let cases = [
        (GuideKind::Npm, Target::Product),
        (GuideKind::Npm, Target::Radiance),
        (GuideKind::Nasg, Target::Product),
        (GuideKind::DfN, Target::Product),
        (GuideKind::DfL, Target::Product),
    ];
    for (i, (kind, target)) in cases.into_iter().enumerate() {
        let o = opts(IntegratorKind::PtNee, 32, w, h, 100 + i as u64, 0);
        let (img, st) = guided(&scene, kind, target, ModelSize::Small, &o, true, 2, 4096);
        assert!(img.all_finite());
        assert!(st.training_steps > 0 && st.guide_queries > 0);
        let (m, se) = (img.mean(), img.mean_std_error());
        for c in 0..3 {
            let sigma = (se[c] * se[c] + rse[c] * rse[c]).sqrt();
            eprintln!(
                "{kind:?} {target:?} ch{c}: guided {:.5} pt-nee {:.5} sigma {:.5} z {:.2}",
                m[c],
                rm[c],
                sigma,
                (m[c] - rm[c]) / sigma
            );
            assert!(
                (m[c] - rm[c]).abs() <= Z * sigma + 1e-6,
                "{kind:?} {target:?} channel {c}: {} vs {} (sigma {sigma})",
                m[c],
                rm[c]
            );
        }
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
        GuideKind::Npm,
        Target::Product,
        ModelSize::Small,
        &o,
        false,
        2,
        4096,
    );
    let (m, se, rm, rse) = (
        img.mean(),
        img.mean_std_error(),
        reference.mean(),
        reference.mean_std_error(),
    );
    for c in 0..3 {
        let sigma = (se[c] * se[c] + rse[c] * rse[c]).sqrt();
        eprintln!(
            "no-NEE ch{c}: guided {:.5} pt-nee {:.5} sigma {:.5}",
            m[c], rm[c], sigma
        );
        assert!((m[c] - rm[c]).abs() <= Z * sigma + 1e-6);
    }
}

/// (b) The trained NPM product guide (demo size, no NEE) lowers the mean per-pixel variance
/// against pt at equal spp on the Cornell box, by a margin: ratio < 0.8 (measured ~0.6; the
/// variance estimate over 4096 pixels × 3 channels has a relative standard error of a few
/// percent, so 0.8 only fails if guiding helps by less than ~20 %). The training passes
/// (30 %, the first with an untrained guide) are part of the guided image.
///
/// The door scene's numbers are printed too but not asserted: with this short training
/// budget the guide barely learns the light path through the door gap (see the report).
#[test]
fn guided_reduces_variance() {
    let spp = 32;
    for (name, w, h, assert_it) in [
        ("cornell-box", res(64), res(64), true),
        ("door", res(80), res(60), false),
    ] {
        let scene = load_builtin(name).unwrap();
        let pt = render(&scene, &opts(IntegratorKind::Pt, spp, w, h, 5, 0));
        let o = opts(IntegratorKind::Pt, spp, w, h, 6, 0);
        let (g, st) = guided(
            &scene,
            GuideKind::Npm,
            Target::Product,
            ModelSize::Demo,
            &o,
            false,
            16,
            8192,
        );
        let (vp, vg) = (mean_pixel_variance(&pt), mean_pixel_variance(&g));
        eprintln!("{st}");
        eprintln!(
            "{name} {w}x{h} {spp} spp: pt mean {:?} var {vp:.3e}; guided (no NEE) mean {:?} var {vg:.3e}; ratio {:.3}",
            pt.mean(),
            g.mean(),
            vg / vp
        );
        if assert_it && !cfg!(debug_assertions) {
            assert!(
                vg < 0.8 * vp,
                "{name}: guided variance {vg} not below 0.8 x pt {vp}"
            );
        }
    }
}

/// (c) Training really stops after the training fraction: no samples recorded, no steps
/// taken, and the guide queries of the remaining passes are inference only.
#[test]
fn training_stops_after_fraction() {
    let scene = load_builtin("cornell-box").unwrap();
    let o = opts(IntegratorKind::PtNee, 10, res(24), res(24), 9, 0);
    let (_, st) = guided(
        &scene,
        GuideKind::Npm,
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
            GuideKind::Nasg,
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
