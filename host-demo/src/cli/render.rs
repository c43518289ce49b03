//! `host-demo render`: one image, its statistics and its output files.

use super::stats::{
    Budget, CommonStages, GuidedRun, MediaInputs, OutputFiles, PlainRun, RunStats, StatsDoc,
};
use super::{
    AutoOnOff, CacheArg, Cmd, DeviceArg, GuideArgs, Integrator, OnOff, TargetArg, TuningArgs,
};
use guiding_core::field::{FieldConfig, PlateauConfig};
use guiding_core::loss::Target;
use host_demo::render::strategy::guide::build_guide;
use host_demo::render::{render_guided, CacheMode, GuidedOptions, GuidedStats, Image};
use host_demo::render::{render_with_stats, RenderStats};
use host_demo::render::{IntegratorKind, RenderOptions};
use host_demo::scene::Scene;
use std::path::Path;
use std::time::{Duration, Instant};

/// `host-demo render`: checks the arguments, loads the scene, renders it, writes the EXR and
/// its PNG preview, prints a summary and, with `--stats`, writes the statistics document.
pub(super) fn render_cmd(cmd: Cmd) -> host_demo::Result<()> {
    let Cmd::Render {
        scene,
        scene_flag,
        integrator,
        spp,
        time,
        rr,
        rr_trial,
        stats: stats_path,
        threads,
        define,
        strict,
        seed,
        max_depth,
        width,
        height,
        out,
        guide: guide_args,
        training,
    } = cmd
    else {
        unreachable!("render_cmd is only called for `render`");
    };
    let Some(scene) = scene.or(scene_flag) else {
        return bad("no scene given (positional SCENE or --scene)".into());
    };
    let time_budget = time_budget(time)?;
    let tuning = training.resolve(guide_args.guide)?;
    let (sc, load_s) = load(&scene, &define, strict)?;
    let (w, h) = image_size(width, height, &sc.settings)?;
    let opts = RenderOptions {
        integrator: match integrator {
            Integrator::Pt => IntegratorKind::Pt,
            Integrator::PtNee | Integrator::Guided => IntegratorKind::PtNee,
        },
        spp: spp.unwrap_or(sc.settings.spp).max(1),
        time_budget,
        rr: rr.resolve(integrator, time_budget.is_some()),
        rr_trial: matches!(rr_trial, OnOff::On),
        progress: true,
        max_depth: max_depth.unwrap_or(sc.settings.max_depth),
        threads,
        seed,
        width: w,
        height: h,
    };
    let t1 = Instant::now();
    let (img, outcome) = if let Integrator::Guided = integrator {
        run_guided(&sc, &opts, &tuning, guide_args)?
    } else {
        let (img, stats) = render_with_stats(&sc, &opts);
        (img, Outcome::Plain(Box::new(stats)))
    };
    let render_s = t1.elapsed().as_secs_f64();
    let png = write_images(&img, &out)?;
    let done = Finished {
        scene: &scene,
        integrator,
        sc: &sc,
        opts: &opts,
        define: &define,
        mean: img.mean(),
        std_error: img.mean_std_error(),
        img: &img,
        outcome: &outcome,
        load_s,
        render_s,
        out: &out,
        png: &png,
    };
    done.print_summary();
    if let Some(path) = stats_path {
        done.write_stats(&path)?;
    }
    Ok(())
}

/// A scene error with message `m` (the error of every bad argument).
fn bad<T>(m: String) -> host_demo::Result<T> {
    Err(host_demo::Error::Scene(m))
}

/// `--time`: a number of seconds in [0, 1e7], or no time budget.
fn time_budget(time: Option<f64>) -> host_demo::Result<Option<Duration>> {
    match time {
        None => Ok(None),
        Some(t) if t.is_finite() && (0.0..=1e7).contains(&t) => {
            Ok(Some(Duration::from_secs_f64(t)))
        }
        Some(t) => bad(format!("--time {t} is not a number of seconds in [0, 1e7]")),
    }
}

/// Loads the scene with the `-D` parameters `define` and prints what it holds; returns it with
/// the seconds the loading took.
fn load(scene: &str, define: &[String], strict: bool) -> host_demo::Result<(Scene, f64)> {
    let params = parse_defines(define)?;
    let t0 = Instant::now();
    let sc = host_demo::load_scene_with(
        scene,
        &host_demo::scene::load::xml::LoadOptions { params, strict },
    )?;
    let load_s = t0.elapsed().as_secs_f64();
    println!(
        "loaded {} primitives, {} textures ({:.1} MiB of texel data) in {load_s:.3} s",
        sc.prims.len(),
        sc.textures.len(),
        sc.texture_bytes as f64 / (1024.0 * 1024.0)
    );
    Ok((sc, load_s))
}

