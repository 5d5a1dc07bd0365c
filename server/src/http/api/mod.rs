//! JSON REST API under `/api/v1` (documented in docs/api.md and served as an
//! OpenAPI document at `/api/v1/openapi.json`, generated from the handlers'
//! annotations and the view structs in [`openapi`]).

pub mod admin;
pub mod cancel;
pub mod compare;
pub mod openapi;
pub mod races;
pub mod robustness;
pub mod rollouts;
pub mod zoo;

use crate::auth::Authed;
use crate::cache::Rendered;
use crate::error::AppError;
use crate::error::ErrorBody;
use crate::http::csv::{board_csv, csv_response};
use crate::http::extract::Query;
use crate::http::extract::{obs_query, Param};
use crate::intake;
use crate::leaderboard::{board_for, View};
use crate::schema;
use crate::state::AppState;
use crate::store::SubmissionStatus;
use crate::views::{
    results_view, submission_view, LeaderboardLink, LeaderboardList, LeaderboardView, MethodList,
    ResultsView, SubmissionView, WhoAmI,
};
use axum::extract::{DefaultBodyLimit, Multipart, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use d3il_protocol::{ObsType, TaskId};
use serde::Deserialize;
use utoipa::IntoParams;

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .route(
            "/submissions",
            post(create_submission)
                .get(list_submissions)
                // The multipart reader refuses bodies past the limit as they stream in.
                .layer(DefaultBodyLimit::max(crate::http::upload_body_limit(
                    max_upload,
                ))),
        )
        .route("/submissions/{id}", get(get_submission))
        .route("/submissions/{id}/cancel", post(cancel::cancel_submission))
        .route("/submissions/{id}/results", get(get_results))
        .route(
            "/submissions/{id}/robustness",
            get(robustness::get_robustness),
        )
        .route("/submissions/{id}/provenance", get(zoo::get_provenance))
        .route("/submissions/{id}/rollouts", get(rollouts::list_rollouts))
        .route("/submissions/{id}/rollouts/{n}", get(rollouts::get_rollout))
        .route(
            "/submissions/{id}/rollouts/{n}/video",
            get(rollouts::get_video),
        )
        .route(
            "/submissions/{id}/rollouts/{n}/paths.svg",
            get(rollouts::get_paths_svg),
        )
        .route("/leaderboards", get(list_leaderboards))
        .route("/leaderboards/{task}", get(get_leaderboard))
        .route("/leaderboards/{task}/csv", get(get_leaderboard_csv))
        .route("/methods", get(list_methods))
        .route("/compare", get(compare::compare))
        .route("/races", post(races::create_race))
        .route("/races/{id}", get(races::get_race))
        .route("/races/{id}/cancel", post(races::cancel_race))
        .merge(race_aliases())
        .route("/whoami", get(whoami))
        .nest("/admin", admin::router())
        .route("/build", get(get_build))
        .route("/openapi.json", get(openapi))
        .fallback(api_not_found)
        .method_not_allowed_fallback(api_method_not_allowed)
}

/// `/comparisons…`, the races' routes before they had their own name:
/// deprecated aliases, answered by the same handlers with a deprecation
/// note ([`races::deprecated_alias`]).
fn race_aliases() -> Router<AppState> {
    Router::new()
        .route("/comparisons", post(races::create_race))
        .route("/comparisons/{id}", get(races::get_race))
        .route("/comparisons/{id}/cancel", post(races::cancel_race))
        .route_layer(axum::middleware::from_fn(races::deprecated_alias))
}

async fn api_method_not_allowed(
    method: axum::http::Method,
    axum::extract::OriginalUri(uri): axum::extract::OriginalUri,
) -> AppError {
    AppError::MethodNotAllowed(format!(
        "{method} is not allowed on {}; see /api/v1/openapi.json for the methods each endpoint takes",
        uri.path()
    ))
}

async fn api_not_found() -> AppError {
    AppError::NotFound("no such API endpoint; see /api/v1/openapi.json".into())
}

#[utoipa::path(get, path = "/build", tag = "leaderboards",
    summary = "The build this server runs and its drift canary",
    responses((status = 200, description = "Version, commit and the canary's outcome", body = crate::views::BuildView)))]
async fn get_build(State(state): State<AppState>) -> Json<crate::views::BuildView> {
    Json(crate::views::BuildView {
        evaluator_version: env!("CARGO_PKG_VERSION").into(),
        git_commit: state.canary.build().git_commit,
        canary: state.canary.state(),
    })
}

#[utoipa::path(get, path = "/whoami", tag = "submissions",
    summary = "Check a token", security(("bearer" = [])),
    responses(
        (status = 200, description = "The token's submitter", body = WhoAmI),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 429, description = "Rate limit exceeded; see the Retry-After header", body = ErrorBody)))]
