//! The wavefront (batched) decode and training paths against the per-query
//! reference kernels: `guiding_core::model::batched`, the `guiding`
//! crate's `DistributionBatch`, and the batched gradient the CPU runtime
//! trains with.
//!
//! Each stage is compared where the two paths compute the same function
//! with the same operations: the decoders and encoders bit for bit (the
//! fast paths only widen vectors, Rust never contracts into FMA), the whole
//! pipeline against the per-query decoders applied to the batched network's
//! own outputs (bit for bit), and the network itself in `tests/mlp.rs`
//! (within the FMA rounding bound stated there).

use guiding::{
    DistributionBatch, FieldConfig, GuidingConfig, GuidingError, GuidingField, ModelSize,
    QueryPoint, Representation, Target,
};
use guiding_core::encoding::grid::{grid_forward, grid_forward_fast};
use guiding_core::encoding::GridConfig;
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::math::INV_FOUR_PI;
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::mlp::Mlp;
use guiding_core::model::batched::{decode_vmf_batch, decode_vmf_batch_portable};
use guiding_core::model::df::{DfCompactRadiance, DfVertex, VertexModel};
use guiding_core::model::nasg::NasgCompactProduct;
use guiding_core::model::npm::{
    encode_inputs, encode_product_inputs, NpmCompactProduct, NpmCompactRadiance, NPM_LOBES,
    NPM_OUTPUTS,
};
use guiding_core::model::GuidingModel;
use guiding_core::pdf1d::Interpolation;
use guiding_core::sample::TrainingSample;
use guiding_core::sphere::square_to_uniform_sphere;
use guiding_tests::rng::{rows_with_specials, Pcg32, IEEE_SPECIALS};

const LO: [f32; 3] = [-1.0, -2.0, 0.0];
const HI: [f32; 3] = [1.0, 2.0, 3.0];

fn query(rng: &mut Pcg32) -> QueryPoint {
    let n = square_to_uniform_sphere(rng.next_vec2());
    let wo = square_to_uniform_sphere(rng.next_vec2());
    QueryPoint {
        // Slightly outside the box too (clamped to its faces).
        position: [
            rng.uniform(LO[0] - 0.1, HI[0] + 0.1),
            rng.uniform(LO[1] - 0.1, HI[1] + 0.1),
            rng.uniform(LO[2] - 0.1, HI[2] + 0.1),
        ],
        roughness: rng.next_f32(),
        normal: n.to_array(),
        wo: wo.to_array(),
        ..QueryPoint::default()
    }
}

fn queries(n: usize, seed: u64) -> Vec<QueryPoint> {
    let mut rng = Pcg32::new(seed, 1);
    (0..n).map(|_| query(&mut rng)).collect()
}

/// Parameters far from the initialisation (so lobes are sharp and the
/// weights uneven): uniform in `[−scale, scale]`.
fn random_params(n: usize, scale: f32, seed: u64) -> Vec<f32> {
    let mut rng = Pcg32::new(seed, 7);
    (0..n).map(|_| rng.uniform(-scale, scale)).collect()
}

/// The compact DF radiance model (linear interpolation) of these tests.
fn df_compact() -> DfCompactRadiance {
    DfCompactRadiance::new(
        guiding::config::compact_grid(LO, HI),
        Target::Radiance,
        Interpolation::Linear,
    )
}

