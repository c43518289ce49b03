//! Recording several dispatches into one command buffer and submitting them.
//!
//! # Dispatch convention
//! Invocations are 1-D. A dispatch of `n` invocations with workgroup size `w`
//! needs `g = ceil(n / w)` workgroups. Devices limit each grid dimension
//! (`maxComputeWorkGroupCount`, 65535 on lavapipe), so the runtime launches
//! `x = min(g, max_x)`, `y = ceil(g / x)` workgroups ([`workgroup_grid`]) and
//! every kernel must
//! * compute its linear index as
//!   `linear = gid.x + gid.y * num_workgroups.x * w`
//!   (`gid` = `global_invocation_id`, `num_workgroups` the built-in), and
//! * return when `linear >= n`, with `n` passed in a push constant: the grid
//!   overshoots `n` by up to `x * w - 1` invocations, and `arrayLength` of a
//!   buffer is not `n` in general (buffers are rounded up to 4 bytes).

use crate::context::{lock, Shared};
use crate::{GpuBuffer, GpuContext, GpuError, Kernel};
use ash::vk;
use std::marker::PhantomData;

/// Sets per descriptor pool; a batch adds pools as it needs them.
const SETS_PER_POOL: u32 = 64;

/// The workgroup grid `[x, y, 1]` for `invocations` 1-D invocations of a
/// kernel with `workgroup_size` invocations per group, on a device whose
/// `maxComputeWorkGroupCount` is `max_groups`: `x = min(g, max_x)`,
/// `y = ceil(g / x)` with `g = ceil(invocations / workgroup_size)`.
/// `[0, 0, 0]` when `invocations == 0` (nothing to launch).
///
/// Fails when the grid would exceed `max_groups[1]` or when the linear index
/// `gid.x + gid.y * x * workgroup_size` could overflow `u32`.
pub fn workgroup_grid(
    invocations: u32,
    workgroup_size: u32,
    max_groups: [u32; 3],
) -> Result<[u32; 3], GpuError> {
    if workgroup_size == 0 || max_groups[0] == 0 {
        return Err(GpuError::BadArgument(
            "workgroup size and maxComputeWorkGroupCount must be positive".into(),
        ));
    }
    if invocations == 0 {
        return Ok([0, 0, 0]);
    }
    let groups = invocations.div_ceil(workgroup_size);
    let x = groups.min(max_groups[0]);
    let y = groups.div_ceil(x);
    let launched = u64::from(x) * u64::from(y) * u64::from(workgroup_size);
    if y > max_groups[1] || launched > u64::from(u32::MAX) + 1 {
        return Err(GpuError::BadArgument(format!(
            "{invocations} invocations need a {x} x {y} grid of {workgroup_size}-wide \
             workgroups, beyond maxComputeWorkGroupCount {max_groups:?} or the u32 index range"
        )));
    }
    Ok([x, y, 1])
}

/// What a submitted batch reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchReport {
    /// Dispatches recorded (those with zero invocations are not counted).
    pub dispatches: u32,
    /// GPU time between the start and the end of the command buffer in
    /// nanoseconds, from timestamp queries; `None` when the queue has none.
    pub gpu_time_ns: Option<f64>,
}

/// Reusable command-recording resources: one command buffer, its fence,
/// descriptor pools and a two-entry timestamp query pool.
pub(crate) struct Recorder {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    descriptor_pools: Vec<vk::DescriptorPool>,
    /// First pool that may still have room.
    current: usize,
    queries: vk::QueryPool,
}

impl Recorder {
    fn new(shared: &Shared) -> Result<Recorder, GpuError> {
        let d = &shared.device;
        let mut r = Recorder {
            pool: vk::CommandPool::null(),
            cmd: vk::CommandBuffer::null(),
            fence: vk::Fence::null(),
            descriptor_pools: Vec::new(),
            current: 0,
            queries: vk::QueryPool::null(),
        };
        // SAFETY: valid device; on error the partially built recorder is
        // destroyed (destroying null handles is a no-op).
        let built = unsafe {
            (|| {
                let info = vk::CommandPoolCreateInfo::default()
                    .flags(vk::CommandPoolCreateFlags::TRANSIENT)
                    .queue_family_index(shared.queue_family);
                r.pool = d
                    .create_command_pool(&info, None)
                    .map_err(GpuError::vk("vkCreateCommandPool"))?;
                let info = vk::CommandBufferAllocateInfo::default()
                    .command_pool(r.pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1);
                r.cmd = d
                    .allocate_command_buffers(&info)
                    .map_err(GpuError::vk("vkAllocateCommandBuffers"))?[0];
                r.fence = d
                    .create_fence(&vk::FenceCreateInfo::default(), None)
                    .map_err(GpuError::vk("vkCreateFence"))?;
                if shared.timestamp_mask != 0 {
                    let info = vk::QueryPoolCreateInfo::default()
                        .query_type(vk::QueryType::TIMESTAMP)
                        .query_count(2);
                    r.queries = d
                        .create_query_pool(&info, None)
                        .map_err(GpuError::vk("vkCreateQueryPool"))?;
                }
                Ok(())
            })()
        };
        match built {
            Ok(()) => Ok(r),
            Err(e) => {
                // SAFETY: nothing was submitted.
                unsafe { r.destroy(d) };
                Err(e)
            }
        }
    }

