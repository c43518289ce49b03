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
use guiding_core::glam::{Quat, Vec2, Vec3};
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

/// A defect planted in the training stream: the negative controls train on it
/// and the learning check must reject what they learn.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Defect {
    /// The stream of the tests.
    None,
    /// Each sample's radiance is the target's at one position, and the position
    /// recorded with it another, independent one (a renderer that records the
    /// wrong hit point, or a learner whose samples lost their positions): the
    /// stream says nothing about how the target varies with position, so the
    /// best the learner can do is the positions' average density.
    ShuffledPositions,
    /// Each sample's direction is recorded rotated by this angle (radians) about
    /// `+z`, its radiance that of the unrotated direction (a renderer whose shading
    /// frame is off by a few degrees): the guide learns the target turned by it.
    RotatedFrame(f32),
}

fn training_samples(scene: Scene, rng: &mut Pcg32, n: usize) -> Vec<TrainingSample> {
    defective_samples(scene, rng, n, Defect::None)
}

fn defective_samples(
    scene: Scene,
    rng: &mut Pcg32,
    n: usize,
    defect: Defect,
) -> Vec<TrainingSample> {
    (0..n)
        .map(|_| {
            let p = uniform_position(rng);
            let wi = square_to_uniform_sphere(rng.next_vec2());
            let mut s = sample_at(scene, p, wi);
            match defect {
                Defect::None => {}
                Defect::ShuffledPositions => s.position = uniform_position(rng).to_array(),
                Defect::RotatedFrame(angle) => {
                    s.wi = (Quat::from_rotation_z(angle) * wi).to_array();
                }
            }
            s
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

/// The target density at `x` in each of `dirs`, in f64.
fn target_densities(scene: Scene, x: Vec3, dirs: &[Vec3]) -> Vec<f64> {
    dirs.iter()
        .map(|&w| f64::from(scene.density(x, w)))
        .collect()
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
        let p = target_densities(scene, x, &dirs);
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
        .map(|&x| discrete_kl(&target_densities(scene, x, &dirs), &u))
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
    seed: u64,
    defect: Defect,
) -> (Field<M>, Outcome) {
    assert!(seed >= 1);
    let mut field = Field::new(model, config.with_seed(seed as u32)).expect("valid config");
    let initial = mean_kl(&field, scene);
    let mut rng = Pcg32::new(0x5eed, scene as u64 + 16 * (seed - 1));
    let per_update = config.batch_size * config.steps_per_update as usize;
    let start = Instant::now();
    for _ in 0..updates {
        field.add_samples(&defective_samples(scene, &mut rng, per_update, defect));
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

/// The learning check's verdict on a trained outcome: `Err` (the reason) when
/// the final KL is not below `bound` nats, or did not fall tenfold from the
/// initial KL.
fn verdict(name: &str, scene: Scene, o: &Outcome, bound: f64) -> Result<(), String> {
    // A NaN KL fails.
    if o.trained.is_nan() || o.trained >= bound {
        return Err(format!(
            "{name} on {scene:?}: KL {} not below its bound {bound}",
            o.trained
        ));
    }
    if o.trained >= 0.1 * o.initial {
        return Err(format!(
            "{name} on {scene:?}: KL {} → {} did not fall tenfold",
            o.initial, o.trained
        ));
    }
    Ok(())
}

/// Trains `model` on `scene` with the tests' schedule (seed 1) on a stream
/// with `defect`, and prints the outcome.
fn run<M: GuidingModel + Send + Sync>(
    name: &str,
    model: M,
    scene: Scene,
    defect: Defect,
) -> Outcome {
    let (field, o) = train(model, scene, config(), UPDATES, 1, defect);
    eprintln!(
        "{name:>6} {scene:<11?} ({:>4} params, {:>4} steps{}): KL {:.4} -> {:.4}  (uniform {:.4}, ratio {:.3}) {:.1}s",
        o.params,
        field.steps(),
        if defect == Defect::None {
            String::new()
        } else {
            format!(", defect {defect:?}")
        },
        o.initial,
        o.trained,
        o.uniform,
        o.trained / o.uniform,
        o.seconds
    );
    o
}

/// Trains `model` on `scene` (no defect), prints and returns the outcome,
/// and fails unless [`verdict`] accepts it.
fn check<M: GuidingModel + Send + Sync>(name: &str, model: M, scene: Scene, bound: f64) -> Outcome {
    let o = run(name, model, scene, Defect::None);
    if let Err(reason) = verdict(name, scene, &o, bound) {
        panic!("{reason}");
    }
    o
}

/// Trains `model` on `scene` from a stream with `defect` and asserts that the
/// learning check rejects the result (a negative control).
fn assert_rejected<M: GuidingModel + Send + Sync>(
    name: &str,
    model: M,
    scene: Scene,
    bound: f64,
    defect: Defect,
) {
    let o = run(name, model, scene, defect);
    match verdict(name, scene, &o, bound) {
        Ok(()) => panic!(
            "{name} on {scene:?} with {defect:?}: KL {} passed the bound {bound}",
            o.trained
        ),
        Err(reason) => eprintln!("       rejected as it must be: {reason}"),
    }
}

const SCENES: [Scene; 3] = [Scene::Rotating, Scene::Anisotropic, Scene::TwoLobes];

/// Significance level of the learning checks as a whole, and their number (4
/// families × 3 scenes, and NPM-20).
const LEARNING_ALPHA: f64 = 0.01;
const LEARNING_CHECKS: usize = 13;

// The bounds, in nats of `KL(p ‖ q)`, per scene [(a) rotating, (b) anisotropic,
// (c) two lobes]; `KL(p ‖ uniform)` is 2.689, 2.729 and 1.784 (printed).
//
// A model that can represent the target exactly is limited by the noise of
// 300 steps of Monte Carlo gradients (the EMA averages some of it out); one
// that cannot, by its representation: NPM's 8 vMF lobes can only tile the 31:1
// lobe of (b); DF (32 × 16 bins) is limited by its bins (11.25° in φ, ~7° in θ
// at the equator, against lobes ~13° wide) and trains its guide on the radiance
// cache's prediction (DF eq. 14), itself learnt during these 300 steps.
//
// Derivation. The committed test runs seed 1; the bound must hold for any
// seed (a changed stream, another platform's rounding: the same as a new seed)
// and should be as tight as that allows. `seed_spread` (ignored, ~4 minutes)
// trains every case with seeds 1–8 (the init and the sample stream). ln KL
// spreads alike for the cases of one family, so its standard deviation `s` is
// pooled per family (NPM with NPM-20: 4 × 7 = 28 degrees of freedom, the
// others 21). The bound is the one-sided upper prediction bound of a new
// seed's KL, `exp(m + t·s·√(1 + 1/8))` (`m` the case's mean ln KL, `t` Student's
// quantile at `1 − α₁`, `α₁ = 1 − 0.99^{1/13}` = 7.7·10⁻⁴: α = 0.01 for the 13
// checks together, Šidák), rounded down to two digits. Where the old bound (a
// fraction of `KL(p ‖ u)`: 2 % for NPM / NASG, 15 % for NPM on (b), 10 % for
// DF) was tighter, it is kept (rounded down) — never loosened:
//
//   case     geo-mean KL (max of 8)          s      t     factor  prediction bound  bound
//   NPM      .0050 (.0077) .169 (.202) .0038 (.0059)   .306  3.51  3.12   .0156 .525 .0118   .015 .40 .011
//   NPM-20   (b) .174 (.208)                    (pooled with NPM)   .543             .40
//   NASG     .0063 (.0100) .0077 (.0119) .0060 (.0095)  .287  3.64  3.03  .0192 .0233 .0183  .019 .023 .018
//   DF-N     .115 (.141) .158 (.195) .093 (.108)   .194  3.64  2.12   .244 .334 .196     .24 .27 .17
//   DF-L     .066 (.085) .083 (.114) .055 (.069)   .357  3.64  3.97   .262 .327 .217     .26 .27 .17
//
// The kept bounds are NPM and NPM-20 on (b), where the KL is capped by the
// tiling plateau (0.195–0.208 at 10 of the 16 seeds, never above 0.21), so the
// lognormal tail overstates the upside, and DF on (b) and (c); each of the 48
// DF runs is below 0.73 of its bound.
//
// What they catch (the negative controls below): a learner that ignores the
// position cannot go below `position_independent_floor` (0.755, 0.785, 0.365
// nats), above every bound; and for NPM and NASG, whose bounds are now 3×
// their typical KL rather than 10×, a shading frame off by 4°, which the guide
// reproduces (`κ A(κ) (1 − cos θ)` ≈ 0.04 nats for κ = 20, the lobe 14° above
// the equator), fails (measured
// 0.038 and 0.037 on (a), against 0.015 and 0.019; the old 2 % bound, 0.054,
// passed it). DF's bound is 2–4× its typical KL too, but that is ~0.2 nats: it
// catches a frame off by ≳ 8°, not 4°.
const NPM_BOUNDS: [f64; 3] = [0.015, 0.40, 0.011];
const NPM20_ANISOTROPIC_BOUND: f64 = 0.40;
const NASG_BOUNDS: [f64; 3] = [0.019, 0.023, 0.018];
const DF_N_BOUNDS: [f64; 3] = [0.24, 0.27, 0.17];
const DF_L_BOUNDS: [f64; 3] = [0.26, 0.27, 0.17];

#[test]
fn npm_learns_the_targets() {
    for scene in SCENES {
        let bound = NPM_BOUNDS[scene as usize];
        check("NPM", NpmSmallRadiance::small(LO, HI), scene, bound);
    }
}

#[test]
fn nasg_learns_the_targets() {
    for scene in SCENES {
        let bound = NASG_BOUNDS[scene as usize];
        check("NASG", NasgSmallRadiance::small(LO, HI), scene, bound);
    }
}

#[test]
fn df_nearest_learns_the_targets() {
    for scene in SCENES {
        let model = DfSmallRadiance::small(LO, HI, Interpolation::Nearest);
        check("DF-N", model, scene, DF_N_BOUNDS[scene as usize]);
    }
}

#[test]
fn df_linear_learns_the_targets() {
    for scene in SCENES {
        let model = DfSmallRadiance::small(LO, HI, Interpolation::Linear);
        check("DF-L", model, scene, DF_L_BOUNDS[scene as usize]);
    }
}

/// Negative control: a learner whose samples lost their positions. Every bound
/// is below the KL of the best position-blind guide (`position_independent_floor`,
/// checked here for all 12 cases), and each family, trained on such a stream
/// with the tests' schedule on the scene where its bound is closest to that
/// floor, is rejected (measured: NPM 0.95 on (b) against 0.40; NASG, DF-N and
/// DF-L 0.50, 0.50, 0.47 on (c) against 0.018, 0.17, 0.17).
#[test]
fn learning_check_rejects_a_position_blind_learner() {
    for scene in SCENES {
        let floor = position_independent_floor(scene);
        for (family, bounds) in [
            ("NPM", NPM_BOUNDS),
            ("NASG", NASG_BOUNDS),
            ("DF-N", DF_N_BOUNDS),
            ("DF-L", DF_L_BOUNDS),
        ] {
            let bound = bounds[scene as usize];
            assert!(
                floor > 1.5 * bound,
                "{family} on {scene:?}: a position-blind guide (KL ≥ {floor}) is within 1.5× of the bound {bound}"
            );
        }
        assert!(floor > 1.5 * NPM20_ANISOTROPIC_BOUND || scene != Scene::Anisotropic);
    }
    let shuffled = Defect::ShuffledPositions;
    let (b, c) = (Scene::Anisotropic, Scene::TwoLobes);
    let npm = NpmSmallRadiance::small(LO, HI);
    assert_rejected("NPM", npm, b, NPM_BOUNDS[b as usize], shuffled);
    let nasg = NasgSmallRadiance::small(LO, HI);
    assert_rejected("NASG", nasg, c, NASG_BOUNDS[c as usize], shuffled);
    let df_n = DfSmallRadiance::small(LO, HI, Interpolation::Nearest);
    assert_rejected("DF-N", df_n, c, DF_N_BOUNDS[c as usize], shuffled);
    let df_l = DfSmallRadiance::small(LO, HI, Interpolation::Linear);
    assert_rejected("DF-L", df_l, c, DF_L_BOUNDS[c as usize], shuffled);
}

/// Negative control near the bounds: NPM and NASG trained on the rotating target
/// with every direction recorded 4° off (about `+z`) learn the lobe turned by 4°
/// and are rejected (see the bounds' comment for the numbers).
#[test]
fn learning_check_rejects_a_frame_off_by_four_degrees() {
    let (a, defect) = (Scene::Rotating, Defect::RotatedFrame(4f32.to_radians()));
    let npm = NpmSmallRadiance::small(LO, HI);
    assert_rejected("NPM", npm, a, NPM_BOUNDS[a as usize], defect);
    let nasg = NasgSmallRadiance::small(LO, HI);
    assert_rejected("NASG", nasg, a, NASG_BOUNDS[a as usize], defect);
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
    let b = Scene::Anisotropic;
    let o_npm = check("NPM-20", npm, b, NPM20_ANISOTROPIC_BOUND);
    let o_nasg = check("NASG", nasg, b, NASG_BOUNDS[b as usize]);
    // One anisotropic lobe is exactly one NASG lobe, while vMF lobes must
    // tile it: measured ≥ 9× at each of the 8 seeds. Asserted: 2×, what the
    // prediction bounds above guarantee — NPM-20's lower one (its geometric
    // mean 0.174 / 3.12 = 0.056) is 2.4× NASG's upper one (0.023).
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

/// Mean over the held-out positions of `KL(p_x ‖ m)`, `m` the positions' average
/// density: no guide that ignores the position gets below it (for a fixed `q`,
/// `Σ_x KL(p_x ‖ q) = Σ_x KL(p_x ‖ m) + n KL(m ‖ q)`).
fn position_independent_floor(scene: Scene) -> f64 {
    let dirs = quadrature_directions();
    let positions = held_out_positions();
    let densities: Vec<Vec<f64>> = positions
        .iter()
        .map(|&x| {
            let p = target_densities(scene, x, &dirs);
            let s: f64 = p.iter().sum();
            p.iter().map(|v| v / s).collect()
        })
        .collect();
    let m: Vec<f64> = (0..dirs.len())
        .map(|i| densities.iter().map(|p| p[i]).sum::<f64>() / positions.len() as f64)
        .collect();
    densities.iter().map(|p| discrete_kl(p, &m)).sum::<f64>() / positions.len() as f64
}

/// Seeds of the spread measurement behind the bounds.
const SPREAD_SEEDS: u64 = 8;

/// `ln KL` of seeds `1..=SPREAD_SEEDS` of the test's schedule on `scene`.
fn log_kls<M: GuidingModel + Send + Sync>(name: &str, model: M, scene: Scene) -> Vec<f64> {
    let kls: Vec<f64> = (1..=SPREAD_SEEDS)
        .map(|s| {
            train(model, scene, config(), UPDATES, s, Defect::None)
                .1
                .trained
        })
        .collect();
    let shown: Vec<String> = kls.iter().map(|k| format!("{k:.4}")).collect();
    eprintln!("{name:>6} {scene:<11?}: KL over seeds {}", shown.join(" "));
    kls.iter().map(|k| k.ln()).collect()
}

/// Prints, per case of one family, the upper prediction bound of the KL of a new seed
/// (see the bounds' comment): `exp(m + t·s·√(1 + 1/n))`.
fn family_bounds(cases: &[(&str, Scene, Vec<f64>)]) {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    let n = SPREAD_SEEDS as f64;
    let means: Vec<f64> = cases
        .iter()
        .map(|(_, _, l)| l.iter().sum::<f64>() / n)
        .collect();
    let ss: f64 = cases
        .iter()
        .zip(&means)
        .map(|((_, _, l), m)| l.iter().map(|x| (x - m).powi(2)).sum::<f64>())
        .sum();
    let dof = cases.len() as f64 * (n - 1.0);
    let s = (ss / dof).sqrt();
    let alpha1 = 1.0 - (1.0 - LEARNING_ALPHA).powf(1.0 / LEARNING_CHECKS as f64);
    let t = StudentsT::new(0.0, 1.0, dof)
        .unwrap()
        .inverse_cdf(1.0 - alpha1);
    let factor = (t * s * (1.0 + 1.0 / n).sqrt()).exp();
    for ((name, scene, l), m) in cases.iter().zip(&means) {
        let max = l.iter().copied().fold(f64::MIN, f64::max).exp();
        eprintln!(
            "{name:>6} {scene:<11?}: geometric mean {:.4}, max {max:.4}, pooled sd(ln) {s:.3} \
             ({dof} dof), t {t:.2}, factor {factor:.2}: bound {:.4} (floor of a position-blind guide {:.3})",
            m.exp(),
            m.exp() * factor,
            position_independent_floor(*scene)
        );
    }
}

/// The measurement behind the bounds (about 4 minutes):
/// `cargo test --release -p guiding-tests --test learning -- --ignored --nocapture seed_spread`.
#[test]
#[ignore = "measurement behind the learning bounds, about 4 minutes"]
fn seed_spread() {
    let npm = NpmSmallRadiance::small(LO, HI);
    let npm20 = NpmMatched::new(small_grid(LO, HI), Target::Radiance);
    let mut cases: Vec<_> = SCENES
        .iter()
        .map(|&s| ("NPM", s, log_kls("NPM", npm, s)))
        .collect();
    let b = Scene::Anisotropic;
    cases.push(("NPM-20", b, log_kls("NPM-20", npm20, b)));
    family_bounds(&cases);
    let nasg = NasgSmallRadiance::small(LO, HI);
    let cases: Vec<_> = SCENES
        .iter()
        .map(|&s| ("NASG", s, log_kls("NASG", nasg, s)))
        .collect();
    family_bounds(&cases);
    for (name, interpolation) in [
        ("DF-N", Interpolation::Nearest),
        ("DF-L", Interpolation::Linear),
    ] {
        let df = DfSmallRadiance::small(LO, HI, interpolation);
        let cases: Vec<_> = SCENES
            .iter()
            .map(|&s| (name, s, log_kls(name, df, s)))
            .collect();
        family_bounds(&cases);
    }
}
