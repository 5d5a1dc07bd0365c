//! The leaderboard's figures (the server's pages and plot endpoints draw
//! these): one task's success-vs-entropy plane with its Pareto front, the
//! data-fraction lines and a submission's behaviour bars. They are built from
//! the same panels and style as the paper figures of `d3il tables --figure`
//! ([`crate::panels`], [`crate::plot`]): one colour per method everywhere,
//! error bars (seed std) wherever a row has two or more seeds, legends beside
//! the data, labels placed without collisions and axes fitted to the data.
//! Points without a finite success rate and entropy are not drawn; a figure
//! without any row says "no results yet" ([`NO_RESULTS`]) instead of
//! showing empty axes.

use crate::panels::{fraction_panel, pareto_panel, shape, FractionLine, PlanePoint, FRONT};
use crate::plot::{canvas, hex, legend, pe, text_width, with_legend, Est, LegendEntry, Overlay};
use crate::rollouts::no_data_svg;
use crate::TablesError;
use d3il_protocol::TaskId;
use plotters::prelude::*;

/// What a leaderboard figure without a row says instead of empty axes.
pub const NO_RESULTS: &str = "No results yet: this figure fills in as results arrive.";

/// One method on the success-vs-entropy plane.
#[derive(Debug, Clone)]
pub struct ParetoPoint {
    pub label: String,
    /// Decides the colour ([`crate::plot::method_colour`]).
    pub method: String,
    pub entropy: Est,
    pub success: Est,
    pub evaluated: bool,
}

/// Success rate vs conditional behaviour entropy with the Pareto front.
pub fn pareto_svg(title: &str, points: &[ParetoPoint]) -> Result<String, TablesError> {
    if points.is_empty() {
        return Ok(no_data_svg(title, NO_RESULTS));
    }
    let mut entries: Vec<LegendEntry> = Vec::new();
    for p in points {
        let label = if p.evaluated {
            format!("{} (evaluated)", p.label)
        } else {
            p.label.clone()
        };
        if !entries.iter().any(|e| e.label == label) {
            entries.push(LegendEntry {
                label,
                colour: crate::plot::method_colour(&p.method),
                shape: Some(shape(p.evaluated)),
                line: None,
            });
        }
    }
    entries.push(LegendEntry {
        label: "Pareto front".into(),
        colour: FRONT,
        shape: None,
        line: Some(true),
    });
    let (plot_w, plot_h) = (640u32, 480u32);
    let (width, height, legend_x) = with_legend((plot_w, plot_h), None, &entries);
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plot, _) = root.split_horizontally(plot_w);
        let (plot, _) = plot.split_vertically(plot_h);
        let plot = plot
            .titled(title, ("sans-serif", 18).into_font())
            .map_err(pe)?;
        let points: Vec<PlanePoint> = points
            .iter()
            .map(|p| PlanePoint {
                // As in the legend: an evaluated row never reads as the paper's.
                label: if p.evaluated {
                    format!("{} (evaluated)", p.label)
                } else {
                    p.label.clone()
                },
                method: p.method.clone(),
                evaluated: p.evaluated,
                entropy: p.entropy,
                success: p.success,
            })
            .collect();
        pareto_panel(&plot, &mut ov, "", &points, true)?;
        legend(&mut ov, (legend_x, 40.0), None, &entries);
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

/// One method's values at each training-data fraction.
#[derive(Debug, Clone)]
pub struct FractionSeries {
    pub label: String,
    /// Decides the colour ([`crate::plot::method_colour`]).
    pub method: String,
    pub evaluated: bool,
    /// (fraction, success, entropy)
    pub points: Vec<(f64, Est, Est)>,
}

/// The paper's data-size figure: success (left) and entropy (right) vs the
/// fraction of training data, one line per method, legend on the right.
pub fn data_fraction_svg(title: &str, series: &[FractionSeries]) -> Result<String, TablesError> {
    if series.is_empty() {
        return Ok(no_data_svg(title, NO_RESULTS));
    }
    let entries: Vec<LegendEntry> = series
        .iter()
        .map(|s| LegendEntry {
            label: s.label.clone(),
            colour: crate::plot::method_colour(&s.method),
            shape: Some(shape(s.evaluated)),
            line: Some(s.evaluated),
        })
        .collect();
    let (panel_w, plot_h) = (460u32, 420u32);
    let (width, height, legend_x) = with_legend((2 * panel_w, plot_h), None, &entries);
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plots, _) = root.split_horizontally(2 * panel_w);
        let (plots, _) = plots.split_vertically(plot_h);
        let plots = plots
            .titled(title, ("sans-serif", 18).into_font())
            .map_err(pe)?;
        let (left, right) = plots.split_horizontally(panel_w);
        for (area, which, ylab) in [(left, 0, "Success rate"), (right, 1, "Conditional entropy")] {
            let lines: Vec<FractionLine> = series
                .iter()
                .map(|s| FractionLine {
                    method: s.method.clone(),
                    evaluated: s.evaluated,
                    points: s
                        .points
                        .iter()
                        .map(|&(f, su, en)| (f, if which == 0 { su } else { en }))
                        .collect(),
                })
                .collect();
            fraction_panel(&area, &mut ov, "", ylab, &lines)?;
        }
        if !entries.is_empty() {
            legend(&mut ov, (legend_x, 40.0), None, &entries);
        }
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

