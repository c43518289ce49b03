//! Densities and samples of many decoded mixtures at once: the CPU path of a
//! wavefront's guide samples and pdfs (the embedding crate's
//! `sample_decoded` / `pdf_decoded`), bit for bit the per-lane
//! [`VmfMixture::pdf`] / [`NasgMixture::pdf`] / `sample`, which stay the
//! reference and the shaders' path.
//!
//! ## Why a block kernel
//!
//! One mixture density is `K` lobe terms, each a chain of dependent
//! operations (NASG: the local frame, three divisions, a logarithm and two
//! exponentials, about a hundred operations; vMF: a chord and one
//! exponential). Vectorised over its 8 lobes, one density is a single
//! latency-bound chain, and a loop of calls overlaps little of it (a NASG
//! density is ~500 instructions, more than the out-of-order window). Here
//! [`PAIRS`] `= 8` (mixture, direction) pairs are laid out lane-major, lobe
//! `k` of pair `b` at lane `b · K + k`, so one loop runs the whole chain over
//! 64 independent lanes with the widest vectors the CPU has; each pair's `K`
//! terms are then summed pairwise as the reference does. The same operations
//! in the same order per lane (Rust never contracts into FMA), so every
//! variant (AVX-512F, AVX2, the baseline) gives the reference's bits.
//!
//! Measured (`benches/distributions.rs`, one thread, this repository's
//! 2-core AMD EPYC Zen 4): see `docs/results.md` and, for the block kernels
//! against the per-lane loop, `docs/architecture.md` ("A cached vertex runs no network").

use crate::factorised::square_from_direction;
use crate::lobe::nasg::{log_g_local, unit_direction};
use crate::lobe::DirectionSample;
use crate::math::{exp, exp_nonpositive, sqrt};
use crate::mixture::nasg::NasgMixture;
use crate::mixture::pairwise_sum;
use crate::mixture::vmf::VmfMixture;
use crate::model::batched::{DfTable, DfTableSums};
use crate::model::nasg::NASG_LOBES;
use crate::model::npm::NPM_LOBES;
use glam::{Vec2, Vec3};

/// (mixture, direction) pairs per block.
pub const PAIRS: usize = 8;
/// Lanes of a NASG block.
const NASG_LANES: usize = PAIRS * NASG_LOBES;
const _: () = assert!(
    NASG_LOBES == 8 && NPM_LOBES == 8,
    "the block helpers take 8 lobes"
);
/// Lanes of a vMF block.
const VMF_LANES: usize = PAIRS * NPM_LOBES;

/// Defines `$name` (runtime dispatch: AVX-512F, else AVX2, else the
/// baseline) over the `#[inline(always)]` body `$portable` (which calls the
/// generic kernel `$kernel`), with one `#[target_feature]` copy per
/// instruction set.
macro_rules! dispatch {
    ($(#[$doc:meta])* $name:ident, $portable:ident = $kernel:ident, $avx512:ident, $avx2:ident,
     ($($arg:ident: $ty:ty),*)) => {
        $(#[$doc])*
        pub fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                if std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx2")
                {
                    // SAFETY: AVX-512F and AVX2 support was just checked.
                    unsafe { $avx512($($arg),*) };
                    return;
                }
                if std::is_x86_feature_detected!("avx2") {
                    // SAFETY: AVX2 support was just checked.
                    unsafe { $avx2($($arg),*) };
                    return;
                }
            }
            $portable($($arg),*);
        }

        #[doc = concat!("[`", stringify!($name), "`] for the baseline instruction set ")]
        /// (public so the tests compare every variant).
        ///
        /// # Panics
        #[doc = concat!("As [`", stringify!($name), "`].")]
        #[inline(always)]
        pub fn $portable($($arg: $ty),*) {
            $kernel($($arg),*);
        }

        /// The AVX-512F copy of the baseline body (public so the tests run
        /// every variant the CPU has).
        ///
        /// # Safety
        /// The CPU must support AVX-512F and AVX2.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx2")]
        pub unsafe fn $avx512($($arg: $ty),*) {
            $portable($($arg),*);
        }

        /// The AVX2 copy of the baseline body (public for the tests).
        ///
        /// # Safety
        /// The CPU must support AVX2.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        pub unsafe fn $avx2($($arg: $ty),*) {
            $portable($($arg),*);
        }
    };
}

