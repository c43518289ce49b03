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
//! * **When the grid learns.** With a guide, in the passes the guide records for its training
//!   ([`crate::render::strategy::Strategy::trains_from_recorded_passes`]), whose paths are
//!   recorded anyway: the grid stops learning when the guide stops training (the training
//!   phase's end, a converged loss, or the training probe's look ending it). Until 2026-12-07
//!   the grid kept its own phase, the first fifth of the budget, and the render recorded every
//!   path for the grid alone after the look had ended the guide's training: on the suite's
//!   scenes whose guide does not pay (30 s, 256 px, 3 seeds) 58–64 of the Cornell box's ~400
//!   passes and 219–258 of veach-mis's ~1600 were recorded where the guide trained in 7–8 and
//!   28–35, and `guided-grr` came out 1.04× `guided` there. Without a guide (`pt-nee --rr
//!   guided`), in the library's training phase ([`guiding::TrainingSchedule`] with the default
//!   options: the first fifth of the budget). In those passes the driver records every path
//!   and adds each
//!   continuing vertex's reflected radiance ([`guiding::BatchRecorder::keep_reflected`]) to the
//!   grid after each piece; then the grid is frozen. Recording in every pass instead cost more
//!   than the better estimates gained (`builtin:door`, 20 s, 160 px, 3 seeds: `pt-nee-grr`
//!   relMSE 0.061 against 0.054, `npm-radiance-grr` 0.047 against 0.039).
//! * **Splitting while recording.** The recorder follows one path per slot: after a split only
//!   the first copy is recorded (`tracked` in the queues), with no `1/k` on its continuation:
//!   one copy's estimate of the vertex's reflected radiance is unbiased by itself. So the
//!   window may split in every pass, the training passes of a guide included (without a time
//!   budget, or with `--rr-trial off`).
//! * **Is the window worth it?** With a time budget the window does not decide while the grid
//!   learns (nothing shows yet that it pays); then the passes run with and without it in the
//!   order of [`guiding::WindowTrial`] (without: the paths go on as `--rr off` would take
//!   them), which compares relMSE per pass × seconds per pass on the image: the window stays
//!   for the rest of the render when the interval of that ratio lies below 1, goes when it
//!   lies above, and while it straddles the cheaper-looking arm runs two passes of three
//!   (`--rr-trial off`: the window in every pass, the learning passes included). The trial
//!   starts only once the strategy's estimator is settled
//!   ([`crate::render::strategy::Strategy::estimator_settled`]: the guide's own efficiency
//!   trial has had its first look, so it has a verdict or goes on between two arms it found
//!   alike); until then the window is off (`waited_passes` in `--stats`). Run beside the
//!   guide's first passes, half of each of its arms' passes were unguided: on `builtin:door`
//!   (20 s, 256 px, 3 seeds) it measured the window at 0.50–0.61 of the plain passes' cost,
//!   about its gain on `pt-nee` (0.72x), while the guided image with the window came out at
//!   1.00x the guided image without it (after the wait: 0.86x). Waiting for the guide's
//!   verdict instead of its first look cost the scenes whose guide trial goes on (classroom:
//!   the window 0.91x against 0.65x). The grid
//!   learns in the learning passes only, from paths the window did not touch. On the Cornell
//!   box (20 s, 256 px, 2 seeds) the window in every pass made `pt-nee`'s relMSE 1.25× worse;
//!   the trial switches it off after 2 + 2 passes. Without a time budget (a fixed spp, the
//!   unbiasedness tests) the window decides in every pass.
//! * **Caps.** At most [`guiding::WeightWindow::max_split`] continuations per vertex and
//!   [`MAX_PATHS_PER_SAMPLE`] paths per camera sample (so a block's queues hold at most that
//!   many times its pixels, which also caps the paths of a pass).
//!
//! `--rr efficiency` swaps ADRRS's `m = Y(β ⊙ L̂)/Î` for the efficiency-aware rule
//! ([`guiding::WeightWindow::efficiency_continuations`]: the grid's variance and second moment
//! against the pixel's variance, [`guiding::pixel_variances`]); measured on the suite it did
//! not beat ADRRS (see `docs/bench-2026-12-07-roulette`), so `guided` is ADRRS.
//!
//! Every decision keeps the estimator unbiased (see [`guiding::roulette`]); `--stats` shows
//! what the window did ([`RouletteStats`]).

