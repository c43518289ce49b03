//! Guided path tracing: the `guided` integrator.
//!
//! A [`Strategy`] of the one [wavefront driver](crate::render::wavefront): the driver does
//! intersection, emission, NEE, the shadow rays and the continuation; this strategy decides
//! the directions and trains the guide between passes. Per bounce:
//!
//! 1. **prepare**: *guidable* vertices (non-delta and not near-specular: diffuse always,
//!    rough conductors with `alpha ≥` [`GuidedOptions::min_alpha`]) are queried in one
//!    batched decode ([`GuidingField::decode_batch`]; one network pass per vertex for NPM /
//!    NASG, the grid and marginal for DF), and each gets its guide-selection probability `c`;
//! 2. **light pdfs** (NEE's MIS partner): the combined density
//!    `p(ω) = c·q(ω) + (1 − c)·p_bsdf(ω)` of every light direction, the guide pdfs in one
//!    batched call on the decoded distributions;
//! 3. **sample**: a guidable vertex picks the guide with probability `c`, else the BSDF; the
//!    guide samples and the guide pdfs of the BSDF-picked directions are one batched call
//!    each, and the weight is `f·cos / p(ω)` with the same combined density (one-sample MIS
//!    of guide and BSDF), so every pass is unbiased whatever the state of the guide.
//!
//! Scattering points inside media are guidable too ([`GuidedOptions::guide_media`]): queried
//! with a zero normal (the guide over the whole sphere), an NPM lane multiplied by the vMF fit
//! of the phase function ([`GuidedOptions::phase_product`]), the phase function in the BSDF's
//! place in the MIS. A render that guides them runs without the cosine product and the
//! per-cell selection fit ([`crate::render::render_guided`]).
//!
//! # Training
//!
//! The library's [`TrainingSchedule`] decides when: the passes that start in the first
//! `train_fraction` of the budget record every path, and each guidable vertex that continued
//! its path becomes a [`TrainingSample`] through `guiding`'s recorder, whose propagation rule is
//! documented there: the training radiance of vertex `k` counts the emission found along its
//! direction in full (with NEE, the MIS-weighted emission alone is only the BSDF share of the
//! direct light) and everything scattered further down the path with its MIS weights.
//! Directions that miss the scene give radiance 0 and are kept (DF's radiance cache must
//! learn zeros). A training pass is traced in pieces of rows spread over the image, as many
//! paths as the schedule asks for (about a quarter of a second of tracing), and after each
//! piece its samples go to [`GuidingField::add_samples`] in row order and the schedule says how
//! many Adam steps are due ([`TrainingSchedule::steps_due`]: a third of the training phase's
//! wall clock by default, however slow or fast a pass is). Training stops early when the loss
//! has converged (a plateau); after the training phase [`GuidingField::stop_training`] is
//! called and nothing is recorded any more. The training passes stay in the image (each is
//! an unbiased estimate, whichever guides its pieces used).
//!
//! # Guide cache
//!
//! With [`GuidedOptions::cache`] a radiance-target guide is answered from a
//! [`GuideCache`] (the decoded guide per occupied cell of a fine spatial grid, looked up with
//! a stochastic trilinear jitter drawn from the path's random stream) instead of one network
//! pass per vertex: [`CacheMode::Frozen`] builds it when training stops, from the positions of
//! the last training pass, [`CacheMode::Always`] also during training (refreshed after every
//! update). A vertex with no cell near it is decoded by the network, and its position is added
//! to the cache after the pass. With the cosine product the cache stores it per normal bin,
//! so a cached vertex pays neither the network nor the product. Product-target guides depend
//! on `ωo`, the normal and the roughness: they never use the cache (`--stats` says so).
//!
//! When training stops, [`GuidedOptions::fit_selection`] fits the guide-selection probability
//! per cache cell to the last training pass ([`GuideCache::fit_selection`]: the candidate of
//! `0, 0.1, …, 0.9` with the least estimated second moment, from the samples' MIS-weighted
//! incident radiance); a vertex whose cell is fitted to `c = 0` is sampled by its BSDF alone
//! and pays no guide sample or pdf.
//!
//! # Efficiency trial
//!
//! With a time budget ([`GuidedOptions::efficiency_trial`]), once training has stopped and one
//! warm-up pass has run, the next passes alternate the guided estimator and the same
//! integrator with the guide off (BSDF sampling and NEE: `pt-nee`'s estimator), 4 each (2 in a
//! clear case; never without NEE), and a
//! [`GuideTrial`] compares their relMSE per pass times seconds per pass on the image itself.
//! If the guide does not pay it stays off for the rest of the render (no lookup, sample or
//! pdf: the cost of `pt-nee`); `--stats` shows the two costs and the verdict. When the first
//! look's interval straddles 1 the guide stays on, the selection probabilities are refitted
//! and the trial continues with the refitted guide's passes (the guided arm restarted), two
//! passes of the cheaper-looking arm per pass of the other, until its interval excludes 1 or
//! the render ends ([`TrialOptions::continuation`]). Every trial pass is unbiased and stays in
//! the image.
//!
//! Radiance-target guides are sampled directly (the learned incident-radiance distribution,
//! times the cosine with [`GuidedOptions::cosine_product`]) instead of the product with the
//! BSDF: still unbiased through the combined density, just less efficient on glossy surfaces.

use crate::math::{Frame, Rng};
use crate::render::image::{mean_image, RenderStats};
use crate::render::queues::{
    Continuations, GuidePdfQueue, GuideSampleQueue, LightSamples, Vertices,
};
use crate::render::schedule::Pass;
use crate::render::strategy::bsdf::sample_bsdf;
use crate::render::strategy::guide::describe;
use crate::render::strategy::probe::ProbeStats;
use crate::render::strategy::{
    CombinedImage, PassImage, PassSamples, Strategy, Traced, VertexStrategy,
};
use crate::scene::bsdf::Material;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use guiding::{
    CacheOptions, CombineOptions, DirectionSample, DistributionBatch, GroupWeight, GuideCache,
    GuideTrial, GuidingError, GuidingField, LookDecision, PassCombiner, ScheduleOptions,
    ScheduleReport, TrainingSchedule, TrialArm, TrialOptions, TrialVerdict,
};
use guiding_core::model::QueryPoint;
use guiding_core::sample::TrainingSample;
use std::time::{Duration, Instant};

/// When the guided integrator answers guide queries from a [`GuideCache`] (radiance-target
/// guides on the CPU only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CacheMode {
    /// Every guidable vertex runs the network (one batched decode per bounce).
    Off,
    /// The network during training; the cache once training has stopped.
    Frozen,
    /// The cache in every pass after the first update (refreshed after each update): the
    /// default (on builtin:door at 20 s, relMSE 0.20 against 0.22 frozen).
    #[default]
    Always,
}

