//! [`GuidingField`]: the non-generic guiding field a renderer embeds, and
//! [`Distribution`], the decoded distribution at one shading point.

use crate::config::GuidingConfig;
use crate::device::{DeviceFailure, DeviceField, DeviceSelection, GpuContext};
use crate::error::{same_lengths, GuidingError};
use crate::models::{self, with_df_field, with_field, AnyField, Decode, Decoded};
use glam::{Vec2, Vec3};
use guiding_core::field::{FieldState, UpdateReport};
use guiding_core::lobe::DirectionSample;
use guiding_core::model::df::DfVertex;
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::sample::{TrainingSample, REJECTION_KINDS};
use std::sync::atomic::{AtomicU64, Ordering};

static NEXT_FIELD_ID: AtomicU64 = AtomicU64::new(1);

/// Queries per batched decode of the field-level batch calls
/// ([`GuidingField::query`], [`GuidingField::sample_batch`], …): one task of
/// the worker pool each.
pub const QUERY_CHUNK: usize = 1024;

/// Counters of a field's training, for the renderer's statistics.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FieldStats {
    /// Adam steps applied.
    pub steps: u64,
    /// Steps skipped for a non-finite gradient.
    pub skipped_steps: u64,
    /// Training samples accepted into the buffer.
    pub accepted_samples: u64,
    /// Rejected samples per kind (non-finite, negative, non-positive pdf,
    /// non-unit direction).
    pub rejected_samples: [u64; REJECTION_KINDS],
    /// Samples dropped because training had stopped.
    pub ignored_samples: u64,
    /// Valid samples dropped because the buffer was full.
    pub overflowed_samples: u64,
    /// Samples waiting for the next update.
    pub buffered_samples: u64,
    /// Number of updates that changed the parameters ([`GuidingField::generation`]).
    pub generation: u64,
    /// Parameters of the model.
    pub param_count: u64,
    /// `1` once training is over, else `0`.
    pub converged: u32,
    /// Padding.
    pub pad: u32,
}

/// A guiding field: a neural model of the incident radiance (or product)
/// over the scene's bounding box, trained online from the renderer's path
/// samples.
///
/// Queries (`&self`) may run from many threads at once; training
/// ([`Self::add_samples`], [`Self::update`]) needs `&mut self`, so a
/// renderer alternates render passes and updates (as with Open PGL's
/// `Field::Update`).
pub struct GuidingField {
    config: GuidingConfig,
    bounds: ([f32; 3], [f32; 3]),
    pub(crate) id: u64,
    pub(crate) generation: u64,
    pub(crate) inner: AnyField,
    /// The Vulkan backend, when the field runs there ([`Self::use_device`]).
    pub(crate) device: Option<DeviceField>,
}

impl std::fmt::Debug for GuidingField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GuidingField")
            .field("config", &self.config)
            .field("bounds", &self.bounds)
            .field("id", &self.id)
            .field("generation", &self.generation)
            .field("device", &self.device_name())
            .field("stats", &self.stats())
            .finish()
    }
}

/// Pads the box by 1 % of its extent (at least `10⁻⁵`) on every side, so
/// surface points on the scene's bounding box never sit on the grid's edge.
fn padded(min: [f32; 3], max: [f32; 3]) -> Result<([f32; 3], [f32; 3]), GuidingError> {
    let err = GuidingError::InvalidBounds { min, max };
    let (lo, hi) = (Vec3::from_array(min), Vec3::from_array(max));
    if !(lo.is_finite() && hi.is_finite() && lo.cmplt(hi).all()) {
        return Err(err);
    }
    let pad = ((hi - lo) * 0.01).max(Vec3::splat(1e-5));
    let (plo, phi) = (lo - pad, hi + pad);
    if !(plo.is_finite() && phi.is_finite()) {
        return Err(err);
    }
    Ok((plo.to_array(), phi.to_array()))
}

impl GuidingField {
    /// A freshly initialised field over the scene box `[bounds_min,
    /// bounds_max]` (padded by 1 %).
    ///
    /// # Errors
    /// An invalid `config` or non-finite / empty bounds.
    pub fn new(
        config: GuidingConfig,
        bounds_min: [f32; 3],
        bounds_max: [f32; 3],
    ) -> Result<Self, GuidingError> {
        Self::with_state(config, bounds_min, bounds_max, None)
    }

