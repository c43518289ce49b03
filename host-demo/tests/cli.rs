//! End-to-end tests of the `host-demo` binary (`render`, `compare`) and the image metrics.
//! Run with `cargo test --release -p host-demo --test cli` (a few seconds).

mod common;

use host_demo::render::compare::compare;
use host_demo::render::output::write_exr;
use host_demo::render::Image;
use host_demo::scene::load::exr::{read_exr, RgbImage};
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-demo"))
}

/// A fresh scratch directory under the target dir (removed at the start of each run).
fn scratch(name: &str) -> PathBuf {
    common::scratch_dir(&format!("cli-{name}"))
}

/// Writes the scene file `name` in `dir` (an 8 × 8 perspective sensor at fov 40 with `sensor`
/// inside it, then `body`) and returns its path.
fn write_scene(dir: &Path, name: &str, sensor: &str, body: &str) -> PathBuf {
    let path = dir.join(name);
    let xml = format!(
        r#"<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>{sensor}
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
        {body}</scene>"#
    );
    std::fs::write(&path, xml).expect("write");
    path
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().expect("runs");
    let (so, se) = (
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    );
    assert!(
        out.status.success(),
        "{cmd:?} failed\nstdout:\n{so}\nstderr:\n{se}"
    );
    so
}

fn read_json(p: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}\n{text}", p.display()))
}

/// Decodes a PNG and returns (width, height, bytes per pixel).
fn png_info(p: &Path) -> (u32, u32, usize) {
    let dec = png::Decoder::new(std::fs::File::open(p).expect("png exists"));
    let mut reader = dec.read_info().expect("png header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png data");
    assert!(
        buf[..info.buffer_size()].iter().any(|&b| b > 0),
        "black png"
    );
    (info.width, info.height, info.color_type.samples())
}

fn rgb(width: usize, height: usize, f: impl Fn(usize) -> [f32; 3]) -> RgbImage {
    RgbImage {
        width,
        height,
        pixels: (0..width * height).map(f).collect(),
    }
}

/// Hand-computed case: 2 pixels, nothing trimmed (⌊0.001·2⌋ = 0).
#[test]
fn compare_metrics_by_hand() {
    let r = rgb(2, 1, |i| if i == 0 { [1.0; 3] } else { [0.0; 3] });
    let i = rgb(2, 1, |i| if i == 0 { [2.0, 1.0, 1.0] } else { [0.125; 3] });
    let m = compare(&i, &r).expect("same size");
    // Pixel 0: ((2-1)²/(1+0.01) + 0 + 0)/3; pixel 1: each channel 0.125²/(0+0.01) = 1.5625.
    let expect_rel = ((1.0 / 1.01) / 3.0 + 1.5625) / 2.0;
    // MAPE: (1/1.01 + 0 + 0 + 3 · 0.125/0.01) / 6.
    let expect_mape = (1.0 / 1.01 + 37.5) / 6.0;
    assert!((m.relmse - expect_rel).abs() < 1e-12, "{m:?}");
    assert!((m.relmse_untrimmed - expect_rel).abs() < 1e-12, "{m:?}");
    assert!((m.mape - expect_mape).abs() < 1e-12, "{m:?}");
    assert_eq!(m.trimmed, 0);
}

