//! The pictures of what rollouts did (`d3il_tables::rollouts`), checked on
//! their SVG geometry with traces recorded through the protocol's own
//! `TraceBuilder`: the top-down view maps the recorded positions to the
//! right pixels in the one orientation (robot at the bottom, x up, y to the
//! left), draws every path with its marks and the landmarks, and targets as
//! targets; the overlay has one path per rollout with its behaviour and a
//! legend entry per behaviour; the start map has one point per initial state
//! in each panel, darker for higher success; the step plots have one panel per
//! action dimension, the TCP speed and the distances, with the recorded
//! values; corrupt traces are refused by name.

use crate::support;
use crate::svg_geometry;

use d3il_protocol::rollout::{pack_f32, TraceBuilder};
use d3il_protocol::{
    ContextResult, Ending, Estimate, EvalResult, Metrics, ObsType, ProtocolKind, ProtocolManifest,
    RolloutRecord, RolloutTrace, TaskId,
};
use d3il_tables::board::behaviour_label;
use d3il_tables::rollouts::{
    no_data_svg, overlay_svg, start_map_svg, start_states, step_plots_svg, top_down_svg, StartState,
};
use roxmltree::{Document, Node};
use serde_json::json;
use support::*;
use svg_geometry::{assert_readable, parse};

// ---- the top-down view -----------------------------------------------------

#[test]
fn one_rollout_from_above_maps_its_paths_marks_and_landmarks() {
    let steps = 120;
    let t = trace(steps, 3, true);
    let r = record(2, 5, true, json!(1), steps);
    let svg = top_down_svg(TaskId::Aligning, &r, &t).expect("drawn");
    dump("rollout-top-down", &svg);
    assert_readable(&svg, "top-down view");
    let doc = Document::parse(&svg).expect("well-formed");
    let frame = TopDown::read(&groups(&doc, "top-down-frame")[0]);
    let (sx, sy) = frame.scale();
    assert!(
        (sx - sy).abs() / sx < 0.01,
        "one scale for both axes: {sx} vs {sy}"
    );

    // The TCP path: one point per state, first and last where recorded.
    let tcp = groups(&doc, "tcp-path");
    assert_eq!(tcp.len(), 1);
    assert_eq!(tcp[0].attribute("data-points"), Some("121"));
    assert_eq!(tcp[0].attribute("data-states"), Some("121"));
    let pts = path_points(&tcp[0]);
    assert_eq!(pts.len(), steps + 1);
    for (i, p) in pts.iter().enumerate() {
        assert!(
            close(frame.world(*p), tcp_at(i, steps), 1e-3),
            "state {i}: {p:?}"
        );
    }
    // Robot at the bottom: the TCP moves away (up) and to the left.
    let (first, last) = (pts[0], pts[steps]);
    assert!(
        last.1 < first.1 - 50.0 && last.0 < first.0 - 50.0,
        "{first:?} -> {last:?}"
    );
    // Coloured by time, light to dark.
    let strokes: Vec<&str> = tcp[0]
        .children()
        .filter(|c| c.has_tag_name("polyline"))
        .map(|c| c.attribute("stroke").expect("stroke"))
        .collect();
    assert!(strokes.len() > 10);
    assert!(luminance(strokes[0]) > luminance(strokes[strokes.len() - 1]) + 80.0);

    // The box's path; the fixed target is a target, not a path.
    let objects = groups(&doc, "object-path");
    let names: Vec<&str> = objects
        .iter()
        .filter_map(|g| g.attribute("data-object"))
        .collect();
    assert_eq!(names, ["push_box"]);
    let box_pts = path_points(&objects[0]);
    assert_eq!(box_pts.len(), steps + 1);
    assert!(close(frame.world(box_pts[0]), box_at(0, steps), 1e-3));
    assert!(close(
        frame.world(box_pts[steps]),
        box_at(steps, steps),
        1e-3
    ));
    let targets = groups(&doc, "landmark target");
    let labels: Vec<(Option<&str>, Option<&str>)> = targets
        .iter()
        .map(|g| (g.attribute("data-label"), g.attribute("data-object")))
        .collect();
    assert_eq!(labels, [(Some("goal"), None), (None, Some("target_box"))]);
    assert_eq!(groups(&doc, "landmark obstacle").len(), 1);
    assert_eq!(groups(&doc, "landmark table").len(), 1);
    let post = groups(&doc, "landmark obstacle")[0]
        .children()
        .find(|c| c.has_tag_name("circle"))
        .expect("a round obstacle is a circle");
    let (cx, cy) = (
        post.attribute("cx").unwrap().parse::<f64>().unwrap(),
        post.attribute("cy").unwrap().parse::<f64>().unwrap(),
    );
    assert!(close(frame.world((cx, cy)), [0.42, 0.15, 0.0], 1e-3));

    // A start (circle) and an end (cross) per path, at its ends.
    let starts = groups(&doc, "start-mark");
    let ends = groups(&doc, "end-mark");
    assert_eq!(starts.len(), 2);
    assert_eq!(ends.len(), 2);
    let tcp_start = starts
        .iter()
        .find(|g| g.attribute("data-path") == Some("tcp"))
        .and_then(|g| g.children().find(|c| c.has_tag_name("circle")))
        .expect("TCP start circle");
    let at = (
        tcp_start.attribute("cx").unwrap().parse::<f64>().unwrap(),
        tcp_start.attribute("cy").unwrap().parse::<f64>().unwrap(),
    );
    assert!(close(frame.world(at), tcp_at(0, steps), 1e-3));
    let tcp_end = ends
        .iter()
        .find(|g| g.attribute("data-path") == Some("tcp"))
        .expect("TCP end");
    assert_eq!(
        tcp_end
            .children()
            .filter(|c| c.has_tag_name("line"))
            .count(),
        2
    );

    let words = texts(&doc);
    for needed in [
        "Aligning (T2): initial state 2, rollout 5",
        "120 steps (4.20 s)",
        Ending::TaskSuccess.describe(),
        "robot at the bottom",
        "4.20 s",
        "time since reset",
        "push_box",
    ] {
        assert!(words.contains(needed), "{needed:?} missing from\n{words}");
    }
    assert_eq!(
        top_down_svg(TaskId::Aligning, &r, &t).unwrap(),
        svg,
        "deterministic"
    );
}

