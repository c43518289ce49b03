//! `f64` reference implementations of the guiding-model chain — grid
//! encoding, spherical harmonics, one-blob, triangle wave, MLP, the vMF /
//! NASG / piecewise decoders and their `ln p`, and the losses — written from
//! the formulas in the kernels' documentation, for finite-difference checks
//! of whole models. Parameters are passed as `&[f64]` in the library's flat
//! layout; layout facts (level resolutions and offsets) are read from the
//! library's config types, everything numeric is recomputed here.

use core::f64::consts::PI;
use glam::{DMat3, DVec3};
use guiding_core::encoding::GridConfig;
use guiding_core::lobe::nasg::NASG_EPSILON;
use guiding_core::mixture::nasg::{
    NASG_LN_A_MAX, NASG_LN_A_MIN, NASG_LN_LAMBDA_MAX, NASG_LN_LAMBDA_MIN, NASG_RAW_PER_LOBE,
    NASG_SELECTION_MAX, NASG_SELECTION_MIN,
};
use guiding_core::mixture::vmf::{VMF_LOG_KAPPA_MAX, VMF_LOG_KAPPA_MIN, VMF_RAW_PER_LOBE};
use guiding_core::pdf1d::{Boundary, Interpolation};

/// Logistic sigmoid.
#[must_use]
pub fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// `ln Σ eˣ`.
#[must_use]
pub fn log_sum_exp(x: &[f64]) -> f64 {
    let max = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    max + x.iter().map(|v| (v - max).exp()).sum::<f64>().ln()
}

/// `ln(1 + eʳ)`.
#[must_use]
pub fn softplus(r: f64) -> f64 {
    r.max(0.0) + (-r.abs()).exp().ln_1p()
}

// ---------------------------------------------------------------------------
// Encodings.

/// The dense multi-resolution grid (`encoding/grid.rs` module docs): per
/// level, the trilinear (or smoothstep) interpolation of the 8 vertices of
/// the cell of the box-normalised position; `L·F` outputs, level-major.
#[must_use]
pub fn grid(params: &[f64], cfg: &GridConfig, position: DVec3) -> Vec<f64> {
    let f = cfg.feature_count();
    let unit = |x: f64, lo: f32, hi: f32| {
        let (lo, hi) = (f64::from(lo), f64::from(hi));
        if hi > lo {
            ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.5
        }
    };
    let u = [
        unit(position.x, cfg.bbox_min[0], cfg.bbox_max[0]),
        unit(position.y, cfg.bbox_min[1], cfg.bbox_max[1]),
        unit(position.z, cfg.bbox_min[2], cfg.bbox_max[2]),
    ];
    let mut out = Vec::with_capacity(cfg.output_dims());
    for l in 0..cfg.level_count() {
        let r = cfg.level_resolution(l as u32) as usize;
        let base = cfg.offset as usize + cfg.level_offset(l as u32);
        let mut cell = [0usize; 3];
        let mut t = [0.0f64; 3];
        for a in 0..3 {
            let p = u[a] * r as f64;
            let i = (p.floor() as usize).min(r - 1);
            let mut ta = p - i as f64;
            if cfg.smoothstep != 0 {
                ta = ta * ta * (3.0 - 2.0 * ta);
            }
            cell[a] = i;
            t[a] = ta;
        }
        let n = r + 1;
        for k in 0..f {
            let mut acc = 0.0;
            for c in 0..8 {
                let d = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
                let w: f64 = (0..3)
                    .map(|a| if d[a] == 1 { t[a] } else { 1.0 - t[a] })
                    .product();
                let vertex = (cell[0] + d[0]) + n * ((cell[1] + d[1]) + n * (cell[2] + d[2]));
                acc += w * params[base + vertex * f + k];
            }
            out.push(acc);
        }
    }
    out
}

