//! `host-demo render --scene builtin:cornell-box|PATH --integrator pt|pt-nee|guided ...`
//!
//! Guided example (about a minute on 2 cores):
//! `host-demo render --scene builtin:door --integrator guided --guide npm --spp 64 --out door-guided.exr`

use clap::{Parser, Subcommand, ValueEnum};
use guiding_core::field::FieldConfig;
use guiding_core::loss::Target;
use host_demo::guide::{build_guide, GuideKind, ModelSize};
use host_demo::guided::{render_guided, GuidedOptions};
use host_demo::integrator::{render, IntegratorKind, RenderOptions};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "host-demo",
    about = "Wavefront path tracer demo for the guiding library"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Clone, Copy, ValueEnum)]
enum Integrator {
    /// BSDF sampling only.
    Pt,
    /// Next-event estimation + MIS (power heuristic).
    PtNee,
    /// Path guiding (trained online), one-sample MIS with the BSDF; NEE per `--nee`.
    Guided,
}

#[derive(Clone, Copy, ValueEnum)]
enum GuideArg {
    /// Neural Parametric Mixtures (vMF).
    Npm,
    /// NASG mixture with a learned selection probability.
    Nasg,
    /// Distribution factorisation, nearest reconstruction.
    DfN,
    /// Distribution factorisation, linear reconstruction.
    DfL,
}

#[derive(Clone, Copy, ValueEnum)]
enum TargetArg {
    /// Learn the incident radiance.
    Radiance,
    /// Learn the product of BSDF, cosine and radiance.
    Product,
}

#[derive(Clone, Copy, ValueEnum)]
enum SizeArg {
    /// 4-level grid (4..32 cells), MLP 2 x 32.
    Demo,
    /// The library's tiny test presets.
    Small,
    /// The papers' sizes (4.1 M parameters; slow on a CPU).
    Paper,
}

#[derive(Clone, Copy, ValueEnum)]
enum OnOff {
    /// Enabled.
    On,
    /// Disabled.
    Off,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render a scene to an EXR file and print the image mean.
    Render {
        /// `builtin:cornell-box`, `builtin:furnace`, `builtin:door`, or a Mitsuba 3 XML path.
        #[arg(long)]
        scene: String,
        /// Estimator.
        #[arg(long, value_enum, default_value = "pt-nee")]
        integrator: Integrator,
        /// Samples per pixel (default: the scene's).
        #[arg(long)]
        spp: Option<u32>,
        /// Worker threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
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
        /// Output EXR path.
        #[arg(long, default_value = "image.exr")]
        out: PathBuf,
        /// Guiding model (`--integrator guided`).
        #[arg(long, value_enum, default_value = "npm")]
        guide: GuideArg,
        /// Guiding target (`--integrator guided`).
        #[arg(long, value_enum, default_value = "product")]
        target: TargetArg,
        /// Model size preset (`--integrator guided`).
        #[arg(long, value_enum, default_value = "demo")]
        model_size: SizeArg,
        /// Fraction of the spp passes used for training, in [0, 1].
        #[arg(long, default_value_t = 0.3)]
        train_fraction: f32,
        /// Guide-selection probability c in [0, 1] (NASG uses its learned value).
        #[arg(long, default_value_t = 0.5)]
        selection_probability: f32,
        /// Adam steps per training pass (32: on builtin:door 160x120 32 spp, 4 steps at lr 5e-3
        /// gave 2.05x pt-nee's per-pixel variance, 32 steps at lr 3e-2 1.22x; Cornell unchanged).
        #[arg(long, default_value_t = 32)]
        steps_per_pass: u32,
        /// Training minibatch size.
        #[arg(long, default_value_t = 8192)]
        batch_size: usize,
        /// Learning rate of the guide's Adam optimiser.
        #[arg(long, default_value_t = 3e-2)]
        learning_rate: f32,
        /// NEE in the guided integrator (default: on when the scene has area lights).
        #[arg(long, value_enum)]
        nee: Option<OnOff>,
    },
}

