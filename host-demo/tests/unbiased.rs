//! Unbiasedness of every integrator per pixel block, from independent seeds.
//! Run with `cargo test --release -p host-demo --test unbiased` (about 10 s on 2 cores).
//!
//! The built-in Cornell box at 16 × 16 pixels is cut into 4 × 4 blocks of 4 × 4 pixels. Each
//! method renders it with `SEEDS` independent seeds (guided renders train their own guide per
//! seed, so the seeds — not the samples inside one render — are the independent
//! replications). Per block and channel, the seed means give the method's mean and standard
//! error `s / √n`; each method is compared with `pt-nee` by a two-sample test of
//! `t = (m_a − m_b) / √(s_a²/n + s_b²/n)`.
//!
//! Reference distribution: with 16 seeds the standard errors are themselves estimates
//! (15 degrees of freedom each), so `t` follows Student's t with the Welch–Satterthwaite
//! degrees of freedom rather than the normal law; using normal quantiles would give far more
//! false alarms at the small per-test levels below. For large seed counts it is the z-test.
//! The per-test level is Šidák-corrected over all `methods × blocks × channels` tests for a
//! family-wise false-alarm rate of 1 %.
//!
//! Power check, committed (`power_check_rejects_a_scaled_guide_pdf`): the guide pdf scaled by
//! 1.5 in the guided continuation's combined density (`TestHooks::guide_pdf_scale`, a test
//! hook) fails `guided npm` in 17 of its 48 block-channel tests, worst at t = −8.5, at the
//! per-test level of `all_integrators_agree_per_block`. By hand, not committed (it needs a
//! defect inside the renderer with no hook): setting the MIS weight of emission found by BSDF
//! sampling to 1 in pt-nee (direct light counted twice) fails `pt` and `guided npm no-NEE`
//! against pt-nee at |t| up to 12. The honest code passes with the smallest p-value ~1e-2
//! against a per-test level of 3.5e-5.
//!
//! `guided_media_agree_per_block_and_a_scaled_pdf_is_caught` does the same with participating
//! media (the fog box of `tests/media.rs`, medium vertices guided), with its own power check.
//!
//! The guides above train briefly and stay broad; `sharp_frozen_guides_agree_per_block`
//! trains guides until their lobes are sharp (measured), freezes them and compares the same
//! way, which catches biases that only show with sharp lobes.

mod common;

use common::{guide, npm_guide, sidak, training_config};
use guiding::{ModelSize, Representation};
use guiding_core::loss::Target;
use host_demo::render::{
    render, render_with_stats, Image, IntegratorKind, RenderOptions, Roulette,
};
use host_demo::render::{render_guided, CacheMode, GuidedOptions, GuidedStats, TestHooks};
use host_demo::scene::builtin::load_builtin;
use host_demo::scene::Scene;

/// Reproducible training for these seeded tests: one update per training pass of one epoch
/// over its samples (capped by the field's `steps_per_update`), the library's training
/// fraction. The time-driven default would make the trained guide, and so the seeds' outcome,
/// change from run to run.
const REPRODUCIBLE: guiding::ScheduleOptions = guiding::ScheduleOptions {
    steps: guiding::StepRule::Epochs(1.0),
    ..guiding::ScheduleOptions::DEFAULT
};

const SEEDS: u64 = 16;
const RES: u32 = 16;
const BLOCK: u32 = 4;
/// Samples per pixel of `pt-nee` and the guided renders per seed.
const SPP: u32 = 16;
/// Samples per pixel of `pt` per seed. Pure BSDF sampling of the small ceiling light is very
/// heavy-tailed in the shadowed blocks (per-sample coefficient of variation ~20 there), so at
/// 16 spp a block's seed means are far from normal (skewed: 16 seeds then underestimate both
/// mean and spread, and the test falsely rejects); 8× the samples bring the per-seed block
/// coefficient of variation to ~0.5.
const SPP_PT: u32 = 128;
const ALPHA: f64 = 0.01;

fn opts(kind: IntegratorKind, spp: u32, seed: u64) -> RenderOptions {
    RenderOptions {
        integrator: kind,
        spp,
        max_depth: 6,
        threads: 0,
        seed,
        width: RES,
        height: RES,
        ..RenderOptions::default()
    }
}

