//! The top-down view every rollout picture shares: which part of the table
//! is shown, at one scale for both axes, in the one orientation (seen from
//! above, robot at the bottom: world x up the page, world y to the left), and
//! the table, targets and obstacles drawn in it.

use super::draw::{self, Frame, Group, Layer, MARGIN, X_LABEL_AREA, Y_LABEL_AREA};
use crate::plot::{LegendEntry, Rect, Shape};
use crate::TablesError;
use d3il_protocol::rollout::{Landmark, LandmarkKind};
use plotters::coord::Shift;
use plotters::prelude::*;

const TABLE_FILL: &str = "#f6f1e6";
const TABLE_EDGE: &str = "#b8a586";
const TARGET_FILL: RGBColor = RGBColor(0xd5, 0xec, 0xcd);
const TARGET_EDGE: &str = "#5a9e54";
const OBSTACLE_FILL: RGBColor = RGBColor(0x9a, 0x9a, 0x9a);
const OBSTACLE_EDGE: &str = "#6e6e6e";
/// How far past the table's edge the view may reach (its outline shows).
const TABLE_MARGIN: f64 = 0.03;

/// The shown part of the table: world x (up the page) and y (to the left).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct View {
    pub x: (f64, f64),
    pub y: (f64, f64),
}

fn extent(l: &Landmark) -> [f64; 2] {
    if l.round {
        [l.half[0], l.half[0]]
    } else {
        l.half
    }
}

impl View {
    /// Around the points and the landmarks other than the table, padded by
    /// at least `pad` (or 8 % of the larger side), no further out than a
    /// little past the table, at least `min_side` metres on each side.
    pub fn fit(
        points: impl IntoIterator<Item = [f64; 2]>,
        landmarks: &[Landmark],
        pad: f64,
        min_side: f64,
    ) -> View {
        let (mut x, mut y) = (
            (f64::INFINITY, f64::NEG_INFINITY),
            (f64::INFINITY, f64::NEG_INFINITY),
        );
        let mut grow = |px: f64, py: f64| {
            if px.is_finite() && py.is_finite() {
                x = (x.0.min(px), x.1.max(px));
                y = (y.0.min(py), y.1.max(py));
            }
        };
        for p in points {
            grow(p[0], p[1]);
        }
        for l in landmarks.iter().filter(|l| l.kind != LandmarkKind::Table) {
            let e = extent(l);
            grow(l.center[0] - e[0], l.center[1] - e[1]);
            grow(l.center[0] + e[0], l.center[1] + e[1]);
        }
        let table = landmarks.iter().find(|l| l.kind == LandmarkKind::Table);
        if !x.0.is_finite() {
            return match table {
                Some(t) => View {
                    x: (t.center[0] - t.half[0], t.center[0] + t.half[0]),
                    y: (t.center[1] - t.half[1], t.center[1] + t.half[1]),
                }
                .widen(min_side),
                None => View {
                    x: (0.2, 0.8),
                    y: (-0.4, 0.4),
                },
            };
        }
        let pad = pad.max(0.08 * (x.1 - x.0).max(y.1 - y.0));
        let mut v = View {
            x: (x.0 - pad, x.1 + pad),
            y: (y.0 - pad, y.1 + pad),
        };
        if let Some(t) = table {
            let clip = |(a, b): (f64, f64), c: f64, h: f64| {
                let (lo, hi) = (a.max(c - h - TABLE_MARGIN), b.min(c + h + TABLE_MARGIN));
                if hi > lo {
                    (lo, hi)
                } else {
                    (a, b)
                }
            };
            v.x = clip(v.x, t.center[0], t.half[0]);
            v.y = clip(v.y, t.center[1], t.half[1]);
        }
        v.widen(min_side)
    }

    /// Whether a world point (x, y) lies in the view, the plotting area.
    pub fn holds(&self, p: [f64; 2]) -> bool {
        (self.x.0..=self.x.1).contains(&p[0]) && (self.y.0..=self.y.1).contains(&p[1])
    }

