//! Status codes, the thread-local last-error message, and the guard every
//! entry point runs its body in (`catch_unwind`, error → status + message).

use guiding::GuidingError;
use std::cell::RefCell;
use std::ffi::{c_char, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Result of every `pg_*` call that can fail. On anything but `PG_OK`,
/// `pg_last_error()` says what went wrong and what to change.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PgStatus {
    /// Success.
    PG_OK = 0,
    /// A required pointer argument was NULL.
    PG_NULL_POINTER = 1,
    /// An argument is out of its documented range (invalid configuration or
    /// bounds, non-finite query, misaligned or overlapping arrays, …).
    PG_INVALID_ARGUMENT = 2,
    /// A count exceeds what a handle holds (e.g. `n` larger than the number
    /// of distributions in a `PgDistributions`).
    PG_SIZE_MISMATCH = 3,
    /// The distributions were decoded before the field's latest update (or
    /// by another field): query again.
    PG_STALE = 4,
    /// A file could not be read or written.
    PG_IO = 5,
    /// A file is not a valid guiding field (wrong magic or version,
    /// truncated, checksum mismatch, inconsistent contents).
    PG_FORMAT = 6,
    /// An earlier call panicked while it was modifying this field; its
    /// state is unknown. Release the field.
    PG_POISONED = 7,
    /// An internal error (a Rust panic) was caught at the C boundary; the
    /// message has its text. Please report it.
    PG_PANIC = 8,
    /// The field's Vulkan device is missing or failed: no Vulkan loader or
    /// matching device, the library built without its SPIR-V (`guiding-gpu`
    /// feature `shaders`), or a device failure mid-render (the message
    /// says which). A field created with `PG_DEVICE_FALLBACK_CPU` goes on on
    /// the CPU instead of failing mid-render.
    PG_DEVICE_UNAVAILABLE = 9,
}

/// A failed call: its status and message.
#[derive(Debug)]
pub(crate) struct Failure {
    pub status: PgStatus,
    pub message: String,
}

impl Failure {
    pub fn new(status: PgStatus, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    pub fn null(what: &str) -> Self {
        Self::new(PgStatus::PG_NULL_POINTER, format!("{what} is NULL"))
    }

    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(PgStatus::PG_INVALID_ARGUMENT, message)
    }

    /// An argument `what` whose value `code` is none of the `PG_<family>_*`
    /// codes (`codes`: their range, e.g. "0 or 1").
    pub fn unknown_code(what: &str, code: u32, family: &str, codes: &str) -> Self {
        Self::invalid(format!(
            "{what} {code} is not a PG_{family}_* code ({codes})"
        ))
    }
}

impl From<GuidingError> for Failure {
    fn from(e: GuidingError) -> Self {
        let status = match &e {
            GuidingError::InvalidConfig(_)
            | GuidingError::InvalidBounds { .. }
            | GuidingError::Field(_) => PgStatus::PG_INVALID_ARGUMENT,
            GuidingError::LengthMismatch { .. } => PgStatus::PG_SIZE_MISMATCH,
            GuidingError::StaleDistribution { .. } => PgStatus::PG_STALE,
            GuidingError::Io { .. } => PgStatus::PG_IO,
            GuidingError::Format { .. } => PgStatus::PG_FORMAT,
            GuidingError::Device(_) => PgStatus::PG_DEVICE_UNAVAILABLE,
        };
        Self::new(status, e.to_string())
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: String) {
    // Interior NULs would cut the C string short: replace them.
    let bytes: Vec<u8> = message
        .into_bytes()
        .into_iter()
        .map(|b| if b == 0 { b'?' } else { b })
        .collect();
    let text = CString::new(bytes).unwrap_or_default();
    // During thread teardown the slot may be gone: then there is nowhere to
    // put the message, and nothing to read it.
    let _ = LAST_ERROR.try_with(|slot| *slot.borrow_mut() = text);
}

/// Pointer to this thread's last error message (`""` after a success).
pub(crate) fn last_error_ptr() -> *const c_char {
    static EMPTY: &[u8] = b"\0";
    LAST_ERROR
        .try_with(|slot| slot.borrow().as_ptr())
        .unwrap_or(EMPTY.as_ptr().cast())
}

fn panic_text(payload: &(dyn std::any::Any + Send)) -> &str {
    if let Some(s) = payload.downcast_ref::<&str>() {
        s
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s
    } else {
        "(no message)"
    }
}

/// Runs the body of the entry point `name`: clears the last error, catches
/// panics, and turns a [`Failure`] into its status with the message
/// `"name: message"` stored for `pg_last_error`.
pub(crate) fn guard(name: &str, body: impl FnOnce() -> Result<(), Failure>) -> PgStatus {
    set_last_error(String::new());
    let failure = match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => return PgStatus::PG_OK,
        Ok(Err(failure)) => failure,
        Err(payload) => Failure::new(
            PgStatus::PG_PANIC,
            format!("internal error (panic): {}", panic_text(payload.as_ref())),
        ),
    };
    set_last_error(format!("{name}: {}", failure.message));
    failure.status
}

/// [`guard`] for functions without a status (`*_release`): a panic is
/// swallowed (it cannot unwind into C) and its message kept.
pub(crate) fn guard_void(name: &str, body: impl FnOnce()) {
    let _ = guard(name, || {
        body();
        Ok(())
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::CStr;

    fn last() -> String {
        // SAFETY: last_error_ptr always returns a valid NUL-terminated string.
        unsafe { CStr::from_ptr(last_error_ptr()) }
            .to_string_lossy()
            .into_owned()
    }

    #[test]
    fn panics_become_pg_panic_with_their_message() {
        let status = guard("pg_test", || panic!("boom {}", 42));
        assert_eq!(status, PgStatus::PG_PANIC);
        assert_eq!(last(), "pg_test: internal error (panic): boom 42");
        let status = guard("pg_test", || std::panic::panic_any(7_u8));
        assert_eq!(status, PgStatus::PG_PANIC);
        assert!(last().ends_with("(no message)"));
        // The next call clears the message.
        assert_eq!(guard("pg_test", || Ok(())), PgStatus::PG_OK);
        assert_eq!(last(), "");
    }

    #[test]
    fn failures_keep_status_and_message_without_interior_nuls() {
        let status = guard("pg_test", || Err(Failure::invalid("a\0b")));
        assert_eq!(status, PgStatus::PG_INVALID_ARGUMENT);
        assert_eq!(last(), "pg_test: a?b");
    }
}
