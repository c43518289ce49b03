//! Fuzz target `training_step`: arbitrary training batches through the CPU
//! runtime [`Field`] of every small model.

use super::{check_density, check_sample, special_values, ByteReader};
use glam::Vec3;
use guiding_core::field::{Field, FieldConfig};
use guiding_core::model::df::{DfSmallProduct, DfSmallRadiance};
use guiding_core::model::nasg::{NasgSmallProduct, NasgSmallRadiance};
use guiding_core::model::npm::{NpmSmallProduct, NpmSmallRadiance};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::optim::all_finite;
use guiding_core::pdf1d::Interpolation;
use guiding_core::sample::{Rejection, TrainingSample, REJECTION_KINDS, UNIT_TOLERANCE};
use guiding_core::sphere::square_to_uniform_sphere;

/// Values at the edges of every field's domain.
const SPECIAL: [f32; 16] = special_values(
    [0.0, -0.0, 1e-45, -1e-45, 1e-38, -1.0, 1.0, 1e6, 1e18],
    [1.0 + 2.0 * UNIT_TOLERANCE],
);

/// Powers of ten for plausible magnitudes.
const SCALE: [f32; 8] = [1e-30, 1e-6, 1e-2, 1.0, 1e2, 1e6, 1e18, 1e30];

impl ByteReader<'_> {
    /// A value that is sometimes any bit pattern, sometimes a special value
    /// and mostly a plausible magnitude in `[0, 10^k)`.
    fn mixed(&mut self) -> f32 {
        let b = self.byte();
        match b % 4 {
            0 => self.any_f32(),
            1 => SPECIAL[usize::from(b >> 4)],
            _ => self.unit() * SCALE[usize::from((b >> 2) % 8)],
        }
    }

    /// A direction: mostly unit (uniform from a sample point), sometimes a
    /// normalised or raw arbitrary vector (zero, NaN, off-unit), or zero.
    fn direction(&mut self, allow_zero: bool) -> Vec3 {
        match self.byte() % 8 {
            0 => self.any_direction(),
            1 => self.any_direction().normalize(),
            2 if allow_zero => Vec3::ZERO,
            3 => square_to_uniform_sphere(self.sample_point()) * (1.0 + self.mixed()),
            _ => square_to_uniform_sphere(self.sample_point()),
        }
    }

    /// A position: mostly inside `[−1, 1]³`, sometimes anywhere.
    fn position(&mut self) -> Vec3 {
        if self.byte() % 4 == 0 {
            self.any_direction()
        } else {
            Vec3::new(self.unit(), self.unit(), self.unit()) * 2.0 - Vec3::ONE
        }
    }

    fn training_sample(&mut self) -> TrainingSample {
        // Read in the order of the struct's fields.
        let position = self.position().to_array();
        let roughness = self.mixed();
        let normal = self.direction(true).to_array();
        let sample_pdf = self.mixed();
        let wo = self.direction(true).to_array();
        let bsdf_pdf = if self.byte() % 2 == 0 {
            0.0
        } else {
            self.mixed()
        };
        let wi = self.direction(false).to_array();
        let radiance = [self.mixed(), self.mixed(), self.mixed()];
        let bsdf_cos = [self.mixed(), self.mixed(), self.mixed()];
        let vertex = QueryPoint::new(position, normal, wo, roughness);
        TrainingSample::new(vertex, wi, radiance, sample_pdf, bsdf_pdf, bsdf_cos)
    }

    fn query(&mut self) -> QueryPoint {
        let position = self.position().to_array();
        let roughness = self.mixed();
        let normal = self.direction(true).to_array();
        QueryPoint::new(position, normal, self.direction(true).to_array(), roughness)
    }
}