dispatch!(
    /// `out[i] = mixtures[lanes[i]].pdf(directions[i])`, bit for bit (see the
    /// [module docs](self)).
    ///
    /// # Panics
    /// If the slices differ in length or a lane is out of range.
    nasg_pdf_batch,
    nasg_pdf_portable = pdf_blocks,
    nasg_pdf_avx512,
    nasg_pdf_avx2,
    (mixtures: &[NasgMixture<NASG_LOBES>], lanes: &[u32], directions: &[Vec3], out: &mut [f32])
);

dispatch!(
    /// `out[i] = mixtures[lanes[i]].sample(u[i])`, bit for bit: the
    /// directions one by one, their densities by blocks.
    ///
    /// # Panics
    /// If the slices differ in length or a lane is out of range.
    nasg_sample_batch,
    nasg_sample_portable = sample_blocks,
    nasg_sample_avx512,
    nasg_sample_avx2,
    (mixtures: &[NasgMixture<NASG_LOBES>], lanes: &[u32], u: &[Vec2], out: &mut [DirectionSample])
);

dispatch!(
    /// `out[i] = mixtures[lanes[i]].pdf(directions[i])`, bit for bit.
    ///
    /// # Panics
    /// If the slices differ in length or a lane is out of range.
    vmf_pdf_batch,
    vmf_pdf_portable = pdf_blocks,
    vmf_pdf_avx512,
    vmf_pdf_avx2,
    (mixtures: &[VmfMixture<NPM_LOBES>], lanes: &[u32], directions: &[Vec3], out: &mut [f32])
);

dispatch!(
    /// `out[i] = mixtures[lanes[i]].sample(u[i])`, bit for bit.
    ///
    /// # Panics
    /// If the slices differ in length or a lane is out of range.
    vmf_sample_batch,
    vmf_sample_portable = sample_blocks,
    vmf_sample_avx512,
    vmf_sample_avx2,
    (mixtures: &[VmfMixture<NPM_LOBES>], lanes: &[u32], u: &[Vec2], out: &mut [DirectionSample])
);

/// A mixture family with a block kernel: how a block lays out its lanes and
/// evaluates its terms, and the per-lane parts of the reference `pdf` and
/// `sample` around them.
trait Blocked: Sized {
    /// The lane-major inputs and terms of one block; its default is zeroed
    /// (made once per call: in a last, partial block the unused lanes keep
    /// the previous block's values, whose terms are computed and never
    /// summed).
    type Scratch: Default;
    /// The unit direction the reference `pdf` evaluates at `d`.
    fn unit(d: Vec3) -> Vec3;
    /// The reference's value where it does not evaluate at [`Self::unit`]
    /// (vMF: a degenerate direction), else `None`.
    fn special(&self, d: Vec3) -> Option<f32>;
    /// The direction the reference `sample` draws.
    fn direction(&self, u: Vec2) -> Vec3;
    /// Copies the lobe fields of `m` and the unit direction `u` into
    /// pair `b`'s lanes of the block ([`load_pair`]).
    fn load(m: &Self, scratch: &mut Self::Scratch, b: usize, u: Vec3);
    /// The reference's terms over the block's lanes, then the pairwise sum
    /// of each of the first `out.len()` pairs into `out`.
    fn terms(scratch: &mut Self::Scratch, out: &mut [f32]);
}

/// The densities of up to [`PAIRS`] pairs (`lanes[b]`'s mixture at the
/// unit direction `unit[b]`) into `out[..lanes.len()]`: every pair loaded,
/// then [`Blocked::terms`].
#[inline(always)]
fn block<M: Blocked>(
    mixtures: &[M],
    lanes: &[u32],
    unit: &[Vec3; PAIRS],
    scratch: &mut M::Scratch,
    out: &mut [f32],
) {
    let n = lanes.len().min(PAIRS);
    for (b, &lane) in lanes[..n].iter().enumerate() {
        M::load(&mixtures[lane as usize], scratch, b, unit[b]);
    }
    M::terms(scratch, &mut out[..n]);
}

