//! The command line: `render`, `bench` and `compare` (clap derive); each command's body lives in
//! its own module.

mod bench;
mod render;
mod stats;

use clap::{Args, Parser, Subcommand, ValueEnum};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "host-demo",
    about = "Wavefront path tracer demo for the guiding library"
)]
pub struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Integrator {
    /// BSDF sampling only.
    Pt,
    /// Next-event estimation + MIS (power heuristic).
    PtNee,
    /// Path guiding (trained online), one-sample MIS with the BSDF; NEE per `--nee`.
    Guided,
}

#[derive(Clone, Copy, ValueEnum)]
enum RouletteArg {
    /// The default: `guided` for the guided integrator with a time budget (the weight window,
    /// kept only where its efficiency trial says it pays), `off` otherwise (the baselines, as
    /// in the papers; a fixed spp, where no trial can weigh the window's time).
    Auto,
    /// No roulette: paths go on to max_depth.
    Off,
    /// Mitsuba's: survival min(max(throughput), 0.95) from the scene's rr_depth.
    Throughput,
    /// The library's weight window (ADRRS) with splitting, from a learned radiance grid.
    Guided,
    /// The same with the efficiency-aware rule (second moment against the pixel's variance).
    Efficiency,
}

impl RouletteArg {
    /// The roulette of a render with `integrator` and, when `timed`, a time budget (see
    /// [`RouletteArg::Auto`]). On the suite of published scenes (30 s, 256 px, 3 seeds) the
    /// window's trial kept it on the classroom, veach-mis and veach-bidir-v3 and switched it off
    /// on the Cornell box, and the guided render with it was 0.69–1.01× `pt-nee`'s relMSE
    /// where without it 0.99–1.18× (`docs/bench-2026-12-08-window`).
    fn resolve(self, integrator: Integrator, timed: bool) -> host_demo::render::Roulette {
        use host_demo::render::Roulette;
        match self {
            Self::Auto if timed && matches!(integrator, Integrator::Guided) => Roulette::Guided,
            Self::Auto | Self::Off => Roulette::Off,
            Self::Throughput => Roulette::Throughput,
            Self::Guided => Roulette::Guided,
            Self::Efficiency => Roulette::Efficiency,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum TargetArg {
    /// Learn the incident radiance.
    Radiance,
    /// Learn the product of BSDF, cosine and radiance.
    Product,
}

/// A library name (`guiding::Representation`, `guiding::ModelSize`) as a CLI value: the
/// library's `FromStr` (one name per concept), its error as clap's.
fn library_name<T: std::str::FromStr<Err = guiding::UnknownName>>(s: &str) -> Result<T, String> {
    s.parse().map_err(|e: guiding::UnknownName| e.to_string())
}

/// `--model-size`: the library's size names; `demo`, this CLI's earlier name of `compact`,
/// still reads as it.
fn model_size_arg(s: &str) -> Result<guiding::ModelSize, String> {
    library_name(if s == "demo" { "compact" } else { s })
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DeviceArg {
    /// The CPU field (no Vulkan).
    Cpu,
    /// A Vulkan device (see --vk-device).
    Gpu,
}

#[derive(Clone, Copy, ValueEnum)]
enum CacheArg {
    /// Every guidable vertex runs the network.
    Off,
    /// The network while training, a spatial cache of the decoded guide afterwards.
    Frozen,
    /// The cache in every pass after the first update (refreshed after each update).
    Always,
}

#[derive(Clone, Copy, ValueEnum)]
enum OnOff {
    /// Enabled.
    On,
    /// Disabled.
    Off,
}

/// A setting the library can decide (auto) or the user forces.
#[derive(Clone, Copy, ValueEnum)]
enum AutoOnOff {
    /// The library's rule decides.
    Auto,
    /// Always.
    On,
    /// Never.
    Off,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render a scene to an EXR file (plus a PNG preview next to it) and print the image mean.
    Render {
        /// `builtin:cornell-box`, `builtin:furnace`, `builtin:door`, or a Mitsuba 3 XML path.
        #[arg(value_name = "SCENE", required_unless_present = "scene_flag")]
        scene: Option<String>,
        /// The scene, as an option (alias of the positional SCENE).
        #[arg(long = "scene", value_name = "SCENE", conflicts_with = "scene")]
        scene_flag: Option<String>,
        /// Estimator.
        #[arg(long, value_enum, default_value = "pt-nee")]
        integrator: Integrator,
        /// Samples per pixel (default: the scene's).
        #[arg(long, conflicts_with = "time")]
        spp: Option<u32>,
        /// Time budget in seconds instead of a fixed spp: passes run until it is used up
        /// (a pass starts only if it is expected to end within the budget; at least one runs).
        /// `--train-fraction` applies to this budget.
        #[arg(long, value_name = "SECONDS")]
        time: Option<f64>,
        /// Russian roulette: auto (the default: guided for the guided integrator with --time,
        /// else off), off (paths go on to max_depth, like the papers), throughput (Mitsuba's,
        /// from the scene's rr_depth; a bare `--rr`) or guided (the library's weight window with
        /// splitting, kept with --time only where its efficiency trial says it pays).
        #[arg(
            long,
            value_enum,
            num_args = 0..=1,
            default_value = "auto",
            default_missing_value = "throughput"
        )]
        rr: RouletteArg,
        /// With --time and a guided --rr: once the grid has learned, alternate passes with and
        /// without the weight window, compare relMSE per pass x seconds per pass on the image,
        /// and keep the window only where it pays (off: the window decides in every pass).
        #[arg(long, value_enum, default_value = "on")]
        rr_trial: OnOff,
        /// Write run statistics (spp, time split, rays/s, training samples, stages) as JSON.
        #[arg(long, value_name = "FILE.json")]
        stats: Option<PathBuf>,
        /// Worker threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Scene parameter `$NAME` (Mitsuba's `-D`): overrides the scene's
        /// `<default name="NAME" value=.../>` (repeatable).
        #[arg(short = 'D', value_name = "NAME=VALUE")]
        define: Vec<String>,
        /// Refuse what the scene loader does not know (an unknown plugin type, property or
        /// element is an error, as before warnings existed); by default it is ignored or
        /// replaced with a warning naming file and line.
        #[arg(long)]
        strict: bool,
        /// Random seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Mitsuba max_depth (default: the scene's).
        #[arg(long)]
        max_depth: Option<u32>,
        /// Override width (height scales to keep the aspect ratio unless --height is given).
        #[arg(long)]
        width: Option<u32>,
        /// Override height.
        #[arg(long)]
        height: Option<u32>,
        /// Output EXR path (the PNG preview goes next to it, same name with `.png`).
        #[arg(long, default_value = "image.exr")]
        out: PathBuf,
        /// The guide and how the guided integrator runs it.
        #[command(flatten)]
        guide: GuideArgs,
        /// How the guide trains (the library's presets unless given).
        #[command(flatten)]
        training: TuningArgs,
    },
    /// Run time against error: scenes × methods × budgets × seeds against references, written as
    /// runs.csv, report.md (equal-budget table, speed-up vs pt, micro-benchmarks) and one
    /// relMSE-vs-time plot per scene (SVG + PNG).
    Bench {
        /// Extra scenes (`builtin:NAME` or Mitsuba XML paths), added to the default set.
        scenes: Vec<String>,
        /// Small matrix (2 built-in scenes, 5 methods, 1 and 2 s, 2 seeds, 64 px wide, quick
        /// micro-benchmarks): a couple of minutes. With --suite: the 2 built-in scenes,
        /// pt-nee and guided, 1 s, 1 seed, 64 px (well under a minute).
        #[arg(long)]
        quick: bool,
        /// The published-scene suite: every ../shared/scenes/*/scene.xml, builtin:door and
        /// host-demo/tests/data/published/*/ (found at run time; what is missing is skipped
        /// with a note); methods pt, pt-nee, guided, npm-radiance, npm-product, nasg-radiance,
        /// df-l-radiance; 30 s, 3 seeds, 256 px; no micro-benchmarks; a scene that fails is
        /// skipped with a note. Writes suite.md / suite.csv (per scene the ratio to pt-nee of
        /// guided and of the best guided method, their geometric mean and the worst case)
        /// besides the usual reports.
        #[arg(long)]
        suite: bool,
        /// Only the scenes given on the command line, not the default set.
        #[arg(long)]
        only: bool,
        /// Methods, comma-separated: pt, pt-nee, guided (the default guided command),
        /// GUIDE-TARGET (npm|nasg|df-n|df-l × radiance|product), each optionally with suffixes
        /// such as -notrial. Default: pt, pt-nee and the eight GUIDE-TARGET.
        #[arg(long, value_delimiter = ',')]
        methods: Option<Vec<String>>,
        /// Budgets, comma-separated: seconds (`10`) or spp (`32spp`). Default 5,10,20,40,32spp
        /// (--suite: 30).
        #[arg(long, value_delimiter = ',')]
        budgets: Option<Vec<String>>,
        /// Seeds per configuration (default 3; --quick 2, --suite --quick 1).
        #[arg(long)]
        seeds: Option<u32>,
        /// Image width in pixels (default 320, --suite 256, --quick 64; height keeps the scene's
        /// aspect ratio).
        #[arg(long)]
        width: Option<u32>,
        /// Render threads per run (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// spp of the cached pt-nee references (default 2048).
        #[arg(long)]
        reference_spp: Option<u32>,
        /// A given reference image for a scene, `SCENE=FILE.exr` (repeatable).
        #[arg(long = "reference", value_name = "SCENE=FILE.exr")]
        references: Vec<String>,
        /// Output directory.
        #[arg(long, default_value = "bench-out")]
        out: PathBuf,
        /// Reference cache directory.
        #[arg(long, default_value = "bench-cache")]
        cache: PathBuf,
        /// Skip the micro-benchmarks.
        #[arg(long)]
        no_micro: bool,
    },
    /// Compare an image with a reference: prints relMSE (trimmed 0.1 %) and MAPE as JSON.
    Compare {
        /// The image to evaluate (EXR).
        image: PathBuf,
        /// The reference (EXR).
        reference: PathBuf,
    },
    /// Write a scene (a built-in one, say) as a Mitsuba 3 scene: DIR/scene.xml and its OBJ
    /// meshes, so that Mitsuba renders what host-demo renders.
    Export {
        /// `builtin:NAME` or a Mitsuba XML path.
        scene: String,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Parses the command line and runs it.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("host-demo: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> host_demo::Result<()> {
    match cli.cmd {
        Cmd::Compare { image, reference } => compare(&image, &reference),
        Cmd::Export { scene, out } => {
            let scene = host_demo::scene::load::load_scene(&scene)?;
            let path = host_demo::scene::export::write_mitsuba(&scene, &out)?;
            println!("wrote {}", path.display());
            Ok(())
        }
        Cmd::Bench { .. } => bench::bench_cmd(cli.cmd),
        Cmd::Render { .. } => render::render_cmd(cli.cmd),
    }
}

fn compare(image: &Path, reference: &Path) -> host_demo::Result<()> {
    let (a, b) = (
        host_demo::scene::load::exr::read_exr(image)?,
        host_demo::scene::load::exr::read_exr(reference)?,
    );
    let m = host_demo::render::compare::compare(&a, &b)?;
    let out = json!({
        "image": image.display().to_string(),
        "reference": reference.display().to_string(),
        "width": a.width,
        "height": a.height,
        "relmse": m.relmse,
        "relmse_untrimmed": m.relmse_untrimmed,
        "relmse_trimmed_pixels": m.trimmed,
        "mape": m.mape,
        "epsilon": host_demo::render::compare::EPSILON,
    });
    println!("{out:#}");
    Ok(())
}

/// The guided integrator's arguments: the guide and how it runs (besides [`TuningArgs`]).
#[derive(Args)]
struct GuideArgs {
    /// Guiding model (`--integrator guided`): npm (vMF mixtures), nasg (NASG mixtures
    /// with a learned selection probability), df-n / df-l (distribution factorisation,
    /// nearest / linear reconstruction).
    #[arg(long, value_parser = library_name::<guiding::Representation>, default_value = "npm")]
    guide: guiding::Representation,
    /// Guiding target (`--integrator guided`). Default: `radiance` (the library's
    /// `npm_radiance` preset: the guide cache and the cosine product apply); `product`
    /// learns `f · L · cos` per outgoing direction and never uses the cache.
    #[arg(long, value_enum)]
    target: Option<TargetArg>,
    /// Model size preset (`--integrator guided`): compact (4-level grid, MLP 2 x 32),
    /// small (the library's tiny test presets), paper (4.1 M parameters; slow on a CPU).
    #[arg(long, value_parser = model_size_arg, default_value = "compact")]
    model_size: guiding::ModelSize,
    /// Answer radiance-target guide queries from a spatial cache of the decoded guide
    /// (one network pass per occupied cell, stochastic trilinear lookup) instead of the
    /// network per vertex; product guides never use it.
    #[arg(long, value_enum, default_value = "always")]
    guide_cache: CacheArg,
    /// With the guide cache (NPM / DF): fit the guide-selection probability per cell when
    /// training stops (minimum estimated second moment of the one-sample MIS estimator over
    /// c = 0, 0.1, ..., 0.9, with the MIS-weighted incident radiance of the last training
    /// pass), instead of the constant --selection-probability; c = 0 skips the guide there.
    #[arg(long, value_enum, default_value = "on")]
    fit_selection: OnOff,
    /// At guided scattering points inside media, multiply an NPM guide by the vMF fit of the
    /// Henyey–Greenstein phase function (Open PGL's product in volumes); off: the radiance
    /// guide alone.
    #[arg(long, value_enum, default_value = "on")]
    phase_product: OnOff,
    /// Multiply a radiance-target NPM guide by the clamped cosine of the shading normal
    /// (Open PGL's `ApplyCosineProduct`; the cache keeps one product lane per normal bin, and
    /// one without it for scattering points in media).
    #[arg(long, value_enum, default_value = "on")]
    cosine_product: OnOff,
    /// Guide the scattering points inside media (full-sphere guide, in one-sample MIS with
    /// the phase function): auto, those of the media the library's thin-medium rule says are
    /// worth it (scattering optical depth across the medium >= 0.05, `guiding::media`); on,
    /// every medium; off, none (they sample the phase function alone).
    #[arg(long, value_enum, default_value = "auto")]
    guide_media: AutoOnOff,
    /// With --time: once training has stopped, alternate 4 guided and 4 unguided passes
    /// (BSDF sampling and NEE), compare relMSE per pass x seconds per pass on the image,
    /// and switch the guide off for the rest of the render when it does not pay.
    #[arg(long, value_enum, default_value = "on")]
    guide_trial: OnOff,
    /// Combine the passes with inverse-variance weights (each training pass its own group,
    /// the guided and the unguided passes after training one each; weights estimated on the
    /// other half of a checkerboard so the image stays unbiased) instead of the plain mean.
    #[arg(long, value_enum, default_value = "on")]
    pass_weights: OnOff,
    /// With the trial on: a quarter of the way into the training phase (and after 64 Adam
    /// steps), pause training for an early look (2 to 4 guided passes read from the guide
    /// cache against as many with the guide off, relMSE per pass x seconds per pass): when the
    /// interval lies above 1 training ends there and the trial after it decides whether the
    /// guide stays on; below 1 training goes on; straddling 1, training goes on to another
    /// look a quarter of the phase later (at most three).
    #[arg(long, value_enum, default_value = "on")]
    training_probe: OnOff,
    /// NEE in the guided integrator (default: on when the scene has an emitter NEE can sample).
    #[arg(long, value_enum)]
    nee: Option<OnOff>,
    /// Where the guide runs (`--integrator guided`, every guide): `cpu`, or `gpu` (Vulkan:
    /// the network's inference, the guide's samples and pdfs and the arithmetic of its
    /// training steps through the SPIR-V kernels of guiding-gpu; tracing stays on the CPU).
    /// Needs a build with `--features guiding-gpu/shaders`. A device failure ends the
    /// render with the error unless --fallback-to-cpu.
    #[arg(long, value_enum, default_value = "cpu")]
    device: DeviceArg,
    /// With `--device gpu`: when the device fails mid-render, go on on the CPU with the
    /// weights the device trained instead of ending the render with the error.
    #[arg(long)]
    fallback_to_cpu: bool,
    /// The Vulkan device of `--device gpu`: `auto` (discrete GPU first, then integrated,
    /// then lavapipe), `gpu` (never a CPU implementation), `cpu` (lavapipe), an index, or
    /// `name:TEXT`. The environment variable GUIDING_VK_DEVICE overrides `auto`.
    #[arg(long, default_value = "auto")]
    vk_device: String,
}

/// The training and guide-selection arguments as given (`None`: the library's preset).
#[derive(Args)]
struct TuningArgs {
    /// Fraction of the budget (spp passes or time) in the training phase, in [0, 1].
    /// Default: the library's `ScheduleOptions::DEFAULT` (0.2).
    #[arg(long)]
    train_fraction: Option<f32>,
    /// Share of the training phase's wall clock given to Adam steps, in (0, 1). Default:
    /// the library's (1/3; `guiding::schedule`).
    #[arg(long)]
    training_share: Option<f64>,
    /// Reproducible training instead of the time share: one update per training pass
    /// with this many epochs over its samples, at most --steps-per-update steps.
    #[arg(long)]
    train_epochs: Option<f64>,
    /// Guide-selection probability c in [0, 1] (NASG uses its learned value). Default: the
    /// library's preset (0.3; `guiding::config::PRESET_SELECTION_PROBABILITY`).
    #[arg(long)]
    selection_probability: Option<f32>,
    /// Most Adam steps per update of --train-epochs (and of the library's plain
    /// `update`). Default: the library's preset (64).
    #[arg(long)]
    steps_per_update: Option<u32>,
    /// Training minibatch size. Default: the library's preset (8192).
    #[arg(long)]
    batch_size: Option<usize>,
    /// Learning rate of the guide's Adam optimiser. Default: the library's preset (5e-3
    /// for NPM, 3e-2 for NASG and DF; `guiding::config`).
    #[arg(long)]
    learning_rate: Option<f32>,
    /// Stop training when the mean loss has not improved by --plateau-margin (relative)
    /// over the best so far for this many consecutive passes (0, the default: train for the
    /// whole training phase).
    #[arg(long, default_value_t = 0)]
    plateau_window: u32,
    /// Relative improvement of the mean loss that counts as progress (see
    /// --plateau-window).
    #[arg(long, default_value_t = 0.01)]
    plateau_margin: f32,
    /// Cells of the guide cache along the scene's longest axis, in [1, 256].
    #[arg(long, default_value_t = 64)]
    guide_cache_resolution: u32,
}
