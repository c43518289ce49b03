//! The single math shim of `guiding-core`.
//!
//! Every transcendental function the kernels use goes through this module, so
//! that one file decides where the math comes from: [`libm`] on the CPU (exact,
//! portable, `no_std`); in SPIR-V (`cfg(target_arch = "spirv")`, rust-gpu)
//! the inlined f32 versions below, because rust-gpu would lower libm calls
//! to GLSL.std.450 instructions whose precision Vulkan leaves loose (Mesa's
//! NIR approximates `atan` and `tan`; a GPU-vs-CPU difftest of NASG
//! sampling saw the difference on 11 of 1714 samples), and `sqrt` / `floor`, which are exact
//! there. Kernels never call `f32::exp` & co. directly.
//!
//! Next to the libm wrappers sit our own inlined, branch-free versions, for
//! the `K`-lobe loops that must vectorise (a libm call is out of line and
//! stops LLVM's vectoriser) and for latency-bound samplers: [`exp`],
//! [`exp_nonpositive`], [`expm1_inline`], [`expm1_nonpositive`],
//! [`ln_inline`], [`ln_1p_inline`], [`sin_cos_turns`] and [`atan2_turns`]
//! (f32 arithmetic and bit operations only, so they compile to SPIR-V as
//! they are; accuracy checked against `f64` in `tests/tests/math.rs`). The
//! libm wrappers keep their exact semantics for every other caller.
//!
//! Only `f32` is offered: GPU kernels must not touch `f64`.

/// π.
pub const PI: f32 = core::f32::consts::PI;
/// 2π.
pub const TWO_PI: f32 = 2.0 * core::f32::consts::PI;
/// 4π, the solid angle of the sphere.
pub const FOUR_PI: f32 = 4.0 * core::f32::consts::PI;
/// 1 / (2π).
pub const INV_TWO_PI: f32 = 0.5 * core::f32::consts::FRAC_1_PI;
/// 1 / (4π), the density of the uniform sphere.
pub const INV_FOUR_PI: f32 = 0.25 * core::f32::consts::FRAC_1_PI;
/// The largest `f32` below one, the upper end of `[0, 1)` random numbers.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON * 0.5;

/// Cody–Waite range reduction shared by the exponential family:
/// `x = n ln 2 + r` with `|r| ≤ ln 2 / 2` (ln 2 split into a high part exact
/// in a few bits and a low correction); `n` is rounded by [`round_nearest`].
/// Returns `(n, r)`.
#[inline(always)]
fn reduce_ln2(x: f32) -> (i32, f32) {
    const LOG2_E: f32 = core::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let (n, n_int) = round_nearest(x * LOG2_E);
    let r = (x - n * LN2_HI) - n * LN2_LO;
    (n_int, r)
}

/// `(round(t), round(t) as i32)` for `|t| < 2²²` (other arguments give an
/// unspecified but harmless pair; callers clamp or select around them).
///
/// On the CPU: the `1.5·2²³` trick — `t + 1.5·2²³` rounds `t` to an integer
/// in the FPU's round-to-nearest-even, subtracting it back gives the float,
/// and the integer is the low mantissa bits (no float → int conversion, which
/// does not vectorise well). In SPIR-V the trick is not safe: spirv-opt and
/// the drivers' compilers (Mesa's NIR for lavapipe) treat float arithmetic
/// as reassociable unless it is marked `NoContraction`, which rust-gpu does
/// not emit, and fold `(t + c) − c` to `t` (measured on lavapipe: `exp(−3)`
/// came out as `0.0625`). There the rounding goes through a conversion:
/// `i = trunc(t ± ½)`, which rounds halves away from zero instead of to even
/// — the reduction `|r| ≤ ½` holds either way.
#[inline(always)]
fn round_nearest(t: f32) -> (f32, i32) {
    #[cfg(not(target_arch = "spirv"))]
    {
        const ROUND: f32 = 12_582_912.0;
        let shifted = t + ROUND;
        (
            shifted - ROUND,
            shifted.to_bits().wrapping_sub(ROUND.to_bits()) as i32,
        )
    }
    #[cfg(target_arch = "spirv")]
    {
        let i = if t >= 0.0 {
            (t + 0.5) as i32
        } else {
            (t - 0.5) as i32
        };
        (i as f32, i)
    }
}

