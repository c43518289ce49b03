//! Throughput of the MLP kernels, one thread, batches of 4096 queries, for
//! the renderer's compact NPM networks (`Mlp<16, 32, 32, 2>`, `Mlp<48, 32,
//! 32, 2>`) and the paper size (`Mlp<32, 64, 32, 3>`): the per-query
//! [`Mlp::infer`](guiding_core::mlp::Mlp::infer) / `forward` + `backward`
//! (the shader kernels run on the CPU, the baseline) and every available
//! [`BatchKernel`], for inference and for a training pass (forward with
//! contexts + backward). The workloads are [`MlpWorkload`], which
//! `host-demo bench` times too.
//!
//! Run: `cargo bench -p guiding-bench --bench mlp`.
//!
//! First a summary table, timed in-process: queries/s, GFLOP/s and the
//! fraction of the **measured FMA peak** of this core ([`fma_peak`], timed
//! before and after the table, the better kept, as the machine may be
//! shared). Then criterion groups `mlp_infer/<size>` and `mlp_train/<size>`
//! over the same work, throughput in flop/s ("elem/s"). `MLP_BENCH_SUMMARY=0`
//! skips the table (e.g. to profile one criterion benchmark alone).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_bench::inputs::BATCH;
use guiding_bench::mlp::MlpWorkload;
use guiding_bench::timing::{best_secs_per_call, fma_peak, FmaPeak};
use guiding_core::mlp::BatchKernel;
use std::time::Duration;

/// The two harnesses of this bench over one size's workload.
trait Timed {
    /// The summary table rows: `(label, flop/s, queries/s)`.
    fn summary(&mut self, rows: &mut Vec<(String, f64, f64)>);
    /// The criterion groups `mlp_infer/<size>` and `mlp_train/<size>`.
    fn criterion_groups(&mut self, c: &mut Criterion);
}

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize> Timed
    for MlpWorkload<IN, WIDTH, OUT, HIDDEN>
{
    fn summary(&mut self, rows: &mut Vec<(String, f64, f64)>) {
        for (train, flops_per_query) in [(false, Self::INFER_FLOPS), (true, Self::TRAIN_FLOPS)] {
            for kernel in Self::kernels() {
                let t = best_secs_per_call(30, || {
                    if train {
                        self.train(kernel);
                    } else {
                        self.infer(kernel);
                    }
                });
                let qps = BATCH as f64 / t;
                let what = if train { "forward+backward" } else { "infer" };
                rows.push((
                    format!(
                        "{:<18} {what:<17} {:<10}",
                        Self::name(),
                        Self::label(kernel)
                    ),
                    qps * flops_per_query as f64,
                    qps,
                ));
            }
        }
    }

    fn criterion_groups(&mut self, c: &mut Criterion) {
        for (train, flops) in [(false, Self::INFER_FLOPS), (true, Self::TRAIN_FLOPS)] {
            let group = if train { "mlp_train" } else { "mlp_infer" };
            let mut g = c.benchmark_group(format!("{group}/{}", Self::name()));
            g.throughput(Throughput::Elements((flops * BATCH) as u64));
            g.warm_up_time(Duration::from_millis(500));
            g.measurement_time(Duration::from_secs(2));
            g.sample_size(20);
            for kernel in Self::kernels() {
                g.bench_function(Self::label(kernel), |b| {
                    if train {
                        b.iter(|| self.train(kernel));
                    } else {
                        b.iter(|| self.infer(kernel));
                    }
                });
            }
            g.finish();
        }
    }
}

fn better(a: Option<FmaPeak>, b: Option<FmaPeak>) -> Option<FmaPeak> {
    match (a, b) {
        (Some(x), Some(y)) => Some(if y.flops > x.flops { y } else { x }),
        (x, y) => x.or(y),
    }
}

fn mlp(c: &mut Criterion) {
    let mut a = MlpWorkload::<16, 32, 32, 2>::new();
    let mut b = MlpWorkload::<48, 32, 32, 2>::new();
    let mut p = MlpWorkload::<32, 64, 32, 3>::new();
    if std::env::var("MLP_BENCH_SUMMARY").as_deref() != Ok("0") {
        let before = fma_peak(20);
        let mut rows = Vec::new();
        a.summary(&mut rows);
        b.summary(&mut rows);
        p.summary(&mut rows);
        let peak = better(before, fma_peak(20));
        match peak {
            Some(pk) => println!(
                "batch {BATCH}, one thread; % of the measured {} FMA peak ({:.1} GFLOP/s = \
                 {:.1} flop/cycle at {:.2} GHz, clock from one dependent FMA chain); \
                 detect() = {:?}",
                pk.name,
                pk.flops / 1e9,
                pk.flops / 1e9 / pk.clock_ghz,
                pk.clock_ghz,
                BatchKernel::detect()
            ),
            None => println!("batch {BATCH}, one thread; FMA peak not measured (no AVX2 + FMA)"),
        }
        for (label, flops, qps) in rows {
            let share = peak.map_or(f64::NAN, |pk| 100.0 * flops / pk.flops);
            println!(
                "{label} {qps:>12.4e} queries/s {:>7.1} GFLOP/s {share:>5.1} % of peak",
                flops / 1e9
            );
        }
    }
    a.criterion_groups(c);
    b.criterion_groups(c);
    p.criterion_groups(c);
}

criterion_group!(benches, mlp);
criterion_main!(benches);
