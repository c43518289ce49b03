//! The MLP (layout, forward pass against an f64 oracle, gradients against
//! central differences, batched kernels, initialisation, range), the
//! optimisers (Adam against an f64 reference, non-finite guards, EMA) and
//! the shader-side RNG.
//!
//! Tolerances are derived from `f32` rounding, with `u = 2⁻²⁴` the unit
//! roundoff and `γ_n = n u / (1 − n u)`:
//! - a dot product of `n` terms plus a bias, summed in any order, is off by
//!   at most `γ_{n+1} Σ|terms|` (Higham, *Accuracy and Stability of
//!   Numerical Algorithms*, §3.1). Through `L` layers (ReLU is 1-Lipschitz)
//!   the forward error is at most `L γ_{n+1} A` to first order, with `A` the
//!   same network evaluated on `|W|`, `|b|`, `|x|` without activations;
//! - a gradient component is a chain of such sums: its relative error is
//!   below `(HIDDEN + 1) γ_64 κ ≈ 1.5·10⁻⁴` for a condition number
//!   `κ = Σ|terms| / |Σ terms| ≤ 10`, so we allow a symmetric relative error
//!   of 10⁻³; components smaller than 10⁻³ × the gradient's RMS are compared
//!   absolutely against that floor, and 0.1 % may fail (ReLU kinks within the
//!   difference step — the network is piecewise linear in every parameter,
//!   so central differences are otherwise exact up to f64 rounding — and the
//!   rare near-cancelling sums with `κ > 10`; see [`MLP_GRADIENT_TOL`],
//!   [`MLP_GRADIENT_IGNORED`] and their negative control);
//! - the batched kernels (fused multiply–adds, their own tiling) against the
//!   per-query kernels: both satisfy the first bound, so each layer's sums
//!   differ by at most `2 γ_{n+1}` times the absolute network's magnitude,
//!   accumulated layer by layer (`err_l = |W_l| err_{l−1} + 2 γ_{n_l+1} A_l`,
//!   in f64), and likewise for the deltas and the parameter gradients summed
//!   over the batch (see [`forward_error_bounds`], [`backward_error_bounds`],
//!   [`gradient_error_bounds`]).
//!
//! Every bound is printed with the largest observed error/bound ratio.

use guiding_core::mlp::{BatchKernel, Mlp, MlpContext, OUTPUT_INIT_SCALE};
use guiding_core::optim::{
    adam_ema_step, adam_step, adam_update, adam_update_with_factors, all_finite, ema_update,
    ema_update_element, ema_weight, powi, AdamConfig, AdamStepFactors,
};
use guiding_core::rng::{hash2, pcg_hash, symmetric_unit_f32, uniform_at, unit_f32, Rng};
use guiding_tests::gradcheck::{central_difference, GradientErrors};
use guiding_tests::rng::Pcg32;
use proptest::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Unit roundoff of `f32`.
const U: f64 = f32::EPSILON as f64 / 2.0;

/// Smallest positive subnormal `f32` (bounds the absolute error of a rounding
/// to a subnormal, twice over).
const ETA: f64 = 1.401_298_464_324_817e-45;

fn gamma(n: usize) -> f64 {
    n as f64 * U / (1.0 - n as f64 * U)
}

/// Bit-identical, treating every NaN as equal.
fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

fn assert_same(what: &str, a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
        assert!(
            same(x, y),
            "{what}[{i}]: {x:e} ({:#x}) vs {y:e} ({:#x})",
            x.to_bits(),
            y.to_bits()
        );
    }
}

// ---------------------------------------------------------------------------
// f64 oracle: the documented layout and network, written independently.

#[derive(Clone, Copy, Debug)]
struct Dims {
    input: usize,
    width: usize,
    out: usize,
    hidden: usize,
}

impl Dims {
    fn of<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>() -> Self {
        Self {
            input: IN,
            width: WIDTH,
            out: OUT,
            hidden: HIDDEN,
        }
    }

    /// `(fan_in, fan_out)` of every layer, in evaluation order.
    fn layers(self) -> Vec<(usize, usize)> {
        let mut v = vec![(self.input, self.width)];
        v.extend((1..self.hidden).map(|_| (self.width, self.width)));
        v.push((self.width, self.out));
        v
    }

    fn param_count(self) -> usize {
        self.layers().iter().map(|&(i, o)| i * o + o).sum()
    }
}

/// Every layer's output (hidden layers after ReLU, the last one linear).
/// `abs`: evaluate `|W| h + |b|` without activation instead (the magnitude
/// bound `A` of the module docs).
fn forward64_layers(d: Dims, params: &[f64], x: &[f64], abs: bool) -> Vec<Vec<f64>> {
    let layers = d.layers();
    let mut outs = Vec::new();
    let mut h: Vec<f64> = if abs {
        x.iter().map(|v| v.abs()).collect()
    } else {
        x.to_vec()
    };
    let mut off = 0;
    for (l, &(fi, fo)) in layers.iter().enumerate() {
        let w = &params[off..off + fi * fo];
        let b = &params[off + fi * fo..off + fi * fo + fo];
        let last = l + 1 == layers.len();
        h = (0..fo)
            .map(|o| {
                let row = &w[o * fi..(o + 1) * fi];
                if abs {
                    b[o].abs() + row.iter().zip(&h).map(|(w, x)| w.abs() * x).sum::<f64>()
                } else {
                    let z = b[o] + row.iter().zip(&h).map(|(w, x)| w * x).sum::<f64>();
                    if last {
                        z
                    } else {
                        z.max(0.0)
                    }
                }
            })
            .collect();
        outs.push(h.clone());
        off += fi * fo + fo;
    }
    outs
}

fn forward64(d: Dims, params: &[f64], x: &[f64]) -> Vec<f64> {
    forward64_layers(d, params, x, false).pop().unwrap()
}

fn to64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| f64::from(x)).collect()
}

/// Initialised parameters plus a perturbation of every entry (so biases are
/// non-zero and the output layer is not tiny).
fn random_params<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>(
    rng: &mut Pcg32,
) -> Vec<f32> {
    let mut p = vec![0.0; Mlp::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT];
    Mlp::<IN, WIDTH, OUT, HIDDEN>::init(&mut p, 0, rng.next_u32());
    for v in &mut p {
        *v += rng.uniform(-0.1, 0.1);
    }
    p
}

fn random_input<const N: usize>(rng: &mut Pcg32) -> [f32; N] {
    core::array::from_fn(|_| rng.uniform(-1.0, 1.0))
}

// ---------------------------------------------------------------------------
// Layout.

fn check_layout<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>() {
    type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
    let d = Dims::of::<IN, WIDTH, OUT, HIDDEN>();
    let formula = (IN + 1) * WIDTH + (HIDDEN - 1) * (WIDTH + 1) * WIDTH + (WIDTH + 1) * OUT;
    assert_eq!(M::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT, formula, "{d:?}");
    assert_eq!(d.param_count(), formula, "{d:?}");
    let mut off = 0;
    for (l, &(fi, fo)) in d.layers().iter().enumerate() {
        assert_eq!(
            M::<IN, WIDTH, OUT, HIDDEN>::layer_offset(l),
            off,
            "{d:?} layer {l}"
        );
        assert_eq!(M::<IN, WIDTH, OUT, HIDDEN>::fan_in(l), fi);
        assert_eq!(M::<IN, WIDTH, OUT, HIDDEN>::fan_out(l), fo);
        off += fi * fo + fo;
    }
    assert_eq!(
        M::<IN, WIDTH, OUT, HIDDEN>::layer_offset(HIDDEN),
        M::<IN, WIDTH, OUT, HIDDEN>::OUTPUT_LAYER_OFFSET
    );
    assert_eq!(
        M::<IN, WIDTH, OUT, HIDDEN>::MACS,
        d.layers().iter().map(|&(i, o)| i * o).sum::<usize>()
    );
}

#[test]
fn param_count_and_layer_offsets_follow_the_documented_layout() {
    check_layout::<7, 16, 5, 2>();
    check_layout::<32, 64, 32, 3>();
    check_layout::<3, 5, 2, 1>();
    check_layout::<1, 4, 1, 4>();
    assert_eq!(Mlp::<32, 64, 32, 3>::PARAM_COUNT, 12_512);
    assert_eq!(Mlp::<32, 64, 32, 3>::MACS, 12_288);
}