/// `e^r` for a reduced `|r| ≤ ln 2 / 2`: the Cephes `expf` polynomial,
/// evaluated by Estrin's scheme (depth 4 instead of 7, which shortens the
/// dependency chain of every lobe loop).
#[inline(always)]
fn exp_reduced(r: f32) -> f32 {
    let r2 = r * r;
    let a = 0.5 + 1.666_666_5e-1 * r;
    let b = 4.166_579_6e-2 + 8.333_452e-3 * r;
    let c = 1.398_199_9e-3 + 1.987_569_2e-4 * r;
    let p = a + r2 * (b + r2 * c);
    (p * r2 + r) + 1.0
}

/// `e^x`, within 2 ulp of the correctly rounded result (checked against `f64`
/// in the tests), `0` below `−87.34` (where `e^x` is no longer a normal `f32`),
/// `+∞` above `88.72`, NaN for NaN.
///
/// Deviation from "libm on the CPU": this one function is our own, because the
/// mixtures evaluate one `exp` per lobe and libm's `expf` is an out-of-line
/// call with branches that stops the `K`-lobe loop from vectorising. It is the
/// classic Cephes `expf`: `x = n ln 2 + r` with `|r| ≤ ln 2 / 2` (Cody–Waite
/// split of ln 2), a degree-7 polynomial for `e^r` (evaluated by Estrin's
/// scheme), and `2^n` built from the exponent bits — branch-free, so LLVM
/// turns the lobe loop into SIMD.
#[inline]
#[must_use]
pub fn exp(x: f32) -> f32 {
    const MAX_ARG: f32 = 88.722_83;
    const MIN_ARG: f32 = -87.336_55;
    // Arguments below the range are evaluated at 0 (and replaced by 0 below)
    // rather than clamped to MIN_ARG: there the result would sit at the edge of
    // the subnormal range, and every subnormal intermediate costs a microcode
    // assist — in a vectorised lobe loop, for every lane.
    let xc = if x < MIN_ARG { 0.0 } else { x.min(MAX_ARG) };
    let (n_int, r) = reduce_ln2(xc);
    let er = exp_reduced(r);
    // 2^n is applied as 2^(n/2) · 2^(n − n/2) so that both factors stay normal
    // over the whole range n ∈ [−126, 128].
    let n_half = n_int >> 1;
    let scale_a = f32::from_bits(((n_half + 127) as u32) << 23);
    let scale_b = f32::from_bits(((n_int - n_half + 127) as u32) << 23);
    let y = er * scale_a * scale_b;
    let y = if x < MIN_ARG { 0.0 } else { y };
    let y = if x > MAX_ARG { f32::INFINITY } else { y };
    // NaN in, NaN out (the clamps above would otherwise hide it).
    if x.is_nan() {
        x
    } else {
        y
    }
}

/// `e^x` for `x ≤ 0`: the same result class as [`exp`] (within 2 ulp, `0`
/// below `−87.34`, checked against `f64` in the tests) on the half-line
/// where the lobe kernels evaluate it (`e^{−κ t}`, `e^{ln G}`); positive
/// arguments are read as `0` (result `1`), NaN gives NaN.
///
/// Shorter dependency chain than [`exp`], for the latency-bound `K`-lobe
/// loops: one scale factor `2ⁿ` (`n ∈ [−126, 0]` is always normal), no
/// overflow select, and the polynomial by Estrin's scheme (depth 4 instead
/// of 7).
#[inline(always)]
#[must_use]
pub fn exp_nonpositive(x: f32) -> f32 {
    const MIN_ARG: f32 = -87.336_55;
    // Below the range: evaluated at 0 (no subnormal intermediates), replaced
    // by 0 at the end; `min` also maps NaN to 0 (restored at the end).
    let xc = if x < MIN_ARG { 0.0 } else { x.min(0.0) };
    let (n_int, r) = reduce_ln2(xc);
    let er = exp_reduced(r);
    let y = er * pow2i(n_int);
    // One select on the result path: below the range 0, NaN stays NaN (the
    // fallback is formed off the critical path).
    let fallback = if x.is_nan() { x } else { 0.0 };
    if x >= MIN_ARG {
        y
    } else {
        fallback
    }
}