    /// Destroys every handle. Caller guarantees the GPU no longer uses them.
    pub(crate) unsafe fn destroy(self, d: &ash::Device) {
        // SAFETY: forwarded from the caller; null handles are no-ops.
        unsafe {
            d.destroy_query_pool(self.queries, None);
            for p in self.descriptor_pools {
                d.destroy_descriptor_pool(p, None);
            }
            d.destroy_fence(self.fence, None);
            d.destroy_command_pool(self.pool, None);
        }
    }

    /// Returns the recorder to its initial state for reuse.
    fn reset(&mut self, d: &ash::Device) -> Result<(), GpuError> {
        // SAFETY: the command buffer is not pending (its fence was waited for,
        // or it was never submitted).
        unsafe {
            d.reset_command_pool(self.pool, vk::CommandPoolResetFlags::empty())
                .map_err(GpuError::vk("vkResetCommandPool"))?;
            for &p in &self.descriptor_pools {
                d.reset_descriptor_pool(p, vk::DescriptorPoolResetFlags::empty())
                    .map_err(GpuError::vk("vkResetDescriptorPool"))?;
            }
            d.reset_fences(&[self.fence])
                .map_err(GpuError::vk("vkResetFences"))?;
        }
        self.current = 0;
        Ok(())
    }

    /// Allocates a descriptor set, adding a pool when the current ones are full.
    fn descriptor_set(
        &mut self,
        d: &ash::Device,
        layout: vk::DescriptorSetLayout,
        bindings: u32,
    ) -> Result<vk::DescriptorSet, GpuError> {
        let layouts = [layout];
        loop {
            if self.current == self.descriptor_pools.len() {
                let sizes = [vk::DescriptorPoolSize::default()
                    .ty(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(SETS_PER_POOL * bindings.max(8))];
                let info = vk::DescriptorPoolCreateInfo::default()
                    .max_sets(SETS_PER_POOL)
                    .pool_sizes(&sizes);
                // SAFETY: valid device and create info.
                let pool = unsafe { d.create_descriptor_pool(&info, None) }
                    .map_err(GpuError::vk("vkCreateDescriptorPool"))?;
                self.descriptor_pools.push(pool);
            }
            let info = vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(self.descriptor_pools[self.current])
                .set_layouts(&layouts);
            // SAFETY: the pool and layout belong to `d`.
            match unsafe { d.allocate_descriptor_sets(&info) } {
                Ok(sets) => return Ok(sets[0]),
                Err(vk::Result::ERROR_OUT_OF_POOL_MEMORY | vk::Result::ERROR_FRAGMENTED_POOL) => {
                    self.current += 1;
                }
                Err(e) => return Err(GpuError::vk("vkAllocateDescriptorSets")(e)),
            }
        }
    }
}

impl Shared {
    fn take_recorder(&self) -> Result<Recorder, GpuError> {
        match lock(&self.recorders).pop() {
            Some(r) => Ok(r),
            None => Recorder::new(self),
        }
    }

    /// Resets and keeps a recorder whose work is finished (or never submitted).
    fn recycle(&self, mut r: Recorder) {
        match r.reset(&self.device) {
            Ok(()) => lock(&self.recorders).push(r),
            // SAFETY: not pending (see `reset`).
            Err(_) => unsafe { r.destroy(&self.device) },
        }
    }

