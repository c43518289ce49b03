//! Wall-clock timing of the report's numbers and the machine's measured FMA
//! peak (the denominator of the MLP's "% of peak").
//!
//! Wall clock on a shared machine is noisy: compare ratios against a
//! baseline timed in the same process, never absolute times across runs.

use std::hint::black_box;
use std::time::{Duration, Instant};

/// Median wall-clock seconds of `repeats` calls of `f`, after one warm-up
/// call.
pub fn median_secs(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Seconds per call of `f`: the best of `rounds` rounds of at least 30 ms
/// each, after one warm-up call (for short kernels, where one call is below
/// the clock's resolution and the best round is the least disturbed).
pub fn best_secs_per_call(rounds: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut best = f64::INFINITY;
    for _ in 0..rounds.max(1) {
        let (mut calls, t0) = (0u32, Instant::now());
        while t0.elapsed() < Duration::from_millis(30) {
            f();
            calls += 1;
        }
        best = best.min(t0.elapsed().as_secs_f64() / f64::from(calls));
    }
    best
}

/// The measured single-core f32 FMA peak.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FmaPeak {
    /// Flop/s (2 per lane per FMA).
    pub flops: f64,
    /// Vector lanes of the widest measured instruction set (8 AVX2, 16 AVX-512).
    pub lanes: u32,
    /// That instruction set.
    pub name: &'static str,
    /// The clock in GHz, estimated from one dependent FMA chain (4 cycles of
    /// latency, as on Zen 4 and recent Intel cores).
    pub clock_ghz: f64,
}

/// Steps of each FMA chain of the peak measurement.
#[cfg(target_arch = "x86_64")]
const PEAK_ITERS: usize = 1 << 22;

/// The FMA chains of the peak measurement (x86-64 only).
#[cfg(target_arch = "x86_64")]
mod chains {
    use super::PEAK_ITERS;
    use core::arch::x86_64::*;

    /// `$name(seed)`: 12 independent chains of `$fmadd` on one vector type
    /// (two FMA pipes × 4 cycles of latency, with margin), `PEAK_ITERS`
    /// steps each, their sum reduced to one float by `$sum`. One body for
    /// every width, so the widths are timed on the same chains.
    macro_rules! fma_chains {
        ($(#[$attr:meta])* $name:ident: $set1:ident, $add:ident, $fmadd:ident,
            $setzero:ident, $sum:ident) => {
            $(#[$attr])*
            pub fn $name(seed: f32) -> f32 {
                let m = $set1(0.999_999);
                let a = $set1(1e-7);
                let mut acc = [$set1(seed); 12];
                for (k, v) in acc.iter_mut().enumerate() {
                    *v = $add(*v, $set1(k as f32));
                }
                for _ in 0..PEAK_ITERS {
                    for v in &mut acc {
                        *v = $fmadd(*v, m, a);
                    }
                }
                let mut s = $setzero();
                for v in acc {
                    s = $add(s, v);
                }
                $sum(s)
            }
        };
    }

    fma_chains! {
        /// On 8 lanes (AVX2).
        #[target_feature(enable = "avx2,fma")]
        avx2: _mm256_set1_ps, _mm256_add_ps, _mm256_fmadd_ps, _mm256_setzero_ps, sum8
    }

    fma_chains! {
        /// On 16 lanes (AVX-512).
        #[target_feature(enable = "avx512f,avx2,fma")]
        avx512: _mm512_set1_ps, _mm512_add_ps, _mm512_fmadd_ps, _mm512_setzero_ps,
            _mm512_reduce_add_ps
    }

    /// The sum of the 8 lanes of `s`.
    #[target_feature(enable = "avx2,fma")]
    fn sum8(s: __m256) -> f32 {
        let mut out = [0.0f32; 8];
        // SAFETY: `out` holds 8 floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), s) };
        out.iter().sum()
    }

    /// One dependent chain of `PEAK_ITERS` FMAs (latency bound: the clock).
    #[target_feature(enable = "avx2,fma")]
    pub fn dependent(seed: f32) -> f32 {
        let m = _mm256_set1_ps(0.999_999);
        let a = _mm256_set1_ps(1e-7);
        let mut v = _mm256_set1_ps(seed);
        for _ in 0..PEAK_ITERS {
            v = _mm256_fmadd_ps(v, m, a);
        }
        _mm256_cvtss_f32(v)
    }
}

/// The single-core FMA peak of this machine, timed now: twelve independent
/// FMA chains as wide as the widest vectors the batched MLP dispatches to
/// (16 lanes with AVX-512F, else 8 with AVX2 + FMA), the best of `rounds`
/// rounds. `None` without AVX2 + FMA (or off x86-64).
#[must_use]
pub fn fma_peak(rounds: usize) -> Option<FmaPeak> {
    #[cfg(target_arch = "x86_64")]
    {
        if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
            return None;
        }
        let flops = |lanes: u32| (PEAK_ITERS * 12) as f64 * f64::from(lanes) * 2.0;
        // SAFETY: AVX2 and FMA were detected above.
        let t_dep = best_secs_per_call(rounds, || {
            black_box(unsafe { chains::dependent(black_box(1.0)) });
        });
        let clock_ghz = 4.0 * PEAK_ITERS as f64 / t_dep / 1e9;
        // SAFETY: as above.
        let t8 = best_secs_per_call(rounds, || {
            black_box(unsafe { chains::avx2(black_box(1.0)) });
        });
        let mut peak = FmaPeak {
            flops: flops(8) / t8,
            lanes: 8,
            name: "AVX2+FMA",
            clock_ghz,
        };
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: AVX-512F detected (AVX2 and FMA above).
            let t16 = best_secs_per_call(rounds, || {
                black_box(unsafe { chains::avx512(black_box(1.0)) });
            });
            if flops(16) / t16 > peak.flops {
                peak = FmaPeak {
                    flops: flops(16) / t16,
                    lanes: 16,
                    name: "AVX-512",
                    clock_ghz,
                };
            }
        }
        Some(peak)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = rounds;
        None
    }
}
