//! Statistics and data helpers shared by the host-demo integration tests (`mod common;`).

#![allow(dead_code)] // each test binary uses a subset

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

/// A Vulkan context for the `--device gpu` tests, or a skip: the workspace's one rule,
/// `guiding_gpu::test_support`.
#[allow(unused_imports)] // each test binary uses a subset
pub use guiding_gpu::test_context as vulkan_context;
