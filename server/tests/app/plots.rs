//! The plots the server serves are drawn by the one plotting module of the
//! tables crate: checked on their SVG geometry (legend off the data, labels
//! apart, error bars for rows with two or more seeds), with the same colour
//! per method as `d3il tables --figure` and readable behaviour names, against
//! the real server on 127.0.0.1 over the paper's rows.

use crate::svg_geometry;

use d3il_protocol::*;
use d3il_tables::plot::{hex, method_colour};
use d3il_tables::{render_figure, FigureKind, SourceFilter};
use d3il_test_support::server::*;
use std::collections::BTreeMap;
use svg_geometry::{assert_readable, parse};

/// Stores a completed paper-protocol evaluation as the worker would.
async fn evaluated(
    app: &TestServer,
    method: &str,
    task: TaskId,
    training_seed: i64,
    success: f64,
    rollouts: Vec<RolloutRecord>,
) -> i64 {
    let store = &app.state().store;
    let id = queued_submission(store, method, task, ProtocolKind::Paper, training_seed, 1).await;
    let job = store.job_for(id).await.expect("job");
    let est = |v: f64| {
        d3il_protocol::Estimate::with_interval(
            v,
            v - 0.05,
            v + 0.05,
            d3il_protocol::IntervalMethod::KornGraubard,
        )
    };
    let result = EvalResult {
        manifest: ProtocolManifest {
            rollouts_per_context: rollouts.len().max(1),
            ..d3il_test_support::test_manifest(task, ProtocolKind::Paper)
        },
        metrics: Metrics {
            success_rate: est(success),
            behaviour_entropy: est(0.5),
            conditional_entropy: est(0.3 + 0.1 * training_seed as f64),
            stacking: None,
            stacking_levels: None,
            inference_ms: 1.5,
        },
        per_context: vec![],
        rollouts,
        rollouts_ended_unstable: 0,
    };
    store
        .complete_job(job.id, id, &result, &[])
        .await
        .expect("complete");
    id
}

#[tokio::test]
async fn served_plots_are_readable_and_colour_methods_as_the_cli_does() {
    let app = spawn_app().await;
    // Two seeds of an evaluated BESO on Aligning: one row with an error bar.
    for seed in 0..2 {
        evaluated(
            &app,
            "BESO",
            TaskId::Aligning,
            seed,
            0.8 + 0.05 * seed as f64,
            vec![],
        )
        .await;
    }
    let mut checked = 0;
    for task in TaskId::ALL {
        for obs in ["state", "image"] {
            let (s, svg) = app
                .get_text(&format!(
                    "/plots/tasks/{}/pareto.svg?obs={obs}",
                    task.slug()
                ))
                .await;
            assert_eq!(s, 200, "{task} {obs}");
            let f = assert_readable(&svg, &format!("{task} {obs} pareto"));
            if f.points.is_empty() {
                // No rows for this task and observation type (Avoiding,
                // image): the figure says so instead of drawing empty axes.
                assert!(svg.contains("No results yet"), "{task} {obs}: {svg}");
                continue;
            }
            checked += 1;
            assert!(
                f.error_bars >= 3 * f.points.len(),
                "{task} {obs}: error bars"
            );
            // Every legend entry has its method's one colour.
            for (label, colour) in &f.legend_entries {
                let method = label.trim_end_matches(" (evaluated)");
                if method != "Pareto front" {
                    assert_eq!(*colour, hex(method_colour(method)), "{task}: {label}");
                }
            }
        }
    }
    assert!(checked >= 10, "only {checked} plots had points");
    let (s, svg) = app
        .get_text("/plots/tasks/aligning/pareto.svg?obs=state")
        .await;
    assert_eq!(s, 200);
    let f = parse(&svg);
    let web: BTreeMap<String, String> = f.legend_entries.iter().cloned().collect();
    assert!(web.contains_key("BESO (evaluated)"), "{web:?}");
    assert!(
        f.labels
            .iter()
            .any(|l| l.group == "labels" && l.text == "BESO (evaluated)"),
        "the evaluated point is labelled as such"
    );
    assert_eq!(
        web.get("BESO (evaluated)"),
        web.get("BESO"),
        "evaluated rows keep the method's colour"
    );
    // The CLI figure from the same database (what `d3il tables --figure` draws).
    let cells = app.state().store.result_cells(None).await.unwrap();
    let cli = parse(
        &render_figure(
            &cells,
            FigureKind::Pareto,
            ObsType::State,
            SourceFilter::Both,
            &BTreeMap::new(),
        )
        .unwrap(),
    );
    for (label, colour) in &cli.legend_entries {
        let method = label.split([' ', '†', '‡']).next().unwrap();
        if let Some(c) = web.get(method) {
            assert_eq!(c, colour, "{method}: web and CLI colours differ");
        }
    }
    let (s, svg) = app
        .get_text("/plots/tasks/aligning/data-fraction.svg?obs=state")
        .await;
    assert_eq!(s, 200);
    let f = assert_readable(&svg, "data fraction");
    assert!(f.error_bars > 0 && f.legend.is_some());
}

#[tokio::test]
async fn behaviour_bars_name_sorting_orders_and_print_integer_counts() {
    let app = spawn_app().await;
    // Sorting-2: 7 × red-then-blue, 3 × blue-then-red, 2 failures.
    // docs/original-d3il.md §11.1.6: RB = 64, BR = 128.
    let codes = [64u32, 128];
    let rollouts = (0..12)
        .map(|i| RolloutRecord {
            context_index: 0,
            rollout_index: i,
            success: i < 10,
            behaviour: serde_json::json!(codes[usize::from(i >= 7)]),
            steps: 10,
            path: None,
            failure: None,
            ending: None,
            trace: None,
        })
        .collect();
    let id = evaluated(&app, "Mine", TaskId::Sorting2, 0, 10.0 / 12.0, rollouts).await;
    let (s, svg) = app
        .get_text(&format!("/plots/submissions/{id}/behaviours.svg"))
        .await;
    assert_eq!(s, 200);
    let f = assert_readable(&svg, "behaviour bars");
    let texts: Vec<&str> = f.labels.iter().map(|l| l.text.as_str()).collect();
    for want in ["RB", "BR", "7", "3"] {
        assert!(texts.contains(&want), "{want} not in {texts:?}");
    }
    assert!(texts.iter().all(|t| !t.ends_with(".0")), "{texts:?}");
    // The submission page embeds the same figure.
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert!(page.contains(">RB</text>") && page.contains(">BR</text>"));
}

/// One plotting module: the server draws no figure itself (no plotters
/// dependency, no SVG drawing code); it hands rows to `d3il_tables::board`.
#[test]
fn the_server_draws_no_figure_of_its_own() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    assert!(
        !manifest.contains("plotters"),
        "server/Cargo.toml depends on plotters"
    );
    let mut stack = vec![root.join("src")];
    let mut files = 0;
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                files += 1;
                let src = std::fs::read_to_string(&p).unwrap();
                for needle in ["plotters::", "SVGBackend", "<circle", "<polyline"] {
                    assert!(!src.contains(needle), "{} draws ({needle})", p.display());
                }
            }
        }
    }
    assert!(files > 10);
}
