//! Image files: OpenEXR (RGB, f32) output and the tonemapped PNG preview (EXR input is
//! [`crate::scene::load::exr`]).

use crate::error::{Error, Result};
use crate::render::Image;
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

/// sRGB transfer function (IEC 61966-2-1) of a linear value clamped to `[0, 1]`, as 8 bits.
pub fn srgb8(linear: f32) -> u8 {
    let x = if linear.is_finite() {
        linear.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let v = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (v * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// Writes an 8-bit sRGB PNG preview of `img`: each linear channel is clamped to `[0, 1]`
/// (no exposure change) and encoded with the sRGB curve; NaN becomes black.
pub fn write_png(img: &Image, path: &Path) -> Result<()> {
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), img.width, img.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    let data: Vec<u8> = img.pixels.iter().flat_map(|p| p.map(srgb8)).collect();
    let png_err =
        |e: png::EncodingError| Error::Image(format!("writing PNG {}: {e}", path.display()));
    let mut writer = enc.write_header().map_err(png_err)?;
    writer.write_image_data(&data).map_err(png_err)?;
    writer.finish().map_err(png_err)
}
