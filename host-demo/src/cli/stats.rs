//! The `--stats FILE.json` document of `host-demo render`, as `serde::Serialize` structs.
//!
//! Every key of the document and the type of its value are named here once. The structs are
//! serialised to a [`serde_json::Value`] and printed from there (keys sorted, numbers as
//! `serde_json` prints an `f64`), so the file reads as it did when it was built with `json!`.
//! Values JSON cannot hold (NaN, infinity) are written as `null` ([`finite`]). Parts whose shape
//! depends on what ran (a stage that did not run has only `ran` and `reason`) are untagged
//! enums or `Option`s.

use guiding::media::MIN_GUIDED_SCATTERING_DEPTH;
use guiding::LookDecision;
use host_demo::render::media_guiding;
use host_demo::render::strategy::guided::{GROUP_GUIDED, GROUP_UNGUIDED};
use host_demo::render::{
    GuidedOptions, GuidedStats, PassWeightStats, ProbeStats, RenderStats, TrialStats,
};
use host_demo::render::{Roulette, RouletteStats};
use host_demo::scene::medium::NO_MEDIUM;
use host_demo::scene::Scene;
use serde::Serialize;

/// A JSON number, or `null` where it is not finite (JSON has no NaN or infinity).
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The whole document: the run's settings and image, then what the integrator measured.
#[derive(Serialize)]
pub(super) struct StatsDoc<'a> {
    pub scene: &'a str,
    /// `pt`, `pt-nee` or `guided`.
    pub integrator: &'static str,
    pub width: u32,
    pub height: u32,
    pub max_depth: u32,
    pub seed: u64,
    pub threads: usize,
    pub budget: Budget,
    pub load_s: f64,
    pub primitives: usize,
    pub texture_bytes: usize,
    /// The `-D NAME=VALUE` arguments, as given.
    pub params: &'a [String],
    pub load_warnings: &'a [String],
    pub mean_rgb: [f64; 3],
    pub mean_std_error_rgb: [f64; 3],
    pub output: OutputFiles,
    /// The integrator's keys (`spp`, `time_s`, `rays`, `stages`, ...) at the top level.
    #[serde(flatten)]
    pub run: RunStats<'a>,
}

/// The render's budget: `{"time_s": seconds}` or `{"spp": passes}`.
#[derive(Serialize)]
pub(super) enum Budget {
    #[serde(rename = "time_s")]
    TimeS(f64),
    #[serde(rename = "spp")]
    Spp(u32),
}

/// The files the render wrote.
#[derive(Serialize)]
pub(super) struct OutputFiles {
    pub exr: String,
    pub png: String,
}

/// What the integrator measured: the unguided integrators' keys or the guided one's.
#[derive(Serialize)]
#[serde(untagged)]
pub(super) enum RunStats<'a> {
    Plain(Box<PlainRun>),
    Guided(Box<GuidedRun<'a>>),
}

/// A stage that has nothing to report but whether it ran and why (or why not).
#[derive(Serialize)]
struct Stage {
    ran: bool,
    reason: &'static str,
}

impl Stage {
    /// A stage that did not run.
    fn skipped(reason: &'static str) -> Self {
        Self { ran: false, reason }
    }
}

/// Russian roulette: `--rr throughput` from the scene's `rr_depth`, `--rr guided` (the
/// library's weight window with splitting, at every vertex) with what it did.
#[derive(Serialize)]
struct RrStage {
    ran: bool,
    mode: &'static str,
    rr_depth: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    guided: Option<Box<GuidedRr>>,
}

/// What the weight window did (`--rr guided`).
#[derive(Serialize)]
struct GuidedRr {
    decisions: u64,
    no_estimate: u64,
    killed: u64,
    survived: u64,
    split_vertices: u64,
    extra_paths: u64,
    mean_split: f64,
    max_split: u32,
    learning_passes: u32,
    grid_samples: u64,
    grid_rejected: u64,
    grid_fine_cells: u64,
    grid_coarse_cells: u64,
    trial_passes: u32,
    window_off_passes: u32,
    waited_passes: u32,
    /// The window's efficiency trial: its verdict, or where it stood when the render ended.
    #[serde(skip_serializing_if = "Option::is_none")]
    trial: Option<WindowTrialStats>,
}

