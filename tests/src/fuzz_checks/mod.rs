//! Properties checked on inputs decoded from arbitrary bytes. The cargo-fuzz
//! targets in `fuzz/` call these functions, and the stable test
//! `tests/fuzz_corpus.rs` replays the checked-in corpus (and a deterministic
//! generated set) through them, so every input a fuzzer ever found stays a
//! regression test without a nightly toolchain.
//!
//! Each check panics (the fuzzer's crash signal) when a property fails.
//!
//! Targets: [`distributions`], [`lobes_extreme`] (here), [`training_step`]
//! (`training.rs`), [`scene_parser`] (`scene.rs`), [`c_api`] (`c_api.rs`:
//! call sequences on the C ABI of `guiding-capi`). A new target needs its
//! check here, a `fuzz/fuzz_targets/<name>.rs` calling it, a `[[bin]]` in
//! `fuzz/Cargo.toml`, seeds in `fuzz/corpus/<name>/` and its replay in
//! `tests/tests/fuzz_corpus.rs` (whose `every_target_is_replayed` test fails
//! until the replay exists).

mod c_api;
mod scene;
mod training;

pub use c_api::{c_api, MAX_OPS as C_API_MAX_OPS};

pub use scene::{check_scene, scene_input, scene_parser, split_scene_input, SCENE_INPUT_LIMIT};
pub use training::{training_step, TrainingInput, TrainingOutcome};

use glam::{Vec2, Vec3};
use guiding_core::factorised::FactorisedTable;
use guiding_core::lobe::nasg::NasgLobe;
use guiding_core::lobe::vmf::VmfLobe;
use guiding_core::lobe::DirectionSample;
use guiding_core::math::ONE_MINUS_EPSILON;
use guiding_core::mixture::nasg::{NasgMixture, NASG_RAW_PER_LOBE};
use guiding_core::mixture::vmf::{VmfMixture, VMF_RAW_PER_LOBE};
use guiding_core::pdf1d::Interpolation;

/// Reads typed values from fuzzer bytes; past the end it yields zeros, so any
/// input length is valid.
pub struct ByteReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> ByteReader<'a> {
    /// Reader over `data`.
    #[must_use]
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    /// Next byte (0 past the end).
    pub fn byte(&mut self) -> u8 {
        let b = self.data.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }

    /// Next 4 bytes as a little-endian `u32`.
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.byte(), self.byte(), self.byte(), self.byte()])
    }

    /// Next 4 bytes reinterpreted as an `f32`: every bit pattern, NaNs,
    /// infinities and subnormals included.
    pub fn any_f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }

    /// A random number in `[0, 1)` (24 bits).
    pub fn unit(&mut self) -> f32 {
        (self.u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// A `[0, 1)²` sample point; sometimes pushed to the edges 0 and 1 − 2⁻²⁴.
    pub fn sample_point(&mut self) -> Vec2 {
        let mode = self.byte();
        let edge = |bit: u8, v: f32| match (mode >> bit) & 3 {
            1 => 0.0,
            2 => ONE_MINUS_EPSILON,
            _ => v,
        };
        let (x, y) = (self.unit(), self.unit());
        Vec2::new(edge(0, x), edge(2, y))
    }

    /// An arbitrary direction (not necessarily unit, possibly zero or NaN).
    pub fn any_direction(&mut self) -> Vec3 {
        Vec3::new(self.any_f32(), self.any_f32(), self.any_f32())
    }
}

/// Huge magnitudes, `f32::MAX`, the infinities and NaN: the far end of every
/// special-value table of the fuzz checks.
pub const FAR_ENDS: [f32; 6] = [
    1e30,
    -1e30,
    f32::MAX,
    f32::INFINITY,
    f32::NEG_INFINITY,
    f32::NAN,
];

/// A special-value table: `head`, [`FAR_ENDS`], `tail`. Sixteen entries, as
/// a nibble of fuzzer bytes indexes it (so the order is part of what a
/// corpus input means).
#[must_use]
pub const fn special_values<const H: usize, const T: usize>(
    head: [f32; H],
    tail: [f32; T],
) -> [f32; 16] {
    assert!(H + FAR_ENDS.len() + T == 16, "a table has 16 entries");
    let mut table = [0.0; 16];
    let mut i = 0;
    while i < 16 {
        table[i] = if i < H {
            head[i]
        } else if i < H + FAR_ENDS.len() {
            FAR_ENDS[i - H]
        } else {
            tail[i - H - FAR_ENDS.len()]
        };
        i += 1;
    }
    table
}

/// Half-width of the neighbourhood over which a direction is only known in
/// f32: about two ulps of 1 on each component.
pub const DIRECTION_RESOLUTION: f32 = 2.5e-7;

/// Largest change of `pdf` between `d` and its six neighbours `d ± r e_i`
/// (`r` = [`DIRECTION_RESOLUTION`]): how much the density itself varies
/// across the f32 resolution of the direction.
pub fn density_variation(pdf: impl Fn(Vec3) -> f32, d: Vec3) -> f32 {
    let p0 = pdf(d);
    let mut variation: f32 = 0.0;
    for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
        for sign in [-1.0, 1.0] {
            let p = pdf((d + axis * (sign * DIRECTION_RESOLUTION)).normalize());
            variation = variation.max((p - p0).abs());
        }
    }
    variation
}

