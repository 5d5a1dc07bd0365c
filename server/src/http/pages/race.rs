//! `/races/{id}`: a race of two submissions (`POST /api/v1/races`,
//! [`crate::races`]) as it runs: the two
//! policies, the paired counts so far, the e-value and anytime-valid p-value,
//! the decision when reached and the rollouts used against the fixed-size
//! test. Refreshes every 2 seconds while queued or running, with a Cancel
//! button (its starter's or an admin's token).

use super::compare::parse_id;
use super::render;
use crate::error::PageError;
use crate::http::extract::Param;
use crate::races::{RaceLive, RaceView};
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
    let row = state.store.race(id).await?;
    let view = RaceView::of(&row);
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
        fixed: d3il_metrics::rate_difference::fixed_size_comparison(r.pairs_used, r.discordant, r.alpha)
            .line(),
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
        task: view.task.to_string(),
        protocol: view.protocol.as_str().to_string(),
        alpha: view.alpha,
        delta: view
            .delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default(),
        running: view.status.is_active(),
        status: view.status.to_string(),
        live: view.live.clone(),
        e_value,
        p_value,
        finished,
        error: view.error.clone(),
        rule,
        walk_svg,
    })
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

/// `POST /races` from the form: the API's checks and race
/// (`races::create`), then on to the live page.
pub(super) async fn race_post(
    State(state): State<AppState>,
    axum::Form(f): axum::Form<RaceForm>,
) -> Result<axum::response::Response, PageError> {
    use axum::response::IntoResponse;
    let who = crate::auth::authenticate_token(&state, f.token.trim()).await?;
    let req = crate::races::RaceRequest {
        a: parse_id("a", &f.a)?,
        b: parse_id("b", &f.b)?,
        task: None,
        alpha: None,
        delta: None,
        protocol: Some(f.protocol.trim().to_string()).filter(|p| !p.is_empty()),
        seed: None,
    };
    let race = crate::races::create(&state, &who, &req).await?;
    Ok(axum::response::Redirect::to(&format!("/races/{race}")).into_response())
}

/// The race page's Cancel button: `POST /races/{id}/cancel` with the
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
    Ok(axum::response::Redirect::to(&format!("/races/{id}")).into_response())
}

/// The race pages' old addresses (`/comparisons…`, before races had their
/// own name): a permanent redirect (308: a form's POST is sent again, with
/// its body) to the same path under `/races`.
pub(super) async fn old_address(
    axum::extract::OriginalUri(uri): axum::extract::OriginalUri,
) -> axum::response::Redirect {
    let path = uri.path().replacen("/comparisons", "/races", 1);
    axum::response::Redirect::permanent(&match uri.query() {
        Some(q) => format!("{path}?{q}"),
        None => path,
    })
}
