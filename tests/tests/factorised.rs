//! Tests of the factorised piecewise densities (Figueiredo et al. 2025):
//! `Pdf1d` for every interpolation × boundary at N ∈ {1, 2, 16, 32, 64}
//! (normalisation, sample/pdf/invert consistency, 1D chi², degenerate
//! quadratics, seam continuity, gradients against an f64 oracle, proptest
//! robustness), and the sphere-level `FactorisedTable` / per-query functions.
//!
//! The sphere-level chi² of the tables runs in `distributions.rs` through the
//! case registry (`guiding_tests::cases::factorised`).

use glam::{Vec2, Vec3};
use guiding_core::factorised::{self, FactorisedTable, LN_FOUR_PI, SAMPLE_MARGIN};
use guiding_core::math::{INV_FOUR_PI, ONE_MINUS_EPSILON};
use guiding_core::pdf1d::{linear_cdf, sample_linear, Boundary, Interpolation, Pdf1d};
use guiding_tests::cases::factorised::{logits, random_table, LogitKind, STANDALONE_CHI2_TESTS};
use guiding_tests::oracles::{pdf1d_eval, pdf1d_ln_pdf};
use guiding_tests::rng::Pcg32;
use proptest::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

const CONFIGS: [(Interpolation, Boundary); 4] = [
    (Interpolation::Nearest, Boundary::Wrap),
    (Interpolation::Nearest, Boundary::Clamp),
    (Interpolation::Linear, Boundary::Wrap),
    (Interpolation::Linear, Boundary::Clamp),
];

/// `check::<N>()` for each bin count `N` listed (a const parameter).
macro_rules! for_sizes {
    ($check:ident: $($n:literal),*) => {
        $($check::<$n>();)*
    };
}

// The f64 oracle, written from the spec (independent of the piece
// decomposition the implementation samples with): `oracles::pdf1d_eval` and
// `oracles::pdf1d_ln_pdf`.

/// `pdf.sample(u)`, asserted to be a point of `[0, 1)` with a finite density
/// `> 0`.
fn valid_sample<const N: usize>(pdf: &Pdf1d<N>, u: f32, what: &str) -> (f32, f32) {
    let (x, p) = pdf.sample(u);
    assert!((0.0..1.0).contains(&x), "{what}: x = {x}");
    assert!(p > 0.0 && p.is_finite(), "{what}: p = {p} at x = {x}");
    (x, p)
}

/// Central finite differences of `f` with respect to each entry of `l`.
fn finite_differences(l: &[f64], f: impl Fn(&[f64]) -> f64) -> Vec<f64> {
    let h = 1e-5;
    (0..l.len())
        .map(|k| {
            let mut lp = l.to_vec();
            let mut lm = l.to_vec();
            lp[k] += h;
            lm[k] -= h;
            (f(&lp) - f(&lm)) / (2.0 * h)
        })
        .collect()
}

/// `(ε₁, ε₂)` of a direction in f64 (the DF warp inverted).
fn oracle_square(d: Vec3) -> (f64, f64) {
    let (x, y, z) = (f64::from(d.x), f64::from(d.y), f64::from(d.z));
    let len = (x * x + y * y + z * z).sqrt();
    let mut phi = y.atan2(x);
    if phi < 0.0 {
        phi += std::f64::consts::TAU;
    }
    (phi / std::f64::consts::TAU, 0.5 * (1.0 - z / len))
}

// ---------------------------------------------------------------------------
// Exact piecewise integration.
// ---------------------------------------------------------------------------

/// Kinks of the density: bin edges (nearest) or bin centres (linear).
fn breakpoints(n: usize, interp: Interpolation) -> Vec<f64> {
    match interp {
        Interpolation::Nearest => (0..=n).map(|k| k as f64 / n as f64).collect(),
        Interpolation::Linear => (0..n).map(|k| (k as f64 + 0.5) / n as f64).collect(),
    }
}

/// `∫_a^b f` for `f` linear between the breakpoints: the midpoint rule on
/// every sub-piece is exact.
fn integrate(f: &dyn Fn(f64) -> f64, breaks: &[f64], a: f64, b: f64) -> f64 {
    let mut pts = vec![a];
    pts.extend(breaks.iter().copied().filter(|&x| x > a && x < b));
    pts.push(b);
    pts.windows(2)
        .map(|w| (w[1] - w[0]) * f(0.5 * (w[0] + w[1])))
        .sum()
}

fn integral_of<const N: usize>(pdf: &Pdf1d<N>, a: f64, b: f64) -> f64 {
    let breaks = breakpoints(N, pdf.interpolation());
    integrate(&|x| f64::from(pdf.pdf(x as f32)), &breaks, a, b)
}

// ---------------------------------------------------------------------------
// Logit generators.
// ---------------------------------------------------------------------------

#[derive(Clone, Copy, Debug)]
enum Kind {
    Random,
    Spiky,
    /// A few logits at ±10³⁰: empty bins (zero density) next to full ones.
    Extreme,
}

const KINDS: [Kind; 3] = [Kind::Random, Kind::Spiky, Kind::Extreme];

fn make_logits<const N: usize>(rng: &mut Pcg32, kind: Kind) -> [f32; N] {
    match kind {
        Kind::Random => logits::<N>(rng, LogitKind::Random),
        Kind::Spiky => logits::<N>(rng, LogitKind::Spiky),
        Kind::Extreme => {
            let mut l = logits::<N>(rng, LogitKind::Random);
            for x in &mut l {
                if rng.next_f32() < 0.5 {
                    *x = -1e30;
                }
            }
            // Make sure at least one bin is not at −10³⁰ … and one is at +10³⁰.
            l[rng.next_u32() as usize % N] = 1e30;
            l
        }
    }
}

fn pdf_from<const N: usize>(
    seed: u64,
    kind: Kind,
    interp: Interpolation,
    boundary: Boundary,
) -> Pdf1d<N> {
    let mut rng = Pcg32::new(seed, N as u64);
    Pdf1d::from_logits(&make_logits::<N>(&mut rng, kind), interp, boundary)
}