#[test]
fn long_rollouts_are_thinned_to_400_points_keeping_both_ends() {
    let steps = 1500;
    let t = trace(steps, 3, true);
    let r = record(0, 0, false, json!(null), steps);
    let svg = top_down_svg(TaskId::Aligning, &r, &t).expect("drawn");
    assert!(svg.len() < 120_000, "{} bytes", svg.len());
    let doc = Document::parse(&svg).unwrap();
    let frame = TopDown::read(&groups(&doc, "top-down-frame")[0]);
    for class in ["tcp-path", "object-path"] {
        let g = groups(&doc, class)[0];
        let pts = path_points(&g);
        let n: usize = g.attribute("data-points").unwrap().parse().unwrap();
        assert_eq!(pts.len(), n);
        assert!(n <= 400 && n > 300, "{class}: {n} points");
        assert_eq!(g.attribute("data-states"), Some("1501"));
    }
    let pts = path_points(&groups(&doc, "tcp-path")[0]);
    assert!(close(frame.world(pts[0]), tcp_at(0, steps), 1e-3));
    assert!(close(
        frame.world(*pts.last().unwrap()),
        tcp_at(steps, steps),
        1e-3
    ));
    assert!(texts(&doc).contains(Ending::TimeLimit.describe()));
}

#[test]
fn an_unstable_rollout_is_drawn_up_to_its_last_finite_state() {
    let steps = 100;
    let mut b = TraceBuilder::start(2, tcp_at(0, steps), vec![], scene());
    for i in 0..steps {
        let tcp = if i >= 49 {
            [f64::NAN; 3]
        } else {
            tcp_at(i + 1, steps)
        };
        b.push_step(&[0.0, 0.0], 0, tcp, &[]);
    }
    let t = b.finish(vec![]);
    let mut r = record(0, 3, false, json!(null), steps);
    r.ending = Some(Ending::SimUnstable);
    let svg = top_down_svg(TaskId::Avoiding, &r, &t).expect("drawn");
    let doc = Document::parse(&svg).unwrap();
    assert_eq!(path_points(&groups(&doc, "tcp-path")[0]).len(), 50);
    assert!(texts(&doc).contains("stop at state 50"), "{}", texts(&doc));
    step_plots_svg(TaskId::Avoiding, &r, &t).expect("step plots of an unstable rollout");
}

// ---- every rollout overlaid ------------------------------------------------

