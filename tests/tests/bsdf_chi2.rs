//! Chi² goodness of fit of the renderer's BSDF sampling routines against their pdfs
//! (Mitsuba 3's BSDF chi² tests, with this crate's sphere grid, pooling and Šidák correction).
//!
//! `Material::sample` may reject a sample (a microfacet reflection below the horizon) or pick
//! a delta lobe (the plastic coating); the distribution under test is the sampler *conditioned
//! on* returning a non-delta direction, whose density is `pdf(ω) / ∫pdf`. The normaliser is
//! computed with the same quadrature as the expected counts, so this test checks the *shape*
//! of the pdf; its scale (∫pdf = acceptance rate) and `weight = f·cos/pdf` are checked by the
//! unit tests in `host-demo/src/bsdf.rs`.
//!
//! Grids: Mitsuba's 101 × 51 with Gauss–Legendre order 6 per cell. The rough dielectrics with
//! η = 1.33 and α = 0.6 get 201 × 101 cells at order 16: their transmission lobe ends in a
//! steep Fresnel edge (F → 1 as the microfacet turns grazing) that cuts through grid cells, and
//! the coarse rule mis-integrates those cells (at 101 × 51, order 6 the expected counts of the
//! edge row are 40 % low and the test rejects with quadrature_z ≈ 6; at order 16 and on the finer
//! grid it passes).
//!
//! Run with `cargo test --release -p guiding-tests --test bsdf_chi2` (a few seconds).

use glam::Vec3;
use guiding_tests::cases::Case;
use guiding_tests::chi2::{run_chi2, Chi2Config, Warp};
use guiding_tests::quadrature::integrate;
use guiding_tests::rng::Pcg32;
use guiding_tests::SphereDistribution;
use host_demo::bsdf::{Coating, Material};

struct Conditioned {
    m: Material,
    wi: Vec3,
    norm: f64,
}

impl SphereDistribution for Conditioned {
    fn sample(&self, rng: &mut Pcg32) -> (Vec3, f32) {
        for _ in 0..10_000 {
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
        alpha,
        eta,
        reflectance: Vec3::ONE,
        transmittance: Vec3::ONE,
    };
    let outside = Vec3::new(0.55, 0.1, 0.6).normalize();
    let inside = Vec3::new(-0.3, 0.2, -0.8).normalize();
    let grazing = Vec3::new(0.95, 0.0, 0.2).normalize();
    let mid = Vec3::new(0.6, 0.0, 0.8);
    vec![
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
            Material::RoughPlastic(Coating::rough(d, s, 1.49, false, 0.2)),
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
                alpha: 0.25,
                eta: Vec3::new(0.2, 0.92, 1.1),
                k: Vec3::new(3.9, 2.45, 2.14),
            },
            outside,
            false,
        ),
        (
            "roughconductor a0.6 grazing".into(),
            Material::RoughConductor {
                alpha: 0.6,
                eta: Vec3::ZERO,
                k: Vec3::ONE,
            },
            grazing,
            false,
        ),
    ]
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
        let warp = Warp::uniform();
        let norm = integrate(
            &warp,
            |d| f64::from(m.eval(*wi, d.as_vec3()).1),
            cfg.res_u,
            cfg.res_v,
            16,
        );
        assert!(norm > 0.05 && norm <= 1.001, "{name}: ∫pdf = {norm}");
        let case = Case {
            name: format!("bsdf/{name}"),
            dist: Box::new(Conditioned {
                m: *m,
                wi: *wi,
                norm,
            }),
            warp,
        };
        let r = run_chi2(
            &case,
            all.len(),
            &Chi2Config {
                seed: 100 + i as u64,
                ..cfg.clone()
            },
        );
        eprintln!("{} (∫pdf {norm:.4})", r.message);
        if !r.passed {
            failures.push(r.message);
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
