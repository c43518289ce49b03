//! `host-demo bench --suite`: the published scenes in one command, reported as a user reads it.
//!
//! The suite runs the benchmark matrix ([`super::run`]) on every scene found on disk
//! ([`scenes`]) and writes `suite.md` / `suite.csv`: per scene and budget `pt-nee`'s relMSE
//! (mean ± standard deviation over seeds), the ratio to it of `pt`, of the default guided
//! command (`guided`) and of the best guided method of that scene, and the guided spp as a
//! fraction of `pt-nee`'s; then the geometric mean of the ratios over the scenes and the worst
//! case ([`table`]). A ratio is `relMSE_method / relMSE_pt-nee` at the same budget, each the
//! mean over seeds first (below 1: the method beats `pt-nee`).

use super::report::{budget_label, csv_field, mean_std, select, write as write_file};
use super::{scene_slug, BenchOptions, Budget, RunRecord};
use crate::error::Result;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The method every ratio is against.
pub const BASELINE: &str = "pt-nee";
/// The default guided command (`render --integrator guided`).
pub const GUIDED: &str = "guided";
/// BSDF sampling only.
pub const PT: &str = "pt";
/// Whether `method` is a guided candidate for the suite's "best guided" column: any method but
/// `pt` and `pt-nee` and their variants (`pt-nee-grr`, the weight window on the unguided path
/// tracer, is roulette, not guiding).
pub fn is_guided_method(method: &str) -> bool {
    method != PT && method != BASELINE && !method.starts_with("pt-")
}

/// The suite's default methods.
pub const METHODS: [&str; 7] = [
    "pt",
    "pt-nee",
    "guided",
    "npm-radiance",
    "npm-product",
    "nasg-radiance",
    "df-l-radiance",
];
/// The shared scenes the suite expects (others with a `scene.xml` are run too).
pub const SHARED_SCENES: [&str; 3] = ["classroom", "cornell-box", "veach-mis"];
/// The built-in scenes of the suite.
pub const BUILTIN_SCENES: [&str; 1] = ["builtin:door"];
/// The fraction of `pt-nee`'s spp the issue asks of the guided command at equal time.
pub const SPP_TARGET: f64 = 0.8;
/// Header of `suite.csv`.
pub const CSV_HEADER: &str = "scene,budget_kind,budget,seeds,pt_nee_relmse,pt_nee_relmse_sd,pt_nee_spp,pt_ratio,guided_ratio,guided_spp_ratio,best_method,best_ratio,best_spp_ratio,note";

/// Where the suite looks for the shared scenes: `../shared/scenes` from the working directory
/// (the repository root), then next to the checkout this binary was built from.
pub fn shared_roots() -> Vec<PathBuf> {
    vec![
        PathBuf::from("../shared/scenes"),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes"),
    ]
}

/// Where the suite looks for the published scenes: `host-demo/tests/data/published` from the
/// working directory, then in the checkout this binary was built from.
pub fn published_roots() -> Vec<PathBuf> {
    vec![
        PathBuf::from("host-demo/tests/data/published"),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/published"),
    ]
}

/// The scene XML of a published folder: `scene.xml`, else its only `.xml` file.
fn scene_xml(dir: &Path) -> Option<PathBuf> {
    let main = dir.join("scene.xml");
    if main.is_file() {
        return Some(main);
    }
    let mut xml: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "xml"))
        .collect();
    (xml.len() == 1).then(|| xml.remove(0))
}