#[test]
fn the_overlay_draws_one_path_per_rollout_coloured_by_behaviour() {
    // Sorting-2: 64 is "RB", 128 is "BR"; two rollouts failed.
    let plan = [
        (true, 64),
        (true, 128),
        (true, 64),
        (false, 0),
        (true, 64),
        (true, 128),
        (false, 192),
    ];
    let traces: Vec<RolloutTrace> = (0..plan.len())
        .map(|i| trace(40 + 10 * i, 2, true))
        .collect();
    let records: Vec<RolloutRecord> = plan
        .iter()
        .enumerate()
        .map(|(i, &(ok, b))| record(i / 3, i % 3, ok, json!(b), 40 + 10 * i))
        .collect();
    let pairs: Vec<(&RolloutRecord, &RolloutTrace)> = records.iter().zip(&traces).collect();
    let svg = overlay_svg(TaskId::Sorting2, &pairs).expect("drawn");
    dump("rollout-overlay", &svg);
    let fig = assert_readable(&svg, "overlay");
    let doc = Document::parse(&svg).unwrap();
    let paths = groups(&doc, "rollout-path");
    assert_eq!(paths.len(), plan.len());
    let frame = TopDown::read(&groups(&doc, "top-down-frame")[0]);
    let mut colour_of = std::collections::BTreeMap::new();
    for g in &paths {
        let (c, i): (usize, usize) = (
            g.attribute("data-context").unwrap().parse().unwrap(),
            g.attribute("data-rollout").unwrap().parse().unwrap(),
        );
        let k = 3 * c + i;
        let (ok, b) = plan[k];
        let label = behaviour_label(TaskId::Sorting2, &json!(b));
        assert_eq!(g.attribute("data-behaviour"), Some(label.as_str()));
        assert_eq!(has_class(g, "failed"), !ok);
        let line = g
            .children()
            .find(|c| c.has_tag_name("polyline"))
            .expect("a line");
        let pts = points_attr(&line);
        let steps = 40 + 10 * k;
        assert!(close(frame.world(pts[0]), tcp_at(0, steps), 1e-3));
        assert!(close(
            frame.world(*pts.last().unwrap()),
            tcp_at(steps, steps),
            1e-3
        ));
        let stroke = line.attribute("stroke").unwrap().to_string();
        if ok {
            let seen = colour_of.entry(label.clone()).or_insert(stroke.clone());
            assert_eq!(*seen, stroke, "one colour per behaviour");
        } else {
            assert_eq!(stroke, "#b0b0b0", "failed rollouts are grey");
        }
    }
    assert_eq!(colour_of.len(), 2);
    assert_ne!(colour_of["RB"], colour_of["BR"]);
    for (label, colour) in [
        ("RB (3)", colour_of["RB"].as_str()),
        ("BR (2)", colour_of["BR"].as_str()),
        ("failed (2)", "#b0b0b0"),
    ] {
        assert!(
            fig.legend_entries
                .iter()
                .any(|(l, c)| l == label && c == colour),
            "legend entry {label} {colour} in {:?}",
            fig.legend_entries
        );
    }

    let empty = overlay_svg(TaskId::Sorting2, &[]).expect("no rollouts");
    assert!(empty.contains("No rollout traces yet"));
}

#[test]
fn an_overlay_of_a_whole_avoiding_evaluation_stays_small() {
    // The paper's protocol: 480 rollouts of up to 250 steps, winding paths.
    let steps = 250;
    let at = |i: usize, k: usize| {
        let s = i as f64 / steps as f64;
        let phase = k as f64 * 0.013;
        [
            0.5 + 0.1 * (8.0 * std::f64::consts::PI * s + phase).sin(),
            -0.3 + 0.65 * s,
            0.12,
        ]
    };
    let traces: Vec<RolloutTrace> = (0..480)
        .map(|k| {
            let mut b = TraceBuilder::start(2, at(0, k), vec![], scene());
            for i in 0..steps {
                b.push_step(&[0.0, 0.0], 0, at(i + 1, k), &[]);
            }
            b.finish(vec![])
        })
        .collect();
    let records: Vec<RolloutRecord> = (0..480)
        .map(|k| record(0, k, k % 5 != 0, json!(k % 4), steps))
        .collect();
    let pairs: Vec<(&RolloutRecord, &RolloutTrace)> = records.iter().zip(&traces).collect();
    let svg = overlay_svg(TaskId::Avoiding, &pairs).expect("drawn");
    dump("rollout-overlay-avoiding", &svg);
    assert!(svg.len() < 2_000_000, "{} bytes", svg.len());
    let doc = Document::parse(&svg).unwrap();
    let paths = groups(&doc, "rollout-path");
    assert_eq!(paths.len(), 480);
    assert_eq!(groups(&doc, "rollout-path failed").len(), 96);
    for g in &paths {
        let line = g.children().find(|c| c.has_tag_name("polyline")).unwrap();
        assert!(points_attr(&line).len() <= 400);
    }
}

