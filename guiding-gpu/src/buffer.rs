//! Storage buffers and host↔device copies.

use crate::context::Shared;
use crate::{GpuContext, GpuError};
use ash::vk;
use bytemuck::Pod;
use std::ptr::NonNull;
use std::sync::Arc;

/// A storage buffer of a fixed byte size, zero-initialised.
///
/// Memory: on unified-memory devices (lavapipe, integrated GPUs) the buffer
/// lives in host-visible coherent memory, mapped for its whole life, and
/// [`upload`](Self::upload) / [`download`](Self::download) are `memcpy`s.
/// Elsewhere it is device-local and every copy goes through a temporary
/// host-visible staging buffer and a transfer submission.
///
/// Sizes: the requested byte size is checked against `maxStorageBufferRange`
/// (128 MiB on lavapipe) and `maxMemoryAllocationSize` before allocating.
/// Allocation is rounded up to a multiple of 4 bytes (at least 4), and that
/// rounded size is what kernels see as the bound range.
///
/// `Send` but not `Sync`: a batch borrows the buffers it uses, and the
/// missing `Sync` keeps other threads from reading one while the GPU writes.
/// Dropping it frees the memory (the context's device outlives it).
pub struct GpuBuffer {
    pub(crate) shared: Arc<Shared>,
    pub(crate) buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    /// Persistent mapping of the whole allocation on unified-memory devices.
    mapped: Option<NonNull<u8>>,
    /// Requested size in bytes.
    size: u64,
    /// Rounded size: the descriptor range.
    pub(crate) bound_size: u64,
}

// SAFETY: the mapping is owned by this buffer alone and only accessed through
// `&mut self` (writes) or `&self` (reads); `!Sync` is kept by `NonNull`.
unsafe impl Send for GpuBuffer {}

/// A raw buffer + memory pair, freed on drop unless taken apart.
struct RawBuffer<'a> {
    device: &'a ash::Device,
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
}

impl RawBuffer<'_> {
    fn into_parts(self) -> (vk::Buffer, vk::DeviceMemory) {
        let parts = (self.buffer, self.memory);
        std::mem::forget(self);
        parts
    }
}

impl Drop for RawBuffer<'_> {
    fn drop(&mut self) {
        // SAFETY: not in use by the GPU (only dropped on error paths or after
        // the transfer that used it completed); null handles are no-ops.
        unsafe {
            self.device.destroy_buffer(self.buffer, None);
            self.device.free_memory(self.memory, None);
        }
    }
}

/// Creates a buffer and binds fresh memory with `required` (preferring
/// `preferred`) properties.
fn raw_buffer<'a>(
    shared: &'a Shared,
    bytes: u64,
    usage: vk::BufferUsageFlags,
    required: vk::MemoryPropertyFlags,
    preferred: vk::MemoryPropertyFlags,
    what: &'static str,
) -> Result<RawBuffer<'a>, GpuError> {
    let d = &shared.device;
    let mut raw = RawBuffer {
        device: d,
        buffer: vk::Buffer::null(),
        memory: vk::DeviceMemory::null(),
    };
    let info = vk::BufferCreateInfo::default()
        .size(bytes)
        .usage(usage)
        .sharing_mode(vk::SharingMode::EXCLUSIVE);
    // SAFETY: valid create infos; `raw` frees what was created on error.
    unsafe {
        raw.buffer =
            d.create_buffer(&info, None)
                .map_err(GpuError::alloc("vkCreateBuffer", bytes, what))?;
        let req = d.get_buffer_memory_requirements(raw.buffer);
        let ty = shared
            .memory_type(req.memory_type_bits, required, preferred)
            .ok_or(GpuError::OutOfMemory {
                kind: "suitable",
                bytes,
                what,
            })?;
        let info = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(ty);
        raw.memory = d.allocate_memory(&info, None).map_err(GpuError::alloc(
            "vkAllocateMemory",
            req.size,
            what,
        ))?;
        d.bind_buffer_memory(raw.buffer, raw.memory, 0)
            .map_err(GpuError::vk("vkBindBufferMemory"))?;
    }
    Ok(raw)
}