/// The rejection a sample must get, written from the documented rules of
/// `TrainingSample::validate` (checked in this order): any non-finite field
/// → non-finite; a negative radiance or BSDF component → negative;
/// `sample_pdf ≤ 0` or `bsdf_pdf < 0` → non-positive pdf; `|wi|` or a
/// non-zero `|normal|`, `|wo|` off 1 by more than `UNIT_TOLERANCE` (lengths
/// in `f32`, as the renderer computes them) → non-unit.
fn expected_rejection(s: &TrainingSample) -> Option<Rejection> {
    let vectors = [
        s.position,
        s.normal,
        s.wo,
        s.wi,
        s.radiance,
        s.bsdf_cos,
        [s.roughness, s.sample_pdf, s.bsdf_pdf],
    ];
    if vectors.iter().flatten().any(|v| !v.is_finite()) {
        return Some(Rejection::NonFinite);
    }
    if s.radiance.iter().chain(&s.bsdf_cos).any(|&v| v < 0.0) {
        return Some(Rejection::Negative);
    }
    if !(s.sample_pdf > 0.0 && s.bsdf_pdf >= 0.0) {
        return Some(Rejection::NonPositivePdf);
    }
    let unit = |v: [f32; 3]| (Vec3::from_array(v).length() - 1.0).abs() <= UNIT_TOLERANCE;
    let zero = |v: [f32; 3]| v == [0.0; 3];
    if !unit(s.wi) || !(zero(s.normal) || unit(s.normal)) || !(zero(s.wo) || unit(s.wo)) {
        return Some(Rejection::NonUnitDirection);
    }
    None
}

/// Fuzz target `training_step`: the first byte picks one of the eight small
/// presets (NPM, NASG, DF-N, DF-L × radiance/product) and whether the grid
/// box is `[−1, 1]³` or arbitrary; then a configuration (learning rate,
/// batch size, steps per update, EMA decay, chunks, buffer capacity, gradient
/// clip, 1 or 2 threads; invalid values must be refused by `Field::new`),
/// a parameter scale (10⁻³⁰ … 10³⁰ times the initialisation), and up to three
/// rounds of up to 24 samples built from the bytes (NaN, ±∞, negative, huge
/// and subnormal values, non-unit and zero directions) followed by an update.
///
/// Asserts: every sample is accepted, rejected under the kind the
/// documented rules give, or counted as overflowed, and the counters add up;
/// parameters, EMA and Adam moments stay finite after every update; step
/// counts add up; inference from the trained field at an arbitrary query
/// gives unit directions with matching finite densities and a selection
/// probability in `[0, 1]`.
pub fn training_step(data: &[u8]) -> TrainingOutcome {
    let mut r = ByteReader::new(data);
    let head = r.byte();
    let (lo, hi) = if head & 0x80 != 0 {
        (r.any_direction().to_array(), r.any_direction().to_array())
    } else {
        ([-1.0; 3], [1.0; 3])
    };
    match head % 8 {
        0 => run(NpmSmallRadiance::small(lo, hi), &mut r),
        1 => run(NpmSmallProduct::small(lo, hi), &mut r),
        2 => run(NasgSmallRadiance::small(lo, hi), &mut r),
        3 => run(NasgSmallProduct::small(lo, hi), &mut r),
        4 => run(
            DfSmallRadiance::small(lo, hi, Interpolation::Nearest),
            &mut r,
        ),
        5 => run(
            DfSmallProduct::small(lo, hi, Interpolation::Nearest),
            &mut r,
        ),
        6 => run(
            DfSmallRadiance::small(lo, hi, Interpolation::Linear),
            &mut r,
        ),
        _ => run(DfSmallProduct::small(lo, hi, Interpolation::Linear), &mut r),
    }
}