/// A network at a non-zero offset of a bigger buffer reads, initialises and
/// writes gradients only in its own range: NaN canaries around it stay
/// untouched and never reach the outputs, and every result equals the one
/// at offset 0.
fn check_canaries<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>() {
    type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
    let n = M::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT;
    let canary = f32::from_bits(0x7fc0_1234);
    let (off, tail) = (37, 29);
    let mut rng = Pcg32::new(11, 3);
    let alone = random_params::<IN, WIDTH, OUT, HIDDEN>(&mut rng);
    let mut buf = vec![canary; off + n + tail];
    buf[off..off + n].copy_from_slice(&alone);

    let x = random_input::<IN>(&mut rng);
    let mut ctx = MlpContext::ZERO;
    let mut ctx0 = MlpContext::ZERO;
    let y = M::<IN, WIDTH, OUT, HIDDEN>::forward(&buf, off, &x, &mut ctx);
    let y0 = M::<IN, WIDTH, OUT, HIDDEN>::forward(&alone, 0, &x, &mut ctx0);
    assert!(y.iter().all(|v| v.is_finite()));
    assert_same("forward at offset", &y, &y0);
    assert_same(
        "infer at offset",
        &M::<IN, WIDTH, OUT, HIDDEN>::infer(&buf, off, &x),
        &y0,
    );

    let dy = random_input::<OUT>(&mut rng);
    let mut grad = vec![canary; off + n + tail];
    grad[off..off + n].fill(0.0);
    let mut grad0 = vec![0.0; n];
    let (mut dx, mut dx0) = ([0.0; IN], [0.0; IN]);
    M::<IN, WIDTH, OUT, HIDDEN>::backward(&buf, off, &x, &ctx, &dy, &mut grad, &mut dx);
    M::<IN, WIDTH, OUT, HIDDEN>::backward(&alone, 0, &x, &ctx0, &dy, &mut grad0, &mut dx0);
    assert_same("backward at offset", &grad[off..off + n], &grad0);
    assert_same("d_input at offset", &dx, &dx0);
    for k in (0..off).chain(off + n..off + n + tail) {
        assert_eq!(
            grad[k].to_bits(),
            canary.to_bits(),
            "backward wrote grad[{k}]"
        );
    }
    // The batched backward too.
    grad[off..off + n].fill(0.0);
    let mut dxs = [[0.0; IN]];
    M::<IN, WIDTH, OUT, HIDDEN>::backward_batch(
        &buf,
        off,
        &[x],
        &[ctx],
        &[dy],
        &mut grad,
        &mut dxs,
    );
    // (Against the batched kernel at offset 0: bit-identical.)
    let mut grad_b0 = vec![0.0; n];
    let mut dxs0 = [[0.0; IN]];
    M::<IN, WIDTH, OUT, HIDDEN>::backward_batch(
        &alone,
        0,
        &[x],
        &[ctx0],
        &[dy],
        &mut grad_b0,
        &mut dxs0,
    );
    assert_same("backward_batch at offset", &grad[off..off + n], &grad_b0);
    assert_same("backward_batch d_input at offset", &dxs[0], &dxs0[0]);
    for k in (0..off).chain(off + n..off + n + tail) {
        assert_eq!(
            grad[k].to_bits(),
            canary.to_bits(),
            "backward_batch wrote grad[{k}]"
        );
    }
    let mut ys = [[0.0; OUT]];
    M::<IN, WIDTH, OUT, HIDDEN>::infer_batch(&buf, off, &[x], &mut ys);
    let mut ys0 = [[0.0; OUT]];
    M::<IN, WIDTH, OUT, HIDDEN>::infer_batch(&alone, 0, &[x], &mut ys0);
    assert!(ys[0].iter().all(|v| v.is_finite()));
    assert_same("infer_batch at offset", &ys[0], &ys0[0]);

    M::<IN, WIDTH, OUT, HIDDEN>::init(&mut buf, off, 5);
    let mut init0 = vec![0.0; n];
    M::<IN, WIDTH, OUT, HIDDEN>::init(&mut init0, 0, 5);
    assert_same("init at offset", &buf[off..off + n], &init0);
    for k in (0..off).chain(off + n..off + n + tail) {
        assert_eq!(buf[k].to_bits(), canary.to_bits(), "init wrote params[{k}]");
    }
}

#[test]
fn a_network_at_an_offset_touches_only_its_range() {
    check_canaries::<7, 16, 5, 2>();
    check_canaries::<3, 5, 2, 1>();
    check_canaries::<32, 64, 32, 3>();
}

// ---------------------------------------------------------------------------
// Forward pass.

fn check_forward<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>(
    seed: u64,
) -> f64 {
    type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
    let d = Dims::of::<IN, WIDTH, OUT, HIDDEN>();
    let mut rng = Pcg32::new(seed, 7);
    let layers = HIDDEN + 1;
    let bound_factor = 2.0 * layers as f64 * gamma(IN.max(WIDTH) + 1);
    let mut worst: f64 = 0.0;
    for _ in 0..50 {
        let p = random_params::<IN, WIDTH, OUT, HIDDEN>(&mut rng);
        let x = random_input::<IN>(&mut rng);
        let mut ctx = MlpContext::ZERO;
        let y = M::<IN, WIDTH, OUT, HIDDEN>::forward(&p, 0, &x, &mut ctx);
        assert_same(
            "forward vs infer",
            &y,
            &M::<IN, WIDTH, OUT, HIDDEN>::infer(&p, 0, &x),
        );
        let (p64, x64) = (to64(&p), to64(&x));
        let exact = forward64_layers(d, &p64, &x64, false);
        let mag = forward64_layers(d, &p64, &x64, true);
        let mut check = |what: &str, got: &[f32], exact: &[f64], mag: &[f64]| {
            for (k, ((&g, &e), &a)) in got.iter().zip(exact).zip(mag).enumerate() {
                let bound = bound_factor * a;
                let err = (f64::from(g) - e).abs();
                worst = worst.max(err / bound);
                assert!(
                    err <= bound,
                    "{d:?} {what}[{k}]: {g:e} vs {e:e} (bound {bound:e})"
                );
            }
        };
        for l in 0..HIDDEN {
            check(&format!("hidden {l}"), &ctx.hidden[l], &exact[l], &mag[l]);
        }
        check("output", &y, &exact[HIDDEN], &mag[HIDDEN]);
    }
    worst
}

#[test]
fn forward_matches_the_f64_oracle_and_infer_bitwise() {
    let w = [
        check_forward::<7, 16, 5, 2>(1),
        check_forward::<32, 64, 32, 3>(2),
        check_forward::<3, 5, 2, 1>(3),
        check_forward::<1, 4, 1, 4>(4),
    ];
    println!("forward: largest error / (2 L γ A) = {w:?}");
}

// ---------------------------------------------------------------------------
// Gradients.

/// Symmetric relative error allowed between `backward` and central
/// differences (`h = 10⁻⁶`) of the f64 oracle. The loss `Σ c_k y_k` is
/// piecewise linear in every single parameter and input (ReLU), so away from
/// a kink the differences are exact up to f64 rounding
/// (`ε₆₄ |loss| / h ≈ 10⁻¹⁰` of the loss's scale). The f32 gradient is a
/// chain of `HIDDEN + 1` sums of at most 64 terms: relative error
/// `≤ (HIDDEN + 1) γ₆₅ κ ≈ 1.5·10⁻⁴` for a condition number
/// `κ = Σ|terms| / |Σ terms| ≤ 10`, and below the floor (`10⁻³ ×` the RMS
/// numeric gradient) the same absolute error against the floor. `10⁻³` leaves
/// a factor 6. Measured over the 31 004 parameter and 200 input components of
/// `backward_matches_central_differences_of_the_f64_oracle` (four networks,
/// fixed seeds): 99th percentiles 2·10⁻⁷–5.5·10⁻⁵, worst 5.5·10⁻⁵ (an
/// input component of the 32 → 3 × 64 → 32 network), none above `10⁻³`.
const MLP_GRADIENT_TOL: f64 = 1e-3;

/// Fraction of the components that may exceed [`MLP_GRADIENT_TOL`]: those
/// whose difference step `±h max(1, |θ|)` (`h = 10⁻⁶`) straddles a ReLU
/// kink. The step moves each downstream pre-activation `z` by
/// `≲ h |∂z/∂θ| ≲ h` (O(1) weights and activations), so it straddles that
/// unit's kink with probability `≲ 2h · p_z(0)`, `p_z(0) ≲ 3` the density of
/// the pre-activations at 0 (spread ~0.3): `≲ 6·10⁻⁶` per unit, `≲ 10⁻³` per
/// component summed over the ≤ 192 units of the widest network. 0.1 % admits
/// that bound; measured: none of the 31 204 components. It was 1 %
/// (tiny-cuda-nn's convention); the negative control
/// (`gradient_check_rejects_planted_defects`) fails 84–1882 components of a
/// check against at most 25 allowed, so it is caught either way.
const MLP_GRADIENT_IGNORED: f64 = 1e-3;