/// Options of the guided integrator (beyond [`RenderOptions`](crate::render::RenderOptions)).
#[derive(Clone, Copy, Debug)]
pub struct GuidedOptions {
    /// Next-event estimation on every emitter NEE can sample (pt-nee mode).
    pub nee: bool,
    /// When to train and how much: the library's schedule (training phase, time share of
    /// training, update interval; [`guiding::StepRule::Epochs`] for reproducible training).
    pub schedule: ScheduleOptions,
    /// Guide-selection probability `c` for NPM / DF (NASG learns its own), in `[0, 1]`.
    pub selection_probability: f32,
    /// Rough conductors with a GGX alpha below this are not guided (near-specular).
    pub min_alpha: f32,
    /// Radiance-target vMF guides (NPM) are multiplied by the clamped cosine of the shading
    /// normal before sampling (Open PGL's `ApplyCosineProduct`). Medium vertices have no
    /// normal and no cosine: the library leaves their guide as it is (the cache keeps a lane
    /// without the product for them).
    pub cosine_product: bool,
    /// Scattering points inside media are guided like surface vertices: the guide's
    /// distribution over the whole sphere (their queries and training samples carry a zero
    /// normal: "no surface") in one-sample MIS with the phase function, the selection
    /// probability and the per-cell fit as at surfaces. Off: they sample the phase function.
    pub guide_media: bool,
    /// With `guide_media`: only the media the library's thin-medium rule says are worth it
    /// ([`guiding::media::guides_medium`], see [`crate::render::media_guiding`]); off: every
    /// medium.
    pub thin_media_rule: bool,
    /// At guided medium vertices, NPM guides are multiplied by the vMF fit of the phase
    /// function (Open PGL's product in volumes); off: the guide alone (radiance).
    pub phase_product: bool,
    /// When guide queries are answered from a spatial cache of the decoded guide.
    pub cache: CacheMode,
    /// Cells of the guide cache along the scene box's longest axis.
    pub cache_resolution: u32,
    /// With the cache on (NPM / DF): when training stops, fit the guide-selection probability
    /// per cell to the last training pass's samples and their MIS-weighted radiances
    /// ([`GuideCache::fit_selection`]) instead of the constant `selection_probability`; a
    /// cell fitted to `c = 0` skips the guide's sample and pdfs.
    pub fit_selection: bool,
    /// With a time budget: once training has stopped (after one warm-up pass), run the
    /// guided / unguided [`GuideTrial`] (alternating passes, the efficiency `V · t` of each on
    /// the image) and switch the guide off for the rest of the render when it does not pay.
    /// spp-budget renders never run it (at equal samples the guide is judged per sample), nor
    /// renders without NEE: the unguided arm is then BSDF sampling alone, and on
    /// `builtin:door` its 4 trial passes among 77 were about a quarter of the image's relMSE.
    pub efficiency_trial: bool,
    /// Combine the passes with inverse-variance weights ([`guiding::PassCombiner`]): each
    /// training pass is a group of its own (its guide is new), the guided and the unguided
    /// passes after training are one group each. Off: the plain mean of all passes.
    pub weight_passes: bool,
    /// With the efficiency trial on: the [training probe](super::probe) (an early look a
    /// quarter of the way into the training phase, guided against unguided passes at the
    /// guide's cost after training; training goes on only for a guide that already looks
    /// cheaper than none on evidence: an interval below 1).
    pub training_probe: bool,
    /// Test hooks (feature `testing`, which only the test crates enable).
    #[cfg(feature = "testing")]
    #[doc(hidden)]
    pub test_hooks: TestHooks,
}

/// Deliberate defects and forced verdicts for the tests' negative controls (feature
/// `testing`); absent from the library and the binary that renders.
#[cfg(feature = "testing")]
#[doc(hidden)]
#[derive(Clone, Copy, Debug)]
pub struct TestHooks {
    /// Forces every look's decision (whatever its interval says).
    pub probe_force: Option<LookDecision>,
    /// Factor on the guide pdf inside the continuation's combined density (≠ 1 is a
    /// deliberate sample/pdf mismatch, a biased estimator; the power check of
    /// `tests/unbiased.rs` uses it).
    pub guide_pdf_scale: f32,
}

#[cfg(feature = "testing")]
impl Default for TestHooks {
    fn default() -> Self {
        Self {
            probe_force: None,
            guide_pdf_scale: 1.0,
        }
    }
}

impl GuidedOptions {
    /// Whether these options guide the scattering points of medium `m`: `guide_media`, and the
    /// thin-medium rule keeps it or is off.
    #[must_use]
    pub fn guides_medium(&self, m: &crate::render::MediumGuiding) -> bool {
        self.guide_media && (m.guided || !self.thin_media_rule)
    }
}

impl Default for GuidedOptions {
    fn default() -> Self {
        Self {
            nee: true,
            schedule: ScheduleOptions::DEFAULT,
            selection_probability: guiding::config::PRESET_SELECTION_PROBABILITY,
            min_alpha: 0.05,
            cosine_product: true,
            guide_media: true,
            thin_media_rule: true,
            phase_product: true,
            cache: CacheMode::Always,
            cache_resolution: CacheOptions::default().resolution,
            fit_selection: true,
            efficiency_trial: true,
            weight_passes: true,
            training_probe: true,
            #[cfg(feature = "testing")]
            test_hooks: TestHooks::default(),
        }
    }
}

/// What a guided render did.
#[derive(Clone, Debug, Default)]
pub struct GuidedStats {
    /// NEE ran.
    pub nee: bool,
    /// The guide's description.
    pub model: String,
    /// The Vulkan device the guide ran on (`--device gpu`), `None` on the CPU.
    pub device: Option<String>,
    /// Passes rendered in total / with training.
    pub passes: u32,
    /// Passes whose vertices were recorded and trained on.
    pub training_passes: u32,
    /// Passes the schedule gave to training (more than `training_passes` when the loss
    /// converged first).
    pub passes_planned_for_training: u32,
    /// Guide queries (selection + sample + pdf evaluations).
    pub guide_queries: u64,
    /// Guide queries during the training passes.
    pub guide_queries_training: u64,
    /// Guidable vertices (guide-or-BSDF decisions).
    pub guided_vertices: u64,
    /// Training samples recorded (all passes).
    pub samples_recorded: u64,
    /// Training samples recorded after the training passes (must be 0).
    pub samples_recorded_after_training: u64,
    /// Adam steps applied (total).
    pub training_steps: u64,
    /// Adam steps applied after training stopped (must be 0).
    pub training_steps_after_training: u64,
    /// Training samples the field rejected.
    pub rejected_samples: u64,
    /// Training samples dropped because the field's buffer was full.
    pub overflowed_samples: u64,
    /// Mean training loss of the last update (`NaN` if none).
    pub last_loss: f64,
    /// Mean training loss of every update, in order.
    pub loss_history: Vec<f64>,
    /// The first training pass skipped because the loss had converged (plateau), if any.
    pub converged_at_pass: Option<u32>,
    /// Wall time of the rendering passes (includes the guide queries).
    pub trace: Duration,
    /// Wall time of the whole render (passes, training, cache, the per-pass bookkeeping and
    /// the final combination).
    pub wall: Duration,
    /// Thread time spent in guide queries, summed over the render threads.
    pub query: Duration,
    /// Wall time of recording back-propagation + `add_samples` + `update`.
    pub training: Duration,
    /// Rays traced (closest-hit and shadow).
    pub rays: u64,
    /// Scattering points inside media.
    pub medium_vertices: u64,
    /// Of those, the guided ones (the media the thin-medium rule keeps, see
    /// [`crate::render::media_guiding`]; in every pass with the guide on).
    pub guided_medium_vertices: u64,
    /// What guided roulette and splitting did (`--rr guided`).
    pub roulette: Option<crate::render::roulette::RouletteStats>,
    /// The guide cache: `None` when off, else why it was not used or its size.
    pub cache: Option<String>,
    /// Guidable vertices answered by the cache / by the network because no cell was near.
    pub cache_hits: u64,
    /// See `cache_hits`.
    pub cache_misses: u64,
    /// Occupied cells of the cache at the end of the render.
    pub cache_cells: u64,
    /// Wall time of building, refreshing and extending the cache (and the selection fit).
    pub cache_build: Duration,
    /// The per-cell selection-probability fit, if it ran.
    pub selection_fit: Option<guiding::SelectionReport>,
    /// The guide's relative cost per vertex the selection fit weighed
    /// ([`guiding::SelectionFit::guide_cost`]).
    pub guide_cost: Option<f32>,
    /// The refit after the trial: the variance share it used and what it found.
    pub selection_refit: Option<(f32, guiding::SelectionReport)>,
    /// The efficiency trial: `None` when it did not run (off, spp budget, or the render ended
    /// before training stopped), else its verdict if it finished.
    pub trial: Option<TrialStats>,
    /// The inverse-variance combination of the passes, if it ran (more than one group).
    pub pass_weights: Option<PassWeightStats>,
    /// The training probe, if it was on.
    pub probe: Option<ProbeStats>,
    /// What the library's training schedule did.
    pub schedule: ScheduleReport,
}

