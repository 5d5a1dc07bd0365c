//! The robustness view's figures, in the style of the leaderboard's others
//! ([`crate::panels::chart`], [`crate::plot`]: one colour per method,
//! legends beside the data, labels placed without collisions): per axis the
//! degradation curves (success rate against level, a line per row, level 0
//! the control arm), and robustness score against conditional behaviour
//! entropy across rows (the D3IL question in one picture). Error bars are
//! the documents' 95 % intervals.

use super::{RobustnessEntry, SuiteGroup};
use crate::panels::{chart, shape, LABEL_FONT, POINT_R};
use crate::plot::{
    area_rect, canvas, draw_labels, fit_unit_axis, legend, method_colour, pe, place_labels,
    with_legend, LegendEntry, Overlay,
};
use crate::TablesError;
use d3il_protocol::perturbation::Axis;
use plotters::prelude::*;

fn entries_legend(entries: &[&RobustnessEntry]) -> Vec<LegendEntry> {
    entries
        .iter()
        .map(|e| LegendEntry {
            label: e.label(),
            colour: method_colour(&e.method),
            shape: Some(shape(true)),
            line: Some(false),
        })
        .collect()
}

/// Success rate against level of `axis`, one line per row of `group`.
pub fn degradation_svg(group: &SuiteGroup<'_>, axis: Axis) -> Result<String, TablesError> {
    let levels = group.levels(axis);
    let x_desc = format!(
        "{axis} level: {}",
        levels
            .iter()
            .map(|(l, label)| format!("{l} = {label}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let title = format!("{} · {axis}: success vs level", group.task.title());
    let entries = entries_legend(&group.entries);
    let (plot_w, plot_h) = (560u32, 380u32);
    let (width, height, legend_x) = with_legend((plot_w, plot_h), None, &entries);
    let curves: Vec<Vec<(usize, d3il_protocol::Estimate)>> =
        group.entries.iter().map(|e| e.curve(axis)).collect();
    let yr = fit_unit_axis(
        curves
            .iter()
            .flatten()
            .map(|(_, e)| (e.ci_low.min(e.value), e.ci_high.max(e.value))),
    );
    let n = levels.len().max(2) - 1;
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plot, _) = root.split_horizontally(plot_w);
        let (plot, _) = plot.split_vertically(plot_h);
        let plot = plot
            .titled(&title, ("sans-serif", 16).into_font())
            .map_err(pe)?;
        let ch = chart(
            &plot,
            "",
            -0.2..n as f64 + 0.2,
            yr.clone(),
            &x_desc,
            "Success rate",
        )?;
        let px = |x: f64, y: f64| {
            let (a, b) = ch.backend_coord(&(x, y.clamp(yr.start, yr.end)));
            (a as f64, b as f64)
        };
        for (e, c) in group.entries.iter().zip(&curves) {
            let colour = method_colour(&e.method);
            let line: Vec<(f64, f64)> = c.iter().map(|(l, s)| px(*l as f64, s.value)).collect();
            ov.polyline("lines", &line, colour, 2.0, false);
            for (l, s) in c {
                // No bar where there is no interval (e.g. 3 initial states).
                if let Some((lo, hi)) = s.interval() {
                    ov.error_bar(px(*l as f64, lo), px(*l as f64, hi), colour);
                }
                ov.marker("points", px(*l as f64, s.value), shape(true), 3.5, colour);
            }
        }
        legend(&mut ov, (legend_x, 40.0), None, &entries);
        Ok(())
    })?;
    Ok(ov.splice(buf))
}

/// Overall robustness score against level 0's conditional behaviour
/// entropy, one point per row of `group` with both intervals.
pub fn score_vs_entropy_svg(group: &SuiteGroup<'_>) -> Result<String, TablesError> {
    let title = format!(
        "{}: robustness vs conditional behaviour entropy",
        group.task.title()
    );
    let drawn: Vec<&RobustnessEntry> = group
        .entries
        .iter()
        .copied()
        .filter(|e| e.doc.overall.is_some())
        .collect();
    let entries = entries_legend(&drawn);
    let (plot_w, plot_h) = (560u32, 420u32);
    let (width, height, legend_x) = with_legend((plot_w, plot_h), None, &entries);
    let h = |e: &RobustnessEntry| e.doc.control.metrics.conditional_entropy;
    let xr = fit_unit_axis(drawn.iter().map(|e| (h(e).ci_low, h(e).ci_high)));
    // Retained success can exceed 1 (a level may do better than level 0).
    let (lo, hi) = drawn
        .iter()
        .filter_map(|e| e.doc.overall)
        .fold((0.0f64, 1.0f64), |(lo, hi), o| {
            (lo.min(o.ci_low), hi.max(o.ci_high))
        });
    let yr = (lo - 0.05).max(lo.min(0.0))..hi + 0.05;
    let mut ov = Overlay::default();
    let buf = canvas((width, height), |root| {
        let (plot, _) = root.split_horizontally(plot_w);
        let (plot, _) = plot.split_vertically(plot_h);
        let plot = plot
            .titled(&title, ("sans-serif", 16).into_font())
            .map_err(pe)?;
        let ch = chart(
            &plot,
            "",
            xr.clone(),
            yr.clone(),
            "Conditional behaviour entropy (level 0)",
            "Robustness score (overall)",
        )?;
        let px = |x: f64, y: f64| {
            let (a, b) = ch.backend_coord(&(x.clamp(xr.start, xr.end), y.clamp(yr.start, yr.end)));
            (a as f64, b as f64)
        };
        let mut anchors = Vec::new();
        for e in &drawn {
            let Some(o) = e.doc.overall else { continue };
            let c = method_colour(&e.method);
            let x = h(e);
            if let Some((lo, hi)) = o.interval() {
                ov.error_bar(px(x.value, lo), px(x.value, hi), c);
            }
            if let Some((lo, hi)) = x.interval() {
                ov.error_bar(px(lo, o.value), px(hi, o.value), c);
            }
            let at = px(x.value, o.value);
            ov.marker("points", at, shape(true), POINT_R, c);
            anchors.push(at);
        }
        let (x, y) = ch.plotting_area().get_pixel_range();
        let texts: Vec<String> = drawn.iter().map(|e| e.label()).collect();
        let colours: Vec<RGBColor> = drawn.iter().map(|e| method_colour(&e.method)).collect();
        let placed = place_labels(&anchors, &texts, LABEL_FONT, POINT_R, area_rect(x, y));
        draw_labels(&mut ov, &anchors, &texts, &colours, &placed, LABEL_FONT);
        if !entries.is_empty() {
            legend(&mut ov, (legend_x, 40.0), None, &entries);
        }
        Ok(())
    })?;
    Ok(ov.splice(buf))
}
