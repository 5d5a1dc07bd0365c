//! The leaderboard's figures (the server's pages and plot endpoints draw
//! these): one task's success-vs-entropy plane with its Pareto front, the
//! data-fraction lines and a submission's behaviour bars. The Pareto front and
//! the handling of missing values are the paper figures' own
//! ([`crate::figures::pareto_front`]: points without a finite success rate and
//! entropy are not drawn).

use crate::figures::pareto_front;
use crate::TablesError;
use plotters::prelude::*;

fn perr<E: std::fmt::Debug>(e: E) -> TablesError {
    TablesError::Plot(format!("{e:?}"))
}

/// One method on the success-vs-entropy plane.
#[derive(Debug, Clone)]
pub struct ParetoPoint {
    pub label: String,
    pub entropy: f64,
    pub success: f64,
    pub evaluated: bool,
}

const REPORTED: RGBColor = RGBColor(70, 110, 180);
const EVALUATED: RGBColor = RGBColor(215, 95, 30);
const FRONT: RGBColor = RGBColor(40, 150, 80);

/// Success rate vs conditional behaviour entropy with the Pareto front.
pub fn pareto_svg(title: &str, points: &[ParetoPoint]) -> Result<String, TablesError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (720, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(54)
            .build_cartesian_2d(0f64..1.05f64, 0f64..1.05f64)
            .map_err(perr)?;
        chart
            .configure_mesh()
            .x_desc("Conditional behaviour entropy")
            .y_desc("Success rate")
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(perr)?;
        let front = pareto_front(
            &points
                .iter()
                .map(|p| (p.entropy, p.success))
                .collect::<Vec<_>>(),
        );
        chart
            .draw_series(LineSeries::new(front, FRONT.stroke_width(2)))
            .map_err(perr)?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], FRONT.stroke_width(2)));
        for (evaluated, colour, name) in [
            (false, REPORTED, "reported (paper)"),
            (true, EVALUATED, "evaluated here"),
        ] {
            chart
                .draw_series(
                    points
                        .iter()
                        .filter(|p| {
                            p.evaluated == evaluated
                                && p.success.is_finite()
                                && p.entropy.is_finite()
                        })
                        .map(|p| Circle::new((p.entropy, p.success), 5, colour.filled())),
                )
                .map_err(perr)?
                .label(name)
                .legend(move |(x, y)| Circle::new((x + 8, y), 5, colour.filled()));
        }
        chart
            .draw_series(
                points
                    .iter()
                    .filter(|p| p.success.is_finite() && p.entropy.is_finite())
                    .map(|p| {
                        Text::new(
                            p.label.clone(),
                            (p.entropy + 0.012, p.success + 0.012),
                            ("sans-serif", 11).into_font().color(&RGBColor(60, 60, 60)),
                        )
                    }),
            )
            .map_err(perr)?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(200, 200, 200))
            .draw()
            .map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(buf)
}

/// One method's values at each training-data fraction.
#[derive(Debug, Clone)]
pub struct FractionSeries {
    pub label: String,
    /// (fraction, success, entropy)
    pub points: Vec<(f64, f64, f64)>,
}

/// The paper's data-size figure: success (left) and entropy (right) vs the
/// fraction of training data, one line per method.
pub fn data_fraction_svg(title: &str, series: &[FractionSeries]) -> Result<String, TablesError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (960, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(perr)?;
        let (left, right) = root.split_horizontally(480);
        for (area, which, ylab) in [(left, 0, "Success rate"), (right, 1, "Conditional entropy")] {
            let mut chart = ChartBuilder::on(&area)
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d(0f64..1.02f64, 0f64..1.02f64)
                .map_err(perr)?;
            chart
                .configure_mesh()
                .x_desc("Fraction of training data")
                .y_desc(ylab)
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(perr)?;
            for (i, s) in series.iter().enumerate() {
                let colour = Palette99::pick(i).to_rgba();
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .map(|&(f, su, en)| (f, if which == 0 { su } else { en }))
                    .filter(|p| p.1.is_finite())
                    .collect();
                let drawn = chart
                    .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                    .map_err(perr)?;
                if which == 0 {
                    drawn.label(s.label.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                    });
                }
                chart
                    .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
                    .map_err(perr)?;
            }
            if which == 0 && !series.is_empty() {
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::LowerRight)
                    .background_style(WHITE.mix(0.85))
                    .border_style(RGBColor(200, 200, 200))
                    .draw()
                    .map_err(perr)?;
            }
        }
        root.present().map_err(perr)?;
    }
    Ok(buf)
}

/// Compact label of a behaviour code (`[1,0,2]` -> `1-0-2`).
pub fn behaviour_label(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Array(a) => a.iter().map(behaviour_label).collect::<Vec<_>>().join("-"),
        serde_json::Value::String(s) => s.clone(),
        serde_json::Value::Null => "none".into(),
        other => other.to_string(),
    }
}

/// Bar chart of how often each behaviour occurred among successful rollouts.
pub fn behaviour_bars_svg(title: &str, counts: &[(String, usize)]) -> Result<String, TablesError> {
    let n = counts.len().max(1);
    let top = counts.iter().map(|c| c.1).max().unwrap_or(1).max(1) as f64;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (720, 360)).into_drawing_area();
        root.fill(&WHITE).map_err(perr)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(60)
            .y_label_area_size(50)
            .build_cartesian_2d(0f64..n as f64, 0f64..top * 1.1)
            .map_err(perr)?;
        let labels: Vec<String> = counts.iter().map(|c| c.0.clone()).collect();
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n.min(30))
            .x_label_formatter(&|x| {
                let i = x.floor() as usize;
                labels.get(i).cloned().unwrap_or_default()
            })
            .x_desc("Behaviour")
            .y_desc("Successful rollouts")
            .draw()
            .map_err(perr)?;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, (_, c))| {
                Rectangle::new(
                    [(i as f64 + 0.15, 0.0), (i as f64 + 0.85, *c as f64)],
                    EVALUATED.filled(),
                )
            }))
            .map_err(perr)?;
        root.present().map_err(perr)?;
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(e: f64, s: f64) -> ParetoPoint {
        ParetoPoint {
            label: format!("{e}/{s}"),
            entropy: e,
            success: s,
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
        let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.entropy, p.success)).collect();
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