    pub(crate) fn with_state(
        config: GuidingConfig,
        bounds_min: [f32; 3],
        bounds_max: [f32; 3],
        state: Option<FieldState>,
    ) -> Result<Self, GuidingError> {
        config.validate()?;
        let (lo, hi) = padded(bounds_min, bounds_max)?;
        let inner = models::build(&config, lo, hi, state)?;
        Ok(Self {
            config,
            bounds: (bounds_min, bounds_max),
            id: NEXT_FIELD_ID.fetch_add(1, Ordering::Relaxed),
            generation: 0,
            inner,
            device: None,
        })
    }

    /// The configuration it was built with.
    pub fn config(&self) -> &GuidingConfig {
        &self.config
    }

    /// The scene bounds it was built with (before padding).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        self.bounds
    }

    /// Number of updates so far that changed the parameters; a
    /// [`DecodedDistribution`] is only valid for the generation that
    /// decoded it.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Number of `f32` parameters of the model.
    pub fn param_count(&self) -> usize {
        with_field!(&self.inner, f => f.model().param_count())
    }

    /// Training counters.
    pub fn stats(&self) -> FieldStats {
        with_field!(&self.inner, f => FieldStats {
            steps: f.steps(),
            skipped_steps: f.skipped_steps(),
            accepted_samples: f.accepted(),
            rejected_samples: f.rejected(),
            ignored_samples: f.ignored(),
            overflowed_samples: f.overflowed(),
            buffered_samples: f.buffered() as u64,
            generation: self.generation,
            param_count: f.model().param_count() as u64,
            converged: u32::from(f.is_converged()),
            pad: 0,
        })
    }

    /// Validates and buffers training samples for the next [`Self::update`];
    /// invalid ones (NaN/∞, negative radiance, pdf ≤ 0, non-unit directions)
    /// are counted in [`FieldStats::rejected_samples`] and dropped.
    pub fn add_samples(&mut self, samples: &[TrainingSample]) {
        with_field!(&mut self.inner, f => f.add_samples(samples));
    }

    /// Runs one iteration of training ([`GuidingConfig::training`]'s
    /// `steps_per_update` Adam steps) on the buffered samples, then clears
    /// the buffer. Does nothing once converged. On a device whose failure
    /// is an error ([`DeviceFailure::Error`]) a failed update trains nothing
    /// and [`Self::device_error`] says why; [`Self::try_update`] returns it.
    pub fn update(&mut self) -> UpdateReport {
        let steps = with_field!(&self.inner, f => f.config().steps_per_update);
        self.train(steps).unwrap_or_else(|_| failed_report())
    }

    /// [`Self::update`], returning a device failure as an error.
    ///
    /// # Errors
    /// [`GuidingError::Device`] when the field runs on a device that failed
    /// (now or before) and falls back to nothing.
    pub fn try_update(&mut self) -> Result<UpdateReport, GuidingError> {
        let steps = with_field!(&self.inner, f => f.config().steps_per_update);
        self.train(steps)
    }

    /// [`Self::update`] with as many Adam steps as `epochs` passes over the
    /// buffered samples take, capped at the configuration's
    /// `steps_per_update` (`clamp(⌈epochs · buffered / batch_size⌉, 1,
    /// steps_per_update)`): training proportional to what the render pass
    /// produced. The renderer's default between passes.
    pub fn update_proportional(&mut self, epochs: f32) -> UpdateReport {
        self.try_update_proportional(epochs)
            .unwrap_or_else(|_| failed_report())
    }

    /// [`Self::update_proportional`], returning a device failure as an error.
    ///
    /// # Errors
    /// As [`Self::try_update`].
    pub fn try_update_proportional(&mut self, epochs: f32) -> Result<UpdateReport, GuidingError> {
        let steps = with_field!(&self.inner, f => f.proportional_steps(epochs));
        self.train(steps)
    }

    /// Runs exactly `steps` Adam steps (at least one) on the buffered samples, then clears the
    /// buffer: what a [`crate::TrainingSchedule`] decides ([`crate::TrainingSchedule::steps_due`]).
    ///
    /// # Errors
    /// As [`Self::try_update`].
    pub fn try_update_steps(&mut self, steps: u32) -> Result<UpdateReport, GuidingError> {
        self.train(steps.max(1))
    }

    /// Valid training samples waiting for the next update.
    pub fn buffered_samples(&self) -> usize {
        with_field!(&self.inner, f => f.buffered())
    }

    /// The one training path of both backends: `steps` steps of the field's
    /// loop, their arithmetic on the CPU threads or on the device.
    fn train(&mut self, steps: u32) -> Result<UpdateReport, GuidingError> {
        self.settle_device()?;
        let result = match &self.device {
            Some(d) => with_field!(&mut self.inner, f => d.train(f, steps)).map_err(|e| d.fail(e)),
            None => Ok(with_field!(&mut self.inner, f => f.update_steps(steps))),
        };
        match result {
            Ok(report) => {
                if report.steps > 0 {
                    self.generation += 1;
                }
                Ok(report)
            }
            Err(e) => {
                // Steps may have been applied on the device before it failed.
                self.generation += 1;
                self.settle_device()?;
                Err(e)
            }
        }
    }

    /// Runs the field's network on a Vulkan device from now on (see
    /// [`crate::device`]): the current training state is uploaded, training
    /// steps and the wavefront queries run there.
    ///
    /// # Errors
    /// [`GuidingError::Device`]: no Vulkan loader or matching device, or
    /// SPIR-V not built into this binary (`guiding-gpu`'s feature
    /// `shaders`).
    pub fn use_device(
        &mut self,
        selection: DeviceSelection,
        on_failure: DeviceFailure,
    ) -> Result<(), GuidingError> {
        let ctx = GpuContext::new(selection).map_err(crate::device::device_error)?;
        self.use_device_context(ctx, on_failure)
    }

    /// [`Self::use_device`] on an open device (several fields can share
    /// one, and its compiled shader modules).
    ///
    /// # Errors
    /// [`GuidingError::Device`]: SPIR-V not built, or the upload failed.
    pub fn use_device_context(
        &mut self,
        ctx: GpuContext,
        on_failure: DeviceFailure,
    ) -> Result<(), GuidingError> {
        let state = self.state();
        let device = DeviceField::new(
            ctx,
            on_failure,
            models::kernel_prefix(&self.inner),
            models::family(&self.inner),
            &self.model_bytes(),
            &state,
        )?;
        self.device = Some(device);
        self.generation += 1;
        Ok(())
    }

    /// The device the field runs on (`None` on the CPU, also after a
    /// fallback).
    pub fn device_name(&self) -> Option<String> {
        self.device.as_ref().map(|d| d.name().to_string())
    }

    /// The device's failure, when the field runs on a device that failed
    /// and does not fall back ([`DeviceFailure::Error`]).
    pub fn device_error(&self) -> Option<GuidingError> {
        let d = self.device.as_ref()?;
        d.failure().map(GuidingError::Device)
    }

    /// Marks the field's device as failed with `message`, as a failed Vulkan
    /// call would: for tests of the failure paths (a working device cannot
    /// be made to fail on demand). Does nothing on the CPU. Feature
    /// `testing` only (the test crates enable it).
    #[cfg(feature = "testing")]
    #[doc(hidden)]
    pub fn fail_device_for_tests(&self, message: &str) {
        if let Some(d) = &self.device {
            d.fail_with(message);
        }
    }

    /// The error every device-backed call returns once the device failed
    /// and the field does not fall back ([`DeviceFailure::Error`]).
    pub(crate) fn device_refusal(&self) -> Option<GuidingError> {
        let d = self.device.as_ref()?;
        if d.on_failure != DeviceFailure::Error {
            return None;
        }
        d.failure().map(GuidingError::Device)
    }

    /// The active device: present and not failed.
    pub(crate) fn active_device(&self) -> Option<&DeviceField> {
        self.device.as_ref().filter(|d| d.failure().is_none())
    }

    /// After a device failure: the error ([`DeviceFailure::Error`]), or the
    /// move to the CPU with the device's weights
    /// ([`DeviceFailure::FallbackToCpu`]).
    fn settle_device(&mut self) -> Result<(), GuidingError> {
        let Some(d) = &self.device else {
            return Ok(());
        };
        if d.failure().is_none() {
            return Ok(());
        }
        if let Some(e) = self.device_refusal() {
            return Err(e);
        }
        let state = self.state();
        with_field!(&mut self.inner, f => f.restore_state(state))?;
        self.device = None;
        self.generation += 1;
        Ok(())
    }

    /// Whether training is over (stopped, plateaued or at its step limit).
    pub fn is_converged(&self) -> bool {
        with_field!(&self.inner, f => f.is_converged())
    }

    /// Stops training for good and frees the training memory; the field
    /// keeps answering queries.
    pub fn stop_training(&mut self) {
        with_field!(&mut self.inner, f => f.stop_training());
    }

    /// The distribution at one shading point (one network pass for NPM and
    /// NASG; DF evaluates its conditional network per sample / pdf call).
    pub fn distribution(&self, query: &QueryPoint) -> Distribution<'_> {
        let decoded = with_field!(&self.inner, f => f.model().decode_at(f.ema_params(), query));
        Distribution {
            field: self,
            decoded,
        }
    }

    /// [`Self::distribution`] for every query (batched decodes spread over
    /// the field's worker pool, on the CPU with the device's weights when the
    /// field runs on a device); `out` is cleared first.
    pub fn query_into<'f>(&'f self, queries: &[QueryPoint], out: &mut Vec<Distribution<'f>>) {
        out.clear();
        // Plain values: decoded on the CPU (device lanes stay on the device).
        let batches = self.decode_chunks_cpu(queries);
        for b in &batches {
            out.extend((0..b.len()).filter_map(|i| b.get(i).and_then(|d| self.attach(d).ok())));
        }
    }

    /// Decodes `queries` in chunks of [`QUERY_CHUNK`], spread over the
    /// field's pool (one chunk per task, results in query order), on the
    /// CPU (with the device's weights when the field runs on a device).
    ///
    /// On a field that runs on a device the chunks are decoded there (see
    /// [`Self::decode_batch`]).
    pub fn decode_chunks(&self, queries: &[QueryPoint]) -> Vec<crate::DistributionBatch> {
        if self.device.is_some() {
            return queries
                .chunks(QUERY_CHUNK.max(1))
                .map(|part| {
                    let mut b = crate::DistributionBatch::new();
                    self.decode_batch(part, &mut b);
                    b
                })
                .collect();
        }
        self.decode_chunks_cpu(queries)
    }

    /// [`Self::decode_chunks`] on the CPU (with the device's weights when
    /// the field runs on a device).
    fn decode_chunks_cpu(&self, queries: &[QueryPoint]) -> Vec<crate::DistributionBatch> {
        use rayon::prelude::*;
        let decode = |part: &[QueryPoint]| {
            let mut b = crate::DistributionBatch::new();
            self.decode_batch_cpu(part, &mut b);
            b
        };
        let pool = with_field!(&self.inner, f => f.pool());
        match pool {
            Some(pool) if queries.len() > QUERY_CHUNK => {
                pool.install(|| queries.par_chunks(QUERY_CHUNK).map(decode).collect())
            }
            _ => queries.chunks(QUERY_CHUNK.max(1)).map(decode).collect(),
        }
    }

    /// [`Self::query_into`] into a new vector.
    pub fn query(&self, queries: &[QueryPoint]) -> Vec<Distribution<'_>> {
        let mut out = Vec::with_capacity(queries.len());
        self.query_into(queries, &mut out);
        out
    }

    /// Samples one direction `wi` per query (`u[i] ∈ [0, 1)²`), spread over
    /// the field's threads.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the three lengths differ.
    pub fn sample_batch(
        &self,
        queries: &[QueryPoint],
        u: &[Vec2],
        out: &mut [DirectionSample],
    ) -> Result<(), GuidingError> {
        self.per_query_call(queries, u, "random pairs", out, Self::sample_decoded)
    }

    /// Density of `directions[i]` (unit `wi`s) at `queries[i]`, spread over
    /// the threads.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the three lengths differ.
    pub fn pdf_batch(
        &self,
        queries: &[QueryPoint],
        directions: &[Vec3],
        out: &mut [f32],
    ) -> Result<(), GuidingError> {
        self.per_query_call(queries, directions, "directions", out, Self::pdf_decoded)
    }

    /// The common body of [`Self::sample_batch`] and [`Self::pdf_batch`]:
    /// checks the lengths (`inputs` named `what`), decodes `queries` in
    /// chunks and runs `call` (a `*_decoded` method) on each chunk's lanes.
    fn per_query_call<I, O>(
        &self,
        queries: &[QueryPoint],
        inputs: &[I],
        what: &str,
        out: &mut [O],
        call: impl Fn(
            &Self,
            &crate::DistributionBatch,
            &[u32],
            &[I],
            &mut [O],
        ) -> Result<(), GuidingError>,
    ) -> Result<(), GuidingError> {
        same_lengths(&[
            (queries.len(), "queries"),
            (inputs.len(), what),
            (out.len(), "outputs"),
        ])?;
        let batches = self.decode_chunks(queries);
        for ((b, inputs), out) in batches
            .iter()
            .zip(inputs.chunks(QUERY_CHUNK))
            .zip(out.chunks_mut(QUERY_CHUNK))
        {
            let lanes: Vec<u32> = (0..inputs.len() as u32).collect();
            call(self, b, &lanes, inputs, out)?;
        }
        Ok(())
    }

    /// Guide-selection probability per query.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the lengths differ.
    pub fn selection_probability_batch(
        &self,
        queries: &[QueryPoint],
        out: &mut [f32],
    ) -> Result<(), GuidingError> {
        same_lengths(&[(queries.len(), "queries"), (out.len(), "outputs")])?;
        let batches = self.decode_chunks(queries);
        for (b, out) in batches.iter().zip(out.chunks_mut(QUERY_CHUNK)) {
            for (i, o) in out.iter_mut().enumerate() {
                *o = b.selection_probability(i);
            }
        }
        Ok(())
    }

    /// Checks that something decoded by field `field_id` at `generation`
    /// is this field's at its current generation.
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] otherwise.
    pub(crate) fn check_current(&self, field_id: u64, generation: u64) -> Result<(), GuidingError> {
        if field_id != self.id || generation != self.generation {
            return Err(GuidingError::StaleDistribution {
                field_id,
                generation,
                used_id: self.id,
                used_generation: self.generation,
            });
        }
        Ok(())
    }

    /// Re-attaches a [`DecodedDistribution`] (e.g. kept in a renderer's
    /// per-lane storage) to this field.
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] if it was decoded by another field
    /// or before this field's latest update.
    pub fn attach(&self, decoded: DecodedDistribution) -> Result<Distribution<'_>, GuidingError> {
        self.check_current(decoded.field_id, decoded.generation)?;
        Ok(Distribution {
            field: self,
            decoded: decoded.decoded,
        })
    }

    /// Everything a GPU runtime needs to run this field's model: the
    /// SPIR-V entry-point prefix, the raw outputs per query, the model's
    /// `Pod` configuration bytes and the training state.
    pub fn export_model(&self) -> ModelExport {
        ModelExport {
            kernel_prefix: models::kernel_prefix(&self.inner),
            raw_outputs: models::raw_outputs(&self.inner),
            model: self.model_bytes(),
            state: self.state(),
        }
    }

    /// The distribution whose raw network outputs (`raw`, length
    /// [`ModelExport::raw_outputs`]) were computed elsewhere — a GPU running
    /// the model's `infer` kernel on the exported weights. Decoding is the
    /// same function [`Self::distribution`] uses, so CPU and GPU differ
    /// only by the network's rounding.
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if `raw` has the wrong length, or
    /// [`GuidingError::InvalidConfig`] for DF models (no raw outputs).
    pub fn distribution_from_raw(&self, raw: &[f32]) -> Result<Distribution<'_>, GuidingError> {
        models::raw_queries(&self.inner, raw.len(), true)?;
        let decoded = models::decode_raw(&self.inner, raw)
            .ok_or_else(|| GuidingError::InvalidConfig("the model has no raw outputs".into()))?;
        Ok(Distribution {
            field: self,
            decoded,
        })
    }

    /// The resumable training state (for [`crate::file`]): the device's
    /// when the field runs on one (also after a failure, while it still
    /// answers); if it cannot be read, the weights the field copied back
    /// (the EMA, as parameters too) with fresh Adam moments.
    pub(crate) fn state(&self) -> FieldState {
        let Some(d) = &self.device else {
            return with_field!(&self.inner, f => f.state());
        };
        with_field!(&self.inner, f => d.state(f).unwrap_or_else(|_| {
            let mut s = f.state();
            s.params = s.ema.clone();
            s.adam_m.fill(0.0);
            s.adam_v.fill(0.0);
            s
        }))
    }

    pub(crate) fn model_bytes(&self) -> Vec<u8> {
        models::model_bytes(&self.inner)
    }

    /// A DF sample as one lane of a batch (the batched conditional network,
    /// so a `Distribution` agrees bit for bit with the batch calls).
    fn sample_df(&self, vertex: &DfVertex, u: Vec2) -> DirectionSample {
        let mut out = [DirectionSample {
            direction: Vec3::Z,
            pdf: 0.0,
        }];
        let v = std::slice::from_ref(vertex);
        // A DF vertex is attached to the DF field that decoded it (`attach`).
        with_df_field!(&self.inner, f => f
            .model()
            .sample_vertices(f.ema_params(), v, &[0], &[u], &mut out), ());
        out[0]
    }

    /// A DF density as one lane of a batch (see [`Self::sample_df`]).
    fn pdf_df(&self, vertex: &DfVertex, direction: Vec3) -> f32 {
        let mut out = [0.0f32];
        let v = std::slice::from_ref(vertex);
        with_df_field!(&self.inner, f => f
            .model()
            .pdf_vertices(f.ema_params(), v, &[0], &[direction], &mut out), ());
        out[0]
    }
}

