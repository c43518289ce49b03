//! Inverse-variance combination of passes: an online-trained guide makes every training pass a
//! different estimator, and the early ones (a guide that has seen a few hundred thousand
//! samples) are often far noisier than the passes after training. Averaging all passes alike
//! gives each the same weight `1/N`; weighting pass `i` by `a_i ∝ 1/V_i`, with `V_i` its relative
//! variance, minimises the image's relMSE.
//!
//! The renderer hands every pass's pixel values to [`PassCombiner::add_pass`] with a **group**:
//! passes of one group are identically distributed (the same estimator: after training, all
//! guided passes; all unguided ones), each training pass is a group of its own. Per group `g`
//! of `n_g` passes the per-pass relative variance is estimated as
//!
//! `V_g = (1 / 3|H| n_g) Σ_{p∈H} Σ_ch D_{g,p,ch} / (m̃_{p,ch}² + ε)`,
//! `D_{g,p,ch} = Σ_{i∈g} (x_{i,p,ch} − x̄_{p,ch})²`,
//!
//! with `x̄` the plain mean of all passes, `m̃` its `(2r + 1)²` box-filtered value and
//! `ε = 0.01` (the relMSE's denominator the benchmark uses). The weights are then
//! `a_g = (1/V'_g) / Σ_h (n_h / V'_h)` per pass of group `g` (`Σ_g n_g a_g = 1`), with
//! `V'_g = max(V_g, V_r)` and `r` the group of the most passes (the later one on a tie).
//!
//! **The cap at the largest group** (a deviation from plain inverse-variance weighting): a
//! group of one pass estimates its `V` from one draw of a heavy-tailed quantity (a firefly
//! lands in a pass with a small probability and dominates `D` when it does), so its `V_g` is
//! usually far below its expectation and `1/V_g` above it (Jensen). The largest group has seen
//! many passes' fireflies. Uncapped, on `veach-mis` the training passes (6 % of the passes)
//! got 17-21 % of the weight with a `V` of 2 against 6-10 for the unguided passes of the same
//! estimator family, and the image's relMSE rose by 23 %. Capped, a group can only be
//! weighted down against the largest group, never up. [`CombineOptions::cap_at_largest_group`]
//! turns it off (for tests that show the defect).
//!
//! **Unbiasedness.** Weights computed from the very values they weight are biased: a pass with
//! a firefly has a larger `V` and a smaller weight, so the firefly's energy is lost (Müller et
//! al., *Practical Path Guiding in Production*, 2019, weight iterations by their estimated
//! variance and accept that bias). Here the pixels are split into the two halves of a
//! checkerboard (`(x + y) mod 2`), and the weights estimated on one half (with `x̄` and `m̃` of
//! that half alone) are applied to the other. A pixel's samples are independent of the other
//! half's, so its weights are independent of its values and `E[Σ_i a_i x_i] = μ Σ_i E[a_i] = μ`.
//! What remains is second order: the guide of a later pass was trained on paths of both halves.
//! Whenever a weight is not finite and positive (a black image, an empty half), both halves fall
//! back to the plain mean.
//!
//! The variance of the combined pixel, for the image's error bars, is
//! `Σ_g a_g² D_g · N / (N − 1)` (the plain mean's `s² / N` when every `a_g = 1/N`).
//!
//! Memory: a group of one pass keeps its pixels (12 B per pixel), a larger one per-pixel sums
//! and sums of squares (48 B per pixel).

use crate::GuidingError;

/// Options of a [`PassCombiner`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CombineOptions {
    /// `ε` of the relative variance's denominator `m̃² + ε`.
    pub epsilon: f64,
    /// Radius `r` of the box filter on the mean image (0: none).
    pub smoothing_radius: u32,
    /// No group gets a larger per-pass weight than the group of the most passes (see the
    /// [module docs](self)).
    pub cap_at_largest_group: bool,
}

impl Default for CombineOptions {
    fn default() -> Self {
        Self {
            epsilon: 0.01,
            smoothing_radius: 2,
            cap_at_largest_group: true,
        }
    }
}

/// Whose pixels give the denominators `m̃` of a half's relative variances.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Denominator {
    /// The half's own (box filtered): what [`PassCombiner::combine`] uses. With many passes
    /// per pixel the mean hardly depends on any one of them.
    SameHalf,
    /// The other half's, box filtered around the pixel (radius at least 1): independent of the
    /// pixel's own values. With a few heavy-tailed passes a pixel's mean and its deviations
    /// come from the same rare large value, and the self-normalised `V` of every group looks
    /// alike (the trial's negative control in `guiding::trial` shows the same): for
    /// comparing groups of a few passes each.
    OtherHalf,
}