/// The 16 real orthonormal spherical harmonics of degree 4 (bands 0–3,
/// Condon–Shortley phase, `spherical_harmonics.rs` ordering) of `d`
/// (normalised here; zero → `+z`).
#[must_use]
pub fn sh4(d: DVec3) -> Vec<f64> {
    let d = if d.length_squared() > 0.0 {
        d.normalize()
    } else {
        DVec3::Z
    };
    let (x, y, z) = (d.x, d.y, d.z);
    let sp = PI.sqrt();
    let (s3, s5, s7, s15) = (3f64.sqrt(), 5f64.sqrt(), 7f64.sqrt(), 15f64.sqrt());
    let (s42, s70, s105) = (42f64.sqrt(), 70f64.sqrt(), 105f64.sqrt());
    vec![
        1.0 / (2.0 * sp),
        -s3 * y / (2.0 * sp),
        s3 * z / (2.0 * sp),
        -s3 * x / (2.0 * sp),
        s15 * x * y / (2.0 * sp),
        -s15 * y * z / (2.0 * sp),
        s5 * (3.0 * z * z - 1.0) / (4.0 * sp),
        -s15 * x * z / (2.0 * sp),
        s15 * (x * x - y * y) / (4.0 * sp),
        s70 * y * (y * y - 3.0 * x * x) / (8.0 * sp),
        s105 * x * y * z / (2.0 * sp),
        s42 * y * (1.0 - 5.0 * z * z) / (8.0 * sp),
        s7 * z * (5.0 * z * z - 3.0) / (4.0 * sp),
        s42 * x * (1.0 - 5.0 * z * z) / (8.0 * sp),
        s105 * z * (x * x - y * y) / (4.0 * sp),
        s70 * x * (3.0 * y * y - x * x) / (8.0 * sp),
    ]
}

/// One-blob encoding: `exp(−((i + ½) − k x)² / 2)`, `x` clamped to `[0, 1]`.
#[must_use]
pub fn one_blob(x: f64, bins: usize) -> Vec<f64> {
    let x = x.clamp(0.0, 1.0);
    (0..bins)
        .map(|i| {
            let d = (i as f64 + 0.5) - bins as f64 * x;
            (-0.5 * d * d).exp()
        })
        .collect()
}

/// tiny-cuda-nn's triangle wave: `4 |frac(2^{i−1} x + i/4) − ½| − 1`.
#[must_use]
pub fn triangle_wave(x: f64, frequencies: usize) -> Vec<f64> {
    (0..frequencies)
        .map(|i| {
            let y = 2f64.powi(i as i32 - 1) * x + 0.25 * i as f64;
            4.0 * (y - y.floor() - 0.5).abs() - 1.0
        })
        .collect()
}

/// NPM's product inputs: `SH₄(ωo)`, one-blob (4 bins) of `½nₐ + ½` for each
/// normal component, one-blob (4 bins) of the roughness — 32 values.
#[must_use]
pub fn product_inputs(normal: DVec3, wo: DVec3, roughness: f64) -> Vec<f64> {
    let mut v = sh4(wo);
    for a in 0..3 {
        v.extend(one_blob(0.5 * normal[a] + 0.5, 4));
    }
    v.extend(one_blob(roughness, 4));
    v
}

// ---------------------------------------------------------------------------
// MLP.

/// Shape of an MLP (`mlp.rs`): `hidden ≥ 1` ReLU layers of `width`, a linear
/// output layer, every layer with biases.
#[derive(Clone, Copy, Debug)]
pub struct MlpShape {
    /// Inputs.
    pub input: usize,
    /// Neurons per hidden layer.
    pub width: usize,
    /// Outputs.
    pub output: usize,
    /// Hidden layers.
    pub hidden: usize,
}

impl MlpShape {
    /// `(fan_in, fan_out)` of every layer, the output layer last.
    #[must_use]
    pub fn layers(&self) -> Vec<(usize, usize)> {
        let mut v = vec![(self.input, self.width)];
        v.extend((1..self.hidden).map(|_| (self.width, self.width)));
        v.push((self.width, self.output));
        v
    }

    /// Number of parameters.
    #[must_use]
    pub fn param_count(&self) -> usize {
        self.layers().iter().map(|(i, o)| (i + 1) * o).sum()
    }
}

/// The MLP's forward pass in `f64` from its flat layout at `offset`
/// (per layer: row-major `W[out][in]`, then `b[out]`).
#[must_use]
pub fn mlp(params: &[f64], offset: usize, shape: MlpShape, input: &[f64]) -> Vec<f64> {
    assert_eq!(input.len(), shape.input, "MLP input width");
    let layers = shape.layers();
    let mut x = input.to_vec();
    let mut o = offset;
    for (l, &(fan_in, fan_out)) in layers.iter().enumerate() {
        let b = o + fan_in * fan_out;
        let y: Vec<f64> = (0..fan_out)
            .map(|j| {
                let z = params[b + j]
                    + (0..fan_in)
                        .map(|i| params[o + j * fan_in + i] * x[i])
                        .sum::<f64>();
                if l + 1 < layers.len() {
                    z.max(0.0)
                } else {
                    z
                }
            })
            .collect();
        x = y;
        o = b + fan_out;
    }
    x
}

