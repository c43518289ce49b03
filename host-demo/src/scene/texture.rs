//! Textures: Mitsuba's `bitmap` (PNG, JPEG, EXR) and `checkerboard`, and the decoded-image
//! cache that shares one copy of every image between all textures that use it.
//!
//! # Conventions (Mitsuba 3)
//!
//! * `uv = (0, 0)` is the top-left corner of the image, `v` grows downwards (row 0 first);
//!   OBJ texture coordinates are flipped on load (`v ↦ 1 − v`) as Mitsuba's OBJ loader does.
//! * `bilinear` filtering interpolates the four texels around `uv · res − 0.5`; `nearest`
//!   takes the texel `⌊uv · res⌋`; each texel index is wrapped by `wrap_mode`
//!   (`repeat`, `mirror`, `clamp`).
//! * 8-bit images are sRGB-encoded unless `raw` is set: texels are decoded with the sRGB
//!   transfer function (through a 256-entry table, so the image stays 8-bit in memory).
//!   EXR images are linear `f32`.
//! * `checkerboard`: `color0` where `frac(u) > ½` equals `frac(v) > ½`, else `color1`
//!   (defaults 0.4 and 0.2).
//! * `to_uv` (Mitsuba 3) or `uoffset`/`voffset`/`uscale`/`vscale` (Mitsuba 0.6): an affine map
//!   applied to the surface `uv` before the lookup.
//!
//! Scalar uses (`alpha` roughness, mask `opacity`, blend `weight`) read the texel's mean over
//! its channels (Mitsuba evaluates the luminance; for the grey maps these parameters use in
//! practice both agree).

use crate::error::{Error, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Texel storage of a decoded image.
#[derive(Debug)]
pub enum Texels {
    /// 8 bits per channel (PNG / JPEG); decoded through a 256-entry table (sRGB or raw).
    U8(Vec<u8>),
    /// Linear floats (EXR).
    F32(Vec<f32>),
}

/// A decoded image, row 0 at the top; 1 (grey) or 3 (RGB) channels.
#[derive(Debug)]
pub struct Image {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Channels per texel (1 or 3).
    pub channels: u32,
    /// Texel data, `height · width · channels` values.
    pub texels: Texels,
    /// 8-bit values to linear (sRGB decoding, or `v / 255` for `raw`).
    lut: [f32; 256],
}

impl Image {
    /// Bytes held by the texel data.
    pub fn bytes(&self) -> usize {
        match &self.texels {
            Texels::U8(v) => v.len(),
            Texels::F32(v) => v.len() * 4,
        }
    }

    /// Linear RGB of texel `(x, y)` (grey images give a grey triple).
    #[inline]
    fn texel(&self, x: u32, y: u32) -> Vec3 {
        let c = self.channels as usize;
        let i = (y as usize * self.width as usize + x as usize) * c;
        let get = |k: usize| match &self.texels {
            Texels::U8(v) => self.lut[v[i + k] as usize],
            Texels::F32(v) => v[i + k],
        };
        if c == 1 {
            Vec3::splat(get(0))
        } else {
            Vec3::new(get(0), get(1), get(2))
        }
    }

    /// Decodes PNG / JPEG (8- or 16-bit; 16-bit is reduced to 8) or OpenEXR bytes. `raw`
    /// keeps 8-bit values linear (`v / 255`) instead of sRGB-decoding them.
    pub fn decode(bytes: &[u8], name: &str, raw: bool) -> Result<Image> {
        let bad = |e: String| Error::Image(format!("{name}: {e}"));
        let mut lut = [0.0f32; 256];
        for (i, l) in lut.iter_mut().enumerate() {
            let v = i as f32 / 255.0;
            *l = if raw { v } else { srgb_to_linear(v) };
        }
        if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
            let img = decode_exr(bytes).map_err(bad)?;
            return Ok(Image {
                width: img.0,
                height: img.1,
                channels: 3,
                texels: Texels::F32(img.2),
                lut,
            });
        }
        let format = image::guess_format(bytes).map_err(|e| {
            bad(format!(
                "unknown image format ({e}); PNG, JPEG and EXR are supported"
            ))
        })?;
        if !matches!(format, image::ImageFormat::Png | image::ImageFormat::Jpeg) {
            return Err(bad(format!(
                "image format {format:?} is not supported (PNG, JPEG and EXR are)"
            )));
        }
        let img =
            image::load_from_memory_with_format(bytes, format).map_err(|e| bad(e.to_string()))?;
        let (width, height) = (img.width(), img.height());
        if width == 0 || height == 0 {
            return Err(bad("empty image".into()));
        }
        let grey = !img.color().has_color();
        let (channels, data) = if grey {
            (1, img.into_luma8().into_raw())
        } else {
            (3, img.into_rgb8().into_raw())
        };
        Ok(Image {
            width,
            height,
            channels,
            texels: Texels::U8(data),
            lut,
        })
    }
}