/// [`df_compact`] with [`random_params`] (scale 0.3, seed `param_seed`) and
/// its batched vertices at `n` [`queries`] of seed `query_seed`.
fn df_vertices(
    param_seed: u64,
    n: usize,
    query_seed: u64,
) -> (DfCompactRadiance, Vec<f32>, Vec<QueryPoint>, Vec<DfVertex>) {
    let model = df_compact();
    let params = random_params(model.param_count(), 0.3, param_seed);
    let qs = queries(n, query_seed);
    let mut vs = vec![DfVertex::ZERO; qs.len()];
    model.decode_batch(&params, &qs, &mut vs);
    (model, params, qs, vs)
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

fn vmf_floats(m: &VmfMixture<NPM_LOBES>) -> Vec<f32> {
    bytemuck::cast_slice(std::slice::from_ref(m)).to_vec()
}

/// Raw rows: ordinary values, the clamps' edges and non-finite values.
fn raw_rows(n: usize, seed: u64) -> Vec<[f32; NPM_OUTPUTS]> {
    let specials: Vec<f32> = IEEE_SPECIALS
        .into_iter()
        .chain([1e30, -1e30, 10.0, -10.0, 87.0, -87.0, 1e-40])
        .collect();
    let mut rng = Pcg32::new(seed, 3);
    rows_with_specials(n, &mut rng, (5, 4), &specials, |rng, j| {
        rng.uniform(-12.0, 12.0) * if j % 4 == 0 { 0.5 } else { 1.0 }
    })
}

#[test]
fn batched_vmf_decoder_is_the_per_query_decoder_bit_for_bit() {
    for n in [1, 3, 8, 9, 64, 1001] {
        let rows = raw_rows(n, n as u64);
        let mut fast = vec![VmfMixture::ZERO; n];
        let mut portable = vec![VmfMixture::ZERO; n];
        decode_vmf_batch(&rows, &mut fast);
        decode_vmf_batch_portable(&rows, &mut portable);
        for (i, row) in rows.iter().enumerate() {
            let raw: [[f32; VMF_RAW_PER_LOBE]; NPM_LOBES] =
                std::array::from_fn(|k| std::array::from_fn(|r| row[k * VMF_RAW_PER_LOBE + r]));
            let reference = vmf_floats(&VmfMixture::decode(&raw));
            assert!(
                same_bits(&vmf_floats(&fast[i]), &reference),
                "n {n} row {i}: {row:?}\nfast {:?}\nref  {:?}",
                fast[i],
                VmfMixture::decode(&raw)
            );
            assert!(
                same_bits(&vmf_floats(&portable[i]), &reference),
                "portable, row {i}"
            );
        }
    }
}

#[test]
fn fast_grid_gather_is_the_grid_forward_bit_for_bit() {
    let grids = [
        GridConfig::new(LO, HI, 4, 4, 2.0, 4),
        GridConfig::new(LO, HI, 2, 2, 2.0, 4).with_smoothstep(true),
        GridConfig::new(LO, HI, 3, 5, 1.5, 4).with_offset(17),
        // Not 4 features: the fast path falls back to grid_forward.
        GridConfig::new(LO, HI, 2, 3, 2.0, 2),
    ];
    for grid in grids {
        let params = random_params(grid.offset as usize + grid.param_count(), 1.0, 5);
        for q in queries(500, 9) {
            let (mut a, mut b) = ([0.0f32; 20], [0.0f32; 20]);
            let ea = grid_forward(&params, &grid, q.position(), &mut a, 2);
            let eb = grid_forward_fast(&params, &grid, q.position(), &mut b, 2);
            assert_eq!(ea, eb);
            assert!(same_bits(&a, &b), "{grid:?} at {:?}", q.position);
        }
        // A too short buffer (reads as zeros past its end) falls back too.
        let short = &params[..params.len() / 2];
        let q = queries(1, 3)[0];
        let (mut a, mut b) = ([0.0f32; 20], [0.0f32; 20]);
        grid_forward(short, &grid, q.position(), &mut a, 0);
        grid_forward_fast(short, &grid, q.position(), &mut b, 0);
        assert!(same_bits(&a, &b));
    }
    // The product encoding around it.
    let model = NpmCompactProduct::new(guiding::config::compact_grid(LO, HI), Target::Product);
    let params = random_params(model.param_count(), 1.0, 8);
    for q in queries(200, 4) {
        let (mut a, mut b) = ([0.0f32; 48], [0.0f32; 48]);
        encode_inputs(&params, &model.grid, model.target, &q, &mut a);
        let o = grid_forward_fast(&params, &model.grid, q.position(), &mut b, 0);
        encode_product_inputs(model.target, &q, &mut b, o);
        assert!(same_bits(&a, &b));
    }
}

/// NPM: `decode_batch` is the per-query decoder applied to the batched
/// network's outputs, for every lane of batches of several lengths.
#[test]
fn npm_decode_batch_composes_encoder_network_and_decoder() {
    type Net = Mlp<16, 32, NPM_OUTPUTS, 2>;
    let model = NpmCompactRadiance::new(guiding::config::compact_grid(LO, HI), Target::Radiance);
    let params = random_params(model.param_count(), 0.5, 11);
    for n in [1, 7, 64, 65, 300] {
        let qs = queries(n, n as u64);
        let mut out = vec![VmfMixture::ZERO; n];
        model.decode_batch(&params, &qs, &mut out);
        let xs: Vec<[f32; 16]> = qs
            .iter()
            .map(|q| {
                let mut x = [0.0; 16];
                encode_inputs(&params, &model.grid, model.target, q, &mut x);
                x
            })
            .collect();
        let mut ys = vec![[0.0f32; NPM_OUTPUTS]; n];
        Net::infer_batch(&params, model.mlp_offset as usize, &xs, &mut ys);
        for i in 0..n {
            let raw = std::array::from_fn(|k| std::array::from_fn(|r| ys[i][4 * k + r]));
            assert!(same_bits(
                &vmf_floats(&out[i]),
                &vmf_floats(&VmfMixture::decode(&raw))
            ));
        }
    }
}

fn small_config(rep: Representation, target: Target, size: ModelSize) -> GuidingConfig {
    GuidingConfig {
        representation: rep,
        target,
        ..GuidingConfig::npm_radiance()
    }
    .with_size(size)
    .with_training(FieldConfig::DEFAULT.with_batch_size(256).with_threads(1))
}

fn training_samples(n: usize, seed: u64) -> Vec<TrainingSample> {
    let mut rng = Pcg32::new(seed, 5);
    (0..n)
        .map(|i| {
            let q = query(&mut rng);
            let wi = square_to_uniform_sphere(rng.next_vec2());
            let l = if wi.z > 0.8 { 5.0 } else { 0.2 };
            let mut s = TrainingSample::new(q, wi.to_array(), [l; 3], INV_FOUR_PI, 0.1, [0.3; 3]);
            // Invalid and zero-weight samples mixed in: both paths skip them.
            match i % 13 {
                3 => s.radiance = [f32::NAN; 3],
                7 => s.radiance = [0.0; 3],
                11 => s.sample_pdf = 0.0,
                _ => {}
            }
            s
        })
        .collect()
}

/// Where the batched network (FMA, blocked) and the per-query network both
/// run, results differ by the network's rounding: each output within the
/// FMA bound of `tests/mlp.rs` (below 10⁻⁶ relative for these small,
/// trained networks), which the decoders (softmax, exp, sigmoid, sin/cos:
/// Lipschitz in log space with constants ≤ 4 for the pdfs) amplify at most
/// a few times. 10⁻⁴ leaves two orders of magnitude of margin; a wrong lane,
/// a wrong model or a stale parameter set moves these values by percents.
const NETWORK_REL: f32 = 1e-4;

/// Through the facade: every representation's batch decode, selection
/// probability, batched samples and pdfs agree with the per-lane
/// `Distribution` (decoded per query), and sample pdfs with the pdfs.
#[test]
fn facade_batch_agrees_with_per_lane_distributions() -> Result<(), GuidingError> {
    for rep in Representation::ALL {
        for target in [Target::Radiance, Target::Product] {
            let mut field = GuidingField::new(small_config(rep, target, ModelSize::Small), LO, HI)?;
            // A few steps, so the network is not at its initialisation.
            for _ in 0..3 {
                field.add_samples(&training_samples(512, 1));
                field.update();
            }
            let qs = queries(150, 2);
            let mut batch = DistributionBatch::new();
            field.decode_batch(&qs, &mut batch);
            assert_eq!(batch.len(), qs.len());
            let mut rng = Pcg32::new(4, 4);
            let lanes: Vec<u32> = (0..400).map(|_| rng.next_u32() % qs.len() as u32).collect();
            let u: Vec<Vec2> = lanes.iter().map(|_| rng.next_vec2()).collect();
            let mut samples = vec![
                guiding::DirectionSample {
                    direction: Vec3::ZERO,
                    pdf: 0.0
                };
                lanes.len()
            ];
            field.sample_decoded(&batch, &lanes, &u, &mut samples)?;
            let dirs: Vec<Vec3> = samples.iter().map(|s| s.direction).collect();
            let mut pdfs = vec![0.0f32; lanes.len()];
            field.pdf_decoded(&batch, &lanes, &dirs, &mut pdfs)?;
            for (k, &l) in lanes.iter().enumerate() {
                let d = field.distribution(&qs[l as usize]);
                assert!(
                    (batch.selection_probability(l as usize) - d.selection_probability()).abs()
                        <= NETWORK_REL * d.selection_probability(),
                    "{rep:?} {target:?}"
                );
                let s = d.sample(u[k]);
                let rel = |a: f32, b: f32| (a - b).abs() / b.abs().max(1e-30);
                assert!(
                    s.direction.distance(samples[k].direction) <= NETWORK_REL,
                    "{rep:?} {target:?} lane {l}: {:?} vs {:?}",
                    s.direction,
                    samples[k].direction
                );
                assert!(
                    rel(s.pdf, samples[k].pdf) <= 1e-4,
                    "{rep:?}: {} vs {}",
                    s.pdf,
                    samples[k].pdf
                );
                assert!(rel(d.pdf(dirs[k]), pdfs[k]) <= 1e-4);
                // The sampled direction's pdf is the pdf of that direction.
                assert!(
                    rel(samples[k].pdf, pdfs[k]) <= 1e-4,
                    "{rep:?}: {} vs {}",
                    samples[k].pdf,
                    pdfs[k]
                );
                assert!(pdfs[k] > 0.0 && pdfs[k].is_finite());
            }
        }
    }
    Ok(())
}

#[test]
fn batch_use_is_checked() -> Result<(), GuidingError> {
    let config = small_config(Representation::Npm, Target::Radiance, ModelSize::Small);
    let mut field = GuidingField::new(config, LO, HI)?;
    let other = GuidingField::new(config, LO, HI)?;
    let qs = queries(10, 1);
    let mut batch = DistributionBatch::new();
    field.decode_batch(&qs, &mut batch);
    let mut out = vec![
        guiding::DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0
        };
        2
    ];
    let u = [Vec2::splat(0.5); 2];
    // Lane out of range, lengths, another field: errors, nothing written.
    assert!(matches!(
        field.sample_decoded(&batch, &[0, 10], &u, &mut out),
        Err(GuidingError::LengthMismatch { .. })
    ));
    assert!(matches!(
        field.sample_decoded(&batch, &[0], &u, &mut out),
        Err(GuidingError::LengthMismatch { .. })
    ));
    assert!(matches!(
        other.pdf_decoded(&batch, &[0], &[Vec3::Z], &mut [0.0]),
        Err(GuidingError::StaleDistribution { .. })
    ));
    assert!(out.iter().all(|s| s.pdf == 0.0));
    // After an update that changed the parameters the batch is stale.
    field.add_samples(&training_samples(256, 3));
    assert!(field.update().steps > 0);
    assert!(matches!(
        field.sample_decoded(&batch, &[0, 1], &u, &mut out),
        Err(GuidingError::StaleDistribution { .. })
    ));
    // An empty request reads nothing from the batch: answered, stale or not
    // (a wavefront that guided no vertex decoded none).
    assert!(field.sample_decoded(&batch, &[], &[], &mut []).is_ok());
    assert!(field.pdf_decoded(&batch, &[], &[], &mut []).is_ok());
    assert!(other.pdf_decoded(&batch, &[], &[], &mut []).is_ok());
    // get() gives values that attach only to a current field.
    let old = batch.get(3).expect("lane 3");
    assert!(field.attach(old).is_err());
    field.decode_batch(&qs, &mut batch);
    assert!(field.attach(batch.get(3).expect("lane 3")).is_ok());
    assert!(batch.get(10).is_none());
    Ok(())
}