// ---------------------------------------------------------------------------
// Decoders.

/// `1 − cos∠(μ, ω)` without cancellation (`μ`, `ω` normalised here), for
/// the log-space oracles, where `κ (1 − cos)` can be 10⁴ and must keep its
/// digits.
#[must_use]
pub fn one_minus_cos(mean: DVec3, d: DVec3) -> f64 {
    let (m, d) = (mean.normalize(), d.normalize());
    let dot = m.dot(d);
    if dot > 0.0 {
        m.cross(d).length_squared() / (1.0 + dot)
    } else {
        1.0 - dot
    }
}

/// `ln(κ / (2π (1 − e^{−2κ})))`.
fn vmf_ln_norm(kappa: f64) -> f64 {
    kappa.ln() - (2.0 * PI).ln() - (-(-2.0 * kappa).exp_m1()).ln()
}

/// `exp(clamp(x, lo, hi))`: a decoder's log parameter within its `f32` clamp.
fn exp_clamped(x: f64, lo: f32, hi: f32) -> f64 {
    x.clamp(f64::from(lo), f64::from(hi)).exp()
}

/// `(κ, μ)` of one raw vMF lobe as `VmfMixture::decode` reads it (NPM Table
/// 1): `κ = exp(clamp(r₁, −10, 10))`, `θ = π σ(r₂)`, `φ = 2π σ(r₃)`.
#[must_use]
pub fn vmf_lobe(r: &[f64]) -> (f64, DVec3) {
    let kappa = exp_clamped(r[1], VMF_LOG_KAPPA_MIN, VMF_LOG_KAPPA_MAX);
    let theta = PI * sigmoid(r[2]);
    let phi = 2.0 * PI * sigmoid(r[3]);
    let mean = DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    );
    (kappa, mean)
}

/// `ln q(ω)` of `VmfMixture::decode(raw)` (NPM Table 1: softmax weights,
/// lobes by [`vmf_lobe`]); `raw` is flat, 4 values per lobe.
#[must_use]
pub fn vmf_ln_pdf(raw: &[f64], d: DVec3) -> f64 {
    mixture_ln_pdf(raw, VMF_RAW_PER_LOBE, |r, ln_w| {
        let (kappa, mean) = vmf_lobe(r);
        ln_w + vmf_ln_norm(kappa) - kappa * one_minus_cos(mean, d)
    })
}

/// `ln Σ_k w_k p_k` of a mixture with softmax weights: `raw` flat, `per_lobe`
/// values per lobe, the first the weight logit; `ln_term(lobe, ln w_k)`
/// gives `ln w_k + ln p_k`.
fn mixture_ln_pdf(raw: &[f64], per_lobe: usize, ln_term: impl Fn(&[f64], f64) -> f64) -> f64 {
    let lobes: Vec<&[f64]> = raw.chunks(per_lobe).collect();
    let logits: Vec<f64> = lobes.iter().map(|r| r[0]).collect();
    let lse = log_sum_exp(&logits);
    let terms: Vec<f64> = lobes.iter().map(|r| ln_term(r, r[0] - lse)).collect();
    log_sum_exp(&terms)
}

fn rz(a: f64) -> DMat3 {
    DMat3::from_rotation_z(a)
}

/// `ln p` of one NASG lobe with frame `(x, y, z)` (lobe/nasg.rs, NASG
/// eq. 19): `ln G − ln K`, `ln t` floored at `ln(f32::MIN_POSITIVE)`.
#[must_use]
pub fn nasg_lobe_ln_pdf(
    frame: (DVec3, DVec3, DVec3),
    lambda: f64,
    a: f64,
    eps: f64,
    d: DVec3,
) -> f64 {
    let (x, y, z) = frame;
    let dn = d.normalize();
    let t = 0.25 * (dn + z).length_squared();
    let h = 0.25 * (dn - z).length_squared();
    let ln_t = if h < 0.5 { (-h).ln_1p() } else { t.ln() };
    let ln_t = ln_t.max(f64::from(f32::MIN_POSITIVE).ln());
    let (vx, vy) = (dn.dot(x), dn.dot(y));
    let c2 = if vx == 0.0 && vy == 0.0 {
        0.0
    } else {
        vx * vx / (vx * vx + vy * vy)
    };
    let b = 1.0 + eps + a * c2;
    let ln_g = 2.0 * lambda * (b * ln_t).exp_m1() + (b - 1.0) * ln_t;
    let k =
        2.0 * PI * (-(-2.0 * lambda).exp_m1()) / (lambda * ((1.0 + eps) * (1.0 + eps + a)).sqrt());
    ln_g - k.ln()
}

