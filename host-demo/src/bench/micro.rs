//! Micro-benchmarks of the benchmark report: ns per sample+pdf of each
//! distribution (ratio to the uniform-sphere warp measured in the same
//! process), queries/s and training samples/s of each guiding model through
//! the embedding facade, ns per guided vertex against one ray, and MLP
//! GFLOP/s against the core's measured FMA peak.
//!
//! The kernel-level workloads (distributions, MLP, the vMF loss gradient) and
//! every input are `guiding-bench`'s, the same the criterion benches time;
//! the facade-level ones (models, guided vertex) are this module's, as they
//! need a `GuidingField` and the door scene.
//!
//! Timing: each measurement is the median of `repeats` wall-clock runs of a
//! fixed workload after one warm-up run. Wall clock on a shared machine is
//! noisy; the ratios against a baseline run in the same process are the
//! numbers to compare across machines.

use glam::{Vec2, Vec3};
use guiding::{
    FieldConfig, GuidingConfig, GuidingField, ModelSize, Representation, TrainingSample,
};
use guiding_bench::distribution::DistributionCase;
use guiding_bench::gradient::VmfGradientWorkload;
use guiding_bench::inputs::{
    directions, queries, training_samples, unit_pairs, unit_points, BATCH,
};
use guiding_bench::mlp::MlpWorkload;
use guiding_bench::timing::{fma_peak, median_secs};
use guiding_core::mlp::BatchKernel;
use guiding_core::model::QueryPoint;
use guiding_core::rng::Rng;
use guiding_core::sphere::square_to_uniform_sphere;
use std::hint::black_box;

/// One measured quantity of the report.
#[derive(Clone, Debug)]
pub struct MicroResult {
    /// Group: `distribution`, `model`, `mlp`.
    pub group: &'static str,
    /// What was measured.
    pub name: String,
    /// The value.
    pub value: f64,
    /// Its unit.
    pub unit: &'static str,
    /// Ratio to the group's baseline (same process), where there is one.
    pub ratio: Option<f64>,
    /// What the ratio or value is relative to.
    pub note: String,
}

/// ns per sample + pdf of every [`DistributionCase`] (the criterion bench
/// `distributions` times the same cases), and each one's ratio to the
/// uniform sphere warp timed in the same process.
fn distributions(quick: bool) -> Vec<MicroResult> {
    let repeats = if quick { 3 } else { 7 };
    let rounds = if quick { 8 } else { 64 };
    let us = unit_pairs(7, BATCH);
    let cases = DistributionCase::all();
    let ns: Vec<f64> = cases
        .iter()
        .map(|case| {
            let secs = median_secs(repeats, || {
                for _ in 0..rounds {
                    black_box(case.sample_then_pdf(black_box(&us)));
                }
            });
            secs * 1e9 / (rounds * us.len()) as f64
        })
        .collect();
    let base = cases
        .iter()
        .zip(&ns)
        .find(|(c, _)| c.is_baseline())
        .map_or(f64::NAN, |(_, &t)| t);
    cases
        .iter()
        .zip(ns)
        .map(|(case, t)| MicroResult {
            group: "distribution",
            name: case.name().into(),
            value: t,
            unit: "ns/sample+pdf",
            ratio: Some(t / base),
            note: if case.is_baseline() {
                "baseline".into()
            } else {
                "× uniform sphere".into()
            },
        })
        .collect()
}

