//! The one rule of the workspace's tests for "this machine cannot run the Vulkan
//! tests" (hidden from the documentation: support for tests, not API).
//!
//! A test skips — `None`, with the reason printed — only when the machine or the
//! build has no Vulkan to offer: no loader ([`GpuError::NoLoader`]), no device
//! ([`GpuError::NoDevice`]), no device matching the selection
//! ([`GpuError::NoMatchingDevice`], e.g. `GUIDING_VK_DEVICE=gpu` on a machine with
//! only lavapipe), or, for a test that runs kernels, no SPIR-V in this build
//! ([`GpuError::ShadersNotBuilt`]). With `GUIDING_REQUIRE_VULKAN=1` (CI, and
//! `run-on-gpu.sh`) each of those is a failure instead. Any other error — a device
//! that exists but cannot be opened, an invalid `GUIDING_VK_DEVICE` — always fails:
//! it is a defect to report, not a machine to skip.

use crate::{shader_module, ContextOptions, DeviceSelection, GpuContext, GpuError};

/// Set to `1` (CI does) to turn "no Vulkan" from a skip into a failure.
pub const REQUIRE_ENV: &str = "GUIDING_REQUIRE_VULKAN";

/// Whether [`REQUIRE_ENV`] is `1` (surrounding blanks ignored).
#[must_use]
pub fn vulkan_required() -> bool {
    std::env::var(REQUIRE_ENV).is_ok_and(|v| v.trim() == "1")
}

/// What a test needs of the machine and the build.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TestNeeds {
    /// A device only: selection, buffers, limits, argument checks.
    Device,
    /// A device and this build's SPIR-V (`--features guiding-gpu/shaders`): kernels.
    Kernels,
}

/// Whether `e` is one of the reasons a test may skip (see the module's rule).
#[must_use]
pub fn is_absent(e: &GpuError) -> bool {
    matches!(
        e,
        GpuError::NoLoader(_)
            | GpuError::NoDevice
            | GpuError::NoMatchingDevice { .. }
            | GpuError::ShadersNotBuilt
    )
}

/// A context on the `Auto` device (honouring `GUIDING_VK_DEVICE`) for a test that
/// needs `needs`, or `None` with the reason printed when the machine or the build
/// cannot run it and [`REQUIRE_ENV`] is not `1`.
///
/// # Panics
/// When the context cannot be opened for any other reason, or for a reason to skip
/// while [`REQUIRE_ENV`] is `1`.
#[must_use]
pub fn test_context_with(needs: TestNeeds, options: &ContextOptions) -> Option<GpuContext> {
    let spirv = match needs {
        TestNeeds::Kernels => shader_module().map(|_| ()),
        TestNeeds::Device => Ok(()),
    };
    match spirv.and_then(|()| GpuContext::with_options(DeviceSelection::Auto, options)) {
        Ok(ctx) => {
            eprintln!(
                "device: {} (mapped buffers: {}, validation: {})",
                ctx.device_info(),
                ctx.mapped_buffers(),
                ctx.validation_enabled()
            );
            Some(ctx)
        }
        Err(e) if is_absent(&e) => {
            assert!(!vulkan_required(), "{REQUIRE_ENV}=1, but: {e}");
            eprintln!("SKIPPED: {e} (set {REQUIRE_ENV}=1 to fail instead)");
            None
        }
        Err(e) => panic!("opening a Vulkan context failed: {e}"),
    }
}

/// [`test_context_with`] for a test that runs kernels, with the default options.
///
/// # Panics
/// As [`test_context_with`].
#[must_use]
pub fn test_context() -> Option<GpuContext> {
    test_context_with(TestNeeds::Kernels, &ContextOptions::default())
}
