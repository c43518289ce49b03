//! The vectorised NPM loss gradient (`model::vmf_gradient`) against the
//! per-sample reference `VmfMixture::grad_log_pdf`, over the whole raw
//! output domain, with a rounding bound that a slightly wrong input breaks.

use guiding_core::glam::Vec3;
use guiding_core::mixture::vmf::{
    VmfMixture, VMF_LOG_KAPPA_MAX, VMF_LOG_KAPPA_MIN, VMF_RAW_PER_LOBE,
};
use guiding_core::model::npm::{NPM_LOBES, NPM_OUTPUTS};
use guiding_core::model::vmf_gradient::{grad_log_pdf_vmf_batch, grad_log_pdf_vmf_portable};
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::{rows_with_specials, Pcg32};

type Row = [f32; NPM_OUTPUTS];

/// Raw rows: moderate values, every fifth row with special values (NaN,
/// ±∞, ±10³⁰, the `ln κ` clamp edges, subnormals) in some entries.
fn rows(n: usize, seed: u64) -> Vec<Row> {
    let specials = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        1e30,
        -1e30,
        VMF_LOG_KAPPA_MAX,
        VMF_LOG_KAPPA_MIN,
        11.0,
        -11.0,
        60.0,
        -60.0,
        1e-40,
        -0.0,
    ];
    let mut rng = Pcg32::new(seed, 11);
    rows_with_specials(n, &mut rng, (5, 3), &specials, |rng, _| {
        rng.uniform(-9.0, 9.0)
    })
}

/// Directions: uniform on the sphere, some not unit length, a few
/// degenerate (zero, NaN: both kernels fall back to `+z`).
fn directions(n: usize, seed: u64) -> Vec<Vec3> {
    let mut rng = Pcg32::new(seed, 12);
    (0..n)
        .map(|i| match i % 17 {
            5 => Vec3::ZERO,
            11 => Vec3::splat(f32::NAN),
            13 => 3.5 * square_to_uniform_sphere(rng.next_vec2()),
            _ => square_to_uniform_sphere(rng.next_vec2()),
        })
        .collect()
}

fn as_rows(y: &Row) -> [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] {
    std::array::from_fn(|k| std::array::from_fn(|r| y[k * VMF_RAW_PER_LOBE + r]))
}

/// κ of lobe `k` as the decoder forms it.
fn kappa(y: &Row, k: usize) -> f32 {
    let r = y[k * VMF_RAW_PER_LOBE + 1];
    let r = if r.is_nan() { 0.0 } else { r };
    r.clamp(VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX).exp()
}