fn models(quick: bool) -> Result<Vec<MicroResult>, guiding::GuidingError> {
    let sizes: &[ModelSize] = if quick {
        &[ModelSize::Compact]
    } else {
        &[ModelSize::Compact, ModelSize::Paper]
    };
    let (repeats, nq, batch) = if quick {
        (3, 1024, 2048)
    } else {
        (5, 4096, 8192)
    };
    let queries: Vec<QueryPoint> = queries(3, nq);
    let us = unit_pairs(5, BATCH);
    let samples: Vec<TrainingSample> = training_samples(9, batch);
    let mut out = Vec::new();
    for &size in sizes {
        for rep in Representation::ALL {
            let config = GuidingConfig {
                representation: rep,
                ..GuidingConfig::npm_product()
            }
            .with_size(size)
            .with_training(
                FieldConfig::DEFAULT
                    .with_batch_size(batch)
                    .with_steps_per_update(1)
                    .with_threads(1),
            );
            let mut field = GuidingField::new(config, [-1.0; 3], [1.0; 3])?;
            let secs = median_secs(repeats, || {
                let mut acc = 0.0f32;
                for (i, q) in queries.iter().enumerate() {
                    let d = field.distribution(q);
                    let s = d.sample(us[i % us.len()]);
                    acc += s.pdf + d.pdf(Vec3::Z) + d.selection_probability();
                }
                black_box(acc);
            });
            let result = |what: &str, value: f64, unit: &'static str, note: String| MicroResult {
                group: "model",
                name: format!("{rep:?} {size:?} product: {what}"),
                value,
                unit,
                ratio: None,
                note,
            };
            let params = format!("{} parameters", field.param_count());
            out.push(result(
                "decode+sample+pdf",
                nq as f64 / secs,
                "queries/s (1 thread)",
                params,
            ));
            let secs = median_secs(repeats, || {
                field.add_samples(&samples);
                field.update();
            });
            let note = format!("batch {batch}, one Adam step");
            out.push(result(
                "training",
                batch as f64 / secs,
                "samples/s (1 thread)",
                note,
            ));
        }
    }
    Ok(out)
}

/// ns per closest-hit ray on `builtin:door`: camera rays through random
/// pixels and, from each hit, one ray in a uniformly drawn direction of the
/// hemisphere (the mix a path tracer's bounces trace), one thread.
fn door_ray_ns(repeats: usize) -> Option<f64> {
    let scene = crate::scene::builtin::load_builtin("door").ok()?;
    let mut rng = Rng::new(17);
    let mut rays = Vec::with_capacity(2 * BATCH);
    for _ in 0..BATCH {
        let (o, d) = scene.camera.ray(rng.next_f32(), rng.next_f32());
        rays.push((o, d));
        if let Some(hit) = scene.intersect(o, d, 0.0, f32::INFINITY) {
            let mut w = square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
            if w.dot(hit.ng) < 0.0 {
                w = -w;
            }
            rays.push((hit.p + hit.ng * 1e-4, w));
        }
    }
    let secs = median_secs(repeats, || {
        let mut hits = 0u32;
        for &(o, d) in &rays {
            hits += u32::from(
                scene
                    .intersect(black_box(o), d, 0.0, f32::INFINITY)
                    .is_some(),
            );
        }
        black_box(hits);
    });
    Some(secs * 1e9 / rays.len() as f64)
}

/// Points a real-scene-sized guide cache of the vertex micro-benchmark is
/// built from (at the default resolution 64 they occupy about 58 000 of the
/// 262 144 cells; the shared Cornell box's cache has 44 000 after 30 s).
const LARGE_CACHE_POINTS: usize = 65_536;

/// ns per guided vertex, all-in, as the wavefront integrator spends it:
/// one batched decode of 4096 vertices (grid, network, decoder), the
/// selection probability of each, one guide sample each and two pdfs each
/// (the BSDF-sampled and the NEE direction), one thread; next to the
/// per-query path (`distribution` + `sample` + two `pdf` per vertex) and the
/// cost of one closest-hit ray on `builtin:door` measured in the same run.
fn guided_vertex(quick: bool) -> Result<Vec<MicroResult>, guiding::GuidingError> {
    let repeats = if quick { 3 } else { 7 };
    let sizes: &[ModelSize] = if quick {
        &[ModelSize::Compact]
    } else {
        &[ModelSize::Compact, ModelSize::Paper]
    };
    let inputs = VertexInputs::new();
    let ray = door_ray_ns(repeats);
    let mut out = Vec::new();
    if let Some(r) = ray {
        out.push(MicroResult {
            group: "vertex",
            name: "closest-hit ray on builtin:door (baseline)".into(),
            value: r,
            unit: "ns (1 thread)",
            ratio: Some(1.0),
            note: "camera rays and one hemisphere bounce from each hit".into(),
        });
    }
    for &size in sizes {
        for rep in Representation::ALL {
            for target in [guiding::Target::Radiance, guiding::Target::Product] {
                let model = VertexModel { rep, size, target };
                out.extend(model.time(&inputs, repeats)?.results(&model, ray));
            }
        }
    }
    Ok(out)
}