/// GPU outputs go through the same decoders: raw outputs written by the
/// model's own `write_raw` decode to the per-query distributions.
#[test]
fn raw_outputs_decode_like_the_field() -> Result<(), GuidingError> {
    use guiding_core::model::RawOutputs;
    for rep in [Representation::Npm, Representation::Nasg] {
        let field = GuidingField::new(
            small_config(rep, Target::Product, ModelSize::Compact),
            LO,
            HI,
        )?;
        let export = field.export_model();
        let qs = queries(40, 6);
        let raw = field_raw(&field, &qs, export.raw_outputs);
        let mut batch = DistributionBatch::new();
        field.decode_raw_batch(&raw, &mut batch)?;
        assert_eq!(batch.len(), qs.len());
        let lanes: Vec<u32> = (0..qs.len() as u32).collect();
        let mut pdfs = vec![0.0; qs.len()];
        field.pdf_decoded(&batch, &lanes, &vec![Vec3::Z; qs.len()], &mut pdfs)?;
        // The raw outputs come from the per-query network, the field's
        // distributions from the batched one.
        for (q, p) in qs.iter().zip(&pdfs) {
            let r = field.distribution(q).pdf(Vec3::Z);
            assert!((p - r).abs() <= NETWORK_REL * r, "{p} vs {r}");
        }
        assert!(field
            .decode_raw_batch(&raw[..raw.len() - 1], &mut batch)
            .is_err());
        let _ = NasgCompactProduct::RAW_OUTPUTS;
    }
    let df = GuidingField::new(
        small_config(Representation::DfLinear, Target::Radiance, ModelSize::Small),
        LO,
        HI,
    )?;
    assert!(df
        .decode_raw_batch(&[0.0; 32], &mut DistributionBatch::new())
        .is_err());
    Ok(())
}

