//! `POST /api/v1/comparisons` and `GET /api/v1/comparisons/{id}`:
//! a sequential race of two submissions' policies on the server
//! ([`crate::races`]); `POST /api/v1/comparisons/{id}/cancel`.

use super::admin::json_body;
use crate::auth::Authed;
use crate::error::{AppError, ErrorBody};
use crate::http::extract::Param;
use crate::races::{self, ComparisonRequest, ComparisonView};
use crate::state::AppState;
use axum::body::Bytes;
use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde::Serialize;
use utoipa::ToSchema;

#[utoipa::path(post, path = "/comparisons", tag = "comparisons",
    summary = "Race two submissions sequentially: both policies on the same initial states in the same random order, stopping when the anytime-valid paired test decides",
    security(("bearer" = [])),
    request_body = ComparisonRequest,
    responses(
        (status = 202, description = "Queued, with what is left of the racer's quota after it: poll GET /comparisons/{id} (or watch /comparisons/{id})", body = CreatedComparisonView),
        (status = 400, description = "A field is wrong (`field` names it): unknown, failed or withdrawn submission, a and b the same, different tasks or observation types, alpha or delta out of range, unknown protocol", body = ErrorBody),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 429, description = "Rate limit or quota exceeded (`quota_exceeded`: neither submission is the racer's own, the race's 2 evaluations do not fit the quota, or the racer's races at once are at `--max-queued-races`; the message names the limit and when, with Retry-After)", body = ErrorBody)))]
pub async fn create_comparison(
    State(state): State<AppState>,
    Authed(who): Authed,
    body: Bytes,
) -> Result<(StatusCode, Json<CreatedComparisonView>), AppError> {
    let req: ComparisonRequest = json_body(&body, r#"{"a": 12, "b": 15, "alpha": 0.05}"#)?;
    let id = races::create(&state, &who, &req).await?;
    let row = state.store.comparison(id).await?;
    Ok((
        StatusCode::ACCEPTED,
        Json(CreatedComparisonView {
            comparison: ComparisonView::of(&row),
            quota: crate::quota::status(&state, &who).await?,
        }),
    ))
}

/// `POST /api/v1/comparisons`' answer: the queued race and what is left of
/// the racer's quota after it (the race's evaluations counted), as a
/// submission's answer carries it.
#[derive(Debug, Serialize, ToSchema)]
pub struct CreatedComparisonView {
    #[serde(flatten)]
    pub comparison: ComparisonView,
    pub quota: crate::quota::QuotaView,
}

#[utoipa::path(get, path = "/comparisons/{id}", tag = "comparisons",
    summary = "A comparison: its status, the race so far (pairs, paired counts, e-value, anytime p-value) and its report once finished",
    params(("id" = i64, Path, description = "Comparison id")),
    responses(
        (status = 200, description = "The comparison", body = ComparisonView),
        (status = 404, description = "No such comparison", body = ErrorBody)))]
pub async fn get_comparison(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Json<ComparisonView>, AppError> {
    let row = state.store.comparison(id).await?;
    Ok(Json(ComparisonView::of(&row)))
}

#[utoipa::path(post, path = "/comparisons/{id}/cancel", tag = "comparisons",
    summary = "Cancel a queued or running race (its starter or an admin; audited): a running race's worker is stopped",
    security(("bearer" = [])),
    params(("id" = i64, Path, description = "Comparison id")),
    responses(
        (status = 200, description = "Cancelled: status `cancelled`, `cancelled_by` set", body = ComparisonView),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 403, description = "Not the race's starter nor an admin", body = ErrorBody),
        (status = 404, description = "No such comparison", body = ErrorBody),
        (status = 409, description = "The race has ended already", body = ErrorBody)))]
pub async fn cancel_comparison(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Authed(who): Authed,
) -> Result<Json<ComparisonView>, AppError> {
    races::cancel_as(&state, id, &who).await?;
    let row = state.store.comparison(id).await?;
    Ok(Json(ComparisonView::of(&row)))
}
