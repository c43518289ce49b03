//! Loader coverage and BVH correctness. Run with `cargo test --release -p host-demo --test loader`
//! (about a second).
//!
//! * Every built-in and shared scene loads; malformed XML, a missing mesh and a non-finite
//!   transform are clear errors naming the file and position / path / element and line.
//! * The obvhs CWBVH closest hit equals a brute-force loop over all primitives on random rays.

use glam::Vec3;
use guiding_core::rng::Pcg32;
use host_demo::scene::bsdf::Material;
use host_demo::scene::load::xml;
use host_demo::scene::Scene;
use std::path::{Path, PathBuf};

mod common;

use common::assert_mentions;

/// Every scene the tests know: the three built-ins and the two shared scenes (their folder
/// missing is a failure, [`common::shared_scenes`]).
fn all_scenes() -> Vec<(String, Scene)> {
    let mut specs: Vec<String> = ["cornell-box", "door", "furnace"]
        .iter()
        .map(|n| format!("builtin:{n}"))
        .collect();
    let dir = common::shared_scenes();
    for n in ["cornell-box", "veach-mis"] {
        specs.push(dir.join(n).join("scene.xml").display().to_string());
    }
    specs
        .into_iter()
        .map(|s| {
            let sc = host_demo::load_scene(&s).unwrap_or_else(|e| panic!("{s}: {e}"));
            (s, sc)
        })
        .collect()
}

fn load_err(text: &str, base: &Path) -> String {
    xml::load_str(text, "t.xml", base)
        .err()
        .expect("must fail")
        .to_string()
}

#[test]
fn every_builtin_and_shared_scene_loads() {
    let scenes = all_scenes();
    for (name, sc) in &scenes {
        let (lo, hi) = sc.bounds();
        eprintln!(
            "{name}: {} prims, {} shapes, {} materials, {} emitters, bounds {lo} .. {hi}",
            sc.prims.len(),
            sc.shapes.len(),
            sc.materials.len(),
            sc.emitter_count()
        );
        assert!(!sc.prims.is_empty(), "{name}: no primitives");
        assert!(sc.emitter_count() > 0, "{name}: no emitters");
        assert!(lo.is_finite() && hi.is_finite() && lo.cmplt(hi).any());
        assert!(sc.settings.width > 0 && sc.settings.height > 0);
    }
    // Emitter counts and images of the shared scenes are checked in render.rs.
    assert_eq!(scenes.len(), 5);
}

#[test]
fn malformed_xml_names_file_and_position() {
    // Unclosed <shape>: roxmltree reports the closing tag mismatch at line 3.
    let text = "<scene version=\"3.0.0\">\n  <shape type=\"sphere\">\n</scene>\n";
    let e = xml::load_str(text, "bad.xml", Path::new("."))
        .err()
        .expect("must fail")
        .to_string();
    eprintln!("{e}");
    assert!(
        e.starts_with("bad.xml: XML syntax error"),
        "names the file: {e}"
    );
    assert!(e.contains("3:"), "names the position (line 3): {e}");

    // The same through `load_file`: the message carries the real path.
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("loader-malformed");
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let path = dir.join("broken.xml");
    std::fs::write(
        &path,
        "<scene version=\"3.0.0\">\n<bsdf type=\"diffuse\" id=\"a\">\n",
    )
    .expect("write");
    let e = xml::load_file(&path).err().expect("must fail").to_string();
    eprintln!("{e}");
    assert!(e.contains(&path.display().to_string()), "{e}");
    assert!(e.contains("XML syntax error"), "{e}");

    // A file that does not exist at all.
    let e = host_demo::load_scene("/nonexistent/dir/scene.xml")
        .err()
        .expect("must fail")
        .to_string();
    assert!(e.contains("/nonexistent/dir/scene.xml"), "{e}");
}

#[test]
fn missing_mesh_names_the_path() {
    let base = Path::new("/nonexistent/meshes");
    for (ty, file) in [("obj", "nope.obj"), ("ply", "sub/nope.ply")] {
        let text = format!(
            "<scene version=\"3.0.0\">\n<shape type=\"{ty}\">\n  <string name=\"filename\" value=\"{file}\"/>\n</shape>\n</scene>"
        );
        let e = load_err(&text, base);
        eprintln!("{e}");
        let full = base.join(file).display().to_string();
        assert!(e.contains(&full), "{ty}: error names {full}: {e}");
    }
}

