//! Shared by the integration tests: the validation check. Whether a test runs
//! or skips is the workspace's one rule, `guiding_gpu::test_support`
//! (`test_context`, `test_context_with`).

use guiding_gpu::GpuContext;

/// Fails the test when the validation layer (if enabled) reported errors.
pub fn assert_validation_clean(ctx: &GpuContext) {
    assert_eq!(
        ctx.validation_errors(),
        0,
        "the validation layer reported errors (printed above)"
    );
}
