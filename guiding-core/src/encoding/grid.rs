//! Multi-resolution dense feature grid over the scene's bounding box (Neural
//! Parametric Mixtures, Dong et al. 2023, §5.1: "multi-resolution spatial
//! embedding", the dense variant of Müller et al. 2022's grid encoding).
//!
//! ## Formula
//!
//! The query position `x` is normalised per axis to `u = clamp((x − min) /
//! (max − min), 0, 1)`. Level `l < L` has `R_l = floor(b · s^l)` cells per axis
//! (`b` = `base_resolution`, `s` = `per_level_scale`, `s^l` computed as `l`
//! successive `f32` multiplications so that every backend gets the same
//! integer) and `(R_l + 1)³` vertices, vertex 0 at `min` and vertex `R_l` at
//! `max` (vertex-aligned). With `p = u · R_l`, cell `i = min(⌊p⌋, R_l − 1)` and
//! fraction `t = p − i ∈ [0, 1]` per axis, the level's `F` features are the
//! trilinear interpolation of the cell's 8 corners:
//!
//! `f_l(x) = Σ_{c ∈ {0,1}³} w_x(c_x) w_y(c_y) w_z(c_z) · θ_l[i + c]`,
//! `w(0) = 1 − τ`, `w(1) = τ`, with `τ = t` or, when `smoothstep ≠ 0`,
//! `τ = t²(3 − 2t)` (C¹ across cell faces).
//!
//! The encoding is the concatenation `[f_0, …, f_{L−1}]`: `L·F` outputs,
//! level-major. It is linear in the parameters θ, so the backward pass
//! scatters `∂loss/∂θ_l[i + c] += w(c) · ∂loss/∂f_l` into the 8 corners of
//! each level (and is exactly the transpose of the forward pass).
//!
//! ## Parameter layout (shared with the GPU build)
//!
//! All network parameters live in ONE flat `f32` buffer; the grid is the
//! region `[offset, offset + param_count())` of it:
//!
//! ```text
//! index(l, x, y, z, f) = offset + level_offset(l) + (x + (R_l+1)·(y + (R_l+1)·z))·F + f
//! level_offset(l)      = Σ_{k<l} (R_k + 1)³ · F        (level_offset(L) = param_count())
//! ```
//!
//! with `0 ≤ x, y, z ≤ R_l` and `0 ≤ f < F`: levels one after the other
//! (coarsest first), vertices x-fastest, the `F` features of one vertex
//! contiguous. Gradients use the same layout in a buffer of the same size.
//!
//! ## Deviations
//!
//! - tiny-cuda-nn's `DenseGrid` uses `scale = b·s^l − 1` with a half-cell
//!   offset (`p = u·scale + 0.5`) and `ceil(scale) + 1` vertices; here the grid
//!   is vertex-aligned with `R_l = floor(b·s^l)` cells (the spec of this
//!   library; for NPM's preset `R = 8, 11, 15, 22, 31, 43, 61, 86`).
//! - No hashing: every level is dense (NPM's choice; the finest preset level
//!   has 87³ vertices).
//! - Runtime sizes are clamped: `L ≤` [`GRID_MAX_LEVELS`], `F ≤`
//!   [`GRID_MAX_FEATURES`], `1 ≤ R_l ≤` [`GRID_MAX_RESOLUTION`]; every function
//!   (layout, forward, backward, init) applies the same clamps, so they agree.
//!
//! ## Why runtime sizes rather than const generics
//!
//! `levels` and `features` live in the [`GridConfig`] (a uniform/storage
//! buffer on the GPU) rather than in const generics: one compiled shader serves
//! every grid shape (presets, ablations, per-scene boxes), and the config is
//! plain data that host and device share byte for byte. The only compile-time
//! size is the MLP input `[f32; N]`, and writes past `N` are skipped. The
//! cost — loop bounds unknown to the compiler — is negligible next to the 8
//! scattered memory reads per level.

