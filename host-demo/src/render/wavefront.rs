//! The wavefront driver: every estimator (`pt`, `pt-nee`, `guided`) is this loop plus a
//! direction-sampling [`Strategy`].
//!
//! Rendering is pass-major (one sample per pixel over the whole image per pass, see
//! [`crate::render::schedule`]); within a pass each thread takes blocks of pixels and runs the
//! block's paths through a per-bounce pipeline of typed [queues](crate::render::queues):
//!
//! 1. **intersect** the ray queue (closest hit);
//! 2. **emission**: add emitted radiance at the hits (MIS-weighted against NEE by the
//!    density the ray was sampled with), apply Russian roulette, and compact the surviving
//!    hits into [`Vertices`];
//! 3. **prepare**: the strategy sees the whole batch once ([`VertexStrategy::prepare`]; the
//!    guided strategy decodes its guide for every vertex in one call);
//! 4. **NEE** (when on, and the scene has an emitter NEE can sample; skipped at delta
//!    vertices): one light sample per vertex; its MIS partner is the strategy's density of
//!    that direction ([`VertexStrategy::light_pdfs`]), combined by the power heuristic;
//! 5. **shadow**: trace the shadow rays and add the unoccluded contributions;
//! 6. **continue**: the strategy samples one direction per vertex
//!    ([`VertexStrategy::sample`]); the driver applies the weight, rejects light leaks of
//!    shading normals and fills the next bounce's ray queue.
//!
//! When the strategy asks for it ([`Strategy::begin_pass`]), every hit, NEE contribution and
//! continuation is recorded, and the paths' training samples go to [`Strategy::end_chunk`] in
//! row order after each piece of the pass (see [`render_passes`]).
//!
//! Depth follows Mitsuba: `max_depth = 1` only shows directly visible emission; a hit at
//! bounce `b` (0 = camera hit) adds emission when `b < max_depth` and does NEE/continues when
//! `b + 1 < max_depth`. No Russian roulette by default (keeps variance comparable; the estimator
//! is unbiased either way); `--rr throughput` is Mitsuba's Russian roulette from the scene's
//! `rr_depth`, `--rr guided` the library's weight window with splitting at every vertex
//! ([`crate::render::roulette`]): a split vertex enters the bounce's [`Vertices`] `k` times,
//! each copy with `β / k`, all in the same path slot (they add to the same pixel).
//!
//! Rays that leave the scene pick up the environment (MIS-weighted against environment NEE);
//! `twosided` materials are resolved per hit (a back hit flips the frame), and the
//! geometric side test lets transmission through dielectrics cross the surface.

use crate::math::{power_heuristic, Frame, Rng};
use crate::render::image::{accumulate, finish_image, Image, RenderStats};
use crate::render::options::RenderOptions;
use crate::render::options::Roulette;
use crate::render::queues::{Continuations, LightSamples, RayQueue, ShadowQueue, Vertices};
use crate::render::roulette::{GuidedRoulette, RouletteStats, MAX_PATHS_PER_SAMPLE};
use crate::render::schedule::Schedule;
use crate::render::strategy::{PassImage, PassSamples, Strategy, Traced, VertexStrategy};
use crate::scene::bsdf::Material;
use crate::scene::emitter::EmitterSample;
use crate::scene::{Scene, SurfaceHit, MAX_NULL_CROSSINGS};
use glam::Vec3;
use guiding::{BatchRecorder, Continuation, PathVertex, ReflectedSample};
use guiding_core::sample::TrainingSample;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

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

/// Geometric-normal side test of a scattering event from `wo` into `wi`: a reflection (with
/// respect to the shading normal) must stay on the geometric side it came from, a
/// transmission must cross it. Rejects the light leaks of interpolated shading normals.
#[inline]
pub(crate) fn side_ok(wo: Vec3, wi: Vec3, ng: Vec3, ns: Vec3) -> bool {
    let shading_reflect = wo.dot(ns) * wi.dot(ns) > 0.0;
    let (go, gi) = (wo.dot(ng), wi.dot(ng));
    gi != 0.0 && (go * gi > 0.0) == shading_reflect
}