/// Block means (`[block][channel]`) of one image.
fn block_means(img: &Image) -> Vec<[f64; 3]> {
    let nb = RES / BLOCK;
    let mut out = vec![[0.0f64; 3]; (nb * nb) as usize];
    for y in 0..RES {
        for x in 0..RES {
            let b = ((y / BLOCK) * nb + x / BLOCK) as usize;
            let px = img.pixels[(y * RES + x) as usize];
            for (o, &v) in out[b].iter_mut().zip(&px) {
                *o += f64::from(v);
            }
        }
    }
    let n = f64::from(BLOCK * BLOCK);
    out.iter().map(|m| m.map(|v| v / n)).collect()
}

/// Per block and channel: (mean over seeds, sample variance over seeds).
fn seed_statistics(render_seed: impl Fn(u64) -> Image) -> Vec<[(f64, f64); 3]> {
    let per_seed: Vec<Vec<[f64; 3]>> = (0..SEEDS)
        .map(|s| {
            let img = render_seed(s);
            assert!(img.all_finite_non_negative());
            block_means(&img)
        })
        .collect();
    let n = SEEDS as f64;
    (0..per_seed[0].len())
        .map(|b| {
            let mut out = [(0.0, 0.0); 3];
            for (c, o) in out.iter_mut().enumerate() {
                let m = per_seed.iter().map(|v| v[b][c]).sum::<f64>() / n;
                let var = per_seed.iter().map(|v| (v[b][c] - m).powi(2)).sum::<f64>() / (n - 1.0);
                *o = (m, var);
            }
            out
        })
        .collect()
}

/// `ln Γ(x)` (Lanczos, g = 7, n = 9; ~1e-15 relative for x > 0).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, &c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularized incomplete beta `I_x(a, b)` (continued fraction, modified Lentz; Numerical
/// Recipes §6.4).
fn inc_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front =
        (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    if x > (a + 1.0) / (a + b + 2.0) {
        return 1.0 - inc_beta(1.0 - x, b, a);
    }
    let tiny = 1e-300;
    let (mut c, mut d) = (1.0f64, 1.0 - (a + b) * x / (a + 1.0));
    if d.abs() < tiny {
        d = tiny;
    }
    d = 1.0 / d;
    let mut f = d;
    for m in 1..500 {
        let m = f64::from(m);
        for num in [
            m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0)),
        ] {
            d = 1.0 + num * d;
            if d.abs() < tiny {
                d = tiny;
            }
            c = 1.0 + num / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            f *= c * d;
        }
        if (c * d - 1.0).abs() < 1e-15 {
            break;
        }
    }
    front * f / a
}

/// Two-sided Student-t tail probability `P(|T| ≥ t)` with `df` degrees of freedom.
fn t_two_sided(t: f64, df: f64) -> f64 {
    inc_beta(df / (df + t * t), 0.5 * df, 0.5)
}

/// A method under test: renders the scene with the given seed.
type Method<'a> = (&'a str, Box<dyn Fn(u64) -> Image + 'a>);

fn guided(scene: &Scene, kind: Representation, nee: bool, seed: u64) -> Image {
    guided_with(scene, kind, nee, seed, None, 1.0)
}

/// A guided render with NEE, the guide on `gpu` when given.
fn guided_on(
    scene: &Scene,
    kind: Representation,
    seed: u64,
    gpu: Option<&guiding_gpu::GpuContext>,
) -> Image {
    guided_with(scene, kind, true, seed, gpu, 1.0)
}

