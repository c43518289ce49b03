//! `host-demo render --scene builtin:cornell-box|PATH --integrator pt|pt-nee ...`

use clap::{Parser, Subcommand, ValueEnum};
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
    } = cli.cmd;
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
            Integrator::PtNee => IntegratorKind::PtNee,
        },
        spp: spp.unwrap_or(sc.settings.spp).max(1),
        max_depth: max_depth.unwrap_or(sc.settings.max_depth),
        threads,
        seed,
        width: w,
        height: h,
    };
    let t1 = Instant::now();
    let img = render(&sc, &opts);
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
    println!(
        "load {load_s:.3} s, render {render_s:.3} s, wrote {}",
        out.display()
    );
    Ok(())
}
