//! Difftests: every batch kernel of `guiding_core::batch` run on the CPU
//! (the function called directly) and as SPIR-V on Vulkan (lavapipe in CI),
//! same inputs, outputs compared element by element.
//!
//! Tolerances: the GPU runs the same f32 operations, but the SPIR-V compiler
//! and the driver may contract `a·b + c` into fused multiply-adds and use
//! other (correctly rounded or 1-ulp) transcendental implementations, so
//! results agree to rounding, not bit for bit. A value `y` computed from
//! terms of magnitude up to `S` can differ by about `k·ε·S` after `k`
//! operations; every check below is `|gpu − cpu| ≤ 1e-5 · max(|cpu|,
//! floor)`, with the floor stated per quantity (the scale of the terms it
//! sums). Directional samples choose a lobe / bin by comparing `u` to a
//! CDF; when `u` lies within rounding of a boundary the two sides may pick
//! neighbours, so sampled directions are compared only where the CPU's
//! margin to every boundary exceeds 1e-4, and the rest is counted and
//! bounded (it must stay below 1 % of the batch, which the margin makes a
//! ~1e-3 event).
#![cfg(feature = "shaders")]

use guiding_core::batch::{self, AdamArgs};
use guiding_core::glam::{Vec2, Vec3};
use guiding_core::model::df::{DfCompactProduct, DfSmallProduct, DfSmallRadiance};
use guiding_core::model::nasg::{NasgCompactProduct, NasgSmallProduct, NasgSmallRadiance};
use guiding_core::model::npm::{
    NpmCompactProduct, NpmCompactRadiance, NpmRadiance, NpmSmallProduct, NpmSmallRadiance,
};
use guiding_core::model::{GuidingModel, QueryPoint, RawOutputs};
use guiding_core::optim::{ema_weight, AdamConfig, AdamStepFactors};
use guiding_core::pdf1d::Interpolation;
use guiding_core::rng::Rng;
use guiding_core::sample::TrainingSample;
use guiding_gpu::{
    DeviceSelection, GpuContext, GpuError, GpuModel, ModelEntryPoints, StepOutcome, TrainOptions,
};

const LO: [f32; 3] = [-1.0, 0.0, -2.0];
const HI: [f32; 3] = [1.0, 3.0, 2.0];

/// The Vulkan context of the tests, or `None` (with the reason printed) when
/// the machine has no Vulkan device and `GUIDING_REQUIRE_VULKAN` is not 1.
fn context() -> Option<GpuContext> {
    match GpuContext::new(DeviceSelection::Auto) {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            let required = std::env::var("GUIDING_REQUIRE_VULKAN").is_ok_and(|v| v == "1");
            assert!(
                !required,
                "GUIDING_REQUIRE_VULKAN=1 but no Vulkan device: {e}"
            );
            eprintln!("skipped: no Vulkan device ({e})");
            None
        }
    }
}

fn unit(rng: &mut Rng) -> [f32; 3] {
    loop {
        let v = [
            rng.next_symmetric_f32(),
            rng.next_symmetric_f32(),
            rng.next_symmetric_f32(),
        ];
        let l2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        if l2 > 1e-4 && l2 <= 1.0 {
            let s = 1.0 / l2.sqrt();
            return [v[0] * s, v[1] * s, v[2] * s];
        }
    }
}

fn position(rng: &mut Rng) -> [f32; 3] {
    let mut p = [0.0; 3];
    for (k, x) in p.iter_mut().enumerate() {
        *x = LO[k] + (HI[k] - LO[k]) * rng.next_f32();
    }
    p
}

fn queries(n: usize, seed: u32) -> Vec<QueryPoint> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let p = position(&mut rng);
            let roughness = rng.next_f32();
            let normal = unit(&mut rng);
            QueryPoint::new(p, normal, unit(&mut rng), roughness)
        })
        .collect()
}

fn randoms(n: usize, seed: u32) -> Vec<[f32; 4]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| [rng.next_f32(), rng.next_f32(), 0.0, 0.0])
        .collect()
}

fn directions(n: usize, seed: u32) -> Vec<[f32; 4]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let d = unit(&mut rng);
            [d[0], d[1], d[2], 0.0]
        })
        .collect()
}

fn training_samples(n: usize, seed: u32) -> Vec<TrainingSample> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let r = 0.1 + 4.0 * rng.next_f32();
            // Drawn in the order of the struct's fields.
            let p = position(&mut rng);
            let roughness = rng.next_f32();
            let normal = unit(&mut rng);
            let sample_pdf = 0.05 + rng.next_f32();
            let wo = unit(&mut rng);
            let bsdf_pdf = 0.05 + rng.next_f32();
            TrainingSample::new(
                QueryPoint::new(p, normal, wo, roughness),
                unit(&mut rng),
                [r, 0.5 * r, 0.25 * r],
                sample_pdf,
                bsdf_pdf,
                [0.3, 0.3, 0.3],
            )
        })
        .collect()
}