/// What [`PassCombiner::combine`] decided for one group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupWeight {
    /// The caller's group id.
    pub group: u32,
    /// Passes of the group.
    pub passes: u32,
    /// Per-pass relative variance `V_g` estimated on each checkerboard half (`NaN` for an empty
    /// half).
    pub relative_variance: [f64; 2],
    /// Per-pass weight `a_g` estimated on each half (applied to the other half's pixels).
    pub pass_weight: [f64; 2],
    /// The group's share of the image, `n_g a_g`, averaged over the halves (`n_g / N` for the
    /// plain mean).
    pub share: f64,
}

impl GroupWeight {
    /// `V_g` averaged over the two halves.
    pub fn mean_relative_variance(&self) -> f64 {
        (self.relative_variance[0] + self.relative_variance[1]) / 2.0
    }
}

/// The combined image and its weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// Per pixel, the weighted mean of the passes (row-major).
    pub pixels: Vec<[f32; 3]>,
    /// Per pixel, the estimated variance of that mean.
    pub var_of_mean: Vec<[f32; 3]>,
    /// Per group, in order of first appearance.
    pub groups: Vec<GroupWeight>,
    /// The weights were not usable (see the [module docs](self)): the image is the plain mean.
    pub fell_back: bool,
}

impl Combination {
    /// Predicted relMSE of the weighted image relative to the plain mean's, from the weights
    /// and variances of the half each weight was estimated on: `Σ n a² V / (Σ n V / N²)`
    /// (1 for the plain mean; below 1 the weighting helps), `a` the weights used.
    pub fn predicted_gain(&self) -> f64 {
        if self.fell_back {
            return 1.0;
        }
        let n: f64 = self.groups.iter().map(|g| f64::from(g.passes)).sum();
        let mut ratio = 0.0;
        let mut halves = 0.0;
        for h in 0..2 {
            let v = |g: &GroupWeight| g.relative_variance[h];
            if self
                .groups
                .iter()
                .any(|g| !(v(g).is_finite() && v(g) > 0.0))
            {
                continue;
            }
            let weighted: f64 = self
                .groups
                .iter()
                .map(|g| f64::from(g.passes) * g.pass_weight[h] * g.pass_weight[h] * v(g))
                .sum();
            let plain: f64 = self
                .groups
                .iter()
                .map(|g| f64::from(g.passes) * v(g))
                .sum::<f64>()
                / (n * n);
            ratio += weighted / plain;
            halves += 1.0;
        }
        if halves > 0.0 {
            ratio / halves
        } else {
            1.0
        }
    }
}

/// The sums of one group.
#[derive(Clone, Debug)]
enum Storage {
    /// One pass: its pixels.
    One(Vec<[f32; 3]>),
    /// Several: per-pixel sums and sums of squares.
    Many {
        sum: Vec<[f64; 3]>,
        sum2: Vec<[f64; 3]>,
    },
}

#[derive(Clone, Debug)]
struct Group {
    id: u32,
    passes: u32,
    storage: Storage,
}

impl Group {
    /// Sum of the group's values at pixel `p`.
    fn sum(&self, p: usize) -> [f64; 3] {
        match &self.storage {
            Storage::One(px) => px[p].map(f64::from),
            Storage::Many { sum, .. } => sum[p],
        }
    }

    /// `D_{g,p,ch} = Σ_i (x_i − mean)²` at pixel `p`.
    fn deviation(&self, p: usize, mean: [f64; 3]) -> [f64; 3] {
        let n = f64::from(self.passes);
        let mut d = [0.0; 3];
        for ch in 0..3 {
            d[ch] = match &self.storage {
                Storage::One(px) => {
                    let e = f64::from(px[p][ch]) - mean[ch];
                    e * e
                }
                Storage::Many { sum, sum2 } => {
                    (sum2[p][ch] - 2.0 * mean[ch] * sum[p][ch] + n * mean[ch] * mean[ch]).max(0.0)
                }
            };
        }
        d
    }
}

