//! Reader for Mitsuba's `.serialized` meshes (format version 3 and 4).
//!
//! Layout (little-endian), from the Mitsuba 0.6 / 3 `serialized` plugin documentation:
//! every shape starts with an uncompressed header `u16 0x041C`, `u16 version` (3 or 4),
//! followed by a zlib stream holding `u32 flags` (`0x0001` vertex normals, `0x0002` uvs,
//! `0x0008` vertex colours, `0x0010` face normals, `0x1000` single / `0x2000` double
//! precision), for version 4 a zero-terminated UTF-8 name, `u64` vertex count, `u64`
//! triangle count, then the positions, the optional normals, uvs and colours (f32 or f64)
//! and the triangle indices (`u32`, or `u64` when there are more than `2³² − 1` vertices).
//! The file ends with a dictionary of shape offsets (`u64` each for version 4, `u32` for
//! version 3) and a `u32` shape count; `shape_index` picks the shape.
//!
//! Vertex colours are skipped. Texture coordinates are kept as stored (no `v` flip); normals
//! are normalised.

use crate::error::{Error, Result};
use crate::scene::mesh::TriangleMesh;
use glam::{Vec2, Vec3};
use std::io::Read;

/// One shape of a `.serialized` file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SerializedMesh {
    /// Shape name (version 4 files; empty for version 3).
    pub name: String,
    /// The triangles, with the vertex normals (normalised) and uvs if stored.
    pub mesh: TriangleMesh,
    /// The file asks for face normals (flag `0x0010`).
    pub face_normals: bool,
}

/// Shape flag: vertex normals present.
pub const HAS_NORMALS: u32 = 0x0001;
/// Shape flag: texture coordinates present.
pub const HAS_UVS: u32 = 0x0002;
/// Shape flag: vertex colours present.
pub const HAS_COLORS: u32 = 0x0008;
/// Shape flag: face normals requested.
pub const FACE_NORMALS: u32 = 0x0010;
/// Shape flag: single-precision floats.
pub const SINGLE_PRECISION: u32 = 0x1000;
/// Shape flag: double-precision floats.
pub const DOUBLE_PRECISION: u32 = 0x2000;
/// File header magic.
pub const MAGIC: u16 = 0x041C;