use crate::encoding::{clamp_unit, write_clamped};
use crate::gradient::GradientSink;
use crate::rng::pcg_hash;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Most levels a grid may have; larger `levels` are clamped to this.
pub const GRID_MAX_LEVELS: u32 = 32;
/// Most features per vertex; larger `features` are clamped to this.
pub const GRID_MAX_FEATURES: u32 = 32;
/// Most cells per axis of one level (`(R + 1)³ = 2³⁰` vertices); larger
/// resolutions are clamped to this. A dense level this fine is already
/// 4 GiB per feature.
pub const GRID_MAX_RESOLUTION: u32 = 1023;
/// Half-width of the uniform initialisation `U(−a, a)` of [`grid_init`]
/// (instant-ngp / NPM: `10⁻⁴`).
pub const GRID_INIT_SCALE: f32 = 1e-4;

/// Shape, placement and scene box of a multi-resolution dense grid.
///
/// `repr(C)`, [`Pod`], 48 bytes, no padding: the `[f32; 3]` arrays have a
/// stride of 4 bytes (std430 / scalar block layout), and each array is
/// followed by a `u32` so the first 32 bytes also read as two 16-byte `vec4`s.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GridConfig {
    /// Lower corner of the scene box (world space).
    pub bbox_min: [f32; 3],
    /// Number of levels `L` (clamped to [`GRID_MAX_LEVELS`]).
    pub levels: u32,
    /// Upper corner of the scene box (world space).
    pub bbox_max: [f32; 3],
    /// Cells per axis of level 0, `b`.
    pub base_resolution: u32,
    /// Growth factor `s` of the resolution per level.
    pub per_level_scale: f32,
    /// Features per vertex `F` (clamped to [`GRID_MAX_FEATURES`]).
    pub features: u32,
    /// Index of the grid's first parameter in the flat parameter buffer.
    pub offset: u32,
    /// Non-zero: smoothstep `t²(3 − 2t)` on the interpolation fractions.
    pub smoothstep: u32,
}

// The GPU build relies on this exact size (and `Pod` on no padding).
const _: () = assert!(core::mem::size_of::<GridConfig>() == 48);

impl GridConfig {
    /// A grid with the given shape at `offset = 0`, linear interpolation.
    #[must_use]
    pub const fn new(
        bbox_min: [f32; 3],
        bbox_max: [f32; 3],
        levels: u32,
        base_resolution: u32,
        per_level_scale: f32,
        features: u32,
    ) -> Self {
        Self {
            bbox_min,
            levels,
            bbox_max,
            base_resolution,
            per_level_scale,
            features,
            offset: 0,
            smoothstep: 0,
        }
    }

    /// NPM's preset (Dong et al. 2023, §5.1): 8 levels, base resolution 8,
    /// per-level scale 1.405 (finest level 86 cells per axis), 4 features per
    /// vertex — 32 outputs, 4 134 012 parameters.
    #[must_use]
    pub const fn npm(bbox_min: [f32; 3], bbox_max: [f32; 3]) -> Self {
        Self::new(bbox_min, bbox_max, 8, 8, 1.405, 4)
    }

    /// The same grid starting at `offset` in the flat parameter buffer.
    #[must_use]
    pub const fn with_offset(mut self, offset: u32) -> Self {
        self.offset = offset;
        self
    }

    /// The same grid with (`true`) or without smoothstep interpolation.
    #[must_use]
    pub const fn with_smoothstep(mut self, smoothstep: bool) -> Self {
        self.smoothstep = smoothstep as u32;
        self
    }

    /// Levels actually used: `min(levels, GRID_MAX_LEVELS)`.
    #[inline]
    #[must_use]
    pub const fn level_count(&self) -> usize {
        (if self.levels < GRID_MAX_LEVELS {
            self.levels
        } else {
            GRID_MAX_LEVELS
        }) as usize
    }

    /// Features per vertex actually used: `min(features, GRID_MAX_FEATURES)`.
    #[inline]
    #[must_use]
    pub const fn feature_count(&self) -> usize {
        (if self.features < GRID_MAX_FEATURES {
            self.features
        } else {
            GRID_MAX_FEATURES
        }) as usize
    }

    /// Width of the encoding, `L · F` (32 for the NPM preset).
    #[inline]
    #[must_use]
    pub const fn output_dims(&self) -> usize {
        self.level_count() * self.feature_count()
    }