use crate::render::image::mean_image;
use crate::render::options::{RenderOptions, Roulette};
use crate::scene::Scene;
use guiding::{
    Budget, GridOptions, GridStats, GuidingError, RadianceGrid, ReflectedSample, ScheduleOptions,
    TrainingSchedule, TrialOptions, TrialVerdict, WeightWindow, WindowTrial,
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
    /// Passes of the window's efficiency trial (both arms).
    pub trial_passes: u32,
    /// Passes that ran without the window with a time budget (the learning passes, the passes
    /// that waited for the guide trial's first look, the trial passes of its "off" arm, and
    /// every pass after a verdict that it does not pay).
    pub window_off_passes: u32,
    /// Of those, the passes after the learning phase that waited for the strategy's estimator
    /// to settle (the guide's efficiency trial to have its first look) before the window's
    /// trial began.
    pub waited_passes: u32,
    /// The trial's verdict, at its first look ([`WindowTrial::window_pays`]: what it decided).
    pub verdict: Option<TrialVerdict>,
    /// A trial still running when the render ended: its estimate from all its passes.
    pub latest: Option<TrialVerdict>,
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
    /// The window applies in the current pass (always without a time budget or with
    /// `--rr-trial off`; else not while the grid learns, then as its trial says).
    pub active: bool,
    /// A time budget: the window's efficiency trial runs after the learning phase.
    timed: bool,
    /// The window's trial (created at the first pass after the learning phase).
    trial: Option<WindowTrial>,
    /// The current pass is a trial pass.
    in_trial: bool,
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
            active: true,
            timed: opts.time_budget.is_some() && opts.rr_trial,
            trial: None,
            in_trial: false,
        }))
    }

    /// Before a pass: whether the grid learns in it, and `Î` (or `σ²`) from the passes so far
    /// (`sum`, `sum2`: the per-pixel sums and sums of squares); `settled`: whether the
    /// strategy's estimator is settled ([`crate::render::strategy::Strategy::estimator_settled`]);
    /// `strategy_records`: for a strategy that trains from recorded passes
    /// ([`crate::render::strategy::Strategy::trains_from_recorded_passes`]), whether it records
    /// this one (the grid then learns exactly when the guide does).
    pub fn begin_pass(
        &mut self,
        elapsed: f64,
        pass: u32,
        (width, height): (u32, u32),
        sum: &[[f64; 3]],
        sum2: &[[f64; 3]],
        (settled, strategy_records): (bool, Option<bool>),
    ) {
        self.learning = match strategy_records {
            Some(records) => records,
            None => self.schedule.in_training_phase(elapsed, pass),
        };
        if self.learning {
            self.stats.learning_passes += 1;
        }
        self.plan_trial_pass(pass, (width, height), sum, settled);
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

    /// Whether the window applies in this pass: always without a time budget; with one, not
    /// while the grid learns or the strategy's estimator is not settled, then what
    /// the [`WindowTrial`] says (see the [module docs](self)).
    fn plan_trial_pass(
        &mut self,
        pass: u32,
        (width, height): (u32, u32),
        sum: &[[f64; 3]],
        settled: bool,
    ) {
        self.in_trial = false;
        self.active = true;
        if !self.timed {
            return;
        }
        if self.learning || pass == 0 {
            // No evidence yet that the window pays: the grid learns from plain paths.
            self.active = false;
            self.stats.window_off_passes += 1;
            return;
        }
        if self.trial.is_none() {
            if !settled {
                // The guide's trial has not looked yet: the window's trial waits for the
                // estimator that will render the rest of the image.
                self.active = false;
                self.stats.window_off_passes += 1;
                self.stats.waited_passes += 1;
                return;
            }
            // Weighted by the image before the trial (the mean of the passes so far).
            let mean = mean_image(sum, pass);
            let (w, h) = (width as usize, height as usize);
            match WindowTrial::new(w, h, &mean, TrialOptions::default()) {
                Ok(t) => self.trial = Some(t),
                Err(_) => {
                    self.timed = false;
                    return;
                }
            }
        }
        if let Some(t) = &self.trial {
            self.active = t.next_pass_uses_window();
            self.in_trial = t.running();
        }
        if !self.active {
            self.stats.window_off_passes += 1;
        }
    }

    /// Whether the pass just traced is a trial pass ([`Self::end_pass`] wants its image).
    pub fn wants_pass_image(&self) -> bool {
        self.in_trial
    }

    /// After a pass: a trial pass's pixel values (row-major) and seconds go to the trial.
    pub fn end_pass(&mut self, pixels: &[[f32; 3]], seconds: f64) {
        let Some(trial) = self.trial.as_mut().filter(|_| self.in_trial) else {
            return;
        };
        if trial.record(self.active, pixels, seconds).is_err() {
            // Cannot happen for passes of the trial's own size and order; the window then
            // stays on.
            self.trial = None;
            self.timed = false;
            return;
        }
        self.stats.trial_passes = trial.passes();
        self.stats.verdict = trial.verdict();
    }

    /// After a piece: the reflected radiance the workers recorded.
    pub fn learn(&mut self, samples: &[ReflectedSample]) {
        self.grid.add_samples(samples);
    }

    /// The render's statistics.
    pub fn finish(&self) -> RouletteStats {
        RouletteStats {
            grid: self.grid.stats(),
            latest: self
                .trial
                .as_ref()
                .filter(|t| t.running())
                .and_then(WindowTrial::current),
            ..self.stats
        }
    }
}