/// Parses shape `shape_index` of a `.serialized` file. `file` names it in errors.
pub fn parse_serialized(bytes: &[u8], shape_index: u32, file: &str) -> Result<SerializedMesh> {
    let err = |msg: String| Error::Serialized {
        file: file.to_string(),
        msg,
    };
    let u16_at = |o: usize| -> Option<u16> {
        bytes
            .get(o..o + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    let (magic, version) = (u16_at(0), u16_at(2));
    if magic != Some(MAGIC) {
        return Err(err("not a Mitsuba .serialized file (bad header)".into()));
    }
    let version = version.unwrap_or(0);
    if version != 3 && version != 4 {
        return Err(err(format!(
            "unsupported format version {version} (3 and 4 are)"
        )));
    }
    let offset = if shape_index == 0 {
        0usize
    } else {
        let n = bytes.len();
        let count = n
            .checked_sub(4)
            .and_then(|o| bytes.get(o..o + 4))
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| err("truncated end-of-file dictionary".into()))?;
        if shape_index >= count {
            return Err(err(format!(
                "shape_index {shape_index} out of range (the file has {count} shapes)"
            )));
        }
        let k = (count - shape_index) as usize;
        let off = if version == 4 {
            n.checked_sub(8 * k + 4)
                .and_then(|o| bytes.get(o..o + 8))
                .map(|b| u64::from_le_bytes(b.try_into().unwrap_or([0; 8])) as usize)
        } else {
            n.checked_sub(4 * k + 4)
                .and_then(|o| bytes.get(o..o + 4))
                .map(|b| u32::from_le_bytes(b.try_into().unwrap_or([0; 4])) as usize)
        }
        .ok_or_else(|| err("truncated end-of-file dictionary".into()))?;
        if u16_at(off) != Some(MAGIC) || u16_at(off + 2) != Some(version) {
            return Err(err(format!(
                "shape {shape_index}: no shape header at offset {off}"
            )));
        }
        off
    };
    let stream = bytes
        .get(offset + 4..)
        .ok_or_else(|| err("truncated".into()))?;
    let mut z = flate2::read::ZlibDecoder::new(stream);
    let mut rd = Reader {
        z: &mut z,
        err: &err,
    };
    let flags = rd.u32()?;
    let mut name = String::new();
    if version == 4 {
        let mut raw = Vec::new();
        loop {
            let b = rd.bytes(1)?[0];
            if b == 0 {
                break;
            }
            raw.push(b);
            if raw.len() > 1 << 16 {
                return Err(err("shape name is not terminated".into()));
            }
        }
        name = String::from_utf8_lossy(&raw).into_owned();
    }
    let nv = rd.u64()?;
    let nt = rd.u64()?;
    // Plausibility before allocating: every vertex needs at least 12 bytes, every triangle 12.
    if nv > 1 << 32 || nt > 1 << 32 {
        return Err(err(format!(
            "implausible sizes: {nv} vertices, {nt} triangles"
        )));
    }
    let (nv, nt) = (nv as usize, nt as usize);
    let double = flags & DOUBLE_PRECISION != 0;
    if double && flags & SINGLE_PRECISION != 0 {
        return Err(err("both single and double precision flags are set".into()));
    }
    let positions = rd.vecs(nv, double)?;
    let normals = if flags & HAS_NORMALS != 0 {
        let n = rd.vecs(nv, double)?;
        Some(n.into_iter().map(|n| Some(n.normalize_or_zero())).collect())
    } else {
        None
    };
    let uvs = if flags & HAS_UVS != 0 {
        let v = rd.floats(nv * 2, double)?;
        Some(
            v.chunks_exact(2)
                .map(|c| Some(Vec2::new(c[0], c[1])))
                .collect(),
        )
    } else {
        None
    };
    if flags & HAS_COLORS != 0 {
        rd.floats(nv * 3, double)?;
    }
    let wide = nv > u32::MAX as usize;
    let mut indices = Vec::with_capacity(nt);
    let raw = rd.bytes(nt * 3 * if wide { 8 } else { 4 })?;
    for t in 0..nt {
        let mut tri = [0u32; 3];
        for (k, slot) in tri.iter_mut().enumerate() {
            let i = if wide {
                let o = (t * 3 + k) * 8;
                u64::from_le_bytes(raw[o..o + 8].try_into().unwrap_or([0; 8])) as usize
            } else {
                let o = (t * 3 + k) * 4;
                u32::from_le_bytes(raw[o..o + 4].try_into().unwrap_or([0; 4])) as usize
            };
            if i >= nv {
                return Err(err(format!(
                    "triangle {t} refers to vertex {i} (the shape has {nv})"
                )));
            }
            *slot = i as u32;
        }
        indices.push(tri);
    }
    Ok(SerializedMesh {
        name,
        mesh: TriangleMesh {
            positions,
            normals,
            uvs,
            indices,
        },
        face_normals: flags & FACE_NORMALS != 0,
    })
}

struct Reader<'a, R: Read> {
    z: &'a mut R,
    err: &'a dyn Fn(String) -> Error,
}

impl<R: Read> Reader<'_, R> {
    fn bytes(&mut self, n: usize) -> Result<Vec<u8>> {
        let mut v = Vec::new();
        // `take` + `read_to_end` grows the buffer with the data actually present, so a
        // lying count cannot make us allocate more than the stream holds.
        (&mut *self.z)
            .take(n as u64)
            .read_to_end(&mut v)
            .map_err(|e| (self.err)(format!("zlib stream: {e}")))?;
        if v.len() != n {
            return Err((self.err)(format!(
                "truncated shape data (needed {n} more bytes, got {})",
                v.len()
            )));
        }
        Ok(v)
    }
    fn u32(&mut self) -> Result<u32> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<u64> {
        let b = self.bytes(8)?;
        Ok(u64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
    }
    fn floats(&mut self, n: usize, double: bool) -> Result<Vec<f32>> {
        if double {
            let b = self.bytes(n * 8)?;
            Ok(b.chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32)
                .collect())
        } else {
            let b = self.bytes(n * 4)?;
            Ok(b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect())
        }
    }
    fn vecs(&mut self, n: usize, double: bool) -> Result<Vec<Vec3>> {
        let v = self.floats(n * 3, double)?;
        Ok(v.chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect())
    }
}

