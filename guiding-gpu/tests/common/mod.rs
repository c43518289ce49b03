//! Shared by the integration tests: open a context or skip.

use guiding_gpu::{ContextOptions, DeviceSelection, GpuContext, GpuError};

/// Set to `1` (CI does) to turn "no Vulkan device" from a skip into a failure.
pub const REQUIRE_ENV: &str = "GUIDING_REQUIRE_VULKAN";

fn required() -> bool {
    std::env::var(REQUIRE_ENV).is_ok_and(|v| v.trim() == "1")
}

/// Whether `e` means "this machine has no usable Vulkan", the only reason a
/// test may skip.
pub fn is_absent(e: &GpuError) -> bool {
    matches!(
        e,
        GpuError::NoLoader(_) | GpuError::NoDevice | GpuError::NoMatchingDevice { .. }
    )
}

/// A context on the `Auto` device (honouring `GUIDING_VK_DEVICE`), or `None`
/// with a printed reason when no Vulkan device exists and
/// `GUIDING_REQUIRE_VULKAN` is not `1`. Any other error fails the test.
pub fn context_with(options: &ContextOptions) -> Option<GpuContext> {
    match GpuContext::with_options(DeviceSelection::Auto, options) {
        Ok(ctx) => {
            eprintln!(
                "device: {} (mapped buffers: {}, validation: {})",
                ctx.device_info(),
                ctx.mapped_buffers(),
                ctx.validation_enabled()
            );
            Some(ctx)
        }
        Err(e) if is_absent(&e) && !required() => {
            eprintln!(
                "SKIPPED: no usable Vulkan device ({e}); set {REQUIRE_ENV}=1 to fail instead"
            );
            None
        }
        Err(e) => panic!("opening a Vulkan context failed: {e}"),
    }
}

pub fn context() -> Option<GpuContext> {
    context_with(&ContextOptions::default())
}

/// Fails the test when the validation layer (if enabled) reported errors.
pub fn assert_validation_clean(ctx: &GpuContext) {
    assert_eq!(
        ctx.validation_errors(),
        0,
        "the validation layer reported errors (printed above)"
    );
}