    /// Cells per axis of level `level`, `R_l = floor(b · s^l)` clamped to
    /// `[1, GRID_MAX_RESOLUTION]` (`s^l` by `l` successive `f32`
    /// multiplications; NaN → 1). Levels past [`GRID_MAX_LEVELS`] are
    /// treated as level `GRID_MAX_LEVELS`.
    #[must_use]
    pub fn level_resolution(&self, level: u32) -> u32 {
        level_walk(self, level).0
    }

    /// Start of level `level` relative to [`Self::offset`]:
    /// `Σ_{k<level} (R_k + 1)³ · F`; `level_offset(levels) = param_count()`.
    /// `level` is clamped to `levels`.
    #[must_use]
    pub fn level_offset(&self, level: u32) -> usize {
        let l = if (level as usize) < self.level_count() {
            level
        } else {
            self.level_count() as u32
        };
        level_walk(self, l).1
    }

    /// Number of grid parameters, `Σ_l (R_l + 1)³ · F` (4 134 012 for the NPM
    /// preset). On 32-bit targets (the GPU) configurations whose
    /// `offset + param_count()` exceeds `u32::MAX` cannot be addressed and
    /// are outside the domain (nothing panics: indices wrap and are
    /// bounds-checked against the buffer).
    #[must_use]
    pub fn param_count(&self) -> usize {
        level_walk(self, self.level_count() as u32).1
    }
}

/// `(R_level, level_offset(level))`, walking the levels from 0 with the same
/// `f32` arithmetic as [`grid_forward`].
fn level_walk(cfg: &GridConfig, level: u32) -> (u32, usize) {
    let target = if level < GRID_MAX_LEVELS {
        level
    } else {
        GRID_MAX_LEVELS
    };
    let f = cfg.feature_count();
    let mut scale_pow = 1.0f32;
    let mut offset = 0usize;
    let mut l = 0;
    while l < target {
        offset = offset.wrapping_add(level_size(resolution_at(cfg.base_resolution, scale_pow), f));
        scale_pow *= cfg.per_level_scale;
        l += 1;
    }
    (resolution_at(cfg.base_resolution, scale_pow), offset)
}

/// `floor(base · scale_pow)` clamped to `[1, GRID_MAX_RESOLUTION]`, NaN → 1.
#[inline]
pub(crate) const fn resolution_at(base: u32, scale_pow: f32) -> u32 {
    let r = base as f32 * scale_pow;
    if r >= GRID_MAX_RESOLUTION as f32 {
        GRID_MAX_RESOLUTION
    } else if r >= 1.0 {
        // In [1, GRID_MAX_RESOLUTION): the cast truncates, i.e. floors.
        r as u32
    } else {
        1
    }
}

/// Parameters of one level: `(R + 1)³ · F` (wrapping, see [`GridConfig::param_count`]).
#[inline]
fn level_size(resolution: u32, features: usize) -> usize {
    let n = resolution as usize + 1;
    n.wrapping_mul(n).wrapping_mul(n).wrapping_mul(features)
}

/// `clamp((x − lo) / (hi − lo), 0, 1)`, computed on halved values so that
/// boxes spanning ±`f32::MAX` do not overflow. A NaN `x` gives `0.5`
/// (the centre); `x = ±∞` clamps to the faces; a degenerate box axis
/// (`hi ≤ lo`, a NaN or infinite corner, or an extent that underflows) gives
/// `0.5` for every `x`.
#[inline]
fn unit_coordinate(x: f32, lo: f32, hi: f32) -> f32 {
    let half_extent = 0.5 * hi - 0.5 * lo;
    if !(half_extent > 0.0 && half_extent <= f32::MAX) {
        return 0.5;
    }
    clamp_unit((0.5 * x - 0.5 * lo) / half_extent)
}