/// `backward` against central differences of the f64 oracle for the loss
/// `Σ c_k y_k` (random `c`), over `trials` random networks and inputs:
/// `[("weights and biases", …), ("input", …)]`, each floored at `10⁻³ ×`
/// the RMS numeric gradient of the first trial.
fn gradient_errors<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>(
    seed: u64,
    trials: usize,
) -> [(&'static str, GradientErrors); 2] {
    type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
    let d = Dims::of::<IN, WIDTH, OUT, HIDDEN>();
    let mut rng = Pcg32::new(seed, 9);
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let mut param_errors: Option<GradientErrors> = None;
    let mut input_errors: Option<GradientErrors> = None;
    for t in 0..trials {
        let p = random_params::<IN, WIDTH, OUT, HIDDEN>(&mut rng);
        let x = random_input::<IN>(&mut rng);
        let c = random_input::<OUT>(&mut rng);
        let mut ctx = MlpContext::ZERO;
        let _ = M::<IN, WIDTH, OUT, HIDDEN>::forward(&p, 0, &x, &mut ctx);
        let mut grad = vec![0.0; p.len()];
        let mut dx = [0.0; IN];
        M::<IN, WIDTH, OUT, HIDDEN>::backward(&p, 0, &x, &ctx, &c, &mut grad, &mut dx);

        let (p64, x64, c64) = (to64(&p), to64(&x), to64(&c));
        let loss = |p: &[f64], x: &[f64]| -> f64 {
            forward64(d, p, x)
                .iter()
                .zip(&c64)
                .map(|(y, c)| y * c)
                .sum()
        };
        let num_p = central_difference(|q| loss(q, &x64), &p64, 1e-6);
        let num_x = central_difference(|q| loss(&p64, q), &x64, 1e-6);
        let pe = param_errors.get_or_insert_with(|| GradientErrors::new(1e-3 * rms(&num_p)));
        pe.push_all(&format!("trial {t} params"), &to64(&grad), &num_p);
        let ie = input_errors.get_or_insert_with(|| GradientErrors::new(1e-3 * rms(&num_x)));
        ie.push_all(&format!("trial {t} input"), &to64(&dx), &num_x);
    }
    [
        ("weights and biases", param_errors.unwrap()),
        ("input", input_errors.unwrap()),
    ]
}

/// [`gradient_errors`] of the four networks the gradient tests check.
fn all_gradient_errors() -> [(Dims, [(&'static str, GradientErrors); 2]); 4] {
    [
        (
            Dims::of::<7, 16, 5, 2>(),
            gradient_errors::<7, 16, 5, 2>(1, 8),
        ),
        (
            Dims::of::<32, 64, 32, 3>(),
            gradient_errors::<32, 64, 32, 3>(2, 2),
        ),
        (
            Dims::of::<3, 5, 2, 1>(),
            gradient_errors::<3, 5, 2, 1>(3, 20),
        ),
        (
            Dims::of::<1, 4, 1, 4>(),
            gradient_errors::<1, 4, 1, 4>(4, 20),
        ),
    ]
}

#[test]
fn backward_matches_central_differences_of_the_f64_oracle() {
    for (d, errors) in all_gradient_errors() {
        for (what, e) in errors {
            let name = format!("{d:?} {what} gradient");
            e.report(&name, MLP_GRADIENT_TOL);
            e.assert(&name, MLP_GRADIENT_TOL, MLP_GRADIENT_IGNORED);
        }
    }
}

/// Negative control: the components of
/// [`backward_matches_central_differences_of_the_f64_oracle`] with a defect
/// planted, the second layer's weight gradient 5 % too large
/// (`e = 0.05/1.05 ≈ 0.048` against the tolerance `10⁻³` for every such
/// component above the floor), or the sign of the first input's gradient
/// flipped, must fail the same check. Measured: 84–1882 parameter
/// components (of 640–25 024) and 2–19 input components (of 20–64) fail,
/// against at most 25 and 0 allowed.
#[test]
fn gradient_check_rejects_planted_defects() {
    for (d, [(_, params), (_, input)]) in all_gradient_errors() {
        let n = d.param_count();
        let layers = d.layers();
        // Layer 1's weights follow layer 0's weights and biases.
        let start = layers[0].0 * layers[0].1 + layers[0].1;
        let w1 = start..start + layers[1].0 * layers[1].1;
        params.assert_rejects_defect(
            &format!("{d:?} weights and biases"),
            "W1 × 1.05",
            (MLP_GRADIENT_TOL, MLP_GRADIENT_IGNORED),
            |i, _| if w1.contains(&(i % n)) { 1.05 } else { 1.0 },
        );
        input.assert_rejects_defect(
            &format!("{d:?} input"),
            "∂/∂x₀ × −1",
            (MLP_GRADIENT_TOL, MLP_GRADIENT_IGNORED),
            |i, _| if i % d.input == 0 { -1.0 } else { 1.0 },
        );
    }
}

/// Backward accumulates (`+=`) into the gradient buffer and writes (`=`)
/// the input gradient.
#[test]
fn backward_accumulates_parameter_gradients_and_overwrites_the_input_gradient() {
    type M = Mlp<7, 16, 5, 2>;
    let mut rng = Pcg32::new(5, 5);
    let p = random_params::<7, 16, 5, 2>(&mut rng);
    let x = random_input::<7>(&mut rng);
    let c = random_input::<5>(&mut rng);
    let mut ctx = MlpContext::ZERO;
    let _ = M::forward(&p, 0, &x, &mut ctx);
    let mut once = vec![0.0; p.len()];
    let mut dx = [f32::NAN; 7];
    M::backward(&p, 0, &x, &ctx, &c, &mut once, &mut dx);
    let dx_once = dx;
    let mut twice = once.clone();
    M::backward(&p, 0, &x, &ctx, &c, &mut twice, &mut dx);
    assert_same("d_input is overwritten", &dx, &dx_once);
    for (k, (&a, &b)) in once.iter().zip(&twice).enumerate() {
        assert_eq!(b, a + a, "grad[{k}] accumulates");
    }
}

// ---------------------------------------------------------------------------
// Batched kernels.
//
// The batched kernels use fused multiply–adds and their own tiling, so they
// are no longer bit-identical to the per-query kernels; they are compared
// within a tolerance derived from the rounding of both.

/// Per-layer bounds on `|batched − per-query|` of one query's forward pass
/// (`[layer][neuron]`, hidden layers then the output layer), to first order.
///
/// A pre-activation `z = b + Σᵢ wᵢ hᵢ` of fan-in `n`, summed in `f32` in any
/// order and with or without fused multiply–adds, is within `γ_{n+1} (|b| +
/// Σᵢ|wᵢ hᵢ|)` of the exact sum of its (computed) inputs, `γ_n = n u / (1 − n
/// u)`, `u = 2⁻²⁴` (Higham, §3.1; an FMA rounds once where a multiply and an
/// add round twice, which only tightens each term's factor). Both kernels
/// satisfy it, so their sums over the same inputs differ by at most `2
/// γ_{n+1} A_l`, with `A_l = |W_l| A_{l−1} + |b_l|` the "absolute network"
/// (`|W|`, `|b|`, `|x|`, activations replaced by the identity) bounding
/// every magnitude. Inputs that already differ by `err_{l−1}` add `|W_l|
/// err_{l−1}` (ReLU is 1-Lipschitz), so, in `f64`:
///
/// ```text
/// err_{−1} = 0,   err_l = |W_l| err_{l−1} + 2 (γ_{n_l+1} A_l + (n_l + 1) η)
/// ```
///
/// `η = 2⁻¹⁴⁹` covers underflow (each rounding to a subnormal errs by at
/// most `η/2` in absolute terms; Higham §2.1); it only matters for the
/// extreme values of the property test.
fn forward_error_bounds(d: Dims, p: &[f64], x: &[f64]) -> Vec<Vec<f64>> {
    let mag = forward64_layers(d, p, x, true);
    let mut prev = vec![0.0; d.input];
    let mut bounds = Vec::new();
    let mut off = 0;
    for (l, &(fi, fo)) in d.layers().iter().enumerate() {
        let w = &p[off..off + fi * fo];
        let err: Vec<f64> = (0..fo)
            .map(|o| {
                let row = &w[o * fi..(o + 1) * fi];
                row.iter().zip(&prev).map(|(w, e)| w.abs() * e).sum::<f64>()
                    + 2.0 * (gamma(fi + 1) * mag[l][o] + (fi + 1) as f64 * ETA)
            })
            .collect();
        bounds.push(err.clone());
        prev = err;
        off += fi * fo + fo;
    }
    bounds
}

/// Bounds of one query's backward pass, given the same context for both
/// kernels (so both use the same ReLU masks): `mag[l]` bounds `|δ_l|` (the
/// gradient at the pre-activation of layer `l`, `l = HIDDEN` being the output
/// gradient), `err[l]` bounds `|δ_l(batched) − δ_l(per-query)|`, and `dx`
/// bounds the input gradient's difference. With `δ_{l−1} = (W_lᵀ δ_l) ⊙
/// [h_{l−1} > 0]` a sum of `fan_out` terms, as in the forward pass:
///
/// ```text
/// mag_H = |dy|,  mag_{l−1} = [h_{l−1} > 0] |W_l|ᵀ mag_l
/// err_H = 0,     err_{l−1} = [h_{l−1} > 0] (|W_l|ᵀ err_l + 2 (γ_{n+1} |W_l|ᵀ mag_l + (n + 1) η))
/// ```
struct BackwardBounds {
    mag: Vec<Vec<f64>>,
    err: Vec<Vec<f64>>,
    dx: Vec<f64>,
}

fn backward_error_bounds(d: Dims, p: &[f64], hidden: &[&[f32]], dy: &[f64]) -> BackwardBounds {
    let layers = d.layers();
    let offsets: Vec<usize> = layers
        .iter()
        .scan(0, |off, &(fi, fo)| {
            let o = *off;
            *off += fi * fo + fo;
            Some(o)
        })
        .collect();
    let mut mag = vec![Vec::new(); layers.len()];
    let mut err = vec![Vec::new(); layers.len()];
    mag[d.hidden] = dy.iter().map(|v| v.abs()).collect();
    err[d.hidden] = vec![0.0; d.out];
    let mut dx = Vec::new();
    for l in (0..layers.len()).rev() {
        let (fi, fo) = layers[l];
        let w = &p[offsets[l]..offsets[l] + fi * fo];
        let (mut m, mut e) = (vec![0.0; fi], vec![0.0; fi]);
        for i in 0..fi {
            let live = l == 0 || hidden[l - 1][i] > 0.0;
            if !live {
                continue;
            }
            let (mut sm, mut se) = (0.0, 0.0);
            for o in 0..fo {
                sm += w[o * fi + i].abs() * mag[l][o];
                se += w[o * fi + i].abs() * err[l][o];
            }
            m[i] = sm;
            e[i] = se + 2.0 * (gamma(fo + 1) * sm + (fo + 1) as f64 * ETA);
        }
        if l == 0 {
            dx = e;
        } else {
            mag[l - 1] = m;
            err[l - 1] = e;
        }
    }
    BackwardBounds { mag, err, dx }
}

/// Bounds on the parameter gradients summed over a batch (layout of the
/// parameters), starting from `g0`. Element `(o, i)` of layer `l` is `g0 +
/// Σ_b δ_{b,o} x_{b,i}` over the `N` queries (`x` the layer's input: the
/// query's input or hidden activations, the same data for both kernels):
/// both kernels sum it in query order, each within `γ_{N+1} (|g0| + Σ_b |δ_{b,o}
/// x_{b,i}|)` of the exact sum of their own terms, and their deltas differ by
/// at most `err_{b,o}`, so
///
/// ```text
/// |ΔG_l[o][i]| ≤ 2 (γ_{N+1} (|g0| + Σ_b mag_{b,o} |x_{b,i}|) + (N + 1) η) + Σ_b err_{b,o} |x_{b,i}|
/// ```
/// (biases: `x = 1`).
fn gradient_error_bounds(
    d: Dims,
    g0: &[f64],
    xs: &[Vec<Vec<f64>>],
    qb: &[BackwardBounds],
) -> Vec<f64> {
    let n = qb.len();
    let mut sum_mag = vec![0.0; g0.len()];
    let mut sum_err = vec![0.0; g0.len()];
    let mut off = 0;
    for (l, &(fi, fo)) in d.layers().iter().enumerate() {
        for (x, b) in xs.iter().zip(qb) {
            let x = &x[l];
            for o in 0..fo {
                let (m, e) = (b.mag[l][o], b.err[l][o]);
                if m == 0.0 && e == 0.0 {
                    continue;
                }
                let row = off + o * fi;
                for i in 0..fi {
                    sum_mag[row + i] += m * x[i].abs();
                    sum_err[row + i] += e * x[i].abs();
                }
                sum_mag[off + fi * fo + o] += m;
                sum_err[off + fi * fo + o] += e;
            }
        }
        off += fi * fo + fo;
    }
    g0.iter()
        .zip(sum_mag.iter().zip(&sum_err))
        .map(|(g, (m, e))| 2.0 * (gamma(n + 1) * (g.abs() + m) + (n + 1) as f64 * ETA) + e)
        .collect()
}

/// Largest `|a − b| / bound` (0 where both are equal, ∞ where they differ and
/// the bound is 0 or one is not finite).
fn worst_ratio(a: &[f32], b: &[f32], bound: &[f64]) -> (f64, usize) {
    assert_eq!(a.len(), b.len());
    assert_eq!(a.len(), bound.len());
    let mut worst = (0.0f64, 0);
    for (k, ((&x, &y), &e)) in a.iter().zip(b).zip(bound).enumerate() {
        let r = if same(x, y) {
            0.0
        } else {
            (f64::from(x) - f64::from(y)).abs() / e
        };
        let r = if r.is_nan() { f64::INFINITY } else { r };
        if r > worst.0 {
            worst = (r, k);
        }
    }
    worst
}

fn assert_within(what: &str, a: &[f32], b: &[f32], bound: &[f64]) -> f64 {
    let (r, k) = worst_ratio(a, b, bound);
    assert!(
        r <= 1.0,
        "{what}[{k}]: {:e} vs {:e}, bound {:e} (ratio {r:.3})",
        a[k],
        b[k],
        bound[k]
    );
    r
}

/// `|a − b| ≤ bound` wherever `a`, `b` and the bound are finite.
fn finite_within(a: &[f32], b: &[f32], bound: &[f64]) -> bool {
    a.iter().zip(b).zip(bound).all(|((&x, &y), &e)| {
        !(x.is_finite() && y.is_finite() && e.is_finite())
            || (f64::from(x) - f64::from(y)).abs() <= e
    })
}

/// Everything the per-query kernels give for a batch, and the bounds.
struct Reference<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize> {
    ys: Vec<[f32; OUT]>,
    ctxs: Vec<MlpContext<WIDTH, HIDDEN>>,
    grad: Vec<f32>,
    dxs: Vec<[f32; IN]>,
    /// `[query]` → flattened bounds of the hidden layers, of the outputs.
    hidden_bound: Vec<Vec<f64>>,
    out_bound: Vec<Vec<f64>>,
    dx_bound: Vec<Vec<f64>>,
    grad_bound: Vec<f64>,
}

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
    Reference<IN, WIDTH, OUT, HIDDEN>
{
    fn new(p: &[f32], g0: &[f32], xs: &[[f32; IN]], dys: &[[f32; OUT]]) -> Self {
        type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
        let d = Dims::of::<IN, WIDTH, OUT, HIDDEN>();
        let n = xs.len();
        let mut ctxs = vec![MlpContext::<WIDTH, HIDDEN>::ZERO; n];
        let ys: Vec<[f32; OUT]> = xs
            .iter()
            .zip(&mut ctxs)
            .map(|(x, c)| M::<IN, WIDTH, OUT, HIDDEN>::forward(p, 0, x, c))
            .collect();
        let mut grad = g0.to_vec();
        let mut dxs = vec![[0.0; IN]; n];
        for q in 0..n {
            M::<IN, WIDTH, OUT, HIDDEN>::backward(
                p,
                0,
                &xs[q],
                &ctxs[q],
                &dys[q],
                &mut grad,
                &mut dxs[q],
            );
        }
        let p64 = to64(p);
        let (mut hidden_bound, mut out_bound, mut dx_bound) = (vec![], vec![], vec![]);
        let mut layer_inputs = vec![];
        let mut qbs = vec![];
        for q in 0..n {
            let mut f = forward_error_bounds(d, &p64, &to64(&xs[q]));
            out_bound.push(f.pop().unwrap());
            hidden_bound.push(f.concat());
            let hidden: Vec<&[f32]> = ctxs[q].hidden.iter().map(|h| h.as_slice()).collect();
            let b = backward_error_bounds(d, &p64, &hidden, &to64(&dys[q]));
            dx_bound.push(b.dx.clone());
            qbs.push(b);
            let mut inputs = vec![to64(&xs[q])];
            inputs.extend(hidden.iter().map(|h| to64(h)));
            layer_inputs.push(inputs);
        }
        let grad_bound = gradient_error_bounds(d, &to64(g0), &layer_inputs, &qbs);
        Self {
            ys,
            ctxs,
            grad,
            dxs,
            hidden_bound,
            out_bound,
            dx_bound,
            grad_bound,
        }
    }

    /// Largest error/bound ratio of a batched kernel's results (infer,
    /// forward with contexts, backward from the reference contexts), each
    /// asserted ≤ 1 when `strict`.
    #[allow(clippy::too_many_arguments)]
    fn ratios(
        &self,
        kernel: BatchKernel,
        p: &[f32],
        g0: &[f32],
        xs: &[[f32; IN]],
        dys: &[[f32; OUT]],
        strict: bool,
        what: &str,
    ) -> [f64; 5] {
        type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
        let n = xs.len();
        let check = |w: &str, a: &[f32], b: &[f32], bound: &[f64]| {
            if strict {
                assert_within(&format!("{w} {what}"), a, b, bound)
            } else {
                worst_ratio(a, b, bound).0
            }
        };
        let flat = |v: &[Vec<f64>]| v.concat();
        let mut ys = vec![[f32::NAN; OUT]; n];
        M::<IN, WIDTH, OUT, HIDDEN>::infer_batch_with(kernel, p, 0, xs, &mut ys);
        let r_infer = check(
            "infer_batch",
            ys.as_flattened(),
            self.ys.as_flattened(),
            &flat(&self.out_bound),
        );
        let mut ys2 = vec![[f32::NAN; OUT]; n];
        let mut ctxs = vec![MlpContext::<WIDTH, HIDDEN>::ZERO; n];
        M::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(kernel, p, 0, xs, &mut ys2, &mut ctxs);
        assert_same(
            &format!("forward_batch vs infer_batch {what}"),
            ys2.as_flattened(),
            ys.as_flattened(),
        );
        let hidden: Vec<f32> = ctxs.iter().flat_map(|c| c.hidden.concat()).collect();
        let hidden_ref: Vec<f32> = self.ctxs.iter().flat_map(|c| c.hidden.concat()).collect();
        let r_ctx = check(
            "forward_batch context",
            &hidden,
            &hidden_ref,
            &flat(&self.hidden_bound),
        );
        let mut g = g0.to_vec();
        let mut dx = vec![[f32::NAN; IN]; n];
        M::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
            kernel, p, 0, xs, &self.ctxs, dys, &mut g, &mut dx,
        );
        let r_grad = check("backward_batch grad", &g, &self.grad, &self.grad_bound);
        let r_dx = check(
            "backward_batch d_input",
            dx.as_flattened(),
            self.dxs.as_flattened(),
            &flat(&self.dx_bound),
        );
        [r_infer, r_ctx, r_grad, r_dx, 0.0]
    }
}

/// Every available kernel on batches of `ns` queries against the per-query
/// kernels, within the derived bounds; also checks that the kernels are
/// deterministic and that a query's forward and input gradient do not depend
/// on its position in the batch (so zero padding of partial blocks does not
/// leak): bit-identical to the same query alone. Returns the largest
/// error/bound ratio of each result kind.
fn check_batches<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>(
    seed: u64,
    ns: &[usize],
) -> [f64; 4] {
    type M<const A: usize, const B: usize, const C: usize, const D: usize> = Mlp<A, B, C, D>;
    let mut rng = Pcg32::new(seed, 13);
    let p = random_params::<IN, WIDTH, OUT, HIDDEN>(&mut rng);
    let mut worst = [0.0f64; 4];
    for &n in ns {
        let mut xs: Vec<[f32; IN]> = (0..n).map(|_| random_input::<IN>(&mut rng)).collect();
        let mut dys: Vec<[f32; OUT]> = (0..n).map(|_| random_input::<OUT>(&mut rng)).collect();
        if n > 2 {
            // Exact zeros (dead rows).
            xs[1] = [0.0; IN];
            dys[2] = [0.0; OUT];
        }
        // Accumulate into an existing gradient.
        let g0: Vec<f32> = (0..p.len()).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let r = Reference::<IN, WIDTH, OUT, HIDDEN>::new(&p, &g0, &xs, &dys);
        for kernel in BatchKernel::ALL.into_iter().filter(|k| k.is_available()) {
            let what = format!(
                "{:?} {kernel:?}, {n} queries",
                Dims::of::<IN, WIDTH, OUT, HIDDEN>()
            );
            let ratios = r.ratios(kernel, &p, &g0, &xs, &dys, true, &what);
            for (w, r) in worst.iter_mut().zip(ratios) {
                *w = w.max(r);
            }
            // Determinism, and independence of the position in the batch.
            let mut ys = vec![[0.0; OUT]; n];
            let mut ctxs = vec![MlpContext::<WIDTH, HIDDEN>::ZERO; n];
            let mut ys2 = ys.clone();
            let mut ctxs2 = ctxs.clone();
            M::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(kernel, &p, 0, &xs, &mut ys, &mut ctxs);
            M::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(
                kernel, &p, 0, &xs, &mut ys2, &mut ctxs2,
            );
            assert_same(
                &format!("forward twice {what}"),
                ys.as_flattened(),
                ys2.as_flattened(),
            );
            let (mut g, mut g2) = (g0.clone(), g0.clone());
            let mut dx = vec![[0.0; IN]; n];
            let mut dx2 = dx.clone();
            M::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
                kernel, &p, 0, &xs, &ctxs, &dys, &mut g, &mut dx,
            );
            M::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
                kernel, &p, 0, &xs, &ctxs, &dys, &mut g2, &mut dx2,
            );
            assert_same(&format!("backward grad twice {what}"), &g, &g2);
            assert_same(
                &format!("backward d_input twice {what}"),
                dx.as_flattened(),
                dx2.as_flattened(),
            );
            for q in [0, n / 2, n.saturating_sub(1)]
                .into_iter()
                .filter(|&q| q < n)
            {
                let mut y1 = [[0.0; OUT]];
                let mut c1 = [MlpContext::<WIDTH, HIDDEN>::ZERO];
                M::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(
                    kernel,
                    &p,
                    0,
                    &xs[q..=q],
                    &mut y1,
                    &mut c1,
                );
                assert_same(&format!("query {q} alone {what}"), &y1[0], &ys[q]);
                assert_same(
                    &format!("query {q} context alone {what}"),
                    c1[0].hidden.as_flattened(),
                    ctxs[q].hidden.as_flattened(),
                );
                let mut g1 = vec![0.0; p.len()];
                let mut dx1 = [[0.0; IN]];
                M::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
                    kernel,
                    &p,
                    0,
                    &xs[q..=q],
                    &c1,
                    &dys[q..=q],
                    &mut g1,
                    &mut dx1,
                );
                assert_same(&format!("query {q} d_input alone {what}"), &dx1[0], &dx[q]);
            }
        }
    }
    worst
}