/// `2^n` for an integer `n ∈ [−126, 127]`, built from the exponent bits.
#[inline(always)]
fn pow2i(n: i32) -> f32 {
    f32::from_bits(((n + 127) as u32) << 23)
}

/// `ln u + extra` for a normal positive `u` and a small `extra` (below an ulp
/// of the result; the rounding correction `e/u` of [`ln_1p_inline`]), branch-
/// free: `u = 2^k m` with `m ∈ [√½, √2)`, the Cephes `logf` polynomial
/// `f − f²/2 + f³ P(f)` of `f = m − 1`, `k ln 2` by a Cody–Waite split, and
/// `extra` added before the final roundings. No special values: zero,
/// subnormal, infinite, negative or NaN `u` give garbage (the public
/// functions select those).
#[inline(always)]
pub(crate) fn ln_normal(u: f32, extra: f32) -> f32 {
    const SQRT_HALF_BITS: u32 = 0x3f35_04f3;
    // u = 2^k · m with m ∈ [√½, √2): subtracting the bits of √½ moves the
    // exponent boundary there (the musl / ARM optimized-routines trick).
    let ix = u.to_bits().wrapping_sub(SQRT_HALF_BITS);
    let k = (ix as i32) >> 23;
    let m = f32::from_bits((ix & 0x007f_ffff) + SQRT_HALF_BITS);
    // Exact (Sterbenz: m ∈ [½, 2]).
    let f = m - 1.0;
    let kf = k as f32;
    let z = f * f;
    // P(f) by Estrin's scheme (depth 4 instead of 8 dependent steps: the
    // kernels that call this are latency-bound chains).
    let f4 = z * z;
    let q01 = 3.333_333e-1 - 2.499_999_4e-1 * f;
    let q23 = 2.000_071_4e-1 - 1.666_805_8e-1 * f;
    let q45 = 1.424_932_3e-1 - 1.242_014_1e-1 * f;
    let q67 = 1.167_699_9e-1 - 1.151_461e-1 * f;
    let r03 = q01 + q23 * z;
    let r47 = q45 + q67 * z;
    let p = (r03 + r47 * f4) + 7.037_683_6e-2 * (f4 * f4);
    let y = p * f * z + (kf * -2.121_944_4e-4 + extra);
    let y = y - 0.5 * z;
    (f + y) + kf * 0.693_359_4
}

/// Natural logarithm, inlined and branch-free: within 2 ulp of the correctly
/// rounded result over all positive `f32` (subnormals included; checked
/// against `f64` in the tests), `−∞` at `±0`, NaN below zero and for NaN,
/// `+∞` at `+∞`.
///
/// The libm-free twin of [`ln`] for loops that must vectorise (a libm call
/// is out of line and blocks it): Cephes `logf` with the exponent split by
/// bit operations; special values by selects.
#[inline]
#[must_use]
pub fn ln_inline(x: f32) -> f32 {
    // Subnormals: scale into the normal range first (2²³ exactly).
    let tiny = x < f32::MIN_POSITIVE;
    let xs = if tiny { x * 8_388_608.0 } else { x };
    let y = ln_normal(xs, 0.0);
    let y = if tiny {
        y - 23.0 * core::f32::consts::LN_2
    } else {
        y
    };
    let y = if x == f32::INFINITY { x } else { y };
    let y = if x == 0.0 { f32::NEG_INFINITY } else { y };
    // x < 0 and NaN (neither is ≥ 0).
    if x >= 0.0 {
        y
    } else {
        f32::NAN
    }
}

