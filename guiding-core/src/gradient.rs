//! Where backward passes put their parameter gradients.
//!
//! Every backward kernel ([`crate::mlp::Mlp::backward`],
//! [`crate::encoding::grid::grid_backward`],
//! [`crate::model::GuidingModel::accumulate_gradient`]) *adds* into a flat
//! buffer with the layout of the parameters. It is written against
//! [`GradientSink`] rather than `&mut [f32]` so that a SPIR-V kernel can hand
//! it a window of a larger storage buffer ([`GradientRow`]: one row per
//! gradient chunk) — rust-gpu cannot sub-slice a storage buffer. On the CPU a
//! plain `[f32]` is the sink. Static dispatch only (generics, no `dyn`).

/// A flat gradient buffer that backward passes add into.
pub trait GradientSink {
    /// Number of slots (indices `0..len()` are valid).
    fn len(&self) -> usize;

    /// `true` if there is no slot.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `self[index] += value`. Callers check `index < len()` or know it.
    fn add(&mut self, index: usize, value: f32);
}

impl GradientSink for [f32] {
    #[inline(always)]
    fn len(&self) -> usize {
        <[f32]>::len(self)
    }

    #[inline(always)]
    fn add(&mut self, index: usize, value: f32) {
        self[index] += value;
    }
}

/// Slots `base .. base + len` of `buffer`, seen as a gradient buffer of
/// `len` slots: the per-chunk rows of the GPU training step.
pub struct GradientRow<'a> {
    buffer: &'a mut [f32],
    base: usize,
    len: usize,
}

impl<'a> GradientRow<'a> {
    /// The row `base .. base + len` of `buffer`, clipped to the buffer's end
    /// (a row past the end has no slot).
    #[inline]
    #[must_use]
    pub fn new(buffer: &'a mut [f32], base: usize, len: usize) -> Self {
        let end = buffer.len();
        let len = if base >= end {
            0
        } else if len > end - base {
            end - base
        } else {
            len
        };
        Self { buffer, base, len }
    }
}

impl GradientSink for GradientRow<'_> {
    #[inline(always)]
    fn len(&self) -> usize {
        self.len
    }

    #[inline(always)]
    fn add(&mut self, index: usize, value: f32) {
        self.buffer[self.base + index] += value;
    }
}

/// A `Vec` is a sink like its slice (host code only).
#[cfg(feature = "std")]
impl GradientSink for std::vec::Vec<f32> {
    #[inline(always)]
    fn len(&self) -> usize {
        self.as_slice().len()
    }

    #[inline(always)]
    fn add(&mut self, index: usize, value: f32) {
        self[index] += value;
    }
}