fn config(r: &mut ByteReader) -> FieldConfig {
    const RATES: [f32; 8] = [1e-4, 1e-3, 1e-2, 5e-2, 0.3, 1.0, 1e3, 1e30];
    const DECAYS: [f32; 4] = [0.0, 0.5, 0.95, 0.999_999];
    const CLIPS: [f32; 4] = [1e18, 1.0, 1e-30, f32::MAX];
    let b = [r.byte(), r.byte(), r.byte()];
    let mut c = FieldConfig::DEFAULT
        .with_learning_rate(RATES[usize::from(b[0] % 8)])
        .with_ema_decay(DECAYS[usize::from((b[0] >> 3) % 4)])
        .with_batch_size(1 + usize::from(b[1] % 8))
        .with_steps_per_update(1 + u32::from((b[1] >> 3) % 4))
        .with_gradient_chunks(1 + usize::from((b[1] >> 5) % 4))
        .with_max_buffered_samples(1 + usize::from(b[2] % 32))
        .with_max_gradient_magnitude(CLIPS[usize::from((b[2] >> 5) % 4)])
        .with_threads(1 + usize::from(b[0] >> 7))
        .with_seed(u32::from(b[2]));
    if b[0] & 0x20 != 0 {
        // Arbitrary hyper-parameters: Field::new must accept or refuse them
        // exactly as `validate` says.
        c = c
            .with_learning_rate(r.mixed())
            .with_ema_decay(r.mixed())
            .with_max_gradient_magnitude(r.mixed());
        c.adam = c
            .adam
            .with_betas(r.mixed(), r.mixed())
            .with_epsilon(r.mixed());
    }
    c
}

/// What one `training_step` input did (for tests of the seeds).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TrainingOutcome {
    /// Whether `Field::from_params` accepted the configuration.
    pub created: bool,
    /// Samples accepted into the buffer.
    pub accepted: u64,
    /// Rejected samples per kind.
    pub rejected: [u64; REJECTION_KINDS],
    /// Valid samples dropped for a full buffer.
    pub overflowed: u64,
    /// Adam steps applied.
    pub steps: u64,
    /// Steps skipped for a non-finite gradient.
    pub skipped: u64,
}

fn run<M: GuidingModel + Send + Sync>(model: M, r: &mut ByteReader) -> TrainingOutcome {
    let config = config(r);
    let scale = match r.byte() % 8 {
        0 => 1e-30,
        1 => 1e3,
        2 => 1e15,
        3 => 1e30,
        _ => 1.0,
    };
    let mut params = vec![0.0; model.param_count()];
    model.init(&mut params, config.seed);
    for p in &mut params {
        *p *= scale;
    }
    let finite = all_finite(&params);
    let mut field = match Field::from_params(model, config, params) {
        Ok(f) => {
            assert!(config.validate().is_ok() && finite);
            f
        }
        Err(e) => {
            assert!(
                config.validate().is_err() || !finite,
                "valid config and params refused: {e}"
            );
            assert!(!e.to_string().is_empty());
            return TrainingOutcome::default();
        }
    };

    let (mut added, mut overflowed, mut accepted) = (0u64, 0u64, 0u64);
    let mut rejected = [0u64; REJECTION_KINDS];
    let (mut steps, mut skipped) = (0u64, 0u64);
    for _ in 0..1 + r.byte() % 3 {
        let n = usize::from(r.byte() % 25);
        let batch: Vec<TrainingSample> = (0..n).map(|_| r.training_sample()).collect();
        let room = config.max_buffered_samples - field.buffered();
        let mut valid = 0;
        for s in &batch {
            match expected_rejection(s) {
                Some(kind) => rejected[kind as usize - 1] += 1,
                None => valid += 1,
            }
        }
        accepted += valid.min(room) as u64;
        overflowed += valid.saturating_sub(room) as u64;
        added += n as u64;
        field.add_samples(&batch);
        assert_eq!(field.rejected(), rejected, "rejections per kind");
        assert_eq!(field.accepted(), accepted, "accepted");
        assert_eq!(field.overflowed(), overflowed, "overflowed");
        assert_eq!(field.ignored(), 0);
        assert_eq!(
            field.accepted() + field.overflowed() + field.rejected().iter().sum::<u64>(),
            added
        );

        let buffered = field.buffered();
        let report = field.update();
        assert_eq!(report.buffered_samples, buffered);
        assert_eq!(field.buffered(), 0);
        if buffered > 0 {
            assert_eq!(
                report.steps + report.skipped_steps,
                config.steps_per_update,
                "{report:?}"
            );
            assert_eq!(report.batch_size, config.batch_size.min(buffered));
        } else {
            assert_eq!(report.steps + report.skipped_steps, 0);
        }
        assert!(report.clipped_steps <= report.steps);
        assert!(
            report.steps == 0 || report.mean_loss.is_finite(),
            "{report:?}"
        );
        steps += u64::from(report.steps);
        skipped += u64::from(report.skipped_steps);
        assert_eq!((field.steps(), field.skipped_steps()), (steps, skipped));
        assert!(all_finite(field.params()), "non-finite parameters");
        assert!(all_finite(field.ema_params()), "non-finite EMA");
        let (m, v) = field.adam_moments();
        assert!(all_finite(m) && all_finite(v), "non-finite Adam moments");
        assert!(v.iter().all(|&x| x >= 0.0), "negative second moment");
    }

    for _ in 0..2 {
        let q = r.query();
        let s = field.sample(&q, r.sample_point());
        check_sample("trained field", s, |d| field.pdf(&q, d), 1e-4);
        check_density("trained field", field.pdf(&q, r.any_direction()));
        let c = field.selection_probability(&q);
        assert!((0.0..=1.0).contains(&c), "selection probability {c}");
    }
    TrainingOutcome {
        created: true,
        accepted,
        rejected,
        overflowed,
        steps,
        skipped,
    }
}

