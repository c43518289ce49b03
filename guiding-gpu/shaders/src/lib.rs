//! SPIR-V compute entry points of the path-guiding library.
//!
//! Every entry point is a thin wrapper: it turns the invocation id into an
//! element index and calls the matching `guiding_core::batch` kernel — the
//! very function the CPU runs in the difftests — so nothing is
//! re-implemented here. Built to SPIR-V by `guiding-gpu/build.rs` (rust-gpu
//! 0.11, feature `shaders`); on the host it compiles as a plain library so
//! that clippy and the stable workspace see the same code.
//!
//! Conventions (the Vulkan runtime in `guiding-gpu` follows them):
//! - 64 invocations per workgroup; a batch larger than 65535 workgroups
//!   (Vulkan's guaranteed `maxComputeWorkGroupCount[0]`) is dispatched as a
//!   2-D grid, so the element index is `gid.x + gid.y · groups.x · 64`;
//! - descriptor set 0, storage buffers at bindings 0, 1, … in the order of
//!   the parameters below; small scalars in push constants
//!   ([`BatchArgs`], [`AdamArgs`]);
//! - a model's configuration (a `#[repr(C)]` `Pod` value such as
//!   `NpmCompactRadiance`) is element 0 of its own storage buffer.
#![no_std]
// An entry point takes one argument per binding and built-in.
#![allow(clippy::too_many_arguments)]

use guiding_core::batch::{self, AdamArgs, BatchArgs};
use guiding_core::factorised::FactorisedTable;
use guiding_core::gradient::GradientSink;
use guiding_core::mixture::nasg::NasgMixture;
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::model::df::{DfVertex, DF_CONDITIONAL_BINS, DF_MARGINAL_BINS};
use guiding_core::model::nasg::NASG_LOBES;
use guiding_core::model::npm::NPM_LOBES;
use guiding_core::model::QueryPoint;
use guiding_core::sample::TrainingSample;
use spirv_std::glam::UVec3;
use spirv_std::spirv;

/// NPM's raw row: 8 vMF lobes ([`batch::RawRowDistribution`]).
type VmfRow = VmfMixture<NPM_LOBES>;
/// NASG's raw row: 8 lobes and the selection logit.
type NasgRow = NasgMixture<NASG_LOBES>;
/// DF's decode row: marginal and conditional logits.
type DfRow = FactorisedTable<DF_MARGINAL_BINS, DF_CONDITIONAL_BINS>;

/// Invocations per workgroup of every entry point.
pub const WORKGROUP_SIZE: u32 = 64;

/// The element index of an invocation (see the crate docs).
#[inline]
#[must_use]
pub fn element_index(id: UVec3, groups: UVec3) -> usize {
    (id.x + id.y * groups.x * WORKGROUP_SIZE) as usize
}

/// A gradient buffer shared by all invocations of a dispatch: `f32` values
/// stored as their bits in a `u32` storage buffer, added with a
/// compare-and-swap loop (`OpAtomicCompareExchange`, core Vulkan; float
/// atomics are an extension). Zero increments are skipped.
pub struct AtomicGradient<'a> {
    buffer: &'a mut [u32],
    len: usize,
}

impl<'a> AtomicGradient<'a> {
    /// The first `len` slots of `buffer` (fewer if it is shorter).
    pub fn new(buffer: &'a mut [u32], len: usize) -> Self {
        let len = if len < buffer.len() {
            len
        } else {
            buffer.len()
        };
        Self { buffer, len }
    }
}

impl GradientSink for AtomicGradient<'_> {
    fn len(&self) -> usize {
        self.len
    }

    fn add(&mut self, index: usize, value: f32) {
        if value == 0.0 || index >= self.len {
            return;
        }
        let slot = &mut self.buffer[index];
        let mut old = *slot;
        // Bounded retries: under contention every round lets at least one
        // invocation through, and the loop counts toward lavapipe's limit.
        let mut tries = 0u32;
        while tries < 1024 {
            let new = (f32::from_bits(old) + value).to_bits();
            let seen = compare_exchange(slot, new, old);
            if seen == old {
                return;
            }
            old = seen;
            tries += 1;
        }
    }
}

/// `OpAtomicCompareExchange` at queue-family scope (every invocation of the
/// dispatch; device scope would need the `VulkanMemoryModelDeviceScope`
/// capability in the module), relaxed: the value the slot
/// held (the exchange happened if it equals `current`).
#[cfg(target_arch = "spirv")]
fn compare_exchange(slot: &mut u32, new: u32, current: u32) -> u32 {
    use spirv_std::memory::{Scope, Semantics};
    // SAFETY: `slot` is a valid storage-buffer word; relaxed atomics on it
    // race only with other atomics of this dispatch.
    unsafe {
        spirv_std::arch::atomic_compare_exchange::<
            u32,
            { Scope::QueueFamily as u32 },
            { Semantics::NONE.bits() },
            { Semantics::NONE.bits() },
        >(slot, new, current)
    }
}

