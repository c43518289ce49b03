//! Minimal PLY reader (Turk 1994 format, as written by Blender and Mitsuba's tools):
//! `ascii 1.0` and `binary_little_endian 1.0`, any scalar property type, `vertex` elements with
//! `x y z` and optional `nx ny nz`, `face` elements with a `vertex_indices` (or `vertex_index`)
//! list, n-gons fan-triangulated. Other elements and properties are parsed and skipped.
//! `binary_big_endian` and malformed files are errors naming the file and the header line or
//! the element.

use crate::error::{Error, Result};
use crate::scene::mesh::TriangleMesh;
use glam::Vec3;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

#[derive(Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for a list property.
    list: Option<Scalar>,
    ty: Scalar,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Source of property values: ASCII tokens or little-endian bytes.
enum Reader<'a> {
    Ascii {
        tokens: std::str::SplitAsciiWhitespace<'a>,
    },
    Binary {
        data: &'a [u8],
        pos: usize,
    },
}

impl Reader<'_> {
    fn value(&mut self, ty: Scalar) -> Option<f64> {
        match self {
            Reader::Ascii { tokens } => {
                let t = tokens.next()?;
                let v: f64 = t.parse().ok()?;
                Some(v)
            }
            Reader::Binary { data, pos } => {
                let n = ty.size();
                let b = data.get(*pos..*pos + n)?;
                *pos += n;
                Some(match ty {
                    Scalar::I8 => f64::from(b[0] as i8),
                    Scalar::U8 => f64::from(b[0]),
                    Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                    Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                    Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::F64 => {
                        f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                    }
                })
            }
        }
    }
}

/// Parses PLY bytes into a triangle mesh, with per-vertex normals when the file has
/// `nx ny nz` and texture coordinates when it has `u v` (or `s t`, `texture_u texture_v`),
/// stored as in the file. `file` is only used in error messages.
pub fn parse_ply(bytes: &[u8], file: &str) -> Result<TriangleMesh> {
    let err = |msg: String| ply_error(file, msg);
    let (lines, body_start) = header_lines(bytes, file)?;
    let (binary, elements) = parse_header(&lines, file)?;
    let body = &bytes[body_start..];
    let mut reader = if binary {
        Reader::Binary { data: body, pos: 0 }
    } else {
        let text = std::str::from_utf8(body).map_err(|_| err("ASCII body is not text".into()))?;
        Reader::Ascii {
            tokens: text.split_ascii_whitespace(),
        }
    };
    let mut data = Body::default();
    for e in &elements {
        read_element(e, &mut reader, &mut data, file)?;
    }
    triangulate(data, file)
}

/// The error `msg` about `file`.
fn ply_error(file: &str, msg: String) -> Error {
    Error::Ply {
        file: file.to_string(),
        msg,
    }
}

/// The header's lines (ASCII, trimmed) up to and including `end_header`, and the offset of
/// the body after it.
fn header_lines(bytes: &[u8], file: &str) -> Result<(Vec<String>, usize)> {
    let err = |msg: String| ply_error(file, msg);
    let mut pos = 0usize;
    let mut lines = Vec::new();
    loop {
        let rest = &bytes[pos..];
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            return Err(err("no end_header line".into()));
        };
        let line = std::str::from_utf8(&rest[..nl])
            .map_err(|_| err(format!("header line {} is not text", lines.len() + 1)))?
            .trim_end_matches('\r')
            .trim()
            .to_string();
        pos += nl + 1;
        let end = line == "end_header";
        lines.push(line);
        if end {
            break;
        }
        if lines.len() > 10_000 {
            return Err(err("header longer than 10000 lines".into()));
        }
    }
    Ok((lines, pos))
}

