//! Builds `shaders/` to SPIR-V with rust-gpu when the `shaders` feature is on.

fn main() {
    #[cfg(feature = "shaders")]
    shaders::build();
}

#[cfg(feature = "shaders")]
mod shaders {
    use cargo_gpu_install::install::Install;
    use cargo_gpu_install::spirv_builder::{ShaderPanicStrategy, SpirvMetadata};
    use std::path::PathBuf;

    pub fn build() {
        let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
        let shader_crate = manifest.join("shaders");
        let backend = Install::from_shader_crate(shader_crate.clone())
            .within_build_script()
            .run()
            .unwrap_or_else(|e| panic!("installing the rust-gpu backend failed: {e:#}"));
        let mut builder = backend.to_spirv_builder(&shader_crate, "spirv-unknown-vulkan1.2");
        builder.spirv_metadata = SpirvMetadata::NameVariables;
        let _ = ShaderPanicStrategy::SilentExit;
        let result = builder
            .build()
            .unwrap_or_else(|e| panic!("compiling the shader crate to SPIR-V failed: {e:#}"));
        let path = result.module.unwrap_single();
        println!("cargo::rustc-env=GUIDING_SHADERS_SPV={}", path.display());
    }
}
