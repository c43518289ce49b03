//! Tests of the three guiding models (`model::npm`, `model::nasg`,
//! `model::df`), on their small presets (grid 2 levels × 4 features, MLPs
//! 2 × 16) with random parameters:
//!
//! 1. whole-chain gradients: `accumulate_gradient` against central
//!    differences of an `f64` re-implementation of grid → encodings → MLP(s)
//!    → decoder → `ln q` → loss (`guiding_tests::oracles`), for NPM
//!    (radiance, product), NASG (product, radiance), DF-N and DF-L with the
//!    radiance-cache term (and DF with the noisy-radiance weight);
//! 2. sampling: the returned pdf is `pdf(direction)`, directions are unit;
//!    `∫ pdf dω = 1` by Gauss–Legendre quadrature;
//! 3. invalid samples (and too short buffers) add nothing and return 0;
//! 4. deterministic initialisation; layout bookkeeping of the presets;
//!    totality on degenerate queries and parameters;
//! 5. a short training run concentrates each guide on a lobe of radiance.
//!
//! Tolerances of the gradient check: symmetric relative error
//! `|a − n| / max(|a|, |n|, floor)` ≤ 10⁻² for ≥ 99% of the components,
//! with `floor = 10⁻³ ×` the RMS of the numeric components of the model (an
//! absolute error for components near zero). The analytic gradient is the
//! `f32` chain: every stage adds a relative error of a few ε = 2⁻²³ (ε·√n
//! for the `n`-term MLP sums), so components agree to ~10⁻⁵ relative, except
//! where the `f32` and `f64` evaluations straddle a kink (a ReLU at 0). The
//! 1% allowance absorbs those; the 10⁻² tolerance is ~10² times the
//! rounding level, while a wrong chain-rule factor is off by O(1). (DF's
//! oracle takes `ε` from the library's `f32` warp: the triangle wave's top
//! frequency, slope 2¹², would turn the ~10⁻⁷ between an `f32` and an `f64`
//! warp into ~10⁻³ relative in the conditional's gradient.)

use core::f64::consts::PI;
use glam::{DVec3, Quat, Vec2, Vec3};
use guiding_core::encoding::{grid_corners, GridConfig};
use guiding_core::loss::Target;
use guiding_core::mixture::nasg::{NASG_SELECTION_MAX, NASG_SELECTION_MIN};
use guiding_core::model::df::{
    Df, DfProduct, DfRadiance, DfSmallProduct, DfSmallRadiance, DfWeightSource,
    DF_CONDITIONAL_BINS, DF_MARGINAL_BINS,
};
use guiding_core::model::nasg::{
    Nasg, NasgProduct, NasgRadiance, NasgSmallProduct, NasgSmallRadiance, NASG_MIS_BLEND,
    NASG_OUTPUTS,
};
use guiding_core::model::npm::{
    grid_param_count, small_grid, Npm, NpmProduct, NpmRadiance, NpmSmallProduct, NpmSmallRadiance,
    NPM_OUTPUTS,
};
use guiding_core::model::{GuidingModel, QueryPoint};
use guiding_core::optim::{adam_step, AdamConfig};
use guiding_core::pdf1d::{Boundary, Interpolation};
use guiding_core::sample::TrainingSample;
use guiding_tests::chi2::Warp;
use guiding_tests::gradcheck::{central_difference, GradientErrors};
use guiding_tests::oracles::{self, MlpShape};
use guiding_tests::quadrature::integrate;
use guiding_tests::rng::Pcg32;
use std::collections::BTreeSet;

const BBOX_MIN: [f32; 3] = [-1.0, -2.0, -0.5];
const BBOX_MAX: [f32; 3] = [2.0, 1.0, 1.5];

const NPM_R: NpmSmallRadiance = NpmSmallRadiance::small(BBOX_MIN, BBOX_MAX);
const NPM_P: NpmSmallProduct = NpmSmallProduct::small(BBOX_MIN, BBOX_MAX);
const NASG_P: NasgSmallProduct = NasgSmallProduct::small(BBOX_MIN, BBOX_MAX);
const NASG_R: NasgSmallRadiance = NasgSmallRadiance::small(BBOX_MIN, BBOX_MAX);
const DF_N: DfSmallProduct = DfSmallProduct::small(BBOX_MIN, BBOX_MAX, Interpolation::Nearest);
const DF_L: DfSmallRadiance = DfSmallRadiance::small(BBOX_MIN, BBOX_MAX, Interpolation::Linear);

// ---------------------------------------------------------------------------
// Layouts and random inputs.