/// `ln q(ω)` of `NasgMixture::decode(raw, ·)` (our reading of NASG Table 2:
/// softmax weights, clamped `exp` of `ln λ`, `ln a`, frame
/// `R_z(2π σ(r₃)) R_y(π σ(r₄)) R_z(π σ(r₅))`, `ε` = `NASG_EPSILON`); `raw`
/// flat, 6 values per lobe.
#[must_use]
pub fn nasg_ln_pdf(raw: &[f64], d: DVec3) -> f64 {
    mixture_ln_pdf(raw, NASG_RAW_PER_LOBE, |r, ln_w| {
        let lambda = exp_clamped(r[1], NASG_LN_LAMBDA_MIN, NASG_LN_LAMBDA_MAX);
        let a = exp_clamped(r[2], NASG_LN_A_MIN, NASG_LN_A_MAX);
        let rot = rz(2.0 * PI * sigmoid(r[3]))
            * DMat3::from_rotation_y(PI * sigmoid(r[4]))
            * rz(PI * sigmoid(r[5]));
        let frame = (rot.x_axis, rot.y_axis, rot.z_axis);
        ln_w + nasg_lobe_ln_pdf(frame, lambda, a, f64::from(NASG_EPSILON), d)
    })
}

/// The decoded selection probability `clamp(σ(r), 0.01, 0.99)`.
#[must_use]
pub fn nasg_selection(r: f64) -> f64 {
    sigmoid(r).clamp(f64::from(NASG_SELECTION_MIN), f64::from(NASG_SELECTION_MAX))
}

/// NASG eq. 18: `−w [(1 − e) ln(c q + (1 − c) p_bsdf) + e ln q]`.
#[must_use]
pub fn nasg_mis_loss(w: f64, ln_q: f64, c: f64, bsdf_pdf: f64, e: f64) -> f64 {
    let mis = c * ln_q.exp() + (1.0 - c) * bsdf_pdf;
    -w * ((1.0 - e) * mis.ln() + e * ln_q)
}

/// Bin values `N · softmax(l)`.
#[must_use]
pub fn pdf1d_values(l: &[f64]) -> Vec<f64> {
    let m = l.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = l.iter().map(|x| (x - m).exp()).collect();
    let s: f64 = e.iter().sum();
    let n = l.len() as f64;
    e.iter().map(|x| n * x / s).collect()
}

/// The piecewise density of bin values `v` at `x ∈ [0, 1]` (pdf1d.rs).
#[must_use]
pub fn pdf1d_eval(v: &[f64], x: f64, interp: Interpolation, boundary: Boundary) -> f64 {
    let n = v.len();
    let nf = n as f64;
    match interp {
        Interpolation::Nearest => v[((x * nf).floor().max(0.0) as usize).min(n - 1)],
        Interpolation::Linear => {
            let s = x * nf - 0.5;
            match boundary {
                Boundary::Clamp => {
                    if s <= 0.0 {
                        v[0]
                    } else if s >= nf - 1.0 {
                        v[n - 1]
                    } else {
                        let i = s.floor() as usize;
                        let f = s - i as f64;
                        (1.0 - f) * v[i] + f * v[i + 1]
                    }
                }
                Boundary::Wrap => {
                    let fl = s.floor();
                    let f = s - fl;
                    let i = (fl as i64).rem_euclid(n as i64) as usize;
                    let j = (i + 1) % n;
                    (1.0 - f) * v[i] + f * v[j]
                }
            }
        }
    }
}

/// `ln p(x)` of the density with logits `l`.
#[must_use]
pub fn pdf1d_ln_pdf(l: &[f64], x: f64, interp: Interpolation, boundary: Boundary) -> f64 {
    pdf1d_eval(&pdf1d_values(l), x, interp, boundary).ln()
}

/// `(ε₁, ε₂)` of a direction: `φ / 2π` and `(1 − cos θ) / 2`.
#[must_use]
pub fn square(d: DVec3) -> (f64, f64) {
    let len = d.length();
    let mut phi = d.y.atan2(d.x);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    (
        (phi / (2.0 * PI)).clamp(0.0, 1.0),
        (0.5 * (1.0 - d.z / len)).clamp(0.0, 1.0),
    )
}