/// The window's efficiency trial (`--rr-trial`): the window ("on") against no window ("off"),
/// relMSE per pass × seconds per pass, and the interval of their ratio.
#[derive(Serialize)]
struct WindowTrialStats {
    /// `verdict` (the interval excluded 1) or `unfinished` (the render ended first).
    state: &'static str,
    keep_window: bool,
    on_passes: u32,
    off_passes: u32,
    cost_ratio: f64,
    ratio_low: f64,
    ratio_high: f64,
    z: f64,
    /// Each arm's relMSE per pass (`V`) and mean seconds per pass (`t`): the cost ratio is
    /// `V_on t_on / (V_off t_off)`.
    on_relmse_per_pass: f64,
    on_seconds_per_pass: f64,
    off_relmse_per_pass: f64,
    off_seconds_per_pass: f64,
}

impl WindowTrialStats {
    fn new(state: &'static str, v: &guiding::TrialVerdict) -> Self {
        Self {
            state,
            keep_window: guiding::WindowTrial::window_pays(v),
            on_passes: v.guided_passes,
            off_passes: v.unguided_passes,
            cost_ratio: v.cost_ratio,
            ratio_low: v.ratio_low,
            ratio_high: v.ratio_high,
            z: v.z,
            on_relmse_per_pass: v.guided_variance,
            on_seconds_per_pass: v.guided_seconds,
            off_relmse_per_pass: v.unguided_variance,
            off_seconds_per_pass: v.unguided_seconds,
        }
    }
}

impl GuidedRr {
    fn new(s: &RouletteStats) -> Self {
        Self {
            decisions: s.decisions,
            no_estimate: s.missing,
            killed: s.killed,
            survived: s.survived,
            split_vertices: s.split_vertices,
            extra_paths: s.extra_paths,
            mean_split: s.mean_split(),
            max_split: s.max_split,
            learning_passes: s.learning_passes,
            grid_samples: s.grid.samples,
            grid_rejected: s.grid.rejected,
            grid_fine_cells: s.grid.fine_cells,
            grid_coarse_cells: s.grid.coarse_cells,
            trial_passes: s.trial_passes,
            window_off_passes: s.window_off_passes,
            waited_passes: s.waited_passes,
            trial: match (&s.verdict, &s.latest) {
                (Some(v), _) => Some(WindowTrialStats::new("verdict", v)),
                (None, Some(v)) => Some(WindowTrialStats::new("unfinished", v)),
                (None, None) => None,
            },
        }
    }
}

/// Participating media: whether the scene has any (or `null` surfaces), the scattering
/// points the render made in them, and which media the guided integrator guided.
#[derive(Serialize, Clone)]
struct MediaStage {
    ran: bool,
    reason: &'static str,
    /// Media in the scene.
    media: usize,
    /// The camera sits in a medium.
    camera_in_medium: bool,
    /// Scattering points inside media (phase-function vertices).
    medium_vertices: u64,
    /// Of those, the ones the guide guided (the media `guiding` lists as guided).
    guided_medium_vertices: u64,
    /// Per medium, in the scene's order: the library's thin-medium rule
    /// (`guiding::media`) and whether this render guided its scattering points.
    guiding: Vec<MediumGuidingStage>,
}

/// One medium's entry of [`MediaStage::guiding`].
#[derive(Serialize, Clone)]
struct MediumGuidingStage {
    /// `τ_s = σ_s,max · d`.
    scattering_depth: f32,
    /// `d`: the diagonal of the region the medium fills.
    extent: f32,
    /// Its scattering points were guided.
    guided: bool,
    reason: String,
}

/// What the media stage reports: the scene, its scattering points, and whether (and by the
/// thin-medium rule or not) the render guided media.
pub(super) struct MediaInputs<'a> {
    pub scene: &'a Scene,
    pub medium_vertices: u64,
    pub guided_medium_vertices: u64,
    /// The guided render's options (`None`: an unguided render).
    pub options: Option<&'a GuidedOptions>,
}

/// The NEE, media and Russian-roulette stages, the same for every integrator.
pub(super) struct CommonStages {
    nee: Stage,
    media: MediaStage,
    russian_roulette: RrStage,
}

