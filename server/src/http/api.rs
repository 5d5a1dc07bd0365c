//! JSON REST API under `/api/v1` (documented in docs/api.md and served as an
//! OpenAPI document at `/api/v1/openapi.json`).

use crate::auth::Authed;
use crate::error::AppError;
use crate::http::csv::{board_csv, csv_response};
use crate::http::extract::{obs_query, Param};
use crate::intake;
use crate::leaderboard::{board_for, View};
use crate::state::AppState;
use crate::views::{results_view, submission_view, ResultsView, SubmissionView};
use axum::extract::{DefaultBodyLimit, Multipart, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use d3il_protocol::{ObsType, TaskId};
use serde::Deserialize;
use serde_json::{json, Value};

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .route(
            "/submissions",
            post(create_submission)
                // The multipart reader refuses bodies past the limit as they stream in.
                .layer(DefaultBodyLimit::max(max_upload + (1 << 20))),
        )
        .route("/submissions/{id}", get(get_submission))
        .route("/submissions/{id}/results", get(get_results))
        .route("/leaderboards", get(list_leaderboards))
        .route("/leaderboards/{task}", get(get_leaderboard))
        .route("/leaderboards/{task}/csv", get(get_leaderboard_csv))
        .route("/methods", get(list_methods))
        .route("/whoami", get(whoami))
        .route("/openapi.json", get(openapi))
        .fallback(api_not_found)
        .method_not_allowed_fallback(api_method_not_allowed)
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

async fn whoami(Authed(who): Authed) -> Json<Value> {
    Json(json!({ "submitter": who.name }))
}

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
    let raw = intake::read_multipart(mp, max).await?;
    let valid = intake::validate(&raw, &state.cfg.limits)?;
    let id = intake::accept(&state, valid, &who).await?;
    let body = submission_view(&state, id).await?;
    let mut resp = (StatusCode::CREATED, Json(body)).into_response();
    if let Ok(v) = header::HeaderValue::from_str(&format!("/api/v1/submissions/{id}")) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

async fn get_submission(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Json<SubmissionView>, AppError> {
    Ok(Json(submission_view(&state, id).await?))
}

async fn get_results(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Json<ResultsView>, AppError> {
    let s = state.store.submission(id).await?;
    let r = state.store.result_for(id).await?.ok_or_else(|| {
        AppError::NotFound(format!(
            "submission {id} has no results yet (status: {}); poll /api/v1/submissions/{id}",
            s.status
        ))
    })?;
    Ok(Json(results_view(&state, r).await?))
}

#[derive(Debug, Deserialize, Default)]
pub struct BoardQuery {
    pub obs: Option<String>,
    /// `main` (default: full training data) or `data-fraction` (the paper's
    /// data-size rows and evaluated rows at every fraction).
    pub view: Option<String>,
}

impl BoardQuery {
    fn parse(&self) -> Result<(ObsType, View), AppError> {
        let obs = obs_query(self.obs.as_deref())?;
        let view = View::parse(self.view.as_deref()).map_err(|e| AppError::invalid("view", e))?;
        Ok((obs, view))
    }
}

async fn list_leaderboards(State(state): State<AppState>) -> Result<Json<Value>, AppError> {
    let rows = state.store.board_rows().await?;
    let mut out = vec![];
    for task in TaskId::ALL {
        for obs in [ObsType::State, ObsType::Image] {
            let n = board_for(&rows, task, obs).len();
            if n == 0 && obs == ObsType::Image && !task.has_image_variant() {
                continue;
            }
            out.push(json!({
                "task": task.slug(),
                "title": task.title(),
                "obs_type": obs.as_str(),
                "rows": n,
                "url": format!("/api/v1/leaderboards/{}?obs={}", task.slug(), obs),
                "csv": format!("/api/v1/leaderboards/{}/csv?obs={}", task.slug(), obs),
                "page": format!("/tasks/{}?obs={}", task.slug(), obs),
            }));
        }
    }
    Ok(Json(json!({ "leaderboards": out })))
}

async fn get_leaderboard(
    State(state): State<AppState>,
    Param(task): Param<TaskId>,
    Query(q): Query<BoardQuery>,
) -> Result<Json<Value>, AppError> {
    let (obs, view) = q.parse()?;
    let rows = view.rows(&state.store.board_rows().await?, task, obs);
    Ok(Json(json!({
        "task": task.slug(),
        "title": task.title(),
        "obs_type": obs.as_str(),
        "view": view.as_str(),
        "rows": rows,
    })))
}

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

async fn list_methods(State(state): State<AppState>) -> Result<Json<Value>, AppError> {
    let methods = state.store.methods().await?;
    Ok(Json(json!({ "methods": methods })))
}

async fn openapi() -> Json<Value> {
    Json(openapi_document())
}

/// The OpenAPI 3.1 description of this API.
pub fn openapi_document() -> Value {
    let error = json!({"$ref": "#/components/schemas/Error"});
    let err_resp =
        |d: &str| json!({"description": d, "content": {"application/json": {"schema": error}}});
    let obs_param = json!({"name": "obs", "in": "query", "required": false,
        "schema": {"type": "string", "enum": ["state", "image"], "default": "state"}});
    let view_param = json!({"name": "view", "in": "query", "required": false,
        "description": "main: full training data; data-fraction: rows at every training-data fraction",
        "schema": {"type": "string", "enum": ["main", "data-fraction"], "default": "main"}});
    let task_param = json!({"name": "task", "in": "path", "required": true,
        "schema": {"type": "string", "enum": TaskId::ALL.iter().map(|t| t.slug()).collect::<Vec<_>>()}});
    let id_param =
        json!({"name": "id", "in": "path", "required": true, "schema": {"type": "integer"}});
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "D3IL leaderboard API",
            "version": "1",
            "description": "Submit imitation-learning policies for evaluation on the D3IL tasks and read leaderboards. Errors always have the shape {\"error\": {\"code\", \"message\", \"field\"}}. See docs/api.md."
        },
        "servers": [{"url": "/api/v1"}],
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer",
                "description": "Token from `d3il token create --name <you>`"}},
            "schemas": {
                "Error": {"type": "object", "required": ["error"], "properties": {"error": {
                    "type": "object", "required": ["code", "message"], "properties": {
                        "code": {"type": "string", "enum": ["invalid_field", "unauthorized", "not_found", "method_not_allowed", "conflict", "payload_too_large", "rate_limited", "endpoint_rejected", "internal"]},
                        "message": {"type": "string"},
                        "field": {"type": ["string", "null"]}}}}},
                "Submission": {"type": "object", "properties": {
                    "id": {"type": "integer"}, "url": {"type": "string"},
                    "status": {"type": "string", "enum": ["queued", "running", "completed", "failed"]},
                    "method": {"type": "string"}, "task": {"type": "string"}, "obs_type": {"type": "string"},
                    "training_seed": {"type": "integer"}, "data_fraction": {"type": "number"},
                    "protocol": {"type": "string", "enum": ["paper", "quick"]},
                    "policy": {"type": "object"}, "manifest": {"type": "object"},
                    "error": {"type": ["object", "null"]},
                    "progress": {"type": "object", "properties": {"rollouts_done": {"type": "integer"}, "rollouts_total": {"type": "integer"}}},
                    "queue_position": {"type": ["integer", "null"]}, "eta_seconds": {"type": ["integer", "null"]},
                    "result": {"type": ["object", "null"]}}},
                "NewSubmission": {"type": "object", "required": ["method", "task", "training_seed"], "properties": {
                    "method": {"type": "string", "description": "Method name (1-64 chars)"},
                    "history": {"type": "integer"}, "backbone": {"type": "string"}, "prediction": {"type": "string"},
                    "diversity": {"type": "string"}, "code_url": {"type": "string"}, "paper_url": {"type": "string"},
                    "description": {"type": "string"},
                    "task": {"type": "string"}, "obs_type": {"type": "string", "default": "state"},
                    "training_seed": {"type": "integer"}, "data_fraction": {"type": "number", "default": 1.0},
                    "protocol": {"type": "string", "default": "paper"},
                    "onnx": {"type": "string", "format": "binary"},
                    "manifest": {"type": "string", "description": "Policy manifest JSON (required with onnx)"},
                    "endpoint_url": {"type": "string", "description": "ws(s)/http(s) URL of a remote policy (instead of onnx)"}}}
            }
        },
        "paths": {
            "/submissions": {"post": {
                "summary": "Create a submission (ONNX upload or remote endpoint)",
                "security": [{"bearer": []}],
                "requestBody": {"required": true, "content": {"multipart/form-data": {"schema": {"$ref": "#/components/schemas/NewSubmission"}}}},
                "responses": {
                    "201": {"description": "Accepted and durably queued", "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Submission"}}}},
                    "400": err_resp("A field is missing or invalid (`field` names it)"),
                    "401": err_resp("Missing or wrong token"),
                    "409": err_resp("Duplicate training seed or method owned by someone else"),
                    "413": err_resp("Upload over the size limit"),
                    "422": err_resp("Remote endpoint failed its conformance dry-run"),
                    "429": err_resp("Rate limit exceeded; see the Retry-After header")}}},
            "/submissions/{id}": {"get": {"summary": "Status, progress, queue position, ETA and result of a submission",
                "parameters": [id_param], "responses": {"200": {"description": "The submission", "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Submission"}}}}, "404": err_resp("No such submission")}}},
            "/submissions/{id}/results": {"get": {"summary": "Metrics, protocol manifest, per-context and per-rollout results",
                "parameters": [id_param], "responses": {"200": {"description": "Results"}, "404": err_resp("No such submission or no result yet")}}},
            "/leaderboards": {"get": {"summary": "List the leaderboards", "responses": {"200": {"description": "Leaderboards with links"}}}},
            "/leaderboards/{task}": {"get": {"summary": "Rows of one leaderboard (reported and evaluated)",
                "parameters": [task_param, obs_param, view_param], "responses": {"200": {"description": "Rows"}, "404": err_resp("Unknown task")}}},
            "/leaderboards/{task}/csv": {"get": {"summary": "CSV export of one leaderboard",
                "parameters": [task_param, obs_param, view_param], "responses": {"200": {"description": "CSV", "content": {"text/csv": {}}}, "404": err_resp("Unknown task")}}},
            "/methods": {"get": {"summary": "Methods and their properties", "responses": {"200": {"description": "Methods"}}}},
            "/whoami": {"get": {"summary": "Check a token", "security": [{"bearer": []}], "responses": {"200": {"description": "The token's submitter"}, "401": err_resp("Missing or wrong token")}}}
        }
    })
}