/// What the inverse-variance combination of a guided render's passes did.
#[derive(Clone, Debug, Default)]
pub struct PassWeightStats {
    /// Per group: the training passes (one each, by pass index), then the guided and the
    /// unguided passes after training ([`GROUP_GUIDED`], [`GROUP_UNGUIDED`]).
    pub groups: Vec<GroupWeight>,
    /// The weights were unusable and the image is the plain mean.
    pub fell_back: bool,
    /// [`guiding::Combination::predicted_gain`]: the weighted image's relMSE over the plain
    /// mean's, as the weights' own variance estimates predict it.
    pub predicted_gain: f64,
    /// Wall seconds of the combination (after the last pass).
    pub seconds: f64,
}

/// Group id of the guided passes after training (a training pass's group is its index).
pub const GROUP_GUIDED: u32 = u32::MAX;
/// Group id of the passes after training with the guide off.
pub const GROUP_UNGUIDED: u32 = u32::MAX - 1;

impl std::fmt::Display for PassWeightStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (mut train_passes, mut train_share) = (0u32, 0.0f64);
        let mut train_var = (f64::INFINITY, 0.0f64);
        let mut rest = String::new();
        for g in &self.groups {
            let v = g.mean_relative_variance();
            let name = match g.group {
                GROUP_GUIDED => "guided",
                GROUP_UNGUIDED => "unguided",
                _ => {
                    train_passes += g.passes;
                    train_share += g.share;
                    train_var = (train_var.0.min(v), train_var.1.max(v));
                    continue;
                }
            };
            rest.push_str(&format!(
                ", {} {name} passes {:.1} % (relMSE per pass {v:.3e})",
                g.passes,
                100.0 * g.share
            ));
        }
        write!(
            f,
            "pass weights: {}; {train_passes} training passes {:.1} % of the image (relMSE per \
             pass {:.3e} .. {:.3e}){rest}; predicted relMSE {:.3}x the plain mean's, {:.3} s",
            if self.fell_back {
                "plain mean (no usable variance estimate)"
            } else {
                "inverse variance, weights from the other checkerboard half"
            },
            100.0 * train_share,
            train_var.0,
            train_var.1,
            self.predicted_gain,
            self.seconds
        )
    }
}

/// What the efficiency trial of a guided render did.
#[derive(Clone, Debug, Default)]
pub struct TrialStats {
    /// Trial passes run (both arms, those a restart dropped included).
    pub passes: u32,
    /// The estimate at the first look (`K` passes per arm, or an early verdict).
    pub first_look: Option<TrialVerdict>,
    /// The guided arm was restarted after the refit at the first look.
    pub restarted: bool,
    /// A trial still running when the render ended: its estimate from all its passes
    /// ([`GuideTrial::current`]); `None` once it has a verdict.
    pub latest: Option<TrialVerdict>,
    /// The verdict, once the interval excluded 1 (or the trial ended at its first look).
    pub verdict: Option<TrialVerdict>,
    /// Passes after the trial rendered with the guide off (it did not pay).
    pub passes_guide_off: u32,
}

impl TrialStats {
    /// One estimate as `--stats` shows it.
    fn describe(v: &TrialVerdict) -> String {
        format!(
            "{} + {} passes; relMSE per pass x seconds per pass: guided {:.3e} x {:.4} s, \
             unguided {:.3e} x {:.4} s, ratio {:.3} [{:.3}, {:.3}] (z {:.2}){}",
            v.guided_passes,
            v.unguided_passes,
            v.guided_variance,
            v.guided_seconds,
            v.unguided_variance,
            v.unguided_seconds,
            v.cost_ratio,
            v.ratio_low,
            v.ratio_high,
            v.z,
            if v.pixels_skipped > 0 {
                format!(" ({} non-finite pixels left out)", v.pixels_skipped)
            } else {
                String::new()
            }
        )
    }
}

impl std::fmt::Display for TrialStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(first) = &self.first_look {
            writeln!(
                f,
                "efficiency trial: first look {}: the interval straddles 1, the guide stayed \
                 on and the trial continued{}",
                Self::describe(first),
                if self.restarted {
                    " (guided arm restarted after the refit)"
                } else {
                    ""
                }
            )?;
        }
        match (&self.verdict, &self.latest) {
            (Some(v), _) => writeln!(
                f,
                "efficiency trial: {} passes, verdict {}: {}",
                self.passes,
                Self::describe(v),
                if v.evidence == guiding::Verdict::Pays {
                    "the guide pays, kept".to_string()
                } else if v.keep_guide {
                    "the interval straddles 1: no evidence against the guide, kept".to_string()
                } else {
                    format!(
                        "skipped: the guide does not pay, off for the remaining {} passes",
                        self.passes_guide_off
                    )
                }
            ),
            (None, Some(v)) => writeln!(
                f,
                "efficiency trial: no verdict when the budget ended ({} passes), latest {}: \
                 the guide stayed on",
                self.passes,
                Self::describe(v)
            ),
            (None, None) => writeln!(
                f,
                "efficiency trial: unfinished ({} passes before the budget ended)",
                self.passes
            ),
        }
    }
}

impl std::fmt::Display for GuidedStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "guide: {}", self.model)?;
        writeln!(
            f,
            "stages: NEE {}, guide queries {} ({} during training), guided vertices {}",
            if self.nee { "yes" } else { "no" },
            self.guide_queries,
            self.guide_queries_training,
            self.guided_vertices
        )?;
        writeln!(
            f,
            "training: {}/{} passes, {} steps ({} after training), {} samples recorded \
             ({} after training), {} rejected, {} overflowed, last loss {:.4}",
            self.training_passes,
            self.passes,
            self.training_steps,
            self.training_steps_after_training,
            self.samples_recorded,
            self.samples_recorded_after_training,
            self.rejected_samples,
            self.overflowed_samples,
            self.last_loss
        )?;
        if let Some(c) = &self.cache {
            writeln!(
                f,
                "guide cache: {c}; {} cells, {} hits, {} misses (network), built in {:.3} s",
                self.cache_cells,
                self.cache_hits,
                self.cache_misses,
                self.cache_build.as_secs_f64()
            )?;
        }
        if let Some(r) = &self.selection_fit {
            writeln!(
                f,
                "selection probability: fitted per cell on {} samples at a guide cost of {:.3} \
                 per vertex: {} cells with samples ({} with the guide off, c = 0), {} at the \
                 global {:.2}; mean {:.3}; estimated vertex variance {:.3}x that of BSDF \
                 sampling alone",
                r.samples_used,
                self.guide_cost.unwrap_or(0.0),
                r.cells_fitted,
                r.cells_off,
                r.cells_global,
                r.global,
                r.mean,
                r.variance_ratio
            )?;
        }
        if let Some((share, r)) = &self.selection_refit {
            writeln!(
                f,
                "selection probability refitted after the trial with {share:.3} of the image \
                 variance on the fitted vertices: {} cells with the guide off, mean {:.3}",
                r.cells_off, r.mean
            )?;
        }
        if let Some(t) = &self.trial {
            write!(f, "{t}")?;
        }
        if let Some(w) = &self.pass_weights {
            writeln!(f, "{w}")?;
        }
        if let Some(p) = &self.probe {
            writeln!(f, "{p}")?;
        }
        if let Some(p) = self.converged_at_pass {
            writeln!(
                f,
                "skipped: training stopped at pass {p} (loss converged), {} training passes \
                 not recorded",
                self.passes_planned_for_training
                    .saturating_sub(self.training_passes)
            )?;
        }
        let sr = &self.schedule;
        writeln!(
            f,
            "training schedule: {} updates, {} steps of {:.2} ms; training {:.3} s of the \
             training phase's {:.3} s ({:.1} % of its wall clock)",
            sr.updates,
            sr.steps,
            1e3 * sr.seconds_per_step,
            sr.trained_seconds,
            sr.traced_seconds + sr.trained_seconds,
            100.0 * sr.training_share()
        )?;
        write!(
            f,
            "time: trace {:.3} s (wall; guide queries {:.3} thread-s of it), training {:.3} s",
            self.trace.as_secs_f64(),
            self.query.as_secs_f64(),
            self.training.as_secs_f64()
        )
    }
}

