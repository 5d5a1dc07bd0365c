//! What a policy did: a submission's rollouts filtered and paged,
//! one rollout's record with its trace (the document `d3il replay --result`
//! reads), its video (MP4 made on demand, served with byte ranges) and its
//! top-down picture.

use crate::error::{AppError, ErrorBody};
use crate::http::extract::Query;
use crate::http::extract::{Param, RolloutParam};
use crate::http::media::serve_video;
use crate::rollouts::{RolloutDetail, RolloutList, RolloutQuery, Rollouts};
use crate::state::AppState;
use axum::extract::State;
use axum::http::{header, HeaderMap};
use axum::response::{IntoResponse, Response};
use axum::Json;

#[utoipa::path(get, path = "/submissions/{id}/rollouts", tag = "rollouts",
    summary = "A submission's rollouts, filtered by outcome, behaviour and initial state, paged",
    params(("id" = i64, Path, description = "Submission id"), RolloutQuery),
    responses(
        (status = 200, description = "A page of rollouts", body = RolloutList),
        (status = 400, description = "A filter or page value names nothing (`field` names it; the message says what is allowed)", body = ErrorBody),
        (status = 404, description = "No such submission or no result yet", body = ErrorBody)))]
pub async fn list_rollouts(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Query(q): Query<RolloutQuery>,
) -> Result<Json<RolloutList>, AppError> {
    let r = Rollouts::load(&state, id).await?;
    let f = r.filter(&q)?;
    Ok(Json(r.list(&f)?))
}

#[utoipa::path(get, path = "/submissions/{id}/rollouts/{n}", tag = "rollouts",
    summary = "One rollout's record with its trace (what `d3il replay --result FILE --rollout N` reads) and its actions",
    params(("id" = i64, Path, description = "Submission id"),
        ("n" = i64, Path, description = "Rollout number: initial state × rollouts per state + index")),
    responses(
        (status = 200, description = "The record", body = RolloutDetail),
        (status = 404, description = "No such submission, result or rollout", body = ErrorBody)))]
pub async fn get_rollout(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
) -> Result<Json<RolloutDetail>, AppError> {
    let r = Rollouts::load(&state, id).await?;
    Ok(Json(r.detail(&state, n).await?))
}

#[utoipa::path(get, path = "/submissions/{id}/rollouts/{n}/video", tag = "rollouts",
    summary = "The rollout's video (MP4, one frame per environment state, real time), made on demand by replaying its record",
    params(("id" = i64, Path, description = "Submission id"),
        ("n" = i64, Path, description = "Rollout number"),
        ("Range" = Option<String>, Header, description = "One byte range (`bytes=0-99`): answered 206")),
    responses(
        (status = 200, description = "The video", content_type = "video/mp4", body = inline(crate::schema::Binary)),
        (status = 206, description = "The asked byte range of the video", content_type = "video/mp4", body = inline(crate::schema::Binary)),
        (status = 404, description = "No such submission or rollout, or no trace to replay (results stored before traces)", body = ErrorBody),
        (status = 416, description = "The range lies past the video's end"),
        (status = 422, description = "The record could not be replayed into a video; the message is the replay's (e.g. naming the step that differs)", body = ErrorBody),
        (status = 503, description = "Too many videos are waiting to be rendered; see Retry-After", body = ErrorBody)))]
pub async fn get_video(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    let path = r.video(&state, n).await?;
    serve_video(&path, &headers).await
}

#[utoipa::path(get, path = "/submissions/{id}/rollouts/{n}/paths.svg", tag = "rollouts",
    summary = "The rollout seen from above: TCP and object paths over the scene's landmarks",
    params(("id" = i64, Path, description = "Submission id"),
        ("n" = i64, Path, description = "Rollout number")),
    responses(
        (status = 200, description = "SVG", content_type = "image/svg+xml", body = String),
        (status = 404, description = "No such submission, result or rollout", body = ErrorBody)))]
pub async fn get_paths_svg(
    State(state): State<AppState>,
    RolloutParam(id, n): RolloutParam,
) -> Result<Response, AppError> {
    let r = Rollouts::load(&state, id).await?;
    let svg = r.top_down_svg(&state, n).await?;
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], svg).into_response())
}
