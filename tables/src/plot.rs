//! The one plotting style every figure uses, on the web and in
//! `d3il tables --figure`: the method → colour map, the SVG overlay the data
//! marks are written to (grouped by class so tests can read the geometry),
//! error bars, axis fitting, label placement without collisions and the
//! legend, which always sits outside the data area.
//!
//! Axes, ticks and captions are drawn by plotters; markers, error bars,
//! labels and legends are written by [`Overlay`] in pixel coordinates (mapped
//! through the plotters chart), inside `<g class="...">` groups:
//! `points`, `errorbars`, `lines`, `labels`, `legend`.

use crate::TablesError;
use d3il_protocol::paper::PAPER_METHOD_ORDER;
use plotters::coord::Shift;
use plotters::prelude::{DrawingArea, IntoDrawingArea, SVGBackend, WHITE};
use plotters::style::RGBColor;
use std::fmt::Write as _;
use std::ops::Range;

pub(crate) fn pe<E: std::fmt::Display>(e: E) -> TablesError {
    TablesError::Plot(e.to_string())
}

/// The one set-up of every figure: a white SVG canvas of `width` × `height`
/// pixels on which `body` draws with plotters. Returns the document plotters
/// wrote; the caller splices its marks into it ([`Overlay::splice`], and the
/// rollout figures their layer first).
pub(crate) fn canvas(
    (width, height): (u32, u32),
    body: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), TablesError>,
) -> Result<String, TablesError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        body(&root)?;
        root.present().map_err(pe)?;
    }
    Ok(buf)
}

/// Colours of the paper's eleven methods, in [`PAPER_METHOD_ORDER`]: the seven
/// Okabe–Ito colours (without its yellow, too pale on white) and four dark
/// colours of Paul Tol's colour-blind-safe schemes.
pub const PAPER_COLOURS: [RGBColor; 11] = [
    RGBColor(0xE6, 0x9F, 0x00), // orange
    RGBColor(0x56, 0xB4, 0xE9), // sky blue
    RGBColor(0x00, 0x9E, 0x73), // bluish green
    RGBColor(0x00, 0x72, 0xB2), // blue
    RGBColor(0xD5, 0x5E, 0x00), // vermillion
    RGBColor(0xCC, 0x79, 0xA7), // reddish purple
    RGBColor(0x00, 0x00, 0x00), // black
    RGBColor(0x88, 0x22, 0x55), // wine (Tol)
    RGBColor(0x99, 0x99, 0x33), // olive (Tol)
    RGBColor(0x33, 0x22, 0x88), // indigo (Tol)
    RGBColor(0x77, 0x77, 0x77), // grey
];

/// Colours for methods that are not in the paper (Paul Tol's muted scheme),
/// chosen by a hash of the name so a method keeps its colour in every figure.
const EXTRA_COLOURS: [RGBColor; 6] = [
    RGBColor(0x44, 0xAA, 0x99),
    RGBColor(0xAA, 0x44, 0x99),
    RGBColor(0x11, 0x77, 0x33),
    RGBColor(0xCC, 0x66, 0x77),
    RGBColor(0x88, 0xCC, 0xEE),
    RGBColor(0xDD, 0xCC, 0x77),
];

/// The one method → colour map of every figure: a paper method's fixed
/// colour, any other method a colour derived from its name only.
pub fn method_colour(method: &str) -> RGBColor {
    if let Some(i) = PAPER_METHOD_ORDER.iter().position(|m| *m == method) {
        return PAPER_COLOURS[i];
    }
    // FNV-1a: stable across runs and machines.
    let h = method.bytes().fold(0xcbf29ce484222325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100000001b3)
    });
    EXTRA_COLOURS[(h % EXTRA_COLOURS.len() as u64) as usize]
}

