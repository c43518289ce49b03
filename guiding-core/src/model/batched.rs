//! Wavefront (batched) evaluation of the models on the CPU (`std`): one call
//! decodes the distributions of a whole batch of shading points, and one call
//! accumulates the training gradient of a whole batch of samples.
//!
//! The per-query kernels of [`super::npm`], [`super::nasg`] and [`super::df`]
//! stay the reference (and the SPIR-V path); this module computes the same
//! functions with the network run over blocks of queries:
//!
//! ```text
//! for each chunk of WAVEFRONT_CHUNK queries:
//!     x_b = encode_inputs(q_b)                 (grid gather per query, as per query)
//!     Y   = Mlp::infer_batch(X)                (blocked, SIMD over queries; FMA where available)
//!     d_b = decode(Y_b)                        (vMF / NASG mixture, or DF marginal + features)
//! ```
//!
//! Training: `Mlp::forward_batch` keeps every hidden activation, the
//! per-sample output gradients are formed as in `accumulate_gradient`, then
//! `Mlp::backward_batch` adds the parameter gradients of the chunk and each
//! sample's input gradient is scattered into the grid. Every gradient element
//! is summed over the samples in the order they are given, so the result
//! does not depend on how a caller distributes chunks over threads.
//!
//! The batched MLP may round differently from the per-query kernel (fused
//! multiply-adds, another summation order); see [`crate::mlp`] for the bound.
//! Everything else (encodings, decoders, losses) is the per-query code.
//!
//! Decode chunks live in stack arrays (no allocation): `WAVEFRONT_CHUNK · IN`
//! inputs and `WAVEFRONT_CHUNK · OUT` outputs. A gradient call allocates its
//! chunk buffers once (`TRAIN_CHUNK` rows of inputs, outputs, gradients and
//! `HIDDEN · WIDTH` activations: 256 KiB for the paper NASG network, 4 × 128)
//! and reuses them for every chunk of the batch.

use super::df::{Df, DfVertex, DF_CONDITIONAL_BINS, DF_MARGINAL_BINS, DF_MAX_BASE};
use super::mixture_model::{MixtureFamily, MixtureModel};
use super::nasg::{NASG_LOBES, NASG_OUTPUTS, NASG_SELECTION_OUTPUT};
use super::npm::{all_finite, encode_product_inputs, NPM_LOBES, NPM_OUTPUTS};
use super::{GuidingModel, QueryPoint};
use crate::encoding::grid::{grid_forward_fast, grid_forward_traced};
use crate::encoding::{grid_backward_traced, GridTrace};
use crate::factorised::{self, direction_from_square, square_from_direction};
use crate::lobe::DirectionSample;
use crate::loss::{kl_weight, Target};
use crate::math::INV_FOUR_PI;
use crate::mixture::nasg::{decode_selection, NasgMixture, NASG_RAW_PER_LOBE};
use crate::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use crate::mlp::{Mlp, MlpContext};
use crate::pdf1d::{Boundary, Pdf1d};
use crate::sample::TrainingSample;
use glam::{Vec2, Vec3};
use std::vec;
use std::vec::Vec;

/// Queries per chunk of a batched decode (inputs and outputs of one chunk
/// stay in L1).
pub const WAVEFRONT_CHUNK: usize = 64;

/// Samples per chunk of a batched gradient. Each chunk pays a fixed cost in
/// the batched MLP (the weights packed for the SIMD kernel, the gradient
/// loaded into and saved from its padded accumulators: about 4 passes over
/// the network's parameters), which a chunk of 32 samples could not amortise.
/// Measured with one thread (NPM / NASG / DF-L compact product, samples per
/// second): 32 → 593 k / 205 k / 393 k, 64 → 625 k / 199 k / 412 k,
/// 128 → 895 k / 212 k / 456 k, 256 → 930 k / 197 k / 330 k (larger chunks
/// leave L2).
pub const TRAIN_CHUNK: usize = 128;

/// The (vertex, table row) of pair `i` of [`Df::tabulate_vertices`]: row-major,
/// [`DF_MARGINAL_BINS`] rows per vertex.
#[inline]
const fn vertex_row(i: usize) -> (usize, usize) {
    (i / DF_MARGINAL_BINS, i % DF_MARGINAL_BINS)
}

/// A DF distribution tabulated per marginal bin ([`Df::tabulate_vertices`]).
pub type DfTable = factorised::FactorisedTable<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS>;
/// A [`DfTable`]'s running sums (kept by the guide cache next to its tables).
pub type DfTableSums = factorised::TableSums<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS>;

/// Encodes `queries` (at most `WAVEFRONT_CHUNK`) and runs the MLP at
/// `offset` over them: `ys[b] = MLP(encode(queries[b]))`.
fn infer_chunk<const IN: usize, const W: usize, const OUT: usize, const H: usize>(
    params: &[f32],
    grid: &crate::encoding::GridConfig,
    target: u32,
    offset: usize,
    queries: &[QueryPoint],
    xs: &mut [[f32; IN]; WAVEFRONT_CHUNK],
    ys: &mut [[f32; OUT]; WAVEFRONT_CHUNK],
) {
    let m = queries.len();
    for (x, q) in xs.iter_mut().zip(queries) {
        *x = [0.0; IN];
        let o = grid_forward_fast(params, grid, q.position(), x, 0);
        encode_product_inputs(target, q, x, o);
    }
    Mlp::<IN, W, OUT, H>::infer_batch(params, offset, &xs[..m], &mut ys[..m]);
}

/// The chunk loop of the mixture models' batched decode: each chunk of
/// [`WAVEFRONT_CHUNK`] queries is encoded, run through the network at
/// `offset` ([`infer_chunk`]) and its raw outputs decoded into `out` by
/// `decode` (a lane-parallel decoder).
#[allow(clippy::too_many_arguments)] // the model's layout plus the decoder
fn infer_and_decode<const IN: usize, const W: usize, const OUT: usize, const H: usize, T>(
    params: &[f32],
    grid: &crate::encoding::GridConfig,
    target: u32,
    offset: usize,
    queries: &[QueryPoint],
    out: &mut [T],
    decode: impl Fn(&[[f32; OUT]], &mut [T]),
) {
    let mut xs = [[0.0f32; IN]; WAVEFRONT_CHUNK];
    let mut ys = [[0.0f32; OUT]; WAVEFRONT_CHUNK];
    for (qs, os) in queries
        .chunks(WAVEFRONT_CHUNK)
        .zip(out.chunks_mut(WAVEFRONT_CHUNK))
    {
        infer_chunk::<IN, W, OUT, H>(params, grid, target, offset, qs, &mut xs, &mut ys);
        decode(&ys[..qs.len()], os);
    }
}

