//! The device context: one logical device with one compute queue.

use crate::batch::Recorder;
use crate::instance::{Candidate, Features, Instance, VALIDATION_ENV};
use crate::select::DEVICE_ENV;
use crate::{DeviceInfo, DeviceSelection, GpuError};
use ash::vk;
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Options of [`GpuContext::with_options`]; `Default` is what
/// [`GpuContext::new`] uses.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ContextOptions {
    /// Enable `VK_LAYER_KHRONOS_validation` (when installed). `None`: enabled
    /// when the environment variable [`VALIDATION_ENV`] is `1`.
    pub validation: Option<bool>,
    /// Keep buffers in device-local memory and copy through staging buffers
    /// even on a unified-memory device. Only useful to test the staging path
    /// (what discrete GPUs use) on lavapipe.
    pub force_staging: bool,
}

/// Locks a mutex, ignoring poisoning (the protected Vulkan handles stay valid
/// when another thread panicked while holding the lock).
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// State shared by the context and everything created from it. Buffers and
/// kernels hold an `Arc` of it, so the device outlives them whatever the drop
/// order on the user's side.
pub(crate) struct Shared {
    pub device: ash::Device,
    pub queue: Mutex<vk::Queue>,
    pub queue_family: u32,
    pub info: DeviceInfo,
    pub enabled: Features,
    pub memory: vk::PhysicalDeviceMemoryProperties,
    /// Mask of the valid timestamp bits; 0 when the queue has no timestamps.
    pub timestamp_mask: u64,
    /// Buffers are host-visible and mapped (no staging).
    pub mapped_buffers: bool,
    /// Idle command recorders for reuse by batches and transfers.
    pub recorders: Mutex<Vec<Recorder>>,
    /// One `VkShaderModule` per distinct SPIR-V blob.
    pub modules: Mutex<HashMap<Vec<u32>, vk::ShaderModule>>,
    // Last field: destroyed after the device (fields drop after `Drop::drop`).
    pub instance: Instance,
}

impl Shared {
    /// Index of a memory type allowed by `type_bits` with all of `required`,
    /// preferring one that also has `preferred`.
    pub fn memory_type(
        &self,
        type_bits: u32,
        required: vk::MemoryPropertyFlags,
        preferred: vk::MemoryPropertyFlags,
    ) -> Option<u32> {
        let types = self.memory.memory_types_as_slice();
        let find = |flags: vk::MemoryPropertyFlags| {
            (0..types.len() as u32).find(|&i| {
                type_bits & (1 << i) != 0 && types[i as usize].property_flags.contains(flags)
            })
        };
        find(required | preferred).or_else(|| find(required))
    }
}

impl Drop for Shared {
    fn drop(&mut self) {
        // SAFETY: every object created from the device is owned here or by a
        // buffer/kernel that holds an Arc of `self`, so none is alive now;
        // waiting for idle first makes destroying in-flight objects impossible.
        unsafe {
            let _ = self.device.device_wait_idle();
            for r in lock(&self.recorders).drain(..) {
                r.destroy(&self.device);
            }
            for (_, m) in lock(&self.modules).drain() {
                self.device.destroy_shader_module(m, None);
            }
            self.device.destroy_device(None);
        }
    }
}

/// A Vulkan device ready to run compute kernels: one compute queue, the
/// Vulkan 1.2 memory-model features rust-gpu SPIR-V needs, and pools reused
/// across batches.
///
/// Cheap to share by reference; `Send + Sync` (the queue is behind a lock, so
/// batches may be submitted from several threads).
///
/// `Clone` gives another handle to the same device (an `Arc`).
#[derive(Clone)]
pub struct GpuContext {
    pub(crate) shared: Arc<Shared>,
}

/// Lists the physical devices the Vulkan loader reports, in the order
/// [`DeviceSelection::Index`] counts them, with the reason a device is unusable
/// where that applies ([`DeviceInfo::unusable_reason`]).
pub fn enumerate_devices() -> Result<Vec<DeviceInfo>, GpuError> {
    let instance = Instance::new(false)?;
    Ok(instance.candidates()?.into_iter().map(|c| c.info).collect())
}

impl GpuContext {
    /// Opens the device chosen by `selection` ([`DeviceSelection::Auto`] and
    /// [`DeviceSelection::Gpu`] honour the [`DEVICE_ENV`] override).
    pub fn new(selection: DeviceSelection) -> Result<GpuContext, GpuError> {
        GpuContext::with_options(selection, &ContextOptions::default())
    }