/// The axes' house style of every chart (Pareto, data-fraction, paths,
/// behaviour bars): tick labels at 14 px, axis titles at 15 px, no minor grid
/// and a light major grid.
pub fn house_mesh<'m, 'a, 'b, X, Y, DB>(
    mesh: &'m mut plotters::chart::MeshStyle<'a, 'b, X, Y, DB>,
) -> &'m mut plotters::chart::MeshStyle<'a, 'b, X, Y, DB>
where
    X: plotters::coord::ranged1d::Ranged,
    Y: plotters::coord::ranged1d::Ranged,
    DB: plotters::backend::DrawingBackend,
{
    use plotters::style::{IntoFont, TRANSPARENT};
    mesh.label_style(("sans-serif", 14).into_font())
        .axis_desc_style(("sans-serif", 15).into_font())
        .light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(225, 225, 225))
}

/// `#rrggbb` of a colour.
pub fn hex(c: RGBColor) -> String {
    format!("#{:02x}{:02x}{:02x}", c.0, c.1, c.2)
}

/// Estimated width of a text in pixels: 0.6 × font size per character (a
/// generous average for sans-serif; the SVG carries no font metrics).
pub fn text_width(text: &str, size: f64) -> f64 {
    0.6 * size * text.chars().count() as f64
}

/// An axis-aligned pixel rectangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    pub fn new(x0: f64, y0: f64, x1: f64, y1: f64) -> Rect {
        Rect { x0, y0, x1, y1 }
    }
    pub fn around(x: f64, y: f64, r: f64) -> Rect {
        Rect::new(x - r, y - r, x + r, y + r)
    }
    pub fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
    pub fn inside(&self, o: &Rect) -> bool {
        self.x0 >= o.x0 && self.x1 <= o.x1 && self.y0 >= o.y0 && self.y1 <= o.y1
    }
}

/// A mean with its seed spread; the error bar is drawn only for n ≥ 2 seeds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Est {
    pub mean: f64,
    pub std: f64,
    pub n_seeds: usize,
}

impl Est {
    pub fn new(mean: f64, std: f64, n_seeds: usize) -> Est {
        Est { mean, std, n_seeds }
    }
    /// Half-length of the error bar (one seed standard deviation), if shown.
    pub fn err(&self) -> Option<f64> {
        (self.n_seeds >= 2 && self.std.is_finite() && self.std >= 0.0).then_some(self.std)
    }
    /// The extent the axis must show.
    pub fn span(&self) -> (f64, f64) {
        let e = self.err().unwrap_or(0.0);
        (self.mean - e, self.mean + e)
    }
}

/// An axis range for a metric in [0, 1] fitted to the data: padded, rounded
/// to 0.05, clipped to [0, 1], and widened to the whole [0, 1] when the data
/// cover most of it (so success rates that span the scale keep it).
pub fn fit_unit_axis(spans: impl IntoIterator<Item = (f64, f64)>) -> Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (a, b) in spans {
        if a.is_finite() && b.is_finite() {
            lo = lo.min(a);
            hi = hi.max(b);
        }
    }
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.12).max(0.03);
    // Whole twentieths, computed as k / 20 so they print exactly.
    let lo = (((lo - pad) * 20.0).floor() / 20.0).max(0.0);
    let hi = (((hi + pad) * 20.0).ceil() / 20.0).min(1.0);
    if hi - lo >= 0.6 {
        0.0..1.0
    } else if hi - lo < 0.1 {
        let mid = (lo + hi) / 2.0;
        (mid - 0.05).max(0.0)..(mid + 0.05).clamp(0.1, 1.0)
    } else {
        lo..hi
    }
}

/// SVG text escaping.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Marker shapes: reported rows are circles, evaluated rows triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    Circle,
    Triangle,
    Square,
}

/// Data marks written in pixel coordinates, spliced into the plotters SVG.
#[derive(Default)]
pub struct Overlay {
    groups: Vec<(String, String)>,
}

impl Overlay {
    fn buf(&mut self, class: &str) -> &mut String {
        if let Some(i) = self.groups.iter().position(|(c, _)| c == class) {
            return &mut self.groups[i].1;
        }
        self.groups.push((class.to_string(), String::new()));
        &mut self.groups.last_mut().expect("just pushed").1
    }

