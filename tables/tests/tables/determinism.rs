//! The same cells give byte-identical output, whatever order they come in
//! (the store may return rows in any order).

use d3il_protocol::{paper, ObsType, ResultCell};
use d3il_tables::{
    render_avoiding_paths, render_figure, render_table, FigureKind, Format, SourceFilter, TableKind,
};
use std::collections::BTreeMap;

fn orders() -> Vec<Vec<ResultCell>> {
    let cells = paper::load_embedded().cells();
    let mut reversed = cells.clone();
    reversed.reverse();
    let mut rotated = cells.clone();
    rotated.rotate_left(97);
    // A deterministic shuffle: stride through the cells with a step coprime to their count.
    let n = cells.len();
    let step = (2..n)
        .find(|s| gcd(*s, n) == 1 && *s > n / 3)
        .expect("coprime step");
    let strided: Vec<ResultCell> = (0..n).map(|i| cells[(i * step) % n].clone()).collect();
    vec![cells, reversed, rotated, strided]
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[test]
fn tables_are_byte_identical_for_any_input_order() {
    let orders = orders();
    for kind in TableKind::ALL {
        for obs in [ObsType::State, ObsType::Image] {
            for format in Format::ALL {
                for source in SourceFilter::ALL {
                    let outs: Vec<String> = orders
                        .iter()
                        .map(|c| {
                            render_table(c, kind, obs, format, source)
                                .unwrap_or_else(|e| e.to_string())
                        })
                        .collect();
                    for o in &outs[1..] {
                        assert_eq!(o, &outs[0], "{kind} {obs} {format} {source}");
                    }
                }
            }
        }
    }
}

#[test]
fn figures_are_byte_identical_for_any_input_order() {
    let orders = orders();
    for (kind, obs) in [
        (FigureKind::Datasize, ObsType::State),
        (FigureKind::Pareto, ObsType::State),
        (FigureKind::Pareto, ObsType::Image),
    ] {
        let outs: Vec<String> = orders
            .iter()
            .map(|c| {
                render_figure(c, kind, obs, SourceFilter::Both, &BTreeMap::new()).expect("figure")
            })
            .collect();
        for o in &outs[1..] {
            assert_eq!(o, &outs[0], "{kind} {obs}");
        }
    }
    let paths = vec![
        (
            serde_json::json!([1, 0, 0]),
            vec![[0.5f32, -0.28], [0.45, 0.0], [0.4, 0.36]],
        ),
        (
            serde_json::json!([0, 1, 0]),
            vec![[0.5f32, -0.28], [0.55, 0.0], [0.6, 0.36]],
        ),
    ];
    let a = render_avoiding_paths(&paths, "t").expect("paths");
    let b = render_avoiding_paths(&paths, "t").expect("paths");
    assert_eq!(a, b);
}
