//! Piecewise densities on `[0, 1]` from `N` bins: the 1D building block of the
//! factorised directional PDFs (Figueiredo et al. 2025, "Neural Path Guiding
//! with Distribution Factorization", EGSR 2025, §3.1).
//!
//! A network outputs `N` logits per dimension; the activation is `N · softmax`,
//! so the bin values `v_i` have mean one and the density integrates to one
//! without any further normalisation. Two reconstructions are offered:
//!
//! - [`Interpolation::Nearest`]: piecewise constant, `p(x) = v_⌊xN⌋`;
//! - [`Interpolation::Linear`]: `v_i` sits at the bin centre `x_i = (i + ½)/N`
//!   and `p` interpolates linearly between centres. On the half bins at the
//!   ends, [`Boundary::Wrap`] (the azimuth φ) interpolates across the seam
//!   between `v_{N−1}` and `v_0`, and [`Boundary::Clamp`] (the polar angle θ)
//!   holds `v_0` on `[0, ½N⁻¹]` and `v_{N−1}` on `[1 − ½N⁻¹, 1]` (§3.1).
//!
//! In both cases `∫₀¹ p = mean(v) = 1`: as pieces, the linear density has
//! knots `[0, x_0, …, x_{N−1}, 1]` with end values `e = (v_{N−1} + v_0)/2`
//! (wrap) or `v_0`, `v_{N−1}` (clamp); the `N − 1` full pieces carry
//! `Σ (v_{k−1} + v_k) / 2N`, the two half pieces `(e_0 + v_0 + v_{N−1} + e_1)/4N`,
//! which sums to `Σ v_k / N` for either boundary.
//!
//! Sampling scans the pieces accumulating their masses (no CDF table: the
//! struct stays `N` floats and two codes) and inverts the quadratic CDF of a
//! linear piece in the cancellation-free form of [`sample_linear`].

use crate::math::{exp, ln, log_sum_exp_parts, sanitize, sqrt, unit_interval, ONE_MINUS_EPSILON};
use crate::mixture::softmax;
use bytemuck::{Pod, Zeroable};

/// Logits are clamped to `±PDF1D_LOGIT_LIMIT` (NaN becomes 0) before the
/// softmax, so that any network output gives a valid density.
pub const PDF1D_LOGIT_LIMIT: f32 = 1e30;

two_mode_enum! {
    /// How the bin values are reconstructed into a density.
    pub enum Interpolation {
        /// Piecewise constant: `p(x) = v_⌊xN⌋`.
        Nearest = 0,
        /// Piecewise linear between bin centres (Figueiredo et al. 2025, §3.1).
        Linear = 1,
    }
}

two_mode_enum! {
    /// How the ends of `[0, 1]` are treated.
    pub enum Boundary {
        /// Periodic (the azimuth φ): `0` and `1` are the same point; linear
        /// interpolation crosses the seam.
        Wrap = 0,
        /// Clamped (the polar angle θ): the end half bins are constant.
        Clamp = 1,
    }
}

/// The end values `a`, `b` of a linear piece for [`sample_linear`] and
/// [`linear_cdf`]: negative and NaN values taken as 0, then both divided by
/// their maximum (so their squares can neither overflow nor underflow to a
/// wrong ratio); `None` when that maximum is 0 or infinite.
#[inline]
fn normalised_ends(a: f32, b: f32) -> Option<(f32, f32)> {
    let a = if a > 0.0 { a } else { 0.0 };
    let b = if b > 0.0 { b } else { 0.0 };
    let m = a.max(b);
    if m > 0.0 && m <= f32::MAX {
        Some((a / m, b / m))
    } else {
        None
    }
}

