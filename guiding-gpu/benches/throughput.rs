//! Kernel throughput: the SPIR-V batch kernels on the Vulkan device against
//! the same `guiding_core::batch` functions on CPU threads, in one process.
//!
//! `cargo bench -p guiding-gpu --features shaders --bench throughput`
//! (`GUIDING_VK_DEVICE` picks the device; `-- --quick` for a small run).
//!
//! Reported per model: inference (grid + MLP, the `infer` kernel) and
//! inference + decode + sample (the `sample` kernel) in queries per second
//! for a 1280 × 720 wavefront (one query per pixel), and training samples
//! per second (`train_step`: per-sample gradients, block maxima, Adam + EMA)
//! on a batch of 2¹⁴. Then the two backends of one `guiding::GuidingField`
//! (CPU threads with the batched kernels, and the Vulkan device) through
//! the same wavefront calls ([`bench_field`]). Each figure is the median of
//! 5 runs after one warm-up;
//! GPU figures use wall time including upload and read-back (and, where
//! the queue has timestamps, the device time is printed too). The CPU
//! baseline runs the element kernels over `available_parallelism` threads.

use guiding_bench::inputs::{queries, training_samples};
use guiding_bench::timing::median_secs;
use guiding_core::batch;
use guiding_core::gradient::GradientSink;
use guiding_core::loss::Target;
use guiding_core::model::nasg::NasgCompactRadiance;
use guiding_core::model::npm::{NpmCompactRadiance, NpmRadiance};
use guiding_core::model::RawOutputs;
use guiding_core::optim::AdamConfig;
use guiding_gpu::{DeviceSelection, GpuContext, GpuModel, ModelEntryPoints, TrainOptions};

const LO: [f32; 3] = guiding_bench::inputs::SCENE_BOX.0;
const HI: [f32; 3] = guiding_bench::inputs::SCENE_BOX.1;

/// `f(i)` for `i in 0..n` over the CPU's threads.
fn cpu_parallel<T: Send>(out: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let chunk = out.len().div_ceil(threads).max(1);
    std::thread::scope(|s| {
        for (c, part) in out.chunks_mut(chunk).enumerate() {
            let f = &f;
            s.spawn(move || {
                for (k, o) in part.iter_mut().enumerate() {
                    f(c * chunk + k, o);
                }
            });
        }
    });
}

