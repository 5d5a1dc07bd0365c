//! A task's Robustness view (docs/robustness.md): per suite
//! version and protocol, methods × axes with retained-success scores and
//! intervals, per-axis degradation curves and robustness against
//! conditional behaviour entropy. A method's training seeds are aggregated
//! as on the boards (mean ± sample std, `SuiteGroup::methods`); the rows
//! per seed, with their intervals, are in a table below it; a row whose
//! score intervals come from too few initial states to cover as they say
//! is labelled with their measured coverage. Tables and
//! figures come from `d3il_tables::robustness` (as `d3il tables --table
//! robustness`).

use super::format::method_url;
use super::render;
use crate::error::PageError;
use crate::http::extract::Param;
use crate::state::AppState;
use askama::Template;
use axum::extract::State;
use axum::response::Html;
use d3il_protocol::TaskId;
use d3il_tables::robustness::figures::{degradation_svg, score_vs_entropy_svg};
use d3il_tables::robustness::{
    group_by_suite, interval_text, note, seed_text, RobustnessEntry, SCORE_COVERAGE_COLUMN,
};

/// A method over its training seeds.
struct MethodRow {
    rank: usize,
    method: String,
    method_url: String,
    seeds: String,
    control: String,
    entropy: String,
    scores: Vec<String>,
    overall: String,
}

struct Row {
    rank: usize,
    method: String,
    method_url: String,
    seed: i64,
    submission: i64,
    control: String,
    entropy: String,
    scores: Vec<String>,
    overall: String,
    /// The label of its score intervals when their measured coverage is
    /// below the nominal 95 % (too few initial states); empty otherwise.
    coverage: String,
}

struct Figure {
    caption: String,
    svg: String,
}

struct Group {
    title: String,
    anchor: String,
    axes: Vec<String>,
    methods: Vec<MethodRow>,
    rows: Vec<Row>,
    /// Rows whose score intervals carry a coverage label.
    labelled: usize,
    figures: Vec<Figure>,
}

#[derive(Template)]
#[template(path = "robustness.html")]
struct RobustnessPage {
    title: &'static str,
    slug: &'static str,
    groups: Vec<Group>,
    note: String,
    coverage_column: &'static str,
}

pub(super) async fn robustness_page(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
) -> Result<Html<String>, PageError> {
    let entries: Vec<RobustnessEntry> = state
        .store
        .robustness_rows(Some(task))
        .await?
        .into_iter()
        .map(|r| r.into_entry())
        .collect();
    let mut groups = Vec::new();
    for (i, g) in group_by_suite(&entries).iter().enumerate() {
        let rows: Vec<Row> = g
            .entries
            .iter()
            .enumerate()
            .map(|(rank, e)| Row {
                rank: rank + 1,
                method: e.method.clone(),
                method_url: method_link(&e.method),
                seed: e.training_seed,
                submission: e.submission_id,
                control: interval_text(&Some(e.doc.control.metrics.success_rate)),
                entropy: format!("{:.3}", e.doc.control.metrics.conditional_entropy.value),
                scores: g
                    .axes
                    .iter()
                    .map(|&a| interval_text(&e.axis_score(a)))
                    .collect(),
                overall: interval_text(&e.doc.overall),
                coverage: e.score_coverage_text(),
            })
            .collect();
        let methods = g
            .methods()
            .iter()
            .enumerate()
            .map(|(rank, m)| {
                let n = m.seeds.len();
                MethodRow {
                    rank: rank + 1,
                    method: m.method.clone(),
                    method_url: method_link(&m.method),
                    seeds: m.seed_list(),
                    control: seed_text(&Some(m.control), n),
                    entropy: seed_text(&Some(m.entropy), n),
                    scores: m.axes.iter().map(|a| seed_text(a, n)).collect(),
                    overall: seed_text(&m.overall, n),
                }
            })
            .collect();
        let internal = |e: d3il_tables::TablesError| {
            PageError(crate::error::AppError::Internal(e.to_string()))
        };
        let mut figures = vec![Figure {
            caption: "Overall robustness score against level 0's conditional behaviour entropy (does diversity buy robustness?)".into(),
            svg: score_vs_entropy_svg(g).map_err(internal)?,
        }];
        for &axis in &g.axes {
            figures.push(Figure {
                caption: format!(
                    "{axis}: success rate per level (level 0 = the control arm), 95 % intervals"
                ),
                svg: degradation_svg(g, axis).map_err(internal)?,
            });
        }
        groups.push(Group {
            title: g.title(),
            anchor: format!("suite-{}", i + 1),
            axes: g.axes.iter().map(|a| a.to_string()).collect(),
            methods,
            labelled: rows.iter().filter(|r| !r.coverage.is_empty()).count(),
            rows,
            figures,
        });
    }
    render(&RobustnessPage {
        title: task.title(),
        slug: task.slug(),
        groups,
        note: note(),
        coverage_column: SCORE_COVERAGE_COLUMN,
    })
}

/// The method page of a row of this view. The zoo's rows are labelled
/// `METHOD (zoo)` (`Store::robustness_rows`) to keep them apart from
/// submitted methods; their page is the paper method's.
fn method_link(label: &str) -> String {
    method_url(label.strip_suffix(" (zoo)").unwrap_or(label))
}
