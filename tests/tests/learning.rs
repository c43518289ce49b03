//! End-to-end learning of the real guiding models (NPM, NASG, DF-N, DF-L)
//! through the CPU runtime, on synthetic radiance fields with a known
//! answer over the box `[−1, 1]³`:
//!
//! - (a) `rotating`: one vMF lobe (κ = 20) whose mean turns with x by
//!   ±1.2 rad about azimuth 1.6 rad;
//! - (b) `anisotropic`: one NASG lobe (λ = 4, a = 30, i.e. ~31× sharper
//!   across than along), axis tilting with y;
//! - (c) `two lobes`: vMF lobes of κ = 25 and 8 (weights 0.6 / 0.4), the
//!   first turning with x.
//!
//! Every lobe stays away from azimuth φ = 0: NPM decodes `φ = 2π·sigmoid(r)`,
//! whose range is cut there, so a lobe that must cross φ = 0 as x varies
//! cannot follow it smoothly (measured: the rotating lobe centred on φ = 0
//! ends at KL ≈ 0.9 nats for NPM against ≈ 0.005 here) — a property of the
//! decoder, not of the runtime, so it is left out of these tests.
//!
//! Each target `p(x, ·)` is a normalised density over the sphere and is used
//! directly as the (grey) radiance. Training samples: positions uniform in
//! the box, `ωᵢ` uniform on the sphere (`sample_pdf = 1/4π`), zero normal and
//! `ωo` (radiance targets), `bsdf_pdf = 0` (so NASG's MIS blend, eq. 18,
//! reduces to `−w ln q − w(1 − e) ln c`: its guide learns `p` itself, and
//! the selection probability saturates — it is not under test). The
//! models minimise
//! `KL(p ‖ q)`; the test measures it on held-out positions by midpoint
//! quadrature on an equal-area (φ, cos θ) grid, in `f64`.
//!
//! Printed with `--nocapture`: the KL of every model / target before and
//! after training, against `KL(p ‖ uniform)`.

use guiding_core::encoding::GridConfig;
use guiding_core::field::{Field, FieldConfig};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::nasg::{NasgLobe, NASG_EPSILON};
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::loss::Target;
use guiding_core::math::INV_FOUR_PI;
use guiding_core::model::df::DfSmallRadiance;
use guiding_core::model::nasg::NasgSmallRadiance;
use guiding_core::model::npm::{small_grid, Npm, NpmSmallRadiance};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;
use guiding_core::sample::TrainingSample;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;
use std::time::Instant;

const LO: [f32; 3] = [-1.0; 3];
const HI: [f32; 3] = [1.0; 3];

/// A synthetic radiance field with a known normalised directional density.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scene {
    Rotating,
    Anisotropic,
    TwoLobes,
}

impl Scene {
    /// Normalised target density at position `p`, direction `w`.
    fn density(self, p: Vec3, w: Vec3) -> f32 {
        match self {
            Self::Rotating => {
                let a = 1.6 + 1.2 * p.x;
                VmfLobe::new(Vec3::new(a.cos(), a.sin(), 0.25).normalize(), 20.0).pdf(w)
            }
            Self::Anisotropic => {
                let b = 0.4 * p.y;
                let axis = Vec3::new(0.3, b.cos(), b.sin()).normalize();
                NasgLobe::new(axis, Vec3::Z, 4.0, 30.0, NASG_EPSILON).pdf(w)
            }
            Self::TwoLobes => {
                let a = -1.8 + 0.8 * p.x;
                let l1 = VmfLobe::new(Vec3::new(a.cos(), a.sin(), 0.2).normalize(), 25.0);
                let l2 = VmfLobe::new(Vec3::new(-0.5, 1.0, -0.3).normalize(), 8.0);
                0.6 * l1.pdf(w) + 0.4 * l2.pdf(w)
            }
        }
    }
}

fn uniform_position(rng: &mut Pcg32) -> Vec3 {
    Vec3::new(
        rng.uniform(LO[0], HI[0]),
        rng.uniform(LO[1], HI[1]),
        rng.uniform(LO[2], HI[2]),
    )
}

fn sample_at(scene: Scene, p: Vec3, wi: Vec3) -> TrainingSample {
    let l = scene.density(p, wi);
    TrainingSample::new(query(p), wi.to_array(), [l; 3], INV_FOUR_PI, 0.0, [0.0; 3])
}