/// A guided render that trains its own guide (`SPP` spp, the default 30 % of the passes);
/// `guide_pdf_scale ≠ 1` is the deliberate defect of the power check.
fn guided_with(
    scene: &Scene,
    kind: Representation,
    nee: bool,
    seed: u64,
    gpu: Option<&guiding_gpu::GpuContext>,
    guide_pdf_scale: f32,
) -> Image {
    let o = opts(IntegratorKind::PtNee, SPP, 1000 + seed);
    let config = training_config(1024, 2, seed as u32 + 7);
    let mut g = guide(kind, Target::Product, ModelSize::Small, scene, 0.5, config);
    let gopts = GuidedOptions {
        nee,
        test_hooks: TestHooks {
            guide_pdf_scale,
            ..TestHooks::default()
        },
        schedule: REPRODUCIBLE,
        ..GuidedOptions::default()
    };
    if let Some(ctx) = gpu {
        g.use_device_context(ctx.clone(), guiding::DeviceFailure::Error)
            .expect("guide on the device");
    }
    let (img, stats) = render_guided(scene, &o, &gopts, &mut g).expect("guided render");
    if gpu.is_some() {
        // The device's own training: the field's loop counted its steps.
        assert!(stats.training_steps > 0, "no training step on the device");
    }
    img
}

#[test]
fn t_distribution_helper_matches_tables() {
    // Two-sided critical values: t(0.975, 15) = 2.131, t(0.995, 10) = 3.169, t(0.975, 1e6) → 1.960.
    for (t, df, p) in [(2.131, 15.0, 0.05), (3.169, 10.0, 0.01), (1.960, 1e6, 0.05)] {
        let got = t_two_sided(t, df);
        assert!((got - p).abs() < 2e-3 * p, "t {t} df {df}: {got} vs {p}");
    }
    assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
}

/// Welch t-tests of every block and channel of `stats` against `reference`
/// (seed means and variances); failures below `level` are pushed.
fn compare_blocks(
    name: &str,
    reference_name: &str,
    stats: &[[(f64, f64); 3]],
    reference: &[[(f64, f64); 3]],
    level: f64,
    failures: &mut Vec<String>,
) {
    let n = SEEDS as f64;
    let (mut worst_p, mut worst_t) = (1.0f64, 0.0f64);
    for b in 0..reference.len() {
        for c in 0..3 {
            let ((ma, va), (mb, vb)) = (stats[b][c], reference[b][c]);
            let (sa, sb) = (va / n, vb / n);
            let se2 = sa + sb;
            assert!(se2 > 0.0, "{name}: block {b} ch {c} has no variance");
            let t = (ma - mb) / se2.sqrt();
            // Welch–Satterthwaite degrees of freedom.
            let df = se2 * se2 / (sa * sa / (n - 1.0) + sb * sb / (n - 1.0));
            let p = t_two_sided(t.abs(), df);
            if p < worst_p {
                (worst_p, worst_t) = (p, t);
            }
            if p < level {
                failures.push(format!(
                    "{name}: block {b} ch {c}: {ma:.5} vs {reference_name} {mb:.5} (t = {t:.2}, df {df:.1}, p = {p:.2e} < {level:.2e})"
                ));
            }
        }
    }
    eprintln!("{name}: worst p {worst_p:.2e} (t = {worst_t:.2}); per-test level {level:.2e}");
}

/// `--device gpu` against `--device cpu`: the guided integrator with the
/// guide's inference and training on Vulkan (lavapipe in CI) renders the
/// same image in expectation, per block, as with the CPU field (NPM, NASG,
/// DF-N and DF-L, NEE on, independent seeds). Skipped (with a note) when the
/// SPIR-V was not built or there is no Vulkan device, unless
/// `GUIDING_REQUIRE_VULKAN=1`.
#[test]
fn gpu_guide_agrees_with_the_cpu_guide_per_block() {
    let Some(ctx) = common::vulkan_context() else {
        return;
    };
    let scene = load_builtin("cornell-box").expect("builtin");
    let kinds = [
        ("npm", Representation::Npm),
        ("nasg", Representation::Nasg),
        ("df-n", Representation::DfNearest),
        ("df-l", Representation::DfLinear),
    ];
    let level = sidak(
        ALPHA,
        kinds.len() * (RES / BLOCK * RES / BLOCK) as usize * 3,
    );
    let mut failures = Vec::new();
    for (name, kind) in kinds {
        let cpu = seed_statistics(|s| guided_on(&scene, kind, 200 + s, None));
        let gpu = seed_statistics(|s| guided_on(&scene, kind, 300 + s, Some(&ctx)));
        compare_blocks(
            &format!("guided {name} --device gpu"),
            "--device cpu",
            &gpu,
            &cpu,
            level,
            &mut failures,
        );
    }
    assert!(
        failures.is_empty(),
        "GPU and CPU guides disagree:\n{}",
        failures.join("\n")
    );
}