/// Vertices of one batch of the vertex micro-benchmark.
const N: usize = BATCH;

/// The inputs of the vertex micro-benchmark, the same for every model: `N` query points and
/// random pairs, the lanes of one guide sample per vertex and of two pdfs per vertex (the
/// BSDF-sampled and the NEE direction) and those directions.
struct VertexInputs {
    queries: Vec<QueryPoint>,
    us: Vec<Vec2>,
    lanes: Vec<u32>,
    lanes2: Vec<u32>,
    dirs: Vec<Vec3>,
}

impl VertexInputs {
    fn new() -> Self {
        Self {
            queries: queries(23, N),
            us: unit_pairs(29, N),
            lanes: (0..N as u32).collect(),
            lanes2: (0..2 * N as u32).map(|i| i % N as u32).collect(),
            dirs: directions(31, 2 * N),
        }
    }
}

/// What the timed vertex batches write: the decoded batch, the guide samples, the pdfs and
/// the selection probabilities.
struct VertexOutputs {
    batch: guiding::DistributionBatch,
    samples: Vec<guiding::DirectionSample>,
    pdfs: Vec<f32>,
    sel: Vec<f32>,
}

impl VertexOutputs {
    fn new() -> Self {
        Self {
            batch: guiding::DistributionBatch::new(),
            samples: vec![
                guiding::DirectionSample {
                    direction: Vec3::ZERO,
                    pdf: 0.0
                };
                N
            ],
            pdfs: vec![0.0f32; 2 * N],
            sel: vec![0.0f32; N],
        }
    }

    /// The selection probability of every vertex of the decoded batch.
    #[inline]
    fn select(&mut self) {
        for (i, c) in self.sel.iter_mut().enumerate() {
            *c = self.batch.selection_probability(i);
        }
    }

    /// One guide sample and two pdfs per vertex of the decoded batch; true if both worked.
    #[inline]
    fn sample_and_pdf(&mut self, field: &GuidingField, inputs: &VertexInputs) -> bool {
        field
            .sample_decoded(&self.batch, &inputs.lanes, &inputs.us, &mut self.samples)
            .is_ok()
            && field
                .pdf_decoded(&self.batch, &inputs.lanes2, &inputs.dirs, &mut self.pdfs)
                .is_ok()
    }

    /// Keeps the outputs (and `ok`) alive for the optimiser.
    #[inline]
    fn consume(&self, ok: bool) {
        black_box((ok, &self.samples, &self.pdfs, &self.sel));
    }
}

/// One guide of the vertex micro-benchmark.
struct VertexModel {
    rep: Representation,
    size: ModelSize,
    target: guiding::Target,
}

/// The median seconds of one batch of `N` vertices of a [`VertexModel`].
struct VertexTimes {
    /// Batched decode, selection, sample and pdfs.
    batched: f64,
    /// The same per query (`distribution` + `sample` + two `pdf`).
    per_query: f64,
    /// Radiance targets: lookups in a guide cache of the `N` query points instead of the
    /// network.
    cached: Option<f64>,
    /// Compact radiance guides: scattered lookups in a cache the size of a real scene's, with
    /// its cell count.
    large: Option<(usize, f64)>,
}

