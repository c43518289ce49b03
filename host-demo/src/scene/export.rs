//! Writes a [`Scene`] as a Mitsuba 3 scene: `scene.xml` and one OBJ per shape, so that Mitsuba
//! (and this loader) render what host-demo renders — the built-in scenes in particular
//! (`host-demo export builtin:door --out door/`).
//!
//! What it writes: triangle shapes (face normals, or the shading normals they carry; uvs where
//! the scene has them), area emitters, the perspective camera (its `to_world` matrix and the
//! horizontal field of view), the film size, and the `path` integrator with the scene's
//! `max_depth` and `rr_depth`. Materials: `diffuse`, `twosided`, `plastic`, `roughplastic` and
//! `roughconductor`, with a checkerboard or constant diffuse reflectance. Anything else
//! (spheres, disks, other BSDFs, bitmaps, point lights, environments, masks, thin lenses) is
//! refused with what it is, never written approximately.

use super::bsdf::{Coating, Material, Microfacet};
use super::texture::{Texture, UvMap};
use super::{Prim, Scene};
use crate::error::{Error, Result};
use glam::Vec3;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn unsupported(what: &str) -> Error {
    Error::Scene(format!("export to Mitsuba: {what} is not supported"))
}

fn rgb(name: &str, v: Vec3) -> String {
    format!(r#"<rgb name="{name}" value="{}, {}, {}"/>"#, v.x, v.y, v.z)
}

fn distribution(d: Microfacet) -> &'static str {
    match d {
        Microfacet::Ggx => "ggx",
        Microfacet::Beckmann => "beckmann",
    }
}

/// The `diffuse_reflectance` / `reflectance` of a material: its texture, or the constant.
fn reflectance(scene: &Scene, name: &str, texture: Option<u32>, constant: Vec3) -> Result<String> {
    let Some(t) = texture else {
        return Ok(rgb(name, constant));
    };
    match scene.textures.get(t as usize) {
        Some(Texture::Checkerboard { color0, color1, uv }) => Ok(format!(
            r#"<texture type="checkerboard" name="{name}">{}{}{}</texture>"#,
            rgb("color0", *color0),
            rgb("color1", *color1),
            to_uv(uv)?
        )),
        _ => Err(unsupported("a bitmap texture")),
    }
}

/// `uv' = m uv + t` as Mitsuba's `to_uv` (a scale, then a translation).
fn to_uv(uv: &UvMap) -> Result<String> {
    let m = uv.m;
    if m.x_axis.y != 0.0 || m.y_axis.x != 0.0 {
        return Err(unsupported("a rotated or sheared uv map"));
    }
    Ok(format!(
        r#"<transform name="to_uv"><scale x="{}" y="{}"/><translate x="{}" y="{}"/></transform>"#,
        m.x_axis.x, m.y_axis.y, uv.t.x, uv.t.y
    ))
}