/// `ln(1 + x)`, inlined and branch-free: within 2 ulp of the correctly
/// rounded result for every `x > −1` (checked against `f64` in the tests),
/// `−∞` at `−1`, NaN below `−1` and for NaN, `+∞` at `+∞`, `x` itself for
/// `|x| < 2⁻²⁵` (so `±0` keep their sign).
///
/// The libm-free twin of [`ln_1p`]: `u = 1 + x` is rounded, the rounding
/// error `e = (1 + x) − u` is recovered exactly (Fast2Sum), and
/// `ln(1 + x) = ln u + ln(1 + e/u) ≈ ln u + e/u` with the Cephes logarithm
/// of [`ln_inline`].
#[inline]
#[must_use]
pub fn ln_1p_inline(x: f32) -> f32 {
    let u = 1.0 + x;
    // Fast2Sum: the larger operand first.
    let err = if x.abs() <= 1.0 {
        (1.0 - u) + x
    } else {
        (x - u) + 1.0
    };
    // u ≥ 2⁻²⁴ for x > −1 (x is then ≥ −1 + 2⁻²⁴), so u is normal; e/u is
    // below half an ulp of ln u.
    let y = ln_normal(u, err / u);
    let y = if x.abs() < 2.980_232_2e-8 { x } else { y };
    let y = if x == f32::INFINITY { x } else { y };
    let y = if x == -1.0 { f32::NEG_INFINITY } else { y };
    // x < −1 and NaN.
    if x >= -1.0 {
        y
    } else {
        f32::NAN
    }
}

/// `ln(1 + x)` without a compensated sum, for SPIR-V: [`ln_1p_inline`]
/// recovers the rounding error of `u = 1 + x` as `(1 − u) + x`, which a
/// SPIR-V compiler may fold to 0 (float arithmetic without `NoContraction`
/// is reassociable for spirv-opt and Mesa's NIR; measured on lavapipe:
/// NASG pdfs of sharp lobes off by up to 0.2 %). Here
/// `ln(1 + x) = 2 atanh(s)`, `s = x / (2 + x)`, as its odd series to `s¹⁷`
/// for `x ∈ [−½, 1]` (`|s| ≤ ⅓`, truncation below `3·10⁻¹⁰` relative),
/// which no algebraic rewrite can cancel; outside, `1 + x` is exact
/// (`x ∈ [−1, −½]`, Sterbenz) or `ln(1 + x) ≥ ln 2` absorbs its rounding,
/// and [`ln_inline`] of it is within 2 ulp. Within 3 ulp everywhere
/// (1.9 measured against `f64` over 2.4 million points in the tests); `−∞` at `−1`, NaN below `−1` and
/// for NaN, `+∞` at `+∞`, signs of zero kept.
#[inline]
#[must_use]
#[allow(clippy::manual_range_contains)] // a plain comparison for rust-gpu
pub fn ln_1p_series(x: f32) -> f32 {
    if x >= -0.5 && x <= 1.0 {
        let s = x / (2.0 + x);
        let s2 = s * s;
        let mut p = 1.0 / 17.0;
        p = p * s2 + 1.0 / 15.0;
        p = p * s2 + 1.0 / 13.0;
        p = p * s2 + 1.0 / 11.0;
        p = p * s2 + 1.0 / 9.0;
        p = p * s2 + 1.0 / 7.0;
        p = p * s2 + 1.0 / 5.0;
        p = p * s2 + 1.0 / 3.0;
        2.0 * (s + s * s2 * p)
    } else if x >= -1.0 {
        ln_inline(1.0 + x)
    } else {
        // Below −1, and NaN.
        f32::NAN
    }
}

