//! `host-demo bench`: the run-time-against-error benchmark suite.
//!
//! For every scene × method × budget × seed it runs `host-demo render` **as a child process**
//! (the same binary, so each run starts cold, with its own memory, exactly as a user would run
//! it) with `--stats`, compares the image with the scene's reference (relMSE trimmed at 0.1 %
//! and MAPE, [`crate::render::compare`]) and writes into the output directory:
//!
//! * `runs.csv`: every run (scene, method, seed, budget, spp, time split, errors);
//! * `report.md`: per scene and budget the mean ± standard deviation over seeds of relMSE and
//!   MAPE, and the speed-up over `pt` (`relMSE_pt / relMSE_method` at equal budget, as NPM's
//!   Table 2), then the micro-benchmarks;
//! * `<scene>.svg` / `<scene>.png`: relMSE against wall time, log-log, one curve per method;
//! * `micro.csv`: the micro-benchmarks ([`micro`]);
//! * with `--suite`, `suite.md` / `suite.csv`: per scene the ratio to `pt-nee` of the default
//!   guided command and of the best guided method, and their geometric mean ([`suite`]).
//!
//! References: `--reference NAME=FILE.exr` (e.g. rendered by Mitsuba 3 from the same XML), or a
//! long `pt-nee` render cached under `--cache` keyed by the scene file's bytes, the loaded scene's
//! content (so a changed built-in scene or mesh gets a new reference), resolution and reference
//! spp, so it is rendered once per machine and scene version.

pub mod micro;
pub mod plot;
pub mod report;
pub mod suite;

use crate::error::{Error, Result};
use crate::render::compare::{compare, Metrics};
use crate::scene::load::exr::read_exr;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A rendering method of the matrix.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Method {
    /// Short name used in tables and plots (`pt`, `pt-nee`, `npm-product`, …).
    pub name: String,
    /// Arguments passed to `render`.
    pub args: Vec<String>,
}

impl Method {
    /// Parses `pt`, `pt-nee`, `guided` (the default guided command, `--integrator guided` with
    /// the library's default guide and target), or `GUIDE-TARGET` with GUIDE in
    /// npm|nasg|df-n|df-l and TARGET in radiance|product (e.g. `npm-product`), optionally
    /// followed by suffixes: `-nonee` (the
    /// guided integrator without next-event estimation, the papers' setting, compared with
    /// `pt`), `-nocache` / `-frozen` (`--guide-cache off` / `frozen` instead of the default),
    /// `-notrial` (`--guide-trial off`: the guide stays on whether it pays or not), `-noweights`
    /// (`--pass-weights off`: the plain mean of all passes), `-noprobe` (`--training-probe off`),
    /// `-nofit` (`--fit-selection off`), `-nocos` (`--cosine-product off`), `-nomedia`
    /// (`--guide-media off`: medium vertices sample the phase function alone), `-allmedia`
    /// (`--guide-media on`: every medium guided, the thin-medium rule ignored),
    /// and on every method, `pt` and `pt-nee` included, `-grr` (`--rr guided`: the library's
    /// weight window with splitting, kept where its efficiency trial says it pays; `guided`
    /// with a time budget has it by default), `-grra` (`--rr guided --rr-trial off`: the
    /// window in every pass), `-err` (`--rr efficiency`) and `-norr` (`--rr off`: `guided`
    /// without its default window, the guide's share of the gain).
    pub fn parse(full: &str) -> Result<Self> {
        const SUFFIXES: [(&str, &[&str]); 14] = [
            ("-grr", &["--rr", "guided"]),
            ("-norr", &["--rr", "off"]),
            ("-grra", &["--rr", "guided", "--rr-trial", "off"]),
            ("-err", &["--rr", "efficiency"]),
            ("-nonee", &["--nee", "off"]),
            ("-nocache", &["--guide-cache", "off"]),
            ("-frozen", &["--guide-cache", "frozen"]),
            ("-notrial", &["--guide-trial", "off"]),
            ("-noweights", &["--pass-weights", "off"]),
            ("-noprobe", &["--training-probe", "off"]),
            ("-nofit", &["--fit-selection", "off"]),
            ("-nocos", &["--cosine-product", "off"]),
            ("-nomedia", &["--guide-media", "off"]),
            ("-allmedia", &["--guide-media", "on"]),
        ];
        let mut name = full;
        let mut extra: Vec<&str> = Vec::new();
        'strip: loop {
            for (suffix, flags) in SUFFIXES {
                match name.strip_suffix(suffix) {
                    // Only the roulette suffixes apply to the unguided methods.
                    Some(base)
                        if !base.is_empty()
                            && (flags[0] == "--rr" || (base != "pt" && base != "pt-nee")) =>
                    {
                        name = base;
                        extra.splice(0..0, flags.iter().copied());
                        continue 'strip;
                    }
                    _ => {}
                }
            }
            break;
        }
        let mut args: Vec<&str> = match name {
            "pt" => vec!["--integrator", "pt"],
            "pt-nee" => vec!["--integrator", "pt-nee"],
            "guided" => vec!["--integrator", "guided"],
            _ => {
                let (guide, target) = name
                    .rsplit_once('-')
                    .filter(|(g, t)| {
                        g.parse::<guiding::Representation>().is_ok()
                            && ["radiance", "product"].contains(t)
                    })
                    .ok_or_else(|| {
                        Error::Bench(format!(
                            "unknown method '{name}': use pt, pt-nee, guided or GUIDE-TARGET with \
                             GUIDE npm|nasg|df-n|df-l and TARGET radiance|product"
                        ))
                    })?;
                vec![
                    "--integrator",
                    "guided",
                    "--guide",
                    guide,
                    "--target",
                    target,
                ]
            }
        };
        args.extend(extra);
        Ok(Self {
            name: full.to_string(),
            args: args.into_iter().map(String::from).collect(),
        })
    }
}