/// Writes the image to `out` (EXR) and its preview next to it (PNG); returns the PNG's path.
fn write_images(img: &Image, out: &Path) -> host_demo::Result<std::path::PathBuf> {
    host_demo::render::output::write_exr(img, out)?;
    let png = out.with_extension("png");
    host_demo::render::output::write_png(img, &png)?;
    Ok(png)
}

/// The `-D NAME=VALUE` scene parameters as (name, value) pairs.
fn parse_defines(define: &[String]) -> host_demo::Result<Vec<(String, String)>> {
    let mut params = Vec::new();
    for d in define {
        match d.split_once('=') {
            Some((k, v))
                if !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') =>
            {
                params.push((k.to_string(), v.to_string()))
            }
            _ => {
                return bad(format!(
                    "-D {d}: expected NAME=VALUE (NAME of letters, digits, _)"
                ))
            }
        }
    }
    Ok(params)
}

/// The image size from `--width` / `--height`: one of them keeps the scene's aspect ratio,
/// neither gives the scene's size; each side in [1, 2^15].
fn image_size(
    width: Option<u32>,
    height: Option<u32>,
    settings: &host_demo::scene::Settings,
) -> host_demo::Result<(u32, u32)> {
    let (w, h) = match (width, height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (
            w,
            ((w as u64 * settings.height as u64) / settings.width as u64).max(1) as u32,
        ),
        (None, Some(h)) => (
            ((h as u64 * settings.width as u64) / settings.height as u64).max(1) as u32,
            h,
        ),
        (None, None) => (settings.width, settings.height),
    };
    if w == 0 || h == 0 || w > 1 << 15 || h > 1 << 15 {
        return Err(host_demo::Error::Scene(format!("bad image size {w}x{h}")));
    }
    Ok((w, h))
}

/// [`TuningArgs`] checked, with the library's defaults filled in (checked for every
/// integrator, used by the guided one).
struct Tuning {
    schedule: guiding::ScheduleOptions,
    selection_probability: f32,
    steps_per_update: u32,
    batch_size: usize,
    learning_rate: f32,
    plateau_window: u32,
    plateau_margin: f32,
    cache_resolution: u32,
}

impl TuningArgs {
    /// Fills in the defaults and checks the ranges; the first bad argument is the error.
    fn resolve(self, guide: guiding::Representation) -> host_demo::Result<Tuning> {
        // Every default is the library's: what an embedder gets is what this measures.
        let preset = guiding::GuidingConfig::for_representation(guide, Target::Radiance);
        let mut schedule = guiding::ScheduleOptions::DEFAULT;
        if let Some(f) = self.train_fraction {
            schedule.train_fraction = f64::from(f);
        }
        if let Some(s) = self.training_share {
            schedule.steps = guiding::StepRule::TimeShare(s);
        }
        if let Some(e) = self.train_epochs {
            schedule.steps = guiding::StepRule::Epochs(e);
        }
        if let Err(e) = schedule.validate() {
            return bad(format!(
                "--train-fraction / --training-share / --train-epochs: {e}"
            ));
        }
        let selection_probability = self
            .selection_probability
            .unwrap_or(preset.selection_probability);
        if !(0.0..=1.0).contains(&selection_probability) {
            return bad(format!(
                "--selection-probability {selection_probability} is not in [0, 1]"
            ));
        }
        let steps_per_update = self
            .steps_per_update
            .unwrap_or(preset.training.steps_per_update);
        if !(1..=10_000).contains(&steps_per_update) {
            return bad(format!(
                "--steps-per-update {steps_per_update} is not in [1, 10000]"
            ));
        }
        let batch_size = self.batch_size.unwrap_or(preset.training.batch_size);
        if !(1..=1 << 20).contains(&batch_size) {
            return bad(format!("--batch-size {batch_size} is not in [1, 2^20]"));
        }
        let learning_rate = self
            .learning_rate
            .unwrap_or(preset.training.adam.learning_rate);
        if !(learning_rate.is_finite() && learning_rate > 0.0) {
            return bad(format!("--learning-rate {learning_rate} must be > 0"));
        }
        let cache_resolution = self.guide_cache_resolution;
        if !(1..=guiding::cache::MAX_CACHE_RESOLUTION).contains(&cache_resolution) {
            return bad(format!(
                "--guide-cache-resolution {cache_resolution} is not in [1, {}]",
                guiding::cache::MAX_CACHE_RESOLUTION
            ));
        }
        let plateau_margin = self.plateau_margin;
        if !(plateau_margin.is_finite() && plateau_margin >= 0.0) {
            return bad(format!("--plateau-margin {plateau_margin} must be >= 0"));
        }
        Ok(Tuning {
            schedule,
            selection_probability,
            steps_per_update,
            batch_size,
            learning_rate,
            plateau_window: self.plateau_window,
            plateau_margin,
            cache_resolution,
        })
    }
}

