//! `host-demo`: a CPU wavefront path tracer that embeds the path-guiding library the way a
//! renderer would.
//!
//! * [`scene`]: camera, triangles and analytic shapes in an `obvhs` CWBVH, BSDFs, emitters,
//!   textures and the built-in scenes ([`scene::builtin`]); [`scene::load`] reads Mitsuba 3 /
//!   0.6 XML and its meshes (OBJ, PLY, serialized), which load as meshes the scene turns into
//!   primitives.
//! * [`render`]: options, the pass [`render::schedule`], images and their output, and the one
//!   [`render::wavefront`] driver (intersection, emission, NEE, continuation, the pass loop).
//!   How a vertex picks its continuation direction is a [`render::strategy`]: BSDF sampling
//!   (`pt`, `pt-nee`) or path guiding (`guided`, which decodes the guide for a whole bounce with
//!   one batched call and records its training samples through the library's batch recorder).
//! * [`bench`](mod@bench): the equal-time benchmark and its report; the command line lives in the binary.
//!
//! Modules depend downwards only: `bench` → `render` → `scene` → `math`/`error`.

pub mod bench;
pub mod error;
pub mod math;
pub mod render;
pub mod scene;

pub use error::{Error, Result};
pub use scene::load::{load_scene, load_scene_with};
