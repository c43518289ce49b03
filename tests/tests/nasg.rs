//! NASG-specific tests (the chi², ∫pdf = 1 and sample/pdf checks of the
//! registered cases run in `distributions.rs`):
//!
//! 1. the vMF limit (`a = 0`, `ε → 0` is the vMF with `κ = λ`), in density and
//!    in the sampled polar angle;
//! 2. the density against an `f64` oracle over the parameter grid, and the
//!    normaliser against its closed form;
//! 3. `invert(sample(u)) = u` round trips, and `sample3` ≡ `sample`;
//! 4. frames: Euler angles against `R_z(α) R_y(β) R_z(γ)` in `f64`,
//!    Gram–Schmidt with degenerate hints, the `x → −x` symmetry behind the
//!    γ range of π;
//! 5. proptest: any raw vector (entries in ±10³⁰, exact ±10³⁰, 0, NaN, ±∞)
//!    decodes to a valid mixture;
//! 6. the gradient of `grad_log_pdf` against central differences of an `f64`
//!    re-implementation of decode + `ln p`;
//! 7. finiteness sweeps over the extreme parameter grid and degenerate
//!    directions;
//! 8. mixture bookkeeping: `pdf = Σ w_k p_k`, `log_pdf`, `Pod` layout, the
//!    selection probability.

use glam::{DMat3, DVec3, Vec2, Vec3};
use guiding_core::lobe::nasg::{
    NasgLobe, NASG_A_MAX, NASG_EPSILON, NASG_EPSILON_MAX, NASG_EPSILON_MIN, NASG_LAMBDA_MAX,
    NASG_LAMBDA_MIN,
};
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::math::ONE_MINUS_EPSILON;
use guiding_core::mixture::nasg::{
    decode_selection, NasgMixture, NASG_RAW_PER_LOBE, NASG_SELECTION_MAX, NASG_SELECTION_MIN,
};
use guiding_tests::cases::nasg::{random_direction, random_frame_lobe, rotation_safe};
use guiding_tests::fuzz_checks::check_sample_is_valid;
use guiding_tests::gradcheck::{central_difference, GradientErrors};
use guiding_tests::oracles;
use guiding_tests::rng::Pcg32;
use proptest::prelude::*;
use std::f64::consts::PI;

const R: usize = NASG_RAW_PER_LOBE;

/// The parameter grid of the sweeps (the lobe's full range).
const LAMBDAS: [f32; 8] = [
    NASG_LAMBDA_MIN,
    1e-2,
    0.1,
    1.0,
    10.0,
    1e3,
    1e4,
    NASG_LAMBDA_MAX,
];
const ANISOTROPIES: [f32; 6] = [0.0, 1e-4, 0.5, 10.0, 1e3, NASG_A_MAX];
const EPSILONS: [f32; 4] = [NASG_EPSILON_MIN, NASG_EPSILON, 0.1, NASG_EPSILON_MAX];

/// Signed world axes `(z, x)`: frames that are exact in `f32`.
const AXIS_FRAMES: [(Vec3, Vec3); 4] = [
    (Vec3::Z, Vec3::X),
    (Vec3::NEG_Y, Vec3::Z),
    (Vec3::X, Vec3::NEG_Y),
    (Vec3::NEG_Z, Vec3::Y),
];

fn dvec(a: [f32; 3]) -> DVec3 {
    Vec3::from_array(a).as_dvec3()
}

fn lobe_frame64(lobe: &NasgLobe) -> (DVec3, DVec3, DVec3) {
    (dvec(lobe.x), dvec(lobe.y), dvec(lobe.z))
}

// ---------------------------------------------------------------------------
// 1. The vMF limit.

/// `a = 0`, `ε = NASG_EPSILON_MIN`: the density is the vMF one with κ = λ up to
/// the exact difference `ln p − ln p_vMF = 2λ t (t^ε − 1) + ε ln t + ln(1 + ε)`
/// (≤ ~3.5·10⁻⁵ here, largest near the antipode where `ε ln t` grows). The
/// residual after subtracting it is `f32` rounding: of the two exponents,
/// `~2·10⁻⁶ (2 + κ (1 − cos θ))`; of the geometry, each implementation seeing
/// the `f32` direction in a rotated frame with an absolute error
/// `δ ≈ 1.2·10⁻⁷`, i.e. `δ |∇_ω ln p| = δ κ sin θ`; and of `ln t` near the
/// antipode, which a rotated frame resolves only down to `t ≈ (2δ)²/4 ≈
/// 1.5·10⁻¹⁴` (`ε (ln(1.5·10⁻¹⁴ / t) + 1)` below that).
#[test]
fn vmf_limit_density() {
    let mut rng = Pcg32::new(1, 100);
    let eps = NASG_EPSILON_MIN;
    let mut worst = 0.0_f64;
    for &lambda in &LAMBDAS {
        for _ in 0..20 {
            let lobe = random_frame_lobe(&mut rng, lambda, 0.0, eps);
            let z = Vec3::from_array(lobe.z);
            let vmf = VmfLobe::new(z, lambda);
            let f = lobe.frame();
            let mut dirs = vec![z, -z, f.x, f.y, -f.x];
            for _ in 0..50 {
                dirs.push(random_direction(&mut rng));
                // Near the axis and near the antipode.
                let s = 10f32.powf(rng.uniform(-7.0, 0.0));
                dirs.push(z + s * random_direction(&mut rng));
                dirs.push(-z + s * random_direction(&mut rng));
            }
            for d in dirs {
                let (pn, pv) = (f64::from(lobe.pdf(d)), f64::from(vmf.pdf(d)));
                if pv < 1e-30 {
                    // Underflowed vMF density: the NASG one must be as small.
                    assert!(pn < 1e-29, "λ {lambda}: nasg {pn:e} vs vmf {pv:e}");
                    continue;
                }
                // t = |d̂ + ẑ|²/4 (the naive (1 + d̂·z)/2 goes negative near the
                // antipode: the f32 axis is not exactly unit).
                let t =
                    0.25 * (d.as_dvec3().normalize() + z.as_dvec3().normalize()).length_squared();
                let ln_t = t.max(f64::from(f32::MIN_POSITIVE)).ln();
                let (l64, e64) = (f64::from(lambda), f64::from(eps));
                let exact = 2.0 * l64 * t * (e64 * ln_t).exp_m1() + e64 * ln_t + e64.ln_1p();
                let exponent = 2.0 * l64 * (1.0 - t);
                let sin_theta = 2.0 * (t * (1.0 - t)).max(0.0).sqrt();
                // In a rotated frame t is resolved down to ~(2δ)²/4 ≈ 1.5·10⁻¹⁴ only.
                let ln_t_error = (1.5e-14_f64.ln() - ln_t).max(0.0) + 1.0;
                let tol = 2e-6 * (2.0 + exponent) + 2.4e-7 * l64 * sin_theta + e64 * ln_t_error;
                let diff = (pn.ln() - pv.ln() - exact).abs();
                worst = worst.max(diff / tol);
                assert!(
                    diff <= tol,
                    "λ {lambda}, d {d}: nasg {pn:e} vs vmf {pv:e} (|Δ ln p| {diff:e} > {tol:e})"
                );
            }
        }
    }
    println!("vmf limit: worst |Δ ln p| / tolerance = {worst:.3}");
}

