//! Minimal Wavefront OBJ reader: `v`, `vn`, `vt`, `f` with n-gons (fan-triangulated)
//! in the `v`, `v/vt`, `v//vn` and `v/vt/vn` forms, negative (relative) indices. Several
//! objects / groups in one file become one mesh. Texture coordinates are flipped to
//! Mitsuba's convention (`v ↦ 1 − v`, image row 0 at `v = 0`), as Mitsuba's OBJ loader does.
//! Grouping/material statements (`o g s usemtl mtllib`) are accepted and ignored because they
//! do not affect geometry; anything else is an error naming the line.

use crate::error::{Error, Result};
use crate::scene::mesh::TriangleMesh;
use glam::{Vec2, Vec3};
use std::collections::HashMap;

/// Parses OBJ text into a triangle mesh. `file` is only used in error messages.
///
/// Vertices are split by their `(v, vt, vn)` triple. A face takes normals (texture
/// coordinates) only when every one of its corners names one; otherwise its vertices have
/// none (it is flat-shaded, gets the default texture coordinates).
pub fn parse_obj(text: &str, file: &str) -> Result<TriangleMesh> {
    let err = |line: usize, msg: String| Error::Obj {
        file: file.to_string(),
        line,
        msg,
    };
    let mut pos: Vec<Vec3> = Vec::new();
    let mut nrm: Vec<Vec3> = Vec::new();
    let mut tex: Vec<Vec2> = Vec::new();
    let mut mesh = TriangleMesh::default();
    let mut normals: Vec<Option<Vec3>> = Vec::new();
    let mut uvs: Vec<Option<Vec2>> = Vec::new();
    let (mut any_n, mut any_uv) = (false, false);
    let mut vertex_of: HashMap<(usize, Option<usize>, Option<usize>), u32> = HashMap::new();
    for (ln, raw) in text.lines().enumerate() {
        let ln = ln + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut it = line.split_whitespace();
        let Some(tag) = it.next() else { continue };
        let floats = |it: std::str::SplitWhitespace, n: usize| -> Result<Vec<f32>> {
            let v: std::result::Result<Vec<f32>, _> = it.map(str::parse::<f32>).collect();
            let v = v.map_err(|e| err(ln, format!("bad number in \"{line}\": {e}")))?;
            if v.len() < n {
                return Err(err(ln, format!("expected {n} numbers in \"{line}\"")));
            }
            Ok(v)
        };
        match tag {
            "v" => {
                let v = floats(it, 3)?;
                pos.push(Vec3::new(v[0], v[1], v[2]));
            }
            "vn" => {
                let v = floats(it, 3)?;
                nrm.push(Vec3::new(v[0], v[1], v[2]).normalize_or_zero());
            }
            "vt" => {
                let v = floats(it, 1)?;
                tex.push(Vec2::new(v[0], 1.0 - v.get(1).copied().unwrap_or(0.0)));
            }
            "f" => {
                let mut verts = Vec::new();
                for tok in it {
                    let mut parts = tok.split('/');
                    let resolve =
                        |s: Option<&str>, len: usize, what: &str| -> Result<Option<usize>> {
                            match s {
                                None | Some("") => Ok(None),
                                Some(s) => {
                                    let i: i64 = s.parse().map_err(|_| {
                                        err(ln, format!("bad {what} index \"{s}\""))
                                    })?;
                                    let idx = if i > 0 { i - 1 } else { len as i64 + i };
                                    if i == 0 || idx < 0 || idx as usize >= len {
                                        return Err(err(
                                            ln,
                                            format!("{what} index {i} out of range (have {len})"),
                                        ));
                                    }
                                    Ok(Some(idx as usize))
                                }
                            }
                        };
                    let vi = resolve(parts.next(), pos.len(), "vertex")?.ok_or_else(|| {
                        err(ln, format!("face vertex \"{tok}\" has no position index"))
                    })?;
                    let ti = resolve(parts.next(), tex.len(), "texture")?;
                    let ni = resolve(parts.next(), nrm.len(), "normal")?;
                    verts.push((vi, ni, ti));
                }
                if verts.len() < 3 {
                    return Err(err(ln, "face with fewer than 3 vertices".into()));
                }
                let all_n = verts.iter().all(|v| v.1.is_some());
                let all_t = verts.iter().all(|v| v.2.is_some());
                any_n |= all_n;
                any_uv |= all_t;
                let mut ids = Vec::with_capacity(verts.len());
                for &(vi, ni, ti) in &verts {
                    let key = (
                        vi,
                        all_t.then_some(ti).flatten(),
                        all_n.then_some(ni).flatten(),
                    );
                    let id = *vertex_of.entry(key).or_insert_with(|| {
                        mesh.positions.push(pos[vi]);
                        uvs.push(key.1.map(|t| tex[t]));
                        normals.push(key.2.map(|n| nrm[n]));
                        (mesh.positions.len() - 1) as u32
                    });
                    ids.push(id);
                }
                for k in 1..ids.len() - 1 {
                    mesh.indices.push([ids[0], ids[k], ids[k + 1]]);
                }
            }
            "o" | "g" | "s" | "usemtl" | "mtllib" => {}
            other => return Err(err(ln, format!("unsupported statement \"{other}\""))),
        }
    }
    if mesh.indices.is_empty() {
        return Err(err(0, "no faces".into()));
    }
    mesh.normals = any_n.then_some(normals);
    mesh.uvs = any_uv.then_some(uvs);
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quad_and_forms() {
        let t = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nf 1//1 2//1 3//1 4//1\nf -4/1 -3/1 -2/1\n";
        let m = parse_obj(t, "x.obj").expect("parses");
        assert_eq!(m.indices.len(), 3);
        assert!(m.triangle_normals(0).is_some());
        assert!(m.triangle_normals(2).is_none());
    }

    #[test]
    fn errors_name_line() {
        let e = parse_obj("v 0 0 0\nf 1 2 3\n", "bad.obj")
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.obj:2"), "{e}");
        let e = parse_obj("v 0 0 0\ncurv 1 2\n", "bad.obj")
            .unwrap_err()
            .to_string();
        assert!(e.contains("curv"), "{e}");
    }
}
