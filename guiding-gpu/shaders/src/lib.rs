//! Compute entry points over guiding-core kernels.
#![no_std]

use spirv_std::spirv;

/// Smoke kernel: `out[i] = exp(in[i])` through guiding-core's math shim.
#[spirv(compute(threads(64)))]
pub fn exp_kernel(
    #[spirv(global_invocation_id)] id: spirv_std::glam::UVec3,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] input: &[f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] output: &mut [f32],
) {
    let i = id.x as usize;
    if i < input.len() {
        output[i] = guiding_core::math::exp(input[i]);
    }
}