/// Mitsuba's throughput Russian roulette (`--rr throughput`): the survival probability
/// `q = min(max(β), 0.95)` if the path survives (its throughput then divided by `q`, which
/// keeps the estimator unbiased), `None` if it ends. One rule for surface and medium vertices.
#[inline]
fn throughput_survival(beta: Vec3, rng: &mut Rng) -> Option<f32> {
    let q = beta.max_element().min(0.95);
    (!q.is_nan() && q > 0.0 && rng.next_f32() < q).then_some(q)
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

/// Per-thread state: the queues (reused across bounces, samples and blocks), the path RNGs and
/// the strategy's worker.
struct Worker<'s, V> {
    scene: &'s Scene,
    opts: RenderOptions,
    /// NEE runs: asked for, and the scene has an emitter NEE can sample.
    nee: bool,
    rays_in: RayQueue,
    rays_out: RayQueue,
    verts: Vertices,
    lights: LightSamples,
    shadow: ShadowQueue,
    next: Continuations,
    /// One RNG per slot; path slots are stable for the whole sample.
    rng: Vec<Rng>,
    /// Radiance of the current sample per slot.
    radiance: Vec<Vec3>,
    /// Rays traced by this worker (closest-hit and shadow).
    rays: u64,
    /// Medium vertices made by this worker.
    medium_vertices: u64,
    strategy: V,
    /// The library's wavefront recorder, on passes the strategy trains on or the roulette's
    /// grid learns in.
    recorder: Option<BatchRecorder>,
    /// The strategy asked for this pass's training samples.
    strategy_records: bool,
    /// The guided roulette's state (`--rr guided`).
    roulette: Option<&'s GuidedRoulette>,
    /// Per slot: the pixel (row-major) it traces, and how many more paths it may split into.
    pixel_of_slot: Vec<u32>,
    room: Vec<u32>,
    /// What the roulette did in this worker.
    rr_stats: RouletteStats,
    /// Reflected radiance of the recorded vertices, for the roulette's grid.
    reflected: Vec<ReflectedSample>,
    /// Training samples of this pass's current block, and their MIS-weighted incident
    /// radiances.
    samples: Vec<TrainingSample>,
    mis_radiance: Vec<[f32; 3]>,
}

impl<'s, V: VertexStrategy> Worker<'s, V> {
    fn new(
        scene: &'s Scene,
        opts: RenderOptions,
        nee: bool,
        strategy: V,
        strategy_records: bool,
        roulette: Option<&'s GuidedRoulette>,
    ) -> Self {
        let learning = roulette.is_some_and(|r| r.learning);
        let recorder = (strategy_records || learning).then(|| {
            let mut r = BatchRecorder::new();
            r.keep_reflected(learning);
            r
        });
        Worker {
            scene,
            opts,
            nee,
            rays_in: RayQueue::default(),
            rays_out: RayQueue::default(),
            verts: Vertices::default(),
            lights: LightSamples::default(),
            shadow: ShadowQueue::default(),
            next: Continuations::default(),
            rng: Vec::new(),
            radiance: Vec::new(),
            rays: 0,
            medium_vertices: 0,
            strategy,
            recorder,
            strategy_records,
            roulette,
            pixel_of_slot: Vec::new(),
            room: Vec::new(),
            rr_stats: RouletteStats::default(),
            reflected: Vec::new(),
            samples: Vec::new(),
            mis_radiance: Vec::new(),
        }
    }

    /// Traces sample `s` of the pixels of image rows `rows` (in that order, each row left to
    /// right) into `self.radiance`.
    fn trace_sample(&mut self, rows: &[u32], width: u32, height: u32, s: u32) {
        let w = width as usize;
        let count = rows.len() * w;
        self.rays_in.clear();
        self.rng.clear();
        self.radiance.clear();
        self.radiance.resize(count, Vec3::ZERO);
        self.pixel_of_slot.clear();
        self.room.clear();
        self.room.resize(count, MAX_PATHS_PER_SAMPLE - 1);
        if let Some(r) = &mut self.recorder {
            r.start(count);
        }
        let cam = &self.scene.camera;
        let scene_camera_medium = self.scene.camera_medium;
        for i in 0..count {
            let pix = rows[i / w] as usize * w + i % w;
            self.pixel_of_slot.push(pix as u32);
            let (x, y) = ((pix % w) as f32, (pix / w) as f32);
            let mut rng = Rng::from_keys(self.opts.seed, pix as u64, s as u64);
            let (u, v) = (
                (x + rng.next_f32()) / width as f32,
                (y + rng.next_f32()) / height as f32,
            );
            let (o, d) = if cam.has_lens() {
                cam.ray_lens(u, v, rng.next_f32(), rng.next_f32())
            } else {
                cam.ray(u, v)
            };
            self.rng.push(rng);
            self.rays_in
                .push(i as u32, o, d, Vec3::ONE, 0.0, true, scene_camera_medium);
            self.rays_in.from_camera[i] = true;
        }
        let mut bounce = 0u32;
        while !self.rays_in.is_empty() && bounce < self.opts.max_depth {
            self.stage_intersect_and_emission(bounce);
            self.strategy
                .prepare(self.scene, &self.verts, &mut self.rng);
            if self.nee {
                self.stage_nee();
                self.stage_shadow();
            }
            self.stage_continue();
            std::mem::swap(&mut self.rays_in, &mut self.rays_out);
            bounce += 1;
        }
        if let Some(r) = &mut self.recorder {
            r.end();
            r.drain_into(&mut self.samples, &mut self.mis_radiance);
            r.drain_reflected_into(&mut self.reflected);
        }
    }