/// Writes `training_step` inputs that decode to exact values (every float
/// in its raw-bits mode), for seed corpora and tests.
#[derive(Default)]
pub struct TrainingInput {
    bytes: Vec<u8>,
}

impl TrainingInput {
    /// Model `head` (see [`training_step`]; bit 7 clear: box `[−1, 1]³`),
    /// configuration bytes, and parameter-scale byte (`≥ 4`: scale 1).
    #[must_use]
    pub fn new(head: u8, config: [u8; 3], scale: u8) -> Self {
        let mut bytes = vec![head & 0x7f];
        bytes.extend_from_slice(&config);
        bytes.push(scale);
        Self { bytes }
    }

    fn raw(&mut self, v: f32) {
        self.bytes.push(0);
        self.bytes.extend_from_slice(&v.to_bits().to_le_bytes());
    }

    fn vector(&mut self, v: [f32; 3]) {
        self.bytes.push(0);
        for x in v {
            self.bytes.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }

    /// The number of rounds (1 to 3) that follow.
    #[must_use]
    pub fn rounds(mut self, rounds: u8) -> Self {
        self.bytes.push(rounds.clamp(1, 3) - 1);
        self
    }

    /// One round of at most 24 samples.
    #[must_use]
    pub fn round(mut self, samples: &[TrainingSample]) -> Self {
        self.bytes.push(samples.len().min(24) as u8);
        for s in samples.iter().take(24) {
            self.vector(s.position);
            self.raw(s.roughness);
            self.vector(s.normal);
            self.raw(s.sample_pdf);
            self.vector(s.wo);
            self.bytes.push(1);
            self.raw(s.bsdf_pdf);
            self.vector(s.wi);
            for v in s.radiance.into_iter().chain(s.bsdf_cos) {
                self.raw(v);
            }
        }
        self
    }

    /// One inference query with its sample point and density direction.
    #[must_use]
    pub fn query(mut self, q: &QueryPoint, u: [u32; 2], d: Vec3) -> Self {
        self.vector(q.position);
        self.raw(q.roughness);
        self.vector(q.normal);
        self.vector(q.wo);
        self.bytes.push(0);
        self.bytes.extend_from_slice(&(u[0] << 8).to_le_bytes());
        self.bytes.extend_from_slice(&(u[1] << 8).to_le_bytes());
        for x in d.to_array() {
            self.bytes.extend_from_slice(&x.to_bits().to_le_bytes());
        }
        self
    }

    /// The input.
    #[must_use]
    pub fn finish(self) -> Vec<u8> {
        self.bytes
    }
}