/// Where a guided render is, in the order its passes go through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// The schedule's training phase: passes record training samples.
    Training,
    /// Training has stopped; with the efficiency trial on, the next pass is its warm-up
    /// (guide on, not judged).
    Stopped,
    /// Past the warm-up pass: the efficiency trial runs, or has decided (its verdict is in
    /// the statistics).
    Trial,
    /// The training probe's early look: training paused, guided and unguided passes
    /// alternate (see [`super::probe`]).
    Look,
}

/// The guided strategy of one render: the guide (trained between passes, on the CPU or on
/// its device with `--device gpu`: the same calls) and the statistics.
pub struct Guided<'g> {
    guide: &'g mut GuidingField,
    gopts: GuidedOptions,
    stats: GuidedStats,
    phase: Phase,
    /// The guide cache (see the module docs) and the samples of the latest training pass.
    cache: Option<GuideCache>,
    use_cache: bool,
    last_samples: Vec<TrainingSample>,
    /// The MIS-weighted incident radiance of each of `last_samples`.
    last_mis: Vec<[f32; 3]>,
    /// The efficiency trial while it runs (created at its first pass, dropped at its verdict).
    trial: Option<GuideTrial>,
    /// The trial arm of the current pass, if it is a trial pass.
    pass_arm: Option<TrialArm>,
    /// The current pass runs with the guide off (BSDF sampling and NEE only).
    guide_off: bool,
    /// The inverse-variance combination of the passes (created at the first pass).
    combiner: Option<PassCombiner>,
    /// The current pass's group in `combiner` (`None` without pass weights).
    pass_group: Option<u32>,
    /// The training probe's look while it runs, and the arm of the current look pass.
    look: Option<GuideTrial>,
    look_arm: Option<TrialArm>,
    /// Guide-query seconds (per thread) and tracing seconds of the training
    /// chunks traced with the cache: the guide's cost for the selection fit.
    cached_query_seconds: f64,
    cached_traced_seconds: f64,
    /// The library's training schedule.
    schedule: TrainingSchedule,
    /// Per medium of the scene: its scattering points are guided.
    media_guided: Vec<bool>,
}

impl<'g> Guided<'g> {
    /// The strategy for `guide` (on the CPU, or on its device with `--device gpu`) in a
    /// render of `budget`.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for schedule options out of range.
    pub fn new(
        guide: &'g mut GuidingField,
        gopts: &GuidedOptions,
        budget: guiding::Budget,
        media_guided: Vec<bool>,
    ) -> Result<Self, GuidingError> {
        let schedule = TrainingSchedule::new(gopts.schedule, budget)?;
        let device = guide.device_name();
        let model = match &device {
            Some(d) => format!("{} on {d}", describe(guide)),
            None => describe(guide),
        };
        let radiance = guide.config().target == guiding::Target::Radiance;
        let cache = match gopts.cache {
            CacheMode::Off => None,
            _ if device.is_some() => Some("not used (the guide runs on the device)".to_string()),
            _ if !radiance => Some(
                "not used (a product guide also depends on the outgoing direction, the normal \
                 and the roughness)"
                    .to_string(),
            ),
            mode => Some(format!(
                "{} at {} cells on the longest axis",
                if mode == CacheMode::Frozen {
                    "after training"
                } else {
                    "every pass after the first update"
                },
                gopts.cache_resolution
            )),
        };
        let use_cache = gopts.cache != CacheMode::Off && device.is_none() && radiance;
        Ok(Guided {
            guide,
            gopts: *gopts,
            stats: GuidedStats {
                model,
                device: device.clone(),
                last_loss: f64::NAN,
                cache,
                ..GuidedStats::default()
            },
            phase: Phase::Training,
            cache: None,
            use_cache,
            last_samples: Vec::new(),
            last_mis: Vec::new(),
            media_guided,
            trial: None,
            pass_arm: None,
            guide_off: false,
            combiner: None,
            pass_group: None,
            look: None,
            look_arm: None,
            cached_query_seconds: 0.0,
            cached_traced_seconds: 0.0,
            schedule,
        })
    }

    /// Decides the current pass's trial arm and whether the guide is off (after
    /// [`Strategy::begin_pass`] has handled training).
    fn plan_trial_pass(&mut self) {
        self.pass_arm = None;
        self.guide_off = false;
        match self.phase {
            Phase::Training | Phase::Look => return,
            _ if !self.gopts.efficiency_trial => return,
            Phase::Stopped => {
                // The warm-up pass.
                self.phase = Phase::Trial;
                return;
            }
            Phase::Trial => {}
        }
        let t = self.stats.trial.get_or_insert_with(TrialStats::default);
        match t.verdict {
            Some(v) => {
                self.guide_off = !v.keep_guide;
                t.passes_guide_off += u32::from(self.guide_off);
            }
            None => {
                let arm = self
                    .trial
                    .as_ref()
                    .map_or(Some(TrialArm::Guided), GuideTrial::next_arm);
                self.pass_arm = arm;
                self.guide_off = arm == Some(TrialArm::Unguided);
            }
        }
    }

    /// Refits the selection probabilities once the trial has kept the guide, with the
    /// share of the image's variance the fitted vertices make as the trial's favourable end
    /// says: `s = (1 − r_low) / (1 − r_vert)`, `r_low` the lower end of the trial's cost
    /// ratio over its time ratio (the image variance ratio at the interval's favourable end),
    /// `r_vert` the first fit's vertex variance ratio
    /// ([`guiding::SelectionFit::variance_share`]). Nothing when `s` comes out at 1 or
    /// cannot be formed (no cost, no interval, a fit that predicted no gain).
    ///
    /// Returns whether the selection probabilities changed.
    fn refit_selection(&mut self, v: &guiding::TrialVerdict) -> bool {
        let (Some(first), Some(guide_cost)) = (self.stats.selection_fit, self.stats.guide_cost)
        else {
            return false;
        };
        let r_low = v.ratio_low * v.unguided_seconds / v.guided_seconds;
        let share = (1.0 - r_low) / (1.0 - first.variance_ratio);
        if !(guide_cost > 0.0 && share.is_finite() && first.variance_ratio < 1.0 && share < 1.0) {
            return false;
        }
        let Some(cache) = self.cache.as_mut() else {
            return false;
        };
        let t0 = Instant::now();
        let fit = guiding::SelectionFit {
            guide_cost,
            variance_share: share.max(0.0) as f32,
            ..guiding::SelectionFit::default()
        };
        let samples = &self.last_samples;
        let mis = (self.last_mis.len() == samples.len()).then_some(self.last_mis.as_slice());
        let refitted = match cache.fit_selection(self.guide, samples, mis, None, &fit) {
            Ok(report) => {
                self.stats.selection_refit = Some((fit.variance_share, report));
                true
            }
            Err(_) => false,
        };
        self.stats.cache_build += t0.elapsed();
        refitted
    }

