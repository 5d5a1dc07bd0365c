//! Pictures stay in their frame (issue 43 item 2): every path of the top-down
//! view and the overlay, and the initial-state map's points, are clipped to
//! the plotting area, and the caption says when a path left it.

use crate::support;
use crate::svg_geometry;

use d3il_protocol::rollout::TraceBuilder;
use d3il_protocol::{RolloutRecord, RolloutTrace, TaskId};
use d3il_tables::rollouts::{overlay_svg, start_map_svg, top_down_svg, StartState};
use roxmltree::{Document, Node};
use serde_json::json;
use support::*;
use svg_geometry::assert_readable;

/// A rollout whose TCP runs off the far end of the table to x = 1.6 m (the
/// table ends at 0.89 m), as a Pushing path that leaves the table did.
fn runaway(steps: usize) -> RolloutTrace {
    let at = |i: usize| {
        let s = i as f64 / steps as f64;
        [0.35 + 1.25 * s, -0.1 + 0.2 * s, 0.12]
    };
    let mut b = TraceBuilder::start(2, at(0), objects(0, steps), scene());
    for i in 0..steps {
        b.push_step(&[0.0, 0.0], i as u32, at(i + 1), &objects(i + 1, steps));
    }
    b.finish(objects(steps, steps))
}

/// The caption's text, its wrapped lines joined.
fn caption(doc: &Document) -> String {
    let g = &groups(doc, "caption")[0];
    g.descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text())
        .collect::<Vec<_>>()
        .join(" ")
}

/// The plotting area (left top right bottom) a group is clipped to, from its
/// `clip-path` and the `<clipPath>` of that id.
fn clip_box(doc: &Document, g: &Node) -> [f64; 4] {
    let url = g
        .attribute("clip-path")
        .unwrap_or_else(|| panic!("{:?} is not clipped", g.attribute("class")));
    let id = url
        .strip_prefix("url(#")
        .and_then(|s| s.strip_suffix(')'))
        .expect("url(#id)");
    let clip = doc
        .descendants()
        .find(|n| n.has_tag_name("clipPath") && n.attribute("id") == Some(id))
        .unwrap_or_else(|| panic!("no <clipPath id=\"{id}\">"));
    let r = clip.children().find(|n| n.has_tag_name("rect")).unwrap();
    let v = |a| r.attribute(a).unwrap().parse::<f64>().unwrap();
    [v("x"), v("y"), v("x") + v("width"), v("y") + v("height")]
}

fn assert_clipped_to_frame(doc: &Document, class: &str) {
    let frame = px_box(&groups(doc, "top-down-frame")[0]);
    let gs = groups(doc, class);
    assert!(!gs.is_empty(), "no {class}");
    for g in gs {
        let b = clip_box(doc, &g);
        assert!(
            b.iter().zip(&frame).all(|(x, y)| (x - y).abs() < 0.01),
            "{class}: {b:?} vs {frame:?}"
        );
    }
}

#[test]
fn a_path_that_leaves_the_table_is_clipped_and_the_caption_says_so() {
    let steps = 60;
    let r = record(1, 0, false, json!(0), steps);
    let svg = top_down_svg(TaskId::Pushing, &r, &runaway(steps)).expect("drawn");
    dump("top-down-runaway", &svg);
    assert_readable(&svg, "top-down view of a runaway path");
    let doc = Document::parse(&svg).unwrap();
    // The path is drawn whole, past the frame: the clip keeps it inside.
    let frame = TopDown::read(&groups(&doc, "top-down-frame")[0]);
    let tcp = path_points(&groups(&doc, "tcp-path")[0]);
    assert!(
        tcp.iter().any(|p| p.1 < frame.px[1]),
        "the TCP goes past the top"
    );
    for class in ["tcp-path", "object-path", "start-mark", "end-mark"] {
        assert_clipped_to_frame(&doc, class);
    }
    let text = caption(&doc);
    assert!(
        text.contains("The path of the TCP leaves the drawn area") && text.contains("cut off"),
        "{text}"
    );

    // A rollout that stays on the table: clipped all the same, no note.
    let svg = top_down_svg(TaskId::Pushing, &r, &trace(steps, 2, true)).expect("drawn");
    let doc = Document::parse(&svg).unwrap();
    assert_clipped_to_frame(&doc, "tcp-path");
    assert!(!caption(&doc).contains("drawn area"), "{}", caption(&doc));
}

#[test]
fn the_overlay_clips_every_path_and_counts_those_that_left() {
    let traces = [trace(40, 2, true), runaway(50), trace(60, 2, true)];
    let records: Vec<RolloutRecord> = (0..3)
        .map(|i| record(i, 0, i != 1, json!(1), 40 + 10 * i))
        .collect();
    let pairs: Vec<(&RolloutRecord, &RolloutTrace)> = records.iter().zip(&traces).collect();
    let svg = overlay_svg(TaskId::Pushing, &pairs).expect("drawn");
    dump("overlay-runaway", &svg);
    assert_readable(&svg, "overlay with a runaway path");
    let doc = Document::parse(&svg).unwrap();
    assert_eq!(groups(&doc, "rollout-path").len(), 3);
    assert_clipped_to_frame(&doc, "rollout-path");
    let text = caption(&doc);
    assert!(
        text.contains("The path of 1 of 3 rollouts leaves the drawn area"),
        "{text}"
    );
}

#[test]
fn the_start_map_clips_its_points_to_each_panel() {
    let contexts: Vec<StartState> = (0..4)
        .map(|c| StartState {
            context_index: c,
            objects: vec![("push_box".into(), [0.4 + 0.05 * c as f64, -0.2, -0.009])],
            success_rate: 0.25 * c as f64,
            dominant_behaviour: (c > 0).then(|| "left".to_string()),
        })
        .collect();
    let svg = start_map_svg(TaskId::Pushing, &contexts).unwrap();
    let doc = Document::parse(&svg).unwrap();
    let frames = groups(&doc, "top-down-frame");
    let points = groups(&doc, "points");
    assert_eq!((frames.len(), points.len()), (2, 2));
    for (f, p) in frames.iter().zip(&points) {
        assert_eq!(clip_box(&doc, p), px_box(f));
    }
    // The map is fitted to the starts: nothing lies outside, nothing to say.
    assert!(!caption(&doc).contains("drawn area"), "{}", caption(&doc));
}
