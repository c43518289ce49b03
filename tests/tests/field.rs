//! The CPU runtime (`guiding_core::field`) against a tiny test model: a grid
//! of independent two-lobe vMF mixtures (nearest cell of the unit box), eight
//! raw parameters per cell. One cell makes a position-independent model; a
//! 20³ grid (64 000 parameters) exercises the multi-threaded element-wise
//! passes, which start at 2¹⁵ parameters.

use guiding_core::field::{
    rejection_index, Field, FieldConfig, FieldError, PlateauConfig, DEFAULT_GRADIENT_CHUNKS,
};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::gradient::GradientSink;
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::lobe::DirectionSample;
use guiding_core::loss::{kl_weight, Target};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::model::{Family, GuidingModel, QueryPoint};
use guiding_core::optim::all_finite;
use guiding_core::rng::{hash2, symmetric_unit_f32};
use guiding_core::sample::{Rejection, TrainingSample, REJECTION_KINDS};
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;

const LOBES: usize = 2;
const PER_CELL: usize = LOBES * VMF_RAW_PER_LOBE;

/// `res³` cells over `[0, 1)³`, each an independent `VmfMixture<2>`.
#[derive(Clone, Copy, Debug)]
struct TinyGrid {
    res: usize,
}

impl TinyGrid {
    fn cell(&self, p: [f32; 3]) -> usize {
        let idx = |x: f32| ((x * self.res as f32) as usize).min(self.res - 1);
        (idx(p[2]) * self.res + idx(p[1])) * self.res + idx(p[0])
    }

    fn raw(&self, params: &[f32], p: [f32; 3]) -> [[f32; VMF_RAW_PER_LOBE]; LOBES] {
        let base = self.cell(p) * PER_CELL;
        core::array::from_fn(|k| core::array::from_fn(|j| params[base + k * VMF_RAW_PER_LOBE + j]))
    }

    fn mixture(&self, params: &[f32], q: &QueryPoint) -> VmfMixture<LOBES> {
        VmfMixture::decode(&self.raw(params, q.position))
    }
}

impl GuidingModel for TinyGrid {
    /// A vMF mixture per cell with a constant selection probability.
    const FAMILY: Family = Family::Npm;

    fn param_count(&self) -> usize {
        self.res * self.res * self.res * PER_CELL
    }

    fn init(&self, params: &mut [f32], seed: u32) {
        for (i, p) in params.iter_mut().enumerate() {
            *p = 0.5 * symmetric_unit_f32(hash2(seed, i as u32));
        }
    }

    fn sample(&self, params: &[f32], query: &QueryPoint, u: Vec2) -> DirectionSample {
        self.mixture(params, query).sample(u)
    }

    fn pdf(&self, params: &[f32], query: &QueryPoint, direction: Vec3) -> f32 {
        self.mixture(params, query).pdf(direction)
    }

    fn selection_probability(&self, _params: &[f32], _query: &QueryPoint) -> f32 {
        0.5
    }

    fn constant_selection_probability(&self) -> Option<f32> {
        Some(0.5)
    }

    fn accumulate_gradient<G: GradientSink + ?Sized>(
        &self,
        params: &[f32],
        sample: &TrainingSample,
        grad: &mut G,
    ) -> f32 {
        let w = kl_weight(sample, Target::Radiance);
        if w == 0.0 {
            return 0.0;
        }
        let mut g = [[0.0; VMF_RAW_PER_LOBE]; LOBES];
        let log_pdf =
            VmfMixture::grad_log_pdf(&self.raw(params, sample.position), sample.wi(), &mut g);
        let base = self.cell(sample.position) * PER_CELL;
        for (k, lobe) in g.iter().enumerate() {
            for (j, &d) in lobe.iter().enumerate() {
                grad.add(base + k * VMF_RAW_PER_LOBE + j, -w * d);
            }
        }
        -w * log_pdf
    }
}

