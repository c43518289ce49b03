//! The generic statistical runner: every case of `cases::all_cases()` is
//! checked, one `#[test]` per family, collecting every failure of the family
//! before panicking.
//!
//! Per case:
//! - (a) chi² goodness of fit of `sample` against `pdf` (10⁶ samples on the
//!   case's 101 × 51 grid, see `guiding_tests::chi2`) at the Šidák-corrected
//!   level of α = 0.01 for the whole registry, so that a correct suite fails
//!   spuriously in at most 1 % of seeds;
//! - (b) `∫ pdf dω = 1` within 10⁻³ by quadrature over the case's warp at
//!   202 × 102 cells × 8² Gauss–Legendre points. The warps are chosen so that
//!   every density is smooth on the scale of a cell; then the quadrature
//!   error is ~(cell/scale)¹⁶, orders of magnitude below 10⁻³ (the summary
//!   prints the difference to the 101 × 51 × 6² rule as evidence; for the
//!   vMF cases it is below 10⁻⁷). What remains is the `f32` rounding of the
//!   pdf itself (~10⁻⁶).
//! - (c) 10⁴ samples: finite unit directions (`|‖d‖ − 1| ≤ 10⁻⁵`), finite
//!   positive sample pdf, and `|pdf_sample − pdf(d)| ≤ 10⁻⁴ pdf(d)` (what
//!   `sample` reports is what `pdf` says).
//!
//! Every case runs on its own seed, a hash of its name, so results are
//! deterministic and independent of the order of the registry.

use guiding_tests::cases::{all_cases, Case};
use guiding_tests::chi2::{run_chi2, Chi2Config};
use guiding_tests::quadrature::integrate;
use guiding_tests::rng::Pcg32;
use std::collections::HashSet;

const FAMILIES: [&str; 3] = ["vmf/", "nasg/", "df/"];

/// FNV-1a of the case name: the case's seed.
fn name_seed(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// (b): `∫ pdf dω` over the case's warp, and the change from a coarser rule.
fn normalisation(case: &Case) -> (f64, f64) {
    let pdf = |d: glam::DVec3| f64::from(case.dist.pdf(d.as_vec3()));
    let fine = integrate(&case.warp, pdf, 202, 102, 8);
    let coarse = integrate(&case.warp, pdf, 101, 51, 6);
    (fine, (fine - coarse).abs())
}

/// (c): per-sample sanity; returns the failures.
fn sample_checks(case: &Case, seed: u64) -> Vec<String> {
    let mut rng = Pcg32::new(seed, 1);
    let mut failures = Vec::new();
    for i in 0..10_000 {
        let (d, pdf_sample) = case.dist.sample(&mut rng);
        let problem = if !d.is_finite() {
            Some("non-finite direction".to_string())
        } else if (f64::from(d.length()) - 1.0).abs() > 1e-5 {
            Some(format!("|d| − 1 = {:e}", f64::from(d.length()) - 1.0))
        } else if !(pdf_sample.is_finite() && pdf_sample > 0.0) {
            Some(format!("sample pdf {pdf_sample:e}"))
        } else {
            let pdf = case.dist.pdf(d);
            let diff = (f64::from(pdf_sample) - f64::from(pdf)).abs();
            // NaN-safe: a NaN pdf(d) fails.
            (diff.is_nan() || diff > 1e-4 * f64::from(pdf) || pdf.is_nan())
                .then(|| format!("sample pdf {pdf_sample:e} vs pdf(d) {pdf:e}"))
        };
        if let Some(p) = problem {
            failures.push(format!("{}: sample {i} (d = {d}): {p}", case.name));
            if failures.len() >= 5 {
                break;
            }
        }
    }
    failures
}

fn check_family(prefix: &str) {
    let cases = all_cases();
    let total = guiding_tests::total_chi2_tests();
    let mut failures = Vec::new();
    let mut ran = 0;
    for case in cases.iter().filter(|c| c.name.starts_with(prefix)) {
        ran += 1;
        let seed = name_seed(&case.name);
        let start = std::time::Instant::now();

        let chi2 = run_chi2(
            case,
            total,
            &Chi2Config {
                seed,
                ..Chi2Config::default()
            },
        );
        if !chi2.passed {
            failures.push(format!("(a) chi²: {}", chi2.message));
        }

        let (integral, quad_change) = normalisation(case);
        if integral.is_nan() || (integral - 1.0).abs() > 1e-3 {
            failures.push(format!(
                "(b) {}: ∫pdf dω = {integral} (coarser rule differs by {quad_change:e})",
                case.name
            ));
        }

        let sample_failures = sample_checks(case, seed);
        failures.extend(sample_failures.into_iter().map(|f| format!("(c) {f}")));

        println!(
            "{}: p {:.3e} (dof {}, threshold {:.2e}, quadrature_z {:.1e}), ∫pdf − 1 = {:+.2e} \
             (Δquad {:.1e}), {:.2} s",
            case.name,
            chi2.p_value,
            chi2.dof,
            chi2.threshold,
            chi2.quadrature_z,
            integral - 1.0,
            quad_change,
            start.elapsed().as_secs_f64()
        );
    }
    println!("{prefix}: {ran} case(s) checked, {total} chi² tests in the suite (Šidák)");
    assert!(
        failures.is_empty(),
        "{} failure(s) in family {prefix}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn vmf_cases() {
    check_family("vmf/");
}

#[test]
fn nasg_cases() {
    check_family("nasg/");
}

#[test]
fn df_cases() {
    check_family("df/");
}

/// Every registered case belongs to a family the runner checks, and names are
/// unique (they seed the tests and name the failure files).
#[test]
fn registry_names_are_unique_and_prefixed() {
    let cases = all_cases();
    let mut seen = HashSet::new();
    for case in &cases {
        assert!(
            FAMILIES.iter().any(|f| case.name.starts_with(f)),
            "case {:?} has no family prefix {FAMILIES:?}",
            case.name
        );
        assert!(
            seen.insert(case.name.clone()),
            "duplicate case name {:?}",
            case.name
        );
    }
}