/// `e^x − 1`, inlined and branch-free: within 2 ulp of the correctly rounded
/// result (checked against `f64` in the tests), `x` itself for `|x| < 2⁻²⁵`
/// (signs of zero kept), `−1` below `−17.4`, `+∞` above `88.72`, NaN for NaN.
///
/// The libm-free twin of [`expm1`]: `x = n ln 2 + r` as in [`exp`],
/// `e^r − 1 = r + r²/2 + r³ Q(r)` (degree-4 minimax `Q` on
/// `|r| ≤ ln 2 / 2`, relative error 10⁻⁹), then
/// `e^x − 1 = 2ⁿ (e^r − 1) + (2ⁿ − 1)`, both terms exact in `f32` for
/// `n ≤ 24` (beyond, `2ⁿ (e^r − 1 + 1)`, the `− 1` being below an ulp).
#[inline]
#[must_use]
pub fn expm1_inline(x: f32) -> f32 {
    const MAX_ARG: f32 = 88.722_83;
    // e^x < 2⁻²⁵ below this, so e^x − 1 rounds to −1.
    const MIN_ARG: f32 = -17.5;
    let xc = x.clamp(MIN_ARG, MAX_ARG);
    let (n_int, r) = reduce_ln2(xc);
    let q = 1.988_269e-4;
    let q = q * r + 1.392_617_6e-3;
    let q = q * r + 8.333_321e-3;
    let q = q * r + 4.166_655_5e-2;
    let q = q * r + 1.666_666_7e-1;
    let r2 = r * r;
    // e^r − 1, relative error ~10⁻⁹ before rounding.
    let p = r + (0.5 * r2 + r2 * r * q);
    // n ∈ [−26, 128]: 2^min(n, 24) is normal; the large-n branch scales by
    // 2^(n − 1) · 2 so that n = 128 does not overflow the factor.
    let scale = pow2i(n_int.min(24));
    let small = scale * p + (scale - 1.0);
    let large = ((1.0 + p) * 2.0) * pow2i(n_int.max(25) - 1);
    let y = if n_int > 24 { large } else { small };
    let y = if n_int == 0 { p } else { y };
    let y = if x > MAX_ARG { f32::INFINITY } else { y };
    // NaN, and the sign of zero (r + r²/2 would turn −0 into +0).
    if x.is_nan() || x == 0.0 {
        x
    } else {
        y
    }
}

/// `e^x − 1` for `x ≤ 0`: the same results as [`expm1_inline`] (within 2
/// ulp, `−1` below `−17.4`) on the half-line where the NASG kernels need it
/// (`t^b − 1` with `t ≤ 1`), with fewer selects: `n ∈ [−25, 0]`, so only the
/// `2ⁿ (e^r − 1) + (2ⁿ − 1)` reconstruction is needed. Positive arguments
/// are read as `0`; NaN gives NaN.
#[inline(always)]
#[must_use]
pub fn expm1_nonpositive(x: f32) -> f32 {
    const MIN_ARG: f32 = -17.5;
    // NaN propagates through the arithmetic and is restored by the final select.
    let xc = x.clamp(MIN_ARG, 0.0);
    let (n_int, r) = reduce_ln2(xc);
    let r2 = r * r;
    // Q(r) by Estrin's scheme.
    let q01 = 1.666_666_7e-1 + 4.166_655_5e-2 * r;
    let q23 = 8.333_321e-3 + 1.392_617_6e-3 * r;
    let q = q01 + r2 * (q23 + r2 * 1.988_269e-4);
    let p = r + (0.5 * r2 + r2 * r * q);
    let scale = pow2i(n_int);
    // n = 0: scale·p + 0 = p exactly, so no select is needed for it.
    let y = scale * p + (scale - 1.0);
    // NaN, and the sign of zero.
    if x.is_nan() || x == 0.0 {
        x
    } else {
        y
    }
}

