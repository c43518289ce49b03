//! NASG cases: single lobes over the parameter grid (every extreme of λ, `a`
//! and `ε`), with both the 2-number [`NasgLobe::sample`] and the 3-number
//! [`NasgLobe::sample3`], and random K = 8 mixtures (built from lobes and
//! decoded from raw network outputs).
//!
//! # Grids
//! A lobe's narrowest scale in `s = 1 − cos θ` is `2 / B` with
//! `B = (2λ + 1)(1 + ε + a) − 1` (near the axis, along the narrow tangent `x`,
//! `ln G ≈ −B s / 2`). Lobes with `B < 100` use Mitsuba's uniform grid; sharper
//! ones a [`Warp::ZoomedCap`] in the lobe's own frame with `s0 = 2/B` and
//! `phi_stretch = √c`, `c = √((1 + ε + a)/(1 + ε))`.
//!
//! `c` itself would make the columns the NASG azimuth CDF, each holding the
//! same share of the φ marginal. But the density is not separable: near the
//! axis, in the columns around the narrow tangent (φ = 0, π), it varies on
//! the scale `1/c` in the grid's `ψ = π(w − ½)`, while those columns are
//! `~20/c` wide, and the 6-point rule then misses ~30% of a cell
//! (`quadrature_z ≈ 5` at `a = 10⁵`; a 64× finer quadrature agrees with the
//! samples, so the sampler is right). `√c` halves the dynamic range on both
//! sides: the ridge at φ = ±π/2 (width `~1/c` in φ) and the narrow-tangent
//! columns both stay resolved (measured `quadrature_z ≤ 0.09` for `a` up to
//! 10⁵, against 5–7 with `c`).
//!
//! Mixtures (`B ≤ ~10³`) use a uniform grid whose poles avoid every lobe with
//! `B > 20`.
//!
//! # Frames, and the `f32` bound behind them
//! The generic runner requires `|pdf_sample − pdf(d)| ≤ 10⁻⁴ pdf(d)`. A lobe
//! sample is computed in the lobe frame and rotated to the world, and `pdf`
//! rotates it back; with a general rotation each local coordinate comes back
//! with an absolute error `δ ≈ 2 ulp(1) ≈ 1.2·10⁻⁷`, so
//! `|Δ ln p| ≈ δ · |∇_ω ln p|`. Two places make `|∇_ω ln p|` large:
//! - near the axis `ln p ≈ −B s/2 + const`, so `|∇_ω ln p| ≈ √(2 B σ)` at a
//!   sample with `B s/2 = σ` (σ ≲ 15 for 10⁶ samples): `|Δ ln p| ≲ 6.6·10⁻⁷ √B`
//!   (measured worst over 10⁶ samples: ~1.5·10⁻⁷ √B);
//! - near the antipode, for `a > 0`, `ln G ∋ a cos²φ ln t`, whose azimuthal
//!   gradient is `≈ √(a |ln t| / t)` across the ridge at `φ = ±π/2`: unbounded
//!   as `t → 0`. It matters only where samples reach the antipode, i.e. for
//!   small λ (the antipode has relative density `e^{−2λ}`).
//!
//! Hence random frames are used only where `B ≤ 4·10⁴` (bound `1.3·10⁻⁴`,
//! measured ≤ 4·10⁻⁵) and `a ≤ 1` or `λ ≥ 5` ([`rotation_safe`]); every other
//! lobe gets a frame made of signed world axes, where the rotation is exact
//! and the measured mismatch is ≤ 8·10⁻⁶ for every parameter combination
//! (including λ = a = 10⁵, a lobe ~10⁻⁵ rad wide, ~100 `f32` ulps). That is
//! not a weakness of the sampler: in a rotated frame such a lobe is narrower
//! than what `f32` world directions resolve, and no implementation can make
//! `pdf(round(d))` match the density of the unrounded `d` there. Mixture
//! samples report `pdf(d)` itself, so they are exact in any frame.

use super::{seeded_cases, Case};
use crate::chi2::{axis_avoiding, Warp};
use crate::rng::Pcg32;
use crate::SphereDistribution;
use glam::{DVec3, Vec3};
use guiding_core::lobe::nasg::NasgLobe;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::sphere::square_to_uniform_sphere;

/// Lobes per mixture in the cases.
pub const K: usize = 8;

/// A single NASG lobe sampled with two random numbers ([`NasgLobe::sample`]).
pub struct LobeDist(pub NasgLobe);

/// A single NASG lobe sampled with three random numbers ([`NasgLobe::sample3`]).
pub struct Lobe3Dist(pub NasgLobe);

impl SphereDistribution for Lobe3Dist {
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
        let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let s = self.0.sample3(u);
        (s.direction, s.pdf)
    }
    fn pdf(&self, direction: Vec3) -> f32 {
        self.0.pdf(direction)
    }
}

/// A K-lobe NASG mixture.
pub struct MixtureDist(pub NasgMixture<K>);

sphere_distribution_of_sampler!(LobeDist, MixtureDist);