/// Samples `t ∈ [0, 1)` with density `∝ (1 − t) a + t b` on the unit interval,
/// from `u ∈ [0, 1)`; `a, b ≥ 0`, not both zero.
///
/// The CDF is `F(t) = t (a (2 − t) + b t) / (a + b)`; its root is written
/// without cancellation (pbrt-v4 `SampleLinear`):
///
/// ```text
/// t = u (a + b) / (a + √((1 − u) a² + u b²))
/// ```
///
/// which degenerates smoothly to `t = u` for `a = b` and to `t = √u` for
/// `a = 0`. Deviation from pbrt: `a` and `b` are first divided by `max(a, b)`
/// so their squares can neither overflow nor underflow to a wrong ratio.
/// Invalid input (NaN, negative, both zero) is treated as `a = b` (`t = u`).
#[inline]
#[must_use]
pub fn sample_linear(u: f32, a: f32, b: f32) -> f32 {
    let u = unit_interval(u);
    let Some((a, b)) = normalised_ends(a, b) else {
        return u;
    };
    if u == 0.0 {
        return 0.0;
    }
    let t = u * (a + b) / (a + sqrt((1.0 - u) * (a * a) + u * (b * b)));
    t.clamp(0.0, ONE_MINUS_EPSILON)
}

/// CDF of [`sample_linear`]: `F(t) = t (a (2 − t) + b t) / (a + b)` for
/// `t ∈ [0, 1]` (clamped), every term non-negative. Invalid `a, b` behave as
/// in [`sample_linear`] (`F(t) = t`).
#[inline]
#[must_use]
pub fn linear_cdf(t: f32, a: f32, b: f32) -> f32 {
    let t = if t > 0.0 { t.min(1.0) } else { 0.0 };
    let Some((a, b)) = normalised_ends(a, b) else {
        return t;
    };
    (t * (a * (2.0 - t) + b * t) / (a + b)).clamp(0.0, 1.0)
}

/// Pieces whose mass is at most this (`2⁻²⁴` of the total, which is one for
/// every density the constructors build) are never chosen by
/// [`Pdf1d::sample`]: the tail cut of the lobes' samplers
/// ([`VMF_TAIL_CUT`](crate::lobe::vmf::VMF_TAIL_CUT)) applied per piece.
///
/// `2⁻²⁴` is the resolution of an `f32` random number in `[0, 1)`. Without
/// the cut, `u = 0` (or a `u` landing exactly on a running sum) chooses the
/// first piece of positive mass however small, e.g. one of mass `10⁻³⁸`
/// next to an empty bin, and samples it at its zero-density end, where the
/// density (and a factorised product of two such) underflows to 0 in
/// `f32`. A chosen piece of mass above the cut has a density above
/// `2⁻²³ / width` at its far end, so the densities of sampled points stay
/// representable. The sampled distribution differs from `p` by at most the
/// cut pieces' total mass, `< N · 2⁻²⁴`; `pdf` still reports their density.
pub const PDF1D_SAMPLE_CUT: f32 = 1.0 / 16_777_216.0;

/// A piece mass for sampling: `m` if it is above [`PDF1D_SAMPLE_CUT`],
/// else 0 (also for negative and NaN `m`).
#[inline]
fn sampled_mass(m: f32) -> f32 {
    if m > PDF1D_SAMPLE_CUT {
        m
    } else {
        0.0
    }
}

/// Brings `x` into `[0, 1]`: NaN and ±∞ become 0; otherwise a wrapping
/// domain takes `x mod 1` and a clamped one clamps. `x ∈ [0, 1]` is kept as
/// is (also `x = 1`, the left limit at the seam).
#[inline]
fn reduce(x: f32, boundary: Boundary) -> f32 {
    if !x.is_finite() {
        return 0.0;
    }
    match boundary {
        // `%` is the truncating remainder, in (−1, 1) and exact.
        Boundary::Wrap => {
            if x < 0.0 {
                (x % 1.0 + 1.0).min(1.0)
            } else if x > 1.0 {
                x % 1.0
            } else {
                x
            }
        }
        Boundary::Clamp => x.clamp(0.0, 1.0),
    }
}