/// 50 × 40 = 2000 pixels: the two largest pixel errors (0.1 %) are dropped. The expected
/// values are computed here without sorting: the outliers are planted at known pixels.
#[test]
fn compare_trims_the_top_tenth_percent() {
    let (w, h) = (50usize, 40usize);
    let refv = |i: usize| [0.2 + 0.001 * (i % 7) as f32, 0.5, 1.5];
    let r = rgb(w, h, refv);
    // Small relative error 5 % everywhere, huge errors at pixels 17 and 1234.
    let img = rgb(w, h, |i| {
        let v = refv(i);
        if i == 17 || i == 1234 {
            [v[0] + 100.0, v[1], v[2]]
        } else {
            v.map(|c| c * 1.05)
        }
    });
    let m = compare(&img, &r).expect("same size");
    assert_eq!(m.trimmed, 2);
    let mut kept = 0.0f64;
    let mut all = 0.0f64;
    let mut ape = 0.0f64;
    for i in 0..w * h {
        let (a, b) = (img.pixels[i], r.pixels[i]);
        let mut e = 0.0;
        for c in 0..3 {
            let (x, y) = (a[c] as f64, b[c] as f64);
            e += (x - y).powi(2) / (y * y + 0.01) / 3.0;
            ape += (x - y).abs() / (y + 0.01);
        }
        all += e;
        if i != 17 && i != 1234 {
            kept += e;
        }
    }
    let n = (w * h) as f64;
    assert!(
        (m.relmse - kept / (n - 2.0)).abs() < 1e-12 * m.relmse.max(1.0),
        "{m:?}"
    );
    assert!((m.relmse_untrimmed - all / n).abs() < 1e-9, "{m:?}");
    assert!((m.mape - ape / (3.0 * n)).abs() < 1e-12, "{m:?}");
    // The trimmed number is the small relative error only: 0.05² · R²/(R² + 0.01) per channel.
    assert!(m.relmse < 0.0025 && m.relmse_untrimmed > 1.0, "{m:?}");
}

#[test]
fn compare_rejects_bad_input() {
    let a = rgb(2, 2, |_| [1.0; 3]);
    let b = rgb(4, 1, |_| [1.0; 3]);
    assert!(compare(&a, &b).is_err());
    let nan = rgb(2, 2, |i| if i == 3 { [f32::NAN; 3] } else { [1.0; 3] });
    let e = compare(&nan, &a).unwrap_err().to_string();
    assert!(e.contains("(1, 1)"), "{e}");
}

#[test]
fn exr_roundtrip_is_exact() {
    let dir = scratch("exr");
    let img = Image {
        width: 3,
        height: 2,
        pixels: (0..6).map(|i| [i as f32, 0.5 * i as f32, 1e3]).collect(),
        var_of_mean: vec![[0.0; 3]; 6],
    };
    let p = dir.join("x.exr");
    write_exr(&img, &p).expect("write");
    let back = read_exr(&p).expect("read");
    assert_eq!((back.width, back.height), (3, 2));
    assert_eq!(back.pixels, img.pixels);
}