/// The per-query raw outputs (what a GPU's inference kernel writes).
fn field_raw(field: &GuidingField, qs: &[QueryPoint], r: usize) -> Vec<f32> {
    use guiding_core::model::nasg::NasgCompactProduct as N;
    use guiding_core::model::RawOutputs;
    let export = field.export_model();
    let mut raw = vec![0.0; qs.len() * r];
    let params = &export.state.ema;
    if export.kernel_prefix.starts_with("npm") {
        let m: NpmCompactProduct = *bytemuck::from_bytes(&export.model);
        for (i, q) in qs.iter().enumerate() {
            m.write_raw(params, q, &mut raw, i * r);
        }
    } else {
        let m: N = *bytemuck::from_bytes(&export.model);
        for (i, q) in qs.iter().enumerate() {
            m.write_raw(params, q, &mut raw, i * r);
        }
    }
    raw
}

/// DF: the decoded vertex carries what sampling needs. A vertex built by
/// the per-query kernels (base input, marginal) samples and evaluates
/// exactly like the model's per-query `sample` / `pdf`; the batched decode
/// gives the batched network's marginal bit for bit; the batched
/// conditional agrees lane by lane with itself (a lane alone or in a
/// batch) and with the per-query conditional within `NETWORK_REL`.
#[test]
fn df_vertices_sample_and_evaluate_like_the_model() {
    type Marginal = Mlp<16, 32, 32, 2>;
    let (model, params, qs, vs) = df_vertices(21, 90, 8);
    let mut rng = Pcg32::new(1, 9);
    let mut lanes = Vec::new();
    let mut dirs = Vec::new();
    let mut us = Vec::new();
    for (i, (q, v)) in qs.iter().zip(&vs).enumerate() {
        // Per-query vertex: exactly the model.
        let mut base = [0.0f32; 16];
        encode_inputs(&params, &model.grid, model.target, q, &mut base);
        let mut pq = DfVertex::ZERO;
        pq.base[..16].copy_from_slice(&base);
        pq.marginal = model.marginal(&params, q);
        let u = rng.next_vec2();
        let (a, b) = (
            model.sample(&params, q, u),
            model.sample_vertex(&params, &pq, u),
        );
        assert_eq!((a.direction, a.pdf), (b.direction, b.pdf));
        let d = square_to_uniform_sphere(rng.next_vec2());
        assert_eq!(model.pdf(&params, q, d), model.pdf_vertex(&params, &pq, d));
        // Batched vertex: the batched marginal network's logits, decoded.
        assert_eq!(v.base, pq.base);
        let mut logits = [[0.0f32; 32]];
        Marginal::infer_batch(
            &params,
            model.marginal_offset as usize,
            &[base],
            &mut logits,
        );
        let m = guiding_core::pdf1d::Pdf1d::from_logits(
            &logits[0],
            Interpolation::Linear,
            guiding_core::pdf1d::Boundary::Wrap,
        );
        assert!(same_bits(&v.marginal.values, &m.values));
        lanes.push(i as u32);
        dirs.push(d);
        us.push(u);
    }
    let rel = |a: f32, b: f32| (a - b).abs() / b.abs().max(1e-30);
    let mut pdfs = vec![0.0f32; lanes.len()];
    model.pdf_vertices(&params, &vs, &lanes, &dirs, &mut pdfs);
    let mut samples = vec![
        guiding::DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0
        };
        lanes.len()
    ];
    model.sample_vertices(&params, &vs, &lanes, &us, &mut samples);
    for (k, &l) in lanes.iter().enumerate() {
        let mut one = [0.0f32];
        model.pdf_vertices(&params, &vs, &[l], &dirs[k..=k], &mut one);
        assert_eq!(
            one[0].to_bits(),
            pdfs[k].to_bits(),
            "lane {l} alone vs in the batch"
        );
        let v = &vs[l as usize];
        assert!(rel(pdfs[k], model.pdf_vertex(&params, v, dirs[k])) <= NETWORK_REL);
        let s = model.sample_vertex(&params, v, us[k]);
        assert!(s.direction.distance(samples[k].direction) <= NETWORK_REL);
        assert!(rel(samples[k].pdf, s.pdf) <= NETWORK_REL);
    }
}

