//! Throughput of the MLP kernels, one thread, batches of 4096 queries, for
//! the renderer's compact NPM networks (`Mlp<16, 32, 32, 2>`, `Mlp<48, 32,
//! 32, 2>`) and the paper size (`Mlp<32, 64, 32, 3>`): the per-query
//! [`Mlp::infer`] / [`Mlp::forward`] + [`Mlp::backward`] (the shader kernels
//! run on the CPU, the baseline) and every available [`BatchKernel`], for
//! inference and for a training pass (forward with contexts + backward).
//!
//! Run: `cargo bench -p guiding-core --features std --bench mlp`.
//!
//! First a summary table, timed in-process: queries/s, GFLOP/s and the
//! fraction of the **measured FMA peak** of this core, which is timed in the
//! same process by a tight loop of 12 independent FMA accumulator chains
//! (8 lanes with AVX2 + FMA, 16 with AVX-512). Flops: `2 · MACS` per query
//! for a forward pass, and `2 · 2 · MACS` more for the backward (input and
//! parameter gradients), so `6 · MACS` per training query. The clock is
//! estimated from the latency of one dependent FMA chain (4 cycles on Zen 4).
//! Then criterion groups `mlp_infer/<size>` and `mlp_train/<size>` over the
//! same work, throughput in flop/s ("elem/s").

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use guiding_core::mlp::{BatchKernel, Mlp, MlpContext};
use std::hint::black_box;
use std::time::{Duration, Instant};

const BATCH: usize = 4096;

/// Deterministic values in [−1, 1) (a 32-bit LCG is plenty for benchmark data).
fn values<const N: usize>(seed: u32) -> Vec<[f32; N]> {
    let mut s = seed;
    let mut next = move || {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (s >> 8) as f32 / 8_388_608.0 - 1.0
    };
    (0..BATCH)
        .map(|_| core::array::from_fn(|_| next()))
        .collect()
}

/// Seconds per call of `f`: the best of `rounds` rounds of ≥ 30 ms each.
fn seconds_per_call(rounds: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut best = f64::INFINITY;
    for _ in 0..rounds {
        let (mut calls, t0) = (0u32, Instant::now());
        while t0.elapsed() < Duration::from_millis(30) {
            f();
            calls += 1;
        }
        best = best.min(t0.elapsed().as_secs_f64() / f64::from(calls));
    }
    best
}

/// The FMA peak measurements (x86-64 only).
#[cfg(target_arch = "x86_64")]
mod peak {
    use core::arch::x86_64::*;

    pub const ITERS: usize = 1 << 22;

    /// 12 independent chains of `vfmadd` on 8 lanes, `ITERS` steps each.
    #[target_feature(enable = "avx2,fma")]
    pub fn avx2(seed: f32) -> f32 {
        let m = _mm256_set1_ps(0.999_999);
        let a = _mm256_set1_ps(1e-7);
        let mut acc = [_mm256_set1_ps(seed); 12];
        for (k, v) in acc.iter_mut().enumerate() {
            *v = _mm256_add_ps(*v, _mm256_set1_ps(k as f32));
        }
        for _ in 0..ITERS {
            for v in &mut acc {
                *v = _mm256_fmadd_ps(*v, m, a);
            }
        }
        let mut s = _mm256_setzero_ps();
        for v in acc {
            s = _mm256_add_ps(s, v);
        }
        let mut out = [0.0f32; 8];
        // SAFETY: `out` holds 8 floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), s) };
        out.iter().sum()
    }

    /// 12 independent chains of `vfmadd` on 16 lanes.
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub fn avx512(seed: f32) -> f32 {
        let m = _mm512_set1_ps(0.999_999);
        let a = _mm512_set1_ps(1e-7);
        let mut acc = [_mm512_set1_ps(seed); 12];
        for (k, v) in acc.iter_mut().enumerate() {
            *v = _mm512_add_ps(*v, _mm512_set1_ps(k as f32));
        }
        for _ in 0..ITERS {
            for v in &mut acc {
                *v = _mm512_fmadd_ps(*v, m, a);
            }
        }
        let mut s = _mm512_setzero_ps();
        for v in acc {
            s = _mm512_add_ps(s, v);
        }
        _mm512_reduce_add_ps(s)
    }

