//! The multi-threaded CPU runtime of a guiding model: online training with
//! Adam over a sample buffer, an exponential moving average of the weights
//! for inference, rejection statistics, convergence detection, and batched
//! inference spread over threads. `std` only (it allocates and spawns scoped
//! threads); generic over [`GuidingModel`] (no `dyn`).
//!
//! # Training
//!
//! The renderer hands its training records to [`Field::add_samples`]; each is
//! [validated](TrainingSample::validate) and rejected ones are only counted
//! (per [`Rejection`] kind), never stored. [`Field::update`] then runs
//! [`FieldConfig::steps_per_update`] Adam steps on minibatches of
//! [`FieldConfig::batch_size`] samples drawn from the buffer and **clears the
//! buffer** (online training: every update trains on the newest samples
//! only; feed about `steps_per_update × batch_size` samples per update —
//! surplus samples are never looked at, a smaller buffer is reused).
//!
//! Minibatches: the buffer is shuffled (Fisher–Yates with an [`Rng`] seeded
//! by `(seed, update index)`) and cut into consecutive batches of
//! `min(batch_size, buffered)` samples; when fewer than a batch remain, it
//! is shuffled again (a new epoch) and drawing restarts at its front.
//!
//! The gradient of a step is `Σ model.accumulate_gradient(sample) / n` over
//! the `n` samples of the batch. If any element of it (or the batch loss) is
//! not finite, the step is **skipped** and counted
//! ([`Field::skipped_steps`]): no NaN or ±∞ is ever written into the
//! parameters, the Adam moments or the EMA. A finite gradient with an
//! element beyond [`FieldConfig::max_gradient_magnitude`] (default
//! [`DEFAULT_MAX_GRADIENT_MAGNITUDE`]) is scaled down as a whole so that its
//! largest element has that magnitude — direction kept, step counted as
//! clipped ([`Field::clipped_steps`]): Adam squares the gradient, and an
//! element above `~1.8·10¹⁹` would overflow `g²` and freeze (see below), so
//! without the clip one huge but valid outlier sample (radiance `10³⁰`)
//! would stop the whole step. Adam's update is invariant to the gradient's
//! scale, so the clip only changes how much the outlier step weighs against
//! its neighbours in the moments. (Within a finite step, [`adam_step`](crate::optim::adam_step)
//! additionally leaves an element untouched if its own update would
//! overflow; [`UpdateReport::element_skips`] counts those.) After each
//! applied step the EMA copy is updated ([`ema_update`](crate::optim::ema_update), debiased, decay
//! [`FieldConfig::ema_decay`]); inference always uses the EMA weights. Before
//! the first step the EMA equals the initial parameters.
//!
//! # Determinism
//!
//! Training is bit-identical for any [`FieldConfig::threads`]: a batch is
//! cut into [`FieldConfig::gradient_chunks`] contiguous chunks (a number that
//! does not depend on the thread count), each chunk sums its samples'
//! gradients in order into its own zeroed buffer, and the chunk sums are
//! added into the step's gradient **in chunk order**: every gradient
//! element is `((0 + c₀) + c₁) + … + c_{C−1}` whichever thread computed which
//! chunk. Threads take the chunks in waves of `min(threads, chunks)`; the
//! element-wise passes (reduction, scaling, Adam, EMA) split the parameter
//! range between threads, which cannot change any result. Losses are summed
//! per chunk in `f64`, likewise in chunk order. Changing `gradient_chunks`
//! (or the seed, batch size…) changes the rounding, changing `threads` does
//! not. Inference is per element and trivially deterministic.
//!
//! # Memory
//!
//! With `P = model.param_count()` floats: parameters, EMA and the two Adam
//! moments (`4P`), allocated by [`Field::new`]; on the first update, one
//! gradient buffer plus `min(threads, gradient_chunks)` chunk buffers
//! (`(1 + W)P`), reused by every later step. For a 4.1 M-parameter model
//! (16.5 MB per copy) on 2 threads that is `7 × 16.5 ≈ 115 MB`. Plus the
//! sample buffer (96 bytes per sample, at most
//! [`FieldConfig::max_buffered_samples`]).
//!
//! # Convergence
//!
//! Each update records the mean loss of its applied steps
//! ([`Field::loss_history`]). The loss is said to have plateaued when
//! [`PlateauConfig::window`] consecutive updates failed to improve the best
//! mean so far by the relative margin [`PlateauConfig::min_relative_improvement`]
//! (an update improves if `mean < best − margin · |best|`). Training stops
//! for good ([`Field::is_converged`]) on a plateau, when the number of
//! attempted steps (applied plus skipped) reaches [`FieldConfig::max_steps`],
//! or on [`Field::stop_training`]; from then on [`Field::update`] does
//! nothing and [`Field::add_samples`] drops samples without looking at them
//! (counted as [`Field::ignored`], not as rejected).

use crate::lobe::DirectionSample;
use crate::model::{GuidingModel, QueryPoint};
use crate::optim::{adam_ema_step, step_clip_factor, AdamConfig};
use crate::rng::{shuffle, Rng};
use crate::sample::{Rejection, TrainingSample, REJECTION_KINDS};
use core::fmt;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::thread;
use std::vec;
use std::vec::Vec;

/// Default [`FieldConfig::gradient_chunks`].
pub const DEFAULT_GRADIENT_CHUNKS: usize = 8;

/// Largest accepted [`FieldConfig::gradient_chunks`].
pub const MAX_GRADIENT_CHUNKS: usize = 1024;

/// Largest accepted [`FieldConfig::threads`].
pub const MAX_THREADS: usize = 1024;

/// Default [`FieldConfig::max_gradient_magnitude`], `10¹⁸`: the largest
/// power of ten whose square (`10³⁶`) Adam's second moment holds without
/// overflowing `f32` (`3.4·10³⁸`).
pub const DEFAULT_MAX_GRADIENT_MAGNITUDE: f32 = 1e18;

/// Element-wise passes over fewer parameters than this run on the calling
/// thread (spawning costs more than the work).
const PARALLEL_MIN_ELEMENTS: usize = 1 << 15;
/// Batched inference over fewer queries than this runs on the calling thread.
const PARALLEL_MIN_QUERIES: usize = 256;
/// Parameter ranges given to threads are multiples of this many floats (one
/// 64-byte cache line), so no two threads write to the same line.
const RANGE_ALIGN: usize = 16;

