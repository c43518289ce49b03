//! Placeholder crate. The rust-gpu shader crate and the Vulkan host runtime
//! that run `guiding-core` kernels on the GPU are not implemented yet; nothing
//! here is a feature.