impl<F: MixtureFamily<OUT>, const IN: usize, const W: usize, const H: usize, const OUT: usize>
    MixtureModel<F, IN, W, H, OUT>
{
    /// [`Self::decode`] of every query, written to `out` (same length): one
    /// batched network pass per chunk (module docs), decoded lane-parallel
    /// ([`MixtureFamily::decode_batch`]).
    ///
    /// # Panics
    /// If `queries` and `out` differ in length.
    pub fn decode_batch(&self, params: &[f32], queries: &[QueryPoint], out: &mut [F::Decoded]) {
        assert_eq!(queries.len(), out.len(), "one output per query");
        if !self.fits(params) {
            for (o, q) in out.iter_mut().zip(queries) {
                *o = self.decode(params, q);
            }
            return;
        }
        infer_and_decode::<IN, W, OUT, H, _>(
            params,
            &self.grid,
            self.target,
            self.mlp_offset as usize,
            queries,
            out,
            F::decode_batch,
        );
    }

    /// The batched form of `accumulate_gradient` over `samples` (module
    /// docs); returns the summed loss. Per chunk of [`TRAIN_CHUNK`] samples,
    /// the samples with a usable weight are encoded, run forward through
    /// the network in one batched call, given their output gradients by
    /// [`MixtureFamily::output_gradients`] (which may vectorise over the
    /// chunk), taken out again if anything is not finite (as the per-query
    /// kernel does: such samples add nothing here either), run backward in
    /// one batched call and scattered into the grid.
    pub(crate) fn gradient_batch(
        &self,
        params: &[f32],
        samples: &[TrainingSample],
        grad: &mut [f32],
    ) -> f64 {
        if params.len() < self.param_count() || grad.len() < self.param_count() {
            return 0.0;
        }
        let target = self.target();
        let offset = self.mlp_offset as usize;
        let mut rows = SampleRows::new();
        let mut net = NetRows::<IN, W, OUT, H>::new();
        let mut total = 0.0f64;
        for chunk in samples.chunks(TRAIN_CHUNK) {
            // Samples with a usable weight, encoded.
            let m = rows.encode_live(params, &self.grid, self.target, chunk, &mut net.xs, |s| {
                kl_weight(s, target) != 0.0
            });
            if m == 0 {
                continue;
            }
            net.forward(params, offset, m);
            for dy in &mut net.dys[..m] {
                *dy = [0.0; OUT];
            }
            self.family.output_gradients(ChunkOutputs {
                target,
                chunk,
                live: &rows.live[..m],
                ys: &net.ys[..m],
                dys: &mut net.dys[..m],
                losses: &mut rows.losses[..m],
            });
            for k in 0..m {
                rows.ok[k] =
                    rows.losses[k].is_finite() && all_finite(&net.ys[k]) && all_finite(&net.dys[k]);
                if !rows.ok[k] {
                    net.exclude(k, &mut rows.losses[k]);
                }
            }
            net.backward(params, offset, m, grad);
            for k in 0..m {
                rows.scatter(&self.grid, chunk, k, &net.dxs[k], grad, &mut total);
            }
        }
        total
    }
}

/// Per-sample state of a training chunk: which samples are live (`live[k]`
/// indexes the chunk), their grid traces, losses and whether they are kept.
/// Heap buffers: too large for a worker's stack.
struct SampleRows {
    live: Vec<usize>,
    ok: Vec<bool>,
    losses: Vec<f32>,
    traces: Vec<GridTrace>,
}

impl SampleRows {
    fn new() -> Self {
        Self {
            live: vec![0; TRAIN_CHUNK],
            ok: vec![false; TRAIN_CHUNK],
            losses: vec![0.0; TRAIN_CHUNK],
            traces: vec![GridTrace::EMPTY; TRAIN_CHUNK],
        }
    }

    /// Encodes the valid samples of `chunk` that `keep` accepts, in order,
    /// into rows `0..m` of `xs` (and their traces); returns `m`.
    fn encode_live<const IN: usize>(
        &mut self,
        params: &[f32],
        grid: &crate::encoding::GridConfig,
        target: u32,
        chunk: &[TrainingSample],
        xs: &mut [[f32; IN]],
        keep: impl Fn(&TrainingSample) -> bool,
    ) -> usize {
        let mut m = 0;
        for (j, s) in chunk.iter().enumerate() {
            if s.validate().is_err() || !keep(s) {
                continue;
            }
            self.live[m] = j;
            xs[m] = [0.0; IN];
            let q = QueryPoint::of_sample(s);
            let o = grid_forward_traced(
                params,
                grid,
                q.position(),
                &mut xs[m],
                0,
                &mut self.traces[m],
            );
            encode_product_inputs(target, &q, &mut xs[m], o);
            m += 1;
        }
        m
    }

    /// Scatters the input gradient `dx` of row `k` into the grid and adds
    /// its loss to `total`, if the row is kept.
    fn scatter<const IN: usize>(
        &self,
        grid: &crate::encoding::GridConfig,
        chunk: &[TrainingSample],
        k: usize,
        dx: &[f32; IN],
        grad: &mut [f32],
        total: &mut f64,
    ) {
        if self.ok[k] {
            let position = chunk[self.live[k]].position();
            grid_backward_traced(grid, position, &self.traces[k], dx, 0, grad);
            *total += f64::from(self.losses[k]);
        }
    }
}

/// One network's rows over a training chunk: inputs, outputs, output and
/// input gradients, activations (heap buffers, as [`SampleRows`]).
struct NetRows<const IN: usize, const W: usize, const OUT: usize, const H: usize> {
    xs: Vec<[f32; IN]>,
    ys: Vec<[f32; OUT]>,
    dys: Vec<[f32; OUT]>,
    dxs: Vec<[f32; IN]>,
    ctxs: Vec<MlpContext<W, H>>,
}

impl<const IN: usize, const W: usize, const OUT: usize, const H: usize> NetRows<IN, W, OUT, H> {
    fn new() -> Self {
        Self {
            xs: vec![[0.0; IN]; TRAIN_CHUNK],
            ys: vec![[0.0; OUT]; TRAIN_CHUNK],
            dys: vec![[0.0; OUT]; TRAIN_CHUNK],
            dxs: vec![[0.0; IN]; TRAIN_CHUNK],
            ctxs: vec![MlpContext::ZERO; TRAIN_CHUNK],
        }
    }

    /// [`Mlp::forward_batch`] of the network at `offset` over rows `0..m`.
    fn forward(&mut self, params: &[f32], offset: usize, m: usize) {
        Mlp::<IN, W, OUT, H>::forward_batch(
            params,
            offset,
            &self.xs[..m],
            &mut self.ys[..m],
            &mut self.ctxs[..m],
        );
    }

    /// [`Mlp::backward_batch`] of the network at `offset` over rows `0..m`:
    /// parameter gradients into `grad`, input gradients into `dxs`.
    fn backward(&mut self, params: &[f32], offset: usize, m: usize, grad: &mut [f32]) {
        Mlp::<IN, W, OUT, H>::backward_batch(
            params,
            offset,
            &self.xs[..m],
            &self.ctxs[..m],
            &self.dys[..m],
            grad,
            &mut self.dxs[..m],
        );
    }

