//! How the wavefront chooses continuation directions: BSDF sampling, or path guiding.

pub mod gpu;
pub mod guide;
pub mod guided;
