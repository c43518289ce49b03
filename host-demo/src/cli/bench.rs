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
const QUICK_METHODS: [&str; 5] = [
    "pt",
    "pt-nee",
    "npm-product",
    "nasg-radiance",
    "df-l-radiance",
];

pub(super) fn bench_cmd(cmd: Cmd) -> host_demo::Result<()> {
    use host_demo::bench::{self, BenchOptions, Budget, Method};
    let Cmd::Bench {
        scenes,
        quick,
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
    let mut all_scenes: Vec<String> = Vec::new();
    if !only {
        if quick {
            all_scenes.extend([
                "builtin:cornell-box".to_string(),
                "builtin:door".to_string(),
            ]);
        } else {
            for s in BENCH_SCENES {
                if s.starts_with("builtin:") || Path::new(s).exists() {
                    all_scenes.push(s.to_string());
                } else {
                    eprintln!("bench: {s} not found, skipped (run from the repository root)");
                }
            }
        }
    }
    all_scenes.extend(scenes);
    if all_scenes.is_empty() {
        return Err(host_demo::Error::Bench("no scenes to run".into()));
    }
    let default_methods: &[&str] = if quick {
        &QUICK_METHODS
    } else {
        &BENCH_METHODS
    };
    let methods = match methods {
        Some(m) => m
            .iter()
            .map(|s| Method::parse(s))
            .collect::<host_demo::Result<Vec<_>>>()?,
        None => default_methods
            .iter()
            .map(|s| Method::parse(s))
            .collect::<host_demo::Result<Vec<_>>>()?,
    };
    let default_budgets: &[&str] = if quick {
        &["1", "2"]
    } else {
        &["5", "10", "20", "40", "32spp"]
    };
    let budgets = match budgets {
        Some(b) => b
            .iter()
            .map(|s| Budget::parse(s))
            .collect::<host_demo::Result<Vec<_>>>()?,
        None => default_budgets
            .iter()
            .map(|s| Budget::parse(s))
            .collect::<host_demo::Result<Vec<_>>>()?,
    };
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
        seeds: seeds.unwrap_or(if quick { 2 } else { 3 }).max(1),
        width: width.unwrap_or(if quick { 64 } else { 320 }),
        threads,
        reference_spp: reference_spp.unwrap_or(if quick { 256 } else { 2048 }),
        references,
        out: out.clone(),
        cache,
        quick_micro: quick,
        no_micro,
    };
    let t0 = Instant::now();
    let records = bench::run(&opts)?;
    println!(
        "bench: {} runs in {:.1} s; wrote {}",
        records.len(),
        t0.elapsed().as_secs_f64(),
        out.join("report.md").display()
    );
    Ok(())
}