/// Writes meshes as a version-4 `.serialized` file (single precision), the inverse of
/// [`parse_serialized`] (up to the normalisation of normals); for tests and the load-time
/// benchmark. A vertex without a normal (uv) in a mesh with them is written as zero.
pub fn write_serialized(meshes: &[SerializedMesh]) -> Vec<u8> {
    use std::io::Write;
    let mut out = Vec::new();
    let mut offsets = Vec::new();
    for sm in meshes {
        let m = &sm.mesh;
        offsets.push(out.len() as u64);
        out.extend_from_slice(&MAGIC.to_le_bytes());
        out.extend_from_slice(&4u16.to_le_bytes());
        let mut flags = SINGLE_PRECISION;
        if m.normals.is_some() {
            flags |= HAS_NORMALS;
        }
        if m.uvs.is_some() {
            flags |= HAS_UVS;
        }
        if sm.face_normals {
            flags |= FACE_NORMALS;
        }
        let mut raw = Vec::new();
        raw.extend_from_slice(&flags.to_le_bytes());
        raw.extend_from_slice(sm.name.as_bytes());
        raw.push(0);
        raw.extend_from_slice(&(m.positions.len() as u64).to_le_bytes());
        raw.extend_from_slice(&(m.indices.len() as u64).to_le_bytes());
        for p in &m.positions {
            for c in p.to_array() {
                raw.extend_from_slice(&c.to_le_bytes());
            }
        }
        for n in m.normals.iter().flatten() {
            for c in n.unwrap_or(Vec3::ZERO).to_array() {
                raw.extend_from_slice(&c.to_le_bytes());
            }
        }
        for uv in m.uvs.iter().flatten() {
            for c in uv.unwrap_or(Vec2::ZERO).to_array() {
                raw.extend_from_slice(&c.to_le_bytes());
            }
        }
        for t in &m.indices {
            for i in t {
                raw.extend_from_slice(&i.to_le_bytes());
            }
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        // Writing into a Vec cannot fail.
        let _ = z.write_all(&raw);
        out.extend(z.finish().unwrap_or_default());
    }
    for o in &offsets {
        out.extend_from_slice(&o.to_le_bytes());
    }
    out.extend_from_slice(&(meshes.len() as u32).to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_two_shapes() {
        let a = SerializedMesh {
            name: "a".into(),
            mesh: TriangleMesh {
                positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
                normals: Some(vec![Some(Vec3::Z); 3]),
                uvs: Some(vec![Some(Vec2::ZERO), Some(Vec2::X), Some(Vec2::Y)]),
                indices: vec![[0, 1, 2]],
            },
            face_normals: false,
        };
        let b = SerializedMesh {
            name: "b".into(),
            mesh: TriangleMesh {
                positions: vec![Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::ONE],
                normals: None,
                uvs: None,
                indices: vec![[0, 1, 2], [1, 3, 2]],
            },
            face_normals: true,
        };
        let bytes = write_serialized(&[a.clone(), b.clone()]);
        assert_eq!(parse_serialized(&bytes, 0, "x").expect("shape 0"), a);
        assert_eq!(parse_serialized(&bytes, 1, "x").expect("shape 1"), b);
        let e = parse_serialized(&bytes, 2, "x").unwrap_err().to_string();
        assert!(e.contains("out of range"), "{e}");
        let e = parse_serialized(&bytes[..20], 0, "x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated") || e.contains("zlib"), "{e}");
    }
}
