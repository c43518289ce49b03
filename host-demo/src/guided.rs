//! Guided path tracing: the `guided` integrator.
//!
//! Runs the same per-bounce wavefront as [`crate::integrator`], with the guiding hook filled
//! in. Per bounce:
//!
//! 1. **intersect + emission** (shared with `pt`/`pt-nee`; emission MIS uses the path's
//!    combined directional density),
//! 2. **guide query** (`stage_guide_query`): for every vertex, the NEE light sample is drawn
//!    (pt-nee mode) and the continuation technique is chosen; *guidable* vertices (non-delta
//!    and not near-specular: diffuse always, rough conductors with `alpha ≥`
//!    [`GuidedOptions::min_alpha`]) pick the guide with probability `c` (else the BSDF). The
//!    guide distribution is decoded **once** per guidable vertex (one network pass for NPM /
//!    NASG); its selection probability, the guide sample and the guide pdfs of BSDF-picked
//!    and NEE directions all reuse it,
//! 3. **NEE** (`stage_guided_nee`): shadow rays with the power heuristic between the light
//!    pdf and the combined density `p(ω) = c·q(ω) + (1 − c)·p_bsdf(ω)`,
//! 4. **shadow** (shared),
//! 5. **continue** (`stage_guided_continue`): throughput `f·cos / p(ω)` with the same
//!    combined density (one-sample MIS of guide and BSDF), so every pass is unbiased whatever
//!    the state of the guide.
//!
//! # Training
//!
//! During the first `train_fraction` of the passes (one pass = one sample per pixel over the
//! whole image), every hit of every path is recorded (emission, MIS-weighted emission, NEE
//! contribution, continuation weight) and each guidable vertex that continued its path
//! becomes a [`TrainingSample`]. After the pass the radiance is propagated back along each
//! path in reverse order:
//!
//! ```text
//! R_k   = NEE_k + w_k ⊙ (Le_mis,k+1 + R_k+1)        (reflected radiance estimate at k)
//! L_i,k = Le_k+1 + R_k+1                             (training radiance of vertex k)
//! ```
//!
//! `w_k = f·cos/p` and `Le_mis` the MIS-weighted emission. The training radiance uses the
//! *unweighted* emission of the next hit: with NEE, `Le_mis,k+1` alone is only the BSDF-MIS
//! share of the direct light, while `Le_k+1 + R_k+1` is an unbiased estimate of the incident
//! radiance `L_i(x_k, ω_k)` (the light's NEE share belongs to vertex `k`, not to direction
//! `ω_k`). Directions that miss the scene give radiance 0 and are kept (DF's radiance cache
//! must learn zeros). The samples are handed to [`GuidingField::add_samples`] in block order
//! (deterministic), followed by one [`GuidingField::update`] (`steps_per_pass` Adam steps). After
//! the training passes, [`GuidingField::stop_training`] is called and nothing is recorded any more.
//! The training passes stay in the image (each is an unbiased estimate).
//!
//! Radiance-target guides are sampled directly (the learned incident-radiance distribution
//! instead of the product with the BSDF): still unbiased through the combined density, just
//! less efficient on glossy surfaces.

use crate::bsdf::Material;
use crate::emitter::EmitterSample;
use crate::gpu::GpuGuide;
use crate::integrator::{
    accumulate, finish_image, offset, shadow_ray, side_ok, Image, IntegratorKind, RenderOptions,
    Worker,
};
use crate::math::{power_heuristic, Frame};
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use guiding::{DirectionSample, DistributionBatch, GuidingField};
use guiding_core::model::QueryPoint;
use guiding_core::sample::TrainingSample;
use guiding_gpu::GpuError;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Options of the guided integrator (beyond [`RenderOptions`]).
#[derive(Clone, Copy, Debug)]
pub struct GuidedOptions {
    /// Next-event estimation on every emitter NEE can sample (pt-nee mode).
    pub nee: bool,
    /// Fraction of the passes (samples per pixel) used for training, in `[0, 1]`.
    pub train_fraction: f32,
    /// Guide-selection probability `c` for NPM / DF (NASG learns its own), in `[0, 1]`.
    pub selection_probability: f32,
    /// Rough conductors with a GGX alpha below this are not guided (near-specular).
    pub min_alpha: f32,
    /// Adam steps per training pass: this many passes over the pass's samples, capped at the
    /// configuration's `steps_per_update` ([`GuidingField::update_proportional`]).
    pub train_epochs: f32,
    /// Radiance-target vMF guides (NPM) are multiplied by the clamped cosine of the shading
    /// normal before sampling (Open PGL's `ApplyCosineProduct`).
    pub cosine_product: bool,
    /// Test hook, 1 in every real render: factor on the guide pdf inside the continuation's
    /// combined density (≠ 1 is a deliberate sample/pdf mismatch, a biased estimator; the
    /// power check of `tests/unbiased.rs` uses it).
    #[doc(hidden)]
    pub guide_pdf_scale: f32,
}

