//! `host-demo render`: one image, its statistics and its output files.

use super::{CacheArg, Cmd, DeviceArg, GuideArg, Integrator, OnOff, SizeArg, TargetArg};
use guiding_core::field::{FieldConfig, PlateauConfig};
use guiding_core::loss::Target;
use host_demo::render::strategy::guide::{build_guide, GuideKind, ModelSize};
use host_demo::render::{render_guided, CacheMode, GuidedOptions};
use host_demo::render::{render_with_stats, RenderStats};
use host_demo::render::{IntegratorKind, RenderOptions};
use serde_json::json;
use std::time::{Duration, Instant};

pub(super) fn render_cmd(cmd: Cmd) -> host_demo::Result<()> {
    let Cmd::Render {
        scene,
        scene_flag,
        integrator,
        spp,
        time,
        rr,
        stats: stats_path,
        threads,
        define,
        strict,
        seed,
        max_depth,
        width,
        height,
        out,
        guide,
        target,
        model_size,
        train_fraction,
        training_share,
        train_epochs,
        selection_probability,
        steps_per_update,
        batch_size,
        learning_rate,
        plateau_window,
        plateau_margin,
        guide_cache,
        guide_cache_resolution,
        fit_selection,
        guide_trial,
        pass_weights,
        training_probe,
        nee,
        device,
        fallback_to_cpu,
        vk_device,
    } = cmd
    else {
        unreachable!("render_cmd is only called for `render`");
    };
    let bad = |m: String| Err(host_demo::Error::Scene(m));
    let Some(scene) = scene.or(scene_flag) else {
        return bad("no scene given (positional SCENE or --scene)".into());
    };
    let time_budget = match time {
        None => None,
        Some(t) if t.is_finite() && (0.0..=1e7).contains(&t) => Some(Duration::from_secs_f64(t)),
        Some(t) => return bad(format!("--time {t} is not a number of seconds in [0, 1e7]")),
    };
    // Every default is the library's: what an embedder gets is what this measures.
    let representation = match guide {
        GuideArg::Npm => guiding::Representation::Npm,
        GuideArg::Nasg => guiding::Representation::Nasg,
        GuideArg::DfN => guiding::Representation::DfNearest,
        GuideArg::DfL => guiding::Representation::DfLinear,
    };
    let preset = guiding::GuidingConfig::for_representation(representation, Target::Radiance);
    let mut schedule = guiding::ScheduleOptions::DEFAULT;
    if let Some(f) = train_fraction {
        schedule.train_fraction = f64::from(f);
    }
    if let Some(s) = training_share {
        schedule.steps = guiding::StepRule::TimeShare(s);
    }
    if let Some(e) = train_epochs {
        schedule.steps = guiding::StepRule::Epochs(e);
    }
    if let Err(e) = schedule.validate() {
        return bad(format!(
            "--train-fraction / --training-share / --train-epochs: {e}"
        ));
    }
    let selection_probability = selection_probability.unwrap_or(preset.selection_probability);
    if !(0.0..=1.0).contains(&selection_probability) {
        return bad(format!(
            "--selection-probability {selection_probability} is not in [0, 1]"
        ));
    }
    let steps_per_update = steps_per_update.unwrap_or(preset.training.steps_per_update);
    if !(1..=10_000).contains(&steps_per_update) {
        return bad(format!(
            "--steps-per-update {steps_per_update} is not in [1, 10000]"
        ));
    }
    let batch_size = batch_size.unwrap_or(preset.training.batch_size);
    if !(1..=1 << 20).contains(&batch_size) {
        return bad(format!("--batch-size {batch_size} is not in [1, 2^20]"));
    }
    let learning_rate = learning_rate.unwrap_or(preset.training.adam.learning_rate);
    if !(learning_rate.is_finite() && learning_rate > 0.0) {
        return bad(format!("--learning-rate {learning_rate} must be > 0"));
    }
    if !(1..=guiding::cache::MAX_CACHE_RESOLUTION).contains(&guide_cache_resolution) {
        return bad(format!(
            "--guide-cache-resolution {guide_cache_resolution} is not in [1, {}]",
            guiding::cache::MAX_CACHE_RESOLUTION
        ));
    }
    if !(plateau_margin.is_finite() && plateau_margin >= 0.0) {
        return bad(format!("--plateau-margin {plateau_margin} must be >= 0"));
    }
    let mut params = Vec::new();
    for d in &define {
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
    let t0 = Instant::now();
    let sc = host_demo::load_scene_with(
        &scene,
        &host_demo::scene::load::xml::LoadOptions { params, strict },
    )?;
    let load_s = t0.elapsed().as_secs_f64();
    println!(
        "loaded {} primitives, {} textures ({:.1} MiB of texel data) in {load_s:.3} s",
        sc.prims.len(),
        sc.textures.len(),
        sc.texture_bytes as f64 / (1024.0 * 1024.0)
    );
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
        time_budget,
        rr,
        progress: true,
        max_depth: max_depth.unwrap_or(sc.settings.max_depth),
        threads,
        seed,
        width: w,
        height: h,
    };
    let t1 = Instant::now();
    let mut guided_stats = None;
    let mut plain_stats = None;
    let all_diffuse = all_materials_diffuse(&sc);
    let img = if let Integrator::Guided = integrator {
        let gopts = GuidedOptions {
            nee: match nee {
                Some(OnOff::On) => true,
                Some(OnOff::Off) => false,
                None => sc.has_samplable_emitter(),
            },
            schedule,
            selection_probability,
            cache: match guide_cache {
                CacheArg::Off => CacheMode::Off,
                CacheArg::Frozen => CacheMode::Frozen,
                CacheArg::Always => CacheMode::Always,
            },
            cache_resolution: guide_cache_resolution,
            fit_selection: matches!(fit_selection, OnOff::On),
            efficiency_trial: matches!(guide_trial, OnOff::On),
            weight_passes: matches!(pass_weights, OnOff::On),
            training_probe: matches!(training_probe, OnOff::On),
            ..GuidedOptions::default()
        };
        let kind = match guide {
            GuideArg::Npm => GuideKind::Npm,
            GuideArg::Nasg => GuideKind::Nasg,
            GuideArg::DfN => GuideKind::DfN,
            GuideArg::DfL => GuideKind::DfL,
        };
        let target = match target {
            Some(TargetArg::Radiance) | None => Target::Radiance,
            Some(TargetArg::Product) => Target::Product,
        };
        let size = match model_size {
            SizeArg::Demo => ModelSize::Demo,
            SizeArg::Small => ModelSize::Small,
            SizeArg::Paper => ModelSize::Paper,
        };
        let config = FieldConfig::DEFAULT
            .with_batch_size(batch_size)
            .with_steps_per_update(steps_per_update)
            .with_learning_rate(learning_rate)
            .with_plateau(PlateauConfig::new(plateau_window, plateau_margin))
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
        if device == DeviceArg::Gpu {
            let selection: guiding::DeviceSelection = vk_device.parse()?;
            let on_failure = if fallback_to_cpu {
                guiding::DeviceFailure::FallbackToCpu
            } else {
                guiding::DeviceFailure::Error
            };
            g.use_device(selection, on_failure)?;
            eprintln!("guide on {}", g.device_name().unwrap_or_default());
        }
        let (img, stats) = render_guided(&sc, &opts, &gopts, &mut g)?;
        guided_stats = Some((stats, target, gopts));
        img
    } else {
        let (img, stats) = render_with_stats(&sc, &opts);
        plain_stats = Some(stats);
        img
    };
    let render_s = t1.elapsed().as_secs_f64();
    host_demo::render::output::write_exr(&img, &out)?;
    let png = out.with_extension("png");
    host_demo::render::output::write_png(&img, &png)?;
    let m = img.mean();
    let se = img.mean_std_error();
    println!(
        "{scene}: {}x{} {} spp max_depth {} ({} prims, {} emitters)",
        w,
        h,
        img_spp(&plain_stats, &guided_stats),
        opts.max_depth,
        sc.prims.len(),
        sc.emitter_count()
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
    if let Some((st, _, _)) = &guided_stats {
        println!("{st}");
    }
    println!(
        "load {load_s:.3} s, render {render_s:.3} s, wrote {} and {}",
        out.display(),
        png.display()
    );
    if let Some(path) = stats_path {
        let threads = opts.thread_count();
        let mut doc = json!({
            "scene": scene,
            "integrator": match integrator {
                Integrator::Pt => "pt",
                Integrator::PtNee => "pt-nee",
                Integrator::Guided => "guided",
            },
            "width": w,
            "height": h,
            "max_depth": opts.max_depth,
            "seed": seed,
            "threads": threads,
            "budget": match time_budget {
                Some(t) => json!({"time_s": t.as_secs_f64()}),
                None => json!({"spp": opts.spp}),
            },
            "load_s": load_s,
            "primitives": sc.prims.len(),
            "texture_bytes": sc.texture_bytes,
            "params": define,
            "load_warnings": sc.warnings,
            "mean_rgb": m,
            "mean_std_error_rgb": se,
            "output": {"exr": out.display().to_string(), "png": png.display().to_string()},
        });
        let (nee_ran, nee_asked) = match (&plain_stats, &guided_stats) {
            (Some(p), _) => (p.nee, integrator == Integrator::PtNee),
            (_, Some((g, _, go))) => (g.nee, go.nee),
            _ => (false, false),
        };
        let nee_reason = if nee_ran {
            "NEE + MIS on every non-delta vertex (delta BSDFs are not connected)"
        } else if !nee_asked {
            "not requested (integrator pt or --nee off)"
        } else {
            "skipped: the scene has no emitter NEE can sample"
        };
        let rr_stage = json!({"ran": rr, "rr_depth": sc.settings.rr_depth});
        if let Some(p) = &plain_stats {
            let wall = p.wall.as_secs_f64();
            doc["spp"] = json!(p.passes);
            doc["time_s"] =
                json!({"wall": wall, "tracing": wall, "inference": 0.0, "training": 0.0});
            doc["rays"] = json!(p.rays);
            doc["rays_per_second"] = json!(p.rays as f64 / wall.max(1e-9));
            doc["training_samples_used"] = json!(0);
            doc["stages"] = json!({
                "nee": {"ran": nee_ran, "reason": nee_reason},
                "guiding": {"ran": false, "reason": "unguided integrator"},
                "product_inputs": {"ran": false, "reason": "unguided integrator"},
                "training": {"ran": false, "reason": "unguided integrator"},
                "russian_roulette": rr_stage,
            });
        }
        if let Some((g, target, _)) = &guided_stats {
            let trace = g.trace.as_secs_f64();
            // Guide queries run inside the render threads: their thread-seconds divided by
            // the thread count estimate their share of the tracing wall time.
            let inference = (g.query.as_secs_f64() / threads as f64).min(trace);
            let training = g.training.as_secs_f64();
            let cache_build = g.cache_build.as_secs_f64();
            // The render's own clock: also the per-pass bookkeeping and the final combination
            // ("other" below), which the parts leave out.
            let wall = g.wall.as_secs_f64().max(trace + training + cache_build);
            let used = g
                .samples_recorded
                .saturating_sub(g.rejected_samples + g.overflowed_samples);
            let product = matches!(target, Target::Product);
            doc["spp"] = json!(g.passes);
            doc["guide"] = json!(g.model);
            doc["device"] = json!(g.device);
            doc["time_s"] = json!({
                "wall": wall,
                "tracing": trace - inference,
                "inference": inference,
                "inference_thread_s": g.query.as_secs_f64(),
                "training": training,
                "cache_build": cache_build,
                "other": wall - trace - training - cache_build,
            });
            doc["rays"] = json!(g.rays);
            doc["rays_per_second"] = json!(g.rays as f64 / wall.max(1e-9));
            doc["training_samples_used"] = json!(used);
            doc["training_samples"] = json!({
                "recorded": g.samples_recorded,
                "rejected": g.rejected_samples,
                "overflowed": g.overflowed_samples,
                "recorded_after_training": g.samples_recorded_after_training,
            });
            doc["stages"] = json!({
                "nee": {"ran": nee_ran, "reason": nee_reason},
                "guiding": {
                    "ran": g.guided_vertices > 0,
                    "guided_vertices": g.guided_vertices,
                    "guide_queries": g.guide_queries,
                    "reason": "delta, smooth-coated and near-specular vertices use BSDF sampling only",
                },
                "product_inputs": {
                    "ran": product,
                    "all_materials_diffuse": all_diffuse,
                    "reason": if !product {
                        "skipped: the radiance target (the default) reads no product inputs"
                    } else if all_diffuse {
                        "product target requested explicitly although every material is diffuse"
                    } else {
                        "product target"
                    },
                },
                "training": {
                    "ran": g.training_passes > 0,
                    "passes": g.training_passes,
                    "stopped_after_pass": g.training_passes,
                    "planned_passes": g.passes_planned_for_training,
                    "converged_at_pass": g.converged_at_pass,
                    "skipped_passes": g.passes_planned_for_training.saturating_sub(g.training_passes),
                    "loss_history": g.loss_history,
                    "steps": g.training_steps,
                    "steps_after_stop": g.training_steps_after_training,
                    "last_loss": finite(g.last_loss),
                    "schedule": {
                        "updates": g.schedule.updates,
                        "steps": g.schedule.steps,
                        "seconds_per_step": finite(g.schedule.seconds_per_step),
                        "training_seconds": g.schedule.trained_seconds,
                        "training_phase_tracing_seconds": g.schedule.traced_seconds,
                        "training_share": finite(g.schedule.training_share()),
                    },
                },
                "russian_roulette": rr_stage,
                "efficiency_trial": trial_json(g.trial.as_ref()),
                "pass_weights": pass_weights_json(g.pass_weights.as_ref()),
                "training_probe": probe_json(g.probe.as_ref()),
                "guide_cache": {
                    "ran": g.cache_hits > 0,
                    "mode": g.cache,
                    "cells": g.cache_cells,
                    "hits": g.cache_hits,
                    "misses": g.cache_misses,
                },
                "selection_fit": g.selection_fit.map_or(serde_json::Value::Null, |r| json!({
                    "guide_cost": g.guide_cost.map(f64::from).map(finite),
                    "samples_used": r.samples_used,
                    "cells_fitted": r.cells_fitted,
                    "cells_off": r.cells_off,
                    "cells_global": r.cells_global,
                    "global": f64::from(r.global),
                    "mean": f64::from(r.mean),
                    "variance_ratio": finite(r.variance_ratio),
                })),
                "selection_refit": g.selection_refit.map_or(serde_json::Value::Null, |(share, r)| json!({
                    "variance_share": f64::from(share),
                    "cells_off": r.cells_off,
                    "global": f64::from(r.global),
                    "mean": f64::from(r.mean),
                    "variance_ratio": finite(r.variance_ratio),
                })),
            });
        }
        let text = format!("{doc:#}\n");
        std::fs::write(&path, text).map_err(|source| host_demo::Error::Io {
            path: path.clone(),
            source,
        })?;
    }
    Ok(())
}

/// A JSON number, or `null` where it is not finite (JSON has no NaN or infinity).
fn finite(x: f64) -> serde_json::Value {
    if x.is_finite() {
        json!(x)
    } else {
        json!(null)
    }
}

/// The `--stats` entry of the efficiency trial.
fn trial_json(t: Option<&host_demo::render::TrialStats>) -> serde_json::Value {
    let Some(t) = t else {
        return json!({"ran": false, "reason": "off, an spp budget, or training never stopped"});
    };
    match &t.verdict {
        None => json!({"ran": true, "finished": false, "passes": t.passes}),
        Some(v) => json!({
            "ran": true,
            "finished": true,
            "passes": t.passes,
            "keep_guide": v.keep_guide,
            "evidence": format!("{:?}", v.evidence),
            "cost_ratio_interval": [finite(v.ratio_low), finite(v.ratio_high)],
            "guided_relmse_per_pass": finite(v.guided_variance),
            "unguided_relmse_per_pass": finite(v.unguided_variance),
            "guided_seconds_per_pass": v.guided_seconds,
            "unguided_seconds_per_pass": v.unguided_seconds,
            "cost_ratio": finite(v.cost_ratio),
            "pixels_skipped": v.pixels_skipped,
            "passes_guide_off": t.passes_guide_off,
        }),
    }
}

/// The `--stats` entry of the training probe.
fn probe_json(p: Option<&host_demo::render::ProbeStats>) -> serde_json::Value {
    let Some(p) = p else {
        return json!({"ran": false, "reason": "off, or the efficiency trial is off"});
    };
    match &p.verdict {
        None => json!({"ran": true, "finished": false, "passes_guide_off": p.passes_guide_off}),
        Some(v) => json!({
            "ran": true,
            "finished": true,
            "at_pass": v.at_pass,
            "abandoned": v.abandoned,
            "guided_pass": v.guided_pass,
            "steps_before_guided_pass": v.steps,
            "guided_relmse_per_pass": finite(v.ratio.guided_variance),
            "unguided_relmse_per_pass": finite(v.ratio.unguided_variance),
            "unguided_seconds_per_pass": v.unguided_seconds,
            "guided_seconds_per_pass_after_training": v.guided_seconds,
            "cost_ratio": finite(v.ratio.ratio),
            "cost_ratio_interval": [finite(v.ratio.low), finite(v.ratio.high)],
            "passes_guide_off": p.passes_guide_off,
        }),
    }
}

/// The `--stats` entry of the inverse-variance combination of the passes.
fn pass_weights_json(w: Option<&host_demo::render::PassWeightStats>) -> serde_json::Value {
    let Some(w) = w else {
        return json!({"ran": false, "reason": "off, or a single group of passes"});
    };
    let groups: Vec<serde_json::Value> = w
        .groups
        .iter()
        .map(|g| {
            let kind = match g.group {
                host_demo::render::strategy::guided::GROUP_GUIDED => json!("guided"),
                host_demo::render::strategy::guided::GROUP_UNGUIDED => json!("unguided"),
                pass => json!({"training_pass": pass}),
            };
            json!({
                "group": kind,
                "passes": g.passes,
                "relmse_per_pass": [finite(g.relative_variance[0]), finite(g.relative_variance[1])],
                "share": finite(g.share),
            })
        })
        .collect();
    json!({
        "ran": true,
        "fell_back": w.fell_back,
        "predicted_gain": finite(w.predicted_gain),
        "seconds": w.seconds,
        "groups": groups,
    })
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

fn img_spp(
    plain: &Option<RenderStats>,
    guided: &Option<(host_demo::render::GuidedStats, Target, GuidedOptions)>,
) -> u32 {
    match (plain, guided) {
        (Some(p), _) => p.passes,
        (_, Some((g, _, _))) => g.passes,
        _ => 0,
    }
}