/// What the integrator reported.
enum Outcome {
    /// `pt` or `pt-nee`.
    Plain(Box<RenderStats>),
    /// `guided`.
    Guided(Box<GuidedOutcome>),
}

/// A guided render's statistics, with the target and the options it ran with.
struct GuidedOutcome {
    stats: GuidedStats,
    target: Target,
    options: GuidedOptions,
}

impl Outcome {
    /// Passes (samples per pixel) rendered.
    fn spp(&self) -> u32 {
        match self {
            Outcome::Plain(p) => p.passes,
            Outcome::Guided(g) => g.stats.passes,
        }
    }
}

/// Builds the guide (on the device `--device` names) and renders `sc` with it.
fn run_guided(
    sc: &Scene,
    opts: &RenderOptions,
    tuning: &Tuning,
    args: GuideArgs,
) -> host_demo::Result<(Image, Outcome)> {
    let gopts = GuidedOptions {
        nee: match args.nee {
            Some(OnOff::On) => true,
            Some(OnOff::Off) => false,
            None => sc.has_samplable_emitter(),
        },
        schedule: tuning.schedule,
        selection_probability: tuning.selection_probability,
        cache: match args.guide_cache {
            CacheArg::Off => CacheMode::Off,
            CacheArg::Frozen => CacheMode::Frozen,
            CacheArg::Always => CacheMode::Always,
        },
        cache_resolution: tuning.cache_resolution,
        fit_selection: matches!(args.fit_selection, OnOff::On),
        phase_product: matches!(args.phase_product, OnOff::On),
        cosine_product: matches!(args.cosine_product, OnOff::On),
        guide_media: !matches!(args.guide_media, AutoOnOff::Off),
        thin_media_rule: matches!(args.guide_media, AutoOnOff::Auto),
        efficiency_trial: matches!(args.guide_trial, OnOff::On),
        weight_passes: matches!(args.pass_weights, OnOff::On),
        training_probe: matches!(args.training_probe, OnOff::On),
        ..GuidedOptions::default()
    };
    let target = match args.target {
        Some(TargetArg::Radiance) | None => Target::Radiance,
        Some(TargetArg::Product) => Target::Product,
    };
    let config = FieldConfig::DEFAULT
        .with_batch_size(tuning.batch_size)
        .with_steps_per_update(tuning.steps_per_update)
        .with_learning_rate(tuning.learning_rate)
        .with_plateau(PlateauConfig::new(
            tuning.plateau_window,
            tuning.plateau_margin,
        ))
        .with_threads(opts.threads)
        .with_seed(opts.seed as u32);
    let mut g = build_guide(
        args.guide,
        target,
        args.model_size,
        sc.bounds(),
        tuning.selection_probability,
        config,
    )?;
    if args.device == DeviceArg::Gpu {
        let selection: guiding::DeviceSelection = args.vk_device.parse()?;
        let on_failure = if args.fallback_to_cpu {
            guiding::DeviceFailure::FallbackToCpu
        } else {
            guiding::DeviceFailure::Error
        };
        g.use_device(selection, on_failure)?;
        eprintln!("guide on {}", g.device_name().unwrap_or_default());
    }
    let (img, stats) = render_guided(sc, opts, &gopts, &mut g)?;
    let outcome = GuidedOutcome {
        stats,
        target,
        options: gopts,
    };
    Ok((img, Outcome::Guided(Box::new(outcome))))
}

/// A finished render: what the summary lines and the `--stats` document report.
struct Finished<'a> {
    scene: &'a str,
    integrator: Integrator,
    sc: &'a Scene,
    opts: &'a RenderOptions,
    /// The `-D` arguments as given.
    define: &'a [String],
    /// Mean RGB of the image and its standard error.
    mean: [f64; 3],
    std_error: [f64; 3],
    img: &'a Image,
    outcome: &'a Outcome,
    load_s: f64,
    render_s: f64,
    out: &'a Path,
    png: &'a Path,
}

