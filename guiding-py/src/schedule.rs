//! `guiding.Schedule`: the library's training schedule (what `host-demo` and the C ABI use).

use crate::py_err;
use crate::reports::ScheduleReport;
use guiding::{Budget, ScheduleOptions, TrainingSchedule};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// When a render trains and how many Adam steps each update runs, from what the renderer
/// reports: `Schedule(spp=…)` or `Schedule(seconds=…)` (exactly one), `train_fraction` the
/// share of that budget in the training phase (the library's default when `None`), and
/// `training_share` the share of the training phase's wall clock given to Adam steps.
#[pyclass(module = "guiding", name = "Schedule")]
pub struct Schedule {
    pub(crate) inner: TrainingSchedule,
}

#[pymethods]
impl Schedule {
    #[new]
    #[pyo3(signature = (spp = None, seconds = None, train_fraction = None, training_share = None))]
    fn new(
        spp: Option<u32>,
        seconds: Option<f64>,
        train_fraction: Option<f64>,
        training_share: Option<f64>,
    ) -> PyResult<Self> {
        let budget = match (spp, seconds) {
            (Some(n), None) => Budget::Spp(n),
            (None, Some(s)) => Budget::Seconds(s),
            _ => {
                return Err(PyValueError::new_err(
                    "Schedule: give exactly one of spp and seconds",
                ))
            }
        };
        let mut options = ScheduleOptions::DEFAULT;
        if let Some(f) = train_fraction {
            options.train_fraction = f;
        }
        if let Some(share) = training_share {
            options.steps = guiding::StepRule::TimeShare(share);
        }
        let inner = TrainingSchedule::new(options, budget).map_err(py_err)?;
        Ok(Self { inner })
    }

    /// Whether the pass `pass_index` (from 0), starting `elapsed` seconds into the render,
    /// belongs to the training phase.
    fn in_training_phase(&mut self, elapsed: f64, pass_index: u32) -> bool {
        self.inner.in_training_phase(elapsed, pass_index)
    }

    /// Ends the training phase now.
    fn end_training(&mut self) {
        self.inner.end_training();
    }

    /// Whether the training phase is over.
    #[getter]
    fn training_over(&self) -> bool {
        self.inner.training_over()
    }

    /// Reports `seconds` of tracing that produced `paths` paths (training phase).
    fn record_traced(&mut self, seconds: f64, paths: u64) {
        self.inner.record_traced(seconds, paths);
    }

    /// What the schedule did.
    fn report(&self) -> ScheduleReport {
        ScheduleReport::from(&self.inner.report())
    }
}