/// Initial parameters of `model`, perturbed so that the grid features and
/// the network outputs are far from their near-zero initial values.
fn parameters<M: GuidingModel>(model: &M, seed: u32) -> Vec<f32> {
    let mut p = vec![0.0f32; model.param_count()];
    model.init(&mut p, seed);
    let mut rng = Rng::new(seed ^ 0x5eed);
    for x in &mut p {
        *x += 0.3 * rng.next_symmetric_f32();
    }
    p
}

/// `|gpu − cpu| ≤ 1e-5 · max(|cpu|, floor)` for every element; returns the
/// largest ratio of the error to its bound.
fn check_close(what: &str, gpu: &[f32], cpu: &[f32], floor: f32) -> f32 {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    let mut worst = 0.0f32;
    for (i, (&g, &c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(
            g.is_finite() && c.is_finite(),
            "{what}[{i}]: gpu {g}, cpu {c}"
        );
        let bound = 1e-5 * c.abs().max(floor);
        let err = (g - c).abs();
        assert!(
            err <= bound,
            "{what}[{i}]: gpu {g}, cpu {c} (|Δ| {err:e} > {bound:e})"
        );
        worst = worst.max(err / bound);
    }
    worst
}

fn upload<M: GuidingModel + bytemuck::Pod>(
    ctx: GpuContext,
    model: &M,
    prefix: &'static str,
    raw_outputs: u32,
    params: &[f32],
) -> Result<GpuModel, GpuError> {
    let zeros = vec![0.0f32; params.len()];
    GpuModel::new(
        ctx,
        ModelEntryPoints {
            prefix,
            raw_outputs,
        },
        bytemuck::bytes_of(model),
        params,
        &zeros,
        &zeros,
        params,
        0,
    )
}

/// How much the CPU density at `d` moves when `d` moves by a few ulp
/// (along two tangents, both ways): the local condition of the pdf. DF
/// maps ω to the square (atan2, acos) and feeds ε₁ through 12
/// triangle-wave octaves, which amplify rounding in ε₁ by up to 2¹¹; the
/// mixtures are far better conditioned.
fn pdf_sensitivity<M: GuidingModel>(model: &M, params: &[f32], q: &QueryPoint, d: Vec3) -> f32 {
    local_sensitivity(&|x| model.pdf(params, q, x), d)
}

/// Sample kernel: GPU `[ω, pdf]` against the CPU's, and the GPU's pdf
/// against the CPU pdf of the GPU's direction (always comparable).
fn check_sample<M: GuidingModel>(
    gpu: &mut GpuModel,
    model: &M,
    params: &[f32],
    q: &[QueryPoint],
    what: &str,
    pdf_rel: f32,
) {
    let u = randoms(q.len(), 7);
    let mut out = vec![[0.0f32; 4]; q.len()];
    gpu.sample(q, &u, &mut out).expect("sample kernel");
    let mut cpu = vec![[0.0f32; 4]; q.len()];
    for i in 0..q.len() {
        batch::sample_element(model, params, q, &u, &mut cpu, i);
    }
    let mut worst = 0.0f32;
    let mut differ = 0usize;
    let mut max_dist = 0.0f32;
    for i in 0..q.len() {
        let g = out[i];
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        assert!(
            (len - 1.0).abs() < 1e-4,
            "{what}: sample {i} not unit: {g:?}"
        );
        let c = cpu[i];
        let dist = ((g[0] - c[0]).powi(2) + (g[1] - c[1]).powi(2) + (g[2] - c[2]).powi(2)).sqrt();
        if dist > 1e-4 {
            // The two sides of a lobe / bin boundary: both must be valid
            // samples of the model (density > 0 where they landed).
            assert!(
                model.pdf(params, &q[i], batch::unpack_direction(g)) > 0.0,
                "{what}: GPU sample {i} where the CPU density is 0"
            );
            differ += 1;
        } else {
            // Same branch: the pdfs differ by rounding, plus what the
            // density itself changes between the two directions (sharp
            // lobes amplify direction rounding), plus the CPU's own gap
            // between its sample pdf and its pdf of that direction.
            max_dist = max_dist.max(dist);
            let e_c = model.pdf(params, &q[i], batch::unpack_direction(c));
            let e_g = model.pdf(params, &q[i], batch::unpack_direction(g));
            // The sampler's own condition: its pdf when u moves by a few
            // ulp (DF feeds ε₁ through 12 triangle-wave octaves, which
            // amplify rounding in ε₁ by up to 2¹¹).
            let mut sens = 0.0f32;
            for k in [-4.0f32, 4.0] {
                let up = Vec2::new(u[i][0] * (1.0 + k * f32::EPSILON), u[i][1]);
                let d = model.sample(params, &q[i], up);
                if (d.direction - batch::unpack_direction(c)).length() <= 1e-4 {
                    sens = sens.max((d.pdf - c[3]).abs());
                }
            }
            let bound = pdf_rel * c[3].abs().max(1e-2)
                + (e_g - e_c).abs()
                + (c[3] - e_c).abs()
                + sens
                + pdf_sensitivity(model, params, &q[i], batch::unpack_direction(c));
            let err = (g[3] - c[3]).abs();
            assert!(
                g[3].is_finite() && err <= bound,
                "{what}: sample {i} pdf gpu {} cpu {} (|Δ| {err:e} > {bound:e})",
                g[3],
                c[3]
            );
            worst = worst.max(err / bound);
        }
    }
    assert!(
        differ * 100 < q.len(),
        "{what}: {differ} of {} sampled directions differ from the CPU's",
        q.len()
    );
    eprintln!(
        "{what} sample: {} queries, {differ} directions on the other side of a CDF boundary, \
         the others within {max_dist:.1e} with pdf error at most {worst:.3} of the bound",
        q.len()
    );
}

fn check_pdf<M: GuidingModel>(
    gpu: &mut GpuModel,
    model: &M,
    params: &[f32],
    q: &[QueryPoint],
    what: &str,
    pdf_rel: f32,
) {
    let d = directions(q.len(), 11);
    let mut out = vec![0.0f32; q.len()];
    gpu.pdf(q, &d, &mut out).expect("pdf kernel");
    let mut cpu = vec![0.0f32; q.len()];
    for i in 0..q.len() {
        batch::pdf_element(model, params, q, &d, &mut cpu, i);
    }
    let mut worst = 0.0f32;
    for i in 0..q.len() {
        let dir = batch::unpack_direction(d[i]);
        let bound = pdf_rel * cpu[i].abs().max(1e-2) + pdf_sensitivity(model, params, &q[i], dir);
        let err = (out[i] - cpu[i]).abs();
        assert!(
            out[i].is_finite() && err <= bound,
            "{what} pdf[{i}]: gpu {}, cpu {} (|Δ| {err:e} > {bound:e})",
            out[i],
            cpu[i]
        );
        worst = worst.max(err / bound);
    }
    eprintln!("{what} pdf: worst error {worst:.3} of the bound");
}

fn check_infer<M: RawOutputs>(
    gpu: &mut GpuModel,
    model: &M,
    params: &[f32],
    q: &[QueryPoint],
    what: &str,
) {
    let r = M::RAW_OUTPUTS;
    let mut out = vec![0.0f32; q.len() * r];
    gpu.infer(q, &mut out).expect("infer kernel");
    let mut cpu = vec![0.0f32; q.len() * r];
    for i in 0..q.len() {
        batch::infer_element(model, params, q, &mut cpu, i);
    }
    let worst = check_close(&format!("{what} infer"), &out, &cpu, 1.0);
    eprintln!("{what} infer: worst error {worst:.3} of the bound");
}

/// The GPU gradient of a batch against the CPU's, then one Adam step.
///
/// The GPU adds the per-sample gradients in the order its atomics land, the
/// CPU in sample order; each per-sample term also carries the rounding of
/// its own forward/backward pass. So per parameter the two means may differ
/// by the reordering bound `2·n·ε·S/n` plus `r·S/n`, with `S = Σ|term|`
/// and `r` the per-term tolerance (1e-5; 1e-3 for DF, whose triangle-wave
/// encoding amplifies the few-ulp differences of ε₁ = atan2(…)/2π by up
/// to 2¹¹ before the conditional network)
/// (computed here from the per-sample CPU gradients).
fn check_train_step<M: GuidingModel>(
    gpu: &mut GpuModel,
    model: &M,
    params: &[f32],
    what: &str,
    term_rel: f32,
) {
    let samples = training_samples(300, 99);
    let n = params.len();
    let count = samples.len() as f32;
    let (g_gpu, loss_gpu) = gpu.gradient(&samples).expect("gradient kernel");

    let mut g_cpu = vec![0.0f32; n];
    let mut abs_sum = vec![0.0f32; n];
    let mut loss_cpu = 0.0f64;
    let mut term = vec![0.0f32; n];
    for s in &samples {
        term.iter_mut().for_each(|x| *x = 0.0);
        loss_cpu += f64::from(model.accumulate_gradient(params, s, &mut term[..]));
        for j in 0..n {
            g_cpu[j] += term[j];
            abs_sum[j] += term[j].abs();
        }
    }
    loss_cpu /= f64::from(count);
    let eps = f32::EPSILON;
    let bound: Vec<f32> = abs_sum
        .iter()
        .map(|&a| (2.0 * count * eps + term_rel) * a / count + f32::MIN_POSITIVE)
        .collect();
    // Strict: the reordering bound. A per-sample term can itself differ by
    // more than 1e-5 where the backward pass cancels (∂L/∂input = Σ W δ of
    // mixed signs feeds the grid), so a few parameters fed by one or two
    // samples may exceed it: at most 0.1 % of them (4 in a small model), and
    // every parameter stays within 100× the bound (1e-3 of its terms'
    // magnitude).
    let mut worst = 0.0f32;
    let mut over = 0usize;
    for j in 0..n {
        g_cpu[j] /= count;
        let err = (g_gpu[j] - g_cpu[j]).abs();
        assert!(
            g_gpu[j].is_finite() && err <= 100.0 * bound[j],
            "{what}: gradient[{j}] gpu {} cpu {} (|Δ| {err:e} > 100 × {:e})",
            g_gpu[j],
            g_cpu[j],
            bound[j]
        );
        if err > bound[j] {
            over += 1;
        } else {
            worst = worst.max(err / bound[j]);
        }
    }
    assert!(
        over <= (n / 1000).max(4),
        "{what}: {over} of {n} gradient entries beyond the reordering bound"
    );
    assert!(
        (loss_gpu - loss_cpu).abs() <= 1e-5 * loss_cpu.abs().max(1.0),
        "{what}: loss gpu {loss_gpu} cpu {loss_cpu}"
    );

    // One Adam step from the same state, against the CPU element kernel.
    let adam = AdamConfig::new(1e-2);
    let options = TrainOptions {
        adam,
        ema_decay: 0.95,
        max_gradient_magnitude: 1e18,
    };
    let outcome = gpu.train_step(&samples, &options).expect("train step");
    assert!(
        matches!(outcome, StepOutcome::Applied { .. }),
        "{what}: GPU step skipped"
    );
    let args = AdamArgs {
        count: n as u32,
        pad: [0; 3],
        adam,
        factors: AdamStepFactors::new(1, &adam),
        gradient_scale: 1.0,
        ema_alpha: ema_weight(0.95, 1),
    };
    let mut p = params.to_vec();
    let (mut m, mut v) = (vec![0.0f32; n], vec![0.0f32; n]);
    let mut ema = params.to_vec();
    let mut g = g_cpu.clone();
    for j in 0..n {
        batch::adam_element(&mut p, &mut g, &mut m, &mut v, &mut ema, &args, j);
    }
    let (gm, gv) = gpu.adam_moments().expect("moments");
    let gp = gpu.params().expect("params");
    let mut decided = 0usize;
    for j in 0..n {
        // m = (1 − β₁) g and v = (1 − β₂) g²: their bounds follow from g's.
        let b = 100.0 * bound[j];
        let bm = (1.0 - adam.beta1) * b * 1.001 + 1e-6 * m[j].abs();
        let bv = (1.0 - adam.beta2) * (2.0 * g_cpu[j].abs() * b + b * b) * 1.001 + 1e-6 * v[j];
        assert!(
            (gm[j] - m[j]).abs() <= bm,
            "{what}: m[{j}] gpu {} cpu {}",
            gm[j],
            m[j]
        );
        assert!(
            (gv[j] - v[j]).abs() <= bv,
            "{what}: v[{j}] gpu {} cpu {}",
            gv[j],
            v[j]
        );
        // θ₁ = θ₀ − α g/(|g| + ε): decided (±α) wherever |g| is well above
        // its uncertainty and Adam's ε.
        if g_cpu[j].abs() > 100.0 * b + 1e-12 {
            decided += 1;
            assert!(
                (gp[j] - p[j]).abs() <= 1e-5 * p[j].abs().max(1.0),
                "{what}: θ[{j}] gpu {} cpu {}",
                gp[j],
                p[j]
            );
        }
    }
    eprintln!(
        "{what} gradient ({} samples, loss {loss_gpu:.6}): {over} of {n} entries beyond the \
         reordering bound (all within 100×), the rest at most {worst:.3} of it; Adam step: m, v within bounds, θ equal on {decided} of {n} \
         parameters with a decided sign",
        samples.len()
    );
}

/// Relative pdf tolerance of the mixtures: the 1e-5 of the issue.
const MIXTURE_PDF_REL: f32 = 1e-5;

/// Relative pdf tolerance of DF, derived from the network outputs' 1e-5:
/// the pdf is `p(ε₁) p(ε₂ | ε₁)`, two softmaxes of logits that agree to
/// `δ = 1e-5` (absolute, the `infer` check's bound for outputs below 1); a
/// softmax moves by at most `2δ` relative when every logit moves by `δ`, so
/// the product by at most `4δ`.
const DF_PDF_REL: f32 = 4e-5;

fn raw_outputs_of<M: RawOutputs>(_: &M) -> u32 {
    M::RAW_OUTPUTS as u32
}

macro_rules! model_difftest {
    ($name:ident, $model:expr, $prefix:literal, raw) => {
        #[test]
        fn $name() {
            let Some(ctx) = context() else { return };
            let model = $model;
            let params = parameters(&model, 3);
            let raw = raw_outputs_of(&model);
            let mut gpu = upload(ctx, &model, $prefix, raw, &params).expect("upload");
            let q = queries(1000, 5);
            check_infer(&mut gpu, &model, &params, &q, $prefix);
            model_difftest!(@common gpu, model, params, q, $prefix, MIXTURE_PDF_REL, 1e-5);
        }
    };
    ($name:ident, $model:expr, $prefix:literal) => {
        #[test]
        fn $name() {
            let Some(ctx) = context() else { return };
            let model = $model;
            let params = parameters(&model, 3);
            let mut gpu = upload(ctx, &model, $prefix, 0, &params).expect("upload");
            let q = queries(1000, 5);
            assert!(gpu.infer(&q, &mut []).is_err(), "DF has no infer kernel");
            model_difftest!(@common gpu, model, params, q, $prefix, DF_PDF_REL, 1e-3);
        }
    };
    (@common $gpu:ident, $model:ident, $params:ident, $q:ident, $prefix:literal, $rel:expr, $term:expr) => {
        check_sample(&mut $gpu, &$model, &$params, &$q, $prefix, $rel);
        check_pdf(&mut $gpu, &$model, &$params, &$q, $prefix, $rel);
        check_train_step(&mut $gpu, &$model, &$params, $prefix, $term);
    };
}

model_difftest!(
    npm_small_radiance,
    NpmSmallRadiance::small(LO, HI),
    "npm_small_radiance",
    raw
);
model_difftest!(
    npm_small_product,
    NpmSmallProduct::small(LO, HI),
    "npm_small_product",
    raw
);
model_difftest!(
    npm_compact_radiance,
    NpmCompactRadiance::new(
        guiding::config::compact_grid(LO, HI),
        guiding_core::loss::Target::Radiance
    ),
    "npm_compact_radiance",
    raw
);
model_difftest!(
    npm_compact_product,
    NpmCompactProduct::new(
        guiding::config::compact_grid(LO, HI),
        guiding_core::loss::Target::Product
    ),
    "npm_compact_product",
    raw
);
model_difftest!(
    npm_paper_radiance,
    NpmRadiance::paper(LO, HI),
    "npm_paper_radiance",
    raw
);
model_difftest!(
    nasg_small_radiance,
    NasgSmallRadiance::small(LO, HI),
    "nasg_small_radiance",
    raw
);
model_difftest!(
    nasg_small_product,
    NasgSmallProduct::small(LO, HI),
    "nasg_small_product",
    raw
);
model_difftest!(
    nasg_compact_product,
    NasgCompactProduct::new(
        guiding::config::compact_grid(LO, HI),
        guiding_core::loss::Target::Product
    ),
    "nasg_compact_product",
    raw
);
model_difftest!(
    df_small_radiance,
    DfSmallRadiance::small(LO, HI, Interpolation::Linear),
    "df_small_radiance"
);
model_difftest!(
    df_small_product,
    DfSmallProduct::small(LO, HI, Interpolation::Nearest),
    "df_small_product"
);
model_difftest!(
    df_compact_product,
    DfCompactProduct::new(
        guiding::config::compact_grid(LO, HI),
        guiding_core::loss::Target::Product,
        Interpolation::Linear
    ),
    "df_compact_product"
);

/// Raw outputs for the decode kernels: ordinary values in `[−3, 3]` plus,
/// every 7th element, extremes (`±1e30`, huge `ln κ` / `ln λ`, subnormals,
/// zeros) — the ranges the distributions' own tests sweep.
fn raw_batch(n: usize, per: usize, seed: u32) -> Vec<f32> {
    let mut rng = Rng::new(seed);
    let extremes = [1e30, -1e30, 88.0, -88.0, 1e-40, 0.0, 20.0, -20.0];
    (0..n * per)
        .map(|k| {
            if (k / per) % 7 == 3 && k % 3 == 0 {
                extremes[(k / 3) % extremes.len()]
            } else {
                3.0 * rng.next_symmetric_f32()
            }
        })
        .collect()
}

/// The CPU decode of element `i`: its sample for `u[i]` and its density.
type CpuDecode<'a> = Box<dyn Fn(&[f32], usize) -> (Vec3, f32, Box<dyn Fn(Vec3) -> f32 + 'a>) + 'a>;