impl Default for GuidedOptions {
    fn default() -> Self {
        Self {
            nee: true,
            train_fraction: 0.3,
            selection_probability: 0.5,
            min_alpha: 0.05,
            cosine_product: true,
            train_epochs: 4.0,
            guide_pdf_scale: 1.0,
        }
    }
}

/// What a guided render did.
#[derive(Clone, Debug, Default)]
pub struct GuidedStats {
    /// NEE ran.
    pub nee: bool,
    /// The guide's description.
    pub model: String,
    /// Passes rendered in total / with training.
    pub passes: u32,
    /// Passes whose vertices were recorded and trained on.
    pub training_passes: u32,
    /// Passes the schedule gave to training (more than `training_passes` when the loss
    /// converged first).
    pub passes_planned_for_training: u32,
    /// Guide queries (selection + sample + pdf evaluations).
    pub guide_queries: u64,
    /// Guide queries during the training passes.
    pub guide_queries_training: u64,
    /// Guidable vertices (guide-or-BSDF decisions).
    pub guided_vertices: u64,
    /// Training samples recorded (all passes).
    pub samples_recorded: u64,
    /// Training samples recorded after the training passes (must be 0).
    pub samples_recorded_after_training: u64,
    /// Adam steps applied (total).
    pub training_steps: u64,
    /// Adam steps applied after training stopped (must be 0).
    pub training_steps_after_training: u64,
    /// Training samples the field rejected.
    pub rejected_samples: u64,
    /// Training samples dropped because the field's buffer was full.
    pub overflowed_samples: u64,
    /// Mean training loss of the last update (`NaN` if none).
    pub last_loss: f64,
    /// Mean training loss of every update, in order.
    pub loss_history: Vec<f64>,
    /// The first training pass skipped because the loss had converged (plateau), if any.
    pub converged_at_pass: Option<u32>,
    /// Wall time of the rendering passes (includes the guide queries).
    pub trace: Duration,
    /// Thread time spent in guide queries, summed over the render threads.
    pub query: Duration,
    /// Wall time of recording back-propagation + `add_samples` + `update`.
    pub training: Duration,
    /// Rays traced (closest-hit and shadow).
    pub rays: u64,
}

impl std::fmt::Display for GuidedStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "guide: {}", self.model)?;
        writeln!(
            f,
            "stages: NEE {}, guide queries {} ({} during training), guided vertices {}",
            if self.nee { "yes" } else { "no" },
            self.guide_queries,
            self.guide_queries_training,
            self.guided_vertices
        )?;
        writeln!(
            f,
            "training: {}/{} passes, {} steps ({} after training), {} samples recorded \
             ({} after training), {} rejected, {} overflowed, last loss {:.4}",
            self.training_passes,
            self.passes,
            self.training_steps,
            self.training_steps_after_training,
            self.samples_recorded,
            self.samples_recorded_after_training,
            self.rejected_samples,
            self.overflowed_samples,
            self.last_loss
        )?;
        if let Some(p) = self.converged_at_pass {
            writeln!(
                f,
                "skipped: training stopped at pass {p} (loss converged), {} training passes \
                 not recorded",
                self.passes_planned_for_training
                    .saturating_sub(self.training_passes)
            )?;
        }
        write!(
            f,
            "time: trace {:.3} s (wall; guide queries {:.3} thread-s of it), training {:.3} s",
            self.trace.as_secs_f64(),
            self.query.as_secs_f64(),
            self.training.as_secs_f64()
        )
    }
}

