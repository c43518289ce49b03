//! A guiding model resident on the GPU: its configuration, parameters,
//! Adam moments and EMA weights in device buffers, and the batch kernels of
//! `guiding_core::batch` (compiled to SPIR-V) for inference and training.
//!
//! [`GpuModel`] is what a renderer's wavefront loop talks to when it runs
//! the guiding stages on the GPU: [`GpuModel::infer`] (grid encoding + MLP
//! for a batch of query points, raw outputs back for the CPU to decode),
//! [`GpuModel::sample`] / [`GpuModel::pdf`] (the whole model per query) and
//! [`GpuModel::train_step`] (per-sample gradients added atomically → block
//! maxima → Adam + EMA, the step of `guiding_core::field::Field` on the
//! GPU; see `guiding_core::batch` for why one sample per invocation). Queries read the EMA
//! weights, as the CPU field does.

use crate::{Batch, BatchReport, GpuBuffer, GpuContext, GpuError, Kernel};
use bytemuck::Pod;
use guiding_core::batch::{AdamArgs, BatchArgs, MAX_ABS_BLOCK};
pub use guiding_core::field::StepOutcome;
use guiding_core::model::df::DfVertex;
use guiding_core::model::{Family, QueryPoint};
use guiding_core::optim::{ema_weight, step_clip_factor, AdamConfig, AdamStepFactors};
use guiding_core::sample::TrainingSample;
use std::mem::size_of;

/// The entry points of one model type: `{prefix}_sample`, `{prefix}_pdf`,
/// `{prefix}_gradient` and, for NPM / NASG, `{prefix}_infer`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelEntryPoints {
    /// Entry-point prefix, e.g. `"npm_compact_radiance"`.
    pub prefix: &'static str,
    /// The model's family: which lane kernels it uses, and its raw outputs
    /// per query of `{prefix}_infer` ([`Family::raw_outputs`]; DF has none).
    pub family: Family,
}

/// Training settings of [`GpuModel::train_step`] (those of the CPU field).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainOptions {
    /// Adam settings.
    pub adam: AdamConfig,
    /// EMA decay of the inference weights.
    pub ema_decay: f32,
    /// A step whose largest gradient magnitude exceeds this is scaled down to it.
    pub max_gradient_magnitude: f32,
}

/// `slot`'s buffer, replaced by one of at least `bytes` (the next power of
/// two, within the device's storage-buffer range) when it is missing or
/// smaller: the growth of the scratch buffers and of the caller-owned
/// resident ones ([`GpuModel::infer_resident`]).
fn grow<'a>(
    ctx: &GpuContext,
    slot: &'a mut Option<GpuBuffer>,
    bytes: u64,
) -> Result<&'a mut GpuBuffer, GpuError> {
    let bytes = bytes.max(16);
    if slot.as_ref().is_none_or(|b| b.size() < bytes) {
        *slot = None;
        let limit = ctx.device_info().max_storage_buffer_range;
        *slot = Some(ctx.buffer(bytes.next_power_of_two().min(limit).max(bytes))?);
    }
    slot.as_mut()
        .ok_or_else(|| GpuError::BadArgument("buffer missing".into()))
}

/// A storage buffer that grows to the largest batch seen.
struct Scratch {
    buffer: Option<GpuBuffer>,
}

impl Scratch {
    const fn new() -> Self {
        Self { buffer: None }
    }

    fn at_least(&mut self, ctx: &GpuContext, bytes: u64) -> Result<&mut GpuBuffer, GpuError> {
        grow(ctx, &mut self.buffer, bytes)
    }

    /// Grows to hold `data` and uploads it.
    fn put<T: Pod>(&mut self, ctx: &GpuContext, data: &[T]) -> Result<(), GpuError> {
        self.at_least(ctx, size_of_val(data) as u64)?.upload(data)
    }

    fn get(&self) -> Result<&GpuBuffer, GpuError> {
        self.buffer
            .as_ref()
            .ok_or_else(|| GpuError::BadArgument("scratch buffer missing".into()))
    }
}