    /// The guide's relative cost per vertex for the selection fit,
    /// `κ = Q / (T − Q)` over the training chunks traced with the cache (`Q`
    /// their guide-query seconds, `T` their tracing seconds); 0 before any.
    fn guide_cost(&self) -> f64 {
        let (q, t) = (self.cached_query_seconds, self.cached_traced_seconds);
        if q > 0.0 && t > q {
            q / (t - q)
        } else {
            0.0
        }
    }

    /// The training probe runs: the efficiency trial is on (time budget, NEE) and so is the
    /// probe.
    fn probe_on(&self) -> bool {
        self.gopts.efficiency_trial && self.gopts.training_probe
    }

    /// The probe decision a test forces (never in a real render).
    fn probe_force(&self) -> Option<LookDecision> {
        #[cfg(feature = "testing")]
        return self.gopts.test_hooks.probe_force;
        #[cfg(not(feature = "testing"))]
        None
    }

    /// Brings the cache to the field's current generation and adds the cells of `positions`
    /// (building it if there is none yet).
    fn update_cache(&mut self, points: &[QueryPoint]) -> Result<(), GuidingError> {
        let t0 = Instant::now();
        match &mut self.cache {
            Some(c) => {
                c.refresh(self.guide)?;
                c.extend(self.guide, points)?;
            }
            None => {
                let options = CacheOptions {
                    resolution: self.gopts.cache_resolution,
                    cosine_product: self.gopts.cosine_product,
                    ..CacheOptions::default()
                };
                self.cache = Some(self.guide.build_cache(points, &options)?);
            }
        }
        self.stats.cache_cells = self.cache.as_ref().map_or(0, |c| c.cells() as u64);
        self.stats.cache_build += t0.elapsed();
        Ok(())
    }

    /// The combiner group of `pass` (`None` without pass weights): the unguided passes one
    /// group, a pass whose guide is still training (`own`) a group of its own, the guided
    /// passes after training one group.
    fn pass_group(&self, pass: &Pass, own: bool) -> Option<u32> {
        self.gopts.weight_passes.then_some(if self.guide_off {
            GROUP_UNGUIDED
        } else if own {
            pass.index.min(GROUP_UNGUIDED - 1)
        } else {
            GROUP_GUIDED
        })
    }

    /// Takes the look pass `image` into the probe's trial; at its first look, resumes
    /// training with or without another look, or ends it ([`guiding::TrialVerdict::look_decision`]).
    fn observe_look_pass(&mut self, arm: TrialArm, image: &PassImage<'_>) {
        if self.look.is_none() {
            self.look = trial_on(
                image,
                TrialOptions {
                    continuation: false,
                    ..TrialOptions::default()
                },
            );
        }
        let recorded = self
            .look
            .as_mut()
            .is_some_and(|t| t.record(arm, image.pixels, image.seconds).is_ok());
        let force = self.probe_force();
        let Some(p) = self.stats.probe.as_mut() else {
            return;
        };
        p.passes += 1;
        p.seconds += image.seconds;
        let verdict = self.look.as_ref().and_then(GuideTrial::first_look);
        if recorded && verdict.is_none() {
            return;
        }
        // A look that cannot go on (an empty image, a failed pass) ends like a guide that
        // does not look cheaper: no more training, the trial after it decides.
        p.verdict = verdict;
        let decision = force
            .unwrap_or_else(|| verdict.map_or(LookDecision::EndTraining, |v| v.look_decision()));
        p.decision = Some(decision);
        let (seconds, passes) = (p.seconds, p.passes);
        self.look = None;
        self.phase = Phase::Training;
        match decision {
            LookDecision::TrainOn => {
                self.schedule.resume_after_look(seconds, passes);
                self.schedule.end_looks();
            }
            LookDecision::LookAgain => self.schedule.resume_after_look(seconds, passes),
            // The next pass finds the phase over and stops training there.
            LookDecision::EndTraining => self.schedule.end_training(),
        }
    }

    /// Ends training (if the schedule has not) and returns the statistics, with the driver's
    /// totals `rs`.
    pub fn finish(self, rs: &RenderStats) -> GuidedStats {
        if self.phase == Phase::Training {
            self.guide.stop_training();
        }
        let mut stats = self.stats;
        if let (Some(trial), Some(t)) = (&self.trial, &mut stats.trial) {
            t.latest = trial.current();
        }
        stats.schedule = self.schedule.report();
        stats.nee = rs.nee;
        stats.passes = rs.passes;
        stats.trace = rs.trace;
        stats.wall = rs.wall;
        stats.rays = rs.rays;
        stats.medium_vertices = rs.medium_vertices;
        stats.roulette = rs.roulette;
        let fs = self.guide.stats();
        stats.training_steps = fs.steps;
        stats.rejected_samples = fs.rejected_samples.iter().sum();
        stats.overflowed_samples = fs.overflowed_samples;
        stats
    }
}

/// The shading points of training samples (position and normal for the cache).
/// A trial (the efficiency trial, or the probe's look) starting at the pass `image`, its
/// pixels weighted by the image before it (the mean of the passes so far); `None` for an
/// empty image.
fn trial_on(image: &PassImage<'_>, options: TrialOptions) -> Option<GuideTrial> {
    let before = mean_image(image.sum_before, image.passes_before);
    let (w, h) = (image.width as usize, image.height as usize);
    GuideTrial::new(w, h, &before, options).ok()
}

fn query_points(samples: &[TrainingSample]) -> Vec<QueryPoint> {
    samples
        .iter()
        .map(|s| QueryPoint::new(s.position, s.normal, s.wo, s.roughness))
        .collect()
}

/// What one render thread's worker did in a pass.
pub struct WorkerReport {
    queries: u64,
    guided_vertices: u64,
    guided_medium_vertices: u64,
    query_time: Duration,
    /// The first failure of the guide's device in this pass (the render ends after it).
    device_error: Option<GuidingError>,
    cache_hits: u64,
    /// The queries the cache missed (decoded by the network).
    missed_points: Vec<QueryPoint>,
}

/// Marks a vertex that is not guided.
const NONE: u32 = u32::MAX;