/// The target: a vMF lobe (κ = 8) whose mean direction turns with x.
fn target_lobe(p: [f32; 3]) -> VmfLobe {
    let a = 2.0 * p[0];
    VmfLobe::new(Vec3::new(a.cos(), a.sin(), 0.3).normalize(), 8.0)
}

/// A valid training sample at a uniform position of the unit box with a
/// uniform-sphere `wi` and the target's density as grey radiance.
fn valid_sample(rng: &mut Pcg32) -> TrainingSample {
    let position = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
    let wi = square_to_uniform_sphere(rng.next_vec2());
    let l = target_lobe(position).pdf(wi);
    TrainingSample::new(
        query(position),
        wi.to_array(),
        [l; 3],
        INV_FOUR_PI,
        0.0,
        [0.0; 3],
    )
}

fn stream(seed: u64, n: usize) -> Vec<TrainingSample> {
    let mut rng = Pcg32::new(seed, 7);
    (0..n).map(|_| valid_sample(&mut rng)).collect()
}

fn query(p: [f32; 3]) -> QueryPoint {
    QueryPoint::new(p, [0.0; 3], [0.0; 3], 0.5)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Trains `updates` updates of `steps_per_update` steps on a fixed stream.
fn train(
    model: TinyGrid,
    config: FieldConfig,
    updates: usize,
    per_update: usize,
) -> Field<TinyGrid> {
    let mut field = Field::new(model, config).expect("valid config");
    for u in 0..updates {
        field.add_samples(&stream(1000 + u as u64, per_update));
        let report = field.update();
        assert_eq!(report.skipped_steps, 0);
    }
    field
}

fn assert_same_state(a: &Field<TinyGrid>, b: &Field<TinyGrid>, what: &str) {
    assert_eq!(bits(a.params()), bits(b.params()), "{what}: params differ");
    assert_eq!(
        bits(a.ema_params()),
        bits(b.ema_params()),
        "{what}: EMA differs"
    );
    assert_eq!(
        bits(a.adam_moments().0),
        bits(b.adam_moments().0),
        "{what}: m differs"
    );
    assert_eq!(
        bits(a.adam_moments().1),
        bits(b.adam_moments().1),
        "{what}: v differs"
    );
    assert_eq!(a.loss_history(), b.loss_history(), "{what}: losses differ");
    assert_eq!(a.steps(), b.steps());
}

#[test]
fn bit_identical_for_any_thread_count_small_model() {
    // 100 steps (10 updates × 10), 8 parameters: chunk work in parallel,
    // element-wise passes on one thread.
    let config = FieldConfig::DEFAULT
        .with_batch_size(256)
        .with_steps_per_update(10)
        .with_learning_rate(0.02)
        .with_seed(3);
    let model = TinyGrid { res: 1 };
    let one = train(model, config.with_threads(1), 10, 2000);
    assert_eq!(one.steps(), 100);
    for threads in [2, 3, 8, 16] {
        let many = train(model, config.with_threads(threads), 10, 2000);
        assert_same_state(&one, &many, &format!("1 vs {threads} threads"));
    }
}

#[test]
fn bit_identical_for_any_thread_count_large_model() {
    // 64 000 parameters: the reduction, scaling and Adam/EMA passes split
    // the parameter range between threads too.
    let config = FieldConfig::DEFAULT
        .with_batch_size(1024)
        .with_steps_per_update(20)
        .with_learning_rate(0.02)
        .with_seed(11);
    let model = TinyGrid { res: 20 };
    assert!(model.param_count() >= 1 << 15);
    let one = train(model, config.with_threads(1), 5, 8000);
    assert_eq!(one.steps(), 100);
    for threads in [2, 3] {
        let many = train(model, config.with_threads(threads), 5, 8000);
        assert_same_state(&one, &many, &format!("1 vs {threads} threads"));
    }
    // Another seed does change the result (the shuffles are seeded).
    let other = train(model, config.with_threads(2).with_seed(12), 5, 8000);
    assert_ne!(bits(one.params()), bits(other.params()));
}

#[test]
fn training_reduces_loss_and_moves_density_towards_the_target() {
    let model = TinyGrid { res: 1 };
    let config = FieldConfig::DEFAULT
        .with_batch_size(512)
        .with_steps_per_update(20)
        .with_learning_rate(0.05)
        .with_threads(2);
    let field = Field::new(model, config).unwrap();
    let q = query([0.25, 0.5, 0.5]);
    let mean = target_lobe(q.position).mean();
    let before = field.pdf(&q, mean);
    // A position-independent model learns the x-average of the target; use
    // samples at one x so that it has a definite answer.
    let mut field = field;
    let mut rng = Pcg32::new(5, 1);
    for _ in 0..15 {
        let batch: Vec<_> = (0..4000)
            .map(|_| {
                let mut s = valid_sample(&mut rng);
                s.position = q.position;
                let l = target_lobe(q.position).pdf(s.wi());
                s.radiance = [l; 3];
                s
            })
            .collect();
        field.add_samples(&batch);
        field.update();
    }
    let after = field.pdf(&q, mean);
    let peak = target_lobe(q.position).pdf(mean);
    assert!(
        after > 3.0 * before && after > 0.5 * peak,
        "density at the target mean: {before} → {after} (target peak {peak})"
    );
    let h = field.loss_history();
    assert!(h.last().unwrap() < &h[0], "loss history {h:?}");
}

/// Copies of a valid sample broken in one way each, with the expected kind.
fn invalid_samples(base: &TrainingSample) -> Vec<(TrainingSample, Rejection)> {
    let mut out = Vec::new();
    let mut add = |f: &dyn Fn(&mut TrainingSample), kind| {
        let mut s = *base;
        f(&mut s);
        out.push((s, kind));
    };
    add(&|s| s.radiance = [f32::NAN; 3], Rejection::NonFinite);
    add(&|s| s.radiance[1] = f32::INFINITY, Rejection::NonFinite);
    add(&|s| s.position[0] = f32::NEG_INFINITY, Rejection::NonFinite);
    add(&|s| s.wi[2] = f32::NAN, Rejection::NonFinite);
    add(&|s| s.sample_pdf = f32::NAN, Rejection::NonFinite);
    add(&|s| s.radiance[0] = -1.0, Rejection::Negative);
    add(&|s| s.bsdf_cos[2] = -0.5, Rejection::Negative);
    add(&|s| s.sample_pdf = 0.0, Rejection::NonPositivePdf);
    add(&|s| s.sample_pdf = -1.0, Rejection::NonPositivePdf);
    add(&|s| s.bsdf_pdf = -1.0, Rejection::NonPositivePdf);
    add(&|s| s.wi = [0.0; 3], Rejection::NonUnitDirection);
    add(&|s| s.wi = [2.0, 0.0, 0.0], Rejection::NonUnitDirection);
    add(&|s| s.normal = [0.0, 0.5, 0.0], Rejection::NonUnitDirection);
    out
}

#[test]
fn invalid_samples_are_counted_per_kind_and_never_trained_on() {
    let model = TinyGrid { res: 1 };
    let config = FieldConfig::DEFAULT
        .with_batch_size(4096)
        .with_learning_rate(0.05)
        .with_threads(2);
    let mut field = Field::new(model, config).unwrap();
    let mut clean = Field::new(model, config).unwrap();
    let valid = stream(42, 1000);
    let mut expected = [0u64; REJECTION_KINDS];
    let mut batch = Vec::new();
    for (i, s) in valid.iter().enumerate() {
        batch.push(*s);
        if i % 10 == 0 {
            for (bad, kind) in invalid_samples(s) {
                batch.push(bad);
                expected[rejection_index(kind)] += 1;
            }
        }
    }
    field.add_samples(&batch);
    assert_eq!(field.rejected(), expected);
    assert_eq!(field.rejected_of(Rejection::NonFinite), 100 * 5);
    assert_eq!(field.rejected_of(Rejection::Negative), 100 * 2);
    assert_eq!(field.rejected_of(Rejection::NonPositivePdf), 100 * 3);
    assert_eq!(field.rejected_of(Rejection::NonUnitDirection), 100 * 3);
    assert_eq!(field.accepted(), 1000);
    assert_eq!(field.buffered(), 1000);

    // Training on the polluted stream is training on its valid part: the
    // same state as a field fed only the valid samples, bit for bit.
    clean.add_samples(&valid);
    let before = bits(field.params());
    for update in 0..10 {
        if update > 0 {
            field.add_samples(&batch);
            clean.add_samples(&valid);
        }
        assert_eq!(field.update().steps, 1);
        clean.update();
    }
    assert_ne!(before, bits(field.params()), "valid samples train");
    assert_eq!(bits(field.params()), bits(clean.params()));
    assert_eq!(bits(field.ema_params()), bits(clean.ema_params()));
    assert_eq!(field.loss_history(), clean.loss_history());
    // Rejections are cumulative over calls.
    assert_eq!(field.rejected_of(Rejection::NonFinite), 10 * 500);

    // Valid outliers (radiance 10³⁰ — finite) make per-step gradients of
    // ~10²⁷, whose squares would overflow Adam's second moment: the step is
    // clipped, not frozen or skipped, and everything stays finite.
    let mut outlier = valid[3];
    outlier.radiance = [1e30; 3];
    let mut with_outliers = batch.clone();
    with_outliers.push(outlier);
    with_outliers.push(outlier);
    for _ in 0..10 {
        let before = bits(field.params());
        field.add_samples(&with_outliers);
        let r = field.update();
        assert_eq!((r.steps, r.skipped_steps, r.clipped_steps), (1, 0, 1));
        assert_ne!(
            before,
            bits(field.params()),
            "the outlier step still trains"
        );
        assert!(all_finite(field.params()) && all_finite(field.ema_params()));
        let (m, v) = field.adam_moments();
        assert!(all_finite(m) && all_finite(v));
    }
    assert_eq!(field.skipped_steps(), 0);
    assert_eq!(field.clipped_steps(), 10);
    // Back to normal data: training continues.
    for _ in 0..5 {
        field.add_samples(&batch);
        let r = field.update();
        assert_eq!((r.steps, r.clipped_steps), (1, 0));
        assert!(r.mean_loss.is_finite());
    }
    let q = query([0.5; 3]);
    for k in 0..64 {
        let u = Vec2::new((k as f32 + 0.5) / 64.0, 0.37);
        let s = field.sample(&q, u);
        assert!(s.pdf.is_finite() && s.pdf > 0.0 && s.direction.is_finite());
    }
}

#[test]
fn only_invalid_samples_train_nothing() {
    let model = TinyGrid { res: 1 };
    let mut field = Field::new(model, FieldConfig::DEFAULT.with_threads(2)).unwrap();
    let base = stream(1, 1)[0];
    let bad: Vec<_> = invalid_samples(&base).into_iter().map(|(s, _)| s).collect();
    field.add_samples(&bad);
    assert_eq!(field.buffered(), 0);
    let before = bits(field.params());
    let r = field.update();
    assert_eq!((r.steps, r.skipped_steps, r.buffered_samples), (0, 0, 0));
    assert!(r.mean_loss.is_nan() && !r.converged);
    assert_eq!(before, bits(field.params()));
    assert_eq!(field.rejected().iter().sum::<u64>(), bad.len() as u64);
}

#[test]
fn overflowing_gradient_skips_the_step() {
    let model = TinyGrid { res: 1 };
    let config = FieldConfig::DEFAULT.with_batch_size(256).with_threads(2);
    let mut field = Field::new(model, config).unwrap();
    // Train a little first so that the Adam state is non-trivial.
    field.add_samples(&stream(9, 256));
    assert_eq!(field.update().steps, 1);
    let snapshot = |f: &Field<TinyGrid>| {
        (
            bits(f.params()),
            bits(f.ema_params()),
            bits(f.adam_moments().0),
            bits(f.adam_moments().1),
        )
    };
    let before = snapshot(&field);

    // Radiance (3·10³⁸, 0, 0) with pdf 0.5 passes validation (finite,
    // non-negative) and its KL weight, 2·10³⁸, is finite, but 256 such
    // gradients (same direction, so same signs) overflow when summed.
    let mut huge = stream(10, 256);
    for s in &mut huge {
        s.radiance = [3e38, 0.0, 0.0];
        s.sample_pdf = 0.5;
        s.wi = [0.0, 0.0, 1.0];
        assert!(s.validate().is_ok());
        let w = kl_weight(s, Target::Radiance);
        assert!(w.is_finite() && w > 1e38, "{w}");
    }
    field.add_samples(&huge);
    assert_eq!(field.buffered(), 256);
    let r = field.update();
    assert_eq!((r.steps, r.skipped_steps), (0, 1));
    assert!(r.mean_loss.is_nan());
    assert_eq!(field.skipped_steps(), 1);
    assert_eq!(field.steps(), 1);
    assert_eq!(before, snapshot(&field), "a skipped step changes nothing");
    assert!(all_finite(field.params()) && all_finite(field.ema_params()));

    // And training goes on normally afterwards.
    field.add_samples(&stream(11, 256));
    let r = field.update();
    assert_eq!((r.steps, r.skipped_steps), (1, 0));
    assert_eq!(field.steps(), 2);
}

#[test]
fn max_steps_stops_training() {
    let model = TinyGrid { res: 1 };
    let config = FieldConfig::DEFAULT
        .with_batch_size(100)
        .with_steps_per_update(2)
        .with_max_steps(5)
        .with_threads(1);
    let mut field = Field::new(model, config).unwrap();
    let data = stream(3, 300);
    for expected_steps in [2, 4] {
        field.add_samples(&data);
        let r = field.update();
        assert!(!r.converged);
        assert_eq!(field.steps(), expected_steps);
        assert!(!field.is_converged());
    }
    field.add_samples(&data);
    let r = field.update();
    assert_eq!(r.steps, 1, "the limit cuts the update short");
    assert!(r.converged && field.is_converged());
    assert_eq!(field.steps(), 5);

    // From now on: no training, samples ignored (not rejected).
    let params = bits(field.params());
    let ema = bits(field.ema_params());
    let accepted = field.accepted();
    let mut bad = data[0];
    bad.radiance[0] = f32::NAN;
    field.add_samples(&data);
    field.add_samples(&[bad]);
    assert_eq!(field.ignored(), 301);
    assert_eq!(field.accepted(), accepted);
    assert_eq!(field.rejected(), [0; REJECTION_KINDS]);
    assert_eq!(field.buffered(), 0);
    let r = field.update();
    assert_eq!((r.steps, r.skipped_steps, r.buffered_samples), (0, 0, 0));
    assert!(r.converged);
    assert_eq!(params, bits(field.params()));
    assert_eq!(ema, bits(field.ema_params()));
    // Inference still works.
    let s = field.sample(&query([0.5; 3]), Vec2::new(0.3, 0.6));
    assert!(s.pdf > 0.0);
}

#[test]
fn plateau_stops_training() {
    // A learning rate so small that the parameters (and so the loss of the
    // same data) do not change: the first update sets the best loss, the
    // next `window` updates do not improve it by 1 %.
    let model = TinyGrid { res: 1 };
    let window = 3;
    let config = FieldConfig::DEFAULT
        .with_batch_size(1 << 14)
        .with_learning_rate(1e-12)
        .with_plateau(PlateauConfig::new(window, 0.01))
        .with_threads(2);
    let mut field = Field::new(model, config).unwrap();
    let data = stream(4, 2000);
    for update in 1..=window + 1 {
        assert!(!field.is_converged(), "converged before update {update}");
        field.add_samples(&data);
        let r = field.update();
        assert_eq!(r.steps, 1);
        assert_eq!(r.converged, update == window + 1, "update {update}");
    }
    assert!(field.is_plateaued() && field.is_converged());
    assert_eq!(field.loss_history().len(), window as usize + 1);
    let params = bits(field.params());
    field.add_samples(&data);
    assert_eq!(field.ignored(), 2000);
    let r = field.update();
    assert_eq!(r.steps, 0);
    assert_eq!(params, bits(field.params()));

    // With a real learning rate the loss keeps improving: no plateau.
    let mut learning = Field::new(
        model,
        config
            .with_learning_rate(0.05)
            .with_steps_per_update(5)
            .with_batch_size(400),
    )
    .unwrap();
    for _ in 0..window + 1 {
        learning.add_samples(&data);
        learning.update();
    }
    assert!(
        !learning.is_converged(),
        "losses {:?}",
        learning.loss_history()
    );
}

#[test]
fn stop_training_is_final() {
    let model = TinyGrid { res: 1 };
    let mut field = Field::new(model, FieldConfig::DEFAULT.with_threads(1)).unwrap();
    field.add_samples(&stream(5, 100));
    assert_eq!(field.buffered(), 100);
    field.stop_training();
    assert!(field.is_converged() && !field.is_plateaued());
    assert_eq!(field.buffered(), 0, "the buffer is dropped");
    let params = bits(field.params());
    field.add_samples(&stream(6, 50));
    let r = field.update();
    assert_eq!(r.steps, 0);
    assert!(r.converged);
    assert_eq!(field.ignored(), 50);
    assert_eq!(params, bits(field.params()));
}

#[test]
fn ema_tracks_parameters() {
    let model = TinyGrid { res: 1 };
    let field = Field::new(model, FieldConfig::DEFAULT).unwrap();
    assert_eq!(
        bits(field.params()),
        bits(field.ema_params()),
        "EMA starts at the init"
    );
    let data = stream(8, 512);
    // Decay 0: the EMA is the latest parameters.
    let mut f0 = Field::new(
        model,
        FieldConfig::DEFAULT
            .with_ema_decay(0.0)
            .with_batch_size(128)
            .with_steps_per_update(4),
    )
    .unwrap();
    f0.add_samples(&data);
    f0.update();
    assert_eq!(bits(f0.params()), bits(f0.ema_params()));
    // Decay 0.95: an average that lags behind the parameters; the debiased
    // EMA copies the parameters at step 1.
    let mut f1 = Field::new(model, FieldConfig::DEFAULT.with_batch_size(128)).unwrap();
    f1.add_samples(&data);
    f1.update();
    assert_eq!(bits(f1.params()), bits(f1.ema_params()), "step 1 copies");
    f1.add_samples(&data);
    f1.update();
    assert_ne!(bits(f1.params()), bits(f1.ema_params()));
    // Inference uses the EMA.
    let q = query([0.5; 3]);
    let ema_model = model.pdf(f1.ema_params(), &q, Vec3::X);
    assert_eq!(f1.pdf(&q, Vec3::X).to_bits(), ema_model.to_bits());
}

#[test]
fn buffer_capacity_and_small_buffers() {
    let model = TinyGrid { res: 1 };
    let config = FieldConfig::DEFAULT
        .with_max_buffered_samples(150)
        .with_batch_size(1000)
        .with_steps_per_update(3);
    let mut field = Field::new(model, config).unwrap();
    field.add_samples(&stream(1, 100));
    field.add_samples(&stream(2, 100));
    assert_eq!(
        (field.buffered(), field.overflowed(), field.accepted()),
        (150, 50, 150)
    );
    let r = field.update();
    // A buffer smaller than a batch is used whole by every step.
    assert_eq!((r.steps, r.batch_size, r.buffered_samples), (3, 150, 150));
    assert_eq!(field.buffered(), 0, "the buffer is cleared");
    // Fewer samples than gradient chunks still train.
    field.add_samples(&stream(3, 3));
    let r = field.update();
    assert_eq!((r.steps, r.batch_size), (3, 3));
    assert!(r.mean_loss.is_finite());
}

#[test]
fn batched_inference_matches_single_queries() {
    let model = TinyGrid { res: 4 };
    let mut field = Field::new(
        model,
        FieldConfig::DEFAULT.with_threads(3).with_batch_size(512),
    )
    .unwrap();
    field.add_samples(&stream(12, 2048));
    field.update();
    let mut rng = Pcg32::new(77, 3);
    let n = 5000;
    let queries: Vec<_> = (0..n)
        .map(|_| query([rng.next_f32(), rng.next_f32(), rng.next_f32()]))
        .collect();
    let us: Vec<_> = (0..n).map(|_| rng.next_vec2()).collect();
    let dirs: Vec<_> = (0..n)
        .map(|_| square_to_uniform_sphere(rng.next_vec2()))
        .collect();
    let mut samples = vec![
        DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0
        };
        n
    ];
    let mut pdfs = vec![0.0; n];
    let mut sel = vec![0.0; n];
    field.sample_batch(&queries, &us, &mut samples);
    field.pdf_batch(&queries, &dirs, &mut pdfs);
    field.selection_probability_batch(&queries, &mut sel);
    for i in 0..n {
        let s = field.sample(&queries[i], us[i]);
        assert_eq!(
            s.direction.to_array().map(f32::to_bits),
            samples[i].direction.to_array().map(f32::to_bits)
        );
        assert_eq!(s.pdf.to_bits(), samples[i].pdf.to_bits());
        assert_eq!(field.pdf(&queries[i], dirs[i]).to_bits(), pdfs[i].to_bits());
        assert_eq!(sel[i], field.selection_probability(&queries[i]));
        // The sampled direction's density agrees with pdf().
        let p = field.pdf(&queries[i], s.direction);
        assert!((p - s.pdf).abs() <= 1e-4 * p.max(1.0), "{p} vs {}", s.pdf);
    }
    // Tiny batches (single-threaded path) too.
    let mut few = vec![0.0; 3];
    field.pdf_batch(&queries[..3], &dirs[..3], &mut few);
    assert_eq!(few, pdfs[..3]);
}