fn main() -> ExitCode {
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
    let Cmd::Render {
        scene,
        integrator,
        spp,
        threads,
        seed,
        max_depth,
        width,
        height,
        out,
        guide,
        target,
        model_size,
        train_fraction,
        selection_probability,
        steps_per_pass,
        batch_size,
        learning_rate,
        nee,
    } = cli.cmd;
    let bad = |m: String| Err(host_demo::Error::Scene(m));
    if !(0.0..=1.0).contains(&train_fraction) {
        return bad(format!(
            "--train-fraction {train_fraction} is not in [0, 1]"
        ));
    }
    if !(0.0..=1.0).contains(&selection_probability) {
        return bad(format!(
            "--selection-probability {selection_probability} is not in [0, 1]"
        ));
    }
    if !(1..=10_000).contains(&steps_per_pass) {
        return bad(format!(
            "--steps-per-pass {steps_per_pass} is not in [1, 10000]"
        ));
    }
    if !(1..=1 << 20).contains(&batch_size) {
        return bad(format!("--batch-size {batch_size} is not in [1, 2^20]"));
    }
    if !(learning_rate.is_finite() && learning_rate > 0.0) {
        return bad(format!("--learning-rate {learning_rate} must be > 0"));
    }
    let t0 = Instant::now();
    let sc = host_demo::load_scene(&scene)?;
    let load_s = t0.elapsed().as_secs_f64();
    let (w, h) = match (width, height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (
            w,
            ((w as u64 * sc.settings.height as u64) / sc.settings.width as u64).max(1) as u32,
        ),
        (None, Some(h)) => (
            ((h as u64 * sc.settings.width as u64) / sc.settings.height as u64).max(1) as u32,
            h,
        ),
        (None, None) => (sc.settings.width, sc.settings.height),
    };
    if w == 0 || h == 0 || w > 1 << 15 || h > 1 << 15 {
        return Err(host_demo::Error::Scene(format!("bad image size {w}x{h}")));
    }
    let opts = RenderOptions {
        integrator: match integrator {
            Integrator::Pt => IntegratorKind::Pt,
            Integrator::PtNee | Integrator::Guided => IntegratorKind::PtNee,
        },
        spp: spp.unwrap_or(sc.settings.spp).max(1),
        max_depth: max_depth.unwrap_or(sc.settings.max_depth),
        threads,
        seed,
        width: w,
        height: h,
    };
    let t1 = Instant::now();
    let mut guided_stats = None;
    let img = if let Integrator::Guided = integrator {
        let gopts = GuidedOptions {
            nee: match nee {
                Some(OnOff::On) => true,
                Some(OnOff::Off) => false,
                None => !sc.lights.is_empty(),
            },
            train_fraction,
            selection_probability,
            ..GuidedOptions::default()
        };
        let kind = match guide {
            GuideArg::Npm => GuideKind::Npm,
            GuideArg::Nasg => GuideKind::Nasg,
            GuideArg::DfN => GuideKind::DfN,
            GuideArg::DfL => GuideKind::DfL,
        };
        let target = match target {
            TargetArg::Radiance => Target::Radiance,
            TargetArg::Product => Target::Product,
        };
        let size = match model_size {
            SizeArg::Demo => ModelSize::Demo,
            SizeArg::Small => ModelSize::Small,
            SizeArg::Paper => ModelSize::Paper,
        };
        let config = FieldConfig::DEFAULT
            .with_batch_size(batch_size)
            .with_steps_per_update(steps_per_pass)
            .with_learning_rate(learning_rate)
            .with_threads(threads)
            .with_seed(seed as u32);
        let mut g = build_guide(
            kind,
            target,
            size,
            sc.bounds(),
            selection_probability,
            config,
        )?;
        let (img, stats) = render_guided(&sc, &opts, &gopts, &mut *g);
        guided_stats = Some(stats);
        img
    } else {
        render(&sc, &opts)
    };
    let render_s = t1.elapsed().as_secs_f64();
    host_demo::output::write_exr(&img, &out)?;
    let m = img.mean();
    let se = img.mean_std_error();
    println!(
        "{scene}: {}x{} {} spp max_depth {} ({} prims, {} lights)",
        w,
        h,
        opts.spp,
        opts.max_depth,
        sc.prims.len(),
        sc.lights.len()
    );
    println!(
        "mean RGB = ({:.4}, {:.4}, {:.4})  std.err = ({:.4}, {:.4}, {:.4})",
        m[0], m[1], m[2], se[0], se[1], se[2]
    );
    let var: f64 = img
        .var_of_mean
        .iter()
        .map(|v| v.iter().map(|&c| c as f64).sum::<f64>())
        .sum::<f64>()
        / (3.0 * img.var_of_mean.len().max(1) as f64);
    println!("mean per-pixel variance of the estimate = {var:.4e}");
    if let Some(st) = guided_stats {
        println!("{st}");
    }
    println!(
        "load {load_s:.3} s, render {render_s:.3} s, wrote {}",
        out.display()
    );
    Ok(())
}