/// The sampled polar angle of the `a = 0`, `ε → 0` lobe is the vMF one for the
/// same polar number (`1 − u = t` of the vMF, `u^{1/(1+ε)}` here).
#[test]
fn vmf_limit_polar_sampling() {
    let mut rng = Pcg32::new(2, 100);
    for &lambda in &LAMBDAS {
        let lobe = random_frame_lobe(&mut rng, lambda, 0.0, NASG_EPSILON_MIN);
        let z = Vec3::from_array(lobe.z);
        let vmf = VmfLobe::new(z, lambda);
        for _ in 0..2000 {
            let u = Vec2::new(rng.next_f32(), rng.uniform(1e-3, 1.0));
            let (dn, dv) = (lobe.sample(u).direction, vmf.sample(u).direction);
            // 1 − cos θ, without cancellation: |d × z|² / (1 + d·z) on the axis side.
            let omc = |d: Vec3| {
                let d = d.as_dvec3().normalize();
                let c = d.dot(z.as_dvec3());
                if c > 0.0 {
                    d.cross(z.as_dvec3()).length_squared() / (1.0 + c)
                } else {
                    1.0 - c
                }
            };
            let (sn, sv) = (omc(dn), omc(dv));
            // f32 rounding of the direction: ~2·10⁻⁷ absolute in sin θ.
            let tol = 2e-5 * sv + 4e-7 * sv.sqrt() + 1e-12;
            assert!(
                (sn - sv).abs() <= tol,
                "λ {lambda}, u {u}: 1 − cos θ {sn:e} (nasg) vs {sv:e} (vmf)"
            );
        }
    }
}

// ---------------------------------------------------------------------------
// 2. Density and normaliser against f64.

/// Over the whole parameter grid, in exact (axis) frames, at directions drawn
/// from the lobe, uniformly, on the frame axes and at tiny angles from the
/// axis and the antipode: `|ln p − ln p_f64| ≤ 2·10⁻⁶ (4 + |ln G|)` (a few
/// `f32` ulps of each term of the exponent), wherever `p_f64` is a normal
/// `f32` (elsewhere `p` must be tiny too).
#[test]
fn density_matches_f64_oracle() {
    let mut rng = Pcg32::new(3, 100);
    let mut worst = 0.0_f64;
    for (i, &lambda) in LAMBDAS.iter().enumerate() {
        for (j, &a) in ANISOTROPIES.iter().enumerate() {
            for &eps in &EPSILONS {
                let (z, x) = AXIS_FRAMES[(i + j) % AXIS_FRAMES.len()];
                let lobe = NasgLobe::new(z, x, lambda, a, eps);
                let frame = lobe_frame64(&lobe);
                let f = lobe.frame();
                let mut dirs = vec![f.x, f.y, -f.x, -f.y, f.z, -f.z];
                for _ in 0..200 {
                    dirs.push(lobe.sample(rng.next_vec2()).direction);
                    dirs.push(random_direction(&mut rng));
                    let s = 10f32.powf(rng.uniform(-12.0, -1.0));
                    let r = random_direction(&mut rng);
                    dirs.push(f.z + s * r);
                    dirs.push(-f.z + s * r);
                }
                for d in dirs {
                    let p = lobe.pdf(d);
                    let ln_p64 = oracles::nasg_lobe_ln_pdf(
                        frame,
                        f64::from(lambda),
                        f64::from(a),
                        f64::from(eps),
                        d.as_dvec3(),
                    );
                    if ln_p64 < -85.0 {
                        assert!(
                            f64::from(p) < 1e-36,
                            "λ {lambda} a {a} ε {eps} d {d}: {p:e} vs ln p {ln_p64}"
                        );
                        continue;
                    }
                    let log_norm = f64::from(lobe.log_norm);
                    let ln_g = ln_p64 - log_norm;
                    let tol = 2e-6 * (4.0 + ln_g.abs() + log_norm.abs());
                    let diff = (f64::from(p).ln() - ln_p64).abs();
                    worst = worst.max(diff / tol);
                    assert!(
                        diff <= tol,
                        "λ {lambda} a {a} ε {eps} d {d}: ln p {} vs {ln_p64} (Δ {diff:e})",
                        f64::from(p).ln()
                    );
                }
            }
        }
    }
    println!("density vs f64: worst |Δ ln p| / tolerance = {worst:.3}");
}

