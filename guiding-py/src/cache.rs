//! `guiding.GuideCache`: the decoded guide per cell of a fine grid, so that a query costs a
//! lookup instead of a network pass (the library's `GuideCache`, what `host-demo` renders
//! with once training has stopped).

use crate::arrays::{rows, same_lengths, Rows};
use crate::field::{Batch, Field};
use crate::py_err;
use crate::recorder::Recorder;
use crate::reports::SelectionReport;
use guiding::{CacheOptions, DistributionBatch, GuideCache, QueryPoint, SelectionFit};
use guiding_core::glam::Vec3;
use guiding_core::model::npm::NPM_LOBES;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A field's guide decoded per occupied cell: `Field.build_cache(position, resolution=64)`
/// (radiance targets). Valid for the field's generation at the build
/// (`refresh(field)` after an update); `GuidingError` otherwise.
#[pyclass(module = "guiding", name = "GuideCache")]
pub struct Cache {
    inner: GuideCache,
    /// Queries the last `decode` answered from the network (no cell near them).
    misses: Vec<u32>,
}

/// Query points at `position` (the cache's guide depends on the position alone).
fn at(position: &Rows<'_>) -> PyResult<Vec<QueryPoint>> {
    Ok(rows(position, "position")?
        .into_iter()
        .map(|p| QueryPoint::from_vec3(Vec3::from(p), Vec3::Z, Vec3::Z, 1.0))
        .collect())
}

impl Cache {
    /// `field.build_cache(…)`.
    pub fn build(
        py: Python<'_>,
        field: &Field,
        position: &Rows<'_>,
        options: CacheOptions,
    ) -> PyResult<Self> {
        let points = at(position)?;
        let inner = py
            .allow_threads(|| field.inner.build_cache(&points, &options))
            .map_err(py_err)?;
        Ok(Self {
            inner,
            misses: Vec::new(),
        })
    }
}

#[pymethods]
impl Cache {
    /// Stored distributions (occupied cells, times their normal bins with the cosine product).
    #[getter]
    fn cells(&self) -> usize {
        self.inner.cells()
    }

    /// One distribution per row of `position` `(n, 3)`: the cell found by the stochastic
    /// trilinear lookup with the uniform numbers `jitter` `(n, 3)`, or the network's decode
    /// where no cell is near (counted in `misses`). Sample and pdf the batch through the field.
    fn decode(&mut self, field: &Field, position: Rows, jitter: Rows) -> PyResult<Batch> {
        let py = position.py();
        let points = at(&position)?;
        let jitter: Vec<Vec3> = rows(&jitter, "jitter")?
            .into_iter()
            .map(Vec3::from)
            .collect();
        same_lengths("position, jitter", &[points.len(), jitter.len()])?;
        let mut out = DistributionBatch::new();
        let (cache, misses) = (&self.inner, &mut self.misses);
        py.allow_threads(|| cache.decode_batch(&field.inner, &points, &jitter, &mut out, misses))
            .map_err(py_err)?;
        Ok(Batch::from(out))
    }

    /// Indices (into the last `decode`'s rows) of the queries no cell answered, `(m,)`
    /// `uint32`: their positions are what `extend` wants.
    #[getter]
    fn misses<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<u32>> {
        numpy::PyArray1::from_slice(py, &self.misses)
    }

    /// Adds the cells of `position` `(n, 3)` not in the cache yet; returns how many.
    fn extend(&mut self, py: Python<'_>, field: &Field, position: Rows) -> PyResult<usize> {
        let points = at(&position)?;
        let cache = &mut self.inner;
        py.allow_threads(|| cache.extend(&field.inner, &points))
            .map_err(py_err)
    }

    /// The cache as plain arrays for a renderer's own kernels, or `None` unless the guide is
    /// NPM's vMF mixtures: a dict with `lo` `(3,)`, `cell` (the side `h`), `res` `(3,)`,
    /// `index` (per cell `(z·res_y + y)·res_x + x`: its lane, or `0xffffffff`), `lanes`
    /// `(L, 7, 8)` (per lane and row `weight, mean_x, mean_y, mean_z, kappa, norm,
    /// one_minus_e2k`, per lobe), `lane_selection` `(L,)` (empty: `selection` for all) and
    /// `selection`. The lookup: the library's `VmfTable`.
    fn vmf_table<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(t) = self.inner.vmf_table() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("lo", PyArray1::from_slice(py, &t.lo))?;
        d.set_item("cell", t.cell)?;
        d.set_item("res", PyArray1::from_slice(py, &t.res))?;
        d.set_item("index", PyArray1::from_slice(py, t.index))?;
        let flat: &[f32] = bytemuck::cast_slice(t.lanes);
        let lanes = PyArray1::from_slice(py, flat).reshape([t.lanes.len(), 7, NPM_LOBES])?;
        d.set_item("lanes", lanes)?;
        d.set_item("lane_selection", PyArray1::from_slice(py, t.lane_selection))?;
        d.set_item("selection", t.selection)?;
        Ok(Some(d))
    }

    /// Fits a guide-selection probability per cell to the samples `recorder` kept (its last
    /// `flush_into(field, keep=True)`): per cell the candidate `c` of least estimated second
    /// moment of the one-sample MIS estimator, shrunk towards the fit over all samples, with
    /// `guide_cost` the extra cost of a vertex that queries the guide (the library's
    /// `GuideCache::fit_selection` and `SelectionFit` document the formulas and the other
    /// settings, its defaults here). Later `decode`s and `vmf_table`s carry the fitted
    /// probabilities.
    #[pyo3(signature = (field, recorder, guide_cost = 0.0))]
    fn fit_selection(
        &mut self,
        py: Python<'_>,
        field: &Field,
        recorder: &Recorder,
        guide_cost: f32,
    ) -> PyResult<SelectionReport> {
        let fit = SelectionFit {
            guide_cost,
            ..SelectionFit::default()
        };
        let (cache, samples, mis) = (&mut self.inner, &recorder.kept, &recorder.kept_mis);
        let mis = (mis.len() == samples.len()).then_some(mis.as_slice());
        let report = py
            .allow_threads(|| cache.fit_selection(&field.inner, samples, mis, None, &fit))
            .map_err(py_err)?;
        Ok(SelectionReport::from(&report))
    }

    /// Decodes every cell again after the field's update.
    fn refresh(&mut self, py: Python<'_>, field: &Field) -> PyResult<()> {
        let cache = &mut self.inner;
        py.allow_threads(|| cache.refresh(&field.inner))
            .map_err(py_err)
    }
}
