//! Where in the initial-state space a policy fails: the initial states'
//! object start positions, seen from above, coloured by success rate and by
//! dominant behaviour.

use super::draw::{
    caption_lines, colour_bar, colour_bar_width, draw_caption, draw_title, hue, sequential, Group,
    CAPTION_ROW, COLOUR_BAR_H, GREY, TITLE_H,
};
use super::scene::{self, world, View, ORIENTATION};
use super::{is_target, StartState};
use crate::plot::{esc, hex, legend, legend_size, text_width, LegendEntry, Shape};
use crate::TablesError;
use d3il_protocol::TaskId;
use plotters::prelude::*;
use std::collections::BTreeMap;

const PLOT_MAX: f64 = 360.0;
const PLOT_MIN: f64 = 220.0;
/// Height of a panel's heading above its chart.
const HEADING_H: u32 = 26;
const POINT_R: f64 = 5.0;
const MAX_LEGEND_BEHAVIOURS: usize = 30;
const NONE_SUCCEEDED: &str = "none succeeded";

/// Marker `k` of the objects: circle, triangle, square, repeating (the
/// legend's shapes).
fn marker(g: &mut Group, (x, y): (f64, f64), k: usize, fill: &str, attrs: &str) {
    let r = POINT_R;
    let extra = format!(r#" stroke-width="0.8"{attrs}"#);
    match legend_shape(k) {
        Shape::Circle => g.circle((x, y), r, fill, "white", &extra),
        Shape::Triangle => g.polygon(
            &[
                (x, y - 1.25 * r),
                (x - 1.15 * r, y + 0.75 * r),
                (x + 1.15 * r, y + 0.75 * r),
            ],
            fill,
            "white",
            &extra,
        ),
        Shape::Square => g.polygon(
            &[
                (x - r, y - r),
                (x + r, y - r),
                (x + r, y + r),
                (x - r, y + r),
            ],
            fill,
            "white",
            &extra,
        ),
    }
}

fn legend_shape(k: usize) -> Shape {
    match k % 3 {
        0 => Shape::Circle,
        1 => Shape::Triangle,
        _ => Shape::Square,
    }
}

/// The initial states (objects' start positions, from each context's
/// rollout-0 trace `start_objects`, skipping `target*`) as points, in two
/// panels side by side: coloured by success rate over that context's
/// rollouts (sequential colour map, darker is higher, with colour bar) and by
/// dominant behaviour among its successful rollouts (categorical, legend;
/// "none succeeded" grey). Shows where in the initial-state space a policy
/// fails. Robot at the bottom: world x up, world y to the left. Each object
/// has its own marker shape when there are several.
///
/// Nothing to place (no initial states, or a task without movable objects
/// such as Avoiding): the "no data" figure. A start position or success rate
/// that is not finite is an error naming the initial state.
pub fn start_map_svg(task: TaskId, contexts: &[StartState]) -> Result<String, TablesError> {
    let title = format!("{}: initial states", task.title());
    let mut names: Vec<&str> = Vec::new();
    // (context, object kind, xy, success rate, behaviour)
    let mut points: Vec<(&StartState, usize, [f64; 2])> = Vec::new();
    for c in contexts {
        if !(c.success_rate.is_finite() && (0.0..=1.0).contains(&c.success_rate)) {
            return Err(TablesError::BadTrace {
                rollout: format!("initial state {}", c.context_index),
                reason: format!("its success rate {} is not in [0, 1]", c.success_rate),
            });
        }
        for (name, p) in c.objects.iter().filter(|(n, _)| !is_target(n)) {
            if !(p[0].is_finite() && p[1].is_finite()) {
                return Err(TablesError::BadTrace {
                    rollout: format!("initial state {}", c.context_index),
                    reason: format!("field `start_objects` holds `{name}` at {p:?}"),
                });
            }
            let k = match names.iter().position(|n| n == name) {
                Some(k) => k,
                None => {
                    names.push(name);
                    names.len() - 1
                }
            };
            points.push((c, k, [p[0], p[1]]));
        }
    }
    if points.is_empty() {
        return Ok(super::no_data_svg(
            &title,
            if contexts.is_empty() {
                "No results yet: no initial state has a recorded trace."
            } else {
                "Every rollout of this task starts with the same objects (there are none to move), so there is no map of initial states."
            },
        ));
    }

    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for c in contexts {
        if let Some(b) = &c.dominant_behaviour {
            *counts.entry(b.as_str()).or_default() += 1;
        }
    }
    let mut behaviours: Vec<(&str, usize)> = counts.into_iter().collect();
    behaviours.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    let n = behaviours.len();
    let colour_of: BTreeMap<&str, RGBColor> = behaviours
        .iter()
        .enumerate()
        .map(|(i, (k, _))| (*k, hue(i, n)))
        .collect();
    let mut behaviour_entries: Vec<LegendEntry> = behaviours
        .iter()
        .take(MAX_LEGEND_BEHAVIOURS)
        .map(|(k, count)| LegendEntry {
            label: format!("{k} ({count})"),
            colour: colour_of[k],
            shape: Some(Shape::Circle),
            line: None,
        })
        .collect();
    if n > MAX_LEGEND_BEHAVIOURS {
        behaviour_entries.push(LegendEntry {
            label: format!("... and {} more behaviours", n - MAX_LEGEND_BEHAVIOURS),
            colour: WHITE,
            shape: None,
            line: None,
        });
    }
    let unsolved = contexts
        .iter()
        .filter(|c| c.dominant_behaviour.is_none())
        .count();
    if unsolved > 0 {
        behaviour_entries.push(LegendEntry {
            label: format!("{NONE_SUCCEEDED} ({unsolved})"),
            colour: GREY,
            shape: Some(Shape::Circle),
            line: None,
        });
    }
    const BEHAVIOUR_TITLE: &str = "Dominant behaviour (states)";
    let object_entries: Vec<LegendEntry> = if names.len() > 1 {
        names
            .iter()
            .enumerate()
            .map(|(k, name)| LegendEntry {
                label: name.to_string(),
                colour: RGBColor(0x55, 0x55, 0x55),
                shape: Some(legend_shape(k)),
                line: None,
            })
            .collect()
    } else {
        Vec::new()
    };
    const OBJECT_TITLE: &str = "Object";
    const BAR_TITLE: &str = "success rate";
    let bar_labels = [
        (0.0, "0".to_string()),
        (0.5, "0.5".to_string()),
        (1.0, "1".to_string()),
    ];
    let bar_texts: Vec<String> = bar_labels.iter().map(|b| b.1.clone()).collect();

    let (view, pw, ph) =
        View::fit(points.iter().map(|p| p.2), &[], 0.03, 0.12).fit_pixels(PLOT_MAX, PLOT_MIN);
    let (cw, ch) = scene::chart_size(pw, ph);
    let (bw, bh) = legend_size(Some(BEHAVIOUR_TITLE), &behaviour_entries);
    let (ow, oh) = if object_entries.is_empty() {
        (0.0, 0.0)
    } else {
        legend_size(Some(OBJECT_TITLE), &object_entries)
    };
    let column_w = bw.max(ow).max(colour_bar_width(BAR_TITLE, &bar_texts)) + 16.0;
    let width = (f64::from(2 * cw) + column_w)
        .max(text_width(&title, 18.0) + 40.0)
        .ceil();
    let mut paragraphs = vec![format!(
        "{ORIENTATION} Each point is where an object stood after the reset of one initial state ({} states; the start poses of its first rollout's trace). Left: the state's success rate over its rollouts, light (none succeeded) to dark (all did). Right: the behaviour most of its successful rollouts showed.",
        contexts.len()
    )];
    let outside = points.iter().filter(|p| !view.holds(p.2)).count();
    if outside > 0 {
        paragraphs.push(format!(
            "{outside} of {} object positions lie outside the drawn area and are cut off at its edge.",
            points.len()
        ));
    }
    let lines = caption_lines(&paragraphs, width - 20.0);
    let column_h =
        f64::from(TITLE_H + HEADING_H) + 8.0 + 20.0 + COLOUR_BAR_H + 12.0 + 4.0 + bh + 16.0 + oh;
    let top_h = f64::from(TITLE_H + HEADING_H + ch).max(column_h);
    let height = (top_h + 8.0 + CAPTION_ROW * lines.len() as f64 + 8.0).ceil();

    super::draw::figure(width, height, |root, layer, ov| {
        let headings = [
            ("success", "Success rate"),
            ("behaviour", "Dominant behaviour"),
        ];
        for (panel, (key, heading)) in headings.iter().enumerate() {
            let x0 = panel as u32 * cw;
            let area = root.clone().shrink((x0, TITLE_H + HEADING_H), (cw, ch));
            let f = scene::axes(&area, view)?;
            layer
                .group("panel-heading", &[("data-panel", key.to_string())])
                .text(
                    ((f.left + f.right) / 2.0, f64::from(TITLE_H) + 4.0),
                    14.0,
                    "middle",
                    heading,
                );
            scene::frame_group(layer, &f, view);
            let clip = layer.clip_to(&f);
            let g = layer.group("points", &[("data-panel", key.to_string()), clip]);
            for (c, k, p) in &points {
                let fill = if panel == 0 {
                    sequential(c.success_rate)
                } else {
                    c.dominant_behaviour
                        .as_deref()
                        .and_then(|b| colour_of.get(b).copied())
                        .unwrap_or(GREY)
                };
                let attrs = format!(
                    r#" data-context="{}" data-object="{}""#,
                    c.context_index,
                    esc(names[*k])
                );
                marker(g, world(&f, p[0], p[1]), *k, &hex(fill), &attrs);
            }
        }
        let column_x = f64::from(2 * cw) + 6.0;
        let mut y = colour_bar(
            layer,
            (column_x, f64::from(TITLE_H + HEADING_H) + 8.0),
            BAR_TITLE,
            &bar_labels,
        );
        y = legend(
            ov,
            (column_x, y + 4.0),
            Some(BEHAVIOUR_TITLE),
            &behaviour_entries,
        )
        .y1;
        if !object_entries.is_empty() {
            legend(
                ov,
                (column_x, y + 16.0),
                Some(OBJECT_TITLE),
                &object_entries,
            );
        }
        draw_caption(layer, (10.0, top_h + 8.0), &lines);
        draw_title(layer, width, &title);
        Ok(())
    })
}