// ---------------------------------------------------------------------------
// Normalisation, pdf vs oracle, sample/pdf/invert.
// ---------------------------------------------------------------------------

fn check_normalisation<const N: usize>() {
    for (c, &(interp, boundary)) in CONFIGS.iter().enumerate() {
        for (k, &kind) in KINDS.iter().enumerate() {
            for seed in 0..4u64 {
                let pdf = pdf_from::<N>(
                    seed * 100 + c as u64 * 10 + k as u64,
                    kind,
                    interp,
                    boundary,
                );
                assert_eq!(pdf.interpolation(), interp);
                assert_eq!(pdf.boundary(), boundary);
                let sum: f64 = pdf.values.iter().map(|&v| f64::from(v)).sum();
                assert!((sum - N as f64).abs() < 1e-5 * N as f64, "Σv = {sum}");
                let total = integral_of(&pdf, 0.0, 1.0);
                assert!(
                    (total - 1.0).abs() < 1e-5,
                    "N={N} {interp:?} {boundary:?} {kind:?}: ∫p = {total}"
                );
                // Against the oracle from the same (f32) values.
                let v: Vec<f64> = pdf.values.iter().map(|&x| f64::from(x)).collect();
                let mut rng = Pcg32::new(seed, 77);
                for _ in 0..1000 {
                    let x = rng.next_f32();
                    let a = f64::from(pdf.pdf(x));
                    let o = pdf1d_eval(&v, f64::from(x), interp, boundary);
                    assert!(
                        (a - o).abs() <= 1e-5 * o.abs().max(1e-3),
                        "N={N} {interp:?} {boundary:?}: pdf({x}) = {a}, oracle {o}"
                    );
                }
            }
        }
    }
}

#[test]
fn normalisation_and_oracle() {
    for_sizes!(check_normalisation: 1, 2, 16, 32, 64);
}

fn check_sample_invert<const N: usize>() {
    for &(interp, boundary) in &CONFIGS {
        for &kind in &KINDS {
            let pdf = pdf_from::<N>(11, kind, interp, boundary);
            let mut rng = Pcg32::new(5, 3);
            for i in 0..100_000 {
                // A few exact end points, then random numbers.
                let u = match i {
                    0 => 0.0,
                    1 => ONE_MINUS_EPSILON,
                    2 => 0.5,
                    _ => rng.next_f32(),
                };
                let (x, p) =
                    valid_sample(&pdf, u, &format!("N={N} {interp:?} {boundary:?} {kind:?}"));
                let q = pdf.pdf(x);
                assert!((p - q).abs() <= 1e-5 * q, "sample pdf {p} vs pdf {q}");
                let back = pdf.invert(x);
                assert!(
                    (back - u).abs() <= 1e-5,
                    "N={N} {interp:?} {boundary:?} {kind:?}: invert(sample({u})) = {back} (x = {x}, p = {p})"
                );
            }
            // The CDF is monotone and spans [0, 1).
            let mut prev = 0.0;
            for i in 0..=4096 {
                let x = i as f32 / 4096.0;
                let c = pdf.invert(x);
                assert!(c >= prev && c < 1.0, "CDF not monotone at {x}");
                prev = c;
            }
            assert_eq!(pdf.invert(0.0), 0.0);
            // Against exact integration.
            for i in 1..64 {
                let x = (i as f64 + 0.37) / 64.0;
                let c = f64::from(pdf.invert(x as f32));
                let exact = integral_of(&pdf, 0.0, f64::from(x as f32));
                assert!((c - exact).abs() < 1e-5, "CDF({x}) = {c}, ∫ = {exact}");
            }
        }
    }
}

#[test]
fn sample_pdf_invert_consistency() {
    for_sizes!(check_sample_invert: 1, 2, 16, 32, 64);
}

// ---------------------------------------------------------------------------
// 1D chi².
// ---------------------------------------------------------------------------

const CHI2_ALPHA: f64 = 0.01;
const CHI2_SAMPLES: usize = 1_000_000;

/// Chi² of `CHI2_SAMPLES` samples against the exact cell integrals of the
/// pdf, cells with expected count < 5 pooled (Mitsuba's scheme). Returns the
/// p-value, or panics on a sample in a cell of zero expected count.
fn chi2_1d<const N: usize>(pdf: &Pdf1d<N>, seed: u64) -> f64 {
    // Cells deliberately not aligned with the bins.
    let cells = 5 * N + 3;
    let mut observed = vec![0u64; cells];
    let mut rng = Pcg32::new(seed, 1234);
    for _ in 0..CHI2_SAMPLES {
        let (x, _) = pdf.sample(rng.next_f32());
        let c = ((f64::from(x) * cells as f64) as usize).min(cells - 1);
        observed[c] += 1;
    }
    let expected: Vec<f64> = (0..cells)
        .map(|c| {
            let a = c as f64 / cells as f64;
            let b = (c + 1) as f64 / cells as f64;
            integral_of(pdf, a, b) * CHI2_SAMPLES as f64
        })
        .collect();
    chi2_p_value(&observed, &expected)
}

