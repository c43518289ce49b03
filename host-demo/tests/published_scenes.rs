//! Published Mitsuba scenes load as they are downloaded and render like Mitsuba 3.
//!
//! `tests/data/published/` holds Benedikt Bitterli's CC0 scenes exactly as published in two
//! public research repositories (see each LICENSE.txt and `data/published/README.md`):
//! the Mitsuba 0.5 original of "Veach, MIS" and the Mitsuba 3 exports of "Cornell Box",
//! "Veach, Bidir Room" and "Veach, MIS". None of them loaded on the main branch before the
//! loader learnt to warn and go on: the 0.5 file stopped at `extEta` and then at
//! `specularReflectance` on a `roughconductor`; the Mitsuba 3 files at their
//! `path_guiding_integrator` (a research plugin) and then at `specular_reflectance` on a
//! `roughconductor`.
//!
//! Each is loaded unchanged (the warnings it must give are listed below) and rendered with
//! `pt-nee` at the size of its Mitsuba 3 reference (`data/published/mitsuba3.csv`, written by
//! `measure.py`: Mitsuba 3.9.1 with `-D integrator=path`, the only change Mitsuba 3 needs;
//! it refuses the 0.5 file, which shares the reference of its Mitsuba 3 twin). Per scene
//! and channel `z = (m − m_ref)/√(se² + se_ref²)` must stay within the two-sided normal
//! quantile of a family-wise level of 1 %, Šidák-corrected over scenes × channels.
//!
//! Run with `cargo test --release -p host-demo --test published_scenes` (a few seconds).

use host_demo::integrator::{render, IntegratorKind, RenderOptions};
use host_demo::xml;
use std::path::{Path, PathBuf};

const SPP: u32 = 256;
const ALPHA: f64 = 0.01;

/// `(folder, reference row, warnings the load must give)`.
const SCENES: [(&str, &str, &[&str]); 4] = [
    (
        "cornell-box-v3",
        "cornell-box-v3",
        &["path_guiding_integrator", "\"tent\""],
    ),
    (
        "veach-bidir-v3",
        "veach-bidir-v3",
        &["path_guiding_integrator", "\"tent\""],
    ),
    (
        "veach-mis-v3",
        "veach-mis-v3",
        &["path_guiding_integrator", "\"tent\""],
    ),
    (
        "veach-mis-v05",
        "veach-mis-v3",
        &["strict_normals", "\"sobol\"", "ldrfilm", "\"tent\""],
    ),
];

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/published")
}

/// `(name, width, height, mean, se)`: one row of `mitsuba3.csv`.
type Reference = (String, u32, u32, [f64; 3], [f64; 3]);

fn references() -> Vec<Reference> {
    let text = std::fs::read_to_string(data_dir().join("mitsuba3.csv")).expect("mitsuba3.csv");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 9, "{l}");
            let v: Vec<f64> = f[3..].iter().map(|x| x.parse().expect("number")).collect();
            (
                f[0].to_string(),
                f[1].parse().expect("width"),
                f[2].parse().expect("height"),
                [v[0], v[1], v[2]],
                [v[3], v[4], v[5]],
            )
        })
        .collect()
}

/// Two-sided normal quantile: `z` with `erfc(z/√2) = alpha`.
fn z_threshold(alpha: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if libm::erfc(mid / std::f64::consts::SQRT_2) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

#[test]
fn published_scenes_load_unchanged_and_match_mitsuba3() {
    let refs = references();
    let per_test = -((-ALPHA).ln_1p() / (SCENES.len() * 3) as f64).exp_m1();
    let z_max = z_threshold(per_test);
    let mut bad = Vec::new();
    for (dir, reference, warnings) in SCENES {
        let path = data_dir().join(dir).join("scene.xml");
        let sc = xml::load_file(&path).unwrap_or_else(|e| panic!("{dir}: {e}"));
        for w in warnings {
            assert!(
                sc.warnings.iter().any(|x| x.contains(w)),
                "{dir}: no warning about {w}: {:#?}",
                sc.warnings
            );
        }
        let (_, width, height, m_ref, se_ref) = refs
            .iter()
            .find(|r| r.0 == reference)
            .unwrap_or_else(|| panic!("no reference {reference}"));
        let img = render(
            &sc,
            &RenderOptions {
                integrator: IntegratorKind::PtNee,
                spp: SPP,
                max_depth: sc.settings.max_depth,
                width: *width,
                height: *height,
                seed: 3,
                ..RenderOptions::default()
            },
        );
        assert!(img.all_finite(), "{dir}");
        let (m, se) = (img.mean(), img.mean_std_error());
        for c in 0..3 {
            let (m, se) = (m[c], se[c]);
            let z = (m - m_ref[c]) / (se * se + se_ref[c] * se_ref[c]).sqrt();
            let line = format!(
                "{dir} channel {c}: {m:.5} vs Mitsuba 3 {:.5} ({:+.2} %, z {z:.2}, threshold {z_max:.2})",
                m_ref[c],
                100.0 * (m - m_ref[c]) / m_ref[c]
            );
            eprintln!("{line}");
            if z.abs() > z_max {
                bad.push(line);
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
