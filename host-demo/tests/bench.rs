//! `host-demo bench`: argument parsing, the `--suite` table on synthetic runs and its scene
//! discovery, and `--quick` and `--suite --quick` end to end (the report files exist and
//! parse; the numbers are not checked there).

use host_demo::bench::report::{mean_std, RUNS_HEADER};
use host_demo::bench::{scene_slug, suite, Budget, Method, RunRecord};
use host_demo::render::compare::Metrics;
use std::path::{Path, PathBuf};
use std::process::Command;

#[test]
fn methods_and_budgets_parse() {
    assert_eq!(Method::parse("pt").unwrap().args, ["--integrator", "pt"]);
    assert_eq!(
        Method::parse("df-l-product").unwrap().args,
        [
            "--integrator",
            "guided",
            "--guide",
            "df-l",
            "--target",
            "product"
        ]
    );
    assert_eq!(
        Method::parse("npm-radiance-nonee-notrial").unwrap().args,
        [
            "--integrator",
            "guided",
            "--guide",
            "npm",
            "--target",
            "radiance",
            "--nee",
            "off",
            "--guide-trial",
            "off"
        ]
    );
    assert_eq!(
        Method::parse("guided").unwrap().args,
        ["--integrator", "guided"]
    );
    assert_eq!(
        Method::parse("guided-notrial").unwrap().args,
        ["--integrator", "guided", "--guide-trial", "off"]
    );
    // `-grr` on every method, the unguided ones included.
    for (method, args) in [
        ("pt-nee-grr", "--integrator pt-nee --rr guided"),
        ("pt-grr", "--integrator pt --rr guided"),
        ("pt-nee-err", "--integrator pt-nee --rr efficiency"),
        (
            "pt-nee-grra",
            "--integrator pt-nee --rr guided --rr-trial off",
        ),
        ("guided-norr", "--integrator guided --rr off"),
        (
            "npm-radiance-notrial-grr",
            "--integrator guided --guide npm --target radiance --guide-trial off --rr guided",
        ),
    ] {
        assert_eq!(Method::parse(method).unwrap().args.join(" "), args);
    }
    for bad in [
        "",
        "pt-nee-notrial",
        "grr",
        "guided-radiance",
        "npm",
        "npm-",
        "foo-radiance",
        "df-x-product",
        "pt-nee-product",
    ] {
        assert!(Method::parse(bad).is_err(), "{bad}");
    }
    // The suite's "best guided" column: guided methods only, not the window on `pt-nee`.
    for (method, guided) in [
        ("guided", true),
        ("guided-norr", true),
        ("npm-product-grr", true),
        ("pt", false),
        ("pt-nee", false),
        ("pt-nee-grr", false),
        ("pt-grr", false),
    ] {
        assert_eq!(
            host_demo::bench::suite::is_guided_method(method),
            guided,
            "{method}"
        );
    }
    assert_eq!(Budget::parse("10").unwrap(), Budget::Seconds(10.0));
    assert_eq!(Budget::parse("2.5s").unwrap(), Budget::Seconds(2.5));
    assert_eq!(Budget::parse("64spp").unwrap(), Budget::Spp(64));
    for bad in ["", "0", "-1", "abc", "nan", "inf", "1.5spp"] {
        assert!(Budget::parse(bad).is_err(), "{bad}");
    }
    assert_eq!(scene_slug("builtin:door"), "door");
    assert_eq!(
        scene_slug("../shared/scenes/veach-mis/scene.xml"),
        "veach-mis"
    );
    assert_eq!(scene_slug("a b/my scene.xml"), "my_scene");
    let (m, s) = mean_std(&[1.0, 2.0, 3.0]);
    assert!((m - 2.0).abs() < 1e-12 && (s - 1.0).abs() < 1e-12);
}

fn parse_csv(path: &Path) -> (String, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().to_string();
    (
        header,
        lines
            .map(|l| l.split(',').map(String::from).collect())
            .collect(),
    )
}

/// Runs `host-demo bench FLAGS` with its output and cache in a fresh temporary folder named
/// after `tag`; returns the folder (to remove) and the output directory.
fn bench_in_temp(tag: &str, flags: &[&str]) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("host-demo-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("out");
    let status = Command::new(env!("CARGO_BIN_EXE_host-demo"))
        .arg("bench")
        .args(flags)
        .arg("--out")
        .arg(&out)
        .arg("--cache")
        .arg(dir.join("cache"))
        .status()
        .unwrap();
    assert!(status.success(), "bench {flags:?}: {status}");
    (dir, out)
}

