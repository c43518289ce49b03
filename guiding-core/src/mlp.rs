//! A fully connected network with compile-time widths, evaluated one query at
//! a time (the shader form) and, with the `std` feature, in blocked batches
//! on the CPU.
//!
//! # Architecture
//!
//! [`Mlp<IN, WIDTH, OUT, HIDDEN>`](Mlp): `HIDDEN ≥ 1` hidden layers of
//! `WIDTH` neurons with ReLU, then a linear output layer:
//!
//! ```text
//! h₀ = relu(W₀ x + b₀)                  W₀: WIDTH × IN
//! hₗ = relu(Wₗ hₗ₋₁ + bₗ),  l = 1 … HIDDEN−1   Wₗ: WIDTH × WIDTH
//! y  = W_H h_{HIDDEN−1} + b_H            W_H: OUT × WIDTH
//! ```
//!
//! This is tiny-cuda-nn's `FullyFusedMLP` (Müller et al. 2021, *Real-time
//! Neural Radiance Caching for Path Tracing*) with ReLU hidden activation and
//! no output activation, **except that every layer has a bias**:
//! tiny-cuda-nn's MLPs have no bias terms (an offset can only enter through
//! the encoding's features). With biases the network does not depend on the
//! encoding to provide one, at a cost of `HIDDEN · WIDTH + OUT` extra
//! parameters. The output activation (softmax,
//! exp, sigmoid…) belongs to the distribution decoder, not to the network.
//!
//! # Parameter layout
//!
//! The network reads its parameters from one flat `&[f32]` at a caller-given
//! `offset` (so several networks, the encoding grid and the optimiser state
//! can share one GPU buffer) and occupies `params[offset .. offset +
//! PARAM_COUNT]`. Layers follow each other in evaluation order, each stored
//! as its weights, row-major `[out][in]` (row `o` holds the `in` weights of
//! output neuron `o`), then its `out` biases:
//!
//! ```text
//! offset + 0                        W₀[WIDTH][IN],  b₀[WIDTH]
//! offset + layer_offset(l)          Wₗ[WIDTH][WIDTH], bₗ[WIDTH]   (l = 1 … HIDDEN−1)
//! offset + layer_offset(HIDDEN)     W_H[OUT][WIDTH], b_H[OUT]
//! PARAM_COUNT = (IN + 1)·WIDTH + (HIDDEN − 1)·(WIDTH + 1)·WIDTH + (WIDTH + 1)·OUT
//! ```
//!
//! Gradients use the same layout (at the same offset of a gradient buffer),
//! and so do the Adam moments of [`crate::optim`].
//!
//! # Arithmetic
//!
//! The per-query kernels ([`Mlp::forward`], [`Mlp::infer`],
//! [`Mlp::backward`]: the shader code) sum every pre-activation in one fixed
//! order, starting from the bias: `((b + w₀x₀) + w₁x₁) + … + w_{n−1}x_{n−1}`,
//! with a separate multiply and add (Rust never contracts them into an FMA);
//! [`Mlp::forward`] and [`Mlp::infer`] are **bit-identical**. A GPU driver
//! may contract `a·b + c` into an FMA, which changes each term's rounding
//! (well within the forward error bound `γ_n Σ|wᵢxᵢ|`, `γ_n = nu/(1 − nu)`,
//! `u = 2⁻²⁴`).
//!
//! The batched CPU kernels (`std` feature, `BatchKernel`) keep that order
//! for every element (bias first, then the terms by increasing index; each
//! parameter gradient over the queries in order, starting from its value in
//! `grad`) but, except `BatchKernel::Portable`, round each term once with
//! a fused multiply–add, and they do not skip dead units. They are therefore
//! **not bit-identical** to the per-query kernels; they guarantee:
//! - **accuracy**: every sum is within `γ_{n+1} Σ|terms|` of the exact sum of
//!   its inputs, as the per-query kernel's is, so the two differ by at most
//!   `2 γ_{n+1} Σ|terms|` per layer, propagated through the network to first
//!   order (`err_l = |W_l| err_{l−1} + 2 γ_{n_l+1} A_l`, `A` the network
//!   evaluated on `|W|`, `|b|`, `|x|` without activations; likewise for the
//!   deltas and the parameter gradients). `tests/tests/mlp.rs` checks exactly
//!   this bound on every kernel and size;
//! - **determinism**: the same inputs give bit-identical results on every
//!   call; a query's outputs, contexts and input gradient do not depend on the
//!   rest of the batch (its length, or the query's position in it); only the
//!   parameter gradients combine queries, always in query order. For one
//!   kernel, `infer_batch_with` and `forward_batch_with` give
//!   the same outputs. Different kernels (and so `BatchKernel::detect` on
//!   different CPUs) may differ within the bound;
//! - **non-finite values** propagate as in the per-query kernels (up to
//!   overflow thresholds, which rounding moves slightly); parameters,
//!   inputs or contexts that are not all finite take the per-query backward
//!   (exactly), since a dead unit's `0 · ∞` would otherwise turn into NaN.
//!
//! ReLU is `if x > 0 { x } else { 0 }` (as tiny-cuda-nn): NaN pre-activations
//! become 0 in hidden layers; its derivative is taken as 0 at the kink.
//!
//! # Range
//!
//! Nothing here can panic on any value (NaN and ±∞ included); only a too
//! short `params` / `grad` slice (or mismatched batch lengths) panics.
//!
//! Finiteness: with every `|param| ≤ P` and `|input| ≤ X`, the exact
//! magnitudes of layer `l = 0 … HIDDEN` are bounded by `B_l = n_l·P·B_{l−1} +
//! P` with `B_{−1} = X` and `n_l` the layer's fan-in; each computed sum
//! exceeds the exact one by at most a factor `1 + γ_{n+1}` (`n = max(IN,
//! WIDTH)`, `γ_k = k u / (1 − k u)`, `u = 2⁻²⁴`), so if `(1 +
//! γ_{n+1})^{HIDDEN+1} · B_HIDDEN < f32::MAX` every forward value is finite.
//! Example: the 32 → 3 × 64 → 32 network is finite for `P = 10⁴`,
//! `X = 10¹⁵` (`B_3 ≈ 8.4·10³⁷`); the 7 → 2 × 16 → 5 network for `P = 10⁶`,
//! `X = 10¹⁵`. Beyond the bound, outputs may overflow to ±∞ or become NaN
//! (`∞ − ∞`); NaN and ±∞ inputs propagate (ReLU turns a NaN into 0).

#[cfg(feature = "std")]
extern crate std;

use crate::gradient::GradientSink;
use crate::math::sqrt;
use crate::rng::{hash2, symmetric_unit_f32};
use bytemuck::{Pod, Zeroable};

/// Output-layer initialisation scale, relative to the ReLU-layer bound (see
/// [`Mlp::init`]).
pub const OUTPUT_INIT_SCALE: f32 = 0.1;

/// A fully connected ReLU network with `IN` inputs, `HIDDEN ≥ 1` hidden
/// layers of `WIDTH` neurons and `OUT` linear outputs; zero-sized, the
/// parameters live in a caller's flat buffer (layout in the
/// [module docs](self)).
#[derive(Clone, Copy, Debug, Default)]
pub struct Mlp<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>;

/// What [`Mlp::forward`] keeps for [`Mlp::backward`]: the post-activation
/// values of every hidden layer (tiny-cuda-nn's forward context).
///
/// `repr(C)`, [`Pod`], `HIDDEN · WIDTH` floats.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MlpContext<const WIDTH: usize, const HIDDEN: usize> {
    /// `hidden[l][j]` = output of neuron `j` of hidden layer `l`, after ReLU.
    pub hidden: [[f32; WIDTH]; HIDDEN],
}

// SAFETY: `repr(C)` struct of one `[[f32; WIDTH]; HIDDEN]` array: no padding,
// every bit pattern valid, zero is valid.
unsafe impl<const WIDTH: usize, const HIDDEN: usize> Zeroable for MlpContext<WIDTH, HIDDEN> {}
// SAFETY: see above; `Copy + 'static` holds for every size.
unsafe impl<const WIDTH: usize, const HIDDEN: usize> Pod for MlpContext<WIDTH, HIDDEN> {}

impl<const WIDTH: usize, const HIDDEN: usize> MlpContext<WIDTH, HIDDEN> {
    /// All zeros.
    pub const ZERO: Self = Self {
        hidden: [[0.0; WIDTH]; HIDDEN],
    };
}

impl<const WIDTH: usize, const HIDDEN: usize> Default for MlpContext<WIDTH, HIDDEN> {
    fn default() -> Self {
        Self::ZERO
    }
}