    /// Stage 1 for one ray: the closest surface that scatters, crossing `null` surfaces (and
    /// moving into the media they bound) on the way, or the point where the ray scatters in
    /// a medium (free-flight sampling, [`crate::scene::medium`]). Returns where it ended and
    /// the throughput factor of the media it went through. A scene without media or `null`
    /// surfaces takes one closest-hit query.
    fn trace_segment(&mut self, o: Vec3, d: Vec3, medium: u32, slot: u32) -> (SegmentEnd, Vec3) {
        let scene = self.scene;
        if !scene.has_volumes {
            let end = match scene.intersect(o, d, 0.0, f32::INFINITY) {
                Some(hit) => SegmentEnd::Surface {
                    travelled: hit.t,
                    hit,
                    medium,
                },
                None => SegmentEnd::Escaped,
            };
            return (end, Vec3::ONE);
        }
        let (mut o, mut medium, mut travelled, mut weight) = (o, medium, 0.0f32, Vec3::ONE);
        for _ in 0..=MAX_NULL_CROSSINGS {
            let hit = scene.intersect(o, d, 0.0, f32::INFINITY);
            if let Some(m) = scene.media.get(medium as usize) {
                let rng = &mut self.rng[slot as usize];
                let t_max = hit.as_ref().map_or(f32::INFINITY, |h| h.t);
                let flight = m.free_flight(o, d, t_max, rng);
                weight *= flight.weight;
                if let Some(t) = flight.t {
                    return (
                        SegmentEnd::Medium {
                            p: o + d * t,
                            medium,
                        },
                        weight,
                    );
                }
                if weight.max_element() <= 0.0 {
                    return (SegmentEnd::Absorbed, Vec3::ZERO);
                }
            }
            let Some(hit) = hit else {
                return (SegmentEnd::Escaped, weight);
            };
            travelled += hit.t;
            if !scene.is_null(hit.shape) {
                return (
                    SegmentEnd::Surface {
                        hit,
                        travelled,
                        medium,
                    },
                    weight,
                );
            }
            if let Some(i) = scene.shapes[hit.shape as usize].media {
                medium = i.target(d, hit.ng);
            }
            o = offset(hit.p, hit.ng, d);
        }
        (SegmentEnd::Absorbed, Vec3::ZERO)
    }

