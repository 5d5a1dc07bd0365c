//! Reads the geometry of a figure's SVG (plotters' output plus the overlay
//! groups of `d3il_tables::plot`): text boxes estimated from font size ×
//! character count, data points, error-bar lines and the legend frame. Shared
//! by the tables and server tests (`#[path]`).

#![allow(dead_code)]

/// An axis-aligned box in SVG pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BBox {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl BBox {
    pub fn overlaps(&self, o: &BBox) -> bool {
        // A one-pixel tolerance: boxes that merely touch do not collide.
        self.x0 + 1.0 < o.x1 && o.x0 + 1.0 < self.x1 && self.y0 + 1.0 < o.y1 && o.y0 + 1.0 < self.y1
    }
    pub fn contains(&self, (x, y): (f64, f64)) -> bool {
        self.x0 <= x && x <= self.x1 && self.y0 <= y && y <= self.y1
    }
}

#[derive(Debug, Clone)]
pub struct Label {
    pub text: String,
    pub bbox: BBox,
    /// The `<g class>` it is in (`""` for plotters' own text).
    pub group: String,
}

#[derive(Debug, Clone)]
pub struct Point {
    pub at: (f64, f64),
    pub fill: String,
}

pub struct Figure {
    pub width: f64,
    pub height: f64,
    pub labels: Vec<Label>,
    pub points: Vec<Point>,
    pub error_bars: usize,
    pub legend: Option<BBox>,
    /// Fill colours of the legend's markers and strokes of its line samples,
    /// with the label on the same row.
    pub legend_entries: Vec<(String, String)>,
}

fn num(n: &roxmltree::Node, a: &str) -> f64 {
    n.attribute(a)
        .and_then(|v| v.trim_end_matches("px").parse().ok())
        .unwrap_or(0.0)
}

fn group_of(n: &roxmltree::Node) -> String {
    n.ancestors()
        .find(|a| a.has_tag_name("g"))
        .and_then(|g| g.attribute("class"))
        .unwrap_or("")
        .to_string()
}

/// The box of a `<text>`: width 0.6 × font size per character, height one
/// font size, placed by `text-anchor`, `dy` and a `rotate(270|90, x, y)`.
fn text_box(n: &roxmltree::Node) -> BBox {
    let (x, y, size) = (num(n, "x"), num(n, "y"), num(n, "font-size"));
    let chars = n.text().unwrap_or("").trim().chars().count() as f64;
    let w = 0.6 * size * chars;
    let (u0, u1) = match n.attribute("text-anchor") {
        Some("middle") => (-w / 2.0, w / 2.0),
        Some("end") => (-w, 0.0),
        _ => (0.0, w),
    };
    let (v0, v1) = match n.attribute("dy") {
        Some("0.5ex") => (-size / 2.0, size / 2.0),
        Some("-0.5ex") => (-size, 0.0),
        _ => (0.0, size),
    };
    match n.attribute("transform") {
        Some(t) if t.starts_with("rotate(270") => BBox {
            x0: x + v0,
            x1: x + v1,
            y0: y - u1,
            y1: y - u0,
        },
        Some(t) if t.starts_with("rotate(90") => BBox {
            x0: x - v1,
            x1: x - v0,
            y0: y + u0,
            y1: y + u1,
        },
        _ => BBox {
            x0: x + u0,
            x1: x + u1,
            y0: y + v0,
            y1: y + v1,
        },
    }
}

fn centre(n: &roxmltree::Node) -> Option<(f64, f64)> {
    if n.has_tag_name("circle") {
        return Some((num(n, "cx"), num(n, "cy")));
    }
    if n.has_tag_name("polygon") {
        let pts: Vec<(f64, f64)> = n
            .attribute("points")?
            .split_whitespace()
            .filter_map(|p| {
                let (a, b) = p.split_once(',')?;
                Some((a.parse().ok()?, b.parse().ok()?))
            })
            .collect();
        let k = pts.len().max(1) as f64;
        return Some((
            pts.iter().map(|p| p.0).sum::<f64>() / k,
            pts.iter().map(|p| p.1).sum::<f64>() / k,
        ));
    }
    if n.has_tag_name("rect") {
        return Some((
            num(n, "x") + num(n, "width") / 2.0,
            num(n, "y") + num(n, "height") / 2.0,
        ));
    }
    None
}