/// ReLU, `x` if `x > 0`, else 0 (also for NaN).
#[inline]
#[must_use]
fn relu(x: f32) -> f32 {
    if x > 0.0 {
        x
    } else {
        0.0
    }
}

/// One dense layer `y = act(W x + b)` with `W` (row-major `[O][I]`) at
/// `params[w]` and `b` right after it.
///
/// Four output rows are summed side by side (each still in its own fixed
/// order, so the results do not change): four independent add chains keep a
/// CPU's adders busy instead of waiting on one chain's latency.
#[inline]
fn dense<const I: usize, const O: usize, const RELU: bool>(
    params: &[f32],
    w: usize,
    x: &[f32; I],
    y: &mut [f32; O],
) {
    let b = w + O * I;
    let mut o = 0;
    while o + 4 <= O {
        let r0 = w + o * I;
        let (r1, r2, r3) = (r0 + I, r0 + 2 * I, r0 + 3 * I);
        let mut a0 = params[b + o];
        let mut a1 = params[b + o + 1];
        let mut a2 = params[b + o + 2];
        let mut a3 = params[b + o + 3];
        let mut i = 0;
        while i < I {
            let xi = x[i];
            a0 += params[r0 + i] * xi;
            a1 += params[r1 + i] * xi;
            a2 += params[r2 + i] * xi;
            a3 += params[r3 + i] * xi;
            i += 1;
        }
        y[o] = if RELU { relu(a0) } else { a0 };
        y[o + 1] = if RELU { relu(a1) } else { a1 };
        y[o + 2] = if RELU { relu(a2) } else { a2 };
        y[o + 3] = if RELU { relu(a3) } else { a3 };
        o += 4;
    }
    while o < O {
        let row = w + o * I;
        let mut acc = params[b + o];
        let mut i = 0;
        while i < I {
            acc += params[row + i] * x[i];
            i += 1;
        }
        y[o] = if RELU { relu(acc) } else { acc };
        o += 1;
    }
}

/// Backward of one dense layer (before its activation): given `dy = ∂L/∂z`
/// of `z = W x + b`, accumulates `∂L/∂W = dy xᵀ` and `∂L/∂b = dy` into
/// `grad` and writes `dx = Wᵀ dy`. Rows with `dy[o] = 0` (dead ReLUs) are
/// skipped: they add exact zeros when `x` is finite.
#[inline]
fn dense_backward<const I: usize, const O: usize, G: GradientSink + ?Sized>(
    params: &[f32],
    grad: &mut G,
    w: usize,
    x: &[f32; I],
    dy: &[f32; O],
    dx: &mut [f32; I],
) {
    let b = w + O * I;
    let mut i = 0;
    while i < I {
        dx[i] = 0.0;
        i += 1;
    }
    let mut o = 0;
    while o < O {
        let d = dy[o];
        if d != 0.0 {
            grad.add(b + o, d);
            let row = w + o * I;
            i = 0;
            while i < I {
                grad.add(row + i, d * x[i]);
                dx[i] += params[row + i] * d;
                i += 1;
            }
        }
        o += 1;
    }
}

/// `delta[j] = 0` where the ReLU output `h[j]` is not positive.
#[inline]
fn relu_mask<const N: usize>(delta: &mut [f32; N], h: &[f32; N]) {
    let mut j = 0;
    while j < N {
        if h[j] <= 0.0 {
            delta[j] = 0.0;
        }
        j += 1;
    }
}

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
    Mlp<IN, WIDTH, OUT, HIDDEN>
{
    /// Compile-time check of the sizes (evaluated when a function is
    /// instantiated).
    const VALID: () = assert!(
        IN >= 1 && WIDTH >= 1 && OUT >= 1 && HIDDEN >= 1,
        "Mlp needs IN, WIDTH, OUT ≥ 1 and at least one hidden layer"
    );

    /// Parameters of the first layer, `(IN + 1) · WIDTH`.
    pub const FIRST_LAYER_PARAMS: usize = WIDTH * IN + WIDTH;
    /// Parameters of one `WIDTH → WIDTH` hidden layer, `(WIDTH + 1) · WIDTH`.
    pub const HIDDEN_LAYER_PARAMS: usize = WIDTH * WIDTH + WIDTH;
    /// Parameters of the output layer, `(WIDTH + 1) · OUT`.
    pub const OUTPUT_LAYER_PARAMS: usize = OUT * WIDTH + OUT;
    /// Offset of the output layer within the network.
    pub const OUTPUT_LAYER_OFFSET: usize =
        Self::FIRST_LAYER_PARAMS + (HIDDEN - 1) * Self::HIDDEN_LAYER_PARAMS;
    /// Total number of parameters (weights and biases).
    pub const PARAM_COUNT: usize = Self::OUTPUT_LAYER_OFFSET + Self::OUTPUT_LAYER_PARAMS;
    /// Multiply–adds of one forward pass (weights only); a forward pass costs
    /// `2 · MACS` flops.
    pub const MACS: usize = WIDTH * IN + (HIDDEN - 1) * WIDTH * WIDTH + OUT * WIDTH;

    /// Offset, within the network, of the weights of layer `layer`
    /// (`0 … HIDDEN`, `HIDDEN` being the output layer); its biases follow at
    /// `+ fan_out · fan_in`.
    #[must_use]
    pub const fn layer_offset(layer: usize) -> usize {
        if layer == 0 {
            0
        } else {
            Self::FIRST_LAYER_PARAMS + (layer - 1) * Self::HIDDEN_LAYER_PARAMS
        }
    }

    /// Inputs of layer `layer` (`IN` for the first, `WIDTH` otherwise).
    #[must_use]
    pub const fn fan_in(layer: usize) -> usize {
        if layer == 0 {
            IN
        } else {
            WIDTH
        }
    }

    /// Outputs of layer `layer` (`OUT` for the output layer `HIDDEN`,
    /// `WIDTH` otherwise).
    #[must_use]
    pub const fn fan_out(layer: usize) -> usize {
        if layer == HIDDEN {
            OUT
        } else {
            WIDTH
        }
    }

    /// Forward pass of one query, keeping the hidden activations in `ctx`
    /// for [`Self::backward`]. Bit-identical to [`Self::infer`].
    ///
    /// # Panics
    /// If `params` is shorter than `offset + PARAM_COUNT`.
    pub fn forward(
        params: &[f32],
        offset: usize,
        input: &[f32; IN],
        ctx: &mut MlpContext<WIDTH, HIDDEN>,
    ) -> [f32; OUT] {
        let () = Self::VALID;
        let mut h = [0.0f32; WIDTH];
        dense::<IN, WIDTH, true>(params, offset, input, &mut h);
        ctx.hidden[0] = h;
        let mut l = 1;
        while l < HIDDEN {
            let mut next = [0.0f32; WIDTH];
            dense::<WIDTH, WIDTH, true>(params, offset + Self::layer_offset(l), &h, &mut next);
            ctx.hidden[l] = next;
            h = next;
            l += 1;
        }
        let mut y = [0.0f32; OUT];
        dense::<WIDTH, OUT, false>(params, offset + Self::OUTPUT_LAYER_OFFSET, &h, &mut y);
        y
    }

    /// Inference-only forward pass of one query (no context).
    ///
    /// # Panics
    /// If `params` is shorter than `offset + PARAM_COUNT`.
    #[must_use]
    pub fn infer(params: &[f32], offset: usize, input: &[f32; IN]) -> [f32; OUT] {
        let () = Self::VALID;
        let mut h = [0.0f32; WIDTH];
        dense::<IN, WIDTH, true>(params, offset, input, &mut h);
        let mut l = 1;
        while l < HIDDEN {
            let mut next = [0.0f32; WIDTH];
            dense::<WIDTH, WIDTH, true>(params, offset + Self::layer_offset(l), &h, &mut next);
            h = next;
            l += 1;
        }
        let mut y = [0.0f32; OUT];
        dense::<WIDTH, OUT, false>(params, offset + Self::OUTPUT_LAYER_OFFSET, &h, &mut y);
        y
    }

    /// Backward pass of one query: given `d_output = ∂L/∂y` and the `ctx`
    /// that [`Self::forward`] filled for the same `input` and parameters,
    /// **adds** `∂L/∂W` and `∂L/∂b` of every layer to `grad` (same layout and
    /// `offset` as `params`) and **writes** `∂L/∂input` to `d_input` (so an
    /// input encoding can be trained through the network).
    ///
    /// Standard reverse-mode: `δ = d_output`; per layer from the top,
    /// `∂L/∂W += δ hᵀ`, `∂L/∂b += δ`, `δ ← (Wᵀ δ) ⊙ [h > 0]`. Sums over
    /// output neurons run in increasing order, starting from 0; neurons with
    /// `δ = 0` (dead ReLUs) are skipped, which changes nothing for finite
    /// activations.
    ///
    /// # Panics
    /// If `params` or `grad` is shorter than `offset + PARAM_COUNT`.
    pub fn backward<G: GradientSink + ?Sized>(
        params: &[f32],
        offset: usize,
        input: &[f32; IN],
        ctx: &MlpContext<WIDTH, HIDDEN>,
        d_output: &[f32; OUT],
        grad: &mut G,
        d_input: &mut [f32; IN],
    ) {
        let () = Self::VALID;
        let mut delta = [0.0f32; WIDTH];
        dense_backward::<WIDTH, OUT, G>(
            params,
            grad,
            offset + Self::OUTPUT_LAYER_OFFSET,
            &ctx.hidden[HIDDEN - 1],
            d_output,
            &mut delta,
        );
        let mut l = HIDDEN - 1;
        while l > 0 {
            relu_mask(&mut delta, &ctx.hidden[l]);
            let mut prev = [0.0f32; WIDTH];
            dense_backward::<WIDTH, WIDTH, G>(
                params,
                grad,
                offset + Self::layer_offset(l),
                &ctx.hidden[l - 1],
                &delta,
                &mut prev,
            );
            delta = prev;
            l -= 1;
        }
        relu_mask(&mut delta, &ctx.hidden[0]);
        dense_backward::<IN, WIDTH, G>(params, grad, offset, input, &delta, d_input);
    }

    /// Initial value of parameter `index` (`0 … PARAM_COUNT`, relative to the
    /// network's offset) for `seed`: a counter-based draw, so a GPU can
    /// initialise every parameter in parallel with the values of
    /// [`Self::init`].
    ///
    /// - weights of the ReLU layers (layer 0 and the hidden layers): Kaiming /
    ///   He uniform (He et al. 2015, *Delving Deep into Rectifiers*),
    ///   `U(−a, a)` with `a = √(6 / fan_in)`, i.e. variance `2 / fan_in`;
    /// - weights of the linear output layer: the same law scaled by
    ///   [`OUTPUT_INIT_SCALE`] = 0.1 (variance `0.02 / WIDTH`), so that the
    ///   initial raw outputs are small and the decoded distributions start
    ///   close to their neutral shape (equal weights, broad lobes) instead of
    ///   with random confident lobes;
    /// - biases: 0.
    ///
    /// The uniform variate is [`symmetric_unit_f32`]`(`[`hash2`]`(seed,
    /// index))`, exactly zero-mean over its 2²³ values. tiny-cuda-nn uses
    /// Xavier-uniform `√(6 / (fan_in + fan_out))` on every layer; Kaiming is
    /// the variance-preserving choice for ReLU.
    ///
    /// Indices `≥ PARAM_COUNT` give 0.
    #[must_use]
    pub fn init_value(index: usize, seed: u32) -> f32 {
        let () = Self::VALID;
        // Locate the layer: (first index of its biases, fan-in, scale).
        let (bias_start, fan_in, scale) = if index < Self::FIRST_LAYER_PARAMS {
            (WIDTH * IN, IN, 1.0)
        } else if index < Self::OUTPUT_LAYER_OFFSET {
            let local = (index - Self::FIRST_LAYER_PARAMS) % Self::HIDDEN_LAYER_PARAMS;
            (index - local + WIDTH * WIDTH, WIDTH, 1.0)
        } else if index < Self::PARAM_COUNT {
            (
                Self::OUTPUT_LAYER_OFFSET + OUT * WIDTH,
                WIDTH,
                OUTPUT_INIT_SCALE,
            )
        } else {
            return 0.0;
        };
        if index >= bias_start {
            return 0.0;
        }
        let bound = scale * sqrt(6.0 / fan_in as f32);
        bound * symmetric_unit_f32(hash2(seed, index as u32))
    }

    /// Deterministic initialisation of `params[offset .. offset +
    /// PARAM_COUNT]` (nothing outside that range is touched): parameter `k`
    /// becomes [`Self::init_value`]`(k, seed)`, independent of `offset`.
    ///
    /// # Panics
    /// If `params` is shorter than `offset + PARAM_COUNT`.
    pub fn init(params: &mut [f32], offset: usize, seed: u32) {
        let mut k = 0;
        while k < Self::PARAM_COUNT {
            params[offset + k] = Self::init_value(k, seed);
            k += 1;
        }
    }
}

