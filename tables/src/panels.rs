//! The panels both the server's figures ([`crate::board`]) and the paper
//! figures of `d3il tables --figure` ([`crate::figures`]) are made of: one
//! success-vs-entropy plane with its Pareto front, and one metric against the
//! fraction of training data. Styles come from [`crate::plot`].

use crate::plot::{
    area_rect, draw_labels, fit_unit_axis, method_colour, pe, place_labels, Est, Overlay, Shape,
};
use crate::TablesError;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::ops::Range;

/// Marker radius of data points.
pub const POINT_R: f64 = 4.5;
/// Font size of point labels.
pub const LABEL_FONT: f64 = 11.0;
/// Colour of the Pareto front line.
pub const FRONT: RGBColor = RGBColor(0x55, 0x55, 0x55);

/// One method on the success-vs-entropy plane.
#[derive(Debug, Clone)]
pub struct PlanePoint {
    pub label: String,
    pub method: String,
    pub evaluated: bool,
    pub entropy: Est,
    pub success: Est,
}

/// One method's line through a metric at several data fractions.
#[derive(Debug, Clone)]
pub struct FractionLine {
    pub method: String,
    pub evaluated: bool,
    /// (fraction, value), sorted by fraction.
    pub points: Vec<(f64, Est)>,
}

pub fn shape(evaluated: bool) -> Shape {
    if evaluated {
        Shape::Triangle
    } else {
        Shape::Circle
    }
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn tick_fmt(span: f64) -> impl Fn(&f64) -> String {
    move |v: &f64| {
        let s = if span < 0.5 {
            format!("{v:.2}")
        } else {
            format!("{v:.1}")
        };
        if s.starts_with("-0.0") && s.trim_start_matches(['-', '0', '.']).is_empty() {
            s[1..].to_string()
        } else {
            s
        }
    }
}

/// A chart with light grid lines, fitted ranges and axis titles.
pub fn chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    x: Range<f64>,
    y: Range<f64>,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, DB>, TablesError> {
    let (xs, ys) = (x.end - x.start, y.end - y.start);
    let mut b = ChartBuilder::on(area);
    if !caption.is_empty() {
        b.caption(caption, ("sans-serif", 15).into_font());
    }
    let mut chart = b
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)
        .map_err(pe)?;
    let (fx, fy) = (tick_fmt(xs), tick_fmt(ys));
    crate::plot::house_mesh(
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .x_labels(6)
            .y_labels(6)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy),
    )
    .draw()
    .map_err(pe)?;
    Ok(chart)
}

fn px<DB: DrawingBackend>(chart: &Chart<'_, DB>, x: f64, y: f64) -> (f64, f64) {
    let (a, b) = chart.backend_coord(&(x, y));
    (a as f64, b as f64)
}

/// Clamps a value into an axis range (error bars stop at the frame).
fn clamp(v: f64, r: &Range<f64>) -> f64 {
    v.clamp(r.start, r.end)
}

