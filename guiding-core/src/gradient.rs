//! Where backward passes put their parameter gradients.
//!
//! Every backward kernel ([`crate::mlp::Mlp::backward`],
//! [`crate::encoding::grid::grid_backward`],
//! [`crate::model::GuidingModel::accumulate_gradient`]) *adds* into a flat
//! buffer with the layout of the parameters. It is written against
//! [`GradientSink`] rather than `&mut [f32]` so that a SPIR-V kernel can
//! hand it an atomic accumulator (crate `guiding-shaders`: compare-and-swap
//! float adds on a `u32` storage buffer, every sample of a batch adding into
//! one gradient at once). On the CPU a plain `[f32]` is the sink. Static
//! dispatch only (generics, no `dyn`).

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