/// The header's format (`true`: binary little endian) and its elements with their
/// properties; errors name the header line.
fn parse_header(lines: &[String], file: &str) -> Result<(bool, Vec<Element>)> {
    let err = |msg: String| ply_error(file, msg);
    if lines.first().map(String::as_str) != Some("ply") {
        return Err(err("line 1: not a PLY file (expected \"ply\")".into()));
    }
    let mut binary = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in lines.iter().enumerate().skip(1) {
        let ln = i + 1;
        let tok: Vec<&str> = line.split_whitespace().collect();
        match tok.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] | ["end_header"] => {}
            ["format", f, _ver] => {
                binary = Some(match *f {
                    "ascii" => false,
                    "binary_little_endian" => true,
                    other => {
                        return Err(err(format!(
                            "line {ln}: unsupported format \"{other}\" (ascii and binary_little_endian are)"
                        )))
                    }
                })
            }
            ["element", name, count] => {
                let count: usize = count
                    .parse()
                    .map_err(|_| err(format!("line {ln}: bad element count \"{count}\"")))?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", ct, it, name] => {
                let (Some(ct), Some(it)) = (Scalar::parse(ct), Scalar::parse(it)) else {
                    return Err(err(format!("line {ln}: unknown list type in \"{line}\"")));
                };
                let e = elements
                    .last_mut()
                    .ok_or_else(|| err(format!("line {ln}: property before any element")))?;
                e.props.push(Property {
                    name: name.to_string(),
                    list: Some(ct),
                    ty: it,
                });
            }
            ["property", ty, name] => {
                let ty = Scalar::parse(ty)
                    .ok_or_else(|| err(format!("line {ln}: unknown property type \"{ty}\"")))?;
                let e = elements
                    .last_mut()
                    .ok_or_else(|| err(format!("line {ln}: property before any element")))?;
                e.props.push(Property {
                    name: name.to_string(),
                    list: None,
                    ty,
                });
            }
            _ => return Err(err(format!("line {ln}: cannot parse header line \"{line}\""))),
        }
    }
    let binary = binary.ok_or_else(|| err("no format line in the header".into()))?;
    Ok((binary, elements))
}

/// What the body's `vertex` and `face` elements hold.
#[derive(Default)]
struct Body {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uvs: Vec<glam::Vec2>,
    /// Vertex indices of each face (n-gons, not yet triangulated).
    faces: Vec<Vec<u32>>,
}

/// Reads the `e.count` items of element `e`: positions, normals and uvs of a `vertex`
/// element and the index lists of a `face` element go to `data`; other elements and
/// properties are read and dropped.
fn read_element(e: &Element, reader: &mut Reader, data: &mut Body, file: &str) -> Result<()> {
    let err = |msg: String| ply_error(file, msg);
    let is_vertex = e.name == "vertex";
    let is_face = e.name == "face";
    let find = |n: &str| e.props.iter().position(|p| p.name == n && p.list.is_none());
    let xyz = [find("x"), find("y"), find("z")];
    let nxyz = [find("nx"), find("ny"), find("nz")];
    let has_n = nxyz.iter().all(Option::is_some);
    let uv = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"]]
        .iter()
        .map(|[a, b]| (find(a), find(b)))
        .find(|(a, b)| a.is_some() && b.is_some());
    if is_vertex && xyz.iter().any(Option::is_none) {
        return Err(err("vertex element lacks x, y or z".into()));
    }
    let idx_prop = e
        .props
        .iter()
        .position(|p| p.list.is_some() && (p.name == "vertex_indices" || p.name == "vertex_index"));
    if is_face && idx_prop.is_none() {
        return Err(err("face element lacks a vertex_indices list".into()));
    }
    if e.count > 1 << 28 {
        return Err(err(format!(
            "element {} count {} is too large",
            e.name, e.count
        )));
    }
    let mut vals = vec![0.0f64; e.props.len()];
    for k in 0..e.count {
        let short = || {
            err(format!(
                "element {} {k}: file ends early or a value does not parse",
                e.name
            ))
        };
        for (j, p) in e.props.iter().enumerate() {
            match p.list {
                None => vals[j] = reader.value(p.ty).ok_or_else(short)?,
                Some(ct) => {
                    let n = reader.value(ct).ok_or_else(short)?;
                    if !(0.0..=1024.0).contains(&n) || n.fract() != 0.0 {
                        return Err(err(format!("element {} {k}: bad list length {n}", e.name)));
                    }
                    let mut list = Vec::with_capacity(n as usize);
                    for _ in 0..n as usize {
                        list.push(reader.value(p.ty).ok_or_else(short)?);
                    }
                    if is_face && Some(j) == idx_prop {
                        data.faces.push(face_indices(list, k, file)?);
                    }
                }
            }
        }
        if is_vertex {
            let g = |i: Option<usize>| vals[i.unwrap_or(0)] as f32;
            data.positions
                .push(Vec3::new(g(xyz[0]), g(xyz[1]), g(xyz[2])));
            if has_n {
                data.normals
                    .push(Vec3::new(g(nxyz[0]), g(nxyz[1]), g(nxyz[2])).normalize_or_zero());
            }
            if let Some((a, b)) = uv {
                data.uvs.push(glam::Vec2::new(g(a), g(b)));
            }
        }
    }
    Ok(())
}