/// When the training loss counts as converged; see the
/// [module docs](self#convergence).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlateauConfig {
    /// Number of consecutive updates without improvement after which the
    /// loss counts as plateaued; `0` disables the criterion.
    pub window: u32,
    /// Relative improvement of the best per-update mean loss that counts as
    /// progress, `≥ 0` (e.g. `0.01` = 1 %).
    pub min_relative_improvement: f32,
}

impl PlateauConfig {
    /// No plateau detection (training stops only at `max_steps` or on
    /// [`Field::stop_training`]).
    pub const DISABLED: Self = Self {
        window: 0,
        min_relative_improvement: 0.0,
    };

    /// Plateau after `window` updates without a relative improvement of
    /// `min_relative_improvement`.
    #[must_use]
    pub const fn new(window: u32, min_relative_improvement: f32) -> Self {
        Self {
            window,
            min_relative_improvement,
        }
    }
}

impl Default for PlateauConfig {
    fn default() -> Self {
        Self::DISABLED
    }
}

/// Training and threading configuration of a [`Field`].
///
/// [`FieldConfig::DEFAULT`]: Adam with learning rate `5·10⁻³` and the
/// [`AdamConfig`] defaults otherwise, batches of 2¹⁴ samples, one step per
/// update, EMA decay 0.95 (the NPM setting), all available threads,
/// [`DEFAULT_GRADIENT_CHUNKS`] chunks, seed 0, no step limit, no plateau
/// detection, at most 2²⁰ buffered samples (96 MiB). Change fields with the
/// `with_*` builders (all `const`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldConfig {
    /// Optimiser hyper-parameters.
    pub adam: AdamConfig,
    /// Samples per minibatch, `≥ 1` (a smaller buffer is used whole).
    pub batch_size: usize,
    /// Adam steps per [`Field::update`], `≥ 1`.
    pub steps_per_update: u32,
    /// Decay of the weight EMA used for inference, in `[0, 1)` (`0`: the
    /// EMA is the latest parameters).
    pub ema_decay: f32,
    /// Worker threads; `0` = [`std::thread::available_parallelism`].
    /// Results do not depend on it.
    pub threads: usize,
    /// Number of chunks a batch is split into for the gradient sum, `≥ 1`;
    /// fixes the summation order (see [determinism](self#determinism)) and
    /// caps the useful thread count of the gradient pass.
    pub gradient_chunks: usize,
    /// Seed of the minibatch shuffles.
    pub seed: u32,
    /// Training stops once this many steps (applied plus skipped) have been
    /// attempted; `u64::MAX` = no limit.
    pub max_steps: u64,
    /// Plateau criterion.
    pub plateau: PlateauConfig,
    /// Samples beyond this many in the buffer are dropped (and counted,
    /// [`Field::overflowed`]) until the next update, `≥ 1`.
    pub max_buffered_samples: usize,
    /// A step's gradient whose largest element exceeds this magnitude is
    /// scaled down to it (finite, `> 0`; see the [module docs](self#training)).
    pub max_gradient_magnitude: f32,
}

impl FieldConfig {
    /// The defaults described on [`FieldConfig`].
    pub const DEFAULT: Self = Self {
        adam: AdamConfig::new(5e-3),
        batch_size: 1 << 14,
        steps_per_update: 1,
        ema_decay: 0.95,
        threads: 0,
        gradient_chunks: DEFAULT_GRADIENT_CHUNKS,
        seed: 0,
        max_steps: u64::MAX,
        plateau: PlateauConfig::DISABLED,
        max_buffered_samples: 1 << 20,
        max_gradient_magnitude: DEFAULT_MAX_GRADIENT_MAGNITUDE,
    };

    /// `self` with another learning rate (other Adam settings kept).
    #[must_use]
    pub const fn with_learning_rate(self, learning_rate: f32) -> Self {
        Self {
            adam: self.adam.with_learning_rate(learning_rate),
            ..self
        }
    }

    /// Adam steps for `epochs` passes over `buffered` samples, capped:
    /// `clamp(⌈epochs · buffered / batch_size⌉, 1, steps_per_update)`. A
    /// non-finite or negative `epochs` reads as 1. The one rule behind
    /// [`Field::proportional_steps`] and the embedding API's reproducible
    /// training schedule.
    #[must_use]
    pub fn proportional_steps(&self, buffered: usize, epochs: f64) -> u32 {
        let e = if epochs.is_finite() && epochs >= 0.0 {
            epochs
        } else {
            1.0
        };
        let batches = (e * buffered as f64 / self.batch_size.max(1) as f64).ceil();
        let cap = self.steps_per_update.max(1);
        if batches >= f64::from(cap) {
            cap
        } else {
            (batches as u32).max(1)
        }
    }

    with_fields! {
        /// `self` with other Adam hyper-parameters.
        with_adam(adam: AdamConfig);
        /// `self` with another batch size.
        with_batch_size(batch_size: usize);
        /// `self` with another number of steps per update.
        with_steps_per_update(steps_per_update: u32);
        /// `self` with another EMA decay.
        with_ema_decay(ema_decay: f32);
        /// `self` with another thread count (`0` = all available).
        with_threads(threads: usize);
        /// `self` with another number of gradient chunks.
        with_gradient_chunks(gradient_chunks: usize);
        /// `self` with another seed.
        with_seed(seed: u32);
        /// `self` with another step limit.
        with_max_steps(max_steps: u64);
        /// `self` with another plateau criterion.
        with_plateau(plateau: PlateauConfig);
        /// `self` with another sample-buffer capacity.
        with_max_buffered_samples(max_buffered_samples: usize);
        /// `self` with another gradient clip.
        with_max_gradient_magnitude(max_gradient_magnitude: f32);
    }

