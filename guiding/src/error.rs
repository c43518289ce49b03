//! The one error type of the facade.

use guiding_core::field::FieldError;
use std::path::PathBuf;

/// Everything that can go wrong in the facade; each variant names what the
/// caller can fix.
#[derive(Debug, thiserror::Error)]
pub enum GuidingError {
    /// A configuration value is out of its documented range.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    /// The scene bounds are not finite or not a proper box.
    #[error(
        "invalid scene bounds {min:?} .. {max:?}: need finite values with min < max on every axis"
    )]
    InvalidBounds {
        /// Lower corner given.
        min: [f32; 3],
        /// Upper corner given.
        max: [f32; 3],
    },
    /// The training runtime refused the configuration or state.
    #[error("guiding field: {0}")]
    Field(#[from] FieldError),
    /// Batch arguments of different lengths.
    #[error("batch length mismatch: {what}")]
    LengthMismatch {
        /// Which arguments disagree, with their lengths.
        what: String,
    },
    /// A decoded distribution was used with a field other than the one that
    /// decoded it, or after that field was updated.
    #[error("stale distribution: it was decoded by field {field_id} generation {generation}, but is used with field {used_id} generation {used_generation}; query again after update()")]
    StaleDistribution {
        /// Field that decoded it.
        field_id: u64,
        /// Its generation then.
        generation: u64,
        /// Field it was used with.
        used_id: u64,
        /// That field's generation now.
        used_generation: u64,
    },
    /// The field's Vulkan device is missing or failed (no loader or
    /// device, SPIR-V not built, a Vulkan call failed).
    #[error("Vulkan device: {0}")]
    Device(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A save file is not a valid guiding field (wrong magic, unsupported
    /// version, truncated, checksum mismatch, inconsistent contents).
    #[error("{path}: not a valid guiding field file: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
}

/// `Ok` if every named length equals the first; else
/// [`GuidingError::LengthMismatch`] listing them all (`"3 queries, 2 random
/// pairs, 3 outputs"`).
pub(crate) fn same_lengths(named: &[(usize, &str)]) -> Result<(), GuidingError> {
    let first = named.first().map_or(0, |&(n, _)| n);
    if named.iter().all(|&(n, _)| n == first) {
        return Ok(());
    }
    let what: Vec<String> = named
        .iter()
        .map(|(n, name)| format!("{n} {name}"))
        .collect();
    Err(GuidingError::LengthMismatch {
        what: what.join(", "),
    })
}
