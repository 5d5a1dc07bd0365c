//! Paper-style figures as SVG (plotters' SVG backend: text is written as
//! `<text>` elements and sized without fonts, so the output is the same on
//! every machine).
//!
//! The datasize and Pareto figures are drawn from the same table model as the
//! tables, so a figure never shows a number the table does not.

use crate::caption::Style;
use crate::model::{build_table, Row, TableModel};
use crate::{MethodInfo, SourceFilter, TableKind, TablesError};
use d3il_protocol::paper::PAPER_METHOD_ORDER;
use d3il_protocol::{ObsType, ResultCell, Source};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// Which figure to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FigureKind {
    /// Success rate and entropy against the fraction of training data.
    Datasize,
    /// Success rate against conditional entropy per task, with the Pareto front.
    Pareto,
    /// End-effector paths of Avoiding rollouts coloured by behaviour
    /// ([`render_avoiding_paths`]).
    AvoidingPaths,
}

impl FigureKind {
    pub const ALL: [FigureKind; 3] = [
        FigureKind::Datasize,
        FigureKind::Pareto,
        FigureKind::AvoidingPaths,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            FigureKind::Datasize => "datasize",
            FigureKind::Pareto => "pareto",
            FigureKind::AvoidingPaths => "avoiding-paths",
        }
    }
}

impl fmt::Display for FigureKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for FigureKind {
    type Err = TablesError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.trim().to_ascii_lowercase().replace('_', "-");
        FigureKind::ALL
            .into_iter()
            .find(|k| k.as_str() == norm)
            .ok_or_else(|| TablesError::Unknown {
                what: "figure",
                value: s.to_string(),
                expected: "datasize, pareto, avoiding-paths",
            })
    }
}

fn pe<E: fmt::Display>(e: E) -> TablesError {
    TablesError::Plot(e.to_string())
}

/// Distinct, colour-blind-friendly colours for the paper's eleven methods
/// (in [`PAPER_METHOD_ORDER`]); further methods get hues from [`hue`].
const PALETTE: [RGBColor; 11] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0xe3, 0x77, 0xc2),
    RGBColor(0x7f, 0x7f, 0x7f),
    RGBColor(0xbc, 0xbd, 0x22),
    RGBColor(0x17, 0xbe, 0xcf),
    RGBColor(0x00, 0x00, 0x80),
];

/// Colour `i` of `n` evenly spaced hues (HSL with s = 0.65, l = 0.45).
fn hue(i: usize, n: usize) -> RGBColor {
    let h = (i as f64 / n.max(1) as f64) * 6.0;
    let (s, l) = (0.65, 0.45);
    let c = (1.0 - (2.0 * l - 1.0_f64).abs()) * s;
    let x = c * (1.0 - (h % 2.0 - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = l - c / 2.0;
    let to = |v: f64| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8;
    RGBColor(to(r), to(g), to(b))
}

/// One method row of a figure (a line or a set of points).
struct Series {
    label: String,
    colour: RGBColor,
    evaluated: bool,
}

fn series_for(rows: &[&Row], annotate_source: bool) -> Vec<Series> {
    let extra: Vec<&str> = {
        let mut v: Vec<&str> = rows
            .iter()
            .filter(|r| !r.in_paper)
            .map(|r| r.method.as_str())
            .collect();
        v.dedup();
        v
    };
    rows.iter()
        .map(|r| {
            let colour = match PAPER_METHOD_ORDER.iter().position(|m| *m == r.method) {
                Some(i) => PALETTE[i],
                None => {
                    let j = extra.iter().position(|m| *m == r.method).unwrap_or(0);
                    hue(j, extra.len())
                }
            };
            let mut label = r.method.clone();
            if r.dagger() {
                label.push_str(Style::Plain.dagger());
            }
            if r.ddagger() {
                label.push_str(Style::Plain.ddagger());
            }
            let ann = r.annotations(annotate_source);
            if !ann.is_empty() {
                label.push_str(&format!(" ({})", ann.join(", ")));
            }
            Series {
                label,
                colour,
                evaluated: r.source == Source::Evaluated,
            }
        })
        .collect()
}

/// Unique rows of a model in table order (a row appears in every block).
fn unique_rows(model: &TableModel) -> Vec<&Row> {
    let mut out: Vec<&Row> = Vec::new();
    for b in &model.blocks {
        for r in &b.rows {
            if !out
                .iter()
                .any(|o| o.method == r.method && o.source == r.source && o.control == r.control)
            {
                out.push(r);
            }
        }
    }
    out
}

fn same_row(a: &Row, b: &Row) -> bool {
    a.method == b.method && a.source == b.source && a.control == b.control
}

fn font(size: u32) -> TextStyle<'static> {
    ("sans-serif", size).into_font().color(&BLACK)
}

fn marker<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    s: &Series,
) -> Result<(), TablesError> {
    if s.evaluated {
        area.draw(&TriangleMarker::new(at, 5, s.colour.filled()))
            .map_err(pe)
    } else {
        area.draw(&Circle::new(at, 3, s.colour.filled()))
            .map_err(pe)
    }
}