/// Asserts the shared length contract of the batch functions.
fn check_lengths(lanes: usize, inputs: usize, outputs: usize) {
    assert!(
        lanes == inputs && lanes == outputs,
        "{lanes} lanes, {inputs} inputs, {outputs} outputs"
    );
}

/// The densities of a batch, block by block.
#[inline(always)]
fn pdf_blocks<M: Blocked>(mixtures: &[M], lanes: &[u32], directions: &[Vec3], out: &mut [f32]) {
    check_lengths(lanes.len(), directions.len(), out.len());
    let mut scratch = M::Scratch::default();
    let mut unit = [Vec3::ZERO; PAIRS];
    for (j, ((l, d), o)) in lanes
        .chunks(PAIRS)
        .zip(directions.chunks(PAIRS))
        .zip(out.chunks_mut(PAIRS))
        .enumerate()
    {
        prefetch_block(mixtures, lanes, j + 1);
        for (u, &d) in unit.iter_mut().zip(d) {
            *u = M::unit(d);
        }
        block(mixtures, l, &unit, &mut scratch, o);
        for ((o, &lane), &d) in o.iter_mut().zip(l).zip(d) {
            if let Some(p) = mixtures[lane as usize].special(d) {
                *o = p;
            }
        }
    }
}

/// The samples of a batch: directions lane by lane, densities by blocks. As
/// the reference `sample`, the sampled direction (unit up to rounding) is
/// evaluated as it is.
#[inline(always)]
fn sample_blocks<M: Blocked>(
    mixtures: &[M],
    lanes: &[u32],
    u: &[Vec2],
    out: &mut [DirectionSample],
) {
    check_lengths(lanes.len(), u.len(), out.len());
    let mut scratch = M::Scratch::default();
    let mut dirs = [Vec3::ZERO; PAIRS];
    let mut pdfs = [0.0f32; PAIRS];
    for (j, ((l, u), o)) in lanes
        .chunks(PAIRS)
        .zip(u.chunks(PAIRS))
        .zip(out.chunks_mut(PAIRS))
        .enumerate()
    {
        prefetch_block(mixtures, lanes, j + 1);
        for ((d, &lane), &ub) in dirs.iter_mut().zip(l).zip(u) {
            *d = mixtures[lane as usize].direction(ub);
        }
        block(mixtures, l, &dirs, &mut scratch, &mut pdfs);
        for ((o, &d), &p) in o.iter_mut().zip(&dirs).zip(&pdfs) {
            *o = DirectionSample {
                direction: d,
                pdf: p,
            };
        }
    }
}

/// Fetches the mixtures of block `j` (a guide cache's thousands of
/// mixtures are megabytes; the block before waits on them otherwise).
#[inline(always)]
fn prefetch_block<M>(mixtures: &[M], lanes: &[u32], j: usize) {
    let lines = core::mem::size_of::<M>().div_ceil(64);
    for &l in lanes.iter().skip(j * PAIRS).take(PAIRS) {
        if let Some(m) = mixtures.get(l as usize) {
            prefetch_lines(m, lines);
        }
    }
}

/// Copies lane `b`'s mixture fields and direction into the block's
/// lane-major arrays (`K` lanes from `b · K`).
#[inline(always)]
fn load_pair<const LANES: usize, const F: usize, const FIELDS: usize>(
    block: &mut [[f32; LANES]; F],
    b: usize,
    fields: [&[f32; 8]; FIELDS],
    u: Vec3,
) {
    let s = b * 8..(b + 1) * 8;
    for (dst, src) in block.iter_mut().zip(fields) {
        dst[s.clone()].copy_from_slice(src);
    }
    block[FIELDS][s.clone()].fill(u.x);
    block[FIELDS + 1][s.clone()].fill(u.y);
    block[FIELDS + 2][s].fill(u.z);
}

/// Each pair's pairwise sum of its `K = 8` terms (the reference's order).
#[inline(always)]
fn sum_pairs<const LANES: usize>(terms: &[f32; LANES], out: &mut [f32]) {
    for (b, o) in out.iter_mut().enumerate() {
        let mut t = [0.0f32; 8];
        t.copy_from_slice(&terms[b * 8..(b + 1) * 8]);
        *o = pairwise_sum(&mut t);
    }
}

