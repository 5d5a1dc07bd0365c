//! `POST /api/v1/races`, `GET /api/v1/races/{id}` and
//! `POST /api/v1/races/{id}/cancel`: a race of two submissions' policies on
//! the server, stopped by the sequential paired test ([`crate::races`]).
//!
//! The same routes under `/comparisons` (their names until races had their
//! own) are deprecated aliases ([`deprecated_alias`]): they answer exactly
//! as the `/races` ones, with a `Deprecation` header and a `Link` to the
//! successor. (`GET /api/v1/compare` is the paired comparison of two
//! finished results, [`super::compare`].)

use crate::auth::Authed;
use crate::error::{AppError, ErrorBody};
use crate::http::extract::{parse_json_request, Param};
use crate::races::{self, RaceRequest, RaceView};
use crate::state::AppState;
use axum::body::Bytes;
use axum::extract::State;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::Response;
use axum::Json;
use serde::Serialize;
use utoipa::ToSchema;

/// The deprecated aliases' prefix and its successor's (both under `/api/v1`).
pub const OLD_PREFIX: &str = "/comparisons";
pub const PREFIX: &str = "/races";

#[utoipa::path(post, path = "/races", tag = "races",
    summary = "Race two submissions: both policies on the same initial states in the same random order, stopping when the sequential paired test decides",
    security(("bearer" = [])),
    request_body = RaceRequest,
    responses(
        (status = 202, description = "Queued, with what is left of the racer's quota after it: poll GET /races/{id} (or watch the page /races/{id})", body = CreatedRaceView),
        (status = 400, description = "A field is wrong (`field` names it): unknown, failed or withdrawn submission, a and b the same, different tasks or observation types, alpha or delta out of range, unknown protocol", body = ErrorBody),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 429, description = "Rate limit or quota exceeded (`quota_exceeded`: neither submission is the racer's own, the race's 2 evaluations do not fit the quota, or the racer's races at once are at `--max-queued-races`; the message names the limit and when, with Retry-After)", body = ErrorBody)))]
pub async fn create_race(
    State(state): State<AppState>,
    Authed(who): Authed,
    body: Bytes,
) -> Result<(StatusCode, Json<CreatedRaceView>), AppError> {
    let req: RaceRequest = parse_json_request(&body, r#"{"a": 12, "b": 15, "alpha": 0.05}"#)?;
    let id = races::create(&state, &who, &req).await?;
    let row = state.store.race(id).await?;
    Ok((
        StatusCode::ACCEPTED,
        Json(CreatedRaceView {
            race: RaceView::of(&row),
            quota: crate::quota::status(&state, &who).await?,
        }),
    ))
}

/// `POST /api/v1/races`' answer: the queued race and what is left of the
/// racer's quota after it (the race's evaluations counted), as a
/// submission's answer carries it.
#[derive(Debug, Serialize, ToSchema)]
pub struct CreatedRaceView {
    #[serde(flatten)]
    pub race: RaceView,
    pub quota: crate::quota::QuotaView,
}

#[utoipa::path(get, path = "/races/{id}", tag = "races",
    summary = "A race: its status, the race so far (pairs, paired counts, e-value, anytime p-value) and its report once finished",
    params(("id" = i64, Path, description = "Race id")),
    responses(
        (status = 200, description = "The race", body = RaceView),
        (status = 404, description = "No such race", body = ErrorBody)))]
pub async fn get_race(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Json<RaceView>, AppError> {
    let row = state.store.race(id).await?;
    Ok(Json(RaceView::of(&row)))
}

#[utoipa::path(post, path = "/races/{id}/cancel", tag = "races",
    summary = "Cancel a queued or running race (its starter or an admin; audited): a running race's worker is stopped",
    security(("bearer" = [])),
    params(("id" = i64, Path, description = "Race id")),
    responses(
        (status = 200, description = "Cancelled: status `cancelled`, `cancelled_by` set", body = RaceView),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 403, description = "Not the race's starter nor an admin", body = ErrorBody),
        (status = 404, description = "No such race", body = ErrorBody),
        (status = 409, description = "The race has ended already", body = ErrorBody)))]
pub async fn cancel_race(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Authed(who): Authed,
) -> Result<Json<RaceView>, AppError> {
    races::cancel_as(&state, id, &who).await?;
    let row = state.store.race(id).await?;
    Ok(Json(RaceView::of(&row)))
}

/// The layer of the deprecated `/comparisons…` aliases: the answer of the
/// `/races…` route they share a handler with, plus `Deprecation: true`
/// (RFC 9745) and `Link: </api/v1/races…>; rel="successor-version"`.
pub async fn deprecated_alias(
    axum::extract::OriginalUri(uri): axum::extract::OriginalUri,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let successor = uri.path().replacen(
        &format!("/api/v1{OLD_PREFIX}"),
        &format!("/api/v1{PREFIX}"),
        1,
    );
    let mut resp = next.run(req).await;
    let h = resp.headers_mut();
    h.insert("deprecation", HeaderValue::from_static("true"));
    if let Ok(v) = HeaderValue::from_str(&format!("<{successor}>; rel=\"successor-version\"")) {
        h.append(header::LINK, v);
    }
    resp
}
