//! Error type shared by the loaders, the renderer and the CLI.

use std::path::PathBuf;

/// Everything that can go wrong while loading a scene or writing an image.
///
/// Loader errors carry the file and line of the offending element so that an unsupported
/// Mitsuba plugin is reported as e.g. `scene.xml:12:5: unsupported bsdf type "plastic"`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A Mitsuba XML element that is malformed or not supported by this loader.
    #[error("{file}:{line}:{col}: {msg}")]
    Xml {
        /// File the element came from.
        file: String,
        /// 1-based line of the element's start tag.
        line: u32,
        /// 1-based column of the element's start tag.
        col: u32,
        /// What is wrong.
        msg: String,
    },
    /// Every problem of a scene that cannot be rendered, collected in one load (each entry
    /// names its file and line): the loader goes on after an error so that one run reports
    /// them all.
    #[error("{}", problems_text(.0))]
    Problems(Vec<String>),
    /// The file is not well-formed XML.
    #[error("{file}: XML syntax error: {source}")]
    XmlSyntax {
        /// File being parsed.
        file: String,
        /// Parser error (contains the position).
        source: roxmltree::Error,
    },
    /// A malformed or unsupported OBJ statement.
    #[error("{file}:{line}: OBJ: {msg}")]
    Obj {
        /// OBJ file.
        file: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        msg: String,
    },
    /// A malformed or unsupported PLY file.
    #[error("{file}: PLY: {msg}")]
    Ply {
        /// PLY file.
        file: String,
        /// What is wrong (with the header line or the element).
        msg: String,
    },
    /// A malformed or unsupported Mitsuba `.serialized` mesh.
    #[error("{file}: serialized mesh: {msg}")]
    Serialized {
        /// Mesh file.
        file: String,
        /// What is wrong.
        msg: String,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// Path that failed.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A semantic problem with the scene as a whole (no shapes, unknown built-in, ...).
    #[error("scene: {0}")]
    Scene(String),
    /// Writing the EXR file failed.
    #[error("EXR output: {0}")]
    Exr(String),
    /// Reading an image or writing the PNG preview failed, or two images do not match.
    #[error("image: {0}")]
    Image(String),
    /// The benchmark suite could not run (bad arguments, a failed child render, I/O).
    #[error("bench: {0}")]
    Bench(String),
    /// `--device gpu`: an invalid device selection.
    #[error("GPU: {0}")]
    Gpu(#[from] guiding_gpu::GpuError),
    /// The guide failed: no usable Vulkan device, shaders not built, or a device failure
    /// mid-render.
    #[error("guide: {0}")]
    Guiding(#[from] guiding::GuidingError),
}

fn problems_text(list: &[String]) -> String {
    match list {
        [one] => one.clone(),
        _ => format!(
            "{} problems in the scene:\n  {}",
            list.len(),
            list.join("\n  ")
        ),
    }
}

/// Convenience alias.
pub type Result<T> = std::result::Result<T, Error>;