/// `render SCENE` writes the EXR, the PNG preview and the stats JSON; `--scene` (the README's
/// spelling) and `--time` work; `compare` prints JSON.
#[test]
fn render_and_compare_end_to_end() {
    let dir = scratch("render");
    // Both renders' size and threads (compare needs equal sizes).
    let size = ["--width", "24", "--height", "16", "--threads", "2"];
    let (exr_a, stats_a) = (dir.join("a.exr"), dir.join("a.json"));
    run_ok(
        bin()
            .args(["render", "builtin:cornell-box", "--integrator", "pt-nee"])
            .args(["--spp", "3"])
            .args(size)
            .args(["--seed", "5", "--max-depth", "4", "--out"])
            .arg(&exr_a)
            .arg("--stats")
            .arg(&stats_a),
    );
    let img = read_exr(&exr_a).expect("exr parses");
    assert_eq!((img.width, img.height), (24, 16));
    assert_eq!(png_info(&exr_a.with_extension("png")), (24, 16, 3));
    let s = read_json(&stats_a);
    assert_eq!(s["spp"], 3);
    assert_eq!(s["max_depth"], 4);
    assert_eq!(s["stages"]["nee"]["ran"], true);
    assert_eq!(s["stages"]["training"]["ran"], false);
    assert!(s["rays"].as_u64().expect("rays") >= 3 * 24 * 16);
    assert!(s["rays_per_second"].as_f64().expect("rays/s") > 0.0);
    for k in ["wall", "tracing", "inference", "training"] {
        assert!(s["time_s"][k].as_f64().is_some(), "time_s.{k}");
    }

    // README spelling (`--scene`), guided, time budget with a training fraction.
    let (exr_b, stats_b) = (dir.join("b.exr"), dir.join("b.json"));
    run_ok(
        bin()
            .args([
                "render",
                "--scene",
                "builtin:cornell-box",
                "--integrator",
                "guided",
            ])
            .args(["--guide", "npm", "--model-size", "small", "--time", "1.0"])
            .args(size)
            .args([
                "--train-fraction",
                "0.5",
                "--batch-size",
                "256",
                "--training-share",
                "0.25",
                "--rr",
                "--out",
            ])
            .arg(&exr_b)
            .arg("--stats")
            .arg(&stats_b),
    );
    let s = read_json(&stats_b);
    let spp = s["spp"].as_u64().expect("spp");
    let train = s["stages"]["training"]["passes"]
        .as_u64()
        .expect("training passes");
    assert!(spp >= 1 && train <= spp, "{s}");
    assert_eq!(s["stages"]["training"]["steps_after_stop"], 0);
    // The library's schedule ran the training and reports its share of the training phase.
    let sched = &s["stages"]["training"]["schedule"];
    assert!(sched["updates"].as_u64() >= Some(1), "{s}");
    assert_eq!(sched["steps"], s["stages"]["training"]["steps"], "{s}");
    // A bare `--rr` is Mitsuba's throughput roulette.
    assert_eq!(s["stages"]["russian_roulette"]["ran"], true);
    assert_eq!(s["stages"]["russian_roulette"]["mode"], "throughput", "{s}");
    assert_eq!(s["stages"]["product_inputs"]["all_materials_diffuse"], true);
    // A time budget with NEE: the probe is on; when its look came (a quarter of the way into
    // training, after 64 Adam steps) it reports the steps it had and whether training went
    // on, else why it did not run. The passes were weighted.
    let probe = &s["stages"]["training_probe"];
    if probe["ran"] == true {
        assert!(
            probe["steps"].as_u64() >= Some(guiding::EARLY_LOOK_MIN_STEPS),
            "{s}"
        );
        assert!(probe["training_resumed"].as_bool().is_some() || probe["finished"] == false);
    } else {
        assert!(probe["reason"].as_str().is_some(), "{s}");
    }
    assert!(s["stages"]["pass_weights"]["ran"].as_bool().is_some());
    assert!(s["training_samples_used"].as_u64().is_some());
    assert!(s["time_s"]["inference"].as_f64().expect("inference") >= 0.0);
    assert!(exr_b.with_extension("png").exists());

    // `--rr guided`: the weight window's statistics (the grid learned in the first fifth of
    // the 10 passes, then split and killed paths).
    let stats_c = dir.join("c.json");
    run_ok(
        bin()
            .args(["render", "builtin:cornell-box", "--integrator", "pt-nee"])
            .args(["--spp", "10", "--rr", "guided"])
            .args(size)
            .arg("--out")
            .arg(dir.join("c.exr"))
            .arg("--stats")
            .arg(&stats_c),
    );
    let s = read_json(&stats_c);
    let rr = &s["stages"]["russian_roulette"];
    assert_eq!(
        (&rr["ran"], &rr["mode"]),
        (&true.into(), &"guided".into()),
        "{s}"
    );
    let g = &rr["guided"];
    assert_eq!(g["learning_passes"], 2, "{s}");
    assert!(g["grid_samples"].as_u64() > Some(0), "{s}");
    for k in ["decisions", "killed", "split_vertices", "extra_paths"] {
        assert!(g[k].as_u64() > Some(0), "{k}: {s}");
    }
    let (mean, max) = (
        g["mean_split"].as_f64().unwrap(),
        g["max_split"].as_f64().unwrap(),
    );
    assert!(mean >= 2.0 && mean <= max && max <= 8.0, "{s}");
    // Without a time budget the window decides in every pass: no trial.
    assert_eq!(
        (&g["trial_passes"], &g["window_off_passes"]),
        (&0.into(), &0.into())
    );
    assert!(g.get("trial").is_none(), "{s}");

    // With one, the window's efficiency trial runs once the grid has learned: its passes,
    // those without the window, and its verdict (or where it stood) in `--stats`.
    for (trial, stats) in [("on", "t.json"), ("off", "u.json")] {
        let stats = dir.join(stats);
        run_ok(
            bin()
                .args(["render", "builtin:cornell-box", "--integrator", "pt-nee"])
                .args(["--time", "2", "--rr", "guided", "--rr-trial", trial])
                .args(size)
                .arg("--out")
                .arg(dir.join("t.exr"))
                .arg("--stats")
                .arg(&stats),
        );
        let s = read_json(&stats);
        let g = &s["stages"]["russian_roulette"]["guided"];
        let passes = g["trial_passes"].as_u64().unwrap();
        let off = g["window_off_passes"].as_u64().unwrap();
        if trial == "off" {
            assert_eq!((passes, off), (0, 0), "{s}");
            continue;
        }
        assert!(passes >= 4, "{s}");
        let t = &g["trial"];
        let (on_arm, off_arm) = (t["on_passes"].as_u64(), t["off_passes"].as_u64());
        assert!(on_arm.unwrap() + off_arm.unwrap() <= passes, "{s}");
        assert!(off >= off_arm.unwrap(), "{s}");
        let state = t["state"].as_str().unwrap();
        assert!(state == "verdict" || state == "unfinished", "{s}");
        if state == "verdict" {
            // ABBA: the first look sees equal arms; a first look that straddles continues
            // with the cheaper-looking arm in two passes of three, so a later verdict may
            // see unequal ones (a loaded machine gets there: fewer, noisier passes). Either
            // way each arm has run at least the first look's two passes.
            assert!(on_arm >= Some(2) && off_arm >= Some(2), "{s}");
        }
        let (lo, hi) = (t["ratio_low"].as_f64(), t["ratio_high"].as_f64());
        assert!(
            lo <= t["cost_ratio"].as_f64() && t["cost_ratio"].as_f64() <= hi,
            "{s}"
        );
    }
    let bad = bin()
        .args([
            "render",
            "builtin:furnace",
            "--spp",
            "1",
            "--rr",
            "sometimes",
        ])
        .output()
        .expect("runs");
    assert!(!bad.status.success());

    let out = run_ok(bin().arg("compare").arg(&exr_a).arg(&exr_b));
    let m: serde_json::Value = serde_json::from_str(&out).expect("compare prints JSON");
    assert!(m["relmse"].as_f64().expect("relmse").is_finite());
    assert!(m["mape"].as_f64().expect("mape") > 0.0);
    let same = run_ok(bin().arg("compare").arg(&exr_a).arg(&exr_a));
    let m: serde_json::Value = serde_json::from_str(&same).expect("JSON");
    assert_eq!(m["relmse"], 0.0);

    // Usage errors are errors, not renders.
    for bad in [
        vec!["render", "builtin:furnace", "--spp", "2", "--time", "1"],
        vec!["render", "builtin:furnace", "--scene", "builtin:door"],
        vec!["render"],
        vec!["render", "builtin:nope", "--spp", "1"],
    ] {
        let o = bin()
            .args(&bad)
            .arg("--out")
            .arg(dir.join("bad.exr"))
            .output()
            .expect("runs");
        assert!(!o.status.success(), "{bad:?} should fail");
    }
}

