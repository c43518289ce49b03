//! Throughput of the CPU runtime ([`Field`]) with the paper-size models
//! (NPM's dense grid, 4.1 M parameters, + each model's MLPs):
//!
//! - `field_inference`: guided-direction sampling (grid + MLP + decode +
//!   sample) and pdf evaluation of 4096 queries on **one** thread —
//!   queries/s per core;
//! - `field_training`: one `add_samples` + `update` of 2¹⁴ samples (one Adam
//!   step, default configuration) with one thread and with all threads —
//!   training samples/s.
//!
//! After the Criterion groups a summary table repeats both measurements
//! (median of a few runs, wall clock) and adds the implied GFLOP/s of the
//! MLP part of inference (`2 · MACS` of the networks a `sample` runs, per
//! query).
//!
//! Run: `cargo bench -p guiding-bench --bench field`
//! (`-- field_inference` for one group; the summary always runs;
//! `FIELD_BENCH_SUMMARY_ONLY=1` skips the Criterion groups).

use criterion::{Criterion, Throughput};
use guiding_bench::inputs::{self, directions, training_samples, unit_pairs, BATCH, SCENE_BOX};
use guiding_bench::timing::median_secs;
use guiding_core::field::{Field, FieldConfig};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::mlp::Mlp;
use guiding_core::model::df::{DfRadiance, DF_CONDITIONAL_BINS, DF_MARGINAL_BINS};
use guiding_core::model::nasg::{NasgProduct, NASG_OUTPUTS};
use guiding_core::model::npm::{NpmRadiance, NPM_OUTPUTS};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;
use std::hint::black_box;
use std::time::Duration;

const LO: [f32; 3] = SCENE_BOX.0;
const HI: [f32; 3] = SCENE_BOX.1;
const QUERIES: usize = BATCH;
const TRAIN_BATCH: usize = 1 << 14;

/// Multiply–adds of the networks one `sample` call evaluates.
const NPM_MACS: usize = Mlp::<32, 64, NPM_OUTPUTS, 3>::MACS;
const NASG_MACS: usize = Mlp::<64, 128, NASG_OUTPUTS, 4>::MACS;
/// Marginal + conditional (once; the cache is not used for sampling).
const DF_MACS: usize =
    Mlp::<32, 64, DF_MARGINAL_BINS, 3>::MACS + Mlp::<44, 64, DF_CONDITIONAL_BINS, 3>::MACS;

/// The queries of one pass, a random pair for each sample and a direction
/// for each pdf.
fn queries(seed: u32) -> (Vec<QueryPoint>, Vec<Vec2>, Vec<Vec3>) {
    (
        inputs::queries(seed, QUERIES),
        unit_pairs(seed + 1, QUERIES),
        directions(seed + 2, QUERIES),
    )
}

fn field<M: GuidingModel + Send + Sync>(model: M, threads: usize) -> Field<M> {
    let config = FieldConfig::DEFAULT
        .with_batch_size(TRAIN_BATCH)
        .with_threads(threads);
    Field::new(model, config).expect("valid configuration")
}

/// A field trained for two steps, so the EMA weights are not the init.
fn warm_field<M: GuidingModel + Send + Sync>(model: M) -> Field<M> {
    let mut f = field(model, 0);
    for k in 0..2 {
        f.add_samples(&training_samples(100 + k, 4096));
        f.update();
    }
    let config = *f.config();
    Field::from_params(model, config.with_threads(1), f.ema_params().to_vec())
        .expect("finite parameters")
}

/// An output buffer for [`QUERIES`] samples.
fn sample_buffer() -> Vec<DirectionSample> {
    let unset = DirectionSample {
        direction: Vec3::Z,
        pdf: 0.0,
    };
    vec![unset; QUERIES]
}