    /// Stages 1 and 2: closest hit (or medium scattering point), emission (with MIS),
    /// Russian roulette, compaction into the vertex batch.
    fn stage_intersect_and_emission(&mut self, bounce: u32) {
        let scene = self.scene;
        self.verts.clear();
        let continue_path = bounce + 1 < self.opts.max_depth;
        let rr = self.opts.rr == Roulette::Throughput && bounce + 1 >= scene.settings.rr_depth;
        let nee = self.nee;
        // Taken out for the loop (the roulette's decision borrows the worker), put back after.
        let queue = std::mem::take(&mut self.rays_in);
        let q = &queue;
        self.rays += q.len() as u64;
        for i in 0..q.len() {
            let (o, d, slot) = (q.origin[i], q.dir[i], q.slot[i]);
            let (end, weight) = self.trace_segment(o, d, q.medium[i], slot);
            // The recorder follows one path per slot: the tracked copy's.
            let mut recorder = self.recorder.as_mut().filter(|_| q.tracked[i]);
            if weight != Vec3::ONE {
                if let Some(r) = &mut recorder {
                    // The media's factor belongs to the previous vertex's continuation. The
                    // recorder's scale is one number: a chromatic factor enters as its mean
                    // (training targets only; the image takes the exact factor).
                    r.scale_continuation(slot, weight.element_sum() / 3.0);
                }
            }
            let mis = |pdf_light: f32| {
                if q.from_camera[i] || !nee || q.pdf[i].is_infinite() {
                    1.0
                } else {
                    power_heuristic(q.pdf[i], pdf_light)
                }
            };
            let (hit, travelled, medium) = match end {
                SegmentEnd::Absorbed => continue,
                SegmentEnd::Escaped => {
                    if scene.env.is_some() {
                        // The path leaves the scene: environment emission, MIS-weighted against
                        // NEE's environment sampling.
                        let le = scene.env_radiance(d);
                        let w = mis(scene.env_pdf(d));
                        self.radiance[slot as usize] += q.beta[i] * weight * le * w;
                        if let Some(r) = &mut recorder {
                            r.add_escaped_radiance(slot, le.to_array(), w);
                        }
                    }
                    continue;
                }
                SegmentEnd::Medium { p, medium } => {
                    if continue_path {
                        let beta = q.beta[i] * weight;
                        self.medium_vertex(slot, q.tracked[i], p, d, medium, beta, rr);
                    }
                    continue;
                }
                SegmentEnd::Surface {
                    hit,
                    travelled,
                    medium,
                } => (hit, travelled, medium),
            };
            let mut beta = q.beta[i] * weight;
            let shape = &scene.shapes[hit.shape as usize];
            let (mut le, mut w) = (Vec3::ZERO, 1.0);
            if let Some(emitted) = shape.emission {
                let cos_l = hit.ns.dot(-d);
                if cos_l > 0.0 {
                    w = mis(scene.light_pdf_area(hit.shape) * travelled * travelled / cos_l);
                    le = emitted;
                    self.radiance[slot as usize] += beta * le * w;
                }
            }
            let mut vertex = PathVertex {
                emitted: le.to_array(),
                emitted_mis_weight: w,
                ..PathVertex::default()
            };
            if !continue_path {
                if let Some(r) = &mut recorder {
                    r.add_vertex(slot, vertex);
                }
                continue;
            }
            let (_, mat, ng, ns) = scene.resolve_material(
                shape.material,
                hit.ng,
                hit.ns,
                d,
                hit.uv,
                &mut self.rng[slot as usize],
            );
            if let Some(r) = &mut recorder {
                vertex.position = hit.p.to_array();
                vertex.normal = ns.to_array();
                vertex.wo = (-d).to_array();
                vertex.roughness = mat.roughness();
                // Radiance propagates through every vertex; only those the strategy guides
                // make training samples (none when only the roulette's grid records).
                vertex.is_delta = !(self.strategy_records
                    && self.strategy.trains(&mat, crate::scene::medium::NO_MEDIUM));
                r.add_vertex(slot, vertex);
            }
            if mat.is_black() || (mat.one_sided() && ns.dot(-d) <= 0.0) {
                continue; // absorbed, or the back of a one-sided BSDF
            }
            if rr {
                let Some(q) = throughput_survival(beta, &mut self.rng[slot as usize]) else {
                    continue;
                };
                beta /= q;
                if let Some(r) = &mut recorder {
                    r.scale_continuation(slot, 1.0 / q);
                }
            }
            let tracked = q.tracked[i];
            let mut copies = 1;
            // The window decides past the camera vertex (there `m = L_r / I` is 1 for exact
            // estimates: only their errors could move it) and at Lambertian vertices (its
            // estimate ignores `ω_o`: a glossy lobe's reflected light is not its cell's mean).
            // The window's trial may leave it out of this pass (the grid still learns).
            let window = self.roulette.filter(|g| {
                g.active
                    && bounce > 0
                    && matches!(
                        mat,
                        Material::Diffuse { .. } | Material::RoughDiffuse { .. }
                    )
            });
            if let Some(g) = window {
                let decided = self.guided_roulette(g, slot, tracked, hit.p, ns, beta);
                let Some((k, weight)) = decided else {
                    continue;
                };
                copies = k;
                beta *= weight;
            }
            // The media a ray leaving the vertex enters, by the side of `ng` it leaves on.
            let media = match shape.media {
                Some(i) => [i.target(ng, hit.ng), i.target(-ng, hit.ng)],
                None => [medium; 2],
            };
            let v = &mut self.verts;
            for copy in 0..copies {
                v.tracked.push(tracked && copy == 0);
                v.slot.push(slot);
                v.position.push(hit.p);
                v.ng.push(ng);
                v.ns.push(ns);
                v.wo.push(-d);
                v.beta.push(beta);
                v.bsdf.push(mat);
                v.media.push(media);
            }
        }
        self.rays_in = queue;
    }