/// Per-render-thread state of the guided strategy: the bounce's decoded guide and the scratch
/// of its batched calls.
pub struct GuidedWorker<'g> {
    guide: &'g GuidingField,
    /// The guide cache of this pass, if any: it answers instead of the network.
    cache: Option<&'g GuideCache>,
    /// This pass runs with the guide off: every vertex samples its BSDF.
    off: bool,
    jitter: Vec<Vec3>,
    missed: Vec<u32>,
    gopts: GuidedOptions,
    /// Per medium: its scattering points are guided (the library's thin-medium rule and
    /// [`GuidedOptions::guide_media`]).
    media_guided: &'g [bool],
    report: WorkerReport,
    /// Per vertex: its index among the guidable vertices, or [`NONE`].
    guided_index: Vec<u32>,
    /// The guidable vertices' queries, decoded distributions and selection probabilities.
    queries: Vec<QueryPoint>,
    decoded: DistributionBatch,
    normals: Vec<Vec3>,
    selection: Vec<f32>,
    /// Guide samples of the bounce, drawn in one batched call.
    samples: GuideSampleQueue,
    /// Guide densities of the bounce (BSDF directions or light samples), one batched call.
    pdfs: GuidePdfQueue,
    /// Guide pdf of each vertex's continuation direction.
    guide_pdf: Vec<f32>,
    /// The phase-function product's lanes, lobe axes and concentrations (scratch).
    lobe_lanes: Vec<u32>,
    lobe_axes: Vec<Vec3>,
    lobe_kappas: Vec<f32>,
}

impl<'g> GuidedWorker<'g> {
    fn new(
        guide: &'g GuidingField,
        cache: Option<&'g GuideCache>,
        gopts: GuidedOptions,
        media_guided: &'g [bool],
        off: bool,
    ) -> Self {
        Self {
            guide,
            cache,
            off,
            jitter: Vec::new(),
            missed: Vec::new(),
            gopts,
            media_guided,
            report: WorkerReport {
                queries: 0,
                guided_vertices: 0,
                guided_medium_vertices: 0,
                query_time: Duration::ZERO,
                device_error: None,
                cache_hits: 0,
                missed_points: Vec::new(),
            },
            guided_index: Vec::new(),
            queries: Vec::new(),
            decoded: DistributionBatch::new(),
            normals: Vec::new(),
            selection: Vec::new(),
            samples: GuideSampleQueue::default(),
            pdfs: GuidePdfQueue::default(),
            guide_pdf: Vec::new(),
            lobe_lanes: Vec::new(),
            lobe_axes: Vec::new(),
            lobe_kappas: Vec::new(),
        }
    }

    /// The product of the guide with the vMF fit of the phase function at the bounce's
    /// guided medium vertices (Henyey–Greenstein with `g ≠ 0`: the lobe
    /// [`guiding_core::lobe::vmf::hg_vmf_kappa`]`(g)` around the forward direction `−ω_o`,
    /// or `ω_o` for `g < 0`); NASG and DF guides are left as they are.
    fn multiply_phase_lobes(&mut self, verts: &Vertices) {
        self.lobe_lanes.clear();
        self.lobe_axes.clear();
        self.lobe_kappas.clear();
        for i in 0..verts.len() {
            let (qi, Material::Phase { g }) = (self.guided_index[i], verts.bsdf[i]) else {
                continue;
            };
            let kappa = guiding_core::lobe::vmf::hg_vmf_kappa(g);
            if qi == NONE || kappa <= 0.0 {
                continue;
            }
            let forward = -verts.wo[i];
            self.lobe_lanes.push(qi);
            self.lobe_axes
                .push(if g > 0.0 { forward } else { -forward });
            self.lobe_kappas.push(kappa);
        }
        if !self.lobe_lanes.is_empty() {
            let _ = self.decoded.apply_lobe_product(
                &self.lobe_lanes,
                &self.lobe_axes,
                &self.lobe_kappas,
            );
        }
    }

    /// Keeps the first failure of the pass (the render ends with it after the pass).
    fn record_error(&mut self, e: GuidingError) {
        self.report.device_error.get_or_insert(e);
    }

    /// The guide pdfs of the queued `(guidable index, direction)` pairs, one batched call on
    /// the decoded distributions (zeros where it failed: a device failure, and the render
    /// ends with it after the pass).
    fn eval_queued_pdfs(&mut self) {
        let q = &mut self.pdfs;
        q.out.clear();
        q.out.resize(q.query.len(), 0.0);
        let t0 = Instant::now();
        if let Err(e) = self
            .guide
            .pdf_decoded(&self.decoded, &q.query, &q.dir, &mut q.out)
        {
            q.out.fill(0.0);
            self.report.device_error.get_or_insert(e);
        }
        for p in &mut q.out {
            *p = if p.is_finite() { p.max(0.0) } else { 0.0 };
        }
        self.report.queries += q.query.len() as u64;
        self.report.query_time += t0.elapsed();
    }
}