/// `−ln K` against NASG eq. 19 in `f64`, over the grid and the clamped range,
/// and `normalization() = K`.
#[test]
fn normaliser_matches_closed_form() {
    for &lambda in &LAMBDAS {
        for &a in &ANISOTROPIES {
            for &eps in &EPSILONS {
                let lobe = NasgLobe::from_euler(0.3, 1.1, 2.0, lambda, a, eps);
                let (l, a64, e) = (f64::from(lambda), f64::from(a), f64::from(eps));
                let k =
                    2.0 * PI * (-(-2.0 * l).exp_m1()) / (l * ((1.0 + e) * (1.0 + e + a64)).sqrt());
                let got = f64::from(lobe.log_norm);
                assert!(
                    (got + k.ln()).abs() <= 1e-6 * (1.0 + k.ln().abs()),
                    "λ {lambda} a {a} ε {eps}: −ln K {got} vs {}",
                    -k.ln()
                );
                let kn = f64::from(lobe.normalization());
                assert!((kn - k).abs() <= 2e-6 * k, "K {kn} vs {k}");
            }
        }
    }
}

// ---------------------------------------------------------------------------
// 3. Sampling: inversion and the 3-number variant.

/// `invert(sample(u)) = u` away from the seam `u.x ∈ {0, 1}` and the axis
/// (`u.y ≤ 0.99`, where φ is ill-conditioned).
///
/// Exact frames, over the whole grid: `|Δu.x| ≤ 10⁻⁶ (1 + c)` with
/// `c = √((1 + ε + a)/(1 + ε))` (`dψ/dφ ≤ c` amplifies the ~10⁻⁷ error of φ),
/// `|Δu.y| ≤ 10⁻⁵`. Random frames (the rotation-safe parameters of the chi²
/// cases): the rotation adds ~1.2·10⁻⁷ absolute to every local coordinate,
/// i.e. `~1.2·10⁻⁷ / sin θ` to φ and `~1.2·10⁻⁷ · √B` relative to `1 − cos θ`,
/// so the tolerance is `10⁻⁶ (1 + c) / sin θ` and `10⁻⁴`.
#[test]
fn invert_round_trip() {
    let mut rng = Pcg32::new(4, 100);
    let mut worst = (0.0_f64, 0.0_f64);
    for (i, &lambda) in LAMBDAS.iter().enumerate() {
        for (j, &a) in ANISOTROPIES.iter().enumerate() {
            for &eps in &EPSILONS {
                let c = f64::from((1.0 + eps + a) / (1.0 + eps)).sqrt();
                let random = rotation_safe(lambda, a, eps);
                let lobe = if random {
                    random_frame_lobe(&mut rng, lambda, a, eps)
                } else {
                    let (z, x) = AXIS_FRAMES[(i + j) % AXIS_FRAMES.len()];
                    NasgLobe::new(z, x, lambda, a, eps)
                };
                let z = Vec3::from_array(lobe.z).as_dvec3();
                for _ in 0..500 {
                    let u = Vec2::new(rng.uniform(1e-3, 1.0 - 1e-3), rng.uniform(0.0, 0.99));
                    let d = lobe.sample(u).direction;
                    let back = lobe.invert(d);
                    let sin_theta = d.as_dvec3().normalize().cross(z).length();
                    let (tol_x, tol_y) = if random {
                        (1e-6 * (1.0 + c) / sin_theta.max(1e-9), 1e-4)
                    } else {
                        (1e-6 * (1.0 + c), 1e-5)
                    };
                    let (ex, ey) = (
                        f64::from((back.x - u.x).abs()),
                        f64::from((back.y - u.y).abs()),
                    );
                    worst = (worst.0.max(ex / tol_x), worst.1.max(ey / tol_y));
                    assert!(
                        ex <= tol_x && ey <= tol_y,
                        "λ {lambda} a {a} ε {eps} ({}): u {u} → {d} → {back}",
                        if random { "random frame" } else { "axis frame" }
                    );
                }
            }
        }
    }
    println!(
        "invert: worst error / tolerance: u.x {:.3}, u.y {:.3}",
        worst.0, worst.1
    );
}

/// The seam: `u.x → 0` and `u.x → 1` both map to `φ = −π/2`; `u.x = ½` joins the
/// halves continuously at `φ = π/2`.
#[test]
fn azimuth_seam_and_halves() {
    let lobe = NasgLobe::new(Vec3::Z, Vec3::X, 10.0, 3.0, 0.1);
    let y = Vec3::Y;
    for &(ux, expect) in &[
        (0.0, -y),
        (ONE_MINUS_EPSILON, -y),
        (0.5, y),
        (0.5 - 1e-7, y),
    ] {
        let d = lobe.sample(Vec2::new(ux, 0.3)).direction;
        let horizontal = Vec3::new(d.x, d.y, 0.0).normalize();
        assert!(
            horizontal.dot(expect) > 1.0 - 1e-5,
            "u.x {ux}: azimuth direction {horizontal}, expected {expect}"
        );
    }
}