    /// A scattering point at `p` in medium `medium`, reached along `d` with throughput
    /// `beta`: recorded (a training sample without a normal where the strategy guides
    /// medium vertices, else it only propagates radiance), rouletted like a surface vertex
    /// with `rr`, and added to the batch with the medium's phase function as its material.
    #[allow(clippy::too_many_arguments)] // the ray's state, as the surface branch has it
    fn medium_vertex(
        &mut self,
        slot: u32,
        tracked: bool,
        p: Vec3,
        d: Vec3,
        medium: u32,
        mut beta: Vec3,
        rr: bool,
    ) {
        let mat = Material::Phase {
            g: self.scene.media[medium as usize].g,
        };
        let trains = self.strategy_records && self.strategy.trains(&mat, medium);
        if let Some(r) = self.recorder.as_mut().filter(|_| tracked) {
            // No normal: a training sample of a point in a medium ("no surface").
            r.add_vertex(
                slot,
                PathVertex {
                    position: p.to_array(),
                    wo: (-d).to_array(),
                    roughness: 1.0,
                    is_delta: !trains,
                    ..PathVertex::default()
                },
            );
        }
        if rr {
            let Some(q) = throughput_survival(beta, &mut self.rng[slot as usize]) else {
                return;
            };
            beta /= q;
            if let Some(r) = self.recorder.as_mut().filter(|_| tracked) {
                r.scale_continuation(slot, 1.0 / q);
            }
        }
        self.medium_vertices += 1;
        let v = &mut self.verts;
        v.tracked.push(tracked);
        v.slot.push(slot);
        v.position.push(p);
        v.ng.push(Vec3::ZERO);
        v.ns.push(-d);
        v.wo.push(-d);
        v.beta.push(beta);
        v.bsdf.push(mat);
        v.media.push([medium; 2]);
    }

    /// The weight window's decision for the path in `slot` at a vertex at `p` (shading normal
    /// `ns`) with throughput `beta`: `None` if roulette ends it, else the number of copies of
    /// the vertex and the factor on their throughput.
    ///
    /// For the recorder (`tracked`: the path it follows), a roulette survival scales the
    /// continuation by `1/m`; a split does not scale it: the tracked copy's estimate alone is
    /// an unbiased estimate of the vertex's reflected radiance (as is the mean of the `k`).
    fn guided_roulette(
        &mut self,
        g: &GuidedRoulette,
        slot: u32,
        tracked: bool,
        p: Vec3,
        ns: Vec3,
        beta: Vec3,
    ) -> Option<(u32, f32)> {
        let s = slot as usize;
        let (p, ns) = (p.to_array(), ns.to_array());
        let radiance = g.grid.estimate(p, ns);
        let moment = if g.efficiency {
            g.grid.second_moment(p, ns)
        } else {
            None
        };
        let pixel = g
            .pixel
            .get(self.pixel_of_slot[s] as usize)
            .copied()
            .unwrap_or(0.0);
        let stats = &mut self.rr_stats;
        stats.decisions += 1;
        if radiance.is_none() || pixel <= 0.0 {
            stats.missing += 1;
        }
        let u = self.rng[s].next_f32();
        let (b, estimate, room) = (beta.to_array(), radiance.unwrap_or([-1.0; 3]), self.room[s]);
        let d = if g.efficiency {
            let moment = moment.unwrap_or([-1.0; 3]);
            g.window
                .decide_efficiency(b, estimate, moment, pixel, u, room)
        } else {
            g.window.decide(b, estimate, pixel, u, room)
        };
        match d.count {
            0 => {
                stats.killed += 1;
                None
            }
            1 => {
                if d.weight > 1.0 {
                    stats.survived += 1;
                }
                if let Some(r) = self.recorder.as_mut().filter(|_| tracked) {
                    r.scale_continuation(slot, d.weight);
                }
                Some((1, d.weight))
            }
            k => {
                stats.split_vertices += 1;
                stats.extra_paths += u64::from(k - 1);
                stats.max_split = stats.max_split.max(k);
                self.room[s] -= k - 1;
                Some((k, if g.unweighted { 1.0 } else { d.weight }))
            }
        }
    }

    /// Stage 4: one light sample per NEE-connectable vertex, MIS-weighted against the
    /// strategy's density of its direction, into shadow rays.
    fn stage_nee(&mut self) {
        let (scene, v) = (self.scene, &self.verts);
        self.lights.clear();
        for i in 0..v.len() {
            let mat = &v.bsdf[i];
            if !mat.nee_connectable() {
                continue; // delta BSDF: no light connection
            }
            let rng = &mut self.rng[v.slot[i] as usize];
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            let Some(es) = scene.sample_emitter(v.position[i], u0, u1, u2) else {
                continue;
            };
            let frame = Frame::from_z(v.ns[i]);
            let (f, pdf_bsdf) = mat.eval(frame.to_local(v.wo[i]), frame.to_local(es.wo));
            if f.max_element() <= 0.0 {
                continue;
            }
            self.lights.vertex.push(i as u32);
            self.lights.light.push(es);
            self.lights.bsdf_cos.push(f);
            self.lights.bsdf_pdf.push(pdf_bsdf);
        }
        self.strategy.light_pdfs(v, &mut self.lights);
        self.shadow.clear();
        let l = &self.lights;
        for k in 0..l.len() {
            let (i, es) = (l.vertex[k] as usize, &l.light[k]);
            let w = if es.delta {
                1.0
            } else {
                power_heuristic(es.pdf, l.sampling_pdf[k])
            };
            let local = l.bsdf_cos[k] * es.radiance * (w / es.pdf);
            let Some((o, d, tmax)) = shadow_ray(v.position[i], v.ng[i], es) else {
                continue;
            };
            self.shadow.medium.push(v.medium_toward(i, d));
            self.shadow.vertex.push(i as u32);
            self.shadow.origin.push(o);
            self.shadow.dir.push(d);
            self.shadow.tmax.push(tmax);
            self.shadow.local.push(local);
        }
    }