fn training_samples(scene: Scene, rng: &mut Pcg32, n: usize) -> Vec<TrainingSample> {
    (0..n)
        .map(|_| {
            let p = uniform_position(rng);
            let wi = square_to_uniform_sphere(rng.next_vec2());
            sample_at(scene, p, wi)
        })
        .collect()
}

fn query(p: Vec3) -> QueryPoint {
    QueryPoint::from_vec3(p, Vec3::ZERO, Vec3::ZERO, 0.5)
}

/// Quadrature grid: `N_PHI × N_Z` equal-area cells (midpoints in φ and
/// cos θ). Cells are 1.8° × ≤ 1.2° near the equator, where the targets'
/// features lie (the narrowest, the NASG lobe across, is ~5° wide).
const N_PHI: usize = 200;
const N_Z: usize = 100;

fn quadrature_directions() -> Vec<Vec3> {
    let mut dirs = Vec::with_capacity(N_PHI * N_Z);
    for j in 0..N_Z {
        for i in 0..N_PHI {
            dirs.push(square_to_uniform_sphere(Vec2::new(
                (i as f32 + 0.5) / N_PHI as f32,
                (j as f32 + 0.5) / N_Z as f32,
            )));
        }
    }
    dirs
}

/// Discrete `KL(p ‖ q)` over the quadrature cells, both densities
/// renormalised on the grid (so the value is ≥ 0 and quadrature error in the
/// normalisation cancels).
fn discrete_kl(p: &[f64], q: &[f64]) -> f64 {
    let sp: f64 = p.iter().sum();
    let sq: f64 = q.iter().sum();
    let mut kl = 0.0;
    for (&pi, &qi) in p.iter().zip(q) {
        if pi > 0.0 {
            let (pn, qn) = (pi / sp, qi / sq);
            kl += pn * (pn / qn.max(1e-300)).ln();
        }
    }
    kl
}

/// Held-out evaluation positions (a stream the training never uses).
fn held_out_positions() -> Vec<Vec3> {
    let mut rng = Pcg32::new(0xfeed, 99);
    (0..8).map(|_| uniform_position(&mut rng)).collect()
}

/// Mean KL(target ‖ learned) over the held-out positions, via the field's
/// batched pdf (the EMA weights).
fn mean_kl<M: GuidingModel + Send + Sync>(field: &Field<M>, scene: Scene) -> f64 {
    let dirs = quadrature_directions();
    let positions = held_out_positions();
    let mut total = 0.0;
    let mut q = vec![0.0f32; dirs.len()];
    for &x in &positions {
        let queries = vec![query(x); dirs.len()];
        field.pdf_batch(&queries, &dirs, &mut q);
        let p: Vec<f64> = dirs
            .iter()
            .map(|&w| f64::from(scene.density(x, w)))
            .collect();
        let qd: Vec<f64> = q.iter().map(|&v| f64::from(v)).collect();
        total += discrete_kl(&p, &qd);
    }
    total / positions.len() as f64
}

/// Mean KL(target ‖ uniform) over the held-out positions.
fn uniform_kl(scene: Scene) -> f64 {
    let dirs = quadrature_directions();
    let positions = held_out_positions();
    let u = vec![1.0; dirs.len()];
    positions
        .iter()
        .map(|&x| {
            let p: Vec<f64> = dirs
                .iter()
                .map(|&w| f64::from(scene.density(x, w)))
                .collect();
            discrete_kl(&p, &u)
        })
        .sum::<f64>()
        / positions.len() as f64
}

struct Outcome {
    initial: f64,
    trained: f64,
    uniform: f64,
    params: usize,
    seconds: f64,
}

fn train<M: GuidingModel + Send + Sync>(
    model: M,
    scene: Scene,
    config: FieldConfig,
    updates: usize,
) -> (Field<M>, Outcome) {
    let mut field = Field::new(model, config).expect("valid config");
    let initial = mean_kl(&field, scene);
    let mut rng = Pcg32::new(0x5eed, scene as u64);
    let per_update = config.batch_size * config.steps_per_update as usize;
    let start = Instant::now();
    for _ in 0..updates {
        field.add_samples(&training_samples(scene, &mut rng, per_update));
        let r = field.update();
        assert_eq!(r.skipped_steps, 0);
    }
    let seconds = start.elapsed().as_secs_f64();
    let trained = mean_kl(&field, scene);
    let outcome = Outcome {
        initial,
        trained,
        uniform: uniform_kl(scene),
        params: model.param_count(),
        seconds,
    };
    (field, outcome)
}