/// `sample3((w, ξ, h))` is `sample((w/2, ξ))` for `h < ½` and
/// `sample(((w + 1)/2, ξ))` otherwise (both exact in `f32` for these `w`).
#[test]
fn sample3_matches_sample() {
    let mut rng = Pcg32::new(5, 100);
    for _ in 0..200 {
        let lambda = 10f32.powf(rng.uniform(-4.0, 5.0));
        let a = 10f32.powf(rng.uniform(-3.0, 5.0));
        let lobe = random_frame_lobe(&mut rng, lambda, a, 0.01);
        for _ in 0..50 {
            // w on a 2⁻²³ grid, so that w/2 and (w + 1)/2 are exact.
            let w = (rng.next_u32() >> 9) as f32 / 8_388_608.0;
            let xi = rng.next_f32();
            let east = lobe.sample3(Vec3::new(w, xi, 0.25));
            let west = lobe.sample3(Vec3::new(w, xi, 0.75));
            assert_eq!(east, lobe.sample(Vec2::new(0.5 * w, xi)));
            assert_eq!(west, lobe.sample(Vec2::new(0.5 * (w + 1.0), xi)));
        }
    }
}

// ---------------------------------------------------------------------------
// 4. Frames.

fn rz(a: f64) -> DMat3 {
    DMat3::from_rotation_z(a)
}

/// NASG eq. 13 in `f64`: `(x, y, z)` are the columns of `R_z(α) R_y(β) R_z(γ)`.
#[test]
fn euler_frame_matches_rotation_matrices() {
    let mut rng = Pcg32::new(6, 100);
    for _ in 0..1000 {
        let (alpha, beta, gamma) = (
            rng.uniform(-7.0, 7.0),
            rng.uniform(-4.0, 4.0),
            rng.uniform(-7.0, 7.0),
        );
        let lobe = NasgLobe::from_euler(alpha, beta, gamma, 1.0, 1.0, 0.1);
        let r =
            rz(f64::from(alpha)) * DMat3::from_rotation_y(f64::from(beta)) * rz(f64::from(gamma));
        for (got, want) in [(lobe.x, r.x_axis), (lobe.y, r.y_axis), (lobe.z, r.z_axis)] {
            assert!(
                (dvec(got) - want).length() < 1e-6,
                "α {alpha} β {beta} γ {gamma}: {got:?} vs {want}"
            );
        }
    }
}

fn assert_orthonormal(lobe: &NasgLobe, what: &str) {
    let (x, y, z) = lobe_frame64(lobe);
    for (v, name) in [(x, "x"), (y, "y"), (z, "z")] {
        assert!(
            v.is_finite() && (v.length() - 1.0).abs() < 1e-6,
            "{what}: |{name}| = {v}"
        );
    }
    assert!(
        x.dot(y).abs() < 1e-6 && y.dot(z).abs() < 1e-6 && z.dot(x).abs() < 1e-6,
        "{what}: not orthogonal: {x} {y} {z}"
    );
    assert!((x.cross(y) - z).length() < 1e-6, "{what}: not right-handed");
}

/// Gram–Schmidt frames: orthonormal and right-handed for every hint,
/// including zero, NaN, infinite, parallel and nearly parallel ones; the axis
/// is the normalised `z_axis` (or `+z` when that is degenerate) and `x` lies
/// in the plane of `z` and the hint.
#[test]
fn gram_schmidt_frames() {
    let mut rng = Pcg32::new(7, 100);
    let degenerate = [
        Vec3::ZERO,
        Vec3::splat(f32::NAN),
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(1e-45, 0.0, 0.0),
        Vec3::new(f32::MAX, f32::MAX, 0.0),
    ];
    for i in 0..2000 {
        let z = if i % 10 == 0 {
            degenerate[(i / 10) % degenerate.len()]
        } else {
            random_direction(&mut rng) * rng.uniform(1e-3, 1e3)
        };
        let hint = match i % 7 {
            0 => z,
            1 => -z * 3.0,
            2 => z + 1e-6 * random_direction(&mut rng),
            3 => degenerate[i % degenerate.len()],
            _ => random_direction(&mut rng),
        };
        let lobe = NasgLobe::new(z, hint, 1.0, 2.0, 0.1);
        assert_orthonormal(&lobe, &format!("z {z}, hint {hint}"));
        let zn = z.as_dvec3();
        if zn.is_finite() && zn.length() > 0.0 {
            assert!((dvec(lobe.z) - zn.normalize()).length() < 1e-6);
        } else {
            assert_eq!(lobe.z, [0.0, 0.0, 1.0]);
        }
        if i % 7 >= 4 && zn.is_finite() && zn.length() > 1e-30 {
            // x is the hint's component orthogonal to z.
            let h = hint.as_dvec3();
            let want = (h - zn.normalize() * h.dot(zn.normalize())).normalize();
            assert!(
                (dvec(lobe.x) - want).length() < 1e-5,
                "x {:?} vs {want}",
                lobe.x
            );
        }
    }
}

