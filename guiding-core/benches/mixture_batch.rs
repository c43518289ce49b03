//! ns per mixture density and per sample, 4096 lanes over 256 decoded
//! mixtures, one thread: the per-lane reference loop (`pdf` / `sample` per
//! lane, what a renderer without the batch API runs) against
//! `model::mixture_batch` (8 pairs per block, runtime dispatch), in the same
//! run.
//!
//! Run: `cargo bench -p guiding-core --features std --bench mixture_batch`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::model::mixture_batch::{
    nasg_pdf_batch, nasg_sample_batch, vmf_pdf_batch, vmf_sample_batch,
};
use guiding_core::sphere::square_to_uniform_sphere;
use std::hint::black_box;

const N: usize = 4096;
const MIXTURES: usize = 256;

/// A 32-bit LCG: plenty for benchmark inputs.
struct Lcg(u32);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (self.0 >> 8) as f32 / 16_777_216.0
    }
}

struct Inputs {
    lanes: Vec<u32>,
    dirs: Vec<Vec3>,
    us: Vec<Vec2>,
}

fn inputs(rng: &mut Lcg) -> Inputs {
    Inputs {
        lanes: (0..N)
            .map(|_| (rng.next() * MIXTURES as f32) as u32 % MIXTURES as u32)
            .collect(),
        dirs: (0..N)
            .map(|_| square_to_uniform_sphere(Vec2::new(rng.next(), rng.next())))
            .collect(),
        us: (0..N).map(|_| Vec2::new(rng.next(), rng.next())).collect(),
    }
}

fn mixture_batch(c: &mut Criterion) {
    let mut rng = Lcg(5);
    let nasg: Vec<NasgMixture<8>> = (0..MIXTURES)
        .map(|_| {
            let mut raw = [[0.0f32; NASG_RAW_PER_LOBE]; 8];
            for r in raw.iter_mut().flatten() {
                *r = 4.0 * (rng.next() - 0.5);
            }
            NasgMixture::decode(&raw, 0.0)
        })
        .collect();
    let vmf: Vec<VmfMixture<8>> = (0..MIXTURES)
        .map(|_| {
            let mut raw = [[0.0f32; VMF_RAW_PER_LOBE]; 8];
            for r in raw.iter_mut().flatten() {
                *r = 4.0 * (rng.next() - 0.5);
            }
            VmfMixture::decode(&raw)
        })
        .collect();
    let inp = inputs(&mut rng);
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

criterion_group!(benches, mixture_batch);
criterion_main!(benches);