fn coating(scene: &Scene, c: &Coating, texture: Option<u32>, rough: bool) -> Result<String> {
    let body = format!(
        r#"<float name="int_ior" value="{}"/><float name="ext_ior" value="1"/><boolean name="nonlinear" value="{}"/>{}{}"#,
        c.eta,
        c.nonlinear,
        reflectance(scene, "diffuse_reflectance", texture, c.diffuse)?,
        rgb("specular_reflectance", c.specular)
    );
    Ok(if rough {
        format!(
            r#"<bsdf type="roughplastic"><string name="distribution" value="{}"/><float name="alpha" value="{}"/>{body}</bsdf>"#,
            distribution(c.distribution),
            c.alpha
        )
    } else {
        format!(r#"<bsdf type="plastic">{body}</bsdf>"#)
    })
}

/// Material `i` as a Mitsuba `<bsdf>` (a `twosided` nests its sides).
fn bsdf(scene: &Scene, i: u32) -> Result<String> {
    let m = scene
        .materials
        .get(i as usize)
        .ok_or_else(|| Error::Scene(format!("export: material {i} does not exist")))?;
    let tex = scene
        .material_textures
        .get(i as usize)
        .copied()
        .unwrap_or_default();
    if tex.specular.is_some() || tex.transmittance.is_some() || tex.scalar.is_some() {
        return Err(unsupported(
            "a textured parameter other than the diffuse reflectance",
        ));
    }
    match m {
        Material::Diffuse { reflectance: r } => Ok(format!(
            r#"<bsdf type="diffuse">{}</bsdf>"#,
            reflectance(scene, "reflectance", tex.diffuse, *r)?
        )),
        Material::TwoSided { front, back } if front == back => Ok(format!(
            r#"<bsdf type="twosided">{}</bsdf>"#,
            bsdf(scene, *front)?
        )),
        Material::TwoSided { front, back } => Ok(format!(
            r#"<bsdf type="twosided">{}{}</bsdf>"#,
            bsdf(scene, *front)?,
            bsdf(scene, *back)?
        )),
        Material::Plastic(c) => coating(scene, c, tex.diffuse, false),
        Material::RoughPlastic(c) => coating(scene, c, tex.diffuse, true),
        Material::RoughConductor {
            distribution: d,
            alpha,
            eta,
            k,
            specular,
        } if tex.diffuse.is_none() => Ok(format!(
            r#"<bsdf type="roughconductor"><string name="distribution" value="{}"/><float name="alpha" value="{alpha}"/>{}{}{}</bsdf>"#,
            distribution(*d),
            rgb("eta", *eta),
            rgb("k", *k),
            rgb("specular_reflectance", *specular)
        )),
        other => Err(unsupported(&format!("the material {other:?}"))),
    }
}

/// A triangle: vertices, uvs, shading normals.
type Triangle = ([Vec3; 3], Option<[glam::Vec2; 3]>, Option<[Vec3; 3]>);
/// The triangles of every shape, in shape order.
type ShapeTriangles = Vec<Vec<Triangle>>;

fn shape_triangles(scene: &Scene) -> Result<ShapeTriangles> {
    let mut shapes: ShapeTriangles = vec![Vec::new(); scene.shapes.len()];
    for (i, prim) in scene.prims.iter().enumerate() {
        let Prim::Tri { p, n } = prim else {
            return Err(unsupported("a sphere or disk primitive"));
        };
        let s = scene.prim_shape[i] as usize;
        shapes[s].push((*p, scene.uvs.get(i).copied(), *n));
    }
    Ok(shapes)
}

/// One shape as OBJ text (every triangle with its own vertices, so nothing is smoothed; `v`
/// written flipped, as OBJ readers flip it).
fn obj(tris: &[Triangle]) -> String {
    let mut s = String::new();
    for (p, uv, n) in tris {
        for v in p {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        // Mitsuba's OBJ loader (and this one) reads `vt u v` as `(u, 1 − v)`.
        for t in uv.iter().flatten() {
            let _ = writeln!(s, "vt {} {}", t.x, 1.0 - t.y);
        }
        for v in n.iter().flatten() {
            let _ = writeln!(s, "vn {} {} {}", v.x, v.y, v.z);
        }
    }
    let (mut v, mut t, mut n) = (1, 1, 1);
    for (_, uv, nn) in tris {
        let _ = write!(s, "f");
        for _ in 0..3 {
            let _ = match (uv.is_some(), nn.is_some()) {
                (true, true) => write!(s, " {v}/{t}/{n}"),
                (true, false) => write!(s, " {v}/{t}"),
                (false, true) => write!(s, " {v}//{n}"),
                (false, false) => write!(s, " {v}"),
            };
            v += 1;
            t += usize::from(uv.is_some());
            n += usize::from(nn.is_some());
        }
        s.push('\n');
    }
    s
}

/// Writes `scene` into `dir` (created if missing): `scene.xml` and `meshes/shape_N.obj`.
/// Returns the XML's path.
///
/// # Errors
/// [`Error::Scene`] for what Mitsuba cannot be given exactly (see the module docs);
/// [`Error::Io`] when a file cannot be written.
pub fn write_mitsuba(scene: &Scene, dir: &Path) -> Result<PathBuf> {
    if scene.env.is_some() || !scene.point_lights.is_empty() {
        return Err(unsupported("an environment or point light"));
    }
    if scene.camera.aperture_radius > 0.0 {
        return Err(unsupported("a thin-lens camera"));
    }
    if scene.has_volumes {
        return Err(unsupported("participating media or null surfaces"));
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| Error::Io { path, source }
    };
    let meshes = dir.join("meshes");
    std::fs::create_dir_all(&meshes).map_err(io(&meshes))?;
    let (c, st) = (&scene.camera, &scene.settings);
    let m = c.to_world.to_cols_array();
    let matrix: Vec<String> = (0..16)
        .map(|k| m[(k % 4) * 4 + k / 4].to_string())
        .collect();
    let mut xml = String::from("<scene version=\"3.0.0\">\n");
    let _ = writeln!(
        xml,
        r#"  <integrator type="path"><integer name="max_depth" value="{}"/><integer name="rr_depth" value="{}"/></integrator>"#,
        st.max_depth, st.rr_depth
    );
    let _ = writeln!(
        xml,
        r#"  <sensor type="perspective"><float name="fov" value="{}"/><string name="fov_axis" value="x"/><transform name="to_world"><matrix value="{}"/></transform><sampler type="independent"><integer name="sample_count" value="{}"/></sampler><film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/><rfilter type="box"/></film></sensor>"#,
        2.0 * c.tan_x.atan().to_degrees(),
        matrix.join(" "),
        st.spp,
        st.width,
        st.height
    );
    for (s, tris) in shape_triangles(scene)?.iter().enumerate() {
        let shape = &scene.shapes[s];
        if tris.is_empty() {
            continue;
        }
        if shape.opacity.is_some() {
            return Err(unsupported("a mask"));
        }
        let file = meshes.join(format!("shape_{s}.obj"));
        std::fs::write(&file, obj(tris)).map_err(io(&file))?;
        let emitter = shape.emission.map_or(String::new(), |e| {
            format!(r#"<emitter type="area">{}</emitter>"#, rgb("radiance", e))
        });
        let _ = writeln!(
            xml,
            r#"  <shape type="obj"><string name="filename" value="meshes/shape_{s}.obj"/><boolean name="face_normals" value="{}"/>{}{emitter}</shape>"#,
            tris.iter().all(|t| t.2.is_none()),
            bsdf(scene, shape.material)?
        );
    }
    xml.push_str("</scene>\n");
    let path = dir.join("scene.xml");
    std::fs::write(&path, xml).map_err(io(&path))?;
    Ok(path)
}