    /// Takes row `k` out after its forward pass: zero output gradient,
    /// input and activations (so `0 · NaN` cannot reach the gradient) and
    /// zero `loss`.
    fn exclude(&mut self, k: usize, loss: &mut f32) {
        self.dys[k] = [0.0; OUT];
        self.xs[k] = [0.0; IN];
        self.ctxs[k] = MlpContext::ZERO;
        *loss = 0.0;
    }
}

/// The live samples of a training chunk and their network outputs, and
/// where [`MixtureFamily::output_gradients`] writes their output gradients
/// (zeroed rows) and losses: `chunk[live[k]]` has outputs `ys[k]`.
pub struct ChunkOutputs<'a, const OUT: usize> {
    /// The model's training target.
    pub target: Target,
    /// The chunk of samples.
    pub chunk: &'a [TrainingSample],
    /// Indices into `chunk` of the live samples.
    pub live: &'a [usize],
    /// Network outputs of the live samples.
    pub ys: &'a [[f32; OUT]],
    /// Their output gradients.
    pub dys: &'a mut [[f32; OUT]],
    /// Their losses.
    pub losses: &'a mut [f32],
}

impl<const OUT: usize> ChunkOutputs<'_, OUT> {
    /// The `k`-th live sample.
    #[inline]
    #[must_use]
    pub fn sample(&self, k: usize) -> &TrainingSample {
        &self.chunk[self.live[k]]
    }
}

/// Queries decoded together by [`decode_vmf_block`]: `8 × 8 = 64` lobes,
/// a loop the vectoriser keeps (a `K = 8` lobe loop is fully unrolled first
/// and then left scalar).
const DECODE_BLOCK: usize = 8;
/// Lobes of one [`decode_vmf_block`].
const BLOCK_LOBES: usize = DECODE_BLOCK * NPM_LOBES;

/// The vMF mixtures of raw outputs (`out[i] = VmfMixture::decode(ys[i])`,
/// bit for bit), with the widest vectors this CPU runs: AVX2 only widens
/// the lanes (Rust never contracts into FMA), so every variant gives the
/// same bits.
///
/// # Panics
/// If `ys` and `out` differ in length.
pub fn decode_vmf_batch(ys: &[[f32; NPM_OUTPUTS]], out: &mut [VmfMixture<NPM_LOBES>]) {
    assert_eq!(ys.len(), out.len(), "one output per raw row");
    run_blocks::<DecodeVmf>(ys, out);
}

/// A kernel over one block of up to [`DECODE_BLOCK`] lanes, run by [`run_blocks`].
///
/// A type rather than a closure or fn item: a call through `Fn::call` is compiled as a
/// separate function without AVX2 and is not inlined into [`run_blocks_avx2`] (callgrind,
/// compact NASG vertex: 24 % more instructions per vertex than the direct call); an
/// `#[inline(always)]` associated function is inlined and compiled for AVX2.
trait BlockKernel {
    /// One lane's input.
    type In;
    /// One lane's output.
    type Out;
    /// Runs the kernel on `ins` and `outs` (up to [`DECODE_BLOCK`] lanes, as far as both go).
    fn block(ins: &[Self::In], outs: &mut [Self::Out]);
}

/// Declares a [`BlockKernel`] type that runs a block function.
macro_rules! block_kernel {
    ($(#[$doc:meta])* $name:ident: $input:ty => $output:ty, $block:ident) => {
        $(#[$doc])*
        struct $name;
        impl BlockKernel for $name {
            type In = $input;
            type Out = $output;
            #[inline(always)]
            fn block(ins: &[$input], outs: &mut [$output]) {
                $block(ins, outs)
            }
        }
    };
}

block_kernel!(
    /// [`decode_vmf_block`].
    DecodeVmf: [f32; NPM_OUTPUTS] => VmfMixture<NPM_LOBES>, decode_vmf_block
);
block_kernel!(
    /// [`decode_nasg_block`].
    DecodeNasg: [f32; NASG_OUTPUTS] => NasgMixture<NASG_LOBES>, decode_nasg_block
);

/// Runs `K` over the blocks of [`DECODE_BLOCK`] lanes of `ins` and `outs` (as far as both
/// go), compiled for AVX2 where this CPU has it: the wider vectors change no bits (Rust
/// never contracts into FMA).
#[inline(always)]
fn run_blocks<K: BlockKernel>(ins: &[K::In], outs: &mut [K::Out]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 support was just checked.
        unsafe { run_blocks_avx2::<K>(ins, outs) };
        return;
    }
    run_blocks_portable::<K>(ins, outs);
}

/// [`run_blocks`] for the target's baseline features.
#[inline(always)]
fn run_blocks_portable<K: BlockKernel>(ins: &[K::In], outs: &mut [K::Out]) {
    for (i, o) in ins.chunks(DECODE_BLOCK).zip(outs.chunks_mut(DECODE_BLOCK)) {
        K::block(i, o);
    }
}

/// [`run_blocks_portable`] compiled for AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn run_blocks_avx2<K: BlockKernel>(ins: &[K::In], outs: &mut [K::Out]) {
    run_blocks_portable::<K>(ins, outs);
}

/// The raw outputs of up to [`DECODE_BLOCK`] queries (rows of `R` values
/// per lobe), transposed lobe-major: `lanes[r][k · DECODE_BLOCK + b] =
/// ys[b][k R + r]`; lanes past `ys.len()` stay 0.
#[inline(always)]
fn transpose_block<const R: usize, const N: usize>(ys: &[[f32; N]]) -> [[f32; BLOCK_LOBES]; R] {
    let n = ys.len().min(DECODE_BLOCK);
    let mut lanes = [[0.0f32; BLOCK_LOBES]; R];
    for (b, y) in ys[..n].iter().enumerate() {
        for k in 0..BLOCK_LOBES / DECODE_BLOCK {
            for (r, lane) in lanes.iter_mut().enumerate() {
                lane[k * DECODE_BLOCK + b] = y[k * R + r];
            }
        }
    }
    lanes
}