/// A tabulated DF vertex keeps the marginal and holds, as row `r`, the
/// conditional at the row centre `ε₁ = (r + ½)/32`: at directions whose
/// square point has that `ε₁` exactly its density is the vertex's own, bit
/// for bit; elsewhere in the row it is not (the table is piecewise constant
/// in `ε₁`, the network continuous).
#[test]
fn tabulated_df_vertices_hold_the_conditional_at_the_row_centres() {
    use guiding_core::factorised::{direction_from_square, square_from_direction};
    use guiding_core::model::batched::DfTable;
    let (model, params, _, vs) = df_vertices(23, 40, 9);
    let mut tables = vec![DfTable::ZERO; vs.len()];
    model.tabulate_vertices(&params, &vs, &mut tables);
    let mut rng = Pcg32::new(3, 9);
    let (mut centred, mut off_centre_differs, mut off_centre) = (0, 0, 0);
    for (l, (v, t)) in vs.iter().zip(&tables).enumerate() {
        assert!(
            same_bits(&t.marginal.values, &v.marginal.values),
            "vertex {l}"
        );
        for r in 0..32 {
            let e1 = (r as f32 + 0.5) / 32.0;
            let mut network = [0.0f32];
            // A direction whose square point keeps ε₁ exactly.
            let d = (0..32)
                .map(|_| direction_from_square(Vec2::new(e1, rng.uniform(0.02, 0.98))))
                .find(|&d| square_from_direction(d).x == e1);
            if let Some(d) = d {
                model.pdf_vertices(&params, &vs, &[l as u32], &[d], &mut network);
                assert_eq!(
                    t.pdf(d).to_bits(),
                    network[0].to_bits(),
                    "vertex {l} row {r}"
                );
                centred += 1;
            }
            let d =
                direction_from_square(Vec2::new((r as f32 + 0.1) / 32.0, rng.uniform(0.02, 0.98)));
            model.pdf_vertices(&params, &vs, &[l as u32], &[d], &mut network);
            off_centre += 1;
            off_centre_differs += usize::from(t.pdf(d) != network[0]);
        }
    }
    assert!(
        centred > 40 * 32 / 2,
        "only {centred} exact row-centre directions"
    );
    assert!(
        off_centre_differs > off_centre / 2,
        "the table matched the network off the row centres ({off_centre_differs} of {off_centre})"
    );
}