/// The position normalised to the box, in `[0, 1]³` (see [`unit_coordinate`]).
#[inline]
fn unit_position(cfg: &GridConfig, position: Vec3) -> [f32; 3] {
    [
        unit_coordinate(position.x, cfg.bbox_min[0], cfg.bbox_max[0]),
        unit_coordinate(position.y, cfg.bbox_min[1], cfg.bbox_max[1]),
        unit_coordinate(position.z, cfg.bbox_min[2], cfg.bbox_max[2]),
    ]
}

/// Cell index `i ∈ [0, R − 1]` and interpolation weight `τ ∈ [0, 1]` of the
/// upper vertex along one axis, for `u ∈ [0, 1]`.
#[inline]
fn axis_cell(u: f32, resolution: u32, smoothstep: bool) -> (usize, f32) {
    let p = u * resolution as f32;
    // p ∈ [0, R] (u is sanitised), so the cast floors and is in range.
    let mut i = p as u32;
    if i >= resolution {
        i = resolution - 1;
    }
    let mut t = p - i as f32;
    t = if t > 1.0 {
        1.0
    } else if t >= 0.0 {
        t
    } else {
        0.0
    };
    if smoothstep {
        t = t * t * (3.0 - 2.0 * t);
    }
    (i as usize, t)
}

/// The 8 corners of one level's cell around a query: where their features
/// start in the flat parameter buffer and their interpolation weights.
///
/// Corner `c = dx + 2·dy + 4·dz` (`d ∈ {0, 1}`) is vertex `(i_x + dx, i_y + dy,
/// i_z + dz)`; its features are `params[index[c] .. index[c] + F]`. The
/// weights are `≥ 0` and sum to one (up to rounding). This is what a GPU
/// backward pass needs to scatter gradients with atomics in the exact layout
/// of [`grid_backward`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridCorners {
    /// Absolute index (in the flat buffer) of feature 0 of each corner.
    pub index: [usize; 8],
    /// Trilinear (or smoothstep) weight of each corner.
    pub weight: [f32; 8],
}

/// Corners of the cell of unit position `u` in a level of resolution `r`
/// whose first parameter is at `base`.
#[inline]
fn corners_at(u: &[f32; 3], r: u32, features: usize, base: usize, smooth: bool) -> GridCorners {
    let (ix, tx) = axis_cell(u[0], r, smooth);
    let (iy, ty) = axis_cell(u[1], r, smooth);
    let (iz, tz) = axis_cell(u[2], r, smooth);
    let n = r as usize + 1;
    let wx = [1.0 - tx, tx];
    let wy = [1.0 - ty, ty];
    let wz = [1.0 - tz, tz];
    let mut corners = GridCorners {
        index: [0; 8],
        weight: [0.0; 8],
    };
    let mut c = 0;
    while c < 8 {
        let dx = c & 1;
        let dy = (c >> 1) & 1;
        let dz = (c >> 2) & 1;
        let vertex = (ix + dx) + n * ((iy + dy) + n * (iz + dz));
        corners.index[c] = base.wrapping_add(vertex.wrapping_mul(features));
        corners.weight[c] = wx[dx] * wy[dy] * wz[dz];
        c += 1;
    }
    corners
}

/// The 8 corners of `position`'s cell in level `level` (see [`GridCorners`]).
/// For `level ≥ levels` the level does not exist: all weights are 0 and all
/// indices are `offset`.
#[must_use]
pub fn grid_corners(cfg: &GridConfig, position: Vec3, level: u32) -> GridCorners {
    if level as usize >= cfg.level_count() {
        return GridCorners {
            index: [cfg.offset as usize; 8],
            weight: [0.0; 8],
        };
    }
    let (r, rel) = level_walk(cfg, level);
    let u = unit_position(cfg, position);
    corners_at(
        &u,
        r,
        cfg.feature_count(),
        (cfg.offset as usize).wrapping_add(rel),
        cfg.smoothstep != 0,
    )
}

