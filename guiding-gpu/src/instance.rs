//! Loader, instance, optional validation layer and physical-device discovery.

use crate::{DeviceInfo, DeviceType, GpuError};
use ash::vk;
use std::ffi::{c_char, c_void, CStr};
use std::sync::atomic::{AtomicU64, Ordering};

/// Environment variable that enables `VK_LAYER_KHRONOS_validation` when set
/// to `1` and the layer is installed (Debian: `vulkan-validationlayers`).
pub const VALIDATION_ENV: &str = "GUIDING_VK_VALIDATION";

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Messages the validation layer reported (they are also printed to stderr).
#[derive(Default)]
pub(crate) struct ValidationCounts {
    pub errors: AtomicU64,
    pub warnings: AtomicU64,
}

struct Debug {
    loader: ash::ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
}

/// An owned `VkInstance` (destroyed on drop) with its loader.
pub(crate) struct Instance {
    // `entry` keeps libvulkan loaded while the instance lives.
    pub entry: ash::Entry,
    pub raw: ash::Instance,
    debug: Option<Debug>,
    /// Boxed so that its address, handed to the layer as user data, is stable.
    pub counts: Box<ValidationCounts>,
}

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes valid callback data (or null, handled) and the
    // user pointer registered in `Instance::new`, which outlives the messenger.
    let (msg, counts) = unsafe {
        let msg = data
            .as_ref()
            .filter(|d| !d.p_message.is_null())
            .map(|d| CStr::from_ptr(d.p_message).to_string_lossy().into_owned())
            .unwrap_or_default();
        (msg, (user as *const ValidationCounts).as_ref())
    };
    let level = if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        if let Some(c) = counts {
            c.errors.fetch_add(1, Ordering::Relaxed);
        }
        "error"
    } else {
        if let Some(c) = counts {
            c.warnings.fetch_add(1, Ordering::Relaxed);
        }
        "warning"
    };
    // Validation output is diagnostics for the developer who asked for it.
    eprintln!("[vulkan validation {level}] {msg}");
    vk::FALSE
}