#[test]
#[should_panic(expected = "pdf_batch")]
fn batched_inference_checks_lengths() {
    let field = Field::new(TinyGrid { res: 1 }, FieldConfig::DEFAULT).unwrap();
    let mut out = vec![0.0; 2];
    field.pdf_batch(&[query([0.5; 3]); 3], &[Vec3::Z; 3], &mut out);
}

#[test]
fn config_validation() {
    let model = TinyGrid { res: 1 };
    let d = FieldConfig::DEFAULT;
    assert!(d.validate().is_ok());
    assert_eq!(d.gradient_chunks, DEFAULT_GRADIENT_CHUNKS);
    let cases: Vec<(FieldConfig, &str)> = vec![
        (d.with_batch_size(0), "batch_size"),
        (d.with_steps_per_update(0), "steps_per_update"),
        (d.with_learning_rate(f32::NAN), "learning_rate"),
        (d.with_learning_rate(f32::INFINITY), "learning_rate"),
        (d.with_learning_rate(0.0), "learning_rate"),
        (d.with_learning_rate(-1e-3), "learning_rate"),
        (d.with_adam(d.adam.with_betas(1.0, 0.99)), "beta1"),
        (d.with_adam(d.adam.with_betas(0.9, f32::NAN)), "beta2"),
        (d.with_adam(d.adam.with_epsilon(0.0)), "epsilon"),
        (
            d.with_adam(d.adam.with_l2_regularization(-1.0)),
            "l2_regularization",
        ),
        (d.with_ema_decay(1.0), "ema_decay"),
        (d.with_ema_decay(f32::NAN), "ema_decay"),
        (d.with_gradient_chunks(0), "gradient_chunks"),
        (d.with_gradient_chunks(1025), "gradient_chunks"),
        (d.with_threads(1025), "threads"),
        (d.with_plateau(PlateauConfig::new(3, f32::NAN)), "plateau"),
        (d.with_plateau(PlateauConfig::new(3, -0.1)), "plateau"),
        (d.with_max_buffered_samples(0), "max_buffered_samples"),
        (
            d.with_max_gradient_magnitude(f32::INFINITY),
            "max_gradient_magnitude",
        ),
        (d.with_max_gradient_magnitude(0.0), "max_gradient_magnitude"),
    ];
    for (config, needle) in cases {
        let err = Field::new(model, config).expect_err(needle);
        let msg = err.to_string();
        assert!(msg.contains(needle), "message {msg:?} should name {needle}");
        assert_eq!(config.validate().unwrap_err().to_string(), msg);
        let _: &dyn std::error::Error = &err;
    }
    assert_eq!(
        Field::new(model, d.with_batch_size(0)).unwrap_err(),
        FieldError::ZeroBatchSize
    );
    // A grid of no cells: a model without parameters.
    let empty = TinyGrid { res: 0 };
    assert_eq!(Field::new(empty, d).unwrap_err(), FieldError::EmptyModel);
    assert!(Field::new(empty, d)
        .unwrap_err()
        .to_string()
        .contains("no parameters"));
    // from_params checks the vector.
    let err = Field::from_params(model, d, vec![0.0; 7]).unwrap_err();
    assert!(err.to_string().contains("7"), "{err}");
    let mut p = vec![0.0; 8];
    p[3] = f32::NAN;
    assert!(Field::from_params(model, d, p).is_err());
    let f = Field::from_params(model, d, vec![0.25; 8]).unwrap();
    assert_eq!(f.params(), &[0.25; 8]);
    assert_eq!(f.ema_params(), &[0.25; 8]);
    // threads = 0 resolves to the machine's parallelism.
    assert!(Field::new(model, d.with_threads(0)).unwrap().threads() >= 1);
    assert_eq!(Field::new(model, d.with_threads(5)).unwrap().threads(), 5);
}

