//! Loader and render tests of the scene features: PLY / cube / disk shapes, the conductor,
//! dielectric, plastic, Mitsuba 0.6 phong / ward and two-sided BSDFs, and the point, constant,
//! envmap and sunsky emitters.
//! Run with `cargo test --release -p host-demo --test scene_features` (a few seconds).
//!
//! Render agreement is a per-block z-test: the image is cut into blocks of `B × B` pixels,
//! the block means of two independent renders (different seeds) differ by
//! `z = Δ / sqrt(se_a² + se_b²)` with each standard error from the per-pixel sample variances;
//! with `M` blocks × 3 channels the two-sided threshold is the normal quantile at the
//! Šidák-corrected level `1 − (1 − 0.01)^{1/3M}` (family-wise false alarm rate 1 %).

mod common;

use common::{assert_mentions, assert_warned, npm_guide, sidak, training_config, z_threshold};
use glam::Vec3;
use host_demo::render::{render, Image, IntegratorKind, RenderOptions};
use host_demo::scene::bsdf::{Material, Microfacet};
use host_demo::scene::load::xml;
use host_demo::scene::{Prim, Scene};
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    common::scratch_dir(&format!("features-{name}"))
}

/// A scene document: path integrator, a `fov` camera at `origin` looking at `target`, and `body`.
fn scene_xml(origin: &str, target: &str, fov: f32, res: u32, max_depth: u32, body: &str) -> String {
    common::scene_doc(
        common::Dialect::V3,
        origin,
        target,
        "0, 0, 1",
        fov,
        res,
        max_depth,
        body,
    )
}

/// The loader tests' scene document: 8 × 8 pixels, a camera at `(0, −10, 0)`, and `body`.
fn loader_xml(body: &str) -> String {
    scene_xml("0, -10, 0", "0, 0, 0", 40.0, 8, 4, body)
}

fn load(text: &str, base: &Path) -> Scene {
    xml::load_str(text, "t.xml", base).unwrap_or_else(|e| panic!("loads: {e}"))
}

/// Loads `text` with a fresh scratch folder `name` as its base.
fn load_in_scratch(name: &str, text: &str) -> Scene {
    load(text, &dir(name))
}

/// The error of a strict load (unknown constructs are errors, see `LoadOptions::strict`).
fn load_err(text: &str, base: &Path) -> String {
    let opts = xml::LoadOptions {
        strict: true,
        ..xml::LoadOptions::default()
    };
    xml::load_str_opts(text, "t.xml", base, &|p| std::fs::read(p), &opts)
        .err()
        .expect("must fail")
        .to_string()
}

fn opts(kind: IntegratorKind, spp: u32, seed: u64) -> RenderOptions {
    RenderOptions {
        integrator: kind,
        spp,
        max_depth: 0, // replaced below with the scene's
        seed,
        ..RenderOptions::default()
    }
}

fn render_scene(sc: &Scene, kind: IntegratorKind, spp: u32, seed: u64) -> Image {
    let mut o = opts(kind, spp, seed);
    o.max_depth = sc.settings.max_depth;
    let img = render(sc, &o);
    assert!(img.all_finite_non_negative());
    img
}

/// Renders `sc` with `pt` (`pt_spp`, seed `seed`) and `pt-nee` (64 spp, seed `seed + 1`),
/// block-z-tests the two (4 × 4 blocks) and returns the `pt-nee` image.
fn pt_agrees_with_nee(name: &str, sc: &Scene, pt_spp: u32, seed: u64) -> Image {
    let a = render_scene(sc, IntegratorKind::Pt, pt_spp, seed);
    let b = render_scene(sc, IntegratorKind::PtNee, 64, seed + 1);
    block_ztest(name, &a, &b, 4);
    b
}

/// Block means and their variances (from the per-pixel variances of the mean).
fn blocks(img: &Image, b: u32) -> Vec<([f64; 3], [f64; 3])> {
    let (w, h) = (img.width, img.height);
    let mut out = Vec::new();
    for by in 0..h / b {
        for bx in 0..w / b {
            let (mut m, mut v) = ([0.0f64; 3], [0.0f64; 3]);
            for y in by * b..(by + 1) * b {
                for x in bx * b..(bx + 1) * b {
                    let i = (y * w + x) as usize;
                    for c in 0..3 {
                        m[c] += f64::from(img.pixels[i][c]);
                        v[c] += f64::from(img.var_of_mean[i][c]);
                    }
                }
            }
            let n = f64::from(b * b);
            out.push((m.map(|x| x / n), v.map(|x| x / (n * n))));
        }
    }
    out
}