fn bench_model<M: RawOutputs + bytemuck::Pod + Sync>(
    ctx: &GpuContext,
    name: &'static str,
    model: M,
    nq: usize,
    nt: usize,
    runs: usize,
) {
    let mut params = vec![0.0f32; model.param_count()];
    model.init(&mut params, 7);
    let zeros = vec![0.0f32; params.len()];
    let mut gpu = GpuModel::new(
        ctx.clone(),
        ModelEntryPoints {
            prefix: name,
            family: M::FAMILY,
        },
        bytemuck::bytes_of(&model),
        &params,
        &zeros,
        &zeros,
        &params,
        0,
    )
    .expect("upload");
    let q = queries(1, nq);
    let r = M::RAW_OUTPUTS;

    // Inference: grid + MLP.
    let mut out = vec![0.0f32; nq * r];
    let mut device_ns = None;
    let gpu_infer = median_secs(runs, || {
        device_ns = gpu.infer(&q, &mut out).expect("infer").gpu_time_ns;
    });
    let mut rows = vec![[0.0f32; 64]; nq];
    let cpu_infer = median_secs(runs, || {
        cpu_parallel(&mut rows, |i, row| {
            model.write_raw(&params, &q[i], row, 0);
        });
    });

    // Inference + decode + sample.
    let u: Vec<[f32; 4]> = (0..nq)
        .map(|i| [(i % 97) as f32 / 97.0, (i % 89) as f32 / 89.0, 0.0, 0.0])
        .collect();
    let mut s_out = vec![[0.0f32; 4]; nq];
    let gpu_sample = median_secs(runs, || {
        gpu.sample(&q, &u, &mut s_out).expect("sample");
    });
    let cpu_sample = median_secs(runs, || {
        cpu_parallel(&mut s_out, |i, o| {
            let d = model.sample(
                &params,
                &q[i],
                guiding_core::glam::Vec2::new(u[i][0], u[i][1]),
            );
            *o = batch::pack_sample(d);
        });
    });

    // Training.
    let t = training_samples(2, nt);
    let options = TrainOptions {
        adam: AdamConfig::new(1e-3),
        ema_decay: 0.95,
        max_gradient_magnitude: 1e18,
    };
    let gpu_train = median_secs(runs, || {
        gpu.train_step(&t, &options).expect("train");
    });
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut grads = vec![vec![0.0f32; params.len()]; threads];
    let (mut p, mut m, mut v, mut ema) =
        (params.clone(), zeros.clone(), zeros.clone(), params.clone());
    let adam_args = batch::AdamArgs {
        count: params.len() as u32,
        pad: [0; 3],
        adam: options.adam,
        factors: guiding_core::optim::AdamStepFactors::new(1, &options.adam),
        gradient_scale: 1.0 / nt as f32,
        ema_alpha: 0.05,
    };
    let cpu_train = median_secs(runs, || {
        let chunk = nt.div_ceil(threads);
        std::thread::scope(|s| {
            for (c, g) in grads.iter_mut().enumerate() {
                let (t, model, params) = (&t, &model, &params);
                s.spawn(move || {
                    let end = ((c + 1) * chunk).min(nt);
                    for sample in &t[(c * chunk).min(end)..end] {
                        model.accumulate_gradient(params, sample, &mut g[..]);
                    }
                });
            }
        });
        // Reduction, then Adam + EMA over the parameters (as the GPU step).
        let n = params.len();
        let mut total = vec![0.0f32; n];
        for g in &mut grads {
            for j in 0..GradientSink::len(&g[..]) {
                total[j] += g[j];
                g[j] = 0.0;
            }
        }
        for j in 0..n {
            batch::adam_element(&mut p, &mut total, &mut m, &mut v, &mut ema, &adam_args, j);
        }
        std::hint::black_box(&p);
    });

    let per_s = |n: usize, s: f64| n as f64 / s;
    println!(
        "{name} ({} params): infer {:.3e} q/s GPU vs {:.3e} CPU ({:.2}×){}; \
         infer+decode+sample {:.3e} vs {:.3e} ({:.2}×); training {:.3e} samples/s vs {:.3e} ({:.2}×)",
        params.len(),
        per_s(nq, gpu_infer),
        per_s(nq, cpu_infer),
        cpu_infer / gpu_infer,
        device_ns.map_or(String::new(), |ns| format!(
            " [device time {:.2} ms per {nq}]",
            ns * 1e-6
        )),
        per_s(nq, gpu_sample),
        per_s(nq, cpu_sample),
        cpu_sample / gpu_sample,
        per_s(nt, gpu_train),
        per_s(nt, cpu_train),
        cpu_train / gpu_train,
    );
}

