//! Statistics and data helpers shared by the host-demo integration tests (`mod common;`).

#![allow(dead_code)] // each test binary uses a subset

use guiding::{GuidingField, ModelSize, Representation};
use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;
use host_demo::render::strategy::guide::build_guide;
use host_demo::scene::Scene;
use std::path::{Path, PathBuf};

/// The shared Mitsuba 3 scenes with published references, `shared/scenes/` beside the
/// repository (`../shared/scenes` from its root; CI always has them). A missing folder fails
/// the test with the path it expected instead of skipping the reference comparisons.
pub fn shared_scenes() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes");
    let probe = dir.join("cornell-box/scene.xml");
    assert!(
        probe.is_file(),
        "shared Mitsuba scenes not found: expected {} (the `shared/scenes` folder beside the \
         repository, i.e. ../shared/scenes from its root)",
        probe.display()
    );
    dir
}

/// `(name, width, height, mean, se)`: one row of a `mitsuba3.csv` of Mitsuba 3 image means
/// (written by the `measure.py` beside it).
pub type MitsubaReference = (String, u32, u32, [f64; 3], [f64; 3]);

/// The rows of the `mitsuba3.csv` at `path`.
pub fn mitsuba_references(path: &Path) -> Vec<MitsubaReference> {
    csv_rows(path, 9)
        .into_iter()
        .map(|f| {
            (
                f[0].clone(),
                f[1].parse().expect("width"),
                f[2].parse().expect("height"),
                [3, 4, 5].map(|i| number(&f[i])),
                [6, 7, 8].map(|i| number(&f[i])),
            )
        })
        .collect()
}

/// A fresh, empty scratch folder `name` under the tests' target temporary directory.
pub fn scratch_dir(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("scratch dir");
    d
}

/// The two spellings of Mitsuba scene documents that the loader reads.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// Mitsuba 3 (`version="3.0.0"`, `max_depth`, `to_world`, `lookat`).
    V3,
    /// Mitsuba 0.6 (`version="0.6.0"`, `maxDepth`, `toWorld`, `lookAt`).
    V06,
}

/// A scene document in `dialect`: the path integrator to `max_depth`, a `fov` camera at
/// `origin` looking at `target` (`up`) with `res²` pixels, and `body` (from line 7).
#[allow(clippy::too_many_arguments)] // the dialect, the camera's five values and the body
pub fn scene_doc(
    dialect: Dialect,
    origin: &str,
    target: &str,
    up: &str,
    fov: f32,
    res: u32,
    max_depth: u32,
    body: &str,
) -> String {
    let (version, depth_name, to_world, lookat) = match dialect {
        Dialect::V3 => ("3.0.0", "max_depth", "to_world", "lookat"),
        Dialect::V06 => ("0.6.0", "maxDepth", "toWorld", "lookAt"),
    };
    format!(
        r#"<scene version="{version}">
  <integrator type="path"><integer name="{depth_name}" value="{max_depth}"/></integrator>
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <transform name="{to_world}"><{lookat} origin="{origin}" target="{target}" up="{up}"/></transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/></film>
  </sensor>
{body}
</scene>"#
    )
}

/// Two-sided normal quantile: `z` with `erfc(z/√2) = alpha` (bisection, exact to f64).
pub fn z_threshold(alpha: f64) -> f64 {
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

/// Šidák-corrected per-test level `1 − (1 − alpha)^{1/n}` for a family-wise level `alpha`:
/// the workspace's one copy.
#[allow(unused_imports)] // each test binary uses a subset
pub use guiding_tests::chi2::sidak;

/// The comma-separated fields of every line of `path` that is neither empty nor a `#`
/// comment, each checked to have `fields` entries.
pub fn csv_rows(path: &Path, fields: usize) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<String> = l.split(',').map(|x| x.trim().to_string()).collect();
            assert_eq!(f.len(), fields, "{}: {l}", path.display());
            f
        })
        .collect()
}

/// `s` as a number (panics naming it otherwise).
pub fn number(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("not a number: {s}"))
}

/// Asserts that `text` (an error message) contains every one of `parts`.
pub fn assert_mentions(text: &str, parts: &[&str]) {
    for part in parts {
        assert!(text.contains(part), "{part:?} missing from: {text}");
    }
}

/// Asserts that one of `warnings` (a scene's) contains every one of `parts`.
pub fn assert_warned(warnings: &[String], parts: &[&str]) {
    assert!(
        warnings.iter().any(|w| parts.iter().all(|p| w.contains(p))),
        "no warning with {parts:?}: {warnings:?}"
    );
}

/// The guided tests' training: `FieldConfig::DEFAULT` with learning rate 1e-2, `batch`
/// samples per step, `steps` Adam steps per update and `seed` (on all cores).
pub fn training_config(batch: usize, steps: u32, seed: u32) -> FieldConfig {
    FieldConfig::DEFAULT
        .with_batch_size(batch)
        .with_steps_per_update(steps)
        .with_learning_rate(1e-2)
        .with_seed(seed)
}

/// [`build_guide`] over `scene`'s bounds (panics on an invalid configuration).
pub fn guide(
    kind: Representation,
    target: Target,
    size: ModelSize,
    scene: &Scene,
    selection: f32,
    config: FieldConfig,
) -> GuidingField {
    build_guide(kind, target, size, scene.bounds(), selection, config).expect("guide")
}

/// An NPM [`guide`] with selection probability 0.5.
pub fn npm_guide(
    target: Target,
    size: ModelSize,
    scene: &Scene,
    config: FieldConfig,
) -> GuidingField {
    guide(Representation::Npm, target, size, scene, 0.5, config)
}

/// A Vulkan context for the `--device gpu` tests, or a skip: the workspace's one rule,
/// `guiding_gpu::test_support`.
#[allow(unused_imports)] // each test binary uses a subset
pub use guiding_gpu::test_context as vulkan_context;