#[test]
fn non_finite_transform_names_element_and_line() {
    let nan_matrix = "<scene version=\"3.0.0\">\n<shape type=\"sphere\">\n  <transform name=\"to_world\">\n    <matrix value=\"1 0 0 0 0 nan 0 0 0 0 1 0 0 0 0 1\"/>\n  </transform>\n</shape>\n</scene>";
    let e = load_err(nan_matrix, Path::new("."));
    eprintln!("{e}");
    assert!(e.starts_with("t.xml:4:"), "line of <matrix>: {e}");
    assert_mentions(&e, &["<matrix>", "not finite"]);

    let inf_translate = "<scene version=\"3.0.0\">\n<shape type=\"rectangle\">\n  <transform name=\"to_world\">\n    <scale value=\"2\"/>\n    <translate x=\"1\" y=\"inf\"/>\n  </transform>\n</shape>\n</scene>";
    let e = load_err(inf_translate, Path::new("."));
    eprintln!("{e}");
    assert!(e.starts_with("t.xml:5:"), "line of <translate>: {e}");
    assert_mentions(&e, &["<translate>", "not finite"]);

    // Camera transforms go through the same path.
    let nan_rotate = "<scene version=\"3.0.0\">\n<sensor type=\"perspective\">\n<transform name=\"to_world\">\n<rotate y=\"1\" angle=\"NaN\"/>\n</transform>\n</sensor>\n<shape type=\"sphere\"/>\n</scene>";
    let e = load_err(nan_rotate, Path::new("."));
    eprintln!("{e}");
    assert!(e.starts_with("t.xml:4:") && e.contains("<rotate>"), "{e}");
}

// ---------------------------------------------------------------------------------------
// BVH against brute force
// ---------------------------------------------------------------------------------------

/// Uniform points in a box and directions on the sphere for the test rays, from the
/// workspace's PCG32.
trait TestRays {
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3;
    fn direction(&mut self) -> Vec3;
}

