//! Deterministic stress sweeps over the extremes of every parameter (issue
//! #8): vMF κ, NASG λ, `a`, ε from 0 through subnormals to 10³⁰ and beyond
//! (±∞, NaN), lobe axes on the poles of the sampling frame, evaluation
//! directions at the mean, the antipode, the poles and with subnormal
//! components, random numbers at the ends of `[0, 1)`, and the guiding
//! models with their parameters scaled from 0 to 10³⁰.
//!
//! Checked everywhere: every density finite and ≥ 0; every sample a finite
//! unit direction with a finite positive density that equals `pdf` of the
//! direction up to 10⁻⁴ relative plus the density's own variation across the
//! `f32` resolution of the direction (`fuzz_checks::check_sample`, the
//! property the fuzz targets check). Where the lobe is resolvable by
//! quadrature, also `∫ pdf dω = 1` (see [`check_normalisation`] for the
//! tolerance and the ranges).
//!
//! The long-run training soak (10⁴ Adam steps with heavy-tailed noise,
//! outliers and invalid records) lives in `learning.rs` next to the short
//! soak and the KL helpers it shares.

use glam::{DVec3, Vec2, Vec3};
use guiding_core::lobe::nasg::{
    NasgLobe, NASG_A_MAX, NASG_EPSILON_MAX, NASG_EPSILON_MIN, NASG_LAMBDA_MAX, NASG_LAMBDA_MIN,
};
use guiding_core::lobe::vmf::{VmfLobe, VMF_KAPPA_MAX};
use guiding_core::lobe::DirectionSample;
use guiding_core::math::ONE_MINUS_EPSILON;
use guiding_core::model::df::{DfSmallProduct, DfSmallRadiance};
use guiding_core::model::nasg::{NasgSmallProduct, NasgSmallRadiance};
use guiding_core::model::npm::{NpmSmallProduct, NpmSmallRadiance};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;
use guiding_tests::cases::{nasg, vmf};
use guiding_tests::chi2::Warp;
use guiding_tests::fuzz_checks::{check_density, check_sample};
use guiding_tests::quadrature::integrate;
use guiding_tests::rng::Pcg32;

/// Smallest positive subnormal `f32`.
const DENORMAL_MIN: f32 = 1e-45;
/// A mid-range subnormal.
const DENORMAL: f32 = f32::MIN_POSITIVE / 1024.0;

/// Random numbers at and next to the ends of `[0, 1)` and a few inside.
const US: [f32; 9] = [
    0.0,
    DENORMAL_MIN,
    1e-30,
    1.0 / 16_777_216.0,
    0.25,
    0.5,
    0.75,
    1.0 - 1.0 / 8_388_608.0,
    ONE_MINUS_EPSILON,
];

/// Numbers outside `[0, 1)` that samplers must clamp.
const BAD_US: [f32; 5] = [-0.0, -1.0, 1.0, f32::INFINITY, f32::NAN];

/// Axes: the poles and equator points of the sampling frames, a general
/// direction, and ones with subnormal components.
fn axes() -> Vec<Vec3> {
    vec![
        Vec3::Z,
        Vec3::NEG_Z,
        Vec3::X,
        Vec3::NEG_Y,
        Vec3::new(0.3, -0.5, 0.8).normalize(),
        Vec3::new(DENORMAL_MIN, 0.0, 1.0),
        Vec3::new(DENORMAL, -DENORMAL, -1.0),
        Vec3::new(1.0, DENORMAL_MIN, DENORMAL_MIN),
    ]
}