    pub fn marker(&mut self, class: &str, (x, y): (f64, f64), shape: Shape, r: f64, c: RGBColor) {
        let fill = hex(c);
        let b = self.buf(class);
        let _ = match shape {
            Shape::Circle => writeln!(
                b,
                r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r:.1}" fill="{fill}" stroke="white" stroke-width="0.8"/>"#
            ),
            Shape::Triangle => writeln!(
                b,
                r#"<polygon points="{:.1},{:.1} {:.1},{:.1} {:.1},{:.1}" fill="{fill}" stroke="white" stroke-width="0.8"/>"#,
                x,
                y - 1.25 * r,
                x - 1.15 * r,
                y + 0.75 * r,
                x + 1.15 * r,
                y + 0.75 * r
            ),
            Shape::Square => writeln!(
                b,
                r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{fill}"/>"#,
                x - r,
                y - r,
                2.0 * r,
                2.0 * r
            ),
        };
    }

    pub fn line(&mut self, class: &str, a: (f64, f64), b: (f64, f64), c: RGBColor, width: f64) {
        let stroke = hex(c);
        let _ = writeln!(
            self.buf(class),
            r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{stroke}" stroke-width="{width}"/>"#,
            a.0,
            a.1,
            b.0,
            b.1
        );
    }

    pub fn polyline(
        &mut self,
        class: &str,
        pts: &[(f64, f64)],
        c: RGBColor,
        width: f64,
        dashed: bool,
    ) {
        if pts.len() < 2 {
            return;
        }
        let p: Vec<String> = pts.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
        let dash = if dashed {
            r#" stroke-dasharray="6 4""#
        } else {
            ""
        };
        let _ = writeln!(
            self.buf(class),
            r#"<polyline points="{}" fill="none" stroke="{}" stroke-width="{width}"{dash}/>"#,
            p.join(" "),
            hex(c)
        );
    }

    pub fn rect(&mut self, class: &str, r: Rect, fill: &str, stroke: &str) {
        let _ = writeln!(
            self.buf(class),
            r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{fill}" stroke="{stroke}"/>"#,
            r.x0,
            r.y0,
            r.x1 - r.x0,
            r.y1 - r.y0
        );
    }

    /// Text with its top-left corner at `(x, y)`.
    pub fn text(&mut self, class: &str, (x, y): (f64, f64), size: f64, s: &str) {
        let _ = writeln!(
            self.buf(class),
            r##"<text x="{x:.1}" y="{y:.1}" dy="0.76em" text-anchor="start" font-family="sans-serif" font-size="{size}" fill="#222222">{}</text>"##,
            esc(s)
        );
    }

    /// A vertical or horizontal error bar with caps, from `a` to `b`.
    pub fn error_bar(&mut self, a: (f64, f64), b: (f64, f64), c: RGBColor) {
        const CAP: f64 = 3.0;
        self.line("errorbars", a, b, c, 1.2);
        let vertical = (a.0 - b.0).abs() < (a.1 - b.1).abs();
        for p in [a, b] {
            if vertical {
                self.line("errorbars", (p.0 - CAP, p.1), (p.0 + CAP, p.1), c, 1.2);
            } else {
                self.line("errorbars", (p.0, p.1 - CAP), (p.0, p.1 + CAP), c, 1.2);
            }
        }
    }

    /// The plotters SVG with the overlay's groups inserted before `</svg>`
    /// (errorbars under lines under points under labels and legend).
    pub fn splice(mut self, svg: String) -> String {
        const ORDER: [&str; 5] = ["errorbars", "lines", "points", "labels", "legend"];
        self.groups
            .sort_by_key(|(c, _)| ORDER.iter().position(|o| o == c).unwrap_or(ORDER.len()));
        let end = svg.rfind("</svg>").unwrap_or(svg.len());
        let mut out = String::with_capacity(svg.len() + 4096);
        out.push_str(&svg[..end]);
        for (class, body) in &self.groups {
            let _ = write!(out, "<g class=\"{class}\">\n{body}</g>\n");
        }
        out.push_str(&svg[end..]);
        out
    }
}