/// The batched gradient (what `Field::update` trains with) is the sum of
/// the per-sample gradients, invalid samples skipped alike.
#[test]
fn batched_gradient_is_the_per_sample_gradient() {
    let npm = NpmCompactProduct::new(guiding::config::compact_grid(LO, HI), Target::Product);
    let nasg = NasgCompactProduct::new(guiding::config::compact_grid(LO, HI), Target::Product);
    let df = df_compact();
    check_gradient(&npm, 1);
    check_gradient(&nasg, 2);
    check_gradient(&df, 3);
}

fn check_gradient<M: GuidingModel>(model: &M, seed: u64) {
    let n = model.param_count();
    let params = random_params(n, 0.3, seed);
    let samples = training_samples(333, seed);
    let mut batched = vec![0.0f32; n];
    let loss_b = model.accumulate_gradient_batch(&params, &samples, &mut batched);
    let mut reference = vec![0.0f32; n];
    let mut loss_r = 0.0f64;
    for s in &samples {
        loss_r += f64::from(model.accumulate_gradient(&params, s, reference.as_mut_slice()));
    }
    // The network's gradients differ by its FMA rounding (tests/mlp.rs
    // bounds them); summed over 333 samples the comparison is the
    // tiny-cuda-nn one: symmetric relative error per element, the worst 1 %
    // ignored (grid gradients sum few terms and can cancel), at most 10⁻³.
    assert!((loss_b - loss_r).abs() <= 1e-6 * loss_r.abs());
    let scale = reference.iter().fold(0.0f32, |m, g| m.max(g.abs()));
    let mut errs: Vec<f32> = batched
        .iter()
        .zip(&reference)
        .filter(|(a, b)| a.abs().max(b.abs()) > 1e-6 * scale)
        .map(|(a, b)| (a - b).abs() / (0.5 * (a.abs() + b.abs())))
        .collect();
    assert!(errs.len() > 100);
    errs.sort_by(f32::total_cmp);
    let p99 = errs[errs.len() * 99 / 100];
    assert!(p99 <= 1e-3, "99th percentile relative gradient error {p99}");
    // Zero contributions stay zero (skipped samples add nothing).
    for (a, b) in batched.iter().zip(&reference) {
        assert_eq!(*a == 0.0, *b == 0.0);
    }
}