/// `(sin 2πu, cos 2πu)`: sine and cosine of an angle given in turns, inlined
/// and branch-free, within 2 ulp, or `10⁻⁷` absolute where the result is
/// below `2⁻¹⁰` (checked against `f64` in the tests).
///
/// The reduction is exact (no `π` enters it): the quadrant `q = round(4u)`
/// and `r = u − q/4 ∈ [−⅛, ⅛]` (Sterbenz), followed by minimax polynomials
/// in `r` for `sin 2πr` (degree 7) and `cos 2πr` (degree 8), relative error
/// below 2·10⁻⁸ before rounding. For `|u| ≥ 2²⁰` (where `f32` spacing is
/// ≥ ⅛) the result is `(0, 1)`; NaN and ±∞ give NaN.
///
/// This is what every warp wants: `φ = 2πu` for `u ∈ [0, 1)` without the
/// rounding of `2πu` and without libm's out-of-line `sincosf`.
#[inline]
#[must_use]
pub fn sin_cos_turns(u: f32) -> (f32, f32) {
    // q = round(4u) (exact for |4u| < 2²²) and r = u − q/4 ∈ [−⅛, ⅛], exact:
    // u and q/4 are within a factor 2 of each other (or q = 0). Beyond
    // |u| = 2²⁰ (and for NaN, ±∞) the angle is read as 0 and fixed up below.
    let small = u.abs() < 1_048_576.0;
    let uc = if small { u } else { 0.0 };
    let (q, q_int) = round_nearest(4.0 * uc);
    let r = uc - 0.25 * q;
    // Two's complement: the low two bits are q mod 4 for negative q too.
    let quadrant = q_int as u32;
    let s2 = r * r;
    // sin 2πr = 2π r + r³ P(r²); 2π as f32 plus its rounding error, so that
    // the leading term is rounded only once.
    const TWO_PI_HI: f32 = 6.283_185_5;
    const TWO_PI_LO: f32 = -1.748_455_6e-7;
    let ps = -7.572_63e1;
    let ps = ps * s2 + 8.159_952e1;
    let ps = ps * s2 - 4.134_169_7e1;
    let sin_r = r * TWO_PI_HI + r * (TWO_PI_LO + s2 * ps);
    let pc = 5.942_410_6e1;
    let pc = pc * s2 - 8.544_882e1;
    let pc = pc * s2 + 6.493_937e1;
    let pc = pc * s2 - 1.973_920_9e1;
    let cos_r = pc * s2 + 1.0;
    // Quadrant q mod 4 from the low bits of q: swap on odd q, then flip the
    // signs by xor of the sign bits —
    // sin for q ≡ 2, 3, cos for q ≡ 1, 2.
    let odd = quadrant & 1 != 0;
    let (s, c) = if odd { (cos_r, sin_r) } else { (sin_r, cos_r) };
    let sign_s = (quadrant & 2) << 30;
    let sign_c = (quadrant.wrapping_add(1) & 2) << 30;
    let s = f32::from_bits(s.to_bits() ^ sign_s);
    let c = f32::from_bits(c.to_bits() ^ sign_c);
    if u.is_finite() {
        (s, c)
    } else {
        (f32::NAN, f32::NAN)
    }
}

/// `atan2(y, x) / 2π`: the four-quadrant arctangent in turns, in `[−½, ½]`,
/// inlined and branch-free, within 3 ulp or `4·10⁻⁹` absolute (checked
/// against `f64` in the tests; the rounding of `t` below alone contributes
/// up to half an ulp). Signed zeros and infinities follow IEEE
/// `atan2` (`atan2(±0, −0) = ±½`, `atan2(±∞, ±∞) = ±⅛, ±⅜`), NaN gives NaN.
///
/// `t = min(|x|, |y|) / max(|x|, |y|) ∈ [0, 1]`, `atan t / 2π = t P(t²)`
/// (degree-8 minimax `P`, relative error 3·10⁻⁹), then the octant by
/// selects.
#[inline]
#[must_use]
pub fn atan2_turns(y: f32, x: f32) -> f32 {
    let ax = x.abs();
    let ay = y.abs();
    let mx = ax.max(ay);
    let mn = ax.min(ay);
    let t = mn / mx;
    // 0/0 (both zero) and ∞/∞ (both infinite).
    let t = if mx == 0.0 { 0.0 } else { t };
    let t = if mn == f32::INFINITY { 1.0 } else { t };
    let s = t * t;
    let p = 4.402_677e-4;
    let p = p * s - 2.503_706e-3;
    let p = p * s + 6.706_411e-3;
    let p = p * s - 1.186_795_3e-2;
    let p = p * s + 1.689_966_2e-2;
    let p = p * s - 2.259_649_7e-2;
    let p = p * s + 3.181_805_3e-2;
    let p = p * s - 5.305_117_6e-2;
    // The constant term split into f32 and its rounding error, so that the
    // leading term t·c₀ is rounded only once.
    const C0_HI: f32 = 1.591_549_4e-1;
    const C0_LO: f32 = 3.521_743e-9;
    let a = t * C0_HI + t * (C0_LO + p * s);
    let a = if ay > ax { 0.25 - a } else { a };
    let a = if x.is_sign_negative() { 0.5 - a } else { a };
    let a = copysign(a, y);
    if x.is_nan() || y.is_nan() {
        x + y
    } else {
        a
    }
}