/// A legend column: a line sample, the marker and the label per series.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    series: &[Series],
    with_lines: bool,
) -> Result<(), TablesError> {
    for (i, s) in series.iter().enumerate() {
        let y = 20 + 18 * i as i32;
        if with_lines {
            area.draw(&PathElement::new(
                vec![(8, y), (32, y)],
                s.colour.stroke_width(2),
            ))
            .map_err(pe)?;
        }
        marker(area, (20, y), s)?;
        area.draw(&Text::new(s.label.clone(), (40, y - 6), font(12)))
            .map_err(pe)?;
    }
    Ok(())
}

/// Draws the datasize or Pareto figure from result cells. `methods` gives the
/// properties of methods that are not in the paper (as for the tables).
pub fn render_figure(
    cells: &[ResultCell],
    kind: FigureKind,
    obs: ObsType,
    source: SourceFilter,
    methods: &BTreeMap<String, MethodInfo>,
) -> Result<String, TablesError> {
    match kind {
        FigureKind::Datasize => {
            let model = build_table(cells, TableKind::Datasize, obs, source, methods)?;
            datasize(&model)
        }
        FigureKind::Pareto => {
            let model = build_table(cells, TableKind::Main, obs, source, methods)?;
            pareto(&model)
        }
        FigureKind::AvoidingPaths => Err(TablesError::NoFigureData {
            figure: "avoiding-paths",
            hint: "it is drawn from the rollout paths of one submission, not from result cells: use render_avoiding_paths",
        }),
    }
}

const LEGEND_WIDTH: u32 = 260;