    /// Checks every field; [`Field::new`] calls this.
    pub fn validate(&self) -> Result<(), FieldError> {
        let a = &self.adam;
        let checks: [(bool, &'static str, f32); 5] = [
            (
                a.learning_rate.is_finite() && a.learning_rate > 0.0,
                "learning_rate",
                a.learning_rate,
            ),
            ((0.0..1.0).contains(&a.beta1), "beta1", a.beta1),
            ((0.0..1.0).contains(&a.beta2), "beta2", a.beta2),
            (
                a.epsilon.is_finite() && a.epsilon > 0.0,
                "epsilon",
                a.epsilon,
            ),
            (
                a.l2_regularization.is_finite() && a.l2_regularization >= 0.0,
                "l2_regularization",
                a.l2_regularization,
            ),
        ];
        for (ok, name, value) in checks {
            if !ok {
                return Err(FieldError::InvalidAdam { name, value });
            }
        }
        if self.batch_size == 0 {
            return Err(FieldError::ZeroBatchSize);
        }
        if self.steps_per_update == 0 {
            return Err(FieldError::ZeroStepsPerUpdate);
        }
        if !(0.0..1.0).contains(&self.ema_decay) {
            return Err(FieldError::InvalidEmaDecay(self.ema_decay));
        }
        if self.gradient_chunks == 0 {
            return Err(FieldError::ZeroGradientChunks);
        }
        if self.gradient_chunks > MAX_GRADIENT_CHUNKS {
            return Err(FieldError::TooManyGradientChunks(self.gradient_chunks));
        }
        if self.threads > MAX_THREADS {
            return Err(FieldError::TooManyThreads(self.threads));
        }
        let rel = self.plateau.min_relative_improvement;
        if !(rel.is_finite() && rel >= 0.0) {
            return Err(FieldError::InvalidPlateau(rel));
        }
        if self.max_buffered_samples == 0 {
            return Err(FieldError::ZeroBufferCapacity);
        }
        let clip = self.max_gradient_magnitude;
        if !(clip.is_finite() && clip > 0.0) {
            return Err(FieldError::InvalidGradientClip(clip));
        }
        Ok(())
    }
}

impl Default for FieldConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a [`Field`] could not be created.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FieldError {
    /// An Adam hyper-parameter is out of range: the learning rate and `ε`
    /// must be finite and `> 0`, `β₁, β₂ ∈ [0, 1)`, the L2 factor finite and
    /// `≥ 0`.
    InvalidAdam {
        /// Name of the [`AdamConfig`] field.
        name: &'static str,
        /// Its value.
        value: f32,
    },
    /// `batch_size` is 0.
    ZeroBatchSize,
    /// `steps_per_update` is 0.
    ZeroStepsPerUpdate,
    /// `ema_decay` is not in `[0, 1)`.
    InvalidEmaDecay(f32),
    /// `gradient_chunks` is 0.
    ZeroGradientChunks,
    /// `gradient_chunks` exceeds [`MAX_GRADIENT_CHUNKS`].
    TooManyGradientChunks(usize),
    /// `threads` exceeds [`MAX_THREADS`].
    TooManyThreads(usize),
    /// The plateau's relative improvement is negative or not finite.
    InvalidPlateau(f32),
    /// `max_buffered_samples` is 0.
    ZeroBufferCapacity,
    /// `max_gradient_magnitude` is not finite and `> 0`.
    InvalidGradientClip(f32),
    /// The model has no parameters.
    EmptyModel,
    /// A parameter vector handed to [`Field::from_params`] has the wrong
    /// length or a non-finite value.
    InvalidParams {
        /// Length the model needs.
        expected: usize,
        /// Length given.
        got: usize,
        /// Whether every given value is finite.
        finite: bool,
    },
}

impl fmt::Display for FieldError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::InvalidAdam { name, value } => {
                write!(f, "invalid Adam {name} = {value}")?;
                match name {
                    "learning_rate" | "epsilon" => f.write_str(" (must be finite and > 0)"),
                    "beta1" | "beta2" => f.write_str(" (must be in [0, 1))"),
                    _ => f.write_str(" (must be finite and >= 0)"),
                }
            }
            Self::ZeroBatchSize => f.write_str("batch_size must be at least 1"),
            Self::ZeroStepsPerUpdate => f.write_str("steps_per_update must be at least 1"),
            Self::InvalidEmaDecay(d) => write!(f, "ema_decay = {d} must be in [0, 1)"),
            Self::ZeroGradientChunks => f.write_str("gradient_chunks must be at least 1"),
            Self::TooManyGradientChunks(c) => {
                write!(f, "gradient_chunks = {c} exceeds {MAX_GRADIENT_CHUNKS}")
            }
            Self::TooManyThreads(t) => write!(f, "threads = {t} exceeds {MAX_THREADS}"),
            Self::InvalidPlateau(r) => write!(
                f,
                "plateau min_relative_improvement = {r} must be finite and >= 0"
            ),
            Self::ZeroBufferCapacity => f.write_str("max_buffered_samples must be at least 1"),
            Self::InvalidGradientClip(c) => {
                write!(f, "max_gradient_magnitude = {c} must be finite and > 0")
            }
            Self::EmptyModel => f.write_str("the model has no parameters"),
            Self::InvalidParams {
                expected,
                got,
                finite,
            } => {
                if expected == got {
                    debug_assert!(!finite);
                    f.write_str("parameter vector contains NaN or infinite values")
                } else {
                    write!(
                        f,
                        "parameter vector has {got} values, the model needs {expected}"
                    )
                }
            }
        }
    }
}

impl std::error::Error for FieldError {}

/// What one [`Field::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateReport {
    /// Adam steps applied.
    pub steps: u32,
    /// Steps skipped because the batch gradient or loss was not finite.
    pub skipped_steps: u32,
    /// Applied steps whose gradient was scaled down to
    /// [`FieldConfig::max_gradient_magnitude`].
    pub clipped_steps: u32,
    /// Samples in the buffer at the start of the update (all of them valid).
    pub buffered_samples: usize,
    /// Samples per minibatch (`min(batch_size, buffered_samples)`).
    pub batch_size: usize,
    /// Mean batch loss over the applied steps (`NaN` if none was applied).
    pub mean_loss: f64,
    /// Parameter elements that [`adam_step`](crate::optim::adam_step) left untouched inside applied
    /// steps because their update would not be finite.
    pub element_skips: u64,
    /// Whether training has stopped (after this update, or before it, in
    /// which case nothing was done).
    pub converged: bool,
}