/// Per-block z-test of `a` against `b` (see the module docs). Blocks where both variances
/// vanish (noise-free estimators) must agree to 1e-4 relative.
fn block_ztest(name: &str, a: &Image, b: &Image, block: u32) {
    let (ba, bb) = (blocks(a, block), blocks(b, block));
    let tests = 3 * ba.len();
    let zmax = z_threshold(sidak(0.01, tests));
    let mut worst = 0.0f64;
    for (k, ((ma, va), (mb, vb))) in ba.iter().zip(&bb).enumerate() {
        for c in 0..3 {
            let d = ma[c] - mb[c];
            // Plus f32 rounding of the pixel sums (1e-6 relative), which matters only where
            // both estimators are (nearly) noise-free, e.g. the directly seen environment.
            let s = (va[c] + vb[c]).sqrt() + 1e-6 * ma[c].abs().max(mb[c].abs());
            if s == 0.0 {
                assert!(
                    d.abs() <= 1e-4 * ma[c].abs().max(1e-3),
                    "{name}: block {k} ch {c}: {} vs {} (both noise-free)",
                    ma[c],
                    mb[c]
                );
                continue;
            }
            let z = d / s;
            worst = worst.max(z.abs());
            assert!(
                z.abs() <= zmax,
                "{name}: block {k} channel {c}: {} vs {} (z = {z:.2}, threshold {zmax:.2})",
                ma[c],
                mb[c]
            );
        }
    }
    eprintln!(
        "{name}: {} blocks, worst |z| {worst:.2} (threshold {zmax:.2})",
        ba.len()
    );
}

fn write_envmap(path: &Path) {
    // 16 x 8 lat-long map: soft gradient plus a bright patch.
    let (w, h) = (16u32, 8u32);
    let pixels = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if (5..=6).contains(&x) && (2..=3).contains(&y) {
                [20.0, 16.0, 12.0]
            } else {
                [0.3 + 0.05 * y as f32, 0.4, 0.2 + 0.02 * x as f32]
            }
        })
        .collect();
    let img = Image {
        width: w,
        height: h,
        pixels,
        var_of_mean: vec![[0.0; 3]; (w * h) as usize],
    };
    host_demo::render::output::write_exr(&img, path).expect("write envmap");
}

// ---------------------------------------------------------------------------------------
// Loader tests
// ---------------------------------------------------------------------------------------

const PLY_ASCII: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";

