//! The SPIR-V module built from `guiding-gpu/shaders` by `build.rs`.

use crate::GpuError;

/// The embedded module's words, copied once into `u32` alignment.
#[cfg(feature = "shaders")]
fn embedded() -> Result<&'static [u32], GpuError> {
    use std::sync::OnceLock;
    static BYTES: &[u8] = include_bytes!(env!("GUIDING_SHADERS_SPV"));
    static WORDS: OnceLock<Result<Vec<u32>, String>> = OnceLock::new();
    WORDS
        .get_or_init(|| crate::spirv::words_from_bytes(BYTES).map_err(|e| e.to_string()))
        .as_deref()
        .map_err(|e| GpuError::InvalidSpirv(e.clone()))
}

/// The SPIR-V module compiled from the shader crate (`guiding-shaders`) by
/// rust-gpu at build time, as words for [`crate::GpuContext::kernel`].
///
/// Fails with [`GpuError::ShadersNotBuilt`] when `guiding-gpu` was built
/// without the `shaders` feature (the default, so that the workspace builds
/// on stable without the rust-gpu nightly).
pub fn shader_module() -> Result<&'static [u32], GpuError> {
    #[cfg(feature = "shaders")]
    {
        embedded()
    }
    #[cfg(not(feature = "shaders"))]
    {
        Err(GpuError::ShadersNotBuilt)
    }
}