/// One hit of a recorded path.
#[derive(Clone, Copy)]
struct Node {
    /// Emitted radiance towards the previous vertex (unweighted).
    le_full: Vec3,
    /// The MIS-weighted emission that went into the image.
    le_mis: Vec3,
    /// NEE contribution (without the path throughput).
    nee: Vec3,
    /// Continuation weight `f·cos/p` (zero if the path ended here).
    weight: Vec3,
    /// Training record of the continuation (guidable vertices only), radiance still empty.
    sample: Option<TrainingSample>,
    /// Russian-roulette factor `1/q` applied at this vertex (1 without RR).
    rr: f32,
}

/// Per-render-thread state of the guided integrator.
pub(crate) struct GuidedWorker<'g> {
    guide: &'g GuidingField,
    /// `--device gpu`: the network runs there (raw outputs decoded here).
    gpu: Option<&'g GpuGuide>,
    /// The first GPU failure of this worker (the render stops after the pass).
    pub(crate) gpu_error: Option<GpuError>,
    /// Raw network outputs of the guidable vertices (GPU path).
    g_raw: Vec<f32>,
    gopts: GuidedOptions,
    record: bool,
    /// Per slot, the recorded hits of the current sample.
    chains: Vec<Vec<Node>>,
    /// Training samples of the current pass (this thread's blocks).
    pub(crate) train: Vec<TrainingSample>,
    pub(crate) queries: u64,
    pub(crate) guided_vertices: u64,
    pub(crate) query_time: Duration,
    // Per-vertex scratch of a bounce.
    v_query: Vec<u32>,
    v_dir: Vec<Vec3>,
    v_weight: Vec<Vec3>,
    v_pdf: Vec<f32>,
    v_qpdf: Vec<f32>,
    v_nee: Vec<Option<NeeCandidate>>,
    // Guidable vertices of a bounce.
    g_query: Vec<QueryPoint>,
    /// The guide's distributions at the guidable vertices, decoded by one batched call
    /// per bounce.
    g_batch: DistributionBatch,
    /// Shading normals of the guidable vertices (cosine product).
    g_normal: Vec<Vec3>,
    g_c: Vec<f32>,
    // Guide samples: guidable-vertex index, random numbers, vertex.
    s_query: Vec<u32>,
    s_u: Vec<Vec2>,
    s_vert: Vec<u32>,
    s_out: Vec<DirectionSample>,
    // Guide pdf evaluations; `p_vert` high bit set = the NEE direction of the vertex.
    p_query: Vec<u32>,
    p_dir: Vec<Vec3>,
    p_vert: Vec<u32>,
    p_out: Vec<f32>,
}

/// Light sample drawn for a vertex in the guide-query stage.
#[derive(Clone, Copy)]
struct NeeCandidate {
    f: Vec3,
    pdf_bsdf: f32,
    /// Guide pdf of `es.wo` (guidable vertices).
    qpdf: f32,
    es: EmitterSample,
}

const NONE: u32 = u32::MAX;
const NEE_BIT: u32 = 1 << 31;

impl<'g> GuidedWorker<'g> {
    pub(crate) fn new(
        guide: &'g GuidingField,
        gpu: Option<&'g GpuGuide>,
        gopts: GuidedOptions,
        record: bool,
    ) -> Self {
        Self {
            guide,
            gpu,
            gpu_error: None,
            g_raw: Vec::new(),
            gopts,
            record,
            chains: Vec::new(),
            train: Vec::new(),
            queries: 0,
            guided_vertices: 0,
            query_time: Duration::ZERO,
            v_query: Vec::new(),
            v_dir: Vec::new(),
            v_weight: Vec::new(),
            v_pdf: Vec::new(),
            v_qpdf: Vec::new(),
            v_nee: Vec::new(),
            g_query: Vec::new(),
            g_batch: DistributionBatch::new(),
            g_normal: Vec::new(),
            g_c: Vec::new(),
            s_query: Vec::new(),
            s_u: Vec::new(),
            s_vert: Vec::new(),
            s_out: Vec::new(),
            p_query: Vec::new(),
            p_dir: Vec::new(),
            p_vert: Vec::new(),
            p_out: Vec::new(),
        }
    }