/// The CPU batch kernels (host only).
///
/// Queries are processed in blocks of [`BLOCK`] = 48, every layer of a block
/// being one small matrix product computed by one register-tiled kernel
/// ([`gemm`]), with `b` the queries of the block:
///
/// ```text
/// forward            H_l[b][o]     = act(b_l[o] + Σ_i H_{l−1}[b][i] · W_lᵀ[i][o])
/// input gradients    Δ_{l−1}[b][i] = [H_{l−1}[b][i] > 0] · Σ_o Δ_l[b][o] · W_l[o][i]
/// weight gradients   ∂W_l[o][i]   += Σ_b Δ_l[b][o] · H_{l−1}[b][i]   (∂b_l[o] += Σ_b Δ_l[b][o])
/// ```
///
/// (`H_{−1}` the inputs, `Δ_HIDDEN` the output gradients.) Activations stay
/// query-major, the layout of the caller's inputs, contexts and outputs, so
/// nothing is transposed and, when the widths are multiples of the vector
/// width, they are read and written in place; `Wᵀ` is packed once per call
/// (`[fan_in][fan_out]`, rows padded to the vector width) for the forward
/// pass and `W`, padded, serves the backward pass. A register tile holds `R`
/// rows × `NV` vectors of the result in accumulators; per step of the sum it
/// loads `NV` vectors of the right operand and broadcasts `R` elements of
/// the left one (which may have any strides, so `Δᵀ` needs no transpose):
/// `R · NV` independent multiply–adds, enough to cover the FMA latency.
/// Weights stay in L1 while the rows of a block stream past them. Row and
/// column remainders take smaller tiles (4, 2, 1 rows; 1 vector), so no
/// query is padded. A weight-gradient tile starts from the current gradient
/// (copied in per call, padded) and is stored back after each block, so each
/// gradient element is summed over the queries in order. The glue (copies,
/// bias gradients, finiteness checks) runs inside the instruction set's
/// `#[target_feature]` function too.
///
/// Accuracy and determinism: see "Arithmetic" in the [module docs](crate::mlp);
/// measured throughput: [`BatchKernel`].
#[cfg(feature = "std")]
mod batch {
    use super::{Mlp, MlpContext};
    use std::vec;
    use std::vec::Vec;