/// Interpolation stencil at `x ∈ [0, 1]`: `p(x) = (1 − f) v_i + f v_j`.
#[inline]
fn stencil<const N: usize>(
    x: f32,
    interp: Interpolation,
    boundary: Boundary,
) -> (usize, usize, f32) {
    let n = N as f32;
    match interp {
        Interpolation::Nearest => {
            let i = bin_index::<N>(x * n);
            (i, i, 0.0)
        }
        Interpolation::Linear => {
            let s = x * n - 0.5;
            match boundary {
                Boundary::Wrap => {
                    if s < 0.0 {
                        // Between the centre of the last bin (at −½N⁻¹ across
                        // the seam) and that of the first.
                        (N - 1, 0, (s + 1.0).clamp(0.0, 1.0))
                    } else {
                        let i = bin_index::<N>(s);
                        let j = if i + 1 < N { i + 1 } else { 0 };
                        (i, j, (s - i as f32).clamp(0.0, 1.0))
                    }
                }
                Boundary::Clamp => {
                    let s = s.clamp(0.0, n - 1.0);
                    let i = bin_index::<N>(s);
                    if i + 1 < N {
                        (i, i + 1, (s - i as f32).clamp(0.0, 1.0))
                    } else {
                        (i, i, 0.0)
                    }
                }
            }
        }
    }
}

/// The logits with NaN replaced by 0 and clamped to
/// ±[`PDF1D_LOGIT_LIMIT`].
#[inline]
fn sanitized_logits<const N: usize>(logits: &[f32; N]) -> [f32; N] {
    let mut clean = [0.0; N];
    let mut k = 0;
    while k < N {
        clean[k] = sanitize(logits[k], PDF1D_LOGIT_LIMIT);
        k += 1;
    }
    clean
}

/// `⌊s⌋` clamped to `[0, N − 1]` (NaN to 0).
#[inline]
pub(crate) fn bin_index<const N: usize>(s: f32) -> usize {
    if s > 0.0 {
        // Through u32: the same saturating truncation for every s > 0 that
        // can index a bin, and a cheaper conversion than f32 → u64.
        let i = s as u32 as usize;
        if i < N {
            i
        } else {
            N - 1
        }
    } else {
        0
    }
}

/// The running sums of a [`Pdf1d`]'s piece masses ([`Pdf1d::running_sums`]):
/// the first `N` pieces' cumulative masses, and the total with a linear
/// density's end piece.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunningSums<const N: usize> {
    /// Cumulative mass after pieces `0..=k`.
    pub ends: [f32; N],
    /// Mass of all pieces.
    pub total: f32,
}

impl<const N: usize> RunningSums<N> {
    /// All zeros (no density's sums; a placeholder to overwrite).
    pub const ZERO: Self = Self {
        ends: [0.0; N],
        total: 0.0,
    };
}

/// A density on `[0, 1]` from `N ≥ 1` bin values of mean one (Figueiredo et
/// al. 2025, §3.1).
///
/// `repr(C)`, `Pod`, `N + 2` four-byte words: the values, then the
/// [`Interpolation`] and [`Boundary`] codes. Built by [`Self::from_logits`] or
/// [`Self::from_values`]; a zeroed value is only a placeholder to be
/// overwritten (its density is zero, and [`Self::sample`] falls back to `x = u`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pdf1d<const N: usize> {
    /// Bin values `v_i ≥ 0` with `Σ v_i = N`.
    pub values: [f32; N],
    /// [`Interpolation`] code.
    pub interpolation: u32,
    /// [`Boundary`] code.
    pub boundary: u32,
}

impl<const N: usize> Pdf1d<N> {
    /// All-zero table (a constant, for code that rust-gpu compiles:
    /// `Zeroable::zeroed` goes through `MaybeUninit`).
    pub const ZERO: Self = Self {
        values: [0.0; N],
        interpolation: 0,
        boundary: 0,
    };
}

// SAFETY: `repr(C)` struct of an `[f32; N]` array and two `u32`s, all 4-byte
// aligned, so no padding; every bit pattern is valid and zero is valid.
unsafe impl<const N: usize> Zeroable for Pdf1d<N> {}
// SAFETY: see above; `Copy + 'static` holds for every `N`.
unsafe impl<const N: usize> Pod for Pdf1d<N> {}

impl<const N: usize> Pdf1d<N> {
    /// The network activation `v = N · softmax(logits)` (DF §3.1). Logits are
    /// sanitised first (NaN → 0, clamped to ±[`PDF1D_LOGIT_LIMIT`]), so any
    /// input gives a valid density.
    #[must_use]
    pub fn from_logits(
        logits: &[f32; N],
        interpolation: Interpolation,
        boundary: Boundary,
    ) -> Self {
        let mut pdf = Self::zeroed(interpolation, boundary);
        softmax(&sanitized_logits(logits), &mut pdf.values);
        pdf.scale(N as f32);
        pdf
    }