/// The mixture weights of a block: per query, the softmax of the logits
/// (lane `raw_logits`, sanitised with `limit`), the max and the sum in lobe
/// order as [`crate::mixture::softmax`], so the same bits.
#[inline(always)]
fn block_softmax(raw_logits: &[f32; BLOCK_LOBES], limit: f32) -> [f32; BLOCK_LOBES] {
    use crate::math::{exp, sanitize};
    let mut logit = *raw_logits;
    for l in &mut logit {
        *l = sanitize(*l, limit);
    }
    let mut max = [f32::MIN; DECODE_BLOCK];
    for k in 0..BLOCK_LOBES / DECODE_BLOCK {
        for (m, &l) in max.iter_mut().zip(&logit[k * DECODE_BLOCK..]) {
            *m = m.max(l);
        }
    }
    let mut w = [0.0f32; BLOCK_LOBES];
    for (i, (wi, &l)) in w.iter_mut().zip(&logit).enumerate() {
        *wi = exp(l - max[i % DECODE_BLOCK]);
    }
    let mut sum = [0.0f32; DECODE_BLOCK];
    for k in 0..BLOCK_LOBES / DECODE_BLOCK {
        for (s, &wi) in sum.iter_mut().zip(&w[k * DECODE_BLOCK..]) {
            *s += wi;
        }
    }
    let mut inv_sum = [0.0f32; DECODE_BLOCK];
    for (v, &s) in inv_sum.iter_mut().zip(&sum) {
        *v = 1.0 / s;
    }
    for (i, wi) in w.iter_mut().enumerate() {
        *wi *= inv_sum[i % DECODE_BLOCK];
    }
    w
}

/// [`decode_vmf_batch`] compiled for the target's baseline features (the
/// variant a CPU without AVX2 runs; public so tests check both).
///
/// # Panics
/// If `ys` and `out` differ in length.
#[inline(always)]
pub fn decode_vmf_batch_portable(ys: &[[f32; NPM_OUTPUTS]], out: &mut [VmfMixture<NPM_LOBES>]) {
    assert_eq!(ys.len(), out.len(), "one output per raw row");
    run_blocks_portable::<DecodeVmf>(ys, out);
}

/// [`VmfMixture::decode`] of up to [`DECODE_BLOCK`] queries at once, the
/// same operations in the same order per lobe (so the same bits), laid out
/// lobe-major (`[k · DECODE_BLOCK + b]`) so every loop runs over 64
/// contiguous lanes; unused lanes decode zeros and are dropped.
#[inline(always)]
fn decode_vmf_block(ys: &[[f32; NPM_OUTPUTS]], out: &mut [VmfMixture<NPM_LOBES>]) {
    use crate::math::{exp, expm1_nonpositive, sanitize, sigmoid, sin_cos_turns};
    use crate::mixture::vmf::{VMF_LOG_KAPPA_MAX, VMF_LOG_KAPPA_MIN, VMF_RAW_LIMIT};
    let n = ys.len().min(DECODE_BLOCK);
    let raw = transpose_block::<VMF_RAW_PER_LOBE, NPM_OUTPUTS>(ys);
    let w = block_softmax(&raw[0], VMF_RAW_LIMIT);
    // Lobes: κ, mean, normaliser.
    let (mut kappa, mut mx, mut my, mut mz) = (
        [0.0f32; BLOCK_LOBES],
        [0.0f32; BLOCK_LOBES],
        [0.0f32; BLOCK_LOBES],
        [0.0f32; BLOCK_LOBES],
    );
    let (mut norm, mut one_minus) = ([0.0f32; BLOCK_LOBES], [0.0f32; BLOCK_LOBES]);
    for i in 0..BLOCK_LOBES {
        let r = sanitize(raw[1][i], VMF_RAW_LIMIT);
        kappa[i] = exp(r.clamp(VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX));
        let s_theta = sigmoid(sanitize(raw[2][i], VMF_RAW_LIMIT));
        let s_phi = sigmoid(sanitize(raw[3][i], VMF_RAW_LIMIT));
        let (sin_t, cos_t) = sin_cos_turns(0.5 * s_theta);
        let (sin_p, cos_p) = sin_cos_turns(s_phi);
        let (x, y, z) = (sin_t * cos_p, sin_t * sin_p, cos_t);
        let inv = 1.0 / (x * x + y * y + z * z).sqrt();
        mx[i] = x * inv;
        my[i] = y * inv;
        mz[i] = z * inv;
        let two_kappa = 2.0 * kappa[i];
        let om = -expm1_nonpositive(-two_kappa);
        one_minus[i] = om;
        norm[i] = two_kappa / om * INV_FOUR_PI;
    }
    for (b, o) in out[..n].iter_mut().enumerate() {
        for k in 0..NPM_LOBES {
            let i = k * DECODE_BLOCK + b;
            o.weight[k] = w[i];
            o.kappa[k] = kappa[i];
            o.mean_x[k] = mx[i];
            o.mean_y[k] = my[i];
            o.mean_z[k] = mz[i];
            o.norm[k] = norm[i];
            o.one_minus_e2k[k] = one_minus[i];
        }
    }
}

/// Multiplies each mixture by the clamped cosine of its normal, as
/// [`VmfMixture::product_with_clamped_cosine`] (NPM §4.2): the lobe product
/// of [`lobe_product_batch`] with the lobe `κ_c = CLAMPED_COSINE_KAPPA`
/// around the normalised normal. Every function is inlined, so a block of 8
/// mixtures (64 lobes) runs as SIMD; within a few ulp of
/// `product_with_clamped_cosine` (which goes through `ln`), and the result is
/// a valid mixture whose samples and pdfs are exact for itself. A zero
/// normal ([`crate::frame::is_no_surface`]) leaves its mixture as it is, as
/// the scalar product does.
///
/// # Panics
/// If `mixtures` and `normals` differ in length.
pub fn cosine_product_batch(mixtures: &mut [VmfMixture<NPM_LOBES>], normals: &[Vec3]) {
    assert_eq!(mixtures.len(), normals.len(), "one normal per mixture");
    run_blocks::<CosineProduct>(normals, mixtures);
}

/// Multiplies each mixture by its vMF lobe `e^{κ (a·ω − 1)}` (`lobes[i] = [a_x, a_y, a_z,
/// κ]`), renormalised, as [`VmfMixture::product_with_lobe`]: per lobe `κ' μ' = κ μ + κ_l a`,
/// weight `∝ w · norm(κ) / norm(κ') · e^{κ' − κ − κ_l}`. The exponent lies in `[−2κ_l, 0]`
/// (`κ' ≥ |κ − κ_l|`), far below `f32`'s range for a sharp lobe (an HG fit reaches
/// `κ_l ≈ 1000`), so the weights are formed in log space as the scalar product does, with
/// each mixture's largest `ln w + κ' − κ − κ_l` subtracted before `exp` (the factor cancels
/// in the normalisation); every function inlined, within a few ulp of it. Which lobes are a
/// product, and their normalised axes: [`crate::lobe::vmf::product_lobe`] (the others leave
/// their mixture as it is).
///
/// # Panics
/// If `mixtures` and `lobes` differ in length.
pub fn lobe_product_batch(mixtures: &mut [VmfMixture<NPM_LOBES>], lobes: &[[f32; 4]]) {
    assert_eq!(mixtures.len(), lobes.len(), "one lobe per mixture");
    run_blocks::<LobeProduct>(lobes, mixtures);
}

/// What one lane of a lobe-product kernel multiplies by: a unit axis and `κ`, or `None`
/// for no product.
trait ProductLobeInput {
    fn axis_and_kappa(&self) -> Option<(Vec3, f32)>;
}

