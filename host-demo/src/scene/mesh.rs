//! Indexed triangle meshes, as the mesh loaders ([`crate::scene::load::obj`],
//! [`crate::scene::load::ply`], [`crate::scene::load::serialized`]) return them, and their
//! conversion to scene primitives ([`TriangleMesh::primitives`]).

use crate::scene::{Prim, DEFAULT_TRI_UV};
use glam::{Mat4, Vec2, Vec3};

/// An indexed triangle mesh with optional per-vertex shading normals and texture
/// coordinates.
///
/// Attributes are per vertex and optional per vertex as well: a triangle is smooth-shaded
/// only when all three of its vertices have a normal, and takes its texture coordinates
/// from its vertices only when all three have one (otherwise [`DEFAULT_TRI_UV`]). Meshes
/// from PLY and `.serialized` files have either all or none; OBJ faces may lack `vn` / `vt`
/// while others have them (the OBJ reader splits vertices by their `(v, vt, vn)` triple).
/// Normals are unit length (or zero for a zero-length normal in the file): each loader
/// normalises them once, as it reads them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (`None` for the whole mesh when no vertex has one).
    pub normals: Option<Vec<Option<Vec3>>>,
    /// Per-vertex texture coordinates (`None` for the whole mesh when no vertex has any).
    pub uvs: Option<Vec<Option<Vec2>>>,
    /// Triangles (vertex indices, counter-clockwise around the geometric normal).
    pub indices: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Vertex positions of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        self.indices[t].map(|i| self.positions[i as usize])
    }

    /// Shading normals of triangle `t`, when all three of its vertices have one.
    pub fn triangle_normals(&self, t: usize) -> Option<[Vec3; 3]> {
        let n = self.normals.as_ref()?;
        let [a, b, c] = self.indices[t].map(|i| n[i as usize]);
        Some([a?, b?, c?])
    }

    /// Texture coordinates of triangle `t`, when all three of its vertices have one.
    pub fn triangle_uv(&self, t: usize) -> Option<[Vec2; 3]> {
        let uv = self.uvs.as_ref()?;
        let [a, b, c] = self.indices[t].map(|i| uv[i as usize]);
        Some([a?, b?, c?])
    }

    /// Applies the affine map `to_world`: positions as points, normals with the inverse
    /// transpose, renormalised.
    pub fn transform(&mut self, to_world: Mat4) {
        let nmat = Mat4::from_mat3(glam::Mat3::from_mat4(to_world).inverse().transpose());
        for p in &mut self.positions {
            *p = to_world.transform_point3(*p);
        }
        for n in self.normals.iter_mut().flatten().flatten() {
            *n = nmat.transform_vector3(*n).normalize_or_zero();
        }
    }

    /// One [`Prim::Tri`] per triangle, with the vertices' shading normals unless
    /// `face_normals` (then every triangle is flat-shaded).
    pub fn primitives(&self, face_normals: bool) -> Vec<Prim> {
        (0..self.indices.len())
            .map(|t| Prim::Tri {
                p: self.triangle(t),
                n: if face_normals {
                    None
                } else {
                    self.triangle_normals(t)
                },
            })
            .collect()
    }

    /// Per-triangle texture coordinates, one entry per [`TriangleMesh::primitives`] entry,
    /// when the mesh has any ([`DEFAULT_TRI_UV`] for triangles whose vertices lack them).
    pub fn triangle_uvs(&self) -> Option<Vec<[Vec2; 3]>> {
        self.uvs.as_ref()?;
        Some(
            (0..self.indices.len())
                .map(|t| self.triangle_uv(t).unwrap_or(DEFAULT_TRI_UV))
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::load::obj::parse_obj;
    use crate::scene::load::ply::parse_ply;
    use crate::scene::load::serialized::{parse_serialized, write_serialized, SerializedMesh};

    fn tri(p: &Prim) -> ([Vec3; 3], Option<[Vec3; 3]>) {
        match *p {
            Prim::Tri { p, n } => (p, n),
            _ => panic!("not a triangle"),
        }
    }

    /// The same quad (non-unit normals, uvs) as OBJ, PLY and `.serialized` gives identical
    /// primitives and texture coordinates, also after a transform.
    #[test]
    fn quad_is_identical_through_obj_ply_and_serialized() {
        let obj = "v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0.5\n\
                   vn 0 0 2\nvn 0 0.1 1\nvn 0 0 3\nvn 1 0 1\n\
                   vt 0 0.25\nvt 1 0.25\nvt 1 1\nvt 0 1\n\
                   f 1/1/1 2/2/2 3/3/3 4/4/4\n";
        // OBJ flips v (v ↦ 1 − v); PLY and .serialized store it as is.
        let ply = "ply\nformat ascii 1.0\nelement vertex 4\n\
                   property float x\nproperty float y\nproperty float z\n\
                   property float nx\nproperty float ny\nproperty float nz\n\
                   property float u\nproperty float v\n\
                   element face 1\nproperty list uchar int vertex_indices\nend_header\n\
                   0 0 0 0 0 2 0 0.75\n2 0 0 0 0.1 1 1 0.75\n2 1 0 0 0 3 1 0\n\
                   0 1 0.5 1 0 1 0 0\n4 0 1 2 3\n";
        let raw = TriangleMesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(2.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.5),
            ],
            normals: Some(
                [
                    Vec3::new(0.0, 0.0, 2.0),
                    Vec3::new(0.0, 0.1, 1.0),
                    Vec3::new(0.0, 0.0, 3.0),
                    Vec3::new(1.0, 0.0, 1.0),
                ]
                .map(Some)
                .to_vec(),
            ),
            uvs: Some(
                [
                    Vec2::new(0.0, 0.75),
                    Vec2::new(1.0, 0.75),
                    Vec2::new(1.0, 0.0),
                    Vec2::ZERO,
                ]
                .map(Some)
                .to_vec(),
            ),
            indices: vec![[0, 1, 2], [0, 2, 3]],
        };
        let bytes = write_serialized(&[SerializedMesh {
            name: "quad".into(),
            mesh: raw,
            face_normals: false,
        }]);
        let meshes = [
            parse_obj(obj, "q.obj").expect("obj"),
            parse_ply(ply.as_bytes(), "q.ply").expect("ply"),
            parse_serialized(&bytes, 0, "q.serialized")
                .expect("serialized")
                .mesh,
        ];
        let to_world = Mat4::from_scale_rotation_translation(
            Vec3::new(1.0, 2.0, 3.0),
            glam::Quat::from_rotation_y(0.3),
            Vec3::X,
        );
        for xf in [Mat4::IDENTITY, to_world] {
            let mut out = Vec::new();
            for m in &meshes {
                let mut m = m.clone();
                m.transform(xf);
                let prims: Vec<_> = m.primitives(false).iter().map(tri).collect();
                out.push((prims, m.triangle_uvs()));
            }
            let (prims, uvs) = &out[0];
            assert_eq!(prims.len(), 2);
            assert!(prims.iter().all(|t| t.1.is_some()));
            assert!(uvs.is_some());
            assert_eq!(out[1], out[0], "ply vs obj");
            assert_eq!(out[2], out[0], "serialized vs obj");
        }
        for m in &meshes {
            assert!(m.primitives(true).iter().all(|p| tri(p).1.is_none()));
        }
        // The normals are the file's, normalised.
        assert_eq!(
            meshes[0].triangle_normals(1),
            Some([Vec3::Z, Vec3::Z, Vec3::new(1.0, 0.0, 1.0).normalize()])
        );
    }

    /// OBJ faces without `vn` / `vt` in a mesh with them: flat-shaded, default uvs.
    #[test]
    fn mixed_obj_faces() {
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nvt 0 1\n\
                   f 1/1/1 2/1/1 3/1/1\nf 1 2 3\nf 1//1 2//1 3//1\n";
        let m = parse_obj(obj, "m.obj").expect("parses");
        let p: Vec<_> = m.primitives(false).iter().map(tri).collect();
        assert_eq!(p.len(), 3);
        assert!(p[0].1.is_some() && p[1].1.is_none() && p[2].1.is_some());
        let uv = m.triangle_uvs().expect("uvs");
        assert_eq!(uv[0], [Vec2::ZERO; 3]);
        assert_eq!(uv[1], DEFAULT_TRI_UV);
        assert_eq!(uv[2], DEFAULT_TRI_UV);
    }
}
