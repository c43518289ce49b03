//! Wavefront path tracer.
//!
//! Rendering is pass-major (one sample per pixel over the whole image per pass, see
//! [`crate::render::schedule`]); within a pass each worker thread takes blocks of pixels and runs the
//! block's paths through a per-bounce pipeline of structure-of-arrays queues:
//!
//! 1. **intersect** the path queue (closest hit),
//! 2. **emission**: add emitted radiance at the hits (MIS-weighted for `pt-nee`) and compact
//!    the surviving hits into a [`VertexBatch`],
//! 3. **guiding query**: [`guiding_query`] receives the whole batch (the plug-in point for the
//!    batched path-guiding model; a no-op today),
//! 4. **NEE** (`pt-nee`, skipped when the scene has no emitter NEE can sample, and at delta
//!    vertices): sample one emitter (area, point or environment, picked uniformly) and emit a
//!    `ShadowQueue`,
//! 5. **shadow**: trace the shadow queue and add the unoccluded contributions,
//! 6. **BSDF sampling**: continue the paths into the next bounce's queue.
//!
//! Depth follows Mitsuba: `max_depth = 1` only shows directly visible emission; a hit at
//! bounce `b` (0 = camera hit) adds emission when `b < max_depth` and does NEE/continues when
//! `b + 1 < max_depth`. No Russian roulette by default (keeps variance comparable; the estimator
//! is unbiased either way); `--rr` enables Mitsuba's Russian roulette from the scene's `rr_depth`.
//!
//! Rays that leave the scene pick up the environment (MIS-weighted against environment NEE);
//! `twosided` materials are resolved per hit (a back hit flips the frame), and the
//! geometric side test lets transmission through dielectrics cross the surface.

use crate::math::{power_heuristic, Frame, Rng};
use crate::scene::bsdf::Material;
use crate::scene::emitter::EmitterSample;
use crate::scene::Scene;
use glam::Vec3;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Which estimator to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntegratorKind {
    /// BSDF sampling only; emission is picked up when a path hits a light.
    Pt,
    /// Next-event estimation (area, point and environment emitters) + BSDF sampling, combined
    /// with the power heuristic.
    PtNee,
}

/// Render parameters.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    /// Estimator.
    pub integrator: IntegratorKind,
    /// Samples per pixel (passes) when `time_budget` is `None`.
    pub spp: u32,
    /// Render passes until this much wall time is used instead of a fixed spp
    /// (see [`crate::render::schedule`]).
    pub time_budget: Option<std::time::Duration>,
    /// Russian roulette from the scene's `rr_depth` on (Mitsuba's rule: survival probability
    /// `min(max(throughput), 0.95)`). Off by default; unbiased either way.
    pub rr: bool,
    /// Show a progress bar on stderr (only when stderr is a terminal).
    pub progress: bool,
    /// Mitsuba max_depth.
    pub max_depth: u32,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Random seed.
    pub seed: u64,
    /// Override the image width/height (0 = scene's).
    pub width: u32,
    /// Override the image height (0 = scene's).
    pub height: u32,
}

impl Default for RenderOptions {
    /// `pt-nee`, 16 spp, depth 8, all cores, seed 0, the scene's image size, no RR, no bar.
    fn default() -> Self {
        Self {
            integrator: IntegratorKind::PtNee,
            spp: 16,
            time_budget: None,
            rr: false,
            progress: false,
            max_depth: 8,
            threads: 0,
            seed: 0,
            width: 0,
            height: 0,
        }
    }
}

impl RenderOptions {
    /// Image size: the override, else the scene's.
    pub fn resolution(&self, scene: &Scene) -> (u32, u32) {
        let w = if self.width > 0 {
            self.width
        } else {
            scene.settings.width
        };
        let h = if self.height > 0 {
            self.height
        } else {
            scene.settings.height
        };
        (w, h)
    }

    /// Worker threads (`0` = all cores).
    pub fn thread_count(&self) -> usize {
        if self.threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            self.threads
        }
    }
}

/// What an unguided render did (the guided integrator reports [`crate::render::strategy::guided::GuidedStats`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    /// Passes (samples per pixel) rendered.
    pub passes: u32,
    /// Wall time of the passes.
    pub wall: std::time::Duration,
    /// Rays traced: camera and continuation rays plus shadow rays.
    pub rays: u64,
    /// The NEE stage ran (`pt-nee` on a scene with an emitter NEE can sample).
    pub nee: bool,
}