impl ProductLobeInput for Vec3 {
    /// The clamped cosine of a normal (none without a surface).
    #[inline(always)]
    fn axis_and_kappa(&self) -> Option<(Vec3, f32)> {
        (!crate::frame::is_no_surface(*self)).then(|| {
            (
                crate::frame::normalize_or(*self, Vec3::Z),
                crate::mixture::vmf::CLAMPED_COSINE_KAPPA,
            )
        })
    }
}

impl ProductLobeInput for [f32; 4] {
    #[inline(always)]
    fn axis_and_kappa(&self) -> Option<(Vec3, f32)> {
        crate::lobe::vmf::product_lobe(Vec3::new(self[0], self[1], self[2]), self[3])
    }
}

/// [`lobe_product_block`] over normals (the clamped cosine).
struct CosineProduct;
impl BlockKernel for CosineProduct {
    type In = Vec3;
    type Out = VmfMixture<NPM_LOBES>;
    #[inline(always)]
    fn block(ins: &[Vec3], outs: &mut [VmfMixture<NPM_LOBES>]) {
        lobe_product_block(ins, outs);
    }
}

/// [`lobe_product_block`] over `[a_x, a_y, a_z, κ]` lobes.
struct LobeProduct;
impl BlockKernel for LobeProduct {
    type In = [f32; 4];
    type Out = VmfMixture<NPM_LOBES>;
    #[inline(always)]
    fn block(ins: &[[f32; 4]], outs: &mut [VmfMixture<NPM_LOBES>]) {
        lobe_product_block(ins, outs);
    }
}

#[inline(always)]
fn lobe_product_block<L: ProductLobeInput>(lobes: &[L], ms: &mut [VmfMixture<NPM_LOBES>]) {
    use crate::lobe::vmf::{VMF_KAPPA_MAX, VMF_KAPPA_UNIFORM};
    use crate::math::{exp, expm1_nonpositive, ln_inline};
    let n = ms.len().min(lobes.len()).min(DECODE_BLOCK);
    // Lobe-major lanes, as decode_vmf_block; `kl` the product lobe's κ (0: none).
    let mut lane = [[0.0f32; BLOCK_LOBES]; 8];
    let [w, mx, my, mz, kappa, norm, nx, ny] = &mut lane;
    let mut nz = [0.0f32; BLOCK_LOBES];
    let mut kl = [0.0f32; BLOCK_LOBES];
    let mut multiplied = [false; DECODE_BLOCK];
    for b in 0..n {
        let Some((a, k_l)) = lobes[b].axis_and_kappa() else {
            continue;
        };
        multiplied[b] = true;
        for k in 0..NPM_LOBES {
            let i = k * DECODE_BLOCK + b;
            let m = &ms[b];
            w[i] = m.weight[k];
            mx[i] = m.mean_x[k];
            my[i] = m.mean_y[k];
            mz[i] = m.mean_z[k];
            kappa[i] = m.kappa[k];
            norm[i] = m.norm[k];
            nx[i] = a.x;
            ny[i] = a.y;
            nz[i] = a.z;
            kl[i] = k_l;
        }
    }
    // out[0]: w · norm / norm', then the exponent κ' − κ − κ_l in `expo`.
    let mut out = [[0.0f32; BLOCK_LOBES]; 7];
    let mut expo = [0.0f32; BLOCK_LOBES];
    for i in 0..BLOCK_LOBES {
        let ax = mx[i] * kappa[i] + nx[i] * kl[i];
        let ay = my[i] * kappa[i] + ny[i] * kl[i];
        let az = mz[i] * kappa[i] + nz[i] * kl[i];
        let kp = (ax * ax + ay * ay + az * az).sqrt();
        // VmfLobe::new(axis, κ'): unit mean (+z if the axis vanishes), κ'
        // clamped, the normaliser 2κ'/(1 − e^{−2κ'})/4π (uniform below
        // VMF_KAPPA_UNIFORM).
        let ok = kp * kp > 1e-30 && kp.is_finite();
        let inv = if ok { 1.0 / kp } else { 0.0 };
        let kpc = kp.min(VMF_KAPPA_MAX);
        // NaN κ′ (never for finite inputs) reads as uniform too.
        let uniform = kpc < VMF_KAPPA_UNIFORM || kpc.is_nan();
        let one_minus = -expm1_nonpositive(-2.0 * kpc);
        let norm_p = if uniform {
            INV_FOUR_PI
        } else {
            2.0 * kpc / one_minus * INV_FOUR_PI
        };
        out[0][i] = norm[i] / norm_p;
        // ln w + κ' − κ − κ_l (−∞ for w = 0).
        expo[i] = if w[i] > 0.0 {
            ln_inline(w[i]) + (kpc - kappa[i] - kl[i])
        } else {
            f32::NEG_INFINITY
        };
        out[1][i] = if ok { ax * inv } else { 0.0 };
        out[2][i] = if ok { ay * inv } else { 0.0 };
        out[3][i] = if ok { az * inv } else { 1.0 };
        out[4][i] = if uniform { 0.0 } else { kpc };
        out[5][i] = norm_p;
        out[6][i] = if uniform { 0.0 } else { one_minus };
    }
    // Each mixture's largest log-weight.
    let mut top = [f32::MIN; DECODE_BLOCK];
    for k in 0..NPM_LOBES {
        for (t, &e) in top.iter_mut().zip(&expo[k * DECODE_BLOCK..]) {
            *t = t.max(e);
        }
    }
    // All weights 0 (never for a decoded mixture): nothing to subtract.
    for t in &mut top {
        if *t == f32::MIN {
            *t = 0.0;
        }
    }
    for k in 0..NPM_LOBES {
        let lanes = k * DECODE_BLOCK..(k + 1) * DECODE_BLOCK;
        for ((o, &e), &t) in out[0][lanes.clone()].iter_mut().zip(&expo[lanes]).zip(&top) {
            *o *= exp(e - t);
        }
    }
    let mut sum = [0.0f32; DECODE_BLOCK];
    for k in 0..NPM_LOBES {
        for (s, &v) in sum.iter_mut().zip(&out[0][k * DECODE_BLOCK..]) {
            *s += v;
        }
    }
    for (b, m) in ms[..n].iter_mut().enumerate() {
        if !multiplied[b] {
            continue;
        }
        // sum > 0: every weight is finite and ≥ 0, and the weighted lobe of the largest
        // exponent keeps its weight times norm / norm'.
        let inv_sum = if sum[b] > 0.0 { 1.0 / sum[b] } else { 0.0 };
        for k in 0..NPM_LOBES {
            let i = k * DECODE_BLOCK + b;
            m.weight[k] = if inv_sum > 0.0 {
                out[0][i] * inv_sum
            } else {
                1.0 / NPM_LOBES as f32
            };
            m.mean_x[k] = out[1][i];
            m.mean_y[k] = out[2][i];
            m.mean_z[k] = out[3][i];
            m.kappa[k] = out[4][i];
            m.norm[k] = out[5][i];
            m.one_minus_e2k[k] = out[6][i];
        }
    }
}

