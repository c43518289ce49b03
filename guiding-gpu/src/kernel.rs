//! Compute pipelines for SPIR-V entry points.

use crate::context::{lock, Shared};
use crate::spirv::{self, CAPABILITY_FEATURES};
use crate::{GpuContext, GpuError};
use ash::vk;
use std::ffi::CString;
use std::sync::Arc;

/// A compute pipeline: one entry point of a SPIR-V module with `storage_buffers`
/// storage buffers at set 0, bindings `0..storage_buffers`, and a push-constant
/// block of `push_constant_bytes` bytes (compute stage, offset 0).
///
/// Dropping it destroys the pipeline and its layouts; the shader module stays
/// cached in the context.
pub struct Kernel {
    pub(crate) shared: Arc<Shared>,
    pub(crate) entry: String,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pub(crate) pipeline_layout: vk::PipelineLayout,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) storage_buffers: u32,
    pub(crate) push_constant_bytes: u32,
    pub(crate) workgroup_size: u32,
}

impl Kernel {
    /// The entry point's name.
    pub fn entry_point(&self) -> &str {
        &self.entry
    }

    /// Invocations per workgroup, read from the entry point's `LocalSize`
    /// (rust-gpu's `#[spirv(compute(threads(N)))]`).
    pub fn workgroup_size(&self) -> u32 {
        self.workgroup_size
    }

    /// Number of storage-buffer bindings a dispatch must supply.
    pub fn storage_buffers(&self) -> u32 {
        self.storage_buffers
    }

    /// Size of the push-constant block a dispatch must supply, in bytes.
    pub fn push_constant_bytes(&self) -> u32 {
        self.push_constant_bytes
    }
}

