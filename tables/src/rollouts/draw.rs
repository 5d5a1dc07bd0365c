//! The drawing pieces every rollout picture shares: SVG groups with data
//! attributes (the [`crate::plot::Overlay`] writes groups by class only), the
//! pixel mapping of a plotters chart, the colour maps, path thinning, text
//! wrapping, the colour bar and the "no data" figure.

use crate::plot::{esc, hex, pe, text_width, Overlay, Rect};
use crate::TablesError;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::ops::Range;

/// Most points a drawn path or series keeps.
pub(super) const MAX_POINTS: usize = 400;
/// Height of the title band at the top of every picture.
pub(super) const TITLE_H: u32 = 36;
/// Font size of captions under the pictures.
pub(super) const CAPTION_FONT: f64 = 13.0;
pub(crate) const CAPTION_ROW: f64 = 18.0;
/// Colour of what failed or has no value.
pub(super) const GREY: RGBColor = RGBColor(0xb0, 0xb0, 0xb0);
/// Chart margins and label areas (pixels).
pub(super) const MARGIN: u32 = 10;
pub(super) const X_LABEL_AREA: u32 = 44;
pub(super) const Y_LABEL_AREA: u32 = 62;

/// A number for SVG: at most two decimals, without trailing zeros.
pub(super) fn num(v: f64) -> String {
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

/// One `<g>` with a class and data attributes, and its elements.
pub(crate) struct Group {
    open: String,
    body: String,
}

impl Group {
    /// `extra` is written into the element as is (further attributes).
    pub fn polyline(&mut self, pts: &[(f64, f64)], stroke: &str, width: f64, extra: &str) {
        if pts.len() < 2 {
            return;
        }
        let mut p = String::with_capacity(pts.len() * 14);
        for (i, (x, y)) in pts.iter().enumerate() {
            if i > 0 {
                p.push(' ');
            }
            let _ = write!(p, "{},{}", num(*x), num(*y));
        }
        let _ = writeln!(
            self.body,
            r#"<polyline points="{p}" fill="none" stroke="{stroke}" stroke-width="{width}" stroke-linejoin="round" stroke-linecap="round"{extra}/>"#
        );
    }

    pub fn circle(&mut self, (x, y): (f64, f64), r: f64, fill: &str, stroke: &str, extra: &str) {
        let _ = writeln!(
            self.body,
            r#"<circle cx="{}" cy="{}" r="{}" fill="{fill}" stroke="{stroke}"{extra}/>"#,
            num(x),
            num(y),
            num(r)
        );
    }

    pub fn polygon(&mut self, pts: &[(f64, f64)], fill: &str, stroke: &str, extra: &str) {
        let p: Vec<String> = pts
            .iter()
            .map(|(x, y)| format!("{},{}", num(*x), num(*y)))
            .collect();
        let _ = writeln!(
            self.body,
            r#"<polygon points="{}" fill="{fill}" stroke="{stroke}"{extra}/>"#,
            p.join(" ")
        );
    }

    /// An × of half-size `r`.
    pub fn cross(&mut self, (x, y): (f64, f64), r: f64, stroke: &str, width: f64) {
        for (dx, dy) in [(r, r), (r, -r)] {
            let _ = writeln!(
                self.body,
                r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{stroke}" stroke-width="{width}" stroke-linecap="round"/>"#,
                num(x - dx),
                num(y - dy),
                num(x + dx),
                num(y + dy)
            );
        }
    }

    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), stroke: &str, width: f64) {
        let _ = writeln!(
            self.body,
            r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{stroke}" stroke-width="{width}"/>"#,
            num(a.0),
            num(a.1),
            num(b.0),
            num(b.1)
        );
    }

    pub fn rect(&mut self, r: Rect, fill: &str, stroke: &str, extra: &str) {
        let _ = writeln!(
            self.body,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{fill}" stroke="{stroke}"{extra}/>"#,
            num(r.x0),
            num(r.y0),
            num(r.x1 - r.x0),
            num(r.y1 - r.y0)
        );
    }

    /// Text with its top at `y`; `anchor` is `start`, `middle` or `end`.
    pub fn text(&mut self, (x, y): (f64, f64), size: f64, anchor: &str, s: &str) {
        let _ = writeln!(
            self.body,
            r##"<text x="{}" y="{}" dy="0.76em" text-anchor="{anchor}" font-family="sans-serif" font-size="{size}" fill="#222222">{}</text>"##,
            num(x),
            num(y),
            esc(s)
        );
    }
}