/// `G` depends on the tangents only through `cos²φ`: γ and γ + π (x → −x,
/// y → −y) give the same density, which is why the decoder's γ range is π.
#[test]
fn x_flip_symmetry() {
    let mut rng = Pcg32::new(8, 100);
    for _ in 0..200 {
        let (alpha, beta, gamma) = (
            rng.uniform(0.0, 6.0),
            rng.uniform(0.0, 3.0),
            rng.uniform(0.0, 3.0),
        );
        let (lambda, a) = (rng.uniform(0.1, 30.0), rng.uniform(0.0, 30.0));
        let l1 = NasgLobe::from_euler(alpha, beta, gamma, lambda, a, 0.01);
        let l2 = NasgLobe::from_euler(alpha, beta, gamma + std::f32::consts::PI, lambda, a, 0.01);
        for _ in 0..20 {
            let d = l1.sample(rng.next_vec2()).direction;
            let (p1, p2) = (l1.pdf(d), l2.pdf(d));
            assert!((p1 - p2).abs() <= 1e-4 * p1, "{p1} vs {p2}");
        }
    }
}

// ---------------------------------------------------------------------------
// 5. Proptest: every raw vector decodes to a valid mixture.

const PK: usize = 4;

fn raw_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -1e30_f32..1e30_f32,
        4 => -30.0_f32..30.0_f32,
        1 => Just(1e30_f32),
        1 => Just(-1e30_f32),
        1 => Just(0.0_f32),
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
        1 => Just(f32::MAX),
        1 => Just(1e-40_f32),
    ]
}

fn check_mixture_valid(m: &NasgMixture<PK>, u: Vec2, d: Vec3) -> Result<(), TestCaseError> {
    let sum: f32 = m.weight.iter().sum();
    prop_assert!((sum - 1.0).abs() < 1e-5, "weights sum {}", sum);
    for k in 0..PK {
        prop_assert!(m.weight[k] >= 0.0 && m.weight[k].is_finite());
        let l = m.lobe(k);
        prop_assert!(
            (NASG_LAMBDA_MIN..=NASG_LAMBDA_MAX).contains(&l.lambda),
            "λ {}",
            l.lambda
        );
        prop_assert!((0.0..=NASG_A_MAX).contains(&l.a), "a {}", l.a);
        prop_assert!(l.log_norm.is_finite() && l.one_minus_e2l > 0.0);
        assert_orthonormal(&l, "decoded lobe");
    }
    let c = m.selection_probability();
    prop_assert!((0.0..=1.0).contains(&c), "selection probability {}", c);
    let s = m.sample(u);
    prop_assert!(s.direction.is_finite(), "direction {}", s.direction);
    prop_assert!(
        (s.direction.length() - 1.0).abs() <= 1e-5,
        "|d| = {}",
        s.direction.length()
    );
    prop_assert!(s.pdf.is_finite() && s.pdf >= 0.0, "sample pdf {}", s.pdf);
    let p = m.pdf(d);
    prop_assert!(p.is_finite() && p >= 0.0, "pdf {}", p);
    let lp = m.log_pdf(d);
    prop_assert!(lp.is_finite(), "log pdf {}", lp);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Any raw output (with exact ±10³⁰, 0, NaN, ±∞, `f32::MAX`, subnormals)
    /// gives a valid mixture: weights a distribution, parameters in range,
    /// orthonormal frames, unit finite samples, finite non-negative
    /// densities, `c ∈ [0, 1]`, and a finite `grad_log_pdf`.
    #[test]
    fn any_raw_decodes_to_a_valid_mixture(
        raw in prop::array::uniform4(prop::array::uniform6(raw_value())),
        selection in raw_value(),
        u in (0.0_f32..1.0, 0.0_f32..1.0),
        d in (raw_value(), raw_value(), raw_value()),
    ) {
        let m = NasgMixture::<PK>::decode(&raw, selection);
        let u = Vec2::new(u.0, u.1);
        let d = Vec3::new(d.0, d.1, d.2);
        check_mixture_valid(&m, u, d)?;
        let c = m.selection_probability();
        prop_assert!((NASG_SELECTION_MIN..=NASG_SELECTION_MAX).contains(&c));
        let mut grad = [[0.0; R]; PK];
        for dir in [d, m.sample(u).direction, Vec3::from_array(m.lobe(0).z), -Vec3::from_array(m.lobe(0).z)] {
            let lp = NasgMixture::grad_log_pdf(&raw, dir, &mut grad);
            prop_assert!(lp.is_finite(), "ln p {}", lp);
            prop_assert!(grad.iter().flatten().all(|g| g.is_finite()), "grad {:?}", grad);
        }
    }
}

// ---------------------------------------------------------------------------
// 6. Gradient against an f64 oracle.

const GK: usize = 4;

fn random_grad_raw(rng: &mut Pcg32) -> [[f32; R]; GK] {
    core::array::from_fn(|_| {
        [
            rng.uniform(-2.0, 2.0),
            rng.uniform(-3.0, 5.0),
            rng.uniform(-4.0, 4.0),
            rng.uniform(-3.0, 3.0),
            rng.uniform(-3.0, 3.0),
            rng.uniform(-3.0, 3.0),
        ]
    })
}

