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
//! Every pre-activation is summed in one fixed order, starting from the
//! bias: `((b + w₀x₀) + w₁x₁) + … + w_{n−1}x_{n−1}`, with a separate multiply
//! and add (Rust never contracts them into an FMA). [`Mlp::forward`],
//! [`Mlp::infer`] and every batched CPU kernel follow this order, so on the
//! CPU they are **bit-identical**. A GPU driver may contract `a·b + c` into
//! an FMA, which changes each term's rounding (well within the forward error
//! bound `γ_n Σ|wᵢxᵢ|`, `γ_n = nε/(1 − nε)`).
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
/// Queries are processed in blocks of `B`, transposed so that the `B` values
/// of one neuron are contiguous; each layer is a small matrix product whose
/// innermost loop runs over the block (`acc[b] += w · x[i][b]`) with one
/// weight broadcast across the block and four weight rows in flight at once,
/// which LLVM turns into SIMD over queries. The backward pass vectorises over
/// the neurons of one query instead (`dx += W[o] · δ_o`, `∇W[o] += δ_o x`)
/// and keeps each gradient row hot while a block of queries updates it.
/// Each query's sums keep the per-query order, so the results are
/// bit-identical to [`Mlp::infer`] / [`Mlp::forward`] / [`Mlp::backward`],
/// whichever instruction set runs.
#[cfg(feature = "std")]
mod batch {
    use super::{relu, Mlp, MlpContext};

