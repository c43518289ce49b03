//! Guided Russian roulette and splitting (`--rr guided`): the wavefront's use of the library's
//! weight window ([`guiding::WeightWindow`], ADRRS).
//!
//! * **Where the window decides.** Past the camera vertex (there `m = L_r / I` is 1 for exact
//!   estimates, so only their errors could move it) and at Lambertian vertices (`diffuse`,
//!   `roughdiffuse`): the grid's estimate ignores `ω_o`, which a glossy lobe's reflected light
//!   does not. On `veach-mis` (glossy plates; 20 s, 256 px, 2 seeds) deciding everywhere made
//!   `pt-nee-grr` 1.17× `pt-nee`'s relMSE, these two rules 1.08×.
//! * **What a path is weighed by.** At each such vertex, before NEE and direction sampling, the
//!   driver asks the window for a [`guiding::Decision`] from the path's throughput `β`, the
//!   vertex's reflected radiance `L̂` from a [`guiding::RadianceGrid`] and the pixel's value `Î`
//!   ([`guiding::pixel_estimates`]: the running mean over the passes so far, box-filtered over
//!   5 × 5 pixels). Zero continuations end the path, one goes on with its weight (roulette),
//!   `k > 1` put `k` copies of the vertex in the bounce's batch, each with `β / k`; each copy
//!   runs its own NEE and samples its own direction, and all add to the same pixel.
//! * **When the grid learns.** In the library's training phase ([`guiding::TrainingSchedule`]
//!   with the default options: the first fifth of the budget, the guide's own training phase):
//!   the driver records every path of those passes (whatever the strategy) and adds each
//!   continuing vertex's reflected radiance ([`guiding::BatchRecorder::keep_reflected`]) to the
//!   grid after each piece; then the grid is frozen. Recording in every pass instead cost more
//!   than the better estimates gained (`builtin:door`, 20 s, 160 px, 3 seeds: `pt-nee-grr`
//!   relMSE 0.061 against 0.054, `npm-radiance-grr` 0.047 against 0.039).
//! * **Splitting while recording.** The recorder follows one path per slot: after a split only
//!   the first copy is recorded (`tracked` in the queues), with no `1/k` on its continuation:
//!   one copy's estimate of the vertex's reflected radiance is unbiased by itself. So the
//!   window splits in every pass, the training passes of a guide included.
//! * **Caps.** At most [`guiding::WeightWindow::max_split`] continuations per vertex and
//!   [`MAX_PATHS_PER_SAMPLE`] paths per camera sample (so a block's queues hold at most that
//!   many times its pixels, which also caps the paths of a pass).
//!
//! `--rr efficiency` swaps ADRRS's `m = Y(β ⊙ L̂)/Î` for the efficiency-aware
//! `m = √(Y(β² ⊙ M)/σ²)` ([`guiding::WeightWindow::efficiency_continuations`]: the grid's second
//! moment against the pixel's variance, [`guiding::pixel_variances`]); measured on the suite it
//! lost to ADRRS on three scenes of five (see `docs/bench-2026-12-07-roulette`), so `guided` is
//! ADRRS.
//!
//! Every decision keeps the estimator unbiased (see [`guiding::roulette`]); `--stats` shows
//! what the window did ([`RouletteStats`]).

use crate::render::options::{RenderOptions, Roulette};
use crate::scene::Scene;
use guiding::{
    Budget, GridOptions, GridStats, GuidingError, RadianceGrid, ReflectedSample, ScheduleOptions,
    TrainingSchedule, WeightWindow,
};

/// The most paths one camera sample may become by splitting.
pub const MAX_PATHS_PER_SAMPLE: u32 = 16;

/// Radius of the box filter of the pixel estimates (5 × 5 pixels). On `builtin:door` (20 s,
/// 160 px, 3 seeds) a filter that shrinks to one pixel once 16 passes are in made `pt-nee-grr`
/// 0.061 (against 0.054) and radius 6 made it 0.058: a noisy `Î` splits paths where the pixel
/// only looks dark, a wide one blurs the lit edges.
pub const PIXEL_FILTER_RADIUS: u32 = 2;

