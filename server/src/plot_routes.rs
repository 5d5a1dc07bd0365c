//! SVG endpoints for the figures (the pages also embed them inline).

use crate::api::{self, board_for, BoardQuery};
use crate::app::AppState;
use crate::error::AppError;
use crate::pages::{behaviour_counts, fraction_rows, fraction_series, pareto_points};
use crate::plots;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/plots/tasks/{task}/pareto.svg", get(pareto))
        .route("/plots/tasks/{task}/data-fraction.svg", get(data_fraction))
        .route("/plots/submissions/{id}/paths.svg", get(paths))
        .route("/plots/submissions/{id}/behaviours.svg", get(behaviours))
}

fn svg(body: Result<String, plots::PlotError>) -> Result<Response, AppError> {
    let body = body.map_err(|e| AppError::Internal(e.to_string()))?;
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], body).into_response())
}

fn id_of(s: &str) -> Result<i64, AppError> {
    s.parse::<i64>()
        .ok()
        .filter(|i| *i > 0)
        .ok_or_else(|| AppError::NotFound(format!("no submission `{s}`")))
}

/// Success vs conditional entropy. For Stacking the full-success row
/// (Stacking-3) is drawn, as in the paper's summary figure.
async fn pareto(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<BoardQuery>,
) -> Result<Response, AppError> {
    let task = api::parse_task(&task)?;
    let obs = api::parse_obs_query(&q)?;
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
    svg(plots::pareto_svg(&title, &pareto_points(&rows)))
}

async fn data_fraction(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<BoardQuery>,
) -> Result<Response, AppError> {
    let task = api::parse_task(&task)?;
    let obs = api::parse_obs_query(&q)?;
    let rows = fraction_rows(&state.store.board_rows().await?, task, obs);
    svg(plots::data_fraction_svg(
        &format!("{}: performance vs training data", task.title()),
        &fraction_series(&rows),
    ))
}

async fn paths(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, AppError> {
    let id = id_of(&id)?;
    state.store.submission(id).await?;
    let paths = state.store.avoiding_paths(id).await?;
    svg(plots::paths_svg(
        &format!("Submission {id}: end-effector paths"),
        &paths,
    ))
}

async fn behaviours(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, AppError> {
    let id = id_of(&id)?;
    state.store.submission(id).await?;
    let counts = behaviour_counts(&state.store.rollouts_for(id).await?);
    svg(plots::behaviour_bars_svg(
        &format!("Submission {id}: behaviours"),
        &counts,
    ))
}