/// The `pt-nee` seed statistics every method is compared with.
fn reference_statistics(scene: &Scene) -> Vec<[(f64, f64); 3]> {
    seed_statistics(|s| render(scene, &opts(IntegratorKind::PtNee, SPP, s)))
}

/// Methods compared in [`all_integrators_agree_per_block`].
const METHODS: usize = 6;

/// Per-test level of [`all_integrators_agree_per_block`]: Šidák over its
/// `METHODS × blocks × channels` tests.
fn all_integrators_level() -> f64 {
    sidak(ALPHA, METHODS * (RES / BLOCK * RES / BLOCK) as usize * 3)
}

#[test]
fn all_integrators_agree_per_block() {
    let scene = load_builtin("cornell-box").expect("builtin");
    let reference = reference_statistics(&scene);
    let methods: Vec<Method<'_>> = vec![
        (
            "pt",
            Box::new(|s| render(&scene, &opts(IntegratorKind::Pt, SPP_PT, 500 + s))),
        ),
        (
            "guided npm",
            Box::new(|s| guided(&scene, Representation::Npm, true, s)),
        ),
        (
            "guided nasg",
            Box::new(|s| guided(&scene, Representation::Nasg, true, s)),
        ),
        (
            "guided df-n",
            Box::new(|s| guided(&scene, Representation::DfNearest, true, s)),
        ),
        (
            "guided df-l",
            Box::new(|s| guided(&scene, Representation::DfLinear, true, s)),
        ),
        (
            "guided npm no-NEE",
            Box::new(|s| guided(&scene, Representation::Npm, false, 100 + s)),
        ),
    ];
    assert_eq!(methods.len(), METHODS);
    let level = all_integrators_level();
    let mut failures = Vec::new();
    for (name, f) in &methods {
        let stats = seed_statistics(f);
        compare_blocks(name, "pt-nee", &stats, &reference, level, &mut failures);
    }
    assert!(failures.is_empty(), "biased:\n{}", failures.join("\n"));
}

/// Power check, committed: the comparison of [`all_integrators_agree_per_block`], at its
/// per-test level, rejects a deliberately biased estimator. `guided npm` (NEE, the same guide
/// and seeds as there) with the guide pdf in the continuation's combined density scaled by
/// 1.5 (`TestHooks::guide_pdf_scale`: a sample/pdf mismatch, so every guided continuation
/// is weighted by `f·cos / p` with `p` too large and the indirect light comes out too dark)
/// must fail at least one block. Measured: 17 of the 48 block-channel tests rejected, the
/// worst at t = −8.5 (p = 2.7e-9 against the level 3.5e-5); the honest `guided npm` passes
/// there with the smallest p = 8e-2.
#[test]
fn power_check_rejects_a_scaled_guide_pdf() {
    let scene = load_builtin("cornell-box").expect("builtin");
    let reference = reference_statistics(&scene);
    let biased = seed_statistics(|s| guided_with(&scene, Representation::Npm, true, s, None, 1.5));
    let mut failures = Vec::new();
    compare_blocks(
        "guided npm, guide pdf x 1.5",
        "pt-nee",
        &biased,
        &reference,
        all_integrators_level(),
        &mut failures,
    );
    eprintln!(
        "{} block-channel tests rejected:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(
        !failures.is_empty(),
        "the per-block comparison did not detect a guide pdf scaled by 1.5"
    );
}

/// A guided render whose radiance-target NPM guide (trained as in [`guided_with`], NEE on) is
/// answered from the guide cache in `mode` at `resolution` cells on the longest axis.
fn guided_cached(
    scene: &Scene,
    mode: CacheMode,
    resolution: u32,
    seed: u64,
) -> (Image, GuidedStats) {
    let o = opts(IntegratorKind::PtNee, SPP, 1000 + seed);
    let config = training_config(1024, 2, seed as u32 + 7);
    let mut g = npm_guide(Target::Radiance, ModelSize::Small, scene, config);
    let gopts = GuidedOptions {
        nee: true,
        cache: mode,
        cache_resolution: resolution,
        schedule: REPRODUCIBLE,
        ..GuidedOptions::default()
    };
    render_guided(scene, &o, &gopts, &mut g).expect("guided render")
}