    /// Density with values proportional to `values`, normalised here to mean
    /// one. Negative, NaN and infinite values count as zero; all-zero values
    /// give the uniform density. Values are divided by their maximum before
    /// summing, so even `f32::MAX` inputs cannot overflow.
    #[must_use]
    pub fn from_values(
        values: &[f32; N],
        interpolation: Interpolation,
        boundary: Boundary,
    ) -> Self {
        let mut pdf = Self::zeroed(interpolation, boundary);
        let mut max = 0.0f32;
        let mut k = 0;
        while k < N {
            let v = values[k];
            let v = if v > 0.0 && v <= f32::MAX { v } else { 0.0 };
            pdf.values[k] = v;
            max = max.max(v);
            k += 1;
        }
        if max <= 0.0 {
            k = 0;
            while k < N {
                pdf.values[k] = 1.0;
                k += 1;
            }
            return pdf;
        }
        let mut sum = 0.0;
        k = 0;
        while k < N {
            pdf.values[k] /= max;
            sum += pdf.values[k];
            k += 1;
        }
        // sum ∈ [1, N].
        pdf.scale(N as f32 / sum);
        pdf
    }

    /// All-zero values (not yet a density) with the given modes.
    fn zeroed(interpolation: Interpolation, boundary: Boundary) -> Self {
        Self {
            values: [0.0; N],
            interpolation: interpolation.code(),
            boundary: boundary.code(),
        }
    }

    /// Multiplies every value by `factor`.
    fn scale(&mut self, factor: f32) {
        let mut k = 0;
        while k < N {
            self.values[k] *= factor;
            k += 1;
        }
    }

    /// The interpolation mode.
    #[inline]
    #[must_use]
    pub fn interpolation(&self) -> Interpolation {
        Interpolation::from_code(self.interpolation)
    }

    /// The boundary mode.
    #[inline]
    #[must_use]
    pub fn boundary(&self) -> Boundary {
        Boundary::from_code(self.boundary)
    }

    /// Density `p(x)`; `x` outside `[0, 1]` is wrapped or clamped according
    /// to the boundary, NaN/±∞ read as 0. It integrates to 1 over `[0, 1]`:
    /// the density is normalised by construction, so there is no separate
    /// unnormalised `eval` (see the crate docs).
    ///
    /// Nearest: `v_⌊xN⌋`. Linear: `(1 − f) v_i + f v_j` with `s = xN − ½`,
    /// `i = ⌊s⌋`, `f = s − i`, `j = i + 1` (indices mod `N` for wrap; `s`
    /// clamped to `[0, N − 1]` for clamp).
    #[inline]
    #[must_use]
    pub fn pdf(&self, x: f32) -> f32 {
        self.pdf_in_unit_interval(reduce(x, self.boundary()))
    }

    /// [`Self::pdf`] of an `x` already in `[0, 1]` (where the reduction is the
    /// identity), for the samplers and the factorised density, whose `x`
    /// always is.
    #[inline]
    pub(crate) fn pdf_in_unit_interval(&self, x: f32) -> f32 {
        let (i, j, f) = stencil::<N>(x, self.interpolation(), self.boundary());
        (1.0 - f) * self.values[i] + f * self.values[j]
    }

    /// Number of pieces the density is made of: `N` (nearest) or `N + 1`
    /// (linear: two half pieces at the ends).
    #[inline]
    fn piece_count(&self) -> usize {
        match self.interpolation() {
            Interpolation::Nearest => N,
            Interpolation::Linear => N + 1,
        }
    }

    /// The linear density's values at `x = 0` and `x = 1`: the seam average
    /// for wrap, the end bins for clamp.
    #[inline]
    fn end_values(&self) -> (f32, f32) {
        let first = self.values[0];
        let last = self.values[N - 1];
        match self.boundary() {
            Boundary::Wrap => {
                let e = 0.5 * (first + last);
                (e, e)
            }
            Boundary::Clamp => (first, last),
        }
    }