/// `--rr` by default: the weight window (with its trial) for the guided integrator with a time
/// budget, no roulette for the baselines and for a fixed spp; an explicit `--rr` wins.
#[test]
fn roulette_defaults_to_the_window_for_timed_guided_renders() {
    let dir = scratch("rr-default");
    let cases: [(&[&str], &str); 5] = [
        (&["--integrator", "guided", "--time", "1"], "guided"),
        (&["--integrator", "guided", "--spp", "2"], "off"),
        (&["--integrator", "pt-nee", "--time", "1"], "off"),
        (&["--integrator", "pt", "--time", "1"], "off"),
        (
            &["--integrator", "guided", "--time", "1", "--rr", "off"],
            "off",
        ),
    ];
    for (i, (args, mode)) in cases.into_iter().enumerate() {
        let stats = dir.join(format!("{i}.json"));
        run_ok(
            bin()
                .args(["render", "builtin:cornell-box", "--model-size", "small"])
                .args(args)
                .args(["--width", "32", "--height", "32"])
                .arg("--out")
                .arg(dir.join(format!("{i}.exr")))
                .arg("--stats")
                .arg(&stats),
        );
        let s = read_json(&stats);
        let rr = &s["stages"]["russian_roulette"];
        assert_eq!(rr["mode"], mode, "{args:?}: {s}");
        assert_eq!(rr["ran"], mode != "off", "{args:?}: {s}");
        assert_eq!(rr["guided"].is_object(), mode == "guided", "{args:?}: {s}");
    }
}