fn ply_binary() -> Vec<u8> {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n".to_vec();
    for p in [[0.0f32, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]] {
        for c in p.into_iter().chain([0.0, 0.0, 1.0]) {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    b.push(3);
    for i in [0u32, 1, 2] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    b
}

#[test]
fn ply_cube_disk_shapes_load() {
    let d = dir("shapes");
    std::fs::write(d.join("quad.ply"), PLY_ASCII).expect("write");
    std::fs::write(d.join("tri.ply"), ply_binary()).expect("write");
    let body = r#"
  <shape type="ply"><string name="filename" value="quad.ply"/>
    <transform name="to_world"><translate x="10"/></transform></shape>
  <shape type="ply"><string name="filename" value="tri.ply"/><boolean name="face_normals" value="true"/></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.5"/><translate z="-5"/></transform></shape>
  <shape type="disk"><transform name="to_world"><scale value="2"/><translate z="3"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"#;
    let sc = load(&loader_xml(body), &d);
    let (mut tris, mut disks) = (Vec::new(), 0);
    for p in &sc.prims {
        match p {
            Prim::Tri { p, n } => tris.push((*p, n.is_some())),
            Prim::Disk { center, n, .. } => {
                disks += 1;
                assert!((*center - Vec3::new(0.0, 0.0, 3.0)).length() < 1e-6);
                assert!((*n - Vec3::Z).length() < 1e-6);
            }
            Prim::Sphere { .. } => panic!("no spheres here"),
        }
    }
    assert_eq!((tris.len(), disks), (2 + 1 + 12, 1));
    // Quad translated to x in [10, 11]; the binary triangle has area 2; the cube 24 · 0.5².
    let quad: Vec<_> = tris.iter().filter(|t| t.0[0].x >= 9.9).collect();
    assert_eq!(quad.len(), 2);
    let cube: Vec<_> = tris.iter().filter(|t| t.0[0].z < -4.0).collect();
    assert_eq!(cube.len(), 12);
    let cube_area: f32 = cube
        .iter()
        .map(|t| 0.5 * (t.0[1] - t.0[0]).cross(t.0[2] - t.0[0]).length())
        .sum();
    assert!((cube_area - 6.0).abs() < 1e-4, "{cube_area}");
    for t in &cube {
        let c = (t.0[0] + t.0[1] + t.0[2]) / 3.0 - Vec3::new(0.0, 0.0, -5.0);
        let n = (t.0[1] - t.0[0]).cross(t.0[2] - t.0[0]);
        assert!(n.dot(c) > 0.0, "cube normals point outwards");
    }
    assert!(
        tris.iter().all(|t| !t.1),
        "face_normals drops the PLY normals; the ASCII file has none"
    );
    // The disk light: area π r² with r = 2.
    assert_eq!(sc.lights.len(), 1);
    assert!((sc.lights[0].area - 4.0 * std::f32::consts::PI).abs() < 1e-4);

    // Errors name the file / element.
    let e = load_err(
        &loader_xml(r#"<shape type="ply"><string name="filename" value="missing.ply"/></shape>"#),
        &d,
    );
    assert!(e.contains("missing.ply"), "{e}");
    std::fs::write(
        d.join("bad.ply"),
        "ply\nformat binary_big_endian 1.0\nend_header\n",
    )
    .expect("write");
    let e = load_err(
        &loader_xml(r#"<shape type="ply"><string name="filename" value="bad.ply"/></shape>"#),
        &d,
    );
    assert_mentions(&e, &["bad.ply", "big_endian"]);
}

#[test]
fn bsdfs_and_emitters_load() {
    let d = dir("bsdfs");
    write_envmap(&d.join("env.exr"));
    let body = r#"
  <bsdf type="conductor" id="c"><rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.1"/></bsdf>
  <bsdf type="dielectric" id="g"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.0"/></bsdf>
  <bsdf type="roughdielectric" id="rg"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
    <string name="int_ior" value="water"/></bsdf>
  <bsdf type="plastic" id="p"><rgb name="diffuse_reflectance" value="0.1, 0.2, 0.3"/><boolean name="nonlinear" value="true"/></bsdf>
  <bsdf type="roughplastic" id="rp"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>
  <bsdf type="twosided" id="t"><bsdf type="diffuse"><rgb name="reflectance" value="0.7"/></bsdf></bsdf>
  <shape type="sphere"><ref id="c"/></shape>
  <emitter type="point"><point name="position" x="1" y="2" z="3"/><rgb name="intensity" value="5"/></emitter>
  <emitter type="envmap"><string name="filename" value="env.exr"/><float name="scale" value="2"/>
    <transform name="to_world"><rotate x="1" angle="90"/></transform></emitter>"#;
    let sc = load(&loader_xml(body), &d);
    let m = &sc.materials;
    assert!(matches!(m[0], Material::Conductor { .. }));
    assert!(matches!(m[1], Material::Dielectric { eta, .. } if (eta - 1.5).abs() < 1e-6));
    assert!(
        matches!(m[2], Material::RoughDielectric { eta, alpha, distribution: Microfacet::Ggx, .. } if (eta - 1.333 / 1.000_277).abs() < 1e-5 && alpha == 0.2)
    );
    assert!(
        matches!(m[3], Material::Plastic(c) if c.nonlinear && c.diffuse == Vec3::new(0.1, 0.2, 0.3) && (c.eta - 1.49 / 1.000_277).abs() < 1e-5)
    );
    assert!(
        matches!(m[4], Material::RoughPlastic(c) if c.alpha == 0.3 && c.distribution == Microfacet::Ggx)
    );
    // The nested diffuse is material 5, the twosided wrapper 6.
    assert!(matches!(m[6], Material::TwoSided { front: 5, back: 5 }));
    assert_eq!(sc.point_lights.len(), 1);
    assert_eq!(sc.point_lights[0].position, Vec3::new(1.0, 2.0, 3.0));
    assert!(sc.env.is_some());
    assert_eq!(sc.emitter_count(), 2);

    let e = |b: &str| load_err(&loader_xml(b), &d);
    let err = e("<shape type=\"sphere\"/>\n<emitter type=\"spot\"/>");
    assert_mentions(&err, &["spot", "emitter", "t.xml:"]);
    let err = e("<emitter type=\"constant\"/>\n<emitter type=\"constant\"/>");
    assert!(err.contains("only one environment"), "{err}");
    let err = e("<bsdf type=\"twosided\" id=\"x\">\n<bsdf type=\"dielectric\"/></bsdf>");
    assert_mentions(&err, &["twosided", "t.xml:8:"]);
    let err =
        e("<emitter type=\"envmap\"><string name=\"filename\" value=\"nope.exr\"/></emitter>");
    assert!(err.contains("nope.exr"), "{err}");
    let err = e("<emitter type=\"envmap\"><string name=\"filename\" value=\"env.exr\"/><transform name=\"to_world\"><scale value=\"2\"/></transform></emitter>");
    assert!(err.contains("rotation"), "{err}");
    // Anisotropic roughness: approximated (isotropic geometric mean) with a warning.
    let aniso = load(
        &loader_xml("<shape type=\"sphere\"><bsdf type=\"roughdielectric\"><float name=\"alpha_u\" value=\"0.1\"/><float name=\"alpha_v\" value=\"0.4\"/></bsdf></shape>",
        ),
        &d,
    );
    // No `distribution`: Beckmann, Mitsuba's default.
    assert!(
        matches!(aniso.materials[0], Material::RoughDielectric { alpha, distribution: Microfacet::Beckmann, .. } if (alpha - 0.2).abs() < 1e-6),
        "{:?}",
        aniso.materials
    );
    assert_warned(&aniso.warnings, &["alpha_u"]);
    let err = e(
        "<bsdf type=\"plastic\" id=\"x\"><string name=\"int_ior\" value=\"unobtainium\"/></bsdf>",
    );
    assert!(err.contains("unobtainium"), "{err}");
    // The microfacet distribution: `beckmann` (also when absent, as in Mitsuba) and `ggx`, on
    // every rough BSDF, without a warning; anything else is an error naming it.
    let dist = load(
        &loader_xml(
            r#"<bsdf type="roughconductor" id="a"/>
  <bsdf type="roughconductor" id="b"><string name="distribution" value="beckmann"/></bsdf>
  <bsdf type="roughplastic" id="c"/>
  <bsdf type="roughdielectric" id="d"><string name="distribution" value="beckmann"/></bsdf>
  <bsdf type="roughconductor" id="e"><string name="distribution" value="ggx"/></bsdf>
  <shape type="sphere"><ref id="a"/></shape>"#,
        ),
        &d,
    );
    assert!(dist.warnings.is_empty(), "{:?}", dist.warnings);
    let m = &dist.materials;
    use Microfacet::{Beckmann, Ggx};
    assert!(
        matches!(m[0], Material::RoughConductor { distribution: Beckmann, alpha, .. } if alpha == 0.1)
    );
    assert!(matches!(
        m[1],
        Material::RoughConductor {
            distribution: Beckmann,
            ..
        }
    ));
    assert!(
        matches!(m[2], Material::RoughPlastic(c) if c.distribution == Beckmann && c.alpha == 0.1)
    );
    assert!(matches!(
        m[3],
        Material::RoughDielectric {
            distribution: Beckmann,
            ..
        }
    ));
    assert!(matches!(
        m[4],
        Material::RoughConductor {
            distribution: Ggx,
            ..
        }
    ));
    // (Mitsuba 0.6's "phong" loads as Beckmann: `published_constructs.rs`.)
    let err = e("<bsdf type=\"roughconductor\" id=\"x\"><string name=\"distribution\" value=\"trowbridge\"/></bsdf>");
    assert_mentions(&err, &["trowbridge", "distribution"]);
}

/// Mitsuba 0.6's `phong` and `ward` in 0.6 spelling (camelCase names, `<spectrum>`, `<srgb>`):
/// defaults, `alpha` / `alphaU` / `alphaV`, the variants, textured reflectances, the
/// energy-conservation scaling (with its warning) and the errors for invalid parameters.
#[test]
fn phong_and_ward_load() {
    use host_demo::scene::bsdf::WardVariant;
    let d = dir("phong-ward");
    let body = r##"
  <bsdf type="phong" id="ph"><float name="exponent" value="40"/><spectrum name="specularReflectance" value="0.3"/></bsdf>
  <bsdf type="ward" id="w"><string name="variant" value="ward-duer"/><float name="alphaU" value="0.1"/><float name="alphaV" value="0.3"/></bsdf>
  <bsdf type="ward" id="w2"><float name="alphaV" value="0.4"/><float name="alpha" value="0.2"/>
    <rgb name="diffuseReflectance" value="0.1, 0.2, 0.3"/></bsdf>
  <bsdf type="phong" id="hot"><srgb name="diffuseReflectance" value="#ffffff"/><spectrum name="specularReflectance" value="0.5"/></bsdf>
  <bsdf type="ward" id="free"><boolean name="ensureEnergyConservation" value="false"/><spectrum name="diffuseReflectance" value="0.9"/></bsdf>
  <bsdf type="phong" id="tex"><texture type="checkerboard" name="diffuseReflectance">
    <rgb name="color0" value="0.9, 0.2, 0.1"/><rgb name="color1" value="0.1"/></texture></bsdf>
  <bsdf type="phong" id="def"/>
  <shape type="sphere"><ref id="ph"/></shape>"##;
    let sc = load(&loader_xml(body), &d);
    let m = &sc.materials;
    assert_eq!(
        m[0],
        Material::Phong {
            exponent: 40.0,
            diffuse: Vec3::splat(0.5),
            specular: Vec3::splat(0.3),
            scale: 1.0
        }
    );
    assert_eq!(
        m[1],
        Material::Ward {
            variant: WardVariant::WardDuer,
            alpha_u: 0.1,
            alpha_v: 0.3,
            diffuse: Vec3::splat(0.5),
            specular: Vec3::splat(0.2),
            scale: 1.0
        }
    );
    // `alpha` sets the default of both, whatever the order; `balanced` is the default variant.
    assert!(
        matches!(m[2], Material::Ward { variant: WardVariant::Balanced, alpha_u, alpha_v, diffuse, .. }
        if alpha_u == 0.2 && alpha_v == 0.4 && diffuse == Vec3::new(0.1, 0.2, 0.3))
    );
    // White + 0.5 = 1.5 > 1: both scaled by 0.99 / 1.5, with a warning.
    assert!(
        matches!(m[3], Material::Phong { scale, diffuse, .. } if (scale - 0.66).abs() < 1e-6 && diffuse == Vec3::ONE)
    );
    assert_warned(&sc.warnings, &["phong", "scaled"]);
    assert_warned(&sc.warnings, &["t.xml:10:", "anisotropic"]);
    assert!(matches!(m[4], Material::Ward { scale, .. } if scale == 1.0));
    // Textured diffuse: the scale comes from the texture's per-channel maximum (0.9 + 0.2).
    assert!(matches!(m[5], Material::Phong { scale, .. } if (scale - 0.9).abs() < 1e-6));
    assert!(sc.material_textures[5].diffuse.is_some());
    let red = sc.shade(5, glam::Vec2::new(0.1, 0.1));
    let blue = sc.shade(5, glam::Vec2::new(0.6, 0.1));
    assert!(
        matches!((red, blue), (Material::Phong { diffuse: a, .. }, Material::Phong { diffuse: b, .. })
            if a != b && (a == Vec3::new(0.9, 0.2, 0.1) || b == Vec3::new(0.9, 0.2, 0.1))),
        "{red:?} {blue:?}"
    );
    assert!(
        matches!(m[6], Material::Phong { exponent, diffuse, specular, scale }
        if exponent == 30.0 && diffuse == Vec3::splat(0.5) && specular == Vec3::splat(0.2) && scale == 1.0)
    );
    for i in [0, 1, 2] {
        assert!(m[i].guidable(0.05) && m[i].nee_connectable() && m[i].one_sided());
        assert!(!m[i].is_delta() && !m[i].is_diffuse());
    }

    let e = |b: &str| load_err(&loader_xml(b), &d);
    for (b, want) in [
        (
            r#"<bsdf type="phong" id="x"><float name="exponent" value="-1"/></bsdf>"#,
            "exponent",
        ),
        (
            r#"<bsdf type="phong" id="x"><float name="exponent" value="inf"/></bsdf>"#,
            "exponent",
        ),
        (
            r#"<bsdf type="ward" id="x"><float name="alphaU" value="0"/></bsdf>"#,
            "alpha",
        ),
        (
            r#"<bsdf type="ward" id="x"><float name="alpha" value="-0.1"/></bsdf>"#,
            "alpha",
        ),
        (
            r#"<bsdf type="ward" id="x"><string name="variant" value="cook-torrance"/></bsdf>"#,
            "cook-torrance",
        ),
        (
            r#"<bsdf type="phong" id="x"><float name="alphaU" value="0.1"/></bsdf>"#,
            "alphaU",
        ),
        (
            r#"<bsdf type="ward" id="x"><float name="exponent" value="3"/></bsdf>"#,
            "exponent",
        ),
        (
            r#"<bsdf type="phong" id="x"><float name="specularSamplingWeight" value="0.5"/></bsdf>"#,
            "specularSamplingWeight",
        ),
        (
            r#"<bsdf type="phong" id="x"><texture type="checkerboard" name="exponent"/></bsdf>"#,
            "textured exponent",
        ),
        (
            r#"<bsdf type="ward" id="x"><texture type="checkerboard" name="alphaV"/></bsdf>"#,
            "textured alpha_v",
        ),
        (r#"<bsdf type="modifiedphong" id="x"/>"#, "modifiedphong"),
    ] {
        let err = e(b);
        assert!(err.contains(want) && err.contains("t.xml:"), "{b}: {err}");
    }
}

// ---------------------------------------------------------------------------------------
// Render checks
// ---------------------------------------------------------------------------------------

/// A furnace: a unit sphere with `bsdf` under a constant environment of `radiance`.
fn furnace_body(bsdf: &str, radiance: f32) -> String {
    format!(
        r#"<shape type="sphere"><float name="radius" value="1"/>
    {bsdf}</shape>
  <emitter type="constant"><rgb name="radiance" value="{radiance}"/></emitter>"#
    )
}

/// A diffuse sphere of albedo ρ filling the view under a constant environment L: every path
/// leaves after one bounce (a convex object does not see itself), so each pixel is exactly ρL.
/// `pt` is noise-free there; `pt-nee` (environment NEE + MIS) must agree by z-test.
#[test]
fn constant_environment_furnace() {
    let bsdf = r#"<bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.7"/></bsdf>"#;
    let body = furnace_body(bsdf, 2.0);
    let sc = load_in_scratch(
        "furnace",
        &scene_xml("0, -1.8, 0", "0, 0, 0", 20.0, 16, 16, &body),
    );
    let expect = [1.0f32, 1.2, 1.4];
    let pt = render_scene(&sc, IntegratorKind::Pt, 4, 1);
    for p in &pt.pixels {
        for c in 0..3 {
            assert!((p[c] - expect[c]).abs() < 1e-5, "{p:?}");
        }
    }
    let nee = render_scene(&sc, IntegratorKind::PtNee, 32, 2);
    block_ztest("constant env furnace pt vs pt-nee", &pt, &nee, 4);
}

/// A smooth glass sphere (and a twosided diffuse card behind it is absent on purpose) in a
/// constant environment: refraction in and out scales radiance by 1/η² and η², reflection
/// keeps it, so every path returns exactly L (no absorption). Paths are delta-only, so `pt`
/// and `pt-nee` coincide; only paths still inside at max_depth lose energy (rare, grazing).
#[test]
fn glass_sphere_furnace() {
    let body = furnace_body(
        r#"<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>"#,
        1.5,
    );
    let sc = load_in_scratch(
        "glass",
        &scene_xml("0, -4, 0", "0, 0, 0", 40.0, 24, 256, &body),
    );
    let img = render_scene(&sc, IntegratorKind::PtNee, 16, 3);
    let exact = img
        .pixels
        .iter()
        .filter(|p| p.iter().all(|c| (c - 1.5).abs() < 1e-4))
        .count();
    assert!(
        exact as f64 >= 0.98 * img.pixels.len() as f64,
        "{exact} of {} pixels exact",
        img.pixels.len()
    );
    let m = img.mean();
    assert!(m.iter().all(|c| (c - 1.5).abs() < 2e-3), "{m:?}");
}

/// Rough dielectric, rough plastic, plastic, rough conductor and a twosided diffuse card
/// under a constant environment: `pt` and `pt-nee` agree per block.
#[test]
fn constant_environment_pt_vs_nee() {
    let body = r#"
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><translate z="-1"/></transform>
    <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></bsdf></shape>
  <shape type="sphere"><point name="center" x="-1.1" y="0" z="0"/><float name="radius" value="0.5"/>
    <bsdf type="roughdielectric"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0" y="0" z="0"/><float name="radius" value="0.5"/>
    <bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="1.1" y="0" z="0"/><float name="radius" value="0.5"/>
    <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.3"/><translate x="0" y="-1" z="-0.7"/></transform>
    <bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="1, 0.8, 0.6"/></emitter>"#;
    let sc = load_in_scratch(
        "const",
        &scene_xml("0, -5, 2", "0, 0, -0.3", 40.0, 32, 6, body),
    );
    pt_agrees_with_nee("constant env pt vs pt-nee", &sc, 64, 10);
}

/// Envmap lighting of diffuse, plastic and smooth-conductor objects: `pt` and `pt-nee`
/// (envmap importance sampling + MIS) agree per block.
#[test]
fn envmap_pt_vs_nee() {
    let sc = envmap_scene("envmap");
    pt_agrees_with_nee("envmap pt vs pt-nee", &sc, 64, 20);
}

/// A ground plane, a rough plastic and a smooth conductor sphere under an envmap (in the
/// scratch folder `name`).
fn envmap_scene(name: &str) -> Scene {
    let d = dir(name);
    write_envmap(&d.join("env.exr"));
    let body = r#"
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.6" y="0" z="0"/><float name="radius" value="0.45"/>
    <bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.25"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0.6" y="0" z="0"/><float name="radius" value="0.45"/>
    <bsdf type="conductor"/></shape>
  <emitter type="envmap"><string name="filename" value="env.exr"/>
    <transform name="to_world"><rotate x="1" angle="90"/></transform></emitter>"#;
    load(&scene_xml("0, -4, 1.5", "0, 0, 0", 35.0, 32, 5, body), &d)
}

/// A disk area light over a cube and a plastic-coated PLY quad: `pt` and `pt-nee` agree.
#[test]
fn disk_light_pt_vs_nee() {
    let d = dir("disk");
    std::fs::write(d.join("quad.ply"), PLY_ASCII).expect("write");
    let body = r#"
  <shape type="ply"><string name="filename" value="quad.ply"/>
    <transform name="to_world"><translate x="-0.5" y="-0.5"/><scale value="4"/></transform>
    <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.5, 0.4, 0.3"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.4"/><translate z="0.4"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7"/></bsdf></shape>
  <shape type="disk"><transform name="to_world"><scale value="0.8"/><rotate x="1" angle="180"/><translate z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="3"/></emitter></shape>"#;
    let sc = load(&scene_xml("0, -4, 2.5", "0, 0, 0.3", 45.0, 32, 5, body), &d);
    pt_agrees_with_nee("disk light pt vs pt-nee", &sc, 128, 30);
}

/// Mitsuba 0.6 `phong` (exponents 40 and 300, with and without a diffuse part) and `ward`
/// (all three variants, anisotropic) under a disk light and a dim constant environment: `pt`
/// and `pt-nee` (light sampling with MIS through the new `eval` / pdf) agree per block.
#[test]
fn phong_ward_pt_vs_nee() {
    let sc = phong_ward_scene("phong-ward-render");
    let b = pt_agrees_with_nee("phong/ward pt vs pt-nee", &sc, 256, 40);
    let mean = b.mean();
    assert!(mean.iter().all(|&c| c > 0.05), "{mean:?}");
}

/// The guided integrator (NPM, product target) on the phong / ward scene: its phong / ward
/// vertices are guidable (equivalent roughness ≥ 0.05), and the render agrees with `pt-nee`
/// per block.
#[test]
fn guided_phong_ward_agrees_with_pt_nee() {
    let sc = phong_ward_scene("phong-ward-guided");
    guided_agrees_with_pt_nee("guided phong/ward vs pt-nee", &sc, 42, 4);
}

/// Trains an NPM product guide (small preset, seed `field_seed`) while rendering `sc` at
/// 64 spp and block-z-tests the guided image against `pt-nee` (seed `seed`; the guided render
/// uses `seed + 1`).
fn guided_agrees_with_pt_nee(name: &str, sc: &Scene, seed: u64, field_seed: u32) {
    use guiding::ModelSize;
    use guiding_core::loss::Target;
    use host_demo::render::{render_guided, GuidedOptions};
    let reference = render_scene(sc, IntegratorKind::PtNee, 64, seed);
    let mut o = opts(IntegratorKind::PtNee, 64, seed + 1);
    o.max_depth = sc.settings.max_depth;
    let config = training_config(1024, 2, field_seed);
    let mut g = npm_guide(Target::Product, ModelSize::Small, sc, config);
    let (img, st) =
        render_guided(sc, &o, &GuidedOptions::default(), &mut g).expect("guided render");
    assert!(img.all_finite_non_negative());
    assert!(
        st.guided_vertices > 0 && st.training_steps > 0 && st.nee,
        "{st}"
    );
    block_ztest(name, &img, &reference, 4);
}

/// Floor `ward-duer` (anisotropic), spheres `phong` n = 40 (with the default diffuse part),
/// `phong` n = 300 (specular only) and `balanced` `ward` αu 0.05 / αv 0.3, a `ward` cube, a disk
/// light and a dim constant environment.
fn phong_ward_scene(name: &str) -> Scene {
    let body = r#"
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-0.5"/></transform>
    <bsdf type="ward"><string name="variant" value="ward-duer"/><float name="alphaU" value="0.1"/><float name="alphaV" value="0.3"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.9" y="0" z="0"/><float name="radius" value="0.4"/>
    <bsdf type="phong"><float name="exponent" value="40"/><spectrum name="specularReflectance" value="0.3"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0" y="0" z="0"/><float name="radius" value="0.4"/>
    <bsdf type="phong"><float name="exponent" value="300"/><spectrum name="diffuseReflectance" value="0"/>
      <spectrum name="specularReflectance" value="0.8"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0.9" y="0" z="0"/><float name="radius" value="0.4"/>
    <bsdf type="ward"><float name="alphaU" value="0.05"/><float name="alphaV" value="0.3"/>
      <rgb name="diffuseReflectance" value="0.2, 0.3, 0.4"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.25"/><translate x="0" y="-0.9" z="-0.25"/></transform>
    <bsdf type="ward"><string name="variant" value="ward"/><float name="alpha" value="0.2"/></bsdf></shape>
  <shape type="disk"><transform name="to_world"><scale value="0.7"/><rotate x="1" angle="180"/><translate x="0.5" z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>
  <emitter type="constant"><rgb name="radiance" value="0.3, 0.25, 0.2"/></emitter>"#;
    let sc = load_in_scratch(name, &scene_xml("0, -4, 1.5", "0, 0, 0", 40.0, 32, 5, body));
    assert!(sc.materials.iter().all(|m| matches!(
        m,
        Material::Phong { .. } | Material::Ward { .. } | Material::Diffuse { .. }
    )));
    sc
}

/// A point light over a large diffuse plane, direct light only (max_depth 2): each pixel is
/// the pixel-area average of `ρ/π · I cos θ / d²`, computed here by 16 × 16 midpoint
/// quadrature through the same camera (relative error far below the 1e-6 slack of the test for
/// this smooth integrand); the render must agree per 4 × 4 block. `pt` cannot see a delta
/// light and renders black.
#[test]
fn point_light_matches_analytic() {
    let body = r#"
  <shape type="rectangle"><transform name="to_world"><scale value="50"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>
  <emitter type="point"><point name="position" x="0.3" y="0.2" z="1"/><rgb name="intensity" value="4, 3, 2"/></emitter>"#;
    let res = 16u32;
    let sc = load_in_scratch(
        "point",
        &scene_xml("0, -2, 1.5", "0, 0, 0", 50.0, res, 2, body),
    );
    let img = render_scene(&sc, IntegratorKind::PtNee, 64, 40);
    let light = Vec3::new(0.3, 0.2, 1.0);
    let intensity = Vec3::new(4.0, 3.0, 2.0);
    let q = 16;
    let mut expected = Vec::new();
    for py in 0..res {
        for px in 0..res {
            let mut acc = glam::DVec3::ZERO;
            for sy in 0..q {
                for sx in 0..q {
                    let u = (px as f32 + (sx as f32 + 0.5) / q as f32) / res as f32;
                    let v = (py as f32 + (sy as f32 + 0.5) / q as f32) / res as f32;
                    let (o, dir) = sc.camera.ray(u, v);
                    if dir.z >= 0.0 {
                        continue;
                    }
                    let p = (o + dir * (-o.z / dir.z)).as_dvec3();
                    let to = light.as_dvec3() - p;
                    let d2 = to.length_squared();
                    let cos = to.z / d2.sqrt();
                    acc += intensity.as_dvec3() * (0.8 / std::f64::consts::PI * cos / d2);
                }
            }
            let e = acc / f64::from(q * q);
            expected.push([e.x as f32, e.y as f32, e.z as f32]);
        }
    }
    let reference = Image {
        width: res,
        height: res,
        pixels: expected,
        var_of_mean: vec![[0.0; 3]; (res * res) as usize],
    };
    block_ztest("point light vs quadrature", &img, &reference, 4);
    let pt = render_scene(&sc, IntegratorKind::Pt, 2, 41);
    assert!(
        pt.pixels.iter().all(|p| *p == [0.0; 3]),
        "BSDF sampling never hits a point light"
    );
}

/// The guided integrator (NPM, product target, small preset) on the envmap scene with a
/// guidable rough plastic, a delta conductor (never guided, no NEE) and environment NEE
/// agrees with `pt-nee` per block.
#[test]
fn guided_envmap_agrees_with_pt_nee() {
    let sc = envmap_scene("guided-env");
    guided_agrees_with_pt_nee("guided envmap vs pt-nee", &sc, 50, 3);
}

/// Russian roulette (`--rr`) keeps the estimator unbiased: pt-nee with and without it agree.
#[test]
fn russian_roulette_is_unbiased() {
    let sc = host_demo::load_scene("builtin:cornell-box").expect("builtin");
    let base = RenderOptions {
        integrator: IntegratorKind::PtNee,
        spp: 32,
        max_depth: 12,
        width: 32,
        height: 32,
        ..RenderOptions::default()
    };
    let a = render(&sc, &RenderOptions { seed: 60, ..base });
    let b = render(
        &sc,
        &RenderOptions {
            seed: 61,
            rr: host_demo::render::Roulette::Throughput,
            ..base
        },
    );
    block_ztest("cornell rr vs no rr", &a, &b, 8);
}

// ---------------------------------------------------------------------------------------
// Daylight (sunsky / sun / sky)
// ---------------------------------------------------------------------------------------

/// A Mitsuba 0.6 scene (y-up sky rotated to z-up) with `body` inside.
fn scene_06(body: &str) -> String {
    let ground_and_box = r#"  <shape type="rectangle"><transform name="toWorld"><scale value="3"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
  <shape type="cube"><transform name="toWorld"><scale value="0.5"/><translate z="0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf></shape>"#;
    common::scene_doc(
        common::Dialect::V06,
        "0, -2, 6",
        "0, 0, 0",
        "0, 0, 1",
        40.0,
        32,
        3,
        &format!("{ground_and_box}\n{body}"),
    )
}

/// A Mitsuba 0.6 `sunsky` (time and place, camelCase names) over a plane with a box
/// occluder: loads with the approximation warning, and `pt` agrees with `pt-nee` (the baked
/// map's importance sampling + MIS) per block. A coarse map (`resolution` 32) keeps the sun
/// findable by `pt`'s BSDF sampling.
#[test]
fn sunsky_pt_vs_nee() {
    let body = r#"  <emitter type="sunsky">
    <float name="turbidity" value="4"/><integer name="resolution" value="32"/>
    <float name="hour" value="10.5"/><float name="sunRadiusScale" value="5"/>
    <float name="skyScale" value="5"/>
    <transform name="toWorld"><rotate x="1" angle="90"/></transform>
  </emitter>"#;
    let sc = load_in_scratch("sunsky", &scene_06(body));
    assert_warned(&sc.warnings, &["sunsky", "Preetham"]);
    assert!(sc.env.is_some());
    let b = pt_agrees_with_nee("sunsky pt vs pt-nee", &sc, 1024, 40);
    assert!(b.mean().iter().all(|c| *c > 0.0));
}

/// Mitsuba 3 spelling (`sun_direction`, z-up frame, no to_world) and the 0.6 `sun` / `sky`
/// parts with `sunDirection`: `pt` and `pt-nee` agree; the sun-only light is brighter on the
/// plane than the sky-only one at this elevation, and the sky direction matters.
#[test]
fn sunsky_sun_direction_pt_vs_nee() {
    let d = dir("sunsky-dir");
    let body = r#"
  <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.5"/><translate z="0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7"/></bsdf></shape>
  <emitter type="sunsky"><vector name="sun_direction" x="0.5" y="0.3" z="0.6"/>
    <float name="turbidity" value="2.5"/><integer name="resolution" value="32"/>
    <float name="sun_aperture" value="3"/><float name="sky_scale" value="5"/>
  </emitter>"#;
    let sc = load(&scene_xml("0, -2, 6", "0, 0, 0", 40.0, 32, 3, body), &d);
    assert_warned(&sc.warnings, &["Preetham"]);
    pt_agrees_with_nee("sunsky (sun_direction) pt vs pt-nee", &sc, 1024, 50);

    // The 0.6 parts, sun from the world direction (0, 0.5, 1) (z up through toWorld).
    let part = |ty: &str| {
        scene_06(&format!(
            r#"  <emitter type="{ty}"><vector name="sunDirection" x="0" y="0.5" z="1"/>
    <integer name="resolution" value="32"/><float name="sunRadiusScale" value="5"/>
    <transform name="toWorld"><rotate x="1" angle="90"/></transform></emitter>"#
        ))
    };
    let sun = load(&part("sun"), &d);
    let sky = load(&part("sky"), &d);
    let (s, k) = (
        render_scene(&sun, IntegratorKind::PtNee, 16, 52).mean(),
        render_scene(&sky, IntegratorKind::PtNee, 16, 53).mean(),
    );
    assert!(s[0] > 3.0 * k[0] && k[2] > 0.0, "sun {s:?} sky {k:?}");
}

/// Invalid daylight parameters name the element's line; a sun below the horizon leaves the
/// emitter out with a warning.
#[test]
fn sunsky_errors_and_night() {
    let d = dir("sunsky-err");
    let e = |em: &str| load_err(&scene_06(em), &d);
    let err = e(r#"<emitter type="sunsky"><float name="turbidity" value="12"/></emitter>"#);
    assert_mentions(&err, &["t.xml:11:", "turbidity"]);
    let err = e(r#"<emitter type="sky"><vector name="sunDirection" x="0" y="0" z="0"/></emitter>"#);
    assert_mentions(&err, &["sun_direction", "non-zero"]);
    let err = e(
        r#"<emitter type="sun"><vector name="sunDirection" x="0" y="1" z="0"/><float name="hour" value="9"/></emitter>"#,
    );
    assert!(err.contains("not both"), "{err}");
    let err = e(r#"<emitter type="sunsky"><float name="latitude" value="nan"/></emitter>"#);
    assert!(err.contains("latitude"), "{err}");
    let err = e(r#"<emitter type="sunsky"><float name="foo" value="1"/></emitter>"#);
    assert!(err.contains("foo"), "{err}");
    // Tokyo at 23:00: night.
    let sc = load(
        &scene_06(r#"<emitter type="sunsky"><float name="hour" value="23"/></emitter>"#),
        &d,
    );
    assert!(sc.env.is_none());
    assert_warned(&sc.warnings, &["below the horizon"]);
}
