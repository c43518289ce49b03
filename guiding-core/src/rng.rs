//! A tiny deterministic random number generator that works the same on the
//! CPU and in a shader: 32-bit integer arithmetic only (no `u64`, which SPIR-V
//! needs the optional `Int64` capability for), no tables, no allocation.
//!
//! Two flavours of the same permutation:
//! - [`pcg_hash`] / [`hash2`] / [`uniform_at`]: counter-based ("stateless")
//!   random numbers, `value = f(seed, index)`. Any element can be drawn
//!   independently of the others, so a buffer is initialised in parallel (one
//!   GPU invocation per parameter) with the same values as the sequential CPU
//!   loop. [`crate::mlp::Mlp::init`] uses this.
//! - [`Rng`]: a sequential PCG generator whose 4-byte state is `#[repr(C)]` +
//!   [`Pod`], so it can live in a GPU buffer (one per pixel or path) and be
//!   carried between kernel launches.
//!
//! Both are PCG-RXS-M-XS 32/32 (O'Neill 2014, *PCG: A Family of Simple Fast
//! Space-Efficient Statistically Good Algorithms for Random Number
//! Generation*, §6.3.4): a 32-bit LCG (multiplier 747 796 405, increment
//! 2 891 336 453) followed by the random-xorshift / multiply / xorshift output
//! permutation. [`pcg_hash`] is the one-round hash that Jarzynski & Olano
//! (2020, *Hash Functions for GPU Rendering*, JCGT 9(3)) recommend as the best
//! speed/quality trade-off among 32-bit GPU hashes. The period of [`Rng`] is
//! 2³², plenty for per-path sampling; it is **not** a cryptographic or
//! high-dimensional-quality generator (tests use their own 64-bit PCG32).

use bytemuck::{Pod, Zeroable};

/// LCG multiplier of PCG 32/32.
const PCG_MULTIPLIER: u32 = 747_796_405;
/// LCG increment of PCG 32/32.
const PCG_INCREMENT: u32 = 2_891_336_453;
/// Multiplier of the RXS-M-XS output permutation.
const RXS_M_XS_MULTIPLIER: u32 = 277_803_737;

/// The RXS-M-XS output permutation of one 32-bit LCG state (a bijection of
/// `u32`).
#[inline]
#[must_use]
fn rxs_m_xs(state: u32) -> u32 {
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(RXS_M_XS_MULTIPLIER);
    (word >> 22) ^ word
}

/// PCG hash (Jarzynski & Olano 2020): one LCG step of `input` followed by the
/// RXS-M-XS permutation. A bijection of `u32`: distinct inputs never collide.
#[inline]
#[must_use]
pub fn pcg_hash(input: u32) -> u32 {
    rxs_m_xs(
        input
            .wrapping_mul(PCG_MULTIPLIER)
            .wrapping_add(PCG_INCREMENT),
    )
}

/// Hash of a `(seed, index)` pair: `pcg_hash(index + pcg_hash(seed))`
/// (wrapping add). For a fixed seed it is a bijection of `index`, so the
/// values of one stream never repeat within 2³² indices; different seeds
/// give streams that are offset by a pseudo-random amount in the same
/// 2³²-cycle.
#[inline]
#[must_use]
pub fn hash2(seed: u32, index: u32) -> u32 {
    pcg_hash(index.wrapping_add(pcg_hash(seed)))
}

/// The top 24 bits of `bits` as a float in `[0, 1)`: `(bits >> 8) · 2⁻²⁴`.
/// Every value is exactly representable, the largest is `1 − 2⁻²⁴`.
#[inline]
#[must_use]
pub fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// The top 23 bits of `bits` as a float in `(−1, 1)`, symmetric about zero:
/// `(2k + 1 − 2²³) · 2⁻²³` for `k = bits >> 9`, i.e. the midpoints of 2²³
/// equal cells. Exactly representable and exactly zero-mean over all `k` (a
/// `2u − 1` of [`unit_f32`] would have mean `−2⁻²⁴` and include `−1`).
#[inline]
#[must_use]
pub fn symmetric_unit_f32(bits: u32) -> f32 {
    ((bits >> 9) as f32 * 2.0 + (1.0 - 8_388_608.0)) * (1.0 / 8_388_608.0)
}

/// Counter-based uniform in `[0, 1)`: [`unit_f32`] of [`hash2`]`(seed, index)`.
#[inline]
#[must_use]
pub fn uniform_at(seed: u32, index: u32) -> f32 {
    unit_f32(hash2(seed, index))
}

