//! Chi² goodness of fit of the renderer's BSDF sampling routines against their pdfs
//! (Mitsuba 3's BSDF chi² tests, with this crate's sphere grid, pooling and Šidák correction).
//!
//! `Material::sample` may reject a sample (a microfacet reflection below the horizon) or pick
//! a delta lobe (the plastic coating); the distribution under test is the sampler *conditioned
//! on* returning a non-delta direction, whose density is `pdf(ω) / ∫pdf`. The normaliser is
//! computed with the same quadrature as the expected counts, so the chi² test checks the
//! *shape* of the pdf; its scale, ∫pdf = the sampler's acceptance rate, is checked against the
//! acceptance counted while sampling (`check_mass`, with its negative control
//! `normalisation_check_rejects_a_scaled_pdf`), and `weight = f·cos/pdf` by the unit tests in
//! `host-demo/src/bsdf.rs`.
//!
//! Grids: Mitsuba's 101 × 51 with Gauss–Legendre order 6 per cell. The rough dielectrics with
//! η = 1.33 and α = 0.6 get 201 × 101 cells at order 16: their transmission lobe ends in a
//! steep Fresnel edge (F → 1 as the microfacet turns grazing) that cuts through grid cells, and
//! the coarse rule mis-integrates those cells (at 101 × 51, order 6 the expected counts of the
//! edge row are 40 % low and the test rejects with quadrature_z ≈ 6; at order 16 and on the finer
//! grid it passes).
//!
//! Cases: GGX and Beckmann rough conductors, dielectrics (both sides) and plastics, `phong`,
//! `ward`, `roughdiffuse`, `blendbsdf`, the media's Henyey–Greenstein phase function; negative
//! controls (`harness-selftest/...`) plant wrong densities (a Beckmann sampler against the GGX
//! pdf or α·1.1, Phong's `n + 1`, Ward's quadrant slip, HG with `−g` or `1.1 g`) that must be
//! rejected.
//!
//! Run with `cargo test --release -p guiding-tests --test bsdf_chi2` (about 1.5 minutes).

use glam::Vec3;
use guiding_tests::cases::Case;
use guiding_tests::chi2::{run_chi2, sidak, Chi2Config, Warp};
use guiding_tests::quadrature::integrate;
use guiding_tests::rng::Pcg32;
use guiding_tests::SphereDistribution;
use host_demo::scene::bsdf::{Coating, Material, Microfacet, WardVariant};
use std::cell::Cell;
use std::rc::Rc;

struct Conditioned {
    m: Material,
    wi: Vec3,
    norm: f64,
    /// Calls of `Material::sample`, accepted or not (for [`check_mass`]).
    attempts: Rc<Cell<u64>>,
}

impl SphereDistribution for Conditioned {
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
        for _ in 0..10_000 {
            self.attempts.set(self.attempts.get() + 1);
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            if let Some(s) = self.m.sample(self.wi, u0, u1, u2) {
                if s.pdf.is_finite() {
                    return (s.wo.normalize(), s.pdf / self.norm as f32);
                }
            }
        }
        (Vec3::NAN, f32::NAN) // reported as a bad sample
    }
    fn pdf(&self, d: Vec3) -> f32 {
        (f64::from(self.m.eval(self.wi, d).1) / self.norm) as f32
    }
}

