//! Save files of a trained [`GuidingField`].
//!
//! # Format (version 1, all values little-endian)
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `GUIDEFLD` |
//! | 4 | format version (`u32`, 1) |
//! | 12 | representation, target, size codes (`u32` each) |
//! | 4 | selection probability (`f32`) |
//! | 24 | scene bounds min, max (`f32` × 6) |
//! | 80 | training config: Adam (learning rate, β₁, β₂, ε, L2: `f32` × 5), batch size (`u64`), steps per update (`u32`), EMA decay (`f32`), threads, gradient chunks (`u64` each), seed (`u32`), max steps (`u64`), plateau window (`u32`) and margin (`f32`), max buffered samples (`u64`), max gradient magnitude (`f32`) |
//! | 4 + m | model descriptor length `m` (`u32`) and bytes (the `repr(C)` model value) |
//! | 24 | parameter count `P`, applied steps, training updates (`u64` each) |
//! | 16 P | parameters, EMA, Adam m, Adam v (`f32` × P each) |
//! | 4 | CRC-32 (IEEE) of every byte before it |
//!
//! Saving writes a temporary file in the destination directory, syncs it and
//! renames it over the destination, so a crash never leaves a half-written
//! field under the final name. Loading checks the size, the checksum, the
//! magic and version, every code, the model descriptor against the one the
//! configuration builds, and finiteness of every value; any failure is a
//! [`GuidingError::Format`].

use crate::config::{GuidingConfig, ModelSize, Representation, Target};
use crate::error::GuidingError;
use crate::field::GuidingField;
use guiding_core::field::{FieldConfig, FieldState, PlateauConfig};
use guiding_core::optim::AdamConfig;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The 8 magic bytes every save file starts with.
pub const MAGIC: [u8; 8] = *b"GUIDEFLD";
/// The format version this library writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Largest model descriptor accepted (bytes); real ones are ~100 bytes.
const MAX_MODEL_BYTES: u32 = 4096;

struct Writer(Vec<u8>);

impl Writer {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32s(&mut self, v: &[f32]) {
        self.0.reserve(v.len() * 4);
        for x in v {
            self.f32(*x);
        }
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| format!("truncated at byte {} (wanted {n} more)", self.at))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.array()?))
    }
    fn f32s(&mut self, n: usize, what: &str) -> Result<Vec<f32>, String> {
        let bytes = self.take(
            n.checked_mul(4)
                .ok_or_else(|| format!("{what}: count {n} overflows"))?,
        )?;
        let v: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(format!("{what}[{i}] is not finite"));
        }
        Ok(v)
    }
}

/// Writes the 80 bytes of a [`FieldConfig`]: Adam (learning rate, β₁, β₂,
/// ε, L2: `f32` × 5), batch size (`u64`), steps per update (`u32`), EMA
/// decay (`f32`), threads (`u64`), gradient chunks (`u64`), seed (`u32`),
/// max steps (`u64`), plateau window (`u32`) and margin (`f32`), max
/// buffered samples (`u64`), max gradient magnitude (`f32`).
fn write_training(w: &mut Writer, t: &FieldConfig) {
    w.f32(t.adam.learning_rate);
    w.f32(t.adam.beta1);
    w.f32(t.adam.beta2);
    w.f32(t.adam.epsilon);
    w.f32(t.adam.l2_regularization);
    w.u64(t.batch_size as u64);
    w.u32(t.steps_per_update);
    w.f32(t.ema_decay);
    w.u64(t.threads as u64);
    w.u64(t.gradient_chunks as u64);
    w.u32(t.seed);
    w.u64(t.max_steps);
    w.u32(t.plateau.window);
    w.f32(t.plateau.min_relative_improvement);
    w.u64(t.max_buffered_samples as u64);
    w.f32(t.max_gradient_magnitude);
}

fn usize_of(v: u64, what: &str) -> Result<usize, String> {
    usize::try_from(v).map_err(|_| format!("{what} {v} does not fit in usize"))
}

fn read_training(r: &mut Reader<'_>) -> Result<FieldConfig, String> {
    let adam = AdamConfig {
        learning_rate: r.f32()?,
        beta1: r.f32()?,
        beta2: r.f32()?,
        epsilon: r.f32()?,
        l2_regularization: r.f32()?,
    };
    let batch_size = usize_of(r.u64()?, "batch size")?;
    let steps_per_update = r.u32()?;
    let ema_decay = r.f32()?;
    let threads = usize_of(r.u64()?, "threads")?;
    let gradient_chunks = usize_of(r.u64()?, "gradient chunks")?;
    let seed = r.u32()?;
    let max_steps = r.u64()?;
    let plateau = PlateauConfig::new(r.u32()?, r.f32()?);
    let max_buffered_samples = usize_of(r.u64()?, "max buffered samples")?;
    let max_gradient_magnitude = r.f32()?;
    Ok(FieldConfig {
        adam,
        batch_size,
        steps_per_update,
        ema_decay,
        threads,
        gradient_chunks,
        seed,
        max_steps,
        plateau,
        max_buffered_samples,
        max_gradient_magnitude,
    })
}