/// Forward pass: writes the `L·F` interpolated features of `position`
/// (formula in the [module docs](self)) to `out[out_offset ..]`, level-major,
/// and returns `out_offset + L·F`.
///
/// `params` is the whole flat parameter buffer; the grid is read from
/// `cfg.offset` on. Outputs at or past `N` are skipped; parameters past
/// `params.len()` read as 0. Every output is a convex combination of 8
/// parameters, so finite parameters give finite outputs bounded by
/// `max |θ|`, for every `position` (NaN → box centre, outside → clamped to
/// the box) and every box (degenerate axes → their centre).
pub fn grid_forward<const N: usize>(
    params: &[f32],
    cfg: &GridConfig,
    position: Vec3,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    let levels = cfg.level_count();
    let f = cfg.feature_count();
    if out_offset >= N {
        return out_offset.wrapping_add(levels * f);
    }
    let u = unit_position(cfg, position);
    let smooth = cfg.smoothstep != 0;
    let len = params.len();
    let mut base = cfg.offset as usize;
    let mut scale_pow = 1.0f32;
    let mut l = 0;
    while l < levels {
        let r = resolution_at(cfg.base_resolution, scale_pow);
        let corners = corners_at(&u, r, f, base, smooth);
        let out_base = out_offset.wrapping_add(l * f);
        let mut k = 0;
        while k < f {
            let o = out_base.wrapping_add(k);
            if o < N {
                let mut acc = 0.0;
                let mut c = 0;
                while c < 8 {
                    let idx = corners.index[c].wrapping_add(k);
                    if idx < len {
                        acc += corners.weight[c] * params[idx];
                    }
                    c += 1;
                }
                write_clamped(out, o, acc);
            }
            k += 1;
        }
        base = base.wrapping_add(level_size(r, f));
        scale_pow *= cfg.per_level_scale;
        l += 1;
    }
    out_offset.wrapping_add(levels * f)
}

/// Most levels a [`GridTrace`] records (grids with more take the untraced
/// path).
#[cfg(feature = "std")]
pub const GRID_TRACE_LEVELS: usize = 8;

/// One query's cell corners at every level, recorded by
/// [`grid_forward_traced`] so that [`grid_backward_traced`] scatters the
/// gradient without locating the cells again (the batched training path,
/// `std`). `levels == 0` means nothing was recorded.
#[cfg(feature = "std")]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridTrace {
    /// Absolute index of feature 0 of each corner, per level.
    index: [[u32; 8]; GRID_TRACE_LEVELS],
    /// Weight of each corner, per level.
    weight: [[f32; 8]; GRID_TRACE_LEVELS],
    /// Levels recorded (0: none, the backward pass locates the cells).
    levels: u32,
}

#[cfg(feature = "std")]
impl GridTrace {
    /// A trace with nothing recorded.
    pub const EMPTY: Self = Self {
        index: [[0; 8]; GRID_TRACE_LEVELS],
        weight: [[0.0; 8]; GRID_TRACE_LEVELS],
        levels: 0,
    };

    /// Levels recorded (0 when the forward pass took the untraced path).
    #[must_use]
    pub const fn levels(&self) -> usize {
        self.levels as usize
    }
}

/// Whether [`grid_forward_traced`] can record `cfg` for a buffer of
/// `len` floats: 4 features, at most [`GRID_TRACE_LEVELS`] levels, the whole
/// grid inside the buffer and its indices below `2³²`.
#[cfg(feature = "std")]
fn traceable(cfg: &GridConfig, len: usize) -> bool {
    let end = (cfg.offset as usize).checked_add(cfg.param_count());
    cfg.feature_count() == 4
        && cfg.level_count() <= GRID_TRACE_LEVELS
        && matches!(end, Some(e) if e <= len && e <= u32::MAX as usize)
}

/// [`grid_forward_fast`] that also records each level's corners in
/// `trace` (bit-identical outputs: the same corners, the same sums). When
/// the grid is not traceable (more than [`GRID_TRACE_LEVELS`] levels, not 4
/// features, a buffer too short or above `2³²` floats) or the outputs do not
/// fit `out`, nothing is recorded (`trace.levels() == 0`) and the result
/// is [`grid_forward_fast`]'s.
#[cfg(feature = "std")]
pub fn grid_forward_traced<const N: usize>(
    params: &[f32],
    cfg: &GridConfig,
    position: Vec3,
    out: &mut [f32; N],
    out_offset: usize,
    trace: &mut GridTrace,
) -> usize {
    const F: usize = 4;
    let levels = cfg.level_count();
    trace.levels = 0;
    if !traceable(cfg, params.len()) || out_offset + levels * F > N {
        return grid_forward_fast(params, cfg, position, out, out_offset);
    }
    let end = forward4(params, cfg, position, out, out_offset, |l, c, i, w| {
        // In range: the whole grid ends below 2³² (`traceable`).
        trace.index[l][c] = i as u32;
        trace.weight[l][c] = w;
    });
    trace.levels = levels as u32;
    end
}

