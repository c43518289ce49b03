//! The Vulkan backend of a [`crate::GuidingField`]: the same field, with its
//! network's inference and the arithmetic of its training steps on a device
//! through `guiding-gpu` (SPIR-V compiled from `guiding-core`'s kernels by
//! rust-gpu).
//!
//! The field keeps everything that is not arithmetic, whichever backend
//! runs: sample validation and rejection counts, the buffer and its cap,
//! the shuffles and minibatches, step counts, `max_steps`, the loss history
//! and the plateau, generations and staleness, save / load
//! ([`guiding_core::field::Field::update_steps_on`] is the one training
//! loop; a step here is [`GpuModel::train_step_at`]). After each update the
//! device's EMA weights are copied back into the field, so the per-query API
//! ([`crate::GuidingField::distribution`], `query`, `sample_batch`, the guide
//! cache) answers with the device's trained weights on the CPU, and a
//! fallback to the CPU continues from them.
//!
//! The wavefront API runs on the device: [`crate::GuidingField::decode_batch`]
//! runs the network of every query there and keeps the raw outputs resident
//! (NASG's selection probabilities are read back); `sample_decoded` /
//! `pdf_decoded` decode the lanes they need on the device (NPM with the
//! cosine product when the batch has one) and read back only the samples
//! and densities. DF splits as on the CPU: `decode_batch` keeps each
//! query's vertex on the device (grid + product inputs and the marginal
//! network's density), and each sample or pdf runs only the conditional
//! network.
//!
//! A device failure is never hidden: with [`DeviceFailure::Error`] every
//! later call of the field that needs the device returns
//! [`GuidingError::Device`] (and [`crate::GuidingField::device_error`] says
//! why); with [`DeviceFailure::FallbackToCpu`] the field goes on on the CPU
//! with the weights the device trained (the full training state when the
//! device can still be read, else the last EMA copy, with fresh Adam
//! moments).

use crate::error::GuidingError;
use guiding_core::field::{Field, FieldConfig, FieldState, StepBackend, StepOutcome, UpdateReport};
use guiding_core::model::{Family, GuidingModel, QueryPoint};
use guiding_core::sample::TrainingSample;
pub use guiding_gpu::{DeviceSelection, GpuContext};
use guiding_gpu::{GpuBuffer, GpuError, GpuModel, ModelEntryPoints, TrainOptions};
use std::sync::{Mutex, MutexGuard, PoisonError};

/// What a field does when its device fails.
#[repr(u32)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceFailure {
    /// Every later call that needs the device returns the error (the
    /// renderer ends its render with it).
    #[default]
    Error = 0,
    /// Go on on the CPU with the weights the device trained.
    FallbackToCpu = 1,
}

/// The lanes of a batch decoded on the device.
pub(crate) struct DeviceLanes {
    /// What stays on the device per lane: the raw network outputs (NPM,
    /// NASG) or the DF vertices (base input and marginal density).
    pub(crate) raw: Option<GpuBuffer>,
    /// The queries (the CPU fallback decodes them again).
    pub(crate) queries: Vec<QueryPoint>,
}

impl std::fmt::Debug for DeviceLanes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceLanes")
            .field("raw_bytes", &self.raw.as_ref().map(GpuBuffer::size))
            .field("lanes", &self.queries.len())
            .finish()
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A field's model on a Vulkan device.
pub(crate) struct DeviceField {
    model: Mutex<GpuModel>,
    name: String,
    pub(crate) family: Family,
    pub(crate) on_failure: DeviceFailure,
    /// The first failure, once there was one (the device is not used after it).
    failure: Mutex<Option<String>>,
}

/// One training step on the device ([`StepBackend`]).
struct DeviceStep<'a> {
    model: &'a mut GpuModel,
}

impl StepBackend for DeviceStep<'_> {
    type Error = GpuError;

    fn train_step(
        &mut self,
        batch: &[TrainingSample],
        step: u32,
        config: &FieldConfig,
    ) -> Result<StepOutcome, GpuError> {
        let options = TrainOptions {
            adam: config.adam,
            ema_decay: config.ema_decay,
            max_gradient_magnitude: config.max_gradient_magnitude,
        };
        self.model.train_step_at(batch, step, &options)
    }
}

impl DeviceField {
    /// Uploads a model (prefix, raw outputs per query, `Pod` bytes, state)
    /// to the device of `ctx`.
    pub(crate) fn new(
        ctx: GpuContext,
        on_failure: DeviceFailure,
        prefix: &'static str,
        family: Family,
        model_bytes: &[u8],
        state: &FieldState,
    ) -> Result<Self, GuidingError> {
        let name = format!(
            "{} ({})",
            ctx.device_info().name,
            ctx.device_info().driver_info
        );
        let model = GpuModel::new(
            ctx,
            ModelEntryPoints { prefix, family },
            model_bytes,
            &state.params,
            &state.adam_m,
            &state.adam_v,
            &state.ema,
            state.steps,
        )
        .map_err(device_error)?;
        Ok(Self {
            model: Mutex::new(model),
            name,
            family,
            on_failure,
            failure: Mutex::new(None),
        })
    }