pub fn parse(svg: &str) -> Figure {
    let doc = roxmltree::Document::parse(svg).expect("well-formed SVG");
    let root = doc.root_element();
    let mut f = Figure {
        width: num(&root, "width"),
        height: num(&root, "height"),
        labels: vec![],
        points: vec![],
        error_bars: 0,
        legend: None,
        legend_entries: vec![],
    };
    let mut legend_marks: Vec<(f64, String)> = vec![];
    for n in doc.descendants().filter(|n| n.is_element()) {
        let group = group_of(&n);
        if n.has_tag_name("text") {
            let text = n.text().unwrap_or("").trim().to_string();
            if !text.is_empty() {
                f.labels.push(Label {
                    text,
                    bbox: text_box(&n),
                    group: group.clone(),
                });
            }
        }
        match group.as_str() {
            "points" => {
                if let Some(at) = centre(&n) {
                    f.points.push(Point {
                        at,
                        fill: n.attribute("fill").unwrap_or("").to_string(),
                    });
                }
            }
            "errorbars" if n.has_tag_name("line") => f.error_bars += 1,
            "legend" if n.has_tag_name("rect") && f.legend.is_none() => {
                f.legend = Some(BBox {
                    x0: num(&n, "x"),
                    y0: num(&n, "y"),
                    x1: num(&n, "x") + num(&n, "width"),
                    y1: num(&n, "y") + num(&n, "height"),
                })
            }
            "legend" if n.has_tag_name("circle") || n.has_tag_name("polygon") => {
                if let Some((_, y)) = centre(&n) {
                    legend_marks.push((y, n.attribute("fill").unwrap_or("").to_string()));
                }
            }
            "legend" if n.has_tag_name("polyline") => {
                let y = n
                    .attribute("points")
                    .and_then(|p| p.split_whitespace().next())
                    .and_then(|p| p.split_once(','))
                    .and_then(|(_, y)| y.parse().ok())
                    .unwrap_or(0.0);
                legend_marks.push((y, n.attribute("stroke").unwrap_or("").to_string()));
            }
            _ => {}
        }
    }
    for l in f.labels.iter().filter(|l| l.group == "legend") {
        let mid = (l.bbox.y0 + l.bbox.y1) / 2.0;
        if let Some((_, c)) = legend_marks.iter().find(|(y, _)| (y - mid).abs() < 4.0) {
            f.legend_entries.push((l.text.clone(), c.clone()));
        }
    }
    f
}

/// Every check of the brief in one place: the legend lies outside every data
/// point, error bar and point label; no two texts overlap.
pub fn assert_readable(svg: &str, what: &str) -> Figure {
    let f = parse(svg);
    if let Some(lg) = f.legend {
        for p in &f.points {
            assert!(
                !lg.contains(p.at),
                "{what}: the legend {lg:?} covers the point at {:?}",
                p.at
            );
        }
        for l in f.labels.iter().filter(|l| l.group == "labels") {
            assert!(
                !lg.overlaps(&l.bbox),
                "{what}: the legend covers the label {:?}",
                l.text
            );
        }
    }
    for (i, a) in f.labels.iter().enumerate() {
        for b in &f.labels[i + 1..] {
            assert!(
                !a.bbox.overlaps(&b.bbox),
                "{what}: labels {:?} {:?} and {:?} {:?} overlap",
                a.text,
                a.bbox,
                b.text,
                b.bbox
            );
        }
        assert!(
            a.bbox.x0 >= -1.0 && a.bbox.x1 <= f.width + 1.0,
            "{what}: label {:?} {:?} leaves the {}-px-wide figure",
            a.text,
            a.bbox,
            f.width
        );
    }
    f
}
