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
//! sums), plus, where the quantity is ill-conditioned (sharp lobes, DF's
//! triangle waves, cancelling backward sums), its measured condition: how
//! much the CPU value moves when its inputs move by [`PROBE_ULPS`] ulp.
//! (This strictness found the one real defect: NASG's `ln t` lost its
//! compensated rounding correction in SPIR-V, which the compilers may fold;
//! the kernel now takes `ln_1p` by a series there, `math::ln_1p_series`.)
//! Every compared value must meet its own bound (no count of exceptions,
//! no multiple of a bound); only sampled directions are counted, as
//! follows. Directional samples choose a lobe / bin by comparing `u` to a
//! CDF; when `u` lies within rounding of a boundary the two sides may pick
//! neighbours, so sampled directions are compared only where the CPU's
//! margin to every boundary exceeds 1e-4, and the rest is counted and
//! bounded (it must stay below 1 % of the batch, which the margin makes a
//! ~1e-3 event).
#![cfg(feature = "shaders")]

use guiding_core::batch::{self, AdamArgs};
use guiding_core::glam::{Quat, Vec2, Vec3};
use guiding_core::gradient::GradientSink;
use guiding_core::lobe::nasg::NasgLobe;
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::lobe::DirectionSample;
use guiding_core::loss::Target;
use guiding_core::mixture::nasg::NasgMixture;
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::mixture::LobeMixture;
use guiding_core::model::df::{DfCompactProduct, DfSmallProduct, DfSmallRadiance};
use guiding_core::model::nasg::{NasgCompactProduct, NasgSmallProduct, NasgSmallRadiance};
use guiding_core::model::npm::{
    NpmCompactProduct, NpmCompactRadiance, NpmRadiance, NpmSmallProduct, NpmSmallRadiance,
};
use guiding_core::model::{Family, GuidingModel, QueryPoint, RawOutputs};
use guiding_core::optim::{ema_weight, AdamConfig, AdamStepFactors};
use guiding_core::pdf1d::Interpolation;
use guiding_core::rng::{hash2, Rng};
use guiding_core::sample::TrainingSample;
use guiding_gpu::{
    test_context, GpuContext, GpuError, GpuModel, ModelEntryPoints, StepOutcome, TrainOptions,
};