/// Worst `|batched − reference| / bound` over every output (and the log
/// pdf), the reference evaluated at `reference_dir(i)`.
///
/// The bound, from rounding: the two kernels differ only in `ln` and
/// `expm1` (each within 2 ulp of the true value, so ≤ 4 ulp apart), whose
/// results (`|ln|` ≤ 16 here) enter the log terms `ln w_k + ln norm_k −
/// κ_k t_k`. A difference there may also flip the rounding of that sum,
/// one ulp of its magnitude `≤ T = 16 + 2 max κ`. So the log terms, and
/// with them `ln q`, differ by at most `δ = 2⁻²⁴ (64 · 16 + 4 T)` absolute,
/// and the responsibilities `r_k` and weights `w_k` (in `[0, 1]`) by a
/// relative `δ` (`e^δ − 1 ≈ δ`). Per output: `r − w`: `2δ`; the `κ` entry
/// `r (∂ ln f/∂κ) κ` with `|∂ ln f/∂κ| ≤ 1/κ + 2/(e^{2κ} − 1) + 2`:
/// `δ (2 + 4κ) + 2⁻²⁰ (1 + 2κ)` (the last term for the `expm1` difference
/// amplified by the cancellation `1/κ − 2/(e^{2κ} − 1)`, ≤ 16 ulp of its
/// terms); the mean entries `r κ ω·∂μ` with `|∂μ| ≤ π/2`: `δ κ π/2`;
/// `ln q`: `δ`.
fn worst_ratio(ys: &[Row], dirs: &[Vec3], reference_dir: impl Fn(usize) -> Vec3) -> f64 {
    let n = ys.len();
    let mut fast = vec![[0.0f32; NPM_OUTPUTS]; n];
    let mut portable = vec![[0.0f32; NPM_OUTPUTS]; n];
    let mut lp_fast = vec![0.0f32; n];
    let mut lp_portable = vec![0.0f32; n];
    grad_log_pdf_vmf_batch(ys, dirs, &mut fast, &mut lp_fast);
    grad_log_pdf_vmf_portable(ys, dirs, &mut portable, &mut lp_portable);
    let mut worst = 0.0f64;
    for i in 0..n {
        // The dispatch only widens the lanes: the same bits.
        for j in 0..NPM_OUTPUTS {
            assert_eq!(fast[i][j].to_bits(), portable[i][j].to_bits(), "row {i}");
        }
        assert_eq!(lp_fast[i].to_bits(), lp_portable[i].to_bits(), "row {i}");
        let mut reference = [[0.0f32; VMF_RAW_PER_LOBE]; NPM_LOBES];
        let lp_ref = VmfMixture::grad_log_pdf(&as_rows(&ys[i]), reference_dir(i), &mut reference);
        let max_kappa = (0..NPM_LOBES).map(|k| kappa(&ys[i], k)).fold(0.0, f32::max);
        let t = 16.0 + 2.0 * f64::from(max_kappa);
        let delta = (64.0 * 16.0 + 4.0 * t) * 2f64.powi(-24);
        let mut check = |got: f32, want: f32, bound: f64| {
            assert!(got.is_finite() && want.is_finite(), "row {i}: {got} {want}");
            worst = worst.max(f64::from((got - want).abs()) / bound);
        };
        check(lp_fast[i], lp_ref, delta);
        for k in 0..NPM_LOBES {
            let kap = f64::from(kappa(&ys[i], k));
            let g = &fast[i][k * VMF_RAW_PER_LOBE..(k + 1) * VMF_RAW_PER_LOBE];
            check(g[0], reference[k][0], 2.0 * delta);
            check(
                g[1],
                reference[k][1],
                delta * (2.0 + 4.0 * kap) + 2f64.powi(-20) * (1.0 + 2.0 * kap),
            );
            let mean_bound = delta * kap * std::f64::consts::FRAC_PI_2;
            check(g[2], reference[k][2], mean_bound);
            check(g[3], reference[k][3], mean_bound);
        }
    }
    worst
}

#[test]
fn batched_vmf_gradient_is_the_per_sample_gradient_within_rounding() {
    for n in [1, 7, 8, 9, 32, 1000] {
        let ys = rows(n, n as u64);
        let dirs = directions(n, n as u64);
        let worst = worst_ratio(&ys, &dirs, |i| dirs[i]);
        eprintln!("n {n}: worst error {worst:.3e} of the bound");
        assert!(worst <= 1.0, "n {n}: error {worst} of the rounding bound");
    }
}

/// The bound is tight enough to see a direction off by 10⁻³ rad.
#[test]
fn the_rounding_bound_catches_a_slightly_wrong_direction() {
    let n = 1000;
    let ys = rows(n, 5);
    let dirs = directions(n, 5);
    let tilt = |d: Vec3| {
        let d = d.normalize_or(Vec3::Z);
        let side = d.any_orthonormal_vector();
        (d + 1e-3 * side).normalize()
    };
    let worst = worst_ratio(&ys, &dirs, |i| tilt(dirs[i]));
    eprintln!("tilted: worst error {worst:.3e} of the bound");
    assert!(worst > 10.0, "a tilted direction passed: {worst}");
}
