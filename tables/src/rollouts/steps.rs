//! The per-step signals of one rollout: its actions, the TCP speed and the
//! objects' distances to the targets, in stacked panels on one time axis.

use super::draw::{
    self, caption_lines, draw_caption, draw_title, envelope, hue, sequential, CAPTION_ROW,
    MAX_POINTS, TITLE_H, X_LABEL_AREA,
};
use super::top_down::{ending_text, seconds};
use super::{finite_prefix, is_target, rollout_name, unpack};
use crate::plot::{hex, legend, legend_size, text_width, LegendEntry};
use crate::TablesError;
use d3il_protocol::{LandmarkKind, RolloutRecord, RolloutTrace, TaskId};
use plotters::prelude::*;

/// Width of the chart areas, and the height of one panel's plot (px).
const CHART_W: u32 = 760;
const PANEL_PLOT_H: u32 = 86;
const PANEL_MARGIN: u32 = 7;
/// The heading band above each panel's chart.
const HEADING_H: u32 = 22;

struct Series {
    name: String,
    colour: RGBColor,
    /// (seconds, value), finite, in time order.
    pts: Vec<(f64, f64)>,
}

struct Panel {
    /// `data-panel`: `action-0`, `speed`, `distance`.
    key: String,
    heading: String,
    y_desc: String,
    /// Values that cannot be negative: the axis starts at 0.
    from_zero: bool,
    series: Vec<Series>,
}

/// The values up to the first one that is not finite.
fn finite_series(pts: impl Iterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    pts.take_while(|p| p.1.is_finite()).collect()
}

