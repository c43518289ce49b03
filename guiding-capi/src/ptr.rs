//! Checked conversions of C pointers into Rust references and slices: NULL,
//! misalignment, sizes beyond `isize::MAX` and overlapping outputs are
//! reported as a [`Failure`] before any reference is made.

use crate::status::{guard_void, Failure, PgStatus};
use std::ffi::{c_char, CStr};
use std::mem::{align_of, size_of};

/// Bytes of `n` values of `T`, or an error if that exceeds `isize::MAX`.
fn byte_len<T>(n: usize, what: &str) -> Result<usize, Failure> {
    n.checked_mul(size_of::<T>())
        .filter(|&b| b <= isize::MAX as usize)
        .ok_or_else(|| {
            Failure::invalid(format!(
                "{what}: {n} elements of {} bytes do not fit in memory",
                size_of::<T>()
            ))
        })
}

fn check<T>(p: *const T, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return Err(Failure::null(what));
    }
    if !p.is_aligned() {
        return Err(Failure::invalid(format!(
            "{what} is not aligned to {} bytes",
            align_of::<T>()
        )));
    }
    Ok(())
}

/// `n · k` without overflow (array lengths of `k` floats per element).
pub(crate) fn times(n: usize, k: usize, what: &str) -> Result<usize, Failure> {
    n.checked_mul(k)
        .ok_or_else(|| Failure::invalid(format!("{what}: {n} × {k} elements overflow")))
}

/// `&*p`.
///
/// # Safety
/// A non-NULL, aligned `p` must point to a valid `T` that nothing mutates
/// for `'a`.
pub(crate) unsafe fn as_ref<'a, T>(p: *const T, what: &str) -> Result<&'a T, Failure> {
    check(p, what)?;
    // SAFETY: non-NULL and aligned (checked); validity is the caller's contract.
    Ok(unsafe { &*p })
}

/// `&mut *p`.
///
/// # Safety
/// A non-NULL, aligned `p` must point to a `T` that nothing else accesses
/// for `'a`.
pub(crate) unsafe fn as_mut<'a, T>(p: *mut T, what: &str) -> Result<&'a mut T, Failure> {
    check(p, what)?;
    // SAFETY: as above.
    Ok(unsafe { &mut *p })
}

/// `&mut *p` for an optional output: `None` when `p` is NULL.
///
/// # Safety
/// As [`as_mut`] for a non-NULL `p`.
pub(crate) unsafe fn as_mut_opt<'a, T>(
    p: *mut T,
    what: &str,
) -> Result<Option<&'a mut T>, Failure> {
    if p.is_null() {
        return Ok(None);
    }
    // SAFETY: the caller's contract.
    unsafe { as_mut(p, what) }.map(Some)
}

/// Writes `value()` to `*p` whole, never reading or referencing the old
/// contents (the caller's struct may be uninitialised, as with the
/// `*_set_defaults` functions); `*p` is unchanged when `value` fails.
///
/// # Safety
/// A non-NULL, aligned `p` must be writable for a `T`.
pub(crate) unsafe fn write_whole<T>(
    p: *mut T,
    what: &str,
    value: impl FnOnce() -> Result<T, Failure>,
) -> Result<(), Failure> {
    if p.is_null() {
        return Err(Failure::null(what));
    }
    if !p.is_aligned() {
        return Err(Failure::invalid(format!("{what} is misaligned")));
    }
    let value = value()?;
    // SAFETY: non-NULL, aligned (checked), writable by the caller's contract.
    unsafe { p.write(value) };
    Ok(())
}

/// The body of an entry point that reads the handle `*handle` (named
/// `what`) and writes one result to `*out`: `handle` is checked first, then
/// `out`, then `value` runs; `*out` is written only when it succeeds.
///
/// # Safety
/// As [`as_ref`] for `handle` and [`as_mut`] for `out`.
pub(crate) unsafe fn read_into<H, T>(
    handle: *const H,
    what: &str,
    out: *mut T,
    value: impl FnOnce(&H) -> Result<T, Failure>,
) -> Result<(), Failure> {
    // SAFETY: the caller's contract.
    let (handle, out) = unsafe { (as_ref(handle, what)?, as_mut(out, "out")?) };
    *out = value(handle)?;
    Ok(())
}

/// Stores a new handle, `make()` boxed, in `*out`; `*out` is NULL whenever
/// `make` fails (or panics). The handle is the caller's, released once with
/// [`release`].
///
/// # Safety
/// As [`as_mut`] for `out`.
pub(crate) unsafe fn new_handle<T>(
    out: *mut *mut T,
    make: impl FnOnce() -> Result<T, Failure>,
) -> Result<(), Failure> {
    // SAFETY: the caller's contract.
    let out = unsafe { as_mut(out, "out") }?;
    *out = std::ptr::null_mut();
    *out = Box::into_raw(Box::new(make()?));
    Ok(())
}

