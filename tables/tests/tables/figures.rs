//! Figures: well-formed SVG with the expected marks, from the paper data and
//! from synthetic Avoiding paths.

use d3il_protocol::{paper, ObsType};
use d3il_tables::{render_avoiding_paths, render_figure, FigureKind, SourceFilter, TablesError};
use std::collections::BTreeMap;

fn texts(doc: &roxmltree::Document) -> Vec<String> {
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| n.text().unwrap_or("").trim().to_string())
        .collect()
}

fn count(doc: &roxmltree::Document, tag: &str) -> usize {
    doc.descendants().filter(|n| n.has_tag_name(tag)).count()
}

#[test]
fn datasize_figure_draws_one_curve_per_method_and_metric() {
    let cells = paper::load_embedded().cells();
    let svg = render_figure(
        &cells,
        FigureKind::Datasize,
        ObsType::State,
        SourceFilter::Reported,
        &BTreeMap::new(),
    )
    .expect("figure");
    let doc = roxmltree::Document::parse(&svg).expect("well-formed SVG");
    let t = texts(&doc);
    for m in paper::PAPER_METHOD_ORDER {
        assert!(t.iter().any(|s| s.starts_with(m)), "legend lacks {m}");
    }
    assert!(t.iter().any(|s| s == "Aligning (T2): Success rate"));
    assert!(t.iter().any(|s| s == "Aligning (T2): Entropy"));
    // 11 methods x 2 panels curves + 11 legend samples (plus the axes).
    assert!(count(&doc, "polyline") >= 2 * 11 + 11);
    // One marker per data point (11 methods x 5 fractions x 2 panels) + legend.
    assert_eq!(count(&doc, "circle"), 11 * 5 * 2 + 11);
}

#[test]
fn pareto_figure_has_a_panel_per_task_and_a_point_per_method() {
    let cells = paper::load_embedded().cells();
    let svg = render_figure(
        &cells,
        FigureKind::Pareto,
        ObsType::State,
        SourceFilter::Reported,
        &BTreeMap::new(),
    )
    .expect("figure");
    let doc = roxmltree::Document::parse(&svg).expect("well-formed SVG");
    let t = texts(&doc);
    for task in ["Avoiding (T1)", "Sorting-6 (T4)", "Stacking-3 (T5)"] {
        assert!(t.iter().any(|s| s == task), "no panel {task}");
    }
    // 9 tasks x 11 methods points, plus 11 legend markers.
    assert_eq!(count(&doc, "circle"), 9 * 11 + 11);
}

#[test]
fn avoiding_paths_are_coloured_by_behaviour() {
    // Three synthetic paths from the start past the obstacles: two share a
    // behaviour (left/top/top, code 37), one goes right (code 138).
    let path = |xs: [f32; 4]| -> Vec<[f32; 2]> {
        let ys = [-0.28f32, -0.1, 0.08, 0.26];
        let mut p: Vec<[f32; 2]> = xs.iter().zip(ys).map(|(&x, y)| [x, y]).collect();
        p.push([xs[3], 0.36]);
        p
    };
    let paths = vec![
        (serde_json::json!(37), path([0.525, 0.43, 0.38, 0.30])),
        (serde_json::json!(138), path([0.525, 0.57, 0.50, 0.575])),
        (serde_json::json!(37), path([0.525, 0.42, 0.37, 0.29])),
    ];
    let svg = render_avoiding_paths(&paths, "Avoiding: test submission").expect("figure");
    let doc = roxmltree::Document::parse(&svg).expect("well-formed SVG");
    let t = texts(&doc);
    assert!(t.iter().any(|s| s == "37 (2)"), "{t:?}");
    assert!(t.iter().any(|s| s == "138 (1)"), "{t:?}");
    assert!(t.iter().any(|s| s == "Avoiding: test submission"));
    // Six obstacles drawn as polygons.
    assert_eq!(count(&doc, "polygon"), 6);
    // The paths are the 5-point polylines, drawn in input order: the two
    // code-37 paths share a colour, the code-138 path has another.
    let strokes: Vec<String> = doc
        .descendants()
        .filter(|n| n.has_tag_name("polyline"))
        .filter(|n| {
            n.attribute("points")
                .is_some_and(|p| p.split_whitespace().count() == 5)
        })
        .filter_map(|n| n.attribute("stroke").map(String::from))
        .collect();
    assert_eq!(strokes.len(), 3, "{strokes:?}");
    assert_eq!(strokes[0], strokes[2]);
    assert_ne!(strokes[0], strokes[1]);

    assert!(matches!(
        render_avoiding_paths(&[], "empty"),
        Err(TablesError::NoFigureData { .. })
    ));
    let bad = vec![(serde_json::json!(1), vec![[f32::NAN, 0.0]])];
    assert!(matches!(
        render_avoiding_paths(&bad, "nan"),
        Err(TablesError::NonFinite { .. })
    ));
}
