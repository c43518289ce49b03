//! Inference throughput of a 32 → 3 × 64 → 32 ReLU MLP (the size of the
//! neural guiding networks): per-query [`Mlp::infer`] (the shader kernel run
//! on the CPU, the in-process baseline), a naive batched triple loop, and the
//! blocked [`Mlp::infer_batch`] in each [`BatchKernel`] variant this CPU
//! supports.
//!
//! Run: `cargo bench -p guiding-core --features std --bench mlp`.
//! Two groups over the same work (a batch of 4096 queries): `mlp_queries`
//! reports queries/s, `mlp_flops` reports flop/s (`2 · MACS` flops per query,
//! 12 288 MACs here) as "elem/s". A third, `mlp_train_queries`, times a
//! training pass (forward with context + backward) per query vs batched.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_core::mlp::{BatchKernel, Mlp, MlpContext};
use std::hint::black_box;
use std::time::Duration;

const IN: usize = 32;
const WIDTH: usize = 64;
const OUT: usize = 32;
const HIDDEN: usize = 3;
type Net = Mlp<IN, WIDTH, OUT, HIDDEN>;
const BATCH: usize = 4096;

/// Deterministic inputs in [−1, 1) (a 32-bit LCG is plenty for benchmark data).
fn inputs(seed: u32) -> Vec<[f32; IN]> {
    let mut s = seed;
    let mut next = move || {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (s >> 8) as f32 / 8_388_608.0 - 1.0
    };
    (0..BATCH)
        .map(|_| core::array::from_fn(|_| next()))
        .collect()
}

/// Layer-at-a-time triple loop over the batch (`for query, for out, for in`),
/// written the obvious way with slices: what the blocked kernel is measured
/// against besides the per-query kernel.
fn naive_batch(
    params: &[f32],
    x: &[[f32; IN]],
    y: &mut [[f32; OUT]],
    a: &mut [f32],
    b: &mut [f32],
) {
    fn layer(w: &[f32], n_in: usize, n_out: usize, x: &[f32], y: &mut [f32], relu: bool) {
        let (weights, biases) = w.split_at(n_in * n_out);
        for (xq, yq) in x.chunks_exact(n_in).zip(y.chunks_exact_mut(n_out)) {
            for o in 0..n_out {
                let mut acc = biases[o];
                for i in 0..n_in {
                    acc += weights[o * n_in + i] * xq[i];
                }
                yq[o] = if relu && acc <= 0.0 { 0.0 } else { acc };
            }
        }
    }
    let flat_x: &[f32] = x.as_flattened();
    layer(
        &params[..Net::FIRST_LAYER_PARAMS],
        IN,
        WIDTH,
        flat_x,
        a,
        true,
    );
    let (mut cur, mut next) = (a, b);
    for l in 1..HIDDEN {
        let o = Net::layer_offset(l);
        layer(
            &params[o..o + Net::HIDDEN_LAYER_PARAMS],
            WIDTH,
            WIDTH,
            cur,
            next,
            true,
        );
        core::mem::swap(&mut cur, &mut next);
    }
    layer(
        &params[Net::OUTPUT_LAYER_OFFSET..Net::PARAM_COUNT],
        WIDTH,
        OUT,
        cur,
        y.as_flattened_mut(),
        false,
    );
}

fn bench_group(c: &mut Criterion, group_name: &str, per_batch: u64) {
    let mut params = vec![0.0; Net::PARAM_COUNT];
    Net::init(&mut params, 0, 1);
    // Give the biases and output layer some size so ReLUs are not all dead.
    for (k, p) in params.iter_mut().enumerate() {
        *p += 0.01 * ((k % 7) as f32 - 3.0);
    }
    let xs = inputs(3);
    let mut ys = vec![[0.0f32; OUT]; BATCH];
    let mut group = c.benchmark_group(group_name);
    group.throughput(Throughput::Elements(per_batch));
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    group.sample_size(30);

    group.bench_function("baseline_per_query_infer", |b| {
        b.iter(|| {
            for (x, y) in xs.iter().zip(ys.iter_mut()) {
                *y = Net::infer(black_box(&params), 0, x);
            }
            black_box(&mut ys);
        });
    });

    let mut ha = vec![0.0f32; BATCH * WIDTH];
    let mut hb = vec![0.0f32; BATCH * WIDTH];
    group.bench_function("naive_batch_triple_loop", |b| {
        b.iter(|| {
            naive_batch(black_box(&params), &xs, &mut ys, &mut ha, &mut hb);
            black_box(&mut ys);
        });
    });

    for kernel in BatchKernel::ALL {
        if !kernel.is_available() {
            continue;
        }
        group.bench_function(format!("infer_batch_{kernel:?}").to_lowercase(), |b| {
            b.iter(|| {
                Net::infer_batch_with(kernel, black_box(&params), 0, &xs, &mut ys);
                black_box(&mut ys);
            });
        });
    }
    group.finish();
}

/// One training pass (forward with context + backward into one gradient
/// buffer) over the batch: per query vs batched. Reports queries/s; the work
/// is about `3 · 2 · MACS` flops per query (forward, input gradients,
/// weight gradients), less the skipped dead-ReLU rows.
fn training(c: &mut Criterion) {
    let mut params = vec![0.0; Net::PARAM_COUNT];
    Net::init(&mut params, 0, 1);
    for (k, p) in params.iter_mut().enumerate() {
        *p += 0.01 * ((k % 7) as f32 - 3.0);
    }
    let xs = inputs(3);
    let dys: Vec<[f32; OUT]> = inputs(5)
        .iter()
        .map(|x| core::array::from_fn(|o| x[o % IN]))
        .collect();
    let mut ys = vec![[0.0f32; OUT]; BATCH];
    let mut ctxs = vec![MlpContext::<WIDTH, HIDDEN>::ZERO; BATCH];
    let mut dxs = vec![[0.0f32; IN]; BATCH];
    let mut grad = vec![0.0f32; Net::PARAM_COUNT];
    let mut group = c.benchmark_group("mlp_train_queries");
    group.throughput(Throughput::Elements(BATCH as u64));
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    group.sample_size(30);
    group.bench_function("baseline_per_query_forward_backward", |b| {
        b.iter(|| {
            for q in 0..BATCH {
                let _ = Net::forward(black_box(&params), 0, &xs[q], &mut ctxs[q]);
                Net::backward(
                    &params,
                    0,
                    &xs[q],
                    &ctxs[q],
                    &dys[q],
                    &mut grad,
                    &mut dxs[q],
                );
            }
            black_box(&mut grad);
        });
    });
    for kernel in BatchKernel::ALL {
        if !kernel.is_available() {
            continue;
        }
        let name = format!("forward_backward_batch_{kernel:?}").to_lowercase();
        group.bench_function(name, |b| {
            b.iter(|| {
                Net::forward_batch_with(kernel, black_box(&params), 0, &xs, &mut ys, &mut ctxs);
                Net::backward_batch_with(kernel, &params, 0, &xs, &ctxs, &dys, &mut grad, &mut dxs);
                black_box(&mut grad);
            });
        });
    }
    group.finish();
}

fn mlp(c: &mut Criterion) {
    bench_group(c, "mlp_queries", BATCH as u64);
    bench_group(c, "mlp_flops", (2 * Net::MACS * BATCH) as u64);
    training(c);
}

criterion_group!(benches, mlp);
criterion_main!(benches);
