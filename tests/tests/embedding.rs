//! The embedding API (`guiding` crate): presets, per-lane and batched
//! queries, the path recorder's radiance propagation, learning through the
//! recorder, save/load round trips and corrupt files, stale distributions.

use guiding::{
    FieldConfig, GuidingConfig, GuidingError, GuidingField, ModelSize, PathRecorder, PathVertex,
    QueryPoint, Representation, Target,
};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;
use guiding_tests::{mirror_path, record_uniform_vertex};

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];

fn presets() -> Vec<GuidingConfig> {
    let mut v = Vec::new();
    for base in [
        GuidingConfig::npm_radiance(),
        GuidingConfig::npm_product(),
        GuidingConfig::nasg(),
        GuidingConfig::nasg_product(),
        GuidingConfig::df_nearest(),
        GuidingConfig::df_linear(),
        GuidingConfig::df_linear().with_target(Target::Product),
    ] {
        v.push(
            base.with_size(ModelSize::Small).with_training(
                FieldConfig::DEFAULT
                    .with_batch_size(512)
                    .with_steps_per_update(4)
                    .with_threads(2),
            ),
        );
    }
    v
}

fn random_query(rng: &mut Pcg32) -> QueryPoint {
    guiding_tests::random_query_in(rng, LO, HI)
}

/// Light from a cone around +z (cos θ > 0.95) of radiance 10, 0.1 elsewhere.
fn radiance(dir: Vec3) -> f32 {
    if dir.z > 0.95 {
        10.0
    } else {
        0.1
    }
}

/// `∫ L dω = 10 · 2π(1 − 0.95) + 0.1 · (4π − 2π(1 − 0.95))`.
fn radiance_integral() -> f64 {
    let cone = 2.0 * std::f64::consts::PI * 0.05;
    10.0 * cone + 0.1 * (4.0 * std::f64::consts::PI - cone)
}

/// One-vertex paths with uniformly sampled directions, through the recorder.
fn record_uniform_paths(recorder: &mut PathRecorder, rng: &mut Pcg32, n: usize) {
    for _ in 0..n {
        let wi = square_to_uniform_sphere(rng.next_vec2());
        let q = random_query(rng);
        record_uniform_vertex(recorder, (q.position, q.normal, q.wo), wi, radiance(wi));
    }
}

#[test]
fn every_preset_builds_and_is_self_consistent() {
    let mut rng = Pcg32::new(7, 1);
    for config in presets() {
        let field = GuidingField::new(config, LO, HI).unwrap();
        assert!(field.param_count() > 0);
        let queries: Vec<_> = (0..64).map(|_| random_query(&mut rng)).collect();
        let batch = field.query(&queries);
        for (q, d) in queries.iter().zip(&batch) {
            let single = field.distribution(q);
            let c = d.selection_probability();
            assert!((0.0..=1.0).contains(&c), "{config:?}: c = {c}");
            assert_eq!(c, single.selection_probability());
            for _ in 0..8 {
                let u = rng.next_vec2();
                let s = d.sample(u);
                assert_eq!(s.direction, single.sample(u).direction);
                assert!((s.direction.length() - 1.0).abs() < 1e-5, "{config:?}");
                assert!(
                    s.pdf.is_finite() && s.pdf > 0.0,
                    "{config:?}: pdf {}",
                    s.pdf
                );
                let p = d.pdf(s.direction);
                assert!(
                    (p / s.pdf - 1.0).abs() < 1e-3,
                    "{config:?}: {p} vs {}",
                    s.pdf
                );
            }
        }
        // The batched entry points agree with the per-lane ones.
        let u: Vec<Vec2> = queries.iter().map(|_| rng.next_vec2()).collect();
        let mut samples = vec![
            guiding::DirectionSample {
                direction: Vec3::Z,
                pdf: 0.0
            };
            64
        ];
        field.sample_batch(&queries, &u, &mut samples).unwrap();
        let dirs: Vec<Vec3> = samples.iter().map(|s| s.direction).collect();
        let mut pdfs = vec![0.0; 64];
        field.pdf_batch(&queries, &dirs, &mut pdfs).unwrap();
        let mut sel = vec![0.0; 64];
        field
            .selection_probability_batch(&queries, &mut sel)
            .unwrap();
        for i in 0..64 {
            assert_eq!(samples[i].direction, batch[i].sample(u[i]).direction);
            assert_eq!(pdfs[i], batch[i].pdf(dirs[i]));
            assert_eq!(sel[i], batch[i].selection_probability());
        }
        assert!(matches!(
            field.pdf_batch(&queries, &dirs[..3], &mut pdfs),
            Err(GuidingError::LengthMismatch { .. })
        ));
    }
}