/// Directions to evaluate a lobe with axis `m` at: the mean, the antipode,
/// the frame poles, points 10⁻⁷, 10⁻⁴ and 10⁻² rad off the mean and off the
/// antipode, subnormal components, and degenerate vectors (zero, NaN, ±∞,
/// subnormal length, huge).
fn stress_directions(m: Vec3) -> Vec<Vec3> {
    let t = m.any_orthonormal_vector();
    let mut out = vec![m, -m, Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::Z, Vec3::NEG_Z];
    for angle in [1e-7f32, 1e-4, 1e-2] {
        out.push((m + t * angle).normalize());
        out.push((-m + t * angle).normalize());
    }
    out.extend([
        Vec3::new(DENORMAL_MIN, 0.0, 1.0),
        Vec3::new(1.0, DENORMAL, -DENORMAL),
        Vec3::splat(DENORMAL_MIN),
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(f32::NEG_INFINITY, f32::INFINITY, 1.0),
        m * 3e38,
    ]);
    out
}

fn check_densities(what: &str, pdf: impl Fn(Vec3) -> f32, m: Vec3) {
    for d in stress_directions(m) {
        check_density(&format!("{what}, d = {d}"), pdf(d));
    }
}

/// `sample` at every `(ux, uy)` of [`US`] × [`US`] and at `(u, u)` for every
/// `u` of [`BAD_US`], each checked by `check_sample` against `pdf`; `also`
/// gets each grid point and its sample (the lobe's further checks).
fn check_lobe_samples(
    what: &str,
    pdf: impl Fn(Vec3) -> f32,
    sample: impl Fn(Vec2) -> DirectionSample,
    mut also: impl FnMut(Vec2, DirectionSample),
) {
    for &ux in &US {
        for &uy in &US {
            let u = Vec2::new(ux, uy);
            let s = sample(u);
            check_sample(what, s, &pdf, 1e-4);
            also(u, s);
        }
    }
    for &u in &BAD_US {
        check_sample(what, sample(Vec2::new(u, u)), &pdf, 1e-4);
    }
}

// ---------------------------------------------------------------------------
// Normalisation.

/// Relative `f32` rounding of one density evaluation, integrated: ≤ 16 ulps
/// (the pdf is a handful of correctly rounded or few-ulp operations; the
/// measured integrated effect over this file's lobes is ≤ 1.3·10⁻⁷).
const F32_FLOOR: f64 = 16.0 * f32::EPSILON as f64;

/// `∫ pdf dω` over `warp` and the tolerance it is checked with:
/// `|∫ − 1| ≤ Δ + F32_FLOOR + rounding`, where
/// - `Δ` is the change from a coarser rule (48 × 24 cells × 6² points) to the
///   one used (64 × 32 × 8²). Gauss–Legendre converges at least
///   algebraically on these warps, so the finer rule's error is below `Δ`;
///   a lobe counts as *resolvable* when `Δ ≤ 10⁻⁴` and the test asserts
///   that every lobe of its grid is.
/// - `rounding` is the error of evaluating the `f32` density at the `f32`
///   rounding of each quadrature node: a direction rounded by `δ ≤ 2⁻²³` per
///   component changes `ln p` by `δ |∇_ω ln p|`, and near the axis
///   `|∇_ω ln p| ≈ √(2 B σ)` at depth `B s/2 = σ` of a lobe of sharpness `B`
///   (`B = 2κ` for vMF, see `cases::nasg` for NASG); averaged over the lobe
///   (`E σ = 1`) and doubled, `rounding = 2⁻²³ √(8B)`. For a lobe whose axis
///   is a coordinate axis, the components near the lobe are small and round
///   relatively, so `rounding = 0` there.
///
/// Returns `(|∫ − 1|, Δ)`.
fn check_normalisation(
    what: &str,
    pdf: impl Fn(Vec3) -> f32,
    warp: &Warp,
    b: f64,
    axis: bool,
) -> (f64, f64) {
    let f = |d: DVec3| f64::from(pdf(d.as_vec3()));
    let fine = integrate(warp, f, 64, 32, 8);
    let coarse = integrate(warp, f, 48, 24, 6);
    let delta = (fine - coarse).abs();
    assert!(delta <= 1e-4, "{what}: not resolvable, Δ = {delta:e}");
    let rounding = if axis {
        0.0
    } else {
        (8.0 * b).sqrt() / 8_388_608.0
    };
    let tol = delta + F32_FLOOR + rounding;
    assert!(
        (fine - 1.0).abs() <= tol,
        "{what}: ∫pdf − 1 = {:e} (tolerance {tol:e}, Δ {delta:e})",
        fine - 1.0
    );
    ((fine - 1.0).abs(), delta)
}