/// [`grid_backward`] from the corners [`grid_forward_traced`] recorded for
/// the same `cfg` and `position`: the same additions `grad[i] += w·d` (each
/// gradient element gets at most one per query and level, so their order
/// within a query cannot change a bit), without locating the cells again.
/// Falls back to [`grid_backward`] when `trace` recorded nothing or the
/// grid does not lie inside `grad`.
#[cfg(feature = "std")]
pub fn grid_backward_traced<const N: usize>(
    cfg: &GridConfig,
    position: Vec3,
    trace: &GridTrace,
    d_out: &[f32; N],
    d_out_offset: usize,
    grad: &mut [f32],
) {
    const F: usize = 4;
    let levels = trace.levels();
    if levels == 0
        || levels != cfg.level_count()
        || !traceable(cfg, grad.len())
        || d_out_offset + levels * F > N
    {
        grid_backward(cfg, position, d_out, d_out_offset, grad);
        return;
    }
    for l in 0..levels {
        let d: &[f32; F] = d_out[d_out_offset + l * F..d_out_offset + (l + 1) * F]
            .try_into()
            .unwrap_or_else(|_| unreachable!());
        for c in 0..8 {
            let i = trace.index[l][c] as usize;
            let w = trace.weight[l][c];
            let g: &mut [f32; F] = (&mut grad[i..i + F])
                .try_into()
                .unwrap_or_else(|_| unreachable!());
            for k in 0..F {
                g[k] += w * d[k];
            }
        }
    }
}

/// [`grid_forward`] for grids of 4 features whose whole parameter region
/// lies inside `params` (checked once here, instead of per element): the
/// four features of a corner are read as one `[f32; 4]` and the corners
/// summed in the same order, `acc = ((0 + w₀θ₀) + w₁θ₁) + …`, so the
/// results are bit-identical to [`grid_forward`] while the inner loop runs
/// as one 4-wide vector. Falls back to [`grid_forward`] otherwise. CPU
/// fast path of the batched decode (`std`).
#[cfg(feature = "std")]
pub fn grid_forward_fast<const N: usize>(
    params: &[f32],
    cfg: &GridConfig,
    position: Vec3,
    out: &mut [f32; N],
    out_offset: usize,
) -> usize {
    const F: usize = 4;
    let levels = cfg.level_count();
    let end = (cfg.offset as usize).checked_add(cfg.param_count());
    let fits = matches!(end, Some(e) if e <= params.len());
    if cfg.feature_count() != F || !fits || out_offset + levels * F > N {
        return grid_forward(params, cfg, position, out, out_offset);
    }
    forward4(params, cfg, position, out, out_offset, |_, _, _, _| {})
}

/// The loop of [`grid_forward_fast`] (its checks done by the caller:
/// 4 features, the grid inside `params`, the outputs inside `out`), telling
/// `corner(level, c, index, weight)` each corner it reads.
#[cfg(feature = "std")]
#[inline(always)]
fn forward4<const N: usize>(
    params: &[f32],
    cfg: &GridConfig,
    position: Vec3,
    out: &mut [f32; N],
    out_offset: usize,
    mut corner: impl FnMut(usize, usize, usize, f32),
) -> usize {
    const F: usize = 4;
    let levels = cfg.level_count();
    let u = unit_position(cfg, position);
    let smooth = cfg.smoothstep != 0;
    let mut base = cfg.offset as usize;
    let mut scale_pow = 1.0f32;
    for l in 0..levels {
        let r = resolution_at(cfg.base_resolution, scale_pow);
        let corners = corners_at(&u, r, F, base, smooth);
        let mut acc = [0.0f32; F];
        for c in 0..8 {
            let i = corners.index[c];
            let theta: &[f32; F] = params[i..i + F]
                .try_into()
                .unwrap_or_else(|_| unreachable!());
            let w = corners.weight[c];
            for k in 0..F {
                acc[k] += w * theta[k];
            }
            corner(l, c, i, w);
        }
        let o = out_offset + l * F;
        out[o..o + F].copy_from_slice(&acc);
        base = base.wrapping_add(level_size(r, F));
        scale_pow *= cfg.per_level_scale;
    }
    out_offset + levels * F
}

