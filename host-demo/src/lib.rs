//! `host-demo`: a CPU wavefront path tracer used to exercise the path-guiding library.
//!
//! * [`xml`] loads a subset of Mitsuba 3 scenes (with [`obj`] and [`ply`] meshes); [`builtin`] builds
//!   `builtin:cornell-box`, `builtin:furnace` and `builtin:door` in code.
//! * [`scene`] holds triangles and analytic spheres in an `obvhs` CWBVH.
//! * [`integrator`] is the wavefront `pt` / `pt-nee` renderer, [`output`] writes EXR.
//! * [`guided`] is the `guided` integrator (online-trained path guiding through [`guide`]).
//! * [`schedule`] decides the passes (spp or time budget) and draws the progress bar;
//!   [`compare`] computes relMSE / MAPE between two images.

pub mod bench;
pub mod bsdf;
pub mod builtin;
pub mod compare;
pub mod emitter;
pub mod error;
pub mod guide;
pub mod guided;
pub mod integrator;
pub mod math;
pub mod obj;
pub mod output;
pub mod ply;
pub mod scene;
pub mod schedule;
pub mod xml;

pub use error::{Error, Result};

/// Loads `builtin:NAME` or a Mitsuba XML file path.
pub fn load_scene(spec: &str) -> Result<scene::Scene> {
    match spec.strip_prefix("builtin:") {
        Some(name) => builtin::load_builtin(name),
        None => xml::load_file(std::path::Path::new(spec)),
    }
}
