//! Input encodings of the neural guiding fields: they turn a query (position,
//! direction, normal, roughness, a warped sample coordinate) into the
//! fixed-size `[f32; IN]` input of the MLP.
//!
//! - [`grid`] — multi-resolution dense feature grid over the scene box
//!   (Neural Parametric Mixtures, Dong et al. 2023, §5.1), the only encoding
//!   with trainable parameters; forward, backward and initialisation;
//! - [`spherical_harmonics`] — real orthonormal SH of a direction, tiny-cuda-nn's
//!   `SphericalHarmonics` (NPM's encoding of `ωo`);
//! - [`one_blob`] — one-blob encoding of a scalar (Müller et al. 2019, §4.3;
//!   NPM's encoding of the normal and the roughness);
//! - [`triangle_wave`] — tiny-cuda-nn's `TriangleWave` (Figueiredo et al.
//!   2025 encode the conditional's `ε1` with 12 frequencies);
//! - [`frequency`] — NeRF's sin/cos positional encoding (radiance cache).
//!
//! ## Common conventions
//!
//! Every encoder writes its `width` outputs to `out[out_offset..out_offset + width]`
//! of a caller-owned `[f32; N]` (the MLP input), so encoders are concatenated
//! by chaining offsets: each returns `out_offset + width` (wrapping add), the
//! offset of the next encoding. Slots at or past `N` are silently skipped
//! (never indexed), so a too-small array or a wrong offset truncates the
//! encoding instead of panicking — on the GPU a failed bounds check would
//! silently kill the invocation. Runtime sizes (levels, features, degree,
//! bins, frequencies) are clamped to small documented maxima, so every loop is
//! bounded.
//!
//! Inputs are sanitised (each function documents how: NaN and ±∞ map to fixed
//! values); for finite parameters every output is finite.

pub mod frequency;
pub mod grid;
pub mod one_blob;
pub mod spherical_harmonics;
pub mod triangle_wave;

pub use frequency::frequency_encode;
pub use grid::{
    grid_backward, grid_corners, grid_forward, grid_init, grid_init_value, GridConfig, GridCorners,
};
#[cfg(feature = "std")]
pub use grid::{grid_backward_traced, grid_forward_traced, GridTrace, GRID_TRACE_LEVELS};
pub use one_blob::{one_blob_encode, one_blob_encode4};
pub use spherical_harmonics::sh_encode;
pub use triangle_wave::{triangle_wave_backward, triangle_wave_encode};

/// `x` clamped to `[0, 1]` (±∞ to the ends), NaN to `0.5` (the centre): the
/// grid's normalised coordinate and the one-blob input.
#[inline]
pub(crate) fn clamp_unit(x: f32) -> f32 {
    if x >= 0.0 {
        if x <= 1.0 {
            x
        } else {
            1.0
        }
    } else if x < 0.0 {
        0.0
    } else {
        0.5
    }
}

/// Writes `value` to `out[index]` if `index < N`; otherwise does nothing.
#[inline]
pub(crate) fn write_clamped<const N: usize>(out: &mut [f32; N], index: usize, value: f32) {
    if index < N {
        out[index] = value;
    }
}

/// How many of the `count` slots `offset, offset + 1, …` of an `N`-slot
/// array lie inside it: the slots an encoding writes (or reads) from
/// `offset` on.
#[inline]
pub(crate) fn slots_inside<const N: usize>(offset: usize, count: u32) -> u32 {
    if offset >= N {
        0
    } else if (count as usize) < N - offset {
        count
    } else {
        (N - offset) as u32
    }
}