impl CommonStages {
    /// `nee_ran`: the NEE stage ran; `nee_asked`: it was requested (the reason why it did not
    /// run tells the two cases apart).
    pub fn new(
        nee_ran: bool,
        nee_asked: bool,
        rr: Roulette,
        media: MediaInputs<'_>,
        guided: Option<&RouletteStats>,
    ) -> Self {
        let MediaInputs {
            scene,
            medium_vertices,
            guided_medium_vertices,
            options,
        } = media;
        // A guided render with `--guide-media` auto or on, in a scene with media.
        let media_guided = options.is_some_and(|o| o.guide_media) && !scene.media.is_empty();
        let thin_rule = options.is_none_or(|o| o.thin_media_rule);
        let rr_depth = scene.settings.rr_depth;
        let reason = if nee_ran {
            "NEE + MIS on every non-delta vertex (delta BSDFs are not connected)"
        } else if !nee_asked {
            "not requested (integrator pt or --nee off)"
        } else {
            "skipped: the scene has no emitter NEE can sample"
        };
        Self {
            nee: Stage {
                ran: nee_ran,
                reason,
            },
            media: MediaStage {
                ran: scene.has_volumes,
                reason: if scene.has_volumes && media_guided {
                    "free-flight sampling in homogeneous media, null surfaces crossed, shadow \
                     rays carry transmittance; the scattering points of the media in `guiding` \
                     are guided (the guide over the whole sphere in MIS with the phase \
                     function)"
                } else if scene.has_volumes {
                    "free-flight sampling in homogeneous media, null surfaces crossed, shadow \
                     rays carry transmittance; medium vertices sample the phase function"
                } else {
                    "skipped: no media and no null surfaces (one closest-hit query per ray)"
                },
                media: scene.media.len(),
                camera_in_medium: scene.camera_medium != NO_MEDIUM,
                medium_vertices,
                guided_medium_vertices,
                guiding: media_guiding(scene)
                    .iter()
                    .map(|m| MediumGuidingStage {
                        scattering_depth: m.scattering_depth,
                        extent: m.extent,
                        guided: options.is_some_and(|o| o.guides_medium(m)),
                        reason: if !media_guided {
                            "phase sampling: not a guided render, or --guide-media off".into()
                        } else if !thin_rule {
                            "guided: --guide-media on (every medium)".into()
                        } else if m.guided {
                            format!(
                                "guided: scattering optical depth {:.3} >= {}",
                                m.scattering_depth, MIN_GUIDED_SCATTERING_DEPTH
                            )
                        } else {
                            format!(
                                "skipped (thin): scattering optical depth {:.3} < {}, a ray \
                                 crossing it scatters with probability below {:.1} %; phase \
                                 sampling, no training samples",
                                m.scattering_depth,
                                MIN_GUIDED_SCATTERING_DEPTH,
                                100.0 * (1.0 - (-m.scattering_depth).exp())
                            )
                        },
                    })
                    .collect(),
            },
            russian_roulette: RrStage {
                ran: rr != Roulette::Off,
                mode: match rr {
                    Roulette::Off => "off",
                    Roulette::Throughput => "throughput",
                    Roulette::Guided => "guided",
                    Roulette::Efficiency => "efficiency",
                    Roulette::GuidedUnweighted => "guided-unweighted",
                },
                rr_depth,
                guided: guided.map(|g| Box::new(GuidedRr::new(g))),
            },
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Unguided integrators (`pt`, `pt-nee`).

/// The keys of an unguided render.
#[derive(Serialize)]
pub(super) struct PlainRun {
    spp: u32,
    time_s: PlainTimes,
    rays: u64,
    rays_per_second: f64,
    /// Always 0: nothing is trained.
    training_samples_used: u64,
    stages: PlainStages,
}

/// The wall time of an unguided render: all of it tracing.
#[derive(Serialize)]
struct PlainTimes {
    wall: f64,
    tracing: f64,
    inference: f64,
    training: f64,
}

/// The stages of an unguided render: no guiding, no training.
#[derive(Serialize)]
struct PlainStages {
    nee: Stage,
    media: MediaStage,
    guiding: Stage,
    product_inputs: Stage,
    training: Stage,
    russian_roulette: RrStage,
}

impl PlainRun {
    pub fn new(p: &RenderStats, common: CommonStages) -> Self {
        let wall = p.wall.as_secs_f64();
        const UNGUIDED: &str = "unguided integrator";
        Self {
            spp: p.passes,
            time_s: PlainTimes {
                wall,
                tracing: wall,
                inference: 0.0,
                training: 0.0,
            },
            rays: p.rays,
            rays_per_second: p.rays as f64 / wall.max(1e-9),
            training_samples_used: 0,
            stages: PlainStages {
                nee: common.nee,
                media: common.media,
                guiding: Stage::skipped(UNGUIDED),
                product_inputs: Stage::skipped(UNGUIDED),
                training: Stage::skipped(UNGUIDED),
                russian_roulette: common.russian_roulette,
            },
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The guided integrator.

/// The keys of a guided render.
#[derive(Serialize)]
pub(super) struct GuidedRun<'a> {
    spp: u32,
    /// The guide's description.
    guide: &'a str,
    /// The Vulkan device of `--device gpu`; `null` on the CPU.
    device: Option<&'a str>,
    time_s: GuidedTimes,
    rays: u64,
    rays_per_second: f64,
    /// Recorded samples the field took (neither rejected nor overflowed).
    training_samples_used: u64,
    training_samples: TrainingSamples,
    stages: GuidedStages<'a>,
}

/// The wall time of a guided render split into its parts.
#[derive(Serialize)]
struct GuidedTimes {
    wall: f64,
    tracing: f64,
    inference: f64,
    /// The guide queries' thread-seconds, summed over the render threads.
    inference_thread_s: f64,
    training: f64,
    cache_build: f64,
    /// The per-pass bookkeeping and the final combination.
    other: f64,
}

/// What became of the training samples the render recorded.
#[derive(Serialize)]
struct TrainingSamples {
    recorded: u64,
    rejected: u64,
    overflowed: u64,
    recorded_after_training: u64,
}

/// The stages of a guided render.
#[derive(Serialize)]
struct GuidedStages<'a> {
    nee: Stage,
    media: MediaStage,
    guiding: GuidingStage,
    product_inputs: ProductInputsStage,
    training: TrainingStage<'a>,
    russian_roulette: RrStage,
    efficiency_trial: TrialStage,
    pass_weights: PassWeightsStage,
    training_probe: ProbeStage,
    guide_cache: CacheStage<'a>,
    /// `null` when the selection fit did not run.
    selection_fit: Option<SelectionFit>,
    /// `null` when the refit after the trial did not run.
    selection_refit: Option<SelectionRefit>,
}

/// Guide-or-BSDF decisions and guide queries.
#[derive(Serialize)]
struct GuidingStage {
    ran: bool,
    guided_vertices: u64,
    guide_queries: u64,
    reason: &'static str,
}

/// Whether the guide read the product inputs (the product target).
#[derive(Serialize)]
struct ProductInputsStage {
    ran: bool,
    all_materials_diffuse: bool,
    reason: &'static str,
}

/// What training did, and what the library's schedule did.
#[derive(Serialize)]
struct TrainingStage<'a> {
    ran: bool,
    passes: u32,
    stopped_after_pass: u32,
    planned_passes: u32,
    converged_at_pass: Option<u32>,
    skipped_passes: u32,
    loss_history: &'a [f64],
    steps: u64,
    steps_after_stop: u64,
    last_loss: Option<f64>,
    schedule: Schedule,
}

/// [`guiding::ScheduleReport`].
#[derive(Serialize)]
struct Schedule {
    updates: u64,
    steps: u64,
    seconds_per_step: Option<f64>,
    training_seconds: f64,
    training_phase_tracing_seconds: f64,
    training_share: Option<f64>,
}

/// The guide cache.
#[derive(Serialize)]
struct CacheStage<'a> {
    ran: bool,
    /// `null` when off, else why it was not used or its size.
    mode: Option<&'a str>,
    cells: u64,
    hits: u64,
    misses: u64,
}

/// The per-cell selection-probability fit ([`guiding::SelectionReport`]).
#[derive(Serialize)]
struct SelectionFit {
    guide_cost: Option<f64>,
    samples_used: u64,
    cells_fitted: u64,
    cells_off: u64,
    cells_global: u64,
    global: f64,
    mean: f64,
    variance_ratio: Option<f64>,
}

/// The refit after the trial, with the variance share it used.
#[derive(Serialize)]
struct SelectionRefit {
    variance_share: f64,
    cells_off: u64,
    global: f64,
    mean: f64,
    variance_ratio: Option<f64>,
}

/// A stage that ends in a verdict (the efficiency trial, the training probe): off, ran
/// without a verdict yet (`U`), or its verdict (`F`), with `ran` and `finished` flags.
#[derive(Serialize)]
#[serde(untagged)]
enum VerdictStage<U, F> {
    Off(Stage),
    Unfinished(Ran<U>),
    Finished(Ran<F>),
}

/// A [`VerdictStage`] that ran: the flags, then the stage's own values.
#[derive(Serialize)]
struct Ran<T> {
    ran: bool,
    finished: bool,
    #[serde(flatten)]
    values: T,
}

impl<U, F> VerdictStage<U, F> {
    fn unfinished(values: U) -> Self {
        Self::Unfinished(Ran {
            ran: true,
            finished: false,
            values,
        })
    }

    fn finished(values: F) -> Self {
        Self::Finished(Ran {
            ran: true,
            finished: true,
            values,
        })
    }
}

/// The efficiency trial: off, unfinished, or its verdict.
type TrialStage = VerdictStage<TrialUnfinished, TrialFinished>;

/// An efficiency trial without a verdict yet: its passes and, once each arm has 2, the
/// latest estimate (the guide stays on meanwhile).
#[derive(Serialize)]
struct TrialUnfinished {
    passes: u32,
    /// The first look straddled 1 and the trial went on.
    continued: bool,
    /// The guided arm was restarted after the refit at the first look.
    restarted: bool,
    first_look: Option<TrialEstimate>,
    latest: Option<TrialEstimate>,
}

/// A finished efficiency trial ([`guiding::TrialVerdict`]).
#[derive(Serialize)]
struct TrialFinished {
    passes: u32,
    keep_guide: bool,
    /// The `Debug` name of the [`guiding::Verdict`].
    evidence: String,
    continued: bool,
    restarted: bool,
    first_look: Option<TrialEstimate>,
    #[serde(flatten)]
    estimate: TrialEstimate,
    passes_guide_off: u32,
}

/// One estimate of the trial ([`guiding::TrialVerdict`]).
#[derive(Serialize)]
struct TrialEstimate {
    guided_passes: u32,
    unguided_passes: u32,
    z: f64,
    cost_ratio_interval: [Option<f64>; 2],
    guided_relmse_per_pass: Option<f64>,
    unguided_relmse_per_pass: Option<f64>,
    guided_seconds_per_pass: f64,
    unguided_seconds_per_pass: f64,
    cost_ratio: Option<f64>,
    pixels_skipped: u64,
}

impl TrialEstimate {
    fn new(v: &guiding::TrialVerdict) -> Self {
        Self {
            guided_passes: v.guided_passes,
            unguided_passes: v.unguided_passes,
            z: v.z,
            cost_ratio_interval: [finite(v.ratio_low), finite(v.ratio_high)],
            guided_relmse_per_pass: finite(v.guided_variance),
            unguided_relmse_per_pass: finite(v.unguided_variance),
            guided_seconds_per_pass: v.guided_seconds,
            unguided_seconds_per_pass: v.unguided_seconds,
            cost_ratio: finite(v.cost_ratio),
            pixels_skipped: v.pixels_skipped,
        }
    }
}

/// The training probe: off, without a verdict, or its verdict.
type ProbeStage = VerdictStage<ProbeUnfinished, ProbeFinished>;

/// A training probe whose look has no estimate (the render ended first).
#[derive(Serialize)]
struct ProbeUnfinished {
    at_pass: u32,
    steps: u64,
    passes: u32,
}

/// A training probe's look and decision ([`host_demo::render::strategy::probe::ProbeStats`]).
#[derive(Serialize)]
struct ProbeFinished {
    at_pass: u32,
    steps: u64,
    passes: u32,
    seconds: f64,
    /// Training went on after the look (its interval lay below 1, or straddled 1).
    training_resumed: bool,
    /// What the latest look decided: `train on` (below 1), `look again` (straddles 1) or
    /// `end training` (above 1, or nothing measured).
    decision: &'static str,
    /// Looks taken (one per quarter of the training phase while each straddles 1).
    looks: u32,
    #[serde(flatten)]
    estimate: TrialEstimate,
}

/// The inverse-variance combination of the passes: off, or what it did.
#[derive(Serialize)]
#[serde(untagged)]
enum PassWeightsStage {
    Off(Stage),
    Ran {
        ran: bool,
        fell_back: bool,
        predicted_gain: Option<f64>,
        seconds: f64,
        groups: Vec<PassGroup>,
    },
}

/// One group of passes of the combination.
#[derive(Serialize)]
struct PassGroup {
    group: GroupName,
    passes: u32,
    relmse_per_pass: [Option<f64>; 2],
    share: Option<f64>,
}

/// A group: `"guided"`, `"unguided"` or `{"training_pass": index}`.
#[derive(Serialize)]
#[serde(untagged)]
enum GroupName {
    Named(&'static str),
    Training { training_pass: u32 },
}

impl<'a> GuidedRun<'a> {
    /// `threads`: the render threads (the guide queries' thread-seconds over them estimate
    /// their share of the tracing wall time); `product`: the product target;
    /// `all_diffuse`: every material is diffuse.
    pub fn new(
        g: &'a GuidedStats,
        threads: usize,
        product: bool,
        all_diffuse: bool,
        common: CommonStages,
    ) -> Self {
        let trace = g.trace.as_secs_f64();
        // Guide queries run inside the render threads: their thread-seconds divided by
        // the thread count estimate their share of the tracing wall time.
        let inference = (g.query.as_secs_f64() / threads as f64).min(trace);
        let training = g.training.as_secs_f64();
        let cache_build = g.cache_build.as_secs_f64();
        // The render's own clock: also the per-pass bookkeeping and the final combination
        // ("other" below), which the parts leave out.
        let wall = g.wall.as_secs_f64().max(trace + training + cache_build);
        Self {
            spp: g.passes,
            guide: &g.model,
            device: g.device.as_deref(),
            time_s: GuidedTimes {
                wall,
                tracing: trace - inference,
                inference,
                inference_thread_s: g.query.as_secs_f64(),
                training,
                cache_build,
                other: wall - trace - training - cache_build,
            },
            rays: g.rays,
            rays_per_second: g.rays as f64 / wall.max(1e-9),
            training_samples_used: g
                .samples_recorded
                .saturating_sub(g.rejected_samples + g.overflowed_samples),
            training_samples: TrainingSamples {
                recorded: g.samples_recorded,
                rejected: g.rejected_samples,
                overflowed: g.overflowed_samples,
                recorded_after_training: g.samples_recorded_after_training,
            },
            stages: GuidedStages::new(g, product, all_diffuse, common),
        }
    }
}

impl<'a> GuidedStages<'a> {
    fn new(g: &'a GuidedStats, product: bool, all_diffuse: bool, common: CommonStages) -> Self {
        Self {
            nee: common.nee,
            media: common.media,
            guiding: GuidingStage {
                ran: g.guided_vertices > 0,
                guided_vertices: g.guided_vertices,
                guide_queries: g.guide_queries,
                reason: "delta, smooth-coated and near-specular vertices use BSDF sampling only",
            },
            product_inputs: ProductInputsStage {
                ran: product,
                all_materials_diffuse: all_diffuse,
                reason: if !product {
                    "skipped: the radiance target (the default) reads no product inputs"
                } else if all_diffuse {
                    "product target requested explicitly although every material is diffuse"
                } else {
                    "product target"
                },
            },
            training: TrainingStage::new(g),
            russian_roulette: common.russian_roulette,
            efficiency_trial: TrialStage::new(g.trial.as_ref()),
            pass_weights: PassWeightsStage::new(g.pass_weights.as_ref()),
            training_probe: ProbeStage::new(g.probe.as_ref()),
            guide_cache: CacheStage {
                ran: g.cache_hits > 0,
                mode: g.cache.as_deref(),
                cells: g.cache_cells,
                hits: g.cache_hits,
                misses: g.cache_misses,
            },
            selection_fit: g.selection_fit.map(|r| SelectionFit {
                guide_cost: g.guide_cost.map(f64::from).and_then(finite),
                samples_used: r.samples_used,
                cells_fitted: r.cells_fitted,
                cells_off: r.cells_off,
                cells_global: r.cells_global,
                global: f64::from(r.global),
                mean: f64::from(r.mean),
                variance_ratio: finite(r.variance_ratio),
            }),
            selection_refit: g.selection_refit.map(|(share, r)| SelectionRefit {
                variance_share: f64::from(share),
                cells_off: r.cells_off,
                global: f64::from(r.global),
                mean: f64::from(r.mean),
                variance_ratio: finite(r.variance_ratio),
            }),
        }
    }
}

impl<'a> TrainingStage<'a> {
    fn new(g: &'a GuidedStats) -> Self {
        let s = &g.schedule;
        Self {
            ran: g.training_passes > 0,
            passes: g.training_passes,
            stopped_after_pass: g.training_passes,
            planned_passes: g.passes_planned_for_training,
            converged_at_pass: g.converged_at_pass,
            skipped_passes: g
                .passes_planned_for_training
                .saturating_sub(g.training_passes),
            loss_history: &g.loss_history,
            steps: g.training_steps,
            steps_after_stop: g.training_steps_after_training,
            last_loss: finite(g.last_loss),
            schedule: Schedule {
                updates: s.updates,
                steps: s.steps,
                seconds_per_step: finite(s.seconds_per_step),
                training_seconds: s.trained_seconds,
                training_phase_tracing_seconds: s.traced_seconds,
                training_share: finite(s.training_share()),
            },
        }
    }
}

impl TrialStage {
    fn new(t: Option<&TrialStats>) -> Self {
        let Some(t) = t else {
            return Self::Off(Stage::skipped(
                "off, an spp budget, or training never stopped",
            ));
        };
        let continued = t.first_look.is_some();
        let first_look = t.first_look.as_ref().map(TrialEstimate::new);
        match &t.verdict {
            None => Self::unfinished(TrialUnfinished {
                passes: t.passes,
                continued,
                restarted: t.restarted,
                first_look,
                latest: t.latest.as_ref().map(TrialEstimate::new),
            }),
            Some(v) => Self::finished(TrialFinished {
                passes: t.passes,
                keep_guide: v.keep_guide,
                evidence: format!("{:?}", v.evidence),
                continued,
                restarted: t.restarted,
                first_look,
                estimate: TrialEstimate::new(v),
                passes_guide_off: t.passes_guide_off,
            }),
        }
    }
}

impl ProbeStage {
    fn new(p: Option<&ProbeStats>) -> Self {
        let Some(p) = p else {
            return Self::Off(Stage::skipped(
                "off, the efficiency trial is off, or training ended before the look",
            ));
        };
        match &p.verdict {
            None => Self::unfinished(ProbeUnfinished {
                at_pass: p.at_pass,
                steps: p.steps,
                passes: p.passes,
            }),
            Some(v) => Self::finished(ProbeFinished {
                at_pass: p.at_pass,
                steps: p.steps,
                passes: p.passes,
                seconds: p.seconds,
                training_resumed: p.resumed(),
                decision: match p.decision {
                    Some(LookDecision::TrainOn) => "train on",
                    Some(LookDecision::LookAgain) => "look again",
                    _ => "end training",
                },
                looks: p.looks,
                estimate: TrialEstimate::new(v),
            }),
        }
    }
}

impl PassWeightsStage {
    fn new(w: Option<&PassWeightStats>) -> Self {
        let Some(w) = w else {
            return Self::Off(Stage::skipped("off, or a single group of passes"));
        };
        let groups = w
            .groups
            .iter()
            .map(|g| PassGroup {
                group: match g.group {
                    GROUP_GUIDED => GroupName::Named("guided"),
                    GROUP_UNGUIDED => GroupName::Named("unguided"),
                    pass => GroupName::Training {
                        training_pass: pass,
                    },
                },
                passes: g.passes,
                relmse_per_pass: [
                    finite(g.relative_variance[0]),
                    finite(g.relative_variance[1]),
                ],
                share: finite(g.share),
            })
            .collect();
        Self::Ran {
            ran: true,
            fell_back: w.fell_back,
            predicted_gain: finite(w.predicted_gain),
            seconds: w.seconds,
            groups,
        }
    }
}

impl StatsDoc<'_> {
    /// The document as printed: pretty JSON with sorted keys and a final newline.
    pub fn to_json(&self) -> std::io::Result<String> {
        // Through `Value`, whose map sorts the keys, as the `json!` document did.
        let value = serde_json::to_value(self)?;
        Ok(format!("{value:#}\n"))
    }
}
