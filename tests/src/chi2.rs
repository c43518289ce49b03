//! Chi² goodness-of-fit test on the sphere, after Mitsuba 3's
//! `ChiSquareTest` (`mitsuba/python/chi2.py`).
//!
//! A [`Warp`] parametrises the sphere by the unit square; the square is cut
//! into a `res_u × res_v` grid. Samples drawn from the distribution are
//! histogrammed on that grid, the expected count of every cell is `samples ×
//! ∫_cell pdf dω` by tensor Gauss–Legendre quadrature in `f64`, cells with an
//! expected count below [`Chi2Config::min_expected`] are pooled, and Pearson's
//! statistic is compared with the χ² distribution at a Šidák-corrected level so
//! that the whole suite (every case of [`crate::cases::all_cases`]) has false
//! positive rate α.
//!
//! Warps: [`Warp::UniformSphere`] is Mitsuba's equal-area grid (fine for broad
//! densities); [`Warp::ZoomedCap`] spaces its rows logarithmically in
//! `1 − cos θ` around an axis and optionally stretches the azimuth around
//! `φ = 0` and `φ = π`, so that lobes as sharp as κ = 10⁴ (and anisotropic
//! ones) spread over many cells and the quadrature sees a smooth integrand.

use crate::cases::Case;
use crate::quadrature::cell_integrals;
use crate::rng::Pcg32;
use core::f64::consts::PI;
use glam::{DVec2, DVec3};
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::fmt::Write as _;

/// Parametrisation of the sphere by the unit square used for the chi² grid
/// and for quadrature.
#[derive(Clone, Copy, Debug)]
pub enum Warp {
    /// Mitsuba's grid: `u → φ = 2πu` about `axis`, `v → cos θ = 1 − 2v`.
    /// Equal-area cells (Jacobian `4π`). `φ = 0` is the `x` axis of
    /// [`f64_frame`]`(axis)`.
    UniformSphere {
        /// Pole of the grid.
        axis: DVec3,
    },
    /// A grid zoomed onto the cap around `z`, in the right-handed orthonormal
    /// frame `(x, y, z)`.
    ///
    /// Radial: `s = 1 − cos θ ∈ [0, 2]`, `v = ln(1 + s/s0) / L` with
    /// `L = ln(1 + 2/s0)`, i.e. `s = s0·expm1(v·L)`, `ds/dv = L (s + s0)`: rows
    /// are uniform in `ln(s + s0)`, so a lobe of angular width `√(2 s0)` gets
    /// about as many rows inside its core as in the far tail.
    ///
    /// Azimuth: `u < ½` is the east half, `w = 2u`,
    /// `φ = atan(c·tan(π(w − ½))) ∈ (−π/2, π/2)`; `u ≥ ½` the west half,
    /// `w = 2u − 1`, `φ` = the same + π. `c = phi_stretch ≥ 1` crowds columns
    /// around `φ = ±π/2` (the `y` axis, where an anisotropic NASG lobe with
    /// `a > 0` concentrates its mass) and thins them around `φ = 0, π`;
    /// `c = 1` is uniform in φ. `dφ/du = 2cπ(1 + τ²)/(1 + c²τ²)`,
    /// `τ = tan(π(w − ½))`.
    ///
    /// Jacobian `dω = |dφ/du|·|ds/dv| du dv`.
    ZoomedCap {
        /// `φ = 0`.
        x: DVec3,
        /// `φ = π/2`, `z × x`.
        y: DVec3,
        /// The axis, `s = 0`.
        z: DVec3,
        /// Radial scale `s0 > 0` (≈ `1/κ` for a vMF lobe of concentration κ).
        s0: f64,
        /// Azimuthal stretch `c ≥ 1`.
        phi_stretch: f64,
    },
}

/// Right-handed orthonormal frame `(x, y, z = n)` around a unit `n` (Duff et
/// al. 2017, in `f64`; the same construction as `guiding_core::frame::Frame`).
#[must_use]
pub fn f64_frame(n: DVec3) -> (DVec3, DVec3, DVec3) {
    let sign = 1.0_f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let x = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let y = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    (x, y, n)
}