#[test]
fn batched_kernels_match_the_per_query_kernels_within_the_rounding_bound() {
    println!(
        "available batch kernels: {:?}, detected {:?}",
        BatchKernel::ALL
            .iter()
            .filter(|k| k.is_available())
            .collect::<Vec<_>>(),
        BatchKernel::detect()
    );
    let ns = [0, 1, 3, 17, 100, 1000];
    let few = [0, 1, 3, 17, 100];
    let w = [
        // Compact models.
        ("16-32-32x2", check_batches::<16, 32, 32, 2>(1, &ns)),
        ("48-32-32x2", check_batches::<48, 32, 32, 2>(2, &ns)),
        ("16-32-49x2", check_batches::<16, 32, 49, 2>(3, &ns)),
        ("28-32-16x2", check_batches::<28, 32, 16, 2>(4, &ns)),
        ("32-32-3x2", check_batches::<32, 32, 3, 2>(5, &ns)),
        // Paper sizes.
        ("32-64-32x3", check_batches::<32, 64, 32, 3>(6, &ns)),
        ("64-64-32x3", check_batches::<64, 64, 32, 3>(7, &few)),
        // Small test size, and widths that are not multiples of any tile.
        ("8-16-32x2", check_batches::<8, 16, 32, 2>(8, &ns)),
        ("7-16-5x2", check_batches::<7, 16, 5, 2>(9, &few)),
        ("3-5-2x1", check_batches::<3, 5, 2, 1>(10, &few)),
        ("1-6-3x4", check_batches::<1, 6, 3, 4>(11, &few)),
    ];
    for (name, [infer, ctx, grad, dx]) in w {
        println!(
            "{name}: largest error/bound: infer {infer:.3}, contexts {ctx:.3}, \
             parameter gradients {grad:.3}, input gradients {dx:.3}"
        );
    }
}

