//! One MLP size's inference and training pass over a batch of queries, one
//! thread: the per-query kernels (what the shaders run, the baseline) and
//! every available [`BatchKernel`].
//!
//! Flops: `2 · MACS` per query for a forward pass and `2 · 2 · MACS` more for
//! the backward (input and parameter gradients), so `6 · MACS` per training
//! query.

use crate::inputs::{symmetric_arrays, BATCH};
use guiding_core::mlp::{BatchKernel, Mlp, MlpContext};
use std::hint::black_box;

/// A batch of [`BATCH`] queries through `Mlp<IN, WIDTH, OUT, HIDDEN>`, with
/// its parameters and every buffer of a training pass.
pub struct MlpWorkload<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize> {
    params: Vec<f32>,
    xs: Vec<[f32; IN]>,
    dys: Vec<[f32; OUT]>,
    ys: Vec<[f32; OUT]>,
    ctxs: Vec<MlpContext<WIDTH, HIDDEN>>,
    dxs: Vec<[f32; IN]>,
    grad: Vec<f32>,
}

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize>
    MlpWorkload<IN, WIDTH, OUT, HIDDEN>
{
    /// Multiply–adds of one forward pass.
    pub const MACS: usize = Mlp::<IN, WIDTH, OUT, HIDDEN>::MACS;
    /// Flops of one query's inference.
    pub const INFER_FLOPS: usize = 2 * Self::MACS;
    /// Flops of one query's training pass (forward + backward).
    pub const TRAIN_FLOPS: usize = 6 * Self::MACS;

    /// Initialised parameters plus a small perturbation (so the biases and
    /// the output layer have some size and the ReLUs are not all dead),
    /// inputs and output gradients uniform in `[−1, 1)`.
    #[must_use]
    pub fn new() -> Self {
        let mut params = vec![0.0; Mlp::<IN, WIDTH, OUT, HIDDEN>::PARAM_COUNT];
        Mlp::<IN, WIDTH, OUT, HIDDEN>::init(&mut params, 0, 1);
        for (k, p) in params.iter_mut().enumerate() {
            *p += 0.01 * ((k % 7) as f32 - 3.0);
        }
        Self {
            grad: vec![0.0; params.len()],
            params,
            xs: symmetric_arrays(3, BATCH),
            dys: symmetric_arrays(5, BATCH),
            ys: vec![[0.0; OUT]; BATCH],
            ctxs: vec![MlpContext::ZERO; BATCH],
            dxs: vec![[0.0; IN]; BATCH],
        }
    }

    /// `Mlp<IN,WIDTH,OUT,HIDDEN>`.
    #[must_use]
    pub fn name() -> String {
        format!("Mlp<{IN},{WIDTH},{OUT},{HIDDEN}>")
    }

    /// The per-query kernel (`None`) and every batch kernel this CPU runs.
    pub fn kernels() -> impl Iterator<Item = Option<BatchKernel>> {
        core::iter::once(None).chain(
            BatchKernel::ALL
                .into_iter()
                .filter(|k| k.is_available())
                .map(Some),
        )
    }

    /// `per-query` or the batch kernel's name.
    #[must_use]
    pub fn label(kernel: Option<BatchKernel>) -> String {
        kernel.map_or_else(|| String::from("per-query"), |k| format!("{k:?}"))
    }

    /// Inference of the whole batch: [`Mlp::infer`] per query (`None`) or
    /// [`Mlp::infer_batch_with`] the kernel.
    pub fn infer(&mut self, kernel: Option<BatchKernel>) {
        match kernel {
            None => {
                for (x, y) in self.xs.iter().zip(self.ys.iter_mut()) {
                    *y = Mlp::<IN, WIDTH, OUT, HIDDEN>::infer(black_box(&self.params), 0, x);
                }
            }
            Some(k) => Mlp::<IN, WIDTH, OUT, HIDDEN>::infer_batch_with(
                k,
                black_box(&self.params),
                0,
                &self.xs,
                &mut self.ys,
            ),
        }
        black_box(&mut self.ys);
    }

    /// A training pass of the whole batch: forward with contexts, then the
    /// backward into the parameter gradient, per query or batched.
    pub fn train(&mut self, kernel: Option<BatchKernel>) {
        let p = black_box(&self.params);
        match kernel {
            None => {
                for q in 0..self.xs.len() {
                    let _ = Mlp::<IN, WIDTH, OUT, HIDDEN>::forward(
                        p,
                        0,
                        &self.xs[q],
                        &mut self.ctxs[q],
                    );
                    Mlp::<IN, WIDTH, OUT, HIDDEN>::backward(
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
                Mlp::<IN, WIDTH, OUT, HIDDEN>::forward_batch_with(
                    k,
                    p,
                    0,
                    &self.xs,
                    &mut self.ys,
                    &mut self.ctxs,
                );
                Mlp::<IN, WIDTH, OUT, HIDDEN>::backward_batch_with(
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
}

impl<const IN: usize, const WIDTH: usize, const OUT: usize, const HIDDEN: usize> Default
    for MlpWorkload<IN, WIDTH, OUT, HIDDEN>
{
    fn default() -> Self {
        Self::new()
    }
}
