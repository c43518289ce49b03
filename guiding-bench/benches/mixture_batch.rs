//! ns per mixture density and per sample, 4096 lanes over 256 decoded
//! mixtures, one thread: the per-lane reference loop (`pdf` / `sample` per
//! lane, what a renderer without the batch API runs) against
//! `model::mixture_batch` (8 pairs per block, runtime dispatch), in the same
//! run.
//!
//! Run: `cargo bench -p guiding-bench --bench mixture_batch`.

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, Criterion, Throughput};
use guiding_bench::gradient::VmfGradientWorkload;
use guiding_bench::inputs::{directions, raw_rows, unit_pairs, BATCH};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::mixture::LobeMixture;
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
    let mut group = c.benchmark_group("mixture_batch");
    group.throughput(Throughput::Elements(N as u64));
    bench_family(&mut group, "nasg_k8", &nasg, &inp, NASG_KERNELS);
    bench_family(&mut group, "vmf_k8", &vmf, &inp, VMF_KERNELS);
    group.finish();
}

/// A family's batch kernels: densities and samples.
type Kernels<M> = (
    fn(&[M], &[u32], &[Vec3], &mut [f32]),
    fn(&[M], &[u32], &[Vec2], &mut [DirectionSample]),
);

const NASG_KERNELS: Kernels<NasgMixture<8>> = (nasg_pdf_batch, nasg_sample_batch);
const VMF_KERNELS: Kernels<VmfMixture<8>> = (vmf_pdf_batch, vmf_sample_batch);

/// A family's densities (`{name}_pdf_…`) and samples (`{name}_sample_…`),
/// each per lane and batched.
fn bench_family<M: LobeMixture>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    mixtures: &[M],
    inp: &Inputs,
    (pdf, sample): Kernels<M>,
) {
    let (pdf_id, sample_id) = (format!("{name}_pdf"), format!("{name}_sample"));
    let (lanes, dirs, us) = (&inp.lanes, &inp.dirs, &inp.us);
    bench_lanes(group, &pdf_id, mixtures, lanes, dirs, M::pdf, pdf);
    bench_lanes(group, &sample_id, mixtures, lanes, us, M::sample, sample);
}

/// `{name}_per_lane`, `per_lane(mixtures[lane], x)` for each (lane, x) (what
/// a renderer without the batch API runs), against `{name}_batch`, the
/// kernel `batch` over all of them.
fn bench_lanes<M, X: Copy, T>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    mixtures: &[M],
    lanes: &[u32],
    xs: &[X],
    per_lane: impl Fn(&M, X) -> T,
    batch: impl Fn(&[M], &[u32], &[X], &mut [T]),
) {
    // Starts as the per-lane results; both loops overwrite it.
    let mut out: Vec<T> = lanes
        .iter()
        .zip(xs)
        .map(|(&l, &x)| per_lane(&mixtures[l as usize], x))
        .collect();
    group.bench_function(format!("{name}_per_lane"), |b| {
        b.iter(|| {
            for ((o, &l), &x) in out.iter_mut().zip(lanes).zip(xs) {
                *o = per_lane(&mixtures[l as usize], black_box(x));
            }
            black_box(&out);
        })
    });
    group.bench_function(format!("{name}_batch"), |b| {
        b.iter(|| {
            batch(mixtures, lanes, black_box(xs), &mut out);
            black_box(&out);
        })
    });
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