impl TestRays for Pcg32 {
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        lo + (hi - lo) * Vec3::new(self.next_f32(), self.next_f32(), self.next_f32())
    }

    fn direction(&mut self) -> Vec3 {
        let z = 1.0 - 2.0 * self.next_f32();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = 2.0 * std::f32::consts::PI * self.next_f32();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// Closest hit by testing every primitive: `(t, prim)`, the lowest index wins exact ties.
fn brute_force(sc: &Scene, o: Vec3, d: Vec3, tmin: f32) -> Option<(f32, u32)> {
    let mut best: Option<(f32, u32)> = None;
    for (i, p) in sc.prims.iter().enumerate() {
        if let Some((t, _, _)) = p.intersect(o, d, tmin, f32::INFINITY) {
            if best.is_none_or(|b| t < b.0) {
                best = Some((t, i as u32));
            }
        }
    }
    best
}

/// Random rays against every scene: origins uniform in the scene box with uniform directions,
/// and origins on a sphere around the box (radius 2× its diagonal) aimed at a random point of
/// the box. The CWBVH and the brute-force loop call the same `Prim::intersect`, so:
///
/// * hit / miss must agree exactly (the BVH's box tests must never cull a hit primitive);
/// * the same primitive must give a bit-identical distance;
/// * a different primitive is allowed only at a tie: the BVH's primitive, intersected
///   directly, must lie within `tol` of the brute-force distance. Ties happen where the ray
///   crosses an edge shared by two triangles (a mesh's quads) or a coincident surface.
///
/// `tol`: Möller–Trumbore computes `t = e2·(tv × e1) / det` from products of coordinates of
/// magnitude ≤ `L` (the distance scale: origin to scene plus scene diagonal); each of the ~10
/// roundings is ≤ ε = 2⁻²⁴ relative to `L`, so the two computations of a shared edge differ by
/// at most ~20 ε L ≈ 1.2·10⁻⁶ L. We allow 1e-5·L (8× headroom), far below any real distance
/// between surfaces of these scenes.
#[test]
fn bvh_matches_brute_force_on_random_rays() {
    const RAYS: usize = 3000;
    for (name, sc) in all_scenes() {
        let (lo, hi) = sc.bounds();
        let diag = (hi - lo).length();
        let center = 0.5 * (lo + hi);
        let mut rng = Pcg32::new(0x5EED_0000 + sc.prims.len() as u64, 7);
        let (mut hits, mut ties) = (0usize, 0usize);
        for k in 0..RAYS {
            let (o, d) = if k % 10 == 4 {
                // Axis-aligned: exactly-zero direction components (1/d = ±∞ in the slab test).
                let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
                (rng.in_box(lo, hi), axes[(k / 10) % 6])
            } else if k % 2 == 0 {
                (rng.in_box(lo, hi), rng.direction())
            } else {
                let o = center + 2.0 * diag * rng.direction();
                let d = (rng.in_box(lo, hi) - o).normalize();
                (o, d)
            };
            let tmin = 1e-4 * diag;
            let bvh = sc.intersect(o, d, tmin, f32::INFINITY);
            let bf = brute_force(&sc, o, d, tmin);
            let l = (o - center).length() + diag;
            let tol = 1e-5 * l;
            match (bvh, bf) {
                (None, None) => {}
                (Some(h), Some((t, id))) => {
                    hits += 1;
                    if h.prim == id {
                        assert_eq!(h.t, t, "{name} ray {k}: same prim {id}, different t");
                    } else {
                        ties += 1;
                        let own = sc.prims[h.prim as usize]
                            .intersect(o, d, tmin, f32::INFINITY)
                            .map(|x| x.0);
                        assert_eq!(own, Some(h.t), "{name} ray {k}: BVH t is its prim's t");
                        assert!(
                            (h.t - t).abs() <= tol,
                            "{name} ray {k} (o {o}, d {d}): BVH prim {} at t {} vs brute force prim {id} at t {t} (tol {tol})",
                            h.prim,
                            h.t
                        );
                    }
                    assert_eq!(h.shape, sc.prim_shape[h.prim as usize]);
                }
                (a, b) => panic!(
                    "{name} ray {k} (o {o}, d {d}): BVH {:?} vs brute force {b:?}",
                    a.map(|h| (h.t, h.prim))
                ),
            }
            // Shadow rays agree with the closest-hit query.
            let occ = sc.occluded(o, d, tmin, f32::INFINITY);
            assert_eq!(occ, bf.is_some(), "{name} ray {k}: occluded() disagrees");
        }
        eprintln!(
            "{name}: {RAYS} rays, {hits} hits, {ties} ties at a different primitive, {} prims",
            sc.prims.len()
        );
        assert!(
            hits > RAYS / 4,
            "{name}: too few hits ({hits}) to test much"
        );
        // Shared edges are hit with probability ~0 by random rays; many ties mean coincident
        // surfaces (e.g. two one-sided quads back to back), where the BVH returns either.
        assert!(
            ties * 100 <= hits,
            "{name}: {ties} of {hits} hits tie between primitives: coincident surfaces?"
        );
    }
}

// ---------------------------------------------------------------------------------------
// Mitsuba 0.6 spellings
// ---------------------------------------------------------------------------------------

/// A small scene: camera `to_world` block, one rectangle light and a sphere with `bsdf`.
fn scene_06(camera_transform: &str, shape_transform: &str, bsdf: &str, radiance: &str) -> String {
    format!(
        r#"<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    {camera_transform}
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <shape type="sphere">{shape_transform}{bsdf}</shape>
  <shape type="rectangle"><transform name="to_world"><translate z="3"/></transform>
    <emitter type="area">{radiance}</emitter></shape>
</scene>"#
    )
}

fn load_ok(text: &str) -> Scene {
    xml::load_str(text, "t.xml", Path::new(".")).unwrap_or_else(|e| panic!("loads: {e}\n{text}"))
}

/// Same materials, camera and geometry (bit for bit: the same operations run).
fn assert_same_scene(a: &Scene, b: &Scene, what: &str) {
    assert_eq!(a.materials, b.materials, "{what}: materials");
    assert_eq!(a.camera.to_world, b.camera.to_world, "{what}: camera");
    assert_eq!(a.prims.len(), b.prims.len(), "{what}: prims");
    assert_eq!(
        format!("{:?}", a.prims),
        format!("{:?}", b.prims),
        "{what}: geometry"
    );
    assert_eq!(
        a.lights.iter().map(|l| l.radiance).collect::<Vec<_>>(),
        b.lights.iter().map(|l| l.radiance).collect::<Vec<_>>(),
        "{what}: emitters"
    );
}

/// sRGB decoding (IEC 61966-2-1) in f64, for the Mitsuba 3 twins' linear values.
fn decode(c: f64) -> f32 {
    (if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }) as f32
}

