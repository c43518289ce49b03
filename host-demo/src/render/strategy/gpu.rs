//! `--device gpu`: the guiding stages of the wavefront loop on Vulkan.
//!
//! Intersection, shading and MIS stay on the CPU. What moves to the GPU is
//! what the CPU profile is dominated by: the network inference of the
//! guide-query stage ([`GpuGuide::infer`]: grid encoding + MLP for every
//! guidable vertex of a wavefront, raw outputs read back and decoded on the
//! CPU by the same function the CPU path uses) and the training step
//! ([`GpuGuide::update`]: Field's update — shuffle, minibatches, gradient,
//! Adam, EMA — with every step run by the SPIR-V kernels).
//!
//! NPM and NASG guides only: DF has no fixed-size network output (its
//! conditional network depends on the direction), so `--device gpu` with a
//! DF guide is an error.

use guiding::{FieldConfig, GuidingField, QueryPoint, TrainingSample};
use guiding_core::rng::{shuffle, Rng};
use guiding_gpu::{
    DeviceSelection, GpuContext, GpuError, GpuModel, ModelEntryPoints, StepOutcome, TrainOptions,
};
use std::sync::Mutex;

/// What one [`GpuGuide::update`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuUpdate {
    /// Steps applied.
    pub steps: u32,
    /// Steps skipped for a non-finite gradient or loss.
    pub skipped: u32,
    /// Mean loss of the applied steps (`NaN` if none).
    pub mean_loss: f64,
}

/// A guide whose network runs on a Vulkan device (see the [module docs](self)).
pub struct GpuGuide {
    model: Mutex<GpuModel>,
    raw_outputs: usize,
    device: String,
    training: FieldConfig,
    updates: u64,
    steps: u64,
    stopped: bool,
}

impl GpuGuide {
    /// Uploads `field`'s model and training state to the device chosen by
    /// `selection`.
    ///
    /// # Errors
    /// A DF field, no usable Vulkan device, or shaders not built (host-demo
    /// built without `--features guiding-gpu/shaders`).
    pub fn new(field: &GuidingField, selection: DeviceSelection) -> Result<GpuGuide, GpuError> {
        Self::with_context(field, GpuContext::new(selection)?)
    }

    /// [`Self::new`] on an open device (several guides can share one).
    ///
    /// # Errors
    /// A DF field, or shaders not built.
    pub fn with_context(field: &GuidingField, ctx: GpuContext) -> Result<GpuGuide, GpuError> {
        let export = field.export_model();
        if export.raw_outputs == 0 {
            return Err(GpuError::BadArgument(format!(
                "--device gpu runs NPM and NASG guides; {} has no fixed-size network output \
                 (its conditional network depends on the direction): use --device cpu",
                export.kernel_prefix
            )));
        }
        let device = format!(
            "{} ({})",
            ctx.device_info().name,
            ctx.device_info().driver_info
        );
        let s = &export.state;
        let raw_outputs = u32::try_from(export.raw_outputs)
            .map_err(|_| GpuError::BadArgument("raw output count over 2^32".into()))?;
        let model = GpuModel::new(
            ctx,
            ModelEntryPoints {
                prefix: export.kernel_prefix,
                raw_outputs,
            },
            &export.model,
            &s.params,
            &s.adam_m,
            &s.adam_v,
            &s.ema,
            s.steps,
        )?;
        Ok(GpuGuide {
            model: Mutex::new(model),
            raw_outputs: export.raw_outputs,
            device,
            training: field.config().training,
            updates: s.updates,
            steps: 0,
            stopped: false,
        })
    }

    /// The device, e.g. `"llvmpipe (LLVM 15.0.6, 256 bits) (Mesa 22.3.6)"`.
    pub fn device(&self) -> &str {
        &self.device
    }

    /// Raw outputs per query.
    pub fn raw_outputs(&self) -> usize {
        self.raw_outputs
    }

    /// Steps applied on the device by [`Self::update`].
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Raw network outputs of `queries` (EMA weights) into `out` (resized to
    /// `queries.len() · raw_outputs`). Callable from several threads; the
    /// device runs one batch at a time.
    pub fn infer(&self, queries: &[QueryPoint], out: &mut Vec<f32>) -> Result<(), GpuError> {
        out.clear();
        out.resize(queries.len() * self.raw_outputs, 0.0);
        let mut model = self.model.lock().unwrap_or_else(|e| e.into_inner());
        model.infer(queries, out)?;
        Ok(())
    }

    /// No more training (the inference weights stay as they are).
    pub fn stop_training(&mut self) {
        self.stopped = true;
    }

    /// One update on `samples` with the field's training settings, as
    /// `Field::update` does it: invalid samples are dropped, the rest
    /// shuffled (seeded by the field's seed and the update count) and cut
    /// into `steps_per_update` minibatches of `batch_size` (reshuffling when
    /// they run out), each a [`GpuModel::train_step`].
    pub fn update(&mut self, samples: &[TrainingSample]) -> Result<GpuUpdate, GpuError> {
        let mut report = GpuUpdate {
            mean_loss: f64::NAN,
            ..GpuUpdate::default()
        };
        if self.stopped {
            return Ok(report);
        }
        let mut buffer: Vec<TrainingSample> = samples
            .iter()
            .filter(|s| s.validate().is_ok())
            .copied()
            .collect();
        let n = buffer.len();
        if n == 0 {
            return Ok(report);
        }
        let cfg = &self.training;
        let b = cfg.batch_size.min(n).max(1);
        let options = TrainOptions {
            adam: cfg.adam,
            ema_decay: cfg.ema_decay,
            max_gradient_magnitude: cfg.max_gradient_magnitude,
        };
        let mut rng = Rng::with_stream(cfg.seed, self.updates as u32);
        shuffle(&mut buffer, &mut rng);
        let mut pos = 0;
        let mut loss_sum = 0.0f64;
        let model = self.model.get_mut().unwrap_or_else(|e| e.into_inner());
        for _ in 0..cfg.steps_per_update {
            if pos + b > n {
                shuffle(&mut buffer, &mut rng);
                pos = 0;
            }
            let batch = &buffer[pos..pos + b];
            pos += b;
            match model.train_step(batch, &options)? {
                StepOutcome::Applied { loss, .. } => {
                    report.steps += 1;
                    loss_sum += f64::from(loss);
                }
                StepOutcome::Skipped => report.skipped += 1,
            }
        }
        self.updates += 1;
        self.steps += u64::from(report.steps);
        if report.steps > 0 {
            report.mean_loss = loss_sum / f64::from(report.steps);
        }
        Ok(report)
    }
}