/// One legend line.
pub struct LegendEntry {
    pub label: String,
    pub colour: RGBColor,
    pub shape: Option<Shape>,
    /// Line sample: `Some(dashed)`.
    pub line: Option<bool>,
}

pub const LEGEND_FONT: f64 = 12.0;
const LEGEND_ROW: f64 = 18.0;

/// Draws a framed legend with its top-left corner at `(x, y)` (callers put
/// it beside the plots, never over them); returns its box.
pub fn legend(
    ov: &mut Overlay,
    (x, y): (f64, f64),
    title: Option<&str>,
    entries: &[LegendEntry],
) -> Rect {
    let (w, h) = legend_size(title, entries);
    let frame = Rect::new(x, y, x + w, y + h);
    ov.rect("legend", frame, "white", "#b4b4b4");
    let mut row = 0.0;
    if let Some(t) = title {
        ov.text("legend", (x + 8.0, y + 6.0), LEGEND_FONT, t);
        row += 1.0;
    }
    for e in entries {
        let cy = y + 5.0 + LEGEND_ROW * row + LEGEND_ROW / 2.0;
        if let Some(dashed) = e.line {
            ov.polyline(
                "legend",
                &[(x + 8.0, cy), (x + 32.0, cy)],
                e.colour,
                2.0,
                dashed,
            );
        }
        if let Some(s) = e.shape {
            ov.marker("legend", (x + 20.0, cy), s, 4.5, e.colour);
        }
        ov.text(
            "legend",
            (x + 40.0, cy - LEGEND_FONT * 0.5),
            LEGEND_FONT,
            &e.label,
        );
        row += 1.0;
    }
    frame
}

/// Width and height of a legend's frame.
pub fn legend_size(title: Option<&str>, entries: &[LegendEntry]) -> (f64, f64) {
    let mut w: f64 = entries
        .iter()
        .map(|e| 44.0 + text_width(&e.label, LEGEND_FONT))
        .fold(0.0, f64::max);
    if let Some(t) = title {
        w = w.max(16.0 + text_width(t, LEGEND_FONT));
    }
    let rows = entries.len() + usize::from(title.is_some());
    (w + 8.0, 10.0 + LEGEND_ROW * rows as f64)
}

/// The canvas size of a figure whose plots take `plots` pixels, with a legend
/// column on the right: (total width, total height, legend column x).
pub fn with_legend(
    plots: (u32, u32),
    title: Option<&str>,
    entries: &[LegendEntry],
) -> (u32, u32, f64) {
    let (w, h) = legend_size(title, entries);
    let width = plots.0 + w.ceil() as u32 + 16;
    let height = plots.1.max(h.ceil() as u32 + 56);
    (width, height, plots.0 as f64 + 6.0)
}

/// A placed point label: its box, and whether it needs a leader line.
pub struct Placed {
    pub rect: Rect,
    pub leader: bool,
}