fn map(d: &ash::Device, memory: vk::DeviceMemory) -> Result<NonNull<u8>, GpuError> {
    // SAFETY: host-visible memory, not yet mapped.
    let p = unsafe { d.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty()) }
        .map_err(GpuError::vk("vkMapMemory"))?;
    NonNull::new(p.cast::<u8>()).ok_or(GpuError::Vk {
        call: "vkMapMemory",
        result: vk::Result::ERROR_MEMORY_MAP_FAILED,
    })
}

const HOST: vk::MemoryPropertyFlags = vk::MemoryPropertyFlags::from_raw(
    vk::MemoryPropertyFlags::HOST_VISIBLE.as_raw()
        | vk::MemoryPropertyFlags::HOST_COHERENT.as_raw(),
);

impl GpuContext {
    /// A zero-filled storage buffer of `bytes` bytes.
    pub fn buffer(&self, bytes: u64) -> Result<GpuBuffer, GpuError> {
        let shared = &self.shared;
        let info = &shared.info;
        for (limit_name, limit) in [
            ("maxStorageBufferRange", info.max_storage_buffer_range),
            ("maxMemoryAllocationSize", info.max_memory_allocation_size),
        ] {
            if bytes > limit {
                return Err(GpuError::BufferTooLarge {
                    bytes,
                    limit_name,
                    limit,
                });
            }
        }
        let bound_size = bytes.div_ceil(4).max(1) * 4;
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST;
        let d = &shared.device;
        let (raw, mapped) = if shared.mapped_buffers {
            let raw = raw_buffer(
                shared,
                bound_size,
                usage,
                HOST,
                vk::MemoryPropertyFlags::DEVICE_LOCAL,
                "a storage buffer",
            )?;
            let p = map(d, raw.memory)?;
            // SAFETY: the mapping covers at least `bound_size` bytes.
            unsafe { p.as_ptr().write_bytes(0, bound_size as usize) };
            (raw, Some(p))
        } else {
            let raw = raw_buffer(
                shared,
                bound_size,
                usage,
                vk::MemoryPropertyFlags::DEVICE_LOCAL,
                vk::MemoryPropertyFlags::empty(),
                "a storage buffer",
            )?;
            let buffer = raw.buffer;
            shared.one_shot(|d, cmd| unsafe {
                // SAFETY: recording into a fresh command buffer.
                d.cmd_fill_buffer(cmd, buffer, 0, vk::WHOLE_SIZE, 0);
                transfer_to_compute(d, cmd);
            })?;
            (raw, None)
        };
        let (buffer, memory) = raw.into_parts();
        Ok(GpuBuffer {
            shared: Arc::clone(shared),
            buffer,
            memory,
            mapped,
            size: bytes,
            bound_size,
        })
    }

    /// A buffer holding a copy of `data` (its size is `size_of_val(data)`).
    pub fn buffer_from<T: Pod>(&self, data: &[T]) -> Result<GpuBuffer, GpuError> {
        let mut b = self.buffer(std::mem::size_of_val(data) as u64)?;
        b.upload(data)?;
        Ok(b)
    }
}

/// Makes transfer writes visible to later compute shaders and host reads.
unsafe fn transfer_to_compute(d: &ash::Device, cmd: vk::CommandBuffer) {
    let barrier = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(
            vk::AccessFlags::SHADER_READ
                | vk::AccessFlags::SHADER_WRITE
                | vk::AccessFlags::HOST_READ,
        );
    // SAFETY: forwarded; `cmd` is recording.
    unsafe {
        d.cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::HOST,
            vk::DependencyFlags::empty(),
            &[barrier],
            &[],
            &[],
        );
    }
}

impl GpuBuffer {
    /// Size in bytes, as requested.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// Number of whole `T`s the buffer holds.
    pub fn len_of<T>(&self) -> u64 {
        match std::mem::size_of::<T>() as u64 {
            0 => 0,
            s => self.size / s,
        }
    }