pub(crate) fn cstr_array(a: &[c_char]) -> String {
    let bytes: Vec<u8> = a
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

impl Instance {
    /// Loads libvulkan and creates a Vulkan 1.2 instance; enables the
    /// validation layer when `validation` is true and the layer exists.
    pub fn new(validation: bool) -> Result<Instance, GpuError> {
        // SAFETY: loading the system's Vulkan loader library; ash resolves
        // entry points through it.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| GpuError::NoLoader(e.to_string()))?;
        // SAFETY: plain global queries on a loaded entry.
        let version = unsafe { entry.try_enumerate_instance_version() }
            .map_err(GpuError::vk("vkEnumerateInstanceVersion"))?
            .unwrap_or(vk::API_VERSION_1_0);
        if version < vk::API_VERSION_1_2 {
            return Err(GpuError::MissingFeature {
                device: "the Vulkan loader".into(),
                feature: "Vulkan 1.2",
                needed_by: format!(
                    "the runtime requires (loader reports {}.{})",
                    vk::api_version_major(version),
                    vk::api_version_minor(version)
                ),
            });
        }
        let validation = validation && {
            // SAFETY: global query.
            let layers = unsafe { entry.enumerate_instance_layer_properties() }
                .map_err(GpuError::vk("vkEnumerateInstanceLayerProperties"))?;
            layers
                .iter()
                .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER))
        };

        let app = vk::ApplicationInfo::default()
            .application_name(c"guiding-gpu")
            .engine_name(c"guiding-gpu")
            .api_version(vk::API_VERSION_1_2);
        let layers = [VALIDATION_LAYER.as_ptr()];
        let extensions = [ash::ext::debug_utils::NAME.as_ptr()];
        let mut info = vk::InstanceCreateInfo::default().application_info(&app);
        if validation {
            info = info
                .enabled_layer_names(&layers)
                .enabled_extension_names(&extensions);
        }
        // SAFETY: valid create info; the instance is destroyed in Drop.
        // The loader answers INCOMPATIBLE_DRIVER when it finds no driver at all.
        let raw = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
            vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDevice,
            e => GpuError::vk("vkCreateInstance")(e),
        })?;
        let mut instance = Instance {
            entry,
            raw,
            debug: None,
            counts: Box::default(),
        };
        if validation {
            let loader = ash::ext::debug_utils::Instance::new(&instance.entry, &instance.raw);
            let sev = vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING;
            let types = vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE;
            let counts: *const ValidationCounts = &*instance.counts;
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(sev)
                .message_type(types)
                .pfn_user_callback(Some(on_message))
                .user_data(counts as *mut c_void);
            // SAFETY: the counts box outlives the messenger (destroyed first in Drop).
            let messenger = unsafe { loader.create_debug_utils_messenger(&info, None) }
                .map_err(GpuError::vk("vkCreateDebugUtilsMessengerEXT"))?;
            instance.debug = Some(Debug { loader, messenger });
        }
        Ok(instance)
    }

    /// Whether the validation layer is active on this instance.
    pub fn validation(&self) -> bool {
        self.debug.is_some()
    }

    /// All physical devices with what the runtime needs to know about them.
    pub fn candidates(&self) -> Result<Vec<Candidate>, GpuError> {
        // SAFETY: valid instance.
        let pds = unsafe { self.raw.enumerate_physical_devices() }
            .map_err(GpuError::vk("vkEnumeratePhysicalDevices"))?;
        Ok(pds
            .into_iter()
            .enumerate()
            .map(|(i, pd)| self.candidate(i, pd))
            .collect())
    }

    fn candidate(&self, index: usize, pd: vk::PhysicalDevice) -> Candidate {
        let inst = &self.raw;
        // SAFETY: `pd` comes from this instance; the property chains only
        // include Vulkan 1.2 structures when the device reports 1.2.
        unsafe {
            let props = inst.get_physical_device_properties(pd);
            let is_12 = props.api_version >= vk::API_VERSION_1_2;
            let mut p11 = vk::PhysicalDeviceVulkan11Properties::default();
            let mut p12 = vk::PhysicalDeviceVulkan12Properties::default();
            let mut p2 = vk::PhysicalDeviceProperties2::default();
            if is_12 {
                p2 = p2.push_next(&mut p11).push_next(&mut p12);
            }
            inst.get_physical_device_properties2(pd, &mut p2);
            let props = p2.properties;

            let mut f11 = vk::PhysicalDeviceVulkan11Features::default();
            let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default();
            if is_12 {
                f2 = f2.push_next(&mut f11).push_next(&mut f12);
            }
            inst.get_physical_device_features2(pd, &mut f2);
            let f = f2.features;
            let supported = Features {
                shader_int64: f.shader_int64 == vk::TRUE,
                shader_int16: f.shader_int16 == vk::TRUE,
                shader_float64: f.shader_float64 == vk::TRUE,
                storage_buffer_16bit: f11.storage_buffer16_bit_access == vk::TRUE,
                variable_pointers_storage_buffer: f11.variable_pointers_storage_buffer == vk::TRUE,
                variable_pointers: f11.variable_pointers == vk::TRUE,
                shader_int8: f12.shader_int8 == vk::TRUE,
                shader_float16: f12.shader_float16 == vk::TRUE,
                storage_buffer_8bit: f12.storage_buffer8_bit_access == vk::TRUE,
                buffer_int64_atomics: f12.shader_buffer_int64_atomics == vk::TRUE,
                memory_model: f12.vulkan_memory_model == vk::TRUE,
                memory_model_device_scope: f12.vulkan_memory_model_device_scope == vk::TRUE,
                memory_model_chains: f12.vulkan_memory_model_availability_visibility_chains
                    == vk::TRUE,
            };

            let families = inst.get_physical_device_queue_family_properties(pd);
            let queue = families
                .iter()
                .position(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE));
            let memory = inst.get_physical_device_memory_properties(pd);
            let device_type = DeviceType::from_vk(props.device_type);
            let host_visible_local = vk::MemoryPropertyFlags::DEVICE_LOCAL
                | vk::MemoryPropertyFlags::HOST_VISIBLE
                | vk::MemoryPropertyFlags::HOST_COHERENT;
            let unified = matches!(device_type, DeviceType::Cpu | DeviceType::Integrated)
                && memory
                    .memory_types_as_slice()
                    .iter()
                    .any(|t| t.property_flags.contains(host_visible_local));
            let l = &props.limits;
            let info = DeviceInfo {
                index,
                name: cstr_array(&props.device_name),
                device_type,
                driver_name: if is_12 {
                    cstr_array(&p12.driver_name)
                } else {
                    String::new()
                },
                driver_info: if is_12 {
                    cstr_array(&p12.driver_info)
                } else {
                    String::new()
                },
                api_version: (
                    vk::api_version_major(props.api_version),
                    vk::api_version_minor(props.api_version),
                    vk::api_version_patch(props.api_version),
                ),
                max_storage_buffer_range: u64::from(l.max_storage_buffer_range),
                max_memory_allocation_size: if is_12 {
                    p11.max_memory_allocation_size
                } else {
                    u64::from(u32::MAX)
                },
                max_compute_work_group_count: l.max_compute_work_group_count,
                max_compute_work_group_invocations: l.max_compute_work_group_invocations,
                max_push_constants_size: l.max_push_constants_size,
                max_storage_buffers_per_stage: l.max_per_stage_descriptor_storage_buffers,
                timestamp_period_ns: l.timestamp_period,
                timestamps: queue.is_some_and(|q| families[q].timestamp_valid_bits > 0),
                unified_memory: unified,
                compute_queue: queue.is_some(),
                vulkan_memory_model: supported.memory_model && supported.memory_model_device_scope,
            };
            Candidate {
                physical: pd,
                queue_family: queue.unwrap_or(0) as u32,
                timestamp_bits: queue.map_or(0, |q| families[q].timestamp_valid_bits),
                memory,
                supported,
                info,
            }
        }
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        // SAFETY: every child object (device, messenger) is destroyed before
        // the instance; the messenger is ours.
        unsafe {
            if let Some(d) = self.debug.take() {
                d.loader.destroy_debug_utils_messenger(d.messenger, None);
            }
            self.raw.destroy_instance(None);
        }
    }
}