/// Accumulates a render's passes by group and combines them with inverse-variance weights;
/// see the [module docs](self).
#[derive(Clone, Debug)]
pub struct PassCombiner {
    width: usize,
    height: usize,
    options: CombineOptions,
    groups: Vec<Group>,
}

impl PassCombiner {
    /// A combiner for images of `width × height` pixels (row-major).
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for no pixels or an `epsilon` that is not finite and
    /// positive.
    pub fn new(width: usize, height: usize, options: CombineOptions) -> Result<Self, GuidingError> {
        if width.saturating_mul(height) == 0 {
            return Err(GuidingError::InvalidConfig(format!(
                "a pass combiner needs pixels, got {width} x {height}"
            )));
        }
        if !(options.epsilon.is_finite() && options.epsilon > 0.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "the combiner's epsilon must be finite and positive, got {}",
                options.epsilon
            )));
        }
        Ok(Self {
            width,
            height,
            options,
            groups: Vec::new(),
        })
    }

    /// Passes added so far.
    pub fn passes(&self) -> u32 {
        self.groups.iter().map(|g| g.passes).sum()
    }

    /// Groups seen so far.
    pub fn group_count(&self) -> usize {
        self.groups.len()
    }

    /// Adds one pass of `group`. Non-finite values count as 0 (the renderer's image would be
    /// non-finite there anyway).
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if `pixels` is not `width × height` long; nothing is
    /// added then.
    pub fn add_pass(&mut self, group: u32, pixels: &[[f32; 3]]) -> Result<(), GuidingError> {
        let n = self.width * self.height;
        if pixels.len() != n {
            return Err(GuidingError::LengthMismatch {
                what: format!("a pass of {} pixels for a combiner of {n}", pixels.len()),
            });
        }
        let clean = |v: &[f32; 3]| v.map(|x| if x.is_finite() { x } else { 0.0 });
        let Some(g) = self.groups.iter_mut().find(|g| g.id == group) else {
            self.groups.push(Group {
                id: group,
                passes: 1,
                storage: Storage::One(pixels.iter().map(clean).collect()),
            });
            return Ok(());
        };
        if let Storage::One(px) = &g.storage {
            let sum: Vec<[f64; 3]> = px.iter().map(|v| v.map(f64::from)).collect();
            let sum2 = sum.iter().map(|v| v.map(|x| x * x)).collect();
            g.storage = Storage::Many { sum, sum2 };
        }
        if let Storage::Many { sum, sum2 } = &mut g.storage {
            for (p, v) in pixels.iter().enumerate() {
                for (ch, &x) in clean(v).iter().enumerate() {
                    let x = f64::from(x);
                    sum[p][ch] += x;
                    sum2[p][ch] += x * x;
                }
            }
        }
        g.passes += 1;
        Ok(())
    }

    /// The combined image (see the [module docs](self)); the plain mean for a single group.
    pub fn combine(&self) -> Combination {
        self.combine_with(Denominator::SameHalf)
    }

    /// [`combine`](Self::combine) with the relative variances' denominators `m̃` taken from
    /// `denominator`'s pixels.
    pub fn combine_with(&self, denominator: Denominator) -> Combination {
        let npix = self.width * self.height;
        let total: u32 = self.passes();
        let n = f64::from(total.max(1));
        let mean = self.plain_mean();
        let half = |p: usize| (p % self.width + p / self.width) % 2;
        let per_half = [0, 1].map(|h| self.half_variance(&mean, h, denominator));
        let variance: Vec<[f64; 2]> = (0..self.groups.len())
            .map(|gi| [per_half[0][gi], per_half[1][gi]])
            .collect();
        let usable = self.groups.len() > 1
            && variance
                .iter()
                .all(|v| v.iter().all(|&x| x.is_finite() && x > 0.0));
        // The group of the most passes, the later one on a tie.
        // (`max_by_key` keeps the last maximum.)
        let largest = (0..self.groups.len())
            .max_by_key(|&gi| self.groups[gi].passes)
            .unwrap_or(0);
        // a[h][g]: per-pass weight of group g estimated on half h.
        let a: Vec<Vec<f64>> = (0..2)
            .map(|h| {
                if usable {
                    let floor = if self.options.cap_at_largest_group {
                        variance[largest][h]
                    } else {
                        0.0
                    };
                    let capped: Vec<f64> = variance.iter().map(|v| v[h].max(floor)).collect();
                    let inv: f64 = self
                        .groups
                        .iter()
                        .zip(&capped)
                        .map(|(g, v)| f64::from(g.passes) / v)
                        .sum();
                    capped.iter().map(|v| 1.0 / (v * inv)).collect()
                } else {
                    vec![1.0 / n; self.groups.len()]
                }
            })
            .collect();
        let correction = if total > 1 { n / (n - 1.0) } else { 0.0 };
        let mut pixels = Vec::with_capacity(npix);
        let mut var_of_mean = Vec::with_capacity(npix);
        for p in 0..npix {
            // Weights from the other half.
            let w = &a[1 - half(p)];
            let (mut value, mut var) = ([0.0f64; 3], [0.0f64; 3]);
            for (gi, g) in self.groups.iter().enumerate() {
                let (s, d) = (g.sum(p), g.deviation(p, mean[p]));
                for ch in 0..3 {
                    value[ch] += w[gi] * s[ch];
                    var[ch] += w[gi] * w[gi] * d[ch] * correction;
                }
            }
            pixels.push(value.map(|x| x as f32));
            var_of_mean.push(var.map(|x| x as f32));
        }
        let groups = self
            .groups
            .iter()
            .enumerate()
            .map(|(gi, g)| GroupWeight {
                group: g.id,
                passes: g.passes,
                relative_variance: variance[gi],
                pass_weight: [a[0][gi], a[1][gi]],
                share: f64::from(g.passes) * (a[0][gi] + a[1][gi]) / 2.0,
            })
            .collect();
        Combination {
            pixels,
            var_of_mean,
            groups,
            fell_back: !usable,
        }
    }

    /// The plain mean of all passes per pixel.
    fn plain_mean(&self) -> Vec<[f64; 3]> {
        let n = f64::from(self.passes().max(1));
        (0..self.width * self.height)
            .map(|p| {
                let mut s = [0.0; 3];
                for g in &self.groups {
                    let gs = g.sum(p);
                    for ch in 0..3 {
                        s[ch] += gs[ch];
                    }
                }
                s.map(|x| x / n)
            })
            .collect()
    }

    /// Per group (in order of first appearance: its id and the values), the per-pass relative
    /// variance `V_g` estimated on each of [`crate::evidence::band_count`] bands of rows (both
    /// checkerboard halves, each with its `denominator`'s weights): the paired band estimates
    /// that [`crate::CostRatio::from_bands`] turns into a confidence interval. `NaN` for a
    /// band without pixels.
    pub fn band_variances(&self, denominator: Denominator) -> Vec<(u32, Vec<f64>)> {
        let mean = self.plain_mean();
        let bands = crate::evidence::band_count(self.height);
        let halves = [0, 1].map(|h| self.weighted_deviations(&mean, h, denominator, bands));
        self.groups
            .iter()
            .enumerate()
            .map(|(gi, g)| {
                let v = (0..bands)
                    .map(|b| {
                        let sum = halves[0].0[gi][b] + halves[1].0[gi][b];
                        per_pass(sum, halves[0].1[b] + halves[1].1[b], g.passes)
                    })
                    .collect();
                (g.id, v)
            })
            .collect()
    }

    /// `V_g` of every group estimated on half `h` (`NaN` for an empty half).
    fn half_variance(&self, mean: &[[f64; 3]], h: usize, denominator: Denominator) -> Vec<f64> {
        let (acc, cells) = self.weighted_deviations(mean, h, denominator, 1);
        acc.iter()
            .zip(&self.groups)
            .map(|(a, g)| per_pass(a[0], cells[0], g.passes))
            .collect()
    }

    /// On half `h`, per group and band of rows (`bands` of them), the weighted deviations
    /// `D / (m̃² + ε)` summed over the band's cells, and per band the cells (pixels × 3
    /// channels).
    fn weighted_deviations(
        &self,
        mean: &[[f64; 3]],
        h: usize,
        denominator: Denominator,
        bands: usize,
    ) -> (Vec<Vec<f64>>, Vec<usize>) {
        let weight = self.half_weights(mean, h, denominator);
        let w = self.width;
        let mut acc = vec![vec![0.0f64; bands]; self.groups.len()];
        let mut cells = vec![0usize; bands];
        for p in (0..mean.len()).filter(|&p| (p % w + p / w) % 2 == h) {
            let b = crate::evidence::band_of_row(p / w, self.height, bands);
            cells[b] += 3;
            for (a, g) in acc.iter_mut().zip(&self.groups) {
                let d = g.deviation(p, mean[p]);
                a[b] += d[0] * weight[p][0] + d[1] * weight[p][1] + d[2] * weight[p][2];
            }
        }
        (acc, cells)
    }

    /// `1 / (m̃² + ε)` on half `h` (the box filter of `mean` over the pixels of that half, or
    /// of the other one with [`Denominator::OtherHalf`]); zero on the other half.
    fn half_weights(&self, mean: &[[f64; 3]], h: usize, denominator: Denominator) -> Vec<[f64; 3]> {
        let (w, ht) = (self.width, self.height);
        let in_half = |p: usize| (p % w + p / w) % 2 == h;
        let (source, radius) = match denominator {
            Denominator::SameHalf => (h, self.options.smoothing_radius as usize),
            Denominator::OtherHalf => (1 - h, (self.options.smoothing_radius as usize).max(1)),
        };
        let masked: Vec<[f64; 4]> = (0..w * ht)
            .map(|p| {
                if (p % w + p / w) % 2 == source {
                    [mean[p][0], mean[p][1], mean[p][2], 1.0]
                } else {
                    [0.0; 4]
                }
            })
            .collect();
        let smooth = box_sum(w, ht, &masked, radius);
        let eps = self.options.epsilon;
        (0..w * ht)
            .map(|p| {
                let s = smooth[p];
                if in_half(p) && s[3] > 0.0 {
                    [0, 1, 2].map(|ch| {
                        let m = s[ch] / s[3];
                        1.0 / (m * m + eps)
                    })
                } else {
                    [0.0; 3]
                }
            })
            .collect()
    }
}

