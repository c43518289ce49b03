//! Participating media render like Mitsuba 3's `volpath` (issue #35, homogeneous media).
//!
//! `tests/data/media/` holds small scenes: `fog-box.xml` (a chromatic, forward-scattering
//! fog inside a cube with a `null` boundary, a diffuse sphere inside the fog, the camera and the
//! light outside), `fog-box-v06.xml` (the same scene in Mitsuba 0.6's spelling: `sigmaS` /
//! `sigmaA` and a boundary without a BSDF), `fog-room.xml` (the camera inside a grey,
//! isotropic fog that fills a closed two-sided room lit by a sphere), and `smoke.xml` /
//! `smoke-v06.xml` (fog-box with a heterogeneous, back-scattering medium: a 16³ density grid,
//! `smoke.vol`, on the unit cube under the volume's `to_world` in Mitsuba 3, on the file's own
//! box in 0.6; delta tracking and ratio tracking). Their image means were
//! measured once with Mitsuba 3's `volpath` (`data/media/measure.py`, `mitsuba3.csv`: Mitsuba
//! 3.9.1, `llvm_ad_rgb`, 8 seeds × 2048 spp; Mitsuba 3 does not load 0.6 files, the 0.6 twins
//! share their twin's row).
//!
//! Each is rendered here at the reference's size with `pt-nee` (NEE through media and null
//! surfaces, MIS against phase and BSDF sampling), and fog-box also with `pt` (emission found
//! by phase and BSDF sampling only) and `guided` (the guide trains on and guides the fog's
//! scattering points as well as the surfaces). Per render and channel
//! `z = (m − m_ref)/√(se² + se_ref²)` must stay within the two-sided normal quantile of a
//! family-wise level of 1 %, Šidák-corrected over renders × channels.
//!
//! Power (`a_wrong_phase_convention_or_albedo_is_caught`): the fog-box with the sign of `g`
//! flipped (the classic slip in the HG convention: z ≈ −250) or with its scattering
//! coefficient 3 % low (z ≈ −25), the smoke with its density grid shifted by half a cell (a
//! node- instead of cell-centred lookup), and the guided render with its guide pdf scaled by 1.5 in
//! the continuation's density (a sample / pdf mismatch at the surface and medium vertices it
//! guides), must fail the same test.
//!
//! The thin-medium rule (`thin_media_are_not_guided_and_dense_ones_are`): each medium's extent
//! and scattering optical depth as the rule defines them, and guided renders that guide the
//! fog-box's scattering points, none of the same fog thinned 100×, and all of it again with
//! the rule off.
//!
//! Run with `cargo test --release -p host-demo --test media` (about 30 s).

mod common;

use guiding::ModelSize;
use guiding_core::loss::Target;
use host_demo::render::{
    render, render_guided, GuidedOptions, IntegratorKind, RenderOptions, TestHooks,
};
use host_demo::scene::bsdf::Material;
use host_demo::scene::load::xml;
use host_demo::scene::medium::NO_MEDIUM;
use host_demo::scene::Scene;
use std::path::{Path, PathBuf};

const ALPHA: f64 = 0.01;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/media")
}

fn references() -> Vec<common::MitsubaReference> {
    common::mitsuba_references(&data_dir().join("mitsuba3.csv"))
}

/// How a render traces: `pt`, `pt-nee`, or `guided` (NPM radiance, trained in the render).
#[derive(Clone, Copy, Debug)]
enum Method {
    Pt,
    PtNee,
    Guided,
    /// `guided` with the guide pdf in the continuation's combined density scaled by 1.5 (a
    /// deliberate sample / pdf mismatch: the negative control).
    GuidedWrongPdf,
}

/// One render to compare: `(file, reference row, method, spp)`.
type Run = (&'static str, &'static str, Method, u32);

