//! Training records and per-sample losses.

use guiding_core::loss::{kl_weight, nasg_mis_loss, relative_l2, target_value, Target};
use guiding_core::model::QueryPoint;
use guiding_core::sample::{Rejection, TrainingSample};
use guiding_tests::rng::Pcg32;

fn valid_sample() -> TrainingSample {
    TrainingSample::new(
        QueryPoint::new([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8], 0.5),
        [0.6, 0.0, 0.8],
        [1.0, 2.0, 3.0],
        0.25,
        0.3,
        [0.5, 0.5, 0.5],
    )
}

#[test]
fn training_sample_is_96_bytes() {
    assert_eq!(std::mem::size_of::<TrainingSample>(), 96);
}

#[test]
fn validation_rejects_every_bad_field() {
    let ok = valid_sample();
    assert_eq!(ok.validate(), Ok(()));
    type Mutation = Box<dyn Fn(&mut TrainingSample)>;
    let cases: Vec<(Mutation, Rejection)> = vec![
        (Box::new(|s| s.radiance[1] = f32::NAN), Rejection::NonFinite),
        (
            Box::new(|s| s.radiance[0] = f32::INFINITY),
            Rejection::NonFinite,
        ),
        (
            Box::new(|s| s.position[2] = f32::NEG_INFINITY),
            Rejection::NonFinite,
        ),
        (Box::new(|s| s.sample_pdf = f32::NAN), Rejection::NonFinite),
        (Box::new(|s| s.radiance[2] = -1.0), Rejection::Negative),
        (Box::new(|s| s.bsdf_cos[0] = -1e-3), Rejection::Negative),
        (Box::new(|s| s.sample_pdf = 0.0), Rejection::NonPositivePdf),
        (Box::new(|s| s.sample_pdf = -1.0), Rejection::NonPositivePdf),
        (Box::new(|s| s.bsdf_pdf = -1.0), Rejection::NonPositivePdf),
        (
            Box::new(|s| s.wi = [0.0, 0.0, 0.0]),
            Rejection::NonUnitDirection,
        ),
        (
            Box::new(|s| s.wi = [1.0, 1.0, 0.0]),
            Rejection::NonUnitDirection,
        ),
        (
            Box::new(|s| s.normal = [0.0, 0.0, 2.0]),
            Rejection::NonUnitDirection,
        ),
    ];
    for (i, (mutate, want)) in cases.iter().enumerate() {
        let mut s = ok;
        mutate(&mut s);
        assert_eq!(s.validate(), Err(*want), "case {i}");
        assert_eq!(kl_weight(&s, Target::Radiance), 0.0, "case {i}");
    }
    // A zero normal and wo are allowed (radiance models do not need them).
    let mut s = ok;
    s.normal = [0.0; 3];
    s.wo = [0.0; 3];
    assert_eq!(s.validate(), Ok(()));
}

#[test]
fn kl_weights() {
    let s = valid_sample();
    assert!((target_value(&s, Target::Radiance) - 2.0).abs() < 1e-6);
    assert!((target_value(&s, Target::Product) - 1.0).abs() < 1e-6);
    assert!((kl_weight(&s, Target::Radiance) - 8.0).abs() < 1e-5);
    assert!((kl_weight(&s, Target::Product) - 4.0).abs() < 1e-5);
    // Overflowing weights are dropped, not propagated.
    let mut huge = s;
    huge.radiance = [3e38; 3];
    huge.sample_pdf = 1e-30;
    assert_eq!(kl_weight(&huge, Target::Radiance), 0.0);
}

/// f64 reference of the NASG loss as a function of (ln q, c).
fn nasg_loss_f64(w: f64, log_q: f64, c: f64, b: f64, e: f64) -> f64 {
    let q = log_q.exp();
    -w * ((1.0 - e) * (c * q + (1.0 - c) * b).ln() + e * log_q)
}

#[test]
fn nasg_mis_loss_gradients_match_finite_differences() {
    let mut rng = Pcg32::new(5, 1);
    for _ in 0..2000 {
        let w = rng.uniform(0.0, 10.0) as f64;
        let log_q = rng.uniform(-8.0, 4.0) as f64;
        let c = rng.uniform(0.01, 0.99) as f64;
        let b = if rng.next_f32() < 0.2 {
            0.0
        } else {
            rng.uniform(0.0, 5.0) as f64
        };
        let e = 0.2;
        let t = nasg_mis_loss(w as f32, log_q as f32, c as f32, b as f32, e as f32);
        let want = nasg_loss_f64(w, log_q, c, b, e);
        assert!(
            (t.loss as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
            "{t:?} vs {want}"
        );
        let h = 1e-5;
        let d_logq = (nasg_loss_f64(w, log_q + h, c, b, e) - nasg_loss_f64(w, log_q - h, c, b, e))
            / (2.0 * h);
        let d_c = (nasg_loss_f64(w, log_q, c + h, b, e) - nasg_loss_f64(w, log_q, c - h, b, e))
            / (2.0 * h);
        for (got, want) in [
            (t.dloss_dlog_guide as f64, d_logq),
            (t.dloss_dselection as f64, d_c),
        ] {
            let err = (got - want).abs() / got.abs().max(want.abs()).max(1e-3);
            assert!(
                err < 1e-3,
                "{got} vs {want} (w {w}, ln q {log_q}, c {c}, b {b})"
            );
        }
    }
    // Underflowing guide and zero BSDF pdf: no NaN, no information.
    let t = nasg_mis_loss(1.0, f32::NEG_INFINITY, 0.5, 0.0, 0.2);
    assert_eq!(
        (t.loss, t.dloss_dlog_guide, t.dloss_dselection),
        (0.0, 0.0, 0.0)
    );
    let t = nasg_mis_loss(1.0, -200.0, 0.5, 0.3, 0.2);
    assert!(t.loss.is_finite() && t.dloss_dlog_guide.is_finite() && t.dloss_dselection.is_finite());
}

#[test]
fn relative_l2_gradient_treats_the_denominator_as_constant() {
    let (loss, grad) = relative_l2([1.0, 0.0, 2.0], [0.5, 0.0, 3.0]);
    let want = (0.25 / 1.01 + 0.0 + 1.0 / 4.01) / 3.0;
    assert!((loss - want).abs() < 1e-6);
    assert!((grad[0] - 2.0 * 0.5 / 1.01 / 3.0).abs() < 1e-6);
    assert_eq!(grad[1], 0.0);
    assert!((grad[2] - -2.0 / 4.01 / 3.0).abs() < 1e-6);
}