/// Host build (clippy, docs): a plain exchange — the entry points only run
/// as SPIR-V.
#[cfg(not(target_arch = "spirv"))]
fn compare_exchange(slot: &mut u32, new: u32, current: u32) -> u32 {
    let seen = *slot;
    if seen == current {
        *slot = new;
    }
    seen
}

/// Entry points of one model type: `sample`, `pdf`, `gradient` (and
/// `infer` for models with [`guiding_core::model::RawOutputs`]).
macro_rules! model_kernels {
    ($model:path, $sample:ident, $pdf:ident, $gradient:ident $(, $infer:ident)?) => {
        /// [`batch::sample_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $sample(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] queries: &[QueryPoint],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] u: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] out: &mut [[f32; 4]],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::sample_element(&model[0], params, queries, u, out, i);
            }
        }

        /// [`batch::pdf_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $pdf(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] queries: &[QueryPoint],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] directions: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] out: &mut [f32],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::pdf_element(&model[0], params, queries, directions, out, i);
            }
        }

        /// [`batch::gradient_sample`] of this model: one invocation per
        /// sample, the gradient added atomically into `grad` (`f32` bits).
        #[spirv(compute(threads(64)))]
        pub fn $gradient(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] samples: &[TrainingSample],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] grad: &mut [u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] losses: &mut [f32],
        ) {
            let i = element_index(id, groups);
            let mut sink = AtomicGradient::new(grad, params.len());
            batch::gradient_sample(
                &model[0],
                params,
                samples,
                args.count as usize,
                &mut sink,
                losses,
                i,
            );
        }

        $(
        /// [`batch::infer_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $infer(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] queries: &[QueryPoint],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] out: &mut [f32],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::infer_element(&model[0], params, queries, out, i);
            }
        }
        )?
    };
}

/// Entry points of every row of the model table
/// ([`guiding_core::for_each_model`]).
macro_rules! table_kernels {
    ($($model:path => $prefix:ident, $family:ident, $size:ident, $target:ident,
       [$($entry:ident),*];)*) => {
        $( row_kernels!($family, $model, $($entry),*); )*
    };
}

/// The entry points of one row, by family: the mixtures' `infer`, DF's
/// per-vertex kernels.
macro_rules! row_kernels {
    (npm, $model:path, $sample:ident, $pdf:ident, $gradient:ident, $infer:ident) => {
        model_kernels!($model, $sample, $pdf, $gradient, $infer);
    };
    (nasg, $model:path, $sample:ident, $pdf:ident, $gradient:ident, $infer:ident) => {
        model_kernels!($model, $sample, $pdf, $gradient, $infer);
    };
    (df, $model:path, $sample:ident, $pdf:ident, $gradient:ident,
     $vertex:ident, $vertex_sample:ident, $vertex_pdf:ident) => {
        model_kernels!($model, $sample, $pdf, $gradient);
        vertex_kernels!($model, $vertex, $vertex_sample, $vertex_pdf);
    };
}

/// DF's per-vertex entry points: the vertex of each query (grid + marginal
/// network), then the conditional per sampled / evaluated direction of a
/// lane of the resident vertices.
macro_rules! vertex_kernels {
    ($model:path, $vertex:ident, $vertex_sample:ident, $vertex_pdf:ident) => {
        /// [`batch::vertex_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $vertex(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] queries: &[QueryPoint],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] out: &mut [DfVertex],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::vertex_element(&model[0], params, queries, out, i);
            }
        }

        /// [`batch::vertex_sample_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $vertex_sample(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] vertices: &[DfVertex],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] lanes: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] u: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] out: &mut [[f32; 4]],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::vertex_sample_element(&model[0], params, vertices, lanes, u, out, i);
            }
        }

        /// [`batch::vertex_pdf_element`] of this model.
        #[spirv(compute(threads(64)))]
        pub fn $vertex_pdf(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] model: &[$model],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] params: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] vertices: &[DfVertex],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] lanes: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] directions: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] out: &mut [f32],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::vertex_pdf_element(&model[0], params, vertices, lanes, directions, out, i);
            }
        }
    };
}

guiding_core::for_each_model!(table_kernels);

/// [`batch::max_abs_partial`]: one invocation per block of 256 gradient
/// elements; `args.count` = parameter count.
#[spirv(compute(threads(64)))]
pub fn max_abs(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] args: &BatchArgs,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] grad: &[f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] out: &mut [f32],
) {
    let b = element_index(id, groups);
    batch::max_abs_partial(grad, args.count as usize, out, b);
}