/// `s = 1 − cos∠(z, d)` without cancellation near `z` (`z` unit, `d` any
/// non-zero vector; `local_z = z·d`, `perp2 = |d|² − local_z²` computed from
/// the tangential coordinates).
fn one_minus_cos(local: DVec3) -> f64 {
    let len = local.length();
    if local.z > 0.0 {
        (local.x * local.x + local.y * local.y) / (len * (len + local.z))
    } else {
        1.0 - local.z / len
    }
}

impl Warp {
    /// Mitsuba's uniform grid about `+z`.
    #[must_use]
    pub fn uniform() -> Self {
        Self::uniform_about(DVec3::Z)
    }

    /// Uniform grid about `axis` (normalised here).
    #[must_use]
    pub fn uniform_about(axis: DVec3) -> Self {
        Self::UniformSphere {
            axis: axis.normalize(),
        }
    }

    /// Zoomed cap with axis `z` and `φ = 0` along `x` (both normalised and
    /// `x` made orthogonal to `z` here), radial scale `s0`, azimuthal stretch
    /// `c ≥ 1`.
    ///
    /// # Panics
    /// If `s0 ≤ 0`, `c < 1`, or `x` is parallel to `z`.
    #[must_use]
    pub fn zoomed(z: DVec3, x: DVec3, s0: f64, c: f64) -> Self {
        assert!(s0 > 0.0 && s0.is_finite(), "s0 = {s0}");
        assert!(c >= 1.0 && c.is_finite(), "phi_stretch = {c}");
        let z = z.normalize();
        let x = (x - z * z.dot(x)).normalize();
        assert!(x.is_finite(), "x axis parallel to z");
        // Re-orthogonalise once more against rounding.
        let x = (x - z * z.dot(x)).normalize();
        Self::ZoomedCap {
            x,
            y: z.cross(x),
            z,
            s0,
            phi_stretch: c,
        }
    }

    /// Zoomed cap about `z` with an arbitrary fixed `φ = 0` direction and
    /// `c = 1`: the grid for rotationally symmetric lobes.
    #[must_use]
    pub fn zoomed_about(z: DVec3, s0: f64) -> Self {
        let z = z.normalize();
        Self::zoomed(z, f64_frame(z).0, s0, 1.0)
    }

    /// Point of the sphere at `uv ∈ [0, 1]²` and the Jacobian `dω / (du dv)`.
    #[must_use]
    pub fn to_sphere(&self, uv: DVec2) -> (DVec3, f64) {
        match *self {
            Self::UniformSphere { axis } => {
                let (x, y, z) = f64_frame(axis);
                let cos_t = 1.0 - 2.0 * uv.y;
                let sin_t = 2.0 * (uv.y * (1.0 - uv.y)).max(0.0).sqrt();
                let (sp, cp) = (2.0 * PI * uv.x).sin_cos();
                (x * (sin_t * cp) + y * (sin_t * sp) + z * cos_t, 4.0 * PI)
            }
            Self::ZoomedCap {
                x,
                y,
                z,
                s0,
                phi_stretch: c,
            } => {
                let l = (2.0 / s0).ln_1p();
                let s = (s0 * (uv.y * l).exp_m1()).min(2.0);
                let ds_dv = l * (s + s0);
                let (w, offset) = if uv.x < 0.5 {
                    (2.0 * uv.x, 0.0)
                } else {
                    (2.0 * uv.x - 1.0, PI)
                };
                let alpha = PI * (w - 0.5);
                let (sa, ca) = alpha.sin_cos();
                // φ = atan(c tan α) (cos α ≥ 0 here) and
                // dφ/du = 2cπ(1 + τ²)/(1 + c²τ²) = 2cπ / (cos²α + c² sin²α).
                let phi = (c * sa).atan2(ca) + offset;
                let dphi_du = 2.0 * c * PI / (ca * ca + c * c * sa * sa);
                let sin_t = (s * (2.0 - s)).max(0.0).sqrt();
                let (sp, cp) = phi.sin_cos();
                (
                    x * (sin_t * cp) + y * (sin_t * sp) + z * (1.0 - s),
                    dphi_du * ds_dv,
                )
            }
        }
    }