/// The guide cache keeps guided rendering unbiased: `guided npm` with a radiance-target guide
/// answered from the cache (`CacheMode::Always`: during training too, refreshed after every
/// update, at a coarse 8 cells so the stochastic lookup often takes a neighbouring cell's
/// guide; `CacheMode::Frozen`: once training stops, at 16 and the default 64 cells) agrees with the
/// `pt-nee` reference per block, the comparison and seeds' role as in
/// [`all_integrators_agree_per_block`], Šidák over `modes × blocks × channels`. Every render
/// must have answered guide queries from the cache (hits > 0); its power against a sample/pdf
/// mismatch is [`power_check_rejects_a_scaled_guide_pdf`]'s.
#[test]
fn cached_guides_agree_per_block() {
    let scene = load_builtin("cornell-box").expect("builtin");
    let reference = reference_statistics(&scene);
    let modes = [
        (
            "guided npm radiance, cache always at 8",
            CacheMode::Always,
            8,
            600,
        ),
        (
            "guided npm radiance, cache frozen at 16",
            CacheMode::Frozen,
            16,
            700,
        ),
        (
            "guided npm radiance, cache frozen at 64",
            CacheMode::Frozen,
            64,
            800,
        ),
    ];
    let level = sidak(ALPHA, modes.len() * reference.len() * 3);
    let mut failures = Vec::new();
    for (name, mode, resolution, seed0) in modes {
        let totals = std::cell::Cell::new((0u64, 0u64, 0u64));
        let stats = seed_statistics(|s| {
            let (img, st) = guided_cached(&scene, mode, resolution, seed0 + s);
            assert!(
                st.cache
                    .as_deref()
                    .is_some_and(|c| !c.starts_with("not used")),
                "{name}: {st}"
            );
            assert!(
                st.cache_hits > 0 && st.cache_cells > 0,
                "{name}: no cache hits: {st}"
            );
            if s == 0 {
                eprintln!("{name}, seed 0:\n{st}");
            }
            let (h, m, c) = totals.get();
            totals.set((h + st.cache_hits, m + st.cache_misses, c + st.cache_cells));
            img
        });
        let (hits, misses, cells) = totals.get();
        eprintln!(
            "{name}: over {SEEDS} renders {hits} cache hits, {misses} misses, {:.0} cells each",
            cells as f64 / SEEDS as f64
        );
        compare_blocks(name, "pt-nee", &stats, &reference, level, &mut failures);
    }
    assert!(failures.is_empty(), "biased:\n{}", failures.join("\n"));
}

/// Query points of the sharpness probe per image side: a `PROBE × PROBE` grid of camera rays.
const PROBE: u32 = 16;
/// Guide samples per query point of the sharpness probe.
const PROBE_SAMPLES: u32 = 64;

/// Effective concentration `κ_eff = 4π · E_q[q(ω)]` of a guide distribution, from
/// `PROBE_SAMPLES` stratified samples of the distribution itself (`E_q[q] = ∫ q² dω`, so no
/// access to the lobes is needed and every representation is measured the same way). One vMF
/// lobe of concentration `κ` has `κ_eff = κ·coth κ` (→ κ for sharp lobes), the uniform sphere
/// 1, the clamped-cosine lobe 8/3; a mixture scores at least `w_k² κ_k` for each lobe `k`.
fn kappa_eff(dist: &guiding::Distribution<'_>) -> f64 {
    let n = PROBE_SAMPLES;
    let mean_pdf = (0..n)
        .map(|k| {
            // u.x stratified, u.y a permutation of the strata (a Latin hypercube).
            let u = glam::Vec2::new(
                (k as f32 + 0.5) / n as f32,
                ((k * 37 + 11) % n) as f32 / n as f32 + 0.5 / n as f32,
            );
            f64::from(dist.sample(u).pdf)
        })
        .sum::<f64>()
        / f64::from(n);
    4.0 * std::f64::consts::PI * mean_pdf
}

