//! The figures are readable, checked on their SVG geometry over the paper's
//! results: the legend covers no data point, no two texts overlap (boxes
//! estimated from font size × characters), error bars (seed std) are drawn
//! where a row has two or more seeds, one colour per method in the CLI and
//! the server figures alike, axes fitted to the data, readable behaviour
//! names, integer counts and the Avoiding obstacles drawn from the task's
//! definition.

use crate::svg_geometry;

use d3il_protocol::behaviour::avoiding;
use d3il_protocol::paper::{self, PAPER_METHOD_ORDER};
use d3il_protocol::{ObsType, ResultCell, TaskId};
use d3il_tables::board::{
    behaviour_bars_svg, data_fraction_svg, pareto_svg, FractionSeries, ParetoPoint,
};
use d3il_tables::plot::{hex, method_colour, Est};
use d3il_tables::{render_avoiding_paths, render_figure, FigureKind, SourceFilter};
use serde_json::json;
use std::collections::BTreeMap;
use svg_geometry::{assert_readable, parse};

/// Writes a figure to `$D3IL_FIGURE_DIR` (when set) for a look by eye.
fn dump(name: &str, svg: &str) {
    if let Some(dir) = std::env::var_os("D3IL_FIGURE_DIR") {
        std::fs::write(std::path::Path::new(&dir).join(format!("{name}.svg")), svg).expect("write");
    }
}

fn cells() -> Vec<ResultCell> {
    paper::load_embedded().cells()
}

/// The server's points for one task title, as `leaderboard::pareto_points`
/// builds them from the paper's rows.
fn board_points(cells: &[ResultCell], title: &str, obs: ObsType) -> Vec<ParetoPoint> {
    cells
        .iter()
        .filter(|c| c.table == "main" && c.task == title && c.obs == obs)
        .map(|c| ParetoPoint {
            label: c.method.clone(),
            method: c.method.clone(),
            entropy: Est::new(c.entropy.mean, c.entropy.std, c.n_seeds),
            success: Est::new(c.success_rate.mean, c.success_rate.std, c.n_seeds),
            evaluated: false,
        })
        .collect()
}

fn titles(cells: &[ResultCell], obs: ObsType) -> Vec<String> {
    let mut t: Vec<String> = cells
        .iter()
        .filter(|c| c.table == "main" && c.obs == obs)
        .map(|c| c.task.clone())
        .collect();
    t.sort();
    t.dedup();
    t
}

#[test]
fn cli_figures_keep_legends_off_the_data_and_labels_apart() {
    let cells = cells();
    for (kind, obs) in [
        (FigureKind::Pareto, ObsType::State),
        (FigureKind::Pareto, ObsType::Image),
        (FigureKind::Datasize, ObsType::State),
    ] {
        let svg = render_figure(&cells, kind, obs, SourceFilter::Reported, &BTreeMap::new())
            .expect("figure");
        dump(&format!("cli-{kind}-{obs}"), &svg);
        let f = assert_readable(&svg, &format!("{kind} {obs}"));
        assert!(f.legend.is_some(), "{kind}: no legend");
        assert!(!f.points.is_empty(), "{kind}: no points");
        if kind == FigureKind::Pareto {
            let labels = f.labels.iter().filter(|l| l.group == "labels").count();
            assert_eq!(labels, f.points.len(), "{obs}: every point is labelled");
        }
        // The paper's rows have 4 to 6 seeds: every point has its error bar
        // (a bar and two caps, in one or both directions).
        assert!(
            f.error_bars >= 3 * f.points.len(),
            "{kind} {obs}: {} error-bar lines for {} points",
            f.error_bars,
            f.points.len()
        );
    }
}

#[test]
fn server_pareto_plots_label_every_point_without_overlap() {
    let cells = cells();
    for obs in [ObsType::State, ObsType::Image] {
        for title in titles(&cells, obs) {
            let pts = board_points(&cells, &title, obs);
            let svg = pareto_svg(&title, &pts).expect("figure");
            dump(&format!("web-pareto-{obs}-{}", &title[..4]), &svg);
            let f = assert_readable(&svg, &title);
            let drawn = pts
                .iter()
                .filter(|p| p.entropy.mean.is_finite() && p.success.mean.is_finite())
                .count();
            assert_eq!(f.points.len(), drawn, "{title}");
            let labels: Vec<&str> = f
                .labels
                .iter()
                .filter(|l| l.group == "labels")
                .map(|l| l.text.as_str())
                .collect();
            assert_eq!(
                labels.len(),
                drawn,
                "{title} ({obs}): a point lost its label: {labels:?}"
            );
            assert!(f.error_bars >= 3 * drawn, "{title}: error bars missing");
        }
    }
    // The case of the issue: IBC and BeT on the Avoiding plot.
    let svg = pareto_svg(
        "Avoiding",
        &board_points(&cells, "Avoiding (T1)", ObsType::State),
    )
    .unwrap();
    let f = parse(&svg);
    let ibc = f
        .labels
        .iter()
        .find(|l| l.group == "labels" && l.text == "IBC")
        .expect("IBC");
    let bet = f
        .labels
        .iter()
        .find(|l| l.group == "labels" && l.text == "BeT-MLP")
        .expect("BeT");
    assert!(!ibc.bbox.overlaps(&bet.bbox));
}