    /// [`GpuContext::new`] with explicit [`ContextOptions`].
    pub fn with_options(
        selection: DeviceSelection,
        options: &ContextOptions,
    ) -> Result<GpuContext, GpuError> {
        let env = std::env::var(DEVICE_ENV).ok();
        let selection = selection.resolve(env.as_deref())?;
        let validation = options
            .validation
            .unwrap_or_else(|| std::env::var(VALIDATION_ENV).is_ok_and(|v| v.trim() == "1"));
        let instance = Instance::new(validation)?;
        let mut candidates = instance.candidates()?;
        let infos: Vec<DeviceInfo> = candidates.iter().map(|c| c.info.clone()).collect();
        let chosen = selection.pick(&infos)?;
        let c = candidates.swap_remove(chosen);
        check_usable(&c)?;
        let enabled = c.supported;

        let mut f11 = vk::PhysicalDeviceVulkan11Features::default()
            .storage_buffer16_bit_access(enabled.storage_buffer_16bit)
            .variable_pointers_storage_buffer(enabled.variable_pointers_storage_buffer)
            .variable_pointers(enabled.variable_pointers);
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .shader_int8(enabled.shader_int8)
            .shader_float16(enabled.shader_float16)
            .storage_buffer8_bit_access(enabled.storage_buffer_8bit)
            .shader_buffer_int64_atomics(enabled.buffer_int64_atomics)
            .vulkan_memory_model(true)
            .vulkan_memory_model_device_scope(true)
            .vulkan_memory_model_availability_visibility_chains(enabled.memory_model_chains);
        let core = vk::PhysicalDeviceFeatures::default()
            .shader_int64(enabled.shader_int64)
            .shader_int16(enabled.shader_int16)
            .shader_float64(enabled.shader_float64);
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .features(core)
            .push_next(&mut f11)
            .push_next(&mut f12);
        let priorities = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(c.queue_family)
            .queue_priorities(&priorities)];
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .push_next(&mut f2);
        // SAFETY: `c.physical` belongs to `instance`; the feature chain only
        // enables supported features; the device is destroyed in Shared::drop.
        let device = unsafe { instance.raw.create_device(c.physical, &info, None) }
            .map_err(GpuError::vk("vkCreateDevice"))?;
        // SAFETY: family and index were requested at device creation.
        let queue = unsafe { device.get_device_queue(c.queue_family, 0) };
        let mapped_buffers = c.info.unified_memory && !options.force_staging;
        let timestamp_mask = match c.timestamp_bits {
            0 => 0,
            64.. => u64::MAX,
            b => (1u64 << b) - 1,
        };
        Ok(GpuContext {
            shared: Arc::new(Shared {
                device,
                queue: Mutex::new(queue),
                queue_family: c.queue_family,
                info: c.info,
                enabled,
                memory: c.memory,
                timestamp_mask,
                mapped_buffers,
                recorders: Mutex::new(Vec::new()),
                modules: Mutex::new(HashMap::new()),
                instance,
            }),
        })
    }

    /// Properties and limits of the device in use.
    pub fn device_info(&self) -> &DeviceInfo {
        &self.shared.info
    }

    /// Whether buffers are host-visible and mapped (unified memory, no
    /// staging copies) rather than device-local with staging copies.
    pub fn mapped_buffers(&self) -> bool {
        self.shared.mapped_buffers
    }

    /// Whether `VK_LAYER_KHRONOS_validation` is active.
    pub fn validation_enabled(&self) -> bool {
        self.shared.instance.validation()
    }

    /// Number of validation-layer errors reported so far (0 when validation
    /// is off). Each message is also printed to stderr.
    pub fn validation_errors(&self) -> u64 {
        self.shared.instance.counts.errors.load(Ordering::Relaxed)
    }

    /// Number of validation-layer warnings (including performance warnings).
    pub fn validation_warnings(&self) -> u64 {
        self.shared.instance.counts.warnings.load(Ordering::Relaxed)
    }
}

fn check_usable(c: &Candidate) -> Result<(), GpuError> {
    let missing = |feature, needed_by: &str| {
        Err(GpuError::MissingFeature {
            device: c.info.name.clone(),
            feature,
            needed_by: needed_by.to_string(),
        })
    };
    if c.info.api_version < (1, 2, 0) {
        return missing("Vulkan 1.2", "the runtime requires");
    }
    if !c.info.compute_queue {
        return missing("a compute queue", "the runtime requires");
    }
    let model = "rust-gpu SPIR-V requires (it declares OpMemoryModel Logical Vulkan)";
    if !c.supported.memory_model {
        return missing("vulkanMemoryModel", model);
    }
    if !c.supported.memory_model_device_scope {
        return missing("vulkanMemoryModelDeviceScope", model);
    }
    Ok(())
}