/// A rendered image plus per-pixel variance information for statistical tests.
#[derive(Clone, Debug)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel estimates (mean over samples), row-major.
    pub pixels: Vec<[f32; 3]>,
    /// Estimated variance of each pixel estimate (sample variance / spp), row-major.
    pub var_of_mean: Vec<[f32; 3]>,
}

impl Image {
    /// Mean RGB over all pixels.
    pub fn mean(&self) -> [f64; 3] {
        let mut m = [0.0f64; 3];
        for p in &self.pixels {
            for c in 0..3 {
                m[c] += p[c] as f64;
            }
        }
        m.map(|v| v / self.pixels.len().max(1) as f64)
    }

    /// Standard error of [`Image::mean`], from the per-pixel sample variances (pixels are
    /// independent, so `Var(mean) = sum_p Var(pixel_p) / P^2`).
    pub fn mean_std_error(&self) -> [f64; 3] {
        let mut v = [0.0f64; 3];
        for p in &self.var_of_mean {
            for c in 0..3 {
                v[c] += p[c] as f64;
            }
        }
        let n = self.var_of_mean.len().max(1) as f64;
        v.map(|x| x.sqrt() / n)
    }

    /// True if every pixel value is finite and non-negative.
    pub fn all_finite(&self) -> bool {
        self.pixels
            .iter()
            .all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0))
    }
}

/// Surviving path vertices of one bounce, structure-of-arrays. This is the unit of work a
/// batched guiding query (or a GPU kernel) operates on.
#[derive(Default, Debug)]
pub struct VertexBatch {
    /// Path slot (pixel within the block).
    pub slot: Vec<u32>,
    /// Hit position.
    pub p: Vec<Vec3>,
    /// Geometric normal.
    pub ng: Vec<Vec3>,
    /// Shading normal.
    pub ns: Vec<Vec3>,
    /// Direction towards the previous vertex (world space, unit).
    pub wi: Vec<Vec3>,
    /// Path throughput up to this vertex.
    pub beta: Vec<Vec3>,
    /// Material index (after `twosided` / `blendbsdf` resolution).
    pub material: Vec<u32>,
    /// The material with its textures evaluated at the hit (what NEE and sampling use).
    pub bsdf: Vec<Material>,
}

impl VertexBatch {
    pub(crate) fn clear(&mut self) {
        self.slot.clear();
        self.p.clear();
        self.ng.clear();
        self.ns.clear();
        self.wi.clear();
        self.beta.clear();
        self.material.clear();
        self.bsdf.clear();
    }
    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.slot.len()
    }
    /// True if empty.
    pub fn is_empty(&self) -> bool {
        self.slot.is_empty()
    }
}

/// Hook for the batched guiding query: receives every vertex of a bounce before any
/// sampling decision is made there.
///
/// GUIDING PLUG-IN POINT: a guiding model will evaluate its (batched) directional distribution
/// for all `batch.p` / `batch.ns` / `batch.wi` here and return per-vertex mixture parameters that
/// the BSDF-sampling stage then mixes with BSDF sampling (one-sample MIS). Today it does nothing.
pub fn guiding_query(batch: &VertexBatch) {
    let _ = batch;
}

/// Paths in flight (structure-of-arrays).
#[derive(Default)]
pub(crate) struct PathQueue {
    pub(crate) slot: Vec<u32>,
    pub(crate) o: Vec<Vec3>,
    pub(crate) d: Vec<Vec3>,
    pub(crate) beta: Vec<Vec3>,
    /// Solid-angle pdf of the direction `d` (for MIS at an emitter hit).
    pub(crate) pdf: Vec<f32>,
    /// `d` came from the camera (no MIS).
    pub(crate) from_camera: Vec<bool>,
}