/// `(name, material, wi, fine grid)`.
fn cases() -> Vec<(String, Material, Vec3, bool)> {
    let (d, s) = (Vec3::new(0.4, 0.5, 0.6), Vec3::ONE);
    let rd = |alpha, eta| Material::RoughDielectric {
        distribution: Microfacet::Ggx,
        alpha,
        eta,
        reflectance: Vec3::ONE,
        transmittance: Vec3::ONE,
    };
    let outside = Vec3::new(0.55, 0.1, 0.6).normalize();
    let inside = Vec3::new(-0.3, 0.2, -0.8).normalize();
    let grazing = Vec3::new(0.95, 0.0, 0.2).normalize();
    let mid = Vec3::new(0.6, 0.0, 0.8);
    let mut cases = vec![
        (
            "roughdielectric a0.3 eta1.5 outside".into(),
            rd(0.3, 1.5),
            outside,
            false,
        ),
        (
            "roughdielectric a0.3 eta1.5 inside".into(),
            rd(0.3, 1.5),
            inside,
            false,
        ),
        (
            "roughdielectric a0.6 eta3 grazing".into(),
            rd(0.6, 3.0),
            grazing,
            false,
        ),
        (
            "roughdielectric a0.2 eta1.33 grazing".into(),
            rd(0.2, 1.33),
            grazing,
            false,
        ),
        (
            "roughdielectric a0.6 eta1.33 oblique".into(),
            rd(0.6, 1.33),
            mid,
            true,
        ),
        (
            "roughdielectric a0.6 eta1.33 grazing".into(),
            rd(0.6, 1.33),
            grazing,
            true,
        ),
        (
            "roughplastic a0.2".into(),
            Material::RoughPlastic(
                Coating::smooth(d, s, 1.49, false).roughened(Microfacet::Ggx, 0.2),
            ),
            outside,
            false,
        ),
        (
            // A textured diffuse_reflectance re-weights the lobe selection per hit.
            "roughplastic a0.2 textured albedo".into(),
            Material::RoughPlastic(
                Coating::smooth(d, s, 1.49, false)
                    .roughened(Microfacet::Ggx, 0.2)
                    .with_albedo(Vec3::new(0.9, 0.1, 0.05), Vec3::splat(0.3)),
            ),
            outside,
            false,
        ),
        (
            "plastic diffuse part".into(),
            Material::Plastic(Coating::smooth(d, s, 1.49, false)),
            grazing,
            false,
        ),
        (
            "roughconductor a0.25".into(),
            Material::RoughConductor {
                distribution: Microfacet::Ggx,
                alpha: 0.25,
                eta: Vec3::new(0.2, 0.92, 1.1),
                k: Vec3::new(3.9, 2.45, 2.14),
                specular: Vec3::ONE,
            },
            outside,
            false,
        ),
        (
            "roughconductor a0.6 grazing".into(),
            Material::RoughConductor {
                distribution: Microfacet::Ggx,
                alpha: 0.6,
                eta: Vec3::ZERO,
                k: Vec3::ONE,
                specular: Vec3::ONE,
            },
            grazing,
            false,
        ),
    ];
    cases.extend(phong_ward_cases());
    cases.extend(beckmann_cases());
    cases.extend(rough_diffuse_cases());
    cases.extend(phase_cases());
    cases
}

/// The Henyey–Greenstein phase function of media (`Material::Phase`, exact CDF inversion):
/// isotropic, forward and backward scattering, over the whole sphere around `ω_o = z`.
fn phase_cases() -> Vec<(String, Material, Vec3, bool)> {
    [0.0f32, 0.4, -0.7]
        .into_iter()
        .map(|g| (format!("hg g{g}"), Material::Phase { g }, Vec3::Z, false))
        .collect()
}

/// Mitsuba 0.6 `roughdiffuse` (cosine-weighted sampling as in Mitsuba; the full and the fast
/// Oren–Nayar model, α 0.3 and 1), from normal, oblique and grazing directions.
/// `(name, material, wi, fine grid)`.
fn rough_diffuse_cases() -> Vec<(String, Material, Vec3, bool)> {
    let mut cases = Vec::new();
    for (alpha, fast) in [(0.3f32, false), (1.0, false), (1.0, true)] {
        for (wname, wi) in [
            ("normal", Vec3::new(0.02, -0.01, 1.0).normalize()),
            ("mid", Vec3::new(0.6, 0.0, 0.8)),
            ("grazing", Vec3::new(0.95, 0.0, 0.2).normalize()),
        ] {
            cases.push((
                format!("roughdiffuse a{alpha} fast {fast} {wname}"),
                Material::RoughDiffuse {
                    reflectance: Vec3::new(0.8, 0.5, 0.2),
                    alpha,
                    fast,
                },
                wi,
                false,
            ));
        }
    }
    cases
}

/// A Beckmann rough conductor (copper) with roughness `alpha`.
fn beckmann_conductor(alpha: f32) -> Material {
    Material::RoughConductor {
        distribution: Microfacet::Beckmann,
        alpha,
        eta: Vec3::new(0.2, 0.92, 1.1),
        k: Vec3::new(3.9, 2.45, 2.14),
        specular: Vec3::ONE,
    }
}