    pub(crate) fn begin_sample(&mut self, count: usize) {
        if self.record {
            self.chains.resize_with(count, Vec::new);
            self.chains.truncate(count);
            self.chains.iter_mut().for_each(Vec::clear);
        }
    }

    pub(crate) fn record_hit(&mut self, slot: u32, le_full: Vec3, le_mis: Vec3) {
        if self.record {
            self.chains[slot as usize].push(Node {
                le_full,
                le_mis,
                nee: Vec3::ZERO,
                weight: Vec3::ZERO,
                sample: None,
                rr: 1.0,
            });
        }
    }

    pub(crate) fn record_rr(&mut self, slot: u32, inv_q: f32) {
        if self.record {
            if let Some(n) = self.chains[slot as usize].last_mut() {
                n.rr = inv_q;
            }
        }
    }

    pub(crate) fn record_nee(&mut self, slot: u32, local: Vec3) {
        if self.record {
            if let Some(n) = self.chains[slot as usize].last_mut() {
                n.nee += local;
            }
        }
    }

    fn record_continue(&mut self, slot: u32, weight: Vec3, sample: Option<TrainingSample>) {
        if self.record {
            if let Some(n) = self.chains[slot as usize].last_mut() {
                n.weight = weight;
                n.sample = sample;
            }
        }
    }

    /// Back-propagates the radiance of every recorded path (module docs) into `self.train`.
    pub(crate) fn end_sample(&mut self) {
        if !self.record {
            return;
        }
        for chain in &self.chains {
            // (Le_full + R, Le_mis + R) of the hit after the current one.
            let mut next = (Vec3::ZERO, Vec3::ZERO);
            for n in chain.iter().rev() {
                if let Some(mut s) = n.sample {
                    s.radiance = next.0.to_array();
                    self.train.push(s);
                }
                let r = (n.nee + n.weight * next.1) * n.rr;
                next = (n.le_full + r, n.le_mis + r);
            }
        }
    }
}

/// Guidable: diffuse always, rough conductors / plastics unless near-specular; never delta,
/// smooth-coated or dielectric vertices ([`Material::guidable`]).
fn guidable(m: &Material, min_alpha: f32) -> bool {
    m.guidable(min_alpha)
}

fn roughness(m: &Material) -> f32 {
    m.roughness()
}