/// `κ_eff` of `guide` at the first hits of a `PROBE × PROBE` grid of camera rays (the query
/// points of the camera paths' first bounce; normals facing the camera), sorted.
fn sharpness(scene: &Scene, guide: &guiding::GuidingField) -> Vec<f64> {
    let mut k = Vec::new();
    for j in 0..PROBE {
        for i in 0..PROBE {
            let (u, v) = (
                (i as f32 + 0.5) / PROBE as f32,
                (j as f32 + 0.5) / PROBE as f32,
            );
            let (o, d) = scene.camera.ray(u, v);
            let Some(hit) = scene.intersect(o, d, 1e-4, f32::INFINITY) else {
                continue;
            };
            let wo = -d;
            let n = if hit.ns.dot(wo) < 0.0 {
                -hit.ns
            } else {
                hit.ns
            };
            let q = guiding::QueryPoint {
                position: hit.p.to_array(),
                roughness: 1.0,
                normal: n.to_array(),
                wo: wo.to_array(),
                ..guiding::QueryPoint::default()
            };
            k.push(kappa_eff(&guide.distribution(&q)));
        }
    }
    k.sort_by(f64::total_cmp);
    k
}

/// Median `κ_eff` the guides of [`sharp_frozen_guides_agree_per_block`] must reach.
const SHARP_KAPPA: f64 = 10.0;

/// Guides trained until their lobes are sharp, then frozen, agree with `pt-nee` per block.
///
/// The guides of [`all_integrators_agree_per_block`] train 5 passes of 2 Adam steps on 16 × 16
/// pixels: their lobes stay broad (median `κ_eff` 1.2 over the probe, an untrained guide 1.3),
/// so a bias that only shows with sharp lobes (a sample/pdf mismatch at high κ) passes there.
/// Here each guide first trains on its own render (32 × 32 pixels, 64 spp, every pass
/// training, 4 Adam steps of 4096 samples per pass: 256 steps), must reach a median `κ_eff` of
/// at least [`SHARP_KAPPA`] over the probe ([`sharpness`]; measured: NPM product 17.5
/// (quartiles 5.5 / 51, max 134), NPM radiance 52 (15 / 77, max 181); with other training
/// seeds the NPM product median ranged 17–29), and is then frozen: `SEEDS` renders with `train_fraction = 0` (independent
/// replications given the guide: unbiasedness must hold for every fixed guide) are compared
/// with the `pt-nee` reference block by block, Šidák over `guides × blocks × channels`.
///
/// Power (checked by hand, not committed: it needs a defect in the library): evaluating the
/// vMF mixture pdf with each κ clamped to 10 while sampling with the true κ — a mismatch that
/// only exists for lobes sharper than κ = 10 — leaves [`all_integrators_agree_per_block`] and
/// `guided.rs`'s `guided_unbiased_cornell*` passing with unchanged numbers and fails here at
/// t = −6.4 (NPM product) and −7.3 (NPM radiance) against the level 1.0e-4.
#[test]
fn sharp_frozen_guides_agree_per_block() {
    let scene = load_builtin("cornell-box").expect("builtin");
    let reference = reference_statistics(&scene);
    let guides = [
        ("npm product", Target::Product),
        ("npm radiance", Target::Radiance),
    ];
    let level = sidak(ALPHA, guides.len() * reference.len() * 3);
    let mut failures = Vec::new();
    for (i, (name, target)) in guides.into_iter().enumerate() {
        let config = training_config(4096, 4, 11 + i as u32);
        let mut g = npm_guide(target, ModelSize::Small, &scene, config);
        let train = RenderOptions {
            spp: 64,
            width: 32,
            height: 32,
            seed: 4000 + i as u64,
            ..opts(IntegratorKind::PtNee, 0, 0)
        };
        let gtrain = GuidedOptions {
            nee: true,
            schedule: guiding::ScheduleOptions {
                train_fraction: 1.0,
                steps: guiding::StepRule::Epochs(1e6),
                ..guiding::ScheduleOptions::DEFAULT
            },
            ..GuidedOptions::default()
        };
        let (_, st) = render_guided(&scene, &train, &gtrain, &mut g).expect("guided render");
        assert_eq!(st.training_passes, 64, "{name}: {st}");
        let k = sharpness(&scene, &g);
        let q = |f: f64| k[((k.len() - 1) as f64 * f).round() as usize];
        eprintln!(
            "{name}: {} training steps; kappa_eff over {} probe points: quartiles {:.1} / {:.1} / {:.1}, max {:.0}",
            st.training_steps,
            k.len(),
            q(0.25),
            q(0.5),
            q(0.75),
            q(1.0)
        );
        assert!(
            q(0.5) >= SHARP_KAPPA,
            "{name}: median kappa_eff {} < {SHARP_KAPPA}: the guide's lobes are not sharp",
            q(0.5)
        );
        let (steps, generation) = (g.stats().steps, g.generation());
        let frozen = GuidedOptions {
            nee: true,
            schedule: guiding::ScheduleOptions {
                train_fraction: 0.0,
                ..guiding::ScheduleOptions::DEFAULT
            },
            ..GuidedOptions::default()
        };
        let guide = std::cell::RefCell::new(g);
        let stats = seed_statistics(|s| {
            let o = opts(IntegratorKind::PtNee, SPP, 5000 + 100 * i as u64 + s);
            let (img, st) =
                render_guided(&scene, &o, &frozen, &mut guide.borrow_mut()).expect("guided render");
            assert_eq!((st.training_passes, st.samples_recorded), (0, 0));
            img
        });
        let g = guide.into_inner();
        assert_eq!(
            (g.stats().steps, g.generation()),
            (steps, generation),
            "{name}: the guide changed after training"
        );
        compare_blocks(
            &format!("frozen sharp {name}"),
            "pt-nee",
            &stats,
            &reference,
            level,
            &mut failures,
        );
    }
    assert!(failures.is_empty(), "biased:\n{}", failures.join("\n"));
}