#[test]
fn invalid_configs_and_bounds_are_errors() {
    let base = GuidingConfig::npm_radiance().with_size(ModelSize::Small);
    for (lo, hi) in [
        ([0.0; 3], [0.0; 3]),
        ([1.0; 3], [0.0; 3]),
        ([f32::NAN, 0.0, 0.0], [1.0; 3]),
        ([0.0; 3], [f32::INFINITY, 1.0, 1.0]),
        ([-3e38; 3], [3e38; 3]),
    ] {
        assert!(matches!(
            GuidingField::new(base, lo, hi),
            Err(GuidingError::InvalidBounds { .. })
        ));
    }
    for p in [-0.1, 1.5, f32::NAN] {
        assert!(matches!(
            GuidingField::new(base.with_selection_probability(p), LO, HI),
            Err(GuidingError::InvalidConfig(_))
        ));
    }
    assert!(matches!(
        GuidingField::new(
            base.with_training(FieldConfig::DEFAULT.with_batch_size(0)),
            LO,
            HI
        ),
        Err(GuidingError::Field(_))
    ));
}

#[test]
fn recorder_propagates_radiance_back_along_the_path() {
    // Diffuse, delta (mirror), diffuse that hits an emitter.
    let [v0, v1, v2] = mirror_path();
    let mut rec = PathRecorder::new();
    rec.start_path();
    rec.add_vertex(v0);
    rec.add_vertex(v1);
    rec.add_vertex(v2);
    rec.add_escaped_radiance([3.0, 3.0, 3.0], 1.0);
    let l0 = rec.end_path();
    // By hand, from the end of the path.
    let li2 = [3.0f32, 3.0, 3.0];
    let lo2: Vec<f32> = (0..3)
        .map(|c| v2.emitted[c] * 0.5 + v2.direct[c] + 2.0 * v2.bsdf_cos[c] / 2.0 * li2[c])
        .collect();
    let lo1: Vec<f32> = (0..3).map(|c| 0.9 * lo2[c]).collect();
    let expected0: Vec<f32> = (0..3)
        .map(|c| v0.emitted[c] + v0.direct[c] + v0.bsdf_cos[c] / 0.5 * lo1[c])
        .collect();
    for c in 0..3 {
        assert!((l0[c] - expected0[c]).abs() <= 1e-6 * expected0[c].abs());
    }
    // Two samples (the delta vertex makes none), in path order.
    let s = rec.samples();
    assert_eq!(s.len(), 2);
    assert_eq!(s[0].position, v0.position);
    assert_eq!(s[0].sample_pdf, 0.5);
    assert_eq!(s[0].bsdf_pdf, 0.4);
    assert_eq!(s[0].bsdf_cos, v0.bsdf_cos);
    assert_eq!(s[0].wi, v0.wi);
    assert_eq!(s[1].position, v2.position);
    assert_eq!(s[1].radiance, li2);
    for (got, want) in s[0].radiance.iter().zip(&lo1) {
        assert!((got - want).abs() <= 1e-6 * want);
    }
    // A path that ends at its first vertex (sample_pdf = 0) makes no sample
    // and returns its emission and direct light.
    rec.start_path();
    rec.add_vertex(PathVertex {
        emitted: [1.0; 3],
        direct: [0.5; 3],
        ..PathVertex::default()
    });
    assert_eq!(rec.end_path(), [1.5; 3]);
    assert_eq!(rec.samples().len(), 2);
    let mut field = GuidingField::new(presets()[0], LO, HI).unwrap();
    assert_eq!(rec.flush_into(&mut field), 2);
    assert!(rec.samples().is_empty());
    assert_eq!(field.stats().accepted_samples, 2);
    // The emission found along a sampled direction is that vertex's training
    // target in full; its MIS weight (against NEE at the vertex) only weights
    // the pixel estimate. Likewise for an escaped ray.
    rec.clear_samples();
    rec.start_path();
    rec.add_vertex(PathVertex {
        wi: [0.0, 0.0, 1.0],
        sample_pdf: 0.5,
        bsdf_cos: [0.25; 3],
        ..PathVertex::default()
    });
    rec.add_vertex(PathVertex {
        emitted: [2.0; 3],
        emitted_mis_weight: 0.25,
        direct: [0.5; 3],
        wi: [0.0, 1.0, 0.0],
        sample_pdf: 1.0,
        bsdf_cos: [0.5; 3],
        ..PathVertex::default()
    });
    rec.add_escaped_radiance([4.0; 3], 0.5);
    // Vertex 1: target 4 (escaped, in full); its path estimate 0.25·2 + 0.5 + 0.5·(0.5·4) = 2.
    // Vertex 0: target 2 + 0.5 + 0.5·(0.5·4) = 3.5; pixel 0.25/0.5 · 2 = 1.
    assert_eq!(rec.end_path(), [1.0; 3]);
    assert_eq!(rec.samples()[0].radiance, [3.5; 3]);
    assert_eq!(rec.samples()[1].radiance, [4.0; 3]);
}

