//! ns per mixture density and per sample, 4096 lanes over 256 decoded
//! mixtures, one thread: the per-lane reference loop (`pdf` / `sample` per
//! lane, what a renderer without the batch API runs) against
//! `model::mixture_batch` (8 pairs per block, runtime dispatch), in the same
//! run.
//!
//! Run: `cargo bench -p guiding-bench --bench mixture_batch`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_bench::gradient::VmfGradientWorkload;
use guiding_bench::inputs::{directions, raw_rows, unit_pairs, BATCH};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::model::mixture_batch::{
    nasg_pdf_batch, nasg_sample_batch, vmf_pdf_batch, vmf_sample_batch,
};
use guiding_core::rng::Rng;
use std::hint::black_box;

const N: usize = BATCH;
const MIXTURES: usize = 256;

struct Inputs {
    lanes: Vec<u32>,
    dirs: Vec<Vec3>,
    us: Vec<Vec2>,
}

fn mixture_batch(c: &mut Criterion) {
    let nasg: Vec<NasgMixture<8>> = (0..MIXTURES as u32)
        .map(|m| NasgMixture::decode(&raw_rows::<8, NASG_RAW_PER_LOBE>(1000 + m, 0.0), 0.0))
        .collect();
    let vmf: Vec<VmfMixture<8>> = (0..MIXTURES as u32)
        .map(|m| VmfMixture::decode(&raw_rows::<8, VMF_RAW_PER_LOBE>(2000 + m, 0.0)))
        .collect();
    let mut rng = Rng::new(5);
    let inp = Inputs {
        lanes: (0..N).map(|_| rng.next_u32() % MIXTURES as u32).collect(),
        dirs: directions(7, N),
        us: unit_pairs(9, N),
    };
    let mut pdfs = vec![0.0f32; N];
    let empty = DirectionSample {
        direction: Vec3::ZERO,
        pdf: 0.0,
    };
    let mut samples = vec![empty; N];
    let mut group = c.benchmark_group("mixture_batch");
    group.throughput(Throughput::Elements(N as u64));
    macro_rules! pair {
        ($name:literal, $mix:expr, $batch_pdf:ident, $batch_sample:ident) => {
            group.bench_function(concat!($name, "_pdf_per_lane"), |b| {
                b.iter(|| {
                    for ((o, &l), &d) in pdfs.iter_mut().zip(&inp.lanes).zip(&inp.dirs) {
                        *o = $mix[l as usize].pdf(black_box(d));
                    }
                    black_box(&pdfs);
                })
            });
            group.bench_function(concat!($name, "_pdf_batch"), |b| {
                b.iter(|| {
                    $batch_pdf(&$mix, &inp.lanes, black_box(&inp.dirs), &mut pdfs);
                    black_box(&pdfs);
                })
            });
            group.bench_function(concat!($name, "_sample_per_lane"), |b| {
                b.iter(|| {
                    for ((o, &l), &u) in samples.iter_mut().zip(&inp.lanes).zip(&inp.us) {
                        *o = $mix[l as usize].sample(black_box(u));
                    }
                    black_box(&samples);
                })
            });
            group.bench_function(concat!($name, "_sample_batch"), |b| {
                b.iter(|| {
                    $batch_sample(&$mix, &inp.lanes, black_box(&inp.us), &mut samples);
                    black_box(&samples);
                })
            });
        };
    }
    pair!("nasg_k8", nasg, nasg_pdf_batch, nasg_sample_batch);
    pair!("vmf_k8", vmf, vmf_pdf_batch, vmf_sample_batch);
    group.finish();
}

/// NPM's loss gradient of 8 vMF lobes ([`VmfGradientWorkload`], also in
/// `host-demo bench`): the per-sample reference against the batched kernel.
fn vmf_gradient(c: &mut Criterion) {
    let mut w = VmfGradientWorkload::new();
    let mut group = c.benchmark_group("vmf_loss_gradient");
    group.throughput(Throughput::Elements(w.len() as u64));
    group.bench_function("per_sample", |b| b.iter(|| black_box(w.per_sample())));
    group.bench_function("batch", |b| b.iter(|| w.batched()));
    group.finish();
}

criterion_group!(benches, mixture_batch, vmf_gradient);
criterion_main!(benches);