/// The vertex indices of face `k` from its list of values: at least 3, each a whole number
/// in `[0, u32::MAX)`.
#[inline]
fn face_indices(list: Vec<f64>, k: usize, file: &str) -> Result<Vec<u32>> {
    if list.len() < 3 {
        return Err(ply_error(
            file,
            format!("face {k} has fewer than 3 vertices"),
        ));
    }
    let mut f = Vec::with_capacity(list.len());
    for v in list {
        if !(v >= 0.0 && v.fract() == 0.0 && v < u32::MAX as f64) {
            return Err(ply_error(file, format!("face {k}: bad vertex index {v}")));
        }
        f.push(v as u32);
    }
    Ok(f)
}

/// The mesh of the body: faces fan-triangulated (indices checked against the vertices),
/// normals if the vertices have them, uvs if every vertex has one.
fn triangulate(data: Body, file: &str) -> Result<TriangleMesh> {
    let err = |msg: String| ply_error(file, msg);
    let Body {
        positions: pos3,
        normals: nrm,
        uvs,
        faces,
    } = data;
    let has_uv = !uvs.is_empty() && uvs.len() == pos3.len();
    let mut indices = Vec::new();
    for (k, f) in faces.iter().enumerate() {
        if let Some(&bad) = f.iter().find(|&&v| v as usize >= pos3.len()) {
            return Err(err(format!(
                "face {k}: vertex index {bad} out of range (have {})",
                pos3.len()
            )));
        }
        for j in 1..f.len() - 1 {
            indices.push([f[0], f[j], f[j + 1]]);
        }
    }
    if indices.is_empty() {
        return Err(err("no faces".into()));
    }
    Ok(TriangleMesh {
        positions: pos3,
        normals: (!nrm.is_empty()).then(|| nrm.into_iter().map(Some).collect()),
        uvs: has_uv.then(|| uvs.into_iter().map(Some).collect()),
        indices,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ASCII: &str = "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 0 0 1 0\n1 0 0 0 0 1 0\n1 1 0 0 0 1 0\n0 1 0 0 0 1 0\n4 0 1 2 3\n";

    #[test]
    fn ascii_quad_with_normals() {
        let t = parse_ply(ASCII.as_bytes(), "q.ply").expect("parses");
        assert_eq!(t.indices.len(), 2);
        assert_eq!(
            t.triangle(1),
            [
                Vec3::ZERO,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0)
            ]
        );
        assert_eq!(t.triangle_normals(1), Some([Vec3::Z; 3]));
    }

    /// The same quad as binary little endian with double positions, a ushort extra property,
    /// an int count and uint indices, plus an unknown element that is skipped.
    #[test]
    fn binary_little_endian_matches_ascii() {
        let mut b = b"ply\r\nformat binary_little_endian 1.0\r\nelement vertex 4\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\nproperty ushort flags\r\nelement face 1\r\nproperty list int uint vertex_index\r\nelement extra 2\r\nproperty char c\r\nend_header\r\n".to_vec();
        for p in [
            [0.0f64, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ] {
            for c in p {
                b.extend_from_slice(&c.to_le_bytes());
            }
            b.extend_from_slice(&7u16.to_le_bytes());
        }
        b.extend_from_slice(&4i32.to_le_bytes());
        for i in [0u32, 1, 2, 3] {
            b.extend_from_slice(&i.to_le_bytes());
        }
        b.extend_from_slice(&[1, 2]);
        let t = parse_ply(&b, "q.ply").expect("parses");
        let a = parse_ply(ASCII.as_bytes(), "q.ply").expect("parses");
        assert_eq!(t.indices.len(), 2);
        for k in 0..2 {
            assert_eq!(t.triangle(k), a.triangle(k));
            assert!(t.triangle_normals(k).is_none());
        }
        // Truncated body: an error naming the element, no panic.
        let e = parse_ply(&b[..b.len() - 20], "q.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("q.ply") && e.contains("face 0"), "{e}");
    }

    #[test]
    fn errors_name_the_problem() {
        let big = ASCII.replace("ascii", "binary_big_endian");
        let e = parse_ply(big.as_bytes(), "b.ply").unwrap_err().to_string();
        assert!(
            e.contains("b.ply") && e.contains("line 2") && e.contains("big_endian"),
            "{e}"
        );
        let bad_idx = ASCII.replace("4 0 1 2 3", "3 0 1 9");
        let e = parse_ply(bad_idx.as_bytes(), "b.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("index 9"), "{e}");
        let e = parse_ply(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty foo x\nend_header\n",
            "b.ply",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("line 4") && e.contains("foo"), "{e}");
        assert!(parse_ply(b"obj\n", "b.ply").is_err());
        assert!(parse_ply(b"ply\nformat ascii 1.0\n", "b.ply").is_err());
    }
}