    /// Piece `k` as `(start, width, value at start, value at end)`.
    #[inline]
    fn piece(&self, k: usize) -> (f32, f32, f32, f32) {
        let inv_n = 1.0 / N as f32;
        match self.interpolation() {
            Interpolation::Nearest => (k as f32 * inv_n, inv_n, self.values[k], self.values[k]),
            Interpolation::Linear => {
                let first = self.values[0];
                let last = self.values[N - 1];
                let (e0, e1) = self.end_values();
                if k == 0 {
                    (0.0, 0.5 * inv_n, e0, first)
                } else if k < N {
                    (
                        (k as f32 - 0.5) * inv_n,
                        inv_n,
                        self.values[k - 1],
                        self.values[k],
                    )
                } else {
                    ((N as f32 - 0.5) * inv_n, 0.5 * inv_n, last, e1)
                }
            }
        }
    }

    /// Mass `w (a + b) / 2` of piece `k`.
    #[inline]
    fn piece_mass(&self, k: usize) -> f32 {
        let (_, w, a, b) = self.piece(k);
        0.5 * w * (a + b)
    }

    /// Sum of the piece masses (one up to rounding).
    #[inline]
    fn total_mass(&self) -> f32 {
        let count = self.piece_count();
        let mut total = 0.0;
        let mut k = 0;
        while k < count {
            total += self.piece_mass(k);
            k += 1;
        }
        total
    }

    /// Draws `x ∈ [0, 1)` from `u ∈ [0, 1)` (clamped; NaN reads as 0) by
    /// inverting the CDF, and returns `(x, p(x))`.
    ///
    /// The running sums of the piece masses are formed in one tight pass
    /// (specialised per interpolation, no per-piece dispatch), and the chosen
    /// piece — the first whose running sum exceeds `u` times the total — is
    /// the number of running sums not above that target (a branch-free
    /// count, vectorised; pieces of zero mass are never chosen, as their
    /// running sum equals the previous one). Pieces of mass at most
    /// [`PDF1D_SAMPLE_CUT`] count as zero mass here. The choice and the
    /// position within the piece are bit-identical to a scan accumulating the
    /// (cut) masses.
    /// Inside the chosen piece, [`sample_linear`] inverts the quadratic CDF
    /// (for nearest interpolation the piece is flat and its inverse is the
    /// identity, which is exactly what `sample_linear` returns for equal end
    /// values, so it is skipped). The returned density
    /// is [`Self::pdf`] at the returned `x`, so the two always agree exactly.
    /// Should rounding place `x` on a point of zero density (the zero end of a
    /// piece, or across the edge into an empty bin; probability ~2⁻²⁴), `x`
    /// is stepped up to four ulps into the piece, and if the density there
    /// still underflows, moved `2⁻¹⁰` of the piece width inwards, so sampled
    /// points have `p > 0` whenever the chosen piece has positive density
    /// inside.
    #[must_use]
    pub fn sample(&self, u: f32) -> (f32, f32) {
        self.sample_with_margin(u, 0.0)
    }

    /// [`Self::sample`], with the sampled `x` kept at least
    /// `m = min(margin, width / 4)` inside the chosen piece: `x` is clamped to
    /// `[start + m, start + width − m]` before the zero-density nudges of
    /// [`Self::sample`]. The returned density is still [`Self::pdf`] at the
    /// returned `x`.
    ///
    /// Only points that would land within `m` of a piece end move, by at most
    /// `m`, and never out of their piece: the sampled distribution differs
    /// from `p` by less than `2 m · max p` of probability mass per piece,
    /// displaced by at most `m`. This is for callers that map `x` through a
    /// warp whose rounding can move it by a few ulps (the factorised sphere
    /// densities, see [`crate::factorised::SAMPLE_MARGIN`]): a point kept
    /// inside its piece cannot be carried across a discontinuity of `p` (the
    /// edge of a nearest bin, the end of the support) by that rounding.
    /// `margin ≤ 0` or NaN is [`Self::sample`] exactly.
    #[must_use]
    pub fn sample_with_margin(&self, u: f32, margin: f32) -> (f32, f32) {
        self.sample_with_sums(&self.running_sums(), u, margin)
    }