    /// Records `record` into a fresh command buffer, submits it and waits.
    pub(crate) fn one_shot(
        &self,
        record: impl FnOnce(&ash::Device, vk::CommandBuffer),
    ) -> Result<(), GpuError> {
        let mut batch = Batch::begin(self, false)?;
        if let Some(r) = &batch.rec {
            record(&self.device, r.cmd);
        }
        batch.finish_and_wait().map(|_| ())
    }
}

/// Dispatches recorded into one command buffer, submitted together.
///
/// ```no_run
/// # use guiding_gpu::*;
/// # fn f(ctx: &GpuContext, fwd: &Kernel, bwd: &Kernel, a: &GpuBuffer, b: &GpuBuffer) -> Result<(), GpuError> {
/// let n: u32 = 1000;
/// let mut batch = ctx.batch()?;
/// batch.dispatch(fwd, &[a, b], bytemuck::bytes_of(&n), n)?;
/// batch.barrier(); // bwd reads what fwd wrote
/// batch.dispatch(bwd, &[b, a], bytemuck::bytes_of(&n), n)?;
/// let report = batch.submit_and_wait()?;
/// # Ok(()) }
/// ```
///
/// The borrow `'a` keeps every kernel and buffer used by the batch alive (and
/// buffers unmodified by the host) until it is submitted or dropped. Dropping
/// a batch without submitting discards the recorded work.
pub struct Batch<'a> {
    shared: &'a Shared,
    /// `None` after a failed submission left the recorder unusable.
    rec: Option<Recorder>,
    dispatches: u32,
    /// Timestamps are written at the start and end.
    timed: bool,
    _uses: PhantomData<&'a GpuBuffer>,
}

