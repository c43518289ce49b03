//! OpenEXR input: environment maps for the scene loader, reference images for comparisons.

use crate::error::{Error, Result};
use std::path::Path;

/// A linear RGB image read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Row-major pixels, top row first.
    pub pixels: Vec<[f32; 3]>,
}

/// Reads the first RGB(A) layer of an OpenEXR file (alpha is ignored; a missing green or blue
/// channel is an error from the exr crate).
pub fn read_exr(path: &Path) -> Result<RgbImage> {
    use exr::prelude::read_first_rgba_layer_from_file;
    let img = read_first_rgba_layer_from_file(
        path,
        |res, _| RgbImage {
            width: res.width(),
            height: res.height(),
            pixels: vec![[0.0; 3]; res.width() * res.height()],
        },
        |img: &mut RgbImage, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            img.pixels[pos.y() * img.width + pos.x()] = [r, g, b];
        },
    )
    .map_err(|e| Error::Image(format!("reading EXR {}: {e}", path.display())))?;
    Ok(img.layer_data.channel_data.pixels)
}