impl VertexModel {
    /// Builds the guide (untrained, one thread) and times its vertex batches.
    fn time(
        &self,
        inputs: &VertexInputs,
        repeats: usize,
    ) -> Result<VertexTimes, guiding::GuidingError> {
        let config = GuidingConfig {
            representation: self.rep,
            target: self.target,
            ..GuidingConfig::npm_radiance()
        }
        .with_size(self.size)
        .with_training(FieldConfig::DEFAULT.with_threads(1));
        let field = GuidingField::new(config, [-1.0; 3], [1.0; 3])?;
        let mut outputs = VertexOutputs::new();
        let batched = median_secs(repeats, || {
            field.decode_batch(&inputs.queries, &mut outputs.batch);
            outputs.select();
            let ok = outputs.sample_and_pdf(&field, inputs);
            outputs.consume(ok);
        });
        let per_query = median_secs(repeats.min(3), || {
            let mut acc = 0.0f32;
            for (i, q) in inputs.queries.iter().enumerate() {
                let d = field.distribution(q);
                acc += d.selection_probability()
                    + d.sample(inputs.us[i]).pdf
                    + d.pdf(inputs.dirs[i])
                    + d.pdf(inputs.dirs[N + i]);
            }
            black_box(acc);
        });
        // The guide cache (radiance targets): lookup with jitter instead of the
        // network, the cosine product already in the lanes for NPM; then the same in
        // a cache the size of a real scene's (tens of thousands of cells, megabytes:
        // the lookups and lanes come from memory, not L2).
        let options = guiding::CacheOptions {
            cosine_product: true,
            ..guiding::CacheOptions::default()
        };
        let mut time_cached =
            |cache: &guiding::GuideCache, queries: &[QueryPoint], jitter: &[Vec3]| {
                let mut missed = Vec::new();
                median_secs(repeats, || {
                    let ok = cache
                        .decode_batch(&field, queries, jitter, &mut outputs.batch, &mut missed)
                        .is_ok();
                    outputs.select();
                    let ok = ok && outputs.sample_and_pdf(&field, inputs);
                    outputs.consume(ok);
                })
            };
        let radiance = self.target == guiding::Target::Radiance;
        let cached = if radiance {
            let cache = field.build_cache(&inputs.queries, &options)?;
            Some(time_cached(&cache, &inputs.queries, &unit_points(37, N)))
        } else {
            None
        };
        let large = if radiance && self.size == ModelSize::Compact {
            let points = guiding_bench::inputs::queries(41, LARGE_CACHE_POINTS);
            let cache = field.build_cache(&points, &options)?;
            // Queries at build points in a scattered order (an odd multiplier
            // permutes the power-of-two index range): every lookup hits a cell.
            let picks: Vec<QueryPoint> = (0..N)
                .map(|i| points[(i * 40_503 + 17) % LARGE_CACHE_POINTS])
                .collect();
            Some((
                cache.cells(),
                time_cached(&cache, &picks, &unit_points(43, N)),
            ))
        } else {
            None
        };
        Ok(VertexTimes {
            batched,
            per_query,
            cached,
            large,
        })
    }
}

impl VertexTimes {
    /// The report's entries in ns per vertex, each against one ray (`ray`, ns): the large
    /// cache, the small cache, then the batched decode (with the per-query path in its note).
    fn results(&self, model: &VertexModel, ray: Option<f64>) -> Vec<MicroResult> {
        let VertexModel { rep, size, target } = model;
        // One entry: what answered the vertex, its ns per vertex, and the note.
        let result = |what: &str, ns: f64, note: String| MicroResult {
            group: "vertex",
            name: format!("{rep:?} {size:?} {target:?}: guided vertex ({what})"),
            value: ns,
            unit: "ns (1 thread)",
            ratio: ray.map(|r| ns / r),
            note,
        };
        let mut out = Vec::new();
        if let Some((cells, secs)) = self.large {
            let ns_l = secs * 1e9 / N as f64;
            let what = format!("guide cache of {cells} cells");
            out.push(result(
                &what,
                ns_l,
                format!(
                    "× one ray; {N} scattered lookups in a cache built from \
                     {LARGE_CACHE_POINTS} points (a real scene's size)"
                ),
            ));
        }
        let ns = self.batched * 1e9 / N as f64;
        let ns_q = self.per_query * 1e9 / N as f64;
        if let Some(c) = self.cached {
            let ns_c = c * 1e9 / N as f64;
            let tabulated = if matches!(rep, Representation::DfNearest | Representation::DfLinear) {
                ", tabulated DF cells"
            } else {
                ""
            };
            out.push(result(
                "guide cache",
                ns_c,
                format!(
                    "× one ray; jittered lookup in a {N}-cell cache (resolution 64{tabulated}), \
                     {:.1}× faster than the batched decode",
                    ns / ns_c
                ),
            ));
        }
        let note = format!(
            "× one ray; per-query path {ns_q:.0} ns ({:.1}× the batched)",
            ns_q / ns
        );
        out.push(result("batched", ns, note));
        out
    }
}

