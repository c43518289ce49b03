//! Scenes as users have them (issue #9): bitmap / checkerboard textures, `.serialized` meshes,
//! shapegroups and instances, `<include>`, `$param` defaults with `-D` overrides, the Mitsuba
//! 0.6 dialect, `mask`, `thindielectric`, `blendbsdf`, and the errors for what is refused.
//! Run with `cargo test --release -p host-demo --test real_scenes` (a few seconds).
//!
//! Render checks are z-tests of region means against their exact values, with each region's
//! standard error from the per-pixel sample variances and a Šidák-corrected threshold.

mod common;

use common::{assert_mentions, assert_warned};
use glam::{Vec2, Vec3};
use host_demo::render::{render, IntegratorKind, RenderOptions};
use host_demo::scene::bsdf::{Material, Microfacet};
use host_demo::scene::load::xml::{self, LoadOptions};
use host_demo::scene::{Prim, Scene};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Almost straight down the −z axis (slightly tilted so that no direction component is zero).
const DOWN: Vec3 = Vec3::new(1e-4, 2e-4, -0.999_999_97);

fn dir(name: &str) -> PathBuf {
    common::scratch_dir(&format!("real-{name}"))
}

/// Camera at `(0, 0, 5)` looking at the origin (image right = +x, image up = +y), `fov`
/// degrees, `res²` pixels, and `body`.
fn scene_xml(fov: f32, res: u32, max_depth: u32, body: &str) -> String {
    common::scene_doc(
        common::Dialect::V3,
        "0, 0, 5",
        "0, 0, 0",
        "0, 1, 0",
        fov,
        res,
        max_depth,
        body,
    )
}

fn load_in(text: &str, base: &Path) -> Scene {
    xml::load_str(text, "t.xml", base).unwrap_or_else(|e| panic!("loads: {e}\n{text}"))
}

fn load_err_in(text: &str, base: &Path) -> String {
    xml::load_str(text, "t.xml", base)
        .err()
        .expect("must fail")
        .to_string()
}

fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) {
    let f = std::fs::File::create(path).expect("create png");
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().expect("png header");
    wr.write_image_data(rgb).expect("png data");
}

fn srgb(v: u8) -> f32 {
    let c = f64::from(v) / 255.0;
    (if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }) as f32
}

/// Normal quantile for a two-sided test at family-wise level 1 % over `n` tests (Šidák).
fn z_threshold(n: usize) -> f64 {
    common::z_threshold(common::sidak(0.01, n))
}

/// A textured quad under a constant white environment (max_depth 2): a one-sided diffuse
/// surface facing the whole environment reflects exactly its albedo, so every pixel's
/// expected value is the (sRGB-decoded) texel it sees. The 2 × 2 texture fills the image, one
/// texel per quadrant (`nearest`), and each quadrant's mean must match its texel.
#[test]
fn textured_quad_shows_its_texels() {
    let d = dir("texquad");
    // Texel (column, row), row 0 = top of the image file.
    let texels: [[u8; 3]; 4] = [[200, 40, 40], [40, 200, 40], [40, 40, 200], [128, 128, 128]];
    write_png(&d.join("checker.png"), 2, 2, texels.as_flattened());
    let body = r#"
  <texture type="bitmap" id="tex"><string name="filename" value="checker.png"/>
    <string name="filter_type" value="nearest"/></texture>
  <texture type="bitmap" id="unused"><string name="filename" value="missing.png"/></texture>
  <shape type="rectangle"><bsdf type="diffuse"><ref name="reflectance" id="tex"/></bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let res = 32;
    let sc = load_in(&scene_xml(20.0, res, 2, body), &d);
    // Only the used texture is decoded (the unused one names a missing file).
    assert_eq!(sc.textures.len(), 1);
    assert_eq!(sc.texture_bytes, 2 * 2 * 3);
    let img = render(
        &sc,
        &RenderOptions {
            integrator: IntegratorKind::PtNee,
            spp: 32,
            max_depth: 2,
            seed: 7,
            width: res,
            height: res,
            ..RenderOptions::default()
        },
    );
    let z = z_threshold(4 * 3);
    let half = res / 2;
    for qy in 0..2u32 {
        for qx in 0..2u32 {
            // Image top = +y = v = 1 = the texture's bottom row.
            let texel = texels[((1 - qy) * 2 + qx) as usize];
            let (mut sum, mut var, mut n) = (Vec3::ZERO, Vec3::ZERO, 0.0f32);
            // Skip a 2-pixel band around the quadrant borders (pixel footprints straddle them).
            for y in qy * half + 2..(qy + 1) * half - 2 {
                for x in qx * half + 2..(qx + 1) * half - 2 {
                    let i = (y * res + x) as usize;
                    sum += Vec3::from(img.pixels[i]);
                    var += Vec3::from(img.var_of_mean[i]);
                    n += 1.0;
                }
            }
            let mean = sum / n;
            let se = var.map(f32::sqrt) / n;
            let want = Vec3::new(srgb(texel[0]), srgb(texel[1]), srgb(texel[2]));
            for c in 0..3 {
                let zc = f64::from((mean[c] - want[c]).abs() / se[c].max(1e-6));
                assert!(
                    zc < z,
                    "quadrant ({qx},{qy}) channel {c}: mean {} vs texel {} (z = {zc:.2}, threshold {z:.2})",
                    mean[c],
                    want[c]
                );
            }
        }
    }
}