/// The training schedule of every learning test: 30 updates of 10 steps on
/// 2048 fresh samples each (300 Adam steps, 614 400 samples), learning rate
/// 2·10⁻², EMA 0.95, two threads, seed 1.
const UPDATES: usize = 30;

fn config() -> FieldConfig {
    FieldConfig::DEFAULT
        .with_batch_size(2048)
        .with_steps_per_update(10)
        .with_learning_rate(2e-2)
        .with_threads(2)
        .with_seed(1)
}

/// Trains `model` on `scene`, prints and returns the outcome, and checks
/// the bounds every model must meet: the final KL is below `max_fraction`
/// of `KL(p ‖ uniform)` and below a tenth of the initial KL.
fn check<M: GuidingModel + Send + Sync>(
    name: &str,
    model: M,
    scene: Scene,
    max_fraction: f64,
) -> Outcome {
    let (field, o) = train(model, scene, config(), UPDATES);
    eprintln!(
        "{name:>6} {scene:<11?} ({:>4} params, {:>4} steps): KL {:.4} -> {:.4}  (uniform {:.4}, ratio {:.3}) {:.1}s",
        o.params,
        field.steps(),
        o.initial,
        o.trained,
        o.uniform,
        o.trained / o.uniform,
        o.seconds
    );
    assert!(
        o.trained < max_fraction * o.uniform,
        "{name} on {scene:?}: KL {} not below {max_fraction} × KL(uniform) = {}",
        o.trained,
        max_fraction * o.uniform
    );
    assert!(
        o.trained < 0.1 * o.initial,
        "{name} on {scene:?}: KL {} → {} did not fall tenfold",
        o.initial,
        o.trained
    );
    o
}

const SCENES: [Scene; 3] = [Scene::Rotating, Scene::Anisotropic, Scene::TwoLobes];

// Thresholds. `KL(p ‖ uniform)` is ≈ 2.7 nats for (a) and (b) and ≈ 1.8 for
// (c) (printed). A model that can represent the target exactly is limited
// by the noise of 300 steps of Monte Carlo gradients (the EMA averages
// some of it out); one that cannot is limited by its representation:
// - NPM (8 vMF lobes) represents (a) and (c) exactly and reaches ≈ 0.005
//   nats: bound 2 % of uniform (≈ 0.05). On (b) a vMF mixture can only
//   tile the 31:1 lobe (≈ 0.2 nats): bound 15 %.
// - NASG represents all three exactly (a = 0 is a vMF lobe): ≈ 0.005–0.01
//   nats, bound 2 %.
// - DF (32 × 16 bins, nearest or linear) is limited by its bin size
//   (11.25° in φ, ~7° in θ at the equator against lobes ~13° wide) and
//   trains its guide on the radiance cache's prediction (DF eq. 14),
//   which itself is learnt during these 300 steps: 0.06–0.18 nats; bound
//   10 % of uniform.

#[test]
fn npm_learns_the_targets() {
    for scene in SCENES {
        let bound = if scene == Scene::Anisotropic {
            0.15
        } else {
            0.02
        };
        check("NPM", NpmSmallRadiance::small(LO, HI), scene, bound);
    }
}

#[test]
fn nasg_learns_the_targets() {
    for scene in SCENES {
        check("NASG", NasgSmallRadiance::small(LO, HI), scene, 0.02);
    }
}

#[test]
fn df_nearest_learns_the_targets() {
    for scene in SCENES {
        let model = DfSmallRadiance::small(LO, HI, Interpolation::Nearest);
        check("DF-N", model, scene, 0.1);
    }
}

#[test]
fn df_linear_learns_the_targets() {
    for scene in SCENES {
        let model = DfSmallRadiance::small(LO, HI, Interpolation::Linear);
        check("DF-L", model, scene, 0.1);
    }
}

/// NPM widened to 20 hidden units (1 880 parameters) against the NASG
/// small preset (1 857): the same grid, two hidden layers, 8 lobes each.
type NpmMatched = Npm<8, 20, 2>;