/// The batched cosine product is `product_with_clamped_cosine` up to the
/// rounding of its different evaluation (linear-space weights instead of
/// `ln`, inlined `expm1`): every field within 8 ulp-scale relative error
/// (2⁻²⁴ · 2⁷ ≈ 7.6·10⁻⁶) or 10⁻⁶ absolute for means near zero.
#[test]
fn batched_cosine_product_is_the_per_mixture_product() {
    use guiding_core::model::batched::cosine_product_batch;
    let rows = raw_rows(300, 77);
    let mut ms = vec![VmfMixture::ZERO; rows.len()];
    decode_vmf_batch(&rows, &mut ms);
    let mut rng = Pcg32::new(3, 3);
    let normals: Vec<Vec3> = (0..ms.len())
        .map(|i| match i % 7 {
            0 => Vec3::ZERO,
            1 => Vec3::new(0.0, 0.0, -3.0),
            _ => square_to_uniform_sphere(rng.next_vec2()),
        })
        .collect();
    let mut batched = ms.clone();
    cosine_product_batch(&mut batched, &normals);
    let tol = 128.0 * f32::EPSILON / 2.0;
    for ((m, b), &n) in ms.iter().zip(&batched).zip(&normals) {
        let r = m.product_with_clamped_cosine(n);
        for (x, y) in vmf_floats(b).iter().zip(vmf_floats(&r)) {
            assert!(
                (x - y).abs() <= tol * y.abs().max(x.abs()) + 1e-6,
                "{x} vs {y} (normal {n:?})\n{b:?}\n{r:?}"
            );
        }
        let w: f32 = b.weight.iter().sum();
        assert!((w - 1.0).abs() <= 1e-5);
        // No surface: the mixture exactly as it was.
        if n == Vec3::ZERO {
            assert_eq!(vmf_floats(b), vmf_floats(m));
        }
    }
}

/// The batched lobe product is `product_with_lobe` (what `apply_lobe_product` multiplies
/// the guides of medium vertices by) up to rounding, the same tolerance as the cosine
/// product, from a flat lobe to the sharpest HG fit (`κ ≈ 1000`, whose exponents underflow
/// `f32` without the subtracted maximum); `κ ≤ 0`, NaN `κ` and non-finite axes leave the
/// mixture exactly as it was.
#[test]
fn batched_lobe_product_is_the_per_mixture_product() {
    use guiding_core::model::batched::lobe_product_batch;
    let rows = raw_rows(400, 78);
    let mut ms = vec![VmfMixture::ZERO; rows.len()];
    decode_vmf_batch(&rows, &mut ms);
    let mut rng = Pcg32::new(3, 4);
    let kappas = [0.05f32, 0.7, 3.4, 40.0, 400.0, 998.0, 0.0, -1.0, f32::NAN];
    let lobes: Vec<[f32; 4]> = (0..ms.len())
        .map(|i| {
            let a = match i % 11 {
                0 => Vec3::ZERO,
                1 => Vec3::new(f32::NAN, 0.0, 1.0),
                2 => Vec3::new(0.0, -2.0, 0.0),
                _ => square_to_uniform_sphere(rng.next_vec2()),
            };
            [a.x, a.y, a.z, kappas[i % kappas.len()]]
        })
        .collect();
    let mut batched = ms.clone();
    lobe_product_batch(&mut batched, &lobes);
    let tol = 128.0 * f32::EPSILON / 2.0;
    let mut multiplied = 0;
    for ((m, b), l) in ms.iter().zip(&batched).zip(&lobes) {
        let (a, k) = (Vec3::new(l[0], l[1], l[2]), l[3]);
        if !(k > 0.0 && k.is_finite() && a.is_finite()) {
            assert_eq!(vmf_floats(b), vmf_floats(m), "lobe {l:?}");
            continue;
        }
        multiplied += 1;
        let r = m.product_with_lobe(guiding_core::frame::normalize_or(a, Vec3::Z), k);
        for (x, y) in vmf_floats(b).iter().zip(vmf_floats(&r)) {
            assert!(
                (x - y).abs() <= tol * y.abs().max(x.abs()) + 1e-6,
                "{x} vs {y} (lobe {l:?})\n{b:?}\n{r:?}"
            );
        }
        let w: f32 = b.weight.iter().sum();
        assert!((w - 1.0).abs() <= 1e-5, "weights sum to {w} (lobe {l:?})");
    }
    assert!(multiplied > ms.len() / 2);
}