/// A budget: wall-clock seconds (equal time) or samples per pixel (equal spp).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// `--time S`.
    Seconds(f64),
    /// `--spp N`.
    Spp(u32),
}

impl Budget {
    /// `10` or `10s` → seconds, `64spp` → spp.
    pub fn parse(s: &str) -> Result<Self> {
        let bad = || {
            Error::Bench(format!(
                "budget '{s}': use seconds (10, 10s) or spp (64spp)"
            ))
        };
        if let Some(n) = s.strip_suffix("spp") {
            return n.parse().map(Self::Spp).map_err(|_| bad());
        }
        let v: f64 = s.trim_end_matches('s').parse().map_err(|_| bad())?;
        if v.is_finite() && v > 0.0 {
            Ok(Self::Seconds(v))
        } else {
            Err(bad())
        }
    }

    /// `budget_kind` column of the CSV.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Seconds(_) => "time_s",
            Self::Spp(_) => "spp",
        }
    }

    /// `budget` column of the CSV.
    pub fn value(&self) -> f64 {
        match *self {
            Self::Seconds(s) => s,
            Self::Spp(n) => f64::from(n),
        }
    }

    fn args(&self) -> Vec<String> {
        match *self {
            Self::Seconds(s) => vec!["--time".into(), format!("{s}")],
            Self::Spp(n) => vec!["--spp".into(), n.to_string()],
        }
    }
}

/// Everything `host-demo bench` was asked to do.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Scene specs (`builtin:NAME` or XML paths).
    pub scenes: Vec<String>,
    /// Methods.
    pub methods: Vec<Method>,
    /// Budgets.
    pub budgets: Vec<Budget>,
    /// Seeds per configuration.
    pub seeds: u32,
    /// Image width (height keeps the aspect ratio).
    pub width: u32,
    /// Render threads per run (0 = all).
    pub threads: usize,
    /// spp of the cached `pt-nee` references.
    pub reference_spp: u32,
    /// Given references, by scene spec.
    pub references: Vec<(String, PathBuf)>,
    /// Output directory.
    pub out: PathBuf,
    /// Reference cache directory.
    pub cache: PathBuf,
    /// Fewer repeats and smaller workloads in the micro-benchmarks.
    pub quick_micro: bool,
    /// Skip the micro-benchmarks.
    pub no_micro: bool,
    /// Also write `suite.md` / `suite.csv` ([`suite::write`]).
    pub suite: bool,
    /// A scene whose reference or run fails is skipped with a note instead of ending the
    /// benchmark (its runs are dropped).
    pub keep_going: bool,
    /// Notes for the reports (scenes that were not found, …); skipped scenes are added to them.
    pub notes: Vec<String>,
}

/// One finished run (a row of `runs.csv`).
#[derive(Clone, Debug)]
pub struct RunRecord {
    /// Scene spec.
    pub scene: String,
    /// Method name.
    pub method: String,
    /// Seed.
    pub seed: u32,
    /// Budget.
    pub budget: Budget,
    /// Samples per pixel rendered.
    pub spp: u64,
    /// Wall time of rendering (tracing + training), seconds.
    pub wall_s: f64,
    /// Tracing share.
    pub tracing_s: f64,
    /// Guide inference share.
    pub inference_s: f64,
    /// Training share.
    pub training_s: f64,
    /// Error against the reference.
    pub metrics: Metrics,
}