#[test]
fn quick_suite_writes_a_report_that_parses() {
    let (dir, out) = bench_in_temp("bench", &["--quick"]);
    // runs.csv: the header and 2 scenes × 5 methods × 2 budgets × 2 seeds rows of numbers.
    let (header, rows) = parse_csv(&out.join("runs.csv"));
    assert_eq!(header, RUNS_HEADER);
    assert_eq!(rows.len(), 2 * 5 * 2 * 2);
    let columns = header.split(',').count();
    for row in &rows {
        assert_eq!(row.len(), columns, "{row:?}");
        for v in &row[4..] {
            let x: f64 = v.parse().unwrap_or_else(|_| panic!("{v} in {row:?}"));
            assert!(x.is_finite() && x >= 0.0, "{row:?}");
        }
    }
    // micro.csv: every value a positive number.
    let (header, rows) = parse_csv(&out.join("micro.csv"));
    assert!(header.starts_with("group,name,value"));
    assert!(rows.len() >= 10);
    for row in &rows {
        let x: f64 = row[2].parse().unwrap();
        assert!(x.is_finite() && x > 0.0, "{row:?}");
    }
    // report.md: one section per scene with a table row per method and budget.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for scene in ["cornell-box", "door"] {
        assert!(md.contains(&format!("## {scene}")), "{md}");
        // Plots: SVG text and a PNG signature.
        let svg = std::fs::read_to_string(out.join(format!("{scene}.svg"))).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("</svg>"));
        let png = std::fs::read(out.join(format!("{scene}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }
    assert_eq!(md.matches("| npm-product |").count(), 2 * 2);
    assert!(md.contains("## Micro-benchmarks"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A synthetic run: only scene, method, seed, budget, spp and relMSE matter to the suite.
fn run(scene: &str, method: &str, seed: u32, budget: Budget, spp: u64, relmse: f64) -> RunRecord {
    RunRecord {
        scene: scene.into(),
        method: method.into(),
        seed,
        budget,
        spp,
        wall_s: 1.0,
        tracing_s: 1.0,
        inference_s: 0.0,
        training_s: 0.0,
        metrics: Metrics {
            relmse,
            relmse_untrimmed: relmse,
            mape: 0.1,
            pixels: 100,
            trimmed: 0,
        },
    }
}

#[test]
fn suite_table_by_hand() {
    let b = Budget::Seconds(30.0);
    // (scene, method, [(spp, relMSE) per seed]).
    type Runs<'a> = (&'a str, &'a str, [(u64, f64); 2]);
    let runs: [Runs; 8] = [
        // a: pt-nee 0.2 ± 0.1414 at 100 spp; pt 1.0 (5×); guided 0.15 (0.75×) at 80 spp
        // (0.8×); npm-radiance 0.1 (0.5×, the best) at 60 spp (0.6×).
        ("a", "pt-nee", [(100, 0.1), (100, 0.3)]),
        ("a", "pt", [(150, 0.8), (150, 1.2)]),
        ("a", "guided", [(90, 0.1), (70, 0.2)]),
        ("a", "npm-radiance", [(60, 0.05), (60, 0.15)]),
        // b: pt-nee 0.04 ± 0 at 200 spp; pt 0.4 (10×); guided 0.08 (2×, the best) at 120 spp
        // (0.6×); npm-radiance 0.16 (4×) at 200 spp (1×).
        ("b", "pt-nee", [(200, 0.04), (200, 0.04)]),
        ("b", "pt", [(300, 0.4), (300, 0.4)]),
        ("b", "guided", [(100, 0.08), (140, 0.08)]),
        ("b", "npm-radiance", [(200, 0.12), (200, 0.20)]),
    ];
    let mut records: Vec<RunRecord> = runs
        .iter()
        .flat_map(|(scene, method, seeds)| {
            seeds
                .iter()
                .enumerate()
                .map(|(i, &(spp, rel))| run(scene, method, i as u32, b, spp, rel))
        })
        .collect();
    // Another budget, and a scene without pt-nee: neither may enter the table.
    records.push(run("a", "guided", 0, Budget::Seconds(5.0), 10, 100.0));
    records.push(run("c", "guided", 0, b, 10, 1.0));
    let scenes: Vec<String> = ["a", "b", "c"].map(String::from).to_vec();
    let methods: Vec<String> = ["pt", "pt-nee", "guided", "npm-radiance"]
        .map(String::from)
        .to_vec();
    let t = suite::table(&records, &scenes, &methods, b);
    let close = |x: f64, y: f64| assert!((x - y).abs() < 1e-12, "{x} != {y}");
    assert_eq!(t.missing, ["c: no pt-nee runs"]);
    assert_eq!(t.rows.len(), 2);
    let (ra, rb) = (&t.rows[0], &t.rows[1]);
    assert_eq!((ra.scene.as_str(), ra.seeds), ("a", 2));
    close(ra.baseline_relmse, 0.2);
    close(ra.baseline_sd, 0.02f64.sqrt());
    close(ra.baseline_spp, 100.0);
    close(ra.pt.as_ref().unwrap().ratio, 5.0);
    let g = ra.guided.as_ref().unwrap();
    close(g.ratio, 0.75);
    close(g.spp_ratio, 0.8);
    let best = ra.best.as_ref().unwrap();
    assert_eq!(best.method, "npm-radiance");
    close(best.ratio, 0.5);
    close(best.spp_ratio, 0.6);
    close(rb.baseline_relmse, 0.04);
    close(rb.baseline_sd, 0.0);
    close(rb.pt.as_ref().unwrap().ratio, 10.0);
    let g = rb.guided.as_ref().unwrap();
    close(g.ratio, 2.0);
    close(g.spp_ratio, 0.6);
    assert_eq!(rb.best.as_ref().unwrap().method, "guided");
    close(rb.best.as_ref().unwrap().ratio, 2.0);
    // Geometric means over a and b; worst cases (all on b).
    let s = &t.summary;
    close(s.pt.unwrap(), 50f64.sqrt());
    close(s.guided.unwrap(), 1.5f64.sqrt());
    close(s.guided_spp.unwrap(), 0.48f64.sqrt());
    close(s.best.unwrap(), 1.0);
    for (w, v) in [
        (&s.worst_guided, 2.0),
        (&s.worst_guided_spp, 0.6),
        (&s.worst_best, 2.0),
    ] {
        let w = w.as_ref().unwrap();
        assert_eq!(w.scene, "b");
        close(w.value, v);
    }
    // One method for every scene: guided (√1.5) beats npm-radiance (√(0.5 × 4) = √2).
    let (m, g) = s.best_single.as_ref().unwrap();
    assert_eq!(m, "guided");
    close(*g, 1.5f64.sqrt());
    assert_eq!(suite::geomean([0.0, f64::NAN, -1.0]), None);
}

#[test]
fn suite_scenes_are_found_at_run_time() {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let published = [manifest.join("tests/data/published")];
    let nowhere = [manifest.join("no-such-folder")];
    // Nothing on disk: only the built-in door, and a note for each missing folder.
    let (scenes, notes) = suite::scenes(&nowhere, &nowhere);
    assert_eq!(scenes, ["builtin:door"]);
    assert_eq!(notes.len(), 2, "{notes:?}");
    assert!(notes[0].starts_with("shared scenes") && notes[1].starts_with("published scenes"));
    // The published scenes of this repository, in folder order after the door.
    let (scenes, notes) = suite::scenes(&nowhere, &published);
    let slugs: Vec<String> = scenes.iter().map(|s| scene_slug(s)).collect();
    assert_eq!(
        slugs,
        [
            "door",
            "cornell-box-v3",
            "veach-bidir-v3",
            "veach-mis-v05",
            "veach-mis-v3"
        ]
    );
    assert_eq!(notes.len(), 1);
    // A shared folder with one expected scene and one extra, and a published folder without
    // an XML file.
    let dir = std::env::temp_dir().join(format!("host-demo-suite-scenes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    for d in ["shared/veach-mis", "shared/extra", "published/empty"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    for f in ["shared/veach-mis/scene.xml", "shared/extra/scene.xml"] {
        std::fs::write(dir.join(f), "<scene/>").unwrap();
    }
    let (scenes, notes) = suite::scenes(&[dir.join("shared")], &[dir.join("published")]);
    let slugs: Vec<String> = scenes.iter().map(|s| scene_slug(s)).collect();
    assert_eq!(slugs, ["extra", "veach-mis", "door"]);
    assert_eq!(notes.len(), 3, "{notes:?}");
    assert!(notes[0].contains("classroom") && notes[1].contains("cornell-box"));
    assert!(notes[2].contains("empty"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn quick_suite_writes_suite_md_and_csv() {
    let (dir, out) = bench_in_temp("suite", &["--suite", "--quick"]);
    // 2 built-in scenes × pt-nee and guided × 1 s × 1 seed.
    let (header, rows) = parse_csv(&out.join("runs.csv"));
    assert_eq!(header, RUNS_HEADER);
    assert_eq!(rows.len(), 2 * 2);
    // suite.csv: a row per scene, then geomean, worst and best_single; every numeric field
    // empty (pt did not run) or a positive number.
    let (header, rows) = parse_csv(&out.join("suite.csv"));
    assert_eq!(header, suite::CSV_HEADER);
    let columns = header.split(',').count();
    let firsts: Vec<&str> = rows.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(
        firsts,
        [
            "builtin:cornell-box",
            "builtin:door",
            "geomean",
            "worst",
            "best_single"
        ]
    );
    for row in &rows {
        assert_eq!(row.len(), columns, "{row:?}");
        assert_eq!((row[1].as_str(), row[2].as_str()), ("time_s", "1"));
        for (i, v) in row.iter().enumerate().skip(3) {
            if v.is_empty() || i == 10 || i == 13 {
                continue;
            }
            let x: f64 = v.parse().unwrap_or_else(|_| panic!("{v} in {row:?}"));
            assert!(x.is_finite() && x >= 0.0, "{row:?}");
        }
    }
    for row in &rows[..2] {
        assert_eq!(row[10], "guided", "{row:?}");
        assert!(row[8].parse::<f64>().unwrap() > 0.0, "{row:?}");
    }
    // suite.md: a table row per scene, the summary rows.
    let md = std::fs::read_to_string(out.join("suite.md")).unwrap();
    assert!(md.contains("## 1 s"), "{md}");
    for row in [
        "| cornell-box |",
        "| door |",
        "| **geometric mean** (2 scenes) |",
        "| **worst** |",
    ] {
        assert!(md.contains(row), "{row} not in {md}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