/// The comparison lines whose `|z|` exceeds the Šidák threshold over `family` renders
/// (empty: within noise). `alter` may change the scene after loading (the negative controls).
fn mismatches(runs: &[Run], family: usize, alter: impl Fn(&mut Scene)) -> Vec<String> {
    let refs = references();
    let z_max = common::z_threshold(common::sidak(ALPHA, family * 3));
    let mut bad = Vec::new();
    for &(file, reference, method, spp) in runs {
        let mut sc =
            xml::load_file(&data_dir().join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        alter(&mut sc);
        let (_, width, height, m_ref, se_ref) = refs
            .iter()
            .find(|r| r.0 == reference)
            .unwrap_or_else(|| panic!("no reference {reference}"));
        let o = RenderOptions {
            integrator: match method {
                Method::Pt => IntegratorKind::Pt,
                _ => IntegratorKind::PtNee,
            },
            spp,
            max_depth: sc.settings.max_depth,
            width: *width,
            height: *height,
            seed: 5,
            ..RenderOptions::default()
        };
        let img = match method {
            Method::Guided | Method::GuidedWrongPdf => {
                let config = common::training_config(1024, 2, 7);
                let mut g = common::npm_guide(Target::Radiance, ModelSize::Small, &sc, config);
                let scale = if matches!(method, Method::Guided) {
                    1.0
                } else {
                    1.5
                };
                let gopts = GuidedOptions {
                    test_hooks: TestHooks {
                        guide_pdf_scale: scale,
                        ..TestHooks::default()
                    },
                    ..GuidedOptions::default()
                };
                let (img, stats) = render_guided(&sc, &o, &gopts, &mut g)
                    .unwrap_or_else(|e| panic!("{file}: {e}"));
                // The guide ran at the fog's scattering points too.
                assert!(stats.medium_vertices > 0 && stats.guided_vertices > 0);
                img
            }
            _ => render(&sc, &o),
        };
        assert!(img.all_finite_non_negative(), "{file} {method:?}");
        let (m, se) = (img.mean(), img.mean_std_error());
        for c in 0..3 {
            let z = (m[c] - m_ref[c]) / (se[c] * se[c] + se_ref[c] * se_ref[c]).sqrt();
            let line = format!(
                "{file} {method:?} channel {c}: {:.6} against Mitsuba 3's {:.6} (z {z:.2}, limit {z_max:.2})",
                m[c], m_ref[c]
            );
            eprintln!("{line}");
            if z.abs() > z_max || !z.is_finite() {
                bad.push(line);
            }
        }
    }
    bad
}

const RUNS: [Run; 8] = [
    ("fog-box.xml", "fog-box", Method::PtNee, 512),
    ("fog-box-v06.xml", "fog-box", Method::PtNee, 512),
    ("fog-box.xml", "fog-box", Method::Pt, 1024),
    ("fog-box.xml", "fog-box", Method::Guided, 256),
    ("fog-room.xml", "fog-room", Method::PtNee, 1024),
    ("smoke.xml", "smoke", Method::PtNee, 512),
    ("smoke-v06.xml", "smoke", Method::PtNee, 512),
    ("smoke.xml", "smoke", Method::Guided, 256),
];

#[test]
fn media_render_like_mitsuba3_volpath() {
    let bad = mismatches(&RUNS, RUNS.len(), |_| {});
    assert!(bad.is_empty(), "{bad:#?}");
}

#[test]
fn a_wrong_phase_convention_or_albedo_is_caught() {
    let run = [RUNS[0]];
    let flipped = mismatches(&run, RUNS.len(), |sc| {
        for m in &mut sc.media {
            m.g = -m.g;
        }
    });
    assert!(!flipped.is_empty(), "a flipped g passed");
    let dim = mismatches(&run, RUNS.len(), |sc| {
        for m in &mut sc.media {
            m.sigma_s *= 0.97;
        }
    });
    assert!(!dim.is_empty(), "a 3 % lower scattering coefficient passed");
    // The density grid read node-centred instead of cell-centred (shifted by half a cell).
    let shifted = mismatches(&[RUNS[5]], RUNS.len(), |sc| {
        for m in &mut sc.media {
            if let Some(g) = &mut m.density {
                let g = std::sync::Arc::make_mut(g);
                let half = glam::Vec3::splat(0.5 / g.res[0] as f32);
                g.to_local = glam::Mat4::from_translation(half) * g.to_local;
            }
        }
    });
    assert!(!shifted.is_empty(), "a grid shifted by half a cell passed");
    let wrong_pdf = [("fog-box.xml", "fog-box", Method::GuidedWrongPdf, RUNS[3].3)];
    assert!(
        !mismatches(&wrong_pdf, RUNS.len(), |_| {}).is_empty(),
        "a guide pdf 1.5x too large passed"
    );
}

/// What the loader builds from the media constructs, and the errors it gives.
#[test]
fn media_constructs_load_as_mitsuba_reads_them() {
    let v3 = xml::load_file(&data_dir().join("fog-box.xml")).unwrap_or_else(|e| panic!("{e}"));
    let v06 = xml::load_file(&data_dir().join("fog-box-v06.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(v3.media.len(), 1);
    // σt = scale · sigma_t, σs = albedo · σt; 0.6's σs, σa give the same medium.
    for sc in [&v3, &v06] {
        let m = &sc.media[0];
        assert!(
            (m.sigma_t - glam::Vec3::new(0.8, 1.2, 1.6))
                .abs()
                .max_element()
                < 1e-5
        );
        assert!(
            (m.sigma_s - glam::Vec3::new(0.72, 0.96, 1.12))
                .abs()
                .max_element()
                < 1e-5
        );
        assert_eq!(m.g, 0.6);
        assert!(sc.has_volumes);
        assert_eq!(sc.camera_medium, NO_MEDIUM);
        // The boundary: null, fog inside, vacuum outside (0.6: a shape without a BSDF).
        let boundary = sc
            .shapes
            .iter()
            .find(|s| s.media.is_some())
            .unwrap_or_else(|| panic!("no boundary"));
        let i = boundary.media.unwrap_or_else(|| unreachable!());
        assert_eq!((i.interior, i.exterior), (0, NO_MEDIUM));
        assert_eq!(sc.materials[boundary.material as usize], Material::Null);
        // The area light without a BSDF gets Mitsuba's black diffuse.
        let light = sc
            .shapes
            .iter()
            .find(|s| s.emission.is_some())
            .unwrap_or_else(|| panic!("no light"));
        assert_eq!(
            sc.materials[light.material as usize],
            Material::Diffuse {
                reflectance: glam::Vec3::ZERO
            }
        );
    }
    let room = xml::load_file(&data_dir().join("fog-room.xml")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(room.camera_medium, 0);
    assert_eq!(room.media[0].g, 0.0);
    // Heterogeneous: Mitsuba 3 places the grid with the volume's to_world, 0.6 on the file's
    // box; both put smoke.vol on the null cube, so the two read the same density.
    let dir = data_dir();
    let smoke = xml::load_file(&dir.join("smoke.xml")).unwrap_or_else(|e| panic!("{e}"));
    let smoke06 = xml::load_file(&dir.join("smoke-v06.xml")).unwrap_or_else(|e| panic!("{e}"));
    let (a, b) = (&smoke.media[0], &smoke06.media[0]);
    assert_eq!(a.sigma_t, glam::Vec3::splat(6.0));
    assert!(
        (a.sigma_s - glam::Vec3::new(5.7, 5.1, 4.2))
            .abs()
            .max_element()
            < 1e-5
    );
    let (ga, gb) = (a.density.as_ref().unwrap(), b.density.as_ref().unwrap());
    assert_eq!(ga.res, [16, 16, 16]);
    for p in [
        [0.0, 0.85, 0.0],
        [-0.5, 0.3, 0.2],
        [0.79, 1.6, -0.7],
        [0.0, 2.0, 0.0],
    ] {
        let p = glam::Vec3::from_array(p);
        assert!((ga.eval(p) - gb.eval(p)).abs() < 1e-5, "{p}");
    }
    assert_eq!(ga.eval(glam::Vec3::new(0.0, 2.0, 0.0)), 0.0);
    assert!(ga.eval(glam::Vec3::new(-0.08, 0.69, 0.0)) > 0.9);

    let doc = |body: &str| {
        common::scene_doc(
            common::Dialect::V3,
            "0, 0, 4",
            "0, 0, 0",
            "0, 1, 0",
            40.0,
            16,
            8,
            body,
        )
    };
    let load = |body: &str| xml::load_str(&doc(body), "media.xml", &dir);
    let err = |body: &str| match load(body) {
        Ok(_) => panic!("loaded: {body}"),
        Err(e) => e.to_string(),
    };
    // Mitsuba 3: a shape that bounds a medium without a BSDF keeps the default diffuse.
    let sc = load(
        r#"<medium type="homogeneous" id="m"/>
           <shape type="sphere"><ref name="interior" id="m"/></shape>"#,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(
        sc.materials[sc.shapes[0].material as usize],
        Material::Diffuse { .. }
    ));
    // Mitsuba 3's defaults: sigma_t 1, albedo 0.75, isotropic.
    assert_eq!(sc.media[0].sigma_t, glam::Vec3::ONE);
    assert_eq!(sc.media[0].sigma_s, glam::Vec3::splat(0.75));
    // A nested medium.
    let sc = load(
        r#"<shape type="sphere"><bsdf type="null"/>
             <medium type="homogeneous" name="exterior"><float name="sigma_t" value="2"/></medium>
           </shape>"#,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let i = sc.shapes[0].media.unwrap_or_else(|| panic!("no interface"));
    assert_eq!((i.interior, i.exterior), (NO_MEDIUM, 0));
    for (body, says) in [
        (
            r#"<medium type="pseudo" id="m"/><shape type="sphere"/>"#,
            "medium type",
        ),
        (
            r#"<shape type="sphere"><ref name="interior" id="nope"/></shape>"#,
            "unknown medium id \"nope\"",
        ),
        (
            r#"<medium type="homogeneous" id="m"><float name="sigma_t" value="1"/>
                 <float name="sigmaS" value="1"/></medium><shape type="sphere"/>"#,
            "not both",
        ),
        (
            r#"<medium type="homogeneous" id="m"><float name="albedo" value="1.5"/></medium>
               <shape type="sphere"/>"#,
            "albedo",
        ),
        (
            r#"<medium type="homogeneous" id="m"><phase type="hg"><float name="g" value="1"/></phase></medium>
               <shape type="sphere"/>"#,
            "-1 < g < 1",
        ),
        (
            r#"<shape type="sphere"><bsdf type="null"/><emitter type="area"/></shape>"#,
            "null BSDF is not supported",
        ),
        (
            r#"<medium type="heterogeneous" id="m"><float name="sigma_t" value="1"/></medium>
               <shape type="sphere"/>"#,
            "needs a gridvolume",
        ),
        (
            r#"<medium type="heterogeneous" id="m"><volume name="sigma_t" type="gridvolume">
                 <string name="filename" value="nope.vol"/></volume></medium><shape type="sphere"/>"#,
            "nope.vol",
        ),
        (
            r#"<medium type="heterogeneous" id="m"><volume name="sigma_t" type="gridvolume">
                 <string name="filename" value="smoke.vol"/></volume>
                 <volume name="albedo" type="gridvolume"><string name="filename" value="smoke.vol"/></volume>
               </medium><shape type="sphere"/>"#,
            "grid albedo",
        ),
        (
            r#"<medium type="heterogeneous" id="m"><volume name="sigma_t" type="gridvolume">
                 <string name="filename" value="fog-box.xml"/></volume></medium><shape type="sphere"/>"#,
            "magic",
        ),
    ] {
        let e = err(body);
        assert!(e.contains(says), "{body}: {e}");
        assert!(e.contains("media.xml"), "no file in {e}");
    }
}

/// The thin-medium rule (`guiding::media`, `host_demo::render::media_guiding`): a medium's
/// extent is the box of the shapes it fills (the fog-box's null cube, side 1.6) or the whole
/// scene around the camera (the fog-room, a cube of side 4); its scattering optical depth
/// `σ_s,max · d` decides. The dense fog's scattering points are guided; thinned 100× (depth
/// 0.031 < 0.05) none is, while the same render with the rule off (`--guide-media on`)
/// guides them, and with the rule on the thin fog's vertices still scatter (phase sampling).
#[test]
fn thin_media_are_not_guided_and_dense_ones_are() {
    use host_demo::render::media_guiding;
    let load = |f: &str| xml::load_file(&data_dir().join(f)).unwrap_or_else(|e| panic!("{e}"));
    let dense = load("fog-box.xml");
    let g = media_guiding(&dense);
    let diagonal = 1.6 * 3f32.sqrt();
    assert_eq!(g.len(), 1);
    assert!((g[0].extent - diagonal).abs() < 1e-4, "{g:?}");
    assert!(
        (g[0].scattering_depth - 1.12 * diagonal).abs() < 1e-3,
        "{g:?}"
    );
    assert!(g[0].guided);
    let room = load("fog-room.xml");
    let (lo, hi) = room.bounds();
    let g_room = media_guiding(&room);
    assert_eq!(g_room[0].extent, (hi - lo).length());
    assert!(
        (g_room[0].extent - 4.0 * 3f32.sqrt()).abs() < 1e-3,
        "{g_room:?}"
    );
    let mut thin = load("fog-box.xml");
    thin.media[0].sigma_t *= 0.01;
    thin.media[0].sigma_s *= 0.01;
    let g_thin = media_guiding(&thin);
    assert!((g_thin[0].scattering_depth - 0.0112 * diagonal).abs() < 1e-4);
    assert!(!g_thin[0].guided);
    // Guided renders: (scene, rule on) -> guided medium vertices.
    let run = |sc: &Scene, rule: bool| {
        let o = RenderOptions {
            spp: 32,
            max_depth: sc.settings.max_depth,
            width: 32,
            height: 32,
            seed: 9,
            ..RenderOptions::default()
        };
        let config = common::training_config(1024, 2, 7);
        let mut guide = common::npm_guide(Target::Radiance, ModelSize::Small, sc, config);
        let gopts = GuidedOptions {
            thin_media_rule: rule,
            ..GuidedOptions::default()
        };
        let (_, stats) =
            render_guided(sc, &o, &gopts, &mut guide).unwrap_or_else(|e| panic!("{e}"));
        assert!(stats.medium_vertices > 0);
        assert!(stats.guided_medium_vertices <= stats.guided_vertices);
        stats.guided_medium_vertices
    };
    assert!(run(&dense, true) > 0);
    assert_eq!(run(&thin, true), 0);
    assert!(run(&thin, false) > 0);
}