/// The pieces of a model's flat buffer: the grid and each MLP with its offset.
struct Layout {
    grid: GridConfig,
    mlps: Vec<(&'static str, usize, MlpShape)>,
}

fn shape(input: usize, width: usize, output: usize, hidden: usize) -> MlpShape {
    MlpShape {
        input,
        width,
        output,
        hidden,
    }
}

/// Random parameters with O(1) activations: grid `U(−1, 1)`, weights
/// `U(−a, a)` with `a = √(6 / fan_in)` in every layer (so the raw outputs
/// are O(1) and the decoded distributions have structure), biases
/// `U(−0.2, 0.2)`.
fn random_params(layout: &Layout, total: usize, rng: &mut Pcg32) -> Vec<f32> {
    let mut p = vec![0.0f32; total];
    for v in p.iter_mut().take(layout.grid.param_count()) {
        *v = rng.uniform(-1.0, 1.0);
    }
    for (_, off, shape) in &layout.mlps {
        let mut o = *off;
        for (fan_in, fan_out) in shape.layers() {
            let a = (6.0 / fan_in as f32).sqrt();
            for k in 0..fan_in * fan_out {
                p[o + k] = rng.uniform(-a, a);
            }
            for k in 0..fan_out {
                p[o + fan_in * fan_out + k] = rng.uniform(-0.2, 0.2);
            }
            o += (fan_in + 1) * fan_out;
        }
    }
    p
}

fn random_unit(rng: &mut Pcg32) -> Vec3 {
    let z = 1.0 - 2.0 * rng.next_f32();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f32::consts::PI * rng.next_f32();
    Vec3::new(r * phi.cos(), r * phi.sin(), z).normalize()
}

fn random_position(rng: &mut Pcg32) -> [f32; 3] {
    [
        rng.uniform(BBOX_MIN[0], BBOX_MAX[0]),
        rng.uniform(BBOX_MIN[1], BBOX_MAX[1]),
        rng.uniform(BBOX_MIN[2], BBOX_MAX[2]),
    ]
}

/// A valid sample; a quarter have a zero (unknown) normal, a quarter an
/// unknown BSDF pdf.
fn random_sample(rng: &mut Pcg32) -> TrainingSample {
    let normal = if rng.next_f32() < 0.25 {
        Vec3::ZERO
    } else {
        random_unit(rng)
    };
    let bsdf_pdf = if rng.next_f32() < 0.25 {
        0.0
    } else {
        rng.uniform(0.01, 2.0)
    };
    // Drawn in the order of the struct's fields.
    let position = random_position(rng);
    let roughness = rng.next_f32();
    let sample_pdf = rng.uniform(0.05, 2.0);
    let wo = random_unit(rng).to_array();
    let wi = random_unit(rng).to_array();
    let radiance = [
        rng.uniform(0.05, 3.0),
        rng.uniform(0.05, 3.0),
        rng.uniform(0.05, 3.0),
    ];
    let bsdf_cos = [
        rng.uniform(0.05, 1.0),
        rng.uniform(0.05, 1.0),
        rng.uniform(0.05, 1.0),
    ];
    let vertex = QueryPoint::new(position, normal.to_array(), wo, roughness);
    let s = TrainingSample::new(vertex, wi, radiance, sample_pdf, bsdf_pdf, bsdf_cos);
    assert!(s.validate().is_ok());
    s
}

fn random_query(rng: &mut Pcg32) -> QueryPoint {
    QueryPoint::of_sample(&random_sample(rng))
}

fn dvec(a: [f32; 3]) -> DVec3 {
    Vec3::from_array(a).as_dvec3()
}

// ---------------------------------------------------------------------------
// f64 oracles of the full models.

fn mean3(v: [f64; 3]) -> f64 {
    (v[0] + v[1] + v[2]) / 3.0
}

fn rgb64(v: [f32; 3]) -> [f64; 3] {
    [f64::from(v[0]), f64::from(v[1]), f64::from(v[2])]
}

/// `p̂ / p_s` (NPM eq. 9).
fn kl_weight64(s: &TrainingSample, target: Target) -> f64 {
    let l = rgb64(s.radiance);
    let f = rgb64(s.bsdf_cos);
    let v = match target {
        Target::Radiance => mean3(l),
        Target::Product => mean3([l[0] * f[0], l[1] * f[1], l[2] * f[2]]),
    };
    v / f64::from(s.sample_pdf)
}

/// DF's weight for radiance `l`.
fn df_weight64(l: [f64; 3], s: &TrainingSample, target: Target) -> f64 {
    let f = rgb64(s.bsdf_cos);
    let v = match target {
        Target::Product => mean3([l[0] * f[0], l[1] * f[1], l[2] * f[2]]),
        Target::Radiance => {
            let n = dvec(s.normal);
            let cos = if n == DVec3::ZERO {
                1.0
            } else {
                n.dot(dvec(s.wi)).abs()
            };
            mean3(l) * cos
        }
    };
    v / f64::from(s.sample_pdf)
}

/// `[grid | product inputs]` in f64.
fn input64(p: &[f64], grid: &GridConfig, target: Target, s: &TrainingSample) -> Vec<f64> {
    let mut x = oracles::grid(p, grid, dvec(s.position));
    if target == Target::Product {
        x.extend(oracles::product_inputs(
            dvec(s.normal),
            dvec(s.wo),
            f64::from(s.roughness),
        ));
    }
    x
}

/// A model with its f64 oracle, written from the docs: the pieces of its
/// flat buffer and its training loss.
trait Oracle: GuidingModel {
    /// The grid and each MLP with its offset.
    fn layout(&self) -> Layout;
    /// The loss at parameters `p`, the stop-gradient quantities (DF's
    /// weight radiance and relative L2 denominator) taken at `base`.
    fn loss64(&self, base: &[f64], p: &[f64], s: &TrainingSample) -> f64;
}

impl Layout {
    /// A grid and one MLP (NPM, NASG).
    fn single_mlp(grid: GridConfig, offset: u32, shape: MlpShape) -> Self {
        Layout {
            grid,
            mlps: vec![("mlp", offset as usize, shape)],
        }
    }

    /// The single MLP's output on [`input64`].
    fn mlp_output64(&self, p: &[f64], target: Target, s: &TrainingSample) -> Vec<f64> {
        let x = input64(p, &self.grid, target, s);
        let (_, offset, shape) = self.mlps[0];
        oracles::mlp(p, offset, shape, &x)
    }
}

impl<const IN: usize, const W: usize, const H: usize> Oracle for Npm<IN, W, H> {
    fn layout(&self) -> Layout {
        Layout::single_mlp(self.grid, self.mlp_offset, shape(IN, W, NPM_OUTPUTS, H))
    }

    fn loss64(&self, _: &[f64], p: &[f64], s: &TrainingSample) -> f64 {
        let y = self.layout().mlp_output64(p, self.target(), s);
        -kl_weight64(s, self.target()) * oracles::vmf_ln_pdf(&y, dvec(s.wi))
    }
}

impl<const IN: usize, const W: usize, const H: usize> Oracle for Nasg<IN, W, H> {
    fn layout(&self) -> Layout {
        Layout::single_mlp(self.grid, self.mlp_offset, shape(IN, W, NASG_OUTPUTS, H))
    }