/// Backward pass: for every level `l`, corner `c` and feature `k`,
/// `grad[index_c + k] += w_c · d_out[d_out_offset + l·F + k]` — the
/// transpose of [`grid_forward`] (whose outputs are linear in the
/// parameters), accumulated into the flat gradient buffer `grad` (same
/// layout and `offset` as the parameters).
///
/// Only the 8 corners of each level are touched (sparse). `d_out` slots at or
/// past `N` count as zero; gradient slots past `grad.len()` are skipped. No
/// gradient with respect to `position` is computed. Finite `d_out` gives
/// finite increments (`|Δ| ≤ |d_out|`).
pub fn grid_backward<const N: usize, G: GradientSink + ?Sized>(
    cfg: &GridConfig,
    position: Vec3,
    d_out: &[f32; N],
    d_out_offset: usize,
    grad: &mut G,
) {
    if d_out_offset >= N {
        return;
    }
    let u = unit_position(cfg, position);
    let levels = cfg.level_count();
    let f = cfg.feature_count();
    let smooth = cfg.smoothstep != 0;
    let len = grad.len();
    let mut base = cfg.offset as usize;
    let mut scale_pow = 1.0f32;
    let mut l = 0;
    while l < levels {
        let r = resolution_at(cfg.base_resolution, scale_pow);
        let corners = corners_at(&u, r, f, base, smooth);
        let d_base = d_out_offset.wrapping_add(l * f);
        let mut k = 0;
        while k < f {
            let o = d_base.wrapping_add(k);
            if o < N {
                let d = d_out[o];
                let mut c = 0;
                while c < 8 {
                    let idx = corners.index[c].wrapping_add(k);
                    if idx < len {
                        grad.add(idx, corners.weight[c] * d);
                    }
                    c += 1;
                }
            }
            k += 1;
        }
        base = base.wrapping_add(level_size(r, f));
        scale_pow *= cfg.per_level_scale;
        l += 1;
    }
}

/// Initial value of grid parameter `index` (relative to the grid's start):
/// `U(−10⁻⁴, 10⁻⁴)` (instant-ngp / NPM, [`GRID_INIT_SCALE`]), from a PCG hash
/// of `(seed, index)`: `a · (2 · h / 2²⁴ − 1)` with `h` the top 24 bits of
/// `pcg_hash(index + pcg_hash(seed))`.
///
/// A pure function of `(seed, index)`, so a GPU can initialise one parameter
/// per invocation and get exactly [`grid_init`]'s values.
#[inline]
#[must_use]
pub fn grid_init_value(seed: u32, index: u32) -> f32 {
    let h = pcg_hash(index.wrapping_add(pcg_hash(seed)));
    let u = (h >> 8) as f32 * (1.0 / 16_777_216.0);
    GRID_INIT_SCALE * (2.0 * u - 1.0)
}

/// Deterministic initialisation of the grid's region of the flat buffer:
/// `params[offset + i] = grid_init_value(seed, i)` for `i < param_count()`
/// (indices past `params.len()` are skipped). Other parameters are untouched.
pub fn grid_init(params: &mut [f32], cfg: &GridConfig, seed: u32) {
    let start = cfg.offset as usize;
    let count = cfg.param_count();
    let len = params.len();
    let mut i = 0usize;
    while i < count {
        let idx = start.wrapping_add(i);
        if idx >= len {
            break;
        }
        params[idx] = grid_init_value(seed, i as u32);
        i += 1;
    }
}