/// Beckmann (Mitsuba's default distribution) rough conductor, rough dielectric (η 1.5 and
/// 1/1.5, from outside and inside) and rough plastic at α 0.05 / 0.3 / 0.8, from several
/// directions including grazing; the narrow α = 0.05 lobes on the fine grid.
/// `(name, material, wi, fine grid)`.
fn beckmann_cases() -> Vec<(String, Material, Vec3, bool)> {
    let outside = Vec3::new(0.55, 0.1, 0.6).normalize();
    let inside = Vec3::new(-0.3, 0.2, -0.8).normalize();
    let grazing = Vec3::new(0.95, 0.0, 0.2).normalize();
    let grazing_inside = Vec3::new(0.1, -0.97, -0.2).normalize();
    let mid = Vec3::new(0.6, 0.0, 0.8);
    let normal = Vec3::new(0.02, -0.01, 1.0).normalize();
    let rd = |alpha, eta| Material::RoughDielectric {
        distribution: Microfacet::Beckmann,
        alpha,
        eta,
        reflectance: Vec3::ONE,
        transmittance: Vec3::ONE,
    };
    let rp = |alpha| {
        Material::RoughPlastic(
            Coating::smooth(Vec3::new(0.4, 0.5, 0.6), Vec3::ONE, 1.49, false)
                .roughened(Microfacet::Beckmann, alpha),
        )
    };
    let mut cases: Vec<(String, Material, Vec3, bool)> = Vec::new();
    for (alpha, fine) in [(0.05f32, true), (0.3, false), (0.8, false)] {
        for (wname, wi) in [("normal", normal), ("mid", mid), ("grazing", grazing)] {
            cases.push((
                format!("roughconductor beckmann a{alpha} {wname}"),
                beckmann_conductor(alpha),
                wi,
                fine,
            ));
        }
        for eta in [1.5f32, 1.0 / 1.5] {
            for (wname, wi) in [("outside", outside), ("inside", inside)] {
                cases.push((
                    format!("roughdielectric beckmann a{alpha} eta{eta:.3} {wname}"),
                    rd(alpha, eta),
                    wi,
                    fine,
                ));
            }
        }
        for (wname, wi) in [("outside", outside), ("grazing", grazing)] {
            cases.push((
                format!("roughplastic beckmann a{alpha} {wname}"),
                rp(alpha),
                wi,
                fine,
            ));
        }
    }
    // Grazing through the dielectric from both sides (the Fresnel edge: fine grid).
    for (eta, wname, wi) in [
        (1.5f32, "grazing", grazing),
        (1.5, "grazing inside", grazing_inside),
    ] {
        cases.push((
            format!("roughdielectric beckmann a0.3 eta1.5 {wname}"),
            rd(0.3, eta),
            wi,
            true,
        ));
    }
    cases
}

/// Mitsuba 0.6 `phong` (exponents 5, 30, 300, with and without the diffuse part) and `ward`
/// (every variant, isotropic and anisotropic alphas 0.05 / 0.3), from several directions
/// including grazing. `(name, material, wi, fine grid)`.
fn phong_ward_cases() -> Vec<(String, Material, Vec3, bool)> {
    let outside = Vec3::new(0.55, 0.1, 0.6).normalize();
    let grazing = Vec3::new(0.95, 0.0, 0.2).normalize();
    let mid = Vec3::new(0.6, 0.0, 0.8);
    let normal = Vec3::new(0.02, -0.01, 1.0).normalize();
    let kd = Vec3::new(0.5, 0.4, 0.3);
    let phong = |n: f32, diffuse: Vec3| Material::Phong {
        exponent: n,
        diffuse,
        specular: Vec3::splat(0.4),
        scale: 1.0,
    };
    let ward = |variant, au, av, diffuse: Vec3| Material::Ward {
        variant,
        alpha_u: au,
        alpha_v: av,
        diffuse,
        specular: Vec3::new(0.3, 0.4, 0.2),
        scale: 1.0,
    };
    use WardVariant::{Balanced, Ward, WardDuer};
    vec![
        (
            "phong n5 diffuse outside".into(),
            phong(5.0, kd),
            outside,
            false,
        ),
        (
            "phong n5 grazing".into(),
            phong(5.0, Vec3::ZERO),
            grazing,
            false,
        ),
        ("phong n30 mid".into(), phong(30.0, Vec3::ZERO), mid, false),
        (
            "phong n30 diffuse grazing".into(),
            phong(30.0, kd),
            grazing,
            false,
        ),
        (
            "phong n300 normal".into(),
            phong(300.0, Vec3::ZERO),
            normal,
            true,
        ),
        (
            "phong n300 diffuse outside".into(),
            phong(300.0, kd),
            outside,
            true,
        ),
        (
            "phong n300 grazing".into(),
            phong(300.0, Vec3::ZERO),
            grazing,
            true,
        ),
        (
            "ward balanced a0.05/0.3 outside".into(),
            ward(Balanced, 0.05, 0.3, Vec3::ZERO),
            outside,
            false,
        ),
        (
            "ward balanced a0.3 diffuse grazing".into(),
            ward(Balanced, 0.3, 0.3, kd),
            grazing,
            false,
        ),
        (
            "ward balanced a0.05 normal".into(),
            ward(Balanced, 0.05, 0.05, Vec3::ZERO),
            normal,
            true,
        ),
        (
            "ward ward a0.05 mid".into(),
            ward(Ward, 0.05, 0.05, Vec3::ZERO),
            mid,
            true,
        ),
        (
            // Fine: at 101 × 51, order 6 the quadrature of the thin lobe cut by the horizon
            // moves a cell by 1.9 σ between orders 6 and 12.
            "ward ward a0.3/0.05 diffuse grazing".into(),
            ward(Ward, 0.3, 0.05, kd),
            grazing,
            true,
        ),
        (
            "ward ward-duer a0.05/0.3 diffuse outside".into(),
            ward(WardDuer, 0.05, 0.3, kd),
            outside,
            false,
        ),
        (
            "ward ward-duer a0.3 grazing".into(),
            ward(WardDuer, 0.3, 0.3, Vec3::ZERO),
            grazing,
            false,
        ),
    ]
}