/// The sub-folders of the first existing root, sorted, or a note naming every root tried.
fn folders(roots: &[PathBuf], what: &str) -> std::result::Result<Vec<PathBuf>, String> {
    let tried = || {
        roots
            .iter()
            .map(|r| r.display().to_string())
            .collect::<Vec<_>>()
            .join(" or ")
    };
    let root = roots.iter().find(|r| r.is_dir()).ok_or_else(|| {
        format!(
            "{what}: no folder {} (run from the repository root)",
            tried()
        )
    })?;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
        .map_err(|e| format!("{what}: {}: {e}", root.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    Ok(dirs)
}

/// The suite's scenes found on disk, in report order (shared scenes, the built-in door,
/// published scenes), and a note for each one expected but missing.
///
/// Shared scenes: every folder of the first existing `shared` root with a `scene.xml`
/// ([`SHARED_SCENES`] are expected). Published scenes: every folder of the first existing
/// `published` root with a scene XML (`scene_xml`).
pub fn scenes(shared: &[PathBuf], published: &[PathBuf]) -> (Vec<String>, Vec<String>) {
    let (mut found, mut notes) = (Vec::new(), Vec::new());
    match folders(shared, "shared scenes") {
        Ok(dirs) => {
            for name in SHARED_SCENES {
                if !dirs
                    .iter()
                    .any(|d| d.ends_with(name) && d.join("scene.xml").is_file())
                {
                    notes.push(format!(
                        "shared scene {name} not found (no {name}/scene.xml)"
                    ));
                }
            }
            found.extend(
                dirs.iter()
                    .map(|d| d.join("scene.xml"))
                    .filter(|x| x.is_file())
                    .map(|x| x.display().to_string()),
            );
        }
        Err(note) => notes.push(note),
    }
    found.extend(BUILTIN_SCENES.iter().map(|s| s.to_string()));
    match folders(published, "published scenes") {
        Ok(dirs) => {
            for dir in dirs {
                match scene_xml(&dir) {
                    Some(x) => found.push(x.display().to_string()),
                    None => notes.push(format!(
                        "published folder {} skipped: no single scene XML in it",
                        dir.display()
                    )),
                }
            }
        }
        Err(note) => notes.push(note),
    }
    (found, notes)
}

/// A method's ratio to `pt-nee` on one scene and budget.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodRatio {
    /// Method name.
    pub method: String,
    /// `relMSE_method / relMSE_pt-nee`, means over seeds.
    pub ratio: f64,
    /// `spp_method / spp_pt-nee`, means over seeds (NaN when `pt-nee` rendered none).
    pub spp_ratio: f64,
}

/// One scene of a [`SuiteTable`].
#[derive(Clone, Debug, PartialEq)]
pub struct SuiteRow {
    /// Scene spec.
    pub scene: String,
    /// Seeds of `pt-nee`.
    pub seeds: usize,
    /// `pt-nee`'s relMSE, mean over seeds.
    pub baseline_relmse: f64,
    /// Its sample standard deviation over seeds.
    pub baseline_sd: f64,
    /// `pt-nee`'s spp, mean over seeds.
    pub baseline_spp: f64,
    /// `pt`'s ratio, when it ran.
    pub pt: Option<MethodRatio>,
    /// The default guided command's ratio, when it ran.
    pub guided: Option<MethodRatio>,
    /// The guided method (any but `pt` and `pt-nee`) with the lowest ratio on this scene.
    pub best: Option<MethodRatio>,
}

/// The largest (or, for spp, smallest) value of a column and its scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Worst {
    /// The value.
    pub value: f64,
    /// Its scene spec.
    pub scene: String,
}

/// The summary of a [`SuiteTable`]: geometric means over its rows and worst cases.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SuiteSummary {
    /// Geometric mean of `pt`'s ratio.
    pub pt: Option<f64>,
    /// Geometric mean of `guided`'s ratio.
    pub guided: Option<f64>,
    /// Geometric mean of `guided`'s spp ratio.
    pub guided_spp: Option<f64>,
    /// Geometric mean of the per-scene best guided ratio.
    pub best: Option<f64>,
    /// The largest `guided` ratio.
    pub worst_guided: Option<Worst>,
    /// The smallest `guided` spp ratio.
    pub worst_guided_spp: Option<Worst>,
    /// The largest per-scene best ratio.
    pub worst_best: Option<Worst>,
    /// The one guided method with the lowest geometric mean ratio over every row (methods
    /// missing on a row are not candidates), and that geometric mean.
    pub best_single: Option<(String, f64)>,
}

/// The suite's table for one budget.
#[derive(Clone, Debug, PartialEq)]
pub struct SuiteTable {
    /// The budget.
    pub budget: Budget,
    /// One row per scene with `pt-nee` runs.
    pub rows: Vec<SuiteRow>,
    /// Scenes without `pt-nee` runs (or with a zero or non-finite relMSE), with why.
    pub missing: Vec<String>,
    /// Geometric means and worst cases over `rows`.
    pub summary: SuiteSummary,
}

/// Geometric mean of the finite positive values, `None` when there is none.
pub fn geomean(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let logs: Vec<f64> = values
        .into_iter()
        .filter(|v| v.is_finite() && *v > 0.0)
        .map(f64::ln)
        .collect();
    (!logs.is_empty()).then(|| (logs.iter().sum::<f64>() / logs.len() as f64).exp())
}