/// [`batch::adam_element`]: one invocation per parameter.
#[spirv(compute(threads(64)))]
pub fn adam(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] args: &AdamArgs,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] params: &mut [f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] grad: &mut [f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] m: &mut [f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] v: &mut [f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] ema: &mut [f32],
) {
    let j = element_index(id, groups);
    batch::adam_element(params, grad, m, v, ema, args, j);
}

/// Entry points of one decode family (raw network outputs → sample, pdf):
/// [`batch::decode_sample_element`] / [`batch::decode_pdf_element`] of the
/// distribution type; `args.code` is its variant code (DF's interpolation).
macro_rules! decode_kernels {
    ($distribution:ty, $sample:ident, $pdf:ident) => {
        /// Decode + sample of a batch of raw outputs.
        #[spirv(compute(threads(64)))]
        pub fn $sample(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] raw: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] u: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] out: &mut [[f32; 4]],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::decode_sample_element::<$distribution>(raw, args.code, u, out, i);
            }
        }

        /// Decode + pdf of a batch of raw outputs and directions.
        #[spirv(compute(threads(64)))]
        pub fn $pdf(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] raw: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] directions: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] out: &mut [f32],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::decode_pdf_element::<$distribution>(raw, args.code, directions, out, i);
            }
        }
    };
}

decode_kernels!(VmfRow, vmf_decode_sample, vmf_decode_pdf);
decode_kernels!(NasgRow, nasg_decode_sample, nasg_decode_pdf);
decode_kernels!(DfRow, df_decode_sample, df_decode_pdf);

/// Entry points of one mixture family on raw outputs resident on the
/// device ([`batch::lane_sample_element`] / [`batch::lane_pdf_element`]): a
/// call samples / evaluates some lanes of a decoded wavefront.
macro_rules! lane_kernels {
    ($distribution:ty, $sample:ident, $pdf:ident) => {
        /// Sample of the lanes `lanes[i]` of resident raw outputs.
        #[spirv(compute(threads(64)))]
        pub fn $sample(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] raw: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] lanes: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] normals: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] u: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] out: &mut [[f32; 4]],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::lane_sample_element::<$distribution>(raw, lanes, normals, u, out, i);
            }
        }

        /// Density of the lanes `lanes[i]` of resident raw outputs.
        #[spirv(compute(threads(64)))]
        pub fn $pdf(
            #[spirv(global_invocation_id)] id: UVec3,
            #[spirv(num_workgroups)] groups: UVec3,
            #[spirv(push_constant)] args: &BatchArgs,
            #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] raw: &[f32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] lanes: &[u32],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] normals: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] directions: &[[f32; 4]],
            #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] out: &mut [f32],
        ) {
            let i = element_index(id, groups);
            if i < args.count as usize {
                batch::lane_pdf_element::<$distribution>(raw, lanes, normals, directions, out, i);
            }
        }
    };
}

lane_kernels!(VmfRow, vmf_lane_sample, vmf_lane_pdf);
lane_kernels!(NasgRow, nasg_lane_sample, nasg_lane_pdf);

/// [`batch::nasg_selection_element`]: the learned selection probability of
/// every resident NASG raw row.
#[spirv(compute(threads(64)))]
pub fn nasg_selection(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] args: &BatchArgs,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] raw: &[f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] out: &mut [f32],
) {
    let i = element_index(id, groups);
    if i < args.count as usize {
        batch::nasg_selection_element(raw, out, i);
    }
}

/// Smoke kernel: `output[i] = exp(input[i])` for `i < n` through
/// guiding-core's math shim. Bindings: 0 input, 1 output; push constant `n: u32`.
#[spirv(compute(threads(64)))]
pub fn exp_kernel(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] n: &u32,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] input: &[f32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] output: &mut [f32],
) {
    let i = element_index(id, groups);
    // Also bounded by the buffers, so a wrong `n` cannot index out of range.
    if i >= *n as usize || i >= input.len() || i >= output.len() {
        return;
    }
    output[i] = guiding_core::math::exp(input[i]);
}

/// Exact smoke kernel for the runtime's tests: `output[i] = input[i] + i`
/// (wrapping `u32`) for `i < n`. Bindings: 0 input, 1 output; push constant
/// `n: u32`. Integer-only, so the GPU result is bit-exact on every device and
/// a wrong index or a missing barrier shows up as a wrong value.
#[spirv(compute(threads(64)))]
pub fn add_index_kernel(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] n: &u32,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] input: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] output: &mut [u32],
) {
    let i = element_index(id, groups);
    if i >= *n as usize || i >= input.len() || i >= output.len() {
        return;
    }
    output[i] = input[i].wrapping_add(i as u32);
}