/// `e^x - 1`, accurate for small `|x|`.
#[inline]
#[must_use]
pub fn expm1(x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::expm1f(x)
    }
    // SPIR-V: rust-gpu lowers libm calls to GLSL.std.450, whose precision
    // Vulkan leaves loose (and Mesa's NIR approximates); the kernels use the
    // inlined f32 versions of this module, checked against f64 in the tests.
    #[cfg(target_arch = "spirv")]
    {
        expm1_inline(x)
    }
}

/// Natural logarithm.
#[inline]
#[must_use]
pub fn ln(x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::logf(x)
    }
    #[cfg(target_arch = "spirv")]
    {
        ln_inline(x)
    }
}

/// `ln(1 + x)`, accurate for small `|x|`.
#[inline]
#[must_use]
pub fn ln_1p(x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::log1pf(x)
    }
    #[cfg(target_arch = "spirv")]
    {
        ln_1p_series(x)
    }
}

/// Square root (correctly rounded, as IEEE 754 requires).
///
/// On x86-64 through the SSE intrinsic, which LLVM sees as its `sqrt`
/// operation: it inlines with the caller's encoding (VEX / EVEX inside the
/// batch kernels' AVX-512 copies) and vectorises. libm's x86 `sqrtf` is an
/// opaque inline-assembly `sqrtss`: legacy-SSE encoded, so inside AVX-512
/// code on Intel cores each call waited on the upper halves of the vector
/// registers (84 % of `vmf_pdf_avx512`'s samples under `perf`, 20 % of a
/// guided render), and no loop containing it vectorised. Same bits.
#[inline]
#[must_use]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        use core::arch::x86_64::{_mm_cvtss_f32, _mm_set_ss, _mm_sqrt_ss};
        // SAFETY: SSE is part of the x86-64 baseline; the intrinsics touch no memory.
        unsafe { _mm_cvtss_f32(_mm_sqrt_ss(_mm_set_ss(x))) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        libm::sqrtf(x)
    }
}

/// Square root of `max(x, 0)`: never NaN for a slightly negative rounding result.
#[inline]
#[must_use]
pub fn safe_sqrt(x: f32) -> f32 {
    sqrt(x.max(0.0))
}

/// `(sin x, cos x)`.
#[inline]
#[must_use]
pub fn sin_cos(x: f32) -> (f32, f32) {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::sincosf(x)
    }
    // SPIR-V: in turns (the argument's rounding adds at most ~|x|·2⁻²⁴).
    #[cfg(target_arch = "spirv")]
    {
        sin_cos_turns(x * INV_TWO_PI)
    }
}

/// Four-quadrant arctangent of `y / x`, in `[-π, π]`.
#[inline]
#[must_use]
pub fn atan2(y: f32, x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::atan2f(y, x)
    }
    #[cfg(target_arch = "spirv")]
    {
        atan2_turns(y, x) * TWO_PI
    }
}

/// Arctangent, in `[-π/2, π/2]`.
#[inline]
#[must_use]
pub fn atan(x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::atanf(x)
    }
    #[cfg(target_arch = "spirv")]
    {
        atan2_turns(x, 1.0) * TWO_PI
    }
}

/// Tangent.
#[inline]
#[must_use]
pub fn tan(x: f32) -> f32 {
    #[cfg(not(target_arch = "spirv"))]
    {
        libm::tanf(x)
    }
    #[cfg(target_arch = "spirv")]
    {
        let (s, c) = sin_cos(x);
        s / c
    }
}

/// `|x|` with the sign of `s`.
#[inline]
#[must_use]
pub fn copysign(x: f32, s: f32) -> f32 {
    // Bit operations instead of libm's out-of-line call: exact, and inlined.
    f32::from_bits((x.to_bits() & 0x7fff_ffff) | (s.to_bits() & 0x8000_0000))
}

