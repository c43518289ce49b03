//! Micro-benchmarks of the benchmark report: ns per sample+pdf of each
//! distribution (ratio to the uniform-sphere warp measured in the same
//! process), queries/s and training samples/s of each guiding model through
//! the embedding facade, and MLP GFLOP/s against the core's nominal peak.
//!
//! Timing: each measurement is the median of `repeats` wall-clock runs of a
//! fixed workload after one warm-up run. Wall clock on a shared machine is
//! noisy; the ratios against a baseline run in the same process are the
//! numbers to compare across machines.

use glam::{Vec2, Vec3};
use guiding::{
    FieldConfig, GuidingConfig, GuidingField, ModelSize, Representation, TrainingSample,
};
use guiding_core::factorised::FactorisedTable;
use guiding_core::math::INV_FOUR_PI;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::mlp::Mlp;
use guiding_core::model::npm::{NPM_LOBES, NPM_OUTPUTS};
use guiding_core::model::QueryPoint;
use guiding_core::pdf1d::Interpolation;
use guiding_core::rng::Rng;
use guiding_core::sphere::{square_to_uniform_sphere, UNIFORM_SPHERE_PDF};
use std::hint::black_box;
use std::time::Instant;

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

const TABLE: usize = 4096;

fn table(seed: u32) -> Vec<Vec2> {
    let mut rng = Rng::new(seed);
    (0..TABLE)
        .map(|_| Vec2::new(rng.next_f32(), rng.next_f32()))
        .collect()
}

