//! `guiding.BatchRecorder`: the library's wavefront recorder, one call per bounce for all
//! the lanes of a wavefront (each path known by its slot `0 … n−1`).

use crate::arrays::{column, from_rows3, rows, same_lengths, Floats, Indices, Rows};
use crate::field::Field;
use guiding::{BatchRecorder, Continuation, PathVertex};
use guiding_core::sample::TrainingSample;
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;

/// Records a wavefront of paths bounce by bounce and turns them into training samples
/// (`flush_into(field)`); the calls per bounce are those of the library's `BatchRecorder`:
/// `start(n)`; at each hit `add_vertices`; `add_direct` for next-event estimation;
/// `set_continuations` once the continuation is sampled; `scale_continuations` for Russian
/// roulette; `add_escaped_radiance` when a ray leaves the scene; `end()`. Rows whose slot is
/// outside the block are ignored and counted (`ignored_calls`).
#[pyclass(module = "guiding", name = "BatchRecorder")]
#[derive(Default)]
pub struct Recorder {
    inner: BatchRecorder,
    /// The samples of the last `flush_into(…, keep=True)` with their MIS-weighted incident
    /// radiances: what `GuideCache.fit_selection` fits to.
    pub(crate) kept: Vec<TrainingSample>,
    pub(crate) kept_mis: Vec<[f32; 3]>,
}

impl Recorder {
    /// Calls `call(recorder, slots[i], values[i])` for every row, after checking that
    /// `values` (named `what`) has a row per slot.
    fn each<T: Send>(
        &mut self,
        slots: &Indices<'_>,
        values: Vec<T>,
        what: &str,
        mut call: impl FnMut(&mut BatchRecorder, u32, T) -> bool + Send,
    ) -> PyResult<()> {
        let py = slots.py();
        let slots = column(slots);
        same_lengths(&format!("slots, {what}"), &[slots.len(), values.len()])?;
        let rec = &mut self.inner;
        py.allow_threads(|| {
            for (s, v) in slots.iter().zip(values) {
                call(rec, *s, v);
            }
        });
        Ok(())
    }
}

#[pymethods]
impl Recorder {
    #[new]
    fn new() -> Self {
        Self::default()
    }

    /// Starts a block of `n` empty paths (the training samples recorded so far are kept).
    fn start(&mut self, n: usize) {
        self.inner.start(n);
    }

    /// One vertex per row for path `slots[i]`: `position`, `normal`, `wo` `(m, 3)`,
    /// `roughness` `(m,)`, the emitted radiance seen along `wo` `emitted` `(m, 3)` with its MIS
    /// weight `emitted_mis_weight` `(m,)`, and `is_delta` `(m,)` (a delta vertex trains
    /// nothing).
    #[allow(clippy::too_many_arguments)] // one array per field of the vertex
    fn add_vertices(
        &mut self,
        slots: Indices<'_>,
        position: Rows<'_>,
        normal: Rows<'_>,
        wo: Rows<'_>,
        roughness: Floats<'_>,
        emitted: Rows<'_>,
        emitted_mis_weight: Floats<'_>,
        is_delta: PyReadonlyArray1<'_, bool>,
    ) -> PyResult<()> {
        let (p, n, w) = (
            rows(&position, "position")?,
            rows(&normal, "normal")?,
            rows(&wo, "wo")?,
        );
        let (r, e) = (column(&roughness), rows(&emitted, "emitted")?);
        let (mis, delta) = (column(&emitted_mis_weight), column(&is_delta));
        let names = "position, normal, wo, roughness, emitted, emitted_mis_weight, is_delta";
        let lengths = [
            p.len(),
            n.len(),
            w.len(),
            r.len(),
            e.len(),
            mis.len(),
            delta.len(),
        ];
        same_lengths(names, &lengths)?;
        let vertices: Vec<PathVertex> = (0..p.len())
            .map(|i| PathVertex {
                position: p[i],
                normal: n[i],
                wo: w[i],
                roughness: r[i],
                emitted: e[i],
                emitted_mis_weight: mis[i],
                is_delta: delta[i],
                ..PathVertex::default()
            })
            .collect();
        self.each(&slots, vertices, "position", BatchRecorder::add_vertex)
    }