    /// Which compiled variant of the batch kernels runs.
    ///
    /// Both variants are the same portable Rust, compiled for the target's
    /// baseline features (SSE2 on x86-64) or, via `#[target_feature]` and
    /// runtime detection, for AVX2, with block sizes fitted to the register
    /// file. They produce bit-identical results (no FMA, same summation
    /// order).
    ///
    /// There is deliberately no AVX-512 variant: on the target CPU (AMD Zen
    /// 4, which splits 512-bit operations into two 256-bit halves) it
    /// measured no faster than AVX2 with 16-query blocks and slower with
    /// 32-query blocks (whose transposes compiled to gathers and scatters), and
    /// the `avx512f` target feature needs Rust ≥ 1.89, above this
    /// workspace's 1.85. FMA is not used either: Zen 4 issues two multiplies
    /// and two adds per cycle, the same peak as two FMAs, and FMA would break
    /// bit-identity with the per-query kernel.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum BatchKernel {
        /// Baseline target features (SSE2 on x86-64); forward blocks of 8
        /// queries × 4 rows, backward blocks of 16 queries.
        Portable,
        /// AVX2 (x86 only); forward blocks of 16 queries × 4 rows, backward
        /// blocks of 16 queries.
        Avx2,
    }

    impl BatchKernel {
        /// Every variant, fastest last.
        pub const ALL: [Self; 2] = [Self::Portable, Self::Avx2];

        /// Whether this CPU can run the variant.
        #[must_use]
        pub fn is_available(self) -> bool {
            match self {
                Self::Portable => true,
                #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
                Self::Avx2 => std::is_x86_feature_detected!("avx2"),
                #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
                _ => false,
            }
        }

        /// The fastest available variant (AVX2, else portable).
        #[must_use]
        pub fn detect() -> Self {
            if Self::Avx2.is_available() {
                Self::Avx2
            } else {
                Self::Portable
            }
        }
    }

    /// Largest block of queries of the backward pass.
    const MAX_BLOCK: usize = 16;

    /// Rows of the weight matrix processed together by [`dense_block`].
    const ROWS: usize = 4;

    /// `y = act(W x + b)` over a block of `B` queries (`x[i][b]`, `y[o][b]`),
    /// `layer` = weights `[O][I]` then biases `[O]`. Four output rows at once
    /// (written out by hand: LLVM does not reliably unroll a generic row
    /// loop), so one load of `x[i]` feeds four broadcast multiply–adds and
    /// four independent accumulator chains hide the add latency.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops over several arrays vectorise best
    fn dense_block<const I: usize, const O: usize, const B: usize, const RELU: bool>(
        layer: &[f32],
        x: &[[f32; B]; I],
        y: &mut [[f32; B]; O],
    ) {
        let (weights, biases) = layer.split_at(O * I);
        let row = |j: usize| -> &[f32; I] {
            weights[j * I..(j + 1) * I]
                .try_into()
                .unwrap_or_else(|_| unreachable!())
        };
        let act = |a: f32| if RELU { relu(a) } else { a };
        let mut j = 0;
        while j + ROWS <= O {
            let (r0, r1, r2, r3) = (row(j), row(j + 1), row(j + 2), row(j + 3));
            let mut a0 = [biases[j]; B];
            let mut a1 = [biases[j + 1]; B];
            let mut a2 = [biases[j + 2]; B];
            let mut a3 = [biases[j + 3]; B];
            for i in 0..I {
                let xi = &x[i];
                let (w0, w1, w2, w3) = (r0[i], r1[i], r2[i], r3[i]);
                for b in 0..B {
                    a0[b] += w0 * xi[b];
                    a1[b] += w1 * xi[b];
                    a2[b] += w2 * xi[b];
                    a3[b] += w3 * xi[b];
                }
            }
            for b in 0..B {
                y[j][b] = act(a0[b]);
                y[j + 1][b] = act(a1[b]);
                y[j + 2][b] = act(a2[b]);
                y[j + 3][b] = act(a3[b]);
            }
            j += ROWS;
        }
        while j < O {
            let r = row(j);
            let mut a = [biases[j]; B];
            for i in 0..I {
                let (w, xi) = (r[i], &x[i]);
                for b in 0..B {
                    a[b] += w * xi[b];
                }
            }
            for b in 0..B {
                y[j][b] = act(a[b]);
            }
            j += 1;
        }
    }

    /// `dx = Wᵀ dy` for `W` row-major `[O][I]`, skipping zero `dy[o]`; the
    /// per-query order of [`super::dense_backward`], vectorised over `i`
    /// with the accumulators in a local array (kept in registers). The rows
    /// with `dy[o] ≠ 0` are listed first (branch-free), so the ~50 % dead
    /// ReLUs cost no mispredicted branches.
    #[inline(always)]
    fn transpose_mul<const I: usize, const O: usize>(
        weights: &[f32],
        dy: &[f32; O],
        dx: &mut [f32; I],
    ) {
        let mut live = [0usize; O];
        let mut n = 0;
        for (o, &d) in dy.iter().enumerate() {
            live[n] = o;
            n += usize::from(d != 0.0);
        }
        let mut acc = [0.0f32; I];
        for &o in &live[..n] {
            let d = dy[o];
            let row = &weights[o * I..(o + 1) * I];
            for (a, &w) in acc.iter_mut().zip(row) {
                *a += w * d;
            }
        }
        *dx = acc;
    }

    /// `∂L/∂W += Σ_b dy_b x_bᵀ`, `∂L/∂b += Σ_b dy_b` over the queries of a
    /// block (at most [`MAX_BLOCK`]), each gradient element summed over `b`
    /// in increasing order (the order of successive per-query
    /// [`Mlp::backward`] calls); zero `dy` are skipped as there (listed out
    /// first, branch-free). Each gradient row is held in a local array while
    /// the block updates it.
    #[inline(always)]
    fn accumulate_layer<const I: usize, const O: usize>(
        grad: &mut [f32],
        dy: &[[f32; O]],
        x: &[[f32; I]],
    ) {
        let (gw, gb) = grad.split_at_mut(O * I);
        debug_assert!(dy.len() <= MAX_BLOCK && x.len() == dy.len());
        let mut live = [0usize; MAX_BLOCK];
        for (o, (grow, gbias)) in gw.chunks_exact_mut(I).zip(gb).enumerate() {
            let mut n = 0;
            for (b, dyb) in dy.iter().enumerate() {
                live[n] = b;
                n += usize::from(dyb[o] != 0.0);
            }
            let mut acc: [f32; I] = (&*grow).try_into().unwrap_or_else(|_| unreachable!());
            let mut bias = *gbias;
            for &b in &live[..n] {
                let d = dy[b][o];
                bias += d;
                for (g, &xv) in acc.iter_mut().zip(&x[b]) {
                    *g += d * xv;
                }
            }
            grow.copy_from_slice(&acc);
            *gbias = bias;
        }
    }

    /// `delta[j] = 0` where the ReLU output `h[j]` is not positive.
    #[inline(always)]
    fn mask<const N: usize>(delta: &mut [f32; N], h: &[f32; N]) {
        for (d, &hv) in delta.iter_mut().zip(h) {
            if hv <= 0.0 {
                *d = 0.0;
            }
        }
    }

    /// Copies the transposed block `h[j][b]` into `ctxs[b].hidden[layer]`.
    #[inline(always)]
    fn store_hidden<const WIDTH: usize, const HIDDEN: usize, const B: usize>(
        h: &[[f32; B]; WIDTH],
        ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        layer: usize,
    ) {
        for (b, ctx) in ctxs.iter_mut().enumerate() {
            for (dst, src) in ctx.hidden[layer].iter_mut().zip(h) {
                *dst = src[b];
            }
        }
    }

    impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
        Mlp<IN, WIDTH, OUT, HIDDEN>
    {
        /// The blocked forward pass; stores hidden activations when `ctxs`
        /// is non-empty (then it has one entry per query).
        #[inline(always)]
        fn forward_blocked<const B: usize>(
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
            let mut x = [[0.0f32; B]; IN];
            let mut ha = [[0.0f32; B]; WIDTH];
            let mut hb = [[0.0f32; B]; WIDTH];
            let mut y = [[0.0f32; B]; OUT];
            for (start, block) in inputs.chunks(B).enumerate().map(|(k, c)| (k * B, c)) {
                let n = block.len();
                if n < B {
                    x = [[0.0; B]; IN];
                }
                for (b, q) in block.iter().enumerate() {
                    for (xi, &v) in x.iter_mut().zip(q) {
                        xi[b] = v;
                    }
                }
                let (mut cur, mut next) = (&mut ha, &mut hb);
                dense_block::<IN, WIDTH, B, true>(&net[..Self::FIRST_LAYER_PARAMS], &x, cur);
                if store {
                    store_hidden(cur, &mut ctxs[start..start + n], 0);
                }
                for l in 1..HIDDEN {
                    let o = Self::layer_offset(l);
                    dense_block::<WIDTH, WIDTH, B, true>(
                        &net[o..o + Self::HIDDEN_LAYER_PARAMS],
                        cur,
                        next,
                    );
                    core::mem::swap(&mut cur, &mut next);
                    if store {
                        store_hidden(cur, &mut ctxs[start..start + n], l);
                    }
                }
                dense_block::<WIDTH, OUT, B, false>(&net[Self::OUTPUT_LAYER_OFFSET..], cur, &mut y);
                for (b, out) in outputs[start..start + n].iter_mut().enumerate() {
                    for (dst, src) in out.iter_mut().zip(&y) {
                        *dst = src[b];
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
            assert!(
                kernel.is_available(),
                "batch kernel {kernel:?} is not supported by this CPU"
            );
            match kernel {
                BatchKernel::Portable => {
                    Self::forward_blocked::<8>(params, offset, inputs, outputs, ctxs);
                }
                #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
                // SAFETY: AVX2 support was checked above.
                BatchKernel::Avx2 => unsafe {
                    Self::forward_avx2(params, offset, inputs, outputs, ctxs);
                },
                #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
                _ => unreachable!(),
            }
        }

        /// [`Self::forward_blocked`] compiled for AVX2.
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        ///
        /// # Safety
        /// The CPU must support AVX2.
        #[target_feature(enable = "avx2")]
        unsafe fn forward_avx2(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            outputs: &mut [[f32; OUT]],
            ctxs: &mut [MlpContext<WIDTH, HIDDEN>],
        ) {
            Self::forward_blocked::<16>(params, offset, inputs, outputs, ctxs);
        }

        /// [`Self::infer`] for every query of `inputs`, written to `outputs`,
        /// with the fastest [`BatchKernel`] of this CPU. Bit-identical to the
        /// per-query kernel.
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
        /// [`Self::backward`] / [`Self::backward_batch`]. Bit-identical to the
        /// per-query kernel.
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

        /// The blocked backward pass (see [`Self::backward_batch`]).
        #[inline(always)]
        fn backward_blocked<const B: usize>(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            ctxs: &[MlpContext<WIDTH, HIDDEN>],
            d_outputs: &[[f32; OUT]],
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
        ) {
            let () = Self::VALID;
            let n = inputs.len();
            assert!(
                ctxs.len() == n && d_outputs.len() == n && d_inputs.len() == n,
                "one context, output gradient and input gradient per input"
            );
            let net = &params[offset..offset + Self::PARAM_COUNT];
            let g = &mut grad[offset..offset + Self::PARAM_COUNT];
            let w_out = &net[Self::OUTPUT_LAYER_OFFSET..Self::OUTPUT_LAYER_OFFSET + OUT * WIDTH];
            // deltas[l][b] = ∂L/∂(pre-activation of hidden layer l), query b.
            let mut deltas = [[[0.0f32; WIDTH]; B]; HIDDEN];
            let mut xs = [[0.0f32; WIDTH]; B];
            let mut start = 0;
            while start < n {
                let m = B.min(n - start);
                let block = start..start + m;
                // 1. Deltas of every layer, query by query, top-down.
                for (b, q) in block.clone().enumerate() {
                    let ctx = &ctxs[q];
                    transpose_mul(w_out, &d_outputs[q], &mut deltas[HIDDEN - 1][b]);
                    mask(&mut deltas[HIDDEN - 1][b], &ctx.hidden[HIDDEN - 1]);
                    for l in (1..HIDDEN).rev() {
                        let (lower, upper) = deltas.split_at_mut(l);
                        let o = Self::layer_offset(l);
                        transpose_mul(
                            &net[o..o + WIDTH * WIDTH],
                            &upper[0][b],
                            &mut lower[l - 1][b],
                        );
                        mask(&mut lower[l - 1][b], &ctx.hidden[l - 1]);
                    }
                    transpose_mul(&net[..WIDTH * IN], &deltas[0][b], &mut d_inputs[q]);
                }
                // 2. Parameter gradients, layer by layer, each gradient row
                //    updated by the whole block while it is hot.
                for (x, ctx) in xs.iter_mut().zip(&ctxs[block.clone()]) {
                    *x = ctx.hidden[HIDDEN - 1];
                }
                accumulate_layer::<WIDTH, OUT>(
                    &mut g[Self::OUTPUT_LAYER_OFFSET..],
                    &d_outputs[block.clone()],
                    &xs[..m],
                );
                for l in (1..HIDDEN).rev() {
                    for (x, ctx) in xs.iter_mut().zip(&ctxs[block.clone()]) {
                        *x = ctx.hidden[l - 1];
                    }
                    let o = Self::layer_offset(l);
                    accumulate_layer::<WIDTH, WIDTH>(
                        &mut g[o..o + Self::HIDDEN_LAYER_PARAMS],
                        &deltas[l][..m],
                        &xs[..m],
                    );
                }
                accumulate_layer::<IN, WIDTH>(
                    &mut g[..Self::FIRST_LAYER_PARAMS],
                    &deltas[0][..m],
                    &inputs[block],
                );
                start += m;
            }
        }

        /// [`Self::backward_blocked`] compiled for AVX2.
        ///
        /// # Safety
        /// The CPU must support AVX2.
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        #[target_feature(enable = "avx2")]
        unsafe fn backward_avx2(
            params: &[f32],
            offset: usize,
            inputs: &[[f32; IN]],
            ctxs: &[MlpContext<WIDTH, HIDDEN>],
            d_outputs: &[[f32; OUT]],
            grad: &mut [f32],
            d_inputs: &mut [[f32; IN]],
        ) {
            Self::backward_blocked::<MAX_BLOCK>(
                params, offset, inputs, ctxs, d_outputs, grad, d_inputs,
            );
        }

        /// [`Self::backward`] for every query, in order: **adds** the
        /// parameter gradients of all queries to `grad` and **writes** each
        /// query's input gradient to `d_inputs`, using the fastest
        /// [`BatchKernel`]. Bit-identical to calling [`Self::backward`] for
        /// query 0, 1, 2, … in turn (every gradient element is summed over
        /// the queries in that order); the blocking only keeps a gradient row
        /// in cache while a block of 16 queries updates it.
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
            assert!(
                kernel.is_available(),
                "batch kernel {kernel:?} is not supported by this CPU"
            );
            match kernel {
                BatchKernel::Portable => Self::backward_blocked::<MAX_BLOCK>(
                    params, offset, inputs, ctxs, d_outputs, grad, d_inputs,
                ),
                #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
                // SAFETY: AVX2 support was checked above.
                BatchKernel::Avx2 => unsafe {
                    Self::backward_avx2(params, offset, inputs, ctxs, d_outputs, grad, d_inputs);
                },
                #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
                _ => unreachable!(),
            }
        }
    }
}

#[cfg(feature = "std")]
pub use batch::BatchKernel;