    /// Copies `data` to the start of the buffer; the rest is unchanged.
    /// Fails if `data` is larger than the buffer.
    pub fn upload<T: Pod>(&mut self, data: &[T]) -> Result<(), GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.len() as u64 > self.size {
            return Err(GpuError::BadArgument(format!(
                "upload of {} bytes into a {}-byte buffer",
                bytes.len(),
                self.size
            )));
        }
        if bytes.is_empty() {
            return Ok(());
        }
        if let Some(p) = self.mapped {
            // SAFETY: the mapping covers `size` bytes, `&mut self` excludes
            // any batch using the buffer, and the memory is coherent.
            unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), p.as_ptr(), bytes.len()) };
            return Ok(());
        }
        let shared = &*self.shared;
        let n = bytes.len() as u64;
        let staging = raw_buffer(
            shared,
            n,
            vk::BufferUsageFlags::TRANSFER_SRC,
            HOST,
            vk::MemoryPropertyFlags::empty(),
            "a staging buffer",
        )?;
        let p = map(&shared.device, staging.memory)?;
        // SAFETY: the staging mapping covers `n` bytes.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), p.as_ptr(), bytes.len()) };
        let (src, dst) = (staging.buffer, self.buffer);
        shared.one_shot(|d, cmd| unsafe {
            // SAFETY: recording into a fresh command buffer; both buffers live
            // until the submission completed.
            let region = vk::BufferCopy::default().size(n);
            d.cmd_copy_buffer(cmd, src, dst, &[region]);
            transfer_to_compute(d, cmd);
        })
    }

    /// The whole buffer as `T`s; its size must be a multiple of `size_of::<T>()`.
    pub fn download<T: Pod>(&self) -> Result<Vec<T>, GpuError> {
        let s = std::mem::size_of::<T>() as u64;
        if s == 0 || self.size % s != 0 {
            return Err(GpuError::BadArgument(format!(
                "a {}-byte buffer is not a whole number of {s}-byte elements",
                self.size
            )));
        }
        let mut out = vec![T::zeroed(); (self.size / s) as usize];
        self.download_into(&mut out)?;
        Ok(out)
    }

    /// Fills `out` from the start of the buffer; fails if `out` is larger.
    pub fn download_into<T: Pod>(&self, out: &mut [T]) -> Result<(), GpuError> {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(out);
        let n = bytes.len() as u64;
        if n > self.size {
            return Err(GpuError::BadArgument(format!(
                "download of {n} bytes from a {}-byte buffer",
                self.size
            )));
        }
        if n == 0 {
            return Ok(());
        }
        if let Some(p) = self.mapped {
            // SAFETY: the mapping covers `size` bytes; a batch that wrote the
            // buffer has completed (it borrowed the buffer) and made its
            // writes host-visible.
            unsafe { std::ptr::copy_nonoverlapping(p.as_ptr(), bytes.as_mut_ptr(), bytes.len()) };
            return Ok(());
        }
        let shared = &*self.shared;
        let staging = raw_buffer(
            shared,
            n,
            vk::BufferUsageFlags::TRANSFER_DST,
            HOST,
            vk::MemoryPropertyFlags::HOST_CACHED,
            "a staging buffer",
        )?;
        let (src, dst) = (self.buffer, staging.buffer);
        shared.one_shot(|d, cmd| unsafe {
            // SAFETY: as in `upload`.
            let region = vk::BufferCopy::default().size(n);
            d.cmd_copy_buffer(cmd, src, dst, &[region]);
            transfer_to_compute(d, cmd);
        })?;
        let p = map(&shared.device, staging.memory)?;
        // SAFETY: the copy completed and its writes were made host-visible.
        unsafe { std::ptr::copy_nonoverlapping(p.as_ptr(), bytes.as_mut_ptr(), bytes.len()) };
        Ok(())
    }
}

impl Drop for GpuBuffer {
    fn drop(&mut self) {
        let d = &self.shared.device;
        // SAFETY: batches borrow the buffer until complete, so the GPU no
        // longer uses it; freeing memory also unmaps it.
        unsafe {
            d.destroy_buffer(self.buffer, None);
            d.free_memory(self.memory, None);
        }
    }
}