    /// Stage 5: trace shadow rays and accumulate unoccluded light.
    fn stage_shadow(&mut self) {
        let (sh, v) = (&self.shadow, &self.verts);
        self.rays += sh.vertex.len() as u64;
        for k in 0..sh.vertex.len() {
            let (o, d, tmax) = (sh.origin[k], sh.dir[k], sh.tmax[k]);
            let local = if self.scene.has_volumes {
                let slot = v.slot[sh.vertex[k] as usize] as usize;
                let rng = &mut self.rng[slot];
                let tr = self.scene.transmittance(o, d, tmax, sh.medium[k], rng);
                if tr.max_element() <= 0.0 {
                    continue;
                }
                sh.local[k] * tr
            } else if self.scene.occluded(o, d, 0.0, tmax) {
                continue;
            } else {
                sh.local[k]
            };
            let i = sh.vertex[k] as usize;
            let slot = v.slot[i];
            self.radiance[slot as usize] += v.beta[i] * local;
            if let Some(r) = self.recorder.as_mut().filter(|_| v.tracked[i]) {
                // The roulette factor of this vertex scales its NEE too (the recorder's
                // continuation scale covers only the scattered radiance).
                let rr = r.last_vertex(slot).map_or(1.0, |v| v.continuation_scale);
                r.add_direct(slot, (local * rr).to_array());
            }
        }
    }

    /// Stage 6: the strategy's continuations into the next bounce's ray queue.
    fn stage_continue(&mut self) {
        let v = &self.verts;
        self.next.reset(v.len());
        self.strategy.sample(v, &mut self.rng, &mut self.next);
        self.rays_out.clear();
        let c = &self.next;
        for i in 0..v.len() {
            let (wi, slot) = (c.wi[i], v.slot[i]);
            let (wo, ng, ns) = (v.wo[i], v.ng[i], v.ns[i]);
            let beta = v.beta[i] * c.weight[i];
            // A medium vertex has no surface to leak through.
            if wi == Vec3::ZERO
                || beta.max_element() <= 0.0
                || !beta.is_finite()
                || (!v.bsdf[i].is_phase() && !side_ok(wo, wi, ng, ns))
            {
                continue;
            }
            if let Some(r) = self.recorder.as_mut().filter(|_| v.tracked[i]) {
                // A vertex that makes no sample only propagates: its weight as `f·cos / p`
                // with `p = 1`.
                let trains = r.last_vertex(slot).is_some_and(|v| !v.is_delta);
                let (sample_pdf, bsdf_cos) = if trains {
                    (c.pdf[i], c.bsdf_cos[i])
                } else {
                    (1.0, c.weight[i])
                };
                r.set_continuation(
                    slot,
                    Continuation {
                        wi: wi.to_array(),
                        sample_pdf,
                        bsdf_pdf: c.bsdf_pdf[i],
                        bsdf_cos: bsdf_cos.to_array(),
                    },
                );
            }
            let o = offset(v.position[i], ng, wi);
            let medium = v.medium_toward(i, wi);
            self.rays_out
                .push(slot, o, wi, beta, c.pdf[i], v.tracked[i], medium);
        }
    }
}

/// Where a ray's segment ended ([`Worker::trace_segment`]).
enum SegmentEnd {
    /// It left the scene.
    Escaped,
    /// It reached a surface that scatters, `travelled` from the ray's origin (through the
    /// `null` surfaces it crossed), arriving in `medium`.
    Surface {
        hit: SurfaceHit,
        travelled: f32,
        medium: u32,
    },
    /// It scattered at `p` inside `medium`.
    Medium { p: Vec3, medium: u32 },
    /// It ended on the way (every channel absorbed, or too many `null` crossings).
    Absorbed,
}