/// The lane kernels on resident data.
#[derive(Clone, Copy)]
enum LaneKernel {
    /// Mixture lanes of raw outputs: sample.
    Sample,
    /// Mixture lanes of raw outputs: pdf.
    Pdf,
    /// DF vertex lanes: sample.
    VertexSample,
    /// DF vertex lanes: pdf.
    VertexPdf,
}

/// The per-query kernels with one input array.
#[derive(Clone, Copy)]
enum QueryKernel {
    Sample,
    Pdf,
}

/// What a call with nothing to do reports.
const NO_WORK: BatchReport = BatchReport {
    dispatches: 0,
    gpu_time_ns: None,
};

/// Push constants of a kernel over `count` elements.
fn args_for(count: u32) -> BatchArgs {
    BatchArgs {
        count,
        ..BatchArgs::default()
    }
}

/// `a` then `b`: dispatch counts and device times added.
fn combine(a: BatchReport, b: BatchReport) -> BatchReport {
    BatchReport {
        dispatches: a.dispatches + b.dispatches,
        gpu_time_ns: match (a.gpu_time_ns, b.gpu_time_ns) {
            (Some(x), Some(y)) => Some(x + y),
            (x, y) => x.or(y),
        },
    }
}

/// Kernels of a model type plus the model-independent training kernels.
struct Kernels {
    infer: Option<Kernel>,
    /// Sample / pdf of lanes of resident raw outputs (NPM: `vmf_lane_*`,
    /// NASG: `nasg_lane_*`); `None` for DF.
    lane_sample: Option<Kernel>,
    lane_pdf: Option<Kernel>,
    /// NASG's learned selection probability of resident raw outputs.
    selection: Option<Kernel>,
    /// DF: the vertex of each query, and sample / pdf of vertex lanes.
    vertex: Option<Kernel>,
    vertex_sample: Option<Kernel>,
    vertex_pdf: Option<Kernel>,
    sample: Kernel,
    pdf: Kernel,
    gradient: Kernel,
    max_abs: Kernel,
    adam: Kernel,
}

/// Training buffers, created at the first step (`losses` grows with the batch).
struct TrainBuffers {
    grad: GpuBuffer,
    partial: GpuBuffer,
}

/// A guiding model on the GPU: its configuration, parameters, Adam moments
/// and EMA weights in device buffers, with the batch kernels for inference
/// and training.
pub struct GpuModel {
    ctx: GpuContext,
    entry: ModelEntryPoints,
    param_count: usize,
    kernels: Kernels,
    model: GpuBuffer,
    params: GpuBuffer,
    adam_m: GpuBuffer,
    adam_v: GpuBuffer,
    ema: GpuBuffer,
    train: Option<TrainBuffers>,
    losses: Scratch,
    steps: u64,
    queries: Scratch,
    inputs: Scratch,
    outputs: Scratch,
    samples: Scratch,
    lanes: Scratch,
    normals: Scratch,
}

fn push<T: Pod>(value: &T) -> &[u8] {
    bytemuck::bytes_of(value)
}

/// The error unless `outputs` holds the `raw` outputs of each of `queries`.
fn check_raw_len(queries: usize, raw: usize, outputs: usize) -> Result<(), GpuError> {
    if outputs == queries * raw {
        return Ok(());
    }
    Err(GpuError::BadArgument(format!(
        "infer: {queries} queries need {} outputs, {outputs} given",
        queries * raw
    )))
}

fn count_u32(n: usize, what: &str) -> Result<u32, GpuError> {
    u32::try_from(n).map_err(|_| GpuError::BadArgument(format!("{what}: {n} is over 2^32")))
}