/// Groups written in order (later ones on top), spliced into plotters' SVG
/// under the [`Overlay`]'s labels and legend.
#[derive(Default)]
pub(crate) struct Layer {
    groups: Vec<Group>,
}

impl Layer {
    /// A new group `<g class="{class}" {name}="{value}"...>`; values are escaped.
    pub fn group(&mut self, class: &str, attrs: &[(&str, String)]) -> &mut Group {
        let mut open = format!("<g class=\"{}\"", esc(class));
        for (k, v) in attrs {
            let _ = write!(open, " {k}=\"{}\"", esc(v));
        }
        open.push('>');
        self.groups.push(Group {
            open,
            body: String::new(),
        });
        self.groups.last_mut().expect("just pushed")
    }

    /// Clips what is drawn to a chart's plotting area: writes the area's
    /// `<clipPath>` (once per area; its id names the area, so pictures
    /// inlined in one page never point at another's) and returns the
    /// attribute that clips a group to it.
    pub fn clip_to(&mut self, f: &Frame) -> (&'static str, String) {
        let r = f.rect();
        let id = format!(
            "plot-area-{}-{}-{}-{}",
            r.x0.round(),
            r.y0.round(),
            r.x1.round(),
            r.y1.round()
        );
        let def = format!("<clipPath id=\"{id}\">");
        if !self.groups.iter().any(|g| g.body.contains(&def)) {
            let g = self.group("plot-clip", &[]);
            let _ = writeln!(
                g.body,
                r#"<defs>{def}<rect x="{}" y="{}" width="{}" height="{}"/></clipPath></defs>"#,
                num(r.x0),
                num(r.y0),
                num(r.x1 - r.x0),
                num(r.y1 - r.y0)
            );
        }
        ("clip-path", format!("url(#{id})"))
    }

    pub fn finish(self, svg: String, ov: Overlay) -> String {
        let end = svg.rfind("</svg>").unwrap_or(svg.len());
        let size: usize = self.groups.iter().map(|g| g.body.len() + 64).sum();
        let mut out = String::with_capacity(svg.len() + size);
        out.push_str(&svg[..end]);
        for g in &self.groups {
            let _ = write!(out, "{}\n{}</g>\n", g.open, g.body);
        }
        out.push_str(&svg[end..]);
        ov.splice(out)
    }
}

/// The linear map of a chart's plotting area: data (u to the right, v up) to
/// pixels, as plotters maps it (the last pixel column and row are the ends).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Frame {
    pub u: (f64, f64),
    pub v: (f64, f64),
    pub left: f64,
    pub top: f64,
    pub right: f64,
    pub bottom: f64,
}

impl Frame {
    pub fn of(pixels: (Range<i32>, Range<i32>), u: Range<f64>, v: Range<f64>) -> Frame {
        Frame {
            u: (u.start, u.end),
            v: (v.start, v.end),
            left: f64::from(pixels.0.start),
            right: f64::from(pixels.0.end - 1),
            top: f64::from(pixels.1.start),
            bottom: f64::from(pixels.1.end - 1),
        }
    }

    pub fn px(&self, u: f64, v: f64) -> (f64, f64) {
        (
            self.left + (u - self.u.0) / (self.u.1 - self.u.0) * (self.right - self.left),
            self.bottom - (v - self.v.0) / (self.v.1 - self.v.0) * (self.bottom - self.top),
        )
    }

    /// Pixels per data unit along u.
    pub fn scale_u(&self) -> f64 {
        (self.right - self.left) / (self.u.1 - self.u.0)
    }

    pub fn rect(&self) -> Rect {
        Rect::new(self.left, self.top, self.right, self.bottom)
    }

    /// `data-px`: "left top right bottom".
    pub fn px_attr(&self) -> String {
        format!(
            "{} {} {} {}",
            num(self.left),
            num(self.top),
            num(self.right),
            num(self.bottom)
        )
    }
}

/// Axis tick text with as many decimals as the span needs, without `-0`.
pub(super) fn tick(span: f64) -> impl Fn(&f64) -> String {
    let decimals = if span >= 20.0 {
        0
    } else if span >= 2.0 {
        1
    } else if span >= 0.2 {
        2
    } else {
        3
    };
    move |v: &f64| {
        let s = format!("{v:.decimals$}");
        if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
            s[1..].to_string()
        } else {
            s
        }
    }
}