const LO: [f32; 3] = [-1.0, 0.0, -2.0];
const HI: [f32; 3] = [1.0, 3.0, 2.0];

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
    family: Family,
    params: &[f32],
) -> Result<GpuModel, GpuError> {
    let zeros = vec![0.0f32; params.len()];
    GpuModel::new(
        ctx,
        ModelEntryPoints { prefix, family },
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

/// A model with its parameters and queries, compared between the GPU and
/// the CPU; `what` names it in messages.
struct Case<'a, M> {
    model: &'a M,
    params: &'a [f32],
    q: &'a [QueryPoint],
    what: &'a str,
}

/// Sample kernel: GPU `[ω, pdf]` against the CPU's, and the GPU's pdf
/// against the CPU pdf of the GPU's direction (always comparable).
fn check_sample<M: GuidingModel>(gpu: &mut GpuModel, case: &Case<'_, M>, pdf_rel: f32) {
    let (model, params, q, what) = (case.model, case.params, case.q, case.what);
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
            for k in [-PROBE_ULPS, PROBE_ULPS] {
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

/// Pdf kernel: GPU against CPU densities of random directions.
fn check_pdf<M: GuidingModel>(gpu: &mut GpuModel, case: &Case<'_, M>, pdf_rel: f32) {
    let (model, params, q, what) = (case.model, case.params, case.q, case.what);
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

/// Size, in ulp, of the probes that measure a quantity's condition: the
/// GPU's arithmetic deviates from the CPU's by at most a few ulp per
/// operation — a contracted `a·b + c` by ½ ulp of the product, the inlined
/// transcendentals of `guiding_core::math` by 2–3 ulp against libm's ≤ 1
/// ulp (`atan2_turns`: 3 ulp plus the ½-ulp rounding of the product with
/// 2π) — so 4 ulp bounds one operation's deviation; the pdf checks above
/// probe directions by the same 4 ulp.
const PROBE_ULPS: f32 = 4.0;

/// Probes of each training sample's gradient term ([`gradient_reference`]).
const GRADIENT_PROBES: usize = 4;

/// The two unit tangents of the unit vector `d` that the direction probes
/// move along.
fn tangents(d: Vec3) -> (Vec3, Vec3) {
    let t = if d.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t1 = d.cross(t).normalize();
    (t1, d.cross(t1))
}

/// The parameters of gradient probe `p`: each one scaled by `1 ± h` (`h` =
/// [`PROBE_ULPS`] ulp) with a pseudo-random sign per parameter, mirrored
/// between probes `2i` and `2i + 1`.
///
/// Independent signs, not one common scale: the GPU's deviations are
/// independent per operation, and a common scale would leave every
/// cancelling sum (`∂L/∂x = Σ W δ` of mixed signs) cancelling exactly as
/// before, which is where the backward pass is ill-conditioned. A product
/// `w·x` whose rounding differs by `η` equals the exact product of
/// `w (1 + η)` and `x`, so per-parameter perturbations of a few ulp stand
/// for the per-operation deviations of the layers they feed (the first
/// layer's inputs included).
fn probe_params(params: &[f32], p: usize) -> Vec<f32> {
    let h = PROBE_ULPS * f32::EPSILON;
    let sign = if p % 2 == 0 { 1.0 } else { -1.0 };
    let pattern = 0x0bad_5eed ^ (p / 2) as u32;
    params
        .iter()
        .enumerate()
        .map(|(j, &x)| {
            let s = if hash2(pattern, j as u32) & 1 == 0 {
                sign
            } else {
                -sign
            };
            x * (1.0 + s * h)
        })
        .collect()
}

/// Training sample `s` as gradient probe `p` sees it: the position's offset
/// from the grid box's corner (which the grid normalises and multiplies by
/// each level's resolution; its interpolation weights are differences of
/// that product and its floor, so they carry ~1 ulp of it) scaled by
/// `1 ± h` per axis, the roughness scaled by `1 ± h`, and `ωi`, `ωo` and
/// the normal moved by `h` along one of their tangents (DF maps `ωi` to
/// `ε₁ = atan2(…)/2π`, whose 12 triangle-wave octaves amplify its rounding
/// by up to 2¹¹; the mixtures' lobes amplify it where they are sharp).
fn probe_sample(s: &TrainingSample, p: usize) -> TrainingSample {
    let h = PROBE_ULPS * f32::EPSILON;
    let sign = if p % 2 == 0 { 1.0 } else { -1.0 };
    let mut q = *s;
    for (c, (x, lo)) in q.position.iter_mut().zip(LO).enumerate() {
        let sc = if (c + p / 2) % 2 == 0 { sign } else { -sign };
        *x = lo + (*x - lo) * (1.0 + sc * h);
    }
    q.roughness = s.roughness * (1.0 + sign * h);
    for d in [&mut q.wi, &mut q.wo, &mut q.normal] {
        let v = Vec3::from_array(*d);
        if (v.length() - 1.0).abs() < 1e-3 {
            let (t1, t2) = tangents(v);
            let t = if p < 2 { t1 } else { t2 };
            *d = (v + sign * h * t).normalize().to_array();
        }
    }
    q
}

/// One sample's gradient term as the model adds it: per touched parameter
/// the value, the number of `add` calls and the sum of their magnitudes
/// (the GPU's atomics add each call on its own).
struct TermSink {
    value: Vec<f32>,
    abs: Vec<f32>,
    adds: Vec<u32>,
    touched: Vec<usize>,
}

impl TermSink {
    fn new(n: usize) -> Self {
        Self {
            value: vec![0.0; n],
            abs: vec![0.0; n],
            adds: vec![0; n],
            touched: Vec::new(),
        }
    }

    fn clear(&mut self) {
        for &j in &self.touched {
            self.value[j] = 0.0;
            self.abs[j] = 0.0;
            self.adds[j] = 0;
        }
        self.touched.clear();
    }
}

impl GradientSink for TermSink {
    fn len(&self) -> usize {
        self.value.len()
    }

    fn add(&mut self, index: usize, value: f32) {
        if self.adds[index] == 0 {
            self.touched.push(index);
        }
        self.adds[index] += 1;
        self.value[index] += value;
        self.abs[index] += value.abs();
    }
}

/// The CPU's mean gradient of a batch and, per parameter, how far a
/// correct GPU gradient may lie from it.
///
/// The GPU adds every `add` of every sample with an atomic, in the order
/// they land; the CPU sums each sample's term, then the terms in sample
/// order. Per parameter `j`, over `n` samples:
///
/// ```text
/// bound_j = 2 ε max(A_j, n) Σ|a|_j / n      reordering (A_j adds a, each side)
///         + Σ_s max_p |t_sj(probe p) − t_sj| / n   measured condition of each term
///         + 1e-5 Σ_s |t_sj| / n             rounding of a well-conditioned term
/// ```
///
/// The middle term is each sample's gradient term `t_sj` recomputed under
/// [`GRADIENT_PROBES`] probes (parameters and inputs moved by
/// [`PROBE_ULPS`] ulp, [`probe_params`], [`probe_sample`]): where the
/// backward pass cancels (`∂L/∂x = Σ W δ` feeding the grid), where a tiny
/// interpolation weight carries the rounding of the grid coordinate, or
/// where DF's triangle waves amplify the rounding of `ε₁`, the term moves
/// by what its own condition makes of a few ulp, and the bound with it.
/// Each sample adds the magnitude of its change (the signs of the GPU's
/// deviations are not known), so the bound assumes no cancellation between
/// samples.
struct GradientReference {
    /// The CPU's mean gradient (terms summed in sample order).
    mean: Vec<f32>,
    /// The reordering part of the bound.
    reorder: Vec<f32>,
    /// The measured-condition part of the bound.
    sensitivity: Vec<f32>,
    /// `bound_j` (plus the smallest normal, so that 0 is never a bound).
    bound: Vec<f32>,
    /// Samples whose term touches each parameter.
    samples: Vec<u32>,
    /// The mean loss.
    loss: f64,
}

fn gradient_reference<M: GuidingModel>(
    model: &M,
    params: &[f32],
    samples: &[TrainingSample],
) -> GradientReference {
    let n = params.len();
    let count = samples.len() as f32;
    let probes: Vec<Vec<f32>> = (0..GRADIENT_PROBES)
        .map(|p| probe_params(params, p))
        .collect();
    let mut term = TermSink::new(n);
    let mut probe = TermSink::new(n);
    let (mut sum, mut abs_terms, mut abs_adds) =
        (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
    let (mut adds, mut touching) = (vec![0u32; n], vec![0u32; n]);
    let mut sens = vec![0.0f32; n];
    // This sample's largest change over the probes, sparse.
    let mut change = vec![0.0f32; n];
    let mut changed = Vec::new();
    let mut loss = 0.0f64;
    for s in samples {
        loss += f64::from(model.accumulate_gradient(params, s, &mut term));
        for (p, probe_params) in probes.iter().enumerate() {
            model.accumulate_gradient(probe_params, &probe_sample(s, p), &mut probe);
            let mut raise = |j: usize, d: f32| {
                if change[j] == 0.0 && d > 0.0 {
                    changed.push(j);
                }
                change[j] = change[j].max(d);
            };
            for &j in &term.touched {
                raise(j, (probe.value[j] - term.value[j]).abs());
            }
            for &j in &probe.touched {
                if term.adds[j] == 0 {
                    raise(j, probe.value[j].abs());
                }
            }
            probe.clear();
        }
        for &j in &term.touched {
            sum[j] += term.value[j];
            abs_terms[j] += term.value[j].abs();
            abs_adds[j] += term.abs[j];
            adds[j] += term.adds[j];
            touching[j] += 1;
        }
        for &j in &changed {
            sens[j] += change[j];
            change[j] = 0.0;
        }
        changed.clear();
        term.clear();
    }
    let eps = f32::EPSILON;
    let mut r = GradientReference {
        mean: sum.iter().map(|&x| x / count).collect(),
        reorder: vec![0.0; n],
        sensitivity: vec![0.0; n],
        bound: vec![0.0; n],
        samples: touching,
        loss: loss / f64::from(count),
    };
    for j in 0..n {
        r.reorder[j] = 2.0 * eps * (adds[j] as f32).max(count) * abs_adds[j] / count;
        r.sensitivity[j] = sens[j] / count;
        r.bound[j] =
            r.reorder[j] + r.sensitivity[j] + 1e-5 * abs_terms[j] / count + f32::MIN_POSITIVE;
    }
    r
}

/// The parameters where `gradient` (a mean over the batch of `reference`)
/// is not finite or lies beyond its bound, and the largest ratio of the
/// error to the bound among the others.
fn gradient_violations(gradient: &[f32], reference: &GradientReference) -> (Vec<usize>, f32) {
    assert_eq!(gradient.len(), reference.mean.len(), "gradient lengths");
    let mut violations = Vec::new();
    let mut worst = 0.0f32;
    for (j, (&g, &c)) in gradient.iter().zip(&reference.mean).enumerate() {
        let err = (g - c).abs();
        if g.is_finite() && err <= reference.bound[j] {
            worst = worst.max(err / reference.bound[j]);
        } else {
            violations.push(j);
        }
    }
    (violations, worst)
}

/// The first violations of [`gradient_violations`], with their bounds'
/// parts, for a failure message.
fn describe_violations(gradient: &[f32], r: &GradientReference, violations: &[usize]) -> String {
    violations
        .iter()
        .take(12)
        .map(|&j| {
            format!(
                "\n  [{j}] gpu {:e} cpu {:e}: |Δ| {:e} = {:.2} × bound {:e} (reorder {:e}, \
                 probes {:e}; {} samples)",
                gradient[j],
                r.mean[j],
                (gradient[j] - r.mean[j]).abs(),
                (gradient[j] - r.mean[j]).abs() / r.bound[j],
                r.bound[j],
                r.reorder[j],
                r.sensitivity[j],
                r.samples[j]
            )
        })
        .collect()
}

/// The GPU gradient of a batch against the CPU's, every entry within its
/// bound ([`gradient_reference`]), then one Adam step.
fn check_train_step<M: GuidingModel>(gpu: &mut GpuModel, model: &M, params: &[f32], what: &str) {
    let samples = training_samples(300, 99);
    let n = params.len();
    let (g_gpu, loss_gpu) = gpu.gradient(&samples).expect("gradient kernel");
    let reference = gradient_reference(model, params, &samples);
    let (violations, worst) = gradient_violations(&g_gpu, &reference);
    assert!(
        violations.is_empty(),
        "{what}: {} of {n} gradient entries beyond their bound:{}",
        violations.len(),
        describe_violations(&g_gpu, &reference, &violations)
    );
    let loss_cpu = reference.loss;
    assert!(
        (loss_gpu - loss_cpu).abs() <= 1e-5 * loss_cpu.abs().max(1.0),
        "{what}: loss gpu {loss_gpu} cpu {loss_cpu}"
    );
    let g_cpu = &reference.mean;
    let bound = &reference.bound;

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
        let b = bound[j];
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
        // The first step is θ₁ = θ₀ − α g / (|g| + ε_Adam). Where |g| > 2b
        // the GPU's g (within b) has the same sign and at least half the
        // magnitude, so both steps are ±α to within 2 α ε_Adam / |g|, below
        // 2·10⁻⁵ α once |g| > 10⁻¹⁰ (ε_Adam = 10⁻¹⁵): θ agrees to rounding.
        if g_cpu[j].abs() > 2.0 * b && g_cpu[j].abs() > 1e-10 {
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
        "{what} gradient ({} samples, loss {loss_gpu:.6}): every one of {n} entries within its \
         bound, at most {worst:.3} of it; Adam step: m, v within bounds, θ equal on {decided} \
         of {n} parameters with a decided sign",
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

fn family_of<M: GuidingModel>(_: &M) -> Family {
    M::FAMILY
}

/// One `#[test]` per model: upload, `infer` (mixtures: `raw`) or its absence
/// (DF: `df`), then sample, pdf and a training step against the CPU; the
/// test's name is the shader prefix.
macro_rules! model_difftest {
    ($kind:ident $name:ident = $model:expr) => {
        #[test]
        fn $name() {
            let Some(ctx) = test_context() else { return };
            let prefix = stringify!($name);
            let model = $model;
            let params = parameters(&model, 3);
            let mut gpu = upload(ctx, &model, prefix, family_of(&model), &params).expect("upload");
            let q = queries(1000, 5);
            let rel = model_difftest!(@infer $kind, gpu, model, params, q, prefix);
            let case = Case {
                model: &model,
                params: &params,
                q: &q,
                what: prefix,
            };
            check_sample(&mut gpu, &case, rel);
            check_pdf(&mut gpu, &case, rel);
            check_train_step(&mut gpu, &model, &params, prefix);
        }
    };
    (@infer raw, $gpu:ident, $model:ident, $params:ident, $q:ident, $prefix:ident) => {{
        check_infer(&mut $gpu, &$model, &$params, &$q, $prefix);
        MIXTURE_PDF_REL
    }};
    (@infer df, $gpu:ident, $model:ident, $params:ident, $q:ident, $prefix:ident) => {{
        assert!($gpu.infer(&$q, &mut []).is_err(), "DF has no infer kernel");
        DF_PDF_REL
    }};
}

/// The compact grid of `[LO, HI]`.
fn compact() -> guiding_core::encoding::GridConfig {
    guiding::config::compact_grid(LO, HI)
}

model_difftest!(raw npm_small_radiance = NpmSmallRadiance::small(LO, HI));
model_difftest!(raw npm_small_product = NpmSmallProduct::small(LO, HI));
model_difftest!(raw npm_compact_radiance = NpmCompactRadiance::new(compact(), Target::Radiance));
model_difftest!(raw npm_compact_product = NpmCompactProduct::new(compact(), Target::Product));
model_difftest!(raw npm_paper_radiance = NpmRadiance::paper(LO, HI));
model_difftest!(raw nasg_small_radiance = NasgSmallRadiance::small(LO, HI));
model_difftest!(raw nasg_small_product = NasgSmallProduct::small(LO, HI));
model_difftest!(raw nasg_compact_product = NasgCompactProduct::new(compact(), Target::Product));
model_difftest!(df df_small_radiance = DfSmallRadiance::small(LO, HI, Interpolation::Linear));
model_difftest!(df df_small_product = DfSmallProduct::small(LO, HI, Interpolation::Nearest));
model_difftest!(
    df df_compact_product = DfCompactProduct::new(compact(), Target::Product, Interpolation::Linear)
);

/// Negative control of the gradient bound (CPU only, no device needed):
/// [`gradient_violations`] passes the CPU's own mean and reports the
/// defects a GPU gradient kernel could have — one sample's adds lost (an
/// atomic that raced), one parameter off by 1 %, and the gradient of
/// another batch — on a mixture model and on DF, whose bound is the widest.
#[test]
fn gradient_bound_reports_wrong_gradients() {
    fn control<M: GuidingModel>(model: &M, what: &str) {
        let params = parameters(model, 3);
        let n = params.len();
        let samples = training_samples(300, 99);
        let count = samples.len() as f32;
        let r = gradient_reference(model, &params, &samples);
        let (none, worst) = gradient_violations(&r.mean, &r);
        assert!(
            none.is_empty() && worst == 0.0,
            "{what}: the reference fails its own check"
        );

        // Sample 0's adds lost.
        let mut term = vec![0.0f32; n];
        model.accumulate_gradient(&params, &samples[0], &mut term[..]);
        let touched = term.iter().filter(|&&t| t != 0.0).count();
        let lost: Vec<f32> = r
            .mean
            .iter()
            .zip(&term)
            .map(|(&g, &t)| (g * count - t) / count)
            .collect();
        let (v_lost, _) = gradient_violations(&lost, &r);
        assert!(
            v_lost.iter().all(|&j| term[j] != 0.0) && 2 * v_lost.len() > touched,
            "{what}: one lost sample shows in only {} of the {touched} entries it touches",
            v_lost.len()
        );

        // The largest entry off by 1 %.
        let j = (0..n)
            .max_by(|&a, &b| r.mean[a].abs().total_cmp(&r.mean[b].abs()))
            .expect("parameters");
        let mut off = r.mean.clone();
        off[j] *= 1.01;
        assert_eq!(
            gradient_violations(&off, &r).0,
            vec![j],
            "{what}: a 1 % error at the largest entry"
        );

        // Another batch's gradient.
        let other = gradient_reference(model, &params, &training_samples(300, 98));
        let (v_other, _) = gradient_violations(&other.mean, &r);
        let nonzero = r.mean.iter().filter(|&&g| g != 0.0).count();
        assert!(
            2 * v_other.len() > nonzero,
            "{what}: another batch's gradient passes on {} of {nonzero} nonzero entries",
            nonzero - v_other.len()
        );

        // How tight the bound is: its median relative to |g|.
        let mut rel: Vec<f32> = (0..n)
            .filter(|&j| r.mean[j] != 0.0)
            .map(|j| r.bound[j] / r.mean[j].abs())
            .collect();
        rel.sort_by(f32::total_cmp);
        eprintln!(
            "{what} control: one lost sample flags {} of the {touched} entries it touches, a 1 % \
             error at the largest entry is flagged, another batch's gradient is flagged at {} \
             entries ({nonzero} nonzero); bound / |g|: median {:.1e}, 90th percentile {:.1e}",
            v_lost.len(),
            v_other.len(),
            rel[rel.len() / 2],
            rel[rel.len() * 9 / 10]
        );
    }
    control(&NpmSmallRadiance::small(LO, HI), "npm_small_radiance");
    control(&NasgSmallProduct::small(LO, HI), "nasg_small_product");
    control(
        &DfSmallRadiance::small(LO, HI, Interpolation::Linear),
        "df_small_radiance",
    );
}

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

/// The CPU decode of one raw vector, as [`check_decode`] uses it.
struct CpuDecoded<'a> {
    /// The sample for the element's `u`.
    direction: Vec3,
    /// Its density.
    pdf: f32,
    /// The decoded density.
    density: Box<dyn Fn(Vec3) -> f32 + 'a>,
    /// How much the density moves when each decoded lobe's own parameters
    /// move by their rounding ([`vmf_lobe_sensitivity`],
    /// [`nasg_lobe_sensitivity`]); 0 for DF, whose table is a softmax of
    /// the logits (no angles, no clamped exponentials), which the raw
    /// probes of [`check_decode`] cover.
    lobe_sensitivity: Box<dyn Fn(Vec3) -> f32 + 'a>,
}

impl<'a> CpuDecoded<'a> {
    /// `dist` decoded on the CPU, with its `sample` at the element's `u`,
    /// its `density` and its `lobe_sensitivity`.
    fn of<D: Copy + 'a>(
        dist: D,
        sample: impl Fn(&D) -> DirectionSample,
        density: fn(&D, Vec3) -> f32,
        lobe_sensitivity: fn(&D, Vec3) -> f32,
    ) -> Self {
        let s = sample(&dist);
        CpuDecoded {
            direction: s.direction,
            pdf: s.pdf,
            density: Box::new(move |d| density(&dist, d)),
            lobe_sensitivity: Box::new(move |d| lobe_sensitivity(&dist, d)),
        }
    }
}

/// The CPU decode of element `i` of a raw batch.
type CpuDecode<'a> = Box<dyn Fn(&[f32], usize) -> CpuDecoded<'a> + 'a>;

/// How much `pdf` moves when `d` moves by a few ulp (along two tangents,
/// both ways).
fn local_sensitivity(pdf: &dyn Fn(Vec3) -> f32, d: Vec3) -> f32 {
    let p0 = pdf(d);
    let (t1, t2) = tangents(d);
    let h = PROBE_ULPS * f32::EPSILON;
    [t1, -t1, t2, -t2]
        .iter()
        .map(|&e| (pdf((d + h * e).normalize()) - p0).abs())
        .fold(0.0, f32::max)
}

/// Rotation, in radians, of NASG's lobe-frame probes: [`PROBE_ULPS`] ulp
/// of the angles' 2π range. NASG's frame angles are computed to ulps of
/// their range, not of the raw values: `α = 2π s` (and β, γ) become a frame
/// through libm's `sincosf` on the CPU and `sin_cos_turns(α / 2π)` on the
/// GPU, which rounds the turn (`2⁻²⁴` of `|α|`) and is within 2 ulp —
/// about 8·10⁻⁷ rad per angle, 2·10⁻⁶ for the three — and the sigmoid's
/// own ulp moves α by `2π` times it. Where the sigmoid saturates (`s = 1`
/// exactly), no nudge of the raw value moves the angle at all, while this
/// rounding remains.
const NASG_FRAME_PROBE: f32 = PROBE_ULPS * f32::EPSILON * core::f32::consts::TAU;

/// Rotation, in radians, of vMF's mean-direction probes: its components
/// come from `sin_cos_turns` on both sides (the same inlined code), so they
/// differ by the rounding of the contracted polynomials, [`PROBE_ULPS`] ulp
/// of a unit vector.
const VMF_MEAN_PROBE: f32 = PROBE_ULPS * f32::EPSILON;

/// The lobe probes of [`vmf_lobe_sensitivity`] and
/// [`nasg_lobe_sensitivity`], each applied both ways (`sign` ±1).
#[derive(Clone, Copy)]
enum LobeProbe {
    /// The frame (vMF: the mean) turned about a world axis by the family's
    /// frame probe ([`NASG_FRAME_PROBE`], [`VMF_MEAN_PROBE`]).
    Turn(Vec3),
    /// The frame vectors scaled by `1 ± h`: they are unit only to a few
    /// ulp, and so is the direction the density sees (the samplers return
    /// `pdf_unit` of their unnormalised result; both mixtures' densities
    /// depend on the direction and the frame only through their dot
    /// products, so scaling one is scaling the other).
    Scale,
    /// The sharpness (vMF κ, NASG λ) scaled by `1 ± h`: `exp` of a value
    /// that the decoder clamps (e¹⁰, e^9.21), where no nudge of the raw
    /// value moves it, while the exponent `κ (1 − cos)` it multiplies is
    /// large where the lobe is sharp.
    Sharpness,
    /// NASG's anisotropy `a` scaled by `1 ± h` (clamped at e¹⁰ likewise).
    Anisotropy,
}

const LOBE_PROBES: [LobeProbe; 6] = [
    LobeProbe::Turn(Vec3::X),
    LobeProbe::Turn(Vec3::Y),
    LobeProbe::Turn(Vec3::Z),
    LobeProbe::Scale,
    LobeProbe::Sharpness,
    LobeProbe::Anisotropy,
];

/// The mixture's density change at `d` when each lobe's decoded parameters
/// move by what their rounding can be ([`LobeProbe`]: [`PROBE_ULPS`] ulp,
/// or the family's frame probe), the larger of both ways summed over the
/// lobes and the probes: to first order the largest change that deviations
/// of that size, in any combination, can make. `rebuilt(m, k, probe,
/// sign)` is the mixture with lobe `k` probed (sign 0: rebuilt unprobed,
/// the reference, so that rebuilding itself does not count).
fn lobe_sensitivity<M>(
    m: &M,
    lobes: usize,
    d: Vec3,
    pdf: impl Fn(&M, Vec3) -> f32,
    rebuilt: impl Fn(&M, usize, LobeProbe, f32) -> M,
) -> f32 {
    let mut total = 0.0;
    for k in 0..lobes {
        let p0 = pdf(&rebuilt(m, k, LobeProbe::Scale, 0.0), d);
        for probe in LOBE_PROBES {
            let change = |sign: f32| (pdf(&rebuilt(m, k, probe, sign), d) - p0).abs();
            total += change(1.0).max(change(-1.0));
        }
    }
    total
}

/// `v` turned by `turn` radians or scaled by `probe` (`sign` ±1; 0 leaves
/// it).
fn probed(v: Vec3, probe: LobeProbe, sign: f32, turn: f32) -> Vec3 {
    match probe {
        LobeProbe::Turn(axis) => Quat::from_axis_angle(axis, sign * turn) * v,
        LobeProbe::Scale => v * (1.0 + sign * PROBE_ULPS * f32::EPSILON),
        _ => v,
    }
}

/// `x` scaled by `1 ± h` where `probe` is `which` (`sign` ±1; 0 leaves it).
fn probed_scalar(x: f32, probe: LobeProbe, which: LobeProbe, sign: f32) -> f32 {
    if std::mem::discriminant(&probe) == std::mem::discriminant(&which) {
        x * (1.0 + sign * PROBE_ULPS * f32::EPSILON)
    } else {
        x
    }
}

/// [`lobe_sensitivity`] of a vMF mixture (`a` does not exist: that probe
/// changes nothing).
fn vmf_lobe_sensitivity<const K: usize>(m: &VmfMixture<K>, d: Vec3) -> f32 {
    lobe_sensitivity(
        m,
        K,
        d,
        |m, d| m.pdf(d),
        |m, k, probe, sign| {
            let l = m.lobe(k);
            let kappa = probed_scalar(l.kappa, probe, LobeProbe::Sharpness, sign);
            let lobe = VmfLobe::new(probed(l.mean(), probe, sign, VMF_MEAN_PROBE), kappa);
            // `new` normalises the mean: scale after it.
            let mean = match probe {
                LobeProbe::Scale => probed(lobe.mean(), probe, sign, VMF_MEAN_PROBE),
                _ => lobe.mean(),
            };
            let mut q = *m;
            (q.mean_x[k], q.mean_y[k], q.mean_z[k]) = (mean.x, mean.y, mean.z);
            q.kappa[k] = lobe.kappa;
            q.norm[k] = lobe.norm;
            q.one_minus_e2k[k] = lobe.one_minus_e2k;
            q
        },
    )
}

/// [`lobe_sensitivity`] of a NASG mixture.
fn nasg_lobe_sensitivity<const K: usize>(m: &NasgMixture<K>, d: Vec3) -> f32 {
    lobe_sensitivity(
        m,
        K,
        d,
        |m, d| m.pdf(d),
        |m, k, probe, sign| {
            let l = m.lobe(k);
            let lobe = NasgLobe::new(
                Vec3::from_array(l.z),
                Vec3::from_array(l.x),
                probed_scalar(l.lambda, probe, LobeProbe::Sharpness, sign),
                probed_scalar(l.a, probe, LobeProbe::Anisotropy, sign),
                l.epsilon,
            );
            let [x, y, z] = [lobe.x, lobe.y, lobe.z]
                .map(|v| probed(Vec3::from_array(v), probe, sign, NASG_FRAME_PROBE));
            let mut q = *m;
            (q.x_x[k], q.x_y[k], q.x_z[k]) = (x.x, x.y, x.z);
            (q.y_x[k], q.y_y[k], q.y_z[k]) = (y.x, y.y, y.z);
            (q.z_x[k], q.z_y[k], q.z_z[k]) = (z.x, z.y, z.z);
            q.lambda[k] = lobe.lambda;
            q.a[k] = lobe.a;
            q.epsilon[k] = lobe.epsilon;
            q.log_norm[k] = lobe.log_norm;
            q.one_minus_e2l[k] = lobe.one_minus_e2l;
            q
        },
    )
}

/// Decode kernels (raw network outputs → distribution → sample / pdf) on
/// the GPU against the CPU functions, extreme parameters included. Sampled
/// directions are compared where no CDF boundary intervenes; every pdf (of
/// the ordinary and of the extreme vectors alike) to `rel` of its value
/// plus the distribution's measured condition: in the direction
/// ([`local_sensitivity`]), in the raw values (all moved by ±4 ulp
/// together) and in the decoded lobes' own parameters
/// (`lobe_sensitivity`: frame angles, frame lengths and clamped
/// exponentials, which the raw nudges cannot move where the activations
/// saturate). The extreme vectors
/// are held to the same bound as the ordinary ones; only their sampled
/// directions are not compared (see below).
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
    let (raw_up, raw_down) = (nudged(PROBE_ULPS), nudged(-PROBE_ULPS));
    let (mut differ, mut extreme_differ, mut worst, mut worst_extreme) =
        (0usize, 0usize, 0.0f32, 0.0f32);
    let mut failures = Vec::new();
    for i in 0..n {
        let c = cpu(&raw, i);
        let (dir, pdf, density) = (c.direction, c.pdf, &*c.density);
        let (up, down) = (cpu(&raw_up, i).density, cpu(&raw_down, i).density);
        let param_sens = |x: Vec3| {
            let p0 = density(x);
            (up(x) - p0).abs().max((down(x) - p0).abs())
        };
        // The density's condition at `x`: in the direction, the raw values
        // and the decoded lobes.
        let condition = |x: Vec3| {
            [
                local_sensitivity(density, x),
                param_sens(x),
                (c.lobe_sensitivity)(x),
            ]
        };
        let extreme = i % 7 == 3;
        let mut record = |what: &str, gpu: f32, cpu: f32, own: f32, cond: [f32; 3]| {
            let err = (gpu - cpu).abs();
            let bound = own + cond.iter().sum::<f32>();
            if gpu.is_finite() && err <= bound {
                let w = if extreme {
                    &mut worst_extreme
                } else {
                    &mut worst
                };
                *w = w.max(err / bound);
            } else {
                failures.push(format!(
                    "\n  {what} {i}{}: gpu {gpu:e} cpu {cpu:e} (|Δ| {err:e} = {:.2} × {bound:e}: \
                     rel + gaps {own:e}, direction {:e}, raw {:e}, lobes {:e})",
                    if extreme { " (extreme)" } else { "" },
                    err / bound,
                    cond[0],
                    cond[1],
                    cond[2]
                ));
            }
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
            if extreme {
                extreme_differ += 1;
            } else {
                differ += 1;
            }
        } else {
            let e_c = density(dir);
            let own = rel * pdf.abs().max(1e-2) + (density(gd) - e_c).abs() + (pdf - e_c).abs();
            record("sample pdf", g[3], pdf, own, condition(dir));
        }
        let dd = batch::unpack_direction(d[i]);
        let pdf_d = density(dd);
        record(
            "pdf",
            p[i],
            pdf_d,
            rel * pdf_d.abs().max(1e-2),
            condition(dd),
        );
    }
    assert!(
        differ * 100 < n,
        "{family}: {differ} of {n} ordinary samples differ"
    );
    assert!(
        failures.is_empty(),
        "{family} (code {code}): {} pdfs beyond their bound:{}",
        failures.len(),
        failures.concat()
    );
    eprintln!(
        "{family} decode (code {code}): {n} raw vectors (1 in 7 extreme), {differ} ordinary and \
         {extreme_differ} extreme samples in another direction, every pdf within its bound: at \
         most {worst:.3} of it on the ordinary vectors, {worst_extreme:.3} on the extreme ones"
    );
}

/// [`check_decode`] of a mixture family (`per` raw outputs per vector,
/// [`MIXTURE_PDF_REL`]): `from_raw` decodes vector `i` on the CPU, which
/// samples it with `uv(i)`.
fn check_mixture_decode<M: LobeMixture + Copy>(
    ctx: &GpuContext,
    family: &str,
    per: usize,
    from_raw: fn(&[f32], usize) -> M,
    lobe_sensitivity: fn(&M, Vec3) -> f32,
    uv: &dyn Fn(usize) -> Vec2,
) {
    let cpu = move |raw: &[f32], i: usize| {
        CpuDecoded::of(
            from_raw(raw, i * per),
            |m| m.sample(uv(i)),
            |m, d| m.pdf(d),
            lobe_sensitivity,
        )
    };
    check_decode(ctx, family, per, 0, MIXTURE_PDF_REL, Box::new(cpu));
}

#[test]
fn decode_kernels_match_the_cpu_on_ordinary_and_extreme_parameters() {
    let Some(ctx) = test_context() else { return };
    use guiding_core::model::df::{DF_CONDITIONAL_BINS, DF_MARGINAL_BINS};
    // `check_decode` draws the same random pairs (seed 19).
    let u = randoms(2000, 19);
    let uv = |i: usize| Vec2::new(u[i][0], u[i][1]);
    check_mixture_decode(
        &ctx,
        "vmf",
        32,
        batch::vmf_mixture_from_raw,
        vmf_lobe_sensitivity,
        &uv,
    );
    check_mixture_decode(
        &ctx,
        "nasg",
        49,
        batch::nasg_mixture_from_raw,
        nasg_lobe_sensitivity,
        &uv,
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
                CpuDecoded::of(
                    batch::df_table_from_raw(raw, i * per, interp),
                    |t| t.sample(uv(i)),
                    |t, d| t.pdf(d),
                    |_, _| 0.0,
                )
            }),
        );
    }
}

/// Agreement of a lane kernel's samples and densities with the CPU's
/// (relative tolerance `rel`, widened by the density's local sensitivity).
struct LaneCheck {
    prefix: &'static str,
    rel: f32,
    /// Samples the GPU drew in another direction (across a CDF boundary).
    differ: usize,
    /// The largest error over its bound.
    worst: f32,
}

impl LaneCheck {
    fn new(prefix: &'static str, rel: f32) -> Self {
        Self {
            prefix,
            rel,
            differ: 0,
            worst: 0.0,
        }
    }

    /// Lane `k`: the GPU's sample `[ω, pdf]` and density at `d` against the
    /// CPU's sample `(ω, pdf)` and density at `d`; `density` is the CPU's.
    fn lane(
        &mut self,
        k: usize,
        density: &dyn Fn(Vec3) -> f32,
        (g, p_gpu): ([f32; 4], f32),
        ((cd, c_pdf), p_cpu): ((Vec3, f32), f32),
        d: Vec3,
    ) {
        let prefix = self.prefix;
        let gd = batch::unpack_direction(g);
        assert!(
            g.iter().all(|x| x.is_finite()) && g[3] > 0.0,
            "{prefix}: GPU sample {k} {g:?}"
        );
        if (gd - cd).length() > 1e-4 {
            assert!(density(gd) > 0.0, "{prefix}: GPU sample {k} at density 0");
            self.differ += 1;
        } else {
            let bound = self.rel * c_pdf.abs().max(1e-2)
                + (density(gd) - density(cd)).abs()
                + (c_pdf - density(cd)).abs()
                + local_sensitivity(density, cd);
            let err = (g[3] - c_pdf).abs();
            assert!(
                err <= bound,
                "{prefix}: sample {k} pdf gpu {} cpu {c_pdf} (bound {bound:e})",
                g[3]
            );
            self.worst = self.worst.max(err / bound);
        }
        let bound = self.rel * p_cpu.abs().max(1e-2) + local_sensitivity(density, d);
        let err = (p_gpu - p_cpu).abs();
        assert!(
            p_gpu.is_finite() && err <= bound,
            "{prefix}: pdf {k} gpu {p_gpu} cpu {p_cpu} (bound {bound:e})"
        );
        self.worst = self.worst.max(err / bound);
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
    let Some(ctx) = test_context() else { return };
    let npm = NpmCompactRadiance::new(compact(), Target::Radiance);
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
    let mut gpu = upload(ctx.clone(), model, prefix, M::FAMILY, &params).expect("upload");
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
        for (i, &g) in selection.iter().enumerate() {
            let c = batch::nasg_mixture_from_raw(&raw, i * r).selection_probability;
            assert!(
                (g - c).abs() <= 1e-5 * c.abs().max(1e-2),
                "{prefix}: selection {i}: gpu {g} cpu {c}"
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
            batch::lane_sample_element::<VmfMixture<8>>(&raw, &lanes, &normals, &u, &mut s_cpu, k);
            batch::lane_pdf_element::<VmfMixture<8>>(&raw, &lanes, &normals, &d, &mut p_cpu, k);
        } else {
            batch::lane_sample_element::<NasgMixture<8>>(&raw, &lanes, &normals, &u, &mut s_cpu, k);
            batch::lane_pdf_element::<NasgMixture<8>>(&raw, &lanes, &normals, &d, &mut p_cpu, k);
        }
    }
    let mut check = LaneCheck::new(prefix, MIXTURE_PDF_REL);
    for k in 0..m {
        let density = |dir: Vec3| -> f32 {
            let mut out = [0.0f32];
            let one = [[dir.x, dir.y, dir.z, 0.0]];
            let (l, nm) = ([lanes[k]], [normals[k]]);
            if vmf {
                batch::lane_pdf_element::<VmfMixture<8>>(&raw, &l, &nm, &one, &mut out, 0);
            } else {
                batch::lane_pdf_element::<NasgMixture<8>>(&raw, &l, &nm, &one, &mut out, 0);
            }
            out[0]
        };
        let c = s_cpu[k];
        let cpu_sample = (batch::unpack_direction(c), c[3]);
        let d = batch::unpack_direction(d[k]);
        check.lane(k, &density, (s_gpu[k], p_gpu[k]), (cpu_sample, p_cpu[k]), d);
    }
    let LaneCheck { differ, worst, .. } = check;
    assert!(
        differ * 100 < m,
        "{prefix}: {differ} of {m} lane samples in another direction"
    );
    eprintln!(
        "{prefix} lanes: {m} lanes of {n} resident rows, {differ} samples across a CDF \
         boundary, the rest and every pdf within {worst:.3} of the bound"
    );
}

/// DF's per-vertex kernels: the vertices of a wavefront kept on the device
/// ([`GpuModel::vertices_resident`]) against [`guiding_core::model::df::VertexModel::vertex`]
/// (base input to `1e-5 · max(|b|, 1)`, as the network outputs; the marginal
/// density at 64 points to [`DF_PDF_REL`]), then sample / pdf of lanes picked
/// in any order against the CPU's `sample_vertex` / `pdf_vertex` on the
/// device's own vertices, compared as the lane kernels (directions where no
/// CDF boundary intervenes; pdfs to `DF_PDF_REL` plus the density's local
/// condition).
#[test]
fn df_vertex_kernels_match_the_cpu() {
    use guiding_core::model::df::DfVertex;
    let Some(ctx) = test_context() else { return };
    for (prefix, model) in [
        (
            "df_small_radiance",
            DfSmallRadiance::small(LO, HI, Interpolation::Linear),
        ),
        (
            "df_small_radiance",
            DfSmallRadiance::small(LO, HI, Interpolation::Nearest),
        ),
    ] {
        check_vertices(&ctx, &model, prefix);
    }
    let product = DfCompactProduct::new(compact(), Target::Product, Interpolation::Linear);
    check_vertices(&ctx, &product, "df_compact_product");

    fn check_vertices<M: guiding_core::model::df::VertexModel + bytemuck::Pod>(
        ctx: &GpuContext,
        model: &M,
        prefix: &'static str,
    ) {
        let params = parameters(model, 13);
        let mut gpu = upload(ctx.clone(), model, prefix, M::FAMILY, &params).expect("upload");
        let n = 600;
        let q = queries(n, 43);
        let mut buf = None;
        gpu.vertices_resident(&q, &mut buf).expect("vertices");
        let buf = buf.expect("vertex buffer");
        // The buffer is grown to a power of two: read the first n vertices.
        let mut vertices = vec![DfVertex::ZERO; n];
        buf.download_into(&mut vertices).expect("download");
        let probes: Vec<f32> = (0..64).map(|k| (k as f32 + 0.37) / 64.0).collect();
        for (i, v) in vertices.iter().enumerate() {
            let c = model.vertex(&params, &q[i]);
            for (j, (&g, &b)) in v.base.iter().zip(&c.base).enumerate() {
                assert!(
                    (g - b).abs() <= 1e-5 * b.abs().max(1.0),
                    "{prefix}: vertex {i} base[{j}] gpu {g} cpu {b}"
                );
            }
            for &e in &probes {
                let (g, b) = (v.marginal.pdf(e), c.marginal.pdf(e));
                assert!(
                    (g - b).abs() <= DF_PDF_REL * b.abs().max(1e-2),
                    "{prefix}: vertex {i} marginal({e}) gpu {g} cpu {b}"
                );
            }
        }
        let lanes: Vec<u32> = (0..n as u32).rev().chain(0..n as u32 / 2).collect();
        let m = lanes.len();
        let u = randoms(m, 47);
        let d = directions(m, 53);
        let mut s_gpu = vec![[0.0f32; 4]; m];
        let mut p_gpu = vec![0.0f32; m];
        gpu.sample_vertex_lanes(&buf, &lanes, &u, &mut s_gpu)
            .expect("sample vertex lanes");
        gpu.pdf_vertex_lanes(&buf, &lanes, &d, &mut p_gpu)
            .expect("pdf vertex lanes");
        let mut check = LaneCheck::new(prefix, DF_PDF_REL);
        for k in 0..m {
            let v = vertices[lanes[k] as usize];
            let density = |dir: Vec3| model.pdf_vertex(&params, &v, dir);
            let c = model.sample_vertex(&params, &v, Vec2::new(u[k][0], u[k][1]));
            let d = batch::unpack_direction(d[k]);
            let cpu = ((c.direction, c.pdf), density(d));
            check.lane(k, &density, (s_gpu[k], p_gpu[k]), cpu, d);
        }
        let LaneCheck { differ, worst, .. } = check;
        assert!(
            differ * 100 < m,
            "{prefix}: {differ} of {m} vertex samples in another direction"
        );
        eprintln!(
            "{prefix} vertices: {n} resident, {m} lanes, {differ} samples across a CDF \
             boundary, the rest and every pdf within {worst:.3} of the bound"
        );
    }
}