/// How much `pdf` moves when `d` moves by a few ulp (along two tangents,
/// both ways).
fn local_sensitivity(pdf: &dyn Fn(Vec3) -> f32, d: Vec3) -> f32 {
    let p0 = pdf(d);
    let t = if d.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t1 = d.cross(t).normalize();
    let t2 = d.cross(t1);
    let h = 4.0 * f32::EPSILON;
    [t1, -t1, t2, -t2]
        .iter()
        .map(|&e| (pdf((d + h * e).normalize()) - p0).abs())
        .fold(0.0, f32::max)
}

/// Decode kernels (raw network outputs → distribution → sample / pdf) on
/// the GPU against the CPU functions, extreme parameters included. Sampled
/// directions are compared where no CDF boundary intervenes; pdfs to `rel`
/// of their value plus the distribution's local condition (as in the model
/// tests).
fn check_decode(
    ctx: &GpuContext,
    family: &str,
    per: usize,
    code: u32,
    rel: f32,
    cpu: CpuDecode<'_>,
) {
    // DF's reference (544 logits → table, three times per vector) is the
    // slow part of this test: fewer vectors there.
    let n = if family == "df" { 500 } else { 2000 };
    let raw = raw_batch(n, per, 17);
    let u = randoms(n, 19);
    let d = directions(n, 23);
    let args = batch::BatchArgs {
        count: n as u32,
        code,
        pad: [0; 2],
    };
    let k_sample = ctx
        .embedded_kernel(&format!("{family}_decode_sample"), 3, 16)
        .expect("kernel");
    let k_pdf = ctx
        .embedded_kernel(&format!("{family}_decode_pdf"), 3, 16)
        .expect("kernel");
    let b_raw = ctx.buffer_from(&raw).expect("buffer");
    let b_u = ctx.buffer_from(&u).expect("buffer");
    let b_d = ctx.buffer_from(&d).expect("buffer");
    let b_s = ctx.buffer((n * 16) as u64).expect("buffer");
    let b_p = ctx.buffer((n * 4) as u64).expect("buffer");
    let push = bytemuck::bytes_of(&args);
    ctx.run(&k_sample, &[&b_raw, &b_u, &b_s], push, n as u32)
        .expect("sample");
    ctx.run(&k_pdf, &[&b_raw, &b_d, &b_p], push, n as u32)
        .expect("pdf");
    let s: Vec<[f32; 4]> = b_s.download().expect("download");
    let p: Vec<f32> = b_p.download().expect("download");
    // The decoded pdf's condition in its parameters: the CPU pdf with every
    // raw value moved by ±4 ulp (sharp lobes, λ up to e^9.2, turn rounding
    // of the frame angles into large relative pdf changes).
    let nudged =
        |k: f32| -> Vec<f32> { raw.iter().map(|&x| x * (1.0 + k * f32::EPSILON)).collect() };
    let (raw_up, raw_down) = (nudged(4.0), nudged(-4.0));
    let (mut differ, mut worst, mut over) = (0usize, 0.0f32, 0usize);
    let (mut extreme_differ, mut over_extreme) = (0usize, 0usize);
    for i in 0..n {
        let (dir, pdf, density) = cpu(&raw, i);
        let (_, _, up) = cpu(&raw_up, i);
        let (_, _, down) = cpu(&raw_down, i);
        let param_sens = |x: Vec3| {
            let p0 = density(x);
            (up(x) - p0).abs().max((down(x) - p0).abs())
        };
        let g = s[i];
        assert!(
            g.iter().all(|x| x.is_finite()) && g[3] > 0.0,
            "{family}: GPU sample {i} {g:?}"
        );
        let gd = batch::unpack_direction(g);
        if (gd - dir).length() > 1e-4 {
            assert!(
                density(gd) > 0.0,
                "{family}: GPU sample {i} where the density is 0"
            );
            // Directions are compared on the ordinary vectors only: with
            // extreme parameters (λ at its e^9.2 clamp, saturated angles)
            // the sample map amplifies rounding beyond 1e-4; there the GPU
            // sample only has to be a valid one (density > 0, checked).
            if i % 7 != 3 {
                differ += 1;
                if std::env::var("DBG").is_ok() {
                    eprintln!(
                        "{family} {i}: dist {} gpu {g:?} cpu {dir:?} {pdf}",
                        (gd - dir).length()
                    );
                }
            } else {
                extreme_differ += 1;
            }
        } else {
            let e_c = density(dir);
            let bound = rel * pdf.abs().max(1e-2)
                + (density(gd) - e_c).abs()
                + (pdf - e_c).abs()
                + local_sensitivity(&*density, dir)
                + param_sens(dir);
            let err = (g[3] - pdf).abs();
            assert!(
                err <= 100.0 * bound,
                "{family}: sample {i} pdf gpu {} cpu {pdf} (bound {bound:e})",
                g[3]
            );
            if err > bound {
                if i % 7 == 3 {
                    over_extreme += 1;
                } else {
                    over += 1;
                }
            }
        }
        let dd = batch::unpack_direction(d[i]);
        let pdf_d = density(dd);
        let bound = rel * pdf_d.abs().max(1e-2) + local_sensitivity(&*density, dd) + param_sens(dd);
        let err = (p[i] - pdf_d).abs();
        assert!(
            p[i].is_finite() && err <= 100.0 * bound,
            "{family}: pdf {i} gpu {} cpu {pdf_d} (|Δ| {err:e} > 100 × {bound:e})",
            p[i]
        );
        if err > bound {
            if i % 7 == 3 {
                over_extreme += 1;
            } else {
                over += 1;
            }
        } else {
            worst = worst.max(err / bound);
        }
    }
    assert!(
        differ * 100 < n,
        "{family}: {differ} of {n} ordinary samples differ"
    );
    // The rounding bounds hold on the ordinary vectors; on the extreme ones
    // (saturated sigmoids and clamps, where a last-ulp difference moves a
    // frame angle by more than the ±4-ulp nudges probe) every pdf stays
    // within 100× its bound.
    assert!(
        over == 0,
        "{family}: {over} pdf checks of ordinary vectors beyond the rounding bound"
    );
    eprintln!(
        "{family} decode (code {code}): {n} raw vectors (1 in 7 extreme), {differ} ordinary and \
         {extreme_differ} extreme samples in another direction, {over_extreme} extreme pdfs \
         beyond the rounding bound (within 100×), the rest at most {worst:.3} of it"
    );
}