/// What one thread did in a work item: its rows' radiance, training samples (with their
/// MIS-weighted radiance) and the reflected radiance of its recorded vertices.
type BlockResult = (
    Vec<Vec3>,
    Vec<TrainingSample>,
    Vec<[f32; 3]>,
    Vec<ReflectedSample>,
);

/// The rows of an image of `height` rows in van der Corput order (bit-reversed indices,
/// skipping those `≥ height`): every run of consecutive entries is spread evenly over the
/// image, so a training pass traced in pieces of consecutive entries updates the guide from
/// paths all over the image, not from its top rows. A permutation: every row once.
pub fn spread_rows(height: u32) -> Vec<u32> {
    let bits = height.max(1).next_power_of_two().trailing_zeros();
    (0..1u64 << bits)
        .map(|i| {
            if bits == 0 {
                0
            } else {
                (i as u32).reverse_bits() >> (32 - bits)
            }
        })
        .filter(|&r| r < height)
        .collect()
}

/// Renders `scene` pass by pass with `strategy` (one sample per pixel over the whole image
/// per pass, for the spp or time budget of `opts`, see [`crate::render::schedule`]).
///
/// A pass the strategy records is traced in pieces ([`Strategy::paths_before_update`]: the
/// library's schedule asks for an update every fraction of a second, whatever the pass time),
/// each piece a set of rows spread over the image ([`spread_rows`]), and the strategy trains
/// between pieces ([`Strategy::end_chunk`]). Every pixel still gets exactly one sample per
/// pass, keyed by its pixel and pass index, so each pass stays an unbiased estimate whichever
/// guide its pieces used.
///
/// Pixel sums are accumulated in pass order and training samples handed over in row order, so
/// the result is the same for any thread count (given the same pieces: time-driven pieces vary
/// from run to run, [`guiding::StepRule::Epochs`] gives whole passes).
///
/// # Errors
/// The first error of [`Strategy::end_chunk`]; the render stops after that piece.
pub fn render_passes<S: Strategy>(
    scene: &Scene,
    opts: &RenderOptions,
    nee: bool,
    strategy: &mut S,
) -> Result<(Image, RenderStats), S::Error> {
    let (width, height) = opts.resolution(scene);
    let npix = width as usize * height as usize;
    let threads = opts.thread_count();
    let block = npix.div_ceil(threads * 8).clamp(64, 4096);
    let rows_per_item = (block / width as usize).max(1);
    let mut sum = vec![[0.0f64; 3]; npix];
    let mut sum2 = vec![[0.0f64; 3]; npix];
    let mut sched = Schedule::new(opts);
    let in_order: Vec<u32> = (0..height).collect();
    let spread = spread_rows(height);
    // The current pass's pixel values (row-major).
    let mut pass_radiance = vec![Vec3::ZERO; npix];
    let mut pass_image: Vec<[f32; 3]> = Vec::new();
    let nee = nee && scene.has_samplable_emitter();
    let mut stats = RenderStats {
        nee,
        ..RenderStats::default()
    };
    // Valid options make a valid grid and schedule; a failure leaves the roulette off.
    let mut roulette = GuidedRoulette::new(scene, opts).ok().flatten();
    while let Some(pass) = sched.next_pass() {
        let record = strategy.begin_pass(&pass);
        if let Some(g) = &mut roulette {
            let size = (width, height);
            let settled = strategy.estimator_settled();
            let strategy_records = strategy.trains_from_recorded_passes().then_some(record);
            g.begin_pass(
                pass.elapsed.as_secs_f64(),
                pass.index,
                size,
                &sum,
                &sum2,
                (settled, strategy_records),
            );
        }
        sched.training_ended(
            &pass,
            record || roulette.as_ref().is_some_and(|g| g.learning),
        );
        let wants_image = strategy.wants_pass_image(&pass);
        let rows = if record { &spread } else { &in_order };
        let mut pass_seconds = 0.0f64;
        let mut done = 0usize;
        while done < rows.len() {
            let paths = if record {
                strategy.paths_before_update(npix as u64)
            } else {
                npix as u64
            };
            let take = (paths.div_ceil(u64::from(width)) as usize).clamp(1, rows.len() - done);
            let piece = &rows[done..done + take];
            done += take;
            let items: Vec<&[u32]> = piece.chunks(rows_per_item).collect();
            let t_piece = Instant::now();
            let next = AtomicUsize::new(0);
            let results: Mutex<Vec<Option<BlockResult>>> =
                Mutex::new((0..items.len()).map(|_| None).collect());
            let reports = Mutex::new(Vec::new());
            let rays = AtomicUsize::new(0);
            let medium_vertices = AtomicUsize::new(0);
            let rr_stats = Mutex::new(RouletteStats::default());
            let shared: &S = strategy;
            let shared_rr = roulette.as_ref();
            std::thread::scope(|sc| {
                for _ in 0..threads.min(items.len()) {
                    sc.spawn(|| {
                        let mut w =
                            Worker::new(scene, *opts, nee, shared.worker(), record, shared_rr);
                        loop {
                            let b = next.fetch_add(1, Ordering::Relaxed);
                            if b >= items.len() {
                                break;
                            }
                            w.trace_sample(items[b], width, height, pass.index);
                            let result = (
                                std::mem::take(&mut w.radiance),
                                std::mem::take(&mut w.samples),
                                std::mem::take(&mut w.mis_radiance),
                                std::mem::take(&mut w.reflected),
                            );
                            results.lock().unwrap_or_else(|e| e.into_inner())[b] = Some(result);
                        }
                        rays.fetch_add(w.rays as usize, Ordering::Relaxed);
                        medium_vertices.fetch_add(w.medium_vertices as usize, Ordering::Relaxed);
                        rr_stats
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .merge(&w.rr_stats);
                        let report = shared.report(w.strategy);
                        reports
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .push(report);
                    });
                }
            });
            let piece_seconds = t_piece.elapsed();
            pass_seconds += piece_seconds.as_secs_f64();
            stats.trace += piece_seconds;
            stats.rays += rays.into_inner() as u64;
            stats.medium_vertices += medium_vertices.into_inner() as u64;
            let mut samples = PassSamples::default();
            let results = results.into_inner().unwrap_or_else(|e| e.into_inner());
            if let Some(g) = &mut roulette {
                g.stats
                    .merge(&rr_stats.into_inner().unwrap_or_else(|e| e.into_inner()));
            }
            for (item, r) in items.iter().zip(results) {
                let Some((rad, s, m, reflected)) = r else {
                    continue;
                };
                if let Some(g) = &mut roulette {
                    g.learn(&reflected);
                }
                let w = width as usize;
                for (k, &row) in item.iter().enumerate() {
                    let at = row as usize * w;
                    pass_radiance[at..at + w].copy_from_slice(&rad[k * w..(k + 1) * w]);
                }
                samples.samples.extend(s);
                samples.mis_radiance.extend(m);
            }
            let reports = reports.into_inner().unwrap_or_else(|e| e.into_inner());
            let traced = Traced {
                seconds: piece_seconds.as_secs_f64(),
                paths: (take * width as usize) as u64,
            };
            strategy.end_chunk(&pass, record, reports, samples, traced)?;
        }
        // The pass's pixel values, once, for the strategy and for a trial pass of the
        // roulette's window ([`GuidedRoulette::end_pass`]).
        let rr_wants_image = roulette.as_ref().is_some_and(|g| g.wants_pass_image());
        if wants_image || rr_wants_image {
            pass_image.clear();
            pass_image.extend(pass_radiance.iter().map(|v| v.to_array()));
        }
        if wants_image {
            strategy.observe_pass_image(
                &pass,
                &PassImage {
                    width,
                    height,
                    pixels: &pass_image,
                    sum_before: &sum,
                    passes_before: pass.index,
                    seconds: pass_seconds,
                },
            );
        }
        if let Some(g) = roulette.as_mut().filter(|_| rr_wants_image) {
            g.end_pass(&pass_image, pass_seconds);
        }
        accumulate(&mut sum, &mut sum2, &pass_radiance);
    }
    stats.passes = sched.passes();
    stats.roulette = roulette.map(|g| g.finish());
    let mut image = finish_image(width, height, stats.passes, &sum, &sum2);
    if let Some((pixels, var_of_mean)) = strategy.combined_image() {
        if pixels.len() == npix && var_of_mean.len() == npix {
            image.pixels = pixels;
            image.var_of_mean = var_of_mean;
        }
    }
    // After the strategy's combination: the render's wall time includes it.
    stats.wall = sched.elapsed();
    sched.finish();
    Ok((image, stats))
}

#[cfg(test)]
mod tests {
    use super::spread_rows;

    #[test]
    fn spread_rows_is_a_permutation_spread_over_the_image() {
        for h in [1, 2, 3, 7, 64, 100, 455] {
            let rows = spread_rows(h);
            let mut sorted = rows.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..h).collect::<Vec<_>>(), "height {h}");
        }
        // The first 4 rows of 100 fall into 4 different quarters of the image.
        let quarters: Vec<u32> = spread_rows(100)[..4].iter().map(|r| r / 25).collect();
        let mut q = quarters.clone();
        q.sort_unstable();
        assert_eq!(q, [0, 1, 2, 3], "{quarters:?}");
    }
}