    /// Adds next-event radiance `rgb` `(m, 3)` (MIS-weighted, leaving the vertex along `wo`,
    /// not multiplied by the path throughput) to the last vertex of `slots[i]`.
    fn add_direct(&mut self, slots: Indices<'_>, rgb: Rows<'_>) -> PyResult<()> {
        let rgb = rows(&rgb, "rgb")?;
        self.each(&slots, rgb, "rgb", BatchRecorder::add_direct)
    }

    /// The sampled continuation of the last vertex of `slots[i]`: unit `wi` `(m, 3)`, the
    /// density it was sampled with `sample_pdf` `(m,)` (0 ends the path), the BSDF's density
    /// `bsdf_pdf` `(m,)` and `bsdf_cos` = `f · |cos|` `(m, 3)` (not divided by a pdf).
    fn set_continuations(
        mut slf: PyRefMut<'_, Self>,
        slots: Indices<'_>,
        wi: Rows<'_>,
        sample_pdf: Floats<'_>,
        bsdf_pdf: Floats<'_>,
        bsdf_cos: Rows<'_>,
    ) -> PyResult<()> {
        let (wi, f) = (rows(&wi, "wi")?, rows(&bsdf_cos, "bsdf_cos")?);
        let (pdf, bpdf) = (column(&sample_pdf), column(&bsdf_pdf));
        let lengths = [wi.len(), pdf.len(), bpdf.len(), f.len()];
        same_lengths("wi, sample_pdf, bsdf_pdf, bsdf_cos", &lengths)?;
        let continuations: Vec<Continuation> = wi
            .into_iter()
            .zip(pdf)
            .zip(bpdf)
            .zip(f)
            .map(|(((wi, sample_pdf), bsdf_pdf), bsdf_cos)| Continuation {
                wi,
                sample_pdf,
                bsdf_pdf,
                bsdf_cos,
            })
            .collect();
        slf.each(&slots, continuations, "wi", BatchRecorder::set_continuation)
    }

    /// Multiplies the continuation of `slots[i]` by `factor[i]` (`1 / q` after Russian
    /// roulette survived with probability `q`).
    fn scale_continuations(&mut self, slots: Indices<'_>, factor: Floats<'_>) -> PyResult<()> {
        let factor = column(&factor);
        self.each(&slots, factor, "factor", BatchRecorder::scale_continuation)
    }

    /// Radiance `rgb` `(m, 3)` that reached `slots[i]` along its last `wi` from outside the
    /// scene, with its MIS weight `mis` `(m,)`.
    fn add_escaped_radiance(&mut self, slots: Indices, rgb: Rows, mis: Floats) -> PyResult<()> {
        let (rgb, mis) = (rows(&rgb, "rgb")?, column(&mis));
        same_lengths("rgb, mis", &[rgb.len(), mis.len()])?;
        let escaped: Vec<([f32; 3], f32)> = rgb.into_iter().zip(mis).collect();
        self.each(&slots, escaped, "rgb", |r, s, (c, m)| {
            r.add_escaped_radiance(s, c, m)
        })
    }

    /// Ends the block: its training samples are made; returns every path's radiance estimate
    /// `L̃_o(0)`, `(n, 3)`.
    fn end<'py>(&mut self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f32>> {
        let rec = &mut self.inner;
        let est = py.allow_threads(|| rec.end().to_vec());
        from_rows3(py, &est)
    }

    /// Hands the recorded samples to `field` (which validates them); returns how many. With
    /// `keep`, the recorder keeps a copy of them (replacing the last one kept) for
    /// `GuideCache.fit_selection`.
    #[pyo3(signature = (field, keep = false))]
    fn flush_into(&mut self, py: Python<'_>, mut field: PyRefMut<'_, Field>, keep: bool) -> usize {
        let (rec, f) = (&mut self.inner, &mut field.inner);
        let (kept, kept_mis) = (&mut self.kept, &mut self.kept_mis);
        py.allow_threads(|| {
            if keep {
                kept.clear();
                kept.extend_from_slice(rec.samples());
                kept_mis.clear();
                kept_mis.extend_from_slice(rec.mis_radiance());
            }
            rec.flush_into(f)
        })
    }

    /// Samples kept by the last `flush_into(…, keep=True)`.
    #[getter]
    fn kept_samples(&self) -> usize {
        self.kept.len()
    }

    /// Training samples recorded and not yet handed over.
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Calls ignored because their slot was outside the block or had no vertex.
    #[getter]
    fn ignored_calls(&self) -> u64 {
        self.inner.ignored_calls()
    }
}
