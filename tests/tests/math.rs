//! The math shim, frames and sphere warps: accuracy against f64 references.

use glam::{DVec3, Vec3};
use guiding_core::frame::{normalize_or, Frame};
use guiding_core::math;
use guiding_core::sphere::{
    one_minus_cos_angle, square_to_uniform_sphere, uniform_sphere_to_square,
};
use guiding_tests::rng::Pcg32;

/// Distance in units in the last place between two finite f32 of equal sign.
fn ulp_distance(a: f32, b: f32) -> u32 {
    (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32
}

#[test]
fn exp_is_within_two_ulp_of_correctly_rounded() {
    let mut rng = Pcg32::new(1, 1);
    let mut worst = 0;
    for i in 0..2_000_000 {
        // Dense sweep plus random points over the whole normal-output range.
        let x = if i < 1_000_000 {
            -87.0 + 175.5 * (i as f32 / 1_000_000.0)
        } else {
            rng.uniform(-87.3, 88.7)
        };
        let reference = (x as f64).exp() as f32;
        if reference < f32::MIN_POSITIVE || !reference.is_finite() {
            continue;
        }
        let d = ulp_distance(math::exp(x), reference);
        worst = worst.max(d);
        assert!(
            d <= 2,
            "exp({x}) = {} vs {reference} ({d} ulp)",
            math::exp(x)
        );
    }
    println!("worst exp error: {worst} ulp");
}

#[test]
fn exp_edges() {
    assert_eq!(math::exp(0.0), 1.0);
    assert_eq!(math::exp(-100.0), 0.0);
    assert_eq!(math::exp(f32::NEG_INFINITY), 0.0);
    assert_eq!(math::exp(-1e30), 0.0);
    assert_eq!(math::exp(100.0), f32::INFINITY);
    assert_eq!(math::exp(f32::INFINITY), f32::INFINITY);
    assert!(math::exp(f32::NAN).is_nan());
    // Subnormal inputs are just zero.
    assert_eq!(math::exp(1e-40), 1.0);
    assert_eq!(math::exp(-1e-40), 1.0);
}

#[test]
fn sigmoid_and_sanitize_are_total() {
    for x in [
        f32::NEG_INFINITY,
        -1e30,
        -100.0,
        -1.0,
        0.0,
        1.0,
        100.0,
        1e30,
        f32::INFINITY,
    ] {
        let s = math::sigmoid(x);
        assert!((0.0..=1.0).contains(&s), "sigmoid({x}) = {s}");
        let reference = 1.0 / (1.0 + (-(x as f64)).exp());
        assert!((s as f64 - reference).abs() <= 1e-7 * reference.max(1e-30) + 1e-45);
    }
    assert_eq!(math::sanitize(f32::NAN, 10.0), 0.0);
    assert_eq!(math::sanitize(f32::INFINITY, 10.0), 10.0);
    assert_eq!(math::sanitize(f32::NEG_INFINITY, 10.0), -10.0);
    assert_eq!(math::sanitize(3.0, 10.0), 3.0);
}

#[test]
fn x_over_one_minus_exp_neg_matches_f64() {
    for x in [
        0.0f32, 1e-38, 1e-30, 1e-10, 1e-4, 0.01, 0.5, 1.0, 10.0, 100.0, 1e6,
    ] {
        let got = math::x_over_one_minus_exp_neg(x) as f64;
        let xd = x as f64;
        let want = if xd < 1e-12 {
            1.0 + xd / 2.0
        } else {
            xd / -(-xd).exp_m1()
        };
        assert!(
            (got - want).abs() <= 2e-7 * want,
            "x = {x}: {got} vs {want}"
        );
    }
}

#[test]
fn frames_are_orthonormal_everywhere() {
    let mut rng = Pcg32::new(2, 1);
    let mut normals: Vec<Vec3> = (0..100_000)
        .map(|_| square_to_uniform_sphere(rng.next_vec2()))
        .collect();
    // The seams and poles of the branchless construction.
    normals.extend([
        Vec3::Z,
        -Vec3::Z,
        Vec3::X,
        -Vec3::X,
        Vec3::Y,
        normalize_or(Vec3::new(1e-20, 0.0, -1.0), Vec3::Z),
        normalize_or(Vec3::new(1.0, 1.0, -1e-30), Vec3::Z),
        normalize_or(Vec3::new(0.0, 1e-3, -1.0), Vec3::Z),
    ]);
    for n in normals {
        let f = Frame::from_z(n);
        for (a, b) in [(f.x, f.y), (f.y, f.z), (f.x, f.z)] {
            assert!(a.dot(b).abs() < 1e-6, "{n}: not orthogonal");
        }
        for v in [f.x, f.y, f.z] {
            assert!((v.length() - 1.0).abs() < 1e-6, "{n}: not unit");
        }
        assert!(f.x.cross(f.y).dot(f.z) > 0.999, "{n}: not right-handed");
    }
}

#[test]
fn one_minus_cos_angle_keeps_relative_precision_near_the_axis() {
    let mut rng = Pcg32::new(3, 1);
    for _ in 0..20_000 {
        let axis = square_to_uniform_sphere(rng.next_vec2());
        // Angles from 1e-6 to π, log-uniform.
        let theta = 1e-6f64 * (std::f64::consts::PI / 1e-6).powf(rng.next_f64());
        let f = Frame::from_z(axis);
        let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
        let ad = DVec3::new(axis.x as f64, axis.y as f64, axis.z as f64);
        let (fx, fy) = (f.x.as_dvec3(), f.y.as_dvec3());
        let d64 = ad * theta.cos() + (fx * phi.cos() + fy * phi.sin()) * theta.sin();
        let d = d64.as_vec3();
        // Reference: exact 1 − cos of the angle between the f32 inputs, in f64.
        let (a64, dd) = (ad, d.as_dvec3());
        let cross = a64.cross(dd).length() / dd.length();
        let dot = a64.dot(dd) / dd.length();
        let reference = if dot > 0.0 {
            cross * cross / (1.0 + dot)
        } else {
            1.0 - dot
        };
        let got = one_minus_cos_angle(axis, d) as f64;
        // Error budget: the f32 cross product cancels near the axis, leaving an
        // absolute error of ~2ε per component against |axis × d| = sin θ, so
        // the relative error of sin²θ is ≤ ~4ε / sin θ; plus a few ε for the
        // remaining products, the division and the f32 axis being unit only
        // to ~ε.
        let eps = f32::EPSILON as f64;
        let bound = 8.0 * eps * (1.0 + 1.0 / theta.sin());
        assert!(
            (got - reference).abs() <= bound * reference,
            "θ = {theta:e}: {got:e} vs {reference:e}"
        );
    }
    assert_eq!(one_minus_cos_angle(Vec3::Z, Vec3::ZERO), 2.0);
    assert_eq!(one_minus_cos_angle(Vec3::Z, Vec3::splat(f32::NAN)), 2.0);
    assert_eq!(
        one_minus_cos_angle(Vec3::Z, Vec3::splat(f32::INFINITY)),
        2.0
    );
}

#[test]
fn uniform_sphere_warp_round_trips() {
    let mut rng = Pcg32::new(4, 1);
    for _ in 0..100_000 {
        let u = rng.next_vec2();
        let d = square_to_uniform_sphere(u);
        assert!((d.length() - 1.0).abs() < 1e-6);
        let back = uniform_sphere_to_square(d);
        // Near the poles φ is ill-conditioned: compare in u only where sin θ is not tiny.
        let sin_theta = (1.0 - d.z * d.z).max(0.0).sqrt();
        if sin_theta > 1e-3 && u.x > 1e-5 && u.x < 1.0 - 1e-5 {
            assert!((back.x - u.x).abs() < 1e-5 / sin_theta, "{u} → {back}");
        }
        assert!((back.y - u.y).abs() < 1e-6, "{u} → {back}");
    }
    assert_eq!(uniform_sphere_to_square(Vec3::Z).y, 0.0);
    assert_eq!(uniform_sphere_to_square(-Vec3::Z).y, 1.0);
}

#[test]
fn copysign_matches_std() {
    let values = [
        0.0f32,
        -0.0,
        1.5,
        -2.5,
        f32::INFINITY,
        f32::NEG_INFINITY,
        1e-40,
        f32::MAX,
    ];
    for x in values {
        for s in values {
            assert_eq!(
                math::copysign(x, s).to_bits(),
                x.copysign(s).to_bits(),
                "{x} {s}"
            );
        }
        assert!(math::copysign(f32::NAN, x).is_nan());
    }
}

// ---------------------------------------------------------------------------
// The inlined, branch-free twins of libm (ln, ln_1p, expm1, sin/cos, atan2)
// and the half-line exp/expm1 of the lobe loops, against f64 references.

/// Error of `got` against the exact `want`, in ulps of the correctly rounded
/// result (the spacing of f32 at `want`, subnormal spacing at the bottom).
fn ulp_error(got: f32, want: f64) -> f64 {
    let w = want as f32;
    let a = w.abs();
    let ulp = if a < f32::MAX {
        f64::from(f32::from_bits(a.to_bits() + 1)) - f64::from(a)
    } else {
        f64::from(a) - f64::from(f32::from_bits(a.to_bits() - 1))
    };
    (f64::from(got) - want).abs() / ulp
}

/// ≥ 10⁶ inputs in `[lo, hi]` (finite, `lo < hi`): every `step`-th f32 bit
/// pattern of the range (so every binade, subnormals included, is covered
/// evenly) plus uniform random points.
fn sweep(lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut xs = Vec::new();
    // Map f32 to a monotone integer line and walk it.
    let key = |x: f32| {
        let b = x.to_bits() as i64;
        if b < 0x8000_0000 {
            b
        } else {
            0x8000_0000 - b
        }
    };
    let unkey = |k: i64| {
        if k >= 0 {
            f32::from_bits(k as u32)
        } else {
            f32::from_bits((0x8000_0000 - k) as u32)
        }
    };
    let (a, b) = (key(lo), key(hi));
    let step = ((b - a) / 1_000_000).max(1);
    let mut k = a;
    while k <= b {
        xs.push(unkey(k));
        k += step;
    }
    xs.push(hi);
    let mut rng = Pcg32::new(seed, 7);
    for _ in 0..200_000 {
        xs.push(rng.uniform(lo, hi));
    }
    xs
}

/// Checks `f` against `reference` on `xs` wherever the reference is a
/// finite f32 with |result| ≥ `floor` (below it, absolute error ≤
/// `abs_tol`); returns the worst ulp error.
fn check_ulps(
    name: &str,
    xs: &[f32],
    f: impl Fn(f32) -> f32,
    reference: impl Fn(f64) -> f64,
    max_ulps: f64,
    floor: f64,
    abs_tol: f64,
) -> f64 {
    let mut worst = 0.0f64;
    for &x in xs {
        let want = reference(f64::from(x));
        let got = f(x);
        if !(want as f32).is_finite() {
            continue;
        }
        if want.abs() < floor {
            let err = (f64::from(got) - want).abs();
            assert!(err <= abs_tol, "{name}({x:e}) = {got:e} vs {want:e}");
            continue;
        }
        let e = ulp_error(got, want);
        worst = worst.max(e);
        assert!(
            e <= max_ulps,
            "{name}({x:e}) = {got:e} vs {want:e} ({e:.2} ulp)"
        );
    }
    println!("{name}: worst {worst:.3} ulp over {} points", xs.len());
    worst
}

#[test]
fn ln_inline_is_within_two_ulp() {
    let xs = sweep(f32::from_bits(1), f32::MAX, 11);
    check_ulps("ln_inline", &xs, math::ln_inline, f64::ln, 2.0, 0.0, 0.0);
    // Agrees with libm's ln to the same accuracy, and at the special values.
    assert_eq!(math::ln_inline(1.0), 0.0);
    assert_eq!(math::ln_inline(0.0), f32::NEG_INFINITY);
    assert_eq!(math::ln_inline(-0.0), f32::NEG_INFINITY);
    assert_eq!(math::ln_inline(f32::INFINITY), f32::INFINITY);
    assert!(math::ln_inline(-1.0).is_nan());
    assert!(math::ln_inline(f32::NEG_INFINITY).is_nan());
    assert!(math::ln_inline(f32::NAN).is_nan());
    assert!((math::ln_inline(f32::MIN_POSITIVE) - (-87.336_55)).abs() < 1e-5);
}

/// `ln(1 + x)` within `max_ulps` of f64 over both sides of 0, and its special values.
fn check_ln_1p(name: &str, f: fn(f32) -> f32, max_ulps: f64) {
    let mut xs = sweep(-1.0 + f32::EPSILON / 2.0, -f32::from_bits(1), 12);
    xs.extend(sweep(f32::from_bits(1), f32::MAX, 13));
    check_ulps(name, &xs, f, f64::ln_1p, max_ulps, 0.0, 0.0);
    assert_eq!(f(-1.0), f32::NEG_INFINITY, "{name}");
    assert_eq!(f(f32::INFINITY), f32::INFINITY, "{name}");
    assert!(f(-1.5).is_nan(), "{name}");
    assert!(f(f32::NEG_INFINITY).is_nan(), "{name}");
    assert!(f(f32::NAN).is_nan(), "{name}");
    assert_eq!(f(0.0).to_bits(), 0.0f32.to_bits(), "{name}");
    assert_eq!(f(-0.0).to_bits(), (-0.0f32).to_bits(), "{name}");
    assert_eq!(f(1e-40), 1e-40, "{name}");
}

/// The SPIR-V `ln_1p` (no compensated sum for a shader compiler to fold).
#[test]
fn ln_1p_series_is_within_three_ulp() {
    check_ln_1p("ln_1p_series", math::ln_1p_series, 3.0);
}

#[test]
fn ln_1p_inline_is_within_two_ulp() {
    check_ln_1p("ln_1p_inline", math::ln_1p_inline, 2.0);
}

#[test]
fn expm1_inline_is_within_two_ulp() {
    let mut xs = sweep(-104.0, -f32::from_bits(1), 14);
    xs.extend(sweep(f32::from_bits(1), 88.7, 15));
    check_ulps(
        "expm1_inline",
        &xs,
        math::expm1_inline,
        f64::exp_m1,
        2.0,
        0.0,
        0.0,
    );
    let neg: Vec<f32> = xs.iter().copied().filter(|&x| x <= 0.0).collect();
    check_ulps(
        "expm1_nonpositive",
        &neg,
        math::expm1_nonpositive,
        f64::exp_m1,
        2.0,
        0.0,
        0.0,
    );
    for f in [math::expm1_inline, math::expm1_nonpositive] {
        assert_eq!(f(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(f(-0.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(f(-1e-40), -1e-40);
        assert_eq!(f(-1e30), -1.0);
        assert_eq!(f(f32::NEG_INFINITY), -1.0);
        assert!(f(f32::NAN).is_nan());
    }
    assert_eq!(math::expm1_inline(88.8), f32::INFINITY);
    assert_eq!(math::expm1_inline(f32::INFINITY), f32::INFINITY);
    assert_eq!(math::expm1_nonpositive(5.0), 0.0);
}

#[test]
fn exp_nonpositive_is_within_two_ulp() {
    let xs = sweep(-87.3, -f32::from_bits(1), 16);
    check_ulps(
        "exp_nonpositive",
        &xs,
        math::exp_nonpositive,
        f64::exp,
        2.0,
        0.0,
        0.0,
    );
    // Agrees with `exp` within its own tolerance everywhere on the half-line.
    for &x in &xs {
        let (a, b) = (math::exp_nonpositive(x), math::exp(x));
        assert!(ulp_distance(a, b) <= 2, "{x}: {a} vs {b}");
    }
    assert_eq!(math::exp_nonpositive(0.0), 1.0);
    assert_eq!(math::exp_nonpositive(-0.0), 1.0);
    assert_eq!(math::exp_nonpositive(3.0), 1.0);
    assert_eq!(math::exp_nonpositive(-87.5), 0.0);
    assert_eq!(math::exp_nonpositive(-1e30), 0.0);
    assert_eq!(math::exp_nonpositive(f32::NEG_INFINITY), 0.0);
    assert!(math::exp_nonpositive(f32::NAN).is_nan());
}

#[test]
fn sin_cos_turns_matches_f64() {
    // Every f32 in [−4, 4] is too many; a dense sweep of the bit patterns
    // (all binades down to subnormals) plus random points.
    let mut xs = sweep(-4.0, -f32::from_bits(1), 17);
    xs.extend(sweep(0.0, 4.0, 18));
    let tau = std::f64::consts::TAU;
    // Within 2 ulp of the result, or 10⁻⁷ absolute where the result is
    // below 2⁻¹⁰ (near its zeros, where ulps shrink but the argument's own
    // resolution does not).
    for (k, reference) in [f64::sin, f64::cos].into_iter().enumerate() {
        check_ulps(
            &format!("sin_cos_turns.{k}"),
            &xs,
            |u| {
                let (s, c) = math::sin_cos_turns(u);
                [s, c][k]
            },
            |u| reference(tau * u),
            2.0,
            1.0 / 1024.0,
            1e-7,
        );
    }
    // Exact reduction: the quarter turns are exact.
    for (u, s, c) in [
        (0.0, 0.0, 1.0),
        (0.25, 1.0, 0.0),
        (0.5, 0.0, -1.0),
        (0.75, -1.0, 0.0),
        (1.0, 0.0, 1.0),
        (-0.25, -1.0, 0.0),
    ] {
        let (gs, gc) = math::sin_cos_turns(u);
        assert!(gs == s && gc == c, "{u}: ({gs}, {gc})");
    }
    assert_eq!(math::sin_cos_turns(1e20), (0.0, 1.0));
    for u in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let (s, c) = math::sin_cos_turns(u);
        assert!(s.is_nan() && c.is_nan());
    }
}

#[test]
fn atan2_turns_matches_f64() {
    let mut rng = Pcg32::new(19, 7);
    let tau = std::f64::consts::TAU;
    let mut worst = 0.0f64;
    let mut check = |y: f32, x: f32| {
        let got = math::atan2_turns(y, x);
        let want = f64::from(y).atan2(f64::from(x)) / tau;
        // 4·10⁻⁹ absolute or 3 ulp of the result.
        let err = (f64::from(got) - want).abs();
        let e = if err <= 4e-9 {
            0.0
        } else {
            ulp_error(got, want)
        };
        worst = worst.max(e);
        assert!(
            err <= 4e-9 || e <= 3.0,
            "atan2_turns({y:e}, {x:e}) = {got:e} vs {want:e}"
        );
    };
    // Angles dense on the circle at magnitudes from subnormal to huge.
    for i in 0..1_000_000 {
        let phi = tau * (i as f64 + 0.5) / 1e6;
        let r = 10f64.powf(-40.0 + 78.0 * rng.next_f64());
        check((r * phi.sin()) as f32, (r * phi.cos()) as f32);
    }
    // Independent random bit patterns.
    for _ in 0..500_000 {
        let y = f32::from_bits(rng.next_u32());
        let x = f32::from_bits(rng.next_u32());
        if y.is_finite() && x.is_finite() {
            check(y, x);
        }
    }
    println!("atan2_turns: worst {worst:.3} ulp beyond 4e-9");
    // IEEE atan2 conventions for zeros and infinities.
    let inf = f32::INFINITY;
    for (y, x, want) in [
        (0.0f32, 0.0f32, 0.0f32),
        (-0.0, 0.0, -0.0),
        (0.0, -0.0, 0.5),
        (-0.0, -0.0, -0.5),
        (0.0, -1.0, 0.5),
        (-0.0, -1.0, -0.5),
        (1.0, 0.0, 0.25),
        (-1.0, 0.0, -0.25),
        (inf, inf, 0.125),
        (-inf, -inf, -0.375),
        (1.0, inf, 0.0),
        (1.0, -inf, 0.5),
        (inf, 1.0, 0.25),
    ] {
        let got = math::atan2_turns(y, x);
        assert!(
            got.to_bits() == want.to_bits() || (got - want).abs() < 1e-7,
            "atan2_turns({y}, {x}) = {got} vs {want}"
        );
    }
    assert!(math::atan2_turns(f32::NAN, 1.0).is_nan());
    assert!(math::atan2_turns(1.0, f32::NAN).is_nan());
}