/// The MLP of NPM's paper size (`Mlp<32, 64, 32, 3>`, the criterion bench
/// `mlp` times the same [`MlpWorkload`]): GFLOP/s of the per-query kernel
/// (the baseline) and of the batch kernel `BatchKernel::detect` picks, with
/// the share of this core's FMA peak measured in the same process.
fn mlp(quick: bool) -> Vec<MicroResult> {
    type Net = MlpWorkload<32, 64, 32, 3>;
    let repeats = if quick { 3 } else { 7 };
    let mut w = Net::new();
    let flops = (Net::INFER_FLOPS * BATCH) as f64;
    let per_query = median_secs(repeats, || w.infer(None));
    let batched = median_secs(repeats, || w.infer(Some(BatchKernel::detect())));
    let peak = fma_peak(if quick { 3 } else { 10 });
    let note = match peak {
        Some(p) => format!(
            "measured 1-core FMA peak {:.0} GFLOP/s (12 × {}-lane FMA chains)",
            p.flops * 1e-9,
            p.lanes
        ),
        None => "peak unknown (no AVX2 + FMA)".into(),
    };
    let mut out = Vec::new();
    for (name, secs) in [
        (
            format!("MLP {} per-query (baseline)", Net::name()),
            per_query,
        ),
        (format!("MLP {} batched", Net::name()), batched),
    ] {
        let gflops = flops / secs * 1e-9;
        out.push(MicroResult {
            group: "mlp",
            name,
            value: gflops,
            unit: "GFLOP/s (1 thread)",
            ratio: Some(per_query / secs),
            note: match peak {
                Some(p) => format!("{:.0} % of the {note}", 100.0 * gflops / (p.flops * 1e-9)),
                None => note.clone(),
            },
        });
    }
    out
}

/// Runs every micro-benchmark (`quick`: fewer repeats, compact models only).
///
/// # Errors
/// If a guiding field cannot be built (never with the built-in configurations).
pub fn run(quick: bool) -> Result<Vec<MicroResult>, guiding::GuidingError> {
    let mut out = distributions(quick);
    out.extend(guided_vertex(quick)?);
    out.extend(models(quick)?);
    out.push(vmf_loss_gradient(quick));
    out.extend(mlp(quick));
    Ok(out)
}

/// ns per sample of NPM's loss gradient `∇_y ln q(ω)` (8 vMF lobes,
/// [`VmfGradientWorkload`], also the criterion bench `mixture_batch`): the
/// vectorised batch kernel the training runs, next to the per-sample
/// reference `VmfMixture::grad_log_pdf` in the same process (the ratio).
fn vmf_loss_gradient(quick: bool) -> MicroResult {
    let repeats = if quick { 3 } else { 7 };
    let mut w = VmfGradientWorkload::new();
    let n = w.len() as f64;
    let batched = median_secs(repeats, || w.batched());
    let per_sample = median_secs(repeats, || {
        black_box(w.per_sample());
    });
    MicroResult {
        group: "model",
        name: "NPM loss gradient of 8 vMF lobes: batched kernel".into(),
        value: batched * 1e9 / n,
        unit: "ns/sample (1 thread)",
        ratio: Some(per_sample / batched),
        note: format!(
            "speed-up over the per-sample VmfMixture::grad_log_pdf ({:.0} ns/sample)",
            per_sample * 1e9 / n
        ),
    }
}