    /// The running sums [`Self::sample_with_margin`] draws from: computed
    /// once and kept ([`RunningSums`]), they save a sampler the serial pass
    /// over the pieces (a frozen, tabulated distribution sampled many times).
    #[must_use]
    pub fn running_sums(&self) -> RunningSums<N> {
        let linear = self.interpolation() == Interpolation::Linear;
        let inv_n = 1.0 / N as f32;
        // Running sums of the piece masses `w (a + b) / 2` (as `piece_mass`;
        // masses up to PDF1D_SAMPLE_CUT, and negative and NaN masses, which
        // no constructor produces, count as zero) over pieces 0..N; the linear end piece N is kept apart. One
        // serial pass: the running sum is the only loop-carried dependency.
        let mut ends = [0.0f32; N];
        let mut acc = 0.0f32;
        let mut last_mass = 0.0;
        if linear {
            let (e0, e1) = self.end_values();
            let half = 0.5 * inv_n;
            acc = sampled_mass(0.5 * half * (e0 + self.values[0]));
            ends[0] = acc;
            let mut k = 1;
            while k < N {
                acc += sampled_mass(0.5 * inv_n * (self.values[k - 1] + self.values[k]));
                ends[k] = acc;
                k += 1;
            }
            last_mass = sampled_mass(0.5 * half * (self.values[N - 1] + e1));
        } else {
            // `w (v + v) / 2 = v / N`, the same f32 (the factors ½ and 2 are
            // exact) for every value below f32::MAX / 2.
            let mut k = 0;
            while k < N {
                acc += sampled_mass(inv_n * self.values[k]);
                ends[k] = acc;
                k += 1;
            }
        }
        RunningSums {
            ends,
            total: acc + last_mass,
        }
    }

    /// [`Self::sample_with_margin`] from this density's [`Self::running_sums`]
    /// (the same result, bit for bit, when `sums` are this density's).
    #[must_use]
    pub fn sample_with_sums(&self, sums: &RunningSums<N>, u: f32, margin: f32) -> (f32, f32) {
        let u = unit_interval(u);
        let linear = self.interpolation() == Interpolation::Linear;
        let ends = &sums.ends;
        let total = sums.total;
        if !(total > 0.0 && total <= f32::MAX) {
            // Not a density built by the constructors (e.g. zeroed).
            return (u, self.pdf(u));
        }
        let target = u * total;
        // First piece whose running sum exceeds the target: the count of
        // running sums that do not (they are non-decreasing).
        let mut chosen = 0;
        let mut k = 0;
        while k < N {
            chosen += usize::from(target >= ends[k]);
            k += 1;
        }
        let count = if linear { N + 1 } else { N };
        if chosen == N && !(linear && target < total) {
            // Rounding left the target beyond the last running sum: the last
            // non-empty piece takes it (one exists, as total > 0).
            chosen = count;
            while chosen > 0 {
                chosen -= 1;
                let below = if chosen > 0 { ends[chosen - 1] } else { 0.0 };
                let end = if chosen < N { ends[chosen] } else { total };
                if end > below {
                    break;
                }
            }
        }
        let below = if chosen > 0 { ends[chosen - 1] } else { 0.0 };
        let local = unit_interval((target - below) / self.piece_mass(chosen));
        let (start, width, a, b) = self.piece(chosen);
        let t = if linear {
            sample_linear(local, a, b)
        } else {
            // A flat piece: `sample_linear(local, a, a)` is exactly `local`.
            local
        };
        let mut x = unit_interval(start + width * t);
        if margin > 0.0 {
            let m = margin.min(0.25 * width);
            x = x.clamp(start + m, start + width - m);
        }
        let mut p = self.pdf_in_unit_interval(x);
        // Rounding put x on zero density: step a few ulps into the piece …
        let mut step = 0;
        while (p <= 0.0 || p.is_nan()) && step < 4 {
            x = if t > 0.5 {
                x - x * f32::EPSILON
            } else {
                x + (x * f32::EPSILON).max(f32::MIN_POSITIVE)
            };
            x = unit_interval(x);
            p = self.pdf_in_unit_interval(x);
            step += 1;
        }
        // … and if the density there still underflows, 2⁻¹⁰ of the width.
        if p <= 0.0 || p.is_nan() {
            let t = t.clamp(1.0 / 1024.0, 1.0 - 1.0 / 1024.0);
            x = unit_interval(start + width * t);
            p = self.pdf_in_unit_interval(x);
        }
        (x, p)
    }