    fn loss64(&self, _: &[f64], p: &[f64], s: &TrainingSample) -> f64 {
        let y = self.layout().mlp_output64(p, self.target(), s);
        let ln_q = oracles::nasg_ln_pdf(&y[..NASG_OUTPUTS - 1], dvec(s.wi));
        let c = oracles::nasg_selection(y[NASG_OUTPUTS - 1]);
        oracles::nasg_mis_loss(
            kl_weight64(s, self.target()),
            ln_q,
            c,
            f64::from(s.bsdf_pdf),
            f64::from(NASG_MIS_BLEND),
        )
    }
}

#[allow(clippy::many_single_char_names)]
impl<
        const A: usize,
        const B: usize,
        const C: usize,
        const D: usize,
        const E: usize,
        const F: usize,
        const G: usize,
    > Oracle for Df<A, B, C, D, E, F, G>
{
    fn layout(&self) -> Layout {
        Layout {
            grid: self.grid,
            mlps: vec![
                (
                    "marginal",
                    self.marginal_offset as usize,
                    shape(A, D, DF_MARGINAL_BINS, E),
                ),
                (
                    "conditional",
                    self.conditional_offset as usize,
                    shape(B, D, DF_CONDITIONAL_BINS, E),
                ),
                ("cache", self.cache_offset as usize, shape(C, F, 3, G)),
            ],
        }
    }

    fn loss64(&self, base: &[f64], p: &[f64], s: &TrainingSample) -> f64 {
        let layout = self.layout();
        let frozen = df_cache64(&layout, base, s);
        let l = match self.weight_source() {
            DfWeightSource::Cache => frozen,
            DfWeightSource::Sample => rgb64(s.radiance),
        };
        let w = df_weight64(l, s, self.target());
        let pred = df_cache64(&layout, p, s);
        let t = rgb64(s.radiance);
        let rel: f64 = (0..3)
            .map(|c| (pred[c] - t[c]).powi(2) / (frozen[c] * frozen[c] + 0.01))
            .sum::<f64>()
            / 3.0;
        let guide = if w == 0.0 {
            0.0
        } else {
            let ln_q = df_ln_q64(&layout, self.target(), self.interpolation(), p, s);
            -w * ln_q
        };
        guide + f64::from(self.cache_loss_weight) * rel
    }
}

/// DF's cache prediction `softplus(MLP_r([grid | SH₄(ωᵢ)]))` (the third MLP
/// of `layout`).
fn df_cache64(layout: &Layout, p: &[f64], s: &TrainingSample) -> [f64; 3] {
    let (_, offset, cache) = layout.mlps[2];
    let mut x = oracles::grid(p, &layout.grid, dvec(s.position));
    x.extend(oracles::sh4(dvec(s.wi)));
    let raw = oracles::mlp(p, offset, cache, &x);
    [
        oracles::softplus(raw[0]),
        oracles::softplus(raw[1]),
        oracles::softplus(raw[2]),
    ]
}

/// DF's `ln q(ωᵢ) = ln p(ε₁) + ln p(ε₂|ε₁) − ln 4π` with both networks (the
/// first two MLPs of `layout`) in f64.
fn df_ln_q64(
    layout: &Layout,
    target: Target,
    interp: Interpolation,
    p: &[f64],
    s: &TrainingSample,
) -> f64 {
    let direction = dvec(s.wi);
    let (_, marginal_offset, marginal) = layout.mlps[0];
    let (_, conditional_offset, conditional) = layout.mlps[1];
    let base = input64(p, &layout.grid, target, s);
    // ε of the f32 warp (tested in factorised.rs), so that both chains feed
    // the same ε₁ to the triangle wave: its top frequency turns the ~10⁻⁷
    // between the f32 and f64 warps into ~10⁻³ relative in the gradient.
    let eps = guiding_core::factorised::square_from_direction(direction.as_vec3());
    let (e1, e2) = (f64::from(eps.x), f64::from(eps.y));
    debug_assert!((e1 - oracles::square(direction).0).abs() < 1e-6);
    let lm = oracles::mlp(p, marginal_offset, marginal, &base);
    let mut xc = base;
    xc.extend(oracles::triangle_wave(e1, 12));
    let lc = oracles::mlp(p, conditional_offset, conditional, &xc);
    oracles::pdf1d_ln_pdf(&lm, e1, interp, Boundary::Wrap)
        + oracles::pdf1d_ln_pdf(&lc, e2, interp, Boundary::Clamp)
        - (4.0 * PI).ln()
}

// ---------------------------------------------------------------------------
// 1. Whole-chain gradient checks.

/// Runs `body` once for each of the five small models, with `name`, `model`
/// (a reference), `layout` (its [`Layout`]) and `seed` (1 to 5) bound:
/// NPM radiance, NPM product, NASG product, DF-N and DF-L. A macro because
/// the models are distinct types.
macro_rules! for_each_small_model {
    (|$name:pat_param, $model:pat_param, $layout:pat_param, $seed:pat_param| $body:expr) => {{
        let ($name, $model, $layout, $seed) = ("NPM radiance", &NPM_R, &NPM_R.layout(), 1u64);
        $body;
        let ($name, $model, $layout, $seed) = ("NPM product", &NPM_P, &NPM_P.layout(), 2u64);
        $body;
        let ($name, $model, $layout, $seed) = ("NASG product", &NASG_P, &NASG_P.layout(), 3u64);
        $body;
        let ($name, $model, $layout, $seed) = ("DF-N", &DF_N, &DF_N.layout(), 4u64);
        $body;
        let ($name, $model, $layout, $seed) = ("DF-L", &DF_L, &DF_L.layout(), 5u64);
        $body;
    }};
}

/// Indices of the grid parameters `position` reads (8 corners × F features
/// per level).
fn touched_grid(grid: &GridConfig, position: Vec3) -> BTreeSet<usize> {
    let mut set = BTreeSet::new();
    for l in 0..grid.level_count() {
        let c = grid_corners(grid, position, l as u32);
        for corner in 0..8 {
            for k in 0..grid.feature_count() {
                set.insert(c.index[corner] + k);
            }
        }
    }
    set
}

/// Tolerance of the whole-chain gradient checks: symmetric relative error
/// `|a − n| / max(|a|, |n|, 10⁻³ · RMS)` per component.
///
/// The numeric side is exact for this purpose: f64 central differences of
/// the f64 loss with `h = 10⁻⁶·max(1, |x|)` have truncation error
/// `h² |f‴| / 6 ≈ 10⁻¹³` and rounding `ε₆₄ |f| / h ≈ 1.1·10⁻¹⁰ |f|`
/// (the loss `|f| ≲ 30`), both far below the floor (`10⁻³ ×` an RMS gradient
/// of 0.09–0.8). The analytic side is `f32`: a component is reached
/// through `N ≲ 100` roundings (three layers of 16-wide dot products
/// backwards, the decoder's log-sum-exp over 8 lobes, the grid's
/// trilinear weights), so with rounding errors of random sign its absolute
/// error is `≈ ε₃₂ √N · S`, `S` the size of the terms it sums (≈ the RMS
/// gradient). Relative to `max(|g|, floor)` that is at most
/// `ε₃₂ √N · S / floor = 1.2·10⁻⁷ · 10 · 10³ = 1.2·10⁻³`, for a component at
/// the floor whose terms are RMS-sized (a cancellation of 10³, the most the
/// floor admits). The tolerance is 8 of those: `10⁻²`. Measured over the
/// 19 440 components of the tests below: median 1–5·10⁻⁷ (a few `ε₃₂`),
/// 99th percentile ≤ 2·10⁻⁵, worst 7.8·10⁻⁴, none above `10⁻²`.
///
/// What it catches: a defect of relative size `δ` in a component above the
/// floor gives `e = δ / (1 + δ)`, so any `δ ≳ 1 %`, once it touches more than
/// [`GRADIENT_IGNORED`] of the components
/// (`gradient_check_rejects_a_planted_defect`).
const GRADIENT_TOL: f64 = 1e-2;

/// Fraction of the components that may exceed [`GRADIENT_TOL`] (the
/// tiny-cuda-nn convention): a difference step that straddles a ReLU kink
/// (probability `~h = 10⁻⁶` per component: 0.02 expected in these tests) or a
/// component beyond the floor's cancellation bound (terms ≫ the RMS
/// gradient); measured: none in 19 440. It is also the blind spot: a defect
/// confined to fewer components passes. It was 1 %, and the negative control
/// showed that too blind: one MLP layer's weight gradient 5 % off makes only
/// 40 of DF-L's 4080 components fail (most of that layer's components are 0:
/// inactive ReLUs, samples the guide loss does not weight), exactly the 1 %
/// allowed. At 0.1 % (2–4 components per check) it still covers the kinks.
const GRADIENT_IGNORED: f64 = 1e-3;

/// Compares `accumulate_gradient` with central differences (`h = 10⁻⁶`)
/// of [`Oracle::loss64`]`(base, params, sample)` on `samples` random (parameters,
/// sample) pairs, at every touched grid entry and 6 weights + 2 biases of
/// every layer of every MLP, and returns the compared components (floor
/// `10⁻³ ×` their RMS numeric value); checks on the way the loss value,
/// finiteness, and that untouched grid entries get exactly zero.
fn gradient_errors<M: Oracle>(name: &str, model: &M, samples: usize, seed: u64) -> GradientErrors {
    let layout = &model.layout();
    let mut rng = Pcg32::new(seed, 11);
    let n = model.param_count();
    let mut entries: Vec<(String, f64, f64)> = Vec::new();
    let mut worst_loss = 0.0f64;
    for t in 0..samples {
        let params = random_params(layout, n, &mut rng);
        let s = random_sample(&mut rng);
        let mut grad = vec![0.0f32; n];
        let loss = model.accumulate_gradient(&params, &s, &mut grad);
        let p64: Vec<f64> = params.iter().map(|&v| f64::from(v)).collect();
        let loss_ref = model.loss64(&p64, &p64, &s);
        let loss_err = (f64::from(loss) - loss_ref).abs() / loss_ref.abs().max(1.0);
        worst_loss = worst_loss.max(loss_err);
        assert!(
            loss_err <= 1e-5,
            "{name}, sample {t}: loss {loss} vs f64 {loss_ref}"
        );
        assert!(
            grad.iter().all(|g| g.is_finite()),
            "{name}: non-finite gradient"
        );
        let touched = touched_grid(&layout.grid, s.position());
        for (i, g) in grad.iter().enumerate().take(layout.grid.param_count()) {
            assert!(
                touched.contains(&i) || *g == 0.0,
                "{name}, sample {t}: untouched grid entry {i} has gradient {g}"
            );
        }
        let mut idx: Vec<(String, usize)> =
            touched.iter().map(|&i| (format!("grid[{i}]"), i)).collect();
        for (net, off, shape) in &layout.mlps {
            let mut o = *off;
            for (l, (fan_in, fan_out)) in shape.layers().into_iter().enumerate() {
                // Distinct components (a repeated index would be perturbed
                // by only one of its copies).
                let mut chosen = BTreeSet::new();
                while chosen.len() < 6 {
                    chosen.insert(rng.next_u32() as usize % (fan_in * fan_out));
                }
                idx.extend(chosen.iter().map(|k| (format!("{net} W{l}[{k}]"), o + k)));
                let mut chosen = BTreeSet::new();
                while chosen.len() < 2 {
                    chosen.insert(rng.next_u32() as usize % fan_out);
                }
                idx.extend(
                    chosen
                        .iter()
                        .map(|k| (format!("{net} b{l}[{k}]"), o + fan_in * fan_out + k)),
                );
                o += (fan_in + 1) * fan_out;
            }
        }
        let x0: Vec<f64> = idx.iter().map(|(_, i)| p64[*i]).collect();
        let numeric = central_difference(
            |x| {
                let mut p = p64.clone();
                for (j, (_, i)) in idx.iter().enumerate() {
                    p[*i] = x[j];
                }
                model.loss64(&p64, &p, &s)
            },
            &x0,
            1e-6,
        );
        for (j, (label, i)) in idx.iter().enumerate() {
            entries.push((
                format!("sample {t} {label}"),
                f64::from(grad[*i]),
                numeric[j],
            ));
        }
    }
    let rms = (entries.iter().map(|e| e.2 * e.2).sum::<f64>() / entries.len() as f64).sqrt();
    let mut errors = GradientErrors::new(1e-3 * rms);
    for (label, a, num) in entries {
        errors.push(label, a, num);
    }
    let (above, worst) = errors.summary(GRADIENT_TOL);
    println!(
        "{name}: {above} of {} components above {GRADIENT_TOL:e} (median {:.1e}, 99th percentile \
         {:.1e}, worst {worst:.2e}, RMS gradient {rms:.2e}); worst loss error {worst_loss:.2e}",
        errors.entries.len(),
        errors.quantile(0.5),
        errors.quantile(0.99),
    );
    errors
}

/// The whole-chain check: [`gradient_errors`] within [`GRADIENT_TOL`] for all
/// but [`GRADIENT_IGNORED`] of the components.
fn gradient_check<M: Oracle>(name: &str, model: &M, samples: usize, seed: u64) {
    gradient_errors(name, model, samples, seed).assert(name, GRADIENT_TOL, GRADIENT_IGNORED);
}

/// Negative control of the whole-chain check: the gradients of
/// `npm_radiance_gradient` and of `df_linear_gradient`'s first case (same
/// models, samples and seeds) with one defect planted — the second layer's
/// weight gradient (`W1`) of the first MLP 5 % too large — must be rejected.
/// That is 6 of the 88 (NPM) or 136 (DF) compared components per sample, each
/// at `e = 0.05/1.05 = 0.048` against the tolerance `10⁻²` unless it is 0
/// (an inactive ReLU, a sample the guide loss does not weight): measured 55 of
/// 2640 (NPM) and 40 of 4080 (DF-L) components fail, against 2 and 4 allowed.
#[test]
fn gradient_check_rejects_a_planted_defect() {
    for (name, errors, first_mlp) in [
        (
            "NPM radiance",
            gradient_errors("NPM radiance", &NPM_R, 30, 1),
            NPM_R.layout().mlps[0].0,
        ),
        (
            "DF-L radiance (cache)",
            gradient_errors("DF-L radiance (cache)", &DF_L, 30, 6),
            DF_L.layout().mlps[0].0,
        ),
    ] {
        errors
            .check(name, GRADIENT_TOL, GRADIENT_IGNORED)
            .expect("the clean gradient passes");
        let marker = format!(" {first_mlp} W1[");
        errors.assert_rejects_defect(
            name,
            &format!("{first_mlp} W1 × 1.05"),
            (GRADIENT_TOL, GRADIENT_IGNORED),
            |_, e| if e.label.contains(&marker) { 1.05 } else { 1.0 },
        );
    }
}

#[test]
fn npm_radiance_gradient() {
    gradient_check("NPM radiance", &NPM_R, 30, 1);
}

#[test]
fn npm_product_gradient() {
    gradient_check("NPM product", &NPM_P, 30, 2);
}

#[test]
fn nasg_gradient() {
    gradient_check("NASG product", &NASG_P, 30, 3);
    gradient_check("NASG radiance", &NASG_R, 15, 4);
}

#[test]
fn df_nearest_gradient() {
    gradient_check("DF-N product (cache)", &DF_N, 30, 5);
}

#[test]
fn df_linear_gradient() {
    gradient_check("DF-L radiance (cache)", &DF_L, 30, 6);
    let noisy = DfSmallProduct::small(BBOX_MIN, BBOX_MAX, Interpolation::Linear)
        .with_weight_source(DfWeightSource::Sample)
        .with_cache_loss_weight(0.5);
    gradient_check("DF-L product (noisy weight)", &noisy, 15, 7);
}

// ---------------------------------------------------------------------------
// 2. Sampling and normalisation.

/// `sample` returns unit directions whose pdf is `pdf(direction)`.
fn check_sampling<M: GuidingModel>(name: &str, model: &M, layout: &Layout, seed: u64) {
    let mut rng = Pcg32::new(seed, 21);
    let mut worst = 0.0f32;
    for _ in 0..20 {
        let params = random_params(layout, model.param_count(), &mut rng);
        let q = random_query(&mut rng);
        for _ in 0..100 {
            let s = model.sample(&params, &q, rng.next_vec2());
            assert!(
                (s.direction.length() - 1.0).abs() <= 1e-5,
                "{name}: direction {:?} not unit",
                s.direction
            );
            assert!(s.pdf.is_finite() && s.pdf > 0.0, "{name}: pdf {}", s.pdf);
            let p = model.pdf(&params, &q, s.direction);
            let rel = (s.pdf - p).abs() / p;
            worst = worst.max(rel);
            assert!(rel <= 1e-4, "{name}: sample pdf {} vs pdf {p}", s.pdf);
        }
    }
    println!("{name}: worst relative sample/pdf mismatch {worst:.2e}");
}

#[test]
fn sample_matches_pdf() {
    for_each_small_model!(|name, model, layout, seed| check_sampling(name, model, layout, seed));
}

/// `∫ pdf dω` over the uniform grid of the sphere (`u = φ/2π`,
/// `v = (1 − cos θ)/2`, i.e. DF's `ε` square).
fn check_normalisation<M: GuidingModel>(
    name: &str,
    model: &M,
    layout: &Layout,
    seed: u64,
    (res_u, res_v, order): (usize, usize, usize),
    tol: f64,
) {
    let mut rng = Pcg32::new(seed, 31);
    let params = random_params(layout, model.param_count(), &mut rng);
    let q = random_query(&mut rng);
    let integral = integrate(
        &Warp::uniform(),
        |d| f64::from(model.pdf(&params, &q, d.as_vec3())),
        res_u,
        res_v,
        order,
    );
    println!("{name}: ∫ pdf = 1 {:+.2e}", integral - 1.0);
    assert!((integral - 1.0).abs() <= tol, "{name}: ∫ pdf = {integral}");
}

/// Smooth mixtures: 128 × 64 cells of a 6-point rule resolve lobes down to
/// ~0.05 rad, so the quadrature error is far below the `f32` density's own
/// ~10⁻⁶; the 10⁻⁴ bound leaves room for the sharpest random lobe. DF's
/// densities are piecewise (bins of 1/32 in `ε₁`, 1/16 in `ε₂`, kinks of the
/// conditional in `ε₁` at ReLU switches and at multiples of 1/4096 from the
/// triangle wave): cells of 1/1024 × 1/32 align with every bin edge, and a
/// kink inside a cell costs O(h²) of that cell.
#[test]
fn pdf_integrates_to_one() {
    for_each_small_model!(|name, model, layout, seed| {
        let cells = if name.starts_with("DF") {
            (1024, 32, 3)
        } else {
            (128, 64, 6)
        };
        check_normalisation(name, model, layout, seed, cells, 1e-4);
    });
}

// ---------------------------------------------------------------------------
// 3. Invalid samples.

fn invalid_samples(rng: &mut Pcg32) -> Vec<(&'static str, TrainingSample)> {
    let base = random_sample(rng);
    let with = |f: &dyn Fn(&mut TrainingSample)| {
        let mut s = base;
        f(&mut s);
        s
    };
    vec![
        ("NaN position", with(&|s| s.position[1] = f32::NAN)),
        (
            "infinite position",
            with(&|s| s.position[0] = f32::INFINITY),
        ),
        ("NaN radiance", with(&|s| s.radiance[2] = f32::NAN)),
        (
            "infinite radiance",
            with(&|s| s.radiance[0] = f32::INFINITY),
        ),
        ("negative radiance", with(&|s| s.radiance[1] = -0.5)),
        ("negative bsdf_cos", with(&|s| s.bsdf_cos[0] = -1e-3)),
        ("zero sample_pdf", with(&|s| s.sample_pdf = 0.0)),
        ("negative sample_pdf", with(&|s| s.sample_pdf = -1.0)),
        ("NaN sample_pdf", with(&|s| s.sample_pdf = f32::NAN)),
        ("negative bsdf_pdf", with(&|s| s.bsdf_pdf = -0.1)),
        (
            "non-unit wi",
            with(&|s| s.wi = (Vec3::from_array(s.wi) * 1.01).to_array()),
        ),
        ("zero wi", with(&|s| s.wi = [0.0; 3])),
        ("NaN wi", with(&|s| s.wi[2] = f32::NAN)),
        ("non-unit normal", with(&|s| s.normal = [0.5, 0.0, 0.0])),
        ("non-unit wo", with(&|s| s.wo = [0.0, 2.0, 0.0])),
        ("NaN roughness", with(&|s| s.roughness = f32::NAN)),
    ]
}

fn check_invalid<M: GuidingModel>(name: &str, model: &M, layout: &Layout, seed: u64) {
    let mut rng = Pcg32::new(seed, 41);
    let n = model.param_count();
    let params = random_params(layout, n, &mut rng);
    for (what, s) in invalid_samples(&mut rng) {
        assert!(s.validate().is_err(), "{what} should be invalid");
        let mut grad: Vec<f32> = (0..n).map(|i| (i % 7) as f32 * 0.25).collect();
        let before = grad.clone();
        let loss = model.accumulate_gradient(&params, &s, &mut grad);
        assert_eq!(
            loss.to_bits(),
            0.0f32.to_bits(),
            "{name}, {what}: loss {loss}"
        );
        assert!(
            grad.iter()
                .zip(&before)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{name}, {what}: the gradient changed"
        );
    }
    // Too short buffers: nothing happens either.
    let s = random_sample(&mut rng);
    let mut grad = vec![0.0f32; n - 1];
    assert_eq!(model.accumulate_gradient(&params, &s, &mut grad), 0.0);
    assert!(grad.iter().all(|&g| g == 0.0));
    let mut grad = vec![0.0f32; n];
    assert_eq!(
        model.accumulate_gradient(&params[..n - 1], &s, &mut grad),
        0.0
    );
    assert!(grad.iter().all(|&g| g == 0.0));
}

#[test]
fn invalid_samples_add_nothing() {
    for_each_small_model!(|name, model, layout, seed| check_invalid(name, model, layout, seed));
}

// ---------------------------------------------------------------------------
// 4. Initialisation, layout, totality.

fn check_init<M: GuidingModel>(name: &str, model: &M, layout: &Layout) {
    let n = model.param_count();
    let run = |seed: u32, len: usize| {
        let mut p = vec![f32::NAN; len];
        model.init(&mut p, seed);
        p
    };
    let a = run(42, n + 5);
    let b = run(42, n + 5);
    assert!(
        a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
        "{name}: init is not deterministic"
    );
    assert!(
        a[..n].iter().all(|v| v.is_finite()),
        "{name}: init left a gap"
    );
    assert!(
        a[n..].iter().all(|v| v.is_nan()),
        "{name}: init wrote past the model"
    );
    let g = layout.grid.param_count();
    assert!(
        a[..g].iter().all(|v| v.abs() <= 1e-4),
        "{name}: grid init range"
    );
    // Another seed changes the grid and every network.
    let c = run(43, n);
    assert!(a[..g] != c[..g], "{name}: grid ignores the seed");
    for (net, off, shape) in &layout.mlps {
        let r = *off..*off + shape.param_count();
        assert!(
            a[r.clone()] != c[r.clone()],
            "{name}: {net} ignores the seed"
        );
        assert!(
            a[r].iter().any(|&v| v != 0.0),
            "{name}: {net} not initialised"
        );
    }
    // The networks get distinct streams.
    if layout.mlps.len() > 1 {
        let (_, o0, _) = layout.mlps[0];
        let (_, o1, _) = layout.mlps[1];
        assert!(
            a[o0..o0 + 8] != a[o1..o1 + 8],
            "{name}: networks share a stream"
        );
    }
    // A short buffer gets the prefix, without panicking.
    let short = run(42, n / 2);
    assert!(short
        .iter()
        .zip(&a)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn init_is_deterministic() {
    for_each_small_model!(|name, model, layout, _| check_init(name, model, layout));
}

/// The `const fn` grid size agrees with the grid's own, and the presets'
/// offsets and sizes agree with an independent count.
#[test]
fn layouts_and_presets() {
    let mut rng = Pcg32::new(5, 51);
    let mut grids = vec![
        GridConfig::npm(BBOX_MIN, BBOX_MAX),
        small_grid(BBOX_MIN, BBOX_MAX),
        GridConfig::new(BBOX_MIN, BBOX_MAX, 40, 1, 1.1, 40),
        GridConfig::new(BBOX_MIN, BBOX_MAX, 3, 0, 0.5, 2),
        GridConfig::new(BBOX_MIN, BBOX_MAX, 5, 3, f32::NAN, 1),
    ];
    for _ in 0..50 {
        grids.push(GridConfig::new(
            BBOX_MIN,
            BBOX_MAX,
            rng.next_u32() % 10,
            rng.next_u32() % 40,
            rng.uniform(0.5, 2.5),
            rng.next_u32() % 9,
        ));
    }
    for g in &grids {
        assert_eq!(grid_param_count(g), g.param_count(), "{g:?}");
    }
    assert_eq!(
        grid_param_count(&GridConfig::npm(BBOX_MIN, BBOX_MAX)),
        4_134_012
    );

    fn check(name: &str, model: &impl GuidingModel, layout: &Layout) {
        let mut end = layout.grid.param_count();
        for (net, off, shape) in &layout.mlps {
            assert_eq!(*off, end, "{name}: {net} offset");
            end += shape.param_count();
        }
        assert_eq!(model.param_count(), end, "{name}: param count");
        let nets: Vec<String> = layout
            .mlps
            .iter()
            .map(|(n, _, s)| format!("{n} {}", s.param_count()))
            .collect();
        println!(
            "{name}: grid {} + {} = {end}",
            layout.grid.param_count(),
            nets.join(" + ")
        );
    }
    let npm_r = NpmRadiance::paper(BBOX_MIN, BBOX_MAX);
    let npm_p = NpmProduct::paper(BBOX_MIN, BBOX_MAX);
    let nasg_p = NasgProduct::paper(BBOX_MIN, BBOX_MAX);
    let nasg_r = NasgRadiance::paper(BBOX_MIN, BBOX_MAX);
    let df_r = DfRadiance::paper(BBOX_MIN, BBOX_MAX, Interpolation::Linear);
    let df_p = DfProduct::paper(BBOX_MIN, BBOX_MAX, Interpolation::Nearest);
    check("NpmRadiance::paper", &npm_r, &npm_r.layout());
    check("NpmProduct::paper", &npm_p, &npm_p.layout());
    check("NasgProduct::paper", &nasg_p, &nasg_p.layout());
    check("NasgRadiance::paper", &nasg_r, &nasg_r.layout());
    check("DfRadiance::paper", &df_r, &df_r.layout());
    check("DfProduct::paper", &df_p, &df_p.layout());
    for_each_small_model!(|name, model, layout, _| check(name, model, layout));
    check("NASG radiance", &NASG_R, &NASG_R.layout());
    assert!(npm_r.is_consistent() && npm_p.is_consistent());
    assert!(nasg_p.is_consistent() && nasg_r.is_consistent());
    assert!(df_r.is_consistent() && df_p.is_consistent());
    assert_eq!(npm_r.target(), Target::Radiance);
    assert_eq!(df_p.target(), Target::Product);
    assert_eq!(df_p.interpolation(), Interpolation::Nearest);
    // An inconsistent configuration is reported as such.
    let wrong = Npm::<32, 64, 3>::new(small_grid(BBOX_MIN, BBOX_MAX), Target::Radiance);
    assert!(!wrong.is_consistent());
    // The configurations are plain data of fixed size (`Pod` in the core crate).
    assert_eq!(std::mem::size_of::<NpmProduct>(), 64);
    assert_eq!(std::mem::size_of::<NasgProduct>(), 64);
    assert_eq!(std::mem::size_of::<DfProduct>(), 80);
}

/// Degenerate queries, too short and absurd parameters: finite results.
fn check_totality<M: GuidingModel>(name: &str, model: &M, layout: &Layout) {
    let mut rng = Pcg32::new(9, 61);
    let n = model.param_count();
    let params = random_params(layout, n, &mut rng);
    let nan_query = QueryPoint::new(
        [f32::NAN, f32::INFINITY, 0.0],
        [f32::NAN; 3],
        [0.0; 3],
        f32::NAN,
    );
    let huge = vec![1e30f32; n];
    let short = &params[..n / 2];
    let q = random_query(&mut rng);
    let cases: [(&str, &[f32], &QueryPoint); 4] = [
        ("NaN query", &params, &nan_query),
        ("short params", short, &q),
        ("huge params", &huge, &q),
        ("empty params", &[], &q),
    ];
    for (what, p, q) in cases {
        for u in [Vec2::ZERO, Vec2::splat(0.999_999_9), rng.next_vec2()] {
            let s = model.sample(p, q, u);
            assert!(
                (s.direction.length() - 1.0).abs() <= 1e-5 && s.pdf.is_finite() && s.pdf > 0.0,
                "{name}, {what}: {s:?}"
            );
        }
        for d in [Vec3::Z, Vec3::ZERO, Vec3::NAN, Vec3::splat(1e30)] {
            let pdf = model.pdf(p, q, d);
            assert!(
                pdf.is_finite() && pdf >= 0.0,
                "{name}, {what}: pdf({d}) = {pdf}"
            );
        }
        let c = model.selection_probability(p, q);
        assert!((0.0..=1.0).contains(&c), "{name}, {what}: c = {c}");
    }
    let s = random_sample(&mut rng);
    let mut grad = vec![0.0f32; n];
    let loss = model.accumulate_gradient(&huge, &s, &mut grad);
    assert!(loss.is_finite(), "{name}: huge params loss {loss}");
    assert!(
        grad.iter().all(|g| g.is_finite()),
        "{name}: huge params gradient"
    );
}

#[test]
fn kernels_are_total() {
    for_each_small_model!(|name, model, layout, _| check_totality(name, model, layout));
}

/// The decoded distributions are the ones the kernels use; NASG's selection
/// probability is the decoded `c`; DF's cache is non-negative.
#[test]
fn decoded_distributions_agree() {
    let mut rng = Pcg32::new(13, 71);
    let p_npm = random_params(&NPM_P.layout(), NPM_P.param_count(), &mut rng);
    let p_nasg = random_params(&NASG_P.layout(), NASG_P.param_count(), &mut rng);
    let p_df = random_params(&DF_L.layout(), DF_L.param_count(), &mut rng);
    for _ in 0..50 {
        let q = random_query(&mut rng);
        let d = random_unit(&mut rng);
        assert_eq!(NPM_P.decode(&p_npm, &q).pdf(d), NPM_P.pdf(&p_npm, &q, d));
        assert_eq!(NPM_P.selection_probability(&p_npm, &q), 0.5);
        let m = NASG_P.decode(&p_nasg, &q);
        assert_eq!(m.pdf(d), NASG_P.pdf(&p_nasg, &q, d));
        let c = NASG_P.selection_probability(&p_nasg, &q);
        assert_eq!(c, m.selection_probability());
        assert!((NASG_SELECTION_MIN..=NASG_SELECTION_MAX).contains(&c));
        let eps = guiding_core::factorised::square_from_direction(d);
        let pm = DF_L.marginal(&p_df, &q).pdf(eps.x);
        let pc = DF_L.conditional(&p_df, &q, eps.x).pdf(eps.y);
        let p = DF_L.pdf(&p_df, &q, d);
        assert!((pm * pc * guiding_core::math::INV_FOUR_PI - p).abs() <= 1e-6 * p);
        let l = DF_L.radiance(&p_df, q.position(), d);
        assert!(l.iter().all(|v| v.is_finite() && *v >= 0.0), "{l:?}");
    }
}

/// DF's weight source: with the noisy radiance, a black sample trains only
/// the cache; with the cache (which predicts > 0), it trains the guide too.
#[test]
fn df_weight_source() {
    let mut rng = Pcg32::new(17, 81);
    let layout = DF_L.layout();
    let params = random_params(&layout, DF_L.param_count(), &mut rng);
    let mut s = random_sample(&mut rng);
    s.radiance = [0.0; 3];
    let (_, off_m, shape_m) = layout.mlps[0];
    let (_, off_c, shape_c) = layout.mlps[1];
    let (_, off_r, shape_r) = layout.mlps[2];
    let guide = off_m..off_c + shape_c.param_count();
    assert_eq!(off_m + shape_m.param_count(), off_c);
    let cache = off_r..off_r + shape_r.param_count();
    for (source, trains_guide) in [
        (DfWeightSource::Sample, false),
        (DfWeightSource::Cache, true),
    ] {
        let model = DF_L.with_weight_source(source);
        let mut grad = vec![0.0f32; model.param_count()];
        let loss = model.accumulate_gradient(&params, &s, &mut grad);
        assert!(loss.is_finite() && loss > 0.0, "{source:?}: loss {loss}");
        assert!(
            grad[cache.clone()].iter().any(|&g| g != 0.0),
            "{source:?}: cache untrained"
        );
        assert_eq!(
            grad[guide.clone()].iter().any(|&g| g != 0.0),
            trains_guide,
            "{source:?}"
        );
    }
}

// ---------------------------------------------------------------------------
// 5. Training sanity.

/// The direction `d₀` of the training target's lobe.
fn training_lobe() -> Vec3 {
    Vec3::new(0.3, -0.5, 0.8).normalize()
}

/// Trains `model` (seed `seed`) on incident radiance `e^{8 (ω·lobe − 1)}`
/// everywhere, samples drawn uniformly (`p_s = 1/4π`), zero normal, 400 Adam
/// steps of 64 samples; returns the guide's density at `d₀`
/// ([`training_lobe`]) averaged over 50 random queries.
fn trained_pdf_at_lobe<M: GuidingModel>(model: &M, seed: u32, lobe: Vec3) -> f32 {
    let mut rng = Pcg32::new(u64::from(seed), 91);
    let d0 = training_lobe();
    let n = model.param_count();
    let mut params = vec![0.0f32; n];
    model.init(&mut params, seed);
    let (mut m, mut v) = (vec![0.0f32; n], vec![0.0f32; n]);
    let cfg = AdamConfig::new(5e-3);
    let mut grad = vec![0.0f32; n];
    for step in 1..=400 {
        grad.fill(0.0);
        for _ in 0..64 {
            let mut s = random_sample(&mut rng);
            s.normal = [0.0; 3];
            s.sample_pdf = 0.25 / std::f32::consts::PI;
            let l = (8.0 * (Vec3::from_array(s.wi).dot(lobe) - 1.0)).exp();
            s.radiance = [l; 3];
            s.bsdf_cos = [1.0; 3];
            s.bsdf_pdf = 0.25 / std::f32::consts::PI;
            model.accumulate_gradient(&params, &s, &mut grad);
        }
        grad.iter_mut().for_each(|g| *g /= 64.0);
        assert_eq!(adam_step(&mut params, &grad, &mut m, &mut v, step, &cfg), 0);
    }
    let mut mean = 0.0;
    for _ in 0..50 {
        let q = random_query(&mut rng);
        mean += model.pdf(&params, &q, d0) / 50.0;
    }
    mean
}

/// Trains on the lobe at `d₀` and checks that the guide's density there
/// exceeds `bound` (see [`TRAINING_BOUNDS`]).
fn check_training<M: GuidingModel>(name: &str, model: &M, seed: u32, bound: f32) -> f32 {
    let mean = trained_pdf_at_lobe(model, seed, training_lobe());
    println!("{name}: mean pdf at the lobe after training {mean:.3} (bound {bound})");
    assert!(mean > bound, "{name}: pdf at the lobe {mean} ≤ {bound}");
    mean
}

#[test]
fn training_concentrates_the_guide() {
    let [npm, nasg, df_l, df_n] = TRAINING_BOUNDS;
    check_training("NPM radiance", &NPM_R, 1, npm);
    check_training("NASG product", &NASG_P, 2, nasg);
    check_training("DF-L radiance (cache)", &DF_L, 3, df_l);
    check_training("DF-N product (cache)", &DF_N, 4, df_n);
}

/// Lower bounds on the trained guide's density at the lobe, `[NPM radiance,
/// NASG product, DF-L radiance (cache), DF-N product (cache)]`.
///
/// What it must be: the normalised target is a vMF lobe of κ = 8, whose
/// density at `d₀` is `κ / (2π (1 − e^{−2κ})) = 1.273` (uniform: `1/4π =
/// 0.080`); DF learns it times `|cos| = 1`. A guide of that sharpness whose
/// axis is off by `δ` has `1.273 e^{−κ (1 − cos δ)}` there, so a bound `b`
/// admits axis errors up to `acos(1 − ln(1.273/b)/κ)`.
///
/// Derivation, as for the learning bounds of `tests/learning.rs`:
/// `training_seed_spread` (ignored, 4 s) trains each model with seeds 1–8;
/// ln(pdf at the lobe) spreads alike for the four (pooled sd 0.169, 28
/// degrees of freedom), and each bound is the one-sided lower prediction
/// bound of a new seed, `exp(m − t·s·√(1 + 1/8))`, `m` the model's mean ln,
/// `t = 3.05` Student's quantile at `1 − α₁`, `α₁ = 1 − 0.99^{1/4}` (α = 0.01
/// for the four, Šidák): a factor 1.73 below the geometric mean, rounded
/// down to two digits.
///
///   model   seeds 1–8 (geometric mean, min)   bound   axis error admitted
///   NPM     1.328, 1.176                      0.76    20°
///   NASG    1.032, 0.747                      0.59    25°
///   DF-L    0.916, 0.696                      0.53    27°
///   DF-N    0.871, 0.715                      0.50    28°
///
/// They replace 0.5 for all four (40 % of the peak, with no source).
/// Negative control: `training_check_rejects_a_lobe_turned_away`.
const TRAINING_BOUNDS: [f32; 4] = [0.76, 0.59, 0.53, 0.50];

/// Negative control: each model trained, with the seed of
/// `training_concentrates_the_guide`, on the lobe turned away from `d₀`
/// (directions handed to the guide in a rotated frame) must fail its bound at
/// `d₀`. A guide of the target's sharpness turned by 30° has `e^{−8 (1 − cos
/// 30°)} = 0.34` of its peak there: NPM, NASG and DF-L measure 0.353, 0.351,
/// 0.435 against 0.76, 0.59, 0.53. DF-N's nearest-bin guide is broader (0.559
/// at 30°, above its 0.50: its bound does not catch 30°), so it is turned by
/// 45° (`e^{−8 (1 − cos 45°)} = 0.096`): 0.140.
#[test]
fn training_check_rejects_a_lobe_turned_away() {
    let d0 = training_lobe();
    let turned = |degrees: f32| {
        let t = Quat::from_axis_angle(d0.any_orthonormal_vector(), degrees.to_radians()) * d0;
        assert!((d0.dot(t) - degrees.to_radians().cos()).abs() < 1e-6);
        t
    };
    let [npm, nasg, df_l, df_n] = TRAINING_BOUNDS;
    let got = [
        (
            "NPM radiance",
            30.0,
            trained_pdf_at_lobe(&NPM_R, 1, turned(30.0)),
            npm,
        ),
        (
            "NASG product",
            30.0,
            trained_pdf_at_lobe(&NASG_P, 2, turned(30.0)),
            nasg,
        ),
        (
            "DF-L radiance (cache)",
            30.0,
            trained_pdf_at_lobe(&DF_L, 3, turned(30.0)),
            df_l,
        ),
        (
            "DF-N product (cache)",
            45.0,
            trained_pdf_at_lobe(&DF_N, 4, turned(45.0)),
            df_n,
        ),
    ];
    for (name, degrees, mean, bound) in got {
        println!("{name}, lobe {degrees}° off: pdf at d₀ {mean:.3} (bound {bound})");
        assert!(
            mean <= bound,
            "{name}: a guide trained {degrees}° off passed the bound ({mean} > {bound})"
        );
    }
}

/// The measurement behind [`TRAINING_BOUNDS`]: `cargo test --release -p
/// guiding-tests --test models -- --ignored --nocapture training_seed_spread`.
#[test]
#[ignore = "measurement behind TRAINING_BOUNDS"]
fn training_seed_spread() {
    fn spread<M: GuidingModel>(name: &str, model: &M) -> Vec<f64> {
        let v: Vec<f64> = (1..=8)
            .map(|s| f64::from(trained_pdf_at_lobe(model, s, training_lobe())))
            .collect();
        let shown: Vec<String> = v.iter().map(|x| format!("{x:.3}")).collect();
        println!(
            "{name}: pdf at the lobe over seeds 1–8: {}",
            shown.join(" ")
        );
        v.iter().map(|x| x.ln()).collect()
    }
    let cases = [
        ("NPM radiance", spread("NPM radiance", &NPM_R)),
        ("NASG product", spread("NASG product", &NASG_P)),
        (
            "DF-L radiance (cache)",
            spread("DF-L radiance (cache)", &DF_L),
        ),
        (
            "DF-N product (cache)",
            spread("DF-N product (cache)", &DF_N),
        ),
    ];
    use statrs::distribution::{ContinuousCDF, StudentsT};
    let n = 8.0;
    let mut ss = 0.0;
    let means: Vec<f64> = cases
        .iter()
        .map(|(_, l)| {
            let m = l.iter().sum::<f64>() / n;
            ss += l.iter().map(|x| (x - m).powi(2)).sum::<f64>();
            m
        })
        .collect();
    let dof = 4.0 * (n - 1.0);
    let s = (ss / dof).sqrt();
    let alpha1 = 1.0 - 0.99f64.powf(1.0 / 4.0);
    let t = StudentsT::new(0.0, 1.0, dof)
        .unwrap()
        .inverse_cdf(1.0 - alpha1);
    let factor = (t * s * (1.0 + 1.0 / n).sqrt()).exp();
    for ((name, l), m) in cases.iter().zip(&means) {
        let min = l.iter().copied().fold(f64::MAX, f64::min).exp();
        println!(
            "{name}: geometric mean {:.3}, min {min:.3}, pooled sd(ln) {s:.3} ({dof} dof), t {t:.2}, \
             factor {factor:.3}: lower bound {:.3}",
            m.exp(),
            m.exp() / factor
        );
    }
}