/// The bytes of a save file of `field`.
#[must_use]
pub fn to_bytes(field: &GuidingField) -> Vec<u8> {
    let config = field.config();
    let (min, max) = field.bounds();
    let state = field.state();
    let model = field.model_bytes();
    let n = state.params.len();
    let mut w = Writer(Vec::with_capacity(200 + model.len() + 16 * n));
    w.0.extend_from_slice(&MAGIC);
    w.u32(FORMAT_VERSION);
    w.u32(config.representation as u32);
    w.u32(config.target as u32);
    w.u32(config.size as u32);
    w.f32(config.selection_probability);
    w.f32s(&min);
    w.f32s(&max);
    write_training(&mut w, &config.training);
    w.u32(model.len() as u32);
    w.0.extend_from_slice(&model);
    w.u64(n as u64);
    w.u64(state.steps);
    w.u64(state.updates);
    w.f32s(&state.params);
    w.f32s(&state.ema);
    w.f32s(&state.adam_m);
    w.f32s(&state.adam_v);
    let crc = crc32fast::hash(&w.0);
    w.u32(crc);
    w.0
}

fn parse(bytes: &[u8]) -> Result<GuidingField, String> {
    if bytes.len() < MAGIC.len() + 8 {
        return Err(format!("{} bytes is too short", bytes.len()));
    }
    if bytes[..8] != MAGIC {
        return Err("wrong magic (not a guiding field file)".into());
    }
    let (body, crc_bytes) = bytes.split_at(bytes.len() - 4);
    let stored = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    let computed = crc32fast::hash(body);
    let mut r = Reader { bytes: body, at: 8 };
    let version = r.u32()?;
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}; this library reads version {FORMAT_VERSION}"
        ));
    }
    if stored != computed {
        return Err(format!(
            "checksum mismatch (stored {stored:08x}, computed {computed:08x}): the file is corrupt or truncated"
        ));
    }
    let code = r.u32()?;
    let representation =
        Representation::from_code(code).ok_or(format!("unknown representation code {code}"))?;
    let target = match r.u32()? {
        0 => Target::Radiance,
        1 => Target::Product,
        c => return Err(format!("unknown target code {c}")),
    };
    let code = r.u32()?;
    let size = ModelSize::from_code(code).ok_or(format!("unknown model size code {code}"))?;
    let selection_probability = r.f32()?;
    let min = [r.f32()?, r.f32()?, r.f32()?];
    let max = [r.f32()?, r.f32()?, r.f32()?];
    let training = read_training(&mut r)?;
    let config = GuidingConfig {
        representation,
        target,
        size,
        selection_probability,
        training,
    };
    let model_len = r.u32()?;
    if model_len > MAX_MODEL_BYTES {
        return Err(format!("model descriptor of {model_len} bytes"));
    }
    let model = r.take(model_len as usize)?.to_vec();
    let n = usize_of(r.u64()?, "parameter count")?;
    let steps = r.u64()?;
    let updates = r.u64()?;
    // The remaining body must hold exactly 4 vectors of n floats.
    let rest = body.len() - r.at;
    if n.checked_mul(16) != Some(rest) {
        return Err(format!(
            "parameter count {n} needs {} bytes of values, the file has {rest}",
            n.saturating_mul(16)
        ));
    }
    let state = FieldState {
        params: r.f32s(n, "params")?,
        ema: r.f32s(n, "ema")?,
        adam_m: r.f32s(n, "adam_m")?,
        adam_v: r.f32s(n, "adam_v")?,
        steps,
        updates,
    };
    let field = GuidingField::with_state(config, min, max, Some(state))
        .map_err(|e| format!("inconsistent contents: {e}"))?;
    if field.model_bytes() != model {
        return Err("model descriptor differs from the one its configuration builds (written by an incompatible library version)".into());
    }
    Ok(field)
}

/// Parses a save file held in memory; `path` only names it in errors.
///
/// # Errors
/// [`GuidingError::Format`] for anything but a valid file.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<GuidingField, GuidingError> {
    parse(bytes).map_err(|reason| GuidingError::Format {
        path: path.to_path_buf(),
        reason,
    })
}

fn io_error(path: &Path, source: std::io::Error) -> GuidingError {
    GuidingError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn temp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

/// Writes `field` to `path` atomically (temporary file, sync, rename).
///
/// # Errors
/// [`GuidingError::Io`] if the directory cannot be written.
pub fn save(field: &GuidingField, path: &Path) -> Result<(), GuidingError> {
    let bytes = to_bytes(field);
    let tmp = temp_path(path);
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(&bytes)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_error(path, e));
    }
    Ok(())
}

/// Reads a field written by [`save`].
///
/// # Errors
/// [`GuidingError::Io`] if the file cannot be read, [`GuidingError::Format`]
/// if it is not a valid save file.
pub fn load(path: &Path) -> Result<GuidingField, GuidingError> {
    let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
    from_bytes(&bytes, path)
}

impl GuidingField {
    /// Saves the field (configuration, bounds, parameters, EMA and Adam
    /// state) to `path`, atomically; see [`crate::file`].
    ///
    /// # Errors
    /// [`GuidingError::Io`].
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), GuidingError> {
        save(self, path.as_ref())
    }

    /// Loads a field saved by [`Self::save`]; it answers queries exactly as
    /// the saved one did and can go on training.
    ///
    /// # Errors
    /// [`GuidingError::Io`] or [`GuidingError::Format`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self, GuidingError> {
        load(path.as_ref())
    }
}
