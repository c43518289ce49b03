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
#[macro_use]
mod reports;
mod cache;
mod combine;
mod field;
mod recorder;
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

/// `m.add_class::<T>()?` for every `T`.
macro_rules! add_classes {
    ($m:ident, $($t:ty),* $(,)?) => { $($m.add_class::<$t>()?;)* };
}

/// The extension module.
#[pymodule]
fn _guiding(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GuidingError", m.py().get_type::<GuidingError>())?;
    add_classes!(
        m,
        field::Field,
        field::Batch,
        cache::Cache,
        combine::Combiner,
        combine::Combination,
        combine::GroupWeight,
        recorder::Recorder,
        schedule::Schedule,
        reports::UpdateReport,
        reports::FieldStats,
        reports::ScheduleReport,
        reports::SelectionReport
    );
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