/// `B = (2λ + 1)(1 + ε + a) − 1`: `2/B` is the lobe's narrowest scale in
/// `1 − cos θ` (see the module docs).
#[must_use]
pub fn sharpness(lobe: &NasgLobe) -> f64 {
    let (l, a, e) = (
        f64::from(lobe.lambda),
        f64::from(lobe.a),
        f64::from(lobe.epsilon),
    );
    (2.0 * l + 1.0) * (1.0 + e + a) - 1.0
}

/// Whether a lobe with these parameters keeps the sample/pdf mismatch below
/// 10⁻⁴ under a general rotation (see the module docs for the bound).
#[must_use]
pub fn rotation_safe(lambda: f32, a: f32, epsilon: f32) -> bool {
    let b = (2.0 * f64::from(lambda) + 1.0) * (1.0 + f64::from(epsilon) + f64::from(a)) - 1.0;
    b <= 4e4 && (a <= 1.0 || lambda >= 5.0)
}

/// Uniformly distributed unit vector.
#[must_use]
pub fn random_direction(rng: &mut Pcg32) -> Vec3 {
    square_to_uniform_sphere(rng.next_vec2())
}

/// Lobe with a uniformly random frame (NASG eq. 13 Euler angles: α uniform,
/// `cos β` uniform, γ uniform).
#[must_use]
pub fn random_frame_lobe(rng: &mut Pcg32, lambda: f32, a: f32, epsilon: f32) -> NasgLobe {
    let alpha = rng.uniform(0.0, core::f32::consts::TAU);
    let beta = rng.uniform(-1.0, 1.0).clamp(-1.0, 1.0).acos();
    let gamma = rng.uniform(0.0, core::f32::consts::TAU);
    NasgLobe::from_euler(alpha, beta, gamma, lambda, a, epsilon)
}

/// Frames made of signed world axes `(z, x)`: exact in `f32`.
const AXIS_FRAMES: [(Vec3, Vec3); 6] = [
    (Vec3::Z, Vec3::X),
    (Vec3::NEG_Y, Vec3::Z),
    (Vec3::X, Vec3::NEG_Y),
    (Vec3::NEG_Z, Vec3::Y),
    (Vec3::Y, Vec3::NEG_X),
    (Vec3::NEG_X, Vec3::NEG_Z),
];

/// The grid for a single lobe (see the module docs).
#[must_use]
pub fn lobe_warp(lobe: &NasgLobe) -> Warp {
    let b = sharpness(lobe);
    if b < 100.0 {
        Warp::uniform()
    } else {
        let (a, e) = (f64::from(lobe.a), f64::from(lobe.epsilon));
        let f = lobe.frame();
        Warp::zoomed(
            f.z.as_dvec3(),
            f.x.as_dvec3(),
            2.0 / b,
            ((1.0 + e + a) / (1.0 + e)).powf(0.25),
        )
    }
}

/// Random mixture built with [`NasgMixture::from_lobes`]: λ log-uniform in
/// `[10⁻², 50]`, `a` log-uniform in `[10⁻³, 10]`, ε log-uniform in
/// `[10⁻⁶, 1]`, random frames, weights uniform in `(0, 1]`.
#[must_use]
pub fn random_mixture(rng: &mut Pcg32) -> NasgMixture<K> {
    let lobes: [NasgLobe; K] = core::array::from_fn(|_| {
        let lambda = 10f32.powf(rng.uniform(-2.0, 50f32.log10()));
        let a = 10f32.powf(rng.uniform(-3.0, 1.0));
        let epsilon = 10f32.powf(rng.uniform(-6.0, 0.0));
        random_frame_lobe(rng, lambda, a, epsilon)
    });
    let weights: [f32; K] = core::array::from_fn(|_| 1.0 - rng.next_f32());
    NasgMixture::from_lobes(&lobes, &weights).with_selection_probability(rng.next_f32())
}

/// Random raw network output whose decoded mixture has λ log-uniform in
/// `[10⁻², 50]` and `a` in `[e⁻⁵, 9]`: logits in `[−2, 2]`, raw angles in
/// `[−4, 4]` (before the sigmoids).
#[must_use]
pub fn random_raw(rng: &mut Pcg32) -> [[f32; NASG_RAW_PER_LOBE]; K] {
    core::array::from_fn(|_| {
        [
            rng.uniform(-2.0, 2.0),
            rng.uniform(-2.0 * core::f32::consts::LN_10, 50f32.ln()),
            rng.uniform(-5.0, 9f32.ln()),
            rng.uniform(-4.0, 4.0),
            rng.uniform(-4.0, 4.0),
            rng.uniform(-4.0, 4.0),
        ]
    })
}

/// Uniform grid whose poles avoid the lobes of `m` with `B > 20`.
#[must_use]
pub fn mixture_warp(m: &NasgMixture<K>) -> Warp {
    let sharp: Vec<DVec3> = (0..K)
        .filter(|&k| m.weight[k] > 0.0 && sharpness(&m.lobe(k)) > 20.0)
        .map(|k| m.lobe(k).frame().z.as_dvec3())
        .collect();
    Warp::uniform_about(axis_avoiding(&sharp))
}

