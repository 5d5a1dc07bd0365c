//! SVG endpoints for the figures (the pages also embed them inline). The
//! figures themselves are drawn by the `tables` crate.

use crate::board_figures::{fraction_series, pareto_points};
use crate::error::AppError;
use crate::http::extract::Query;
use crate::http::extract::{obs_query, Param, RolloutParam};
use crate::leaderboard::{behaviour_counts, board_for, fraction_rows};
use crate::rollouts::Rollouts;
use crate::state::AppState;
use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use d3il_protocol::TaskId;
use d3il_tables::{board, render_avoiding_paths, TablesError};
use serde::Deserialize;

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/plots/tasks/{task}/pareto.svg", get(pareto))
        .route("/plots/tasks/{task}/data-fraction.svg", get(data_fraction))
        .route("/plots/submissions/{id}/paths.svg", get(paths))
        .route("/plots/submissions/{id}/starts.svg", get(starts))
        .route("/plots/submissions/{id}/behaviours.svg", get(behaviours))
        .route(
            "/plots/submissions/{id}/rollouts/{n}/paths.svg",
            get(rollout_paths),
        )
        .route(
            "/plots/submissions/{id}/rollouts/{n}/steps.svg",
            get(rollout_steps),
        )
}

fn svg_text(body: String) -> Response {
    ([(header::CONTENT_TYPE, "image/svg+xml")], body).into_response()
}

#[derive(Debug, Deserialize, Default)]
struct ObsQuery {
    obs: Option<String>,
}

fn svg(body: Result<String, TablesError>) -> Result<Response, AppError> {
    let body = body.map_err(|e| match e {
        TablesError::NoFigureData { .. } => AppError::NotFound(e.to_string()),
        e => AppError::Internal(e.to_string()),
    })?;
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], body).into_response())
}

/// Success vs conditional entropy. For Stacking the full-success row
/// (Stacking-3) is drawn, as in the paper's summary figure.
async fn pareto(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<ObsQuery>,
) -> Result<Response, AppError> {
    let obs = obs_query(q.obs.as_deref())?;
    let rows = board_for(&state.store.board_rows().await?, task, obs);
    let last_title = rows.iter().map(|r| r.task_title.clone()).max();
    let rows: Vec<_> = rows
        .into_iter()
        .filter(|r| Some(&r.task_title) == last_title.as_ref())
        .collect();
    let title = format!(
        "{} ({obs}): success vs diversity",
        last_title.unwrap_or_else(|| task.title().into())
    );
    svg(board::pareto_svg(&title, &pareto_points(&rows)))
}

async fn data_fraction(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<ObsQuery>,
) -> Result<Response, AppError> {
    let obs = obs_query(q.obs.as_deref())?;
    let rows = fraction_rows(&state.store.board_rows().await?, task, obs);
    svg(board::data_fraction_svg(
        &format!("{}: performance vs training data", task.title()),
        &fraction_series(&rows),
    ))
}

/// Every rollout's TCP path by behaviour, from the rollouts' traces; for a
/// result stored before traces, the Avoiding end-effector paths it recorded,
/// or the "no traces" picture. 404 until there is a result.
async fn paths(State(state): State<AppState>, Param(id): Param<i64>) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    if !r.any_trace() {
        let paths = state.store.avoiding_paths(id).await?;
        if !paths.is_empty() {
            return svg(render_avoiding_paths(
                &paths,
                &format!("Submission {id}: end-effector paths"),
            ));
        }
    }
    Ok(svg_text(r.overlay_svg(&state).await?))
}

/// The initial states by success rate and dominant behaviour.
async fn starts(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    Ok(svg_text(r.start_map_svg(&state).await?))
}

/// One rollout seen from above.
async fn rollout_paths(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    Ok(svg_text(r.top_down_svg(&state, n).await?))
}

/// One rollout's signals step by step.
async fn rollout_steps(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    Ok(svg_text(r.step_plots_svg(&state, n).await?))
}

async fn behaviours(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Response, AppError> {
    let s = state.store.submission(id).await?;
    let rollouts = state.store.rollouts_for(id).await?;
    let counts = behaviour_counts(s.task, rollouts.iter().map(|r| (r.success, &r.behaviour.0)));
    svg(board::behaviour_bars_svg(
        &format!("Submission {id}: behaviours"),
        &counts,
    ))
}