/// Pearson's chi² p-value, cells with expected count < 5 pooled (Mitsuba's
/// scheme). Panics on a sample in a cell of zero expected count.
fn chi2_p_value(observed: &[u64], expected: &[f64]) -> f64 {
    let mut chi2 = 0.0;
    let mut dof = 0usize;
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for (c, (&o, &e)) in observed.iter().zip(expected).enumerate() {
        let o = o as f64;
        if e == 0.0 {
            assert!(o == 0.0, "{o} samples in cell {c} of zero density");
        } else if e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            chi2 += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_e >= 5.0 {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        dof += 1;
    }
    if dof <= 1 {
        // Everything in one cell: nothing to test.
        return 1.0;
    }
    ChiSquared::new((dof - 1) as f64).unwrap().sf(chi2)
}

/// Šidák-corrected per-test level over every chi² test of the suite (this
/// file's [`STANDALONE_CHI2_TESTS`] and the registry's cases).
fn sidak_alpha() -> f64 {
    guiding_tests::chi2::sidak(CHI2_ALPHA, guiding_tests::total_chi2_tests())
}

fn check_chi2<const N: usize>() {
    let alpha = sidak_alpha();
    for (c, &(interp, boundary)) in CONFIGS.iter().enumerate() {
        for (k, &kind) in KINDS.iter().enumerate() {
            let seed = 1000 + N as u64 * 16 + c as u64 * 4 + k as u64;
            let pdf = pdf_from::<N>(seed, kind, interp, boundary);
            let p = chi2_1d(&pdf, seed);
            assert!(
                p > alpha,
                "chi² rejected N={N} {interp:?} {boundary:?} {kind:?}: p = {p:e} < {alpha:e}"
            );
        }
    }
}

#[test]
fn chi2_small() {
    for_sizes!(check_chi2: 1, 2, 16);
}

#[test]
fn chi2_32() {
    check_chi2::<32>();
}

#[test]
fn chi2_64() {
    check_chi2::<64>();
}

// ---------------------------------------------------------------------------
// Degenerate cases.
// ---------------------------------------------------------------------------

#[test]
fn sample_linear_degenerate() {
    let us = [
        0.0,
        1e-30,
        1e-7,
        0.1,
        0.25,
        0.5,
        0.75,
        0.9,
        0.999_999,
        ONE_MINUS_EPSILON,
    ];
    let pairs: [(f32, f32); 12] = [
        (1.0, 1.0),
        (1.0, 1.0 + 1e-7),
        (1.0 - 1e-7, 1.0),
        (0.0, 1.0),
        (1.0, 0.0),
        (0.0, 0.0),
        (1e-38, 2e-38),
        (1e-45, 1e-45),
        (3e38, 1e38),
        (f32::MAX, f32::MAX),
        (1e-30, 1.0),
        (1.0, 1e-30),
    ];
    for &(a, b) in &pairs {
        for &u in &us {
            let t = sample_linear(u, a, b);
            assert!(
                (0.0..1.0).contains(&t),
                "sample_linear({u}, {a}, {b}) = {t}"
            );
            let back = linear_cdf(t, a, b);
            assert!((back - u).abs() < 2e-6, "F(t({u}, {a}, {b})) = {back}");
            // Against the f64 closed form.
            let (a64, b64, u64) = (f64::from(a), f64::from(b), f64::from(u));
            let m = a64.max(b64);
            let exact = if m == 0.0 {
                u64
            } else {
                let (a64, b64) = (a64 / m, b64 / m);
                if (a64 - b64).abs() < 1e-12 {
                    u64
                } else {
                    // Root in [0, 1] of (b − a)/2 t² + a t − u (a + b)/2 = 0.
                    let (qa, qb, qc) = (0.5 * (b64 - a64), a64, -u64 * 0.5 * (a64 + b64));
                    (-qb + (qb * qb - 4.0 * qa * qc).sqrt()) / (2.0 * qa)
                }
            };
            assert!(
                (f64::from(t) - exact).abs() < 1e-5,
                "sample_linear({u}, {a}, {b}) = {t}, exact {exact}"
            );
        }
    }
    // Equal ends: the identity; a = 0: √u; b = 0: 1 − √(1 − u).
    for i in 0..1000 {
        let u = i as f32 / 1000.0;
        assert!((sample_linear(u, 2.5, 2.5) - u).abs() <= 1e-7);
        assert!((sample_linear(u, 0.0, 3.0) - u.sqrt()).abs() <= 1e-6);
        assert!((sample_linear(u, 3.0, 0.0) - (1.0 - (1.0 - u).sqrt())).abs() <= 1e-6);
    }
    // Invalid input behaves as uniform.
    assert_eq!(sample_linear(0.3, f32::NAN, -1.0), 0.3);
    assert_eq!(sample_linear(f32::NAN, 1.0, 2.0), 0.0);
    assert!(linear_cdf(f32::NAN, 1.0, 2.0).is_finite());
}

fn check_degenerate_values<const N: usize>(values: &[f32; N]) {
    for &(interp, boundary) in &CONFIGS {
        let pdf = Pdf1d::from_values(values, interp, boundary);
        let total = integral_of(&pdf, 0.0, 1.0);
        assert!((total - 1.0).abs() < 1e-5, "{values:?}: ∫p = {total}");
        let mut rng = Pcg32::new(9, 9);
        for _ in 0..20_000 {
            let u = rng.next_f32();
            let (x, p) = pdf.sample(u);
            assert!((0.0..1.0).contains(&x));
            assert!(
                p > 0.0 && p == pdf.pdf(x),
                "{values:?} {interp:?} {boundary:?}: p({x}) = {p}"
            );
            let back = pdf.invert(x);
            assert!(
                (back - u).abs() <= 1e-5,
                "{values:?}: invert(sample({u})) = {back}"
            );
        }
    }
}

#[test]
fn degenerate_values() {
    check_degenerate_values(&[1.0]);
    check_degenerate_values(&[0.0]);
    check_degenerate_values(&[1.0, 0.0]);
    check_degenerate_values(&[0.0, 1.0]);
    check_degenerate_values(&[1.0; 16]);
    check_degenerate_values(&[3.0, 3.0, 0.0, 0.0, 1.0, 1.0 + 1e-7, 0.0, 5.0]);
    check_degenerate_values(&[0.0, 0.0, 0.0, 7.0, 0.0, 0.0, 0.0, 0.0]);
    check_degenerate_values(&[f32::MAX, f32::MAX, 0.0, 1.0]);
    check_degenerate_values(&[1e-45, 0.0, 0.0, 1e-45]);
    check_degenerate_values(&[f32::NAN, -1.0, f32::INFINITY, 2.0]);
    // All invalid: uniform.
    let u = Pdf1d::from_values(
        &[f32::NAN, -1.0, 0.0],
        Interpolation::Linear,
        Boundary::Clamp,
    );
    assert_eq!(u.values, [1.0; 3]);

    // Spiky ±10³⁰ logits: one bin holds everything.
    let mut l = [-1e30f32; 32];
    l[7] = 1e30;
    for &(interp, boundary) in &CONFIGS {
        let pdf = Pdf1d::from_logits(&l, interp, boundary);
        assert_eq!(pdf.values[7], 32.0);
        assert!((integral_of(&pdf, 0.0, 1.0) - 1.0).abs() < 1e-5);
        for i in 0..1000 {
            let u = i as f32 / 1000.0;
            let (x, p) = pdf.sample(u);
            assert!(p > 0.0 && p.is_finite());
            let lo = if interp == Interpolation::Linear {
                6.5
            } else {
                7.0
            } / 32.0;
            let hi = if interp == Interpolation::Linear {
                8.5
            } else {
                8.0
            } / 32.0;
            assert!(x >= lo && x <= hi, "x = {x} outside the spike's support");
            assert!((pdf.invert(x) - u).abs() <= 1e-5);
        }
        // ln p where p underflows: finite, and the gradient pushes the bin up.
        let mut g = [0.0; 32];
        let lp = Pdf1d::grad_log_pdf(&l, 0.02, interp, boundary, &mut g);
        assert!(lp.is_finite() && lp < -1e29, "ln p = {lp}");
        assert!(g.iter().all(|x| x.is_finite()));
        // The stencil entries (bins 0, 1 or 31, all at −10³⁰) share +1, bin 7
        // loses its full softmax weight.
        let sum: f32 = g.iter().sum();
        assert!(sum.abs() < 1e-6 && (g[7] + 1.0).abs() < 1e-6, "{g:?}");
        assert!(g.iter().all(|x| (-1.0..=1.0).contains(x)));
    }
}

#[test]
fn boundaries() {
    let mut rng = Pcg32::new(3, 3);
    for &interp in &[Interpolation::Nearest, Interpolation::Linear] {
        let l: [f32; 16] = logits(&mut rng, LogitKind::Random);
        let wrap = Pdf1d::from_logits(&l, interp, Boundary::Wrap);
        let clamp = Pdf1d::from_logits(&l, interp, Boundary::Clamp);
        // Periodicity of the wrap density; clamping of the clamp density.
        for i in 0..100 {
            let x = (i as f32 + 0.3) / 100.0;
            let tol = 1e-5 * wrap.pdf(x);
            assert!((wrap.pdf(x + 1.0) - wrap.pdf(x)).abs() <= tol * 2.0);
            assert!((wrap.pdf(x - 3.0) - wrap.pdf(x)).abs() <= tol * 8.0);
            assert_eq!(clamp.pdf(x + 2.0), clamp.pdf(1.0));
            assert_eq!(clamp.pdf(-x), clamp.pdf(0.0));
        }
        for pdf in [&wrap, &clamp] {
            for x in [
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::MAX,
                -f32::MAX,
            ] {
                assert!(pdf.pdf(x).is_finite() && pdf.pdf(x) >= 0.0);
                assert!((0.0..1.0).contains(&pdf.invert(x)));
            }
        }
    }
    // Linear wrap: continuous across the seam, equal to the mean of the end bins.
    let l: [f32; 16] = logits(&mut rng, LogitKind::Random);
    let wrap = Pdf1d::from_logits(&l, Interpolation::Linear, Boundary::Wrap);
    let seam = 0.5 * (wrap.values[0] + wrap.values[15]);
    for x in [0.0, 1e-7, -1e-7, ONE_MINUS_EPSILON, 1.0, 1.0 + 1e-7] {
        assert!(
            (wrap.pdf(x) - seam).abs() <= 1e-5 * seam,
            "p({x}) = {}, seam {seam}",
            wrap.pdf(x)
        );
    }
    // The left half bin climbs from the seam to v₀ at the first centre.
    assert!((wrap.pdf(0.5 / 16.0) - wrap.values[0]).abs() <= 1e-5 * wrap.values[0]);
    // Linear clamp: constant on the end half bins.
    let clamp = Pdf1d::from_logits(&l, Interpolation::Linear, Boundary::Clamp);
    for i in 0..=10 {
        let x = i as f32 / 10.0 * 0.5 / 16.0;
        assert_eq!(clamp.pdf(x), clamp.values[0]);
        assert_eq!(clamp.pdf(1.0 - x), clamp.values[15]);
    }
}

// ---------------------------------------------------------------------------
// Gradients.
// ---------------------------------------------------------------------------

/// Symmetric relative error with a floor.
fn rel_err(a: f64, n: f64) -> f64 {
    (a - n).abs() / a.abs().max(n.abs()).max(1e-3)
}

/// A point whose distance from every kink is at least 1 % of a bin.
fn point_off_kinks(rng: &mut Pcg32, n: usize, interp: Interpolation) -> f32 {
    loop {
        let x = rng.next_f32();
        let s = f64::from(x) * n as f64
            - match interp {
                Interpolation::Nearest => 0.0,
                Interpolation::Linear => 0.5,
            };
        let f = s - s.floor();
        if f > 0.01 && f < 0.99 {
            return x;
        }
    }
}

fn to_f64<const K: usize>(a: &[f32; K]) -> Vec<f64> {
    a.iter().map(|&x| f64::from(x)).collect()
}

/// `(bad components, total components)` over the trials.
fn check_grad_1d<const N: usize>(rng: &mut Pcg32) -> (usize, usize) {
    let (mut bad, mut total) = (0, 0);
    for &(interp, boundary) in &CONFIGS {
        for trial in 0..40 {
            let kind = if trial % 4 == 3 {
                LogitKind::Spiky
            } else {
                LogitKind::Random
            };
            let l: [f32; N] = logits(rng, kind);
            let x = point_off_kinks(rng, N, interp);
            let mut g = [0.0; N];
            let lp = Pdf1d::grad_log_pdf(&l, x, interp, boundary, &mut g);
            let l64 = to_f64(&l);
            let x64 = f64::from(x);
            let oracle = pdf1d_ln_pdf(&l64, x64, interp, boundary);
            assert!(
                (f64::from(lp) - oracle).abs() <= 1e-4 * oracle.abs().max(1.0),
                "N={N} {interp:?} {boundary:?}: ln p = {lp}, oracle {oracle}"
            );
            let direct = Pdf1d::from_logits(&l, interp, boundary).pdf(x).ln();
            assert!((lp - direct).abs() <= 1e-4 * direct.abs().max(1.0));
            let fd = finite_differences(&l64, |l| pdf1d_ln_pdf(l, x64, interp, boundary));
            for k in 0..N {
                total += 1;
                if rel_err(f64::from(g[k]), fd[k]) > 1e-2 {
                    bad += 1;
                }
            }
        }
    }
    (bad, total)
}

#[test]
fn gradient_pdf1d() {
    let mut rng = Pcg32::new(42, 0);
    let mut sums = (0, 0);
    for (b, t) in [
        check_grad_1d::<1>(&mut rng),
        check_grad_1d::<2>(&mut rng),
        check_grad_1d::<16>(&mut rng),
        check_grad_1d::<32>(&mut rng),
        check_grad_1d::<64>(&mut rng),
    ] {
        sums.0 += b;
        sums.1 += t;
    }
    assert!(
        sums.0 * 100 <= sums.1,
        "{} of {} gradient components off by > 1 %",
        sums.0,
        sums.1
    );
}

#[test]
fn gradient_factorised() {
    const M: usize = 32;
    const N: usize = 16;
    let mut rng = Pcg32::new(43, 0);
    let (mut bad, mut total) = (0, 0);
    for &interp in &[Interpolation::Nearest, Interpolation::Linear] {
        for trial in 0..100 {
            let kind = if trial % 4 == 3 {
                LogitKind::Spiky
            } else {
                LogitKind::Random
            };
            let lm: [f32; M] = logits(&mut rng, kind);
            let lc: [f32; N] = logits(&mut rng, kind);
            let eps = Vec2::new(
                point_off_kinks(&mut rng, M, interp),
                point_off_kinks(&mut rng, N, interp),
            );
            let d = factorised::direction_from_square(eps);
            let (mut gm, mut gc) = ([0.0; M], [0.0; N]);
            let lp = factorised::grad_log_pdf(&lm, &lc, interp, d, &mut gm, &mut gc);
            let (e1, e2) = oracle_square(d);
            let (lm64, lc64) = (to_f64(&lm), to_f64(&lc));
            let oracle_m = |l: &[f64]| pdf1d_ln_pdf(l, e1, interp, Boundary::Wrap);
            let oracle_c = |l: &[f64]| pdf1d_ln_pdf(l, e2, interp, Boundary::Clamp);
            let oracle = oracle_m(&lm64) + oracle_c(&lc64) - (4.0 * std::f64::consts::PI).ln();
            assert!((f64::from(lp) - oracle).abs() <= 1e-4 * oracle.abs().max(1.0));
            // The same density as the per-query pdf.
            let pm = Pdf1d::from_logits(&lm, interp, Boundary::Wrap);
            let pc = Pdf1d::from_logits(&lc, interp, Boundary::Clamp);
            let direct = factorised::pdf(&pm, &pc, d).ln();
            assert!((lp - direct).abs() <= 1e-4 * direct.abs().max(1.0));
            let fd_m = finite_differences(&lm64, oracle_m);
            let fd_c = finite_differences(&lc64, oracle_c);
            for k in 0..M {
                total += 1;
                bad += usize::from(rel_err(f64::from(gm[k]), fd_m[k]) > 1e-2);
            }
            for k in 0..N {
                total += 1;
                bad += usize::from(rel_err(f64::from(gc[k]), fd_c[k]) > 1e-2);
            }
        }
    }
    assert!(
        bad * 100 <= total,
        "{bad} of {total} gradient components off by > 1 %"
    );
    assert!((LN_FOUR_PI - (4.0 * std::f32::consts::PI).ln()).abs() < 1e-6);
}

// ---------------------------------------------------------------------------
// Sphere level.
// ---------------------------------------------------------------------------

fn check_table<const M: usize, const N: usize>(seed: u64, kind: LogitKind, interp: Interpolation) {
    let table = random_table::<M, N>(seed, kind, interp);
    // ∫∫ p(ε) dε = 1, exactly piecewise (row constant over each marginal bin).
    let bm = breakpoints(M, interp);
    let mut total = 0.0;
    for i in 0..M {
        let (a, b) = (i as f64 / M as f64, (i + 1) as f64 / M as f64);
        let row = &table.conditionals[i];
        let mass_m = integrate(&|x| f64::from(table.marginal.pdf(x as f32)), &bm, a, b);
        total += mass_m * integral_of(row, 0.0, 1.0);
    }
    assert!((total - 1.0).abs() < 1e-5, "table ∫p = {total}");

    let mut rng = Pcg32::new(seed, 99);
    let (mut skipped, mut mismatched, count) = (0, 0, 100_000);
    for _ in 0..count {
        let u = rng.next_vec2();
        let s = table.sample(u);
        assert!((s.direction.length() - 1.0).abs() < 1e-5);
        assert!(s.pdf > 0.0 && s.pdf.is_finite());
        assert_eq!(s.pdf, table.pdf(s.direction));
        // The sampled ε, recomputed from the 1D samplers (with the margin the
        // table keeps; its row clamp moves ε₁ by ≤ SAMPLE_MARGIN, same row).
        let (e1, p1) = factorised::sample_marginal(&table.marginal, u.x);
        let row = FactorisedTable::<M, N>::row(e1);
        let (e2, p2) = factorised::sample_conditional(&table.conditionals[row], u.y);
        let eps = factorised::square_from_direction(s.direction);
        assert!((eps.x - e1).abs() < 1e-5 || (eps.x - e1).abs() > 1.0 - 1e-5);
        assert!((eps.y - e2).abs() < 1e-5);
        if FactorisedTable::<M, N>::row(eps.x) != row {
            skipped += 1;
            continue;
        }
        // Linear densities are continuous, so the pdf of the sampled ε agrees
        // up to the warp's rounding (~10⁻⁷ in ε) times the slope, which for
        // spiky tables (slopes ~M² next to a peak) can reach 10⁻³ relative.
        let expected = p1 * p2 * INV_FOUR_PI;
        if interp == Interpolation::Linear && (s.pdf - expected).abs() > 1e-3 * expected {
            mismatched += 1;
        }
        let back = table.invert(s.direction);
        assert!(
            (back - u).abs().max_element() <= 1e-4,
            "invert(sample({u})) = {back}"
        );
    }
    assert!(skipped * 1000 <= count, "{skipped} samples changed row");
    assert!(
        mismatched * 1000 <= count,
        "{mismatched} sample pdfs off by > 1e-3"
    );
}

/// Sphere-level chi² of a table on Mitsuba's 101 × 51 grid about `+z`
/// (`u = φ/2π = ε₁`, `v = (1 − cos θ)/2 = ε₂`: the grid is the DF square),
/// binned from the sampled directions in f64 like the generic runner, with
/// exact expected counts: the table is a sum over rows of products of 1D
/// piecewise densities, integrated exactly per cell. (The generic runner in
/// `distributions.rs` integrates cells by Gauss–Legendre, exact only for
/// densities smooth inside a cell, so it can only check table sizes aligned
/// with its grid; see `guiding_tests::cases::factorised`.)
fn chi2_table<const M: usize, const N: usize>(table: &FactorisedTable<M, N>, seed: u64) -> f64 {
    let (res_u, res_v) = (101, 51);
    let mut observed = vec![0u64; res_u * res_v];
    let mut rng = Pcg32::new(seed, 4321);
    for _ in 0..CHI2_SAMPLES {
        let s = table.sample(rng.next_vec2());
        let (e1, e2) = oracle_square(s.direction);
        let iu = ((e1 * res_u as f64) as usize).min(res_u - 1);
        let iv = ((e2 * res_v as f64) as usize).min(res_v - 1);
        observed[iv * res_u + iu] += 1;
    }
    let bm = breakpoints(M, table.marginal.interpolation());
    let mut expected = vec![0.0; res_u * res_v];
    for iu in 0..res_u {
        let (u0, u1) = (iu as f64 / res_u as f64, (iu + 1) as f64 / res_u as f64);
        for r in 0..M {
            let (r0, r1) = (r as f64 / M as f64, (r + 1) as f64 / M as f64);
            let (a, b) = (u0.max(r0), u1.min(r1));
            if a >= b {
                continue;
            }
            let mass = integrate(&|x| f64::from(table.marginal.pdf(x as f32)), &bm, a, b);
            for iv in 0..res_v {
                let (v0, v1) = (iv as f64 / res_v as f64, (iv + 1) as f64 / res_v as f64);
                expected[iv * res_u + iu] +=
                    mass * integral_of(&table.conditionals[r], v0, v1) * CHI2_SAMPLES as f64;
            }
        }
    }
    chi2_p_value(&observed, &expected)
}

/// The declared count that the suite-wide Šidák correction uses must match
/// the chi² tests this file really runs.
#[test]
fn standalone_chi2_count_is_declared() {
    let sizes_1d = 5; // check_chi2::<1, 2, 16, 32, 64>
    let one_d = sizes_1d * CONFIGS.len() * KINDS.len();
    let tables = 2 * 2 * 2 * 2; // chi2_tables: sizes × interpolations × kinds × seeds
    assert_eq!(one_d + tables, STANDALONE_CHI2_TESTS);
}

#[test]
fn chi2_tables() {
    let alpha = sidak_alpha();
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        for kind in [LogitKind::Random, LogitKind::Spiky] {
            for seed in [5, 6] {
                let p = chi2_table(&*random_table::<32, 16>(seed, kind, interp), seed);
                assert!(
                    p > alpha,
                    "chi² rejected 32×16 {interp:?} {kind:?} seed {seed}: p = {p:e}"
                );
                let p = chi2_table(&*random_table::<64, 32>(seed, kind, interp), seed);
                assert!(
                    p > alpha,
                    "chi² rejected 64×32 {interp:?} {kind:?} seed {seed}: p = {p:e}"
                );
            }
        }
    }
}