/// The lane-major arrays of one block: `F` lobe fields (the direction's
/// three last) and the terms.
struct BlockScratch<const LANES: usize, const F: usize> {
    fields: [[f32; LANES]; F],
    terms: [f32; LANES],
}

impl<const LANES: usize, const F: usize> Default for BlockScratch<LANES, F> {
    #[inline(always)]
    fn default() -> Self {
        Self {
            fields: [[0.0; LANES]; F],
            terms: [0.0; LANES],
        }
    }
}

/// A NASG block: weight, x (3), y (3), z (3), λ, a, ε, −ln K, the direction (3).
type NasgScratch = BlockScratch<NASG_LANES, 17>;

impl Blocked for NasgMixture<NASG_LOBES> {
    type Scratch = NasgScratch;

    #[inline(always)]
    fn unit(d: Vec3) -> Vec3 {
        // As `NasgMixture::pdf`: an invalid direction is (0, 0, 0).
        unit_direction(d).0
    }

    #[inline(always)]
    fn special(&self, _: Vec3) -> Option<f32> {
        None
    }

    #[inline(always)]
    fn direction(&self, u: Vec2) -> Vec3 {
        self.sample_direction(u)
    }

    #[inline(always)]
    fn load(m: &Self, f: &mut NasgScratch, b: usize, u: Vec3) {
        let fields = [
            &m.weight,
            &m.x_x,
            &m.x_y,
            &m.x_z,
            &m.y_x,
            &m.y_y,
            &m.y_z,
            &m.z_x,
            &m.z_y,
            &m.z_z,
            &m.lambda,
            &m.a,
            &m.epsilon,
            &m.log_norm,
        ];
        load_pair(&mut f.fields, b, fields, u);
    }

    /// The terms of `NasgMixture::pdf_unit`.
    #[inline(always)]
    fn terms(f: &mut NasgScratch, out: &mut [f32]) {
        let [w, x_x, x_y, x_z, y_x, y_y, y_z, z_x, z_y, z_z, lambda, a, epsilon, log_norm, ux, uy, uz] =
            &f.fields;
        let terms = &mut f.terms;
        for l in 0..NASG_LANES {
            let vx = ux[l] * x_x[l] + uy[l] * x_y[l] + uz[l] * x_z[l];
            let vy = ux[l] * y_x[l] + uy[l] * y_y[l] + uz[l] * y_z[l];
            let vz = ux[l] * z_x[l] + uy[l] * z_y[l] + uz[l] * z_z[l];
            let log_pdf = log_g_local(vx, vy, vz, lambda[l], a[l], epsilon[l]) + log_norm[l];
            let p = w[l] * exp(log_pdf);
            // Unused lanes have weight 0: exactly 0, whatever their arithmetic gave.
            terms[l] = if w[l] > 0.0 { p } else { 0.0 };
        }
        sum_pairs(terms, out);
    }
}

/// A vMF block: weight, mean (3), κ, normaliser, the direction (3).
type VmfScratch = BlockScratch<VMF_LANES, 9>;

/// Whether `VmfMixture::pdf` normalises `d` (else it has a formula of its own).
#[inline(always)]
fn vmf_regular(d: Vec3) -> bool {
    let len2 = d.length_squared();
    len2 > 0.0 && len2 <= f32::MAX
}

impl Blocked for VmfMixture<NPM_LOBES> {
    type Scratch = VmfScratch;

    #[inline(always)]
    fn unit(d: Vec3) -> Vec3 {
        if vmf_regular(d) {
            d * (1.0 / sqrt(d.length_squared()))
        } else {
            Vec3::ZERO
        }
    }

    #[inline(always)]
    fn special(&self, d: Vec3) -> Option<f32> {
        (!vmf_regular(d)).then(|| self.pdf(d))
    }

    #[inline(always)]
    fn direction(&self, u: Vec2) -> Vec3 {
        self.sample_direction(u)
    }

    #[inline(always)]
    fn load(m: &Self, f: &mut VmfScratch, b: usize, u: Vec3) {
        let fields = [
            &m.weight, &m.mean_x, &m.mean_y, &m.mean_z, &m.kappa, &m.norm,
        ];
        load_pair(&mut f.fields, b, fields, u);
    }