/// The model's buffers that training mutates (kept apart from the sample
/// buffer so a step can borrow both).
struct TrainState {
    params: Vec<f32>,
    ema: Vec<f32>,
    adam_m: Vec<f32>,
    adam_v: Vec<f32>,
    /// Gradient of the current step (zero between steps); empty until the
    /// first update.
    grad: Vec<f32>,
    /// Per-chunk gradient buffers (zero between uses), `min(threads, chunks)`
    /// of them once allocated.
    scratch: Vec<Vec<f32>>,
    /// Applied steps (Adam's and the EMA's step count).
    steps: u64,
    /// Skipped steps.
    skipped_steps: u64,
    /// Applied steps with a clipped gradient.
    clipped_steps: u64,
}

/// What one step of [`Field::run_update`] may use: the field without its
/// sample buffer (which the minibatch borrows).
struct StepView<'a, M> {
    model: &'a M,
    config: &'a FieldConfig,
    threads: usize,
    pool: Option<&'a rayon::ThreadPool>,
    state: &'a mut TrainState,
}

/// The resumable training state of a [`Field`] ([`Field::state`],
/// [`Field::from_state`]); what a save file stores.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldState {
    /// Trained parameters.
    pub params: Vec<f32>,
    /// Their exponential moving average (what inference uses).
    pub ema: Vec<f32>,
    /// Adam's first moment.
    pub adam_m: Vec<f32>,
    /// Adam's second moment (`≥ 0`).
    pub adam_v: Vec<f32>,
    /// Applied steps.
    pub steps: u64,
    /// Updates that trained (seeds the minibatch shuffles).
    pub updates: u64,
}

/// Outcome of one training step, on whichever backend ran it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepOutcome {
    /// Adam and the EMA were applied.
    Applied {
        /// Mean loss of the batch.
        loss: f64,
        /// Parameter elements Adam left untouched because their update
        /// would not be finite (0 where the backend does not count them).
        element_skips: u64,
        /// The gradient was scaled down to
        /// [`FieldConfig::max_gradient_magnitude`].
        clipped: bool,
    },
    /// The gradient or the loss was not finite; nothing changed.
    Skipped,
}

/// The arithmetic of one training step, run somewhere other than this
/// field's CPU threads (a Vulkan device in crate `guiding`): the gradient
/// of the mean loss over `batch`, the skip / clip decision
/// ([`crate::optim::step_clip_factor`]), Adam with bias correction for step
/// `step` (1-based) and the EMA, on the backend's own copy of the
/// parameters.
///
/// [`Field::update_steps_on`] keeps everything else — validation and the
/// buffer, the shuffles and minibatches, step counts, `max_steps`, the
/// loss history and the plateau — so a field trains by the same loop
/// whichever backend does the arithmetic.
pub trait StepBackend {
    /// Why a step could not run (the device failed).
    type Error;

    /// One step on `batch` (non-empty, every sample valid) with `config`'s
    /// Adam, EMA and clip settings.
    ///
    /// # Errors
    /// The backend failed; the field counts nothing for this step.
    fn train_step(
        &mut self,
        batch: &[TrainingSample],
        step: u32,
        config: &FieldConfig,
    ) -> Result<StepOutcome, Self::Error>;
}

/// A guiding model with its parameters, optimiser state and sample buffer:
/// the CPU runtime. See the [module docs](self).
pub struct Field<M: GuidingModel> {
    model: M,
    config: FieldConfig,
    threads: usize,
    /// The persistent worker pool (`None` with one thread): training and
    /// batched inference run on it, no OS thread is spawned per call.
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
    state: TrainState,
    buffer: Vec<TrainingSample>,
    /// Updates that trained (had samples).
    updates: u64,
    accepted: u64,
    rejected: [u64; REJECTION_KINDS],
    ignored: u64,
    overflowed: u64,
    loss_history: Vec<f64>,
    best_loss: f64,
    updates_since_improvement: u32,
    plateaued: bool,
    stopped: bool,
}

impl<M: GuidingModel + Send + Sync> fmt::Debug for Field<M> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Field")
            .field("config", &self.config)
            .field("threads", &self.threads)
            .field("param_count", &self.state.params.len())
            .field("steps", &self.state.steps)
            .field("skipped_steps", &self.state.skipped_steps)
            .field("buffered", &self.buffer.len())
            .field("rejected", &self.rejected)
            .field("converged", &self.is_converged())
            .finish_non_exhaustive()
    }
}

/// Index of a rejection kind in [`Field::rejected`].
#[must_use]
pub const fn rejection_index(kind: Rejection) -> usize {
    kind as usize - 1
}

impl<M: GuidingModel + Send + Sync> Field<M> {
    /// A field with the model's deterministic initialisation
    /// (`model.init(params, config.seed)`).
    ///
    /// # Errors
    /// If `config` fails [`FieldConfig::validate`] or the model has no
    /// parameters.
    pub fn new(model: M, config: FieldConfig) -> Result<Self, FieldError> {
        config.validate()?;
        let n = model.param_count();
        if n == 0 {
            return Err(FieldError::EmptyModel);
        }
        let mut params = vec![0.0; n];
        model.init(&mut params, config.seed);
        Ok(Self::with_state(model, config, params))
    }

    /// A field starting from given parameters (e.g. loaded from a file);
    /// the Adam moments start at zero and the EMA at `params`.
    ///
    /// # Errors
    /// As [`Self::new`], and if `params` does not have `model.param_count()`
    /// values or contains a non-finite one.
    pub fn from_params(
        model: M,
        config: FieldConfig,
        params: Vec<f32>,
    ) -> Result<Self, FieldError> {
        config.validate()?;
        let n = model.param_count();
        if n == 0 {
            return Err(FieldError::EmptyModel);
        }
        let finite = crate::optim::all_finite(&params);
        if params.len() != n || !finite {
            return Err(FieldError::InvalidParams {
                expected: n,
                got: params.len(),
                finite,
            });
        }
        Ok(Self::with_state(model, config, params))
    }