    /// Inverse of [`Self::to_sphere`] for binning: `uv ∈ [0, 1]²` of the
    /// direction of `d` (any non-zero finite vector; its length is divided out).
    #[must_use]
    pub fn from_sphere(&self, d: DVec3) -> DVec2 {
        match *self {
            Self::UniformSphere { axis } => {
                let (x, y, z) = f64_frame(axis);
                let local = DVec3::new(d.dot(x), d.dot(y), d.dot(z));
                let mut phi = local.y.atan2(local.x);
                if phi < 0.0 {
                    phi += 2.0 * PI;
                }
                DVec2::new(
                    (phi / (2.0 * PI)).clamp(0.0, 1.0),
                    (0.5 * one_minus_cos(local)).clamp(0.0, 1.0),
                )
            }
            Self::ZoomedCap {
                x,
                y,
                z,
                s0,
                phi_stretch: c,
            } => {
                let local = DVec3::new(d.dot(x), d.dot(y), d.dot(z));
                let s = one_minus_cos(local);
                let l = (2.0 / s0).ln_1p();
                let v = (s / s0).ln_1p() / l;
                // tan α = tan φ / c, α ∈ [−π/2, π/2], with φ taken in the half
                // of the sample (east: x ≥ 0 … west: rotated by π).
                let u = if local.x > 0.0 {
                    let alpha = local.y.atan2(c * local.x);
                    0.5 * (alpha / PI + 0.5)
                } else {
                    let alpha = (-local.y).atan2(-c * local.x);
                    0.5 * (alpha / PI + 0.5) + 0.5
                };
                DVec2::new(u.clamp(0.0, 1.0), v.clamp(0.0, 1.0))
            }
        }
    }
}

/// Unit axis among a fixed set of 2000 near-uniform candidates (a Fibonacci
/// sphere) that stays furthest from every point of `avoid` and its antipode,
/// i.e. maximises `min_k (1 − |axis·p_k|)`: the pole of a
/// [`Warp::UniformSphere`] grid that keeps sharp lobes away from its poles,
/// where its cells are thin. Deterministic.
#[must_use]
pub fn axis_avoiding(avoid: &[DVec3]) -> DVec3 {
    const N: usize = 2000;
    let golden = PI * (3.0 - 5.0_f64.sqrt());
    let mut best = (f64::NEG_INFINITY, DVec3::Z);
    for i in 0..N {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / N as f64;
        let r = (1.0 - z * z).sqrt();
        let (s, c) = (golden * i as f64).sin_cos();
        let axis = DVec3::new(r * c, r * s, z);
        let score = avoid
            .iter()
            .map(|p| 1.0 - axis.dot(p.normalize()).abs())
            .fold(f64::INFINITY, f64::min);
        if score > best.0 {
            best = (score, axis);
        }
    }
    best.1
}

/// Parameters of [`run_chi2`].
#[derive(Clone, Debug)]
pub struct Chi2Config {
    /// Grid columns (azimuth), `2 res_v − 1` for Mitsuba's 2:1 grid.
    pub res_u: usize,
    /// Grid rows (polar), odd.
    pub res_v: usize,
    /// Number of samples histogrammed.
    pub samples: usize,
    /// Gauss–Legendre points per cell per axis for the expected counts
    /// (`1..=16`).
    pub integration_order: usize,
    /// Significance level of the whole suite (before the Šidák correction).
    pub alpha: f64,
    /// Cells expecting fewer samples than this are pooled.
    pub min_expected: f64,
    /// Seed of the sample generator.
    pub seed: u64,
}

impl Default for Chi2Config {
    fn default() -> Self {
        Self {
            res_u: 101,
            res_v: 51,
            samples: 1_000_000,
            integration_order: 6,
            alpha: 0.01,
            min_expected: 5.0,
            seed: 0,
        }
    }
}