/// Magnitudes every lobe parameter is stressed at: zero, the smallest
/// denormal and powers of ten from 1e-30 to 1e30.
const MAGNITUDES: [f32; 11] = [
    0.0,
    DENORMAL_MIN,
    1e-30,
    1e-6,
    1e-2,
    1.0,
    1e2,
    1e4,
    1e5,
    1e7,
    1e30,
];

// ---------------------------------------------------------------------------
// vMF.

/// κ from zero through subnormals to beyond the clamp (and invalid values,
/// which the constructor maps to 0 or the clamp).
const KAPPAS: [f32; 26] = [
    0.0,
    -0.0,
    DENORMAL_MIN,
    DENORMAL,
    f32::MIN_POSITIVE,
    1e-30,
    1e-20,
    1e-6,
    1e-5,
    1e-4,
    1e-3,
    1e-2,
    0.1,
    1.0,
    10.0,
    1e2,
    1e3,
    1e4,
    1e5,
    1e6,
    1e7,
    1e8,
    1e30,
    f32::MAX,
    f32::INFINITY,
    f32::NAN,
];

/// Every κ of [`KAPPAS`] at every axis of [`axes`]: finite densities at the
/// stress directions, sample/pdf agreement over the `u` grid (also at the
/// tail cut, `u = 0` and `1 − 2⁻²⁴`), clamped `u` outside `[0, 1)`, finite
/// `invert`.
#[test]
fn vmf_extremes_finite_and_consistent() {
    let mut n = 0;
    for &kappa in &KAPPAS {
        for axis in axes() {
            let lobe = VmfLobe::new(axis, kappa);
            let what = format!("vMF κ {kappa:e}, axis {axis}");
            assert!((0.0..=VMF_KAPPA_MAX).contains(&lobe.kappa), "{what}");
            check_densities(&what, |d| lobe.pdf(d), lobe.mean());
            check_lobe_samples(
                &what,
                |d| lobe.pdf(d),
                |u| lobe.sample(u),
                |_, s| {
                    let back = lobe.invert(s.direction);
                    assert!(back.is_finite(), "{what}: invert {back}");
                    n += 1;
                },
            );
        }
    }
    println!("vMF: {n} samples checked");
}

/// `∫ pdf dω = 1` for κ from 0 (and subnormal, 10⁻³⁰: the uniform lobe)
/// to 10⁷ and beyond (clamped to 10⁷, a lobe 3·10⁻⁴ rad wide), about the
/// pole, an equator point and a general axis, on the registry's grids
/// (uniform below κ = 100, a zoomed cap with `s0 = 1/κ` above).
#[test]
fn vmf_normalisation_across_kappa() {
    let kappas = [&MAGNITUDES[..], &[1e-3, 0.1, 10.0, 99.0, 1e3, 1e6]].concat();
    let mut worst = (0.0f64, 0.0f64);
    for &kappa in &kappas {
        for (axis, exact_axis) in [
            (Vec3::Z, true),
            (Vec3::NEG_X, true),
            (Vec3::new(0.3, -0.5, 0.8), false),
        ] {
            let lobe = VmfLobe::new(axis, kappa);
            let (e, d) = check_normalisation(
                &format!("vMF κ {kappa:e}, axis {axis}"),
                |d| lobe.pdf(d),
                &vmf::lobe_warp(&lobe),
                2.0 * f64::from(lobe.kappa),
                exact_axis,
            );
            worst = (worst.0.max(e), worst.1.max(d));
        }
    }
    println!(
        "vMF normalisation: max |∫pdf − 1| {:.1e}, max Δ {:.1e}",
        worst.0, worst.1
    );
}