    /// Which compiled variant of the batch kernels runs.
    ///
    /// The variants share one generic kernel: per block of 48 queries, each
    /// layer (forward: `H_l = act(H_{l−1} W_lᵀ + b_l)`; backward: `Δ_{l−1} =
    /// (Δ_l W_l) ⊙ [H_{l−1} > 0]` and `∂W_l += Δ_lᵀ H_{l−1}`, the queries as
    /// rows, query-major as the caller's buffers) is one small matrix product
    /// with a register tile of `R` rows × `NV` vectors of accumulators, one
    /// broadcast element of the left operand times `NV` loaded vectors of
    /// the right one per step. It is instantiated for an instruction set
    /// with `core::arch` intrinsics inside `#[target_feature]` functions; the
    /// x86 variants are selected by runtime detection
    /// ([`Self::is_available`], `is_x86_feature_detected!`) and only exist on
    /// x86-64 (other targets run [`Self::Portable`]).
    /// [`Self::Portable`] uses a separate multiply and add, so it needs no
    /// FMA hardware (and calls no `libm` `fmaf`); the others fuse them.
    /// Results of different variants differ within the bound of the
    /// [module docs](crate::mlp) ("Arithmetic").
    ///
    /// [`Self::detect`] prefers AVX-512, then AVX2 + FMA. On the Zen 4
    /// target both reach the same measured FMA peak (Zen 4 executes a
    /// 512-bit FMA as two 256-bit halves: ≈ 117 GFLOP/s, 32 flop/cycle, for
    /// either), and AVX-512 measured equal for inference and 0–3 % faster for
    /// training (6.01 vs 5.81, 4.42 vs 4.27, 1.37 vs 1.29 M queries/s for the
    /// three sizes below), within the noise of that shared machine; it
    /// is preferred for its fewer instructions and larger register file.
    ///
    /// Measured (`cargo bench -p guiding-bench --bench mlp`,
    /// AMD EPYC Zen 4, one thread, batch 4096; measured FMA peak 117.4
    /// GFLOP/s, 32 flop/cycle at ≈ 3.65 GHz, the same with AVX2 and
    /// AVX-512; flops: `2 · MACS` per query forward, `6 · MACS` forward +
    /// backward). Each row is the best over several runs on a 2-core VM
    /// shared with other builds; single runs under load read 10–30 % lower.
    ///
    /// ```text
    /// size             pass     kernel      queries/s  GFLOP/s  % of peak
    /// Mlp<16,32,32,2>  infer    per-query    1.16 M       5.9      5.1
    ///                           Portable     6.90 M      35.3     30.1
    ///                           Avx2Fma     20.9  M     107.0     91.1
    ///                           Avx512      21.0  M     107.5     91.6
    ///                  fwd+bwd  per-query    0.48 M       7.3      6.3
    ///                           Portable     2.21 M      33.9     28.9
    ///                           Avx2Fma      5.81 M      89.2     76.0
    ///                           Avx512       6.01 M      92.3     78.6
    /// Mlp<48,32,32,2>  infer    per-query    0.82 M       5.9      5.0
    ///                           Portable     5.06 M      36.3     30.9
    ///                           Avx2Fma     15.0  M     107.5     91.6
    ///                           Avx512      15.2  M     109.0     92.8
    ///                  fwd+bwd  per-query    0.41 M       8.8      7.5
    ///                           Portable     1.57 M      33.8     28.8
    ///                           Avx2Fma      4.27 M      91.8     78.2
    ///                           Avx512       4.42 M      95.0     81.0
    /// Mlp<32,64,32,3>  infer    per-query    0.23 M       5.7      4.9
    ///                           Portable     1.47 M      36.1     30.8
    ///                           Avx2Fma      4.48 M     110.1     93.8
    ///                           Avx512       4.55 M     111.8     95.2
    ///                  fwd+bwd  per-query    0.13 M       9.6      8.2
    ///                           Portable     0.47 M      34.4     29.3
    ///                           Avx2Fma      1.29 M      95.1     81.0
    ///                           Avx512       1.37 M     101.0     86.0
    /// ```
    ///
    /// For comparison, the `gemm` crate (0.18, one product per layer over the
    /// whole batch, then bias and ReLU, one thread) measured 53–98 GFLOP/s on
    /// the same inference passes, below these kernels, so it is not used.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum BatchKernel {
        /// Baseline target features (SSE2 on x86-64), separate multiply and
        /// add (no FMA hardware needed); register tiles of 4 rows × 8
        /// columns.
        Portable,
        /// AVX2 + FMA (x86-64 only); register tiles of 6 rows × 16 columns
        /// (12 `ymm` accumulators).
        Avx2Fma,
        /// AVX-512F (+ AVX2, FMA; x86-64 only); register tiles of 8 rows × 32
        /// columns (16 `zmm` accumulators).
        Avx512,
    }

    impl BatchKernel {
        /// Every variant.
        pub const ALL: [Self; 3] = [Self::Portable, Self::Avx2Fma, Self::Avx512];

        /// Whether this CPU can run the variant (runtime detection).
        #[must_use]
        pub fn is_available(self) -> bool {
            match self {
                Self::Portable => true,
                #[cfg(target_arch = "x86_64")]
                Self::Avx2Fma => x86::Avx2Fma::new().is_some(),
                #[cfg(target_arch = "x86_64")]
                Self::Avx512 => x86::Avx512::new().is_some(),
                #[cfg(not(target_arch = "x86_64"))]
                _ => false,
            }
        }

        /// The fastest available variant, as measured (see the type's docs).
        #[must_use]
        pub fn detect() -> Self {
            if Self::Avx512.is_available() {
                Self::Avx512
            } else if Self::Avx2Fma.is_available() {
                Self::Avx2Fma
            } else {
                Self::Portable
            }
        }
    }

    /// Queries per block: the activations of one block stay in L1/L2 while
    /// every layer runs over it (a multiple of every row tile).
    const BLOCK: usize = 48;

    /// Accumulators start at zero.
    const INIT_ZERO: u8 = 0;
    /// Accumulators start at the (padded) bias vector.
    const INIT_BIAS: u8 = 1;
    /// Accumulators start at the current `C` (accumulate into it).
    const INIT_LOAD: u8 = 2;
    /// Results are stored as they are.
    const EPI_NONE: u8 = 0;
    /// ReLU (`x > 0 ? x : 0`, NaN → 0) before storing.
    const EPI_RELU: u8 = 1;
    /// Results are zeroed where `h ≤ 0` (the ReLU derivative of the layer
    /// below; NaN `h` keeps the result, as [`super::relu_mask`]).
    const EPI_MASK: u8 = 2;

    /// One small matrix product `C[r][n] = init + Σ_k A[r][k] · B[k][n]`
    /// for `r < rows`, `n < nvecs · LANES`, the sum over `k = 0, 1, …`
    /// in increasing order with one (fused, where the ISA has it)
    /// multiply–add per term. `A[r][k] = a[r · a_rs + k · a_ks]` (any
    /// strides: its elements are broadcast one at a time), `B` and `C` are
    /// row-major with leading dimensions `ldb`, `ldc` and padded rows;
    /// `bias` (for [`INIT_BIAS`]) and `h` (for [`EPI_MASK`], leading
    /// dimension `ldh`) are read in whole vectors too.
    struct Gemm<'a> {
        rows: usize,
        nvecs: usize,
        k: usize,
        a: &'a [f32],
        a_rs: usize,
        a_ks: usize,
        b: &'a [f32],
        ldb: usize,
        c: &'a mut [f32],
        ldc: usize,
        /// A second destination for the results (empty: none).
        c2: &'a mut [f32],
        ldc2: usize,
        bias: &'a [f32],
        h: &'a [f32],
        ldh: usize,
    }

    /// A SIMD instruction set: the vector type and the few operations the
    /// kernel needs. A value of an implementing type proves that the CPU
    /// supports the instruction set (the x86 ones are only constructed after
    /// runtime detection).
    trait Simd: Copy {
        /// `f32` lanes of [`Self::V`].
        const LANES: usize;
        /// One vector.
        type V: Copy;
        fn zero(self) -> Self::V;
        /// # Safety
        /// `p` must be valid for reading `LANES` floats.
        unsafe fn load(self, p: *const f32) -> Self::V;
        /// # Safety
        /// `p` must be valid for writing `LANES` floats.
        unsafe fn store(self, p: *mut f32, v: Self::V);
        /// # Safety
        /// `p` must be valid for reading one float.
        unsafe fn splat(self, p: *const f32) -> Self::V;
        /// `a · b + c`, fused where the instruction set has an FMA.
        fn mul_add(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
        /// ReLU per lane (`x > 0 ? x : 0`, NaN → 0).
        fn relu(self, v: Self::V) -> Self::V;
        /// `v` per lane, zeroed where `h ≤ 0`.
        fn mask(self, v: Self::V, h: Self::V) -> Self::V;
        /// Runs [`gemm_body`] with this set's tile shape, compiled for its
        /// target features.
        ///
        /// # Safety
        /// `g` must have passed the bounds checks of [`gemm`].
        unsafe fn kernel<const INIT: u8, const EPI: u8>(self, g: &mut Gemm<'_>);
        /// Runs `f` inside a function compiled for this set's target
        /// features, so that the glue code inlined into it (copies, bias
        /// gradients, finiteness checks) uses them too.
        fn vectorize<R>(self, f: impl FnOnce() -> R) -> R;
    }

    /// Checks every bound that [`gemm_body`] relies on, then runs it.
    fn gemm<S: Simd, const INIT: u8, const EPI: u8>(s: S, g: &mut Gemm<'_>) {
        let n = g.nvecs * S::LANES;
        assert!(g.rows >= 1 && g.k >= 1 && g.nvecs >= 1, "empty product");
        assert!(
            (g.rows - 1) * g.a_rs + (g.k - 1) * g.a_ks < g.a.len(),
            "A out of bounds"
        );
        assert!((g.k - 1) * g.ldb + n <= g.b.len(), "B out of bounds");
        assert!((g.rows - 1) * g.ldc + n <= g.c.len(), "C out of bounds");
        assert!(
            g.c2.is_empty() || (g.rows - 1) * g.ldc2 + n <= g.c2.len(),
            "C2 out of bounds"
        );
        assert!(INIT != INIT_BIAS || n <= g.bias.len(), "bias out of bounds");
        assert!(
            EPI != EPI_MASK || (g.rows - 1) * g.ldh + n <= g.h.len(),
            "mask out of bounds"
        );
        // SAFETY: the kernel reads A[r][k], B[k][0..n], C[r][0..n], bias[0..n]
        // and h[r][0..n] and writes C[r][0..n] and C2[r][0..n] (if not
        // empty) for r < rows, k < k only: all within the bounds checked
        // above.
        unsafe { s.kernel::<INIT, EPI>(g) }
    }

    /// The column tiles (`NV` vectors, then the remainder) of [`Gemm`].
    ///
    /// # Safety
    /// As [`Simd::kernel`].
    #[inline(always)]
    unsafe fn gemm_body<S: Simd, const R: usize, const NV: usize, const INIT: u8, const EPI: u8>(
        s: S,
        g: &mut Gemm<'_>,
    ) {
        let mut v = 0;
        while v + NV <= g.nvecs {
            rows_body::<S, R, NV, INIT, EPI>(s, g, v * S::LANES);
            v += NV;
        }
        if NV > 2 && g.nvecs - v >= 2 {
            rows_body::<S, R, 2, INIT, EPI>(s, g, v * S::LANES);
            v += 2;
        }
        if NV > 1 && g.nvecs - v >= 1 {
            rows_body::<S, R, 1, INIT, EPI>(s, g, v * S::LANES);
        }
    }

    /// The row tiles (`R` rows, then 4, 2, 1) of one column tile.
    ///
    /// # Safety
    /// As [`Simd::kernel`], and `n0 + NV · LANES ≤ nvecs · LANES`.
    #[inline(always)]
    unsafe fn rows_body<S: Simd, const R: usize, const NV: usize, const INIT: u8, const EPI: u8>(
        s: S,
        g: &mut Gemm<'_>,
        n0: usize,
    ) {
        let mut r = 0;
        while r + R <= g.rows {
            tile::<S, R, NV, INIT, EPI>(s, g, r, n0);
            r += R;
        }
        while R > 4 && g.rows - r >= 4 {
            tile::<S, 4, NV, INIT, EPI>(s, g, r, n0);
            r += 4;
        }
        if R > 2 && g.rows - r >= 2 {
            tile::<S, 2, NV, INIT, EPI>(s, g, r, n0);
            r += 2;
        }
        if R > 1 && g.rows - r >= 1 {
            tile::<S, 1, NV, INIT, EPI>(s, g, r, n0);
        }
    }

    /// One register tile: rows `r0 .. r0 + R`, columns `n0 .. n0 + NV ·
    /// LANES`; `R · NV` accumulators, and per `k` one load of `NV` vectors
    /// of `B` and `R` broadcasts of `A`.
    ///
    /// # Safety
    /// As [`rows_body`], and `r0 + R ≤ rows`.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // fixed-size register arrays
    unsafe fn tile<S: Simd, const R: usize, const NV: usize, const INIT: u8, const EPI: u8>(
        s: S,
        g: &mut Gemm<'_>,
        r0: usize,
        n0: usize,
    ) {
        let l = S::LANES;
        let (a_rs, a_ks, ldb, ldc, ldh) = (g.a_rs, g.a_ks, g.ldb, g.ldc, g.ldh);
        let c = g.c.as_mut_ptr();
        let (dual, c2, ldc2) = (!g.c2.is_empty(), g.c2.as_mut_ptr(), g.ldc2);
        let mut acc = [[s.zero(); NV]; R];
        if INIT == INIT_BIAS {
            for v in 0..NV {
                let bv = s.load(g.bias.as_ptr().add(n0 + v * l));
                for row in &mut acc {
                    row[v] = bv;
                }
            }
        } else if INIT == INIT_LOAD {
            for r in 0..R {
                for v in 0..NV {
                    acc[r][v] = s.load(c.add((r0 + r) * ldc + n0 + v * l));
                }
            }
        }
        let mut a = g.a.as_ptr().wrapping_add(r0 * a_rs);
        let mut b = g.b.as_ptr().wrapping_add(n0);
        for _ in 0..g.k {
            let mut bv = [s.zero(); NV];
            for v in 0..NV {
                bv[v] = s.load(b.add(v * l));
            }
            for r in 0..R {
                let x = s.splat(a.add(r * a_rs));
                for v in 0..NV {
                    acc[r][v] = s.mul_add(x, bv[v], acc[r][v]);
                }
            }
            a = a.wrapping_add(a_ks);
            b = b.wrapping_add(ldb);
        }
        for r in 0..R {
            for v in 0..NV {
                let mut y = acc[r][v];
                if EPI == EPI_RELU {
                    y = s.relu(y);
                } else if EPI == EPI_MASK {
                    y = s.mask(y, s.load(g.h.as_ptr().add((r0 + r) * ldh + n0 + v * l)));
                }
                s.store(c.add((r0 + r) * ldc + n0 + v * l), y);
                if dual {
                    s.store(c2.add((r0 + r) * ldc2 + n0 + v * l), y);
                }
            }
        }
    }

    /// Plain Rust on `[f32; 4]` (SSE on x86-64 by autovectorisation),
    /// multiply then add: no FMA hardware needed, and no `mul_add` libm call.
    #[derive(Clone, Copy)]
    struct Portable;

    impl Simd for Portable {
        const LANES: usize = 4;
        type V = [f32; 4];
        #[inline(always)]
        fn zero(self) -> [f32; 4] {
            [0.0; 4]
        }
        #[inline(always)]
        unsafe fn load(self, p: *const f32) -> [f32; 4] {
            p.cast::<[f32; 4]>().read_unaligned()
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f32, v: [f32; 4]) {
            p.cast::<[f32; 4]>().write_unaligned(v);
        }
        #[inline(always)]
        unsafe fn splat(self, p: *const f32) -> [f32; 4] {
            [*p; 4]
        }
        #[inline(always)]
        fn mul_add(self, a: [f32; 4], b: [f32; 4], c: [f32; 4]) -> [f32; 4] {
            [
                a[0] * b[0] + c[0],
                a[1] * b[1] + c[1],
                a[2] * b[2] + c[2],
                a[3] * b[3] + c[3],
            ]
        }
        #[inline(always)]
        fn relu(self, v: [f32; 4]) -> [f32; 4] {
            v.map(super::relu)
        }
        #[inline(always)]
        fn mask(self, v: [f32; 4], h: [f32; 4]) -> [f32; 4] {
            core::array::from_fn(|k| if h[k] <= 0.0 { 0.0 } else { v[k] })
        }
        unsafe fn kernel<const INIT: u8, const EPI: u8>(self, g: &mut Gemm<'_>) {
            gemm_body::<Self, 4, 2, INIT, EPI>(self, g);
        }
        #[inline(always)]
        fn vectorize<R>(self, f: impl FnOnce() -> R) -> R {
            f()
        }
    }

    /// The x86-64 instruction sets, with `core::arch` intrinsics.
    #[cfg(target_arch = "x86_64")]
    mod x86 {
        use super::{gemm_body, Gemm, Simd};
        use core::arch::x86_64::{
            __m256, __m512, _mm256_and_ps, _mm256_broadcast_ss, _mm256_cmp_ps, _mm256_fmadd_ps,
            _mm256_loadu_ps, _mm256_max_ps, _mm256_setzero_ps, _mm256_storeu_ps,
            _mm512_cmp_ps_mask, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_maskz_mov_ps,
            _mm512_max_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps, _CMP_NLE_UQ,
        };

        /// Declares an instruction set `$name`: a type constructed only when
        /// every one of `$feature` is detected, its `#[target_feature]` entry
        /// points (the kernel with register tiles of `$rows` rows × 2
        /// vectors, and `vectorize`), and its [`Simd`] impl on `$lanes`
        /// lanes of `$v` from the set's intrinsics. A macro because
        /// `#[target_feature]` takes a literal, not a generic parameter.
        macro_rules! simd_set {
            (
                $(#[$doc:meta])*
                $name:ident: [$($feature:tt),+], rows $rows:literal, $lanes:literal x $v:ty {
                    zero: $zero:path,
                    load: $load:path,
                    store: $store:path,
                    splat: |$sp:ident| $splat:expr,
                    fmadd: $fmadd:path,
                    max: $max:path,
                    mask: |$mv:ident, $mh:ident| $mask:expr $(,)?
                }
            ) => {
                $(#[$doc])*
                #[derive(Clone, Copy)]
                pub(in super::super) struct $name(());

                impl $name {
                    pub(in super::super) fn new() -> Option<Self> {
                        ($(std::is_x86_feature_detected!($feature))&&+).then_some(Self(()))
                    }

                    /// Runs `f` compiled with this set's features (`f` is inlined).
                    $(#[target_feature(enable = $feature)])+
                    fn vectorize_tf<R>(self, f: impl FnOnce() -> R) -> R {
                        f()
                    }

                    /// # Safety
                    /// As [`Simd::kernel`]; `self` proves the features.
                    $(#[target_feature(enable = $feature)])+
                    unsafe fn kernel_tf<const INIT: u8, const EPI: u8>(self, g: &mut Gemm<'_>) {
                        gemm_body::<Self, $rows, 2, INIT, EPI>(self, g);
                    }
                }

                // SAFETY (every `unsafe` block below): a `$name` exists only
                // when its features were detected, so the intrinsics' target
                // features are available; pointer validity is the caller's
                // contract.
                impl Simd for $name {
                    const LANES: usize = $lanes;
                    type V = $v;
                    #[inline(always)]
                    fn zero(self) -> $v {
                        // SAFETY: see the impl.
                        unsafe { $zero() }
                    }
                    #[inline(always)]
                    unsafe fn load(self, p: *const f32) -> $v {
                        $load(p)
                    }
                    #[inline(always)]
                    unsafe fn store(self, p: *mut f32, v: $v) {
                        $store(p, v);
                    }
                    #[inline(always)]
                    unsafe fn splat(self, $sp: *const f32) -> $v {
                        $splat
                    }
                    #[inline(always)]
                    fn mul_add(self, a: $v, b: $v, c: $v) -> $v {
                        // SAFETY: see the impl.
                        unsafe { $fmadd(a, b, c) }
                    }
                    #[inline(always)]
                    fn relu(self, v: $v) -> $v {
                        // SAFETY: see the impl. `max(v, 0)` returns the
                        // second operand (0) when `v` is NaN or ±0.
                        unsafe { $max(v, $zero()) }
                    }
                    #[inline(always)]
                    fn mask(self, $mv: $v, $mh: $v) -> $v {
                        // SAFETY: see the impl.
                        unsafe { $mask }
                    }
                    unsafe fn kernel<const INIT: u8, const EPI: u8>(self, g: &mut Gemm<'_>) {
                        self.kernel_tf::<INIT, EPI>(g);
                    }
                    #[inline(always)]
                    fn vectorize<R>(self, f: impl FnOnce() -> R) -> R {
                        // SAFETY: see the impl.
                        unsafe { self.vectorize_tf(f) }
                    }
                }
            };
        }

        // `mask` keeps `v` where `!(h ≤ 0)` (NaN `h` included).
        simd_set! {
            /// AVX2 + FMA; only constructed when both are detected.
            Avx2Fma: ["avx2", "fma"], rows 6, 8 x __m256 {
                zero: _mm256_setzero_ps,
                load: _mm256_loadu_ps,
                store: _mm256_storeu_ps,
                splat: |p| _mm256_broadcast_ss(&*p),
                fmadd: _mm256_fmadd_ps,
                max: _mm256_max_ps,
                mask: |v, h| _mm256_and_ps(v, _mm256_cmp_ps::<_CMP_NLE_UQ>(h, _mm256_setzero_ps())),
            }
        }

        simd_set! {
            /// AVX-512F + AVX2 + FMA; only constructed when all are detected.
            Avx512: ["avx512f", "avx2", "fma"], rows 8, 16 x __m512 {
                zero: _mm512_setzero_ps,
                load: _mm512_loadu_ps,
                store: _mm512_storeu_ps,
                splat: |p| _mm512_set1_ps(*p),
                fmadd: _mm512_fmadd_ps,
                max: _mm512_max_ps,
                mask: |v, h| _mm512_maskz_mov_ps(
                    _mm512_cmp_ps_mask::<_CMP_NLE_UQ>(h, _mm512_setzero_ps()),
                    v,
                ),
            }
        }
    }

    /// Runs `$body` with `$s` bound to the instruction set of `$kernel`
    /// (inside its [`Simd::vectorize`]); a macro, as `$body` is
    /// monomorphised for each set.
    ///
    /// # Panics
    /// If this CPU does not support `$kernel`.
    macro_rules! with_simd {
        ($kernel:expr, |$s:ident| $body:expr) => {{
            let kernel: BatchKernel = $kernel;
            let unsupported =
                || -> ! { panic!("batch kernel {kernel:?} is not supported by this CPU") };
            match kernel {
                BatchKernel::Portable => {
                    let $s = Portable;
                    $body
                }
                #[cfg(target_arch = "x86_64")]
                BatchKernel::Avx2Fma => {
                    let $s = x86::Avx2Fma::new().unwrap_or_else(|| unsupported());
                    $s.vectorize(|| $body)
                }
                #[cfg(target_arch = "x86_64")]
                BatchKernel::Avx512 => {
                    let $s = x86::Avx512::new().unwrap_or_else(|| unsupported());
                    $s.vectorize(|| $body)
                }
                #[cfg(not(target_arch = "x86_64"))]
                _ => unsupported(),
            }
        }};
    }

    /// `n` rounded up to a multiple of `lanes`.
    const fn pad(n: usize, lanes: usize) -> usize {
        n.div_ceil(lanes) * lanes
    }

    /// One layer's packed parameters for the backward pass.
    struct BackLayer {
        /// Offset of the layer within the network.
        off: usize,
        fan_in: usize,
        fan_out: usize,
        /// `fan_in` padded to the vector width.
        in_pad: usize,
        /// `W[o][i]`, rows padded to `in_pad` with zeros.
        w: Vec<f32>,
        /// `∂L/∂W`, same shape as `w` (copied from and back to `grad`).
        gw: Vec<f32>,
        /// `∂L/∂b`.
        gb: Vec<f32>,
    }

    impl BackLayer {
        /// Copies each layer's gradient from `grad` into its padded accumulators.
        fn load_all(layers: &mut [BackLayer], grad: &[f32]) {
            for l in layers {
                let (fi, fo) = (l.fan_in, l.fan_out);
                let g = &grad[l.off..l.off + fi * fo + fo];
                for (dst, src) in l.gw.chunks_exact_mut(l.in_pad).zip(g.chunks_exact(fi)) {
                    dst[..fi].copy_from_slice(src);
                }
                l.gb.copy_from_slice(&g[fi * fo..]);
            }
        }

        /// `∂L/∂W += Σ_b δ_b x_bᵀ` (rows `o`, columns `i`, summed over the
        /// block's `nb` queries) and `∂L/∂b += Σ_b δ_b`, with the block's deltas
        /// (rows of `ldd`) and layer inputs (rows of `ldx`).
        #[inline(always)]
        fn add_gradients<S: Simd>(
            &mut self,
            s: S,
            (delta, ldd): (&[f32], usize),
            (x, ldx): (&[f32], usize),
            nb: usize,
        ) {
            gemm::<S, INIT_LOAD, EPI_NONE>(
                s,
                &mut Gemm {
                    rows: self.fan_out,
                    nvecs: self.in_pad / S::LANES,
                    k: nb,
                    a: delta,
                    a_rs: 1,
                    a_ks: ldd,
                    b: x,
                    ldb: ldx,
                    c: &mut self.gw,
                    ldc: self.in_pad,
                    c2: &mut [],
                    ldc2: 0,
                    bias: &[],
                    h: &[],
                    ldh: 0,
                },
            );
            for d in delta.chunks_exact(ldd).take(nb) {
                for (g, &dv) in self.gb.iter_mut().zip(&d[..self.fan_out]) {
                    *g += dv;
                }
            }
        }

        /// Writes each layer's accumulators back to `grad` (without the padding).
        fn save_all(layers: &[BackLayer], grad: &mut [f32]) {
            for l in layers {
                let (fi, fo) = (l.fan_in, l.fan_out);
                let g = &mut grad[l.off..l.off + fi * fo + fo];
                let (gw, gb) = g.split_at_mut(fi * fo);
                for (dst, src) in gw.chunks_exact_mut(fi).zip(l.gw.chunks_exact(l.in_pad)) {
                    dst.copy_from_slice(&src[..fi]);
                }
                gb.copy_from_slice(&l.gb);
            }
        }
    }

    /// What the blocked backward pass reads (the inputs of
    /// [`Mlp::backward_batch`]; it writes `grad` and `d_inputs`).
    #[derive(Clone, Copy)]
    struct BackwardInputs<
        'a,
        const IN: usize,
        const WIDTH: usize,
        const OUT: usize,
        const HIDDEN: usize,
    > {
        params: &'a [f32],
        offset: usize,
        inputs: &'a [[f32; IN]],
        ctxs: &'a [MlpContext<WIDTH, HIDDEN>],
        d_outputs: &'a [[f32; OUT]],
    }

    impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
        BackwardInputs<'_, IN, WIDTH, OUT, HIDDEN>
    {
        /// Per-query [`Mlp::backward`] of the queries `range` (the exact
        /// fallback for non-finite parameters or activations).
        fn per_query(
            &self,
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
            range: core::ops::Range<usize>,
        ) {
            for q in range {
                Mlp::<IN, WIDTH, OUT, HIDDEN>::backward(
                    self.params,
                    self.offset,
                    &self.inputs[q],
                    &self.ctxs[q],
                    &self.d_outputs[q],
                    grad,
                    &mut d_inputs[q],
                );
            }
        }
    }

    impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
        Mlp<IN, WIDTH, OUT, HIDDEN>
    {
        /// `(layer_offset, fan_in, fan_out)` of layer `layer`.
        const fn layer_shape(layer: usize) -> (usize, usize, usize) {
            (
                Self::layer_offset(layer),
                Self::fan_in(layer),
                Self::fan_out(layer),
            )
        }

        /// The blocked forward pass; stores hidden activations when `ctxs`
        /// is non-empty (then it has one entry per query).
        ///
        /// Per block of [`BLOCK`] queries, each layer is one [`gemm`] with
        /// the queries as rows: `A` the layer's inputs (query-major, the
        /// caller's inputs for the first layer), `B = Wᵀ` packed once per
        /// call as `[fan_in][fan_out padded]`. Hidden layers go to a scratch
        /// block and, when `WIDTH` is a multiple of the vector width,
        /// straight into the contexts too (a second store); the output layer
        /// goes straight to `outputs` when `OUT` is.
        #[inline(always)]
        fn forward_impl<S: Simd>(
            s: S,
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
            ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        ) {
            let () = Self::VALID;
            assert_eq!(inputs.len(), outputs.len(), "one output per input");
            let store = !ctxs.is_empty();
            assert!(
                !store || ctxs.len() == inputs.len(),
                "one context per input"
            );
            let net = &params[offset..offset + Self::PARAM_COUNT];
            if inputs.is_empty() {
                return;
            }
            let lanes = S::LANES;
            // Per layer: Wᵀ as [fan_in][fan_out padded], then the padded bias.
            let packed: Vec<(Vec<f32>, Vec<f32>)> = (0..=HIDDEN)
                .map(|layer| {
                    let (o, fi, fo) = Self::layer_shape(layer);
                    let fo_pad = pad(fo, lanes);
                    let mut wt = vec![0.0; fi * fo_pad];
                    for (j, row) in net[o..o + fi * fo].chunks_exact(fi).enumerate() {
                        for (i, &w) in row.iter().enumerate() {
                            wt[i * fo_pad + j] = w;
                        }
                    }
                    let mut b = vec![0.0; fo_pad];
                    b[..fo].copy_from_slice(&net[o + fi * fo..o + fi * fo + fo]);
                    (wt, b)
                })
                .collect();
            let (wp, op) = (pad(WIDTH, lanes), pad(OUT, lanes));
            let hw = HIDDEN * WIDTH;
            let direct_ctx = store && WIDTH.is_multiple_of(lanes);
            let direct_out = OUT.is_multiple_of(lanes);
            let mut cur = vec![0.0f32; BLOCK * wp];
            let mut next = vec![0.0f32; BLOCK * wp];
            let mut y = vec![0.0f32; if direct_out { 0 } else { BLOCK * op }];
            let ctx_flat: &mut [f32] = bytemuck::cast_slice_mut(ctxs);
            let out_flat: &mut [f32] = outputs.as_flattened_mut();
            for (k, block) in inputs.chunks(BLOCK).enumerate() {
                let (start, nb) = (k * BLOCK, block.len());
                let ctx_block: &mut [f32] = if store {
                    &mut ctx_flat[start * hw..(start + nb) * hw]
                } else {
                    &mut []
                };
                for layer in 0..HIDDEN {
                    let (a, a_rs, fi): (&[f32], usize, usize) = if layer == 0 {
                        (block.as_flattened(), IN, IN)
                    } else {
                        (&cur, wp, WIDTH)
                    };
                    gemm::<S, INIT_BIAS, EPI_RELU>(
                        s,
                        &mut Gemm {
                            rows: nb,
                            nvecs: wp / lanes,
                            k: fi,
                            a,
                            a_rs,
                            a_ks: 1,
                            b: &packed[layer].0,
                            ldb: wp,
                            c: &mut next,
                            ldc: wp,
                            c2: if direct_ctx {
                                &mut ctx_block[layer * WIDTH..]
                            } else {
                                &mut []
                            },
                            ldc2: hw,
                            bias: &packed[layer].1,
                            h: &[],
                            ldh: 0,
                        },
                    );
                    core::mem::swap(&mut cur, &mut next);
                    if store && !direct_ctx {
                        for (ctx, h) in ctx_block.chunks_exact_mut(hw).zip(cur.chunks_exact(wp)) {
                            ctx[layer * WIDTH..(layer + 1) * WIDTH].copy_from_slice(&h[..WIDTH]);
                        }
                    }
                }
                let (c, ldc): (&mut [f32], usize) = if direct_out {
                    (&mut out_flat[start * OUT..(start + nb) * OUT], OUT)
                } else {
                    (&mut y, op)
                };
                gemm::<S, INIT_BIAS, EPI_NONE>(
                    s,
                    &mut Gemm {
                        rows: nb,
                        nvecs: op / lanes,
                        k: WIDTH,
                        a: &cur,
                        a_rs: wp,
                        a_ks: 1,
                        b: &packed[HIDDEN].0,
                        ldb: op,
                        c,
                        ldc,
                        c2: &mut [],
                        ldc2: 0,
                        bias: &packed[HIDDEN].1,
                        h: &[],
                        ldh: 0,
                    },
                );
                if !direct_out {
                    for (out, yq) in out_flat[start * OUT..(start + nb) * OUT]
                        .chunks_exact_mut(OUT)
                        .zip(y.chunks_exact(op))
                    {
                        out.copy_from_slice(&yq[..OUT]);
                    }
                }
            }
        }

        /// Dispatches to the compiled variant `kernel`.
        fn forward_dispatch(
            kernel: BatchKernel,
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
            ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        ) {
            with_simd!(kernel, |s| Self::forward_impl(
                s, params, offset, inputs, outputs, ctxs
            ));
        }

        /// [`Self::infer`] for every query of `inputs`, written to `outputs`,
        /// with the fastest [`BatchKernel`] of this CPU (within the
        /// tolerance of the [module docs](crate::mlp) of the per-query kernel).
        ///
        /// # Panics
        /// If the lengths of `inputs` and `outputs` differ or `params` is
        /// shorter than `offset + PARAM_COUNT`.
        pub fn infer_batch(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
        ) {
            Self::forward_dispatch(
                BatchKernel::detect(),
                params,
                offset,
                inputs,
                outputs,
                &mut [],
            );
        }

        /// [`Self::infer_batch`] with a chosen kernel variant.
        ///
        /// # Panics
        /// As [`Self::infer_batch`], and if `kernel` is not available.
        pub fn infer_batch_with(
            kernel: BatchKernel,
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
        ) {
            Self::forward_dispatch(kernel, params, offset, inputs, outputs, &mut []);
        }

        /// [`Self::forward`] for every query: outputs, and the contexts for
        /// [`Self::backward`] / [`Self::backward_batch`] (within the
        /// tolerance of the [module docs](crate::mlp) of the per-query kernel;
        /// the outputs are bit-identical to [`Self::infer_batch_with`] with
        /// the same kernel).
        ///
        /// # Panics
        /// If `inputs`, `outputs` and `ctxs` differ in length or `params` is
        /// shorter than `offset + PARAM_COUNT`.
        pub fn forward_batch(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
            ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        ) {
            Self::forward_batch_with(BatchKernel::detect(), params, offset, inputs, outputs, ctxs);
        }

        /// [`Self::forward_batch`] with a chosen kernel variant.
        ///
        /// # Panics
        /// As [`Self::forward_batch`], and if `kernel` is not available.
        pub fn forward_batch_with(
            kernel: BatchKernel,
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
            ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        ) {
            assert_eq!(ctxs.len(), inputs.len(), "one context per input");
            if inputs.is_empty() {
                return;
            }
            Self::forward_dispatch(kernel, params, offset, inputs, outputs, ctxs);
        }

        /// The layers of the network `net` (at `offset` in the parameter
        /// buffer) for the blocked backward pass: weights with rows padded to
        /// the vector width `lanes`, zeroed gradient accumulators.
        fn back_layers(net: &[f32], offset: usize, lanes: usize) -> Vec<BackLayer> {
            (0..=HIDDEN)
                .map(|layer| {
                    let (off, fan_in, fan_out) = Self::layer_shape(layer);
                    let in_pad = pad(fan_in, lanes);
                    let mut w = vec![0.0; fan_out * in_pad];
                    for (dst, src) in w
                        .chunks_exact_mut(in_pad)
                        .zip(net[off..off + fan_in * fan_out].chunks_exact(fan_in))
                    {
                        dst[..fan_in].copy_from_slice(src);
                    }
                    BackLayer {
                        off: offset + off,
                        fan_in,
                        fan_out,
                        in_pad,
                        w,
                        gw: vec![0.0; fan_out * in_pad],
                        gb: vec![0.0; fan_out],
                    }
                })
                .collect()
        }

        /// The padded query-major copies of a block's inputs `x_blk` (rows of
        /// `ip`) and hidden activations `h_blk` (layer `j` at `j · BLOCK · wp`,
        /// rows of `wp`), where the backward pass cannot read them in place;
        /// an empty destination (read in place) is left alone.
        #[inline(always)]
        fn pad_block(
            x_blk: &[f32],
            h_blk: &[f32],
            xin: &mut [f32],
            hs: &mut [f32],
            ip: usize,
            wp: usize,
        ) {
            for (dst, src) in xin.chunks_exact_mut(ip).zip(x_blk.chunks_exact(IN)) {
                dst[..IN].copy_from_slice(src);
            }
            let hw = HIDDEN * WIDTH;
            for (j, hj) in hs.chunks_exact_mut(BLOCK * wp).enumerate() {
                for (dst, src) in hj.chunks_exact_mut(wp).zip(h_blk.chunks_exact(hw)) {
                    dst[..WIDTH].copy_from_slice(&src[j * WIDTH..(j + 1) * WIDTH]);
                }
            }
        }

        /// The blocked backward pass (see [`Self::backward_batch`]).
        #[allow(clippy::too_many_lines)]
        #[inline(always)]
        fn backward_impl<S: Simd>(
            s: S,
            read: BackwardInputs<'_, IN, WIDTH, OUT, HIDDEN>,
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
        ) {
            let () = Self::VALID;
            let BackwardInputs {
                params,
                offset,
                inputs,
                ctxs,
                d_outputs,
            } = read;
            let n = inputs.len();
            assert!(
                ctxs.len() == n && d_outputs.len() == n && d_inputs.len() == n,
                "one context, output gradient and input gradient per input"
            );
            let net = &params[offset..offset + Self::PARAM_COUNT];
            let _ = &grad[offset..offset + Self::PARAM_COUNT];
            if n == 0 {
                return;
            }
            // A dead unit (δ = 0) times a non-finite weight or activation is
            // NaN, where the per-query kernel skips the unit: such inputs take
            // the per-query path.
            if !net.iter().fold(true, |ok, v| ok & v.is_finite()) {
                read.per_query(grad, d_inputs, 0..n);
                return;
            }
            let lanes = S::LANES;
            let (ip, wp) = (pad(IN, lanes), pad(WIDTH, lanes));
            let mut layers = Self::back_layers(net, offset, lanes);
            BackLayer::load_all(&mut layers, grad);
            // The block's inputs and hidden activations are read in place
            // when their widths are multiples of the vector width, else from
            // padded query-major copies (hidden layer j at j · BLOCK · wp);
            // the deltas of two consecutive layers live in scratch blocks.
            let hw = HIDDEN * WIDTH;
            let direct_in = IN.is_multiple_of(lanes);
            let direct_h = WIDTH.is_multiple_of(lanes);
            let in_flat = inputs.as_flattened();
            let ctx_flat: &[f32] = bytemuck::cast_slice(ctxs);
            let dy_flat = d_outputs.as_flattened();
            let mut xin = vec![0.0f32; if direct_in { 0 } else { BLOCK * ip }];
            let mut dxin = vec![0.0f32; if direct_in { 0 } else { BLOCK * ip }];
            let mut hs = vec![0.0f32; if direct_h { 0 } else { HIDDEN * BLOCK * wp }];
            let mut d_cur = vec![0.0f32; BLOCK * wp];
            let mut d_next = vec![0.0f32; BLOCK * wp];
            let mut start = 0;
            while start < n {
                let nb = BLOCK.min(n - start);
                let x_blk = &in_flat[start * IN..(start + nb) * IN];
                let h_blk = &ctx_flat[start * hw..(start + nb) * hw];
                if !x_blk
                    .iter()
                    .chain(h_blk)
                    .fold(true, |ok, v| ok & v.is_finite())
                {
                    BackLayer::save_all(&layers, grad);
                    read.per_query(grad, d_inputs, start..start + nb);
                    BackLayer::load_all(&mut layers, grad);
                    start += nb;
                    continue;
                }
                Self::pad_block(x_blk, h_blk, &mut xin, &mut hs, ip, wp);
                for layer in (0..=HIDDEN).rev() {
                    let bl = &mut layers[layer];
                    let fo = bl.fan_out;
                    let (x, ldx): (&[f32], usize) = match (layer, direct_in, direct_h) {
                        (0, true, _) => (x_blk, IN),
                        (0, false, _) => (&xin, ip),
                        (_, _, true) => (&h_blk[(layer - 1) * WIDTH..], hw),
                        _ => (&hs[(layer - 1) * BLOCK * wp..layer * BLOCK * wp], wp),
                    };
                    let (delta, ldd): (&[f32], usize) = if layer == HIDDEN {
                        (&dy_flat[start * OUT..(start + nb) * OUT], OUT)
                    } else {
                        (&d_cur, wp)
                    };
                    bl.add_gradients(s, (delta, ldd), (x, ldx), nb);
                    // δ ← (Wᵀ δ) ⊙ [h > 0], or the input gradient.
                    let (c, ldc): (&mut [f32], usize) = match (layer, direct_in) {
                        (0, true) => (
                            &mut d_inputs.as_flattened_mut()[start * IN..(start + nb) * IN],
                            IN,
                        ),
                        (0, false) => (&mut dxin, ip),
                        _ => (&mut d_next, wp),
                    };
                    let mut prod = Gemm {
                        rows: nb,
                        nvecs: bl.in_pad / lanes,
                        k: fo,
                        a: delta,
                        a_rs: ldd,
                        a_ks: 1,
                        b: &bl.w,
                        ldb: bl.in_pad,
                        c,
                        ldc,
                        c2: &mut [],
                        ldc2: 0,
                        bias: &[],
                        h: x,
                        ldh: ldx,
                    };
                    if layer == 0 {
                        gemm::<S, INIT_ZERO, EPI_NONE>(s, &mut prod);
                    } else {
                        gemm::<S, INIT_ZERO, EPI_MASK>(s, &mut prod);
                        core::mem::swap(&mut d_cur, &mut d_next);
                    }
                }
                // Padded input gradients (empty when written in place) back to their rows.
                for (dst, src) in d_inputs[start..start + nb]
                    .iter_mut()
                    .zip(dxin.chunks_exact(ip))
                {
                    dst.copy_from_slice(&src[..IN]);
                }
                start += nb;
            }
            BackLayer::save_all(&layers, grad);
        }

        /// [`Self::backward`] for every query, in order: **adds** the
        /// parameter gradients of all queries to `grad` and **writes** each
        /// query's input gradient to `d_inputs`, using the fastest
        /// [`BatchKernel`]. Every gradient element is summed over the
        /// queries 0, 1, 2, … in turn, starting from its value in `grad`,
        /// as successive [`Self::backward`] calls would, but with fused
        /// multiply–adds and no skipped dead units (within the tolerance of
        /// the [module docs](crate::mlp)); parameters or a block's activations
        /// that are not all finite take the per-query kernel, so that dead
        /// units never turn `0 · ∞` into NaN.
        ///
        /// # Panics
        /// If `inputs`, `ctxs`, `d_outputs` and `d_inputs` differ in length
        /// or `params` / `grad` is shorter than `offset + PARAM_COUNT`.
        pub fn backward_batch(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            ctxs: &[MlpContext<WIDTH, HIDDEN>],
            d_outputs: &[[f32; OUT]],
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
        ) {
            Self::backward_batch_with(
                BatchKernel::detect(),
                params,
                offset,
                inputs,
                ctxs,
                d_outputs,
                grad,
                d_inputs,
            );
        }

        /// [`Self::backward_batch`] with a chosen kernel variant.
        ///
        /// # Panics
        /// As [`Self::backward_batch`], and if `kernel` is not available.
        #[allow(clippy::too_many_arguments)] // the per-query signature plus the variant
        pub fn backward_batch_with(
            kernel: BatchKernel,
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            ctxs: &[MlpContext<WIDTH, HIDDEN>],
            d_outputs: &[[f32; OUT]],
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
        ) {
            let read = BackwardInputs {
                params,
                offset,
                inputs,
                ctxs,
                d_outputs,
            };
            with_simd!(kernel, |s| Self::backward_impl(s, read, grad, d_inputs));
        }
    }
}

#[cfg(feature = "std")]
pub use batch::BatchKernel;
