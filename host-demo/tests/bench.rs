//! `host-demo bench`: argument parsing, and the `--quick` suite end to end (the report files
//! exist and parse; the numbers are not checked here).

use host_demo::bench::report::{mean_std, RUNS_HEADER};
use host_demo::bench::{scene_slug, Budget, Method};
use std::path::Path;
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
    for bad in [
        "",
        "guided-radiance",
        "npm",
        "npm-",
        "foo-radiance",
        "df-x-product",
        "pt-nee-product",
    ] {
        assert!(Method::parse(bad).is_err(), "{bad}");
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

#[test]
fn quick_suite_writes_a_report_that_parses() {
    let dir = std::env::temp_dir().join(format!("host-demo-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("out");
    let status = Command::new(env!("CARGO_BIN_EXE_host-demo"))
        .args(["bench", "--quick", "--out"])
        .arg(&out)
        .arg("--cache")
        .arg(dir.join("cache"))
        .status()
        .unwrap();
    assert!(status.success());
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