impl Finished<'_> {
    /// The summary on stdout: size and spp, image mean and its error, the guided render's
    /// report, the times and the files written.
    fn print_summary(&self) {
        let (m, se) = (self.mean, self.std_error);
        println!(
            "{}: {}x{} {} spp max_depth {} ({} prims, {} emitters)",
            self.scene,
            self.opts.width,
            self.opts.height,
            self.outcome.spp(),
            self.opts.max_depth,
            self.sc.prims.len(),
            self.sc.emitter_count()
        );
        println!(
            "mean RGB = ({:.4}, {:.4}, {:.4})  std.err = ({:.4}, {:.4}, {:.4})",
            m[0], m[1], m[2], se[0], se[1], se[2]
        );
        let var: f64 = self
            .img
            .var_of_mean
            .iter()
            .map(|v| v.iter().map(|&c| c as f64).sum::<f64>())
            .sum::<f64>()
            / (3.0 * self.img.var_of_mean.len().max(1) as f64);
        println!("mean per-pixel variance of the estimate = {var:.4e}");
        if let Outcome::Guided(g) = self.outcome {
            println!("{}", g.stats);
        }
        println!(
            "load {:.3} s, render {:.3} s, wrote {} and {}",
            self.load_s,
            self.render_s,
            self.out.display(),
            self.png.display()
        );
    }

    /// The `--stats` document.
    fn stats_doc(&self) -> StatsDoc<'_> {
        let (opts, sc) = (self.opts, self.sc);
        let threads = opts.thread_count();
        let (nee_ran, nee_asked) = match self.outcome {
            Outcome::Plain(p) => (p.nee, self.integrator == Integrator::PtNee),
            Outcome::Guided(g) => (g.stats.nee, g.options.nee),
        };
        let roulette = match self.outcome {
            Outcome::Plain(p) => p.roulette.as_ref(),
            Outcome::Guided(g) => g.stats.roulette.as_ref(),
        };
        let (medium_vertices, guided_medium_vertices, options) = match self.outcome {
            Outcome::Plain(p) => (p.medium_vertices, 0, None),
            Outcome::Guided(g) => (
                g.stats.medium_vertices,
                g.stats.guided_medium_vertices,
                Some(&g.options),
            ),
        };
        let media = MediaInputs {
            scene: sc,
            medium_vertices,
            guided_medium_vertices,
            options,
        };
        let common = CommonStages::new(nee_ran, nee_asked, opts.rr, media, roulette);
        let run = match self.outcome {
            Outcome::Plain(p) => RunStats::Plain(Box::new(PlainRun::new(p, common))),
            Outcome::Guided(g) => RunStats::Guided(Box::new(GuidedRun::new(
                &g.stats,
                threads,
                matches!(g.target, Target::Product),
                all_materials_diffuse(sc),
                common,
            ))),
        };
        StatsDoc {
            scene: self.scene,
            integrator: match self.integrator {
                Integrator::Pt => "pt",
                Integrator::PtNee => "pt-nee",
                Integrator::Guided => "guided",
            },
            width: opts.width,
            height: opts.height,
            max_depth: opts.max_depth,
            seed: opts.seed,
            threads,
            budget: match opts.time_budget {
                Some(t) => Budget::TimeS(t.as_secs_f64()),
                None => Budget::Spp(opts.spp),
            },
            load_s: self.load_s,
            primitives: sc.prims.len(),
            texture_bytes: sc.texture_bytes,
            params: self.define,
            load_warnings: &sc.warnings,
            mean_rgb: self.mean,
            mean_std_error_rgb: self.std_error,
            output: OutputFiles {
                exr: self.out.display().to_string(),
                png: self.png.display().to_string(),
            },
            run,
        }
    }

    /// Writes the `--stats` document to `path`.
    fn write_stats(&self, path: &Path) -> host_demo::Result<()> {
        let io = |source| host_demo::Error::Io {
            path: path.to_path_buf(),
            source,
        };
        let text = self.stats_doc().to_json().map_err(io)?;
        std::fs::write(path, text).map_err(io)
    }
}

/// True when every material is Lambertian (a `twosided` counts when both its sides are), so
/// the guiding product `f·cos·L` is `L·cos·albedo/π` and the product target learns nothing the
/// radiance target does not.
fn all_materials_diffuse(sc: &host_demo::scene::Scene) -> bool {
    let diffuse = |i: u32| sc.materials.get(i as usize).is_some_and(|m| m.is_diffuse());
    sc.materials.iter().all(|m| match *m {
        host_demo::scene::bsdf::Material::TwoSided { front, back } => {
            diffuse(front) && diffuse(back)
        }
        ref m => m.is_diffuse(),
    })
}