    /// A field resuming from a saved training state: parameters, their EMA,
    /// both Adam moments, the applied step count (Adam's bias correction
    /// and the EMA debiasing continue from `steps`) and the update count
    /// (the minibatch shuffles continue their sequence), so that training
    /// goes on bit-identically. Sample counters, loss history, plateau state
    /// and the sample buffer start empty.
    ///
    /// # Errors
    /// As [`Self::new`], and if any of the four vectors does not have
    /// `model.param_count()` values or contains a non-finite one (or a
    /// negative second moment).
    pub fn from_state(
        model: M,
        config: FieldConfig,
        state: FieldState,
    ) -> Result<Self, FieldError> {
        let FieldState {
            params,
            ema,
            adam_m,
            adam_v,
            steps,
            updates,
        } = state;
        let mut field = Self::from_params(model, config, params)?;
        check_vectors(field.state.params.len(), &[&ema, &adam_m, &adam_v], &adam_v)?;
        field.state.ema = ema;
        field.state.adam_m = adam_m;
        field.state.adam_v = adam_v;
        field.state.steps = steps;
        field.updates = updates;
        Ok(field)
    }

    /// A copy of the training state that [`Self::from_state`] resumes from.
    pub fn state(&self) -> FieldState {
        FieldState {
            params: self.state.params.clone(),
            ema: self.state.ema.clone(),
            adam_m: self.state.adam_m.clone(),
            adam_v: self.state.adam_v.clone(),
            steps: self.state.steps,
            updates: self.updates,
        }
    }

