//! One rollout seen from above, and every rollout's TCP path of a submission
//! overlaid.

use super::draw::{
    self, caption_lines, colour_bar, colour_bar_width, draw_caption, draw_title, hue, sequential,
    Frame, Layer, CAPTION_ROW, COLOUR_BAR_H, GREY, MAX_POINTS, TITLE_H,
};
use super::scene::{self, world, View, ORIENTATION};
use super::{finite_prefix, is_target, rollout_name, unpack};
use crate::plot::{
    draw_labels, hex, legend, legend_size, place_labels, text_width, LegendEntry, Shape,
};
use crate::TablesError;
use d3il_protocol::{LandmarkKind, RolloutRecord, RolloutTrace, TaskId};
use plotters::prelude::*;
use std::collections::BTreeMap;

/// Colour steps along a path coloured by time.
const CHUNKS: usize = 32;
/// The longer side of a top-down plot, and the least of either side (px).
const PLOT_MAX: f64 = 540.0;
const PLOT_MIN: f64 = 260.0;
/// Legend entries beyond this are summarised in one line.
const MAX_LEGEND_BEHAVIOURS: usize = 30;
/// Rows of [`crate::plot::legend`] are this far apart (its layout).
const LEGEND_ROW: f64 = 18.0;
const LABEL_FONT: f64 = 11.0;

/// Seconds as a label: "7.35 s".
pub(super) fn seconds(s: f64) -> String {
    let t = if s >= 10.0 {
        format!("{s:.1}")
    } else {
        format!("{s:.2}")
    };
    format!("{t} s")
}

/// How the rollout ended, in words (older records have no `ending`).
pub(super) fn ending_text(task: TaskId, r: &RolloutRecord) -> String {
    let mut s = match (r.ending, &r.failure) {
        (Some(e), _) => e.describe().to_string(),
        (None, Some(_)) => "the simulation became unstable".to_string(),
        (None, None) if r.success => "succeeded (how it ended was not recorded)".to_string(),
        (None, None) => "did not succeed (how it ended was not recorded)".to_string(),
    };
    if r.success {
        s.push_str(&format!(
            "; behaviour {}",
            d3il_protocol::behaviour_name(task, &r.behaviour)
        ));
    }
    if let Some(f) = &r.failure {
        s.push_str(&format!("; at step {}: {}", f.step, f.message));
    }
    s
}

/// A path coloured by time: the states it holds are `pts` (state 0 first),
/// out of `states` in the rollout; at most [`MAX_POINTS`] are drawn, evenly
/// in time, as [`CHUNKS`] polylines that share their end points. Returns the
/// pixels of its first and last drawn point.
fn time_path(
    layer: &mut Layer,
    f: &Frame,
    class: &str,
    mut attrs: Vec<(&str, String)>,
    pts: &[[f64; 2]],
    states: usize,
    style: (f64, &str),
) -> Option<((f64, f64), (f64, f64))> {
    let idx = draw::even_indices(pts.len(), MAX_POINTS);
    let px: Vec<(f64, f64)> = idx
        .iter()
        .map(|&i| world(f, pts[i][0], pts[i][1]))
        .collect();
    attrs.push(("data-points", px.len().to_string()));
    attrs.push(("data-states", states.to_string()));
    let g = layer.group(class, &attrs);
    let last_state = (states.max(2) - 1) as f64;
    let segments = px.len().saturating_sub(1);
    let chunks = CHUNKS.min(segments);
    for c in 0..chunks {
        let (a, b) = (c * segments / chunks, (c + 1) * segments / chunks);
        let mid = (idx[a] + idx[b]) as f64 / 2.0;
        g.polyline(
            &px[a..=b],
            &hex(sequential(mid / last_state)),
            style.0,
            style.1,
        );
    }
    Some((*px.first()?, *px.last()?))
}