async fn whoami(
    State(state): State<AppState>,
    Authed(who): Authed,
) -> Result<Json<WhoAmI>, AppError> {
    let quota = crate::quota::status(&state, &who).await?;
    Ok(Json(WhoAmI {
        submitter: who.name,
        quota,
    }))
}

#[utoipa::path(post, path = "/submissions", tag = "submissions",
    summary = "Create a submission (ONNX upload or remote endpoint)",
    security(("bearer" = [])),
    request_body(content = openapi::NewSubmissionForm, content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Accepted and durably queued, with what is left of the quota", body = crate::views::CreatedView),
        (status = 400, description = "A field is missing or invalid (`field` names it)", body = ErrorBody),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 409, description = "Duplicate training seed or method owned by someone else", body = ErrorBody),
        (status = 413, description = "Upload over the size limit", body = ErrorBody),
        (status = 422, description = "Remote endpoint failed its conformance dry-run", body = ErrorBody),
        (status = 429, description = "Rate limit exceeded (`rate_limited`), or the submission quota allows no submission now (`quota_exceeded`: the message and `next_submission_at` say when); see the Retry-After header", body = ErrorBody)))]
async fn create_submission(
    State(state): State<AppState>,
    headers: HeaderMap,
    Authed(who): Authed,
    mp: Result<Multipart, axum::extract::multipart::MultipartRejection>,
) -> Result<Response, AppError> {
    let max = state.cfg.max_upload_bytes;
    intake::check_declared_length(&headers, max)?;
    let mp = mp.map_err(|e| AppError::Invalid {
        field: None,
        message: format!("expected a multipart/form-data body: {e}"),
    })?;
    let mut raw = intake::RawSubmission::default();
    let who = intake::read_multipart(mp, &state, intake::Caller::Known(who), &mut raw).await?;
    let valid = intake::validate(raw, &state.cfg.limits)?;
    let id = intake::accept(&state, valid, &who).await?;
    let body = crate::views::CreatedView {
        submission: crate::views::submission_view_for(&state, id, Some(&who)).await?,
        quota: crate::quota::status(&state, &who).await?,
    };
    let mut resp = (StatusCode::CREATED, Json(body)).into_response();
    if let Ok(v) = header::HeaderValue::from_str(&format!("/api/v1/submissions/{id}")) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

#[utoipa::path(get, path = "/submissions/{id}", tag = "submissions",
    summary = "Status, progress, queue position, ETA and result of a submission",
    params(("id" = i64, Path, description = "Submission id")),
    responses(
        (status = 200, description = "The submission", body = SubmissionView),
        (status = 404, description = "No such submission", body = ErrorBody)))]
async fn get_submission(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    who: Option<axum::Extension<crate::auth::Verified>>,
) -> Result<Response, AppError> {
    // Its submitter and admins see a remote endpoint's URL:
    // rendered for them, never cached.
    if let Some(axum::Extension(crate::auth::Verified(who))) = who {
        let s = state.store.submission(id).await?;
        if s.endpoint_url.is_some() && crate::views::may_see_endpoint(Some(&who), &s) {
            let view = crate::views::submission_view_for(&state, id, Some(&who)).await?;
            return Ok(Json(view).into_response());
        }
    }
    // A completed submission never changes (its progress, attempts and
    // embedded results are final): render it once, as its results.
    if let Some(body) = state.finished.get(Rendered::Submission, id) {
        return Ok(rendered_json_response(body));
    }
    let view = submission_view(&state, id).await?;
    let body = serde_json::to_string(&view)
        .map_err(|e| AppError::Internal(format!("submission encoding: {e}")))?;
    Ok(rendered_json_response(
        if view.status == SubmissionStatus::Completed {
            state.finished.put(Rendered::Submission, id, body)
        } else {
            body.into()
        },
    ))
}

/// A JSON answer of a document rendered ahead (see [`crate::cache`]).
fn rendered_json_response(body: std::sync::Arc<str>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        body.to_string(),
    )
        .into_response()
}

#[utoipa::path(get, path = "/submissions/{id}/results", tag = "submissions",
    summary = "Metrics, protocol manifest, per-context and per-rollout results",
    params(("id" = i64, Path, description = "Submission id")),
    responses(
        (status = 200, description = "Results", body = ResultsView),
        (status = 404, description = "No such submission or no result yet", body = ErrorBody)))]
async fn get_results(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Response, AppError> {
    // A stored result never changes: render it once.
    if let Some(body) = state.finished.get(Rendered::Results, id) {
        return Ok(rendered_json_response(body));
    }
    let s = state.store.submission(id).await?;
    let r = state.store.result_for(id).await?.ok_or_else(|| {
        AppError::NotFound(format!(
            "submission {id} has no results yet (status: {}); poll /api/v1/submissions/{id}",
            s.status
        ))
    })?;
    let view = results_view(&state, r).await?;
    let body = serde_json::to_string(&view)
        .map_err(|e| AppError::Internal(format!("results encoding: {e}")))?;
    Ok(rendered_json_response(state.finished.put(
        Rendered::Results,
        id,
        body,
    )))
}

#[derive(Debug, Deserialize, Default, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct BoardQuery {
    /// `state` (default) or `image`.
    #[param(value_type = Option<schema::Obs>)]
    pub obs: Option<String>,
    /// `main` (default: full training data) or `data-fraction` (the paper's
    /// data-size rows and evaluated rows at every fraction).
    #[param(schema_with = openapi::view_schema)]
    pub view: Option<String>,
}