    /// The device, e.g. `"llvmpipe (LLVM 15.0.6, 256 bits) (Mesa 22.3.6)"`.
    pub(crate) fn name(&self) -> &str {
        &self.name
    }

    /// The first failure, if any.
    pub(crate) fn failure(&self) -> Option<String> {
        lock(&self.failure).clone()
    }

    /// Records `e` as the device's failure (the first one stays) and
    /// returns it as a [`GuidingError`].
    pub(crate) fn fail(&self, e: GpuError) -> GuidingError {
        self.fail_with(&e.to_string())
    }

    /// [`Self::fail`] with a message.
    pub(crate) fn fail_with(&self, what: &str) -> GuidingError {
        let mut f = lock(&self.failure);
        let message = format!("{} failed: {what}", self.name);
        if f.is_none() {
            *f = Some(message.clone());
        }
        GuidingError::Device(message)
    }

    /// `update_steps_on` with the device as the backend, then the device's
    /// EMA copied into `field` (when a step was applied).
    pub(crate) fn train<M: GuidingModel + Send + Sync>(
        &self,
        field: &mut Field<M>,
        steps: u32,
    ) -> Result<UpdateReport, GpuError> {
        let mut model = lock(&self.model);
        let report = field.update_steps_on(steps, &mut DeviceStep { model: &mut model })?;
        if report.steps > 0 {
            model.ema_into(field.ema_params_mut())?;
        }
        Ok(report)
    }

    /// The device's training state (parameters, EMA, Adam moments), with
    /// `field`'s step and update counts.
    pub(crate) fn state<M: GuidingModel + Send + Sync>(
        &self,
        field: &Field<M>,
    ) -> Result<FieldState, GpuError> {
        let model = lock(&self.model);
        let (adam_m, adam_v) = model.adam_moments()?;
        let n = field.model().param_count();
        let cut = |mut v: Vec<f32>| {
            v.truncate(n);
            v
        };
        Ok(FieldState {
            params: cut(model.params()?),
            ema: cut(model.ema()?),
            adam_m: cut(adam_m),
            adam_v: cut(adam_v),
            steps: field.steps(),
            updates: field.updates(),
        })
    }

    /// Runs the network at every query, keeping the raw outputs in `lanes`
    /// on the device; NASG's selection probabilities into `selection`.
    pub(crate) fn decode(
        &self,
        queries: &[QueryPoint],
        lanes: &mut DeviceLanes,
        selection: &mut Vec<f32>,
    ) -> Result<(), GpuError> {
        lanes.queries.clear();
        lanes.queries.extend_from_slice(queries);
        selection.clear();
        let mut model = lock(&self.model);
        if self.family == Family::Df {
            model.vertices_resident(queries, &mut lanes.raw)?;
        } else {
            model.infer_resident(queries, &mut lanes.raw, selection)?;
        }
        Ok(())
    }

    /// Samples lanes `lanes[k]` with `inputs[k]` (`u`) into `out[k]` (`[ω, pdf]`),
    /// or takes the density of direction `inputs[k]` under lane `lanes[k]`.
    pub(crate) fn eval_lanes(
        &self,
        decoded: &DeviceLanes,
        lanes: &[u32],
        normals: &[[f32; 4]],
        inputs: &[[f32; 4]],
        out: LanesOut<'_>,
    ) -> Result<(), GpuError> {
        let mut model = lock(&self.model);
        // An empty decode: no lanes.
        let Some(raw) = &decoded.raw else {
            return Ok(());
        };
        match (out, self.family) {
            (LanesOut::Samples(out), Family::Npm | Family::Nasg) => {
                model.sample_lanes(raw, lanes, normals, inputs, out)?;
            }
            (LanesOut::Samples(out), Family::Df) => {
                model.sample_vertex_lanes(raw, lanes, inputs, out)?;
            }
            (LanesOut::Pdfs(out), Family::Npm | Family::Nasg) => {
                model.pdf_lanes(raw, lanes, normals, inputs, out)?;
            }
            (LanesOut::Pdfs(out), Family::Df) => {
                model.pdf_vertex_lanes(raw, lanes, inputs, out)?;
            }
        }
        Ok(())
    }
}

/// Where [`DeviceField::eval_lanes`] writes: samples (`[ω, pdf]`) or densities.
pub(crate) enum LanesOut<'a> {
    Samples(&'a mut [[f32; 4]]),
    Pdfs(&'a mut [f32]),
}

/// A device error as the facade's error.
pub(crate) fn device_error(e: GpuError) -> GuidingError {
    GuidingError::Device(e.to_string())
}