fn datasize(model: &TableModel) -> Result<String, TablesError> {
    let rows = unique_rows(model);
    let series = series_for(&rows, model.annotate_source());
    let tasks = model.facts.tasks.clone();
    // points[task][row] = [(fraction, success, entropy)]
    let mut points: Vec<Vec<Vec<(f64, f64, f64)>>> =
        vec![vec![Vec::new(); rows.len()]; tasks.len()];
    for b in &model.blocks {
        for r in &b.rows {
            let Some(ri) = rows.iter().position(|o| same_row(o, r)) else {
                continue;
            };
            for (g, vals) in b.groups.iter().zip(&r.values) {
                let Some(ti) = tasks.iter().position(|t| *t == g.task) else {
                    continue;
                };
                if let (Some(Some(s)), Some(Some(e))) = (vals.first(), vals.get(1)) {
                    points[ti][ri].push((g.data_fraction, s.mean, e.mean));
                }
            }
        }
    }
    let (panel_w, panel_h) = (420u32, 340u32);
    let width = 2 * panel_w + LEGEND_WIDTH;
    let height = 40 + panel_h * tasks.len() as u32;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let root = root
            .titled(
                &format!(
                    "Data size: {}-based policies ({} results)",
                    model.obs,
                    model.source.as_str()
                ),
                font(18),
            )
            .map_err(pe)?;
        let (plots, legend) = root.split_horizontally(2 * panel_w);
        let panels = plots.split_evenly((tasks.len(), 2));
        for (ti, task) in tasks.iter().enumerate() {
            for (pi, metric) in ["Success rate", "Entropy"].iter().enumerate() {
                let area = &panels[2 * ti + pi];
                let mut chart = ChartBuilder::on(area)
                    .caption(format!("{task}: {metric}"), font(14))
                    .margin(12)
                    .x_label_area_size(36)
                    .y_label_area_size(44)
                    .build_cartesian_2d(0.0f64..1.05f64, 0.0f64..1.0f64)
                    .map_err(pe)?;
                chart
                    .configure_mesh()
                    .x_desc("Fraction of demonstrations")
                    .y_desc(*metric)
                    .x_labels(6)
                    .y_labels(6)
                    .label_style(font(11))
                    .light_line_style(RGBColor(235, 235, 235))
                    .draw()
                    .map_err(pe)?;
                for (ri, s) in series.iter().enumerate() {
                    let pts: Vec<(f64, f64)> = points[ti][ri]
                        .iter()
                        .map(|&(f, sr, en)| (f, if pi == 0 { sr } else { en }))
                        .collect();
                    if pts.is_empty() {
                        continue;
                    }
                    if s.evaluated {
                        chart
                            .draw_series(DashedLineSeries::new(
                                pts.clone(),
                                6,
                                4,
                                s.colour.stroke_width(2),
                            ))
                            .map_err(pe)?;
                        chart
                            .draw_series(
                                pts.iter()
                                    .map(|&p| TriangleMarker::new(p, 5, s.colour.filled())),
                            )
                            .map_err(pe)?;
                    } else {
                        chart
                            .draw_series(LineSeries::new(pts.clone(), s.colour.stroke_width(2)))
                            .map_err(pe)?;
                        chart
                            .draw_series(pts.iter().map(|&p| Circle::new(p, 3, s.colour.filled())))
                            .map_err(pe)?;
                    }
                }
            }
        }
        draw_legend(&legend, &series, true)?;
        root.present().map_err(pe)?;
    }
    Ok(buf)
}

/// Points not dominated in (entropy, success): no other point is at least as
/// good in both and better in one. Sorted by entropy. Points without a finite
/// entropy and success rate are never on the front (nor drawn).
pub(crate) fn pareto_front(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let finite: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(e, s)| e.is_finite() && s.is_finite())
        .collect();
    let points = &finite;
    let mut front: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(e, s)| {
            !points
                .iter()
                .any(|&(e2, s2)| e2 >= e && s2 >= s && (e2 > e || s2 > s))
        })
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.total_cmp(&a.1)));
    front.dedup();
    front
}