impl<'a> Batch<'a> {
    fn begin(shared: &'a Shared, timed: bool) -> Result<Batch<'a>, GpuError> {
        let rec = shared.take_recorder()?;
        let timed = timed && rec.queries != vk::QueryPool::null();
        let batch = Batch {
            shared,
            rec: Some(rec),
            dispatches: 0,
            timed,
            _uses: PhantomData,
        };
        let d = &shared.device;
        let info = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        if let Some(r) = &batch.rec {
            // SAFETY: the recorder's command buffer is in the initial state.
            unsafe {
                d.begin_command_buffer(r.cmd, &info)
                    .map_err(GpuError::vk("vkBeginCommandBuffer"))?;
                if timed {
                    d.cmd_reset_query_pool(r.cmd, r.queries, 0, 2);
                    d.cmd_write_timestamp(r.cmd, vk::PipelineStageFlags::TOP_OF_PIPE, r.queries, 0);
                }
            }
        }
        Ok(batch)
    }

    fn recorder(&mut self) -> Result<&mut Recorder, GpuError> {
        self.rec.as_mut().ok_or(GpuError::Vk {
            call: "vkQueueSubmit",
            result: vk::Result::ERROR_DEVICE_LOST,
        })
    }

    /// Records `kernel` over `invocations` 1-D invocations with `buffers`
    /// bound to set 0, bindings `0..buffers.len()`, and `push` as its push
    /// constants (see the module docs for the indexing convention).
    ///
    /// Checks that the buffer count and push-constant size match the kernel
    /// and that everything belongs to this context. A dispatch with zero
    /// invocations records nothing.
    pub fn dispatch(
        &mut self,
        kernel: &'a Kernel,
        buffers: &[&'a GpuBuffer],
        push: &[u8],
        invocations: u32,
    ) -> Result<(), GpuError> {
        let shared = self.shared;
        let foreign = |s: &Shared| !std::ptr::eq(s, shared);
        if foreign(&kernel.shared) || buffers.iter().any(|b| foreign(&b.shared)) {
            return Err(GpuError::BadArgument(format!(
                "kernel {} or one of its buffers belongs to another GpuContext",
                kernel.entry
            )));
        }
        check_count(
            kernel,
            kernel.storage_buffers,
            buffers.len(),
            "storage buffers",
        )?;
        check_count(
            kernel,
            kernel.push_constant_bytes,
            push.len(),
            "bytes of push constants",
        )?;
        let grid = workgroup_grid(
            invocations,
            kernel.workgroup_size,
            shared.info.max_compute_work_group_count,
        )?;
        if invocations == 0 {
            return Ok(());
        }
        let d = &shared.device;
        let r = self.recorder()?;
        let set = r.descriptor_set(d, kernel.set_layout, kernel.storage_buffers)?;
        let infos: Vec<vk::DescriptorBufferInfo> = buffers
            .iter()
            .map(|b| {
                vk::DescriptorBufferInfo::default()
                    .buffer(b.buffer)
                    .offset(0)
                    .range(b.bound_size)
            })
            .collect();
        let writes: Vec<vk::WriteDescriptorSet> = (0..infos.len())
            .map(|i| {
                vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(i as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(&infos[i..i + 1])
            })
            .collect();
        // SAFETY: all handles belong to this device (checked above) and stay
        // alive for `'a`; the command buffer is recording.
        unsafe {
            d.update_descriptor_sets(&writes, &[]);
            d.cmd_bind_pipeline(r.cmd, vk::PipelineBindPoint::COMPUTE, kernel.pipeline);
            d.cmd_bind_descriptor_sets(
                r.cmd,
                vk::PipelineBindPoint::COMPUTE,
                kernel.pipeline_layout,
                0,
                &[set],
                &[],
            );
            if !push.is_empty() {
                d.cmd_push_constants(
                    r.cmd,
                    kernel.pipeline_layout,
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    push,
                );
            }
            d.cmd_dispatch(r.cmd, grid[0], grid[1], grid[2]);
        }
        self.dispatches += 1;
        Ok(())
    }

    /// A compute→compute memory barrier: dispatches recorded after it see
    /// every write of the dispatches recorded before it. Without one,
    /// dispatches of a batch may overlap.
    pub fn barrier(&mut self) {
        self.memory_barrier(
            vk::PipelineStageFlags::COMPUTE_SHADER,
            vk::AccessFlags::SHADER_WRITE,
            vk::PipelineStageFlags::COMPUTE_SHADER,
            vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE,
        );
    }

    fn memory_barrier(
        &mut self,
        src_stage: vk::PipelineStageFlags,
        src: vk::AccessFlags,
        dst_stage: vk::PipelineStageFlags,
        dst: vk::AccessFlags,
    ) {
        let d = &self.shared.device;
        if let Some(r) = &self.rec {
            let barrier = vk::MemoryBarrier::default()
                .src_access_mask(src)
                .dst_access_mask(dst);
            // SAFETY: the command buffer is recording.
            unsafe {
                d.cmd_pipeline_barrier(
                    r.cmd,
                    src_stage,
                    dst_stage,
                    vk::DependencyFlags::empty(),
                    &[barrier],
                    &[],
                    &[],
                );
            }
        }
    }

    /// Number of dispatches recorded so far.
    pub fn len(&self) -> u32 {
        self.dispatches
    }

    /// Whether nothing has been recorded.
    pub fn is_empty(&self) -> bool {
        self.dispatches == 0
    }

    /// Submits the recorded work, waits for it, and makes every write visible
    /// to the host (and to later transfers). Returns the GPU time when the
    /// batch was created by [`GpuContext::timed_batch`] and the queue supports
    /// timestamps.
    pub fn submit_and_wait(mut self) -> Result<BatchReport, GpuError> {
        self.memory_barrier(
            vk::PipelineStageFlags::COMPUTE_SHADER,
            vk::AccessFlags::SHADER_WRITE,
            vk::PipelineStageFlags::HOST | vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::HOST_READ | vk::AccessFlags::TRANSFER_READ,
        );
        self.finish_and_wait()
    }

    fn finish_and_wait(&mut self) -> Result<BatchReport, GpuError> {
        let shared = self.shared;
        let d = &shared.device;
        let timed = self.timed;
        let dispatches = self.dispatches;
        let r = self.recorder()?;
        let (cmd, fence, queries) = (r.cmd, r.fence, r.queries);
        // SAFETY: the command buffer is recording; after a successful submit
        // the fence is waited for before anything is reused or freed.
        unsafe {
            if timed {
                d.cmd_write_timestamp(cmd, vk::PipelineStageFlags::BOTTOM_OF_PIPE, queries, 1);
            }
            d.end_command_buffer(cmd)
                .map_err(GpuError::vk("vkEndCommandBuffer"))?;
            let cmds = [cmd];
            let submit = vk::SubmitInfo::default().command_buffers(&cmds);
            {
                let queue = lock(&shared.queue);
                d.queue_submit(*queue, &[submit], fence)
                    .map_err(GpuError::vk("vkQueueSubmit"))?;
            }
            if let Err(e) = d.wait_for_fences(&[fence], true, u64::MAX) {
                // The work may still be pending: wait for the whole device
                // before the recorder is destroyed, never reuse it.
                let _ = d.device_wait_idle();
                if let Some(r) = self.rec.take() {
                    r.destroy(d);
                }
                return Err(GpuError::vk("vkWaitForFences")(e));
            }
            let gpu_time_ns = if timed {
                let mut t = [0u64; 2];
                d.get_query_pool_results(
                    queries,
                    0,
                    &mut t,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
                .map_err(GpuError::vk("vkGetQueryPoolResults"))?;
                let ticks = t[1].wrapping_sub(t[0]) & shared.timestamp_mask;
                Some(ticks as f64 * f64::from(shared.info.timestamp_period_ns))
            } else {
                None
            };
            Ok(BatchReport {
                dispatches,
                gpu_time_ns,
            })
        }
    }
}

impl Drop for Batch<'_> {
    fn drop(&mut self) {
        if let Some(r) = self.rec.take() {
            // Either never submitted or its fence was waited for.
            self.shared.recycle(r);
        }
    }
}

impl GpuContext {
    /// Starts recording a batch of dispatches.
    pub fn batch(&self) -> Result<Batch<'_>, GpuError> {
        Batch::begin(&self.shared, false)
    }

    /// Like [`GpuContext::batch`], with timestamp queries around the batch so
    /// that [`BatchReport::gpu_time_ns`] is set (when the queue supports them).
    pub fn timed_batch(&self) -> Result<Batch<'_>, GpuError> {
        Batch::begin(&self.shared, true)
    }

    /// Runs one dispatch and waits for it: a batch of one.
    pub fn run(
        &self,
        kernel: &Kernel,
        buffers: &[&GpuBuffer],
        push: &[u8],
        invocations: u32,
    ) -> Result<BatchReport, GpuError> {
        let mut batch = self.batch()?;
        batch.dispatch(kernel, buffers, push, invocations)?;
        batch.submit_and_wait()
    }
}

/// The error unless a dispatch of `kernel` supplies the `expected` number
/// of `what` (storage buffers, bytes of push constants).
fn check_count(kernel: &Kernel, expected: u32, given: usize, what: &str) -> Result<(), GpuError> {
    if given == expected as usize {
        return Ok(());
    }
    Err(GpuError::BadArgument(format!(
        "kernel {} takes {expected} {what}, {given} given",
        kernel.entry
    )))
}

#[cfg(test)]
mod tests {
    use super::workgroup_grid;