/// A field's model as a GPU runtime uploads it ([`GuidingField::export_model`]).
#[derive(Clone, Debug)]
pub struct ModelExport {
    /// Entry-point prefix in the `guiding-shaders` SPIR-V module, e.g.
    /// `"npm_compact_radiance"`.
    pub kernel_prefix: &'static str,
    /// Raw network outputs per query (`{prefix}_infer`); 0 for DF.
    pub raw_outputs: usize,
    /// The model's configuration as bytes (`repr(C)`, `Pod`).
    pub model: Vec<u8>,
    /// Parameters, EMA weights, Adam moments and step counts.
    pub state: FieldState,
}

/// The guiding distribution at one shading point, borrowed from its field.
///
/// `sample` returns a unit direction and its density (finite, `> 0`);
/// `pdf` is the density of any direction (finite, `≥ 0`); both in solid
/// angle. The directions are `wi`s of the [crate conventions](crate#conventions):
/// world space, pointing away from the surface. Combine with BSDF sampling by one-sample MIS with
/// [`Self::selection_probability`] `c`: sample the guide with probability
/// `c`, and use `c · p_guide + (1 − c) · p_bsdf` as the path pdf.
#[derive(Clone, Copy, Debug)]
pub struct Distribution<'f> {
    field: &'f GuidingField,
    decoded: Decoded,
}