    fn widen(mut self, min_side: f64) -> View {
        for r in [&mut self.x, &mut self.y] {
            if r.1 - r.0 < min_side {
                let c = (r.0 + r.1) / 2.0;
                *r = (c - min_side / 2.0, c + min_side / 2.0);
            }
        }
        self
    }

    /// The plot's size in pixels at one scale for both axes, its longer side
    /// `max_px`, neither side under `min_px` (the view widens to fill it).
    pub fn fit_pixels(mut self, max_px: f64, min_px: f64) -> (View, u32, u32) {
        let (wy, wx) = (self.y.1 - self.y.0, self.x.1 - self.x.0);
        let s = (max_px / wy).min(max_px / wx);
        let side = |r: &mut (f64, f64), span: f64| -> u32 {
            let px = (span * s).round().max(min_px);
            let c = (r.0 + r.1) / 2.0;
            let half = px / s / 2.0;
            *r = (c - half, c + half);
            px as u32
        };
        let w = side(&mut self.y, wy);
        let h = side(&mut self.x, wx);
        (self, w, h)
    }
}

/// The caption's note on paths that leave the drawn area, which are clipped
/// at its edge: `whose` are "the TCP" and object names, or "3 of 40 rollouts".
pub(super) fn outside_note(whose: &[String], count: usize) -> Option<String> {
    outside_note_of(whose, count, "the table and a margin around it")
}

/// [`outside_note`] for a drawn area described as `area` (every path plot
/// says it the same way, `crate::figures`' Avoiding paths too).
pub(crate) fn outside_note_of(whose: &[String], count: usize, area: &str) -> Option<String> {
    let (who, leave, be) = match (whose, count) {
        ([], _) => return None,
        ([one], 1) => (format!("The path of {one}"), "leaves", "is"),
        ([one], _) => (format!("The paths of {one}"), "leave", "are"),
        ([init @ .., last], _) => (
            format!("The paths of {} and {last}", init.join(", ")),
            "leave",
            "are",
        ),
    };
    Some(format!(
        "{who} {leave} the drawn area ({area}) and {be} cut off at its edge."
    ))
}

/// The size of a chart area whose plot is `w` × `h` pixels.
pub(super) fn chart_size(w: u32, h: u32) -> (u32, u32) {
    (
        w + 1 + Y_LABEL_AREA + 2 * MARGIN,
        h + 1 + X_LABEL_AREA + 2 * MARGIN,
    )
}

/// Axes of a top-down view filling `area` (sized by [`chart_size`]).
pub(super) fn axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    view: View,
) -> Result<Frame, TablesError> {
    let span = (view.x.1 - view.x.0).max(view.y.1 - view.y.0);
    let t = draw::tick(span);
    // The horizontal axis runs along -y so that y grows to the left.
    let flipped = |u: &f64| t(&-u);
    draw::axes(
        area,
        &draw::Axes {
            u: -view.y.1..-view.y.0,
            v: view.x.0..view.x.1,
            x_desc: "y (m), growing to the left",
            y_desc: "x (m), away from the robot",
            x_ticks: &flipped,
            y_ticks: &t,
            x_labels: 6,
            y_labels: 6,
            x_label_area: X_LABEL_AREA,
            margin: MARGIN,
        },
    )
}

/// The pixel of world (x, y).
pub(super) fn world(f: &Frame, x: f64, y: f64) -> (f64, f64) {
    f.px(-y, x)
}

/// The view's mapping for readers of the SVG (tests, tools).
pub(super) fn frame_group(layer: &mut Layer, f: &Frame, view: View) {
    layer.group(
        "top-down-frame",
        &[
            ("data-world-x", format!("{:.5} {:.5}", view.x.0, view.x.1)),
            ("data-world-y", format!("{:.5} {:.5}", view.y.0, view.y.1)),
            ("data-px", f.px_attr()),
        ],
    );
}

