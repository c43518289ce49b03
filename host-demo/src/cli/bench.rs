//! `host-demo bench`: the equal-time benchmark matrix.

use super::Cmd;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The default scenes of `bench`: the two shared Bitterli scenes (when `../shared/scenes`
/// exists next to the working directory) and the built-in door.
const BENCH_SCENES: [&str; 3] = [
    "../shared/scenes/cornell-box/scene.xml",
    "../shared/scenes/veach-mis/scene.xml",
    "builtin:door",
];
const BENCH_METHODS: [&str; 10] = [
    "pt",
    "pt-nee",
    "npm-radiance",
    "npm-product",
    "nasg-radiance",
    "nasg-product",
    "df-n-radiance",
    "df-n-product",
    "df-l-radiance",
    "df-l-product",
];
/// Methods of `--suite --quick`.
const QUICK_SUITE_METHODS: [&str; 2] = ["pt-nee", "guided"];
/// Built-in scenes of `--quick` (with or without `--suite`).
const QUICK_SCENES: [&str; 2] = ["builtin:cornell-box", "builtin:door"];
const QUICK_METHODS: [&str; 5] = [
    "pt",
    "pt-nee",
    "npm-product",
    "nasg-radiance",
    "df-l-radiance",
];

/// What `bench` runs unless told otherwise, per mode (`--quick`, `--suite`).
struct Defaults {
    methods: &'static [&'static str],
    budgets: &'static [&'static str],
    seeds: u32,
    width: u32,
    reference_spp: u32,
}

impl Defaults {
    fn new(quick: bool, suite: bool) -> Self {
        use host_demo::bench::suite;
        let (methods, budgets, seeds, width): (
            &'static [&'static str],
            &'static [&'static str],
            _,
            _,
        ) = match (suite, quick) {
            (false, false) => (&BENCH_METHODS, &["5", "10", "20", "40", "32spp"], 3, 320),
            (false, true) => (&QUICK_METHODS, &["1", "2"], 2, 64),
            (true, false) => (&suite::METHODS, &["30"], 3, 256),
            (true, true) => (&QUICK_SUITE_METHODS, &["1"], 1, 64),
        };
        Self {
            methods,
            budgets,
            seeds,
            width,
            reference_spp: if quick { 256 } else { 2048 },
        }
    }
}

/// The default scenes of the mode, with a note for each expected one that is missing.
fn default_scenes(quick: bool, suite: bool) -> (Vec<String>, Vec<String>) {
    let mut notes = Vec::new();
    let scenes = if quick {
        QUICK_SCENES.iter().map(|s| s.to_string()).collect()
    } else if suite {
        let (scenes, missing) = host_demo::bench::suite::scenes(
            &host_demo::bench::suite::shared_roots(),
            &host_demo::bench::suite::published_roots(),
        );
        notes = missing;
        scenes
    } else {
        let mut scenes = Vec::new();
        for s in BENCH_SCENES {
            if s.starts_with("builtin:") || Path::new(s).exists() {
                scenes.push(s.to_string());
            } else {
                notes.push(format!("{s} not found (run from the repository root)"));
            }
        }
        scenes
    };
    (scenes, notes)
}

/// Parses every item of `given`, or of `default` when nothing was given.
fn parse_list<T>(
    given: Option<Vec<String>>,
    default: &[&str],
    parse: fn(&str) -> host_demo::Result<T>,
) -> host_demo::Result<Vec<T>> {
    let items = given.unwrap_or_else(|| default.iter().map(|s| s.to_string()).collect());
    items.iter().map(|s| parse(s)).collect()
}

pub(super) fn bench_cmd(cmd: Cmd) -> host_demo::Result<()> {
    use host_demo::bench::{self, suite, BenchOptions, Budget, Method};
    let Cmd::Bench {
        scenes,
        quick,
        suite: is_suite,
        only,
        methods,
        budgets,
        seeds,
        width,
        threads,
        reference_spp,
        references,
        out,
        cache,
        no_micro,
    } = cmd
    else {
        unreachable!("bench_cmd is only called for Cmd::Bench")
    };
    let defaults = Defaults::new(quick, is_suite);
    let (mut all_scenes, mut notes) = if only {
        (Vec::new(), Vec::new())
    } else {
        default_scenes(quick, is_suite)
    };
    for n in &notes {
        eprintln!("bench: {n}, skipped");
    }
    all_scenes.extend(scenes);
    if all_scenes.is_empty() {
        return Err(host_demo::Error::Bench("no scenes to run".into()));
    }
    let mut methods = parse_list(methods, defaults.methods, Method::parse)?;
    if methods.is_empty() {
        return Err(host_demo::Error::Bench("no methods to run".into()));
    }
    if is_suite && !methods.iter().any(|m| m.name == suite::BASELINE) {
        let note = format!(
            "{} added to the methods: the suite's ratios are against it",
            suite::BASELINE
        );
        eprintln!("bench: {note}");
        notes.push(note);
        methods.insert(0, Method::parse(suite::BASELINE)?);
    }
    let budgets = parse_list(budgets, defaults.budgets, Budget::parse)?;
    if budgets.is_empty() {
        return Err(host_demo::Error::Bench("no budgets to run".into()));
    }
    let references = references
        .iter()
        .map(|r| {
            r.split_once('=')
                .map(|(s, p)| (s.to_string(), PathBuf::from(p)))
                .ok_or_else(|| {
                    host_demo::Error::Bench(format!("--reference {r}: expected SCENE=FILE.exr"))
                })
        })
        .collect::<host_demo::Result<Vec<_>>>()?;
    let opts = BenchOptions {
        scenes: all_scenes,
        methods,
        budgets,
        seeds: seeds.unwrap_or(defaults.seeds).max(1),
        width: width.unwrap_or(defaults.width),
        threads,
        reference_spp: reference_spp.unwrap_or(defaults.reference_spp),
        references,
        out: out.clone(),
        cache,
        quick_micro: quick,
        no_micro: no_micro || is_suite,
        suite: is_suite,
        keep_going: is_suite,
        notes,
    };
    let t0 = Instant::now();
    let records = bench::run(&opts)?;
    println!(
        "bench: {} runs in {:.1} s; wrote {}",
        records.len(),
        t0.elapsed().as_secs_f64(),
        out.join(if is_suite { "suite.md" } else { "report.md" })
            .display()
    );
    Ok(())
}
