//! `host-demo`: a CPU wavefront path tracer used to exercise the path-guiding library.
//!
//! * [`xml`] loads a subset of Mitsuba 3 / 0.6 scenes (with [`obj`], [`ply`] and [`serialized`]
//!   meshes and [`texture`]s); [`builtin`] builds
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
pub mod conductors;
pub mod emitter;
pub mod error;
pub mod gpu;
pub mod guide;
pub mod guided;
pub mod integrator;
pub mod math;
pub mod obj;
pub mod output;
pub mod ply;
pub mod scene;
pub mod schedule;
pub mod serialized;
pub mod spectrum;
pub mod sunsky;
pub mod texture;
pub mod xml;

pub use error::{Error, Result};

/// Loads `builtin:NAME` or a Mitsuba XML file path.
pub fn load_scene(spec: &str) -> Result<scene::Scene> {
    load_scene_with(spec, &xml::LoadOptions::default())
}

/// [`load_scene`] with load options (`$param` values; built-ins have no parameters and
/// refuse them).
pub fn load_scene_with(spec: &str, opts: &xml::LoadOptions) -> Result<scene::Scene> {
    match spec.strip_prefix("builtin:") {
        Some(name) => {
            if let Some((k, _)) = opts.params.first() {
                return Err(Error::Scene(format!(
                    "-D {k}=...: built-in scenes have no parameters"
                )));
            }
            builtin::load_builtin(name)
        }
        None => xml::load_file_with(std::path::Path::new(spec), opts),
    }
}