#[test]
fn table_sample_invert_normalisation() {
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        for kind in [LogitKind::Random, LogitKind::Spiky] {
            check_table::<32, 16>(1, kind, interp);
            check_table::<64, 32>(2, kind, interp);
            check_table::<1, 1>(3, kind, interp);
            check_table::<2, 2>(4, kind, interp);
        }
    }
}

/// The warp round trip `ε → ω → ε` moves `ε` by at most 4 ulps of 1 in each
/// coordinate (2 and 1 measured), a quarter of `SAMPLE_MARGIN`, over points
/// concentrated at bin edges, at the seam and near the poles.
#[test]
fn warp_round_trip_within_margin() {
    let ulp = 1.0 / 16_777_216.0f32;
    let mut rng = Pcg32::new(61, 3);
    let (mut worst_x, mut worst_y) = (0.0f32, 0.0f32);
    for i in 0..1_000_000u32 {
        let mut e = rng.next_vec2();
        let near = |rng: &mut Pcg32| {
            let k = (rng.next_u32() % 129) as f32 / 128.0;
            (k + (rng.next_f32() - 0.5) * 64.0 * ulp).clamp(SAMPLE_MARGIN, 1.0 - SAMPLE_MARGIN)
        };
        match i % 4 {
            1 => e.x = near(&mut rng),
            2 => e.y = near(&mut rng),
            3 => {
                // Near the poles, down to the margin.
                let t = SAMPLE_MARGIN * (1.0 + 1e3 * rng.next_f32());
                e.y = if rng.next_u32() % 2 == 0 { t } else { 1.0 - t };
            }
            _ => {}
        }
        let b = factorised::square_from_direction(factorised::direction_from_square(e));
        let dx = (b.x - e.x).abs();
        worst_x = worst_x.max(dx.min(1.0 - dx));
        worst_y = worst_y.max((b.y - e.y).abs());
    }
    println!(
        "warp round trip: {} ulps in ε₁, {} in ε₂",
        worst_x / ulp,
        worst_y / ulp
    );
    assert!(worst_x <= 4.0 * ulp && worst_y <= 4.0 * ulp);
    assert!(4.0 * ulp <= 0.25 * SAMPLE_MARGIN);
}