/// Mean over seeds of relMSE and of spp of `method` on `scene` at `budget`.
fn means(records: &[RunRecord], scene: &str, method: &str, budget: Budget) -> Option<[f64; 3]> {
    let runs = select(records, scene, method, budget);
    if runs.is_empty() {
        return None;
    }
    let (rel, sd) = mean_std(&runs.iter().map(|r| r.metrics.relmse).collect::<Vec<_>>());
    let (spp, _) = mean_std(&runs.iter().map(|r| r.spp as f64).collect::<Vec<_>>());
    Some([rel, sd, spp])
}

/// The row of `scene`, or why there is none.
fn row(
    records: &[RunRecord],
    scene: &str,
    methods: &[String],
    budget: Budget,
) -> std::result::Result<SuiteRow, String> {
    let [base, base_sd, base_spp] = means(records, scene, BASELINE, budget)
        .ok_or_else(|| format!("{}: no {BASELINE} runs", scene_slug(scene)))?;
    if !(base.is_finite() && base > 0.0) {
        return Err(format!(
            "{}: {BASELINE} relMSE is {base}, no ratio",
            scene_slug(scene)
        ));
    }
    let ratio = |method: &str| {
        means(records, scene, method, budget).map(|[rel, _, spp]| MethodRatio {
            method: method.to_string(),
            ratio: rel / base,
            spp_ratio: if base_spp > 0.0 {
                spp / base_spp
            } else {
                f64::NAN
            },
        })
    };
    let best = methods
        .iter()
        .filter(|m| is_guided_method(m))
        .filter_map(|m| ratio(m))
        .filter(|r| r.ratio.is_finite())
        .reduce(|a, b| if b.ratio < a.ratio { b } else { a });
    Ok(SuiteRow {
        scene: scene.to_string(),
        seeds: select(records, scene, BASELINE, budget).len(),
        baseline_relmse: base,
        baseline_sd: base_sd,
        baseline_spp: base_spp,
        pt: ratio(PT),
        guided: ratio(GUIDED),
        best,
    })
}

/// The largest (`largest`) or smallest finite value of `pick` over `rows`, with its scene.
fn worst(
    rows: &[SuiteRow],
    largest: bool,
    pick: impl Fn(&SuiteRow) -> Option<f64>,
) -> Option<Worst> {
    rows.iter()
        .filter_map(|r| pick(r).filter(|v| v.is_finite()).map(|v| (v, r)))
        .reduce(|a, b| {
            let beyond = if largest { b.0 > a.0 } else { b.0 < a.0 };
            if beyond {
                b
            } else {
                a
            }
        })
        .map(|(value, r)| Worst {
            value,
            scene: r.scene.clone(),
        })
}

/// The suite's table at `budget`: one row per scene of `scenes` that has `pt-nee` runs in
/// `records`, the guided candidates being `methods` other than `pt` and `pt-nee`, then the
/// geometric means and worst cases over the rows.
pub fn table(
    records: &[RunRecord],
    scenes: &[String],
    methods: &[String],
    budget: Budget,
) -> SuiteTable {
    let (mut rows, mut missing) = (Vec::new(), Vec::new());
    for scene in scenes {
        match row(records, scene, methods, budget) {
            Ok(r) => rows.push(r),
            Err(why) => missing.push(why),
        }
    }
    let ratio_of = |r: &Option<MethodRatio>| r.as_ref().map(|m| m.ratio);
    let best_single = methods
        .iter()
        .filter(|m| is_guided_method(m))
        .filter_map(|m| {
            let ratios: Vec<f64> = rows
                .iter()
                .map(|r| {
                    means(records, &r.scene, m, budget).map(|[rel, ..]| rel / r.baseline_relmse)
                })
                .collect::<Option<_>>()?;
            Some((m.clone(), geomean(ratios)?))
        })
        .reduce(|a, b| if b.1 < a.1 { b } else { a });
    let summary = SuiteSummary {
        pt: geomean(rows.iter().filter_map(|r| ratio_of(&r.pt))),
        guided: geomean(rows.iter().filter_map(|r| ratio_of(&r.guided))),
        guided_spp: geomean(
            rows.iter()
                .filter_map(|r| r.guided.as_ref().map(|g| g.spp_ratio)),
        ),
        best: geomean(rows.iter().filter_map(|r| ratio_of(&r.best))),
        worst_guided: worst(&rows, true, |r| ratio_of(&r.guided)),
        worst_guided_spp: worst(&rows, false, |r| r.guided.as_ref().map(|g| g.spp_ratio)),
        worst_best: worst(&rows, true, |r| ratio_of(&r.best)),
        best_single,
    };
    SuiteTable {
        budget,
        rows,
        missing,
        summary,
    }
}

