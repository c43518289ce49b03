//! Shared by the integration tests: the validation check. Whether a test runs
//! or skips is the workspace's one rule, `guiding_gpu::test_support`
//! (`test_context`, `test_context_with`).

use guiding_gpu::{test_context_with, ContextOptions, GpuContext, TestNeeds};

/// Fails the test when the validation layer (if enabled) reported errors.
pub fn assert_validation_clean(ctx: &GpuContext) {
    assert_eq!(
        ctx.validation_errors(),
        0,
        "the validation layer reported errors (printed above)"
    );
}

/// A context that moves every transfer through staging buffers
/// (`force_staging`), checked to have no mapped buffers; `None` where the
/// test skips.
pub fn staging_context(needs: TestNeeds) -> Option<GpuContext> {
    let options = ContextOptions {
        force_staging: true,
        ..ContextOptions::default()
    };
    let ctx = test_context_with(needs, &options)?;
    assert!(!ctx.mapped_buffers());
    Some(ctx)
}
