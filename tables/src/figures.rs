//! Paper-style figures as SVG (plotters' SVG backend: text is written as
//! `<text>` elements and sized without fonts, so the output is the same on
//! every machine).
//!
//! The datasize and Pareto figures are drawn from the same table model as the
//! tables, so a figure never shows a number the table does not, with the same
//! panels and style as the server's figures ([`crate::panels`],
//! [`crate::plot`]).

use crate::caption::Style;
use crate::model::{build_table, Row, TableModel, Value};
use crate::panels::{fraction_panel, pareto_panel, shape, FractionLine, PlanePoint, FRONT};
use crate::plot::{canvas, legend, method_colour, pe, with_legend, Est, LegendEntry, Overlay};
use crate::{MethodInfo, SourceFilter, TableKind, TablesError};
use d3il_protocol::behaviour::avoiding;
use d3il_protocol::{behaviour_name, ObsType, ResultCell, Source, TaskId};
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

/// Colour `i` of `n` evenly spaced hues (HSL with s = 0.65, l = 0.45), for
/// behaviours (methods use [`method_colour`]): the paper figures' and the
/// rollout figures' (`rollouts::draw`).
pub(crate) fn hue(i: usize, n: usize) -> RGBColor {
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

/// The legend label of a row: method, paper marks and annotations.
fn row_label(r: &Row, annotate_source: bool) -> String {
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
    label
}

fn entries(rows: &[&Row], annotate_source: bool, lines: bool) -> Vec<LegendEntry> {
    rows.iter()
        .map(|r| {
            let evaluated = r.source == Source::Evaluated;
            LegendEntry {
                label: row_label(r, annotate_source),
                colour: method_colour(&r.method),
                shape: Some(shape(evaluated)),
                line: lines.then_some(evaluated),
            }
        })
        .collect()
}

/// Unique rows of a model in table order (a row appears in every block).
fn unique_rows(model: &TableModel) -> Vec<&Row> {
    let mut out: Vec<&Row> = Vec::new();
    for b in &model.blocks {
        for r in &b.rows {
            if !out.iter().any(|o| same_row(o, r)) {
                out.push(r);
            }
        }
    }
    out
}

fn same_row(a: &Row, b: &Row) -> bool {
    a.method == b.method && a.source == b.source && a.control == b.control
}

fn est(v: &Value) -> Est {
    Est::new(v.mean, v.std, v.n_seeds)
}

/// (success, entropy) of every row in every task: `[task][row]`, one entry
/// per data fraction.
type Grid = Vec<Vec<Vec<(f64, Est, Est)>>>;

fn grid(model: &TableModel, rows: &[&Row]) -> Grid {
    let tasks = &model.facts.tasks;
    let mut points: Grid = vec![vec![Vec::new(); rows.len()]; tasks.len()];
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
                    points[ti][ri].push((g.data_fraction, est(s), est(e)));
                }
            }
        }
    }
    for task in &mut points {
        for row in task {
            row.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
    }
    points
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

fn datasize(model: &TableModel) -> Result<String, TablesError> {
    let rows = unique_rows(model);
    let legend_rows = entries(&rows, model.annotate_source(), true);
    let tasks = model.facts.tasks.clone();
    let points = grid(model, &rows);
    let (panel_w, panel_h) = (420u32, 340u32);
    let plots_h = 40 + panel_h * tasks.len() as u32;
    let (width, height, legend_x) = with_legend((2 * panel_w, plots_h), None, &legend_rows);
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plots, _) = root.split_horizontally(2 * panel_w);
        let (plots, _) = plots.split_vertically(plots_h);
        let plots = plots
            .titled(
                &format!(
                    "Data size: {}-based policies ({} results)",
                    model.obs,
                    model.source.as_str()
                ),
                ("sans-serif", 18).into_font(),
            )
            .map_err(pe)?;
        let panels = plots.split_evenly((tasks.len(), 2));
        for (ti, task) in tasks.iter().enumerate() {
            for (pi, metric) in ["Success rate", "Entropy"].iter().enumerate() {
                let lines: Vec<FractionLine> = rows
                    .iter()
                    .zip(&points[ti])
                    .map(|(r, pts)| FractionLine {
                        method: r.method.clone(),
                        evaluated: r.source == Source::Evaluated,
                        points: pts
                            .iter()
                            .map(|&(f, s, e)| (f, if pi == 0 { s } else { e }))
                            .collect(),
                    })
                    .collect();
                fraction_panel(
                    &panels[2 * ti + pi],
                    &mut ov,
                    &format!("{task}: {metric}"),
                    metric,
                    &lines,
                )?;
            }
        }
        legend(&mut ov, (legend_x, 40.0), None, &legend_rows);
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

fn pareto(model: &TableModel) -> Result<String, TablesError> {
    let rows = unique_rows(model);
    let mut legend_rows = entries(&rows, model.annotate_source(), false);
    legend_rows.push(LegendEntry {
        label: "Pareto front".into(),
        colour: FRONT,
        shape: None,
        line: Some(true),
    });
    let tasks = model.facts.tasks.clone();
    let points = grid(model, &rows);
    let cols = 3usize.min(tasks.len()).max(1);
    let grid_rows = tasks.len().div_ceil(cols);
    let (panel_w, panel_h) = (380u32, 340u32);
    let plots_h = 40 + panel_h * grid_rows as u32;
    let (width, height, legend_x) =
        with_legend((cols as u32 * panel_w, plots_h), None, &legend_rows);
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plots, _) = root.split_horizontally(cols as u32 * panel_w);
        let (plots, _) = plots.split_vertically(plots_h);
        let plots = plots
            .titled(
                &format!(
                    "Success rate vs. entropy: {}-based policies ({} results), Pareto front dashed",
                    model.obs,
                    model.source.as_str()
                ),
                ("sans-serif", 18).into_font(),
            )
            .map_err(pe)?;
        let panels = plots.split_evenly((grid_rows, cols));
        for (ti, task) in tasks.iter().enumerate() {
            let pts: Vec<PlanePoint> = rows
                .iter()
                .zip(&points[ti])
                .filter_map(|(r, p)| {
                    let &(_, success, entropy) = p.first()?;
                    Some(PlanePoint {
                        label: r.method.clone(),
                        method: r.method.clone(),
                        evaluated: r.source == Source::Evaluated,
                        entropy,
                        success,
                    })
                })
                .collect();
            pareto_panel(&panels[ti], &mut ov, task.as_str(), &pts, true)?;
        }
        legend(&mut ov, (legend_x, 40.0), None, &legend_rows);
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

/// Legend entries beyond this are summarised in one line.
const MAX_LEGEND_BEHAVIOURS: usize = 30;

/// Draws Avoiding end-effector xy paths, one colour per behaviour (named as
/// everywhere, [`behaviour_name`]: the gap taken in each obstacle row), over
/// the obstacle field and finish line of the task definition
/// ([`avoiding::obstacles`]). Paths are clipped to the plotting area as in
/// every path plot (`crate::rollouts`), and a caption says how many rollouts
/// left it.
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
    // Behaviours by name, most frequent first (ties by name).
    let names: Vec<String> = paths
        .iter()
        .map(|(b, _)| behaviour_name(TaskId::Avoiding, b))
        .collect();
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for n in &names {
        *counts.entry(n.as_str()).or_default() += 1;
    }
    let mut behaviours: Vec<(&str, usize)> = counts.into_iter().collect();
    behaviours.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    let n = behaviours.len();
    let colour_of: BTreeMap<&str, RGBColor> = behaviours
        .iter()
        .enumerate()
        .map(|(i, (k, _))| (*k, hue(i, n)))
        .collect();

    let (x0, x1, y0, y1) = (0.2f64, 0.85f64, -0.35f64, 0.42f64);
    // Equal scale on both axes: 700 px per metre plus the label areas.
    let plot_w = ((x1 - x0) * 700.0) as u32 + 60;
    let plot_h = ((y1 - y0) * 700.0) as u32 + 50;
    let entries: Vec<LegendEntry> = behaviours
        .iter()
        .take(MAX_LEGEND_BEHAVIOURS)
        .map(|(k, count)| LegendEntry {
            label: format!("{k} ({count})"),
            colour: colour_of[k],
            shape: None,
            line: Some(false),
        })
        .chain((n > MAX_LEGEND_BEHAVIOURS).then(|| LegendEntry {
            label: format!("... and {} more behaviours", n - MAX_LEGEND_BEHAVIOURS),
            colour: WHITE,
            shape: None,
            line: None,
        }))
        .collect();
    const LEGEND_TITLE: &str = "Gap per obstacle row (from small x)";
    let outside = paths
        .iter()
        .filter(|(_, p)| {
            p.iter().any(|q| {
                let (x, y) = (f64::from(q[0]), f64::from(q[1]));
                x < x0 || x > x1 || y < y0 || y > y1
            })
        })
        .count();
    let whose: Vec<String> = (outside > 0)
        .then(|| format!("{outside} of {} rollouts", paths.len()))
        .into_iter()
        .collect();
    let note = crate::rollouts::outside_note_of(
        &whose,
        outside,
        "the obstacle field and a margin around it",
    );
    let lines = crate::rollouts::caption_lines(
        &note.into_iter().collect::<Vec<_>>(),
        f64::from(plot_w) - 20.0,
    );
    let caption_h = if lines.is_empty() {
        0
    } else {
        (crate::rollouts::CAPTION_ROW * lines.len() as f64 + 8.0).ceil() as u32
    };
    let (width, height, legend_x) = with_legend(
        (plot_w, plot_h + 40 + caption_h),
        Some(LEGEND_TITLE),
        &entries,
    );
    let mut layer = crate::rollouts::Layer::default();
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plot, _) = root.split_horizontally(plot_w);
        let (plot, _) = plot.split_vertically(plot_h + 40);
        let plot = plot
            .titled(title, ("sans-serif", 18).into_font())
            .map_err(pe)?;
        let mut chart = ChartBuilder::on(&plot)
            .margin(5)
            .x_label_area_size(44)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(pe)?;
        crate::plot::house_mesh(
            chart
                .configure_mesh()
                .x_desc("x (m)")
                .y_desc("y (m)")
                .x_label_formatter(&tick)
                .y_label_formatter(&tick),
        )
        .draw()
        .map_err(pe)?;
        let fy = avoiding::finish_y();
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(x0, fy), (x1, fy)],
                RGBColor(0x00, 0x9E, 0x73).stroke_width(2),
            )))
            .map_err(pe)?;
        chart
            .draw_series(avoiding::obstacles().iter().map(|o| {
                let pts: Vec<(f64, f64)> = (0..32)
                    .map(|i| {
                        let a = i as f64 / 32.0 * std::f64::consts::TAU;
                        (o.x + o.radius * a.cos(), o.y + o.radius * a.sin())
                    })
                    .collect();
                Polygon::new(pts, RGBColor(0x44, 0x44, 0x44).filled())
            }))
            .map_err(pe)?;
        let f = crate::rollouts::Frame::of(chart.plotting_area().get_pixel_range(), x0..x1, y0..y1);
        let clip = layer.clip_to(&f);
        for ((_, p), name) in paths.iter().zip(&names) {
            let colour = colour_of.get(name.as_str()).copied().unwrap_or(BLACK);
            let pts: Vec<(f64, f64)> = p
                .iter()
                .map(|q| f.px(f64::from(q[0]), f64::from(q[1])))
                .collect();
            layer
                .group(
                    "avoiding-path",
                    &[("data-behaviour", name.clone()), clip.clone()],
                )
                .polyline(
                    &pts,
                    &crate::plot::hex(colour),
                    1.0,
                    r#" stroke-opacity="0.7""#,
                );
        }
        // The start: where the recorded paths begin (one fixed start).
        if let Some(first) = paths.iter().find_map(|(_, p)| p.first()) {
            chart
                .draw_series(std::iter::once(Circle::new(
                    (first[0] as f64, first[1] as f64),
                    4,
                    BLACK.filled(),
                )))
                .map_err(pe)?;
        }
        crate::rollouts::draw_caption(&mut layer, (10.0, f64::from(plot_h + 40) + 4.0), &lines);
        legend(&mut ov, (legend_x, 40.0), Some(LEGEND_TITLE), &entries);
        Ok(())
    })?;
    Ok(layer.finish(buf, ov))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Paths that run off the obstacle field are cut at the plotting area
    /// (each path's group is clipped to a clip path of the area's rectangle)
    /// and the caption says how many rollouts left it; paths inside get no
    /// such note.
    #[test]
    fn avoiding_paths_are_clipped_to_the_plotting_area_and_the_caption_says_so() {
        let inside = vec![[0.5f32, 0.0], [0.55, 0.1], [0.6, 0.3]];
        let wild = vec![[0.5f32, 0.0], [1.4, 0.1], [1.6, -0.9]];
        let b = serde_json::json!(null);
        let svg = render_avoiding_paths(&[(b.clone(), inside.clone()), (b.clone(), wild)], "paths")
            .unwrap();
        let clip_id = svg
            .split("<clipPath id=\"")
            .nth(1)
            .and_then(|r| r.split('"').next())
            .expect("a clip path");
        let rect: Vec<f64> = svg
            .split(&format!("<clipPath id=\"{clip_id}\"><rect "))
            .nth(1)
            .unwrap()
            .split('"')
            .skip(1)
            .step_by(2)
            .take(4)
            .map(|v| v.parse().unwrap())
            .collect();
        let paths: Vec<&str> = svg.split("<g class=\"avoiding-path\"").skip(1).collect();
        assert_eq!(paths.len(), 2);
        for p in &paths {
            let open = p.split('>').next().unwrap();
            assert!(
                open.contains(&format!("clip-path=\"url(#{clip_id})\"")),
                "{open}"
            );
        }
        // The wild path's second point lies right of the clip rectangle: it
        // would be drawn over the legend without the clip.
        let wild_pts = paths[1].split("points=\"").nth(1).unwrap();
        let x: f64 = wild_pts
            .split(' ')
            .nth(1)
            .unwrap()
            .split(',')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(x > rect[0] + rect[2], "{x} {rect:?}");
        assert!(
            svg.contains("1 of 2 rollouts leave")
                || svg.contains("The path of 1 of 2 rollouts leaves"),
            "the caption names what left"
        );
        let calm = render_avoiding_paths(&[(b, inside)], "paths").unwrap();
        assert!(
            !calm.contains("cut off"),
            "no note when every path stays inside"
        );
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