/// Median seconds of `repeats` runs of `f` (after one warm-up).
fn median_secs(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// ns per sample+pdf of `f` over the random table, `rounds` passes per run.
fn ns_per_call(repeats: usize, rounds: usize, us: &[Vec2], f: impl Fn(Vec2) -> (Vec3, f32)) -> f64 {
    let secs = median_secs(repeats, || {
        let mut acc = 0.0f32;
        for _ in 0..rounds {
            for &u in us {
                let (d, p) = f(black_box(u));
                acc += d.x + p;
            }
        }
        black_box(acc);
    });
    secs * 1e9 / (rounds * us.len()) as f64
}

fn random_raw<const K: usize, const R: usize>(seed: u32, offset_of_1: f32) -> [[f32; R]; K] {
    let mut rng = Rng::new(seed);
    let mut raw = [[0.0; R]; K];
    for lobe in &mut raw {
        for v in lobe.iter_mut() {
            *v = 4.0 * (rng.next_f32() - 0.5);
        }
        lobe[1] += offset_of_1;
    }
    raw
}

fn distributions(quick: bool) -> Vec<MicroResult> {
    let (repeats, rounds) = if quick { (3, 8) } else { (7, 64) };
    let us = table(7);
    let base = ns_per_call(repeats, rounds, &us, |u| {
        (square_to_uniform_sphere(u), UNIFORM_SPHERE_PDF)
    });
    let vmf = VmfMixture::<8>::decode(&random_raw::<8, VMF_RAW_PER_LOBE>(11, 3.0));
    let nasg = NasgMixture::<8>::decode(&random_raw::<8, NASG_RAW_PER_LOBE>(13, 0.0), 0.0);
    let mut rng = Rng::new(17);
    let marginal: [f32; 32] = core::array::from_fn(|_| 3.0 * rng.next_f32());
    let conditional: [[f32; 16]; 32] =
        core::array::from_fn(|_| core::array::from_fn(|_| 3.0 * rng.next_f32()));
    let df_n = FactorisedTable::from_logits(&marginal, &conditional, Interpolation::Nearest);
    let df_l = FactorisedTable::from_logits(&marginal, &conditional, Interpolation::Linear);
    let mut out = vec![MicroResult {
        group: "distribution",
        name: "uniform sphere (baseline)".into(),
        value: base,
        unit: "ns/sample+pdf",
        ratio: Some(1.0),
        note: "baseline".into(),
    }];
    let cases: [(&str, f64); 4] = [
        (
            "vMF mixture K=8",
            ns_per_call(repeats, rounds, &us, |u| {
                let s = vmf.sample(u);
                (s.direction, vmf.pdf(s.direction))
            }),
        ),
        (
            "NASG mixture K=8",
            ns_per_call(repeats, rounds, &us, |u| {
                let s = nasg.sample(u);
                (s.direction, nasg.pdf(s.direction))
            }),
        ),
        (
            "DF-N table 32x16",
            ns_per_call(repeats, rounds, &us, |u| {
                let s = df_n.sample(u);
                (s.direction, df_n.pdf(s.direction))
            }),
        ),
        (
            "DF-L table 32x16",
            ns_per_call(repeats, rounds, &us, |u| {
                let s = df_l.sample(u);
                (s.direction, df_l.pdf(s.direction))
            }),
        ),
    ];
    for (name, ns) in cases {
        out.push(MicroResult {
            group: "distribution",
            name: name.into(),
            value: ns,
            unit: "ns/sample+pdf",
            ratio: Some(ns / base),
            note: "× uniform sphere".into(),
        });
    }
    out
}

fn query(rng: &mut Rng) -> QueryPoint {
    let n = square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
    let wo = square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
    QueryPoint {
        position: [
            2.0 * rng.next_f32() - 1.0,
            2.0 * rng.next_f32() - 1.0,
            2.0 * rng.next_f32() - 1.0,
        ],
        roughness: rng.next_f32(),
        normal: n.to_array(),
        wo: wo.to_array(),
        ..QueryPoint::default()
    }
}

fn training_samples(n: usize, seed: u32) -> Vec<TrainingSample> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let q = query(&mut rng);
            let wi = square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()));
            let l = if wi.z > 0.9 { 10.0 } else { 0.1 };
            TrainingSample::new(q, wi.to_array(), [l; 3], INV_FOUR_PI, INV_FOUR_PI, [0.3; 3])
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
    let mut rng = Rng::new(3);
    let queries: Vec<QueryPoint> = (0..nq).map(|_| query(&mut rng)).collect();
    let us = table(5);
    let samples = training_samples(batch, 9);
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
            out.push(MicroResult {
                group: "model",
                name: format!("{rep:?} {size:?} product: decode+sample+pdf"),
                value: nq as f64 / secs,
                unit: "queries/s (1 thread)",
                ratio: None,
                note: format!("{} parameters", field.param_count()),
            });
            let secs = median_secs(repeats, || {
                field.add_samples(&samples);
                field.update();
            });
            out.push(MicroResult {
                group: "model",
                name: format!("{rep:?} {size:?} product: training"),
                value: batch as f64 / secs,
                unit: "samples/s (1 thread)",
                ratio: None,
                note: format!("batch {batch}, one Adam step"),
            });
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
    let mut rays = Vec::with_capacity(2 * TABLE);
    for _ in 0..TABLE {
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
    const N: usize = 4096;
    let mut rng = Rng::new(23);
    let queries: Vec<QueryPoint> = (0..N).map(|_| query(&mut rng)).collect();
    let us = table(29);
    let lanes: Vec<u32> = (0..N as u32).collect();
    let lanes2: Vec<u32> = (0..2 * N as u32).map(|i| i % N as u32).collect();
    let dirs: Vec<Vec3> = (0..2 * N)
        .map(|_| square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32())))
        .collect();
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
                let config = GuidingConfig {
                    representation: rep,
                    target,
                    ..GuidingConfig::npm_radiance()
                }
                .with_size(size)
                .with_training(FieldConfig::DEFAULT.with_threads(1));
                let field = GuidingField::new(config, [-1.0; 3], [1.0; 3])?;
                let mut batch = guiding::DistributionBatch::new();
                let mut samples = vec![
                    guiding::DirectionSample {
                        direction: Vec3::ZERO,
                        pdf: 0.0
                    };
                    N
                ];
                let mut pdfs = vec![0.0f32; 2 * N];
                let mut sel = vec![0.0f32; N];
                let batched = median_secs(repeats, || {
                    field.decode_batch(&queries, &mut batch);
                    for (i, c) in sel.iter_mut().enumerate() {
                        *c = batch.selection_probability(i);
                    }
                    let ok = field
                        .sample_decoded(&batch, &lanes, &us, &mut samples)
                        .is_ok()
                        && field.pdf_decoded(&batch, &lanes2, &dirs, &mut pdfs).is_ok();
                    black_box((ok, &samples, &pdfs, &sel));
                });
                let per_query = median_secs(repeats.min(3), || {
                    let mut acc = 0.0f32;
                    for (i, q) in queries.iter().enumerate() {
                        let d = field.distribution(q);
                        acc += d.selection_probability()
                            + d.sample(us[i]).pdf
                            + d.pdf(dirs[i])
                            + d.pdf(dirs[N + i]);
                    }
                    black_box(acc);
                });
                // The guide cache (radiance targets): lookup with jitter instead of the
                // network, the cosine product already in the lanes for NPM.
                let cached = if target == guiding::Target::Radiance {
                    let options = guiding::CacheOptions {
                        cosine_product: true,
                        ..guiding::CacheOptions::default()
                    };
                    let cache = field.build_cache(&queries, &options)?;
                    let jitter: Vec<Vec3> = (0..N)
                        .map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()))
                        .collect();
                    let mut missed = Vec::new();
                    Some(median_secs(repeats, || {
                        let ok = cache
                            .decode_batch(&field, &queries, &jitter, &mut batch, &mut missed)
                            .is_ok();
                        for (i, c) in sel.iter_mut().enumerate() {
                            *c = batch.selection_probability(i);
                        }
                        let ok = ok
                            && field
                                .sample_decoded(&batch, &lanes, &us, &mut samples)
                                .is_ok()
                            && field.pdf_decoded(&batch, &lanes2, &dirs, &mut pdfs).is_ok();
                        black_box((ok, &samples, &pdfs, &sel));
                    }))
                } else {
                    None
                };
                let ns = batched * 1e9 / N as f64;
                let ns_q = per_query * 1e9 / N as f64;
                if let Some(c) = cached {
                    let ns_c = c * 1e9 / N as f64;
                    out.push(MicroResult {
                        group: "vertex",
                        name: format!("{rep:?} {size:?} {target:?}: guided vertex (guide cache)"),
                        value: ns_c,
                        unit: "ns (1 thread)",
                        ratio: ray.map(|r| ns_c / r),
                        note: format!(
                            "× one ray; jittered lookup in a {N}-cell cache (resolution 64{}), \
                             {:.1}× faster than the batched decode",
                            if matches!(rep, Representation::DfNearest | Representation::DfLinear) {
                                ", tabulated DF cells"
                            } else {
                                ""
                            },
                            ns / ns_c
                        ),
                    });
                }
                out.push(MicroResult {
                    group: "vertex",
                    name: format!("{rep:?} {size:?} {target:?}: guided vertex (batched)"),
                    value: ns,
                    unit: "ns (1 thread)",
                    ratio: ray.map(|r| ns / r),
                    note: format!(
                        "× one ray; per-query path {ns_q:.0} ns ({:.1}× the batched)",
                        ns_q / ns
                    ),
                });
            }
        }
    }
    Ok(out)
}