/// The embedding API's wavefront on both backends of one `GuidingField`:
/// the CPU field (the batched SIMD kernels on the field's threads) against
/// the same field moved to the device (`use_device_context`). Per wavefront
/// of `nq` queries: `decode_batch`, every lane's selection probability,
/// one `sample_decoded` and one `pdf_decoded` over all lanes (a guided
/// vertex's work; the cosine product for NPM); training: `add_samples` +
/// one `update` of one step on a batch of `nt`.
fn bench_field(
    ctx: &GpuContext,
    name: &str,
    config: guiding::GuidingConfig,
    nq: usize,
    nt: usize,
    runs: usize,
) {
    use guiding::{DistributionBatch, GuidingField};
    use guiding_core::glam::{Vec2, Vec3};
    let config = config.with_training(
        guiding::FieldConfig::DEFAULT
            .with_batch_size(nt)
            .with_steps_per_update(1)
            .with_threads(0),
    );
    let q = queries(1, nq);
    let normals: Vec<Vec3> = q.iter().map(|x| Vec3::from_array(x.normal)).collect();
    let lanes: Vec<u32> = (0..nq as u32).collect();
    let u: Vec<Vec2> = (0..nq)
        .map(|i| Vec2::new((i % 97) as f32 / 97.0, (i % 89) as f32 / 89.0))
        .collect();
    let dirs: Vec<Vec3> = q.iter().map(|x| Vec3::from_array(x.wo)).collect();
    let t = training_samples(2, nt);
    let mut result = Vec::new();
    for on_device in [false, true] {
        let mut field = GuidingField::new(config, LO, HI).expect("field");
        if on_device {
            field
                .use_device_context(ctx.clone(), guiding::DeviceFailure::Error)
                .expect("device");
        }
        let mut batch = DistributionBatch::new();
        let mut out = vec![
            guiding::DirectionSample {
                direction: Vec3::Z,
                pdf: 0.0
            };
            nq
        ];
        let mut pdfs = vec![0.0f32; nq];
        let query = median_secs(runs, || {
            field.try_decode_batch(&q, &mut batch).expect("decode");
            batch.apply_cosine_product(&normals);
            let mut c = 0.0f32;
            for i in 0..nq {
                c += batch.selection_probability(i);
            }
            std::hint::black_box(c);
            field
                .sample_decoded(&batch, &lanes, &u, &mut out)
                .expect("sample");
            field
                .pdf_decoded(&batch, &lanes, &dirs, &mut pdfs)
                .expect("pdf");
        });
        let train = median_secs(runs, || {
            field.add_samples(&t);
            field.try_update().expect("update");
        });
        result.push((query, train));
    }
    let ((cq, ct), (gq, gt)) = (result[0], result[1]);
    println!(
        "{name} field: guided wavefront (decode + selection + sample + pdf) {:.3e} vertices/s \
         device vs {:.3e} CPU backend ({:.2}x); training {:.3e} samples/s vs {:.3e} ({:.2}x)",
        nq as f64 / gq,
        nq as f64 / cq,
        cq / gq,
        nt as f64 / gt,
        nt as f64 / ct,
        ct / gt
    );
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let ctx = match GpuContext::new(DeviceSelection::Auto) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("no Vulkan device: {e}");
            return;
        }
    };
    let info = ctx.device_info();
    println!(
        "device: {} ({:?}, {}); CPU baseline: {} threads",
        info.name,
        info.device_type,
        info.driver_info,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    let (nq, nt, runs) = if quick {
        (64 * 1024, 4096, 3)
    } else {
        (1280 * 720, 1 << 14, 5)
    };
    bench_model(
        &ctx,
        "npm_compact_radiance",
        NpmCompactRadiance::new(guiding::config::compact_grid(LO, HI), Target::Radiance),
        nq,
        nt,
        runs,
    );
    bench_model(
        &ctx,
        "nasg_compact_radiance",
        NasgCompactRadiance::new(guiding::config::compact_grid(LO, HI), Target::Radiance),
        nq,
        nt,
        runs,
    );
    bench_model(
        &ctx,
        "npm_paper_radiance",
        NpmRadiance::paper(LO, HI),
        nq,
        nt,
        runs,
    );
    // The backends of one field (a guided wavefront of 64 k vertices; 16 k quick).
    let nf = if quick { 16 * 1024 } else { 64 * 1024 };
    for (name, config) in [
        (
            "npm compact radiance",
            guiding::GuidingConfig::npm_radiance(),
        ),
        ("nasg compact radiance", guiding::GuidingConfig::nasg()),
        ("df-l compact radiance", guiding::GuidingConfig::df_linear()),
    ] {
        bench_field(&ctx, name, config, nf, nt, runs);
    }
}