/// The body of the `*_release` entry point `name`: drops the handle made by
/// [`new_handle`] (NULL: no-op) inside [`guard_void`].
///
/// # Safety
/// `handle` must be NULL or a live handle from [`new_handle`] of this `T`
/// that nothing uses afterwards.
pub(crate) unsafe fn release<T>(name: &str, handle: *mut T) {
    guard_void(name, || {
        if !handle.is_null() {
            // SAFETY: made by Box::into_raw (caller's contract).
            drop(unsafe { Box::from_raw(handle) });
        }
    });
}

/// The `n` values at `p`; `p` may be NULL when `n == 0`.
///
/// # Safety
/// For `n > 0` a non-NULL, aligned `p` must point to `n` initialised
/// values that nothing mutates for `'a`.
pub(crate) unsafe fn slice<'a, T>(p: *const T, n: usize, what: &str) -> Result<&'a [T], Failure> {
    if n == 0 {
        return Ok(&[]);
    }
    check(p, what)?;
    byte_len::<T>(n, what)?;
    // SAFETY: non-NULL, aligned, size ≤ isize::MAX (checked); validity is
    // the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// The `n` values at `p`, writable; `p` may be NULL when `n == 0`.
///
/// # Safety
/// For `n > 0` a non-NULL, aligned `p` must point to `n` values that
/// nothing else accesses for `'a` (overlap with other arguments is checked
/// by [`disjoint`] beforehand).
pub(crate) unsafe fn slice_mut<'a, T>(
    p: *mut T,
    n: usize,
    what: &str,
) -> Result<&'a mut [T], Failure> {
    if n == 0 {
        return Ok(&mut []);
    }
    check(p, what)?;
    byte_len::<T>(n, what)?;
    // SAFETY: as in `slice`.
    Ok(unsafe { std::slice::from_raw_parts_mut(p, n) })
}

/// The `n` RGB or xyz triples of `3n` floats at `p` (NULL when `n == 0`).
///
/// # Safety
/// As [`slice`] for `3n` floats.
pub(crate) unsafe fn triples<'a>(
    p: *const f32,
    n: usize,
    what: &str,
) -> Result<&'a [[f32; 3]], Failure> {
    times(n, 3, what)?;
    // `[f32; 3]` has the alignment of `f32`.
    unsafe { slice(p.cast::<[f32; 3]>(), n, what) }
}

/// A memory range an argument covers: name, start address, byte length.
pub(crate) struct Region<'n> {
    name: &'n str,
    start: usize,
    len: usize,
}

/// The range of `n` values of `T` at `p` (empty for `n == 0`, NULL or an
/// overflowing size: those are reported by [`slice`]).
pub(crate) fn region<'n, T>(name: &'n str, p: *const T, n: usize) -> Region<'n> {
    let len = n.checked_mul(size_of::<T>()).unwrap_or(0);
    Region {
        name,
        start: p as usize,
        len: if p.is_null() { 0 } else { len },
    }
}

fn overlap(a: &Region<'_>, b: &Region<'_>) -> bool {
    a.len > 0
        && b.len > 0
        && a.start < b.start.saturating_add(b.len)
        && b.start < a.start.saturating_add(a.len)
}

/// Checks that no output overlaps another output or an input.
pub(crate) fn disjoint(outputs: &[Region<'_>], inputs: &[Region<'_>]) -> Result<(), Failure> {
    for (i, out) in outputs.iter().enumerate() {
        for other in outputs[i + 1..].iter().chain(inputs) {
            if overlap(out, other) {
                return Err(Failure::new(
                    PgStatus::PG_INVALID_ARGUMENT,
                    format!("output {} overlaps {}", out.name, other.name),
                ));
            }
        }
    }
    Ok(())
}

/// A C path string as a [`std::path::PathBuf`].
///
/// # Safety
/// A non-NULL `p` must point to a NUL-terminated string.
pub(crate) unsafe fn path(p: *const c_char, what: &str) -> Result<std::path::PathBuf, Failure> {
    if p.is_null() {
        return Err(Failure::null(what));
    }
    // SAFETY: non-NULL; NUL termination is the caller's contract.
    let bytes = unsafe { CStr::from_ptr(p) }.to_bytes();
    if bytes.is_empty() {
        return Err(Failure::invalid(format!("{what} is empty")));
    }
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        Ok(std::ffi::OsStr::from_bytes(bytes).into())
    }
    #[cfg(not(unix))]
    {
        std::str::from_utf8(bytes)
            .map(Into::into)
            .map_err(|_| Failure::invalid(format!("{what} is not UTF-8")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_overlap_only_when_they_share_a_byte() {
        let a = [0.0f32; 8];
        let p = a.as_ptr();
        let r = |name, off: usize, n| region(name, p.wrapping_add(off), n);
        assert!(disjoint(&[r("x", 0, 4)], &[r("y", 4, 4)]).is_ok());
        assert!(disjoint(&[r("x", 0, 5)], &[r("y", 4, 4)]).is_err());
        assert!(disjoint(&[r("x", 0, 4), r("y", 3, 1)], &[]).is_err());
        assert!(disjoint(&[r("x", 0, 0)], &[r("y", 0, 4)]).is_ok());
        assert!(disjoint(&[region::<f32>("x", std::ptr::null(), 4)], &[r("y", 0, 4)]).is_ok());
    }
}