/// What [`axes`] draws.
pub(super) struct Axes<'a> {
    pub u: Range<f64>,
    pub v: Range<f64>,
    pub x_desc: &'a str,
    pub y_desc: &'a str,
    pub x_ticks: &'a dyn Fn(&f64) -> String,
    pub y_ticks: &'a dyn Fn(&f64) -> String,
    pub x_labels: usize,
    pub y_labels: usize,
    /// 0: no tick labels under the plot (a stacked panel above another).
    pub x_label_area: u32,
    pub margin: u32,
}

/// Draws the axes and grid of a chart filling `area` in the house style and
/// returns its pixel mapping.
pub(super) fn axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    a: &Axes<'_>,
) -> Result<Frame, TablesError> {
    let mut chart = ChartBuilder::on(area)
        .margin(a.margin)
        .x_label_area_size(a.x_label_area)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(a.u.clone(), a.v.clone())
        .map_err(pe)?;
    crate::plot::house_mesh(
        chart
            .configure_mesh()
            .x_desc(a.x_desc)
            .y_desc(a.y_desc)
            .x_labels(a.x_labels)
            .y_labels(a.y_labels)
            .x_label_formatter(a.x_ticks)
            .y_label_formatter(a.y_ticks),
    )
    .draw()
    .map_err(pe)?;
    Ok(Frame::of(
        chart.plotting_area().get_pixel_range(),
        a.u.clone(),
        a.v.clone(),
    ))
}

/// ColorBrewer's YlGnBu from its third class on: light to dark, with a
/// luminance that falls monotonically and a light end still visible on white.
const SEQUENTIAL: [RGBColor; 7] = [
    RGBColor(0xc7, 0xe9, 0xb4),
    RGBColor(0x7f, 0xcd, 0xbb),
    RGBColor(0x41, 0xb6, 0xc4),
    RGBColor(0x1d, 0x91, 0xc0),
    RGBColor(0x22, 0x5e, 0xa8),
    RGBColor(0x25, 0x34, 0x94),
    RGBColor(0x08, 0x1d, 0x58),
];