impl VertexStrategy for GuidedWorker<'_> {
    /// One batched decode of the guide at the bounce's guidable vertices (on the guide's
    /// device with `--device gpu`, whose failure ends the render after the pass).
    fn prepare(&mut self, _: &Scene, verts: &Vertices, rng: &mut [Rng]) {
        self.guided_index.clear();
        self.queries.clear();
        self.jitter.clear();
        self.selection.clear();
        if self.off {
            self.guided_index.resize(verts.len(), NONE);
            return;
        }
        for i in 0..verts.len() {
            let mat = &verts.bsdf[i];
            if self.trains(mat, verts.media[i][0]) {
                if self.cache.is_some() {
                    // Three 10-bit uniforms (cell centres of a 1024-grid) for the lookup.
                    let bits = rng[verts.slot[i] as usize].next_u32();
                    let unit = |b: u32| ((b & 1023) as f32 + 0.5) * (1.0 / 1024.0);
                    self.jitter
                        .push(Vec3::new(unit(bits), unit(bits >> 10), unit(bits >> 20)));
                }
                self.guided_index.push(self.queries.len() as u32);
                // A medium vertex's query has no normal (its `ns` is only the phase
                // function's frame).
                let normal = if mat.is_phase() {
                    self.report.guided_medium_vertices += 1;
                    Vec3::ZERO
                } else {
                    verts.ns[i]
                };
                self.queries.push(QueryPoint::from_vec3(
                    verts.position[i],
                    normal,
                    verts.wo[i],
                    mat.roughness(),
                ));
            } else {
                self.guided_index.push(NONE);
            }
        }
        let nq = self.queries.len();
        self.report.guided_vertices += nq as u64;
        let t0 = Instant::now();
        let field = self.guide;
        let mut from_cache = self.cache.is_some();
        match self.cache {
            Some(cache) => {
                let looked_up = cache.decode_batch(
                    field,
                    &self.queries,
                    &self.jitter,
                    &mut self.decoded,
                    &mut self.missed,
                );
                match looked_up {
                    Ok(l) => {
                        self.report.cache_hits += l.hits;
                        self.report
                            .missed_points
                            .extend(self.missed.iter().map(|&k| self.queries[k as usize]));
                    }
                    // A stale cache (a bug): the network answers every vertex.
                    Err(_) => {
                        field.decode_batch(&self.queries, &mut self.decoded);
                        self.report.missed_points.extend_from_slice(&self.queries);
                        from_cache = false;
                    }
                }
            }
            None => {
                if let Err(e) = field.try_decode_batch(&self.queries, &mut self.decoded) {
                    self.record_error(e);
                }
            }
        }
        // A cache with the cosine product hands out multiplied lanes (stale-cache fallback
        // aside, which only a bug reaches).
        let producted = from_cache && self.cache.is_some_and(GuideCache::has_cosine_product);
        if self.gopts.cosine_product
            && field.config().target == guiding::Target::Radiance
            && !producted
        {
            self.normals.clear();
            self.normals
                .extend(self.queries.iter().map(|q| Vec3::from_array(q.normal)));
            self.decoded.apply_cosine_product(&self.normals);
        }
        if self.gopts.phase_product {
            self.multiply_phase_lobes(verts);
        }
        self.selection.clear();
        for k in 0..nq {
            self.selection.push(self.decoded.selection_probability(k));
        }
        self.report.queries += nq as u64;
        self.report.query_time += t0.elapsed();
    }

    fn light_pdfs(&mut self, _: &Vertices, lights: &mut LightSamples) {
        self.pdfs.clear();
        for k in 0..lights.len() {
            let qi = self.guided_index[lights.vertex[k] as usize];
            // c = 0 (a fitted cell where the guide does not pay): the BSDF density alone.
            if qi != NONE && !lights.light[k].delta && self.selection[qi as usize] > 0.0 {
                self.pdfs.push(qi, lights.light[k].wo, k as u32);
            }
        }
        self.eval_queued_pdfs();
        lights.sampling_pdf.clear();
        lights.sampling_pdf.extend_from_slice(&lights.bsdf_pdf);
        let q = &self.pdfs;
        for e in 0..q.entry.len() {
            let k = q.entry[e] as usize;
            let c = self.selection[q.query[e] as usize];
            lights.sampling_pdf[k] = c * q.out[e] + (1.0 - c) * lights.bsdf_pdf[k];
        }
    }

    fn trains(&self, mat: &Material, medium: u32) -> bool {
        mat.guidable(self.gopts.min_alpha)
            || (mat.is_phase() && self.media_guided.get(medium as usize) == Some(&true))
    }

    fn sample(&mut self, verts: &Vertices, rng: &mut [Rng], out: &mut Continuations) {
        let n = verts.len();
        self.samples.clear();
        self.pdfs.clear();
        self.guide_pdf.clear();
        self.guide_pdf.resize(n, 0.0);
        // Technique selection: the guide with probability `c`, else the BSDF.
        for i in 0..n {
            let qi = self.guided_index[i];
            let rng = &mut rng[verts.slot[i] as usize];
            if qi != NONE && rng.next_f32() < self.selection[qi as usize] {
                let _ = rng.next_f32(); // the BSDF's lobe choice, unused
                let u = Vec2::new(rng.next_f32(), rng.next_f32());
                self.samples.push(qi, u, i as u32);
                continue;
            }
            sample_bsdf(verts, i, rng, out);
            if qi != NONE && self.selection[qi as usize] > 0.0 && out.wi[i] != Vec3::ZERO {
                self.pdfs.push(qi, out.wi[i], i as u32);
            }
        }
        // Guide samples and the guide pdfs of the BSDF's directions, one batched call each.
        let t0 = Instant::now();
        let none = DirectionSample {
            direction: Vec3::ZERO,
            pdf: 0.0,
        };
        let s = &mut self.samples;
        s.out.clear();
        s.out.resize(s.query.len(), none);
        if let Err(e) = self
            .guide
            .sample_decoded(&self.decoded, &s.query, &s.u, &mut s.out)
        {
            s.out.fill(none);
            self.report.device_error.get_or_insert(e);
        }
        for (ds, &i) in s.out.iter().zip(&s.vertex) {
            if ds.direction.is_finite() && ds.pdf.is_finite() && ds.pdf > 0.0 {
                out.wi[i as usize] = ds.direction.normalize();
                self.guide_pdf[i as usize] = ds.pdf;
            }
        }
        self.report.queries += s.query.len() as u64;
        self.report.query_time += t0.elapsed();
        self.eval_queued_pdfs();
        for e in 0..self.pdfs.entry.len() {
            self.guide_pdf[self.pdfs.entry[e] as usize] = self.pdfs.out[e];
        }
        // Weights with the combined density of the guided vertices.
        for i in 0..n {
            let (qi, wi) = (self.guided_index[i], out.wi[i]);
            // c = 0: BSDF sampling alone, whose weight sample_bsdf has set.
            if qi == NONE || wi == Vec3::ZERO || self.selection[qi as usize] <= 0.0 {
                continue;
            }
            let frame = Frame::from_z(verts.ns[i]);
            let (f, pdf_bsdf) = verts.bsdf[i].eval(frame.to_local(verts.wo[i]), frame.to_local(wi));
            let c = self.selection[qi as usize];
            #[cfg(feature = "testing")]
            let guide_pdf = self.guide_pdf[i] * self.gopts.test_hooks.guide_pdf_scale;
            #[cfg(not(feature = "testing"))]
            let guide_pdf = self.guide_pdf[i];
            let pdf = c * guide_pdf + (1.0 - c) * pdf_bsdf;
            if !(pdf > 0.0 && pdf.is_finite()) || f.max_element() <= 0.0 {
                out.set(i, Vec3::ZERO, Vec3::ZERO, 0.0);
                continue;
            }
            out.set(i, wi, f / pdf, pdf);
            out.bsdf_pdf[i] = pdf_bsdf;
            out.bsdf_cos[i] = f;
        }
    }
}

impl<'g> Strategy for Guided<'g> {
    type Worker<'a>
        = GuidedWorker<'a>
    where
        Self: 'a;
    type Report = WorkerReport;
    type Error = GuidingError;

    /// Settled once the guide is abandoned, or training has stopped and the efficiency trial
    /// (when on) has had its first look: a verdict, or a continuation between two arms whose
    /// cost ratio's interval straddles 1.
    fn estimator_settled(&self) -> bool {
        match self.phase {
            Phase::Training | Phase::Look => false,
            _ if !self.gopts.efficiency_trial => true,
            Phase::Stopped => false,
            Phase::Trial => self
                .stats
                .trial
                .as_ref()
                .is_some_and(|t| t.verdict.is_some() || t.first_look.is_some()),
        }
    }

    fn trains_from_recorded_passes(&self) -> bool {
        true
    }