/// The lane-parallel NASG decoder against `NasgMixture::decode` (libm's
/// `sincosf` / `logf` / `expm1f` there, the inlined functions here, each
/// within 2 ulp; the angles in turns skip the rounding of `π s`): frame
/// components within 4·10⁻⁷ absolute, λ, `a`, weights within 16 ulp
/// relative, `ln` normaliser within 2·10⁻⁶ absolute, the selection
/// probability exactly (the same code).
#[test]
fn batched_nasg_decoder_matches_the_per_query_decoder() {
    use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
    use guiding_core::model::batched::decode_nasg_batch;
    use guiding_core::model::nasg::{NASG_LOBES, NASG_OUTPUTS};
    let mut rng = Pcg32::new(12, 1);
    let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, -1e30, 0.0];
    let rows: Vec<[f32; NASG_OUTPUTS]> =
        rows_with_specials(777, &mut rng, (9, 8), &specials, |rng, _| {
            rng.uniform(-12.0, 12.0)
        });
    let mut out = vec![NasgMixture::ZERO; rows.len()];
    decode_nasg_batch(&rows, &mut out);
    let close = |a: f32, b: f32, abs: f32, rel: f32| (a - b).abs() <= abs + rel * b.abs();
    let ulp16 = 16.0 * f32::EPSILON;
    for (row, m) in rows.iter().zip(&out) {
        let raw: [[f32; NASG_RAW_PER_LOBE]; NASG_LOBES] =
            std::array::from_fn(|k| std::array::from_fn(|r| row[k * NASG_RAW_PER_LOBE + r]));
        let r = NasgMixture::decode(&raw, row[NASG_OUTPUTS - 1]);
        assert_eq!(m.selection_probability, r.selection_probability);
        for k in 0..NASG_LOBES {
            for (a, b) in [
                (m.x_x[k], r.x_x[k]),
                (m.x_y[k], r.x_y[k]),
                (m.x_z[k], r.x_z[k]),
                (m.y_x[k], r.y_x[k]),
                (m.y_y[k], r.y_y[k]),
                (m.y_z[k], r.y_z[k]),
                (m.z_x[k], r.z_x[k]),
                (m.z_y[k], r.z_y[k]),
                (m.z_z[k], r.z_z[k]),
            ] {
                assert!(close(a, b, 1.2e-6, 0.0), "frame {a} vs {b}: {row:?}");
            }
            assert!(close(m.lambda[k], r.lambda[k], 0.0, ulp16));
            assert!(close(m.a[k], r.a[k], 0.0, ulp16));
            assert!(close(m.weight[k], r.weight[k], 1e-30, ulp16));
            assert_eq!(m.epsilon[k], r.epsilon[k]);
            assert!(
                close(m.log_norm[k], r.log_norm[k], 2e-6, 0.0),
                "{} vs {}",
                m.log_norm[k],
                r.log_norm[k]
            );
            assert!(close(m.one_minus_e2l[k], r.one_minus_e2l[k], 0.0, ulp16));
        }
    }
}