fn bench_inference<M: GuidingModel + Send + Sync>(c: &mut Criterion, name: &str, model: M) {
    let f = warm_field(model);
    let (qs, us, ds) = queries(1);
    let mut out = sample_buffer();
    let mut pdfs = vec![0.0f32; QUERIES];
    let mut group = c.benchmark_group("field_inference");
    group.throughput(Throughput::Elements(QUERIES as u64));
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    group.sample_size(20);
    group.bench_function(format!("{name}/sample_1_thread"), |b| {
        b.iter(|| {
            f.sample_batch(black_box(&qs), &us, &mut out);
            black_box(&mut out);
        });
    });
    group.bench_function(format!("{name}/pdf_1_thread"), |b| {
        b.iter(|| {
            f.pdf_batch(black_box(&qs), &ds, &mut pdfs);
            black_box(&mut pdfs);
        });
    });
    group.finish();
}

fn bench_training<M: GuidingModel + Send + Sync>(c: &mut Criterion, name: &str, model: M) {
    let samples = training_samples(7, TRAIN_BATCH);
    let mut group = c.benchmark_group("field_training");
    group.throughput(Throughput::Elements(TRAIN_BATCH as u64));
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(5));
    group.sample_size(10);
    for threads in [1, 0] {
        let mut f = field(model, threads);
        let label = if threads == 1 {
            "1_thread".to_string()
        } else {
            format!("{}_threads", f.threads())
        };
        group.bench_function(format!("{name}/{label}"), |b| {
            b.iter(|| {
                f.add_samples(black_box(&samples));
                black_box(f.update());
            });
        });
    }
    group.finish();
}

fn summary_row<M: GuidingModel + Send + Sync>(name: &str, model: M, macs: usize) {
    let f = warm_field(model);
    let (qs, us, _) = queries(2);
    let mut out = sample_buffer();
    let s = median_secs(7, || f.sample_batch(black_box(&qs), &us, &mut out));
    let qps = QUERIES as f64 / s;
    let gflops = qps * (2 * macs) as f64 * 1e-9;
    let samples = training_samples(9, TRAIN_BATCH);
    let train_rate = |threads: usize| {
        let mut f = field(model, threads);
        let t = median_secs(3, || {
            f.add_samples(&samples);
            f.update();
        });
        (f.threads(), TRAIN_BATCH as f64 / t)
    };
    let (_, one) = train_rate(1);
    let (n, all) = train_rate(0);
    println!(
        "{name:<6} {:>9}  {qps:>12.0}  {gflops:>9.2}  {one:>12.0}  {all:>12.0} ({n} thr)  {:>5.2}x",
        model.param_count(),
        all / one
    );
}

fn summary() {
    println!();
    println!("field summary (median wall clock; one sample() = grid + MLP + decode + sample)");
    println!(
        "{:<6} {:>9}  {:>12}  {:>9}  {:>12}  {:>12}",
        "model", "params", "queries/s/c", "MLP GF/s", "train 1 thr", "train all"
    );
    summary_row("NPM", NpmRadiance::paper(LO, HI), NPM_MACS);
    summary_row("NASG", NasgProduct::paper(LO, HI), NASG_MACS);
    summary_row(
        "DF-N",
        DfRadiance::paper(LO, HI, Interpolation::Nearest),
        DF_MACS,
    );
    summary_row(
        "DF-L",
        DfRadiance::paper(LO, HI, Interpolation::Linear),
        DF_MACS,
    );
}

fn main() {
    if std::env::var_os("FIELD_BENCH_SUMMARY_ONLY").is_none() {
        let mut c = Criterion::default().configure_from_args();
        // `bench(c, name, model)` for each paper model (distinct types).
        macro_rules! each_model {
            ($bench:ident) => {
                $bench(&mut c, "npm", NpmRadiance::paper(LO, HI));
                $bench(&mut c, "nasg", NasgProduct::paper(LO, HI));
                $bench(
                    &mut c,
                    "df_n",
                    DfRadiance::paper(LO, HI, Interpolation::Nearest),
                );
                $bench(
                    &mut c,
                    "df_l",
                    DfRadiance::paper(LO, HI, Interpolation::Linear),
                );
            };
        }
        each_model!(bench_inference);
        each_model!(bench_training);
        c.final_summary();
    }
    summary();
}
