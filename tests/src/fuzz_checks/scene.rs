//! Fuzz target `scene_parser`: arbitrary bytes through the Mitsuba XML and
//! OBJ loaders of `host-demo`.

use host_demo::scene::bsdf::Material;
use host_demo::scene::load::obj::parse_obj;
use host_demo::scene::load::ply::parse_ply;
use host_demo::scene::load::xml::load_str_with;
use host_demo::scene::{Prim, Scene};
use std::path::Path;

/// Inputs longer than this are not examined (the loaders are linear in the
/// input, except that every `obj` shape parses its mesh again: at most
/// `(64 KiB)²/40` bytes of OBJ text per input, well under a second).
pub const SCENE_INPUT_LIMIT: usize = 1 << 16;

/// Splits an input into the XML text and named OBJ meshes: `XML`, then for
/// each mesh a NUL byte, its file name, a newline and its text. The mesh
/// reader serves a requested path by exact name, else the first mesh (so any
/// `filename` finds some mesh), else reports the file as missing.
#[must_use]
pub fn split_scene_input(text: &str) -> (&str, Vec<(&str, &str)>) {
    let mut parts = text.split('\0');
    let xml = parts.next().unwrap_or("");
    let meshes = parts
        .map(|m| m.split_once('\n').unwrap_or((m, "")))
        .collect();
    (xml, meshes)
}

/// Builds a `scene_parser` input from an XML text and named meshes (the
/// inverse of [`split_scene_input`]), for seeds and tests.
#[must_use]
pub fn scene_input(xml: &str, meshes: &[(&str, &str)]) -> Vec<u8> {
    let mut out = xml.as_bytes().to_vec();
    for (name, text) in meshes {
        out.push(0);
        out.extend_from_slice(name.as_bytes());
        out.push(b'\n');
        out.extend_from_slice(text.as_bytes());
    }
    out
}

fn finite_non_negative(v: glam::Vec3) -> bool {
    v.is_finite() && v.min_element() >= 0.0
}