impl<'f> Distribution<'f> {
    /// Draws a direction `wi` (unit, world space) from `u ∈ [0, 1)²`.
    pub fn sample(&self, u: Vec2) -> DirectionSample {
        match &self.decoded {
            Decoded::Vmf { mixture, .. } => mixture.sample(u),
            Decoded::Nasg(mixture) => mixture.sample(u),
            Decoded::Df { vertex, .. } => self.field.sample_df(vertex, u),
        }
    }

    /// Density of `direction` (a unit `wi`, world space) in solid angle.
    pub fn pdf(&self, direction: Vec3) -> f32 {
        match &self.decoded {
            Decoded::Vmf { mixture, .. } => mixture.pdf(direction),
            Decoded::Nasg(mixture) => mixture.pdf(direction),
            Decoded::Df { vertex, .. } => self.field.pdf_df(vertex, direction),
        }
    }

    /// Probability of sampling the guide rather than the BSDF (learned by
    /// NASG, the configured constant otherwise).
    pub fn selection_probability(&self) -> f32 {
        match &self.decoded {
            Decoded::Vmf { selection, .. } | Decoded::Df { selection, .. } => *selection,
            Decoded::Nasg(mixture) => mixture.selection_probability,
        }
    }

    /// The field it was decoded from.
    pub fn field(&self) -> &'f GuidingField {
        self.field
    }

    /// An owned copy that can be stored without borrowing the field and
    /// re-attached with [`GuidingField::attach`].
    pub fn detach(&self) -> DecodedDistribution {
        DecodedDistribution {
            field_id: self.field.id,
            generation: self.field.generation,
            decoded: self.decoded,
        }
    }
}

/// A [`Distribution`] detached from its field ([`Distribution::detach`]):
/// `'static`, `Copy`, valid for the field generation that decoded it. Its
/// directions are `wi`s as the [`Distribution`]'s ([crate
/// conventions](crate#conventions)).
#[derive(Clone, Copy, Debug)]
pub struct DecodedDistribution {
    field_id: u64,
    generation: u64,
    decoded: Decoded,
}

impl DecodedDistribution {
    pub(crate) fn new(field_id: u64, generation: u64, decoded: Decoded) -> Self {
        Self {
            field_id,
            generation,
            decoded,
        }
    }
}

/// What an update that could not run reports (nothing trained).
fn failed_report() -> UpdateReport {
    UpdateReport {
        mean_loss: f64::NAN,
        ..UpdateReport::default()
    }
}