/// Proportional training: `clamp(⌈epochs · buffered / batch⌉, 1, steps_per_update)`
/// Adam steps, and `update_steps` takes exactly that many.
#[test]
fn proportional_steps_follow_the_buffer() {
    let config = FieldConfig::DEFAULT
        .with_batch_size(100)
        .with_steps_per_update(8)
        .with_threads(1);
    let mut field = Field::new(TinyGrid { res: 2 }, config).expect("valid config");
    assert_eq!(
        field.proportional_steps(1.0),
        1,
        "an empty buffer still takes one step"
    );
    for (n, epochs, expected) in [
        (50usize, 1.0f32, 1u32),
        (100, 1.0, 1),
        (101, 1.0, 2),
        (250, 1.0, 3),
        (250, 2.0, 5),
        (250, 0.1, 1),
        (5000, 1.0, 8),
        (250, f32::NAN, 3),
        (250, -1.0, 3),
        (250, f32::MAX, 8),
    ] {
        let mut f = Field::new(TinyGrid { res: 2 }, config).expect("valid config");
        f.add_samples(&stream(7, n));
        assert_eq!(
            f.proportional_steps(epochs),
            expected,
            "n {n} epochs {epochs}"
        );
        if epochs == 1.0 {
            let report = f.update_steps(expected);
            assert_eq!(report.steps + report.skipped_steps, expected);
        }
    }
    field.add_samples(&stream(8, 250));
    assert_eq!(field.update_steps(0).steps, 1, "zero steps reads as one");
}