    /// The CDF `∫₀ˣ p`, the inverse of [`Self::sample`]: `u ∈ [0, 1)` with
    /// `sample(u).0 = x`. `x` is reduced to `[0, 1]` as in [`Self::pdf`].
    #[must_use]
    pub fn invert(&self, x: f32) -> f32 {
        let x = reduce(x, self.boundary());
        let total = self.total_mass();
        if !(total > 0.0 && total <= f32::MAX) {
            return unit_interval(x);
        }
        let n = N as f32;
        let count = self.piece_count();
        // Piece holding x: bins for nearest; for linear, piece k covers
        // [(k − ½)/N, (k + ½)/N) with the half pieces at the ends.
        let s = match self.interpolation() {
            Interpolation::Nearest => x * n,
            Interpolation::Linear => x * n + 0.5,
        };
        let piece = if s > 0.0 {
            let i = s as usize;
            if i < count {
                i
            } else {
                count - 1
            }
        } else {
            0
        };
        let mut cum = 0.0;
        let mut k = 0;
        while k < piece {
            cum += self.piece_mass(k);
            k += 1;
        }
        let (start, width, a, b) = self.piece(piece);
        let t = (x - start) / width;
        cum += self.piece_mass(piece) * linear_cdf(t, a, b);
        unit_interval(cum / total)
    }

    /// `ln p(x)` of the density [`Self::from_logits`] builds from `logits`,
    /// and its gradient `∂ ln p / ∂ logits` into `grad`, through the
    /// `N · softmax` activation.
    ///
    /// With the stencil `p = (1 − f) v_i + f v_j` of [`Self::pdf`] and
    /// `∂v_k/∂l_m = v_k (δ_km − s_m)` (`s = softmax(l)`):
    ///
    /// ```text
    /// ∂ ln p / ∂ l_m = [(1 − f) v_i δ_im + f v_j δ_jm] / p − s_m
    /// ```
    ///
    /// Everything is evaluated in log space: `ln p = ln N + (m − L) − ln Σ_k
    /// e^{l_k − L} + ln[(1 − f) e^{l_i − m} + f e^{l_j − m}]`, with `L` the
    /// largest logit and `m` the largest logit among the stencil entries of
    /// non-zero weight, so `ln p` and the gradient stay finite (and accurate)
    /// even where `p` underflows to zero in `f32` (e.g. ±10³⁰ logits). Logits
    /// are sanitised as in [`Self::from_logits`]; `x` is reduced as in
    /// [`Self::pdf`]. At kinks (bin edges for nearest, centres for linear)
    /// the one-sided stencil of [`Self::pdf`] is used.
    pub fn grad_log_pdf(
        logits: &[f32; N],
        x: f32,
        interpolation: Interpolation,
        boundary: Boundary,
        grad: &mut [f32; N],
    ) -> f32 {
        let l = sanitized_logits(logits);
        let (max, log_sum) = log_sum_exp_parts(&l);
        let mut k = 0;
        while k < N {
            grad[k] = -exp(l[k] - max - log_sum);
            k += 1;
        }

        let x = reduce(x, boundary);
        let (i, j, f) = stencil::<N>(x, interpolation, boundary);
        let (ci, cj) = if i == j { (1.0, 0.0) } else { (1.0 - f, f) };
        // Largest logit among the entries that carry weight (ci > 0 or cj > 0;
        // ci + cj = 1, so at least one does).
        let m = if ci > 0.0 && cj > 0.0 {
            l[i].max(l[j])
        } else if ci > 0.0 {
            l[i]
        } else {
            l[j]
        };
        let ti = if ci > 0.0 { ci * exp(l[i] - m) } else { 0.0 };
        let tj = if cj > 0.0 { cj * exp(l[j] - m) } else { 0.0 };
        // ≥ the weight of the entry holding m, > 0.
        let local = ti + tj;
        grad[i] += ti / local;
        if cj > 0.0 {
            grad[j] += tj / local;
        }
        ln(N as f32) + (m - max) - log_sum + ln(local)
    }
}