/// Success rate against conditional entropy: error bars (seed std) in both
/// directions, the Pareto front through the means, optional point labels
/// placed without collisions. Returns how many labels found no free place.
pub fn pareto_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ov: &mut Overlay,
    caption: &str,
    points: &[PlanePoint],
    labels: bool,
) -> Result<usize, TablesError> {
    let drawn: Vec<&PlanePoint> = points
        .iter()
        .filter(|p| p.entropy.mean.is_finite() && p.success.mean.is_finite())
        .collect();
    let xr = fit_unit_axis(drawn.iter().map(|p| p.entropy.span()));
    let yr = fit_unit_axis(drawn.iter().map(|p| p.success.span()));
    let chart = chart(
        area,
        caption,
        xr.clone(),
        yr.clone(),
        "Conditional behaviour entropy",
        "Success rate",
    )?;
    let front = pareto_front(
        &drawn
            .iter()
            .map(|p| (p.entropy.mean, p.success.mean))
            .collect::<Vec<_>>(),
    );
    let front_px: Vec<(f64, f64)> = front.iter().map(|&(e, s)| px(&chart, e, s)).collect();
    ov.polyline("lines", &front_px, FRONT, 1.5, true);
    let mut anchors = Vec::new();
    for p in &drawn {
        let c = method_colour(&p.method);
        let (e, s) = (p.entropy.mean, p.success.mean);
        if let Some(err) = p.success.err() {
            ov.error_bar(
                px(&chart, e, clamp(s - err, &yr)),
                px(&chart, e, clamp(s + err, &yr)),
                c,
            );
        }
        if let Some(err) = p.entropy.err() {
            ov.error_bar(
                px(&chart, clamp(e - err, &xr), s),
                px(&chart, clamp(e + err, &xr), s),
                c,
            );
        }
        let at = px(&chart, e, s);
        ov.marker("points", at, shape(p.evaluated), POINT_R, c);
        anchors.push(at);
    }
    if !labels {
        return Ok(0);
    }
    let (x, y) = chart.plotting_area().get_pixel_range();
    let texts: Vec<String> = drawn.iter().map(|p| p.label.clone()).collect();
    let colours: Vec<RGBColor> = drawn.iter().map(|p| method_colour(&p.method)).collect();
    let placed = place_labels(&anchors, &texts, LABEL_FONT, POINT_R, area_rect(x, y));
    draw_labels(ov, &anchors, &texts, &colours, &placed, LABEL_FONT);
    Ok(placed.iter().filter(|p| p.is_none()).count())
}

/// One metric against the fraction of training data: a line per method
/// (dashed for evaluated rows) with error bars (seed std) on every point.
pub fn fraction_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    ov: &mut Overlay,
    caption: &str,
    y_desc: &str,
    lines: &[FractionLine],
) -> Result<(), TablesError> {
    let finite = |l: &FractionLine| -> Vec<(f64, Est)> {
        l.points
            .iter()
            .copied()
            .filter(|(f, v)| f.is_finite() && v.mean.is_finite())
            .collect()
    };
    let yr = fit_unit_axis(lines.iter().flat_map(&finite).map(|(_, v)| v.span()));
    let chart = chart(
        area,
        caption,
        0.0..1.05,
        yr.clone(),
        "Fraction of training data",
        y_desc,
    )?;
    for l in lines {
        let c = method_colour(&l.method);
        let pts = finite(l);
        let line: Vec<(f64, f64)> = pts.iter().map(|&(f, v)| px(&chart, f, v.mean)).collect();
        ov.polyline("lines", &line, c, 2.0, l.evaluated);
        for &(f, v) in &pts {
            if let Some(err) = v.err() {
                ov.error_bar(
                    px(&chart, f, clamp(v.mean - err, &yr)),
                    px(&chart, f, clamp(v.mean + err, &yr)),
                    c,
                );
            }
            ov.marker("points", px(&chart, f, v.mean), shape(l.evaluated), 3.5, c);
        }
    }
    Ok(())
}

/// Points not dominated in (entropy, success): no other point is at least as
/// good in both and better in one. Sorted by entropy. Points without a finite
/// entropy and success rate are never on the front (nor drawn).
pub(crate) fn pareto_front(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let finite: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(e, s)| e.is_finite() && s.is_finite())
        .collect();
    let points = &finite;
    let mut front: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(e, s)| {
            !points
                .iter()
                .any(|&(e2, s2)| e2 >= e && s2 >= s && (e2 > e || s2 > s))
        })
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.total_cmp(&a.1)));
    front.dedup();
    front
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [
            (0.1, 0.9),
            (0.5, 0.5),
            (0.4, 0.4),
            (0.9, 0.1),
            (0.5, 0.5),
            (0.2, 0.2),
        ];
        assert_eq!(pareto_front(&pts), vec![(0.1, 0.9), (0.5, 0.5), (0.9, 0.1)]);
    }
}
