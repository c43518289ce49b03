//! ns per sample+pdf of every directional distribution, against the uniform
//! sphere warp as the in-process baseline.
//!
//! Run: `cargo bench -p guiding-core --bench distributions`. Each iteration
//! draws one direction and its density from a fresh `u ∈ [0,1)²` out of a
//! fixed table of 4096, so the branch predictor cannot memorise one path.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use guiding_core::factorised::FactorisedTable;
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::lobe::nasg::{NasgLobe, NASG_EPSILON};
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::pdf1d::Interpolation;
use guiding_core::sphere::{square_to_uniform_sphere, UNIFORM_SPHERE_PDF};
use std::hint::black_box;

const BATCH: usize = 4096;

/// Deterministic random numbers (a 32-bit LCG is plenty for a benchmark
/// input table).
fn random_table(seed: u32) -> Vec<Vec2> {
    let mut s = seed;
    let mut next = move || {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (s >> 8) as f32 / 16_777_216.0
    };
    (0..BATCH).map(|_| Vec2::new(next(), next())).collect()
}

fn random_raw<const K: usize, const R: usize>(seed: u32) -> [[f32; R]; K] {
    let table = random_table(seed);
    let mut raw = [[0.0; R]; K];
    for (k, lobe) in raw.iter_mut().enumerate() {
        for (j, v) in lobe.iter_mut().enumerate() {
            let u = table[k * R + j];
            *v = 4.0 * (u.x - 0.5);
        }
    }
    raw
}

/// Runs `f` over the whole table; criterion reports time per element.
fn bench_batch<F: Fn(Vec2) -> (Vec3, f32)>(c: &mut Criterion, name: &str, f: F) {
    let us = random_table(7);
    let mut group = c.benchmark_group("sample_and_pdf");
    group.throughput(Throughput::Elements(BATCH as u64));
    group.bench_function(name, |b| {
        b.iter_batched_ref(
            || (),
            |_| {
                let mut acc = 0.0f32;
                for &u in &us {
                    let (d, p) = f(black_box(u));
                    acc += d.x + p;
                }
                black_box(acc)
            },
            BatchSize::SmallInput,
        )
    });
    group.finish();
}

fn distributions(c: &mut Criterion) {
    bench_batch(c, "baseline_uniform_sphere", |u| {
        (square_to_uniform_sphere(u), UNIFORM_SPHERE_PDF)
    });

    let lobe = VmfLobe::new(Vec3::new(0.3, -0.5, 0.8), 25.0);
    bench_batch(c, "vmf_lobe", |u| {
        let s = lobe.sample(u);
        (s.direction, s.pdf)
    });

    let mut raw = random_raw::<8, 4>(11);
    for lobe in raw.iter_mut() {
        lobe[1] += 3.0; // ln κ around 3: lobes of κ ≈ 20
    }
    let vmf8 = VmfMixture::<8>::decode(&raw);
    bench_batch(c, "vmf_mixture_k8", |u| {
        let s = vmf8.sample(u);
        (s.direction, s.pdf)
    });
    bench_batch(c, "vmf_mixture_k8_pdf_only", |u| {
        let d = square_to_uniform_sphere(u);
        (d, vmf8.pdf(d))
    });

    let nasg = NasgLobe::new(Vec3::new(0.3, -0.5, 0.8), Vec3::X, 25.0, 4.0, NASG_EPSILON);
    bench_batch(c, "nasg_lobe", |u| {
        let s = nasg.sample(u);
        (s.direction, s.pdf)
    });

    let mut raw = random_raw::<8, NASG_RAW_PER_LOBE>(13);
    for lobe in raw.iter_mut() {
        lobe[1] += 3.0; // ln λ around 3
    }
    let nasg8 = NasgMixture::<8>::decode(&raw, 0.0);
    bench_batch(c, "nasg_mixture_k8", |u| {
        let s = nasg8.sample(u);
        (s.direction, s.pdf)
    });
    bench_batch(c, "nasg_mixture_k8_pdf_only", |u| {
        let d = square_to_uniform_sphere(u);
        (d, nasg8.pdf(d))
    });
}

fn factorised(c: &mut Criterion) {
    let marginal: [[f32; 32]; 1] = random_raw::<1, 32>(21);
    let conditional: [[f32; 16]; 32] = random_raw::<32, 16>(23);
    for (name, interpolation) in [
        ("df_nearest_32x16", Interpolation::Nearest),
        ("df_linear_32x16", Interpolation::Linear),
    ] {
        let table =
            FactorisedTable::<32, 16>::from_logits(&marginal[0], &conditional, interpolation);
        bench_batch(c, name, |u| {
            let s = table.sample(u);
            (s.direction, s.pdf)
        });
    }
}

criterion_group!(benches, distributions, factorised);
criterion_main!(benches);
