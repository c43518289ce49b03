//! Vulkan runtime that runs `guiding-core` kernels compiled to SPIR-V by
//! rust-gpu (entry points in the `guiding-shaders` crate, `shaders/`).
//!
//! Built on [`ash`]: a [`GpuContext`] owns one logical device with one compute
//! queue, created with the Vulkan 1.2 features `vulkanMemoryModel` and
//! `vulkanMemoryModelDeviceScope` that rust-gpu modules need (they declare
//! `OpMemoryModel Logical Vulkan`). [`GpuBuffer`]s hold data, [`Kernel`]s are
//! compute pipelines for SPIR-V entry points, and a [`Batch`] records several
//! dispatches (with [`Batch::barrier`]s between dependent ones) into one
//! command buffer and submits them together.
//!
//! ```no_run
//! use guiding_gpu::{DeviceSelection, GpuContext};
//! # fn main() -> Result<(), guiding_gpu::GpuError> {
//! let ctx = GpuContext::new(DeviceSelection::Auto)?;
//! let kernel = ctx.embedded_kernel("exp_kernel", 2, 4)?;
//! let input: Vec<f32> = (0..1000).map(|i| i as f32 * 0.01).collect();
//! let a = ctx.buffer_from(&input)?;
//! let b = ctx.buffer(4 * 1000)?;
//! let n = input.len() as u32;
//! ctx.run(&kernel, &[&a, &b], bytemuck::bytes_of(&n), n)?;
//! let out: Vec<f32> = b.download()?;
//! # Ok(()) }
//! ```
//!
//! Kernels follow the indexing convention of [`batch`](workgroup_grid): 1-D
//! invocations on a grid that turns 2-D past `maxComputeWorkGroupCount[0]`,
//! bounded by a count passed in push constants.
//!
//! Errors: every Vulkan failure is a [`GpuError`], never a panic; arguments
//! are checked against the kernel's SPIR-V and the device limits before the
//! driver sees them.

mod batch;
mod buffer;
mod context;
mod error;
mod info;
mod instance;
mod kernel;
mod model;
mod select;
mod shaders;
mod spirv;
#[doc(hidden)]
pub mod test_support;

pub use ash::vk;
pub use batch::{workgroup_grid, Batch, BatchReport};
pub use buffer::GpuBuffer;
pub use context::{enumerate_devices, ContextOptions, GpuContext};
pub use error::GpuError;
pub use info::{DeviceInfo, DeviceType};
pub use instance::VALIDATION_ENV;
pub use kernel::Kernel;
pub use model::{GpuModel, ModelEntryPoints, StepOutcome, TrainOptions};
pub use select::{DeviceSelection, DEVICE_ENV};
pub use shaders::shader_module;
pub use spirv::words_from_bytes;
#[doc(hidden)]
pub use test_support::{test_context, test_context_with, TestNeeds};