#[test]
fn axes_fit_the_data_so_low_scoring_tasks_are_not_buried() {
    let cells = cells();
    for title in ["Sorting-6 (T4)", "Stacking-3 (T5)"] {
        let svg = pareto_svg(title, &board_points(&cells, title, ObsType::State)).unwrap();
        let f = parse(&svg);
        let ys: Vec<f64> = f.points.iter().map(|p| p.at.1).collect();
        let xs: Vec<f64> = f.points.iter().map(|p| p.at.0).collect();
        let spread = |v: &[f64]| {
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        // The plotting area is about 390 px tall and 560 px wide; on fixed
        // 0-1 axes these points would lie within some 20 px of the origin.
        assert!(
            spread(&ys) > 90.0,
            "{title}: success spread {} px",
            spread(&ys)
        );
        assert!(
            spread(&xs) > 140.0,
            "{title}: entropy spread {} px",
            spread(&xs)
        );
    }
}

#[test]
fn one_colour_per_method_in_every_figure() {
    let cells = cells();
    let cli = parse(
        &render_figure(
            &cells,
            FigureKind::Pareto,
            ObsType::State,
            SourceFilter::Reported,
            &BTreeMap::new(),
        )
        .unwrap(),
    );
    let web = parse(
        &pareto_svg(
            "Avoiding",
            &board_points(&cells, "Avoiding (T1)", ObsType::State),
        )
        .unwrap(),
    );
    let ds = parse(
        &render_figure(
            &cells,
            FigureKind::Datasize,
            ObsType::State,
            SourceFilter::Reported,
            &BTreeMap::new(),
        )
        .unwrap(),
    );
    for m in PAPER_METHOD_ORDER {
        let want = hex(method_colour(m));
        for (name, f) in [
            ("cli pareto", &cli),
            ("web pareto", &web),
            ("cli datasize", &ds),
        ] {
            let got: Vec<&String> = f
                .legend_entries
                .iter()
                .filter(|(l, _)| l.trim_end_matches(['†', '‡']) == m)
                .map(|(_, c)| c)
                .collect();
            assert!(!got.is_empty(), "{name}: {m} not in the legend");
            assert!(
                got.iter().all(|c| **c == want),
                "{name}: {m} drawn in {got:?}, not {want}"
            );
        }
    }
    // Every point's colour is its legend entry's: distinct methods, distinct colours.
    let colours: std::collections::BTreeSet<&str> =
        web.points.iter().map(|p| p.fill.as_str()).collect();
    assert_eq!(colours.len(), 11, "eleven methods, eleven colours");
}

#[test]
fn single_seed_points_have_no_error_bars() {
    let p = |m: &str, s: f64| ParetoPoint {
        label: m.into(),
        method: m.into(),
        entropy: Est::new(0.5, 0.1, 1),
        success: Est::new(s, 0.1, 1),
        evaluated: true,
    };
    let f = assert_readable(
        &pareto_svg("t", &[p("A", 0.2), p("B", 0.8)]).unwrap(),
        "one seed",
    );
    assert_eq!(f.error_bars, 0);
    assert_eq!(f.points.len(), 2);
}

#[test]
fn data_fraction_lines_have_error_bars_and_an_outside_legend() {
    let cells = cells();
    let mut by: BTreeMap<String, Vec<(f64, Est, Est)>> = BTreeMap::new();
    for c in cells
        .iter()
        .filter(|c| c.table == "datasize" && c.obs == ObsType::State)
    {
        by.entry(c.method.clone()).or_default().push((
            c.data_fraction,
            Est::new(c.success_rate.mean, c.success_rate.std, c.n_seeds),
            Est::new(c.entropy.mean, c.entropy.std, c.n_seeds),
        ));
    }
    assert!(!by.is_empty());
    let series: Vec<FractionSeries> = by
        .into_iter()
        .map(|(m, mut points)| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            FractionSeries {
                label: m.clone(),
                method: m,
                evaluated: false,
                points,
            }
        })
        .collect();
    let svg = data_fraction_svg("Aligning", &series).unwrap();
    dump("web-fraction", &svg);
    let f = assert_readable(&svg, "data fraction");
    let n: usize = series.iter().map(|s| s.points.len()).sum();
    assert_eq!(f.points.len(), 2 * n);
    assert_eq!(f.error_bars, 3 * 2 * n);
    let lg = f.legend.expect("legend");
    assert!(
        f.points.iter().all(|p| p.at.0 < lg.x0),
        "the legend is right of the plots"
    );
}

