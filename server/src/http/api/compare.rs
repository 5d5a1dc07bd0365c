//! `GET /api/v1/compare?a=<submission>&b=<submission>`: paired comparison of
//! two evaluated submissions on the same task, protocol and initial states
//! (`d3il_metrics::compare`, the same as `d3il compare a.json b.json`).

use crate::comparison::{finished, paired};
use crate::error::{AppError, ErrorBody};
use crate::state::AppState;
use axum::extract::{Query, State};
use axum::Json;
use d3il_protocol::Comparison;
use serde::Deserialize;
use utoipa::IntoParams;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct CompareQuery {
    /// Submission id of A.
    pub a: Option<String>,
    /// Submission id of B (the comparison is A − B).
    pub b: Option<String>,
}

fn id(field: &str, v: Option<&str>) -> Result<i64, AppError> {
    let v = v.ok_or_else(|| {
        AppError::invalid(
            field,
            format!("query parameter `{field}` is missing; use /api/v1/compare?a=<submission id>&b=<submission id>"),
        )
    })?;
    v.parse().map_err(|_| {
        AppError::invalid(
            field,
            format!("`{field}` must be a submission id (an integer), got `{v}`"),
        )
    })
}

#[utoipa::path(get, path = "/compare", tag = "leaderboards",
    summary = "Paired comparison of two evaluated submissions (A − B)",
    params(CompareQuery),
    responses(
        (status = 200, description = "Differences in success rate and conditional entropy with paired bootstrap intervals, p-values and minimum detectable differences", body = super::openapi::ComparisonSchema),
        (status = 400, description = "Missing or malformed ids, a submission that has not finished, or results that cannot be paired (different task, protocol or initial states)", body = ErrorBody),
        (status = 404, description = "No such submission or no result yet", body = ErrorBody)))]
pub async fn compare(
    State(state): State<AppState>,
    Query(q): Query<CompareQuery>,
) -> Result<Json<Comparison>, AppError> {
    let a = id("a", q.a.as_deref())?;
    let b = id("b", q.b.as_deref())?;
    let pa = finished(&state, "a", a).await?;
    let pb = finished(&state, "b", b).await?;
    paired(&pa, &pb).map(Json)
}