/// Places one label per anchor point (pixel coordinates) inside `bounds`:
/// for each point, in order, the first candidate position (right, left,
/// above, below, the diagonals, then the same farther out with a leader line)
/// whose box overlaps no placed label and no marker. `None` when no position
/// is free: the caller lists that point in the legend instead.
pub fn place_labels(
    anchors: &[(f64, f64)],
    labels: &[String],
    size: f64,
    marker_r: f64,
    bounds: Rect,
) -> Vec<Option<Placed>> {
    let markers: Vec<Rect> = anchors
        .iter()
        .map(|&(x, y)| Rect::around(x, y, marker_r + 1.0))
        .collect();
    let mut taken: Vec<Rect> = Vec::new();
    let mut out = Vec::with_capacity(anchors.len());
    for (&(x, y), label) in anchors.iter().zip(labels) {
        let (w, h) = (text_width(label, size), size);
        let mut found = None;
        'search: for ring in 0..14 {
            let d = marker_r + 3.0 + ring as f64 * (h * 0.8);
            // Right, left, above, below first; then the diagonals and the
            // directions between, every 22.5°.
            for k in [0, 8, 4, 12, 2, 6, 10, 14, 1, 7, 9, 15, 3, 5, 11, 13] {
                let a = k as f64 * std::f64::consts::PI / 8.0;
                let (c, s) = (a.cos(), a.sin());
                let cx = x + d * c + c * w / 2.0;
                let cy = y - d * s - s * h / 2.0;
                let r = Rect::new(cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0);
                if r.inside(&bounds)
                    && !taken.iter().any(|t| t.overlaps(&r))
                    && !markers.iter().any(|m| m.overlaps(&r))
                {
                    found = Some(Placed {
                        rect: r,
                        leader: ring > 1,
                    });
                    break 'search;
                }
            }
        }
        if let Some(p) = &found {
            taken.push(p.rect);
        }
        out.push(found);
    }
    out
}

/// Draws placed labels (and their leader lines) for points in one colour each.
pub fn draw_labels(
    ov: &mut Overlay,
    anchors: &[(f64, f64)],
    labels: &[String],
    colours: &[RGBColor],
    placed: &[Option<Placed>],
    size: f64,
) {
    for (((&(x, y), label), c), p) in anchors.iter().zip(labels).zip(colours).zip(placed) {
        let Some(p) = p else { continue };
        if p.leader {
            let tx = p.rect.x0.max(x.min(p.rect.x1));
            let ty = p.rect.y0.max(y.min(p.rect.y1));
            ov.line("labels", (x, y), (tx, ty), *c, 0.6);
        }
        ov.text("labels", (p.rect.x0, p.rect.y0), size, label);
    }
}

/// Plotters' pixel range of a chart's plotting area as a [`Rect`].
pub fn area_rect(x: Range<i32>, y: Range<i32>) -> Rect {
    Rect::new(x.start as f64, y.start as f64, x.end as f64, y.end as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_methods_have_distinct_fixed_colours() {
        for (i, m) in PAPER_METHOD_ORDER.iter().enumerate() {
            assert_eq!(method_colour(m), PAPER_COLOURS[i]);
        }
        for (i, a) in PAPER_COLOURS.iter().enumerate() {
            assert!(PAPER_COLOURS[i + 1..].iter().all(|b| b != a));
        }
        assert_eq!(method_colour("my-policy"), method_colour("my-policy"));
    }

    #[test]
    fn unit_axes_fit_the_data_and_keep_zero_to_one_when_spanned() {
        assert_eq!(fit_unit_axis([(0.05, 0.95)]), 0.0..1.0);
        let r = fit_unit_axis([(0.0, 0.08), (0.02, 0.17)]);
        assert_eq!(r.start, 0.0);
        assert!(r.end > 0.17 && r.end <= 0.3, "{r:?}");
        let r = fit_unit_axis([(0.7, 0.9)]);
        assert!(r.start >= 0.6 && r.start < 0.7 && r.end == 0.95, "{r:?}");
    }

    #[test]
    fn labels_never_overlap_each_other_or_markers() {
        let anchors: Vec<(f64, f64)> = (0..12)
            .map(|i| (100.0 + (i % 3) as f64, 100.0 + i as f64))
            .collect();
        let labels: Vec<String> = (0..12).map(|i| format!("Method {i}")).collect();
        let placed = place_labels(
            &anchors,
            &labels,
            11.0,
            4.0,
            Rect::new(0.0, 0.0, 400.0, 300.0),
        );
        let rects: Vec<Rect> = placed.iter().flatten().map(|p| p.rect).collect();
        assert_eq!(rects.len(), 12);
        for i in 0..rects.len() {
            for j in i + 1..rects.len() {
                assert!(!rects[i].overlaps(&rects[j]));
            }
        }
    }
}