/// The NASG mixtures of raw outputs (`[8 × 6 lobe values | selection]`
/// per row), lane-parallel like [`decode_vmf_batch`]: the activations of
/// [`NasgMixture::decode`] (NASG Table 2 as read in `mixture/nasg.rs`) with
/// every transcendental function inlined — `sin_cos_turns` for the Euler
/// angles (`α = 2π s_α`, `β = π s_β`, `γ = π s_γ` in turns), `ln_inline`,
/// `ln_1p_inline`, `expm1_nonpositive` for the normaliser — so 8 mixtures
/// (64 lobes) run as SIMD. `NasgMixture::decode` goes through libm's
/// out-of-line `sincosf` / `logf` / `expm1f`: the two agree within a few
/// ulp (tested), not bit for bit.
///
/// # Panics
/// If `ys` and `out` differ in length.
pub fn decode_nasg_batch(ys: &[[f32; NASG_OUTPUTS]], out: &mut [NasgMixture<NASG_LOBES>]) {
    assert_eq!(ys.len(), out.len(), "one output per raw row");
    run_blocks::<DecodeNasg>(ys, out);
}

#[inline(always)]
fn decode_nasg_block(ys: &[[f32; NASG_OUTPUTS]], out: &mut [NasgMixture<NASG_LOBES>]) {
    use crate::lobe::nasg::{NASG_A_MAX, NASG_EPSILON, NASG_LAMBDA_MAX, NASG_LAMBDA_MIN};
    use crate::math::{
        exp, expm1_nonpositive, ln_1p_inline, ln_inline, sanitize, sigmoid, sin_cos_turns, FOUR_PI,
    };
    use crate::mixture::nasg::{
        NASG_LN_A_MAX, NASG_LN_A_MIN, NASG_LN_LAMBDA_MAX, NASG_LN_LAMBDA_MIN, NASG_RAW_LIMIT,
    };
    let n = ys.len().min(DECODE_BLOCK);
    let raw = transpose_block::<NASG_RAW_PER_LOBE, NASG_OUTPUTS>(ys);
    let w = block_softmax(&raw[0], NASG_RAW_LIMIT);
    let log_eps = 0.5 * ln_1p_inline(NASG_EPSILON) - ln_inline(FOUR_PI);
    // One row per decoded field, every entry written below (a row more, never written,
    // cost a 3.5 KiB memset per block).
    let mut f = [[0.0f32; BLOCK_LOBES]; 13];
    for i in 0..BLOCK_LOBES {
        let lambda =
            exp(sanitize(raw[1][i], NASG_RAW_LIMIT).clamp(NASG_LN_LAMBDA_MIN, NASG_LN_LAMBDA_MAX))
                .clamp(NASG_LAMBDA_MIN, NASG_LAMBDA_MAX);
        let a = exp(sanitize(raw[2][i], NASG_RAW_LIMIT).clamp(NASG_LN_A_MIN, NASG_LN_A_MAX))
            .min(NASG_A_MAX);
        let s_alpha = sigmoid(sanitize(raw[3][i], NASG_RAW_LIMIT));
        let s_beta = sigmoid(sanitize(raw[4][i], NASG_RAW_LIMIT));
        let s_gamma = sigmoid(sanitize(raw[5][i], NASG_RAW_LIMIT));
        let (sa, ca) = sin_cos_turns(s_alpha);
        let (sb, cb) = sin_cos_turns(0.5 * s_beta);
        let (sg, cg) = sin_cos_turns(0.5 * s_gamma);
        // The frame of NASG eq. 13 (`euler_frame`).
        f[0][i] = ca * cb * cg - sa * sg;
        f[1][i] = sa * cb * cg + ca * sg;
        f[2][i] = -sb * cg;
        f[3][i] = -ca * cb * sg - sa * cg;
        f[4][i] = -sa * cb * sg + ca * cg;
        f[5][i] = sb * sg;
        f[6][i] = ca * sb;
        f[7][i] = sa * sb;
        f[8][i] = cb;
        f[9][i] = lambda;
        f[10][i] = a;
        // log_norm = ln(2λ / (1 − e^{−2λ})) − ln 4π + ½ (ln(1 + ε) + ln(1 + ε + a)).
        let one_minus = -expm1_nonpositive(-2.0 * lambda);
        f[11][i] =
            ln_inline(2.0 * lambda / one_minus) + log_eps + 0.5 * ln_1p_inline(NASG_EPSILON + a);
        f[12][i] = one_minus;
    }
    for (b, o) in out[..n].iter_mut().enumerate() {
        for k in 0..NASG_LOBES {
            let i = k * DECODE_BLOCK + b;
            o.weight[k] = w[i];
            o.x_x[k] = f[0][i];
            o.x_y[k] = f[1][i];
            o.x_z[k] = f[2][i];
            o.y_x[k] = f[3][i];
            o.y_y[k] = f[4][i];
            o.y_z[k] = f[5][i];
            o.z_x[k] = f[6][i];
            o.z_y[k] = f[7][i];
            o.z_z[k] = f[8][i];
            o.lambda[k] = f[9][i];
            o.a[k] = f[10][i];
            o.epsilon[k] = NASG_EPSILON;
            o.log_norm[k] = f[11][i];
            o.one_minus_e2l[k] = f[12][i];
        }
        o.selection_probability = decode_selection(ys[b][NASG_SELECTION_OUTPUT]).0;
    }
}

impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const WIDTH: usize,
        const HIDDEN: usize,
        const CACHE_WIDTH: usize,
        const CACHE_HIDDEN: usize,
    > Df<IN_M, IN_C, IN_R, WIDTH, HIDDEN, CACHE_WIDTH, CACHE_HIDDEN>
{
    const BASE_FITS: () = assert!(IN_M <= DF_MAX_BASE, "DfVertex holds at most 64 inputs");

    /// The base input and marginal at every query (one batched marginal
    /// pass per chunk), written to `out`.
    ///
    /// # Panics
    /// If `queries` and `out` differ in length.
    pub fn decode_batch(&self, params: &[f32], queries: &[QueryPoint], out: &mut [DfVertex]) {
        let () = Self::BASE_FITS;
        assert_eq!(queries.len(), out.len(), "one output per query");
        if !self.fits(params) {
            for o in out.iter_mut() {
                *o = DfVertex {
                    base: [0.0; DF_MAX_BASE],
                    marginal: self.uniform_marginal(),
                };
            }
            return;
        }
        let mut xs = [[0.0f32; IN_M]; WAVEFRONT_CHUNK];
        let mut ys = [[0.0f32; DF_MARGINAL_BINS]; WAVEFRONT_CHUNK];
        for (qs, os) in queries
            .chunks(WAVEFRONT_CHUNK)
            .zip(out.chunks_mut(WAVEFRONT_CHUNK))
        {
            infer_chunk::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>(
                params,
                &self.grid,
                self.target,
                self.marginal_offset as usize,
                qs,
                &mut xs,
                &mut ys,
            );
            for ((o, x), y) in os.iter_mut().zip(&xs).zip(&ys) {
                o.base = [0.0; DF_MAX_BASE];
                o.base[..IN_M].copy_from_slice(x);
                o.marginal = Pdf1d::from_logits(y, self.interpolation(), Boundary::Wrap);
            }
        }
    }

    /// The frozen distribution of each vertex as a [`DfTable`]: its
    /// marginal, and as row `r` the conditional at the row's centre
    /// `ε₁ = (r + ½) / 32` (the conditional network batched over all
    /// `32 · vertices.len()` pairs). A deviation from DF, whose conditional
    /// is continuous in `ε₁`: the table holds it piecewise constant in `ε₁`
    /// (the guide cache's tabulated DF lanes; sampling and pdf of a table
    /// agree exactly, so estimators stay unbiased). A too short `params`
    /// gives uniform tables.
    ///
    /// # Panics
    /// If `vertices` and `out` differ in length.
    pub fn tabulate_vertices(&self, params: &[f32], vertices: &[DfVertex], out: &mut [DfTable]) {
        assert_eq!(vertices.len(), out.len(), "one table per vertex");
        if !self.fits(params) {
            let uniform = DfTable::from_logits(
                &[0.0; DF_MARGINAL_BINS],
                &[[0.0; DF_CONDITIONAL_BINS]; DF_MARGINAL_BINS],
                self.interpolation(),
            );
            out.fill(uniform);
            return;
        }
        for (o, v) in out.iter_mut().zip(vertices) {
            o.marginal = v.marginal;
        }
        let pairs = vertices.len() * DF_MARGINAL_BINS;
        let mut lanes = [0u32; WAVEFRONT_CHUNK];
        let mut eps1 = [0.0f32; WAVEFRONT_CHUNK];
        let mut ys = [[0.0f32; DF_CONDITIONAL_BINS]; WAVEFRONT_CHUNK];
        let mut start = 0;
        while start < pairs {
            let m = (pairs - start).min(WAVEFRONT_CHUNK);
            for b in 0..m {
                let (v, r) = vertex_row(start + b);
                lanes[b] = v as u32;
                eps1[b] = (r as f32 + 0.5) / DF_MARGINAL_BINS as f32;
            }
            self.conditional_chunk(params, vertices, &lanes[..m], &eps1[..m], &mut ys);
            for (b, y) in ys[..m].iter().enumerate() {
                let (v, r) = vertex_row(start + b);
                out[v].conditionals[r] =
                    Pdf1d::from_logits(y, self.interpolation(), Boundary::Clamp);
            }
            start += m;
        }
    }

    /// Conditional logits at `(vertex, ε₁)` pairs, batched: `ys[b] =
    /// MLP_c([base(vertices[lanes[b]]) | TW(eps1[b])])`.
    fn conditional_chunk(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        eps1: &[f32],
        ys: &mut [[f32; DF_CONDITIONAL_BINS]; WAVEFRONT_CHUNK],
    ) {
        let mut xs = [[0.0f32; IN_C]; WAVEFRONT_CHUNK];
        let m = lanes.len();
        for b in 0..m {
            xs[b] = Self::conditional_input(&Self::base_of(&vertices[lanes[b] as usize]), eps1[b]);
        }
        Mlp::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::infer_batch(
            params,
            self.conditional_offset as usize,
            &xs[..m],
            &mut ys[..m],
        );
    }

    /// [`VertexModel::sample_vertex`](super::df::VertexModel::sample_vertex) for `out[b]` = a sample of vertex
    /// `vertices[lanes[b]]` with `u[b]`, the conditional network batched
    /// over the lanes.
    ///
    /// # Panics
    /// If `lanes`, `u` and `out` differ in length or a lane is out of range.
    pub fn sample_vertices(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        u: &[Vec2],
        out: &mut [DirectionSample],
    ) {
        assert!(lanes.len() == u.len() && lanes.len() == out.len());
        if !self.fits(params) {
            for (o, &ub) in out.iter_mut().zip(u) {
                *o = DirectionSample {
                    direction: direction_from_square(ub),
                    pdf: INV_FOUR_PI,
                };
            }
            return;
        }
        self.for_each_conditional(
            params,
            vertices,
            lanes,
            |i| {
                let (e1, p1) =
                    factorised::sample_marginal(&vertices[lanes[i] as usize].marginal, u[i].x);
                (e1, (e1, p1))
            },
            |i, (e1, p1), conditional| {
                let v = &vertices[lanes[i] as usize];
                out[i] = self.finish_sample(params, v, e1, p1, conditional, u[i].y);
            },
        );
    }

    /// [`VertexModel::pdf_vertex`](super::df::VertexModel::pdf_vertex) for `out[b]` = the density of `directions[b]` at
    /// vertex `vertices[lanes[b]]`, the conditional network batched over the
    /// lanes.
    ///
    /// # Panics
    /// If `lanes`, `directions` and `out` differ in length or a lane is out
    /// of range.
    pub fn pdf_vertices(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        directions: &[Vec3],
        out: &mut [f32],
    ) {
        assert!(lanes.len() == directions.len() && lanes.len() == out.len());
        if !self.fits(params) {
            out.fill(INV_FOUR_PI);
            return;
        }
        self.for_each_conditional(
            params,
            vertices,
            lanes,
            |i| (square_from_direction(directions[i]).x, ()),
            |i, (), conditional| {
                let marginal = &vertices[lanes[i] as usize].marginal;
                out[i] = factorised::pdf(marginal, conditional, directions[i]);
            },
        );
    }

    /// The conditional density at `(vertices[lanes[i]], ε₁)` for every lane
    /// `i`, the network batched over chunks of [`WAVEFRONT_CHUNK`] lanes:
    /// `prepare(i)` gives lane `i`'s `ε₁` and a value handed on to
    /// `finish(i, value, conditional)`.
    fn for_each_conditional<T: Copy + Default>(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        prepare: impl Fn(usize) -> (f32, T),
        mut finish: impl FnMut(usize, T, &Pdf1d<DF_CONDITIONAL_BINS>),
    ) {
        let mut e1 = [0.0f32; WAVEFRONT_CHUNK];
        let mut values = [T::default(); WAVEFRONT_CHUNK];
        let mut ys = [[0.0f32; DF_CONDITIONAL_BINS]; WAVEFRONT_CHUNK];
        for (c, ls) in lanes.chunks(WAVEFRONT_CHUNK).enumerate() {
            let start = c * WAVEFRONT_CHUNK;
            for b in 0..ls.len() {
                (e1[b], values[b]) = prepare(start + b);
            }
            self.conditional_chunk(params, vertices, ls, &e1[..ls.len()], &mut ys);
            for b in 0..ls.len() {
                let conditional = Pdf1d::from_logits(&ys[b], self.interpolation(), Boundary::Clamp);
                finish(start + b, values[b], &conditional);
            }
        }
    }

    /// The batched form of DF's `accumulate_gradient` (module docs): the
    /// cache, marginal and conditional networks each run forward and
    /// backward over the chunk; the guide term is skipped where its weight
    /// is zero and a sample the per-query kernel would reject (invalid,
    /// non-finite output or gradient) adds nothing. Returns the summed loss.
    pub(crate) fn gradient_batch(
        &self,
        params: &[f32],
        samples: &[TrainingSample],
        grad: &mut [f32],
    ) -> f64 {
        let count = self.param_count();
        if params.len() < count || grad.len() < count {
            return 0.0;
        }
        let (off_m, off_c, off_r) = (
            self.marginal_offset as usize,
            self.conditional_offset as usize,
            self.cache_offset as usize,
        );
        let mut rows = SampleRows::new();
        let mut base = NetRows::<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>::new();
        let mut cond = NetRows::<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>::new();
        let mut cache = NetRows::<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>::new();
        let g = self.grid.output_dims();
        let mut total = 0.0f64;
        for chunk in samples.chunks(TRAIN_CHUNK) {
            let m = rows.encode_live(params, &self.grid, self.target, chunk, &mut base.xs, |_| {
                true
            });
            if m == 0 {
                continue;
            }
            for k in 0..m {
                let wi = chunk[rows.live[k]].wi();
                cache.xs[k] = self.cache_input(&base.xs[k], wi);
                cond.xs[k] = Self::conditional_input(&base.xs[k], square_from_direction(wi).x);
            }
            cache.forward(params, off_r, m);
            base.forward(params, off_m, m);
            cond.forward(params, off_c, m);
            self.chunk_output_gradients(chunk, m, &mut rows, &mut base, &mut cond, &mut cache);
            base.backward(params, off_m, m, grad);
            cond.backward(params, off_c, m, grad);
            cache.backward(params, off_r, m, grad);
            for k in 0..m {
                // d_base = marginal + conditional + cache input gradients, in
                // the per-query kernel's order.
                let mut d = base.dxs[k];
                for (di, &dc) in d.iter_mut().zip(&cond.dxs[k]) {
                    *di += dc;
                }
                for (di, &dr) in d.iter_mut().zip(&cache.dxs[k]).take(g) {
                    *di += dr;
                }
                rows.scatter(&self.grid, chunk, k, &d, grad, &mut total);
            }
        }
        total
    }

    /// Every live sample's loss and output gradients ([`Self::output_gradients`]);
    /// a sample whose guide term is skipped keeps no marginal or conditional
    /// rows, one with anything non-finite no rows at all.
    fn chunk_output_gradients(
        &self,
        chunk: &[TrainingSample],
        m: usize,
        rows: &mut SampleRows,
        base: &mut NetRows<IN_M, WIDTH, DF_MARGINAL_BINS, HIDDEN>,
        cond: &mut NetRows<IN_C, WIDTH, DF_CONDITIONAL_BINS, HIDDEN>,
        cache: &mut NetRows<IN_R, CACHE_WIDTH, 3, CACHE_HIDDEN>,
    ) {
        let lambda_c = self.cache_weight();
        for k in 0..m {
            let (loss, finite, guided) = self.output_gradients(
                &chunk[rows.live[k]],
                lambda_c,
                (&cache.ys[k], &base.ys[k], &cond.ys[k]),
                (&mut cache.dys[k], &mut base.dys[k], &mut cond.dys[k]),
            );
            if !guided {
                // The per-query kernel never runs these networks here.
                base.xs[k] = [0.0; IN_M];
                cond.xs[k] = [0.0; IN_C];
                base.ctxs[k] = MlpContext::ZERO;
                cond.ctxs[k] = MlpContext::ZERO;
            }
            rows.ok[k] = finite
                && loss.is_finite()
                && all_finite(&cache.dys[k])
                && all_finite(&base.dys[k])
                && all_finite(&cond.dys[k]);
            if rows.ok[k] {
                rows.losses[k] = loss;
            } else {
                cache.exclude(k, &mut rows.losses[k]);
                base.exclude(k, &mut 0.0);
                cond.exclude(k, &mut 0.0);
            }
        }
    }

    /// One sample's loss and output gradients, as the per-query kernel forms them: the
    /// cache's relative L2 (weight `lambda_c`, [`Self::cache_weight`]) on the softplus of `yr`, and `−w ln q(ωᵢ)` through
    /// the marginal and conditional outputs when the guide weight `w` is not 0. Returns the
    /// loss, whether the outputs it read were finite, and whether the guide's networks ran
    /// (`w ≠ 0`).
    #[inline]
    #[allow(clippy::type_complexity)] // the three networks' outputs and gradients
    fn output_gradients(
        &self,
        s: &TrainingSample,
        lambda_c: f32,
        (yr, ym, yc): (
            &[f32; 3],
            &[f32; DF_MARGINAL_BINS],
            &[f32; DF_CONDITIONAL_BINS],
        ),
        (dr, dm, dc): (
            &mut [f32; 3],
            &mut [f32; DF_MARGINAL_BINS],
            &mut [f32; DF_CONDITIONAL_BINS],
        ),
    ) -> (f32, bool, bool) {
        use super::df::{guide_weight, softplus, DfWeightSource};
        use crate::loss::relative_l2;
        let mut pred = [0.0f32; 3];
        let mut dpred = [0.0f32; 3];
        for c in 0..3 {
            (pred[c], dpred[c]) = softplus(yr[c]);
        }
        let (loss_r, dl) = relative_l2(pred, s.radiance);
        for c in 0..3 {
            dr[c] = lambda_c * dl[c] * dpred[c];
        }
        let mut loss = lambda_c * loss_r;
        let mut finite = all_finite(yr);
        let l = match self.weight_source() {
            DfWeightSource::Cache => pred,
            DfWeightSource::Sample => s.radiance,
        };
        let w = guide_weight(l, s, self.target());
        *dm = [0.0; DF_MARGINAL_BINS];
        *dc = [0.0; DF_CONDITIONAL_BINS];
        if w == 0.0 {
            return (loss, finite, false);
        }
        finite = finite && all_finite(ym) && all_finite(yc);
        let log_q = factorised::grad_log_pdf(ym, yc, self.interpolation(), s.wi(), dm, dc);
        loss += -w * log_q;
        for d in dm.iter_mut() {
            *d *= -w;
        }
        for d in dc.iter_mut() {
            *d *= -w;
        }
        (loss, finite, true)
    }
}
