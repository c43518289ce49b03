//! ns per sample + pdf of every directional distribution
//! ([`DistributionCase::all`]), against the uniform sphere warp as the
//! in-process baseline: one sample and the density of the sampled direction
//! per random pair, as a guided vertex asks of its guide.
//!
//! Run: `cargo bench -p guiding-bench --bench distributions`. Each iteration
//! runs the whole table of 4096 random pairs, so the branch predictor cannot
//! memorise one path; criterion reports time per pair. `host-demo bench`
//! times the same cases for its report.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_bench::distribution::DistributionCase;
use guiding_bench::inputs::{unit_pairs, BATCH};
use std::hint::black_box;

fn distributions(c: &mut Criterion) {
    let us = unit_pairs(7, BATCH);
    let mut group = c.benchmark_group("sample_and_pdf");
    group.throughput(Throughput::Elements(BATCH as u64));
    for case in DistributionCase::all() {
        group.bench_function(case.name(), |b| {
            b.iter(|| black_box(case.sample_then_pdf(black_box(&us))));
        });
    }
    group.finish();
}

criterion_group!(benches, distributions);
criterion_main!(benches);
