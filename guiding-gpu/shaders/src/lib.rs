//! Compute entry points over guiding-core kernels.
//!
//! Every entry point follows the `guiding-gpu` dispatch convention: 1-D work,
//! launched as a grid that becomes 2-D past `maxComputeWorkGroupCount[0]`;
//! the linear index is [`linear_index`] and the element count `n` comes in a
//! push constant, so invocations with `linear >= n` return at once.
#![no_std]

use spirv_std::glam::UVec3;
use spirv_std::spirv;

/// Invocations per workgroup of every entry point here (the literal in
/// `#[spirv(compute(threads(64)))]` must match).
pub const WORKGROUP_SIZE: u32 = 64;

/// The linear invocation index of the runtime's 1-D-over-2-D grid:
/// `gid.x + gid.y * num_workgroups.x * WORKGROUP_SIZE`.
#[inline]
#[must_use]
pub fn linear_index(global_invocation_id: UVec3, num_workgroups: UVec3) -> u32 {
    global_invocation_id.x + global_invocation_id.y * num_workgroups.x * WORKGROUP_SIZE
}

/// Smoke kernel: `output[i] = exp(input[i])` for `i < n` through
/// guiding-core's math shim. Bindings: 0 input, 1 output; push constant `n: u32`.
#[spirv(compute(threads(64)))]
pub fn exp_kernel(
    #[spirv(global_invocation_id)] gid: UVec3,
    #[spirv(num_workgroups)] num_workgroups: UVec3,
    #[spirv(push_constant)] n: &u32,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] input: &[f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] output: &mut [f32],
) {
    let i = linear_index(gid, num_workgroups);
    // Also bounded by the buffers, so a wrong `n` cannot index out of range.
    if i >= *n || i as usize >= input.len() || i as usize >= output.len() {
        return;
    }
    output[i as usize] = guiding_core::math::exp(input[i as usize]);
}

/// Exact smoke kernel for the runtime's tests: `output[i] = input[i] + i`
/// (wrapping `u32`) for `i < n`. Bindings: 0 input, 1 output; push constant
/// `n: u32`. Integer-only, so the GPU result is bit-exact on every device and
/// a wrong index or a missing barrier shows up as a wrong value.
#[spirv(compute(threads(64)))]
pub fn add_index_kernel(
    #[spirv(global_invocation_id)] gid: UVec3,
    #[spirv(num_workgroups)] num_workgroups: UVec3,
    #[spirv(push_constant)] n: &u32,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] input: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] output: &mut [u32],
) {
    let i = linear_index(gid, num_workgroups);
    if i >= *n || i as usize >= input.len() || i as usize >= output.len() {
        return;
    }
    output[i as usize] = input[i as usize].wrapping_add(i);
}