/// Every representation learns, through the recorder, a light cone it can
/// then sample: the guided one-sample-MIS estimator of `∫ L dω` stays
/// unbiased (4σ) and has less than half the variance of uniform sampling
/// (measured: see the printed ratios).
#[test]
fn learned_guide_reduces_variance_of_a_known_integral() {
    for rep in Representation::ALL {
        let config = GuidingConfig::npm_radiance()
            .with_size(ModelSize::Small)
            .with_selection_probability(0.7)
            .with_training(
                FieldConfig::DEFAULT
                    .with_learning_rate(2e-2)
                    .with_batch_size(2048)
                    .with_steps_per_update(8)
                    .with_threads(2),
            );
        let config = GuidingConfig {
            representation: rep,
            ..config
        };
        let mut field = GuidingField::new(config, LO, HI).unwrap();
        let mut rng = Pcg32::new(11, rep as u64);
        let mut rec = PathRecorder::new();
        for _ in 0..30 {
            record_uniform_paths(&mut rec, &mut rng, 4096);
            rec.flush_into(&mut field);
            field.update();
        }
        assert_eq!(field.stats().generation, 30);
        let n = 20_000;
        let (mut sum_g, mut sum2_g, mut sum_u, mut sum2_u) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for _ in 0..n {
            let q = random_query(&mut rng);
            let d = field.distribution(&q);
            let c = d.selection_probability();
            let u = rng.next_vec2();
            let dir = if rng.next_f32() < c {
                d.sample(u).direction
            } else {
                square_to_uniform_sphere(u)
            };
            let pdf = c * d.pdf(dir) + (1.0 - c) * INV_FOUR_PI;
            let g = f64::from(radiance(dir) / pdf);
            sum_g += g;
            sum2_g += g * g;
            let du = square_to_uniform_sphere(rng.next_vec2());
            let e = f64::from(radiance(du) / INV_FOUR_PI);
            sum_u += e;
            sum2_u += e * e;
        }
        let nf = n as f64;
        let (mean_g, mean_u) = (sum_g / nf, sum_u / nf);
        let var_g = sum2_g / nf - mean_g * mean_g;
        let var_u = sum2_u / nf - mean_u * mean_u;
        let exact = radiance_integral();
        println!(
            "{rep:?}: guided mean {mean_g:.4} var {var_g:.3}; uniform mean {mean_u:.4} var {var_u:.3}; exact {exact:.4}; ratio {:.3}",
            var_g / var_u
        );
        assert!(
            (mean_g - exact).abs() < 4.0 * (var_g / nf).sqrt(),
            "{rep:?}: biased guided estimate {mean_g} vs {exact}"
        );
        assert!(var_g < 0.5 * var_u, "{rep:?}: {var_g} vs {var_u}");
    }
}

fn trained(config: GuidingConfig, seed: u64) -> GuidingField {
    let mut field = GuidingField::new(config, LO, HI).unwrap();
    let mut rng = Pcg32::new(seed, 3);
    let mut rec = PathRecorder::new();
    for _ in 0..3 {
        record_uniform_paths(&mut rec, &mut rng, 600);
        rec.flush_into(&mut field);
        field.update();
    }
    field
}

