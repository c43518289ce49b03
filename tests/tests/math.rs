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