/// With a guide, the window's efficiency trial waits for the guide's first look: run beside
/// its first passes, it would weigh the window on a mix of guided and unguided passes, not on
/// the estimator that renders the rest (on `builtin:door` it measured the unguided arm's gain
/// while the window did nothing for the guided image). Without a guide (pt-nee) nothing waits.
/// Without the wait, `waited_passes` is 0 and the window's trial starts with the guide's. The
/// grid learns in the guide's training passes only (with the grid's own phase, the first fifth
/// of the budget, it learned in passes the guide no longer recorded).
#[test]
fn window_trial_waits_for_the_guide_trial() {
    let dir = scratch("window-waits");
    let size = ["--width", "64", "--height", "64"];
    let stats = dir.join("g.json");
    run_ok(
        bin()
            .args(["render", "builtin:door", "--integrator", "guided"])
            .args(["--guide", "npm", "--model-size", "small", "--time", "3"])
            .args(["--rr", "guided"])
            .args(size)
            .arg("--out")
            .arg(dir.join("g.exr"))
            .arg("--stats")
            .arg(&stats),
    );
    let s = read_json(&stats);
    let g = &s["stages"]["russian_roulette"]["guided"];
    let guide = &s["stages"]["efficiency_trial"];
    let waited = g["waited_passes"].as_u64().unwrap();
    let window_passes = g["trial_passes"].as_u64().unwrap();
    // The grid learns in the guide's training passes and in no others: their paths are
    // recorded anyway, and recording for the grid alone after the guide's training ended cost
    // the scenes whose guide does not pay.
    assert_eq!(
        g["learning_passes"], s["stages"]["training"]["passes"],
        "{s}"
    );
    assert!(g["window_off_passes"].as_u64() >= Some(waited), "{s}");
    if guide["ran"] == true {
        // The training passes (the grid learned in them), the warm-up pass after training and
        // every guide-trial pass up to its first look ran without the window; the window's
        // trial only after that look.
        let before_window = g["learning_passes"].as_u64().unwrap() + waited;
        let training = s["stages"]["training"]["passes"].as_u64().unwrap();
        let look = &guide["first_look"];
        let guide_passes = if look.is_null() {
            // A verdict at the first look, or no look yet (then no window trial either).
            if guide["finished"] != true {
                assert_eq!(window_passes, 0, "no look, no window trial: {s}");
            }
            guide["passes"].as_u64().unwrap()
        } else {
            look["guided_passes"].as_u64().unwrap() + look["unguided_passes"].as_u64().unwrap()
        };
        assert!(before_window > training + guide_passes, "{s}");
    }
    // The plain estimator has no trial of its own: the window's trial starts at once.
    let plain = dir.join("p.json");
    run_ok(
        bin()
            .args(["render", "builtin:door", "--integrator", "pt-nee"])
            .args(["--time", "2", "--rr", "guided"])
            .args(size)
            .arg("--out")
            .arg(dir.join("p.exr"))
            .arg("--stats")
            .arg(&plain),
    );
    let s = read_json(&plain);
    let g = &s["stages"]["russian_roulette"]["guided"];
    assert_eq!(g["waited_passes"], 0, "{s}");
    assert!(g["trial_passes"].as_u64() > Some(0), "{s}");
}

