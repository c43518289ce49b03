//! Error-against-time plots of the benchmark (`plotters`): one log-log chart per scene,
//! relMSE (mean over seeds) against mean wall time, one curve per method, as SVG and PNG.

use super::report::{mean_std, select};
use super::{scene_slug, Budget, RunRecord};
use crate::error::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Where the label font is looked for (Debian's `fonts-dejavu-core`).
pub const FONT_PATHS: [&str; 2] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

fn register_font() -> Result<()> {
    static FONT: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let bytes = FONT_PATHS
            .iter()
            .find_map(|p| std::fs::read(p).ok())
            .ok_or_else(|| {
                format!(
                    "no label font found at {FONT_PATHS:?} (install Debian's fonts-dejavu-core)"
                )
            })?;
        plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            Box::leak(bytes.into_boxed_slice()),
        )
        .map_err(|_| "the DejaVu font could not be parsed".to_string())
    })
    .clone()
    .map_err(Error::Bench)
}

/// One curve: method name and its (time, relMSE) points sorted by time.
type Curve = (String, Vec<(f64, f64)>);

fn curves(scene: &str, records: &[RunRecord]) -> Vec<Curve> {
    let mut methods: Vec<&str> = Vec::new();
    let mut budgets: Vec<Budget> = Vec::new();
    for r in records.iter().filter(|r| r.scene == scene) {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
        if !budgets.contains(&r.budget) {
            budgets.push(r.budget);
        }
    }
    methods
        .into_iter()
        .map(|m| {
            let mut pts: Vec<(f64, f64)> = budgets
                .iter()
                .filter_map(|&b| {
                    let runs = select(records, scene, m, b);
                    if runs.is_empty() {
                        return None;
                    }
                    let t = mean_std(&runs.iter().map(|r| r.wall_s).collect::<Vec<_>>()).0;
                    let e = mean_std(&runs.iter().map(|r| r.metrics.relmse).collect::<Vec<_>>()).0;
                    (t > 0.0 && e > 0.0).then_some((t, e))
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            (m.to_string(), pts)
        })
        .filter(|(_, p)| !p.is_empty())
        .collect()
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    curves: &[Curve],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| Error::Bench(format!("plot: {e:?}"));
    root.fill(&WHITE).map_err(err)?;
    let all = curves.iter().flat_map(|(_, p)| p.iter());
    let (mut t0, mut t1, mut e0, mut e1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(t, e) in all {
        (t0, t1, e0, e1) = (t0.min(t), t1.max(t), e0.min(e), e1.max(e));
    }
    if t0 > t1 {
        (t0, t1, e0, e1) = (1.0, 10.0, 0.01, 1.0);
    }
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(
            (t0 / 1.3..t1 * 1.3).log_scale(),
            (e0 / 1.5..e1 * 1.5).log_scale(),
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("wall time [s]")
        .y_desc("relMSE (trimmed 0.1 %)")
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&|v| format!("{v:.3}"))
        .y_label_formatter(&|v| format!("{v:.1e}"))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    for (i, (name, pts)) in curves.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .map_err(err)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// The plots' size in pixels.
const SIZE: (u32, u32) = (800, 560);

/// Writes `<slug>.svg` and `<slug>.png` for `scene` into `dir`.
pub fn error_vs_time(dir: &Path, scene: &str, records: &[RunRecord]) -> Result<()> {
    register_font()?;
    let slug = scene_slug(scene);
    let curves = curves(scene, records);
    let title = format!("{slug}: relMSE against time");
    let (svg, png) = (
        dir.join(format!("{slug}.svg")),
        dir.join(format!("{slug}.png")),
    );
    draw(
        SVGBackend::new(&svg, SIZE).into_drawing_area(),
        &title,
        &curves,
    )?;
    draw(
        BitMapBackend::new(&png, SIZE).into_drawing_area(),
        &title,
        &curves,
    )
}
