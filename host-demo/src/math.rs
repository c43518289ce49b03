//! Small math helpers: RNG, orthonormal frames and sampling routines.

use glam::Vec3;
use std::f32::consts::PI;

/// PCG32 random number generator (O'Neill), one per path so results are thread-count independent.
#[derive(Clone, Copy, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

/// SplitMix64 finaliser, used to derive well-mixed per-path seeds.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// Creates a generator for stream `(seed, a, b)` (e.g. pixel and sample index).
    pub fn new(seed: u64, a: u64, b: u64) -> Self {
        let s = mix64(seed ^ mix64(a ^ mix64(b)));
        let mut r = Rng {
            state: 0,
            inc: (mix64(s ^ 0xDA3E_39CB_94B9_5BDB) << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(s);
        r.next_u32();
        r
    }

    /// Next 32 random bits.
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform float in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }
}

/// Orthonormal frame with `n` as its z axis.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Tangent.
    pub s: Vec3,
    /// Bitangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// Builds a frame around the unit vector `n` (Duff et al. 2017).
    pub fn new(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }
    /// World to local.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }
    /// Local to world.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// Cosine-weighted hemisphere sample (local frame, z up); pdf is `z / pi`.
pub fn sample_cosine_hemisphere(u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk (area preserving).
pub fn sample_concentric_disk(u1: f32, u2: f32) -> (f32, f32) {
    let (x, y) = (2.0 * u1 - 1.0, 2.0 * u2 - 1.0);
    if x == 0.0 && y == 0.0 {
        return (0.0, 0.0);
    }
    let (r, phi) = if x.abs() > y.abs() {
        (x, std::f32::consts::FRAC_PI_4 * (y / x))
    } else {
        (
            y,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (x / y),
        )
    };
    (r * phi.cos(), r * phi.sin())
}

/// Uniform direction on the unit sphere.
pub fn sample_uniform_sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Power heuristic (beta = 2) weight of strategy `a` against `b`.
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && a2.is_finite() {
        a2 / (a2 + b2)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}