/// Regression (fuzz target `distributions`): one-hot tables (logits ±10³⁰)
/// sampled at `u ∈ {0, 1 − 2⁻²⁴}` and next to every bin edge put `ε` on a bin
/// edge or a pole, whose direction used to come back from the warp in the
/// zero-density neighbour (`pdf(ω) = 0` for a sampled `ω`). Every sample must
/// now lie strictly inside its cell and have `pdf(ω) = ` the sampled pdf.
fn check_one_hot<const M: usize, const N: usize>(interp: Interpolation) {
    let edges = [0.0, 1e-30, 1e-7, 0.5, 1.0 - 1e-7, ONE_MINUS_EPSILON];
    for hot_m in 0..M {
        for hot_n in [0, N / 2, N - 1] {
            let mut lm = [-1e30f32; M];
            lm[hot_m] = 1e30;
            let mut lc = [[-1e30f32; N]; M];
            for row in &mut lc {
                row[hot_n] = 1e30;
            }
            let table = FactorisedTable::<M, N>::from_logits(&lm, &lc, interp);
            for &ux in &edges {
                for &uy in &edges {
                    let s = table.sample(Vec2::new(ux, uy));
                    let at = table.pdf(s.direction);
                    assert!(
                        s.pdf > 0.0 && s.pdf == at,
                        "{M}×{N} {interp:?} hot ({hot_m}, {hot_n}) u = ({ux}, {uy}): \
                         sample pdf {} vs pdf(ω) {at}",
                        s.pdf
                    );
                    let eps = factorised::square_from_direction(s.direction);
                    assert!(
                        eps.y >= 0.5 * SAMPLE_MARGIN && eps.y <= 1.0 - 0.5 * SAMPLE_MARGIN,
                        "ε₂ = {} at a pole",
                        eps.y
                    );
                    if interp == Interpolation::Nearest {
                        let cell = ((eps.x * M as f32) as usize, (eps.y * N as f32) as usize);
                        assert_eq!(cell, (hot_m, hot_n), "ε = {eps} left its cell");
                    }
                }
            }
        }
    }
}