/// Guide-query stage: NEE light samples, technique selection and the batched guide queries.
pub(crate) fn stage_guide_query(w: &mut Worker<'_>, nee: bool) {
    let scene = w.scene;
    let Some(g) = w.guided.as_mut() else {
        return;
    };
    let verts = &w.verts;
    let n = verts.len();
    g.v_query.clear();
    g.v_query.resize(n, NONE);
    g.g_query.clear();
    for i in 0..n {
        let mat = &verts.bsdf[i];
        if guidable(mat, g.gopts.min_alpha) {
            g.v_query[i] = g.g_query.len() as u32;
            g.g_query.push(QueryPoint {
                position: verts.p[i].to_array(),
                roughness: roughness(mat),
                normal: verts.ns[i].to_array(),
                pad0: 0.0,
                wo: verts.wi[i].to_array(),
                pad1: 0.0,
            });
        }
    }
    let nq = g.g_query.len();
    g.guided_vertices += nq as u64;
    // One batched decode per bounce (one network pass per guidable vertex): selection,
    // sampling and every pdf below reuse it (DF runs its conditional network per
    // direction, batched). With `--device gpu` the network runs there and its raw outputs
    // go through the same decoders; a device or decode failure ends the render.
    let t0 = Instant::now();
    let field = g.guide;
    match g.gpu {
        Some(gpu) if g.gpu_error.is_none() => {
            let decoded = gpu.infer(&g.g_query, &mut g.g_raw).and_then(|()| {
                field
                    .decode_raw_batch(&g.g_raw, &mut g.g_batch)
                    .map_err(|e| {
                        GpuError::BadArgument(format!("decoding the device's outputs: {e}"))
                    })
            });
            if let Err(e) = decoded {
                g.gpu_error = Some(e);
                g.g_batch = DistributionBatch::new();
            }
        }
        Some(_) => g.g_batch = DistributionBatch::new(),
        None => field.decode_batch(&g.g_query, &mut g.g_batch),
    }
    if g.gopts.cosine_product && field.config().target == guiding::Target::Radiance {
        g.g_normal.clear();
        g.g_normal
            .extend(g.g_query.iter().map(|q| Vec3::from_array(q.normal)));
        g.g_batch.apply_cosine_product(&g.g_normal);
    }
    g.g_c.clear();
    g.g_c
        .extend((0..nq).map(|i| g.g_batch.selection_probability(i)));
    g.queries += nq as u64;
    g.query_time += t0.elapsed();

    g.v_dir.clear();
    g.v_dir.resize(n, Vec3::ZERO);
    g.v_weight.clear();
    g.v_weight.resize(n, Vec3::ZERO);
    g.v_pdf.clear();
    g.v_pdf.resize(n, 0.0);
    g.v_qpdf.clear();
    g.v_qpdf.resize(n, 0.0);
    g.v_nee.clear();
    g.s_query.clear();
    g.s_u.clear();
    g.s_vert.clear();
    g.p_query.clear();
    g.p_dir.clear();
    g.p_vert.clear();
    for i in 0..n {
        let slot = verts.slot[i] as usize;
        let rng = &mut w.rng[slot];
        let frame = Frame::new(verts.ns[i]);
        let mat = &verts.bsdf[i];
        let wi_l = frame.to_local(verts.wi[i]);
        let qi = g.v_query[i];
        // NEE light sample (same draws as pt-nee).
        let mut cand = None;
        if nee && mat.nee_connectable() {
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            if let Some(es) = scene.sample_emitter(verts.p[i], u0, u1, u2) {
                let (f, pdf_bsdf) = mat.eval(wi_l, frame.to_local(es.wo));
                if f.max_element() > 0.0 {
                    cand = Some(NeeCandidate {
                        f,
                        pdf_bsdf,
                        qpdf: 0.0,
                        es,
                    });
                    if qi != NONE && !es.delta {
                        g.p_query.push(qi);
                        g.p_dir.push(es.wo);
                        g.p_vert.push(i as u32 | NEE_BIT);
                    }
                }
            }
        }
        g.v_nee.push(cand);
        // Continuation technique.
        let pick_guide = if qi != NONE {
            let c = g.g_c[qi as usize];
            rng.next_f32() < c
        } else {
            false
        };
        let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
        if pick_guide {
            g.s_query.push(qi);
            g.s_u.push(Vec2::new(u1, u2));
            g.s_vert.push(i as u32);
        } else if let Some(bs) = mat.sample(wi_l, u0, u1, u2) {
            let dir = frame.to_world(bs.wo).normalize();
            g.v_dir[i] = dir;
            g.v_weight[i] = bs.weight;
            g.v_pdf[i] = bs.pdf;
            if qi != NONE {
                g.p_query.push(qi);
                g.p_dir.push(dir);
                g.p_vert.push(i as u32);
            }
        }
    }
    // Guide samples and pdfs from the decoded distributions, one batched call each.
    let t0 = Instant::now();
    g.s_out.clear();
    g.s_out.resize(
        g.s_query.len(),
        DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0,
        },
    );
    if field
        .sample_decoded(&g.g_batch, &g.s_query, &g.s_u, &mut g.s_out)
        .is_err()
    {
        // Only a batch left empty by a device failure (the render ends after this pass).
        g.s_out.fill(DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0,
        });
    }
    for (ds, &i) in g.s_out.iter().zip(&g.s_vert) {
        if ds.direction.is_finite() && ds.pdf.is_finite() && ds.pdf > 0.0 {
            g.v_dir[i as usize] = ds.direction.normalize();
            g.v_qpdf[i as usize] = ds.pdf;
        }
    }
    g.p_out.clear();
    g.p_out.resize(g.p_query.len(), 0.0);
    if field
        .pdf_decoded(&g.g_batch, &g.p_query, &g.p_dir, &mut g.p_out)
        .is_err()
    {
        g.p_out.fill(0.0);
    }
    for (&p, &v) in g.p_out.iter().zip(&g.p_vert) {
        let q = if p.is_finite() { p.max(0.0) } else { 0.0 };
        if v & NEE_BIT != 0 {
            if let Some(c) = g.v_nee[(v & !NEE_BIT) as usize].as_mut() {
                c.qpdf = q;
            }
        } else {
            g.v_qpdf[v as usize] = q;
        }
    }
    g.queries += (g.s_query.len() + g.p_query.len()) as u64;
    g.query_time += t0.elapsed();
}