/// The sequential colour map of every rollout picture: 0 light, 1 dark.
pub(super) fn sequential(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (SEQUENTIAL.len() - 1) as f64;
    let i = (x.floor() as usize).min(SEQUENTIAL.len() - 2);
    let f = x - i as f64;
    let (a, b) = (SEQUENTIAL[i], SEQUENTIAL[i + 1]);
    let mix = |p: u8, q: u8| (f64::from(p) + (f64::from(q) - f64::from(p)) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

pub(super) use crate::figures::hue;

/// One figure: a white SVG canvas of `width` × `height` points on which
/// `body` draws with plotters (`root`) and writes the groups of `layer` and
/// the `ov` overlay (text, legends), spliced into one document in that order.
pub(super) fn figure(
    width: f64,
    height: f64,
    body: impl FnOnce(
        &DrawingArea<SVGBackend<'_>, Shift>,
        &mut Layer,
        &mut Overlay,
    ) -> Result<(), TablesError>,
) -> Result<String, TablesError> {
    let mut layer = Layer::default();
    let mut ov = Overlay::default();
    let buf = crate::plot::canvas((width as u32, height as u32), |root| {
        body(root, &mut layer, &mut ov)
    })?;
    Ok(layer.finish(buf, ov))
}

/// Indices of at most `max` of `n` points, evenly spaced, first and last kept.
pub(super) fn even_indices(n: usize, max: usize) -> Vec<usize> {
    if n <= max || max < 2 {
        return (0..n).collect();
    }
    let mut out: Vec<usize> = (0..max)
        .map(|k| ((k as f64) * (n - 1) as f64 / (max - 1) as f64).round() as usize)
        .collect();
    out.dedup();
    out
}

/// Ramer–Douglas–Peucker in pixels: drops points closer than `eps` to the
/// line through their neighbours that are kept, then at most `max` points.
pub(super) fn simplify(pts: &[(f64, f64)], eps: f64, max: usize) -> Vec<(f64, f64)> {
    if pts.len() <= 2 {
        return pts.to_vec();
    }
    let mut keep = vec![false; pts.len()];
    keep[0] = true;
    keep[pts.len() - 1] = true;
    let mut stack = vec![(0usize, pts.len() - 1)];
    while let Some((a, b)) = stack.pop() {
        if b <= a + 1 {
            continue;
        }
        let (p, q) = (pts[a], pts[b]);
        let (dx, dy) = (q.0 - p.0, q.1 - p.1);
        let len = dx.hypot(dy);
        let (mut far, mut dmax) = (a, -1.0);
        for (i, r) in pts.iter().enumerate().take(b).skip(a + 1) {
            let d = if len < 1e-12 {
                (r.0 - p.0).hypot(r.1 - p.1)
            } else {
                ((r.0 - p.0) * dy - (r.1 - p.1) * dx).abs() / len
            };
            if d > dmax {
                (far, dmax) = (i, d);
            }
        }
        if dmax > eps {
            keep[far] = true;
            stack.push((a, far));
            stack.push((far, b));
        }
    }
    let kept: Vec<(f64, f64)> = pts
        .iter()
        .zip(&keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect();
    even_indices(kept.len(), max)
        .into_iter()
        .map(|i| kept[i])
        .collect()
}

/// At most `max` points of a series, keeping each bucket's lowest and
/// highest value (in time order) so that spikes survive the thinning.
pub(super) fn envelope(series: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if series.len() <= max || max < 4 {
        return series.to_vec();
    }
    let buckets = (max - 2) / 2;
    let inner = &series[1..series.len() - 1];
    let mut out = vec![series[0]];
    for b in 0..buckets {
        let lo = b * inner.len() / buckets;
        let hi = ((b + 1) * inner.len() / buckets).max(lo + 1);
        let chunk = &inner[lo..hi.min(inner.len())];
        let (mut imin, mut imax) = (0, 0);
        for (i, p) in chunk.iter().enumerate() {
            if p.1 < chunk[imin].1 {
                imin = i;
            }
            if p.1 > chunk[imax].1 {
                imax = i;
            }
        }
        out.push(chunk[imin.min(imax)]);
        if imin != imax {
            out.push(chunk[imin.max(imax)]);
        }
    }
    out.push(series[series.len() - 1]);
    out
}

/// Words of `text` in lines no wider than `width` pixels at `size`.
pub(super) fn wrap(text: &str, size: f64, width: f64) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        let candidate = if line.is_empty() {
            word.to_string()
        } else {
            format!("{line} {word}")
        };
        if !line.is_empty() && text_width(&candidate, size) > width {
            lines.push(std::mem::replace(&mut line, word.to_string()));
        } else {
            line = candidate;
        }
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

/// Caption paragraphs wrapped to `width`, each paragraph on new lines.
pub(crate) fn caption_lines(paragraphs: &[String], width: f64) -> Vec<String> {
    paragraphs
        .iter()
        .flat_map(|p| wrap(p, CAPTION_FONT, width))
        .collect()
}

/// Writes caption lines from `(x, y)` down.
pub(crate) fn draw_caption(layer: &mut Layer, (x, y): (f64, f64), lines: &[String]) {
    let g = layer.group("caption", &[]);
    for (i, l) in lines.iter().enumerate() {
        g.text((x, y + CAPTION_ROW * i as f64), CAPTION_FONT, "start", l);
    }
}

/// The title centred over `width`.
pub(super) fn draw_title(layer: &mut Layer, width: f64, title: &str) {
    layer
        .group("title", &[])
        .text((width / 2.0, 9.0), 18.0, "middle", title);
}

/// Width a colour bar with these labels takes.
pub(super) fn colour_bar_width(title: &str, labels: &[String]) -> f64 {
    let widest = labels
        .iter()
        .map(|l| text_width(l, 12.0))
        .fold(0.0, f64::max);
    (text_width(title, 12.0) + 8.0).max(14.0 + 6.0 + widest + 8.0)
}

pub(super) const COLOUR_BAR_H: f64 = 150.0;

/// A vertical colour bar of [`sequential`] with `title` above it, the top
/// (dark) end at `hi`, the bottom at `lo`, and `labels` at fractions of the
/// scale; returns the y under it.
pub(super) fn colour_bar(
    layer: &mut Layer,
    (x, y): (f64, f64),
    title: &str,
    labels: &[(f64, String)],
) -> f64 {
    const STEPS: usize = 32;
    const W: f64 = 14.0;
    let g = layer.group("colour-bar", &[("data-title", title.to_string())]);
    g.text((x, y), 12.0, "start", title);
    let top = y + 20.0;
    let h = COLOUR_BAR_H / STEPS as f64;
    for k in 0..STEPS {
        let t = 1.0 - (k as f64 + 0.5) / STEPS as f64;
        let y0 = top + h * k as f64;
        // A hair taller than a step so no white seam shows between them.
        g.rect(
            Rect::new(x, y0, x + W, y0 + h + 0.3),
            &hex(sequential(t)),
            "none",
            "",
        );
    }
    g.rect(
        Rect::new(x, top, x + W, top + COLOUR_BAR_H),
        "none",
        "#888888",
        r#" stroke-width="0.6""#,
    );
    for (f, label) in labels {
        let ly = top + (1.0 - f.clamp(0.0, 1.0)) * COLOUR_BAR_H;
        g.line((x + W, ly), (x + W + 4.0, ly), "#555555", 1.0);
        g.text((x + W + 6.0, ly - 6.0), 12.0, "start", label);
    }
    top + COLOUR_BAR_H + 12.0
}

/// The size of the "no data" figure (the size of a typical top-down view).
const NO_DATA_SIZE: (f64, f64) = (720.0, 480.0);

pub(super) fn no_data(title: &str, message: &str) -> String {
    let (w, h) = NO_DATA_SIZE;
    let message = if message.trim().is_empty() {
        "No results yet."
    } else {
        message
    };
    let mut layer = Layer::default();
    draw_title(&mut layer, w, title);
    let g = layer.group("no-data", &[("data-message", message.to_string())]);
    g.rect(
        Rect::new(20.0, 50.0, w - 20.0, h - 20.0),
        "#fafafa",
        "#c8c8c8",
        r#" stroke-dasharray="6 4""#,
    );
    let lines = wrap(message, 16.0, w - 120.0);
    let y0 = (h + 30.0) / 2.0 - 11.0 * lines.len() as f64;
    for (i, l) in lines.iter().enumerate() {
        g.text((w / 2.0, y0 + 22.0 * i as f64), 16.0, "middle", l);
    }
    let svg = format!(
        "<svg width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" xmlns=\"http://www.w3.org/2000/svg\">\n\
         <rect x=\"0\" y=\"0\" width=\"{w}\" height=\"{h}\" fill=\"#FFFFFF\"/>\n</svg>\n"
    );
    layer.finish(svg, Overlay::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn luminance(c: RGBColor) -> f64 {
        0.2126 * f64::from(c.0) + 0.7152 * f64::from(c.1) + 0.0722 * f64::from(c.2)
    }

    #[test]
    fn the_sequential_map_darkens_monotonically() {
        let l: Vec<f64> = (0..=50)
            .map(|i| luminance(sequential(i as f64 / 50.0)))
            .collect();
        assert!(l.windows(2).all(|w| w[1] < w[0]), "{l:?}");
        assert_eq!(sequential(-1.0), SEQUENTIAL[0]);
        assert_eq!(sequential(f64::NAN), SEQUENTIAL[0]);
        assert_eq!(sequential(1.0), SEQUENTIAL[6]);
    }

    #[test]
    fn thinning_keeps_the_ends_and_the_cap() {
        let idx = even_indices(1001, 400);
        assert_eq!((idx[0], *idx.last().unwrap()), (0, 1000));
        assert!(idx.len() <= 400 && idx.len() > 390);
        assert_eq!(even_indices(5, 400), vec![0, 1, 2, 3, 4]);
        let line: Vec<(f64, f64)> = (0..100).map(|i| (i as f64, 2.0 * i as f64)).collect();
        assert_eq!(simplify(&line, 0.3, 400), vec![(0.0, 0.0), (99.0, 198.0)]);
        let series: Vec<(f64, f64)> = (0..2000)
            .map(|i| (i as f64, if i == 777 { 50.0 } else { 0.0 }))
            .collect();
        let e = envelope(&series, 400);
        assert!(e.len() <= 400);
        assert!(e.contains(&(777.0, 50.0)));
        assert_eq!((e[0], e[e.len() - 1]), (series[0], series[1999]));
    }

    #[test]
    fn numbers_are_short() {
        assert_eq!(num(1.0), "1");
        assert_eq!(num(-0.001), "0");
        assert_eq!(num(12.3456), "12.35");
        assert_eq!(num(100.5), "100.5");
        assert_eq!(tick(0.5)(&-0.0001), "0.00");
    }
}