fn label(x: f32) -> String {
    if x == 0.0 {
        "0".into()
    } else if (0.01..1000.0).contains(&x) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

fn lobe_case(name: String, lobe: NasgLobe, three: bool) -> Case {
    Case {
        name,
        warp: lobe_warp(&lobe),
        dist: if three {
            Box::new(Lobe3Dist(lobe))
        } else {
            Box::new(LobeDist(lobe))
        },
    }
}

fn mixture_case(name: String, m: NasgMixture<K>) -> Case {
    Case {
        name,
        warp: mixture_warp(&m),
        dist: Box::new(MixtureDist(m)),
    }
}

/// The parameter grid of the single-lobe cases.
pub const LAMBDAS: [f32; 8] = [1e-4, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5];
/// Anisotropies of the single-lobe cases.
pub const ANISOTROPIES: [f32; 5] = [0.0, 0.5, 10.0, 1e3, 1e5];
/// `ε` values, cycled over the grid so that each appears with every λ.
pub const EPSILONS: [f32; 4] = [1e-6, 0.1, 1.0, 1e-3];

/// Every case of this family.
#[must_use]
pub fn cases() -> Vec<Case> {
    let mut cases = Vec::new();
    let mut rng = Pcg32::new(0x4a56_0001, 0);
    let mut axis_frame = 0;
    let mut make = |rng: &mut Pcg32, lambda: f32, a: f32, epsilon: f32| {
        if rotation_safe(lambda, a, epsilon) {
            (random_frame_lobe(rng, lambda, a, epsilon), "random-frame")
        } else {
            let (z, x) = AXIS_FRAMES[axis_frame % AXIS_FRAMES.len()];
            axis_frame += 1;
            (NasgLobe::new(z, x, lambda, a, epsilon), "axis-frame")
        }
    };
    // 8 × 5 = 40 lobes over the full (λ, a) grid, 2-number sampling; ε cycles
    // through its extremes.
    let mut i = 0;
    for &lambda in &LAMBDAS {
        for &a in &ANISOTROPIES {
            let epsilon = EPSILONS[i % EPSILONS.len()];
            i += 1;
            let (lobe, frame) = make(&mut rng, lambda, a, epsilon);
            cases.push(lobe_case(
                format!(
                    "nasg/lobe/lambda={}/a={}/eps={}/{frame}",
                    label(lambda),
                    label(a),
                    label(epsilon)
                ),
                lobe,
                false,
            ));
        }
    }
    // 3-number sampling, including the four (λ, a) corners with both ε
    // extremes.
    for &(lambda, a, epsilon) in &[
        (1e-4, 0.0, 1e-6),
        (1e-4, 1e5, 1e-6),
        (1e-4, 1e5, 1.0),
        (1e5, 0.0, 1.0),
        (1e5, 1e5, 1e-6),
        (1e5, 1e5, 1.0),
        (1.0, 0.5, 0.1),
        (10.0, 10.0, 1e-3),
        (100.0, 1e3, 1e-6),
        (0.1, 1e3, 1.0),
    ] {
        let (lobe, frame) = make(&mut rng, lambda, a, epsilon);
        cases.push(lobe_case(
            format!(
                "nasg/lobe3/lambda={}/a={}/eps={}/{frame}",
                label(lambda),
                label(a),
                label(epsilon)
            ),
            lobe,
            true,
        ));
    }
    // The 2-number corners with ε = 1 (the grid above has them with other ε).
    for &(lambda, a) in &[(1e-4, 1e5), (1e5, 1e5), (1e5, 0.0)] {
        let (lobe, frame) = make(&mut rng, lambda, a, 1.0);
        cases.push(lobe_case(
            format!(
                "nasg/lobe/lambda={}/a={}/eps=1/{frame}-corner",
                label(lambda),
                label(a)
            ),
            lobe,
            false,
        ));
    }
    // Axes exactly at ±z with a degenerate (parallel) tangent hint: the
    // Gram–Schmidt fallback of `NasgLobe::new`.
    cases.push(lobe_case(
        "nasg/lobe/lambda=10/a=10/axis=+z/parallel-hint".into(),
        NasgLobe::new(Vec3::Z, Vec3::Z, 10.0, 10.0, 1e-3),
        false,
    ));
    cases.push(lobe_case(
        "nasg/lobe/lambda=1/a=0.5/axis=-z/zero-hint".into(),
        NasgLobe::new(Vec3::NEG_Z, Vec3::ZERO, 1.0, 0.5, 1e-3),
        false,
    ));

    cases.extend(seeded_cases(
        "nasg/mixture/from-lobes",
        3,
        11,
        |name, rng| mixture_case(name, random_mixture(rng)),
    ));
    cases.extend(seeded_cases("nasg/mixture/decoded", 3, 12, |name, rng| {
        let raw = random_raw(rng);
        let selection = rng.uniform(-3.0, 3.0);
        mixture_case(name, NasgMixture::decode(&raw, selection))
    }));
    cases
}