    /// One dependent chain of `ITERS` FMAs (latency bound).
    #[target_feature(enable = "avx2,fma")]
    pub fn chain(seed: f32) -> f32 {
        let m = _mm256_set1_ps(0.999_999);
        let a = _mm256_set1_ps(1e-7);
        let mut v = _mm256_set1_ps(seed);
        for _ in 0..ITERS {
            v = _mm256_fmadd_ps(v, m, a);
        }
        _mm256_cvtss_f32(v)
    }
}

/// The measured peak in flop/s (the best instruction set) and its name; prints
/// both instruction sets' peaks and the estimated clock.
fn measured_peak() -> (f64, String) {
    #[cfg(target_arch = "x86_64")]
    {
        let flops = |lanes: usize| (peak::ITERS * 12 * lanes * 2) as f64;
        let mut best = (0.0, String::from("none"));
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: AVX2 and FMA were detected.
            let t = seconds_per_call(20, || {
                black_box(unsafe { peak::avx2(black_box(1.0)) });
            });
            // SAFETY: as above.
            let tc = seconds_per_call(20, || {
                black_box(unsafe { peak::chain(black_box(1.0)) });
            });
            let ghz = 4.0 * peak::ITERS as f64 / tc / 1e9;
            let p = flops(8) / t;
            println!(
                "measured FMA peak, AVX2 (12 × 8-lane chains): {:.1} GFLOP/s = {:.1} flop/cycle \
                 at {ghz:.2} GHz (clock from one dependent FMA chain, 4-cycle latency)",
                p / 1e9,
                p / 1e9 / ghz
            );
            best = (p, String::from("AVX2+FMA"));
        }
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: AVX-512F (and AVX2, FMA, implied on every AVX-512 CPU; checked above) detected.
            let t = seconds_per_call(20, || {
                black_box(unsafe { peak::avx512(black_box(1.0)) });
            });
            let p = flops(16) / t;
            println!(
                "measured FMA peak, AVX-512 (12 × 16-lane chains): {:.1} GFLOP/s",
                p / 1e9
            );
            if p > best.0 {
                best = (p, String::from("AVX-512"));
            }
        }
        best
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        (f64::NAN, String::from("not measured"))
    }
}

/// Parameters: initialised, plus a perturbation so the biases and the output
/// layer have some size and the ReLUs are not all dead.
fn params<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>() -> Vec<f32>
{
    let mut params = vec![0.0; Mlp::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT];
    Mlp::<IN, WIDTH, OUT, HIDDEN>::init(&mut params, 0, 1);
    for (k, p) in params.iter_mut().enumerate() {
        *p += 0.01 * ((k % 7) as f32 - 3.0);
    }
    params
}

/// One size's data and buffers.
struct Bench<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize> {
    params: Vec<f32>,
    xs: Vec<[f32; IN]>,
    dys: Vec<[f32; OUT]>,
    ys: Vec<[f32; OUT]>,
    ctxs: Vec<MlpContext<WIDTH, HIDDEN>>,
    dxs: Vec<[f32; IN]>,
    grad: Vec<f32>,
}