#[test]
fn behaviour_bars_show_names_and_integer_counts() {
    let names = [
        (TaskId::Sorting2, json!(64)),
        (TaskId::Stacking, json!("rgb")),
        (
            TaskId::Avoiding,
            json!([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
        ),
    ];
    let counts: Vec<(String, usize)> = names
        .iter()
        .zip([70, 12, 3])
        .map(|((t, v), n)| (d3il_tables::board::behaviour_label(*t, v), n))
        .collect();
    assert_eq!(counts[0].0, "RB");
    assert_eq!(counts[1].0, "rgb");
    assert_eq!(counts[2].0, "1-2-3");
    let svg = behaviour_bars_svg("Behaviours", &counts).unwrap();
    dump("web-behaviours", &svg);
    let f = assert_readable(&svg, "behaviour bars");
    let texts: Vec<&str> = f.labels.iter().map(|l| l.text.as_str()).collect();
    for want in ["RB", "rgb", "1-2-3", "70", "12", "3"] {
        assert!(texts.contains(&want), "{want} missing from {texts:?}");
    }
    assert!(
        texts.iter().all(|t| !t.ends_with(".0")),
        "a count printed as a float: {texts:?}"
    );
}

#[test]
fn avoiding_paths_draw_the_task_obstacles_and_name_the_paths() {
    // Three straight-ish paths through the field's gaps.
    let path =
        |x: f32| -> Vec<[f32; 2]> { (0..60).map(|i| [x, -0.28 + i as f32 * 0.011]).collect() };
    let bits = |b: [f64; 9]| json!(b.to_vec());
    let paths = vec![
        (
            bits([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
            path(0.45),
        ),
        (
            bits([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
            path(0.46),
        ),
        (
            bits([0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
            path(0.7),
        ),
    ];
    let svg = render_avoiding_paths(&paths, "paths").unwrap();
    dump("paths", &svg);
    let f = assert_readable(&svg, "avoiding paths");
    let doc = roxmltree::Document::parse(&svg).unwrap();
    let obstacles: Vec<(f64, f64)> = doc
        .descendants()
        .filter(|n| n.has_tag_name("polygon") && n.attribute("fill") == Some("#444444"))
        .map(|n| {
            let pts: Vec<(f64, f64)> = n
                .attribute("points")
                .unwrap()
                .split_whitespace()
                .map(|p| {
                    let (a, b) = p.split_once(',').unwrap();
                    (a.parse().unwrap(), b.parse().unwrap())
                })
                .collect();
            let k = pts.len() as f64;
            (
                pts.iter().map(|p| p.0).sum::<f64>() / k,
                pts.iter().map(|p| p.1).sum::<f64>() / k,
            )
        })
        .collect();
    assert_eq!(obstacles.len(), avoiding::obstacles().len());
    // Pixel positions follow the field: row 1 below row 2 below row 3, the
    // middle cylinders in line.
    let field = avoiding::obstacles();
    for (a, b) in [(0, 1), (1, 3)] {
        assert!(obstacles[a].1 > obstacles[b].1, "row order on screen");
        assert!(field[a].y < field[b].y);
    }
    assert!((obstacles[0].0 - obstacles[4].0).abs() < 1.0);
    let legend: Vec<&str> = f.legend_entries.iter().map(|(l, _)| l.as_str()).collect();
    assert!(legend.contains(&"1-2-3 (2)"), "{legend:?}");
    assert!(legend.contains(&"2-3-4 (1)"), "{legend:?}");
}

#[test]
fn snapshot_of_a_pareto_plot_with_error_bars() {
    let cells = cells();
    let svg = pareto_svg(
        "Avoiding (T1): success vs diversity",
        &board_points(&cells, "Avoiding (T1)", ObsType::State),
    )
    .unwrap();
    assert!(parse(&svg).error_bars > 0);
    insta::assert_snapshot!(svg);
}