/// NEE stage of the guided integrator: MIS between the light pdf and the combined density.
pub(crate) fn stage_guided_nee(w: &mut Worker<'_>) {
    let Some(g) = w.guided.as_ref() else {
        return;
    };
    w.shadow.clear();
    for i in 0..w.verts.len() {
        let Some(c) = g.v_nee[i] else {
            continue;
        };
        let qi = g.v_query[i];
        let pdf_dir = if qi == NONE {
            c.pdf_bsdf
        } else {
            let sel = g.g_c[qi as usize];
            sel * c.qpdf + (1.0 - sel) * c.pdf_bsdf
        };
        let weight = if c.es.delta {
            1.0
        } else {
            power_heuristic(c.es.pdf, pdf_dir)
        };
        let local = c.f * c.es.radiance * (weight / c.es.pdf);
        let Some((o, d, tmax)) = shadow_ray(w.verts.p[i], w.verts.ng[i], &c.es) else {
            continue;
        };
        w.shadow.slot.push(w.verts.slot[i]);
        w.shadow.o.push(o);
        w.shadow.d.push(d);
        w.shadow.tmax.push(tmax);
        w.shadow.contrib.push(w.verts.beta[i] * local);
        w.shadow.local.push(local);
    }
}

/// Continuation stage: throughput `f·cos/p` with the combined density; training records.
pub(crate) fn stage_guided_continue(w: &mut Worker<'_>) {
    let Some(g) = w.guided.as_mut() else {
        return;
    };
    w.next.clear();
    for i in 0..w.verts.len() {
        let slot = w.verts.slot[i];
        let dir = g.v_dir[i];
        if dir == Vec3::ZERO {
            g.record_continue(slot, Vec3::ZERO, None);
            continue;
        }
        let (wi, ng, ns) = (w.verts.wi[i], w.verts.ng[i], w.verts.ns[i]);
        let qi = g.v_query[i];
        let mut sample = None;
        let (weight, pdf) = if qi == NONE {
            (g.v_weight[i], g.v_pdf[i])
        } else {
            let frame = Frame::new(ns);
            let mat = &w.verts.bsdf[i];
            let (f, pdf_bsdf) = mat.eval(frame.to_local(wi), frame.to_local(dir));
            let c = g.g_c[qi as usize];
            let pdf = c * g.v_qpdf[i] * g.gopts.guide_pdf_scale + (1.0 - c) * pdf_bsdf;
            if !(pdf > 0.0 && pdf.is_finite()) || f.max_element() <= 0.0 {
                g.record_continue(slot, Vec3::ZERO, None);
                continue;
            }
            if g.record {
                let q = &g.g_query[qi as usize];
                sample = Some(TrainingSample {
                    position: q.position,
                    roughness: q.roughness,
                    normal: q.normal,
                    sample_pdf: pdf,
                    wo: q.wo,
                    bsdf_pdf: pdf_bsdf,
                    wi: dir.to_array(),
                    pad0: 0.0,
                    radiance: [0.0; 3],
                    pad1: 0.0,
                    bsdf_cos: f.to_array(),
                    pad2: 0.0,
                });
            }
            (f / pdf, pdf)
        };
        let beta = w.verts.beta[i] * weight;
        if beta.max_element() <= 0.0 || !beta.is_finite() || !side_ok(wi, dir, ng, ns) {
            g.record_continue(slot, Vec3::ZERO, None);
            continue;
        }
        g.record_continue(slot, weight, sample);
        let o = offset(w.verts.p[i], ng, dir);
        w.next.push(slot, o, dir, beta, pdf, false);
    }
}