impl PathQueue {
    pub(crate) fn clear(&mut self) {
        self.slot.clear();
        self.o.clear();
        self.d.clear();
        self.beta.clear();
        self.pdf.clear();
        self.from_camera.clear();
    }
    pub(crate) fn push(
        &mut self,
        slot: u32,
        o: Vec3,
        d: Vec3,
        beta: Vec3,
        pdf: f32,
        from_camera: bool,
    ) {
        self.slot.push(slot);
        self.o.push(o);
        self.d.push(d);
        self.beta.push(beta);
        self.pdf.push(pdf);
        self.from_camera.push(from_camera);
    }
}

/// Shadow rays of the NEE stage.
#[derive(Default)]
pub(crate) struct ShadowQueue {
    pub(crate) slot: Vec<u32>,
    pub(crate) o: Vec<Vec3>,
    pub(crate) d: Vec<Vec3>,
    pub(crate) tmax: Vec<f32>,
    pub(crate) contrib: Vec<Vec3>,
    /// `contrib` without the path throughput (training records only).
    pub(crate) local: Vec<Vec3>,
}

impl ShadowQueue {
    pub(crate) fn clear(&mut self) {
        self.slot.clear();
        self.o.clear();
        self.d.clear();
        self.tmax.clear();
        self.contrib.clear();
        self.local.clear();
    }
}

/// Offsets `p` along the geometric normal to the side of `dir`, against self-intersection.
#[inline]
pub(crate) fn offset(p: Vec3, ng: Vec3, dir: Vec3) -> Vec3 {
    let eps = 1e-4 * (1.0 + p.abs().max_element());
    if ng.dot(dir) >= 0.0 {
        p + ng * eps
    } else {
        p - ng * eps
    }
}

/// Geometric-normal side test of a scattering event: a reflection (with respect to the
/// shading normal) must stay on the geometric side it came from, a transmission must cross
/// it. Rejects the light leaks of interpolated shading normals.
#[inline]
pub(crate) fn side_ok(wi: Vec3, wo: Vec3, ng: Vec3, ns: Vec3) -> bool {
    let shading_reflect = wi.dot(ns) * wo.dot(ns) > 0.0;
    let (gi, go) = (wi.dot(ng), wo.dot(ng));
    go != 0.0 && (gi * go > 0.0) == shading_reflect
}

/// Shadow ray `(origin, unit direction, tmax)` from the vertex at `p` (geometric normal `ng`)
/// to an emitter sample; unbounded for the environment, stopping just short of area and point
/// lights. `None` if degenerate.
pub(crate) fn shadow_ray(p: Vec3, ng: Vec3, es: &EmitterSample) -> Option<(Vec3, Vec3, f32)> {
    let o = offset(p, ng, es.wo);
    if es.dist.is_infinite() {
        return Some((o, es.wo, f32::INFINITY));
    }
    let target = if es.n == Vec3::ZERO {
        es.p
    } else {
        offset(es.p, es.n, -es.wo)
    };
    let seg = target - o;
    let len = seg.length();
    (len > 0.0 && len.is_finite()).then(|| (o, seg / len, len * (1.0 - 1e-4)))
}

/// Per-block worker state (queues are reused across bounces and samples).
pub(crate) struct Worker<'s> {
    pub(crate) scene: &'s Scene,
    pub(crate) opts: RenderOptions,
    /// NEE runs: `pt-nee` and the scene has an emitter NEE can sample.
    pub(crate) nee: bool,
    pub(crate) paths: PathQueue,
    pub(crate) next: PathQueue,
    pub(crate) verts: VertexBatch,
    pub(crate) shadow: ShadowQueue,
    /// One RNG per slot; path slots are stable for the whole sample.
    pub(crate) rng: Vec<Rng>,
    /// Radiance of the current sample per slot.
    pub(crate) radiance: Vec<Vec3>,
    /// Rays traced by this worker (closest-hit and shadow).
    pub(crate) rays: u64,
    /// Guided-integrator state (`None` for `pt` / `pt-nee`).
    pub(crate) guided: Option<crate::render::strategy::guided::GuidedWorker<'s>>,
}

impl<'s> Worker<'s> {
    /// A worker for `scene` with empty queues.
    pub(crate) fn new(
        scene: &'s Scene,
        opts: RenderOptions,
        guided: Option<crate::render::strategy::guided::GuidedWorker<'s>>,
    ) -> Self {
        Worker {
            scene,
            opts,
            nee: opts.integrator == IntegratorKind::PtNee && scene.has_samplable_emitter(),
            paths: PathQueue::default(),
            next: PathQueue::default(),
            verts: VertexBatch::default(),
            shadow: ShadowQueue::default(),
            rng: Vec::new(),
            radiance: Vec::new(),
            rays: 0,
            guided,
        }
    }