// ---------------------------------------------------------------------------
// NASG.

/// λ: the magnitudes, negative zero, the smallest normal, 1e-4 and the
/// non-finite values (16).
fn lambdas() -> Vec<f32> {
    let special = [-0.0, f32::MIN_POSITIVE, 1e-4, f32::INFINITY, f32::NAN];
    [&MAGNITUDES[..], &special].concat()
}

/// Anisotropy: the magnitudes and a denormal (12).
fn anisotropies() -> Vec<f32> {
    [&MAGNITUDES[..], &[DENORMAL]].concat()
}

const EPSILONS: [f32; 7] = [DENORMAL_MIN, 1e-30, 1e-7, 1e-6, 1e-3, 1.0, 1e30];

/// Every (λ, a, ε) of the grids above (1344 lobes) in an exact frame about
/// `+z` and in a general frame: parameters clamped into their documented
/// ranges, finite densities at the stress directions, and sample/pdf
/// agreement for both samplers over the `u` grid.
#[test]
fn nasg_extremes_finite_and_consistent() {
    let frames = [
        (Vec3::Z, Vec3::X),
        (Vec3::new(0.3, -0.5, 0.8), Vec3::new(1.0, 0.2, 0.0)),
    ];
    let mut n = 0;
    for &lambda in &lambdas() {
        for &a in &anisotropies() {
            for &eps in &EPSILONS {
                for &(z, x) in &frames {
                    let lobe = NasgLobe::new(z, x, lambda, a, eps);
                    let what = format!("NASG λ {lambda:e} a {a:e} ε {eps:e}, axis {z}");
                    assert!(
                        (NASG_LAMBDA_MIN..=NASG_LAMBDA_MAX).contains(&lobe.lambda)
                            && (0.0..=NASG_A_MAX).contains(&lobe.a)
                            && (NASG_EPSILON_MIN..=NASG_EPSILON_MAX).contains(&lobe.epsilon),
                        "{what}: {lobe:?}"
                    );
                    let axis = lobe.frame().z;
                    check_densities(&what, |d| lobe.pdf(d), axis);
                    check_lobe_samples(
                        &what,
                        |d| lobe.pdf(d),
                        |u| lobe.sample(u),
                        |u, _| {
                            let s = lobe.sample3(Vec3::new(u.x, u.y, 1.0 - u.x));
                            check_sample(&what, s, |d| lobe.pdf(d), 1e-4);
                            n += 2;
                        },
                    );
                }
            }
        }
    }
    println!("NASG: {n} samples checked");
}

/// `∫ pdf dω = 1` over λ from the clamp at 10⁻⁴ (also reached from 10⁻³⁰)
/// to 10⁵, `a` from 0 to 10⁵ and ε from 10⁻⁶ to 1, in the exact frame about
/// `+z`, and in a general frame where `B ≤ 4·10⁴` (beyond, a rotated lobe is
/// narrower than what `f32` world directions resolve; see `cases::nasg`).
/// The grids are `cases::nasg::lobe_warp`'s.
#[test]
fn nasg_normalisation_across_parameters() {
    let mut worst = (0.0f64, 0.0f64);
    for &lambda in &[1e-30, 1e-2, 1.0, 1e2, 1e4, 1e5] {
        for &a in &[0.0, 1.0, 1e2, 1e4, 1e5] {
            for &eps in &[1e-6, 1e-3, 1.0] {
                let mut frames = vec![(Vec3::Z, Vec3::X, true)];
                if nasg::rotation_safe(lambda, a, eps) {
                    frames.push((Vec3::new(0.3, -0.5, 0.8), Vec3::new(1.0, 0.2, 0.0), false));
                }
                for (z, x, exact_axis) in frames {
                    let lobe = NasgLobe::new(z, x, lambda, a, eps);
                    let (e, d) = check_normalisation(
                        &format!("NASG λ {lambda:e} a {a:e} ε {eps:e}, axis {z}"),
                        |d| lobe.pdf(d),
                        &nasg::lobe_warp(&lobe),
                        nasg::sharpness(&lobe),
                        exact_axis,
                    );
                    worst = (worst.0.max(e), worst.1.max(d));
                }
            }
        }
    }
    println!(
        "NASG normalisation: max |∫pdf − 1| {:.1e}, max Δ {:.1e}",
        worst.0, worst.1
    );
}