/// `checkerboard` and `bitmap` sampling through the loaded scene: `to_uv` scaling, bilinear
/// filtering between texel centres, `raw` (no sRGB decoding) and `wrap_mode`.
#[test]
fn texture_lookups_through_the_loader() {
    let d = dir("texlookup");
    write_png(&d.join("ramp.png"), 2, 1, &[0, 0, 0, 255, 255, 255]);
    let body = |tex: &str| {
        format!(
            r#"<shape type="rectangle"><bsdf type="diffuse">{tex}</bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#
        )
    };
    let eval = |tex: &str, uv: Vec2| {
        let sc = load_in(&scene_xml(20.0, 4, 2, &body(tex)), &d);
        sc.shade(sc.shapes[0].material, uv)
    };
    let refl = |m: Material| match m {
        Material::Diffuse { reflectance } => reflectance,
        other => panic!("{other:?}"),
    };
    let cb = r#"<texture type="checkerboard" name="reflectance"><rgb name="color0" value="1"/><rgb name="color1" value="0"/><transform name="to_uv"><scale x="2" y="2"/></transform></texture>"#;
    assert_eq!(refl(eval(cb, Vec2::new(0.1, 0.1))), Vec3::ONE);
    assert_eq!(refl(eval(cb, Vec2::new(0.3, 0.1))), Vec3::ZERO);
    let bm = |extra: &str| {
        format!(
            r#"<texture type="bitmap" name="reflectance"><string name="filename" value="ramp.png"/>{extra}</texture>"#
        )
    };
    // Bilinear halfway between the two texel centres: the mean of the decoded values (1/2).
    let mid = refl(eval(&bm(""), Vec2::new(0.5, 0.5)));
    assert!((mid - Vec3::splat(0.5)).abs().max_element() < 1e-6, "{mid}");
    // repeat: u = 0 interpolates texel 1 (left neighbour, wrapped) and texel 0.
    let wrap = refl(eval(&bm(""), Vec2::new(0.0, 0.5)));
    assert!(
        (wrap - Vec3::splat(0.5)).abs().max_element() < 1e-6,
        "{wrap}"
    );
    let clamp = refl(eval(
        &bm(r#"<string name="wrap_mode" value="clamp"/>"#),
        Vec2::new(0.0, 0.5),
    ));
    assert_eq!(clamp, Vec3::ZERO);
    // raw: 8-bit values are used linearly (the 128 grey of a one-texel image).
    write_png(&d.join("grey.png"), 1, 1, &[128, 128, 128]);
    let g = |raw: &str| {
        refl(eval(
            &format!(r#"<texture type="bitmap" name="reflectance"><string name="filename" value="grey.png"/>{raw}</texture>"#),
            Vec2::splat(0.3),
        ))
        .x
    };
    assert!((g(r#"<boolean name="raw" value="true"/>"#) - 128.0 / 255.0).abs() < 1e-6);
    assert!((g("") - srgb(128)).abs() < 1e-6);
    // Two textures of one file share one decoded image.
    let two = format!(
        r#"<shape type="rectangle"><bsdf type="diffuse">{}</bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><bsdf type="diffuse">{}</bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#,
        bm(""),
        bm(r#"<string name="filter_type" value="nearest"/>"#)
    );
    let sc = load_in(&scene_xml(20.0, 4, 2, &two), &d);
    assert_eq!(sc.textures.len(), 2);
    assert_eq!(sc.texture_bytes, 2 * 3, "decoded once");
    // An unreadable image names the file and the element's line.
    let e = load_err_in(
        &scene_xml(
            20.0,
            4,
            2,
            &body(
                r#"<texture type="bitmap" name="reflectance"><string name="filename" value="nope.png"/></texture>"#,
            ),
        ),
        &d,
    );
    assert_mentions(&e, &["nope.png", "t.xml:"]);
}

/// Three instances of a shapegroup are hit by three times the rays that hit one: a grid of
/// parallel rays (offset half a step from every edge, spacing dividing the instance offset)
/// is traced through the BVH.
#[test]
fn instances_count_through_the_bvh() {
    let group = r#"<shape type="shapegroup" id="g">
    <shape type="rectangle"><transform name="to_world"><scale value="0.5"/></transform></shape>
    <shape type="sphere"><point name="center" x="0" y="2" z="0"/><float name="radius" value="0.5"/></shape>
  </shape>"#;
    let inst = |x: f32| {
        format!(
            r#"<shape type="instance"><ref id="g"/><transform name="to_world"><translate x="{x}"/></transform></shape>"#
        )
    };
    let count = |sc: &Scene| {
        let mut hits = 0;
        for iy in 0..80 {
            for ix in 0..400 {
                let o = Vec3::new(
                    -5.0 + (ix as f32 + 0.5) * 0.1,
                    -2.0 + (iy as f32 + 0.5) * 0.1,
                    5.0,
                );
                if let Some(h) = sc.intersect(o, DOWN, 0.0, f32::INFINITY) {
                    assert!(h.t > 0.0);
                    hits += 1;
                }
            }
        }
        hits
    };
    let one = load_in(
        &scene_xml(20.0, 4, 2, &format!("{group}{}", inst(0.0))),
        Path::new("."),
    );
    let three = load_in(
        &scene_xml(
            20.0,
            4,
            2,
            &format!("{group}{}{}{}", inst(0.0), inst(10.0), inst(20.0)),
        ),
        Path::new("."),
    );
    let (n1, n3) = (count(&one), count(&three));
    assert!(n1 > 100, "{n1}");
    assert_eq!(n3, 3 * n1, "one instance {n1} hits, three {n3}");
    assert_eq!(three.prims.len(), 3 * one.prims.len());
    // The group alone renders nothing; an unknown group is an error with its line.
    let e = load_err_in(&scene_xml(20.0, 4, 2, &inst(0.0)), Path::new("."));
    assert_mentions(&e, &["t.xml:7:", "shapegroup"]);
}

/// Writes a `.serialized` file by hand (zlib through flate2): version 4, two shapes, the
/// second with normals and uvs, and reads shape 1 back through the loader.
#[test]
fn serialized_mesh_round_trip() {
    let d = dir("serialized");
    let positions = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let normals = [
        Vec3::Z,
        Vec3::new(0.0, 0.6, 0.8),
        Vec3::Z,
        Vec3::new(0.6, 0.0, 0.8),
    ];
    let uvs = [Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y];
    let tris = [[0u32, 1, 2], [0, 2, 3]];
    let shape = |flags: u32, with_attrs: bool| {
        let mut raw = Vec::new();
        raw.extend_from_slice(&flags.to_le_bytes());
        raw.extend_from_slice(b"quad\0");
        raw.extend_from_slice(&4u64.to_le_bytes());
        raw.extend_from_slice(&2u64.to_le_bytes());
        for p in positions {
            for c in p.to_array() {
                raw.extend_from_slice(&c.to_le_bytes());
            }
        }
        if with_attrs {
            for n in normals {
                for c in n.to_array() {
                    raw.extend_from_slice(&c.to_le_bytes());
                }
            }
            for uv in uvs {
                for c in uv.to_array() {
                    raw.extend_from_slice(&c.to_le_bytes());
                }
            }
        }
        for t in tris {
            for i in t {
                raw.extend_from_slice(&i.to_le_bytes());
            }
        }
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&raw).expect("zlib");
        let mut out = vec![0x1C, 0x04, 0x04, 0x00];
        out.extend(z.finish().expect("zlib"));
        out
    };
    let a = shape(0x1000, false);
    let b = shape(0x1000 | 0x0001 | 0x0002, true);
    let mut file = a.clone();
    file.extend(&b);
    file.extend_from_slice(&0u64.to_le_bytes());
    file.extend_from_slice(&(a.len() as u64).to_le_bytes());
    file.extend_from_slice(&2u32.to_le_bytes());
    std::fs::write(d.join("m.serialized"), &file).expect("write");
    let body = r#"<shape type="serialized"><string name="filename" value="m.serialized"/>
    <integer name="shapeIndex" value="1"/>
    <transform name="to_world"><translate x="2"/></transform></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let sc = load_in(&scene_xml(20.0, 4, 2, body), &d);
    assert_eq!(sc.prims.len(), 2);
    assert_eq!(sc.uvs.len(), 2);
    let mut seen = 0;
    for (k, p) in sc.prims.iter().enumerate() {
        let Prim::Tri { p, n } = *p else {
            panic!("triangle expected")
        };
        let n = n.expect("vertex normals");
        let t = tris
            .iter()
            .find(|t| {
                t.iter()
                    .zip(&p)
                    .all(|(&i, q)| (positions[i as usize] + Vec3::X * 2.0 - *q).length() < 1e-6)
            })
            .expect("a triangle of the file");
        for j in 0..3 {
            let i = t[j] as usize;
            assert!((n[j] - normals[i].normalize()).length() < 1e-6);
            assert_eq!(sc.uvs[k][j], uvs[i]);
        }
        seen += 1;
    }
    assert_eq!(seen, 2);
    // Shape 0 has neither normals nor uvs; shape 2 does not exist.
    let sc0 = load_in(
        &scene_xml(
            20.0,
            4,
            2,
            &body.replace("value=\"1\"/>\n", "value=\"0\"/>\n"),
        ),
        &d,
    );
    assert!(matches!(sc0.prims[0], Prim::Tri { n: None, .. }));
    let e = load_err_in(
        &scene_xml(
            20.0,
            4,
            2,
            &body.replace("value=\"1\"/>\n", "value=\"2\"/>\n"),
        ),
        &d,
    );
    assert_mentions(&e, &["m.serialized", "out of range"]);
}

/// `<default>` values and `-D` overrides: through the loader and the CLI.
#[test]
fn params_and_cli_overrides() {
    let d = dir("params");
    let text = scene_xml(
        20.0,
        4,
        2,
        r#"<default name="refl" value="0.2"/>
  <shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="$refl"/></bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#,
    );
    std::fs::write(d.join("p.xml"), &text).expect("write");
    let refl = |sc: &Scene| match sc.materials[0] {
        Material::Diffuse { reflectance } => reflectance.x,
        other => panic!("{other:?}"),
    };
    let base = xml::load_file(&d.join("p.xml")).expect("loads");
    assert_eq!(refl(&base), 0.2);
    let over = xml::load_file_with(
        &d.join("p.xml"),
        &LoadOptions {
            params: vec![("refl".into(), "0.7".into())],
            ..LoadOptions::default()
        },
    )
    .expect("loads");
    assert_eq!(refl(&over), 0.7);
    // A parameter without value is an error naming it, the file and the line.
    let e = load_err_in(
        &text.replace("<default name=\"refl\" value=\"0.2\"/>", ""),
        &d,
    );
    assert_mentions(&e, &["$refl", "t.xml:8:", "-D refl="]);
    // Through the CLI: the image mean follows the override (exact: albedo × white sky).
    let mean = |def: &str| {
        let stats = d.join(format!("s{def}.json"));
        let out = Command::new(env!("CARGO_BIN_EXE_host-demo"))
            .args(["render", d.join("p.xml").to_str().expect("utf-8"), "-D"])
            .arg(format!("refl={def}"))
            .args(["--spp", "4", "--out"])
            .arg(d.join(format!("o{def}.exr")))
            .arg("--stats")
            .arg(&stats)
            .output()
            .expect("runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).expect("stats")).expect("json");
        v["mean_rgb"][0].as_f64().expect("mean")
    };
    let (lo, hi) = (mean("0.1"), mean("0.9"));
    assert!(lo < 0.2 && hi > 0.7, "{lo} {hi}");
}

/// `<include>` with relative paths (the included file's own folder), and a cycle error
/// that lists the chain.
#[test]
fn include_and_cycles() {
    let d = dir("include");
    std::fs::create_dir_all(d.join("sub")).expect("sub");
    std::fs::write(
        d.join("sub/mat.xml"),
        r#"<scene version="3.0.0"><bsdf type="diffuse" id="m"><rgb name="reflectance" value="0.3"/></bsdf>
<shape type="obj"><string name="filename" value="tri.obj"/><ref id="m"/></shape></scene>"#,
    )
    .expect("write");
    std::fs::write(
        d.join("sub/tri.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .expect("obj");
    let main = scene_xml(
        20.0,
        4,
        2,
        r#"<include filename="sub/mat.xml"/>
  <shape type="rectangle"><ref id="m"/></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#,
    );
    std::fs::write(d.join("main.xml"), &main).expect("write");
    let sc = xml::load_file(&d.join("main.xml")).expect("loads");
    assert_eq!(sc.prims.len(), 3);
    assert_eq!(sc.shapes[0].material, sc.shapes[1].material);
    // a.xml includes b.xml includes a.xml.
    std::fs::write(
        d.join("a.xml"),
        r#"<scene version="3.0.0"><include filename="b.xml"/></scene>"#,
    )
    .expect("a");
    std::fs::write(
        d.join("b.xml"),
        "<scene version=\"3.0.0\">\n<include filename=\"a.xml\"/></scene>",
    )
    .expect("b");
    let e = xml::load_file(&d.join("a.xml"))
        .err()
        .expect("cycle")
        .to_string();
    assert_mentions(&e, &["include cycle", "b.xml:2:"]);
    assert_mentions(&e, &["a.xml -> ", "b.xml -> "]);
}

/// A Mitsuba 0.6 file (camelCase names, `lookAt`, `<spectrum>` triples, `uoffset`/`uscale`)
/// loads to the same scene as its Mitsuba 3 twin.
#[test]
fn mitsuba_06_file_equals_its_mitsuba_3_twin() {
    let v06 = r#"<?xml version="1.0" encoding="utf-8"?>
<scene version="0.6.0">
  <integrator type="path"><integer name="maxDepth" value="5"/><integer name="rrDepth" value="3"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="35"/><string name="fovAxis" value="smaller"/><float name="nearClip" value="0.1"/>
    <transform name="toWorld"><lookAt origin="0, 1, 6" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sampleCount" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/></film>
  </sensor>
  <bsdf type="roughplastic" id="p"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
    <float name="intIOR" value="1.6"/><float name="extIOR" value="1.0"/>
    <spectrum name="diffuseReflectance" value="0.2, 0.4, 0.6"/></bsdf>
  <bsdf type="dielectric" id="g"><float name="intIOR" value="1.5"/><spectrum name="specularTransmittance" value="0.9"/></bsdf>
  <shape type="rectangle"><transform name="toWorld"><scale value="2"/></transform><ref id="p"/></shape>
  <shape type="sphere"><point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.5"/><ref id="g"/>
    <boolean name="flipNormals" value="false"/></shape>
  <shape type="rectangle"><transform name="toWorld"><translate z="-2"/></transform>
    <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
      <float name="uoffset" value="0.25"/><float name="uscale" value="4"/><float name="vscale" value="2"/></texture></bsdf></shape>
  <emitter type="constant"><spectrum name="radiance" value="1"/></emitter>
</scene>"#;
    let v3 = r#"<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="5"/><integer name="rr_depth" value="3"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="35"/><string name="fov_axis" value="smaller"/><float name="near_clip" value="0.1"/>
    <transform name="to_world"><lookat origin="0, 1, 6" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/></film>
  </sensor>
  <bsdf type="roughplastic" id="p"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
    <float name="int_ior" value="1.6"/><float name="ext_ior" value="1.0"/>
    <rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/></bsdf>
  <bsdf type="dielectric" id="g"><float name="int_ior" value="1.5"/><rgb name="specular_transmittance" value="0.9"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="p"/></shape>
  <shape type="sphere"><point name="center" x="0" y="0.5" z="0"/><float name="radius" value="0.5"/><ref id="g"/>
    <boolean name="flip_normals" value="false"/></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-2"/></transform>
    <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
      <transform name="to_uv"><scale x="4" y="2"/><translate x="0.25"/></transform></texture></bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
</scene>"#;
    let (a, b) = (load_in(v06, Path::new(".")), load_in(v3, Path::new(".")));
    assert_eq!(a.materials, b.materials);
    assert_eq!(a.material_textures, b.material_textures);
    assert_eq!(format!("{:?}", a.textures), format!("{:?}", b.textures));
    assert_eq!(format!("{:?}", a.prims), format!("{:?}", b.prims));
    assert_eq!(format!("{:?}", a.camera), format!("{:?}", b.camera));
    assert_eq!(format!("{:?}", a.settings), format!("{:?}", b.settings));
    assert_eq!(format!("{:?}", a.env), format!("{:?}", b.env));
    assert!(
        a.warnings.is_empty() && b.warnings.is_empty(),
        "{:?}",
        a.warnings
    );
}

/// Approximations load with a warning that names the line; refused plugins are errors
/// naming the file, line and plugin.
#[test]
fn approximations_warn_and_refusals_name_the_line() {
    let light = r#"<emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let sc = load_in(
        &scene_xml(
            20.0,
            4,
            2,
            &format!(
                r#"<shape type="rectangle"><bsdf type="bumpmap"><texture type="checkerboard"/><bsdf type="roughconductor"><float name="alpha" value="0.3"/></bsdf></bsdf></shape>
{light}"#
            ),
        ),
        Path::new("."),
    );
    assert_eq!(sc.warnings.len(), 1, "{:?}", sc.warnings); // bumpmap
    assert_warned(&sc.warnings, &["t.xml:7:", "bumpmap"]);
    // Beckmann (Mitsuba's default distribution) is implemented, not approximated.
    assert!(
        !sc.warnings
            .iter()
            .any(|w| w.to_ascii_lowercase().contains("beckmann")),
        "{:?}",
        sc.warnings
    );
    assert!(matches!(
        sc.materials[sc.shapes[0].material as usize],
        Material::RoughConductor {
            distribution: Microfacet::Beckmann,
            ..
        }
    ));
    // Invalid parameters of known BSDFs are errors in every mode.
    for (bsdf, needle) in [
        (
            r#"<bsdf type="phong"><float name="exponent" value="-1"/></bsdf>"#,
            "exponent",
        ),
        (
            r#"<bsdf type="ward"><string name="variant" value="cook"/></bsdf>"#,
            "variant",
        ),
    ] {
        let e = load_err_in(
            &scene_xml(
                20.0,
                4,
                2,
                &format!("<shape type=\"rectangle\">\n{bsdf}</shape>{light}"),
            ),
            Path::new("."),
        );
        assert!(e.starts_with("t.xml:8:") && e.contains(needle), "{e}");
    }
    // Unknown plugins and properties: a warning naming the line and what was done, or
    // with `strict` an error naming the file, line and plugin.
    for (bsdf, needle, done) in [
        (r#"<bsdf type="hair"/>"#, "hair", "grey diffuse"),
        (
            r#"<bsdf type="modifiedphong"/>"#,
            "modifiedphong",
            "grey diffuse",
        ),
        (
            r#"<bsdf type="diffuse"><float name="sheen" value="1"/></bsdf>"#,
            "<float name=\"sheen\">",
            "ignored",
        ),
    ] {
        let text = scene_xml(
            20.0,
            4,
            2,
            &format!("<shape type=\"rectangle\">\n{bsdf}</shape>{light}"),
        );
        let e = load_strict_err_in(&text);
        assert!(e.starts_with("t.xml:8:") && e.contains(needle), "{e}");
        let sc = load_in(&text, Path::new("."));
        assert!(
            sc.warnings
                .iter()
                .any(|w| w.starts_with("t.xml:8:") && w.contains(needle) && w.contains(done)),
            "{:?}",
            sc.warnings
        );
    }
    let text = scene_xml(
        20.0,
        4,
        2,
        &format!("<shape type=\"hair\"/><shape type=\"sphere\"/>{light}"),
    );
    let e = load_strict_err_in(&text);
    assert!(e.starts_with("t.xml:7:") && e.contains("hair"), "{e}");
    let sc = load_in(&text, Path::new("."));
    assert_eq!(sc.prims.len(), 1, "hair is skipped, the sphere stays");
    assert!(
        sc.warnings
            .iter()
            .any(|w| w.starts_with("t.xml:7:") && w.contains("hair") && w.contains("skipped")),
        "{:?}",
        sc.warnings
    );
}

fn load_strict_err_in(text: &str) -> String {
    let opts = LoadOptions {
        strict: true,
        ..LoadOptions::default()
    };
    xml::load_str_opts(text, "t.xml", Path::new("."), &|p| std::fs::read(p), &opts)
        .err()
        .expect("must fail with strict")
        .to_string()
}

/// A `mask` cut-out: the front quad's opacity checkerboard lets rays (camera and shadow)
/// through its transparent cells to the quad behind, and only there.
#[test]
fn mask_cuts_out_for_every_ray() {
    let body = r#"<shape type="rectangle"><bsdf type="mask">
      <texture type="checkerboard" name="opacity"><float name="color0" value="1"/><float name="color1" value="0"/></texture>
      <bsdf type="diffuse"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-1"/></transform></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let sc = load_in(&scene_xml(20.0, 4, 2, body), Path::new("."));
    let masked = sc
        .shapes
        .iter()
        .position(|s| s.opacity.is_some())
        .expect("mask") as u32;
    // uv = (x/2 + 1/2, y/2 + 1/2): color0 (opaque) where both or neither of u, v exceed ½.
    for (x, y, opaque) in [
        (-0.5, -0.5, true),
        (0.5, 0.5, true),
        (0.5, -0.5, false),
        (-0.5, 0.5, false),
    ] {
        let o = Vec3::new(x, y, 5.0);
        let h = sc
            .intersect(o, DOWN, 0.0, f32::INFINITY)
            .expect("hits something");
        assert_eq!(h.shape == masked, opaque, "({x}, {y})");
        assert!(
            (h.t - if opaque { 5.0 } else { 6.0 }).abs() < 1e-3,
            "{}",
            h.t
        );
        assert_eq!(
            sc.occluded(o, DOWN, 0.0, 5.5),
            opaque,
            "shadow ray at ({x}, {y})"
        );
    }
}

/// thindielectric: the reflected fraction of sampled directions is `R' = 2F/(1+F)` (binomial
/// z-test, 10⁵ samples), transmission leaves along `−wi`, and both weights are the white
/// multipliers (energy conserved exactly).
#[test]
fn thindielectric_reflects_its_series_fraction() {
    let m = Material::ThinDielectric {
        eta: 1.5,
        reflectance: Vec3::ONE,
        transmittance: Vec3::ONE,
    };
    let mut rng = host_demo::math::Rng::from_keys(3, 1, 4);
    for wi in [
        Vec3::new(0.3, 0.0, 0.95).normalize(),
        Vec3::new(0.8, 0.1, -0.3).normalize(),
    ] {
        // The series F + T²F Σ F^{2k} summed numerically.
        let f = host_demo::scene::bsdf::fresnel_dielectric(wi.z.abs(), 1.5).0 as f64;
        let series = f + (1.0 - f).powi(2) * f * (0..200).map(|k| f.powi(2 * k)).sum::<f64>();
        let r = host_demo::scene::bsdf::thin_dielectric_reflectance(wi.z, 1.5) as f64;
        assert!((r - series).abs() < 1e-6, "{r} vs {series}");
        let n = 100_000;
        let mut refl = 0;
        for _ in 0..n {
            let s = m
                .sample(wi, rng.next_f32(), rng.next_f32(), rng.next_f32())
                .expect("samples");
            assert!(s.pdf.is_infinite());
            assert_eq!(s.weight, Vec3::ONE);
            if s.wo.z * wi.z > 0.0 {
                assert!((s.wo - Vec3::new(-wi.x, -wi.y, wi.z)).length() < 1e-6);
                refl += 1;
            } else {
                assert_eq!(s.wo, -wi);
            }
        }
        let p = refl as f64 / n as f64;
        let se = (r * (1.0 - r) / n as f64).sqrt();
        assert!((p - r).abs() < z_threshold(2) * se, "reflected {p} vs {r}");
    }
}

/// blendbsdf with a textured weight: the weight follows the texture, and a half-and-half
/// blend of two diffuse albedos has the expected value of the mixture.
#[test]
fn blendbsdf_weight_texture_and_expectation() {
    let body = r#"<shape type="rectangle"><bsdf type="blendbsdf">
      <texture type="checkerboard" name="weight"><float name="color0" value="0.9"/><float name="color1" value="0.1"/></texture>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.2"/></bsdf>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let sc = load_in(&scene_xml(20.0, 4, 2, body), Path::new("."));
    let id = sc.shapes[0].material;
    let (wi, wo) = (Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.6, 0.0, 0.8));
    for (uv, w) in [(Vec2::splat(0.25), 0.9f32), (Vec2::new(0.75, 0.25), 0.1)] {
        let (f, _) = sc.eval_mixture(id, uv, wi, wo);
        let want = (0.2 * (1.0 - w) + 0.8 * w) * 0.8 / std::f32::consts::PI;
        assert!((f.x - want).abs() < 1e-6, "{} vs {want}", f.x);
        // Stochastic selection picks b with probability w (binomial z-test).
        let mut rng = host_demo::math::Rng::from_keys(9, 9, 9);
        let n = 20_000;
        let mut picked_b = 0;
        for _ in 0..n {
            let (_, m, _, _) = sc.resolve_material(id, Vec3::Z, Vec3::Z, -Vec3::Z, uv, &mut rng);
            if let Material::Diffuse { reflectance } = m {
                picked_b += usize::from(reflectance.x > 0.5);
            }
        }
        let p = picked_b as f64 / n as f64;
        let se = (f64::from(w) * f64::from(1.0 - w) / n as f64).sqrt();
        assert!((p - f64::from(w)).abs() < z_threshold(2) * se, "{p} vs {w}");
    }
}

/// Load-time measurement (not a test of correctness; run by hand): writes a scene with a
/// 10⁶-triangle `.serialized` grid (normals + uvs) and six 4096² RGB PNG textures (each
/// referenced twice, so 12 textures over 6 images) to `$HOST_DEMO_LOAD_DIR` (default
/// `/tmp/host-demo-load`), then loads it and prints the time and texel memory. Render it with
/// `/usr/bin/time -v target/release/host-demo render DIR/scene.xml --spp 1 --width 64` for
/// the peak memory.
/// `cargo test --release -p host-demo --test real_scenes -- --ignored --nocapture load_time`
#[test]
#[ignore = "writes ~100 MB to /tmp and takes a while; a measurement, run by hand"]
fn load_time_large_scene() {
    use host_demo::scene::load::serialized::{write_serialized, SerializedMesh};
    let d = PathBuf::from(
        std::env::var("HOST_DEMO_LOAD_DIR").unwrap_or_else(|_| "/tmp/host-demo-load".into()),
    );
    std::fs::create_dir_all(&d).expect("dir");
    let (nx, ny) = (1000usize, 500usize);
    if !d.join("grid.serialized").exists() {
        let mut sm = SerializedMesh {
            name: "grid".into(),
            ..SerializedMesh::default()
        };
        let m = &mut sm.mesh;
        m.normals = Some(Vec::new());
        m.uvs = Some(Vec::new());
        for j in 0..=ny {
            for i in 0..=nx {
                let (u, v) = (i as f32 / nx as f32, j as f32 / ny as f32);
                m.positions.push(Vec3::new(
                    2.0 * u - 1.0,
                    2.0 * v - 1.0,
                    0.05 * (20.0 * u).sin(),
                ));
                m.normals.as_mut().expect("n").push(Some(Vec3::Z));
                m.uvs.as_mut().expect("uv").push(Some(Vec2::new(u, v)));
            }
        }
        for j in 0..ny {
            for i in 0..nx {
                let k = (j * (nx + 1) + i) as u32;
                let w = nx as u32 + 1;
                m.indices.push([k, k + 1, k + w + 1]);
                m.indices.push([k, k + w + 1, k + w]);
            }
        }
        std::fs::write(d.join("grid.serialized"), write_serialized(&[sm])).expect("write mesh");
    }
    let n = 4096u32;
    for t in 0..6 {
        let p = d.join(format!("tex{t}.png"));
        if !p.exists() {
            let mut rgb = vec![0u8; (n * n * 3) as usize];
            for (i, px) in rgb.chunks_exact_mut(3).enumerate() {
                let (x, y) = (i as u32 % n, i as u32 / n);
                px.copy_from_slice(&[(x ^ y) as u8, (x >> 4) as u8 ^ t, (y >> 4) as u8]);
            }
            write_png(&p, n, n, &rgb);
        }
    }
    let mut body = String::new();
    for t in 0..6 {
        for copy in 0..2 {
            body += &format!(
                r#"<shape type="serialized"><string name="filename" value="grid.serialized"/>
  <transform name="to_world"><translate x="{}" y="{}"/></transform>
  <bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="tex{t}.png"/>{}</texture></bsdf></shape>
"#,
                2.5 * t as f32,
                2.5 * copy as f32,
                if copy == 1 {
                    r#"<string name="filter_type" value="nearest"/>"#
                } else {
                    ""
                }
            );
            if t > 0 || copy > 0 {
                // Only the first shape carries the full mesh; the others are small stand-ins
                // so that the scene stays at ~10⁶ triangles.
                body = body.replace(
                    &format!(r#"<shape type="serialized"><string name="filename" value="grid.serialized"/>
  <transform name="to_world"><translate x="{}" y="{}"/>"#, 2.5 * t as f32, 2.5 * copy as f32),
                    &format!(r#"<shape type="rectangle">
  <transform name="to_world"><translate x="{}" y="{}"/>"#, 2.5 * t as f32, 2.5 * copy as f32),
                );
            }
        }
    }
    body += r#"<emitter type="constant"><rgb name="radiance" value="1"/></emitter>"#;
    let text = scene_xml(60.0, 64, 4, &body)
        .replace("0, 0, 5", "6, 1, 12")
        .replace("target=\"0, 0, 0\"", "target=\"6, 1, 0\"");
    std::fs::write(d.join("scene.xml"), text).expect("scene");
    let t0 = std::time::Instant::now();
    let sc = xml::load_file(&d.join("scene.xml")).expect("loads");
    let dt = t0.elapsed().as_secs_f64();
    eprintln!(
        "loaded {} primitives, {} textures, {:.1} MiB of texels in {dt:.2} s",
        sc.prims.len(),
        sc.textures.len(),
        sc.texture_bytes as f64 / (1 << 20) as f64
    );
    assert_eq!(sc.textures.len(), 12);
    assert_eq!(
        sc.texture_bytes,
        6 * (n * n * 3) as usize,
        "each image stored once"
    );
}
