//! numpy arrays in, checked: `(n, 3)` rows and `(n,)` columns of a common length `n`.

use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::PyResult;

/// An `(n, k)` `float32` array argument (points, directions, colours, random pairs).
pub type Rows<'py> = PyReadonlyArray2<'py, f32>;
/// An `(n,)` `float32` array argument.
pub type Floats<'py> = PyReadonlyArray1<'py, f32>;
/// An `(n,)` `uint32` array argument (lanes of a batch, slots of a recorder).
pub type Indices<'py> = PyReadonlyArray1<'py, u32>;
/// An `(n,)` `float32` array result.
pub type Column<'py> = pyo3::Bound<'py, numpy::PyArray1<f32>>;

/// The rows of an `(n, K)` array (any strides).
///
/// # Errors
/// `ValueError` naming `what` if the second axis is not `K`.
pub fn rows<const K: usize>(a: &Rows<'_>, what: &str) -> PyResult<Vec<[f32; K]>> {
    let v = a.as_array();
    if v.ncols() != K {
        return Err(PyValueError::new_err(format!(
            "{what}: expected an array of shape (n, {K}), got {:?}",
            v.shape()
        )));
    }
    Ok(v.rows()
        .into_iter()
        .map(|r| std::array::from_fn(|k| r[k]))
        .collect())
}

/// The values of an `(n,)` array.
pub fn column<T: numpy::Element + Copy>(a: &PyReadonlyArray1<'_, T>) -> Vec<T> {
    a.as_array().iter().copied().collect()
}

/// Checks that the arrays named in `names` (comma-separated, in order) have the same
/// `lengths`, and returns it.
///
/// # Errors
/// `ValueError` naming the first array whose length differs from the first's.
pub fn same_lengths(names: &str, lengths: &[usize]) -> PyResult<usize> {
    let names: Vec<&str> = names.split(',').map(str::trim).collect();
    let n = lengths.first().copied().unwrap_or(0);
    for (i, &m) in lengths.iter().enumerate() {
        if m != n {
            let name = |k: usize| names.get(k).copied().unwrap_or("an array");
            return Err(PyValueError::new_err(format!(
                "{} has {m} rows where {} has {n}",
                name(i),
                name(0)
            )));
        }
    }
    Ok(n)
}

/// `rows` as an `(n, 3)` array.
pub fn from_rows3<'py>(
    py: pyo3::Python<'py>,
    rows: &[[f32; 3]],
) -> pyo3::Bound<'py, numpy::PyArray2<f32>> {
    use numpy::IntoPyArray;
    let flat: Vec<f32> = rows.iter().flatten().copied().collect();
    numpy::ndarray::Array2::from_shape_vec((rows.len(), 3), flat)
        .expect("3 values per row")
        .into_pyarray(py)
}