#[test]
fn one_hot_tables_at_edges() {
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        check_one_hot::<32, 16>(interp);
        check_one_hot::<8, 4>(interp);
        check_one_hot::<1, 2>(interp);
    }
}

/// Regression (fuzz target `distributions`, crash minimised to
/// `fuzz/corpus/distributions/crash-df-product-underflow-u0`): a bin of
/// value ~10⁻³⁷ next to empty ones was chosen at `u = 0` and sampled next to
/// its zero end; marginal × conditional underflowed to a sample pdf of 0.
/// Pieces of mass ≤ `PDF1D_SAMPLE_CUT` are now never chosen.
#[test]
fn tiny_mass_pieces_are_not_sampled() {
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        for tiny in [-87.0f32, -60.0, -30.0] {
            // Logits: empty bins, one bin e^tiny times the big one, the big one.
            let mut lm = [-1e30f32; 32];
            lm[11] = tiny;
            lm[12] = 0.0;
            let mut row = [-1e30f32; 16];
            row[14] = tiny;
            row[15] = 0.0;
            let table = FactorisedTable::<32, 16>::from_logits(&lm, &[row; 32], interp);
            for ux in [0.0, 1e-30, 1.0 / 16_777_216.0, 0.5, ONE_MINUS_EPSILON] {
                for uy in [0.0, 1e-30, 1.0 / 16_777_216.0, 0.5, ONE_MINUS_EPSILON] {
                    let s = table.sample(Vec2::new(ux, uy));
                    let at = table.pdf(s.direction);
                    assert!(
                        s.pdf > 0.0 && s.pdf == at,
                        "{interp:?} e^{tiny} u ({ux}, {uy}): sample pdf {} vs {at}",
                        s.pdf
                    );
                }
            }
            let pdf = Pdf1d::from_logits(&row, interp, Boundary::Clamp);
            let (x, p) = pdf.sample(0.0);
            // The tiny piece (mass ≤ 2⁻²⁴: bin 14 for nearest, between the
            // centres of bins 13 and 14 for linear) is skipped.
            let start = match interp {
                Interpolation::Nearest => 15.0 / 16.0,
                Interpolation::Linear => 14.5 / 16.0,
            };
            assert!(
                x >= start && p > 0.0,
                "{interp:?} e^{tiny}: sample(0) = ({x}, {p})"
            );
        }
    }
}