/// Logistic sigmoid `1 / (1 + e^{-x})`, finite for every finite or infinite `x`.
#[inline]
#[must_use]
pub fn sigmoid(x: f32) -> f32 {
    // Branch on the sign so that `exp` only ever sees a non-positive argument.
    let e = exp(-x.abs());
    if x >= 0.0 {
        1.0 / (1.0 + e)
    } else {
        e / (1.0 + e)
    }
}

/// `x` clamped to `[0, ONE_MINUS_EPSILON]`, NaN to 0 (the identity on
/// `[0, 1)`): a random number kept inside `[0, 1)`.
#[inline]
#[must_use]
pub fn unit_interval(x: f32) -> f32 {
    if x > 0.0 {
        x.min(ONE_MINUS_EPSILON)
    } else {
        0.0
    }
}

/// `max(…max(max(f32::MIN, x₀), x₁)…)`: the largest entry of `x`, in index
/// order (`f32::max` skips NaN entries; `f32::MIN` for none).
#[inline]
#[must_use]
pub fn max_entry<const N: usize>(x: &[f32; N]) -> f32 {
    let mut max = f32::MIN;
    let mut k = 0;
    while k < N {
        max = max.max(x[k]);
        k += 1;
    }
    max
}

/// The stable log-sum-exp of `x` in two parts, `(m, ln Σ_k e^{x_k − m})`
/// with `m = max_k x_k` (from `f32::MIN`, each sum in index order):
/// `ln Σ_k e^{x_k} = m + ln Σ_k e^{x_k − m}`, the parts kept apart so that
/// `x_k − m − lse` (a log-softmax) subtracts the large `m` first. The sum is
/// `≥ 1`, so the logarithm is finite for finite `x`.
#[inline]
#[must_use]
pub fn log_sum_exp_parts<const N: usize>(x: &[f32; N]) -> (f32, f32) {
    let max = max_entry(x);
    let mut sum = 0.0;
    let mut k = 0;
    while k < N {
        sum += exp(x[k] - max);
        k += 1;
    }
    (max, ln(sum))
}

/// Replaces NaN by `0` and clamps to `[-limit, limit]`.
///
/// Used on raw network outputs before any activation, so that a corrupt
/// output can never produce a NaN distribution.
#[inline]
#[must_use]
pub fn sanitize(x: f32, limit: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        x.clamp(-limit, limit)
    }
}

/// `x / (1 - e^{-x})`, the ratio behind the vMF/NASG normalisers
/// (`κ / (1 - e^{-2κ})`); equals `1` at `x = 0` and is accurate for every `x ≥ 0`.
#[inline]
#[must_use]
pub fn x_over_one_minus_exp_neg(x: f32) -> f32 {
    if x < 1e-30 {
        // Series: 1 + x/2 + x²/12 + …; at this size only the constant survives.
        1.0
    } else {
        x / -expm1(-x)
    }
}

/// Largest integer `≤ x` (libm `floorf`; a native instruction on the GPU).
/// NaN and ±∞ are returned unchanged.
#[inline]
#[must_use]
pub fn floor(x: f32) -> f32 {
    libm::floorf(x)
}

/// `a + b`, saturating at `usize::MAX` — the index arithmetic of the
/// kernels that must not wrap on corrupt offsets. Written out because
/// rust-gpu 0.11 does not implement the `saturating_add` intrinsic.
#[inline]
#[must_use]
pub const fn add_saturating(a: usize, b: usize) -> usize {
    let s = a.wrapping_add(b);
    if s < a {
        usize::MAX
    } else {
        s
    }
}

/// `true` if every entry of the array is finite (no NaN, no ±∞). The
/// kernels' form: an index loop over a fixed-size array, which rust-gpu
/// compiles (a slice of a local array it cannot); on whole buffers the CPU
/// runtime uses the branch-free [`crate::optim::all_finite`] over a slice.
#[inline]
#[must_use]
pub fn all_finite<const N: usize>(v: &[f32; N]) -> bool {
    let mut i = 0;
    while i < N {
        if !v[i].is_finite() {
            return false;
        }
        i += 1;
    }
    true
}