    /// Traces sample `s` of pixels `[start, start + count)` into `self.radiance`.
    pub(crate) fn trace_sample(
        &mut self,
        start: usize,
        count: usize,
        width: u32,
        height: u32,
        s: u32,
    ) {
        let max_depth = self.opts.max_depth;
        self.paths.clear();
        self.rng.clear();
        self.radiance.clear();
        self.radiance.resize(count, Vec3::ZERO);
        if let Some(g) = &mut self.guided {
            g.begin_sample(count);
        }
        for i in 0..count {
            let pix = start + i;
            let (x, y) = ((pix % width as usize) as f32, (pix / width as usize) as f32);
            let mut rng = Rng::new(self.opts.seed, pix as u64, s as u64);
            let (u, v) = (
                (x + rng.next_f32()) / width as f32,
                (y + rng.next_f32()) / height as f32,
            );
            let cam = &self.scene.camera;
            let (o, d) = if cam.has_lens() {
                cam.ray_lens(u, v, rng.next_f32(), rng.next_f32())
            } else {
                cam.ray(u, v)
            };
            self.rng.push(rng);
            self.paths.push(i as u32, o, d, Vec3::ONE, 0.0, true);
        }
        let nee = self.nee;
        let mut bounce = 0u32;
        while !self.paths.slot.is_empty() && bounce < max_depth {
            self.stage_intersect_and_emission(bounce);
            if self.guided.is_some() {
                // Guided: the batched guide query replaces the no-op hook and makes every
                // sampling decision of the bounce (light samples, guide/BSDF selection).
                crate::render::strategy::guided::stage_guide_query(self, nee);
                if nee {
                    crate::render::strategy::guided::stage_guided_nee(self);
                    self.stage_shadow();
                }
                crate::render::strategy::guided::stage_guided_continue(self);
            } else {
                guiding_query(&self.verts);
                if nee {
                    self.stage_nee();
                    self.stage_shadow();
                }
                self.stage_bsdf_sample();
            }
            std::mem::swap(&mut self.paths, &mut self.next);
            bounce += 1;
        }
        if let Some(g) = &mut self.guided {
            g.end_sample();
        }
    }

    /// Stages 1 and 2: closest hit, emission (with MIS), compaction into the vertex batch.
    pub(crate) fn stage_intersect_and_emission(&mut self, bounce: u32) {
        let scene = self.scene;
        self.verts.clear();
        let continue_path = bounce + 1 < self.opts.max_depth;
        let rr = self.opts.rr && bounce + 1 >= scene.settings.rr_depth;
        self.rays += self.paths.slot.len() as u64;
        for i in 0..self.paths.slot.len() {
            let (o, d) = (self.paths.o[i], self.paths.d[i]);
            let Some(hit) = scene.intersect(o, d, 0.0, f32::INFINITY) else {
                if scene.env.is_some() {
                    // The path leaves the scene: environment emission, MIS-weighted against
                    // NEE's environment sampling.
                    let le = scene.env_radiance(d);
                    let w = if self.paths.from_camera[i]
                        || !self.nee
                        || self.paths.pdf[i].is_infinite()
                    {
                        1.0
                    } else {
                        power_heuristic(self.paths.pdf[i], scene.env_pdf(d))
                    };
                    let slot = self.paths.slot[i];
                    self.radiance[slot as usize] += self.paths.beta[i] * le * w;
                    if let Some(g) = &mut self.guided {
                        g.record_hit(slot, le, le * w);
                    }
                }
                continue;
            };
            let slot = self.paths.slot[i];
            let mut beta = self.paths.beta[i];
            let shape = &scene.shapes[hit.shape as usize];
            let (mut le_full, mut le_mis) = (Vec3::ZERO, Vec3::ZERO);
            if let Some(le) = shape.emission {
                let cos_l = hit.ns.dot(-d);
                if cos_l > 0.0 {
                    let w = if self.paths.from_camera[i] || !self.nee {
                        1.0
                    } else {
                        let pdf_light = scene.light_pdf_area(hit.shape) * hit.t * hit.t / cos_l;
                        power_heuristic(self.paths.pdf[i], pdf_light)
                    };
                    self.radiance[slot as usize] += beta * le * w;
                    (le_full, le_mis) = (le, le * w);
                }
            }
            if let Some(g) = &mut self.guided {
                g.record_hit(slot, le_full, le_mis);
            }
            if !continue_path {
                continue;
            }
            let (mat_id, mat, ng, ns) = scene.resolve_material(
                shape.material,
                hit.ng,
                hit.ns,
                d,
                hit.uv,
                &mut self.rng[slot as usize],
            );
            if mat.is_black() || (mat.one_sided() && ns.dot(-d) <= 0.0) {
                continue; // absorbed, or the back of a one-sided BSDF
            }
            if rr {
                // Russian roulette (Mitsuba: q = min(max(throughput), 0.95)); the survivors'
                // throughput is divided by q, which keeps the estimator unbiased.
                let q = beta.max_element().min(0.95);
                if q.is_nan() || q <= 0.0 || self.rng[slot as usize].next_f32() >= q {
                    continue;
                }
                beta /= q;
                if let Some(g) = &mut self.guided {
                    g.record_rr(slot, 1.0 / q);
                }
            }
            self.verts.slot.push(slot);
            self.verts.p.push(hit.p);
            self.verts.ng.push(ng);
            self.verts.ns.push(ns);
            self.verts.wi.push(-d);
            self.verts.beta.push(beta);
            self.verts.material.push(mat_id);
            self.verts.bsdf.push(mat);
        }
    }