/// `∫pdf` over the sphere by [`integrate`] (Gauss–Legendre order 16 on the case's grid)
/// and an estimate of its quadrature error: the larger difference to two other rules,
/// order 8 on the same cells and order 8 on cells halved in both directions. Where the
/// rules converge the order-16 value is the most accurate and the differences bound its
/// error; a lobe narrower than a cell (Phong n = 300 or Beckmann α = 0.05 at normal
/// incidence: the whole lobe in the polar row) defeats the same-cell comparison alone
/// (measured: it gave 1.2·10⁻⁶ for an error of 4.3·10⁻⁶), the halved cells do not.
fn pdf_mass(pdf: impl Fn(glam::DVec3) -> f64 + Copy, res_u: usize, res_v: usize) -> (f64, f64) {
    let warp = Warp::uniform();
    let i16 = integrate(&warp, pdf, res_u, res_v, 16);
    let i8 = integrate(&warp, pdf, res_u, res_v, 8);
    let i8_fine = integrate(&warp, pdf, 2 * res_u, 2 * res_v, 8);
    (i16, (i16 - i8).abs().max((i16 - i8_fine).abs()))
}

/// Significance level of all the normalisation checks of this file together.
const MASS_ALPHA: f64 = 0.01;

/// The sharpness `s` of a material's narrowest lobe, for the rounding term of
/// [`check_mass`]: the Phong exponent, `1/α²` of a microfacet or Ward lobe, 1 for
/// diffuse lobes.
fn lobe_sharpness(m: &Material) -> f64 {
    let inv_sq = |a: f32| 1.0 / f64::from(a).powi(2);
    match *m {
        Material::Phong { exponent, .. } => f64::from(exponent).max(1.0),
        Material::RoughConductor { alpha, .. } | Material::RoughDielectric { alpha, .. } => {
            inv_sq(alpha)
        }
        Material::RoughPlastic(c) => inv_sq(c.alpha),
        Material::Ward {
            alpha_u, alpha_v, ..
        } => inv_sq(alpha_u.min(alpha_v)),
        _ => 1.0,
    }
}

/// The normalisation check: `∫pdf` must be the probability that the sampler returns a
/// non-delta direction.
///
/// `Material::sample` draws one direction per call, or gives up (a microfacet reflection
/// below the horizon), or picks a delta lobe (infinite pdf); `eval`'s pdf is the density of
/// the directions it does return, *including* the lobe-selection probabilities, so its
/// integral is that acceptance probability `p` — not the albedo, which weighs by `f·cos`
/// instead; `p ≤ 1`, with equality for a material that always returns a direction. (A pdf
/// that is right up to a constant factor passes the chi² test, which conditions on
/// acceptance and renormalises; this check is what pins the scale.)
///
/// `p` is measured by counting the attempts behind `accepted` samples: `p̂ = accepted /
/// attempts`, standard deviation `σ = p √((1 − p)/accepted)` (the attempts are a negative
/// binomial count), taken with one extra rejection counted so that `p̂ = 1` does not give
/// `σ = 0`. Tolerance `|∫pdf − p̂| ≤ z σ + q + r`:
/// - `z`, the two-sided normal quantile at α = 0.01 Šidák-corrected over `checks` (3.78 for
///   the 65 checks of this file);
/// - `q`, the quadrature error estimate of [`pdf_mass`];
/// - `r = ε₃₂ (16 + 2s) ∫pdf`, the `f32` evaluation of the pdf: a product of ~16 rounded
///   factors (normalisation, Fresnel and selection weights, Jacobian), and a lobe
///   `exp(−s g)` or `cosˢ` whose argument, formed from unit vectors good to `ε₃₂`, errs by
///   `≈ 2 s ε₃₂` absolute (`s` from [`lobe_sharpness`]): a relative error of the lobe. (It
///   is what a sharp lobe needs: Phong n = 300 at normal incidence always returns a
///   direction, yet its `∫pdf` is 1 − 4.1·10⁻⁶ on every grid tried, within `r` = 7.4·10⁻⁵.)
///
/// The result is at most 1 + tolerance, since `p̂ ≤ 1`. It replaces `0.05 < ∫pdf ≤
/// 1.001`, whose 0.05 admitted a pdf 20 times too small and whose 10⁻³ had no source.
/// Measured over the 65 checks: `|∫pdf − p̂|` ≤ 0.51 of its tolerance; beyond 2 σ only
/// for the sharp lobes (α = 0.05, n = 300: 4–10 σ, covered by their quadrature and
/// rounding terms).
fn check_mass(
    name: &str,
    (mass, quadrature): (f64, f64),
    sharpness: f64,
    accepted: u64,
    attempts: u64,
    checks: usize,
) -> Result<String, String> {
    use statrs::distribution::{ContinuousCDF, Normal};
    let n = accepted as f64;
    let p = n / attempts as f64;
    let p_pad = n / (attempts + 1) as f64;
    let sigma = p_pad * ((1.0 - p_pad) / n).sqrt();
    let z = Normal::new(0.0, 1.0)
        .expect("standard normal")
        .inverse_cdf(1.0 - 0.5 * sidak(MASS_ALPHA, checks));
    let rounding = f64::from(f32::EPSILON) * (16.0 + 2.0 * sharpness) * mass;
    let tol = z * sigma + quadrature + rounding;
    let report = format!(
        "{name}: ∫pdf {mass:.6} vs acceptance {p:.6} ({accepted} of {attempts}): |Δ| {:.2e}, \
         {:.2} σ; tolerance {tol:.2e} (z {z:.2} × σ {sigma:.2e} + quadrature {quadrature:.2e} \
         + rounding {rounding:.2e})",
        (mass - p).abs(),
        (mass - p).abs() / sigma
    );
    if (mass - p).abs() > tol {
        return Err(format!("∫pdf is not the acceptance probability: {report}"));
    }
    Ok(report)
}