/// Sum of each pixel's `(2r + 1)²` neighbourhood (clipped at the borders), separable.
fn box_sum(width: usize, height: usize, src: &[[f64; 4]], r: usize) -> Vec<[f64; 4]> {
    let rows = box_pass(width, height, src, r, true);
    box_pass(width, height, &rows, r, false)
}

/// One pass of [`box_sum`]: each pixel's sum over `±r` pixels along the
/// rows (`along_rows`) or the columns, in increasing order.
fn box_pass(
    width: usize,
    height: usize,
    src: &[[f64; 4]],
    r: usize,
    along_rows: bool,
) -> Vec<[f64; 4]> {
    let mut out = vec![[0.0; 4]; src.len()];
    for y in 0..height {
        for x in 0..width {
            // The pixel's position `at` on its line of `len` pixels, which
            // starts at `first` with `stride` between neighbours.
            let (at, len, first, stride) = if along_rows {
                (x, width, y * width, 1)
            } else {
                (y, height, x, width)
            };
            let mut acc = [0.0; 4];
            for t in at.saturating_sub(r)..=(at + r).min(len - 1) {
                let b = src[first + t * stride];
                for k in 0..4 {
                    acc[k] += b[k];
                }
            }
            out[y * width + x] = acc;
        }
    }
    out
}

