//! What to render: the estimator, the sample budget, depth, threads, seed and image size.

use crate::scene::Scene;

/// Which estimator to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntegratorKind {
    /// BSDF sampling only; emission is picked up when a path hits a light.
    Pt,
    /// Next-event estimation (area, point and environment emitters) + BSDF sampling, combined
    /// with the power heuristic.
    PtNee,
}

/// Russian roulette (and splitting) of the wavefront's paths.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Roulette {
    /// Every path goes on to `max_depth` (the papers' setting; the default).
    #[default]
    Off,
    /// Mitsuba's rule from the scene's `rr_depth` on: survival probability
    /// `min(max(throughput), 0.95)`.
    Throughput,
    /// The library's weight window (ADRRS, [`guiding::WeightWindow`]) at every vertex:
    /// roulette and splitting by the path's expected contribution against its pixel's, from a
    /// [`guiding::RadianceGrid`] learned in the library's training phase (see
    /// [`crate::render::roulette`]).
    Guided,
    /// The efficiency-aware rule ([`guiding::WeightWindow::efficiency_continuations`]): the
    /// path's second moment against the pixel's variance instead of its mean against the
    /// pixel's value; the same grid, window and caps as [`Roulette::Guided`].
    Efficiency,
    /// [`Roulette::Guided`] with the split continuations' weights *not* divided by `k`: a
    /// biased estimator, the negative control of the unbiasedness tests.
    #[doc(hidden)]
    GuidedUnweighted,
}

impl Roulette {
    /// Whether the guided rule (or its negative control) runs.
    pub fn is_guided(self) -> bool {
        matches!(
            self,
            Roulette::Guided | Roulette::Efficiency | Roulette::GuidedUnweighted
        )
    }
}

/// Render parameters.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    /// Estimator.
    pub integrator: IntegratorKind,
    /// Samples per pixel (passes) when `time_budget` is `None`.
    pub spp: u32,
    /// Render passes until this much wall time is used instead of a fixed spp
    /// (see [`crate::render::schedule`]).
    pub time_budget: Option<std::time::Duration>,
    /// Russian roulette and splitting; off by default, unbiased in every mode.
    pub rr: Roulette,
    /// With a time budget and a guided rule: the window's efficiency trial after the learning
    /// phase ([`crate::render::roulette`]); off, the window decides in every pass.
    pub rr_trial: bool,
    /// Show a progress bar on stderr (only when stderr is a terminal).
    pub progress: bool,
    /// Mitsuba max_depth.
    pub max_depth: u32,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Random seed.
    pub seed: u64,
    /// Override the image width/height (0 = scene's).
    pub width: u32,
    /// Override the image height (0 = scene's).
    pub height: u32,
}

impl Default for RenderOptions {
    /// `pt-nee`, 16 spp, depth 8, all cores, seed 0, the scene's image size, no RR, no bar.
    fn default() -> Self {
        Self {
            integrator: IntegratorKind::PtNee,
            spp: 16,
            time_budget: None,
            rr: Roulette::Off,
            rr_trial: true,
            progress: false,
            max_depth: 8,
            threads: 0,
            seed: 0,
            width: 0,
            height: 0,
        }
    }
}

impl RenderOptions {
    /// Image size: the override, else the scene's.
    pub fn resolution(&self, scene: &Scene) -> (u32, u32) {
        let w = if self.width > 0 {
            self.width
        } else {
            scene.settings.width
        };
        let h = if self.height > 0 {
            self.height
        } else {
            scene.settings.height
        };
        (w, h)
    }

    /// Worker threads (`0` = all cores).
    pub fn thread_count(&self) -> usize {
        if self.threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            self.threads
        }
    }
}