/// Asserts what a sample must be on its own: a finite unit direction (to
/// `10⁻⁵`) and a finite density `> 0`.
pub fn check_sample_is_valid(what: &str, s: DirectionSample) {
    let d = s.direction;
    assert!(d.is_finite(), "{what}: non-finite direction {d}");
    assert!(
        (d.length() - 1.0).abs() <= 1e-5,
        "{what}: |d| = {}",
        d.length()
    );
    assert!(
        s.pdf.is_finite() && s.pdf > 0.0,
        "{what}: sample pdf {}",
        s.pdf
    );
}

/// Asserts the properties every sample must have: [`check_sample_is_valid`],
/// and a density that equals `pdf(direction)` up to `rel_tol` plus
/// the density's own variation across the f32 resolution of the direction.
///
/// The second term is what an f32 direction can honestly promise: where a
/// lobe is narrower than ~10⁻⁵ rad (a NASG with a = 10⁵ near its antipode,
/// a table sample landing exactly on a bin edge) the sampler's exact density
/// and the density at the rounded direction differ by that much, and a fixed
/// relative tolerance would be either wrong there or meaningless elsewhere.
pub fn check_sample(what: &str, s: DirectionSample, pdf: impl Fn(Vec3) -> f32, rel_tol: f32) {
    check_sample_is_valid(what, s);
    let d = s.direction;
    let at_d = pdf(d);
    assert!(at_d.is_finite() && at_d >= 0.0, "{what}: pdf(d) = {at_d}");
    let allowed = rel_tol * at_d.max(s.pdf) + density_variation(&pdf, d);
    assert!(
        (s.pdf - at_d).abs() <= allowed,
        "{what}: sample pdf {} vs pdf(d) {at_d} (allowed {allowed})",
        s.pdf
    );
}

/// Asserts that a density evaluated at an arbitrary direction is finite and ≥ 0.
pub fn check_density(what: &str, p: f32) {
    assert!(p.is_finite() && p >= 0.0, "{what}: pdf {p}");
}

/// Fuzz target `distributions`: arbitrary raw network outputs for each
/// representation (vMF mixture, NASG mixture, DF-N, DF-L) decode to a valid
/// distribution whose samples and densities are consistent.
pub fn distributions(data: &[u8]) {
    let mut r = ByteReader::new(data);
    match r.byte() % 4 {
        0 => {
            let mut raw = [[0.0; VMF_RAW_PER_LOBE]; 8];
            for lobe in &mut raw {
                for v in lobe.iter_mut() {
                    *v = r.any_f32();
                }
            }
            let m = VmfMixture::<8>::decode(&raw);
            let s = m.sample(r.sample_point());
            check_sample("vmf mixture", s, |d| m.pdf(d), 1e-4);
            check_density("vmf mixture", m.pdf(r.any_direction()));
        }
        1 => {
            let mut raw = [[0.0; NASG_RAW_PER_LOBE]; 8];
            for lobe in &mut raw {
                for v in lobe.iter_mut() {
                    *v = r.any_f32();
                }
            }
            let m = NasgMixture::<8>::decode(&raw, r.any_f32());
            let c = m.selection_probability();
            assert!((0.0..=1.0).contains(&c), "selection probability {c}");
            let s = m.sample(r.sample_point());
            check_sample("nasg mixture", s, |d| m.pdf(d), 1e-4);
            check_density("nasg mixture", m.pdf(r.any_direction()));
        }
        kind => {
            let interpolation = if kind == 2 {
                Interpolation::Nearest
            } else {
                Interpolation::Linear
            };
            let mut marginal = [0.0; 32];
            for v in &mut marginal {
                *v = r.any_f32();
            }
            let mut conditional = [[0.0; 16]; 32];
            for row in &mut conditional {
                for v in row.iter_mut() {
                    *v = r.any_f32();
                }
            }
            let t = FactorisedTable::<32, 16>::from_logits(&marginal, &conditional, interpolation);
            let s = t.sample(r.sample_point());
            check_sample("factorised", s, |d| t.pdf(d), 1e-4);
            check_density("factorised", t.pdf(r.any_direction()));
        }
    }
}

/// Fuzz target `lobes_extreme`: single lobes with arbitrary parameters (κ, λ,
/// a, ε from any bit pattern: 0 to 10³⁰, NaN, ∞, subnormals) and arbitrary
/// axes, sampled at arbitrary points and evaluated at arbitrary directions.
pub fn lobes_extreme(data: &[u8]) {
    let mut r = ByteReader::new(data);
    if r.byte() % 2 == 0 {
        let lobe = VmfLobe::new(r.any_direction(), r.any_f32());
        let s = lobe.sample(r.sample_point());
        check_sample("vmf lobe", s, |d| lobe.pdf(d), 1e-4);
        check_density("vmf lobe", lobe.pdf(r.any_direction()));
        let u = lobe.invert(r.any_direction());
        assert!(u.is_finite(), "vmf invert: {u}");
    } else {
        let (z, x) = (r.any_direction(), r.any_direction());
        let lobe = NasgLobe::new(z, x, r.any_f32(), r.any_f32(), r.any_f32());
        let s = if r.byte() % 2 == 0 {
            lobe.sample(r.sample_point())
        } else {
            let p = r.sample_point();
            lobe.sample3(Vec3::new(p.x, p.y, r.unit()))
        };
        check_sample("nasg lobe", s, |d| lobe.pdf(d), 1e-4);
        check_density("nasg lobe", lobe.pdf(r.any_direction()));
        let u = lobe.invert(r.any_direction());
        assert!(u.is_finite(), "nasg invert: {u}");
    }
}