#[test]
fn save_and_load_round_trip_exactly_and_resume_training() {
    let dir = std::env::temp_dir().join(format!("guiding-save-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = Pcg32::new(5, 5);
    for (i, config) in presets().into_iter().enumerate() {
        let mut field = trained(config, i as u64);
        let path = dir.join(format!("field-{i}.guide"));
        field.save(&path).unwrap();
        let mut loaded = GuidingField::load(&path).unwrap();
        assert_eq!(loaded.config(), field.config());
        assert_eq!(loaded.bounds(), field.bounds());
        for _ in 0..32 {
            let q = random_query(&mut rng);
            let u = rng.next_vec2();
            let (a, b) = (field.distribution(&q), loaded.distribution(&q));
            let (sa, sb) = (a.sample(u), b.sample(u));
            assert_eq!(sa.direction, sb.direction);
            assert_eq!(sa.pdf, sb.pdf);
            assert_eq!(a.selection_probability(), b.selection_probability());
        }
        // Training resumes from the saved Adam state: both stay identical.
        let mut rec = PathRecorder::new();
        record_uniform_paths(&mut rec, &mut Pcg32::new(99, 1), 600);
        let samples = rec.samples().to_vec();
        field.add_samples(&samples);
        loaded.add_samples(&samples);
        field.update();
        loaded.update();
        assert!(
            guiding::file::to_bytes(&field) == guiding::file::to_bytes(&loaded),
            "{config:?}: training diverged after loading"
        );
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert!(names.iter().all(|n| !n.contains(".tmp-")), "{names:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn corrupt_and_truncated_files_are_errors() {
    let field = trained(presets()[2], 1);
    let bytes = guiding::file::to_bytes(&field);
    let path = std::path::Path::new("mem.guide");
    assert!(guiding::file::from_bytes(&bytes, path).is_ok());
    let is_format = |b: &[u8]| {
        matches!(
            guiding::file::from_bytes(b, path),
            Err(GuidingError::Format { .. })
        )
    };
    // Every truncation in the header region, then a spread of longer ones.
    for len in (0..300.min(bytes.len())).chain((300..bytes.len()).step_by(997)) {
        assert!(is_format(&bytes[..len]), "truncated to {len}");
    }
    assert!(is_format(&bytes[..bytes.len() - 1]));
    // Every single-bit flip of the header, and flips spread over the body,
    // are caught (by the checksum or a check before it).
    let mut rng = Pcg32::new(1, 9);
    let spread: Vec<usize> = (0..300)
        .map(|_| rng.next_u32() as usize % bytes.len())
        .collect();
    let positions = (0..200).chain(spread);
    for pos in positions {
        let mut b = bytes.clone();
        b[pos] ^= 1 << (rng.next_u32() % 8);
        assert!(is_format(&b), "flip at {pos}");
    }
    // Appended bytes.
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 16]);
    assert!(is_format(&longer));
    // A well-formed file with a NaN parameter (valid checksum) is refused.
    let mut b = bytes[..bytes.len() - 4].to_vec();
    let n = b.len();
    b[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
    let crc = crc32(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    assert!(is_format(&b));
    // Missing file and unwritable destination are I/O errors.
    assert!(matches!(
        GuidingField::load("/nonexistent/dir/field.guide"),
        Err(GuidingError::Io { .. })
    ));
    assert!(matches!(
        field.save("/nonexistent/dir/field.guide"),
        Err(GuidingError::Io { .. })
    ));
}

/// Bitwise CRC-32 (IEEE, reflected, polynomial 0xEDB88320) as an
/// independent oracle of the library's checksum.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[test]
fn stale_distributions_are_refused() {
    let mut field = trained(presets()[0], 2);
    let other = trained(presets()[0], 3);
    let q = QueryPoint {
        position: [0.0, 0.0, 1.0],
        ..QueryPoint::default()
    };
    let detached = field.distribution(&q).detach();
    assert!(field.attach(detached).is_ok());
    assert!(matches!(
        other.attach(detached),
        Err(GuidingError::StaleDistribution { .. })
    ));
    let mut rec = PathRecorder::new();
    record_uniform_paths(&mut rec, &mut Pcg32::new(4, 4), 600);
    rec.flush_into(&mut field);
    field.update();
    assert!(matches!(
        field.attach(detached),
        Err(GuidingError::StaleDistribution { .. })
    ));
}

#[test]
fn queries_from_many_threads_agree_with_one() {
    let field = trained(presets()[4], 6);
    let mut rng = Pcg32::new(8, 8);
    let queries: Vec<_> = (0..256).map(|_| random_query(&mut rng)).collect();
    let serial: Vec<f32> = queries
        .iter()
        .map(|q| field.distribution(q).pdf(Vec3::Z))
        .collect();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| {
                s.spawn(|| {
                    queries
                        .iter()
                        .map(|q| field.distribution(q).pdf(Vec3::Z))
                        .collect::<Vec<f32>>()
                })
            })
            .collect();
        for h in handles {
            assert_eq!(h.join().unwrap(), serial);
        }
    });
}