/// `sample_with_margin` keeps `x` inside its piece and is `sample` with a
/// zero margin; the margin moves `x` by at most the margin.
#[test]
fn pdf1d_sample_margin() {
    let mut rng = Pcg32::new(62, 1);
    for &(interp, boundary) in &CONFIGS {
        for &kind in &KINDS {
            let pdf = pdf_from::<16>(12, kind, interp, boundary);
            for i in 0..20_000 {
                let u = match i {
                    0 => 0.0,
                    1 => ONE_MINUS_EPSILON,
                    _ => rng.next_f32(),
                };
                let (x0, _) = pdf.sample(u);
                assert_eq!(pdf.sample_with_margin(u, 0.0), pdf.sample(u));
                let (x, p) = pdf.sample_with_margin(u, SAMPLE_MARGIN);
                assert!(p > 0.0 && p == pdf.pdf(x));
                assert!((x - x0).abs() <= SAMPLE_MARGIN, "moved {x0} → {x}");
                // Piece ends: bin edges (nearest) or centres and 0, 1 (linear).
                let s = match interp {
                    Interpolation::Nearest => x * 16.0,
                    Interpolation::Linear => x * 16.0 + 0.5,
                };
                let to_end = (s - s.round()).abs() / 16.0;
                let to_end = if interp == Interpolation::Linear {
                    to_end.min(x).min(1.0 - x)
                } else {
                    to_end
                };
                assert!(
                    to_end >= SAMPLE_MARGIN * (1.0 - 1e-3),
                    "x = {x} within {to_end} of a piece end"
                );
            }
        }
    }
}