// ---------------------------------------------------------------------------
// Models.

const LO: [f32; 3] = [-1.0; 3];
const HI: [f32; 3] = [1.0; 3];

/// Queries: inside the box, on its corner, far outside, and degenerate
/// (NaN/∞ position, zero and NaN normal, subnormal roughness).
fn queries() -> Vec<QueryPoint> {
    let q = QueryPoint::new;
    vec![
        q([0.1, -0.3, 0.5], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8], 0.5),
        q([1.0, 1.0, 1.0], [0.0; 3], [0.0; 3], 0.0),
        q([1e30, -1e30, 3e38], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], 1.0),
        q(
            [f32::NAN, f32::INFINITY, DENORMAL_MIN],
            [f32::NAN; 3],
            [0.0; 3],
            DENORMAL,
        ),
    ]
}

/// `model` with its initial parameters times each scale from 0 to 10³⁰
/// (the MLPs saturate: one-hot DF bins, κ and λ at their clamps, lobes on
/// arbitrary axes): finite densities, selection probabilities in `[0, 1]`,
/// and sample/pdf agreement at every query over the `u` grid (the DF-N /
/// DF-L one-hot tables at `u = 0` and `1 − 2⁻²⁴` are the case the factorised
/// `SAMPLE_MARGIN` fixed).
fn check_model<M: GuidingModel>(name: &str, model: M) {
    let mut init = vec![0.0; model.param_count()];
    model.init(&mut init, 3);
    let mut rng = Pcg32::new(17, 3);
    for scale in [0.0, DENORMAL_MIN, 1e-30, 1e-3, 1.0, 1e3, 1e10, 1e20, 1e30] {
        let params: Vec<f32> = init.iter().map(|p| p * scale).collect();
        for (i, q) in queries().iter().enumerate() {
            let what = format!("{name} × {scale:e}, query {i}");
            let c = model.selection_probability(&params, q);
            assert!((0.0..=1.0).contains(&c), "{what}: c = {c}");
            let pdf = |d: Vec3| model.pdf(&params, q, d);
            check_densities(&what, pdf, Vec3::new(0.3, -0.5, 0.8).normalize());
            let mut us: Vec<Vec2> = US
                .iter()
                .flat_map(|&x| US.iter().map(move |&y| Vec2::new(x, y)))
                .collect();
            us.extend((0..20).map(|_| rng.next_vec2()));
            for u in us {
                let s = model.sample(&params, q, u);
                check_sample(&format!("{what}, u {u}"), s, pdf, 1e-4);
            }
        }
    }
}

#[test]
fn models_at_extreme_parameter_scales() {
    check_model("NPM radiance", NpmSmallRadiance::small(LO, HI));
    check_model("NPM product", NpmSmallProduct::small(LO, HI));
    check_model("NASG radiance", NasgSmallRadiance::small(LO, HI));
    check_model("NASG product", NasgSmallProduct::small(LO, HI));
    for interp in [Interpolation::Nearest, Interpolation::Linear] {
        check_model("DF radiance", DfSmallRadiance::small(LO, HI, interp));
        check_model("DF product", DfSmallProduct::small(LO, HI, interp));
    }
}