/// How many normalisation checks the file makes: one per case and two in
/// `blendbsdf_sampling_matches_mixture_pdf`.
fn mass_checks() -> usize {
    cases().len() + 2
}

/// One conditioned sampler, `dist(∫pdf, attempts)`: its chi² test (named
/// `bsdf/{name}`, seed `seed`, one of `tests`), then [`check_mass`] of `∫pdf`
/// by [`pdf_mass`] against the attempts it counted. Returns the failures.
fn check_conditioned<D: SphereDistribution + 'static>(
    name: &str,
    (tests, seed): (usize, u64),
    cfg: &Chi2Config,
    pdf: impl Fn(glam::DVec3) -> f64 + Copy,
    sharpness: f64,
    dist: impl FnOnce(f64, Rc<Cell<u64>>) -> D,
) -> Vec<String> {
    let mass = pdf_mass(pdf, cfg.res_u, cfg.res_v);
    let attempts = Rc::new(Cell::new(0));
    let case = Case {
        name: format!("bsdf/{name}"),
        dist: Box::new(dist(mass.0, Rc::clone(&attempts))),
        warp: Warp::uniform(),
    };
    let r = run_chi2(
        &case,
        tests,
        &Chi2Config {
            seed,
            ..cfg.clone()
        },
    );
    eprintln!("{}", r.message);
    let mut failures = Vec::new();
    if !r.passed {
        failures.push(r.message);
    }
    let (samples, checks) = (cfg.samples as u64, mass_checks());
    match check_mass(name, mass, sharpness, samples, attempts.get(), checks) {
        Ok(report) => eprintln!("  {report}"),
        Err(e) => failures.push(e),
    }
    failures
}