    /// Stage 4: next-event estimation, producing shadow rays.
    fn stage_nee(&mut self) {
        let scene = self.scene;
        self.shadow.clear();
        for i in 0..self.verts.len() {
            let slot = self.verts.slot[i];
            if !self.verts.bsdf[i].nee_connectable() {
                continue; // delta BSDF: no light connection
            }
            let rng = &mut self.rng[slot as usize];
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            let p = self.verts.p[i];
            let Some(es) = scene.sample_emitter(p, u0, u1, u2) else {
                continue;
            };
            let frame = Frame::new(self.verts.ns[i]);
            let mat: &Material = &self.verts.bsdf[i];
            let (f, pdf_bsdf) = mat.eval(frame.to_local(self.verts.wi[i]), frame.to_local(es.wo));
            if f.max_element() <= 0.0 {
                continue;
            }
            let w = if es.delta {
                1.0
            } else {
                power_heuristic(es.pdf, pdf_bsdf)
            };
            let contrib = self.verts.beta[i] * f * es.radiance * (w / es.pdf);
            let Some((o, d, tmax)) = shadow_ray(p, self.verts.ng[i], &es) else {
                continue;
            };
            self.shadow.slot.push(slot);
            self.shadow.o.push(o);
            self.shadow.d.push(d);
            self.shadow.tmax.push(tmax);
            self.shadow.contrib.push(contrib);
        }
    }

    /// Stage 5: trace shadow rays and accumulate unoccluded light.
    pub(crate) fn stage_shadow(&mut self) {
        self.rays += self.shadow.slot.len() as u64;
        for i in 0..self.shadow.slot.len() {
            if !self
                .scene
                .occluded(self.shadow.o[i], self.shadow.d[i], 0.0, self.shadow.tmax[i])
            {
                let slot = self.shadow.slot[i];
                self.radiance[slot as usize] += self.shadow.contrib[i];
                if let Some(g) = &mut self.guided {
                    g.record_nee(slot, self.shadow.local[i]);
                }
            }
        }
    }

    /// Stage 6: BSDF sampling into the next bounce's queue.
    fn stage_bsdf_sample(&mut self) {
        self.next.clear();
        for i in 0..self.verts.len() {
            let slot = self.verts.slot[i];
            let rng = &mut self.rng[slot as usize];
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            let frame = Frame::new(self.verts.ns[i]);
            let mat = &self.verts.bsdf[i];
            let Some(bs) = mat.sample(frame.to_local(self.verts.wi[i]), u0, u1, u2) else {
                continue;
            };
            let wo = frame.to_world(bs.wo).normalize();
            let beta = self.verts.beta[i] * bs.weight;
            if beta.max_element() <= 0.0 || !beta.is_finite() {
                continue;
            }
            if !side_ok(self.verts.wi[i], wo, self.verts.ng[i], self.verts.ns[i]) {
                continue;
            }
            let o = offset(self.verts.p[i], self.verts.ng[i], wo);
            self.next.push(slot, o, wo, beta, bs.pdf, false);
        }
    }
}