/// Decimals that show three significant digits of `x`.
fn decimals(x: f64) -> usize {
    if x.is_finite() && x > 0.0 {
        (2 - x.log10().floor() as i64).clamp(0, 9) as usize
    } else {
        3
    }
}

/// `0.42×`, or `–` for a missing or non-finite ratio.
fn times(x: Option<f64>) -> String {
    match x.filter(|v| v.is_finite()) {
        Some(v) => format!("{v:.prec$}×", prec = decimals(v)),
        None => "–".to_string(),
    }
}

/// `0.82× ✓` (or ✗ below [`SPP_TARGET`]).
fn spp_times(x: Option<f64>) -> String {
    match x.filter(|v| v.is_finite()) {
        Some(v) => format!(
            "{} {}",
            times(Some(v)),
            if v >= SPP_TARGET { "✓" } else { "✗" }
        ),
        None => "–".to_string(),
    }
}

/// `1.09× (cornell-box)`.
fn worst_md(w: &Option<Worst>, fmt: fn(Option<f64>) -> String) -> String {
    w.as_ref().map_or("–".to_string(), |w| {
        format!("{} ({})", fmt(Some(w.value)), scene_slug(&w.scene))
    })
}

/// A CSV number with `decimals` decimals (`None`: 7 significant digits in scientific
/// notation), empty when missing or non-finite.
fn csv_num(x: Option<f64>, decimals: Option<usize>) -> String {
    match (x.filter(|v| v.is_finite()), decimals) {
        (Some(v), Some(d)) => format!("{v:.d$}"),
        (Some(v), None) => format!("{v:.6e}"),
        (None, _) => String::new(),
    }
}

/// A ratio in the CSV (4 decimals).
fn csv_ratio(x: Option<f64>) -> String {
    csv_num(x, Some(4))
}

