//! What the runtime knows about a physical device.

use std::fmt;

/// Kind of physical device, as `VkPhysicalDeviceType` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DeviceType {
    /// A discrete GPU.
    Discrete,
    /// A GPU integrated with the CPU (shares its memory).
    Integrated,
    /// A virtualised GPU.
    Virtual,
    /// A CPU implementation: lavapipe (llvmpipe), SwiftShader.
    Cpu,
    /// Anything else.
    Other,
}

impl DeviceType {
    /// Preference order of [`crate::DeviceSelection::Auto`]: lower is better.
    pub(crate) fn auto_rank(self) -> u8 {
        match self {
            DeviceType::Discrete => 0,
            DeviceType::Integrated => 1,
            DeviceType::Virtual => 2,
            DeviceType::Cpu => 3,
            DeviceType::Other => 4,
        }
    }

    pub(crate) fn from_vk(t: ash::vk::PhysicalDeviceType) -> Self {
        use ash::vk::PhysicalDeviceType as T;
        match t {
            T::DISCRETE_GPU => DeviceType::Discrete,
            T::INTEGRATED_GPU => DeviceType::Integrated,
            T::VIRTUAL_GPU => DeviceType::Virtual,
            T::CPU => DeviceType::Cpu,
            _ => DeviceType::Other,
        }
    }
}

impl fmt::Display for DeviceType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DeviceType::Discrete => "discrete GPU",
            DeviceType::Integrated => "integrated GPU",
            DeviceType::Virtual => "virtual GPU",
            DeviceType::Cpu => "CPU",
            DeviceType::Other => "other",
        })
    }
}

/// Properties and limits of a physical device that matter to the runtime.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceInfo {
    /// Position in `vkEnumeratePhysicalDevices` order (what `--device N` selects).
    pub index: usize,
    /// `deviceName`, e.g. `"llvmpipe (LLVM 15.0.6, 256 bits)"`.
    pub name: String,
    /// `deviceType`.
    pub device_type: DeviceType,
    /// `driverName` (Vulkan 1.2), e.g. `"llvmpipe"`; empty before 1.2.
    pub driver_name: String,
    /// `driverInfo` (Vulkan 1.2), e.g. `"Mesa 22.3.6 (LLVM 15.0.6)"`; empty before 1.2.
    pub driver_info: String,
    /// Device API version `(major, minor, patch)`.
    pub api_version: (u32, u32, u32),
    /// `maxStorageBufferRange`: the largest buffer a kernel can bind (lavapipe: 128 MiB).
    pub max_storage_buffer_range: u64,
    /// `maxMemoryAllocationSize` (Vulkan 1.1).
    pub max_memory_allocation_size: u64,
    /// `maxComputeWorkGroupCount` (lavapipe: 65535 in each dimension).
    pub max_compute_work_group_count: [u32; 3],
    /// `maxComputeWorkGroupInvocations`.
    pub max_compute_work_group_invocations: u32,
    /// `maxPushConstantsSize` in bytes (at least 128).
    pub max_push_constants_size: u32,
    /// `maxPerStageDescriptorStorageBuffers`.
    pub max_storage_buffers_per_stage: u32,
    /// Nanoseconds per timestamp tick (`timestampPeriod`).
    pub timestamp_period_ns: f32,
    /// Whether the chosen compute queue family writes timestamps (`timestampValidBits > 0`).
    pub timestamps: bool,
    /// CPU device or integrated GPU: buffers live in host-visible memory the
    /// kernels read directly, no staging copies.
    pub unified_memory: bool,
    /// A queue family with `VK_QUEUE_COMPUTE_BIT` exists.
    pub compute_queue: bool,
    /// `vulkanMemoryModel` and `vulkanMemoryModelDeviceScope` are supported
    /// (required: rust-gpu modules declare `OpMemoryModel Logical Vulkan`).
    pub vulkan_memory_model: bool,
}

impl DeviceInfo {
    /// Why the runtime cannot use this device, or `None` when it can.
    pub fn unusable_reason(&self) -> Option<&'static str> {
        if self.api_version < (1, 2, 0) {
            Some("Vulkan < 1.2")
        } else if !self.compute_queue {
            Some("no compute queue")
        } else if !self.vulkan_memory_model {
            Some("no vulkanMemoryModel / vulkanMemoryModelDeviceScope")
        } else {
            None
        }
    }
}

impl fmt::Display for DeviceInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (ma, mi, pa) = self.api_version;
        write!(
            f,
            "#{} {} [{}, Vulkan {ma}.{mi}.{pa}",
            self.index, self.name, self.device_type
        )?;
        if !self.driver_name.is_empty() {
            write!(f, ", {} {}", self.driver_name, self.driver_info)?;
        }
        f.write_str("]")
    }
}