fn y_range(p: &Panel) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for s in &p.series {
        for &(_, v) in &s.pts {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if p.from_zero {
        lo = lo.min(0.0);
    }
    let span = hi - lo;
    let pad = if span < 1e-9 {
        (hi.abs() * 0.1).max(1e-3)
    } else {
        span * 0.08
    };
    let lo = if p.from_zero && lo >= 0.0 {
        0.0
    } else {
        lo - pad
    };
    (lo, hi + pad)
}

/// Per-step plots of one rollout, stacked panels sharing the time axis
/// (seconds): each action dimension (as the environment received it, at the
/// start of its step), the TCP speed (m/s, the 3-D distance between
/// consecutive TCP states over 35 ms, at the end of its step), and each
/// non-target object's distance in the table plane to the centre of its
/// nearest Target landmark or `target*` object, one line per object (the
/// panel is left out when there are no such objects or no targets). Series
/// stop at their first value that is not finite; long ones keep each stretch's
/// lowest and highest value (at most 400 points). A rollout without steps:
/// the "no data" figure.
pub fn step_plots_svg(
    task: TaskId,
    record: &RolloutRecord,
    trace: &RolloutTrace,
) -> Result<String, TablesError> {
    let who = rollout_name(record);
    let t = unpack(trace, &who)?;
    let steps = t.actions.len();
    let title = format!("{}: {who}, step by step", task.title());
    if steps == 0 {
        return Ok(super::no_data_svg(
            &title,
            "This rollout has no steps to plot.",
        ));
    }
    let dt = task.step_seconds();
    let duration = steps as f64 * dt;
    let line = sequential(0.8);
    let mut panels: Vec<Panel> = (0..t.act_dim)
        .map(|k| Panel {
            key: format!("action-{k}"),
            heading: format!("Action {k}"),
            y_desc: format!("a[{k}]"),
            from_zero: false,
            series: vec![Series {
                name: format!("action-{k}"),
                colour: line,
                pts: finite_series(
                    t.actions
                        .iter()
                        .enumerate()
                        .map(|(i, a)| (i as f64 * dt, f64::from(a[k]))),
                ),
            }],
        })
        .collect();
    let (tcp, _) = finite_prefix(&t.tcp);
    panels.push(Panel {
        key: "speed".into(),
        heading: "TCP speed (m/s)".into(),
        y_desc: "m/s".into(),
        from_zero: true,
        series: vec![Series {
            name: "speed".into(),
            colour: line,
            pts: tcp
                .windows(2)
                .enumerate()
                .map(|(i, w)| {
                    let d = (0..3).map(|j| (w[1][j] - w[0][j]).powi(2)).sum::<f64>();
                    ((i + 1) as f64 * dt, d.sqrt() / dt)
                })
                .collect(),
        }],
    });
    let mut targets: Vec<[f64; 2]> = trace
        .landmarks
        .iter()
        .filter(|l| l.kind == LandmarkKind::Target)
        .map(|l| l.center)
        .collect();
    let mut moving = Vec::new();
    for (name, path) in &t.objects {
        let (p, _) = finite_prefix(path);
        if is_target(name) {
            targets.extend(p.first().copied());
        } else {
            moving.push((name.as_str(), p));
        }
    }
    if !targets.is_empty() && !moving.is_empty() {
        let n = moving.len();
        let series = moving
            .iter()
            .enumerate()
            .map(|(i, (name, p))| Series {
                name: name.to_string(),
                colour: if n == 1 { line } else { hue(i, n) },
                pts: p
                    .iter()
                    .enumerate()
                    .map(|(j, q)| {
                        let d = targets
                            .iter()
                            .map(|c| (q[0] - c[0]).hypot(q[1] - c[1]))
                            .fold(f64::INFINITY, f64::min);
                        (j as f64 * dt, d)
                    })
                    .collect(),
            })
            .collect();
        panels.push(Panel {
            key: "distance".into(),
            heading:
                "Distance of each object to the nearest target's centre (m, in the table plane)"
                    .into(),
            y_desc: "m".into(),
            from_zero: true,
            series,
        });
    }
    let distance_entries: Vec<LegendEntry> = panels
        .iter()
        .filter(|p| p.key == "distance")
        .flat_map(|p| &p.series)
        .map(|s| LegendEntry {
            label: s.name.clone(),
            colour: s.colour,
            shape: None,
            line: Some(false),
        })
        .collect();
    const LEGEND_TITLE: &str = "Object";

    let heights: Vec<u32> = (0..panels.len())
        .map(|i| {
            let labels = if i + 1 == panels.len() {
                X_LABEL_AREA
            } else {
                0
            };
            PANEL_PLOT_H + 1 + 2 * PANEL_MARGIN + labels
        })
        .collect();
    let plots_h: u32 = heights.iter().map(|h| h + HEADING_H).sum();
    let column_w = if distance_entries.is_empty() {
        16.0
    } else {
        legend_size(Some(LEGEND_TITLE), &distance_entries).0 + 16.0
    };
    let width = (f64::from(CHART_W) + column_w)
        .max(text_width(&title, 18.0) + 40.0)
        .ceil();
    let paragraphs = vec![format!(
        "{} steps of 35 ms ({}); {}. Actions as the environment received them, at the start of their step; the TCP speed is the distance between consecutive TCP positions over 35 ms.",
        record.steps,
        seconds(record.steps as f64 * dt),
        ending_text(task, record)
    )];
    let lines = caption_lines(&paragraphs, width - 20.0);
    let top_h = f64::from(TITLE_H + plots_h);
    let height = (top_h + 8.0 + CAPTION_ROW * lines.len() as f64 + 8.0).ceil();

    draw::figure(width, height, |root, layer, ov| {
        let x_ticks = draw::tick(duration);
        let mut y = TITLE_H;
        for (i, (p, h)) in panels.iter().zip(&heights).enumerate() {
            let last = i + 1 == panels.len();
            let area = root.clone().shrink((0, y + HEADING_H), (CHART_W, *h));
            let (lo, hi) = y_range(p);
            let y_ticks = draw::tick(hi - lo);
            let f = draw::axes(
                &area,
                &draw::Axes {
                    u: 0.0..duration,
                    v: lo..hi,
                    x_desc: if last { "time since reset (s)" } else { "" },
                    y_desc: &p.y_desc,
                    x_ticks: &x_ticks,
                    y_ticks: &y_ticks,
                    x_labels: 10,
                    y_labels: 4,
                    x_label_area: if last { X_LABEL_AREA } else { 0 },
                    margin: PANEL_MARGIN,
                },
            )?;
            layer
                .group("panel-heading", &[("data-panel", p.key.clone())])
                .text((f.left, f64::from(y) + 5.0), 13.0, "start", &p.heading);
            let g = layer.group(
                "step-panel",
                &[
                    ("data-panel", p.key.clone()),
                    ("data-x-range", format!("0 {duration:.5}")),
                    ("data-y-range", format!("{lo:.6} {hi:.6}")),
                    ("data-px", f.px_attr()),
                ],
            );
            for s in &p.series {
                let px: Vec<(f64, f64)> = envelope(&s.pts, MAX_POINTS)
                    .into_iter()
                    .map(|(t, v)| f.px(t, v))
                    .collect();
                let extra = format!(r#" data-series="{}""#, crate::plot::esc(&s.name));
                g.polyline(&px, &hex(s.colour), 1.5, &extra);
            }
            if p.key == "distance" {
                legend(
                    ov,
                    (f64::from(CHART_W) + 6.0, f64::from(y + HEADING_H)),
                    Some(LEGEND_TITLE),
                    &distance_entries,
                );
            }
            y += HEADING_H + h;
        }
        draw_caption(layer, (10.0, top_h + 8.0), &lines);
        draw_title(layer, width, &title);
        Ok(())
    })
}