/// The compared components of [`gradient_matches_f64_oracle`] (it asserts
/// `ln p` on the way).
fn oracle_gradient_errors() -> GradientErrors {
    let mut rng = Pcg32::new(9, 100);
    let mut errors = GradientErrors::new(1e-3);
    for trial in 0..400 {
        let raw = random_grad_raw(&mut rng);
        let m = NasgMixture::<GK>::decode(&raw, 0.0);
        let d = match trial % 3 {
            0 => m.sample(rng.next_vec2()).direction,
            1 => random_direction(&mut rng),
            _ => Vec3::from_array(m.lobe(trial % GK).z),
        };
        let mut grad = [[0.0; R]; GK];
        let lp = NasgMixture::grad_log_pdf(&raw, d, &mut grad);
        let raw64: Vec<f64> = raw.iter().flatten().map(|&x| f64::from(x)).collect();
        let d64 = d.as_dvec3();
        let lp64 = oracles::nasg_ln_pdf(&raw64, d64);
        assert!(
            (f64::from(lp) - lp64).abs() <= 1e-5 * (1.0 + lp64.abs()),
            "trial {trial}: ln p {lp} vs {lp64}"
        );
        assert!(
            (m.log_pdf(d) - lp).abs() <= 1e-5 * (1.0 + lp.abs()),
            "log_pdf {} vs grad_log_pdf {lp}",
            m.log_pdf(d)
        );
        let numeric = central_difference(|x| oracles::nasg_ln_pdf(x, d64), &raw64, 1e-6);
        let analytic: Vec<f64> = grad.iter().flatten().map(|&g| f64::from(g)).collect();
        errors.push_all(&format!("trial {trial}"), &analytic, &numeric);
    }
    errors
}

/// `grad_log_pdf` against central differences (`h = 10⁻⁶`) of the `f64`
/// oracle, on 400 random raw vectors away from the clamp boundaries
/// (`ln λ ∈ [−3, 5]`, `ln a ∈ [−4, 4]`), at directions drawn from the mixture,
/// uniform directions, and exactly on a lobe axis (the pole of its frame).
/// Symmetric relative error `|a − n| / max(|a|, |n|, 10⁻³) ≤ 10⁻²` for ≥ 99% of
/// all components. What exceeds it (measured: 12 of 9600, all below 4·10⁻²) are
/// frame-angle components of size ~10⁻⁵ in the on-axis trials: the oracle's
/// `f64` frame differs from the decoded `f32` one by ~10⁻⁷ rad, so the
/// "on-axis" direction is ~10⁻⁷ off the oracle's axis, where
/// `∂ ln G/∂angle ≈ B θ` (`B = (2λ + 1)(1 + ε + a)`) is ~10⁻⁵ rather than 0.
/// Also `ln p` itself agrees with the oracle.
///
/// The tolerance. Numeric side: truncation `h² |f‴| / 6`, relative `~h² B ≤
/// 10⁻¹² · 1.7·10⁴` (`B ≤ 297 · 56` at `ln λ = 5`, `ln a = 4`), and rounding
/// `ε₆₄ |ln p| / h ≤ 1.1·10⁻¹⁶ · 3·10⁴ / 10⁻⁶ = 3.3·10⁻⁶` absolute (`|ln p| ≤
/// 2B`), i.e. ≤ 3.3·10⁻³ at the floor 10⁻³ and negligible above it. Analytic
/// side (`f32`): a component is a product of a few factors of size up to `B`
/// through `N ≈ 30` roundings, relative error `~ε₃₂ √N ≈ 7·10⁻⁷` (measured
/// median 1.4·10⁻⁷); where terms of size `S` cancel to `|g|` it grows by
/// `S / max(|g|, 10⁻³)`, which the tolerance admits up to `10⁻² / 7·10⁻⁷ ≈
/// 1.4·10⁴` (99th percentile measured: 4·10⁻⁴). A defect of relative size `δ`
/// gives `e = δ / (1 + δ)`: any `δ ≳ 1 %` in more than 1 % of the components
/// fails (`gradient_check_rejects_a_planted_nasg_defect`).
#[test]
fn gradient_matches_f64_oracle() {
    let errors = oracle_gradient_errors();
    errors.report("gradient", 1e-2);
    errors.assert("NASG grad_log_pdf vs f64 oracle", 1e-2, 0.01);
}

/// Negative control: the components of [`gradient_matches_f64_oracle`] with one
/// defect planted — lobe 0's `∂/∂ ln λ` 5 % too large (400 of the 9600
/// components, each at `e = 0.05/1.05 = 0.048` unless it is below `2·10⁻⁴`,
/// where the floor hides it) — fail the same check: measured 278 components
/// fail, against 96 allowed.
#[test]
fn gradient_check_rejects_a_planted_nasg_defect() {
    oracle_gradient_errors().assert_rejects_defect(
        "NASG grad_log_pdf",
        "lobe 0's ∂/∂ln λ × 1.05",
        (1e-2, 0.01),
        |i, _| if i % (GK * R) == 1 { 1.05 } else { 1.0 },
    );
}

/// Clamped `ln λ`, `ln a` outputs get a zero gradient; saturated sigmoids too.
#[test]
fn clamped_outputs_have_zero_gradient() {
    let mut raw = [[0.5_f32, 0.0, 0.0, 0.3, -0.2, 0.1]; 2];
    raw[0][1] = 20.0;
    raw[0][2] = -20.0;
    raw[1][1] = -1e30;
    raw[1][2] = f32::NAN; // sanitised to 0: inside the range.
    raw[1][3] = 1e30;
    let mut grad = [[0.0; R]; 2];
    let d = Vec3::new(0.3, -0.4, 0.8);
    let lp = NasgMixture::grad_log_pdf(&raw, d, &mut grad);
    assert!(lp.is_finite());
    assert_eq!(grad[0][1], 0.0);
    assert_eq!(grad[0][2], 0.0);
    assert_eq!(grad[1][1], 0.0);
    assert_eq!(grad[1][3], 0.0);
    assert!(grad[1][2] != 0.0);
}