/// Sequential PCG-RXS-M-XS 32/32 generator.
///
/// `repr(C)`, [`Pod`], 4 bytes: the whole state is one `u32`, so an array of
/// generators can be uploaded to and read back from a GPU buffer. Output
/// `i` (0-based) of `Rng::new(seed)` is `rxs_m_xs(s_i)` with
/// `s_0 = pcg_hash(seed)` and `s_{i+1} = 747 796 405 · s_i + 2 891 336 453`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Pod, Zeroable)]
pub struct Rng {
    /// Current LCG state.
    pub state: u32,
}

impl Rng {
    /// Generator for `seed`; the seed is hashed first so that consecutive
    /// seeds (pixel indices, say) start at unrelated points of the cycle.
    #[inline]
    #[must_use]
    pub fn new(seed: u32) -> Self {
        Self {
            state: pcg_hash(seed),
        }
    }

    /// Generator for a `(seed, stream)` pair, e.g. `(frame, pixel)`: starts
    /// at [`hash2`]`(seed, stream)`.
    #[inline]
    #[must_use]
    pub fn with_stream(seed: u32, stream: u32) -> Self {
        Self {
            state: hash2(seed, stream),
        }
    }

    /// Next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(PCG_MULTIPLIER).wrapping_add(PCG_INCREMENT);
        rxs_m_xs(old)
    }

    /// Uniform in `[0, 1)` with 24 random bits ([`unit_f32`]).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        unit_f32(self.next_u32())
    }

    /// Uniform in `(−1, 1)`, symmetric ([`symmetric_unit_f32`]).
    #[inline]
    pub fn next_symmetric_f32(&mut self) -> f32 {
        symmetric_unit_f32(self.next_u32())
    }
}

/// Fisher–Yates shuffle driven by `rng` (`u32` draws, reduced by Lemire's
/// multiply-shift; the tiny bias is irrelevant here): the minibatch shuffle
/// of `Field::update`, shared with GPU trainers that must draw the same
/// batches.
pub fn shuffle<T>(items: &mut [T], rng: &mut Rng) {
    let mut i = items.len();
    while i > 1 {
        let j = ((u64::from(rng.next_u32()) * i as u64) >> 32) as usize;
        i -= 1;
        items.swap(i, j);
    }
}

/// SplitMix64's finaliser (Steele et al. 2014): a bijection of `u64` that
/// mixes every input bit into every output bit, for deriving seeds and
/// streams from keys.
#[cfg(not(target_arch = "spirv"))]
#[inline]
#[must_use]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// PCG32 (XSH RR 64/32, O'Neill 2014): the 64-bit-state generator of the
/// CPU side — the renderer's per-path streams and the tests' reproducible
/// draws (period 2⁶⁴ per stream, 2⁶³ streams). Not for shaders (64-bit
/// integers need SPIR-V's optional `Int64`); they use [`Rng`].
#[cfg(not(target_arch = "spirv"))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

#[cfg(not(target_arch = "spirv"))]
impl Pcg32 {
    /// The generator for `seed` on stream `stream` (O'Neill's
    /// `pcg32_srandom_r`).
    #[must_use]
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut rng = Self {
            state: 0,
            inc: (stream << 1) | 1,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(seed);
        rng.next_u32();
        rng
    }

    /// A generator keyed by `(seed, a, b)` (e.g. a render seed, a pixel and
    /// a sample index): seed `s = mix64(seed ⊕ mix64(a ⊕ mix64(b)))` on
    /// stream `mix64(s ⊕ 0xDA3E39CB94B95BDB)`, so nearby keys give
    /// unrelated streams.
    #[must_use]
    pub fn from_keys(seed: u64, a: u64, b: u64) -> Self {
        let s = mix64(seed ^ mix64(a ^ mix64(b)));
        Self::new(s, mix64(s ^ 0xDA3E_39CB_94B9_5BDB))
    }

    /// Next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in `[0, 1)` with 24 random bits ([`unit_f32`]: every value
    /// exactly representable).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        unit_f32(self.next_u32())
    }

    /// Uniform in `[0, 1)` with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        let hi = u64::from(self.next_u32());
        let lo = u64::from(self.next_u32());
        (((hi << 32) | lo) >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// Two uniforms in `[0, 1)`.
    pub fn next_vec2(&mut self) -> glam::Vec2 {
        glam::Vec2::new(self.next_f32(), self.next_f32())
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }
}