/// Random parameters of the `16 → 2 × 32 → 32` network with `n` random
/// inputs and output gradients, from `Pcg32::new(seed, 13)`.
fn batch_case(seed: u64, n: usize) -> (Vec<f32>, Vec<[f32; 16]>, Vec<[f32; 32]>) {
    let mut rng = Pcg32::new(seed, 13);
    let p = random_params::<16, 32, 32, 2>(&mut rng);
    let xs = (0..n).map(|_| random_input::<16>(&mut rng)).collect();
    let dys = (0..n).map(|_| random_input::<32>(&mut rng)).collect();
    (p, xs, dys)
}

/// Non-finite inputs (a NaN, an ∞, in different blocks of 48 queries):
/// every batched result has the per-query result's class (NaN, ±∞, finite),
/// and the finite ones are within the bound. The backward pass of a block
/// with a non-finite input or context is the per-query one, so dead units
/// never turn `0 · ∞` into NaN.
#[test]
fn non_finite_inputs_give_the_per_query_classes() {
    type M = Mlp<16, 32, 32, 2>;
    let n = 150;
    let (p, mut xs, dys) = batch_case(31, n);
    xs[10][0] = f32::NAN;
    xs[60][3] = f32::INFINITY;
    xs[61][5] = f32::NEG_INFINITY;
    let g0 = vec![0.0; p.len()];
    let r = Reference::<16, 32, 32, 2>::new(&p, &g0, &xs, &dys);
    let class = |v: f32| {
        (
            v.is_nan(),
            v.is_infinite() && v > 0.0,
            v.is_infinite() && v < 0.0,
        )
    };
    let same_class = |what: &str, a: &[f32], b: &[f32]| {
        for (k, (&x, &y)) in a.iter().zip(b).enumerate() {
            assert_eq!(class(x), class(y), "{what}[{k}]: {x:e} vs {y:e}");
        }
    };
    // The ∞ reaches the contexts (so the backward sees non-finite activations).
    assert!(r.ctxs[60].hidden[0].iter().any(|v| v.is_infinite()));
    for kernel in BatchKernel::ALL.into_iter().filter(|k| k.is_available()) {
        let mut ys = vec![[0.0; 32]; n];
        let mut ctxs = vec![MlpContext::ZERO; n];
        M::forward_batch_with(kernel, &p, 0, &xs, &mut ys, &mut ctxs);
        same_class("outputs", ys.as_flattened(), r.ys.as_flattened());
        let flat = |c: &[MlpContext<32, 2>]| -> Vec<f32> {
            c.iter().flat_map(|c| c.hidden.concat()).collect()
        };
        same_class("contexts", &flat(&ctxs), &flat(&r.ctxs));
        assert!(finite_within(
            ys.as_flattened(),
            r.ys.as_flattened(),
            &r.out_bound.concat()
        ));
        let mut g = g0.clone();
        let mut dx = vec![[0.0; 16]; n];
        M::backward_batch_with(kernel, &p, 0, &xs, &r.ctxs, &dys, &mut g, &mut dx);
        same_class("grad", &g, &r.grad);
        same_class("d_input", dx.as_flattened(), r.dxs.as_flattened());
        assert!(finite_within(&g, &r.grad, &r.grad_bound));
        assert!(finite_within(
            dx.as_flattened(),
            r.dxs.as_flattened(),
            &r.dx_bound.concat()
        ));
    }
}

/// The tolerance is not vacuous: a relative 10⁻⁴ perturbation of one weight
/// of the first layer (in the batched call only) fails the first hidden
/// layer's check (`2 γ_{17} A₀`, the tightest bound), for every kernel. The
/// bounds of later layers and of the gradients accumulate the earlier
/// layers' bounds through `|W|` and are looser: the same perturbation, or one
/// of an output-layer weight, stays below them (the ratios are printed).
#[test]
fn the_batch_tolerance_catches_a_perturbed_weight() {
    type M = Mlp<16, 32, 32, 2>;
    let n = 200;
    let (p, xs, dys) = batch_case(21, n);
    let g0 = vec![0.0; p.len()];
    let r = Reference::<16, 32, 32, 2>::new(&p, &g0, &xs, &dys);
    let perturbed = |k: usize| {
        let mut bad = p.clone();
        bad[k] *= 1.0 + 1e-4;
        bad
    };
    let first = perturbed(3);
    let last = perturbed(M::OUTPUT_LAYER_OFFSET + 5);
    for kernel in BatchKernel::ALL.into_iter().filter(|k| k.is_available()) {
        let good = r.ratios(kernel, &p, &g0, &xs, &dys, false, "");
        let f = r.ratios(kernel, &first, &g0, &xs, &dys, false, "");
        let l = r.ratios(kernel, &last, &g0, &xs, &dys, false, "");
        println!(
            "{kernel:?}: error/bound [infer, contexts, grad, d_input] unperturbed {:.3?}; \
             first-layer weight {:.2?}; output-layer weight {:.2?}",
            &good[..4],
            &f[..4],
            &l[..4]
        );
        assert!(good.iter().all(|&r| r <= 1.0));
        assert!(
            f[1] > 1.0,
            "{kernel:?}: first-layer perturbation not caught"
        );
    }
}