/// Single-core f32 FMA peak measured in this process: twelve independent chains of fused
/// multiply-adds (two FMA pipes × 4 cycles of latency, with margin) as wide as the widest
/// vectors the batched MLP dispatches to (16 lanes with AVX-512F, else 8 with AVX2 + FMA), in
/// GFLOP/s (2 flops per lane per FMA), with the lane count. `None` without AVX2 + FMA.
fn measured_fma_peak_gflops() -> Option<(f64, u32)> {
    #[cfg(target_arch = "x86_64")]
    {
        const ITERS: usize = 1 << 22;
        /// Twelve chains of `$lanes`-lane FMAs in a function with `$features` enabled (the loop
        /// must sit in that function for `mul_add` to become one vector FMA per chain).
        macro_rules! fma_chains {
            ($name:ident, $features:literal, $lanes:literal) => {
                /// # Safety
                /// The CPU must support the enabled features.
                #[target_feature(enable = $features)]
                unsafe fn $name() -> f32 {
                    // 12 chains of $lanes lanes, flat so the compiler keeps one vector
                    // register per chain.
                    let mut acc = [1.0f32; 12 * $lanes];
                    let (a, b) = (black_box(0.999_999_9f32), black_box(1e-7f32));
                    for _ in 0..ITERS {
                        for x in acc.iter_mut() {
                            *x = x.mul_add(a, b);
                        }
                    }
                    acc.iter().sum()
                }
            };
        }
        fma_chains!(chains16, "avx512f,avx2,fma", 16);
        fma_chains!(chains8, "avx2,fma", 8);
        let lanes = if std::is_x86_feature_detected!("avx512f") {
            16u32
        } else if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            8
        } else {
            return None;
        };
        let secs = median_secs(5, || {
            // SAFETY: the features were checked above.
            black_box(unsafe {
                if lanes == 16 {
                    chains16()
                } else {
                    chains8()
                }
            });
        });
        Some((
            12.0 * f64::from(lanes) * 2.0 * ITERS as f64 / secs * 1e-9,
            lanes,
        ))
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

fn mlp(quick: bool) -> Vec<MicroResult> {
    type Net = Mlp<32, 64, NPM_OUTPUTS, 3>;
    let (repeats, n) = if quick { (3, 4096) } else { (7, 16384) };
    let mut rng = Rng::new(21);
    let params: Vec<f32> = (0..Net::PARAM_COUNT)
        .map(|_| 0.2 * (rng.next_f32() - 0.5))
        .collect();
    let inputs: Vec<[f32; 32]> = (0..n)
        .map(|_| core::array::from_fn(|_| rng.next_f32()))
        .collect();
    let flops = 2.0 * Net::MACS as f64 * n as f64;
    let per_query = median_secs(repeats, || {
        let mut acc = 0.0f32;
        for x in &inputs {
            acc += Net::infer(&params, 0, black_box(x))[0];
        }
        black_box(acc);
    });
    let mut outputs = vec![[0.0f32; NPM_OUTPUTS]; n];
    let batched = median_secs(repeats, || {
        Net::infer_batch(&params, 0, &inputs, &mut outputs);
        black_box(&outputs);
    });
    let peak = measured_fma_peak_gflops();
    let note = match peak {
        Some((g, lanes)) => {
            format!("measured 1-core FMA peak {g:.0} GFLOP/s (12 × {lanes}-lane FMA chains)")
        }
        None => "peak unknown (no AVX2 + FMA)".into(),
    };
    let mut out = Vec::new();
    for (name, secs, ratio_base) in [
        ("MLP 32→3×64→32 per-query (baseline)", per_query, per_query),
        ("MLP 32→3×64→32 batched", batched, per_query),
    ] {
        let gflops = flops / secs * 1e-9;
        out.push(MicroResult {
            group: "mlp",
            name: name.into(),
            value: gflops,
            unit: "GFLOP/s (1 thread)",
            ratio: Some(ratio_base / secs),
            note: match peak {
                Some((g, _)) => format!("{:.0} % of the {note}", 100.0 * gflops / g),
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

/// ns per sample of NPM's loss gradient `∇_y ln q(ω)` (8 vMF lobes):
/// the vectorised batch kernel the training runs, next to the per-sample
/// reference `VmfMixture::grad_log_pdf` in the same process (the ratio).
fn vmf_loss_gradient(quick: bool) -> MicroResult {
    use guiding_core::model::vmf_gradient::grad_log_pdf_vmf_batch;
    let (repeats, n) = if quick { (3, 2048) } else { (7, 8192) };
    let mut rng = Rng::new(31);
    let ys: Vec<[f32; NPM_OUTPUTS]> = (0..n)
        .map(|_| std::array::from_fn(|_| 6.0 * rng.next_f32() - 3.0))
        .collect();
    let dirs: Vec<Vec3> = (0..n)
        .map(|_| square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32())))
        .collect();
    let mut dys = vec![[0.0f32; NPM_OUTPUTS]; n];
    let mut lps = vec![0.0f32; n];
    let batched = median_secs(repeats, || {
        grad_log_pdf_vmf_batch(black_box(&ys), &dirs, &mut dys, &mut lps);
        black_box(&dys);
    });
    let per_sample = median_secs(repeats, || {
        let mut acc = 0.0f32;
        for (y, &d) in ys.iter().zip(&dirs) {
            let raw: [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] =
                std::array::from_fn(|k| std::array::from_fn(|r| y[k * VMF_RAW_PER_LOBE + r]));
            let mut g = [[0.0f32; VMF_RAW_PER_LOBE]; NPM_LOBES];
            acc += VmfMixture::grad_log_pdf(&raw, black_box(d), &mut g) + g[0][0];
        }
        black_box(acc);
    });
    MicroResult {
        group: "model",
        name: "NPM loss gradient of 8 vMF lobes: batched kernel".into(),
        value: batched * 1e9 / n as f64,
        unit: "ns/sample (1 thread)",
        ratio: Some(per_sample / batched),
        note: format!(
            "speed-up over the per-sample VmfMixture::grad_log_pdf ({:.0} ns/sample)",
            per_sample * 1e9 / n as f64
        ),
    }
}