fn corners(f: &Frame, c: [f64; 2], e: [f64; 2]) -> Rect {
    let (a, b) = (
        world(f, c[0] - e[0], c[1] - e[1]),
        world(f, c[0] + e[0], c[1] + e[1]),
    );
    Rect::new(a.0.min(b.0), a.1.min(b.1), a.0.max(b.0), a.1.max(b.1))
}

fn draw_shape(g: &mut Group, f: &Frame, l: &Landmark, fill: &str, edge: &str) {
    if l.round {
        g.circle(
            world(f, l.center[0], l.center[1]),
            l.half[0] * f.scale_u(),
            fill,
            edge,
            "",
        );
    } else {
        g.rect(corners(f, l.center, l.half), fill, edge, "");
    }
}

/// The table (clipped to the view, its edges where they are in view), the
/// targets filled light and the obstacles grey.
pub(super) fn draw_landmarks(layer: &mut Layer, f: &Frame, landmarks: &[Landmark]) {
    let area = f.rect();
    for l in landmarks.iter().filter(|l| l.kind == LandmarkKind::Table) {
        let r = corners(f, l.center, l.half);
        let clipped = Rect::new(
            r.x0.max(area.x0),
            r.y0.max(area.y0),
            r.x1.min(area.x1),
            r.y1.min(area.y1),
        );
        if clipped.x1 <= clipped.x0 || clipped.y1 <= clipped.y0 {
            continue;
        }
        let g = layer.group("landmark table", &[("data-label", l.label.clone())]);
        g.rect(clipped, TABLE_FILL, "none", "");
        let inside = |v: f64, lo: f64, hi: f64| v >= lo && v <= hi;
        for x in [r.x0, r.x1] {
            if inside(x, area.x0, area.x1) {
                g.line((x, clipped.y0), (x, clipped.y1), TABLE_EDGE, 1.5);
            }
        }
        for y in [r.y0, r.y1] {
            if inside(y, area.y0, area.y1) {
                g.line((clipped.x0, y), (clipped.x1, y), TABLE_EDGE, 1.5);
            }
        }
    }
    for (kind, class, fill, edge) in [
        (
            LandmarkKind::Target,
            "landmark target",
            TARGET_FILL,
            TARGET_EDGE,
        ),
        (
            LandmarkKind::Obstacle,
            "landmark obstacle",
            OBSTACLE_FILL,
            OBSTACLE_EDGE,
        ),
    ] {
        for l in landmarks.iter().filter(|l| l.kind == kind) {
            let g = layer.group(class, &[("data-label", l.label.clone())]);
            draw_shape(g, f, l, &crate::plot::hex(fill), edge);
        }
    }
}

/// A fixed `target*` object: its position is known, its extent is not, so a
/// diamond marks it.
pub(super) fn draw_target_object(layer: &mut Layer, f: &Frame, name: &str, at: [f64; 2]) {
    let (x, y) = world(f, at[0], at[1]);
    const R: f64 = 7.0;
    layer
        .group("landmark target", &[("data-object", name.to_string())])
        .polygon(
            &[(x, y - R), (x + R, y), (x, y + R), (x - R, y)],
            &crate::plot::hex(TARGET_FILL),
            TARGET_EDGE,
            r#" stroke-width="1.5""#,
        );
}

/// Legend entries of the kinds of landmark present.
pub(super) fn landmark_entries(landmarks: &[Landmark], target_objects: bool) -> Vec<LegendEntry> {
    let mut out = Vec::new();
    if target_objects || landmarks.iter().any(|l| l.kind == LandmarkKind::Target) {
        out.push(LegendEntry {
            label: "target".into(),
            colour: TARGET_FILL,
            shape: Some(Shape::Square),
            line: None,
        });
    }
    if landmarks.iter().any(|l| l.kind == LandmarkKind::Obstacle) {
        out.push(LegendEntry {
            label: "obstacle".into(),
            colour: OBSTACLE_FILL,
            shape: Some(Shape::Square),
            line: None,
        });
    }
    out
}

/// The caption sentence of the orientation, the same in every picture.
pub(super) const ORIENTATION: &str =
    "Seen from above with the robot at the bottom: x points away from the robot (up), y to the left.";