/// Renders `scene` with guided path tracing, training `guide` online during the first
/// `gopts.train_fraction` of the passes. `opts.integrator` is ignored (NEE follows
/// `gopts.nee`).
pub fn render_guided(
    scene: &Scene,
    opts: &RenderOptions,
    gopts: &GuidedOptions,
    guide: &mut GuidingField,
) -> (Image, GuidedStats) {
    let (img, stats, _) = render_guided_on(scene, opts, gopts, guide, None);
    (img, stats)
}

/// [`render_guided`] with the guide's network inference and training on a
/// Vulkan device (`--device gpu`; see [`crate::gpu`]). `guide` supplies the
/// configuration and the decoding; its own weights are not trained.
///
/// # Errors
/// The first GPU failure; the render stops after the pass it happened in.
pub fn render_guided_gpu(
    scene: &Scene,
    opts: &RenderOptions,
    gopts: &GuidedOptions,
    guide: &mut GuidingField,
    gpu: &mut GpuGuide,
) -> Result<(Image, GuidedStats), GpuError> {
    match render_guided_on(scene, opts, gopts, guide, Some(gpu)) {
        (img, stats, None) => Ok((img, stats)),
        (_, _, Some(e)) => Err(e),
    }
}

fn render_guided_on(
    scene: &Scene,
    opts: &RenderOptions,
    gopts: &GuidedOptions,
    guide: &mut GuidingField,
    mut gpu: Option<&mut GpuGuide>,
) -> (Image, GuidedStats, Option<GpuError>) {
    let mut opts = *opts;
    opts.integrator = if gopts.nee {
        IntegratorKind::PtNee
    } else {
        IntegratorKind::Pt
    };
    let (width, height) = opts.resolution(scene);
    let npix = width as usize * height as usize;
    let threads = opts.thread_count();
    let block = npix.div_ceil(threads * 8).clamp(64, 4096);
    let nblocks = npix.div_ceil(block);
    let mut stats = GuidedStats {
        nee: gopts.nee && scene.has_samplable_emitter(),
        model: match &gpu {
            Some(d) => format!("{} on {}", crate::guide::describe(guide), d.device()),
            None => crate::guide::describe(guide),
        },
        last_loss: f64::NAN,
        ..Default::default()
    };
    let mut sum = vec![[0.0f64; 3]; npix];
    let mut sum2 = vec![[0.0f64; 3]; npix];
    let mut sched = crate::schedule::Schedule::new(&opts, gopts.train_fraction);
    let mut stopped = false;
    while let Some(pass) = sched.next_pass() {
        // Training ends early when the loss has converged (plateau): the remaining training
        // passes render without recording.
        let converged = gpu.is_none() && guide.is_converged();
        if pass.train && converged && stats.converged_at_pass.is_none() {
            stats.converged_at_pass = Some(pass.index);
        }
        let (s, record) = (pass.index, pass.train && !converged);
        if !record && !stopped {
            guide.stop_training();
            if let Some(d) = gpu.as_deref_mut() {
                d.stop_training();
            }
            stopped = true;
        }
        stats.training_passes += u32::from(record);
        stats.passes_planned_for_training += u32::from(pass.train);
        let t_pass = Instant::now();
        let next = AtomicUsize::new(0);
        // Per block: radiance of this pass and its training samples (kept in block order).
        let results: Mutex<Vec<Option<BlockResult>>> =
            Mutex::new((0..nblocks).map(|_| None).collect());
        let counters = Mutex::new((0u64, 0u64, Duration::ZERO, 0u64));
        let guide_ref: &GuidingField = guide;
        let gpu_ref: Option<&GpuGuide> = gpu.as_deref();
        let gpu_error: Mutex<Option<GpuError>> = Mutex::new(None);
        std::thread::scope(|sc| {
            for _ in 0..threads.min(nblocks) {
                sc.spawn(|| {
                    let gw = GuidedWorker::new(guide_ref, gpu_ref, *gopts, record);
                    let mut w = Worker::new(scene, opts, Some(gw));
                    loop {
                        let b = next.fetch_add(1, Ordering::Relaxed);
                        if b >= nblocks {
                            break;
                        }
                        let start = b * block;
                        let count = block.min(npix - start);
                        w.trace_sample(start, count, width, height, s);
                        let train = w
                            .guided
                            .as_mut()
                            .map(|g| std::mem::take(&mut g.train))
                            .unwrap_or_default();
                        let rad = std::mem::take(&mut w.radiance);
                        let mut r = results.lock().unwrap_or_else(|e| e.into_inner());
                        r[b] = Some((rad, train));
                    }
                    if let Some(e) = w.guided.as_mut().and_then(|g| g.gpu_error.take()) {
                        gpu_error
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .get_or_insert(e);
                    }
                    if let Some(g) = &w.guided {
                        let mut c = counters.lock().unwrap_or_else(|e| e.into_inner());
                        c.0 += g.queries;
                        c.1 += g.guided_vertices;
                        c.2 += g.query_time;
                    }
                    counters.lock().unwrap_or_else(|e| e.into_inner()).3 += w.rays;
                });
            }
        });
        if let Some(e) = gpu_error.into_inner().unwrap_or_else(|e| e.into_inner()) {
            return (
                finish_image(width, height, pass.index + 1, &sum, &sum2),
                stats,
                Some(e),
            );
        }
        let (q, gv, qt, rays) = counters.into_inner().unwrap_or_else(|e| e.into_inner());
        stats.rays += rays;
        stats.guide_queries += q;
        if record {
            stats.guide_queries_training += q;
        }
        stats.guided_vertices += gv;
        stats.query += qt;
        stats.trace += t_pass.elapsed();
        let t_train = Instant::now();
        let results = results.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut train = Vec::new();
        for (b, r) in results.into_iter().enumerate() {
            let Some((rad, t)) = r else {
                continue;
            };
            let start = b * block;
            accumulate(&mut sum[start..], &mut sum2[start..], &rad);
            train.extend(t);
        }
        stats.samples_recorded += train.len() as u64;
        if !record {
            stats.samples_recorded_after_training += train.len() as u64;
        }
        if !train.is_empty() {
            if let Some(d) = gpu.as_deref_mut() {
                let steps_before = d.steps();
                match d.update(&train) {
                    Ok(rep) => {
                        if rep.steps > 0 {
                            stats.last_loss = rep.mean_loss;
                        }
                    }
                    Err(e) => {
                        return (
                            finish_image(width, height, pass.index + 1, &sum, &sum2),
                            stats,
                            Some(e),
                        )
                    }
                }
                if !record {
                    stats.training_steps_after_training += d.steps() - steps_before;
                }
            } else {
                let steps_before = guide.stats().steps;
                guide.add_samples(&train);
                // Adam steps proportional to the samples of this pass (capped).
                let rep = guide.update_proportional(gopts.train_epochs);
                if rep.steps > 0 {
                    stats.last_loss = rep.mean_loss;
                    stats.loss_history.push(rep.mean_loss);
                }
                if !record {
                    stats.training_steps_after_training += guide.stats().steps - steps_before;
                }
            }
            stats.training += t_train.elapsed();
        }
    }
    if !stopped {
        guide.stop_training();
    }
    stats.passes = sched.passes();
    sched.finish();
    let fs = guide.stats();
    stats.training_steps = match &gpu {
        Some(d) => d.steps(),
        None => fs.steps,
    };
    stats.rejected_samples = fs.rejected_samples.iter().sum();
    stats.overflowed_samples = fs.overflowed_samples;
    (
        finish_image(width, height, stats.passes, &sum, &sum2),
        stats,
        None,
    )
}

/// One block's pass: per-pixel radiance and the block's training samples.
type BlockResult = (Vec<Vec3>, Vec<TrainingSample>);
