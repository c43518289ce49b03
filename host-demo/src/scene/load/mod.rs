//! Scene files: Mitsuba 3 / 0.6 XML ([`xml`]) and the mesh formats it references
//! ([`obj`], [`ply`], Mitsuba's [`serialized`], all read into a
//! [`crate::scene::mesh::TriangleMesh`]) and images ([`exr`]).

pub mod exr;
pub mod obj;
pub mod ply;
pub mod serialized;
pub mod xml;

use crate::error::{Error, Result};
use crate::scene::Scene;

/// Loads `builtin:NAME` or a Mitsuba XML file path.
pub fn load_scene(spec: &str) -> Result<Scene> {
    load_scene_with(spec, &xml::LoadOptions::default())
}

/// [`load_scene`] with load options (`$param` values; built-ins have no parameters and
/// refuse them).
pub fn load_scene_with(spec: &str, opts: &xml::LoadOptions) -> Result<Scene> {
    match spec.strip_prefix("builtin:") {
        Some(name) => {
            if let Some((k, _)) = opts.params.first() {
                return Err(Error::Scene(format!(
                    "-D {k}=...: built-in scenes have no parameters"
                )));
            }
            crate::scene::builtin::load_builtin(name)
        }
        None => xml::load_file_with(std::path::Path::new(spec), opts),
    }
}