impl BoardQuery {
    fn parse(&self) -> Result<(ObsType, View), AppError> {
        let obs = obs_query(self.obs.as_deref())?;
        let view = View::parse(self.view.as_deref()).map_err(|e| AppError::invalid("view", e))?;
        Ok((obs, view))
    }
}

#[utoipa::path(get, path = "/leaderboards", tag = "leaderboards",
    summary = "List the leaderboards",
    responses((status = 200, description = "Leaderboards with links", body = LeaderboardList)))]
async fn list_leaderboards(
    State(state): State<AppState>,
) -> Result<Json<LeaderboardList>, AppError> {
    let rows = state.store.board_rows().await?;
    let mut out = vec![];
    for task in TaskId::ALL {
        for obs in [ObsType::State, ObsType::Image] {
            let n = board_for(&rows, task, obs).len();
            if n == 0 && obs == ObsType::Image && !task.has_image_variant() {
                continue;
            }
            out.push(LeaderboardLink {
                task,
                title: task.title(),
                obs_type: obs,
                rows: n,
                url: format!("/api/v1/leaderboards/{}?obs={}", task.slug(), obs),
                csv: format!("/api/v1/leaderboards/{}/csv?obs={}", task.slug(), obs),
                page: format!("/tasks/{}?obs={}", task.slug(), obs),
            });
        }
    }
    Ok(Json(LeaderboardList { leaderboards: out }))
}

#[utoipa::path(get, path = "/leaderboards/{task}", tag = "leaderboards",
    summary = "Rows of one leaderboard (reported and evaluated)",
    params(("task" = schema::Task, Path), BoardQuery),
    responses(
        (status = 200, description = "Rows", body = LeaderboardView),
        (status = 400, description = "Unknown `obs` or `view`", body = ErrorBody),
        (status = 404, description = "Unknown task", body = ErrorBody)))]
async fn get_leaderboard(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<BoardQuery>,
) -> Result<Json<LeaderboardView>, AppError> {
    let (obs, view) = q.parse()?;
    let rows = view.rows(&state.store.board_rows().await?, task, obs);
    Ok(Json(LeaderboardView {
        task,
        title: task.title(),
        obs_type: obs,
        view: view.as_str(),
        rows,
    }))
}

#[utoipa::path(get, path = "/leaderboards/{task}/csv", tag = "leaderboards",
    summary = "CSV export of one leaderboard",
    params(("task" = schema::Task, Path), BoardQuery),
    responses(
        (status = 200, description = "CSV", content_type = "text/csv", body = String),
        (status = 400, description = "Unknown `obs` or `view`", body = ErrorBody),
        (status = 404, description = "Unknown task", body = ErrorBody)))]
async fn get_leaderboard_csv(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<BoardQuery>,
) -> Result<Response, AppError> {
    let (obs, view) = q.parse()?;
    let rows = view.rows(&state.store.board_rows().await?, task, obs);
    let suffix = match view {
        View::Main => String::new(),
        other => format!("-{}", other.as_str()),
    };
    Ok(csv_response(
        &format!("d3il-{}-{}{suffix}.csv", task.slug(), obs),
        &board_csv(&rows)?,
    ))
}

#[utoipa::path(get, path = "/submissions", tag = "submissions",
    summary = "List submissions (newest first, at most 500; withdrawn ones left out), filtered by task, method, status, submitter",
    params(crate::views::SubmissionListQuery),
    responses(
        (status = 200, description = "Matching submissions", body = crate::views::SubmissionList),
        (status = 400, description = "Unknown task or status (`field` names it)", body = ErrorBody)))]
async fn list_submissions(
    State(state): State<AppState>,
    Query(q): Query<crate::views::SubmissionListQuery>,
) -> Result<Json<crate::views::SubmissionList>, AppError> {
    let rows = state.store.list_submissions(&q.filter()?, 500).await?;
    Ok(Json(crate::views::SubmissionList {
        submissions: rows.into_iter().map(Into::into).collect(),
    }))
}

#[utoipa::path(get, path = "/methods", tag = "leaderboards",
    summary = "Methods and their properties",
    responses((status = 200, description = "Methods", body = MethodList)))]
async fn list_methods(State(state): State<AppState>) -> Result<Json<MethodList>, AppError> {
    Ok(Json(MethodList {
        methods: state.store.methods().await?,
    }))
}

async fn openapi() -> Json<utoipa::openapi::OpenApi> {
    Json(openapi::document())
}
