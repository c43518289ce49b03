//! The one error type of the runtime.

use ash::vk;

/// Everything that can go wrong between loading Vulkan and reading results back.
///
/// The runtime never panics on a Vulkan failure: every `vk*` call that can fail
/// is mapped to [`GpuError::Vk`] (or to [`GpuError::OutOfMemory`] for the
/// allocation results), and every argument is checked before it reaches the
/// driver, because drivers are allowed to crash on invalid usage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// `libvulkan.so.1` (or the platform's loader) could not be opened.
    #[error(
        "no Vulkan loader (libvulkan.so.1): install libvulkan1 + a driver, e.g. \
         mesa-vulkan-drivers for lavapipe ({0})"
    )]
    NoLoader(String),

    /// The loader works but reports no physical device at all.
    #[error(
        "the Vulkan loader reports no device: install a driver, e.g. mesa-vulkan-drivers \
         for lavapipe (the CPU implementation)"
    )]
    NoDevice,

    /// Devices exist, but none matches the requested [`crate::DeviceSelection`]
    /// (or none of the matching ones has a compute queue and Vulkan 1.2).
    #[error("no Vulkan device matches --device {selection}; devices found: {found}")]
    NoMatchingDevice {
        /// The selection as it would be written on the command line.
        selection: String,
        /// One line per device found, with the reason it was not taken.
        found: String,
    },

    /// A `--device` / `GUIDING_VK_DEVICE` value that does not parse.
    #[error(
        "invalid device selection {value:?}: {reason} \
         (expected auto, gpu, cpu, an index such as 0, or name:SUBSTRING)"
    )]
    InvalidSelection {
        /// The rejected text.
        value: String,
        /// Why it was rejected.
        reason: &'static str,
    },

    /// A Vulkan call returned an error code.
    #[error("{call} failed: {result}")]
    Vk {
        /// The Vulkan entry point, e.g. `"vkCreateComputePipelines"`.
        call: &'static str,
        /// Its result code.
        result: vk::Result,
    },

    /// The chosen device lacks something the SPIR-V or the runtime needs.
    #[error("device {device:?} does not support {feature}, which {needed_by}")]
    MissingFeature {
        /// Device name.
        device: String,
        /// The feature, e.g. `"vulkanMemoryModel"` or `"shaderInt64"`.
        feature: &'static str,
        /// Who needs it, e.g. `"rust-gpu SPIR-V requires (OpMemoryModel Vulkan)"`.
        needed_by: String,
    },

    /// The driver could not allocate memory (`VK_ERROR_OUT_OF_{DEVICE,HOST}_MEMORY`).
    #[error("out of {kind} memory allocating {bytes} bytes for {what}")]
    OutOfMemory {
        /// `"device"` or `"host"`.
        kind: &'static str,
        /// Requested size.
        bytes: u64,
        /// What the memory was for.
        what: &'static str,
    },

    /// A buffer larger than a device limit (checked before allocating).
    #[error("buffer of {bytes} bytes exceeds {limit_name} = {limit} bytes of this device")]
    BufferTooLarge {
        /// Requested size.
        bytes: u64,
        /// The limit's Vulkan name, e.g. `"maxStorageBufferRange"`.
        limit_name: &'static str,
        /// The limit's value (128 MiB for `maxStorageBufferRange` on lavapipe).
        limit: u64,
    },

    /// No SPIR-V is embedded because the crate was built without `--features shaders`.
    #[error(
        "no SPIR-V embedded: guiding-gpu was built without the `shaders` feature \
         (rebuild with --features shaders; it needs the rust-gpu nightly, installed by build.rs)"
    )]
    ShadersNotBuilt,

    /// A SPIR-V blob that is not a module this runtime can run.
    #[error("invalid SPIR-V module: {0}")]
    InvalidSpirv(String),

    /// Arguments that do not fit the kernel or the device: binding count,
    /// push-constant size, invocation count, buffer sizes.
    #[error("bad kernel arguments: {0}")]
    BadArgument(String),
}

impl GpuError {
    /// `map_err` helper for a failed Vulkan call.
    pub(crate) fn vk(call: &'static str) -> impl FnOnce(vk::Result) -> GpuError {
        move |result| GpuError::Vk { call, result }
    }

    /// `map_err` helper for a failed allocation: the out-of-memory codes become
    /// [`GpuError::OutOfMemory`], anything else [`GpuError::Vk`].
    pub(crate) fn alloc(
        call: &'static str,
        bytes: u64,
        what: &'static str,
    ) -> impl FnOnce(vk::Result) -> GpuError {
        move |result| match result {
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY => GpuError::OutOfMemory {
                kind: "device",
                bytes,
                what,
            },
            vk::Result::ERROR_OUT_OF_HOST_MEMORY => GpuError::OutOfMemory {
                kind: "host",
                bytes,
                what,
            },
            result => GpuError::Vk { call, result },
        }
    }
}