/// What the window did in a render.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RouletteStats {
    /// Vertices the window decided on.
    pub decisions: u64,
    /// Of those, where the grid or the pixel had no estimate (the path went on untouched).
    pub missing: u64,
    /// Paths ended by roulette.
    pub killed: u64,
    /// Paths that survived a roulette (weight `1/m > 1`).
    pub survived: u64,
    /// Vertices split into `k > 1` continuations.
    pub split_vertices: u64,
    /// Continuations added by splitting (`Σ (k − 1)`).
    pub extra_paths: u64,
    /// The largest `k` of one vertex.
    pub max_split: u32,
    /// Passes in which the grid learned (recorded, no splitting).
    pub learning_passes: u32,
    /// The grid at the end of the render.
    pub grid: GridStats,
}

impl RouletteStats {
    /// Mean continuations of a split vertex (0 without splits).
    pub fn mean_split(&self) -> f64 {
        if self.split_vertices == 0 {
            0.0
        } else {
            1.0 + self.extra_paths as f64 / self.split_vertices as f64
        }
    }

    /// Adds a worker's counters.
    pub(crate) fn merge(&mut self, other: &RouletteStats) {
        self.decisions += other.decisions;
        self.missing += other.missing;
        self.killed += other.killed;
        self.survived += other.survived;
        self.split_vertices += other.split_vertices;
        self.extra_paths += other.extra_paths;
        self.max_split = self.max_split.max(other.max_split);
    }
}

/// The guided roulette's state: read by the workers during a piece of a pass, updated by the
/// driver between pieces.
pub(crate) struct GuidedRoulette {
    pub window: WeightWindow,
    pub grid: RadianceGrid,
    /// Per pixel (row-major), `Î` (the adjoint rule) or `σ²` (the efficiency rule).
    pub pixel: Vec<f32>,
    /// The efficiency-aware rule instead of ADRRS's.
    pub efficiency: bool,
    /// The grid learns in this pass (recorded, no splitting).
    pub learning: bool,
    /// The negative control: split copies keep the full weight.
    pub unweighted: bool,
    schedule: TrainingSchedule,
    pub stats: RouletteStats,
}

impl GuidedRoulette {
    /// The state for a render of `scene` with `opts` (`None` unless `opts.rr` is guided).
    pub fn new(scene: &Scene, opts: &RenderOptions) -> Result<Option<Self>, GuidingError> {
        if !opts.rr.is_guided() {
            return Ok(None);
        }
        let (lo, hi) = scene.bounds();
        let budget = match opts.time_budget {
            Some(t) => Budget::Seconds(t.as_secs_f64()),
            None => Budget::Spp(opts.spp),
        };
        Ok(Some(Self {
            window: WeightWindow::default(),
            grid: RadianceGrid::new(lo.to_array(), hi.to_array(), GridOptions::default())?,
            pixel: Vec::new(),
            learning: true,
            unweighted: opts.rr == Roulette::GuidedUnweighted,
            efficiency: opts.rr == Roulette::Efficiency,
            schedule: TrainingSchedule::new(ScheduleOptions::default(), budget)?,
            stats: RouletteStats::default(),
        }))
    }

    /// Before a pass: whether the grid learns in it, and `Î` (or `σ²`) from the passes so far
    /// (`sum`, `sum2`: the per-pixel sums and sums of squares).
    pub fn begin_pass(
        &mut self,
        elapsed: f64,
        pass: u32,
        (width, height): (u32, u32),
        sum: &[[f64; 3]],
        sum2: &[[f64; 3]],
    ) {
        self.learning = self.schedule.in_training_phase(elapsed, pass);
        if self.learning {
            self.stats.learning_passes += 1;
        }
        let r = PIXEL_FILTER_RADIUS;
        let done = if self.efficiency {
            guiding::pixel_variances(width, height, sum, sum2, pass, r, &mut self.pixel)
        } else {
            guiding::pixel_estimates(width, height, sum, pass, r, &mut self.pixel)
        };
        if done.is_err() {
            self.pixel.clear();
        }
    }

    /// After a piece: the reflected radiance the workers recorded.
    pub fn learn(&mut self, samples: &[ReflectedSample]) {
        self.grid.add_samples(samples);
    }

    /// The render's statistics.
    pub fn finish(&self) -> RouletteStats {
        RouletteStats {
            grid: self.grid.stats(),
            ..self.stats
        }
    }
}