// ---- the initial states ----------------------------------------------------

fn start(context: usize, rate: f64, behaviour: Option<&str>) -> StartState {
    let c = context as f64;
    StartState {
        context_index: context,
        objects: vec![
            (
                "push_box".into(),
                [0.42 + 0.04 * c, -0.22 + 0.03 * c, -0.009],
            ),
            ("target_box".into(), TARGET_AT),
        ],
        success_rate: rate,
        dominant_behaviour: behaviour.map(str::to_string),
    }
}

#[test]
fn the_start_map_has_a_point_per_initial_state_darker_where_more_succeeded() {
    let contexts = vec![
        start(0, 0.5, Some("1")),
        start(1, 0.0, None),
        start(2, 1.0, Some("0")),
        start(3, 0.25, Some("1")),
        start(4, 0.75, Some("0")),
    ];
    let svg = start_map_svg(TaskId::Aligning, &contexts).expect("drawn");
    dump("rollout-start-map", &svg);
    let fig = assert_readable(&svg, "start map");
    let doc = Document::parse(&svg).unwrap();
    let frames = groups(&doc, "top-down-frame");
    assert_eq!(frames.len(), 2);
    let mut by_panel = std::collections::BTreeMap::new();
    for (panel, frame) in ["success", "behaviour"].iter().zip(&frames) {
        let frame = TopDown::read(frame);
        let g = groups(&doc, "points")
            .into_iter()
            .find(|g| g.attribute("data-panel") == Some(*panel))
            .expect("panel");
        let marks: Vec<Node> = g.children().filter(|c| c.is_element()).collect();
        assert_eq!(
            marks.len(),
            contexts.len(),
            "{panel}: one point per initial state"
        );
        let mut fills = vec![String::new(); contexts.len()];
        for m in &marks {
            let c: usize = m.attribute("data-context").unwrap().parse().unwrap();
            assert_eq!(m.attribute("data-object"), Some("push_box"));
            let at = (
                m.attribute("cx").unwrap().parse().unwrap(),
                m.attribute("cy").unwrap().parse().unwrap(),
            );
            assert!(close(frame.world(at), contexts[c].objects[0].1, 1e-3));
            fills[c] = m.attribute("fill").unwrap().to_string();
        }
        by_panel.insert(*panel, fills);
    }
    // Higher success, darker.
    let mut order: Vec<&StartState> = contexts.iter().collect();
    order.sort_by(|a, b| a.success_rate.total_cmp(&b.success_rate));
    let lum: Vec<f64> = order
        .iter()
        .map(|c| luminance(&by_panel["success"][c.context_index]))
        .collect();
    assert!(lum.windows(2).all(|w| w[1] < w[0]), "{lum:?}");
    // One colour per dominant behaviour; grey where none succeeded.
    let b = &by_panel["behaviour"];
    assert_eq!(b[1], "#b0b0b0");
    assert_eq!(b[0], b[3]);
    assert_eq!(b[2], b[4]);
    assert_ne!(b[0], b[2]);
    for label in ["1 (2)", "0 (2)", "none succeeded (1)"] {
        assert!(
            fig.legend_entries.iter().any(|(l, _)| l == label),
            "{label} in {:?}",
            fig.legend_entries
        );
    }
    assert!(texts(&doc).contains("success rate"));

    // Avoiding has nothing to move: the figure says so instead of empty axes.
    let avoiding = vec![StartState {
        context_index: 0,
        objects: vec![],
        success_rate: 0.5,
        dominant_behaviour: None,
    }];
    let svg = start_map_svg(TaskId::Avoiding, &avoiding).expect("drawn");
    assert!(groups(&Document::parse(&svg).unwrap(), "no-data").len() == 1);
}

