//! Image output: OpenEXR (RGB, f32).

use crate::error::{Error, Result};
use crate::integrator::Image;
use std::path::Path;

/// Writes `img` as an RGB f32 OpenEXR file.
pub fn write_exr(img: &Image, path: &Path) -> Result<()> {
    let w = img.width as usize;
    exr::prelude::write_rgb_file(path, w, img.height as usize, |x, y| {
        let p = img.pixels[y * w + x];
        (p[0], p[1], p[2])
    })
    .map_err(|e| Error::Exr(format!("{}: {e}", path.display())))
}