#[test]
fn bsdf_sampling_matches_pdf() {
    let all = cases();
    let mut failures = Vec::new();
    for (i, (name, m, wi, fine)) in all.iter().enumerate() {
        let cfg = if *fine {
            Chi2Config {
                res_u: 201,
                res_v: 101,
                integration_order: 16,
                ..Chi2Config::default()
            }
        } else {
            Chi2Config::default()
        };
        failures.extend(check_conditioned(
            name,
            (all.len(), 100 + i as u64),
            &cfg,
            |d| f64::from(m.eval(*wi, d.as_vec3()).1),
            lobe_sharpness(m),
            |norm, attempts| Conditioned {
                m: *m,
                wi: *wi,
                norm,
                attempts,
            },
        ));
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Negative control of the normalisation check: a pdf claimed 3 % too small or too large
/// (a lost or doubled selection probability would be far worse) is rejected, where the
/// right one passes, for a rough plastic, the diffuse part of a smooth plastic (acceptance
/// ≈ 0.51: the rest is the delta coating), a grazing rough conductor (≈ 0.90: reflections
/// below the horizon) and the sharpest lobe (Phong n = 300, the largest rounding term).
/// The acceptance comes from 10⁵ samples (σ ≤ 1.6·10⁻³, against a defect of 3 % of `p`);
/// `∫` is linear, so the claimed pdf's integral is the scaled `∫pdf`.
#[test]
fn normalisation_check_rejects_a_scaled_pdf() {
    const SAMPLES: u64 = 100_000;
    let picks = [
        "roughplastic a0.2",
        "plastic diffuse part",
        "roughconductor a0.6 grazing",
        "phong n300 normal",
    ];
    let checks = mass_checks();
    let mut seen = 0;
    for (i, (name, m, wi, fine)) in cases().into_iter().enumerate() {
        if !picks.contains(&name.as_str()) {
            continue;
        }
        seen += 1;
        let (res_u, res_v) = if fine { (201, 101) } else { (101, 51) };
        let mass = pdf_mass(|d| f64::from(m.eval(wi, d.as_vec3()).1), res_u, res_v);
        let mut rng = Pcg32::new(900 + i as u64, 0);
        let (mut accepted, mut attempts) = (0u64, 0u64);
        while accepted < SAMPLES {
            attempts += 1;
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            if m.sample(wi, u0, u1, u2).is_some_and(|s| s.pdf.is_finite()) {
                accepted += 1;
            }
        }
        let s = lobe_sharpness(&m);
        match check_mass(&name, mass, s, accepted, attempts, checks) {
            Ok(report) => eprintln!("{report}"),
            Err(e) => panic!("the right pdf is rejected: {e}"),
        }
        for scale in [0.97, 1.03] {
            let claimed = (scale * mass.0, scale * mass.1);
            let label = format!("{name}, pdf × {scale}");
            match check_mass(&label, claimed, s, accepted, attempts, checks) {
                Ok(report) => panic!("a scaled pdf passed the normalisation check: {report}"),
                Err(e) => eprintln!("rejected as it must be: {e}"),
            }
        }
    }
    assert_eq!(seen, picks.len());
}

/// Samples of `sampled` (conditioned on a non-delta sample, as [`Conditioned`]) tested
/// against the normalised pdf of `claimed`: a defect planted in the pdf (or, with `quadrant_bug`,
/// in the Ward half-vector sampler) must make the chi² test reject.
struct Mismatched {
    sampled: Material,
    claimed: Material,
    wi: Vec3,
    norm: f64,
    /// Sample Ward's half vector with `φ = atan(αv/αu · tan 2πu)` and no quadrant
    /// correction (φ only in (−π/2, π/2)): the classic slip Walter 2005 warns of.
    quadrant_bug: bool,
}

impl SphereDistribution for Mismatched {
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
        for _ in 0..10_000 {
            let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
            let wo = match self.sampled {
                Material::Ward {
                    alpha_u: au,
                    alpha_v: av,
                    ..
                } if self.quadrant_bug => {
                    let phi = (av / au * (2.0 * std::f32::consts::PI * u1).tan()).atan();
                    let (sp, cp) = phi.sin_cos();
                    let tan2 = -(1.0 - u2).ln() / (cp * cp / (au * au) + sp * sp / (av * av));
                    let ct = 1.0 / (1.0 + tan2).sqrt();
                    let h = Vec3::new(ct * tan2.sqrt() * cp, ct * tan2.sqrt() * sp, ct);
                    Some(2.0 * self.wi.dot(h) * h - self.wi).filter(|w| w.z > 0.0)
                }
                m => m
                    .sample(self.wi, u0, u1, u2)
                    .filter(|s| s.pdf.is_finite())
                    .map(|s| s.wo),
            };
            if let Some(wo) = wo {
                let d = wo.normalize();
                return (d, self.pdf(d));
            }
        }
        (Vec3::NAN, f32::NAN)
    }
    fn pdf(&self, d: Vec3) -> f32 {
        (f64::from(self.claimed.eval(self.wi, d).1) / self.norm) as f32
    }
}

/// One negative-control run: `sampled`'s sampler tested as one chi² test (seed `seed`)
/// against `claimed`'s pdf; it must pass when `ok`, and be rejected with `p < 1e-6` otherwise.
fn check_pairing(
    name: &str,
    sampled: Material,
    claimed: Material,
    quadrant_bug: bool,
    wi: Vec3,
    seed: u64,
    ok: bool,
) {
    let cfg = Chi2Config {
        seed,
        ..Chi2Config::default()
    };
    let warp = Warp::uniform();
    let norm = integrate(
        &warp,
        |d| f64::from(claimed.eval(wi, d.as_vec3()).1),
        cfg.res_u,
        cfg.res_v,
        16,
    );
    let case = Case {
        name: format!("harness-selftest/{name}"),
        dist: Box::new(Mismatched {
            sampled,
            claimed,
            wi,
            norm,
            quadrant_bug,
        }),
        warp,
    };
    let r = run_chi2(&case, 1, &cfg);
    eprintln!("{}", r.message);
    if ok {
        assert!(r.passed, "correct pairing rejected: {}", r.message);
    } else {
        assert!(
            !r.passed && r.p_value < 1e-6,
            "defect not caught: {}",
            r.message
        );
    }
}

/// The chi² test catches defects of the `phong` / `ward` densities (each as one test at
/// α = 0.01, the grid of the cases above): Phong's pdf with exponent `n + 1` instead of `n`,
/// Ward's with `αu` 10 % too large, Ward's with the `ward` instead of the `balanced`
/// normalisation claimed for the sampling (identical pdf: must pass, the variants differ in
/// `f` only), and a Ward sampler without the quadrant correction of `φ`. The correct
/// pairings pass under the same configuration.
#[test]
fn chi2_catches_wrong_phong_ward_pdf() {
    let wi = Vec3::new(0.6, 0.0, 0.8);
    let phong = |n: f32| Material::Phong {
        exponent: n,
        diffuse: Vec3::ZERO,
        specular: Vec3::splat(0.5),
        scale: 1.0,
    };
    let ward = |variant, au: f32| Material::Ward {
        variant,
        alpha_u: au,
        alpha_v: 0.3,
        diffuse: Vec3::splat(0.2),
        specular: Vec3::splat(0.5),
        scale: 1.0,
    };
    let (bal, plain) = (WardVariant::Balanced, WardVariant::Ward);
    // (name, sampled, claimed, quadrant bug, must pass)
    let runs = [
        ("phong n30 right", phong(30.0), phong(30.0), false, true),
        ("phong n30 pdf n+1", phong(30.0), phong(31.0), false, false),
        (
            "ward a0.1 right",
            ward(bal, 0.1),
            ward(bal, 0.1),
            false,
            true,
        ),
        (
            "ward a0.1 pdf a0.11",
            ward(bal, 0.1),
            ward(bal, 0.11),
            false,
            false,
        ),
        (
            "ward variant pdf",
            ward(bal, 0.1),
            ward(plain, 0.1),
            false,
            true,
        ),
        (
            "ward quadrant bug",
            ward(bal, 0.1),
            ward(bal, 0.1),
            true,
            false,
        ),
    ];
    for (i, (name, sampled, claimed, quadrant_bug, ok)) in runs.into_iter().enumerate() {
        check_pairing(name, sampled, claimed, quadrant_bug, wi, 700 + i as u64, ok);
    }
}

/// The chi² test catches a Henyey–Greenstein density with the sign convention of `g`
/// flipped (forward samples against a backward pdf, the classic slip between `ω_o · ω_i` and
/// the angle to the forward direction), and `g` 10 % too large; the right pairing passes.
#[test]
fn chi2_catches_wrong_phase_pdf() {
    let hg = |g: f32| Material::Phase { g };
    let runs = [
        ("hg g0.5 right", hg(0.5), true),
        ("hg g0.5 pdf of -g", hg(-0.5), false),
        ("hg g0.5 pdf g0.55", hg(0.55), false),
    ];
    for (i, (name, claimed, ok)) in runs.into_iter().enumerate() {
        check_pairing(name, hg(0.5), claimed, false, Vec3::Z, 900 + i as u64, ok);
    }
}

/// The chi² test catches a wrong Beckmann density: Beckmann samples tested against the GGX
/// pdf of the same alpha, and against the Beckmann pdf with α 10 % too large, for the rough
/// conductor and the rough dielectric (α 0.3, the grid of the cases above). The correct
/// pairings pass under the same configuration.
#[test]
fn chi2_catches_wrong_beckmann_pdf() {
    let wi = Vec3::new(0.6, 0.0, 0.8);
    let conductor = |distribution, alpha| Material::RoughConductor {
        distribution,
        alpha,
        eta: Vec3::new(0.2, 0.92, 1.1),
        k: Vec3::new(3.9, 2.45, 2.14),
        specular: Vec3::ONE,
    };
    let dielectric = |distribution, alpha| Material::RoughDielectric {
        distribution,
        alpha,
        eta: 1.5,
        reflectance: Vec3::ONE,
        transmittance: Vec3::ONE,
    };
    let (b, g) = (Microfacet::Beckmann, Microfacet::Ggx);
    // (name, sampled, claimed, must pass)
    let runs = [
        (
            "conductor right",
            conductor(b, 0.3),
            conductor(b, 0.3),
            true,
        ),
        (
            "conductor ggx pdf",
            conductor(b, 0.3),
            conductor(g, 0.3),
            false,
        ),
        (
            "conductor pdf a0.33",
            conductor(b, 0.3),
            conductor(b, 0.33),
            false,
        ),
        (
            "dielectric right",
            dielectric(b, 0.3),
            dielectric(b, 0.3),
            true,
        ),
        (
            "dielectric ggx pdf",
            dielectric(b, 0.3),
            dielectric(g, 0.3),
            false,
        ),
        (
            "dielectric pdf a0.33",
            dielectric(b, 0.3),
            dielectric(b, 0.33),
            false,
        ),
    ];
    for (i, (name, sampled, claimed, ok)) in runs.into_iter().enumerate() {
        let name = format!("beckmann {name}");
        check_pairing(&name, sampled, claimed, false, wi, 800 + i as u64, ok);
    }
}

/// `blendbsdf` as the renderer realises it: [`Scene::resolve_material`] picks a component
/// stochastically (here with a textured weight), then that component samples. The sampled
/// directions must follow the mixture density `Σ P(k)·pdf_k` ([`Scene::eval_mixture`]),
/// conditioned on non-delta samples like the cases above.
#[test]
fn blendbsdf_sampling_matches_mixture_pdf() {
    use glam::{Mat4, Vec2};
    use host_demo::scene::texture::{Texture, UvMap};
    use host_demo::scene::{Camera, MaterialTextures, SceneBuilder, Settings};

    let mut b = SceneBuilder::default();
    let rough = b.material(Material::RoughConductor {
        distribution: Microfacet::Ggx,
        alpha: 0.15,
        eta: Vec3::new(0.2, 0.92, 1.1),
        k: Vec3::new(3.9, 2.45, 2.14),
        specular: Vec3::ONE,
    });
    let diffuse = b.material(Material::Diffuse {
        reflectance: Vec3::splat(0.7),
    });
    let plastic = b.material(Material::Plastic(Coating::smooth(
        Vec3::splat(0.5),
        Vec3::ONE,
        1.5,
        false,
    )));
    let tex = b.texture(Texture::Checkerboard {
        color0: Vec3::splat(0.35),
        color1: Vec3::splat(0.8),
        uv: UvMap::default(),
    });
    let inner = b.textured_material(
        Material::Blend {
            a: rough,
            b: diffuse,
            weight: 0.5,
        },
        MaterialTextures {
            scalar: Some(tex),
            ..MaterialTextures::default()
        },
    );
    // A nested blend with a delta-carrying component (the plastic coating).
    let outer = b.material(Material::Blend {
        a: inner,
        b: plastic,
        weight: 0.25,
    });
    b.quad([Vec3::ZERO, Vec3::X, Vec3::ONE, Vec3::Y], outer, None);
    let camera = Camera::new(Mat4::IDENTITY, 40.0, "x", 4, 4).expect("camera");
    let settings = Settings {
        width: 4,
        height: 4,
        spp: 1,
        max_depth: 2,
        rr_depth: 5,
    };
    let scene = std::sync::Arc::new(b.build(camera, settings).expect("scene"));

    struct Blend {
        scene: std::sync::Arc<host_demo::scene::Scene>,
        id: u32,
        uv: Vec2,
        wi: Vec3,
        norm: f64,
        attempts: Rc<Cell<u64>>,
    }
    impl SphereDistribution for Blend {
        fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
            let mut r = host_demo::math::Rng::from_keys(u64::from(rng.next_u32()), 1, 2);
            for _ in 0..10_000 {
                self.attempts.set(self.attempts.get() + 1);
                let (_, m, _, _) = self.scene.resolve_material(
                    self.id,
                    Vec3::Z,
                    Vec3::Z,
                    -self.wi,
                    self.uv,
                    &mut r,
                );
                let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
                if let Some(s) = m.sample(self.wi, u0, u1, u2) {
                    if s.pdf.is_finite() {
                        let d = s.wo.normalize();
                        return (d, self.pdf(d));
                    }
                }
            }
            (Vec3::NAN, f32::NAN)
        }
        fn pdf(&self, d: Vec3) -> f32 {
            let p = self.scene.eval_mixture(self.id, self.uv, self.wi, d).1;
            (f64::from(p) / self.norm) as f32
        }
    }
    let wi = Vec3::new(0.55, 0.1, 0.6).normalize();
    let uvs = [Vec2::splat(0.25), Vec2::new(0.75, 0.25)];
    for (i, uv) in uvs.iter().enumerate() {
        let failures = check_conditioned(
            &format!("blendbsdf uv{i}"),
            (uvs.len(), 300 + i as u64),
            &Chi2Config::default(),
            |d| f64::from(scene.eval_mixture(outer, *uv, wi, d.as_vec3()).1),
            // The sharpest lobe is the rough conductor's, α = 0.15.
            1.0 / 0.15f64.powi(2),
            |norm, attempts| Blend {
                scene: std::sync::Arc::clone(&scene),
                id: outer,
                uv: *uv,
                wi,
                norm,
                attempts,
            },
        );
        assert!(failures.is_empty(), "{failures:#?}");
    }
}