/// `decode_selection`: `c = clamp(sigmoid(r), 0.01, 0.99)` and its derivative.
#[test]
fn selection_probability_and_derivative() {
    for &r in &[
        -10.0_f32,
        -4.0,
        -1.0,
        0.0,
        0.5,
        3.0,
        4.5,
        10.0,
        1e30,
        f32::NAN,
        f32::NEG_INFINITY,
    ] {
        let (c, dc) = decode_selection(r);
        assert!(
            (NASG_SELECTION_MIN..=NASG_SELECTION_MAX).contains(&c),
            "{r}: {c}"
        );
        let s = |x: f64| {
            oracles::sigmoid(x).clamp(f64::from(NASG_SELECTION_MIN), f64::from(NASG_SELECTION_MAX))
        };
        // NaN is sanitised to 0.
        let r = if r.is_nan() { 0.0 } else { r };
        if r.is_finite() && r.abs() < 100.0 {
            let r64 = f64::from(r);
            assert!((f64::from(c) - s(r64)).abs() < 1e-6);
            let n = (s(r64 + 1e-5) - s(r64 - 1e-5)) / 2e-5;
            assert!(
                (f64::from(dc) - n).abs() <= 1e-4 * n.abs().max(1e-3),
                "{r}: {dc} vs {n}"
            );
        } else {
            assert_eq!(dc, 0.0);
        }
    }
    let m = NasgMixture::<2>::decode(&[[0.0; R]; 2], 2.0);
    assert_eq!(m.selection_probability(), decode_selection(2.0).0);
}

// ---------------------------------------------------------------------------
// 7. Finiteness sweeps.

/// Directions that stress the evaluation of a lobe with frame `f`.
fn stress_directions(lobe: &NasgLobe) -> Vec<Vec3> {
    let f = lobe.frame();
    let mut dirs = vec![
        f.x,
        -f.x,
        f.y,
        -f.y,
        f.z,
        -f.z,
        f.z + 1e-20 * f.x,
        f.z + 1e-7 * f.y,
        -f.z + 1e-38 * f.x,
        -f.z + 1e-7 * (f.x + f.y),
        Vec3::X,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
        Vec3::new(1e-40, 0.0, 0.0),
        Vec3::new(1e-45, 1e-45, -1e-45),
        Vec3::new(1e-40, 0.0, 1.0),
        Vec3::new(0.0, -1e-40, -1.0),
        Vec3::new(1e20, -1e20, 3.0),
        Vec3::new(f32::MAX, f32::MAX, 0.0),
        Vec3::ZERO,
        Vec3::splat(f32::NAN),
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(0.0, f32::NEG_INFINITY, f32::NAN),
    ];
    dirs.extend(dirs.clone().iter().map(|d| *d * 3.0));
    dirs
}

fn stress_us() -> Vec<f32> {
    vec![
        0.0,
        1.0 / 16_777_216.0,
        1e-30,
        0.25,
        0.5 - 6e-8,
        0.5,
        0.75,
        ONE_MINUS_EPSILON,
        1.0,
        -1.0,
        2.0,
        f32::NAN,
    ]
}

/// Every lobe of the extreme grid (including out-of-range and NaN parameters
/// and angles, which are clamped) is finite everywhere: `pdf ≥ 0` finite,
/// `eval ∈ [0, 1]`, finite `log_pdf`, `invert ∈ [0, 1)²`; every sample is a
/// finite unit vector with a finite positive pdf, also for `u` outside
/// `[0, 1)` or NaN.
#[test]
fn finiteness_sweep_lobes() {
    let lambdas = [
        NASG_LAMBDA_MIN,
        1e-3,
        1.0,
        1e3,
        NASG_LAMBDA_MAX,
        0.0,
        -1.0,
        1e30,
        f32::MAX,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ];
    let anisotropies = [
        0.0,
        1e-5,
        1.0,
        1e3,
        NASG_A_MAX,
        -1.0,
        1e30,
        f32::INFINITY,
        f32::NAN,
    ];
    let epsilons = [
        NASG_EPSILON_MIN,
        1e-3,
        1.0,
        0.0,
        -1.0,
        5.0,
        f32::INFINITY,
        f32::NAN,
    ];
    let angles = [
        (0.0, 0.0, 0.0),
        (0.3, 2.0, 1.0),
        (f32::NAN, f32::INFINITY, f32::NEG_INFINITY),
        (1e30, -1e30, 3.0),
        (0.0, std::f32::consts::PI, 0.0),
    ];
    let us = stress_us();
    let mut n = 0_usize;
    for &lambda in &lambdas {
        for &a in &anisotropies {
            for &eps in &epsilons {
                for &(al, be, ga) in &angles {
                    let lobe = NasgLobe::from_euler(al, be, ga, lambda, a, eps);
                    let what = format!("λ {lambda} a {a} ε {eps} angles ({al}, {be}, {ga})");
                    assert!(
                        (NASG_LAMBDA_MIN..=NASG_LAMBDA_MAX).contains(&lobe.lambda),
                        "{what}"
                    );
                    assert!((0.0..=NASG_A_MAX).contains(&lobe.a), "{what}");
                    assert!(
                        (NASG_EPSILON_MIN..=NASG_EPSILON_MAX).contains(&lobe.epsilon),
                        "{what}"
                    );
                    assert!(
                        lobe.log_norm.is_finite() && lobe.one_minus_e2l > 0.0,
                        "{what}"
                    );
                    assert_orthonormal(&lobe, &what);
                    for d in stress_directions(&lobe) {
                        let p = lobe.pdf(d);
                        let e = lobe.eval(d);
                        let lp = lobe.log_pdf(d);
                        let inv = lobe.invert(d);
                        assert!(p.is_finite() && p >= 0.0, "{what}, d {d}: pdf {p}");
                        assert!((0.0..=1.0).contains(&e), "{what}, d {d}: eval {e}");
                        assert!(lp.is_finite(), "{what}, d {d}: log pdf {lp}");
                        assert!(
                            (0.0..1.0).contains(&inv.x) && (0.0..1.0).contains(&inv.y),
                            "{what}, d {d}: invert {inv}"
                        );
                        n += 1;
                    }
                    for &ux in &us {
                        for &uy in &us {
                            for s in [
                                lobe.sample(Vec2::new(ux, uy)),
                                lobe.sample3(Vec3::new(ux, uy, 0.9)),
                            ] {
                                check_sample_is_valid(&format!("{what}, u ({ux}, {uy})"), s);
                                let p = lobe.pdf(s.direction);
                                assert!(p.is_finite() && p >= 0.0, "{what}: pdf(sample) {p}");
                            }
                        }
                    }
                }
            }
        }
    }
    println!("finiteness sweep: {n} lobe evaluations");
}