/// FNV-1a 64 of `bytes`, continuing from `h` (cache keys; not cryptographic).
fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// [`fnv1a`] as a `fmt::Write` sink, to hash `Debug` output without building the string.
struct FnvWriter(u64);

impl std::fmt::Write for FnvWriter {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.0 = fnv1a(self.0, s.as_bytes());
        Ok(())
    }
}

/// Hash of what a scene renders: its primitives, materials, shapes, media, camera and settings as
/// loaded (so a change to a built-in scene's code or to a mesh file gives a new key; an envmap
/// image's pixels are not included, only its settings through the XML bytes).
fn scene_content_hash(spec: &str) -> Result<u64> {
    use std::fmt::Write as _;
    let scene = crate::load_scene(spec)?;
    let mut w = FnvWriter(0xcbf2_9ce4_8422_2325);
    let _ = write!(
        w,
        "{:?}{:?}{:?}{:?}{:?}{:?}{:?}{:?}",
        scene.prims,
        scene.materials,
        scene.shapes,
        scene.point_lights,
        scene.camera,
        scene.settings,
        scene.media,
        scene.camera_medium
    );
    Ok(w.0)
}

/// File-name-safe short name of a scene spec.
pub fn scene_slug(scene: &str) -> String {
    let base = scene
        .strip_prefix("builtin:")
        .map(String::from)
        .unwrap_or_else(|| {
            let p = Path::new(scene);
            let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
            match p
                .parent()
                .and_then(|d| d.file_name())
                .and_then(|s| s.to_str())
            {
                Some(dir) if stem == "scene" => dir.to_string(),
                _ => stem.to_string(),
            }
        });
    base.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Environment variable naming another `host-demo` binary to render with (an A/B comparison
/// of two builds through the same bench, tables and references: e.g. the binary of the
/// commit before a change). By default the bench renders with its own binary.
pub const EXE_VARIABLE: &str = "HOST_DEMO_BENCH_EXE";

fn render(args: &[String]) -> Result<serde_json::Value> {
    let exe = match std::env::var_os(EXE_VARIABLE) {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => std::env::current_exe().map_err(|e| Error::Bench(format!("current_exe: {e}")))?,
    };
    let stats = args
        .iter()
        .position(|a| a == "--stats")
        .and_then(|i| args.get(i + 1))
        .cloned()
        .ok_or_else(|| Error::Bench("internal: render without --stats".into()))?;
    let output = Command::new(&exe)
        .arg("render")
        .args(args)
        .output()
        .map_err(|e| Error::Bench(format!("cannot run {}: {e}", exe.display())))?;
    if !output.status.success() {
        return Err(Error::Bench(format!(
            "render {} failed ({}): {}",
            args.join(" "),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    let text =
        std::fs::read_to_string(&stats).map_err(|e| Error::Bench(format!("{stats}: {e}")))?;
    serde_json::from_str(&text).map_err(|e| Error::Bench(format!("{stats}: {e}")))
}

fn reference_for(opts: &BenchOptions, scene: &str, pb: &ProgressBar) -> Result<PathBuf> {
    if let Some((_, p)) = opts.references.iter().find(|(s, _)| s == scene) {
        return Ok(p.clone());
    }
    let mut key = fnv1a(0xcbf2_9ce4_8422_2325, scene.as_bytes());
    key = fnv1a(key, &scene_content_hash(scene)?.to_le_bytes());
    if !scene.starts_with("builtin:") {
        let bytes = std::fs::read(scene).map_err(|e| Error::Bench(format!("{scene}: {e}")))?;
        key = fnv1a(key, &bytes);
    }
    key = fnv1a(
        key,
        format!(
            "w{} spp{} v{}",
            opts.width,
            opts.reference_spp,
            env!("CARGO_PKG_VERSION")
        )
        .as_bytes(),
    );
    std::fs::create_dir_all(&opts.cache)
        .map_err(|e| Error::Bench(format!("{}: {e}", opts.cache.display())))?;
    let path = opts
        .cache
        .join(format!("{}-{key:016x}.exr", scene_slug(scene)));
    if path.exists() {
        return Ok(path);
    }
    pb.set_message(format!(
        "reference {scene} ({} spp pt-nee)",
        opts.reference_spp
    ));
    let stats = opts
        .cache
        .join(format!("{}-{key:016x}.json", scene_slug(scene)));
    let args: Vec<String> = [
        scene,
        "--integrator",
        "pt-nee",
        "--spp",
        &opts.reference_spp.to_string(),
        "--width",
        &opts.width.to_string(),
        "--seed",
        "1000003",
        "--threads",
        &opts.threads.to_string(),
        "--stats",
        stats.to_str().unwrap_or("reference.json"),
        "--out",
        path.to_str().unwrap_or("reference.exr"),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    render(&args)?;
    Ok(path)
}

fn num(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut v = v;
    for p in path {
        v = &v[*p];
    }
    v.as_f64().unwrap_or(0.0)
}

/// Runs every method × budget × seed of `scene` against its reference, appending to `records`.
fn run_scene(
    opts: &BenchOptions,
    scene: &str,
    pb: &ProgressBar,
    records: &mut Vec<RunRecord>,
) -> Result<()> {
    let reference = read_exr(&reference_for(opts, scene, pb)?)?;
    let slug = scene_slug(scene);
    for budget in &opts.budgets {
        // Seeds outside, methods inside: on a shared machine whose speed drifts over
        // minutes, the methods of one seed run next to each other, so a slow spell falls on
        // every method alike instead of on all seeds of one.
        for seed in 0..opts.seeds {
            for method in &opts.methods {
                pb.set_message(format!("{slug} {} {:?} seed {seed}", method.name, budget));
                let stem = opts.out.join("runs").join(format!(
                    "{slug}-{}-{}{}-s{seed}",
                    method.name,
                    budget.kind(),
                    budget.value()
                ));
                let exr = stem.with_extension("exr");
                let json = stem.with_extension("json");
                let mut args = vec![scene.to_string()];
                args.extend(method.args.iter().cloned());
                args.extend(budget.args());
                for (k, v) in [
                    ("--width", opts.width.to_string()),
                    ("--seed", seed.to_string()),
                    ("--threads", opts.threads.to_string()),
                    ("--stats", json.display().to_string()),
                    ("--out", exr.display().to_string()),
                ] {
                    args.push(k.into());
                    args.push(v);
                }
                let stats = render(&args)?;
                let metrics = compare(&read_exr(&exr)?, &reference)?;
                records.push(RunRecord {
                    scene: scene.to_string(),
                    method: method.name.clone(),
                    seed,
                    budget: *budget,
                    spp: num(&stats, &["spp"]) as u64,
                    wall_s: num(&stats, &["time_s", "wall"]),
                    tracing_s: num(&stats, &["time_s", "tracing"]),
                    inference_s: num(&stats, &["time_s", "inference"]),
                    training_s: num(&stats, &["time_s", "training"]),
                    metrics,
                });
                pb.inc(1);
            }
        }
    }
    Ok(())
}

/// Runs the whole matrix and writes the report; returns the runs.
pub fn run(opts: &BenchOptions) -> Result<Vec<RunRecord>> {
    let io = |e: std::io::Error| Error::Bench(format!("{}: {e}", opts.out.display()));
    std::fs::create_dir_all(opts.out.join("runs")).map_err(io)?;
    let total = opts.scenes.len() * opts.methods.len() * opts.budgets.len() * opts.seeds as usize;
    let pb = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
    pb.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} runs, {elapsed} elapsed, ~{eta} left  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut records = Vec::with_capacity(total);
    let mut notes = opts.notes.clone();
    let per_scene = opts.methods.len() * opts.budgets.len() * opts.seeds as usize;
    for (i, scene) in opts.scenes.iter().enumerate() {
        let before = records.len();
        if let Err(e) = run_scene(opts, scene, &pb, &mut records) {
            if !opts.keep_going {
                return Err(e);
            }
            records.truncate(before);
            let note = format!("{scene} skipped: {e}");
            pb.println(format!("bench: {note}"));
            notes.push(note);
        }
        pb.set_position(((i + 1) * per_scene) as u64);
    }
    pb.finish_and_clear();
    let micro = if opts.no_micro {
        Vec::new()
    } else {
        eprintln!("micro-benchmarks…");
        micro::run(opts.quick_micro).map_err(|e| Error::Bench(format!("micro-benchmarks: {e}")))?
    };
    report::write_all(opts, &records, &micro)?;
    if opts.suite {
        suite::write(opts, &records, &notes)?;
    }
    for scene in &opts.scenes {
        plot::error_vs_time(&opts.out, scene, &records)?;
    }
    Ok(records)
}