fn decode_exr(bytes: &[u8]) -> std::result::Result<(u32, u32, Vec<f32>), String> {
    use exr::prelude::*;
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| {
                (
                    res.width(),
                    res.height(),
                    vec![0.0f32; res.width() * res.height() * 3],
                )
            },
            |px: &mut (usize, usize, Vec<f32>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let i = (pos.y() * px.0 + pos.x()) * 3;
                px.2[i] = r;
                px.2[i + 1] = g;
                px.2[i + 2] = b;
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| format!("EXR: {e}"))?;
    let (w, h, mut px) = img.layer_data.channel_data.pixels;
    if w == 0 || h == 0 {
        return Err("empty EXR image".into());
    }
    for v in &mut px {
        if !v.is_finite() || *v < 0.0 {
            *v = 0.0;
        }
    }
    Ok((w as u32, h as u32, px))
}

/// sRGB transfer function inverse (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Texel filter of a bitmap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// Bilinear interpolation of the four nearest texels.
    Bilinear,
    /// The texel containing `uv`.
    Nearest,
}

/// What happens to texel indices outside the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    /// Periodic.
    Repeat,
    /// Periodic with every other copy mirrored.
    Mirror,
    /// Clamped to the border texel.
    Clamp,
}

impl Wrap {
    #[inline]
    fn apply(self, i: i64, n: u32) -> u32 {
        let n = i64::from(n);
        (match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::Clamp => i.clamp(0, n - 1),
            Wrap::Mirror => {
                let m = i.rem_euclid(2 * n);
                if m < n {
                    m
                } else {
                    2 * n - 1 - m
                }
            }
        }) as u32
    }
}

/// Affine uv map `uv' = m · uv + t` (Mitsuba's `to_uv`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvMap {
    /// Linear part (columns).
    pub m: glam::Mat2,
    /// Offset.
    pub t: Vec2,
}

impl Default for UvMap {
    fn default() -> Self {
        UvMap {
            m: glam::Mat2::IDENTITY,
            t: Vec2::ZERO,
        }
    }
}

impl UvMap {
    #[inline]
    fn apply(&self, uv: Vec2) -> Vec2 {
        self.m * uv + self.t
    }
}

/// A texture.
#[derive(Clone, Debug)]
pub enum Texture {
    /// An image (shared with every other texture of the same file and `raw` flag).
    Bitmap {
        /// Decoded image.
        image: Arc<Image>,
        /// Texel filter.
        filter: Filter,
        /// Index wrapping.
        wrap: Wrap,
        /// uv map.
        uv: UvMap,
    },
    /// Two-colour checkerboard.
    Checkerboard {
        /// Colour where the u and v half-periods agree.
        color0: Vec3,
        /// The other colour.
        color1: Vec3,
        /// uv map.
        uv: UvMap,
    },
}

impl Texture {
    /// Linear RGB at surface coordinates `uv`.
    pub fn eval(&self, uv: Vec2) -> Vec3 {
        match self {
            Texture::Bitmap {
                image,
                filter,
                wrap,
                uv: map,
            } => {
                let uv = map.apply(uv);
                if !uv.is_finite() {
                    return Vec3::ZERO;
                }
                let (w, h) = (image.width, image.height);
                let x = uv.x * w as f32;
                let y = uv.y * h as f32;
                match filter {
                    Filter::Nearest => image.texel(
                        wrap.apply(x.floor() as i64, w),
                        wrap.apply(y.floor() as i64, h),
                    ),
                    Filter::Bilinear => {
                        let (x, y) = (x - 0.5, y - 0.5);
                        let (x0, y0) = (x.floor(), y.floor());
                        let (fx, fy) = (x - x0, y - y0);
                        let (x0, y0) = (x0 as i64, y0 as i64);
                        let (xa, xb) = (wrap.apply(x0, w), wrap.apply(x0 + 1, w));
                        let (ya, yb) = (wrap.apply(y0, h), wrap.apply(y0 + 1, h));
                        let top = image.texel(xa, ya) * (1.0 - fx) + image.texel(xb, ya) * fx;
                        let bottom = image.texel(xa, yb) * (1.0 - fx) + image.texel(xb, yb) * fx;
                        top * (1.0 - fy) + bottom * fy
                    }
                }
            }
            Texture::Checkerboard {
                color0,
                color1,
                uv: map,
            } => {
                let uv = map.apply(uv);
                let fu = uv.x - uv.x.floor() > 0.5;
                let fv = uv.y - uv.y.floor() > 0.5;
                if fu == fv {
                    *color0
                } else {
                    *color1
                }
            }
        }
    }

