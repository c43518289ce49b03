//! ns per query of every input encoding: the NPM dense grid (forward and
//! backward, 8 levels × 4 features over 4.1 M parameters, so mostly cache
//! misses at the finer levels), spherical harmonics, one-blob, triangle-wave
//! and frequency encodings.
//!
//! Run: `cargo bench -p guiding-bench --bench encoding`. Each iteration
//! encodes 4096 fixed pseudo-random queries; criterion reports time per query.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_bench::inputs::{unit_points, BATCH};
use guiding_core::encoding::{
    frequency_encode, grid_backward, grid_forward, grid_init, one_blob_encode, sh_encode,
    triangle_wave_encode, GridConfig,
};
use guiding_core::glam::Vec3;
use std::hint::black_box;

fn bench<F: Fn(Vec3) -> f32>(c: &mut Criterion, name: &str, points: &[Vec3], f: F) {
    let mut group = c.benchmark_group("encoding");
    group.throughput(Throughput::Elements(BATCH as u64));
    group.bench_function(name, |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for &p in points {
                acc += f(black_box(p));
            }
            black_box(acc)
        })
    });
    group.finish();
}

fn encodings(c: &mut Criterion) {
    let points = unit_points(7, BATCH);
    let cfg = GridConfig::npm([-1.0; 3], [1.0; 3]);
    let mut params = vec![0.0f32; cfg.param_count()];
    grid_init(&mut params, &cfg, 1);
    let world: Vec<Vec3> = points.iter().map(|&p| p * 2.0 - 1.0).collect();
    bench(c, "grid_forward_npm", &world, |p| {
        let mut out = [0.0f32; 32];
        grid_forward(&params, &cfg, p, &mut out, 0);
        out[0] + out[31]
    });
    let small = GridConfig::new([-1.0; 3], [1.0; 3], 8, 2, 1.2, 4);
    let small_params = vec![0.5f32; small.param_count()];
    bench(c, "grid_forward_small_in_cache", &world, |p| {
        let mut out = [0.0f32; 32];
        grid_forward(&small_params, &small, p, &mut out, 0);
        out[0] + out[31]
    });
    let grad = std::cell::RefCell::new(vec![0.0f32; cfg.param_count()]);
    let d_out = [1e-3f32; 32];
    bench(c, "grid_backward_npm", &world, |p| {
        let mut g = grad.borrow_mut();
        grid_backward(&cfg, p, &d_out, 0, &mut g[..]);
        g[0]
    });
    let dirs: Vec<Vec3> = world.iter().map(|&p| p + Vec3::splat(1e-3)).collect();
    bench(c, "sh_degree4", &dirs, |d| {
        let mut out = [0.0f32; 16];
        sh_encode(d, 4, &mut out, 0);
        out[15]
    });
    bench(c, "one_blob_4bins_x4", &points, |p| {
        let mut out = [0.0f32; 16];
        let o = one_blob_encode(p.x, 4, &mut out, 0);
        let o = one_blob_encode(p.y, 4, &mut out, o);
        let o = one_blob_encode(p.z, 4, &mut out, o);
        one_blob_encode(p.x * p.y, 4, &mut out, o);
        out[3] + out[15]
    });
    bench(c, "triangle_wave_12", &points, |p| {
        let mut out = [0.0f32; 12];
        triangle_wave_encode(p.x, 12, &mut out, 0);
        out[11]
    });
    bench(c, "frequency_3x12", &points, |p| {
        let mut out = [0.0f32; 72];
        frequency_encode(&p.to_array(), 12, &mut out, 0);
        out[71]
    });
}

criterion_group!(benches, encodings);
criterion_main!(benches);
