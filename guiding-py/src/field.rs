//! `guiding.Field` (a [`GuidingField`]) and `guiding.DistributionBatch` (its decoded lanes).

use crate::arrays::{column, from_rows3, rows, same_lengths, Column, Floats, Indices, Rows};
use crate::py_err;
use crate::reports::{FieldStats, UpdateReport};
use guiding::{
    DirectionSample, DistributionBatch, GuidingConfig, GuidingField, ModelSize, QueryPoint,
    Representation, Target,
};
use guiding_core::glam::{Vec2, Vec3};
use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::PathBuf;

/// A learned guide over a scene's bounding box: the library's `GuidingField`.
///
/// `Field(bounds_min, bounds_max, representation="npm", target="radiance", size="compact",
/// threads=0)`: the library's preset for the representation (`npm`, `nasg`, `df-n`, `df-l`) and
/// target (`radiance`, `product`); `size` is `small`, `compact` or `paper`; `threads` runs the
/// batched calls (0: all cores); `selection_probability` replaces the preset's probability of
/// sampling the guide rather than the BSDF (NPM and DF; NASG learns its own).
#[pyclass(module = "guiding", name = "Field")]
pub struct Field {
    pub(crate) inner: GuidingField,
}

/// The distributions decoded at a batch of query points (`Field.decode`); valid until the
/// field's next update (`GuidingError` then).
#[pyclass(module = "guiding", name = "DistributionBatch")]
pub struct Batch {
    inner: DistributionBatch,
}

impl From<DistributionBatch> for Batch {
    fn from(inner: DistributionBatch) -> Self {
        Self { inner }
    }
}

/// `Field.sample`'s result: directions `(m, 3)` and pdfs `(m,)`.
type Samples<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<f32>>);

fn parse_target(s: &str) -> PyResult<Target> {
    match s {
        "radiance" => Ok(Target::Radiance),
        "product" => Ok(Target::Product),
        _ => Err(PyValueError::new_err(format!(
            "unknown target {s:?} (radiance or product)"
        ))),
    }
}

fn target_name(t: Target) -> &'static str {
    match t {
        Target::Radiance => "radiance",
        Target::Product => "product",
    }
}

impl Field {
    /// The query points of `n` rows (`normal`, `wo`, `roughness` default to zero, zero, 1).
    fn queries(
        position: &Rows<'_>,
        normal: Option<&Rows<'_>>,
        wo: Option<&Rows<'_>>,
        roughness: Option<&Floats<'_>>,
    ) -> PyResult<Vec<QueryPoint>> {
        let p = rows(position, "position")?;
        let n = normal.map(|a| rows(a, "normal")).transpose()?;
        let w = wo.map(|a| rows(a, "wo")).transpose()?;
        let r = roughness.map(column);
        let len = |v: &Option<Vec<_>>| v.as_ref().map_or(p.len(), Vec::len);
        same_lengths(
            "position, normal, wo, roughness",
            &[
                p.len(),
                len(&n),
                len(&w),
                r.as_ref().map_or(p.len(), Vec::len),
            ],
        )?;
        Ok((0..p.len())
            .map(|i| {
                QueryPoint::new(
                    p[i],
                    n.as_ref().map_or([0.0; 3], |n| n[i]),
                    w.as_ref().map_or([0.0; 3], |w| w[i]),
                    r.as_ref().map_or(1.0, |r| r[i]),
                )
            })
            .collect())
    }
}

#[pymethods]
impl Field {
    #[new]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments with defaults
    #[pyo3(signature = (bounds_min, bounds_max, representation = "npm", target = "radiance", size = "compact", threads = 0, selection_probability = None))]
    fn new(
        py: Python<'_>,
        bounds_min: [f32; 3],
        bounds_max: [f32; 3],
        representation: &str,
        target: &str,
        size: &str,
        threads: usize,
        selection_probability: Option<f32>,
    ) -> PyResult<Self> {
        let rep: Representation = representation
            .parse()
            .map_err(|e| PyValueError::new_err(format!("representation: {e}")))?;
        let size: ModelSize = size
            .parse()
            .map_err(|e| PyValueError::new_err(format!("size: {e}")))?;
        let mut config = GuidingConfig::for_representation(rep, parse_target(target)?);
        config.size = size;
        config.training.threads = threads;
        if let Some(c) = selection_probability {
            config.selection_probability = c;
        }
        let inner = py
            .allow_threads(|| GuidingField::new(config, bounds_min, bounds_max))
            .map_err(py_err)?;
        Ok(Self { inner })
    }