/// A group's per-pass relative variance from its weighted deviations summed over `cells`
/// (`NaN` without cells).
fn per_pass(sum: f64, cells: usize, passes: u32) -> f64 {
    if cells > 0 {
        sum / (cells as f64 * f64::from(passes))
    } else {
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_group_is_the_plain_mean() {
        let mut c = PassCombiner::new(3, 2, CombineOptions::default()).unwrap();
        let a = vec![[1.0, 2.0, 3.0]; 6];
        let b = vec![[3.0, 2.0, 1.0]; 6];
        c.add_pass(7, &a).unwrap();
        c.add_pass(7, &b).unwrap();
        let out = c.combine();
        assert!(out.fell_back);
        for v in &out.pixels {
            assert_eq!(*v, [2.0, 2.0, 2.0]);
        }
        // s² / N with s² = 2 (values 1 and 3), N = 2.
        assert_eq!(out.var_of_mean[0], [1.0, 0.0, 1.0]);
        assert_eq!(out.groups[0].share, 1.0);
    }

    #[test]
    fn box_sum_counts_the_clipped_neighbourhood() {
        let src = vec![[1.0; 4]; 5 * 4];
        let out = box_sum(5, 4, &src, 1);
        assert_eq!(out[0][3], 4.0);
        assert_eq!(out[5 + 1][3], 9.0);
        assert_eq!(out[4][3], 4.0);
    }
}