/// Readable label of a stored behaviour value for a task
/// ([`d3il_protocol::behaviour_name`]: Avoiding corridors, Sorting colour
/// orders like "RB", Stacking letters like "rgb", integer modes otherwise).
pub fn behaviour_label(task: TaskId, v: &serde_json::Value) -> String {
    d3il_protocol::behaviour_name(task, v)
}

/// Horizontal bars: how often each behaviour occurred among successful
/// rollouts, names on the left, integer counts at the bar ends.
pub fn behaviour_bars_svg(title: &str, counts: &[(String, usize)]) -> Result<String, TablesError> {
    const ROW: f64 = 22.0;
    const FONT: f64 = 12.0;
    let name_w = counts
        .iter()
        .map(|(n, _)| text_width(n, FONT))
        .fold(60.0, f64::max)
        + 16.0;
    let top = counts.iter().map(|c| c.1).max().unwrap_or(1).max(1) as f64;
    let width = 720u32.max(name_w as u32 + 360);
    let height = (110.0 + ROW * counts.len().max(1) as f64) as u32;
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let root = root
            .titled(title, ("sans-serif", 18).into_font())
            .map_err(pe)?;
        // Room for the count printed after the longest bar.
        let x_max = top * 1.12 + 1.0;
        let int_tick = |v: &f64| {
            if (v - v.round()).abs() < 1e-9 {
                format!("{}", v.round() as i64)
            } else {
                String::new()
            }
        };
        let mut chart = ChartBuilder::on(&root)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(name_w as u32)
            .build_cartesian_2d(0f64..x_max, 0f64..counts.len().max(1) as f64)
            .map_err(pe)?;
        crate::plot::house_mesh(
            chart
                .configure_mesh()
                .disable_y_mesh()
                .y_labels(0)
                .x_labels(((top as usize) + 1).min(8))
                .x_label_formatter(&int_tick)
                .x_desc("Successful rollouts"),
        )
        .draw()
        .map_err(pe)?;
        let colour = crate::plot::PAPER_COLOURS[3];
        for (i, (name, c)) in counts.iter().enumerate() {
            // Most frequent on top.
            let y_hi = counts.len() as f64 - i as f64;
            let (x0, y0) = chart.backend_coord(&(0.0, y_hi - 0.15));
            let (x1, y1) = chart.backend_coord(&(*c as f64, y_hi - 0.85));
            ov.rect(
                "points",
                crate::plot::Rect::new(x0 as f64, y0 as f64, x1 as f64, y1 as f64),
                &hex(colour),
                "none",
            );
            let mid = (y0 + y1) as f64 / 2.0;
            ov.text(
                "labels",
                (x0 as f64 - 8.0 - text_width(name, FONT), mid - FONT / 2.0),
                FONT,
                name,
            );
            ov.text(
                "labels",
                (x1 as f64 + 4.0, mid - FONT / 2.0),
                FONT,
                &c.to_string(),
            );
        }
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::panels::pareto_front;

    #[test]
    fn figures_without_rows_say_no_results_yet_instead_of_empty_axes() {
        for svg in [
            pareto_svg("Pushing (state): success vs diversity", &[]).unwrap(),
            data_fraction_svg("Pushing: performance vs training data", &[]).unwrap(),
        ] {
            assert!(svg.contains("no-data"), "{svg}");
            assert!(svg.contains("No results yet"), "{svg}");
            assert!(svg.contains("Pushing"), "the title stays: {svg}");
        }
    }

    fn p(e: f64, s: f64) -> ParetoPoint {
        ParetoPoint {
            label: format!("{e}/{s}"),
            method: "M".into(),
            entropy: Est::new(e, 0.0, 1),
            success: Est::new(s, 0.0, 1),
            evaluated: false,
        }
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [
            p(0.0, 0.9),
            p(0.5, 0.8),
            p(0.4, 0.7),
            p(0.9, 0.3),
            p(0.8, 0.2),
            p(f64::NAN, 1.0),
        ];
        let xy: Vec<(f64, f64)> = pts
            .iter()
            .map(|p| (p.entropy.mean, p.success.mean))
            .collect();
        // Points 0, 1 and 3; the one without an entropy is not on the front.
        assert_eq!(pareto_front(&xy), vec![(0.0, 0.9), (0.5, 0.8), (0.9, 0.3)]);
    }

    #[test]
    fn svg_output_escapes_labels() {
        let mut q = p(0.5, 0.5);
        q.label = "<script>alert(1)</script>".into();
        let svg = pareto_svg("t", &[q]).unwrap();
        assert!(svg.starts_with("<svg"));
        assert!(!svg.contains("<script>"));
        assert!(svg.contains("&lt;script&gt;"));
    }
}