/// What a loaded scene must satisfy to be renderable: at least one
/// primitive, all finite with finite area (spheres: radius > 0), indices in
/// range, finite non-negative reflectance and emission, a finite GGX
/// `α > 0` and IOR, light tables with positive finite area and monotone
/// CDFs, a finite camera with positive finite field of view, positive image
/// size and sample count (any `max_depth`), media with finite non-negative coefficients,
/// `σs ≤ σt` and `|g| < 1`. Then a few camera rays must be finite unit
/// directions, they and light samples must not panic, and hits must be finite and inside the
/// ray's interval.
pub fn check_scene(what: &str, s: &Scene) {
    assert!(!s.prims.is_empty(), "{what}: no primitives");
    assert_eq!(s.prims.len(), s.prim_shape.len());
    for p in &s.prims {
        let ok = match *p {
            Prim::Tri { p, n } => {
                p.iter().all(|v| v.is_finite()) && n.is_none_or(|n| n.iter().all(|v| v.is_finite()))
            }
            Prim::Sphere { center, radius, .. } => center.is_finite() && radius > 0.0,
            Prim::Disk {
                center, a, b, n, ..
            } => center.is_finite() && a.is_finite() && b.is_finite() && n.is_finite(),
        };
        assert!(ok && p.area().is_finite(), "{what}: primitive {p:?}");
    }
    for &k in &s.prim_shape {
        assert!((k as usize) < s.shapes.len(), "{what}: shape index {k}");
    }
    for (i, shape) in s.shapes.iter().enumerate() {
        assert!((shape.material as usize) < s.materials.len());
        if let Some(e) = shape.emission {
            assert!(finite_non_negative(e), "{what}: shape {i} emission {e}");
        }
    }
    for (i, m) in s.media.iter().enumerate() {
        let ok = finite_non_negative(m.sigma_t)
            && finite_non_negative(m.sigma_s)
            && (m.sigma_s - m.sigma_t).max_element() <= 0.0
            && m.g > -1.0
            && m.g < 1.0;
        assert!(ok, "{what}: medium {i} {m:?}");
    }
    for m in &s.materials {
        let ok = match *m {
            Material::Diffuse { reflectance } => finite_non_negative(reflectance),
            Material::RoughDiffuse {
                reflectance, alpha, ..
            } => finite_non_negative(reflectance) && alpha.is_finite() && alpha >= 0.0,
            Material::RoughConductor {
                alpha,
                eta,
                k,
                specular,
                distribution: _,
            } => {
                alpha.is_finite()
                    && alpha > 0.0
                    && finite_non_negative(eta)
                    && finite_non_negative(k)
                    && finite_non_negative(specular)
            }
            Material::Conductor { eta, k, specular } => {
                finite_non_negative(eta) && finite_non_negative(k) && finite_non_negative(specular)
            }
            Material::Dielectric {
                eta,
                reflectance,
                transmittance,
            }
            | Material::ThinDielectric {
                eta,
                reflectance,
                transmittance,
            } => {
                eta.is_finite()
                    && eta > 0.0
                    && finite_non_negative(reflectance)
                    && finite_non_negative(transmittance)
            }
            Material::RoughDielectric {
                alpha,
                eta,
                reflectance,
                transmittance,
                distribution: _,
            } => {
                alpha.is_finite()
                    && alpha > 0.0
                    && eta.is_finite()
                    && eta > 0.0
                    && finite_non_negative(reflectance)
                    && finite_non_negative(transmittance)
            }
            Material::Plastic(c) | Material::RoughPlastic(c) => {
                finite_non_negative(c.diffuse)
                    && finite_non_negative(c.specular)
                    && c.eta.is_finite()
                    && c.eta > 0.0
                    && c.alpha.is_finite()
                    && c.alpha >= 0.0
                    && c.internal.is_finite()
                    && c.ext_t.iter().all(|t| t.is_finite())
            }
            Material::Phong {
                exponent,
                diffuse,
                specular,
                scale,
            } => {
                exponent.is_finite()
                    && exponent >= 0.0
                    && finite_non_negative(diffuse)
                    && finite_non_negative(specular)
                    && scale > 0.0
                    && scale <= 1.0
            }
            Material::Ward {
                alpha_u,
                alpha_v,
                diffuse,
                specular,
                scale,
                ..
            } => {
                alpha_u.is_finite()
                    && alpha_u > 0.0
                    && alpha_v.is_finite()
                    && alpha_v > 0.0
                    && finite_non_negative(diffuse)
                    && finite_non_negative(specular)
                    && scale > 0.0
                    && scale <= 1.0
            }
            Material::Blend { a, b, weight } => {
                (a as usize) < s.materials.len()
                    && (b as usize) < s.materials.len()
                    && (0.0..=1.0).contains(&weight)
            }
            Material::Null => true,
            // Made per medium vertex, never loaded as a material.
            Material::Phase { .. } => false,
            Material::TwoSided { front, back } => {
                (front as usize) < s.materials.len() && (back as usize) < s.materials.len()
            }
        };
        assert!(ok, "{what}: material {m:?}");
    }
    assert_eq!(s.shape_light.len(), s.shapes.len());
    for l in &s.lights {
        assert!(
            l.area.is_finite() && l.area > 0.0,
            "{what}: light area {}",
            l.area
        );
        assert!(!l.prims.is_empty() && l.prims.len() == l.cdf.len());
        assert!(l.prims.iter().all(|&p| (p as usize) < s.prims.len()));
        assert!(l.cdf.windows(2).all(|w| w[0] <= w[1]));
    }
    let c = &s.camera;
    assert!(c.to_world.is_finite(), "{what}: camera {c:?}");
    assert!(
        c.tan_x.is_finite() && c.tan_x > 0.0 && c.tan_y.is_finite() && c.tan_y > 0.0,
        "{what}: camera {c:?}"
    );
    let st = &s.settings;
    // (`max_depth = 0` is valid Mitsuba: an all-black image.)
    assert!(st.width >= 1 && st.height >= 1 && st.spp >= 1);

    for (u, v) in [(0.5, 0.5), (0.0, 0.0), (1.0, 1.0), (0.25, 0.75)] {
        let (o, d) = c.ray(u, v);
        // A singular sensor transform gives zero / NaN directions (the loader refuses it).
        assert!(
            o.is_finite() && d.is_finite() && (d.length() - 1.0).abs() < 1e-3,
            "{what}: camera ray {o} {d} at ({u}, {v})"
        );
        if let Some(h) = s.intersect(o, d, 1e-4, f32::INFINITY) {
            assert!(h.t > 1e-4 && h.t.is_finite(), "{what}: hit t = {}", h.t);
            assert!((h.shape as usize) < s.shapes.len());
        }
        let _ = s.occluded(o, d, 1e-4, 1.0);
        // Through media and null surfaces: a transmittance in [0, 1] per channel.
        let mut rng = guiding_core::rng::Pcg32::new(1, 2);
        let tr = s.transmittance(o, d, f32::INFINITY, s.camera_medium, &mut rng);
        assert!(
            tr.is_finite() && tr.min_element() >= 0.0 && tr.max_element() <= 1.0,
            "{what}: transmittance {tr}"
        );
        if let Some(es) = s.sample_emitter(o, u, v, 0.5) {
            assert!(es.pdf.is_finite() && es.pdf > 0.0, "{what}: emitter pdf");
            assert!(
                es.wo.is_finite() && es.radiance.is_finite(),
                "{what}: emitter sample"
            );
        }
    }
}

/// Fuzz target `scene_parser`: an input (at most [`SCENE_INPUT_LIMIT`]
/// bytes, decoded as lossy UTF-8, split by [`split_scene_input`]) goes
/// through `parse_obj` (each mesh), `parse_ply` (the raw bytes) and `load_str_with` (the XML, meshes
/// served from the input). Each must return an error, whose message is not
/// empty, or a result that passes [`check_scene`] (for OBJ: at least one
/// triangle). Never a panic; a hang shows as a fuzzer timeout.
pub fn scene_parser(data: &[u8]) {
    if data.len() > SCENE_INPUT_LIMIT {
        return;
    }
    let text = String::from_utf8_lossy(data);
    let (xml, meshes) = split_scene_input(&text);
    let objs: Vec<&str> = if meshes.is_empty() {
        vec![xml]
    } else {
        meshes.iter().map(|m| m.1).collect()
    };
    for obj in objs {
        match parse_obj(obj, "fuzz.obj") {
            Ok(mesh) => assert!(!mesh.indices.is_empty()),
            Err(e) => assert!(!e.to_string().is_empty()),
        }
    }
    // The same bytes as a PLY file (ASCII or binary): an error or triangles.
    match parse_ply(data, "fuzz.ply") {
        Ok(mesh) => assert!(!mesh.indices.is_empty()),
        Err(e) => assert!(!e.to_string().is_empty()),
    }
    let read = |path: &Path| -> std::io::Result<Vec<u8>> {
        let name = path.to_string_lossy();
        meshes
            .iter()
            .find(|m| m.0 == name)
            .or(meshes.first())
            .map(|m| m.1.as_bytes().to_vec())
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::NotFound))
    };
    match load_str_with(xml, "fuzz.xml", Path::new(""), &read) {
        Ok(scene) => check_scene("fuzz.xml", &scene),
        Err(e) => assert!(!e.to_string().is_empty()),
    }
}