#[test]
fn decode_kernels_match_the_cpu_on_ordinary_and_extreme_parameters() {
    let Some(ctx) = context() else { return };
    use guiding_core::model::df::{DF_CONDITIONAL_BINS, DF_MARGINAL_BINS};
    // `check_decode` draws the same random pairs (seed 19).
    let u = randoms(2000, 19);
    let uv = |i: usize| Vec2::new(u[i][0], u[i][1]);
    check_decode(
        &ctx,
        "vmf",
        32,
        0,
        MIXTURE_PDF_REL,
        Box::new(|raw, i| {
            let m = batch::vmf_mixture_from_raw(raw, i * 32);
            let s = m.sample(uv(i));
            (s.direction, s.pdf, Box::new(move |d| m.pdf(d)))
        }),
    );
    check_decode(
        &ctx,
        "nasg",
        49,
        0,
        MIXTURE_PDF_REL,
        Box::new(|raw, i| {
            let m = batch::nasg_mixture_from_raw(raw, i * 49);
            let s = m.sample(uv(i));
            (s.direction, s.pdf, Box::new(move |d| m.pdf(d)))
        }),
    );
    let per = DF_MARGINAL_BINS + DF_MARGINAL_BINS * DF_CONDITIONAL_BINS;
    for (code, interp) in [(0u32, Interpolation::Nearest), (1, Interpolation::Linear)] {
        check_decode(
            &ctx,
            "df",
            per,
            code,
            DF_PDF_REL,
            Box::new(move |raw, i| {
                let t = batch::df_table_from_raw(raw, i * per, interp);
                let s = t.sample(uv(i));
                (s.direction, s.pdf, Box::new(move |d| t.pdf(d)))
            }),
        );
    }
}