#[test]
fn per_query_functions() {
    let mut rng = Pcg32::new(8, 8);
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        let table = random_table::<16, 8>(8, LogitKind::Random, interp);
        for _ in 0..10_000 {
            let u = rng.next_vec2();
            let (e1, p1) = factorised::sample_marginal(&table.marginal, u.x);
            let conditional = &table.conditionals[FactorisedTable::<16, 8>::row(e1)];
            let (e2, p2) = factorised::sample_conditional(conditional, u.y);
            let d = factorised::direction_from_square(Vec2::new(e1, e2));
            assert!((d.length() - 1.0).abs() < 1e-5);
            let p = factorised::pdf(&table.marginal, conditional, d);
            if interp == Interpolation::Linear {
                let expected = p1 * p2 * INV_FOUR_PI;
                assert!((p - expected).abs() <= 1e-3 * expected);
            }
            assert!(p.is_finite() && p >= 0.0);
        }
    }
    // Degenerate directions.
    let table = random_table::<16, 8>(9, LogitKind::Spiky, Interpolation::Linear);
    for d in [
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::splat(f32::INFINITY),
        Vec3::new(1e-30, 0.0, 0.0),
        Vec3::new(f32::MAX, f32::MAX, 0.0),
        Vec3::Z,
        -Vec3::Z,
    ] {
        let p = table.pdf(d);
        assert!(p.is_finite() && p >= 0.0, "pdf({d}) = {p}");
        let u = table.invert(d);
        assert!(u.is_finite() && u.cmpge(Vec2::ZERO).all() && u.cmplt(Vec2::ONE).all());
        let eps = factorised::square_from_direction(d);
        assert!(eps.cmpge(Vec2::ZERO).all() && eps.cmple(Vec2::ONE).all());
    }
    assert_eq!(
        factorised::square_from_direction(Vec3::new(1e-30, 0.0, 0.0)),
        factorised::square_from_direction(Vec3::X)
    );
    assert_eq!(
        std::mem::size_of::<FactorisedTable<16, 8>>(),
        4 * ((16 + 2) + 16 * (8 + 2))
    );
}

// ---------------------------------------------------------------------------
// Robustness.
// ---------------------------------------------------------------------------

fn any_logit() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(1e30f32),
        Just(-1e30f32),
        Just(0.0f32),
        -1e30f32..=1e30f32,
        -40f32..40f32,
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
    ]
}

fn any_x() -> impl Strategy<Value = f32> {
    prop_oneof![
        0f32..1f32,
        Just(0.0f32),
        Just(1.0f32),
        Just(ONE_MINUS_EPSILON),
        proptest::num::f32::ANY,
    ]
}

fn check_pdf1d_valid<const N: usize>(l: &[f32; N], us: &[f32], x: f32) {
    for &(interp, boundary) in &CONFIGS {
        let pdf = Pdf1d::from_logits(l, interp, boundary);
        let sum: f32 = pdf.values.iter().sum();
        assert!(
            (sum - N as f32).abs() <= 1e-4 * N as f32,
            "{:?}",
            pdf.values
        );
        for &u in us {
            let (s, _) = valid_sample(&pdf, u, &format!("{l:?} {interp:?} {boundary:?}"));
            let c = pdf.invert(s);
            assert!((0.0..1.0).contains(&c));
        }
        let p = pdf.pdf(x);
        assert!(p >= 0.0 && p.is_finite());
        let c = pdf.invert(x);
        assert!((0.0..1.0).contains(&c));
        let mut g = [0.0; N];
        let lp = Pdf1d::grad_log_pdf(l, x, interp, boundary, &mut g);
        assert!(lp.is_finite(), "ln p = {lp}");
        assert!(
            g.iter().all(|v| v.is_finite() && v.abs() <= 1.0 + 1e-5),
            "{g:?}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn pdf1d_any_logits_16(
        l in proptest::array::uniform16(any_logit()),
        us in proptest::collection::vec(prop_oneof![0f32..1f32, Just(0.0f32), Just(ONE_MINUS_EPSILON), proptest::num::f32::ANY], 8),
        x in any_x(),
    ) {
        check_pdf1d_valid(&l, &us, x);
    }

    #[test]
    fn pdf1d_any_logits_small(
        l1 in proptest::array::uniform1(any_logit()),
        l2 in proptest::array::uniform2(any_logit()),
        l3 in proptest::array::uniform3(any_logit()),
        us in proptest::collection::vec(prop_oneof![0f32..1f32, Just(0.0f32), Just(ONE_MINUS_EPSILON)], 8),
        x in any_x(),
    ) {
        check_pdf1d_valid(&l1, &us, x);
        check_pdf1d_valid(&l2, &us, x);
        check_pdf1d_valid(&l3, &us, x);
    }

    #[test]
    fn table_any_logits(
        lm in proptest::array::uniform8(any_logit()),
        lc in proptest::array::uniform8(proptest::array::uniform4(any_logit())),
        u in proptest::collection::vec((0f32..1f32, 0f32..1f32), 8),
        d in (proptest::num::f32::ANY, proptest::num::f32::ANY, proptest::num::f32::ANY),
        nearest in any::<bool>(),
    ) {
        let interp = if nearest { Interpolation::Nearest } else { Interpolation::Linear };
        let table = FactorisedTable::<8, 4>::from_logits(&lm, &lc, interp);
        for &(a, b) in &u {
            let s = table.sample(Vec2::new(a, b));
            prop_assert!((s.direction.length() - 1.0).abs() < 1e-5);
            prop_assert!(s.pdf > 0.0 && s.pdf.is_finite());
            let back = table.invert(s.direction);
            prop_assert!(back.cmpge(Vec2::ZERO).all() && back.cmplt(Vec2::ONE).all());
        }
        let d = Vec3::new(d.0, d.1, d.2);
        let p = table.pdf(d);
        prop_assert!(p >= 0.0 && p.is_finite());
        let back = table.invert(d);
        prop_assert!(back.cmpge(Vec2::ZERO).all() && back.cmplt(Vec2::ONE).all());
        let (mut gm, mut gc) = ([0.0; 8], [0.0; 4]);
        let lp = factorised::grad_log_pdf(&lm, &lc[0], interp, d, &mut gm, &mut gc);
        prop_assert!(lp.is_finite());
        prop_assert!(gm.iter().chain(gc.iter()).all(|v| v.is_finite()));
    }
}
