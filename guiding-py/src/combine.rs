//! `guiding.PassCombiner`: the inverse-variance combination of a render's passes (the
//! library's `PassCombiner`, what `host-demo` combines its guided passes with).

use crate::arrays::{from_rows3, rows, Rows};
use crate::py_err;
use guiding::{CombineOptions, PassCombiner};
use pyo3::prelude::*;

report_class! {
    /// One group of passes in a combination: its id, passes, per-pass relative variance and
    /// per-pass weight estimated on each checkerboard half (half `(x + y) mod 2`; a pixel of
    /// half `h` takes the weight estimated on half `1 - h`), and its share of the image.
    GroupWeight from guiding::GroupWeight as g {
        group: u32 = g.group, passes: u32 = g.passes,
        relative_variance: (f64, f64) = (g.relative_variance[0], g.relative_variance[1]),
        pass_weight: (f64, f64) = (g.pass_weight[0], g.pass_weight[1]),
        share: f64 = g.share,
    }
}

/// Accumulates passes by group and combines them with inverse-variance weights:
/// `PassCombiner(width, height, epsilon=0.01, smoothing_radius=2, cap_at_largest_group=True)`.
/// Passes of one group are the same estimator (all passes after training); each training pass
/// is a group of its own. The library's documentation of `guiding::combine` has the formulas.
#[pyclass(module = "guiding", name = "PassCombiner")]
pub struct Combiner {
    inner: PassCombiner,
}

#[pymethods]
impl Combiner {
    #[new]
    #[pyo3(signature = (width, height, epsilon = 0.01, smoothing_radius = 2, cap_at_largest_group = true))]
    fn new(
        width: usize,
        height: usize,
        epsilon: f64,
        smoothing_radius: u32,
        cap_at_largest_group: bool,
    ) -> PyResult<Self> {
        let options = CombineOptions {
            epsilon,
            smoothing_radius,
            cap_at_largest_group,
        };
        let inner = PassCombiner::new(width, height, options).map_err(py_err)?;
        Ok(Self { inner })
    }

    /// Adds one pass of `group`: `pixels` `(width · height, 3)` `float32`, row-major.
    fn add_pass(&mut self, py: Python<'_>, group: u32, pixels: Rows<'_>) -> PyResult<()> {
        let pixels = rows::<3>(&pixels, "pixels")?;
        py.allow_threads(|| self.inner.add_pass(group, &pixels))
            .map_err(py_err)
    }

    /// Passes added so far.
    #[getter]
    fn passes(&self) -> u32 {
        self.inner.passes()
    }

    /// Groups seen so far.
    #[getter]
    fn group_count(&self) -> usize {
        self.inner.group_count()
    }

    /// The combined image, its variance and the weights.
    fn combine(&self, py: Python<'_>) -> Combination {
        let c = py.allow_threads(|| self.inner.combine());
        Combination {
            groups: c.groups.iter().map(GroupWeight::from).collect(),
            predicted_gain: c.predicted_gain(),
            fell_back: c.fell_back,
            pixels: c.pixels,
            var_of_mean: c.var_of_mean,
        }
    }
}

/// What `PassCombiner.combine()` returns.
#[pyclass(module = "guiding", frozen)]
pub struct Combination {
    pixels: Vec<[f32; 3]>,
    var_of_mean: Vec<[f32; 3]>,
    /// Per group, in order of first appearance.
    #[pyo3(get)]
    groups: Vec<GroupWeight>,
    /// Predicted relMSE of the weighted image relative to the plain mean's.
    #[pyo3(get)]
    predicted_gain: f64,
    /// The weights were not usable: the image is the plain mean.
    #[pyo3(get)]
    fell_back: bool,
}

#[pymethods]
impl Combination {
    /// Per pixel, the weighted mean of the passes, `(width · height, 3)`.
    #[getter]
    fn pixels<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f32>> {
        from_rows3(py, &self.pixels)
    }

    /// Per pixel, the estimated variance of that mean, `(width · height, 3)`.
    #[getter]
    fn var_of_mean<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f32>> {
        from_rows3(py, &self.var_of_mean)
    }
}