/// A render with the library's guided roulette and splitting (`--rr guided`, or its negative
/// control): `pt-nee`, or `guided npm` (the guide as in [`guided_with`]). Asserts that the
/// window both killed and split paths, so the comparison tests what it claims to.
fn with_guided_roulette(scene: &Scene, rr: Roulette, guided_npm: bool, seed: u64) -> Image {
    let o = RenderOptions {
        rr,
        ..opts(IntegratorKind::PtNee, SPP, seed)
    };
    let (img, roulette) = if guided_npm {
        let config = training_config(1024, 2, seed as u32 + 7);
        let mut g = guide(
            Representation::Npm,
            Target::Product,
            ModelSize::Small,
            scene,
            0.5,
            config,
        );
        let gopts = GuidedOptions {
            schedule: REPRODUCIBLE,
            ..GuidedOptions::default()
        };
        let (img, st) = render_guided(scene, &o, &gopts, &mut g).expect("guided render");
        (img, st.roulette)
    } else {
        let (img, st) = render_with_stats(scene, &o);
        (img, st.roulette)
    };
    let r = roulette.expect("guided roulette ran");
    assert!(
        r.killed > 0 && r.split_vertices > 0 && r.learning_passes > 0,
        "the window did not both kill and split: {r:?}"
    );
    img
}