    /// The terms of `VmfMixture::pdf_unit`.
    #[inline(always)]
    fn terms(f: &mut VmfScratch, out: &mut [f32]) {
        let [w, mx, my, mz, kappa, norm, ux, uy, uz] = &f.fields;
        let terms = &mut f.terms;
        for l in 0..VMF_LANES {
            let dx = ux[l] - mx[l];
            let dy = uy[l] - my[l];
            let dz = uz[l] - mz[l];
            let half_chord2 = 0.5 * (dx * dx + dy * dy + dz * dz);
            terms[l] = w[l] * norm[l] * exp_nonpositive(-kappa[l] * half_chord2);
        }
        sum_pairs(terms, out);
    }
}

/// Lanes a table batch fetches ahead.
const AHEAD: usize = 8;

/// Asks the CPU to fetch the cache line at `p` (a hint; no effect where the
/// architecture has none). Public for the embedding crate's guide cache,
/// whose lookups wait on memory the same way.
#[inline(always)]
pub fn prefetch<T>(p: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults and reads nothing the program sees.
    unsafe {
        use core::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>(core::ptr::from_ref(p).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Fetches the first `lines` cache lines of `p`.
#[inline(always)]
fn prefetch_lines<T>(p: &T, lines: usize) {
    let bytes = core::ptr::from_ref(p).cast::<u8>();
    for k in 0..lines.min(core::mem::size_of::<T>().div_ceil(64)) {
        // SAFETY: within the object (`k · 64 < size_of::<T>()`).
        prefetch(unsafe { &*bytes.add(64 * k) });
    }
}

/// `out[i] = tables[lanes[i]].pdf(directions[i])`, bit for bit: the square
/// points first, then each lane's marginal and row fetched eight lanes
/// early (a guide cache's tables are megabytes: a lone lookup waits on
/// memory).
///
/// # Panics
/// If the slices differ in length or a lane is out of range.
pub fn table_pdf_batch(tables: &[DfTable], lanes: &[u32], directions: &[Vec3], out: &mut [f32]) {
    check_lengths(lanes.len(), directions.len(), out.len());
    let n = lanes.len();
    let eps: std::vec::Vec<Vec2> = directions
        .iter()
        .map(|&d| square_from_direction(d))
        .collect();
    for i in 0..n {
        if i + AHEAD < n {
            let t = &tables[lanes[i + AHEAD] as usize];
            let e = eps[i + AHEAD];
            prefetch_lines(&t.marginal, 3);
            prefetch_lines(&t.conditionals[DfTable::row(e.x)], 2);
        }
        out[i] = tables[lanes[i] as usize].pdf_at_square(eps[i]);
    }
}

/// `out[i] = tables[lanes[i]].sample(u[i])`, bit for bit, from the tables'
/// running sums `sums[lanes[i]]` ([`DfTable::running_sums`]), in two passes
/// (the marginals, then the rows), each fetching eight lanes early.
///
/// # Panics
/// If the slices differ in length (`sums` and `tables` too) or a lane is out
/// of range.
pub fn table_sample_batch(
    tables: &[DfTable],
    sums: &[DfTableSums],
    lanes: &[u32],
    u: &[Vec2],
    out: &mut [DirectionSample],
) {
    check_lengths(lanes.len(), u.len(), out.len());
    assert_eq!(tables.len(), sums.len(), "one set of sums per table");
    let n = lanes.len();
    let mut first = std::vec::Vec::with_capacity(n);
    for i in 0..n {
        if i + AHEAD < n {
            let l = lanes[i + AHEAD] as usize;
            prefetch_lines(&tables[l].marginal, 3);
            prefetch_lines(&sums[l].marginal, 3);
        }
        let l = lanes[i] as usize;
        first.push(tables[l].sample_first_with(&sums[l], u[i].x));
    }
    for i in 0..n {
        if i + AHEAD < n {
            let l = lanes[i + AHEAD] as usize;
            let r = DfTable::row(first[i + AHEAD].0);
            prefetch_lines(&tables[l].conditionals[r], 2);
            prefetch_lines(&sums[l].rows[r], 2);
        }
        let (e1, p1) = first[i];
        let l = lanes[i] as usize;
        out[i] = tables[l].sample_second_with(&sums[l], e1, p1, u[i].y);
    }
}
