//! What the library reports, as frozen Python objects with one read-only attribute per value
//! (`repr` lists them).

use pyo3::prelude::*;

/// Declares a frozen Python class with one attribute per `name: type = value` (the value an
/// expression of `$r`, the library's report) and its `From<&library type>`.
macro_rules! report_class {
    ($(#[$doc:meta])* $name:ident from $src:ty as $r:ident { $($field:ident: $ty:ty = $value:expr),* $(,)? }) => {
        $(#[$doc])*
        #[pyclass(module = "guiding", get_all, frozen)]
        #[derive(Clone, Debug)]
        pub struct $name { $($field: $ty),* }

        impl From<&$src> for $name {
            fn from($r: &$src) -> Self { Self { $($field: $value),* } }
        }

        #[pymethods]
        impl $name {
            fn __repr__(&self) -> String { format!("guiding.{:?}", self) }
        }
    };
}

report_class! {
    /// One update of a field: Adam steps run and skipped (non-finite gradients), samples
    /// buffered, the minibatch size, the mean loss (`nan` when no step ran), convergence.
    UpdateReport from guiding::UpdateReport as r {
        steps: u32 = r.steps, skipped_steps: u32 = r.skipped_steps, mean_loss: f64 = r.mean_loss,
        buffered_samples: usize = r.buffered_samples, batch_size: usize = r.batch_size,
        converged: bool = r.converged,
    }
}

report_class! {
    /// A field's training counters (`rejected_samples`: all kinds of invalid samples).
    FieldStats from guiding::FieldStats as s {
        steps: u64 = s.steps, skipped_steps: u64 = s.skipped_steps, generation: u64 = s.generation,
        accepted_samples: u64 = s.accepted_samples, ignored_samples: u64 = s.ignored_samples,
        rejected_samples: u64 = s.rejected_samples.iter().sum(), converged: bool = s.converged != 0,
        overflowed_samples: u64 = s.overflowed_samples, buffered_samples: u64 = s.buffered_samples,
        param_count: u64 = s.param_count,
    }
}

report_class! {
    /// What a schedule did: tracing and training seconds of the training phase, Adam steps,
    /// updates, seconds per step (`nan` before any) and training's share of the wall clock.
    ScheduleReport from guiding::ScheduleReport as r {
        traced_seconds: f64 = r.traced_seconds, trained_seconds: f64 = r.trained_seconds,
        steps: u64 = r.steps, updates: u64 = r.updates, seconds_per_step: f64 = r.seconds_per_step,
        training_share: f64 = r.training_share(),
    }
}

report_class! {
    /// What a guide-selection fit found: samples used, cells fitted to their own samples, cells
    /// given the global value, cells fitted to `c = 0` (the guide off), the fit over all
    /// samples (`global_selection`), the mean fitted probability, and the estimated vertex
    /// variance relative to BSDF sampling alone.
    SelectionReport from guiding::SelectionReport as r {
        samples_used: u64 = r.samples_used, cells_fitted: u64 = r.cells_fitted,
        cells_global: u64 = r.cells_global, cells_off: u64 = r.cells_off,
        global_selection: f32 = r.global,
        mean: f32 = r.mean, variance_ratio: f64 = r.variance_ratio,
    }
}