// ---------------------------------------------------------------------------
// Initialisation.

#[test]
fn init_is_deterministic_and_seed_dependent() {
    type M = Mlp<32, 64, 32, 3>;
    let mut a = vec![0.0; M::PARAM_COUNT];
    let mut b = vec![1.0; M::PARAM_COUNT];
    M::init(&mut a, 0, 42);
    M::init(&mut b, 0, 42);
    assert_same("same seed", &a, &b);
    for (k, &v) in a.iter().enumerate() {
        assert_eq!(
            v.to_bits(),
            M::init_value(k, 42).to_bits(),
            "init_value({k})"
        );
    }
    assert_eq!(M::init_value(M::PARAM_COUNT, 42), 0.0);
    M::init(&mut b, 0, 43);
    let (mut weights, mut differ) = (0, 0);
    for (&x, &y) in a.iter().zip(&b) {
        if x != 0.0 || y != 0.0 {
            weights += 1;
            differ += usize::from(x != y);
        }
    }
    assert_eq!(weights, M::MACS, "every weight non-zero, every bias zero");
    assert_eq!(differ, weights, "another seed changes every weight");
}

/// Per layer: biases exactly 0; weights inside `(−a, a)` with
/// `a = √(6 / fan_in)` (× 0.1 for the output layer), mean and variance
/// `a²/3` within 5 standard errors of the uniform law (`sd(mean) =
/// a / √(3n)`, `sd(s²)/σ² = √(0.8 / n)` since `μ₄ = a⁴/5`), and a 32-bin
/// chi² test of uniformity at `α = 10⁻⁶`.
#[test]
fn init_follows_kaiming_uniform_statistics() {
    type M = Mlp<64, 256, 64, 3>;
    let mut p = vec![0.0; M::PARAM_COUNT];
    M::init(&mut p, 0, 7);
    let bins = 32;
    let chi2_limit = ChiSquared::new((bins - 1) as f64)
        .unwrap()
        .inverse_cdf(1.0 - 1e-6);
    for l in 0..=3 {
        let (fi, fo) = (M::fan_in(l), M::fan_out(l));
        let off = M::layer_offset(l);
        let w = to64(&p[off..off + fi * fo]);
        assert!(
            p[off + fi * fo..off + fi * fo + fo]
                .iter()
                .all(|&b| b == 0.0),
            "layer {l} biases"
        );
        let scale = if l == 3 {
            f64::from(OUTPUT_INIT_SCALE)
        } else {
            1.0
        };
        let a = scale * (6.0 / fi as f64).sqrt();
        let n = w.len() as f64;
        let mean = w.iter().sum::<f64>() / n;
        let var = w.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let sigma2 = a * a / 3.0;
        assert!(
            w.iter().all(|x| x.abs() < a * (1.0 + 1e-6)),
            "layer {l}: a weight outside ±{a}"
        );
        assert!(
            mean.abs() <= 5.0 * a / (3.0 * n).sqrt(),
            "layer {l}: mean {mean:e}"
        );
        let rel_var = var / sigma2 - 1.0;
        assert!(
            rel_var.abs() <= 5.0 * (0.8 / n).sqrt(),
            "layer {l}: variance {var:e} vs {sigma2:e}"
        );
        if l < 3 {
            assert!(
                (sigma2 - 2.0 / fi as f64).abs() < 1e-12,
                "Kaiming: variance 2 / fan_in"
            );
        }
        let mut counts = vec![0.0; bins];
        for x in &w {
            counts[(((x / a + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1)] += 1.0;
        }
        let expected = n / bins as f64;
        let chi2: f64 = counts
            .iter()
            .map(|c| (c - expected).powi(2) / expected)
            .sum();
        assert!(chi2 < chi2_limit, "layer {l}: chi² {chi2} ≥ {chi2_limit}");
        println!(
            "layer {l}: n {n}, mean {mean:+.2e}, var/σ² − 1 = {rel_var:+.2e}, chi² {chi2:.1} (limit {chi2_limit:.1})"
        );
    }
}

// ---------------------------------------------------------------------------
// Range.

/// The worst case of the documented bound (every parameter `+P`, every
/// input `+X`: no cancellation, every ReLU open) stays finite for the
/// documented example `P = 10⁴`, `X = 10¹⁵` of the 32 → 3 × 64 → 32 network,
/// and its output is the bound recurrence within rounding.
#[test]
fn documented_magnitude_bound_holds_at_its_worst_case() {
    type M = Mlp<32, 64, 32, 3>;
    let (p, x) = (1e4_f32, 1e15_f32);
    let params = vec![p; M::PARAM_COUNT];
    let y = M::infer(&params, 0, &[x; 32]);
    let (p64, x64) = (f64::from(p), f64::from(x));
    let mut b = 32.0 * p64 * x64 + p64;
    for _ in 0..3 {
        b = 64.0 * p64 * b + p64;
    }
    assert!(b * (1.0 + gamma(65)).powi(4) < f64::from(f32::MAX));
    for v in y {
        assert!(
            v.is_finite() && (f64::from(v) - b).abs() <= 4.0 * gamma(65) * b,
            "{v:e} vs {b:e}"
        );
    }
}

/// Magnitude bound of the module docs, in f64.
fn magnitude_bound(d: Dims, p: f64, x: f64) -> f64 {
    d.layers()
        .iter()
        .fold(x, |b, &(fi, _)| fi as f64 * p * b + p)
}

/// Any value: finite ones over ±10³⁰ and their full range, NaN, ±∞.
fn any_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => (-30.0f32..30.0, any::<bool>()).prop_map(|(e, s)| if s { 10f32.powf(e) } else { -10f32.powf(e) }),
        1 => prop::num::f32::ANY,
        1 => Just(0.0f32),
    ]
}

/// A finite value of magnitude at most `10^max_exp` (or zero).
fn bounded_value(max_exp: f32) -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => (-30.0f32..max_exp, any::<bool>()).prop_map(|(e, s)| if s { 10f32.powf(e) } else { -10f32.powf(e) }),
        1 => Just(0.0f32),
    ]
}

