//! Python bindings of the `guiding` crate, imported as `guiding` (the extension module is
//! `guiding._guiding`; `guiding-py/python/guiding` re-exports it and adds the Mitsuba 3
//! integrator).
//!
//! Arrays are numpy arrays in structure-of-arrays form, as Dr.Jit hands them over: `(n, 3)`
//! `float32` for points, normals, directions and colours, `(n,)` for scalars, `(n,)` `uint32` for
//! lanes and slots. Every heavy call releases the GIL. Wrong shapes raise `ValueError`; what
//! the library refuses (a stale batch, a bad configuration, a corrupt file) raises
//! `guiding.GuidingError` with the library's message.

mod arrays;
mod cache;
mod field;
mod recorder;
mod reports;
mod schedule;

use pyo3::create_exception;
use pyo3::prelude::*;

create_exception!(
    _guiding,
    GuidingError,
    pyo3::exceptions::PyException,
    "An error of the guiding library (its message says what to change)."
);

/// The library's error as a `guiding.GuidingError`.
pub(crate) fn py_err(e: guiding::GuidingError) -> PyErr {
    GuidingError::new_err(e.to_string())
}

/// The extension module.
#[pymodule]
fn _guiding(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GuidingError", m.py().get_type::<GuidingError>())?;
    m.add_class::<field::Field>()?;
    m.add_class::<field::Batch>()?;
    m.add_class::<cache::Cache>()?;
    m.add_class::<recorder::Recorder>()?;
    m.add_class::<schedule::Schedule>()?;
    m.add_class::<reports::UpdateReport>()?;
    m.add_class::<reports::FieldStats>()?;
    m.add_class::<reports::ScheduleReport>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