/// A physical device as found during enumeration.
pub(crate) struct Candidate {
    pub physical: vk::PhysicalDevice,
    pub queue_family: u32,
    pub timestamp_bits: u32,
    pub memory: vk::PhysicalDeviceMemoryProperties,
    pub supported: Features,
    pub info: DeviceInfo,
}

/// The optional device features the runtime knows how to enable; a device is
/// created with every one of them it supports, and a kernel whose SPIR-V
/// declares a capability needing a disabled one is refused by name.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Features {
    pub shader_int64: bool,
    pub shader_int16: bool,
    pub shader_float64: bool,
    pub storage_buffer_16bit: bool,
    pub variable_pointers_storage_buffer: bool,
    pub variable_pointers: bool,
    pub shader_int8: bool,
    pub shader_float16: bool,
    pub storage_buffer_8bit: bool,
    pub buffer_int64_atomics: bool,
    pub memory_model: bool,
    pub memory_model_device_scope: bool,
    pub memory_model_chains: bool,
}

impl Features {
    /// Whether the feature with this Vulkan name (as in
    /// [`crate::spirv::CAPABILITY_FEATURES`]) is on.
    pub fn by_name(&self, name: &str) -> bool {
        match name {
            "shaderInt64" => self.shader_int64,
            "shaderInt16" => self.shader_int16,
            "shaderFloat64" => self.shader_float64,
            "storageBuffer16BitAccess" => self.storage_buffer_16bit,
            "variablePointersStorageBuffer" => self.variable_pointers_storage_buffer,
            "variablePointers" => self.variable_pointers,
            "shaderInt8" => self.shader_int8,
            "shaderFloat16" => self.shader_float16,
            "storageBuffer8BitAccess" => self.storage_buffer_8bit,
            "shaderBufferInt64Atomics" => self.buffer_int64_atomics,
            "vulkanMemoryModel" => self.memory_model,
            "vulkanMemoryModelDeviceScope" => self.memory_model_device_scope,
            // bufferDeviceAddress and anything unknown: never enabled.
            _ => false,
        }
    }
}