/// `cases` cases from a fixed seed, nothing persisted: reproducible like
/// every other test here.
fn fixed_seed_config(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

type Small = Mlp<7, 16, 5, 2>;
const SMALL_PARAMS: usize = Small::PARAM_COUNT;

proptest! {
    // Fixed seed: reproducible like every other test here.
    #![proptest_config(fixed_seed_config(500, 0x6d6c70))]

    /// No panic for any parameters and inputs (NaN, ±∞, ±f32::MAX,
    /// subnormals included); `forward` and `infer` agree bit for bit; every
    /// batched kernel is deterministic and, wherever its result, the
    /// per-query one and the bound are finite, within the bound of
    /// [`forward_error_bounds`] / [`gradient_error_bounds`] (whose `η` terms
    /// cover underflow). Overflow thresholds differ with the rounding, so a
    /// result finite in one kernel may be infinite in the other.
    #[test]
    fn any_values_never_panic_and_kernels_agree(
        params in prop::collection::vec(any_value(), SMALL_PARAMS),
        xs in prop::collection::vec(prop::array::uniform7(any_value()), 1..20),
        dy in prop::array::uniform5(any_value()),
    ) {
        let n = xs.len();
        let dys = vec![dy; n];
        let g0 = vec![0.0; SMALL_PARAMS];
        for (x, c) in xs.iter().zip(vec![MlpContext::ZERO; n].iter_mut()) {
            let y = Small::forward(&params, 0, x, c);
            let yi = Small::infer(&params, 0, x);
            for o in 0..5 {
                prop_assert!(same(y[o], yi[o]));
            }
        }
        let r = Reference::<7, 16, 5, 2>::new(&params, &g0, &xs, &dys);
        for kernel in BatchKernel::ALL.into_iter().filter(|k| k.is_available()) {
            let mut ys = vec![[0.0; 5]; n];
            let mut ys2 = vec![[0.0; 5]; n];
            let mut ctxs = vec![MlpContext::ZERO; n];
            Small::forward_batch_with(kernel, &params, 0, &xs, &mut ys, &mut ctxs);
            Small::infer_batch_with(kernel, &params, 0, &xs, &mut ys2);
            for (a, b) in ys.as_flattened().iter().zip(ys2.as_flattened()) {
                prop_assert!(same(*a, *b));
            }
            prop_assert!(finite_within(ys.as_flattened(), r.ys.as_flattened(), &r.out_bound.concat()));
            let mut grad = g0.clone();
            let mut grad2 = g0.clone();
            let mut dxs = vec![[0.0; 7]; n];
            Small::backward_batch_with(kernel, &params, 0, &xs, &r.ctxs, &dys, &mut grad, &mut dxs);
            Small::backward_batch_with(kernel, &params, 0, &xs, &r.ctxs, &dys, &mut grad2, &mut dxs);
            for (a, b) in grad.iter().zip(&grad2) {
                prop_assert!(same(*a, *b));
            }
            prop_assert!(finite_within(&grad, &r.grad, &r.grad_bound));
            prop_assert!(finite_within(dxs.as_flattened(), r.dxs.as_flattened(), &r.dx_bound.concat()));
        }
    }

    /// Parameters within ±10⁶ and inputs within ±10¹⁵: the documented bound
    /// is below `f32::MAX`, so the output is finite.
    #[test]
    fn bounded_values_give_finite_outputs(
        params in prop::collection::vec(bounded_value(6.0), SMALL_PARAMS),
        x in prop::array::uniform7(bounded_value(15.0)),
    ) {
        let d = Dims::of::<7, 16, 5, 2>();
        prop_assert!(magnitude_bound(d, 1e6, 1e15) * (1.0 + gamma(17)).powi(3) < f64::from(f32::MAX));
        let y = Small::infer(&params, 0, &x);
        prop_assert!(y.iter().all(|v| v.is_finite()), "{:?}", y);
    }
}

proptest! {
    #![proptest_config(fixed_seed_config(64, 0x6d6c71))]

    /// The documented example: 32 → 3 × 64 → 32 with `|param| ≤ 10⁴` and
    /// `|input| ≤ 10¹⁵` is finite (magnitudes log-uniform, random signs).
    #[test]
    fn documented_example_bound_gives_finite_outputs(seed in any::<u64>()) {
        type M = Mlp<32, 64, 32, 3>;
        let mut rng = Pcg32::new(seed, 1);
        let mut value = |max_exp: f32| {
            let v = 10f32.powf(rng.uniform(-30.0, max_exp));
            if rng.next_u32() & 1 == 0 { v } else { -v }
        };
        let params: Vec<f32> = (0..M::PARAM_COUNT).map(|_| value(4.0)).collect();
        let x: [f32; 32] = core::array::from_fn(|_| value(15.0));
        let d = Dims::of::<32, 64, 32, 3>();
        prop_assert!(magnitude_bound(d, 1e4, 1e15) * (1.0 + gamma(65)).powi(4) < f64::from(f32::MAX));
        let y = M::infer(&params, 0, &x);
        prop_assert!(y.iter().all(|v| v.is_finite()));
    }
}

// ---------------------------------------------------------------------------
// Adam.

/// Kingma & Ba (2015), Algorithm 1, in f64 with the f32 hyper-parameters.
struct Adam64 {
    p: Vec<f64>,
    m: Vec<f64>,
    v: Vec<f64>,
}

impl Adam64 {
    fn step(&mut self, g: &[f32], t: u32, cfg: &AdamConfig) {
        let (lr, b1, b2, eps, l2) = (
            f64::from(cfg.learning_rate),
            f64::from(cfg.beta1),
            f64::from(cfg.beta2),
            f64::from(cfg.epsilon),
            f64::from(cfg.l2_regularization),
        );
        for i in 0..self.p.len() {
            let g = f64::from(g[i]) + l2 * self.p[i];
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * g;
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * g * g;
            let m_hat = self.m[i] / (1.0 - b1.powi(t as i32));
            let v_hat = self.v[i] / (1.0 - b2.powi(t as i32));
            self.p[i] -= lr * m_hat / (v_hat.sqrt() + eps);
        }
    }
}

/// 100 steps on random gradients (magnitudes 10⁻³ … 10) against f64.
/// Bounds: the moments carry a relative error of at most `~3u / (1 − β)`
/// (each step rounds at ~3u and old errors decay by β); the step
/// `α m̂ / √v̂` then has a relative error `≲ 3u (1/(1−β₁) + ½/(1−β₂))`,
/// and the parameter also rounds at `u |θ|` per step: summed over `T`
/// steps, `|Δθ| ≤ T (u |θ| + α r · 3u (1/(1−β₁) + ½/(1−β₂)))` with `r` the
/// largest `|m̂| / √v̂` seen (≤ 1 here), times a safety factor 2.
#[test]
fn adam_matches_an_f64_reference() {
    for (ci, cfg) in [
        AdamConfig::DEFAULT.with_learning_rate(1e-2),
        AdamConfig::new(1e-3)
            .with_betas(0.9, 0.999)
            .with_epsilon(1e-8)
            .with_l2_regularization(1e-2),
    ]
    .into_iter()
    .enumerate()
    {
        let n = 200;
        let mut rng = Pcg32::new(3, ci as u64);
        let mut p: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
        let mut r = Adam64 {
            p: to64(&p),
            m: vec![0.0; n],
            v: vec![0.0; n],
        };
        let scales: Vec<f32> = (0..n).map(|_| 10f32.powf(rng.uniform(-3.0, 1.0))).collect();
        let steps = 100;
        for t in 1..=steps {
            let g: Vec<f32> = scales.iter().map(|s| s * rng.uniform(-1.0, 1.0)).collect();
            assert_eq!(adam_step(&mut p, &g, &mut m, &mut v, t, &cfg), 0);
            r.step(&g, t, &cfg);
        }
        let (b1, b2) = (f64::from(cfg.beta1), f64::from(cfg.beta2));
        let step_rel = 3.0 * U * (1.0 / (1.0 - b1) + 0.5 / (1.0 - b2));
        let mut worst: f64 = 0.0;
        for i in 0..n {
            let bound =
                2.0 * f64::from(steps) * (U * 2.0 + f64::from(cfg.learning_rate) * 1.0 * step_rel);
            let err = (f64::from(p[i]) - r.p[i]).abs();
            worst = worst.max(err / bound);
            assert!(
                err <= bound,
                "config {ci} θ[{i}]: {} vs {} (bound {bound:e})",
                p[i],
                r.p[i]
            );
            let m_err = (f64::from(m[i]) - r.m[i]).abs();
            assert!(
                m_err
                    <= 2.0 * 3.0 * U / (1.0 - b1) * r.m.iter().map(|x| x.abs()).fold(0.0, f64::max)
            );
            let v_err = (f64::from(v[i]) - r.v[i]).abs();
            assert!(
                v_err <= 2.0 * 3.0 * U / (1.0 - b2) * r.v[i].max(1e-30) + 1e-30,
                "config {ci} v[{i}]"
            );
        }
        println!("Adam config {ci}: largest parameter error / bound = {worst:.3}");
    }
}

/// `adam_update` (per element, factors recomputed) equals `adam_step`.
#[test]
fn adam_update_equals_adam_step() {
    let cfg = AdamConfig::DEFAULT
        .with_learning_rate(5e-3)
        .with_l2_regularization(1e-3);
    let mut rng = Pcg32::new(8, 8);
    let n = 64;
    let mut p: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    let (mut p2, mut m2, mut v2) = (p.clone(), m.clone(), v.clone());
    for t in 1..=20 {
        let g: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
        adam_step(&mut p, &g, &mut m, &mut v, t, &cfg);
        for i in 0..n {
            assert!(adam_update(
                &mut p2[i], &mut m2[i], &mut v2[i], g[i], t, &cfg
            ));
        }
    }
    assert_same("params", &p, &p2);
    assert_same("m", &m, &m2);
    assert_same("v", &v, &v2);
    // Step 0 is step 1.
    assert_eq!(AdamStepFactors::new(0, &cfg), AdamStepFactors::new(1, &cfg));
    assert_eq!(AdamConfig::default(), AdamConfig::DEFAULT);
    assert_eq!(AdamConfig::DEFAULT.beta2, 0.99);
    assert_eq!(AdamConfig::DEFAULT.epsilon, 1e-15);
}

/// The fused CPU step (`adam_ema_step`: vectorised Adam, EMA and zeroing,
/// block by block) equals the per-element kernels bit for bit: over a
/// length that is neither a multiple of the lane count nor of the block,
/// at step 1 (EMA weight 1: a copy) and later steps, with non-finite
/// gradients and an element whose update overflows (both skipped and
/// counted, exactly as `adam_update_with_factors` skips them).
#[test]
fn fused_adam_ema_step_equals_the_per_element_kernels() {
    let cfg = AdamConfig::DEFAULT
        .with_learning_rate(3e-2)
        .with_l2_regularization(1e-4);
    let decay = 0.95;
    let mut rng = Pcg32::new(21, 4);
    let n = 2 * 4096 + 37;
    let mut p: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let (mut m, mut v, mut e) = (vec![0.0f32; n], vec![0.0f32; n], p.clone());
    let (mut p2, mut m2, mut v2, mut e2) = (p.clone(), m.clone(), v.clone(), e.clone());
    for t in 1..=6u32 {
        let mut g: Vec<f32> = (0..n).map(|_| rng.uniform(-2.0, 2.0)).collect();
        let bad = [
            (3, f32::NAN),
            (4100, f32::INFINITY),
            (n - 1, f32::NEG_INFINITY),
        ];
        for &(i, x) in &bad {
            g[i] = x;
        }
        // Finite, but g² overflows: v would be ∞, so the element is skipped.
        g[17] = 3e19;
        let mut expected_skips = 0;
        let f = AdamStepFactors::new(t, &cfg);
        let alpha = ema_weight(decay, t);
        for i in 0..n {
            if !adam_update_with_factors(&mut p2[i], &mut m2[i], &mut v2[i], g[i], &cfg, &f) {
                expected_skips += 1;
            }
            ema_update_element(&mut e2[i], p2[i], alpha);
        }
        let skipped = adam_ema_step(&mut p, &mut g, &mut m, &mut v, &mut e, t, &cfg, decay);
        assert_eq!(skipped, expected_skips, "step {t}");
        assert_eq!(skipped, bad.len() + 1, "step {t}");
        assert!(g.iter().all(|&x| x.to_bits() == 0), "gradient zeroed");
        assert_same(&format!("params, step {t}"), &p, &p2);
        assert_same(&format!("m, step {t}"), &m, &m2);
        assert_same(&format!("v, step {t}"), &v, &v2);
        assert_same(&format!("ema, step {t}"), &e, &e2);
    }
    assert!(p
        .iter()
        .chain(&m)
        .chain(&v)
        .chain(&e)
        .all(|x| x.is_finite()));
}

/// Square-and-multiply: relative error ≤ `t u` (squaring doubles it), × 2.
#[test]
fn powi_matches_f64() {
    for &b in &[0.9f32, 0.99, 0.999, 0.95, 1.0, 0.0, 2.0, -1.5] {
        for t in [0u32, 1, 2, 3, 10, 100, 1000, 12_345, 1 << 20] {
            let exact = f64::from(b).powi(t as i32);
            let got = f64::from(powi(b, t));
            if exact.abs() > f64::from(f32::MAX) {
                assert!(got.is_infinite(), "{b}^{t}: {got:e}");
                continue;
            }
            let tol = 2.0 * f64::from(t) * U * exact.abs() + 1e-45;
            assert!((got - exact).abs() <= tol, "{b}^{t}: {got:e} vs {exact:e}");
        }
    }
}

/// Minimises `½ Σ aᵢ (θᵢ − cᵢ)²` (curvatures 0.1 … 10) to a tiny fraction of
/// the initial loss.
#[test]
fn adam_minimises_a_quadratic() {
    let n = 16;
    let mut rng = Pcg32::new(4, 4);
    let a: Vec<f32> = (0..n).map(|_| 10f32.powf(rng.uniform(-1.0, 1.0))).collect();
    let c: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let loss = |p: &[f32]| -> f64 {
        (0..n)
            .map(|i| 0.5 * f64::from(a[i]) * f64::from(p[i] - c[i]).powi(2))
            .sum()
    };
    let mut p = vec![0.0f32; n];
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    let initial = loss(&p);
    let cfg = AdamConfig::DEFAULT.with_learning_rate(1e-2);
    for t in 1..=3000 {
        let g: Vec<f32> = (0..n).map(|i| a[i] * (p[i] - c[i])).collect();
        adam_step(&mut p, &g, &mut m, &mut v, t, &cfg);
    }
    let last = loss(&p);
    println!("quadratic: loss {initial:.3e} → {last:.3e}");
    assert!(last < 1e-6 * initial, "loss {initial:e} → {last:e}");
}

/// NaN, ±∞ and a gradient whose square overflows leave those elements'
/// parameter and moments bit-identical (and finite); the other elements
/// take their normal step.
#[test]
fn non_finite_gradients_never_reach_the_state() {
    let cfg = AdamConfig::DEFAULT.with_learning_rate(1e-2);
    let n = 12;
    let mut rng = Pcg32::new(6, 6);
    let mut p: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let mut m: Vec<f32> = (0..n).map(|_| rng.uniform(-0.1, 0.1)).collect();
    let mut v: Vec<f32> = (0..n).map(|_| rng.uniform(0.0, 0.1)).collect();
    let mut g: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    assert!(all_finite(&g));
    let bad = [
        (3, f32::NAN),
        (5, f32::INFINITY),
        (7, f32::NEG_INFINITY),
        (9, 1e30),
    ];
    for &(i, x) in &bad {
        g[i] = x;
    }
    assert!(!all_finite(&g[..10]));
    assert!(all_finite(&g[10..]) && all_finite(&[]));
    let (p0, m0, v0) = (p.clone(), m.clone(), v.clone());
    let skipped = adam_step(&mut p, &g, &mut m, &mut v, 7, &cfg);
    assert_eq!(skipped, bad.len());
    for i in 0..n {
        assert!(
            p[i].is_finite() && m[i].is_finite() && v[i].is_finite(),
            "element {i}"
        );
        if bad.iter().any(|&(j, _)| j == i) {
            assert_eq!(
                (p[i].to_bits(), m[i].to_bits(), v[i].to_bits()),
                (p0[i].to_bits(), m0[i].to_bits(), v0[i].to_bits()),
                "element {i} changed"
            );
        } else {
            let (mut pe, mut me, mut ve) = (p0[i], m0[i], v0[i]);
            assert!(adam_update(&mut pe, &mut me, &mut ve, g[i], 7, &cfg));
            assert_same(&format!("element {i}"), &[p[i], m[i], v[i]], &[pe, me, ve]);
            assert_ne!(p[i], p0[i]);
        }
    }
    // A parameter so large that the L2 term overflows is not touched either.
    let (mut pe, mut me, mut ve) = (3e38f32, 0.0, 0.0);
    let l2 = cfg.with_l2_regularization(10.0);
    assert!(!adam_update(&mut pe, &mut me, &mut ve, 1.0, 1, &l2));
    assert_eq!((pe, me, ve), (3e38, 0.0, 0.0));
}

// ---------------------------------------------------------------------------
// EMA.

/// The debiased one-buffer EMA equals tiny-cuda-nn's two-buffer form
/// `S_t = d S_{t−1} + (1 − d) θ_t`, `S_t / (1 − dᵗ)` in f64; relative error
/// per step ≤ ~4u, decaying by `1 − α`, so ≤ `4u / (1 − d)` overall (× 2).
#[test]
fn ema_matches_its_debiased_formula() {
    let (decay, n, steps) = (0.95f32, 32, 60u32);
    let d = f64::from(decay);
    let mut rng = Pcg32::new(9, 9);
    let mut ema = vec![f32::NAN; n]; // never initialised: step 1 overwrites
    let mut s = vec![0.0f64; n];
    let mut worst: f64 = 0.0;
    for t in 1..=steps {
        let params: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
        ema_update(&mut ema, &params, decay, t);
        if t == 1 {
            assert_same("first EMA step copies", &ema, &params);
        }
        for i in 0..n {
            s[i] = d * s[i] + (1.0 - d) * f64::from(params[i]);
            let exact = s[i] / (1.0 - d.powi(t as i32));
            let bound = 2.0 * 4.0 * U / (1.0 - d) * 1.0; // |θ| ≤ 1
            let err = (f64::from(ema[i]) - exact).abs();
            worst = worst.max(err / bound);
            assert!(err <= bound, "step {t} [{i}]: {} vs {exact}", ema[i]);
        }
    }
    println!("EMA: largest error / bound = {worst:.3}");
    assert_eq!(ema_weight(decay, 0), 1.0);
    assert_eq!(ema_weight(decay, 1), 1.0);
    assert!((f64::from(ema_weight(decay, 2)) - 0.05 / (1.0 - 0.95f64 * 0.95)).abs() < 1e-6);
    assert!((ema_weight(decay, 100_000) - 0.05).abs() < 1e-6);
    assert_eq!(ema_weight(1.0, 1), 1.0);
    assert_eq!(ema_weight(1.0, 2), 0.0);
}

// ---------------------------------------------------------------------------
// RNG.

/// Known answers from an independent Python implementation of PCG-RXS-M-XS
/// 32/32 and the documented seeding.
#[test]
fn rng_known_answers() {
    assert_eq!(
        [0u32, 1, 2, 12_345, u32::MAX].map(pcg_hash),
        [
            129_708_002,
            2_831_084_092,
            2_055_130_248,
            4_099_845_390,
            3_861_530_882
        ]
    );
    assert_eq!(
        [0u32, 1, 1000].map(|i| hash2(7, i)),
        [2_158_420_637, 2_809_854_175, 4_019_734_520]
    );
    let mut r = Rng::new(42);
    assert_eq!(
        [(); 4].map(|()| r.next_u32()),
        [833_113_347, 2_785_308_739, 391_924_586, 3_212_367_989]
    );
    assert_eq!(Rng::with_stream(7, 1000).state, hash2(7, 1000));
    assert_eq!(core::mem::size_of::<Rng>(), 4);
}

#[test]
fn rng_float_conversions() {
    assert_eq!(unit_f32(0), 0.0);
    assert_eq!(unit_f32(u32::MAX), 1.0 - 2f32.powi(-24));
    assert_eq!(symmetric_unit_f32(0), -(1.0 - 2f32.powi(-23)));
    assert_eq!(symmetric_unit_f32(u32::MAX), 1.0 - 2f32.powi(-23));
    // Exactly symmetric: k and 2²³ − 1 − k map to opposite values.
    for k in [0u32, 1, 12_345, (1 << 23) - 1] {
        assert_eq!(
            symmetric_unit_f32(k << 9),
            -symmetric_unit_f32(((1 << 23) - 1 - k) << 9)
        );
    }
    let mut r = Rng::new(1);
    for _ in 0..10_000 {
        let u = r.next_f32();
        assert!((0.0..1.0).contains(&u));
        let s = r.next_symmetric_f32();
        assert!(s > -1.0 && s < 1.0);
    }
}

/// 64-bin chi² of the counter-based and the sequential generators (10⁶
/// draws each, α = 10⁻⁶), and no collision of `hash2(seed, ·)` over 10⁵
/// indices (it is a bijection).
#[test]
fn rng_is_uniform_and_hash2_is_injective() {
    let bins = 64;
    let n = 1_000_000;
    let limit = ChiSquared::new((bins - 1) as f64)
        .unwrap()
        .inverse_cdf(1.0 - 1e-6);
    let chi2 = |draw: &mut dyn FnMut() -> f32| {
        let mut counts = vec![0.0f64; bins];
        for _ in 0..n {
            counts[(draw() * bins as f32) as usize] += 1.0;
        }
        let e = n as f64 / bins as f64;
        counts.iter().map(|c| (c - e).powi(2) / e).sum::<f64>()
    };
    let mut i = 0u32;
    let c1 = chi2(&mut || {
        i += 1;
        uniform_at(5, i)
    });
    let mut r = Rng::new(5);
    let c2 = chi2(&mut || r.next_f32());
    println!("chi² uniform_at {c1:.1}, Rng {c2:.1} (limit {limit:.1})");
    assert!(c1 < limit && c2 < limit);
    let mut seen: Vec<u32> = (0..100_000).map(|i| hash2(3, i)).collect();
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(seen.len(), 100_000);
}