/// Outcome of [`run_chi2`].
#[derive(Clone, Debug)]
pub struct Chi2Result {
    /// Pearson's statistic `Σ (observed − expected)² / expected` over the
    /// pooled cells.
    pub statistic: f64,
    /// Degrees of freedom: pooled cells − 1.
    pub dof: usize,
    /// `P(χ²_dof ≥ statistic)`.
    pub p_value: f64,
    /// Šidák-corrected significance `1 − (1 − α)^{1/total_tests}`; the test
    /// fails when `p_value < threshold`.
    pub threshold: f64,
    /// Whether the test passed.
    pub passed: bool,
    /// One-line summary; on failure the reason and the path of the written
    /// histograms.
    pub message: String,
    /// `Σ expected / samples`, i.e. `∫ pdf dω` at the grid's quadrature.
    pub expected_total: f64,
    /// Diagnostic: the largest change of a cell's expected count between
    /// `integration_order` and twice that order (capped at 16), in units of
    /// the cell's Poisson standard deviation. Well below 1 when the grid
    /// resolves the density.
    pub quadrature_z: f64,
}

/// Stream of the generator used by [`run_chi2`].
pub const CHI2_STREAM: u64 = 0x000c_4152;

/// Cells `(expected, observed)` sorted by expected count, those expecting
/// fewer than `min_expected` pooled into one (added to the smallest kept
/// cell when the pool itself expects fewer); returns the cells and how many
/// were pooled.
#[must_use]
pub fn pool_low_cells(mut cells: Vec<(f64, f64)>, min_expected: f64) -> (Vec<(f64, f64)>, usize) {
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n_low = cells.partition_point(|c| c.0 < min_expected);
    let pooled = cells[..n_low]
        .iter()
        .fold((0.0, 0.0), |acc, c| (acc.0 + c.0, acc.1 + c.1));
    let mut kept: Vec<(f64, f64)> = cells[n_low..].to_vec();
    if n_low > 0 {
        if pooled.0 < min_expected && !kept.is_empty() {
            kept[0].0 += pooled.0;
            kept[0].1 += pooled.1;
        } else {
            kept.push(pooled);
        }
    }
    (kept, n_low)
}

/// Pearson's statistic `Σ (o − e)² / e` of cells `(expected, observed)`.
#[must_use]
pub fn pearson_statistic(cells: &[(f64, f64)]) -> f64 {
    cells.iter().map(|(e, o)| (o - e) * (o - e) / e).sum()
}

/// Šidák-corrected per-test significance: `1 − (1 − α)^{1/n}`.
#[must_use]
pub fn sidak(alpha: f64, total_tests: usize) -> f64 {
    -((-alpha).ln_1p() / total_tests.max(1) as f64).exp_m1()
}

/// File name for a case name: anything but `[A-Za-z0-9._-]` becomes `_`.
#[must_use]
pub fn sanitize_name(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Directory the histograms of failed tests go to: `<workspace>/target/chi2-failures`.
#[must_use]
pub fn failure_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("target")
        .join("chi2-failures")
}

