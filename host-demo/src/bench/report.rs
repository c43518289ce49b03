//! The benchmark's tables: `runs.csv`, `micro.csv` and `report.md`.

use super::micro::MicroResult;
use super::{scene_slug, BenchOptions, Budget, RunRecord};
use crate::error::{Error, Result};
use std::fmt::Write as _;
use std::path::Path;

/// Header of `runs.csv`.
pub const RUNS_HEADER: &str = "scene,method,seed,budget_kind,budget,spp,wall_s,tracing_s,inference_s,training_s,relmse,relmse_untrimmed,mape";

/// `s` as one CSV field (quoted when it holds a comma, a quote or a newline).
pub(super) fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Writes `text` to `path`, naming the path in the error.
pub(super) fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| Error::Bench(format!("{}: {e}", path.display())))
}

/// Mean and sample standard deviation (0 for one value).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 {
        v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (mean, var.sqrt())
}

/// The runs of `scene` / `method` / `budget`, in seed order.
pub fn select<'a>(
    records: &'a [RunRecord],
    scene: &str,
    method: &str,
    budget: Budget,
) -> Vec<&'a RunRecord> {
    records
        .iter()
        .filter(|r| r.scene == scene && r.method == method && r.budget == budget)
        .collect()
}

/// `30 s` or `64 spp`.
pub(super) fn budget_label(b: Budget) -> String {
    match b {
        Budget::Seconds(s) => format!("{s} s"),
        Budget::Spp(n) => format!("{n} spp"),
    }
}

/// Writes `runs.csv`, `micro.csv` and `report.md` into `opts.out`.
pub fn write_all(opts: &BenchOptions, records: &[RunRecord], micro: &[MicroResult]) -> Result<()> {
    let mut csv = String::from(RUNS_HEADER);
    csv.push('\n');
    for r in records {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.6e},{:.6e},{:.6e}",
            csv_field(&r.scene),
            csv_field(&r.method),
            r.seed,
            r.budget.kind(),
            r.budget.value(),
            r.spp,
            r.wall_s,
            r.tracing_s,
            r.inference_s,
            r.training_s,
            r.metrics.relmse,
            r.metrics.relmse_untrimmed,
            r.metrics.mape
        );
    }
    write(&opts.out.join("runs.csv"), &csv)?;

    let mut mcsv = String::from("group,name,value,unit,ratio,note\n");
    for m in micro {
        let _ = writeln!(
            mcsv,
            "{},{},{:.6},{},{},{}",
            m.group,
            csv_field(&m.name),
            m.value,
            csv_field(m.unit),
            m.ratio.map_or(String::new(), |r| format!("{r:.4}")),
            csv_field(&m.note)
        );
    }
    write(&opts.out.join("micro.csv"), &mcsv)?;

    let mut md = String::from("# Benchmark report\n\n");
    let _ = writeln!(
        md,
        "Width {} px, {} seed(s) per configuration, {} render thread(s) (0 = all cores), \
         references: {} spp `pt-nee` unless given. relMSE trimmed at 0.1 %, MAPE with ε = 0.01; \
         mean ± standard deviation over seeds. Speed-up = relMSE(`pt`) / relMSE(method) at the \
         same budget (> 1: better than `pt`).\n",
        opts.width, opts.seeds, opts.threads, opts.reference_spp
    );
    for scene in &opts.scenes {
        let _ = writeln!(md, "## {}\n", scene_slug(scene));
        let _ = writeln!(
            md,
            "| budget | method | spp | wall s | inference s | training s | relMSE | MAPE | speed-up vs pt |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|");
        for &budget in &opts.budgets {
            let pt = select(records, scene, "pt", budget);
            let pt_rel = (!pt.is_empty())
                .then(|| mean_std(&pt.iter().map(|r| r.metrics.relmse).collect::<Vec<_>>()).0);
            for method in &opts.methods {
                let runs = select(records, scene, &method.name, budget);
                if runs.is_empty() {
                    continue;
                }
                let col = |f: fn(&RunRecord) -> f64| {
                    mean_std(&runs.iter().map(|r| f(r)).collect::<Vec<_>>())
                };
                let (rel, rel_sd) = col(|r| r.metrics.relmse);
                let (mape, mape_sd) = col(|r| r.metrics.mape);
                let (spp, _) = col(|r| r.spp as f64);
                let (wall, _) = col(|r| r.wall_s);
                let (inf, _) = col(|r| r.inference_s);
                let (train, _) = col(|r| r.training_s);
                let speedup = pt_rel.map_or("–".to_string(), |p| format!("{:.2}×", p / rel));
                let _ = writeln!(
                    md,
                    "| {} | {} | {spp:.0} | {wall:.2} | {inf:.2} | {train:.2} | {rel:.4} ± {rel_sd:.4} | {mape:.4} ± {mape_sd:.4} | {speedup} |",
                    budget_label(budget),
                    method.name
                );
            }
        }
        let _ = writeln!(md, "\n![relMSE against time]({}.svg)\n", scene_slug(scene));
    }
    if !micro.is_empty() {
        let _ = writeln!(md, "## Micro-benchmarks\n");
        let _ = writeln!(md, "| group | name | value | unit | ratio | note |");
        let _ = writeln!(md, "|---|---|---|---|---|---|");
        for m in micro {
            let _ = writeln!(
                md,
                "| {} | {} | {:.4} | {} | {} | {} |",
                m.group,
                m.name,
                m.value,
                m.unit,
                m.ratio.map_or("–".to_string(), |r| format!("{r:.2}")),
                m.note
            );
        }
    }
    write(&opts.out.join("report.md"), &md)
}
