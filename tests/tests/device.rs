//! A `GuidingField` on a Vulkan device (lavapipe in CI): the field's one
//! training loop with the device doing the arithmetic, the wavefront calls
//! answered by the device, and device failures that are errors (or a
//! fallback to the CPU with the device's trained weights), never silent.
//!
//! Skipped with a note when the SPIR-V is not built into this binary or no
//! Vulkan device exists, unless `GUIDING_REQUIRE_VULKAN=1` (CI).

use guiding::{
    DeviceFailure, DistributionBatch, FieldConfig, GpuContext, GuidingConfig, GuidingError,
    GuidingField, ModelSize, QueryPoint, Representation, TrainingSample,
};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::Pcg32;

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];

/// The device of the tests, or `None` (with the reason printed): the
/// workspace's one rule, `guiding_gpu::test_support`.
fn context() -> Option<GpuContext> {
    guiding_gpu::test_context()
}

fn config(base: GuidingConfig, seed: u32) -> GuidingConfig {
    base.with_size(ModelSize::Small).with_training(
        FieldConfig::DEFAULT
            .with_batch_size(256)
            .with_steps_per_update(1)
            .with_learning_rate(1e-2)
            .with_threads(2)
            .with_seed(seed),
    )
}

fn bases() -> [(&'static str, GuidingConfig); 4] {
    [
        ("npm", GuidingConfig::npm_radiance()),
        ("nasg", GuidingConfig::nasg()),
        ("df-n", GuidingConfig::df_nearest()),
        ("df-l", GuidingConfig::df_linear()),
    ]
}

fn random_query(rng: &mut Pcg32) -> QueryPoint {
    guiding_tests::random_query_in(rng, LO, HI)
}

/// Uniformly sampled directions with a bright cone around +z (radiances
/// spread over two decades, so different minibatches have different
/// losses), and every `invalid`-th sample with a NaN radiance.
fn samples(n: usize, seed: u64, invalid: usize) -> Vec<TrainingSample> {
    let mut rng = Pcg32::new(seed, 5);
    (0..n)
        .map(|i| {
            let q = random_query(&mut rng);
            let wi = square_to_uniform_sphere(rng.next_vec2());
            let l = if wi.z > 0.8 { 20.0 } else { 0.2 } * (0.5 + rng.next_f32());
            let l = if invalid > 0 && i % invalid == 0 {
                f32::NAN
            } else {
                l
            };
            TrainingSample::new(q, wi.to_array(), [l; 3], INV_FOUR_PI, INV_FOUR_PI, [1.0; 3])
        })
        .collect()
}

/// Trains `field` for `updates` updates of fresh samples; the per-update
/// mean losses.
fn train(field: &mut GuidingField, updates: u64, seed: u64) -> Vec<f64> {
    (0..updates)
        .map(|k| {
            field.add_samples(&samples(1024, seed + k, 97));
            field.try_update().expect("update").mean_loss
        })
        .collect()
}

/// The device trains through the field's loop: the same validation and
/// rejection counts, the same minibatches (the first update's loss, at the
/// same initial weights, agrees to rounding), the same counters, and the
/// device's EMA comes back into the field. Negative control: another
/// shuffle seed gives another minibatch, whose loss is far outside that
/// tolerance — the comparison sees which samples the device trained on.
#[test]
fn the_device_trains_by_the_fields_loop() {
    let Some(ctx) = context() else { return };
    for (name, base) in bases() {
        let mut cpu = GuidingField::new(config(base, 3), LO, HI).unwrap();
        let mut gpu = GuidingField::new(config(base, 3), LO, HI).unwrap();
        let mut other = GuidingField::new(config(base, 4), LO, HI).unwrap();
        gpu.use_device_context(ctx.clone(), DeviceFailure::Error)
            .unwrap();
        other
            .use_device_context(ctx.clone(), DeviceFailure::Error)
            .unwrap();
        assert!(gpu.device_name().is_some());
        let before = gpu.distribution(&QueryPoint::default()).pdf(Vec3::Z);
        let l_cpu = train(&mut cpu, 3, 10);
        let l_gpu = train(&mut gpu, 3, 10);
        let l_other = train(&mut other, 3, 10);
        let (sc, sg) = (cpu.stats(), gpu.stats());
        assert_eq!(sg.steps, 3, "{name}: device steps counted by the field");
        assert_eq!(sg.skipped_steps, sc.skipped_steps, "{name}");
        assert_eq!(sg.rejected_samples, sc.rejected_samples, "{name}");
        assert!(sg.rejected_samples[0] > 0, "{name}: NaN radiances rejected");
        assert_eq!(sg.accepted_samples, sc.accepted_samples, "{name}");
        // `use_device` is a generation of its own (batches decoded before
        // it are stale), then one per update as on the CPU.
        assert_eq!(sg.generation, sc.generation + 1, "{name}");
        // The per-sample losses are rounded alike to ~1e-6 relative; the
        // batch mean of 256 of them to the same order.
        let tol = 1e-4 * l_cpu[0].abs().max(1e-3);
        assert!(
            (l_gpu[0] - l_cpu[0]).abs() <= tol,
            "{name}: first loss device {} CPU {}",
            l_gpu[0],
            l_cpu[0]
        );
        assert!(
            (l_other[0] - l_cpu[0]).abs() > 10.0 * tol,
            "{name}: another minibatch should give another loss ({} vs {})",
            l_other[0],
            l_cpu[0]
        );
        // The EMA came back: the CPU-side query sees trained weights.
        let after = gpu.distribution(&QueryPoint::default()).pdf(Vec3::Z);
        assert!(
            after != before,
            "{name}: the field's weights did not change"
        );
        eprintln!(
            "{name}: first loss device {:.6} CPU {:.6} other seed {:.6}; later {:?} vs {:?}",
            l_gpu[0], l_cpu[0], l_other[0], l_gpu, l_cpu
        );
    }
}

/// The wavefront calls on the device: selection probabilities, samples and
/// pdfs of device lanes agree with the CPU decode of the same (copied back)
/// weights, with and without the cosine product; the samples' pdfs equal
/// the device's pdfs of the sampled directions.
#[test]
fn device_lanes_agree_with_the_cpu_decode() {
    let Some(ctx) = context() else { return };
    let mut rng = Pcg32::new(21, 9);
    for (name, base) in bases() {
        let mut field = GuidingField::new(config(base, 5), LO, HI).unwrap();
        field
            .use_device_context(ctx.clone(), DeviceFailure::Error)
            .unwrap();
        train(&mut field, 2, 40);
        // The same weights on the CPU: the device's state through a file.
        let path =
            std::env::temp_dir().join(format!("guiding-lanes-{name}-{}.pgf", std::process::id()));
        field.save(&path).unwrap();
        let cpu_field = GuidingField::load(&path).unwrap();
        std::fs::remove_file(&path).ok();
        assert!(cpu_field.device_name().is_none());
        let n = 300;
        let queries: Vec<QueryPoint> = (0..n).map(|_| random_query(&mut rng)).collect();
        let mut cpu = DistributionBatch::new();
        cpu_field.decode_batch(&queries, &mut cpu);
        let mut batch = DistributionBatch::new();
        field.try_decode_batch(&queries, &mut batch).unwrap();
        assert_eq!(batch.len(), n);
        for i in 0..n {
            let (g, c) = (batch.selection_probability(i), cpu.selection_probability(i));
            assert!((g - c).abs() <= 1e-5, "{name}: selection {i}: {g} vs {c}");
        }
        let lanes: Vec<u32> = (0..n as u32).rev().step_by(2).collect();
        let u: Vec<Vec2> = lanes.iter().map(|_| rng.next_vec2()).collect();
        let dirs: Vec<Vec3> = lanes
            .iter()
            .map(|_| square_to_uniform_sphere(rng.next_vec2()))
            .collect();
        for cosine in [false, true] {
            if cosine {
                let normals: Vec<Vec3> =
                    queries.iter().map(|q| Vec3::from_array(q.normal)).collect();
                let applied = batch.apply_cosine_product(&normals);
                assert_eq!(
                    applied,
                    field.config().representation == Representation::Npm
                );
                assert_eq!(cpu.apply_cosine_product(&normals), applied);
                if !applied {
                    continue;
                }
            }
            let mut pdfs = vec![0.0f32; lanes.len()];
            field.pdf_decoded(&batch, &lanes, &dirs, &mut pdfs).unwrap();
            let mut samples = vec![
                guiding::DirectionSample {
                    direction: Vec3::Z,
                    pdf: 0.0,
                };
                lanes.len()
            ];
            field
                .sample_decoded(&batch, &lanes, &u, &mut samples)
                .unwrap();
            let sampled: Vec<Vec3> = samples.iter().map(|s| s.direction).collect();
            let mut again = vec![0.0f32; lanes.len()];
            field
                .pdf_decoded(&batch, &lanes, &sampled, &mut again)
                .unwrap();
            let mut cpu_pdfs = vec![0.0f32; lanes.len()];
            cpu_field
                .pdf_decoded(&cpu, &lanes, &dirs, &mut cpu_pdfs)
                .unwrap();
            let mut cpu_again = vec![0.0f32; lanes.len()];
            cpu_field
                .pdf_decoded(&cpu, &lanes, &sampled, &mut cpu_again)
                .unwrap();
            let sens_dirs = local_sensitivity(&cpu_field, &cpu, &lanes, &dirs);
            let sens_sampled = local_sensitivity(&cpu_field, &cpu, &lanes, &sampled);
            // The difftests' relative tolerances of a whole model's pdf
            // (guiding-gpu/tests/difftest.rs: 1e-5 for the mixtures, 4e-5
            // for DF's two softmaxes) with their floor of 1e-2, plus the
            // CPU density's own change when the direction moves by 4 ulp.
            let rel = if name.starts_with("df") { 4e-5 } else { 1e-5 };
            let mut worst = 0.0f32;
            for k in 0..lanes.len() {
                let s = samples[k];
                assert!(
                    s.pdf.is_finite() && s.pdf > 0.0 && (s.direction.length() - 1.0).abs() < 1e-4,
                    "{name}: sample {k} {s:?}"
                );
                for (what, g, c, sens) in [
                    ("pdf", pdfs[k], cpu_pdfs[k], sens_dirs[k]),
                    ("pdf of sample", again[k], cpu_again[k], sens_sampled[k]),
                    // The device's sample pdf against its own pdf there.
                    ("sample pdf", s.pdf, again[k], sens_sampled[k]),
                ] {
                    let bound = rel * c.abs().max(1e-2) + sens;
                    let err = (g - c).abs();
                    assert!(
                        g.is_finite() && err <= bound,
                        "{name} cosine {cosine}: {what} {k}: device {g} CPU {c} (bound {bound:e})"
                    );
                    worst = worst.max(err / bound);
                }
            }
            eprintln!("{name} cosine {cosine}: worst {worst:.3} of the bound");
        }
    }
}

/// A failed device is an error everywhere it is needed (decode, sample,
/// pdf, update), and `device_error` says why; nothing answers with the
/// untrained CPU weights.
#[test]
fn a_device_failure_is_an_error() {
    let Some(ctx) = context() else { return };
    let mut field = GuidingField::new(config(GuidingConfig::npm_radiance(), 1), LO, HI).unwrap();
    field.use_device_context(ctx, DeviceFailure::Error).unwrap();
    train(&mut field, 1, 60);
    let mut rng = Pcg32::new(2, 2);
    let queries: Vec<QueryPoint> = (0..16).map(|_| random_query(&mut rng)).collect();
    let mut batch = DistributionBatch::new();
    field.try_decode_batch(&queries, &mut batch).unwrap();
    assert!(field.device_error().is_none());
    field.fail_device_for_tests("injected");
    let is_device = |r: Result<(), GuidingError>| matches!(r, Err(GuidingError::Device(_)));
    let mut out = vec![0.0f32; 1];
    assert!(is_device(field.pdf_decoded(
        &batch,
        &[0],
        &[Vec3::Z],
        &mut out
    )));
    let mut s = [guiding::DirectionSample {
        direction: Vec3::Z,
        pdf: 0.0,
    }];
    assert!(is_device(field.sample_decoded(
        &batch,
        &[0],
        &[Vec2::splat(0.5)],
        &mut s
    )));
    assert!(is_device(field.try_decode_batch(&queries, &mut batch)));
    assert!(batch.is_empty());
    field.add_samples(&samples(512, 61, 0));
    assert!(matches!(field.try_update(), Err(GuidingError::Device(_))));
    let e = field.device_error().expect("the failure is kept");
    assert!(e.to_string().contains("injected"), "{e}");
}

/// With `FallbackToCpu` the field goes on on the CPU with exactly the
/// training state the device reached (parameters, EMA, Adam moments, step
/// and update counts), and keeps training there. Negative control: that
/// state is not the untrained one.
#[test]
fn a_fallback_continues_on_the_cpu_with_the_devices_weights() {
    let Some(ctx) = context() else { return };
    let base = config(GuidingConfig::nasg(), 2);
    let mut field = GuidingField::new(base, LO, HI).unwrap();
    field
        .use_device_context(ctx, DeviceFailure::FallbackToCpu)
        .unwrap();
    train(&mut field, 2, 70);
    let dir = std::env::temp_dir().join(format!("guiding-device-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (on_device, on_cpu) = (dir.join("device.pgf"), dir.join("cpu.pgf"));
    field.save(&on_device).unwrap();
    let trained_state = std::fs::read(&on_device).unwrap();
    field.fail_device_for_tests("injected");
    // Still answers (on the CPU), and the next update moves it there.
    let mut rng = Pcg32::new(3, 3);
    let queries: Vec<QueryPoint> = (0..16).map(|_| random_query(&mut rng)).collect();
    let mut batch = DistributionBatch::new();
    field.try_decode_batch(&queries, &mut batch).unwrap();
    assert_eq!(batch.len(), 16);
    field.save(&on_cpu).unwrap();
    assert!(
        std::fs::read(&on_cpu).unwrap() == trained_state,
        "the CPU copy after the failure is not the device's trained state"
    );
    let fresh = GuidingField::new(base, LO, HI).unwrap();
    let fresh_path = dir.join("fresh.pgf");
    fresh.save(&fresh_path).unwrap();
    assert!(std::fs::read(&fresh_path).unwrap() != trained_state);
    field.add_samples(&samples(1024, 80, 0));
    let report = field.try_update().expect("training goes on on the CPU");
    assert_eq!(report.steps, 1);
    assert!(field.device_name().is_none(), "the device was dropped");
    assert_eq!(field.stats().steps, 3);
    std::fs::remove_dir_all(&dir).ok();
}

/// How much the CPU density of each lane moves when its direction moves by
/// 4 ulp along two tangents, both ways (the pdf's local condition).
fn local_sensitivity(
    field: &GuidingField,
    batch: &DistributionBatch,
    lanes: &[u32],
    dirs: &[Vec3],
) -> Vec<f32> {
    let h = 4.0 * f32::EPSILON;
    let mut nudged_lanes = Vec::new();
    let mut nudged = Vec::new();
    for (&l, &d) in lanes.iter().zip(dirs) {
        let t = if d.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
        let t1 = d.cross(t).normalize();
        let t2 = d.cross(t1);
        for e in [Vec3::ZERO, t1, -t1, t2, -t2] {
            nudged_lanes.push(l);
            nudged.push((d + h * e).normalize());
        }
    }
    let mut p = vec![0.0f32; nudged.len()];
    field
        .pdf_decoded(batch, &nudged_lanes, &nudged, &mut p)
        .unwrap();
    p.chunks(5)
        .map(|c| c[1..].iter().map(|x| (x - c[0]).abs()).fold(0.0, f32::max))
        .collect()
}