/// The lane kernels of a wavefront decoded on the device: the network's raw
/// outputs stay resident ([`GpuModel::infer_resident`], checked against
/// `infer`), NASG's selection probabilities come back, and lanes picked in
/// any order are sampled / evaluated (NPM with the cosine product on every
/// other lane) against the CPU lane kernels run on the same raw outputs.
/// Sampled directions and pdfs are compared as in [`check_decode`]: where
/// no CDF boundary intervenes, to `rel` plus the density's local condition.
#[test]
fn lane_kernels_match_the_cpu_on_resident_outputs() {
    let Some(ctx) = context() else { return };
    let npm = NpmCompactRadiance::new(
        guiding::config::compact_grid(LO, HI),
        guiding_core::loss::Target::Radiance,
    );
    let nasg = NasgSmallRadiance::small(LO, HI);
    check_lanes(&ctx, &npm, "npm_compact_radiance", true);
    check_lanes(&ctx, &nasg, "nasg_small_radiance", false);
}

fn check_lanes<M: RawOutputs + bytemuck::Pod>(
    ctx: &GpuContext,
    model: &M,
    prefix: &'static str,
    vmf: bool,
) {
    let params = parameters(model, 9);
    let r = M::RAW_OUTPUTS;
    let mut gpu = upload(ctx.clone(), model, prefix, r as u32, &params).expect("upload");
    let n = 1500;
    let q = queries(n, 31);
    let mut raw_buf = None;
    let mut selection = Vec::new();
    gpu.infer_resident(&q, &mut raw_buf, &mut selection)
        .expect("resident inference");
    let raw_buf = raw_buf.expect("raw-output buffer");
    let mut raw: Vec<f32> = raw_buf.download().expect("download");
    raw.truncate(n * r);
    let mut reference = vec![0.0f32; n * r];
    gpu.infer(&q, &mut reference).expect("infer");
    assert!(
        raw == reference,
        "{prefix}: resident outputs differ from infer's"
    );
    if vmf {
        assert!(
            selection.is_empty(),
            "{prefix}: NPM has no learned selection"
        );
    } else {
        assert_eq!(selection.len(), n);
        for i in 0..n {
            let c = batch::nasg_mixture_from_raw(&raw, i * r).selection_probability;
            assert!(
                (selection[i] - c).abs() <= 1e-5 * c.abs().max(1e-2),
                "{prefix}: selection {i}: gpu {} cpu {c}",
                selection[i]
            );
        }
    }
    // Lanes in reverse order, every third one twice; normals on every other.
    let lanes: Vec<u32> = (0..n as u32)
        .rev()
        .flat_map(|l| if l % 3 == 0 { vec![l, l] } else { vec![l] })
        .collect();
    let m = lanes.len();
    let normals: Vec<[f32; 4]> = lanes
        .iter()
        .enumerate()
        .map(|(k, &l)| {
            let nq = q[l as usize].normal;
            [
                nq[0],
                nq[1],
                nq[2],
                if vmf && k % 2 == 0 { 1.0 } else { 0.0 },
            ]
        })
        .collect();
    let u = randoms(m, 37);
    let d = directions(m, 41);
    let mut s_gpu = vec![[0.0f32; 4]; m];
    let mut p_gpu = vec![0.0f32; m];
    gpu.sample_lanes(&raw_buf, &lanes, &normals, &u, &mut s_gpu)
        .expect("sample lanes");
    gpu.pdf_lanes(&raw_buf, &lanes, &normals, &d, &mut p_gpu)
        .expect("pdf lanes");
    let mut s_cpu = vec![[0.0f32; 4]; m];
    let mut p_cpu = vec![0.0f32; m];
    for k in 0..m {
        if vmf {
            batch::vmf_lane_sample_element(&raw, &lanes, &normals, &u, &mut s_cpu, k);
            batch::vmf_lane_pdf_element(&raw, &lanes, &normals, &d, &mut p_cpu, k);
        } else {
            batch::nasg_lane_sample_element(&raw, &lanes, &normals, &u, &mut s_cpu, k);
            batch::nasg_lane_pdf_element(&raw, &lanes, &normals, &d, &mut p_cpu, k);
        }
    }
    let (mut differ, mut worst) = (0usize, 0.0f32);
    for k in 0..m {
        let density = |dir: Vec3| -> f32 {
            let mut out = [0.0f32];
            let one = [[dir.x, dir.y, dir.z, 0.0]];
            let (l, nm) = ([lanes[k]], [normals[k]]);
            if vmf {
                batch::vmf_lane_pdf_element(&raw, &l, &nm, &one, &mut out, 0);
            } else {
                batch::nasg_lane_pdf_element(&raw, &l, &nm, &one, &mut out, 0);
            }
            out[0]
        };
        let (g, c) = (s_gpu[k], s_cpu[k]);
        let (gd, cd) = (batch::unpack_direction(g), batch::unpack_direction(c));
        assert!(
            g.iter().all(|x| x.is_finite()) && g[3] > 0.0,
            "{prefix}: GPU sample {k} {g:?}"
        );
        if (gd - cd).length() > 1e-4 {
            assert!(density(gd) > 0.0, "{prefix}: GPU sample {k} at density 0");
            differ += 1;
        } else {
            let bound = MIXTURE_PDF_REL * c[3].abs().max(1e-2)
                + (density(gd) - density(cd)).abs()
                + (c[3] - density(cd)).abs()
                + local_sensitivity(&density, cd);
            let err = (g[3] - c[3]).abs();
            assert!(
                err <= bound,
                "{prefix}: sample {k} pdf gpu {} cpu {} (bound {bound:e})",
                g[3],
                c[3]
            );
            worst = worst.max(err / bound);
        }
        let dd = batch::unpack_direction(d[k]);
        let bound = MIXTURE_PDF_REL * p_cpu[k].abs().max(1e-2) + local_sensitivity(&density, dd);
        let err = (p_gpu[k] - p_cpu[k]).abs();
        assert!(
            p_gpu[k].is_finite() && err <= bound,
            "{prefix}: pdf {k} gpu {} cpu {} (bound {bound:e})",
            p_gpu[k],
            p_cpu[k]
        );
        worst = worst.max(err / bound);
    }
    assert!(
        differ * 100 < m,
        "{prefix}: {differ} of {m} lane samples in another direction"
    );
    eprintln!(
        "{prefix} lanes: {m} lanes of {n} resident rows, {differ} samples across a CDF \
         boundary, the rest and every pdf within {worst:.3} of the bound"
    );
}