/// Chi² goodness-of-fit test of `case.dist.sample` against `case.dist.pdf`
/// on the grid of `case.warp`, one of `total_tests` tests of the suite.
///
/// Fails immediately (statistic NaN) if a sample is not a finite non-zero
/// vector, if the pdf is negative or not finite at a quadrature node, or if a
/// sample falls into a cell whose expected count is below
/// `samples · 10⁻¹⁵` (a probability no test could ever observe: Mitsuba's
/// "samples in cells with expected frequency 0"). On failure the observed and
/// expected histograms are written to [`failure_dir`] (and a file left there
/// by an earlier failure of the same case is removed when it passes).
#[must_use]
pub fn run_chi2(case: &Case, total_tests: usize, cfg: &Chi2Config) -> Chi2Result {
    let (res_u, res_v) = (cfg.res_u, cfg.res_v);
    let threshold = sidak(cfg.alpha, total_tests);
    let n = cfg.samples as f64;
    let warp = case.warp;

    // Histogram.
    let mut observed = vec![0_u64; res_u * res_v];
    let mut rng = Pcg32::new(cfg.seed, CHI2_STREAM);
    let mut bad_sample = None;
    for i in 0..cfg.samples {
        let (d, _) = case.dist.sample(&mut rng);
        let d = d.as_dvec3();
        if !(d.is_finite() && d.length_squared() > 0.0) {
            bad_sample.get_or_insert(format!("sample {i} is {d:?}"));
            continue;
        }
        let uv = warp.from_sphere(d);
        let iu = ((uv.x * res_u as f64) as usize).min(res_u - 1);
        let iv = ((uv.y * res_v as f64) as usize).min(res_v - 1);
        observed[iv * res_u + iu] += 1;
    }

    // Expected counts.
    let mut bad_pdf = None;
    let pdf = |d: DVec3| {
        let p = f64::from(case.dist.pdf(d.as_vec3()));
        if !(p.is_finite() && p >= 0.0) {
            // Reported below; NaN poisons the cell either way.
            return f64::NAN;
        }
        p
    };
    let mut expected = cell_integrals(&warp, pdf, res_u, res_v, cfg.integration_order);
    for e in &mut expected {
        *e *= n;
    }
    if let Some(i) = expected.iter().position(|e| !e.is_finite()) {
        bad_pdf = Some(format!(
            "pdf is negative or not finite in cell (u {}, v {})",
            i % res_u,
            i / res_u
        ));
    }
    let check_order = (2 * cfg.integration_order).min(crate::quadrature::MAX_ORDER);
    let check = cell_integrals(&warp, pdf, res_u, res_v, check_order);
    let quadrature_z = expected
        .iter()
        .zip(&check)
        .map(|(e, c)| (e - c * n).abs() / (c * n).max(1.0).sqrt())
        .fold(0.0, f64::max);
    let expected_total = expected.iter().sum::<f64>() / n;

    let fail = |reason: String, statistic: f64, dof: usize, p_value: f64| {
        let path = write_histograms(
            &case.name,
            &observed,
            &expected,
            res_u,
            res_v,
            &format!(
                "{reason}\nstatistic {statistic}, dof {dof}, p {p_value:e}, threshold {threshold:e}, \
                 ∫pdf {expected_total}, quadrature_z {quadrature_z:.3e}, seed {}",
                cfg.seed
            ),
        );
        Chi2Result {
            statistic,
            dof,
            p_value,
            threshold,
            passed: false,
            message: format!("{}: {reason} (histograms: {path})", case.name),
            expected_total,
            quadrature_z,
        }
    };

    if let Some(reason) = bad_sample.or(bad_pdf) {
        return fail(reason, f64::NAN, 0, 0.0);
    }
    let zero_tolerance = n * 1e-15;
    let stray: Vec<usize> = (0..expected.len())
        .filter(|&i| observed[i] > 0 && expected[i] < zero_tolerance)
        .collect();
    if !stray.is_empty() {
        let count: u64 = stray.iter().map(|&i| observed[i]).sum();
        let first = stray[0];
        return fail(
            format!(
                "{count} samples in {} cells with expected count < {zero_tolerance:e} \
                 (first: cell u {}, v {}, observed {}, expected {:e})",
                stray.len(),
                first % res_u,
                first / res_u,
                observed[first],
                expected[first]
            ),
            f64::NAN,
            0,
            0.0,
        );
    }

    // Sort by expected count and pool the cells expecting < min_expected.
    let cells: Vec<(f64, f64)> = expected
        .iter()
        .zip(&observed)
        .filter(|(e, o)| !(**e == 0.0 && **o == 0))
        .map(|(e, o)| (*e, *o as f64))
        .collect();
    let (kept, n_low) = pool_low_cells(cells, cfg.min_expected);
    let statistic = pearson_statistic(&kept);
    let dof = kept.len().saturating_sub(1);
    if dof < 1 {
        return fail(
            format!(
                "only {} cell(s) expect ≥ {} samples: the grid does not resolve the distribution",
                kept.len(),
                cfg.min_expected
            ),
            statistic,
            dof,
            0.0,
        );
    }
    let p_value = ChiSquared::new(dof as f64).expect("dof ≥ 1").sf(statistic);
    let summary = format!(
        "statistic {statistic:.1}, dof {dof} ({n_low} cells pooled), p {p_value:.3e}, \
         threshold {threshold:.3e}, quadrature_z {quadrature_z:.1e}"
    );
    if p_value.is_nan() || p_value < threshold {
        return fail(format!("rejected: {summary}"), statistic, dof, p_value);
    }
    // A stale failure file of an earlier run would mislead.
    let _ = std::fs::remove_file(failure_dir().join(format!("{}.txt", sanitize_name(&case.name))));
    Chi2Result {
        statistic,
        dof,
        p_value,
        threshold,
        passed: true,
        message: format!("{}: {summary}", case.name),
        expected_total,
        quadrature_z,
    }
}