    fn with_state(model: M, config: FieldConfig, params: Vec<f32>) -> Self {
        let n = params.len();
        let threads = if config.threads == 0 {
            thread::available_parallelism().map_or(1, usize::from)
        } else {
            config.threads
        };
        let pool = (threads > 1)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(|i| std::format!("guiding-field-{i}"))
                    .build()
                    .ok()
            })
            .flatten()
            .map(std::sync::Arc::new);
        // A pool that could not be built leaves one thread (same results).
        let threads = if pool.is_some() { threads } else { 1 };
        Self {
            model,
            config,
            threads,
            pool,
            state: TrainState {
                ema: params.clone(),
                params,
                adam_m: vec![0.0; n],
                adam_v: vec![0.0; n],
                grad: Vec::new(),
                scratch: Vec::new(),
                steps: 0,
                skipped_steps: 0,
                clipped_steps: 0,
            },
            buffer: Vec::new(),
            updates: 0,
            accepted: 0,
            rejected: [0; REJECTION_KINDS],
            ignored: 0,
            overflowed: 0,
            loss_history: Vec::new(),
            best_loss: f64::INFINITY,
            updates_since_improvement: 0,
            plateaued: false,
            stopped: false,
        }
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The configuration.
    pub fn config(&self) -> &FieldConfig {
        &self.config
    }

    /// The persistent worker pool (`None` when the field runs on one
    /// thread), for callers that spread batched inference over it.
    pub fn pool(&self) -> Option<&rayon::ThreadPool> {
        self.pool.as_deref()
    }

    /// Worker threads in use (the resolved [`FieldConfig::threads`]).
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The trained parameters.
    pub fn params(&self) -> &[f32] {
        &self.state.params
    }

    /// The EMA of the parameters (what inference uses).
    pub fn ema_params(&self) -> &[f32] {
        &self.state.ema
    }

    /// Adam's first and second moment estimates.
    pub fn adam_moments(&self) -> (&[f32], &[f32]) {
        (&self.state.adam_m, &self.state.adam_v)
    }

    /// The EMA weights, writable: a caller that trains on another backend
    /// ([`Self::update_steps_on`]) brings the backend's weights back here so
    /// that this field's queries use them.
    pub fn ema_params_mut(&mut self) -> &mut [f32] {
        &mut self.state.ema
    }

    /// Replaces the parameters, EMA and Adam moments (and the applied step
    /// count) by `state`'s, e.g. those a device trained; counters, the loss
    /// history and the buffer are kept. Checked as [`Self::from_state`].
    ///
    /// # Errors
    /// A vector of the wrong length, a non-finite value or a negative
    /// second moment; nothing is changed then.
    pub fn restore_state(&mut self, state: FieldState) -> Result<(), FieldError> {
        let all = [&state.params, &state.ema, &state.adam_m, &state.adam_v];
        check_vectors(self.state.params.len(), &all, &state.adam_v)?;
        self.state.params = state.params;
        self.state.ema = state.ema;
        self.state.adam_m = state.adam_m;
        self.state.adam_v = state.adam_v;
        self.state.steps = state.steps;
        self.updates = state.updates;
        Ok(())
    }

    /// Updates that trained so far (they seed the minibatch shuffles).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Adam steps applied so far.
    pub fn steps(&self) -> u64 {
        self.state.steps
    }

    /// Steps skipped for a non-finite gradient or loss.
    pub fn skipped_steps(&self) -> u64 {
        self.state.skipped_steps
    }

    /// Applied steps whose gradient was clipped.
    pub fn clipped_steps(&self) -> u64 {
        self.state.clipped_steps
    }

    /// Samples accepted into the buffer so far.
    pub fn accepted(&self) -> u64 {
        self.accepted
    }

    /// Rejected samples per kind, indexed by [`rejection_index`]
    /// (`Rejection` code − 1).
    pub fn rejected(&self) -> [u64; REJECTION_KINDS] {
        self.rejected
    }

    /// Rejected samples of one kind.
    pub fn rejected_of(&self, kind: Rejection) -> u64 {
        self.rejected[rejection_index(kind)]
    }

    /// Samples dropped unexamined because training had stopped.
    pub fn ignored(&self) -> u64 {
        self.ignored
    }

    /// Valid samples dropped because the buffer was full.
    pub fn overflowed(&self) -> u64 {
        self.overflowed
    }

    /// Samples waiting for the next update.
    pub fn buffered(&self) -> usize {
        self.buffer.len()
    }

    /// Mean loss of every update that applied at least one step, in order.
    pub fn loss_history(&self) -> &[f64] {
        &self.loss_history
    }

    /// Whether the loss has plateaued (see [`PlateauConfig`]).
    pub fn is_plateaued(&self) -> bool {
        self.plateaued
    }

    /// Whether training is over: stopped, plateaued, or `max_steps` attempted.
    pub fn is_converged(&self) -> bool {
        self.stopped
            || self.plateaued
            || self.state.steps.saturating_add(self.state.skipped_steps) >= self.config.max_steps
    }

    /// Stops training for good: frees the training buffers and the sample
    /// buffer; later updates do nothing and samples are ignored.
    pub fn stop_training(&mut self) {
        self.stopped = true;
        self.release_training_memory();
    }

    fn release_training_memory(&mut self) {
        self.buffer = Vec::new();
        self.state.grad = Vec::new();
        self.state.scratch = Vec::new();
    }

    /// Validates and buffers training samples. Invalid ones are counted per
    /// [`Rejection`] kind and dropped; valid ones beyond
    /// [`FieldConfig::max_buffered_samples`] are counted as overflowed;
    /// after convergence every sample is counted as ignored without being
    /// examined.
    pub fn add_samples(&mut self, samples: &[TrainingSample]) {
        if self.is_converged() {
            self.ignored += samples.len() as u64;
            return;
        }
        let room = self
            .config
            .max_buffered_samples
            .saturating_sub(self.buffer.len());
        self.buffer.reserve(samples.len().min(room));
        for s in samples {
            match s.validate() {
                Ok(()) => {
                    if self.buffer.len() < self.config.max_buffered_samples {
                        self.buffer.push(*s);
                        self.accepted += 1;
                    } else {
                        self.overflowed += 1;
                    }
                }
                Err(kind) => self.rejected[rejection_index(kind)] += 1,
            }
        }
    }

    /// Trains on the buffered samples (see the [module docs](self#training))
    /// and clears the buffer. Does nothing once converged.
    pub fn update(&mut self) -> UpdateReport {
        self.update_steps(self.config.steps_per_update)
    }

    /// Adam steps for `epochs` passes over the buffered samples, capped:
    /// `clamp(⌈epochs · buffered / batch_size⌉, 1, steps_per_update)` —
    /// training effort proportional to the samples a render pass produced,
    /// with [`FieldConfig::steps_per_update`] as the ceiling (a small pass is
    /// not trained on 32 times over). A non-finite or negative `epochs`
    /// reads as 1.
    #[must_use]
    pub fn proportional_steps(&self, epochs: f32) -> u32 {
        self.config
            .proportional_steps(self.buffer.len(), f64::from(epochs))
    }

    /// [`Self::update`] with `steps` Adam steps instead of
    /// [`FieldConfig::steps_per_update`] (at least one; see
    /// [`Self::proportional_steps`]).
    pub fn update_steps(&mut self, steps: u32) -> UpdateReport {
        let result: Result<UpdateReport, core::convert::Infallible> =
            self.run_update(steps, |field, batch| {
                let (model, config, threads) = (field.model, field.config, field.threads);
                let state = &mut *field.state;
                Ok(match field.pool {
                    Some(pool) => pool.install(|| train_step(model, config, threads, state, batch)),
                    None => train_step(model, config, 1, state, batch),
                })
            });
        match result {
            Ok(report) => report,
            Err(never) => match never {},
        }
    }

    /// [`Self::update_steps`] with the arithmetic of each step on
    /// `backend` (see [`StepBackend`]): the same validation, shuffles,
    /// minibatches, counters, step limit and plateau. This field's own
    /// parameters are not touched; the caller brings the backend's back
    /// (e.g. into [`Self::ema_params_mut`]) when it needs them here.
    ///
    /// # Errors
    /// The backend's first failure: the update ends there (the steps before
    /// it count) and the buffer is cleared.
    pub fn update_steps_on<B: StepBackend>(
        &mut self,
        steps: u32,
        backend: &mut B,
    ) -> Result<UpdateReport, B::Error> {
        self.run_update(steps, |field, batch| {
            let step = u32::try_from(field.state.steps + 1).unwrap_or(u32::MAX);
            backend.train_step(batch, step, field.config)
        })
    }

    /// The one training loop (see the [module docs](self#training)): `step`
    /// runs the arithmetic of one minibatch.
    fn run_update<E>(
        &mut self,
        steps: u32,
        mut step: impl FnMut(&mut StepView<'_, M>, &[TrainingSample]) -> Result<StepOutcome, E>,
    ) -> Result<UpdateReport, E> {
        let steps = steps.max(1);
        let mut report = UpdateReport {
            mean_loss: f64::NAN,
            ..UpdateReport::default()
        };
        if self.is_converged() {
            self.buffer.clear();
            report.converged = true;
            return Ok(report);
        }
        let n = self.buffer.len();
        report.buffered_samples = n;
        if n == 0 {
            return Ok(report);
        }
        let b = self.config.batch_size.min(n);
        report.batch_size = b;
        let mut rng = Rng::with_stream(self.config.seed, self.updates as u32);
        shuffle(&mut self.buffer, &mut rng);
        let mut buffer = core::mem::take(&mut self.buffer);
        let mut pos = 0;
        let mut loss_sum = 0.0f64;
        let mut failure = None;
        for _ in 0..steps {
            if self.state.steps.saturating_add(self.state.skipped_steps) >= self.config.max_steps {
                break;
            }
            if pos + b > n {
                shuffle(&mut buffer, &mut rng);
                pos = 0;
            }
            let batch = &buffer[pos..pos + b];
            pos += b;
            let mut view = StepView {
                model: &self.model,
                config: &self.config,
                threads: self.threads,
                pool: self.pool.as_deref(),
                state: &mut self.state,
            };
            match step(&mut view, batch) {
                Ok(StepOutcome::Applied {
                    loss,
                    element_skips,
                    clipped,
                }) => {
                    self.state.steps += 1;
                    self.state.clipped_steps += u64::from(clipped);
                    report.steps += 1;
                    report.clipped_steps += u32::from(clipped);
                    report.element_skips += element_skips;
                    loss_sum += loss;
                }
                Ok(StepOutcome::Skipped) => {
                    self.state.skipped_steps += 1;
                    report.skipped_steps += 1;
                }
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        buffer.clear();
        self.buffer = buffer;
        self.updates += 1;
        if report.steps > 0 {
            let mean = loss_sum / f64::from(report.steps);
            report.mean_loss = mean;
            self.record_loss(mean);
        }
        report.converged = self.is_converged();
        if report.converged {
            self.release_training_memory();
        }
        match failure {
            Some(e) => Err(e),
            None => Ok(report),
        }
    }

    /// Plateau bookkeeping for one update's mean loss.
    fn record_loss(&mut self, mean: f64) {
        self.loss_history.push(mean);
        let margin = f64::from(self.config.plateau.min_relative_improvement);
        if self.best_loss == f64::INFINITY || mean < self.best_loss - margin * self.best_loss.abs()
        {
            self.best_loss = mean;
            self.updates_since_improvement = 0;
        } else {
            self.best_loss = self.best_loss.min(mean);
            self.updates_since_improvement += 1;
            let window = self.config.plateau.window;
            if window > 0 && self.updates_since_improvement >= window {
                self.plateaued = true;
            }
        }
    }

    /// Draws a direction for `query` from the EMA model.
    pub fn sample(&self, query: &QueryPoint, u: Vec2) -> DirectionSample {
        self.model.sample(&self.state.ema, query, u)
    }

    /// Density of `direction` at `query` under the EMA model.
    pub fn pdf(&self, query: &QueryPoint, direction: Vec3) -> f32 {
        self.model.pdf(&self.state.ema, query, direction)
    }

    /// Guide-selection probability at `query` under the EMA model.
    pub fn selection_probability(&self, query: &QueryPoint) -> f32 {
        self.model.selection_probability(&self.state.ema, query)
    }

    /// [`Self::sample`] for every `(queries[i], u[i])` into `out[i]`, spread
    /// over the threads.
    ///
    /// # Panics
    /// If the three lengths differ.
    pub fn sample_batch(&self, queries: &[QueryPoint], u: &[Vec2], out: &mut [DirectionSample]) {
        assert_batch_lengths("sample_batch", queries, (u, "random pairs"), out);
        self.fill_with_ema(out, |model, params, i| {
            model.sample(params, &queries[i], u[i])
        });
    }

    /// [`Self::pdf`] for every `(queries[i], directions[i])` into `out[i]`,
    /// spread over the threads.
    ///
    /// # Panics
    /// If the three lengths differ.
    pub fn pdf_batch(&self, queries: &[QueryPoint], directions: &[Vec3], out: &mut [f32]) {
        assert_batch_lengths("pdf_batch", queries, (directions, "directions"), out);
        self.fill_with_ema(out, |model, params, i| {
            model.pdf(params, &queries[i], directions[i])
        });
    }

    /// [`Self::selection_probability`] for every query into `out`, spread
    /// over the threads.
    ///
    /// # Panics
    /// If the lengths differ.
    pub fn selection_probability_batch(&self, queries: &[QueryPoint], out: &mut [f32]) {
        assert_eq!(queries.len(), out.len(), "one output per query");
        self.fill_with_ema(out, |model, params, i| {
            model.selection_probability(params, &queries[i])
        });
    }

    /// `out[i] = f(model, EMA parameters, i)` for every `i`, spread over the
    /// threads.
    fn fill_with_ema<O: Send>(&self, out: &mut [O], f: impl Fn(&M, &[f32], usize) -> O + Sync) {
        let (model, params) = (&self.model, &self.state.ema[..]);
        parallel_fill(self.pool.as_deref(), out, |i| f(model, params, i));
    }
}

/// Panics unless a batch's `queries`, other inputs and `outputs` are
/// equally long; the message gives the three lengths.
#[track_caller]
fn assert_batch_lengths<I, O>(
    what: &str,
    queries: &[QueryPoint],
    (inputs, inputs_name): (&[I], &str),
    outputs: &[O],
) {
    let (q, i, o) = (queries.len(), inputs.len(), outputs.len());
    assert!(
        q == i && q == o,
        "{what}: {q} queries, {i} {inputs_name}, {o} outputs"
    );
}

/// Checks a training state's vectors against a model of `n` parameters:
/// each of length `n` and finite, and the second Adam moment `adam_v` not
/// negative.
fn check_vectors(n: usize, vectors: &[&Vec<f32>], adam_v: &[f32]) -> Result<(), FieldError> {
    for v in vectors {
        let finite = crate::optim::all_finite(v);
        if v.len() != n || !finite {
            return Err(FieldError::InvalidParams {
                expected: n,
                got: v.len(),
                finite,
            });
        }
    }
    if adam_v.iter().any(|&x| x < 0.0) {
        return Err(FieldError::InvalidParams {
            expected: n,
            got: n,
            finite: false,
        });
    }
    Ok(())
}

/// Length of each of at most `parts` ranges covering `n` elements, a
/// multiple of [`RANGE_ALIGN`].
fn range_len(n: usize, parts: usize) -> usize {
    n.div_ceil(parts.max(1))
        .next_multiple_of(RANGE_ALIGN)
        .max(RANGE_ALIGN)
}

/// Threads for an element-wise pass over `n` parameters (each gets at
/// least half of [`PARALLEL_MIN_ELEMENTS`]).
fn element_threads(threads: usize, n: usize) -> usize {
    if n < PARALLEL_MIN_ELEMENTS {
        1
    } else {
        threads.clamp(1, n / (PARALLEL_MIN_ELEMENTS / 2))
    }
}

/// The gradient and loss sum of one chunk, summed in sample order into
/// `grad` (zero on entry).
fn chunk_gradient<M: GuidingModel>(
    model: &M,
    params: &[f32],
    samples: &[TrainingSample],
    grad: &mut [f32],
) -> f64 {
    model.accumulate_gradient_batch(params, samples, grad)
}

/// `total += s` for every buffer `s` of `scratch`, in order, then `s = 0`.
///
/// Blocks of [`RANGE_ALIGN`] floats whose bits are all zero are skipped
/// (adding `+0` changes nothing: `total` is never `−0`, since it starts at
/// `+0` and a sum is `−0` only if both terms are). Most of a fine grid's
/// gradient is untouched by one chunk, so this saves most of the writes.
/// Which blocks are skipped depends on the chunk's values only, never on
/// the threads.
fn reduce_range(total: &mut [f32], scratch: &mut [&mut [f32]]) {
    for s in scratch.iter_mut() {
        for (tb, sb) in total.chunks_mut(RANGE_ALIGN).zip(s.chunks_mut(RANGE_ALIGN)) {
            let any = sb.iter().fold(0u32, |acc, x| acc | x.to_bits());
            if any != 0 {
                for (t, x) in tb.iter_mut().zip(sb.iter_mut()) {
                    *t += *x;
                    *x = 0.0;
                }
            }
        }
    }
}

/// One training step on `batch`; see the [module docs](self#determinism).
fn train_step<M: GuidingModel + Send + Sync>(
    model: &M,
    config: &FieldConfig,
    threads: usize,
    state: &mut TrainState,
    batch: &[TrainingSample],
) -> StepOutcome {
    let n = state.params.len();
    let chunks = config.gradient_chunks;
    let wave = threads.clamp(1, chunks);
    if state.grad.len() != n {
        state.grad = vec![0.0; n];
    }
    while state.scratch.len() < wave {
        state.scratch.push(vec![0.0; n]);
    }

    // Balanced contiguous chunks; empty ones (batch < chunks) are left out,
    // which depends on the batch size only.
    let len = batch.len();
    let pieces: Vec<&[TrainingSample]> = (0..chunks)
        .map(|c| &batch[c * len / chunks..(c + 1) * len / chunks])
        .filter(|p| !p.is_empty())
        .collect();

    let params = &state.params[..];
    let elem_threads = element_threads(threads, n);
    let mut loss = 0.0f64;
    for group in pieces.chunks(wave) {
        let bufs = &mut state.scratch[..group.len()];
        let mut losses = vec![0.0f64; group.len()];
        if group.len() == 1 {
            losses[0] = chunk_gradient(model, params, group[0], &mut bufs[0]);
        } else {
            group
                .par_iter()
                .zip(bufs.par_iter_mut())
                .zip(losses.par_iter_mut())
                .for_each(|((piece, buf), out)| *out = chunk_gradient(model, params, piece, buf));
        }
        for l in losses {
            loss += l;
        }
        // total += chunk buffers in chunk order, parameter ranges in parallel.
        let rl = range_len(n, elem_threads);
        if elem_threads == 1 {
            let mut views: Vec<&mut [f32]> = bufs.iter_mut().map(|b| &mut b[..]).collect();
            reduce_range(&mut state.grad, &mut views);
        } else {
            // views[range][buffer]: the chunk buffers cut like the gradient.
            let mut splits: Vec<_> = bufs.iter_mut().map(|b| b.chunks_mut(rl)).collect();
            let views: Vec<Vec<&mut [f32]>> = (0..n.div_ceil(rl))
                .map(|_| {
                    splits
                        .iter_mut()
                        .map(|it| it.next().expect("same length as the gradient"))
                        .collect()
                })
                .collect();
            state
                .grad
                .par_chunks_mut(rl)
                .zip(views)
                .for_each(|(total, mut v)| reduce_range(total, &mut v));
        }
    }
    let loss = loss / len as f64;

    // Scale by 1/n; check finiteness and find the largest magnitude (both
    // independent of the range split).
    let inv = 1.0 / len as f32;
    let scale = |g: &mut [f32]| -> (bool, f32) {
        let mut ok = true;
        let mut max = 0.0f32;
        for x in g.iter_mut() {
            *x *= inv;
            ok &= x.is_finite();
            max = max.max(x.abs());
        }
        (ok, max)
    };
    let rl = range_len(n, elem_threads);
    let (finite, max_abs) = if elem_threads == 1 {
        scale(&mut state.grad)
    } else {
        state
            .grad
            .par_chunks_mut(rl)
            .map(scale)
            .reduce(|| (true, 0.0f32), |(a, x), (b, y)| (a & b, x.max(y)))
    };
    let Some(factor) = step_clip_factor(
        finite && loss.is_finite(),
        max_abs,
        config.max_gradient_magnitude,
    ) else {
        state.grad.fill(0.0);
        return StepOutcome::Skipped;
    };
    let clipped = factor < 1.0;
    if clipped {
        // Rare: one more serial pass.
        for g in &mut state.grad {
            *g *= factor;
        }
    }

    // Adam, EMA, and re-zeroing of the gradient, range by range.
    let step = u32::try_from(state.steps + 1).unwrap_or(u32::MAX);
    let adam = &config.adam;
    let decay = config.ema_decay;
    let apply = |p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], e: &mut [f32]| {
        adam_ema_step(p, g, m, v, e, step, adam, decay) as u64
    };
    let element_skips = if elem_threads == 1 {
        apply(
            &mut state.params,
            &mut state.grad,
            &mut state.adam_m,
            &mut state.adam_v,
            &mut state.ema,
        )
    } else {
        state
            .params
            .par_chunks_mut(rl)
            .zip(state.grad.par_chunks_mut(rl))
            .zip(state.adam_m.par_chunks_mut(rl))
            .zip(state.adam_v.par_chunks_mut(rl))
            .zip(state.ema.par_chunks_mut(rl))
            .map(|((((p, g), m), v), e)| apply(p, g, m, v, e))
            .sum()
    };
    StepOutcome::Applied {
        loss,
        element_skips,
        clipped,
    }
}

/// `out[i] = f(i)` for every `i`, spread over `pool` in pieces of at least
/// half of `PARALLEL_MIN_QUERIES` (serial without a pool or for a short
/// `out`).
fn parallel_fill<O: Send, F: Fn(usize) -> O + Sync>(
    pool: Option<&rayon::ThreadPool>,
    out: &mut [O],
    f: F,
) {
    let n = out.len();
    match pool {
        Some(pool) if n >= PARALLEL_MIN_QUERIES => {
            let len = n
                .div_ceil(pool.current_num_threads())
                .max(PARALLEL_MIN_QUERIES / 2);
            pool.install(|| {
                out.par_chunks_mut(len).enumerate().for_each(|(k, piece)| {
                    for (j, o) in piece.iter_mut().enumerate() {
                        *o = f(k * len + j);
                    }
                });
            });
        }
        _ => {
            for (i, o) in out.iter_mut().enumerate() {
                *o = f(i);
            }
        }
    }
}