#[test]
fn mitsuba_06_spellings_equal_their_mitsuba_3_twins() {
    let cam3 = r#"<transform name="to_world"><lookat origin="0, -5, 1" target="0, 0, 0" up="0, 0, 1"/></transform>"#;
    let cam06 = r#"<transform name="toWorld"><lookAt origin="0, -5, 1" target="0, 0, 0" up="0, 0, 1"/></transform>"#;
    let tr3 = r#"<transform name="to_world"><scale value="0.5"/><translate x="0.25"/></transform>"#;
    let tr06 = r#"<transform name="toWorld"><scale value="0.5"/><translate x="0.25"/></transform>"#;
    let diffuse = |c: &str| format!(r#"<bsdf type="diffuse">{c}</bsdf>"#);
    let rgb = |v: [f32; 3]| {
        format!(
            r#"<rgb name="reflectance" value="{}, {}, {}"/>"#,
            v[0], v[1], v[2]
        )
    };
    let light3 = r#"<rgb name="radiance" value="2"/>"#;

    // lookAt + toWorld on the camera and a shape.
    let m3 = load_ok(&scene_06(cam3, tr3, &diffuse(&rgb([0.5; 3])), light3));
    let m06 = load_ok(&scene_06(cam06, tr06, &diffuse(&rgb([0.5; 3])), light3));
    assert_same_scene(&m06, &m3, "lookAt/toWorld");
    // toWorld on a top-level point emitter too.
    let point = |name: &str| {
        format!(
            r#"<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/></sensor><shape type="sphere"/><emitter type="point"><transform name="{name}"><translate z="4"/></transform><rgb name="intensity" value="3"/></emitter></scene>"#
        )
    };
    let (p3, p06) = (load_ok(&point("to_world")), load_ok(&point("toWorld")));
    assert_eq!(
        format!("{:?}", p3.point_lights),
        format!("{:?}", p06.point_lights)
    );

    // srgb: hex and numbers, decoded to linear as Mitsuba 0.6 does.
    let hex = decode(f64::from(0x88u8) / 255.0);
    assert!((hex - 0.246_201).abs() < 1e-5, "{hex}");
    for (srgb, linear) in [
        (
            r##"<srgb name="reflectance" value="#ff8800"/>"##,
            [1.0, hex, 0.0],
        ),
        (
            r#"<srgb name="reflectance" value="0.5, 0.2, 0.02"/>"#,
            [decode(0.5), decode(0.2), decode(0.02)],
        ),
        (
            r#"<srgb name="reflectance" value="0.5"/>"#,
            [decode(0.5); 3],
        ),
    ] {
        let a = load_ok(&scene_06(cam3, tr3, &diffuse(srgb), light3));
        let b = load_ok(&scene_06(cam3, tr3, &diffuse(&rgb(linear)), light3));
        // The loader decodes in f32: equal to the f64 decoding within a few ulps.
        match (a.materials[0], b.materials[0]) {
            (
                host_demo::scene::bsdf::Material::Diffuse { reflectance: ra },
                host_demo::scene::bsdf::Material::Diffuse { reflectance: rb },
            ) => assert!(
                (ra - rb).abs().max_element() <= 4.0 * f32::EPSILON,
                "{srgb}: {ra} vs {rb}"
            ),
            other => panic!("{srgb}: {other:?}"),
        }
    }
    // decode(0.02) is on the linear segment: 0.02 / 12.92.
    assert!((decode(0.02) - 0.02 / 12.92).abs() < 1e-9);

    // spectrum with a single value: grey, for a BSDF and an emitter.
    let a = load_ok(&scene_06(
        cam3,
        tr3,
        &diffuse(r#"<spectrum name="reflectance" value="0.3"/>"#),
        r#"<spectrum name="radiance" value="2"/>"#,
    ));
    let b = load_ok(&scene_06(cam3, tr3, &diffuse(&rgb([0.3; 3])), light3));
    assert_same_scene(&a, &b, "spectrum");

    // Wavelength:value pairs are reduced to RGB (crate::scene::spectrum); malformed ones are errors.
    let sc = load_ok(&scene_06(
        cam3,
        tr3,
        &diffuse(r#"<spectrum name="reflectance" value="400:0.1, 700:0.5"/>"#),
        light3,
    ));
    assert!(
        matches!(sc.materials[0], Material::Diffuse { reflectance } if reflectance.x > reflectance.z),
        "{:?}",
        sc.materials[0]
    );
    let e = load_err(
        &scene_06(
            cam3,
            tr3,
            &diffuse(r#"<spectrum name="reflectance" value="700:0.1, 400:0.5"/>"#),
            light3,
        ),
        Path::new("."),
    );
    assert_mentions(&e, &["spectrum", "wavelength"]);
    let e = load_err(
        &scene_06(
            cam3,
            tr3,
            &diffuse(r##"<srgb name="reflectance" value="#ff88"/>"##),
            light3,
        ),
        Path::new("."),
    );
    assert!(e.contains("#ff88"), "{e}");
}

/// One load reports every error of a scene (each with its file and line), not only the first;
/// unknown constructs are warnings there and join the errors with `strict`.
#[test]
fn every_problem_is_reported_in_one_run() {
    let text = r#"<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <vector name="min_bounds" x="0" y="0" z="0"/>
  </sensor>
  <bsdf type="principled" id="p"/>
  <shape type="obj"><string name="filename" value="missing.obj"/></shape>
  <shape type="sphere"><ref id="nope"/></shape>
  <shape type="sphere"><transform name="to_world"><translate x="nan"/></transform></shape>
  <shape type="sphere"><emitter type="area"><rgb name="radiance" value="-1"/></emitter></shape>
  <shape type="sphere"><bsdf type="diffuse"><boolean name="usePathGuiding" value="true"/></bsdf></shape>
</scene>"#;
    let lenient = load_err(text, Path::new("/nonexistent"));
    let lines: Vec<&str> = lenient.lines().collect();
    assert!(lines[0].contains("4 problems"), "{lenient}");
    for (line, needle) in [
        ("t.xml:6:", "missing.obj"),
        ("t.xml:7:", "nope"),
        ("t.xml:8:", "not finite"),
        ("t.xml:9:", "-1"),
    ] {
        assert!(
            lines.iter().any(|l| l.contains(line) && l.contains(needle)),
            "{line} {needle}: {lenient}"
        );
    }
    // The missing mesh names the shape that asked for it and the path it tried.
    assert!(
        lenient.contains("t.xml:6:3: obj shape: /nonexistent/missing.obj"),
        "{lenient}"
    );
    let opts = xml::LoadOptions {
        strict: true,
        ..xml::LoadOptions::default()
    };
    let strict = xml::load_str_opts(
        text,
        "t.xml",
        Path::new("/nonexistent"),
        &|p| std::fs::read(p),
        &opts,
    )
    .err()
    .expect("must fail")
    .to_string();
    assert!(
        strict.lines().next().unwrap().contains("7 problems"),
        "{strict}"
    );
    for needle in [
        "<vector name=\"min_bounds\">",
        "<bsdf type=\"principled\" id=\"p\">",
        "<boolean name=\"usePathGuiding\">",
    ] {
        assert!(strict.contains(needle), "{needle}: {strict}");
    }

    // Without the errors the scene loads, and the warnings name file, line and what was done.
    let fixable: String = text
        .lines()
        .filter(|l| {
            !l.contains("missing.obj")
                && !l.contains("nope")
                && !l.contains("nan")
                && !l.contains("-1")
        })
        .collect::<Vec<_>>()
        .join("\n");
    let sc = xml::load_str(&fixable, "t.xml", Path::new(".")).expect("loads with warnings");
    for (line, needle) in [
        ("t.xml:3:", "<vector name=\"min_bounds\">: ignored"),
        ("t.xml:5:", "grey diffuse"),
        ("t.xml:6:", "<boolean name=\"usePathGuiding\">: ignored"),
    ] {
        assert!(
            sc.warnings
                .iter()
                .any(|w| w.starts_with(line) && w.contains(needle)),
            "{line} {needle}: {:#?}",
            sc.warnings
        );
    }
}

/// The fuzz-found singular sensor (`fuzz/corpus/scene_parser/crash-singular-sensor`): the
/// shared Cornell box with the `-1` of its camera's z axis written `-0`. The camera's linear
/// part then maps every view direction into the x-y plane and the centre pixel's to zero (NaN
/// after normalising): release rendered black, debug builds panicked in obvhs's ray
/// constructor. It is refused, naming the file and the `<sensor>`'s line; a shear that makes
/// the columns coplanar is refused too, while a scaled or mirrored camera loads.
#[test]
fn singular_sensor_transform_is_an_error() {
    let dir = common::shared_scenes().join("cornell-box");
    let text = std::fs::read_to_string(dir.join("scene.xml")).expect("shared scene");
    let good = r#"<matrix value="-1 0 0 0 0 1 0 1 0 0 -1 6.8 0 0 0 1"/>"#;
    assert!(text.contains(good), "the shared scene's sensor changed");
    let singular = text.replace(
        good,
        r#"<matrix value="-1 0 0 0 0 1 0 1 0 0 -0 6.8 0 0 0 1"/>"#,
    );
    let e = load_err(&singular, &dir);
    eprintln!("{e}");
    assert_eq!(e.lines().count(), 1, "one problem: {e}");
    assert!(
        e.starts_with("t.xml:4:") && e.contains("sensor to_world is singular"),
        "names the file and the <sensor> line: {e}"
    );
    // The corpus file is the same scene (with its meshes inlined for the fuzzer).
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus/scene_parser/crash-singular-sensor");
    let bytes = std::fs::read(&corpus).expect("corpus file");
    let xml_part = String::from_utf8_lossy(&bytes);
    let xml_part = xml_part.split('\0').next().unwrap_or("");
    let e = load_err(xml_part, &dir);
    assert!(e.contains("sensor to_world is singular"), "{e}");

    let sensor = |m: &str| {
        format!(
            r#"<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>
<transform name="to_world"><matrix value="{m}"/></transform></sensor>
<shape type="sphere"/></scene>"#
        )
    };
    // Coplanar columns (z = x + y): refused.
    let e = load_err(&sensor("1 0 1 0 0 1 1 0 0 0 0 5 0 0 0 1"), Path::new("."));
    assert!(e.contains("singular"), "{e}");
    // Scaled by 10⁻³ and mirrored: a valid camera.
    let sc = load_ok(&sensor("-0.001 0 0 0 0 0.001 0 0 0 0 0.001 -5 0 0 0 1"));
    let (o, d) = sc.camera.ray(0.5, 0.5);
    assert!(o.is_finite() && (d.length() - 1.0).abs() < 1e-5);
}

/// Rays the BVH cannot traverse (NaN, infinite or zero directions, a NaN origin; subnormal
/// components whose inverse overflows) never reach obvhs: they miss and count as occluded,
/// and a subnormal component is traversed like a zero one.
#[test]
fn invalid_rays_miss() {
    let sc = load_ok(
        r#"<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>
<transform name="to_world"><lookat origin="0, 0, -5" target="0, 0, 0"/></transform></sensor>
<shape type="sphere"/></scene>"#,
    );
    let o = Vec3::new(0.0, 0.0, -5.0);
    for d in [
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::new(0.0, 0.0, f32::INFINITY),
        Vec3::new(f32::NAN, 0.0, 1.0),
    ] {
        assert!(sc.intersect(o, d, 1e-4, f32::INFINITY).is_none(), "{d}");
        assert!(sc.occluded(o, d, 1e-4, 10.0), "{d}");
    }
    assert!(sc.intersect(Vec3::NAN, Vec3::Z, 1e-4, 10.0).is_none());
    let sub = Vec3::new(1e-40, -1e-42, 1.0);
    let hit = sc
        .intersect(o, sub, 1e-4, f32::INFINITY)
        .expect("hits the sphere");
    assert!((hit.t - 4.0).abs() < 1e-4, "{}", hit.t);
    assert!(sc.occluded(o, sub, 1e-4, 10.0));
}