    /// Scalar value at `uv`: the mean of the channels.
    pub fn eval_scalar(&self, uv: Vec2) -> f32 {
        self.eval(uv).element_sum() / 3.0
    }

    /// Per-channel maxima over the texels (Mitsuba 0.6's `Texture::getMaximum`).
    pub fn max_rgb(&self) -> Vec3 {
        match self {
            Texture::Bitmap { image, .. } => {
                let mut m = Vec3::ZERO;
                for y in 0..image.height {
                    for x in 0..image.width {
                        m = m.max(image.texel(x, y));
                    }
                }
                m
            }
            Texture::Checkerboard { color0, color1, .. } => color0.max(*color1),
        }
    }

    /// Largest value any channel can take (for validation and sampling weights).
    pub fn max_value(&self) -> f32 {
        match self {
            Texture::Bitmap { image, .. } => match &image.texels {
                Texels::U8(v) => v.iter().map(|&b| image.lut[b as usize]).fold(0.0, f32::max),
                Texels::F32(v) => v.iter().copied().fold(0.0, f32::max),
            },
            Texture::Checkerboard { color0, color1, .. } => {
                color0.max_element().max(color1.max_element())
            }
        }
    }
}

/// A material parameter: a constant or a texture index (into [`crate::scene::Scene::textures`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Param {
    /// Constant RGB (or a scalar in all three channels).
    Const(Vec3),
    /// Texture.
    Tex(u32),
}

/// Decoded images by resolved path and `raw` flag: every file is decoded once per scene.
#[derive(Default)]
pub struct ImageCache {
    images: HashMap<(PathBuf, bool), Arc<Image>>,
}

impl ImageCache {
    /// The image at `path` (decoded with `read` on first use).
    pub fn get(
        &mut self,
        path: &Path,
        raw: bool,
        read: &dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
    ) -> Result<Arc<Image>> {
        let key = (path.to_path_buf(), raw);
        if let Some(img) = self.images.get(&key) {
            return Ok(Arc::clone(img));
        }
        let bytes = read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let img = Arc::new(Image::decode(&bytes, &path.display().to_string(), raw)?);
        self.images.insert(key, Arc::clone(&img));
        Ok(img)
    }

    /// Bytes of texel data held (each image counted once).
    pub fn bytes(&self) -> usize {
        self.images.values().map(|i| i.bytes()).sum()
    }

    /// Number of distinct decoded images.
    pub fn len(&self) -> usize {
        self.images.len()
    }

    /// True if no image was decoded.
    pub fn is_empty(&self) -> bool {
        self.images.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, data: Vec<f32>) -> Arc<Image> {
        Arc::new(Image {
            width: w,
            height: h,
            channels: 1,
            texels: Texels::F32(data),
            lut: [0.0; 256],
        })
    }

    #[test]
    fn wrap_modes() {
        assert_eq!(Wrap::Repeat.apply(-1, 4), 3);
        assert_eq!(Wrap::Repeat.apply(5, 4), 1);
        assert_eq!(Wrap::Clamp.apply(-3, 4), 0);
        assert_eq!(Wrap::Clamp.apply(9, 4), 3);
        assert_eq!(Wrap::Mirror.apply(-1, 4), 0);
        assert_eq!(Wrap::Mirror.apply(4, 4), 3);
        assert_eq!(Wrap::Mirror.apply(8, 4), 0);
    }

    #[test]
    fn bilinear_and_nearest() {
        let image = img(2, 1, vec![0.0, 1.0]);
        let t = |filter| Texture::Bitmap {
            image: Arc::clone(&image),
            filter,
            wrap: Wrap::Clamp,
            uv: UvMap::default(),
        };
        // Texel centres at u = 0.25 and 0.75.
        assert_eq!(t(Filter::Bilinear).eval(Vec2::new(0.25, 0.5)).x, 0.0);
        assert_eq!(t(Filter::Bilinear).eval(Vec2::new(0.75, 0.5)).x, 1.0);
        assert!((t(Filter::Bilinear).eval(Vec2::new(0.5, 0.5)).x - 0.5).abs() < 1e-6);
        assert_eq!(t(Filter::Nearest).eval(Vec2::new(0.49, 0.5)).x, 0.0);
        assert_eq!(t(Filter::Nearest).eval(Vec2::new(0.51, 0.5)).x, 1.0);
    }

    #[test]
    fn checkerboard_quadrants() {
        let t = Texture::Checkerboard {
            color0: Vec3::ONE,
            color1: Vec3::ZERO,
            uv: UvMap::default(),
        };
        assert_eq!(t.eval(Vec2::new(0.25, 0.25)), Vec3::ONE);
        assert_eq!(t.eval(Vec2::new(0.75, 0.75)), Vec3::ONE);
        assert_eq!(t.eval(Vec2::new(0.75, 0.25)), Vec3::ZERO);
    }
}