/// Writes the observed and expected histograms (`res_v` rows × `res_u`
/// columns each) to `failure_dir()/<sanitised name>.txt`; returns the path
/// (or why it could not be written).
fn write_histograms(
    name: &str,
    observed: &[u64],
    expected: &[f64],
    res_u: usize,
    res_v: usize,
    header: &str,
) -> String {
    let dir = failure_dir();
    let path = dir.join(format!("{}.txt", sanitize_name(name)));
    let mut text = format!(
        "# chi² failure: {name}\n# {}\n",
        header.replace('\n', "\n# ")
    );
    let _ = writeln!(
        text,
        "# observed ({res_v} rows of v × {res_u} columns of u)"
    );
    for row in observed.chunks(res_u) {
        let line: Vec<String> = row.iter().map(u64::to_string).collect();
        let _ = writeln!(text, "{}", line.join(" "));
    }
    let _ = writeln!(
        text,
        "# expected ({res_v} rows of v × {res_u} columns of u)"
    );
    for row in expected.chunks(res_u) {
        let line: Vec<String> = row.iter().map(|e| format!("{e:.3}")).collect();
        let _ = writeln!(text, "{}", line.join(" "));
    }
    debug_assert_eq!(observed.len(), res_u * res_v);
    match std::fs::create_dir_all(&dir).and_then(|()| std::fs::write(&path, text)) {
        Ok(()) => path.display().to_string(),
        Err(e) => format!("<could not write {}: {e}>", path.display()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn warps() -> Vec<Warp> {
        vec![
            Warp::uniform(),
            Warp::uniform_about(DVec3::new(-0.3, 0.1, -0.9)),
            Warp::zoomed(
                DVec3::new(0.2, 0.3, -0.9),
                DVec3::new(1.0, 0.0, 0.3),
                1e-4,
                1.0,
            ),
            Warp::zoomed(DVec3::Z, DVec3::X, 0.3, 5.0),
            Warp::zoomed_about(-DVec3::Z, 1e-2),
        ]
    }

    #[test]
    fn from_sphere_inverts_to_sphere() {
        let mut rng = Pcg32::new(7, 0);
        for warp in warps() {
            for _ in 0..10_000 {
                let uv = DVec2::new(rng.next_f64(), rng.next_f64());
                let (d, jac) = warp.to_sphere(uv);
                assert!((d.length() - 1.0).abs() < 1e-14, "{warp:?} {uv}");
                assert!(jac > 0.0 && jac.is_finite());
                let back = warp.from_sphere(d * 3.0);
                assert!(
                    (back - uv).abs().max_element() < 1e-9,
                    "{warp:?}: {uv} → {back}"
                );
            }
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let mut rng = Pcg32::new(8, 0);
        let h = 1e-6;
        for warp in warps() {
            for _ in 0..1000 {
                let uv = DVec2::new(0.01 + 0.98 * rng.next_f64(), 0.01 + 0.98 * rng.next_f64());
                let (_, jac) = warp.to_sphere(uv);
                let du = (warp.to_sphere(uv + DVec2::X * h).0
                    - warp.to_sphere(uv - DVec2::X * h).0)
                    / (2.0 * h);
                let dv = (warp.to_sphere(uv + DVec2::Y * h).0
                    - warp.to_sphere(uv - DVec2::Y * h).0)
                    / (2.0 * h);
                let numeric = du.cross(dv).length();
                assert!(
                    (numeric - jac).abs() <= 1e-5 * jac,
                    "{warp:?} at {uv}: {numeric} vs {jac}"
                );
            }
        }
    }

    #[test]
    fn sidak_threshold() {
        assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
        let t = sidak(0.01, 50);
        assert!(((1.0 - t).powi(50) - 0.99).abs() < 1e-12);
    }
}