fn marks(
    layer: &mut Layer,
    name: &str,
    ends: ((f64, f64), (f64, f64)),
    clip: &(&'static str, String),
) {
    layer
        .group(
            "start-mark",
            &[("data-path", name.to_string()), clip.clone()],
        )
        .circle(
            ends.0,
            4.5,
            &hex(sequential(0.0)),
            "#222222",
            r#" stroke-width="1.2""#,
        );
    layer
        .group("end-mark", &[("data-path", name.to_string()), clip.clone()])
        .cross(ends.1, 4.5, "#222222", 2.0);
}

/// The legend column's width for these entries and colour bar labels.
fn column_width(
    entries: &[LegendEntry],
    title: Option<&str>,
    bar: Option<(&str, &[String])>,
) -> f64 {
    let (lw, _) = legend_size(title, entries);
    let bw = bar.map_or(0.0, |(t, l)| colour_bar_width(t, l));
    lw.max(bw) + 16.0
}

/// One rollout seen from above: table outline, landmarks (targets filled
/// light, obstacles grey), the TCP path and each object's path coloured by
/// time (a sequential colour map, light→dark, with a small colour bar
/// labelled in seconds), start marks (circle) and end marks (cross) per path,
/// a caption with task, initial state, rollout, steps and how it ended.
///
/// Robot at the bottom: world x points up, world y to the left. `target*`
/// objects are fixed targets and are drawn as targets, not as paths: as the
/// Target landmark of the same label when the trace has one, else as a
/// diamond at their position. A path stops at the first state that is not
/// finite (a simulation that became unstable) and the caption says so.
pub fn top_down_svg(
    task: TaskId,
    record: &RolloutRecord,
    trace: &RolloutTrace,
) -> Result<String, TablesError> {
    let who = rollout_name(record);
    let t = unpack(trace, &who)?;
    let steps = t.actions.len();
    let states = steps + 1;
    let (tcp, mut cut) = finite_prefix(&t.tcp);
    let tcp: Vec<[f64; 2]> = tcp.iter().map(|p| [p[0], p[1]]).collect();
    let mut moving: Vec<(&str, Vec<[f64; 2]>)> = Vec::new();
    let mut targets: Vec<(&str, [f64; 2])> = Vec::new();
    for (name, path) in &t.objects {
        let (p, c) = finite_prefix(path);
        if is_target(name) {
            // The evaluator draws a task's targets as landmarks too (same
            // label): those need no second mark.
            let drawn = trace
                .landmarks
                .iter()
                .any(|l| l.kind == LandmarkKind::Target && l.label == *name);
            if let (Some(first), false) = (p.first(), drawn) {
                targets.push((name, *first));
            }
        } else {
            cut = match (cut, c) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            moving.push((name, p));
        }
    }
    let all = tcp
        .iter()
        .chain(moving.iter().flat_map(|(_, p)| p))
        .copied()
        .chain(targets.iter().map(|t| t.1));
    let (view, pw, ph) = View::fit(all, &trace.landmarks, 0.04, 0.2).fit_pixels(PLOT_MAX, PLOT_MIN);
    let (cw, ch) = scene::chart_size(pw, ph);

    let mid = sequential(0.6);
    let mut entries = vec![LegendEntry {
        label: "TCP path".into(),
        colour: mid,
        shape: None,
        line: Some(false),
    }];
    if !moving.is_empty() {
        entries.push(LegendEntry {
            label: "object path".into(),
            colour: mid,
            shape: None,
            line: Some(true),
        });
    }
    entries.push(LegendEntry {
        label: "start".into(),
        colour: sequential(0.0),
        shape: Some(Shape::Circle),
        line: None,
    });
    let end_row = entries.len();
    entries.push(LegendEntry {
        label: "end".into(),
        colour: WHITE,
        shape: None,
        line: None,
    });
    entries.extend(scene::landmark_entries(
        &trace.landmarks,
        !targets.is_empty(),
    ));
    let duration = steps as f64 * task.step_seconds();
    let bar_labels = [
        (0.0, seconds(0.0)),
        (0.5, seconds(duration / 2.0)),
        (1.0, seconds(duration)),
    ];
    let bar_texts: Vec<String> = bar_labels.iter().map(|b| b.1.clone()).collect();
    const BAR_TITLE: &str = "time since reset";
    let title = format!("{}: {who}", task.title());
    let width = (f64::from(cw) + column_width(&entries, None, Some((BAR_TITLE, &bar_texts))))
        .max(text_width(&title, 18.0) + 40.0)
        .ceil();
    let mut paragraphs = vec![
        format!(
            "{} steps ({}); {}.",
            record.steps,
            seconds(record.steps as f64 * task.step_seconds()),
            ending_text(task, record)
        ),
        format!("{ORIENTATION} Paths are coloured by the time since the reset, light to dark."),
    ];
    if steps != record.steps {
        paragraphs.push(format!("The trace holds {steps} steps."));
    }
    if let Some(c) = cut {
        paragraphs.push(format!(
            "The paths stop at state {c}: from there the simulation state was not finite."
        ));
    }
    let outside: Vec<String> = std::iter::once(("the TCP", &tcp))
        .chain(moving.iter().map(|(n, p)| (*n, p)))
        .filter(|(_, p)| p.iter().any(|q| !view.holds(*q)))
        .map(|(n, _)| n.to_string())
        .collect();
    paragraphs.extend(scene::outside_note(&outside, outside.len()));
    let lines = caption_lines(&paragraphs, width - 20.0);
    let (_, lh) = legend_size(None, &entries);
    let column_h = 44.0 + lh + 16.0 + 20.0 + COLOUR_BAR_H + 12.0;
    let top_h = f64::from(TITLE_H + ch).max(column_h);
    let height = (top_h + 8.0 + CAPTION_ROW * lines.len() as f64 + 8.0).ceil();

    draw::figure(width, height, |root, layer, ov| {
        let area = root.clone().shrink((0, TITLE_H), (cw, ch));
        let f = scene::axes(&area, view)?;
        scene::frame_group(layer, &f, view);
        let clip = layer.clip_to(&f);
        scene::draw_landmarks(layer, &f, &trace.landmarks);
        for (name, at) in &targets {
            scene::draw_target_object(layer, &f, name, *at);
        }
        let mut ends = Vec::new();
        for (name, p) in &moving {
            let attrs = vec![("data-object", name.to_string()), clip.clone()];
            if let Some(e) = time_path(
                layer,
                &f,
                "object-path",
                attrs,
                p,
                states,
                (2.6, r#" stroke-dasharray="6 3""#),
            ) {
                ends.push((name.to_string(), e));
            }
        }
        if let Some(e) = time_path(
            layer,
            &f,
            "tcp-path",
            vec![clip.clone()],
            &tcp,
            states,
            (2.0, ""),
        ) {
            ends.push(("tcp".to_string(), e));
        }
        for (name, e) in &ends {
            marks(layer, name, *e, &clip);
        }
        // Names at the objects' starts and the targets.
        let mut anchors = Vec::new();
        let mut texts = Vec::new();
        for (name, e) in ends.iter().filter(|(n, _)| n != "tcp") {
            anchors.push(e.0);
            texts.push(name.clone());
        }
        for (name, at) in &targets {
            anchors.push(world(&f, at[0], at[1]));
            texts.push(name.to_string());
        }
        for l in trace
            .landmarks
            .iter()
            .filter(|l| l.kind == LandmarkKind::Target && !l.label.is_empty())
        {
            anchors.push(world(&f, l.center[0], l.center[1]));
            texts.push(l.label.clone());
        }
        let placed = place_labels(&anchors, &texts, LABEL_FONT, 7.0, f.rect());
        let colours = vec![RGBColor(0x55, 0x55, 0x55); anchors.len()];
        draw_labels(ov, &anchors, &texts, &colours, &placed, LABEL_FONT);

        let column_x = f64::from(cw) + 6.0;
        let frame = legend(ov, (column_x, f64::from(TITLE_H) + 8.0), None, &entries);
        let cy = frame.y0 + 5.0 + LEGEND_ROW * end_row as f64 + LEGEND_ROW / 2.0;
        ov.line(
            "legend",
            (column_x + 16.0, cy - 4.0),
            (column_x + 24.0, cy + 4.0),
            BLACK,
            2.0,
        );
        ov.line(
            "legend",
            (column_x + 16.0, cy + 4.0),
            (column_x + 24.0, cy - 4.0),
            BLACK,
            2.0,
        );
        colour_bar(layer, (column_x, frame.y1 + 16.0), BAR_TITLE, &bar_labels);
        draw_caption(layer, (10.0, top_h + 8.0), &lines);
        draw_title(layer, width, &title);
        Ok(())
    })
}

/// Every rollout's TCP path of one submission overlaid (the paper's figure
/// of Avoiding's diverse solutions, for every task), coloured by behaviour
/// (legend of behaviour labels via [`d3il_protocol::behaviour_name`], most
/// frequent first, colours as in the paper figures; failed rollouts thin
/// grey, drawn underneath), landmarks and table drawn once from the first
/// trace. Robot at the bottom: world x up, world y to the left. Paths are
/// simplified to within a third of a pixel (at most 400 points each). No
/// rollouts: the "no data" figure.
pub fn overlay_svg(
    task: TaskId,
    rollouts: &[(&RolloutRecord, &RolloutTrace)],
) -> Result<String, TablesError> {
    let title = format!("{}: TCP paths of {} rollouts", task.title(), rollouts.len());
    let Some(first) = rollouts.first() else {
        return Ok(super::no_data_svg(
            &title,
            "No rollout traces yet: evaluate a submission to see what its rollouts did.",
        ));
    };
    let landmarks = &first.1.landmarks;
    let mut paths: Vec<(&RolloutRecord, String, Vec<[f64; 2]>)> = Vec::new();
    for (r, trace) in rollouts {
        let t = unpack(trace, &rollout_name(r))?;
        let (p, _) = finite_prefix(&t.tcp);
        let label = d3il_protocol::behaviour_name(task, &r.behaviour);
        paths.push((r, label, p.iter().map(|q| [q[0], q[1]]).collect()));
    }
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for (r, label, _) in &paths {
        if r.success {
            *counts.entry(label.as_str()).or_default() += 1;
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
    let failed = paths.iter().filter(|p| !p.0.success).count();

    let mut entries: Vec<LegendEntry> = behaviours
        .iter()
        .take(MAX_LEGEND_BEHAVIOURS)
        .map(|(k, count)| LegendEntry {
            label: format!("{k} ({count})"),
            colour: colour_of[k],
            shape: None,
            line: Some(false),
        })
        .collect();
    if n > MAX_LEGEND_BEHAVIOURS {
        entries.push(LegendEntry {
            label: format!("... and {} more behaviours", n - MAX_LEGEND_BEHAVIOURS),
            colour: WHITE,
            shape: None,
            line: None,
        });
    }
    if failed > 0 {
        entries.push(LegendEntry {
            label: format!("failed ({failed})"),
            colour: GREY,
            shape: None,
            line: Some(false),
        });
    }
    entries.extend(scene::landmark_entries(landmarks, false));
    const LEGEND_TITLE: &str = "Behaviour (rollouts)";

    let all = paths.iter().flat_map(|p| p.2.iter().copied());
    let (view, pw, ph) = View::fit(all, landmarks, 0.04, 0.2).fit_pixels(PLOT_MAX, PLOT_MIN);
    let (cw, ch) = scene::chart_size(pw, ph);
    let width = (f64::from(cw) + column_width(&entries, Some(LEGEND_TITLE), None))
        .max(text_width(&title, 18.0) + 40.0)
        .ceil();
    let mut paragraphs = vec![format!(
        "{ORIENTATION} Each line is one rollout's TCP path, coloured by its behaviour when it succeeded; failed rollouts are thin grey. The table and landmarks are those of the first rollout's trace."
    )];
    let outside = paths
        .iter()
        .filter(|p| p.2.iter().any(|q| !view.holds(*q)))
        .count();
    if outside > 0 {
        let whose = format!("{outside} of {} rollouts", paths.len());
        paragraphs.extend(scene::outside_note(&[whose], outside));
    }
    let lines = caption_lines(&paragraphs, width - 20.0);
    let (_, lh) = legend_size(Some(LEGEND_TITLE), &entries);
    let top_h = f64::from(TITLE_H + ch).max(f64::from(TITLE_H) + 16.0 + lh);
    let height = (top_h + 8.0 + CAPTION_ROW * lines.len() as f64 + 8.0).ceil();

    draw::figure(width, height, |root, layer, ov| {
        let area = root.clone().shrink((0, TITLE_H), (cw, ch));
        let f = scene::axes(&area, view)?;
        scene::frame_group(layer, &f, view);
        let clip = layer.clip_to(&f);
        scene::draw_landmarks(layer, &f, landmarks);
        // Failed rollouts underneath, then the successful ones.
        for pass in [false, true] {
            for (r, label, p) in paths.iter().filter(|p| p.0.success == pass) {
                let px: Vec<(f64, f64)> = p.iter().map(|q| world(&f, q[0], q[1])).collect();
                let px = draw::simplify(&px, 0.33, MAX_POINTS);
                let class = if pass {
                    "rollout-path"
                } else {
                    "rollout-path failed"
                };
                let g = layer.group(
                    class,
                    &[
                        ("data-behaviour", label.clone()),
                        ("data-context", r.context_index.to_string()),
                        ("data-rollout", r.rollout_index.to_string()),
                        clip.clone(),
                    ],
                );
                if pass {
                    let c = colour_of.get(label.as_str()).copied().unwrap_or(BLACK);
                    g.polyline(&px, &hex(c), 1.4, r#" stroke-opacity="0.75""#);
                } else {
                    g.polyline(&px, &hex(GREY), 0.8, "");
                }
            }
        }
        legend(
            ov,
            (f64::from(cw) + 6.0, f64::from(TITLE_H) + 8.0),
            Some(LEGEND_TITLE),
            &entries,
        );
        draw_caption(layer, (10.0, top_h + 8.0), &lines);
        draw_title(layer, width, &title);
        Ok(())
    })
}