#[test]
fn start_states_come_from_each_initial_states_first_trace() {
    let est = Estimate::with_interval(0.5, 0.0, 1.0, d3il_protocol::IntervalMethod::KornGraubard);
    let traces: Vec<RolloutTrace> = (0..2).map(|c| trace(10 + c, 3, true)).collect();
    let mut rollouts = Vec::new();
    for (c, t) in traces.iter().enumerate() {
        for i in 0..4 {
            let ok = i < 3 - 2 * c;
            let mut r = record(c, i, ok, json!(if i == 0 { 0 } else { 1 }), 10 + c);
            if i == 0 {
                r.trace = Some(Box::new(t.clone()));
            }
            rollouts.push(r);
        }
    }
    let result = EvalResult {
        manifest: ProtocolManifest {
            task: TaskId::Aligning,
            task_version: "1".into(),
            obs_type: ObsType::State,
            protocol: ProtocolKind::Quick,
            robot_look: None,
            mjcf_sha256: String::new(),
            initial_states_sha256: String::new(),
            initial_states: String::new(),
            mujoco_version: "2.2.2".into(),
            evaluator_version: "test".into(),
            n_contexts: 2,
            rollouts_per_context: 4,
            max_steps: 400,
            policy_sha256: String::new(),
            history: 1,
            horizon: 1,
            execute: 1,
            seed: 0,
            simulated_once: true,
            build: None,
            perturbation: None,
        },
        metrics: Metrics {
            success_rate: est,
            behaviour_entropy: est,
            conditional_entropy: est,
            stacking: None,
            stacking_levels: None,
            inference_ms: 1.0,
        },
        per_context: (0..2)
            .map(|c| ContextResult {
                context_index: c,
                success_rate: 0.5,
                conditional_entropy: 0.0,
                behaviours: vec![],
            })
            .collect(),
        rollouts,
        rollouts_ended_unstable: 0,
    };
    let starts = start_states(TaskId::Aligning, &result);
    assert_eq!(starts.len(), 2);
    assert_eq!(starts[0].objects, traces[0].start_objects);
    assert_eq!(starts[1].objects, traces[1].start_objects);
    // State 0: rollouts 0, 1, 2 succeeded with behaviours 0, 1, 1.
    assert_eq!(starts[0].success_rate, 0.75);
    assert_eq!(starts[0].dominant_behaviour.as_deref(), Some("1"));
    // State 1: only rollout 0 succeeded.
    assert_eq!(starts[1].success_rate, 0.25);
    assert_eq!(starts[1].dominant_behaviour.as_deref(), Some("0"));
    start_map_svg(TaskId::Aligning, &starts).expect("drawn");
}

// ---- per step --------------------------------------------------------------

/// A step panel's series as data: (seconds, value) per drawn point.
fn series(doc: &Document, panel: &str) -> Vec<(String, Vec<(f64, f64)>)> {
    let g = groups(doc, "step-panel")
        .into_iter()
        .find(|g| g.attribute("data-panel") == Some(panel))
        .unwrap_or_else(|| panic!("panel {panel}"));
    let (t0, t1) = pair(&g, "data-x-range");
    let (lo, hi) = pair(&g, "data-y-range");
    let [left, top, right, bottom] = px_box(&g);
    g.children()
        .filter(|c| c.has_tag_name("polyline"))
        .map(|line| {
            let pts = points_attr(&line)
                .into_iter()
                .map(|(u, v)| {
                    (
                        t0 + (u - left) / (right - left) * (t1 - t0),
                        lo + (bottom - v) / (bottom - top) * (hi - lo),
                    )
                })
                .collect();
            (line.attribute("data-series").unwrap_or("").to_string(), pts)
        })
        .collect()
}