/// Renders `scene` with the given options.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Image {
    render_with_stats(scene, opts).0
}

/// Renders `scene` pass by pass (one sample per pixel over the whole image per pass, for the
/// spp or time budget of `opts`, see [`crate::render::schedule`]) and reports what ran.
///
/// Pixel sums are accumulated in pass order, so the image is bit-identical for any thread
/// count and for any block size.
pub fn render_with_stats(scene: &Scene, opts: &RenderOptions) -> (Image, RenderStats) {
    let (width, height) = opts.resolution(scene);
    let npix = width as usize * height as usize;
    let threads = opts.thread_count();
    let block = npix.div_ceil(threads * 8).clamp(64, 4096);
    let nblocks = npix.div_ceil(block);
    let mut sum = vec![[0.0f64; 3]; npix];
    let mut sum2 = vec![[0.0f64; 3]; npix];
    let mut sched = crate::render::schedule::Schedule::new(opts, 0.0);
    let mut stats = RenderStats {
        nee: opts.integrator == IntegratorKind::PtNee && scene.has_samplable_emitter(),
        ..RenderStats::default()
    };
    while let Some(pass) = sched.next_pass() {
        let next = AtomicUsize::new(0);
        let acc = Mutex::new((&mut sum, &mut sum2, 0u64));
        std::thread::scope(|s| {
            for _ in 0..threads.min(nblocks) {
                s.spawn(|| {
                    let mut w = Worker::new(scene, *opts, None);
                    loop {
                        let b = next.fetch_add(1, Ordering::Relaxed);
                        if b >= nblocks {
                            break;
                        }
                        let start = b * block;
                        let count = block.min(npix - start);
                        w.trace_sample(start, count, width, height, pass.index);
                        let mut g = acc.lock().unwrap_or_else(|e| e.into_inner());
                        let (s1, s2, _) = &mut *g;
                        accumulate(&mut s1[start..], &mut s2[start..], &w.radiance);
                    }
                    acc.lock().unwrap_or_else(|e| e.into_inner()).2 += w.rays;
                });
            }
        });
        stats.rays += acc.into_inner().unwrap_or_else(|e| e.into_inner()).2;
    }
    stats.passes = sched.passes();
    stats.wall = sched.elapsed();
    sched.finish();
    (
        finish_image(width, height, stats.passes, &sum, &sum2),
        stats,
    )
}

/// Adds one pass's radiance of a block to the per-pixel sums (non-finite samples count as 0).
pub(crate) fn accumulate(sum: &mut [[f64; 3]], sum2: &mut [[f64; 3]], radiance: &[Vec3]) {
    for (k, l) in radiance.iter().enumerate() {
        for c in 0..3 {
            let v = if l[c].is_finite() { l[c] as f64 } else { 0.0 };
            sum[k][c] += v;
            sum2[k][c] += v * v;
        }
    }
}

/// Per-pixel mean and variance of the mean from the running sums over `passes` samples.
pub(crate) fn finish_image(
    width: u32,
    height: u32,
    passes: u32,
    sum: &[[f64; 3]],
    sum2: &[[f64; 3]],
) -> Image {
    let n = passes.max(1) as f64;
    let pixels = sum.iter().map(|s| s.map(|v| (v / n) as f32)).collect();
    let var_of_mean = sum
        .iter()
        .zip(sum2)
        .map(|(s, s2)| {
            let mut v = [0.0f32; 3];
            for c in 0..3 {
                let mean = s[c] / n;
                let var = if n > 1.0 {
                    ((s2[c] - n * mean * mean) / (n - 1.0)).max(0.0)
                } else {
                    0.0
                };
                v[c] = (var / n) as f32;
            }
            v
        })
        .collect();
    Image {
        width,
        height,
        pixels,
        var_of_mean,
    }
}