/// Guided Russian roulette and splitting (`--rr guided`: the library's weight window, its
/// radiance grid learned in the first passes) keep `pt-nee` and `guided npm` unbiased: per
/// block, against plain `pt-nee`, with the Welch test and Šidák level of
/// [`all_integrators_agree_per_block`] over this test's own `2 × blocks × channels` tests.
/// The negative control, `pt-nee` whose split copies keep the full weight instead of `β / k`
/// (`Roulette::GuidedUnweighted`: the splitting adds light), must fail the same comparison.
#[test]
fn guided_roulette_and_splitting_agree_per_block() {
    let scene = load_builtin("cornell-box").expect("builtin");
    let reference = reference_statistics(&scene);
    let blocks = (RES / BLOCK * RES / BLOCK) as usize;
    let level = sidak(ALPHA, 2 * blocks * 3);
    let mut failures = Vec::new();
    let nee = seed_statistics(|s| with_guided_roulette(&scene, Roulette::Guided, false, 700 + s));
    compare_blocks(
        "pt-nee --rr guided",
        "pt-nee",
        &nee,
        &reference,
        level,
        &mut failures,
    );
    let npm = seed_statistics(|s| with_guided_roulette(&scene, Roulette::Guided, true, 800 + s));
    compare_blocks(
        "guided npm --rr guided",
        "pt-nee",
        &npm,
        &reference,
        level,
        &mut failures,
    );
    assert!(failures.is_empty(), "biased:\n{}", failures.join("\n"));

    let unweighted = seed_statistics(|s| {
        with_guided_roulette(&scene, Roulette::GuidedUnweighted, false, 700 + s)
    });
    let mut control = Vec::new();
    compare_blocks(
        "pt-nee --rr guided, split copies unweighted",
        "pt-nee",
        &unweighted,
        &reference,
        level,
        &mut control,
    );
    eprintln!(
        "negative control: {} of {} block-channel tests rejected",
        control.len(),
        blocks * 3
    );
    assert!(
        !control.is_empty(),
        "the per-block comparison did not detect split copies that keep the full weight"
    );
}

/// Guided volumetric path tracing is unbiased per block: the fog box of `tests/media.rs`
/// (a chromatic, forward-scattering fog inside a null cube, a diffuse sphere in it) rendered
/// by the default guided integrator (NPM radiance, the guide cache, medium vertices guided
/// with the phase-lobe product: the render's dense fog passes the thin-medium rule) against
/// `pt-nee`, block by block as above, at the per-test level of two methods; the same guided
/// render with its guide pdf scaled by 1.5 in the continuation's density (at surface and
/// medium vertices) must be rejected. Measured: the honest render's smallest p 7.3e-3 against
/// the per-test level 1.05e-4; the scaled pdf rejected in 19 of 48 block-channel tests, the
/// worst at t = −10.6.
#[test]
fn guided_media_agree_per_block_and_a_scaled_pdf_is_caught() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/media/fog-box.xml");
    let scene = host_demo::scene::load::xml::load_file(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(host_demo::render::media_guiding(&scene)[0].guided);
    let medium_opts = |seed: u64| RenderOptions {
        max_depth: scene.settings.max_depth,
        ..opts(IntegratorKind::PtNee, SPP, seed)
    };
    let guided_fog = |seed: u64, guide_pdf_scale: f32| {
        let config = training_config(1024, 2, seed as u32 + 7);
        let mut g = npm_guide(Target::Radiance, ModelSize::Small, &scene, config);
        let gopts = GuidedOptions {
            test_hooks: TestHooks {
                guide_pdf_scale,
                ..TestHooks::default()
            },
            schedule: REPRODUCIBLE,
            ..GuidedOptions::default()
        };
        let (img, stats) =
            render_guided(&scene, &medium_opts(1000 + seed), &gopts, &mut g).expect("guided");
        assert!(stats.guided_medium_vertices > 0, "no guided medium vertex");
        img
    };
    let reference = seed_statistics(|s| render(&scene, &medium_opts(s)));
    let level = sidak(ALPHA, 2 * (RES / BLOCK * RES / BLOCK) as usize * 3);
    let mut failures = Vec::new();
    let honest = seed_statistics(|s| guided_fog(s, 1.0));
    compare_blocks(
        "guided npm, fog box",
        "pt-nee",
        &honest,
        &reference,
        level,
        &mut failures,
    );
    assert!(failures.is_empty(), "biased:\n{}", failures.join("\n"));
    let biased = seed_statistics(|s| guided_fog(s, 1.5));
    compare_blocks(
        "guided npm, fog box, guide pdf x 1.5",
        "pt-nee",
        &biased,
        &reference,
        level,
        &mut failures,
    );
    eprintln!(
        "{} block-channel tests rejected the scaled pdf",
        failures.len()
    );
    assert!(
        !failures.is_empty(),
        "the per-block comparison did not detect a guide pdf scaled by 1.5 in the fog"
    );
}
