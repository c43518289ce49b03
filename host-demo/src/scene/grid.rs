//! Density grids of heterogeneous media: Mitsuba's `gridvolume` and its binary `.vol` files.
//!
//! # The `.vol` format (Mitsuba 0.6, read unchanged by Mitsuba 3)
//!
//! | bytes | content |
//! |---|---|
//! | 3 | `VOL` |
//! | 1 | version, 3 |
//! | 4 | encoding (little-endian `i32`): 1 = `f32`, 3 = `u8` (value / 255) |
//! | 12 | `xres`, `yres`, `zres` (`i32`) |
//! | 4 | channels (`i32`); only 1 is read here (a density) |
//! | 24 | bounding box `xmin, ymin, zmin, xmax, ymax, zmax` (`f32`) |
//! | … | values, `x` fastest: index `(z · yres + y) · xres + x` |
//!
//! # Lookup
//!
//! The grid covers the unit cube of its local frame; Mitsuba 3 places it with the volume's
//! `to_world` (the file's box is ignored), Mitsuba 0.6 with the file's box (then `toWorld`): the
//! loader builds `to_local` accordingly. Values are cell-centred and interpolated trilinearly
//! with clamped indices (Mitsuba 3's `trilinear` filter); outside the cube the density is 0.

use glam::{Mat4, Vec3};

/// The most tentative collisions one free flight or transmittance estimate takes before it
/// gives up (the walk then ends: a collision-free pass is counted as absorbed). At a majorant
/// optical depth of 10⁴ along the ray this is never reached by a published scene.
pub const MAX_TRACKING_STEPS: u32 = 1 << 16;

/// A scalar density on a regular grid (see the module docs).
#[derive(Clone, PartialEq)]
pub struct DensityGrid {
    /// Cells along x, y, z (each ≥ 1).
    pub res: [u32; 3],
    /// Values, `x` fastest; every value finite and ≥ 0.
    pub data: Vec<f32>,
    /// World → local (the grid's unit cube).
    pub to_local: Mat4,
    /// The largest value (the majorant's density).
    pub max: f32,
}

impl std::fmt::Debug for DensityGrid {
    /// The resolution, placement, maximum and a checksum of the values (not the values).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for v in &self.data {
            h = (h ^ u64::from(v.to_bits())).wrapping_mul(0x100_0000_01b3);
        }
        f.debug_struct("DensityGrid")
            .field("res", &self.res)
            .field("to_local", &self.to_local)
            .field("max", &self.max)
            .field("checksum", &format_args!("{h:016x}"))
            .finish()
    }
}

/// A `.vol` file's grid and the bounding box it declares (`min`, `max`).
pub type VolFile = (DensityGrid, [Vec3; 2]);