impl Drop for Kernel {
    fn drop(&mut self) {
        let d = &self.shared.device;
        // SAFETY: batches borrow the kernel until they completed, so the GPU
        // no longer uses these; null handles (partial construction) are no-ops.
        unsafe {
            d.destroy_pipeline(self.pipeline, None);
            d.destroy_pipeline_layout(self.pipeline_layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

fn bad(msg: String) -> GpuError {
    GpuError::BadArgument(msg)
}

impl GpuContext {
    /// Creates the compute pipeline for `entry_point` of the SPIR-V module
    /// `spirv_words`, with `storage_buffers` storage-buffer bindings (set 0,
    /// bindings `0..n`) and a `push_constant_bytes`-byte push-constant range.
    ///
    /// Before the driver sees the module, its preamble is checked: the entry
    /// point exists as a `GLCompute` entry with a 1-D `LocalSize` (the
    /// workgroup size used by dispatches, so it cannot disagree with the
    /// shader), every descriptor it uses is a storage buffer in set 0 with a
    /// binding below `storage_buffers`, it has push constants only if
    /// `push_constant_bytes > 0`, and every capability it declares that
    /// needs a device feature has it enabled. The `VkShaderModule` is created
    /// once per distinct blob and cached in the context.
    pub fn kernel(
        &self,
        spirv_words: &[u32],
        entry_point: &str,
        storage_buffers: u32,
        push_constant_bytes: u32,
    ) -> Result<Kernel, GpuError> {
        let shared = &self.shared;
        let module = spirv::parse(spirv_words)?;
        let Some(ep) = module.entry_points.iter().find(|e| e.name == entry_point) else {
            let names: Vec<&str> = module
                .entry_points
                .iter()
                .map(|e| e.name.as_str())
                .collect();
            return Err(GpuError::InvalidSpirv(format!(
                "no compute entry point {entry_point:?}; the module has {names:?}"
            )));
        };
        let workgroup_size =
            self.checked_workgroup_size(&module, ep, storage_buffers, push_constant_bytes)?;
        let name = CString::new(entry_point)
            .map_err(|_| bad(format!("entry point name {entry_point:?} contains NUL")))?;

        let d = &shared.device;
        let shader = self.shader_module(spirv_words)?;

        let mut kernel = Kernel {
            shared: Arc::clone(shared),
            entry: entry_point.to_string(),
            set_layout: vk::DescriptorSetLayout::null(),
            pipeline_layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
            storage_buffers,
            push_constant_bytes,
            workgroup_size,
        };
        let bindings: Vec<vk::DescriptorSetLayoutBinding> = (0..storage_buffers)
            .map(|i| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(i)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        // SAFETY: valid create infos; on error `kernel` is dropped, which
        // destroys whatever was created so far.
        unsafe {
            let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
            kernel.set_layout = d
                .create_descriptor_set_layout(&info, None)
                .map_err(GpuError::vk("vkCreateDescriptorSetLayout"))?;
            let layouts = [kernel.set_layout];
            let ranges = [vk::PushConstantRange::default()
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
                .offset(0)
                .size(push_constant_bytes)];
            let mut info = vk::PipelineLayoutCreateInfo::default().set_layouts(&layouts);
            if push_constant_bytes > 0 {
                info = info.push_constant_ranges(&ranges);
            }
            kernel.pipeline_layout = d
                .create_pipeline_layout(&info, None)
                .map_err(GpuError::vk("vkCreatePipelineLayout"))?;
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(shader)
                .name(&name);
            let info = vk::ComputePipelineCreateInfo::default()
                .stage(stage)
                .layout(kernel.pipeline_layout);
            kernel.pipeline = d
                .create_compute_pipelines(vk::PipelineCache::null(), &[info], None)
                .map_err(|(_, e)| GpuError::vk("vkCreateComputePipelines")(e))?[0];
        }
        Ok(kernel)
    }

    /// The preamble checks of [`Self::kernel`] (its docs) of entry point
    /// `ep` of `module`: its workgroup size if they pass.
    fn checked_workgroup_size(
        &self,
        module: &spirv::ModuleInfo,
        ep: &spirv::EntryPoint,
        storage_buffers: u32,
        push_constant_bytes: u32,
    ) -> Result<u32, GpuError> {
        let shared = &self.shared;
        let info = &shared.info;
        let entry_point = ep.name.as_str();
        let workgroup_size = match ep.local_size {
            Some([x, 1, 1]) if x > 0 => x,
            other => {
                return Err(GpuError::InvalidSpirv(format!(
                    "entry point {entry_point} has LocalSize {other:?}; the runtime needs a \
                     literal 1-D size [x, 1, 1]"
                )))
            }
        };
        if workgroup_size > info.max_compute_work_group_invocations {
            return Err(bad(format!(
                "{entry_point}: workgroup size {workgroup_size} exceeds \
                 maxComputeWorkGroupInvocations = {}",
                info.max_compute_work_group_invocations
            )));
        }
        for &cap in &module.capabilities {
            if let Some(&(_, feature)) = CAPABILITY_FEATURES.iter().find(|c| c.0 == cap) {
                if !shared.enabled.by_name(feature) {
                    return Err(GpuError::MissingFeature {
                        device: info.name.clone(),
                        feature,
                        needed_by: format!("the SPIR-V module declares (OpCapability {cap})"),
                    });
                }
            }
        }
        if storage_buffers > info.max_storage_buffers_per_stage {
            return Err(bad(format!(
                "{storage_buffers} storage buffers exceed maxPerStageDescriptorStorageBuffers = {}",
                info.max_storage_buffers_per_stage
            )));
        }
        if push_constant_bytes % 4 != 0 || push_constant_bytes > info.max_push_constants_size {
            return Err(bad(format!(
                "push-constant size {push_constant_bytes} must be a multiple of 4 and at most \
                 maxPushConstantsSize = {}",
                info.max_push_constants_size
            )));
        }
        if let Some(bindings) = &ep.bindings {
            for b in bindings {
                if b.set != 0 || b.binding >= storage_buffers || b.storage_class != 12 {
                    return Err(bad(format!(
                        "{entry_point} uses a descriptor at set {} binding {} (storage class {}); \
                         the kernel was declared with {storage_buffers} storage buffers at set 0",
                        b.set, b.binding, b.storage_class
                    )));
                }
            }
        }
        if ep.push_constants == Some(true) && push_constant_bytes == 0 {
            return Err(bad(format!(
                "{entry_point} reads push constants but push_constant_bytes is 0"
            )));
        }
        Ok(workgroup_size)
    }

    /// The `VkShaderModule` of `spirv_words`, created at its first use and
    /// cached in the context.
    fn shader_module(&self, spirv_words: &[u32]) -> Result<vk::ShaderModule, GpuError> {
        let d = &self.shared.device;
        let mut modules = lock(&self.shared.modules);
        let m = match modules.get(spirv_words) {
            Some(&m) => m,
            None => {
                let info = vk::ShaderModuleCreateInfo::default().code(spirv_words);
                // SAFETY: `Self::kernel`, the only caller, parsed and checked
                // the blob's header first.
                let m = unsafe { d.create_shader_module(&info, None) }.map_err(GpuError::alloc(
                    "vkCreateShaderModule",
                    4 * spirv_words.len() as u64,
                    "a shader module",
                ))?;
                modules.insert(spirv_words.to_vec(), m);
                m
            }
        };
        Ok(m)
    }

    /// [`GpuContext::kernel`] for an entry point of the SPIR-V module embedded
    /// at build time ([`crate::shader_module`]).
    pub fn embedded_kernel(
        &self,
        entry_point: &str,
        storage_buffers: u32,
        push_constant_bytes: u32,
    ) -> Result<Kernel, GpuError> {
        self.kernel(
            crate::shader_module()?,
            entry_point,
            storage_buffers,
            push_constant_bytes,
        )
    }
}