    fn worker(&self) -> GuidedWorker<'_> {
        GuidedWorker::new(
            self.guide,
            self.cache.as_ref(),
            self.gopts,
            &self.media_guided,
            self.guide_off,
        )
    }

    fn report(&self, worker: GuidedWorker<'_>) -> WorkerReport {
        worker.report
    }

    /// Records the passes of the schedule's training phase until the loss has converged (a
    /// plateau) or the probe ends training; the first pass that does not record stops
    /// training. The probe's look passes (see [`super::probe`]) record nothing and leave
    /// training paused.
    fn begin_pass(&mut self, pass: &Pass) -> bool {
        let elapsed = pass.elapsed.as_secs_f64();
        if self.phase == Phase::Training
            && self.probe_on()
            // The look measures the guide at its cost after training: from the cache where
            // the render will read it from one (not before it is built, `--guide-cache frozen`).
            && (self.cache.is_some() || !self.use_cache)
            && self.schedule.look_due(elapsed, pass.index)
        {
            self.phase = Phase::Look;
            let looks = self.stats.probe.map_or(0, |p| p.looks) + 1;
            self.stats.probe = Some(ProbeStats {
                at_pass: pass.index,
                steps: self.guide.stats().steps,
                looks,
                ..ProbeStats::default()
            });
        }
        if self.phase == Phase::Look {
            let arm = self
                .look
                .as_ref()
                .map_or(Some(TrialArm::Guided), GuideTrial::next_arm);
            self.pass_arm = None;
            self.look_arm = arm;
            self.guide_off = arm == Some(TrialArm::Unguided);
            // A guided look pass is a group of its own, as a training pass (its guide is
            // still training).
            self.pass_group = self.pass_group(pass, true);
            return false;
        }
        self.look_arm = None;
        let train = self.schedule.in_training_phase(elapsed, pass.index);
        // (Once stopped, by the schedule or the probe, the field counts as converged.)
        let training = self.phase == Phase::Training;
        let converged = training && self.guide.is_converged();
        if train && converged && self.stats.converged_at_pass.is_none() {
            self.stats.converged_at_pass = Some(pass.index);
        }
        let record = train && !converged && training;
        if !record && training {
            self.schedule.end_training();
            self.guide.stop_training();
            self.phase = Phase::Stopped;
            if self.use_cache {
                let samples = std::mem::take(&mut self.last_samples);
                let points = query_points(&samples);
                // Only a bug makes this fail (radiance target and resolution checked): the
                // network then answers every query.
                if self.update_cache(&points).is_err() {
                    self.cache = None;
                }
                let nasg = self.guide.config().representation == guiding::Representation::Nasg;
                let guide_cost = self.guide_cost() as f32;
                if let (Some(cache), true, false) =
                    (self.cache.as_mut(), self.gopts.fit_selection, nasg)
                {
                    let t0 = Instant::now();
                    let fit = guiding::SelectionFit {
                        guide_cost,
                        ..guiding::SelectionFit::default()
                    };
                    self.stats.guide_cost = Some(fit.guide_cost);
                    let mis =
                        (self.last_mis.len() == samples.len()).then_some(self.last_mis.as_slice());
                    self.stats.selection_fit = cache
                        .fit_selection(self.guide, &samples, mis, None, &fit)
                        .ok();
                    self.stats.cache_build += t0.elapsed();
                }
                // Kept for the refit after the efficiency trial.
                self.last_samples = samples;
            }
        }
        if record {
            // The selection fit uses the samples of the last whole training pass.
            self.last_samples.clear();
            self.last_mis.clear();
        }
        self.stats.training_passes += u32::from(record);
        self.stats.passes_planned_for_training += u32::from(train);
        self.plan_trial_pass();
        self.pass_group = self.pass_group(pass, record);
        record
    }

    fn paths_before_update(&self, pass_paths: u64) -> u64 {
        self.schedule.paths_before_update(pass_paths)
    }

    fn wants_pass_image(&self, _: &Pass) -> bool {
        self.pass_arm.is_some() || self.look_arm.is_some() || self.pass_group.is_some()
    }

    fn combined_image(&mut self) -> Option<CombinedImage> {
        if !self.gopts.weight_passes {
            return None;
        }
        let combiner = self.combiner.as_ref().filter(|c| c.group_count() > 1)?;
        let t0 = Instant::now();
        let c = combiner.combine();
        self.stats.pass_weights = Some(PassWeightStats {
            predicted_gain: c.predicted_gain(),
            groups: c.groups,
            fell_back: c.fell_back,
            seconds: t0.elapsed().as_secs_f64(),
        });
        Some((c.pixels, c.var_of_mean))
    }

    fn observe_pass_image(&mut self, _: &Pass, image: &PassImage<'_>) {
        if let Some(group) = self.pass_group {
            let (w, h) = (image.width as usize, image.height as usize);
            if self.combiner.is_none() {
                // Only an empty image fails: the render keeps the plain mean.
                self.combiner = PassCombiner::new(w, h, CombineOptions::default()).ok();
            }
            if let Some(c) = &mut self.combiner {
                if c.add_pass(group, image.pixels).is_err() {
                    self.combiner = None;
                }
            }
        }
        if let Some(arm) = self.look_arm {
            self.observe_look_pass(arm, image);
            return;
        }
        let Some(arm) = self.pass_arm else {
            return;
        };
        if self.trial.is_none() {
            // Only an empty image fails: the trial then never decides (the guide stays on).
            self.trial = trial_on(image, TrialOptions::default());
        }
        let Some(trial) = &mut self.trial else {
            return;
        };
        if trial.record(arm, image.pixels, image.seconds).is_err() {
            return;
        }
        let t = self.stats.trial.get_or_insert_with(TrialStats::default);
        t.passes += 1;
        if let Some(v) = trial.verdict() {
            let refit = t.first_look.is_none() && v.keep_guide;
            t.verdict = Some(v);
            self.trial = None;
            if refit {
                self.refit_selection(&v);
            }
            self.last_samples = Vec::new();
            self.last_mis = Vec::new();
        } else if let (Some(first), None) = (trial.first_look(), t.first_look) {
            // The first look straddles 1: the guide stays on, refitted as a kept guide is,
            // and the trial continues with the refitted guide's passes.
            t.first_look = Some(first);
            if self.refit_selection(&first) {
                if let Some(trial) = &mut self.trial {
                    trial.restart(TrialArm::Guided);
                }
                if let Some(t) = &mut self.stats.trial {
                    t.restarted = true;
                }
            }
            self.last_samples = Vec::new();
            self.last_mis = Vec::new();
        }
    }

    fn end_chunk(
        &mut self,
        _: &Pass,
        recorded: bool,
        reports: Vec<WorkerReport>,
        pass_samples: PassSamples,
        traced: Traced,
    ) -> Result<(), GuidingError> {
        let PassSamples {
            samples,
            mis_radiance,
        } = pass_samples;
        let mut missed = Vec::new();
        let threads = reports.len().max(1) as f64;
        // The chunk used the cache if there was one when it was traced (it is refreshed below).
        let cost_sample = recorded && self.cache.is_some() && !self.guide_off;
        let mut chunk_query_seconds = 0.0;
        let st = &mut self.stats;
        for r in reports {
            chunk_query_seconds += r.query_time.as_secs_f64() / threads;
            if let Some(e) = r.device_error {
                return Err(e);
            }
            st.cache_hits += r.cache_hits;
            st.cache_misses += r.missed_points.len() as u64;
            missed.extend(r.missed_points);
            st.guide_queries += r.queries;
            if recorded {
                st.guide_queries_training += r.queries;
            }
            st.guided_vertices += r.guided_vertices;
            st.guided_medium_vertices += r.guided_medium_vertices;
            st.query += r.query_time;
        }
        if cost_sample {
            self.cached_query_seconds += chunk_query_seconds;
            self.cached_traced_seconds += traced.seconds;
        }
        st.samples_recorded += samples.len() as u64;
        if !recorded {
            st.samples_recorded_after_training += samples.len() as u64;
        }
        let mut updated = false;
        if recorded {
            self.schedule.record_traced(traced.seconds, traced.paths);
        }
        if !samples.is_empty() {
            let t_train = Instant::now();
            let steps_before = self.guide.stats().steps;
            self.guide.add_samples(&samples);
            // The steps the library's schedule says are due, on the CPU threads or on the
            // guide's device: one training loop.
            if let Some(rep) = self.schedule.train(self.guide)? {
                updated = rep.steps > 0;
                if rep.steps > 0 {
                    st.last_loss = rep.mean_loss;
                    st.loss_history.push(rep.mean_loss);
                }
            }
            if !recorded {
                st.training_steps_after_training += self.guide.stats().steps - steps_before;
            }
            st.training += t_train.elapsed();
        }
        if self.use_cache {
            let result = if recorded {
                // The cache follows every update (or is built at the first one).
                let r =
                    if self.gopts.cache == CacheMode::Always && (updated || self.cache.is_some()) {
                        self.update_cache(&query_points(&samples))
                    } else {
                        Ok(())
                    };
                // Kept for the selection fit when training stops.
                self.last_samples.extend_from_slice(&samples);
                self.last_mis.extend_from_slice(&mis_radiance);
                r
            } else if self.cache.is_some() && !missed.is_empty() {
                self.update_cache(&missed)
            } else {
                Ok(())
            };
            // Only a bug makes this fail: the network then answers every query.
            if result.is_err() {
                self.cache = None;
            }
        }
        Ok(())
    }
}