/// The Markdown section of one table.
fn markdown(t: &SuiteTable, md: &mut String) {
    let _ = writeln!(md, "## {}\n", budget_label(t.budget));
    let _ = writeln!(
        md,
        "| scene | `pt-nee` relMSE (spp) | `pt` | `guided` | `guided` spp | best guided | best | best spp |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
    let ratio = |r: &Option<MethodRatio>| times(r.as_ref().map(|m| m.ratio));
    for r in &t.rows {
        let d = decimals(r.baseline_relmse);
        let _ = writeln!(
            md,
            "| {} | {:.d$} ± {:.d$} ({:.0} spp) | {} | {} | {} | {} | {} | {} |",
            scene_slug(&r.scene),
            r.baseline_relmse,
            r.baseline_sd,
            r.baseline_spp,
            ratio(&r.pt),
            ratio(&r.guided),
            spp_times(r.guided.as_ref().map(|g| g.spp_ratio)),
            r.best
                .as_ref()
                .map_or("–".to_string(), |b| format!("`{}`", b.method)),
            ratio(&r.best),
            times(r.best.as_ref().map(|b| b.spp_ratio)),
        );
    }
    let s = &t.summary;
    let _ = writeln!(
        md,
        "| **geometric mean** ({} scenes) | | {} | **{}** | {} | per scene | **{}** | |",
        t.rows.len(),
        times(s.pt),
        times(s.guided),
        spp_times(s.guided_spp),
        times(s.best)
    );
    let _ = writeln!(
        md,
        "| **worst** | | | {} | {} | | {} | |\n",
        worst_md(&s.worst_guided, times),
        worst_md(&s.worst_guided_spp, spp_times),
        worst_md(&s.worst_best, times)
    );
    if let Some((m, g)) = &s.best_single {
        let _ = writeln!(
            md,
            "Best single guided method over these scenes: `{m}`, geometric mean {}.\n",
            times(Some(*g))
        );
    }
    for m in &t.missing {
        let _ = writeln!(md, "- not in the table: {m}");
    }
    if !t.missing.is_empty() {
        md.push('\n');
    }
}

/// The CSV rows of one table (per scene, then `geomean`, `worst` and `best_single`).
fn csv(t: &SuiteTable, out: &mut String) {
    let budget = format!("{},{}", t.budget.kind(), t.budget.value());
    let ratio = |r: &Option<MethodRatio>| csv_ratio(r.as_ref().map(|m| m.ratio));
    for r in &t.rows {
        let _ = writeln!(
            out,
            "{},{budget},{},{},{},{},{},{},{},{},{},{},",
            csv_field(&r.scene),
            r.seeds,
            csv_num(Some(r.baseline_relmse), None),
            csv_num(Some(r.baseline_sd), None),
            csv_num(Some(r.baseline_spp), Some(1)),
            ratio(&r.pt),
            ratio(&r.guided),
            csv_ratio(r.guided.as_ref().map(|g| g.spp_ratio)),
            r.best
                .as_ref()
                .map_or(String::new(), |b| csv_field(&b.method)),
            ratio(&r.best),
            csv_ratio(r.best.as_ref().map(|b| b.spp_ratio)),
        );
    }
    let s = &t.summary;
    let _ = writeln!(
        out,
        "geomean,{budget},,,,,{},{},{},,{},,{} scenes; best: per-scene best",
        csv_ratio(s.pt),
        csv_ratio(s.guided),
        csv_ratio(s.guided_spp),
        csv_ratio(s.best),
        t.rows.len()
    );
    let scene = |w: &Option<Worst>| w.as_ref().map_or("–".to_string(), |w| scene_slug(&w.scene));
    let _ = writeln!(
        out,
        "worst,{budget},,,,,,{},{},,{},,{}",
        csv_ratio(s.worst_guided.as_ref().map(|w| w.value)),
        csv_ratio(s.worst_guided_spp.as_ref().map(|w| w.value)),
        csv_ratio(s.worst_best.as_ref().map(|w| w.value)),
        csv_field(&format!(
            "guided: {}; guided spp: {}; best: {}",
            scene(&s.worst_guided),
            scene(&s.worst_guided_spp),
            scene(&s.worst_best)
        ))
    );
    if let Some((m, g)) = &s.best_single {
        let _ = writeln!(
            out,
            "best_single,{budget},,,,,,,,{},{},,lowest geometric mean over the scenes",
            csv_field(m),
            csv_ratio(Some(*g))
        );
    }
}

/// Writes `suite.md` and `suite.csv` into `opts.out`: one [`table`] per budget of `opts`, and
/// `notes` (scenes not found or skipped).
pub fn write(opts: &BenchOptions, records: &[RunRecord], notes: &[String]) -> Result<()> {
    let methods: Vec<String> = opts.methods.iter().map(|m| m.name.clone()).collect();
    let guided: Vec<String> = methods
        .iter()
        .filter(|m| is_guided_method(m))
        .map(|m| format!("`{m}`"))
        .collect();
    let mut md = String::from("# Benchmark suite\n\n");
    let _ = writeln!(
        md,
        "Equal time against `pt-nee`: ratio = relMSE(method) / relMSE(`pt-nee`) at the same \
         budget, each the mean over {} seed(s) first (below 1: better than `pt-nee`); relMSE \
         trimmed at 0.1 % against {}-spp `pt-nee` references unless given. `guided` is the \
         default command (`render --integrator guided`, the library's default guide and \
         target); best guided: the lowest ratio on that scene among {}. spp: the method's \
         samples per pixel over `pt-nee`'s (✓: at least {SPP_TARGET}×). Width {} px, {} render \
         thread(s) per run (0 = all cores). Every run: `runs.csv`, `report.md`.\n",
        opts.seeds,
        opts.reference_spp,
        if guided.is_empty() {
            "no guided method".to_string()
        } else {
            guided.join(", ")
        },
        opts.width,
        opts.threads
    );
    for n in notes {
        let _ = writeln!(md, "- note: {n}");
    }
    if !notes.is_empty() {
        md.push('\n');
    }
    let mut out = String::from(CSV_HEADER);
    out.push('\n');
    for &budget in &opts.budgets {
        let t = table(records, &opts.scenes, &methods, budget);
        markdown(&t, &mut md);
        csv(&t, &mut out);
    }
    write_file(&opts.out.join("suite.md"), &md)?;
    write_file(&opts.out.join("suite.csv"), &out)
}