#[test]
fn nasg_beats_vmf_on_the_anisotropic_target_at_equal_size() {
    let npm = NpmMatched::new(small_grid(LO, HI), Target::Radiance);
    let nasg = NasgSmallRadiance::small(LO, HI);
    let (np, ng) = (npm.param_count(), nasg.param_count());
    assert!(
        (np as f64 / ng as f64 - 1.0).abs() < 0.02,
        "parameter counts {np} vs {ng}"
    );
    let o_npm = check("NPM-20", npm, Scene::Anisotropic, 0.15);
    let o_nasg = check("NASG", nasg, Scene::Anisotropic, 0.02);
    // One anisotropic lobe is exactly one NASG lobe, while vMF lobes must
    // tile it: expect an order of magnitude; assert a factor of two.
    assert!(
        o_nasg.trained < 0.5 * o_npm.trained,
        "NASG {} vs NPM {}",
        o_nasg.trained,
        o_npm.trained
    );
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Trains `steps` steps (one per update) with `threads` threads.
fn train_threads<M: GuidingModel + Send + Sync>(
    model: M,
    threads: usize,
    steps: usize,
) -> Field<M> {
    let config = FieldConfig::DEFAULT
        .with_batch_size(1000)
        .with_learning_rate(1e-2)
        .with_threads(threads)
        .with_seed(7);
    let mut field = Field::new(model, config).unwrap();
    let mut rng = Pcg32::new(21, 0);
    for _ in 0..steps {
        field.add_samples(&training_samples(Scene::TwoLobes, &mut rng, 1000));
        assert_eq!(field.update().steps, 1);
    }
    field
}

fn assert_bit_identical<M: GuidingModel + Send + Sync>(name: &str, model: M, steps: usize) {
    let one = train_threads(model, 1, steps);
    let two = train_threads(model, 2, steps);
    assert_eq!(one.steps(), steps as u64);
    assert!(
        bits(one.params()) == bits(two.params()),
        "{name}: params differ"
    );
    assert!(
        bits(one.ema_params()) == bits(two.ema_params()),
        "{name}: EMA differs"
    );
    let ((m1, v1), (m2, v2)) = (one.adam_moments(), two.adam_moments());
    assert!(
        bits(m1) == bits(m2) && bits(v1) == bits(v2),
        "{name}: Adam state differs"
    );
    assert_eq!(
        one.loss_history(),
        two.loss_history(),
        "{name}: losses differ"
    );
    // The EMA has moved away from the initialisation.
    let init = Field::new(model, FieldConfig::DEFAULT.with_seed(7)).unwrap();
    assert_ne!(bits(init.ema_params()), bits(one.ema_params()));
}

#[test]
fn training_is_bit_identical_for_one_and_two_threads() {
    assert_bit_identical("NPM small", NpmSmallRadiance::small(LO, HI), 25);
    assert_bit_identical(
        "DF-L small",
        DfSmallRadiance::small(LO, HI, Interpolation::Linear),
        20,
    );
    // A finer grid (4 levels, 4…32 cells, 166 816 parameters): the
    // element-wise passes (chunk reduction, scaling, Adam, EMA) are split
    // between the threads too.
    let grid = GridConfig::new(LO, HI, 4, 4, 2.0, 4);
    let npm = Npm::<16, 16, 2>::new(grid, Target::Radiance);
    assert!(npm.is_consistent() && npm.param_count() > 100_000);
    assert_bit_identical("NPM 4-level grid", npm, 20);
}

/// A stream with rare huge-but-valid outliers and invalid records.
fn soak<M: GuidingModel + Send + Sync>(name: &str, model: M) {
    let config = FieldConfig::DEFAULT
        .with_batch_size(512)
        .with_steps_per_update(4)
        .with_learning_rate(1e-2)
        .with_threads(2);
    let mut field = Field::new(model, config).unwrap();
    let mut rng = Pcg32::new(0x50a4, 1);
    let mut invalid = 0u64;
    let mut outliers = 0;
    let initial = mean_kl(&field, Scene::Rotating);
    for update in 0..40 {
        let mut batch = training_samples(Scene::Rotating, &mut rng, 2048);
        for (i, s) in batch.iter_mut().enumerate() {
            match (i + update) % 97 {
                // ~1 % invalid records of every kind.
                0 => s.radiance[1] = f32::NAN,
                1 => s.sample_pdf = 0.0,
                2 => s.wi = [0.0; 3],
                3 => s.radiance[0] = -2.0,
                4 => s.position[2] = f32::INFINITY,
                _ => continue,
            }
            invalid += 1;
        }
        // A firefly in every fourth update: 10⁶ times the radiance.
        if update % 4 == 0 {
            let s = &mut batch[update * 13 % 2048];
            if s.validate().is_ok() {
                s.radiance = s.radiance.map(|l| l * 1e6 + 1e3);
                outliers += 1;
            }
        }
        field.add_samples(&batch);
        let r = field.update();
        assert_eq!(r.skipped_steps, 0, "{name}: update {update}");
        assert!(
            field.params().iter().all(|x| x.is_finite()),
            "{name}: params"
        );
        assert!(
            field.ema_params().iter().all(|x| x.is_finite()),
            "{name}: EMA"
        );
        let (m, v) = field.adam_moments();
        assert!(
            m.iter().chain(v).all(|x| x.is_finite()),
            "{name}: Adam state"
        );
    }
    assert_eq!(field.rejected().iter().sum::<u64>(), invalid, "{name}");
    assert!(outliers >= 8);
    // Inference stays sane everywhere.
    let mut qrng = Pcg32::new(3, 3);
    for _ in 0..2000 {
        let q = query(uniform_position(&mut qrng));
        let s = field.sample(&q, qrng.next_vec2());
        assert!(s.direction.is_finite() && (s.direction.length() - 1.0).abs() < 1e-3);
        assert!(s.pdf.is_finite() && s.pdf > 0.0, "{name}: pdf {}", s.pdf);
        assert!(field.pdf(&q, s.direction).is_finite());
        let c = field.selection_probability(&q);
        assert!((0.0..=1.0).contains(&c));
    }
    let trained = mean_kl(&field, Scene::Rotating);
    eprintln!(
        "{name:>6} soak: KL {initial:.4} -> {trained:.4}, {invalid} rejected, {outliers} fireflies"
    );
    assert!(trained < initial, "{name}: {initial} -> {trained}");
}

#[test]
fn robustness_soak_outliers_and_invalid_samples() {
    soak("NPM", NpmSmallRadiance::small(LO, HI));
    soak("NASG", NasgSmallRadiance::small(LO, HI));
    soak(
        "DF-N",
        DfSmallRadiance::small(LO, HI, Interpolation::Nearest),
    );
    soak(
        "DF-L",
        DfSmallRadiance::small(LO, HI, Interpolation::Linear),
    );
}

/// Pareto(α = 1.5) noise with mean 1 (`x_m = 1/3`): heavy-tailed, infinite
/// variance, independent of the direction.
fn pareto_noise(rng: &mut Pcg32) -> f64 {
    (1.0 / 3.0) * (1.0 - rng.next_f64()).powf(-1.0 / 1.5)
}

/// Long-run soak: 10⁴ Adam steps (2500 updates × 4 steps × 64 samples) of
/// the small NPM on the rotating target, every radiance multiplied by
/// Pareto(1.5) noise of mean 1, one sample in 10³ a firefly (× 10⁶ on top),
/// and ~1 % invalid records (NaN radiance, infinite position, negative
/// radiance, zero pdf, zero direction).
///
/// Asserts: no step is skipped, parameters, EMA and Adam moments stay finite
/// after every update, each rejection kind is counted exactly, inference
/// stays sane, and the KL bound below holds at every checkpoint (every 10³
/// steps) after the first 2·10³.
///
/// The bound. The noise is multiplicative and independent of the direction,
/// and invalid records are dropped, so the expected loss is `E[η] ·
/// KL(p ‖ q) + const`: the corruption does not move the optimum, only adds
/// gradient noise. The test requires that this noise never costs the guide
/// more than a quarter of what it gains over uniform sampling:
/// `KL(p‖u) − KL(p‖q) = E_p[ln q/u] ≥ ¾ E_p[ln p/u]`, i.e.
/// `KL(p‖q) ≤ KL(p‖u)/4` (≈ 0.67 nats here). Measured: the clean stream
/// gives 0.01–0.06 nats over these checkpoints, Pareto noise alone
/// 0.05–0.25, this soak 0.03–0.2; a guide dragged around by its fireflies
/// reaches 1–4 nats and fails.
///
/// That is what happens with the default gradient clip (10¹⁸, an overflow
/// guard only): a firefly's gradient is ~10⁶ times a normal one, Adam's
/// second moment then shrinks every normal step for ~10³ steps, and each
/// firefly moves the lobes towards its single direction by ~3 learning
/// rates (measured with the default clip: KL 1.1–4.0 at one firefly per
/// 10³ samples, 0.1–1.7 at one per 10⁴). The soak therefore sets
/// `max_gradient_magnitude = 10` (~5 % of the steps clipped, printed),
/// which bounds a firefly step to ten times a normal one. One thread and
/// one chunk: with 64-sample batches, spawning the chunk threads costs more
/// than it saves (2 threads × 8 chunks measured 2× slower).
#[test]
fn long_soak_heavy_tailed_noise_fireflies_and_invalid_samples() {
    let model = NpmSmallRadiance::small(LO, HI);
    let config = FieldConfig::DEFAULT
        .with_batch_size(64)
        .with_steps_per_update(4)
        .with_learning_rate(5e-3)
        .with_max_gradient_magnitude(10.0)
        .with_threads(1)
        .with_gradient_chunks(1);
    let mut field = Field::new(model, config).unwrap();
    let mut rng = Pcg32::new(0x50a5, 2);
    let bound = 0.25 * uniform_kl(Scene::Rotating);
    let mut rejected = [0u64; 4];
    let (mut fireflies, mut trajectory) = (0u64, Vec::new());
    let start = Instant::now();
    for update in 0..2500 {
        let mut batch = training_samples(Scene::Rotating, &mut rng, 256);
        for s in &mut batch {
            let eta = pareto_noise(&mut rng);
            let firefly = rng.next_u32() % 1000 == 0;
            let f = if firefly { 1e6 } else { 1.0 };
            s.radiance = s.radiance.map(|l| (f64::from(l) * eta * f) as f32);
            fireflies += u64::from(firefly);
            let kind = match rng.next_u32() % 500 {
                0 => {
                    s.radiance[1] = f32::NAN;
                    0
                }
                1 => {
                    s.position[2] = f32::INFINITY;
                    0
                }
                2 => {
                    s.radiance[0] = -1.0;
                    1
                }
                3 => {
                    s.sample_pdf = 0.0;
                    2
                }
                4 => {
                    s.wi = [0.0; 3];
                    3
                }
                _ => continue,
            };
            rejected[kind] += 1;
        }
        field.add_samples(&batch);
        let r = field.update();
        assert_eq!(r.skipped_steps, 0, "update {update}: {r:?}");
        assert!(field.params().iter().all(|x| x.is_finite()), "params");
        assert!(field.ema_params().iter().all(|x| x.is_finite()), "EMA");
        let (m, v) = field.adam_moments();
        assert!(m.iter().chain(v).all(|x| x.is_finite()), "Adam state");
        if (update + 1) % 250 == 0 {
            trajectory.push(mean_kl(&field, Scene::Rotating));
        }
    }
    assert_eq!(field.steps(), 10_000);
    assert_eq!(field.rejected(), rejected);
    let mut qrng = Pcg32::new(3, 3);
    for _ in 0..2000 {
        let q = query(uniform_position(&mut qrng));
        let s = field.sample(&q, qrng.next_vec2());
        assert!(s.direction.is_finite() && (s.direction.length() - 1.0).abs() < 1e-3);
        assert!(s.pdf.is_finite() && s.pdf > 0.0);
        assert!(field.pdf(&q, s.direction).is_finite());
    }
    let shown: Vec<String> = trajectory.iter().map(|k| format!("{k:.3}")).collect();
    eprintln!(
        "long soak: {} steps ({} clipped), {fireflies} fireflies, {} rejected, KL every 10³ steps {} \
         (bound {bound:.3}), {:.1}s",
        field.steps(),
        field.clipped_steps(),
        rejected.iter().sum::<u64>(),
        shown.join(" "),
        start.elapsed().as_secs_f64()
    );
    for (i, &kl) in trajectory.iter().enumerate().skip(1) {
        assert!(
            kl <= bound,
            "KL {kl} after {} steps exceeds KL(p‖u)/4 = {bound}",
            (i + 1) * 1000
        );
    }
}