fn pareto(model: &TableModel) -> Result<String, TablesError> {
    let rows = unique_rows(model);
    let series = series_for(&rows, model.annotate_source());
    let tasks = model.facts.tasks.clone();
    let mut points: Vec<Vec<Option<(f64, f64)>>> = vec![vec![None; rows.len()]; tasks.len()];
    for b in &model.blocks {
        for r in &b.rows {
            let Some(ri) = rows.iter().position(|o| same_row(o, r)) else {
                continue;
            };
            for (g, vals) in b.groups.iter().zip(&r.values) {
                let Some(ti) = tasks.iter().position(|t| *t == g.task) else {
                    continue;
                };
                if let (Some(Some(s)), Some(Some(e))) = (vals.first(), vals.get(1)) {
                    points[ti][ri] = Some((e.mean, s.mean));
                }
            }
        }
    }
    let cols = 3usize.min(tasks.len()).max(1);
    let grid_rows = tasks.len().div_ceil(cols);
    let (panel_w, panel_h) = (330u32, 300u32);
    let width = cols as u32 * panel_w + LEGEND_WIDTH;
    let height = 40 + panel_h * grid_rows as u32;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let root = root
            .titled(
                &format!(
                    "Success rate vs. entropy: {}-based policies ({} results), Pareto front dashed",
                    model.obs,
                    model.source.as_str()
                ),
                font(18),
            )
            .map_err(pe)?;
        let (plots, legend) = root.split_horizontally(cols as u32 * panel_w);
        let panels = plots.split_evenly((grid_rows, cols));
        for (ti, task) in tasks.iter().enumerate() {
            let mut chart = ChartBuilder::on(&panels[ti])
                .caption(task.as_str(), font(14))
                .margin(12)
                .x_label_area_size(36)
                .y_label_area_size(44)
                .build_cartesian_2d(0.0f64..1.0f64, 0.0f64..1.0f64)
                .map_err(pe)?;
            chart
                .configure_mesh()
                .x_desc("Entropy")
                .y_desc("Success rate")
                .x_labels(6)
                .y_labels(6)
                .label_style(font(11))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(pe)?;
            let all: Vec<(f64, f64)> = points[ti].iter().flatten().copied().collect();
            let front = pareto_front(&all);
            if front.len() > 1 {
                chart
                    .draw_series(DashedLineSeries::new(front, 5, 4, BLACK.stroke_width(1)))
                    .map_err(pe)?;
            }
            for (ri, s) in series.iter().enumerate() {
                let Some(p) = points[ti][ri] else { continue };
                if s.evaluated {
                    chart
                        .draw_series(std::iter::once(TriangleMarker::new(
                            p,
                            6,
                            s.colour.filled(),
                        )))
                        .map_err(pe)?;
                } else {
                    chart
                        .draw_series(std::iter::once(Circle::new(p, 4, s.colour.filled())))
                        .map_err(pe)?;
                }
            }
        }
        draw_legend(&legend, &series, false)?;
        root.present().map_err(pe)?;
    }
    Ok(buf)
}

/// Axis tick text with one decimal and no `-0.0`.
fn tick(v: &f64) -> String {
    let s = format!("{v:.1}");
    if s == "-0.0" {
        "0.0".to_string()
    } else {
        s
    }
}

/// Avoiding obstacles (docs/original-d3il.md §10.2.1): centre (x, y) and radius.
const AVOIDING_OBSTACLES: [(f64, f64, f64); 6] = [
    (0.5, -0.1, 0.03),
    (0.425, 0.08, 0.025),
    (0.575, 0.08, 0.025),
    (0.35, 0.26, 0.025),
    (0.5, 0.26, 0.025),
    (0.65, 0.26, 0.025),
];
/// Success line y = 0.35 and the fixed start (docs/original-d3il.md §10.2.2, §10.2.5).
const AVOIDING_FINISH_Y: f64 = 0.35;
const AVOIDING_START: (f64, f64) = (0.525, -0.28);
/// Legend entries beyond this are summarised in one line.
const MAX_LEGEND_BEHAVIOURS: usize = 30;