/// Mixtures decoded from raw vectors of extreme entries: finite `ln p` and
/// gradient at every stress direction, including every lobe's axis and
/// antipode exactly.
#[test]
fn finiteness_sweep_gradient() {
    let extremes = [
        0.0_f32,
        1e30,
        -1e30,
        f32::MAX,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        9.21,
        -9.21,
        10.0,
        -10.0,
        30.0,
        -30.0,
        1e-40,
    ];
    let mut rng = Pcg32::new(10, 100);
    for trial in 0..3000 {
        let raw: [[f32; R]; 2] = core::array::from_fn(|_| {
            core::array::from_fn(|_| {
                if rng.next_f32() < 0.7 {
                    extremes[(rng.next_u32() as usize) % extremes.len()]
                } else {
                    rng.uniform(-12.0, 12.0)
                }
            })
        });
        let m = NasgMixture::<2>::decode(&raw, raw[0][0]);
        let lobe = m.lobe(trial % 2);
        let mut dirs = stress_directions(&lobe);
        dirs.push(m.sample(rng.next_vec2()).direction);
        let mut grad = [[0.0; R]; 2];
        for d in dirs {
            let lp = NasgMixture::grad_log_pdf(&raw, d, &mut grad);
            assert!(lp.is_finite(), "raw {raw:?}, d {d}: ln p {lp}");
            assert!(
                grad.iter().flatten().all(|g| g.is_finite()),
                "raw {raw:?}, d {d}: grad {grad:?}"
            );
            let p = m.pdf(d);
            assert!(p.is_finite() && p >= 0.0);
        }
    }
}

// ---------------------------------------------------------------------------
// 8. Mixture bookkeeping.

#[test]
fn mixture_is_the_weighted_sum_of_its_lobes() {
    let mut rng = Pcg32::new(11, 100);
    for _ in 0..100 {
        let lobes: [NasgLobe; 8] = core::array::from_fn(|_| {
            let lambda = 10f32.powf(rng.uniform(-4.0, 3.0));
            let a = 10f32.powf(rng.uniform(-3.0, 3.0));
            random_frame_lobe(&mut rng, lambda, a, 0.01)
        });
        let mut weights: [f32; 8] = core::array::from_fn(|_| rng.uniform(0.0, 3.0));
        weights[3] = f32::NAN;
        weights[5] = -1.0;
        let m = NasgMixture::from_lobes(&lobes, &weights);
        assert_eq!(m.weight[3], 0.0);
        assert_eq!(m.weight[5], 0.0);
        assert!((m.weight.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert_eq!(m.selection_probability(), 0.5);
        for (k, lobe) in lobes.iter().enumerate() {
            assert_eq!(m.lobe(k), *lobe);
        }
        for _ in 0..20 {
            let d = if rng.next_f32() < 0.5 {
                random_direction(&mut rng)
            } else {
                m.sample(rng.next_vec2()).direction
            };
            let sum: f64 = (0..8)
                .map(|k| f64::from(m.weight[k]) * f64::from(lobes[k].pdf(d)))
                .sum();
            let p = f64::from(m.pdf(d));
            assert!((p - sum).abs() <= 1e-5 * sum + 1e-30, "{p} vs {sum}");
            if p > 1e-30 {
                assert!((f64::from(m.log_pdf(d)) - p.ln()).abs() <= 1e-5 * (1.0 + p.ln().abs()));
            }
        }
    }
    let zero = NasgMixture::<4>::from_lobes(
        &[NasgLobe::new(Vec3::Z, Vec3::X, 1.0, 1.0, 0.1); 4],
        &[0.0; 4],
    );
    assert_eq!(zero.weight, [0.25; 4]);
    let c = zero
        .with_selection_probability(f32::NAN)
        .selection_probability();
    assert_eq!(c, 0.5);
    assert_eq!(
        zero.with_selection_probability(7.0).selection_probability(),
        1.0
    );
}

/// `repr(C)` + `Pod`: 15 K + 1 floats, no padding; a lobe is 14 floats.
#[test]
fn pod_layout() {
    assert_eq!(std::mem::size_of::<NasgLobe>(), 14 * 4);
    assert_eq!(std::mem::size_of::<NasgMixture<8>>(), (15 * 8 + 1) * 4);
    assert_eq!(std::mem::size_of::<NasgMixture<3>>(), (15 * 3 + 1) * 4);
    assert_eq!(std::mem::align_of::<NasgMixture<8>>(), 4);
}