#[test]
fn step_plots_have_a_panel_per_action_the_speed_and_the_distances() {
    let steps = 60;
    let t = trace(steps, 3, true);
    let r = record(1, 0, true, json!(0), steps);
    let svg = step_plots_svg(TaskId::Aligning, &r, &t).expect("drawn");
    dump("rollout-steps", &svg);
    assert_readable(&svg, "step plots");
    let doc = Document::parse(&svg).unwrap();
    let panels: Vec<&str> = groups(&doc, "step-panel")
        .iter()
        .filter_map(|g| g.attribute("data-panel"))
        .collect();
    assert_eq!(
        panels,
        ["action-0", "action-1", "action-2", "speed", "distance"]
    );
    let tol = |lo_hi: f64| lo_hi * 1e-3;

    let a1 = &series(&doc, "action-1")[0].1;
    assert_eq!(a1.len(), steps);
    for (i, &(s, v)) in a1.iter().enumerate() {
        assert!((s - i as f64 * 0.035).abs() < 1e-3);
        assert!(
            (v - f64::from(action(i, 1))).abs() < tol(0.02),
            "step {i}: {v}"
        );
    }
    // The TCP covers (0.24, 0.36) m in 60 steps of 35 ms.
    let speed = &series(&doc, "speed")[0].1;
    assert_eq!(speed.len(), steps);
    let expected = 0.24f64.hypot(0.36) / steps as f64 / 0.035;
    for &(_, v) in speed {
        assert!(
            (v - expected).abs() < expected * 0.01,
            "{v} vs {expected} m/s"
        );
    }
    // The box's distance to the nearer target centre (goal or target_box).
    let d = series(&doc, "distance");
    assert_eq!(d.len(), 1);
    assert_eq!(d[0].0, "push_box");
    assert_eq!(d[0].1.len(), steps + 1);
    for (i, &(_, v)) in d[0].1.iter().enumerate() {
        let b = box_at(i, steps);
        let want = [[0.62, 0.22], [TARGET_AT[0], TARGET_AT[1]]]
            .iter()
            .map(|c| (b[0] - c[0]).hypot(b[1] - c[1]))
            .fold(f64::INFINITY, f64::min);
        assert!((v - want).abs() < 1e-3, "state {i}: {v} vs {want}");
    }
    assert!(texts(&doc).contains("time since reset (s)"));
    // Stacking's steps last 30 ms (30 substeps of 1 ms), the others' 35 ms.
    let svg = step_plots_svg(TaskId::Stacking, &r, &t).expect("drawn");
    let doc = Document::parse(&svg).unwrap();
    let a1 = &series(&doc, "action-1")[0].1;
    for (i, &(s, _)) in a1.iter().enumerate() {
        assert!((s - i as f64 * 0.030).abs() < 1e-3, "step {i}: {s} s");
    }

    // Nothing to move: no distance panel.
    let bare = trace(30, 2, false);
    let svg = step_plots_svg(
        TaskId::Avoiding,
        &record(0, 1, true, json!(null), 30),
        &bare,
    )
    .unwrap();
    let doc = Document::parse(&svg).unwrap();
    let panels: Vec<&str> = groups(&doc, "step-panel")
        .iter()
        .filter_map(|g| g.attribute("data-panel"))
        .collect();
    assert_eq!(panels, ["action-0", "action-1", "speed"]);
}

// ---- refusals and the empty figure -----------------------------------------

#[test]
fn a_corrupt_trace_is_refused_naming_the_field() {
    let steps = 20;
    let good = trace(steps, 3, true);
    let r = record(2, 5, true, json!(1), steps);
    let corrupt = [
        (
            "`tcp`",
            RolloutTrace {
                tcp: "not base64!".into(),
                ..good.clone()
            },
        ),
        (
            "`tcp` holds 1 positions",
            RolloutTrace {
                tcp: pack_f32(&[0.1, 0.2, 0.3]),
                ..good.clone()
            },
        ),
        (
            "`actions`",
            RolloutTrace {
                act_dim: 7,
                ..good.clone()
            },
        ),
        ("`objects.xy` of `push_box`", {
            let mut t = good.clone();
            t.objects[0].xy = pack_f32(&[0.5, 0.0]);
            t
        }),
        ("`landmarks`", {
            let mut t = good.clone();
            t.landmarks[1].center[0] = f64::NAN;
            t
        }),
        (
            "format 9",
            RolloutTrace {
                format: 9,
                ..good.clone()
            },
        ),
    ];
    for (needle, t) in &corrupt {
        for (what, e) in [
            (
                "top-down",
                top_down_svg(TaskId::Aligning, &r, t).unwrap_err(),
            ),
            (
                "steps",
                step_plots_svg(TaskId::Aligning, &r, t).unwrap_err(),
            ),
            (
                "overlay",
                overlay_svg(TaskId::Aligning, &[(&r, t)]).unwrap_err(),
            ),
        ] {
            let msg = e.to_string();
            assert!(msg.contains(needle), "{what}: {needle} not in {msg}");
            assert!(msg.contains("initial state 2, rollout 5"), "{what}: {msg}");
        }
    }
}

#[test]
fn the_no_data_figure_says_so() {
    let svg = no_data_svg(
        "Submission 7: rollout 3",
        "No trace <recorded> for this rollout.",
    );
    let fig = parse(&svg);
    assert_eq!((fig.width, fig.height), (720.0, 480.0));
    let doc = Document::parse(&svg).unwrap();
    let words = texts(&doc);
    assert!(words.contains("Submission 7: rollout 3"));
    assert!(words.contains("No trace <recorded> for this rollout."));
    assert!(no_data_svg("t", "").contains("No results yet."));
    assert_readable(&svg, "no data");
}