    /// Loads a field saved by `save` (or by the Rust / C API).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py
            .allow_threads(|| GuidingField::load(&path))
            .map_err(py_err)?;
        Ok(Self { inner })
    }

    /// Saves the field (versioned, CRC-checked, written atomically).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.allow_threads(|| self.inner.save(&path)).map_err(py_err)
    }

    /// `npm`, `nasg`, `df-n` or `df-l`.
    #[getter]
    fn representation(&self) -> &'static str {
        self.inner.config().representation.name()
    }

    /// `radiance` or `product`.
    #[getter]
    fn target(&self) -> &'static str {
        target_name(self.inner.config().target)
    }

    /// `small`, `compact` or `paper`.
    #[getter]
    fn size(&self) -> &'static str {
        self.inner.config().size.name()
    }

    /// Updates so far that changed the parameters (a batch decoded before is stale).
    #[getter]
    fn generation(&self) -> u64 {
        self.inner.generation()
    }

    /// Training counters.
    fn stats(&self) -> FieldStats {
        FieldStats::from(&self.inner.stats())
    }

    /// Decodes the guide at `n` query points: `position` `(n, 3)`; `normal`, `wo` `(n, 3)` and
    /// `roughness` `(n,)` for product targets (radiance guides ignore them).
    #[pyo3(signature = (position, normal = None, wo = None, roughness = None))]
    fn decode(
        &self,
        py: Python<'_>,
        position: Rows<'_>,
        normal: Option<Rows<'_>>,
        wo: Option<Rows<'_>>,
        roughness: Option<Floats<'_>>,
    ) -> PyResult<Batch> {
        let queries = Self::queries(&position, normal.as_ref(), wo.as_ref(), roughness.as_ref())?;
        if let Some(i) = queries
            .iter()
            .position(|q| !q.position.iter().all(|x| x.is_finite()))
        {
            return Err(PyValueError::new_err(format!(
                "position: row {i} is not finite ({:?})",
                queries[i].position
            )));
        }
        let mut inner = DistributionBatch::new();
        py.allow_threads(|| self.inner.try_decode_batch(&queries, &mut inner))
            .map_err(py_err)?;
        Ok(Batch { inner })
    }

    /// Samples one direction per lane: `lanes` `(m,)` indices into `batch`, `u` `(m, 2)` in
    /// `[0, 1)²`. Returns `(directions (m, 3), pdfs (m,))`.
    fn sample<'py>(&self, batch: &Batch, lanes: Indices<'py>, u: Rows) -> PyResult<Samples<'py>> {
        let py = lanes.py();
        let lanes = column(&lanes);
        let u: Vec<Vec2> = rows(&u, "u")?.into_iter().map(Vec2::from).collect();
        let none = DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0,
        };
        let mut out = vec![none; lanes.len()];
        py.allow_threads(|| {
            self.inner
                .sample_decoded(&batch.inner, &lanes, &u, &mut out)
        })
        .map_err(py_err)?;
        let dirs: Vec<[f32; 3]> = out.iter().map(|s| s.direction.to_array()).collect();
        let pdfs: Vec<f32> = out.iter().map(|s| s.pdf).collect();
        Ok((from_rows3(py, &dirs), PyArray1::from_vec(py, pdfs)))
    }

    /// The density of `directions` `(m, 3)` (unit `wi`s) under lanes `lanes` `(m,)` of
    /// `batch`. Returns `(m,)`.
    fn pdf<'py>(
        &self,
        batch: &Batch,
        lanes: Indices<'py>,
        directions: Rows,
    ) -> PyResult<Column<'py>> {
        let py = lanes.py();
        let lanes = column(&lanes);
        let dirs: Vec<Vec3> = rows(&directions, "directions")?
            .into_iter()
            .map(Vec3::from)
            .collect();
        let mut out = vec![0.0f32; lanes.len()];
        py.allow_threads(|| {
            self.inner
                .pdf_decoded(&batch.inner, &lanes, &dirs, &mut out)
        })
        .map_err(py_err)?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// One update with the preset's steps over the buffered samples.
    fn update(&mut self, py: Python<'_>) -> PyResult<UpdateReport> {
        let r = py
            .allow_threads(|| self.inner.try_update())
            .map_err(py_err)?;
        Ok(UpdateReport::from(&r))
    }

    /// The Adam steps the schedule says are due now (none when it says none); the update's
    /// report (`steps` 0 when none ran).
    fn train_scheduled(
        &mut self,
        py: Python<'_>,
        mut schedule: PyRefMut<'_, crate::schedule::Schedule>,
    ) -> PyResult<UpdateReport> {
        let (s, field) = (&mut schedule.inner, &mut self.inner);
        let r = py
            .allow_threads(|| s.train(field))
            .map_err(py_err)?
            .unwrap_or_default();
        Ok(UpdateReport::from(&r))
    }

    /// A cache of the decoded guide over the cells of `position` `(n, 3)` (typically the
    /// vertices of the last training pass), `resolution` cells along the box's longest axis.
    /// Radiance targets only (`GuidingError` otherwise).
    #[pyo3(signature = (position, resolution = 64))]
    fn build_cache(&self, position: Rows, resolution: u32) -> PyResult<crate::cache::Cache> {
        let options = guiding::CacheOptions {
            resolution,
            ..guiding::CacheOptions::default()
        };
        crate::cache::Cache::build(position.py(), self, &position, options)
    }

    /// Ends training: the field keeps its parameters and refuses further updates.
    fn stop_training(&mut self) {
        self.inner.stop_training();
    }

    fn __repr__(&self) -> String {
        format!(
            "guiding.Field({} {} {}, generation {})",
            self.representation(),
            self.target(),
            self.size(),
            self.inner.generation()
        )
    }
}

#[pymethods]
impl Batch {
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// The guide-selection probability of every lane, `(n,)` (NASG's learned one, the
    /// preset's constant otherwise).
    fn selection_probability<'py>(&self, py: Python<'py>) -> Column<'py> {
        let c: Vec<f32> = (0..self.inner.len())
            .map(|i| self.inner.selection_probability(i))
            .collect();
        PyArray1::from_vec(py, c)
    }
}