impl DensityGrid {
    /// Reads a `.vol` file (see the module docs); `to_local` is left at the identity.
    /// Errors name what is wrong (truncated, bad magic, unsupported encoding or channel count,
    /// non-finite or negative values).
    pub fn from_vol(bytes: &[u8]) -> Result<VolFile, String> {
        let head = bytes.get(..48).ok_or("a .vol file has a 48-byte header")?;
        if &head[..3] != b"VOL" {
            return Err("not a .vol file (no \"VOL\" magic)".into());
        }
        if head[3] != 3 {
            return Err(format!(".vol version {} (only 3 is known)", head[3]));
        }
        let int = |i: usize| i32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]);
        let float = |i: usize| f32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]);
        let encoding = int(4);
        let (xres, yres, zres, channels) = (int(8), int(12), int(16), int(20));
        if channels != 1 {
            return Err(format!(
                ".vol with {channels} channels (only a one-channel density is read)"
            ));
        }
        let dims = [xres, yres, zres];
        if dims.iter().any(|&r| r < 1) {
            return Err(format!(".vol resolution {xres} x {yres} x {zres}"));
        }
        let count = dims
            .iter()
            .try_fold(1usize, |n, &r| n.checked_mul(r as usize))
            .filter(|&n| n <= 1 << 28)
            .ok_or(".vol has more than 2^28 values")?;
        let body = &bytes[48..];
        let data: Vec<f32> = match encoding {
            1 => {
                let raw = body
                    .get(..count * 4)
                    .ok_or_else(|| format!(".vol is truncated: {count} f32 values declared"))?;
                raw.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect()
            }
            3 => body
                .get(..count)
                .ok_or_else(|| format!(".vol is truncated: {count} u8 values declared"))?
                .iter()
                .map(|&b| f32::from(b) / 255.0)
                .collect(),
            e => {
                return Err(format!(
                    ".vol encoding {e} (only 1 = f32 and 3 = u8 are read)"
                ))
            }
        };
        if let Some(v) = data.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(format!(
                ".vol holds the density {v} (must be finite and >= 0)"
            ));
        }
        let max = data.iter().fold(0.0f32, |m, &v| m.max(v));
        let bbox = [
            Vec3::new(float(24), float(28), float(32)),
            Vec3::new(float(36), float(40), float(44)),
        ];
        let grid = DensityGrid {
            res: dims.map(|r| r as u32),
            data,
            to_local: Mat4::IDENTITY,
            max,
        };
        Ok((grid, bbox))
    }

    /// The density at world position `p`: trilinear between cell centres, clamped at the
    /// faces, 0 outside the unit cube.
    pub fn eval(&self, p: Vec3) -> f32 {
        let q = self.to_local.transform_point3(p);
        if !(q.cmpge(Vec3::ZERO).all() && q.cmple(Vec3::ONE).all()) {
            return 0.0;
        }
        let [nx, ny, nz] = self.res.map(|r| r as usize);
        let axis = |x: f32, n: usize| {
            let s = (x * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            let i = (s as usize).min(n.saturating_sub(2));
            let j = (i + 1).min(n - 1);
            (i, j, s - i as f32)
        };
        let (x0, x1, fx) = axis(q.x, nx);
        let (y0, y1, fy) = axis(q.y, ny);
        let (z0, z1, fz) = axis(q.z, nz);
        let at = |x: usize, y: usize, z: usize| self.data[(z * ny + y) * nx + x];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(at(x0, y0, z0), at(x1, y0, z0), fx);
        let c10 = lerp(at(x0, y1, z0), at(x1, y1, z0), fx);
        let c01 = lerp(at(x0, y0, z1), at(x1, y0, z1), fx);
        let c11 = lerp(at(x0, y1, z1), at(x1, y1, z1), fx);
        lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)
    }

    /// The part `[t0, t1]` of the ray `o + t d`, `t ∈ [0, t_max]`, inside the grid's cube
    /// (`None` if it misses). The local frame is affine, so `t` is the same in both frames.
    pub fn clip(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, f32)> {
        let lo = self.to_local.transform_point3(o);
        let ld = self.to_local.transform_vector3(d);
        let (mut t0, mut t1) = (0.0f32, t_max);
        for a in 0..3 {
            let (p, v) = (lo[a], ld[a]);
            if v == 0.0 {
                if !(0.0..=1.0).contains(&p) {
                    return None;
                }
                continue;
            }
            let (a0, a1) = ((0.0 - p) / v, (1.0 - p) / v);
            t0 = t0.max(a0.min(a1));
            t1 = t1.min(a0.max(a1));
        }
        (t0 < t1).then_some((t0, t1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `.vol` file's bytes (f32 encoding, one channel).
    pub(crate) fn vol_bytes(res: [i32; 3], bbox: [f32; 6], values: &[f32]) -> Vec<u8> {
        let mut b = b"VOL\x03".to_vec();
        for i in [1, res[0], res[1], res[2], 1] {
            b.extend(i.to_le_bytes());
        }
        for f in bbox.iter().chain(values) {
            b.extend(f.to_le_bytes());
        }
        b
    }

    #[test]
    fn reads_a_vol_file_and_interpolates_between_cell_centres() {
        // 2 × 1 × 1 cells: 0 at x = ¼ (first centre), 1 at x = ¾.
        let bytes = vol_bytes([2, 1, 1], [0.0, 0.0, 0.0, 1.0, 2.0, 3.0], &[0.0, 1.0]);
        let (g, bbox) = DensityGrid::from_vol(&bytes).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(g.res, [2, 1, 1]);
        assert_eq!(bbox, [Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0)]);
        assert_eq!(g.max, 1.0);
        assert_eq!(g.eval(Vec3::new(0.25, 0.5, 0.5)), 0.0);
        assert!((g.eval(Vec3::new(0.5, 0.5, 0.5)) - 0.5).abs() < 1e-6);
        assert_eq!(g.eval(Vec3::new(0.9, 0.5, 0.5)), 1.0); // clamped beyond the last centre
        assert_eq!(g.eval(Vec3::new(1.5, 0.5, 0.5)), 0.0); // outside the cube
        assert_eq!(
            g.clip(Vec3::new(-1.0, 0.5, 0.5), Vec3::X, 10.0),
            Some((1.0, 2.0))
        );
        assert_eq!(g.clip(Vec3::new(-1.0, 1.5, 0.5), Vec3::X, 10.0), None);
    }

    #[test]
    fn bad_vol_files_are_refused_with_a_reason() {
        let good = vol_bytes([1, 1, 1], [0.0; 6], &[0.5]);
        let cases: [(Vec<u8>, &str); 5] = [
            (good[..20].to_vec(), "48-byte header"),
            ([b"VOX".as_slice(), &good[3..]].concat(), "magic"),
            (good[..50].to_vec(), "truncated"),
            (vol_bytes([1, 1, 1], [0.0; 6], &[-1.0]), "finite and >= 0"),
            (vol_bytes([0, 1, 1], [0.0; 6], &[]), "resolution"),
        ];
        for (bytes, says) in cases {
            match DensityGrid::from_vol(&bytes) {
                Ok(_) => panic!("accepted: {says}"),
                Err(e) => assert!(e.contains(says), "{e}"),
            }
        }
    }
}