type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
    Bench<IN, WIDTH, OUT, HIDDEN>
{
    fn new() -> Self {
        Self {
            params: params::<IN, WIDTH, OUT, HIDDEN>(),
            xs: values(3),
            dys: values(5),
            ys: vec![[0.0; OUT]; BATCH],
            ctxs: vec![MlpContext::ZERO; BATCH],
            dxs: vec![[0.0; IN]; BATCH],
            grad: vec![0.0; M::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT],
        }
    }

    fn name() -> String {
        format!("Mlp<{IN},{WIDTH},{OUT},{HIDDEN}>")
    }

    /// `None`: the per-query kernel.
    fn infer(&mut self, kernel: Option<BatchKernel>) {
        match kernel {
            None => {
                for (x, y) in self.xs.iter().zip(self.ys.iter_mut()) {
                    *y = M::<IN, WIDTH, OUT, HIDDEN>::infer(black_box(&self.params), 0, x);
                }
            }
            Some(k) => M::<IN, WIDTH, OUT, HIDDEN>::infer_batch_with(
                k,
                black_box(&self.params),
                0,
                &self.xs,
                &mut self.ys,
            ),
        }
        black_box(&mut self.ys);
    }

    fn train(&mut self, kernel: Option<BatchKernel>) {
        let p = black_box(&self.params);
        match kernel {
            None => {
                for q in 0..BATCH {
                    let _ =
                        M::<IN, WIDTH, OUT, HIDDEN>::forward(p, 0, &self.xs[q], &mut self.ctxs[q]);
                    M::<IN, WIDTH, OUT, HIDDEN>::backward(
                        p,
                        0,
                        &self.xs[q],
                        &self.ctxs[q],
                        &self.dys[q],
                        &mut self.grad,
                        &mut self.dxs[q],
                    );
                }
            }
            Some(k) => {
                M::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(
                    k,
                    p,
                    0,
                    &self.xs,
                    &mut self.ys,
                    &mut self.ctxs,
                );
                M::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
                    k,
                    p,
                    0,
                    &self.xs,
                    &self.ctxs,
                    &self.dys,
                    &mut self.grad,
                    &mut self.dxs,
                );
            }
        }
        black_box(&mut self.grad);
    }

    fn kernels() -> impl Iterator<Item = Option<BatchKernel>> {
        core::iter::once(None).chain(
            BatchKernel::ALL
                .into_iter()
                .filter(|k| k.is_available())
                .map(Some),
        )
    }

    fn label(kernel: Option<BatchKernel>) -> String {
        kernel.map_or_else(|| String::from("per-query"), |k| format!("{k:?}"))
    }

    /// The summary table rows of this size: `(label, flop/s, queries/s)`.
    fn summary(&mut self, rows: &mut Vec<(String, f64, f64)>) {
        let macs = M::<IN, WIDTH, OUT, HIDDEN>::MACS as f64;
        for (what, flops_per_query) in [("infer", 2.0 * macs), ("forward+backward", 6.0 * macs)] {
            for kernel in Self::kernels() {
                let t = if what == "infer" {
                    seconds_per_call(30, || self.infer(kernel))
                } else {
                    seconds_per_call(30, || self.train(kernel))
                };
                let qps = BATCH as f64 / t;
                rows.push((
                    format!(
                        "{:<18} {what:<17} {:<10}",
                        Self::name(),
                        Self::label(kernel)
                    ),
                    qps * flops_per_query,
                    qps,
                ));
            }
        }
    }

    fn criterion(&mut self, c: &mut Criterion) {
        let macs = M::<IN, WIDTH, OUT, HIDDEN>::MACS as u64;
        for (group, flops) in [("mlp_infer", 2 * macs), ("mlp_train", 6 * macs)] {
            let mut g = c.benchmark_group(format!("{group}/{}", Self::name()));
            g.throughput(Throughput::Elements(flops * BATCH as u64));
            g.warm_up_time(Duration::from_millis(500));
            g.measurement_time(Duration::from_secs(2));
            g.sample_size(20);
            for kernel in Self::kernels() {
                g.bench_function(Self::label(kernel), |b| {
                    if group == "mlp_infer" {
                        b.iter(|| self.infer(kernel));
                    } else {
                        b.iter(|| self.train(kernel));
                    }
                });
            }
            g.finish();
        }
    }
}

fn mlp(c: &mut Criterion) {
    let mut a = Bench::<16, 32, 32, 2>::new();
    let mut b = Bench::<48, 32, 32, 2>::new();
    let mut p = Bench::<32, 64, 32, 3>::new();
    // `MLP_BENCH_SUMMARY=0` skips the table (e.g. to profile one criterion
    // benchmark alone). Every time is the best of several rounds, and the
    // peak the better of two measurements, before and after the table (this
    // machine may be shared).
    if std::env::var("MLP_BENCH_SUMMARY").as_deref() != Ok("0") {
        let (peak0, kind0) = measured_peak();
        let mut rows = Vec::new();
        a.summary(&mut rows);
        b.summary(&mut rows);
        p.summary(&mut rows);
        let (peak1, kind1) = measured_peak();
        let (peak, kind) = if peak1 > peak0 {
            (peak1, kind1)
        } else {
            (peak0, kind0)
        };
        println!(
            "batch {BATCH}, one thread; % of the measured {kind} FMA peak ({:.1} GFLOP/s); \
             detect() = {:?}",
            peak / 1e9,
            BatchKernel::detect()
        );
        for (label, flops, qps) in rows {
            println!(
                "{label} {qps:>12.4e} queries/s {:>7.1} GFLOP/s {:>5.1} % of peak",
                flops / 1e9,
                100.0 * flops / peak
            );
        }
    }
    a.criterion(c);
    b.criterion(c);
    p.criterion(c);
}

criterion_group!(benches, mlp);
criterion_main!(benches);