    #[test]
    fn grid_is_1d_until_the_limit_then_2d() {
        let lim = [65535, 65535, 65535];
        assert_eq!(workgroup_grid(0, 64, lim).unwrap(), [0, 0, 0]);
        assert_eq!(workgroup_grid(1, 64, lim).unwrap(), [1, 1, 1]);
        assert_eq!(workgroup_grid(64, 64, lim).unwrap(), [1, 1, 1]);
        assert_eq!(workgroup_grid(65, 64, lim).unwrap(), [2, 1, 1]);
        assert_eq!(workgroup_grid(1_000_000, 64, lim).unwrap(), [15625, 1, 1]);
        assert_eq!(workgroup_grid(65535 * 64, 64, lim).unwrap(), [65535, 1, 1]);
        assert_eq!(
            workgroup_grid(65535 * 64 + 17, 64, lim).unwrap(),
            [65535, 2, 1]
        );
        // The largest grid whose linear index stays within u32.
        let n = 65535 * 64 * 1024;
        assert_eq!(workgroup_grid(n, 64, lim).unwrap(), [65535, 1024, 1]);
        // u32::MAX invocations would launch past 2^32 and wrap the index.
        assert!(workgroup_grid(u32::MAX, 64, lim).is_err());
        // Too many groups for the y limit.
        assert!(workgroup_grid(u32::MAX, 1, [65535, 2, 1]).is_err());
        assert!(workgroup_grid(10, 0, lim).is_err());
    }

    #[test]
    fn grid_covers_every_invocation_exactly_once() {
        // Every linear index < n is produced by exactly one (gid.x, gid.y),
        // and the overshoot is below one row of the grid.
        for (n, w, max_x) in [(1000u32, 64u32, 3u32), (17, 4, 2), (4097, 64, 7), (5, 8, 1)] {
            let [x, y, _] = workgroup_grid(n, w, [max_x, 65535, 1]).unwrap();
            let launched = x * y * w;
            assert!(launched >= n && launched - n < x * w, "{n} {w} {max_x}");
            let mut seen = vec![0u32; launched as usize];
            for gy in 0..y {
                for gx in 0..x * w {
                    seen[(gx + gy * x * w) as usize] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1));
        }
    }
}