impl GpuModel {
    /// Uploads a model: `model` holds the bytes of the `Pod` configuration
    /// value of the type `entry` names (e.g. a `NpmCompactRadiance`), then the training state
    /// (`params`, Adam moments `adam_m` / `adam_v`, `ema` weights; all of the
    /// model's parameter count) and the number of steps already taken.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        ctx: GpuContext,
        entry: ModelEntryPoints,
        model: &[u8],
        params: &[f32],
        adam_m: &[f32],
        adam_v: &[f32],
        ema: &[f32],
        steps: u64,
    ) -> Result<GpuModel, GpuError> {
        let n = params.len();
        if n == 0 || adam_m.len() != n || adam_v.len() != n || ema.len() != n {
            return Err(GpuError::BadArgument(format!(
                "model state lengths differ or are zero: params {n}, m {}, v {}, ema {}",
                adam_m.len(),
                adam_v.len(),
                ema.len()
            )));
        }
        let b = size_of::<BatchArgs>() as u32;
        let p = entry.prefix;
        // A kernel only the models of some families have.
        let only = |has: bool, name: &str, buffers: u32| -> Result<Option<Kernel>, GpuError> {
            has.then(|| ctx.embedded_kernel(name, buffers, b))
                .transpose()
        };
        let (df, nasg) = (entry.family == Family::Df, entry.family == Family::Nasg);
        // The lane kernels of the mixture's family: `vmf_lane_*`, `nasg_lane_*`.
        let mixture = if nasg { "nasg" } else { "vmf" };
        let kernels = Kernels {
            infer: only(!df, &format!("{p}_infer"), 4)?,
            lane_sample: only(!df, &format!("{mixture}_lane_sample"), 5)?,
            lane_pdf: only(!df, &format!("{mixture}_lane_pdf"), 5)?,
            selection: only(nasg, "nasg_selection", 2)?,
            vertex: only(df, &format!("{p}_vertex"), 4)?,
            vertex_sample: only(df, &format!("{p}_vertex_sample"), 6)?,
            vertex_pdf: only(df, &format!("{p}_vertex_pdf"), 6)?,
            sample: ctx.embedded_kernel(&format!("{p}_sample"), 5, b)?,
            pdf: ctx.embedded_kernel(&format!("{p}_pdf"), 5, b)?,
            gradient: ctx.embedded_kernel(&format!("{p}_gradient"), 5, b)?,
            max_abs: ctx.embedded_kernel("max_abs", 2, b)?,
            adam: ctx.embedded_kernel("adam", 5, size_of::<AdamArgs>() as u32)?,
        };
        Ok(GpuModel {
            model: ctx.buffer_from(model)?,
            params: ctx.buffer_from(params)?,
            adam_m: ctx.buffer_from(adam_m)?,
            adam_v: ctx.buffer_from(adam_v)?,
            ema: ctx.buffer_from(ema)?,
            ctx,
            entry,
            param_count: n,
            kernels,
            train: None,
            losses: Scratch::new(),
            steps,
            queries: Scratch::new(),
            inputs: Scratch::new(),
            outputs: Scratch::new(),
            samples: Scratch::new(),
            lanes: Scratch::new(),
            normals: Scratch::new(),
        })
    }

    /// The device context.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The model's entry points.
    pub fn entry_points(&self) -> ModelEntryPoints {
        self.entry
    }

    /// Number of parameters.
    pub fn param_count(&self) -> usize {
        self.param_count
    }

    /// Training steps taken (including those before upload).
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Largest batch whose buffers (`bytes_per_element` in the largest of
    /// them) fit the device's storage-buffer range.
    fn max_batch(&self, bytes_per_element: usize) -> usize {
        let limit = self.ctx.device_info().max_storage_buffer_range as usize;
        (limit / bytes_per_element.max(1)).max(1)
    }

    /// Raw network outputs (EMA weights) of every query into `out`
    /// (`queries.len() · raw_outputs` floats, query-major). Batches larger
    /// than the device's storage-buffer range are split.
    pub fn infer(
        &mut self,
        queries: &[QueryPoint],
        out: &mut [f32],
    ) -> Result<BatchReport, GpuError> {
        let r = self.entry.family.raw_outputs();
        check_raw_len(queries.len(), r, out.len())?;
        let per = self.max_batch((r * 4).max(size_of::<QueryPoint>()));
        let mut report = NO_WORK;
        let mut start = 0;
        while start < queries.len() {
            let end = (start + per).min(queries.len());
            let rep = self.infer_batch(&queries[start..end], &mut out[start * r..end * r])?;
            report = combine(report, rep);
            start = end;
        }
        Ok(report)
    }

    fn infer_batch(
        &mut self,
        queries: &[QueryPoint],
        out: &mut [f32],
    ) -> Result<BatchReport, GpuError> {
        let r = self.entry.family.raw_outputs();
        let Some(kernel) = self.kernels.infer.as_ref() else {
            return Err(self.missing_kernel(
                "has no raw outputs (its conditional network depends on the direction): use \
                 sample / pdf",
            ));
        };
        check_raw_len(queries.len(), r, out.len())?;
        if queries.is_empty() {
            return Ok(NO_WORK);
        }
        let n = count_u32(queries.len(), "queries")?;
        self.queries.put(&self.ctx, queries)?;
        self.outputs.at_least(&self.ctx, size_of_val(out) as u64)?;
        let batch = self.query_batch(kernel, self.outputs.get()?, n)?;
        let report = batch.submit_and_wait()?;
        self.outputs.get()?.download_into(out)?;
        Ok(report)
    }

    /// `out[i] = [ω, pdf]` sampled at `queries[i]` with `u[i] = [u₀, u₁, ·, ·]`.
    pub fn sample(
        &mut self,
        queries: &[QueryPoint],
        u: &[[f32; 4]],
        out: &mut [[f32; 4]],
    ) -> Result<BatchReport, GpuError> {
        self.per_query(QueryKernel::Sample, queries, u, out)
    }

    /// `out[i]` = density of `directions[i] = [x, y, z, ·]` at `queries[i]`.
    pub fn pdf(
        &mut self,
        queries: &[QueryPoint],
        directions: &[[f32; 4]],
        out: &mut [f32],
    ) -> Result<BatchReport, GpuError> {
        self.per_query(QueryKernel::Pdf, queries, directions, out)
    }

    /// One input and one output per query, through the `which` kernel.
    fn per_query<I: Pod, O: Pod>(
        &mut self,
        which: QueryKernel,
        queries: &[QueryPoint],
        input: &[I],
        out: &mut [O],
    ) -> Result<BatchReport, GpuError> {
        let (what, kernel) = match which {
            QueryKernel::Sample => ("sample", &self.kernels.sample),
            QueryKernel::Pdf => ("pdf", &self.kernels.pdf),
        };
        if input.len() != queries.len() || out.len() != queries.len() {
            return Err(GpuError::BadArgument(format!(
                "{what}: {} queries, {} inputs, {} outputs",
                queries.len(),
                input.len(),
                out.len()
            )));
        }
        Self::query_kernel(
            &self.ctx,
            kernel,
            [&self.model, &self.ema],
            (&mut self.queries, &mut self.inputs, &mut self.outputs),
            queries,
            input,
            out,
        )
    }

    /// A `(model, params, queries, input) → out` kernel over the batch,
    /// split where the buffers would exceed the storage-buffer range.
    fn query_kernel<I: Pod, O: Pod>(
        ctx: &GpuContext,
        kernel: &Kernel,
        state: [&GpuBuffer; 2],
        scratch: (&mut Scratch, &mut Scratch, &mut Scratch),
        queries: &[QueryPoint],
        input: &[I],
        out: &mut [O],
    ) -> Result<BatchReport, GpuError> {
        let limit = ctx.device_info().max_storage_buffer_range as usize;
        let widest = size_of::<QueryPoint>()
            .max(size_of::<I>())
            .max(size_of::<O>());
        let per = (limit / widest).max(1);
        let (sq, si, so) = scratch;
        let mut report = NO_WORK;
        let mut start = 0;
        while start < queries.len() {
            // One dispatch per piece.
            let end = (start + per).min(queries.len());
            let (q, i, o) = (
                &queries[start..end],
                &input[start..end],
                &mut out[start..end],
            );
            let n = count_u32(q.len(), "queries")?;
            sq.put(ctx, q)?;
            si.put(ctx, i)?;
            so.at_least(ctx, size_of_val(o) as u64)?;
            let mut batch = ctx.timed_batch()?;
            batch.dispatch(
                kernel,
                &[state[0], state[1], sq.get()?, si.get()?, so.get()?],
                push(&args_for(n)),
                n,
            )?;
            let rep = batch.submit_and_wait()?;
            so.get()?.download_into(o)?;
            report = combine(report, rep);
            start = end;
        }
        Ok(report)
    }

    /// Runs the gradient kernel on `samples` (one invocation per sample,
    /// atomic adds into the gradient buffer), then the block maxima; returns
    /// the per-sample losses' sum and the block maxima of the *unscaled* sum.
    fn accumulate(&mut self, samples: &[TrainingSample]) -> Result<(f64, Vec<f32>), GpuError> {
        if samples.is_empty() {
            return Err(GpuError::BadArgument(
                "training step without samples".into(),
            ));
        }
        let n = count_u32(samples.len(), "samples")?;
        let p = self.param_count;
        let pc = count_u32(p, "parameters")?;
        let blocks = p.div_ceil(MAX_ABS_BLOCK);
        if self.train.is_none() {
            self.train = Some(TrainBuffers {
                grad: self.ctx.buffer(p as u64 * 4)?,
                partial: self.ctx.buffer(blocks as u64 * 4)?,
            });
        }
        self.samples.put(&self.ctx, samples)?;
        self.losses.at_least(&self.ctx, u64::from(n) * 4)?;
        let t = self
            .train
            .as_ref()
            .ok_or_else(|| GpuError::BadArgument("training buffers missing".into()))?;
        let args = args_for(n);
        let k = &self.kernels;
        let mut batch: Batch<'_> = self.ctx.batch()?;
        batch.dispatch(
            &k.gradient,
            &[
                &self.model,
                &self.params,
                self.samples.get()?,
                &t.grad,
                self.losses.get()?,
            ],
            push(&args),
            n,
        )?;
        batch.barrier();
        let max_args = args_for(pc);
        batch.dispatch(
            &k.max_abs,
            &[&t.grad, &t.partial],
            push(&max_args),
            count_u32(blocks, "blocks")?,
        )?;
        batch.submit_and_wait()?;
        let mut losses = vec![0.0f32; samples.len()];
        self.losses.get()?.download_into(&mut losses)?;
        let partial: Vec<f32> = t.partial.download()?;
        let mut loss = 0.0f64;
        for l in &losses {
            loss += f64::from(*l);
        }
        Ok((loss, partial))
    }

    /// The gradient of the mean loss over `samples` and that mean loss, as
    /// the GPU computes it (for tests and diagnostics; nothing is updated).
    pub fn gradient(&mut self, samples: &[TrainingSample]) -> Result<(Vec<f32>, f64), GpuError> {
        let (loss, _) = self.accumulate(samples)?;
        let t = self
            .train
            .as_mut()
            .ok_or_else(|| GpuError::BadArgument("training buffers missing".into()))?;
        let mut g: Vec<f32> = t.grad.download()?;
        g.truncate(self.param_count);
        t.grad.upload(&vec![0.0f32; self.param_count])?;
        let inv = 1.0 / samples.len() as f32;
        for x in &mut g {
            *x *= inv;
        }
        Ok((g, loss / samples.len() as f64))
    }

    /// One training step on `samples` as Adam step `self.steps() + 1`
    /// ([`Self::train_step_at`]).
    pub fn train_step(
        &mut self,
        samples: &[TrainingSample],
        options: &TrainOptions,
    ) -> Result<StepOutcome, GpuError> {
        let step = u32::try_from(self.steps + 1).unwrap_or(u32::MAX);
        self.train_step_at(samples, step, options)
    }

    /// One training step on `samples`: per-sample gradients added on the
    /// device, then the decision every backend shares
    /// ([`guiding_core::optim::step_clip_factor`]: a skip if the sum or the
    /// loss is not finite, else the clip factor of the mean gradient), then
    /// Adam (bias correction of the 1-based `step`) and the EMA — the
    /// arithmetic of `Field`'s step, run by the kernels of
    /// `guiding_core::batch`. `element_skips` is not counted on the device
    /// (reported as 0).
    pub fn train_step_at(
        &mut self,
        samples: &[TrainingSample],
        step: u32,
        options: &TrainOptions,
    ) -> Result<StepOutcome, GpuError> {
        let (loss_sum, partial) = self.accumulate(samples)?;
        let n = samples.len() as f32;
        let loss = loss_sum / f64::from(n);
        let mut max = 0.0f32;
        let mut finite = loss.is_finite();
        for m in &partial {
            finite &= m.is_finite();
            max = max.max(*m);
        }
        let p = self.param_count;
        let pc = count_u32(p, "parameters")?;
        // The mean gradient's largest magnitude, and the clip factor on it.
        let Some(factor) = step_clip_factor(finite, max / n, options.max_gradient_magnitude) else {
            if let Some(t) = self.train.as_mut() {
                t.grad.upload(&vec![0.0f32; p])?;
            }
            return Ok(StepOutcome::Skipped);
        };
        let adam_args = AdamArgs {
            count: pc,
            pad: [0; 3],
            adam: options.adam,
            factors: AdamStepFactors::new(step, &options.adam),
            gradient_scale: factor / n,
            ema_alpha: ema_weight(options.ema_decay, step),
        };
        let t = self
            .train
            .as_ref()
            .ok_or_else(|| GpuError::BadArgument("training buffers missing".into()))?;
        self.ctx.run(
            &self.kernels.adam,
            &[&self.params, &t.grad, &self.adam_m, &self.adam_v, &self.ema],
            push(&adam_args),
            pc,
        )?;
        self.steps = u64::from(step);
        Ok(StepOutcome::Applied {
            loss,
            element_skips: 0,
            clipped: factor < 1.0,
        })
    }

    /// Raw network outputs (EMA weights) of every query into `raw`, which
    /// stays on the device (grown to fit; reused when large enough) for
    /// [`Self::sample_lanes`] / [`Self::pdf_lanes`]; for NASG also the
    /// learned selection probability of every query into `selection`
    /// (cleared first; left empty for NPM). One submission.
    ///
    /// # Errors
    /// DF (no raw outputs), a batch over the device's storage-buffer range,
    /// or a device failure.
    pub fn infer_resident(
        &mut self,
        queries: &[QueryPoint],
        raw: &mut Option<GpuBuffer>,
        selection: &mut Vec<f32>,
    ) -> Result<BatchReport, GpuError> {
        selection.clear();
        let r = self.entry.family.raw_outputs();
        let Some(kernel) = self.kernels.infer.as_ref() else {
            return Err(self.missing_kernel(
                "has no raw outputs (its conditional network depends on the direction)",
            ));
        };
        if queries.is_empty() {
            return Ok(NO_WORK);
        }
        let n = count_u32(queries.len(), "queries")?;
        // Over the storage-buffer range: `GpuError::BufferTooLarge` from the allocation.
        let out = &*grow(&self.ctx, raw, (queries.len() * r * 4) as u64)?;
        self.queries.put(&self.ctx, queries)?;
        if self.kernels.selection.is_some() {
            self.outputs.at_least(&self.ctx, u64::from(n) * 4)?;
        }
        let mut batch = self.query_batch(kernel, out, n)?;
        if let Some(sel) = self.kernels.selection.as_ref() {
            batch.barrier();
            batch.dispatch(sel, &[out, self.outputs.get()?], push(&args_for(n)), n)?;
        }
        let report = batch.submit_and_wait()?;
        if self.kernels.selection.is_some() {
            selection.resize(queries.len(), 0.0);
            self.outputs.get()?.download_into(selection)?;
        }
        Ok(report)
    }

    /// `out[i] = [ω, pdf]` sampled with `u[i] = [u₀, u₁, ·, ·]` from lane
    /// `lanes[i]` of the resident raw outputs `raw`
    /// ([`Self::infer_resident`]), times the clamped cosine of
    /// `normals[i].xyz` where `normals[i].w > 0` (NPM; NASG reads no
    /// normal). `normals` may be empty (no product).
    ///
    /// # Errors
    /// DF, lengths that differ, or a device failure.
    pub fn sample_lanes(
        &mut self,
        raw: &GpuBuffer,
        lanes: &[u32],
        normals: &[[f32; 4]],
        u: &[[f32; 4]],
        out: &mut [[f32; 4]],
    ) -> Result<BatchReport, GpuError> {
        self.lane_call(LaneKernel::Sample, raw, lanes, normals, u, out)
    }

    /// `out[i]` = density of `directions[i] = [x, y, z, ·]` under lane
    /// `lanes[i]` of `raw` (cosine product as [`Self::sample_lanes`]).
    ///
    /// # Errors
    /// As [`Self::sample_lanes`].
    pub fn pdf_lanes(
        &mut self,
        raw: &GpuBuffer,
        lanes: &[u32],
        normals: &[[f32; 4]],
        directions: &[[f32; 4]],
        out: &mut [f32],
    ) -> Result<BatchReport, GpuError> {
        self.lane_call(LaneKernel::Pdf, raw, lanes, normals, directions, out)
    }

    /// The DF vertex ([`guiding_core::model::df::DfVertex`]: base input and
    /// marginal, with the EMA weights) of every query into `vertices`, which
    /// stays on the device (grown to fit; reused when large enough) for
    /// [`Self::sample_vertex_lanes`] / [`Self::pdf_vertex_lanes`].
    ///
    /// # Errors
    /// A model without vertex kernels (NPM, NASG), a batch over the
    /// storage-buffer range, or a device failure.
    pub fn vertices_resident(
        &mut self,
        queries: &[QueryPoint],
        vertices: &mut Option<GpuBuffer>,
    ) -> Result<BatchReport, GpuError> {
        let Some(kernel) = self.kernels.vertex.as_ref() else {
            return Err(
                self.missing_kernel("has no vertex kernels (only DF has): use infer_resident")
            );
        };
        if queries.is_empty() {
            return Ok(NO_WORK);
        }
        let n = count_u32(queries.len(), "queries")?;
        // Over the storage-buffer range: `GpuError::BufferTooLarge` from the allocation.
        let out = &*grow(
            &self.ctx,
            vertices,
            (queries.len() * size_of::<DfVertex>()) as u64,
        )?;
        self.queries.put(&self.ctx, queries)?;
        self.query_batch(kernel, out, n)?.submit_and_wait()
    }

    /// The error that this model has no such kernel (`why`, after the
    /// model's prefix).
    fn missing_kernel(&self, why: &str) -> GpuError {
        GpuError::BadArgument(format!("{} {why}", self.entry.prefix))
    }

    /// A new batch with `kernel` dispatched over the `n` queries on the
    /// device: it reads the model, the EMA weights and the queries and
    /// writes `out`.
    fn query_batch<'a>(
        &'a self,
        kernel: &'a Kernel,
        out: &'a GpuBuffer,
        n: u32,
    ) -> Result<Batch<'a>, GpuError> {
        let mut batch = self.ctx.timed_batch()?;
        batch.dispatch(
            kernel,
            &[&self.model, &self.ema, self.queries.get()?, out],
            push(&args_for(n)),
            n,
        )?;
        Ok(batch)
    }

    /// `out[i] = [ω, pdf]` sampled with `u[i]` at the resident DF vertex
    /// `vertices[lanes[i]]` ([`Self::vertices_resident`]): the conditional
    /// network per lane.
    ///
    /// # Errors
    /// A model without vertex kernels, lengths that differ, or a device
    /// failure.
    pub fn sample_vertex_lanes(
        &mut self,
        vertices: &GpuBuffer,
        lanes: &[u32],
        u: &[[f32; 4]],
        out: &mut [[f32; 4]],
    ) -> Result<BatchReport, GpuError> {
        self.lane_call(LaneKernel::VertexSample, vertices, lanes, &[], u, out)
    }

    /// `out[i]` = density of `directions[i]` at the resident DF vertex
    /// `vertices[lanes[i]]`.
    ///
    /// # Errors
    /// As [`Self::sample_vertex_lanes`].
    pub fn pdf_vertex_lanes(
        &mut self,
        vertices: &GpuBuffer,
        lanes: &[u32],
        directions: &[[f32; 4]],
        out: &mut [f32],
    ) -> Result<BatchReport, GpuError> {
        self.lane_call(LaneKernel::VertexPdf, vertices, lanes, &[], directions, out)
    }

    /// One dispatch of a lane kernel on `resident` (raw outputs, or DF
    /// vertices after the model and its EMA weights).
    fn lane_call<O: Pod>(
        &mut self,
        which: LaneKernel,
        resident: &GpuBuffer,
        lanes: &[u32],
        normals: &[[f32; 4]],
        input: &[[f32; 4]],
        out: &mut [O],
    ) -> Result<BatchReport, GpuError> {
        let (what, kernel) = match which {
            LaneKernel::Sample => ("sample_lanes", self.kernels.lane_sample.as_ref()),
            LaneKernel::Pdf => ("pdf_lanes", self.kernels.lane_pdf.as_ref()),
            LaneKernel::VertexSample => {
                ("sample_vertex_lanes", self.kernels.vertex_sample.as_ref())
            }
            LaneKernel::VertexPdf => ("pdf_vertex_lanes", self.kernels.vertex_pdf.as_ref()),
        };
        let Some(kernel) = kernel else {
            return Err(GpuError::BadArgument(format!(
                "{what}: {} has no such kernel (raw-output lanes: NPM, NASG; vertex lanes: DF)",
                self.entry.prefix
            )));
        };
        if input.len() != lanes.len()
            || out.len() != lanes.len()
            || !(normals.is_empty() || normals.len() == lanes.len())
        {
            return Err(GpuError::BadArgument(format!(
                "{what}: {} lanes, {} normals, {} inputs, {} outputs",
                lanes.len(),
                normals.len(),
                input.len(),
                out.len()
            )));
        }
        if lanes.is_empty() {
            return Ok(NO_WORK);
        }
        let n = count_u32(lanes.len(), "lanes")?;
        // Over the storage-buffer range: `GpuError::BufferTooLarge` from the scratch buffers.
        self.lanes.put(&self.ctx, lanes)?;
        self.inputs.put(&self.ctx, input)?;
        self.outputs.at_least(&self.ctx, size_of_val(out) as u64)?;
        let vertex = matches!(which, LaneKernel::VertexSample | LaneKernel::VertexPdf);
        if !vertex {
            // No normals: zeros (w = 0, no product), so that a longer
            // buffer's earlier contents are never read as this call's.
            let zeros;
            let normals = if normals.is_empty() {
                zeros = vec![[0.0f32; 4]; lanes.len()];
                &zeros[..]
            } else {
                normals
            };
            self.normals.put(&self.ctx, normals)?;
        }
        let mut batch = self.ctx.timed_batch()?;
        let tail = [self.lanes.get()?, self.inputs.get()?, self.outputs.get()?];
        if vertex {
            batch.dispatch(
                kernel,
                &[&self.model, &self.ema, resident, tail[0], tail[1], tail[2]],
                push(&args_for(n)),
                n,
            )?;
        } else {
            let normals = self.normals.get()?;
            batch.dispatch(
                kernel,
                &[resident, tail[0], normals, tail[1], tail[2]],
                push(&args_for(n)),
                n,
            )?;
        }
        let report = batch.submit_and_wait()?;
        self.outputs.get()?.download_into(out)?;
        Ok(report)
    }

    /// The current parameters.
    pub fn params(&self) -> Result<Vec<f32>, GpuError> {
        self.params.download()
    }

    /// The current EMA weights (what queries use).
    pub fn ema(&self) -> Result<Vec<f32>, GpuError> {
        self.ema.download()
    }

    /// The current EMA weights into `out` (at most the parameter count).
    pub fn ema_into(&self, out: &mut [f32]) -> Result<(), GpuError> {
        self.ema.download_into(out)
    }

    /// The Adam moments `(m, v)`.
    pub fn adam_moments(&self) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        Ok((self.adam_m.download()?, self.adam_v.download()?))
    }
}