/// Draws Avoiding end-effector xy paths, one colour per behaviour label (the
/// reference encoding, compared as compact JSON), over the obstacle field.
pub fn render_avoiding_paths(
    paths: &[(serde_json::Value, Vec<[f32; 2]>)],
    title: &str,
) -> Result<String, TablesError> {
    if paths.iter().all(|(_, p)| p.is_empty()) {
        return Err(TablesError::NoFigureData {
            figure: "avoiding-paths",
            hint: "no rollout path was recorded: evaluate an Avoiding submission (paths are kept for Avoiding only)",
        });
    }
    for (_, p) in paths {
        if let Some(bad) = p.iter().find(|q| !q[0].is_finite() || !q[1].is_finite()) {
            return Err(TablesError::NonFinite {
                method: title.to_string(),
                task: "Avoiding (T1)".to_string(),
                what: "path point",
                value: if bad[0].is_finite() { bad[1] } else { bad[0] } as f64,
            });
        }
    }
    // Behaviours in a stable order: numeric codes (Avoiding's mode code)
    // numerically, anything else by its compact JSON, which is deterministic.
    let mut counts: BTreeMap<String, (usize, Option<f64>)> = BTreeMap::new();
    for (b, _) in paths {
        counts.entry(b.to_string()).or_insert((0, b.as_f64())).0 += 1;
    }
    let mut behaviours: Vec<(String, usize, Option<f64>)> = counts
        .into_iter()
        .map(|(k, (c, num))| (k, c, num))
        .collect();
    behaviours.sort_by(|a, b| match (a.2, b.2) {
        (Some(x), Some(y)) => x.total_cmp(&y).then_with(|| a.0.cmp(&b.0)),
        (Some(_), None) => std::cmp::Ordering::Less,
        (None, Some(_)) => std::cmp::Ordering::Greater,
        (None, None) => a.0.cmp(&b.0),
    });
    let n = behaviours.len();
    let colour_of: BTreeMap<&str, RGBColor> = behaviours
        .iter()
        .enumerate()
        .map(|(i, (k, _, _))| (k.as_str(), hue(i, n)))
        .collect();

    let (x0, x1, y0, y1) = (0.2f64, 0.85f64, -0.35f64, 0.42f64);
    // Equal scale on both axes: 700 px per metre plus the label areas.
    let plot_w = ((x1 - x0) * 700.0) as u32 + 60;
    let plot_h = ((y1 - y0) * 700.0) as u32 + 50;
    let width = plot_w + LEGEND_WIDTH;
    let height = plot_h + 40;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let root = root.titled(title, font(18)).map_err(pe)?;
        let (plot, legend) = root.split_horizontally(plot_w);
        let mut chart = ChartBuilder::on(&plot)
            .margin(5)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(pe)?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .label_style(font(11))
            .light_line_style(RGBColor(240, 240, 240))
            .draw()
            .map_err(pe)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x0, AVOIDING_FINISH_Y), (x1, AVOIDING_FINISH_Y)],
                GREEN.stroke_width(2),
            )))
            .map_err(pe)?;
        chart
            .draw_series(AVOIDING_OBSTACLES.iter().map(|&(cx, cy, r)| {
                let pts: Vec<(f64, f64)> = (0..32)
                    .map(|i| {
                        let a = i as f64 / 32.0 * std::f64::consts::TAU;
                        (cx + r * a.cos(), cy + r * a.sin())
                    })
                    .collect();
                Polygon::new(pts, RED.mix(0.8).filled())
            }))
            .map_err(pe)?;
        for (b, p) in paths {
            let colour = colour_of
                .get(b.to_string().as_str())
                .copied()
                .unwrap_or(BLACK);
            let pts: Vec<(f64, f64)> = p.iter().map(|q| (q[0] as f64, q[1] as f64)).collect();
            chart
                .draw_series(LineSeries::new(pts, colour.mix(0.7).stroke_width(1)))
                .map_err(pe)?;
        }
        chart
            .draw_series(std::iter::once(Circle::new(
                AVOIDING_START,
                4,
                BLACK.filled(),
            )))
            .map_err(pe)?;

        let entries: Vec<Series> = behaviours
            .iter()
            .take(MAX_LEGEND_BEHAVIOURS)
            .map(|(k, count, _)| Series {
                label: format!("{k} ({count})"),
                colour: colour_of[k.as_str()],
                evaluated: false,
            })
            .collect();
        draw_legend(&legend, &entries, true)?;
        if n > MAX_LEGEND_BEHAVIOURS {
            let y = 20 + 18 * MAX_LEGEND_BEHAVIOURS as i32;
            legend
                .draw(&Text::new(
                    format!("... and {} more behaviours", n - MAX_LEGEND_BEHAVIOURS),
                    (8, y - 6),
                    font(12),
                ))
                .map_err(pe)?;
        }
        root.present().map_err(pe)?;
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [
            (0.1, 0.9),
            (0.5, 0.5),
            (0.4, 0.4),
            (0.9, 0.1),
            (0.5, 0.5),
            (0.2, 0.2),
        ];
        assert_eq!(pareto_front(&pts), vec![(0.1, 0.9), (0.5, 0.5), (0.9, 0.1)]);
    }

    #[test]
    fn hues_are_distinct() {
        let cs: Vec<RGBColor> = (0..24).map(|i| hue(i, 24)).collect();
        for i in 0..cs.len() {
            for j in i + 1..cs.len() {
                assert_ne!(cs[i], cs[j]);
            }
        }
    }
}
