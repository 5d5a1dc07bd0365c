//! `/comparisons/{id}`: a sequential race of two submissions
//! (`POST /api/v1/comparisons`, [`crate::races`]) as it runs: the two
//! policies, the paired counts so far, the e-value and anytime-valid p-value,
//! the decision when reached and the rollouts used against the fixed-size
//! test. Refreshes every 2 seconds while queued or running, with a Cancel
//! button (its starter's or an admin's token).

use super::compare::parse_id;
use super::render;
use crate::error::PageError;
use crate::http::extract::Param;
use crate::races::{ComparisonView, RaceLive};
use crate::state::AppState;
use askama::Template;
use axum::extract::State;
use axum::response::Html;

struct Side {
    id: i64,
    method: String,
}

/// The finished race's lines.
struct Finished {
    decision: String,
    decided_at: String,
    rollouts_used: usize,
    rollouts_full: usize,
    ratio: String,
    fixed_note: String,
    /// The fixed-size comparison of the pairs used: difference, interval, p.
    fixed: String,
    rate_a: String,
    rate_b: String,
}

#[derive(Template)]
#[template(path = "race.html")]
struct RacePage {
    id: i64,
    a: Side,
    b: Side,
    task: String,
    protocol: String,
    alpha: f64,
    delta: String,
    status: String,
    running: bool,
    live: Option<RaceLive>,
    e_value: String,
    p_value: String,
    finished: Option<Finished>,
    error: Option<String>,
    /// Which rule decides (or decided) and what it guarantees.
    rule: String,
    /// The walk against its boundary and the e-value's path, pair by pair.
    walk_svg: Option<String>,
}

pub(super) async fn race_page(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Html<String>, PageError> {
    let row = state.store.comparison(id).await?;
    let view = ComparisonView::of(&row);
    let side = |s: crate::store::SubmissionRow| Side {
        id: s.id,
        method: s.method,
    };
    let a = side(state.store.submission(view.a).await?);
    let b = side(state.store.submission(view.b).await?);
    let finished = view.race_report().map(|r| Finished {
        decision: r
            .decision
            .clone()
            .unwrap_or_else(|| "none at the protocol's full size".into()),
        decided_at: r
            .decided_at
            .map(|p| format!("at pair {p} (initial state {} of {})", r.states_used, r.states_full))
            .unwrap_or_default(),
        rollouts_used: r.rollouts_used,
        rollouts_full: r.rollouts_full,
        ratio: format!("{:.3}", r.rollouts_used as f64 / r.rollouts_full.max(1) as f64),
        fixed_note: r
            .fixed_pairs_for_power_90
            .map(|n| {
                format!("at the discordance observed, the exact sign test needs {n} pairs for 90 % power")
            })
            .unwrap_or_default(),
        fixed: fixed_comparison_line(&r),
        rate_a: format!("{:.3}", r.rate_a),
        rate_b: format!("{:.3}", r.rate_b),
    });
    // The pairs in the test's order: the report's once finished, else the
    // live record's (both absent for races run before they were kept).
    let report = view.race_report();
    let outcomes = report
        .as_ref()
        .map(|r| r.outcomes.clone())
        .filter(|o| !o.is_empty())
        .or_else(|| view.live.as_ref().map(|l| l.outcomes.clone()))
        .unwrap_or_default();
    let horizon = report
        .as_ref()
        .map(|r| r.pairs_full as usize)
        .or_else(|| view.live.as_ref().map(|l| l.states_total as usize))
        .unwrap_or(0);
    let decision = report
        .as_ref()
        .and_then(|r| r.decision.clone())
        .or_else(|| view.live.as_ref().and_then(|l| l.decision.clone()));
    let rule = d3il_metrics::horizon::decided_by(view.alpha, horizon, decision.as_deref());
    let walk_svg = match d3il_protocol::race::pairs_of(&outcomes) {
        Ok(pairs) if !pairs.is_empty() => Some(
            d3il_tables::race::race_svg(&pairs, view.alpha, horizon)
                .map_err(|e| PageError(crate::error::AppError::Internal(e.to_string())))?,
        ),
        _ => None,
    };
    let (e_value, p_value) = match (&view.live, view.race_report()) {
        (_, Some(r)) => (format!("{:.3}", r.e_value), format!("{:.4}", r.p_value)),
        (Some(l), None) => (format!("{:.3}", l.e_value), format!("{:.4}", l.p_value)),
        (None, None) => ("1.000".into(), "1.0000".into()),
    };
    render(&RacePage {
        id,
        a,
        b,
        task: view.task.clone(),
        protocol: view.protocol.clone(),
        alpha: view.alpha,
        delta: view
            .delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default(),
        running: matches!(view.status.as_str(), "queued" | "running"),
        status: view.status.clone(),
        live: view.live.clone(),
        e_value,
        p_value,
        finished,
        error: view.error.clone(),
        rule,
        walk_svg,
    })
}

/// The fixed-size comparison of a finished race's pairs in words
/// ([`crate::races::fixed_comparison`]).
fn fixed_comparison_line(r: &d3il_protocol::race::RaceReport) -> String {
    let f = crate::races::fixed_comparison(r);
    let d = &f.difference;
    let interval = match d.interval() {
        Some(_) => format!(
            "{:.0} % interval {} ({})",
            100.0 * (1.0 - r.alpha),
            d.interval_text(3),
            d.interval_note()
        ),
        None => d.interval_note(),
    };
    format!(
        "Fixed-size comparison of the {} pairs used: A − B {:+.3}, {interval}, exact McNemar p-value {:.4} (0 lies outside the interval exactly when p ≤ {}; for reference: neither is valid after the race's data-dependent stop)",
        f.pairs, d.value, f.p_value, r.alpha
    )
}

/// The `/compare` page's "Race them" form: two submission ids, the
/// protocol and the submitter's token.
#[derive(serde::Deserialize)]
pub(super) struct RaceForm {
    a: String,
    b: String,
    #[serde(default)]
    protocol: String,
    #[serde(default)]
    token: String,
}

/// `POST /comparisons` from the form: the API's checks and race
/// (`races::create`), then on to the live page.
pub(super) async fn race_post(
    State(state): State<AppState>,
    axum::Form(f): axum::Form<RaceForm>,
) -> Result<axum::response::Response, PageError> {
    use axum::response::IntoResponse;
    let who = crate::auth::authenticate_token(&state, f.token.trim()).await?;
    let req = crate::races::ComparisonRequest {
        a: parse_id("a", &f.a)?,
        b: parse_id("b", &f.b)?,
        task: None,
        alpha: None,
        delta: None,
        protocol: Some(f.protocol.trim().to_string()).filter(|p| !p.is_empty()),
        seed: None,
    };
    let race = crate::races::create(&state, &who, &req).await?;
    Ok(axum::response::Redirect::to(&format!("/comparisons/{race}")).into_response())
}

/// The race page's Cancel button: `POST /comparisons/{id}/cancel` with the
/// starter's (or an admin's) token (`races::cancel_as`, the API's rule),
/// then back to the page.
pub(super) async fn race_cancel_post(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    axum::Form(f): axum::Form<super::cancel::CancelForm>,
) -> Result<axum::response::Response, PageError> {
    use axum::response::IntoResponse;
    let who = crate::auth::authenticate_token(&state, f.token.trim()).await?;
    crate::races::cancel_as(&state, id, &who).await?;
    Ok(axum::response::Redirect::to(&format!("/comparisons/{id}")).into_response())
}