#[test]
fn stats_report_skipped_nee() {
    let dir = scratch("nolight");
    let xml = write_scene(&dir, "dark.xml", "", r#"<shape type="sphere"/>"#);
    let stats = dir.join("s.json");
    run_ok(
        bin()
            .arg("render")
            .arg(&xml)
            .args(["--integrator", "pt-nee", "--spp", "1", "--out"])
            .arg(dir.join("d.exr"))
            .arg("--stats")
            .arg(&stats),
    );
    let s = read_json(&stats);
    assert_eq!(s["stages"]["nee"]["ran"], false);
    assert!(s["stages"]["nee"]["reason"]
        .as_str()
        .expect("reason")
        .contains("no emitter"));
}

/// The guided render's default target is radiance (the library's `npm_radiance` preset): the
/// stats say the product inputs were skipped; `--target product` runs them and notes when
/// every material is diffuse (the product then adds nothing: the BSDF is the cosine).
#[test]
fn stats_report_skipped_product_inputs_when_all_diffuse() {
    let dir = scratch("product");
    let glossy = write_scene(
        &dir,
        "glossy.xml",
        r#"<transform name="to_world"><lookat origin="0, -5, 0" target="0, 0, 0" up="0, 0, 1"/></transform>"#,
        r#"<shape type="sphere"><bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><translate z="3"/></transform>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>"#,
    );
    let glossy = glossy.display().to_string();
    let run = |scene: &str, target: Option<&str>, name: &str| {
        let stats = dir.join(format!("{name}.json"));
        let mut cmd = bin();
        cmd.args(["render", scene, "--integrator", "guided", "--guide", "npm"])
            .args(["--model-size", "small", "--spp", "2", "--width", "16"])
            .args([
                "--height",
                "16",
                "--batch-size",
                "256",
                "--train-epochs",
                "1",
            ])
            .args(target.map(|t| vec!["--target", t]).unwrap_or_default())
            .arg("--out")
            .arg(dir.join(format!("{name}.exr")))
            .arg("--stats")
            .arg(&stats);
        let out = cmd.output().expect("runs");
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{cmd:?} failed:\n{stderr}");
        (
            read_json(&stats)["stages"]["product_inputs"].clone(),
            stderr,
        )
    };

    let (p, _) = run("builtin:cornell-box", None, "default");
    assert_eq!(p["ran"], false, "{p}");
    assert_eq!(p["all_materials_diffuse"], true, "{p}");
    assert!(
        p["reason"].as_str().expect("reason").contains("radiance"),
        "{p}"
    );

    let (p, _) = run("builtin:cornell-box", Some("product"), "forced");
    assert_eq!(p["ran"], true, "{p}");
    assert!(
        p["reason"].as_str().expect("reason").contains("diffuse"),
        "{p}"
    );

    let (p, _) = run(&glossy, Some("product"), "glossy");
    assert_eq!(p["ran"], true, "{p}");
    assert_eq!(p["all_materials_diffuse"], false, "{p}");
    assert_eq!(p["reason"], "product target", "{p}");
}

/// `--device gpu` renders every guide with the guide on the Vulkan device, and `--stats`
/// reports the device and its own training (steps, loss, samples used and rejected counted
/// by the field's loop). Skipped without a device or SPIR-V, unless
/// `GUIDING_REQUIRE_VULKAN=1`.
#[test]
fn gpu_renders_of_every_guide_report_the_devices_training() {
    if common::vulkan_context().is_none() {
        return;
    }
    let dir = scratch("gpu");
    for guide in ["npm", "nasg", "df-n", "df-l"] {
        let stats = dir.join(format!("{guide}.json"));
        run_ok(
            bin()
                .args(["render", "builtin:cornell-box", "--integrator", "guided"])
                .args(["--guide", guide, "--device", "gpu", "--model-size", "small"])
                .args(["--spp", "8", "--width", "24", "--out"])
                .arg(dir.join(format!("{guide}.exr")))
                .arg("--stats")
                .arg(&stats),
        );
        let s = read_json(&stats);
        assert!(s["device"].is_string(), "{guide}: no device in {s:#}");
        let training = &s["stages"]["training"];
        assert!(
            training["steps"].as_u64().is_some_and(|n| n > 0),
            "{guide}: no training step on the device: {training:#}"
        );
        assert!(training["last_loss"].is_number(), "{guide}: {training:#}");
        assert!(
            s["training_samples"]["recorded"]
                .as_u64()
                .is_some_and(|n| n > 0),
            "{guide}: {s:#}"
        );
        assert!(s["training_samples"]["rejected"].is_u64(), "{guide}");
        assert!(s["stages"]["guiding"]["guided_vertices"].as_u64() > Some(0));
    }
}
