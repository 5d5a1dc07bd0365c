//! What the rollout-picture tests share: rollouts recorded through the
//! protocol's `TraceBuilder`, and readers of the pictures' SVG groups and
//! pixel mappings.

use d3il_protocol::rollout::TraceBuilder;
use d3il_protocol::{Ending, Landmark, LandmarkKind, RolloutRecord, RolloutTrace};
use roxmltree::{Document, Node};
use serde_json::Value;

/// Writes a picture to `$D3IL_FIGURE_DIR` (when set) for a look by eye.
pub fn dump(name: &str, svg: &str) {
    if let Some(dir) = std::env::var_os("D3IL_FIGURE_DIR") {
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.svg")), svg).expect("write");
    }
}

// ---- the recorded rollouts -------------------------------------------------

pub const TARGET_AT: [f64; 3] = [0.6, 0.3, 0.0];

pub fn scene() -> Vec<Landmark> {
    vec![
        Landmark {
            kind: LandmarkKind::Table,
            label: "table".into(),
            center: [0.4, 0.0],
            half: [0.49, 0.98],
            round: false,
        },
        Landmark {
            kind: LandmarkKind::Target,
            label: "goal".into(),
            center: [0.62, 0.22],
            half: [0.05, 0.05],
            round: false,
        },
        Landmark {
            kind: LandmarkKind::Obstacle,
            label: "post".into(),
            center: [0.42, 0.15],
            half: [0.025, 0.025],
            round: true,
        },
    ]
}

/// The TCP moves in a straight line from (0.35, -0.1) to (0.59, 0.26): away
/// from the robot and to the left.
pub fn tcp_at(i: usize, steps: usize) -> [f64; 3] {
    let s = i as f64 / steps as f64;
    [0.35 + 0.24 * s, -0.1 + 0.36 * s, 0.12]
}

/// The box waits for the first fifth of the rollout, then moves.
pub fn box_at(i: usize, steps: usize) -> [f64; 3] {
    let s = (i as f64 / steps as f64 - 0.2).max(0.0);
    [0.5 + 0.1 * s, 0.2 * s, -0.009]
}

pub fn objects(i: usize, steps: usize) -> Vec<(String, [f64; 3])> {
    vec![
        ("push_box".to_string(), box_at(i, steps)),
        ("target_box".to_string(), TARGET_AT),
    ]
}

pub fn action(i: usize, k: usize) -> f32 {
    ((i as f32) * 0.1 + k as f32).sin() * 0.01
}

/// A trace recorded as the engine records one: the state after the reset,
/// then one push per step.
pub fn trace(steps: usize, act_dim: usize, with_objects: bool) -> RolloutTrace {
    let objs = |i| {
        if with_objects {
            objects(i, steps)
        } else {
            vec![]
        }
    };
    let mut b = TraceBuilder::start(act_dim, tcp_at(0, steps), objs(0), scene());
    for i in 0..steps {
        let a: Vec<f32> = (0..act_dim).map(|k| action(i, k)).collect();
        b.push_step(&a, i as u32 * 7, tcp_at(i + 1, steps), &objs(i + 1));
    }
    b.finish(objs(steps))
}

pub fn record(
    context: usize,
    rollout: usize,
    success: bool,
    behaviour: Value,
    steps: usize,
) -> RolloutRecord {
    RolloutRecord {
        context_index: context,
        rollout_index: rollout,
        success,
        behaviour,
        steps,
        path: None,
        failure: None,
        ending: Some(if success {
            Ending::TaskSuccess
        } else {
            Ending::TimeLimit
        }),
        trace: None,
    }
}

// ---- reading the SVG -------------------------------------------------------

pub fn has_class(n: &Node, class: &str) -> bool {
    let have: Vec<&str> = n
        .attribute("class")
        .unwrap_or("")
        .split_whitespace()
        .collect();
    class.split_whitespace().all(|c| have.contains(&c))
}

/// The `<g>` elements having every class word of `class`.
pub fn groups<'a, 'i>(doc: &'a Document<'i>, class: &str) -> Vec<Node<'a, 'i>> {
    doc.descendants()
        .filter(|n| n.has_tag_name("g") && has_class(n, class))
        .collect()
}

pub fn points_attr(n: &Node) -> Vec<(f64, f64)> {
    n.attribute("points")
        .unwrap_or("")
        .split_whitespace()
        .map(|p| {
            let (x, y) = p.split_once(',').expect("x,y");
            (x.parse().expect("x"), y.parse().expect("y"))
        })
        .collect()
}

/// The points of a path drawn as polylines that share their end points.
pub fn path_points(g: &Node) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for (i, line) in g
        .children()
        .filter(|c| c.has_tag_name("polyline"))
        .enumerate()
    {
        let pts = points_attr(&line);
        out.extend(pts.into_iter().skip(usize::from(i > 0)));
    }
    out
}

pub fn pair(n: &Node, attr: &str) -> (f64, f64) {
    let v: Vec<f64> = n
        .attribute(attr)
        .unwrap_or_else(|| panic!("no {attr}"))
        .split_whitespace()
        .map(|v| v.parse().expect("number"))
        .collect();
    (v[0], v[1])
}

pub fn px_box(n: &Node) -> [f64; 4] {
    let v: Vec<f64> = n
        .attribute("data-px")
        .expect("data-px")
        .split_whitespace()
        .map(|v| v.parse().expect("number"))
        .collect();
    [v[0], v[1], v[2], v[3]]
}

/// The top-down view's pixel mapping, read from its `top-down-frame`.
pub struct TopDown {
    pub x: (f64, f64),
    pub y: (f64, f64),
    pub px: [f64; 4],
}

impl TopDown {
    pub fn read(g: &Node) -> TopDown {
        TopDown {
            x: pair(g, "data-world-x"),
            y: pair(g, "data-world-y"),
            px: px_box(g),
        }
    }
    /// World (x, y) of a pixel: x grows up the page, y to the left.
    pub fn world(&self, (u, v): (f64, f64)) -> (f64, f64) {
        let [left, top, right, bottom] = self.px;
        (
            self.x.0 + (bottom - v) / (bottom - top) * (self.x.1 - self.x.0),
            self.y.1 - (u - left) / (right - left) * (self.y.1 - self.y.0),
        )
    }
    pub fn scale(&self) -> (f64, f64) {
        let [left, top, right, bottom] = self.px;
        (
            (right - left) / (self.y.1 - self.y.0),
            (bottom - top) / (self.x.1 - self.x.0),
        )
    }
}

pub fn close(a: (f64, f64), b: [f64; 3], tol: f64) -> bool {
    (a.0 - b[0]).abs() < tol && (a.1 - b[1]).abs() < tol
}

pub fn luminance(hex: &str) -> f64 {
    let c = |i: usize| f64::from(u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"));
    0.2126 * c(1) + 0.7152 * c(3) + 0.0722 * c(5)
}

pub fn texts(doc: &Document) -> String {
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text())
        .collect::<Vec<_>>()
        .join("\n")
}
