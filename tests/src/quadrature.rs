//! Tensor Gauss–Legendre quadrature over the cells of a [`Warp`]'s unit
//! square, in `f64`.
//!
//! The square `[0, 1]²` is cut into `res_u × res_v` cells and each cell is
//! integrated with an `order × order` Gauss–Legendre rule of the integrand
//! times the warp's Jacobian `dω / (du dv)`. An `order`-point rule is exact for
//! polynomials of degree `2·order − 1` per axis, so for an integrand that is
//! smooth on the scale of a cell the error falls off like `(cell / scale)^{2·order}`;
//! the warps of [`crate::chi2`] exist to make every tested density smooth on
//! the scale of a cell.

use crate::chi2::Warp;
use glam::{DVec2, DVec3};

/// Largest supported rule.
pub const MAX_ORDER: usize = 16;

/// Gauss–Legendre rule with `order` points on `[0, 1]`: `(nodes, weights)`,
/// the weights summing to one.
///
/// Computed by Newton's method on the Legendre recurrence in `f64`
/// (Numerical Recipes' `gauleg`); nodes and weights are accurate to a few ulp
/// for every `order ≤ 16`.
///
/// # Panics
/// If `order` is not in `1..=16`.
#[must_use]
pub fn gauss_legendre(order: usize) -> (Vec<f64>, Vec<f64>) {
    assert!(
        (1..=MAX_ORDER).contains(&order),
        "Gauss–Legendre order {order} outside 1..={MAX_ORDER}"
    );
    let n = order;
    let nf = n as f64;
    // (P_n(x), P_n'(x)) by the three-term recurrence.
    let legendre = |x: f64| {
        let (mut p0, mut p1) = (1.0, x);
        for k in 2..=n {
            let kf = k as f64;
            let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
            p0 = p1;
            p1 = p2;
        }
        (p1, nf * (x * p1 - p0) / (x * x - 1.0))
    };
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut x = (core::f64::consts::PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        for _ in 0..100 {
            let (p, dp) = legendre(x);
            let dx = p / dp;
            x -= dx;
            if dx.abs() <= 1e-16 {
                break;
            }
        }
        let (_, dp) = legendre(x);
        // Weight on [-1, 1] is 2 / ((1 − x²) P_n'(x)²); on [0, 1] half of it.
        let w = 1.0 / ((1.0 - x * x) * dp * dp);
        nodes[i] = 0.5 * (1.0 - x);
        nodes[n - 1 - i] = 0.5 * (1.0 + x);
        weights[i] = w;
        weights[n - 1 - i] = w;
    }
    (nodes, weights)
}

/// Integral of `f(ω) dω` over every cell of the warp's square, row-major
/// (`res_v` rows of `res_u` cells; cell `(i, j)` covers
/// `u ∈ [i, i+1]/res_u`, `v ∈ [j, j+1]/res_v` and is entry `j·res_u + i`).
#[must_use]
pub fn cell_integrals(
    warp: &Warp,
    f: impl Fn(DVec3) -> f64,
    res_u: usize,
    res_v: usize,
    order: usize,
) -> Vec<f64> {
    let (nodes, weights) = gauss_legendre(order);
    let du = 1.0 / res_u as f64;
    let dv = 1.0 / res_v as f64;
    let mut out = vec![0.0; res_u * res_v];
    for j in 0..res_v {
        for i in 0..res_u {
            let mut sum = 0.0;
            for (nv, wv) in nodes.iter().zip(&weights) {
                let v = (j as f64 + nv) * dv;
                for (nu, wu) in nodes.iter().zip(&weights) {
                    let u = (i as f64 + nu) * du;
                    let (d, jac) = warp.to_sphere(DVec2::new(u, v));
                    sum += wu * wv * f(d) * jac;
                }
            }
            out[j * res_u + i] = sum * du * dv;
        }
    }
    out
}

/// `∫_{S²} f(ω) dω`, as the sum of [`cell_integrals`] (e.g. `∫ pdf dω = 1`).
#[must_use]
pub fn integrate(
    warp: &Warp,
    f: impl Fn(DVec3) -> f64,
    res_u: usize,
    res_v: usize,
    order: usize,
) -> f64 {
    cell_integrals(warp, f, res_u, res_v, order).iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rules_are_exact_for_their_degree() {
        for order in 1..=MAX_ORDER {
            let (x, w) = gauss_legendre(order);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-14, "order {order}");
            for degree in 0..2 * order {
                let q: f64 = x
                    .iter()
                    .zip(&w)
                    .map(|(x, w)| w * x.powi(degree as i32))
                    .sum();
                let exact = 1.0 / (degree as f64 + 1.0);
                assert!(
                    (q - exact).abs() < 1e-14,
                    "order {order}, degree {degree}: {q}"
                );
            }
        }
    }

    #[test]
    fn sphere_area_and_moments() {
        let warps = [
            Warp::uniform(),
            Warp::uniform_about(DVec3::new(1.0, 2.0, -0.5)),
            Warp::zoomed(DVec3::new(0.3, -0.2, 0.9), DVec3::X, 1e-3, 1.0),
            Warp::zoomed(DVec3::new(-0.1, 0.7, 0.2), DVec3::Y, 0.05, 8.0),
        ];
        let a = DVec3::new(0.48, -0.6, 0.64);
        for warp in &warps {
            // 100 columns: the c = 8 stretch concentrates dφ/du within
            // |w − ½| ≲ 1/(πc) ≈ 0.04, which 20 columns would not resolve.
            let area = integrate(warp, |_| 1.0, 100, 50, 8);
            assert!(
                (area - 4.0 * core::f64::consts::PI).abs() < 1e-10,
                "{warp:?}: {area}"
            );
            // ∫ (a·ω)² dω = 4π |a|² / 3.
            let m2 = integrate(warp, |d| d.dot(a).powi(2), 100, 50, 8);
            let exact = 4.0 * core::f64::consts::PI * a.length_squared() / 3.0;
            assert!((m2 - exact).abs() < 1e-10, "{warp:?}: {m2} vs {exact}");
        }
    }
}
