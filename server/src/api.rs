//! JSON REST API under `/api/v1` (documented in docs/api.md and served as an
//! OpenAPI document at `/api/v1/openapi.json`).

use crate::app::AppState;
use crate::error::AppError;
use crate::intake;
use crate::store::{now, BoardRow, Submitter};
use axum::extract::{DefaultBodyLimit, FromRequestParts, Multipart, Path, Query, State};
use axum::http::request::Parts;
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use d3il_protocol::{ObsType, TaskId};
use serde::Deserialize;
use serde_json::{json, Value};
use std::str::FromStr;

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

/// An authenticated, rate-limited API caller (`Authorization: Bearer <token>`).
pub struct Authed(pub Submitter);

impl FromRequestParts<AppState> for Authed {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, AppError> {
        let header = parts
            .headers
            .get(header::AUTHORIZATION)
            .ok_or_else(|| {
                AppError::Unauthorized(
                    "missing `Authorization: Bearer <token>` header; mint a token with `d3il token create --name <you>`".into(),
                )
            })?
            .to_str()
            .map_err(|_| AppError::Unauthorized("the Authorization header is not text".into()))?;
        // The auth scheme is case-insensitive (RFC 9110 §11.1).
        let token = header
            .split_once(' ')
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, t)| t.trim())
            .filter(|t| !t.is_empty())
            .ok_or_else(|| {
                AppError::Unauthorized("the Authorization header must be `Bearer <token>`".into())
            })?;
        authenticate_token(state, token).await.map(Authed)
    }
}

/// Checks a token and counts the request against its rate limit.
pub async fn authenticate_token(state: &AppState, token: &str) -> Result<Submitter, AppError> {
    let who = state.store.authenticate(token).await?.ok_or_else(|| {
        AppError::Unauthorized("the API token is unknown or revoked; mint a new one with `d3il token create --name <you>`".into())
    })?;
    state
        .limiter
        .check(who.token_id)
        .map_err(|retry_after| AppError::RateLimited { retry_after })?;
    Ok(who)
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
    let body = submission_json(&state, id).await?;
    let mut resp = (StatusCode::CREATED, Json(body)).into_response();
    if let Ok(v) = header::HeaderValue::from_str(&format!("/api/v1/submissions/{id}")) {
        resp.headers_mut().insert(header::LOCATION, v);
    }
    Ok(resp)
}

fn parse_id(s: &str) -> Result<i64, AppError> {
    s.parse::<i64>()
        .ok()
        .filter(|i| *i > 0)
        .ok_or_else(|| AppError::invalid("id", format!("`{s}` is not a submission id")))
}

async fn get_submission(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<Value>, AppError> {
    Ok(Json(submission_json(&state, parse_id(&id)?).await?))
}

async fn get_results(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<Value>, AppError> {
    let id = parse_id(&id)?;
    let s = state.store.submission(id).await?;
    let r = state.store.result_for(id).await?.ok_or_else(|| {
        AppError::NotFound(format!(
            "submission {id} has no results yet (status: {}); poll /api/v1/submissions/{id}",
            s.status
        ))
    })?;
    Ok(Json(results_json(&state, &r).await?))
}

/// Progress, queue position and an ETA for a submission.
pub struct Progress {
    pub rollouts_done: i64,
    pub rollouts_total: i64,
    pub queue_position: Option<i64>,
    pub eta_seconds: Option<i64>,
}

pub async fn progress(state: &AppState, job: &crate::store::JobRow) -> Result<Progress, AppError> {
    let pos = state.store.queue_position(job.id).await?;
    // Without history, guess ten minutes per evaluation.
    let mean = state
        .store
        .mean_job_seconds()
        .await?
        .unwrap_or(600.0)
        .max(1.0);
    let workers = state.cfg.workers.max(1) as f64;
    let eta = match (job.state.as_str(), pos) {
        ("queued", Some(p)) => Some(((p as f64 / workers).floor() + 1.0) * mean),
        ("leased", _) => {
            let frac = if job.rollouts_total > 0 {
                job.rollouts_done as f64 / job.rollouts_total as f64
            } else {
                0.0
            };
            let elapsed = (now() - job.started_at.unwrap_or_else(now)) as f64;
            // Extrapolate from progress once there is some; else from history.
            Some(if frac > 0.05 {
                elapsed / frac - elapsed
            } else {
                (mean - elapsed).max(0.0)
            })
        }
        _ => None,
    };
    Ok(Progress {
        rollouts_done: job.rollouts_done,
        rollouts_total: job.rollouts_total,
        queue_position: pos,
        eta_seconds: eta.map(|e| e.round() as i64),
    })
}

/// The submission as the API (and the page's JSON download) shows it.
pub async fn submission_json(state: &AppState, id: i64) -> Result<Value, AppError> {
    let s = state.store.submission(id).await?;
    let job = state.store.job_for(id).await?;
    let p = progress(state, &job).await?;
    let manifest: Value = serde_json::from_str(&s.manifest_json).unwrap_or(Value::Null);
    let result = match state.store.result_for(id).await? {
        Some(r) => results_json(state, &r).await?,
        None => Value::Null,
    };
    Ok(json!({
        "id": s.id,
        "url": format!("/submissions/{}", s.id),
        "status": s.status,
        "method": s.method,
        "submitter": s.submitter,
        "task": s.task,
        "obs_type": s.obs_type,
        "training_seed": s.training_seed,
        "data_fraction": s.data_fraction,
        "protocol": s.protocol,
        "policy": {
            "kind": s.policy_kind,
            "sha256": s.onnx_sha256,
            "bytes": s.onnx_bytes,
            "endpoint_url": s.endpoint_url,
        },
        "manifest": manifest,
        "error": s.error_kind.as_ref().map(|k| json!({"kind": k, "message": s.error_message})),
        "attempts": job.attempts,
        "max_attempts": job.max_attempts,
        "progress": {"rollouts_done": p.rollouts_done, "rollouts_total": p.rollouts_total},
        "queue_position": p.queue_position,
        "eta_seconds": p.eta_seconds,
        "created_at": s.created_at,
        "updated_at": s.updated_at,
        "result": result,
    }))
}

pub async fn results_json(
    state: &AppState,
    r: &crate::store::ResultRow,
) -> Result<Value, AppError> {
    let rollouts = state.store.rollouts_for(r.submission_id).await?;
    let job = state.store.job_for(r.submission_id).await?;
    let parse = |s: &str| serde_json::from_str::<Value>(s).unwrap_or(Value::Null);
    Ok(json!({
        "submission_id": r.submission_id,
        "metrics": {
            "success_rate": {"value": r.success_rate, "ci_low": r.success_ci_low, "ci_high": r.success_ci_high},
            "behaviour_entropy": {"value": r.behaviour_entropy, "ci_low": r.behaviour_ci_low, "ci_high": r.behaviour_ci_high},
            "conditional_entropy": {"value": r.conditional_entropy, "ci_low": r.conditional_ci_low, "ci_high": r.conditional_ci_high},
            "stacking": r.stacking_json.as_deref().map(parse),
            "stacking_levels": r.stacking_levels_json.as_deref().map(parse),
            "inference_ms": r.inference_ms,
        },
        "protocol_manifest": parse(&r.manifest_json),
        "per_context": parse(&r.per_context_json),
        "rollouts": rollouts.iter().map(|x| json!({
            "context_index": x.context_index,
            "rollout_index": x.rollout_index,
            "success": x.success,
            "behaviour": parse(&x.behaviour_json),
            "steps": x.steps,
            "path": x.path_json.as_deref().map(parse),
        })).collect::<Vec<_>>(),
        "sandbox": job.sandbox_json.as_deref().map(parse),
        "created_at": r.created_at,
    }))
}

#[derive(Debug, Deserialize, Default)]
pub struct BoardQuery {
    pub obs: Option<String>,
    /// `main` (default: full training data) or `data-fraction` (the paper's
    /// data-size rows and evaluated rows at every fraction).
    pub view: Option<String>,
}

/// The rows of one leaderboard view (`?view=`), as the pages show them.
pub fn view_rows(
    rows: &[BoardRow],
    task: TaskId,
    obs: ObsType,
    q: &BoardQuery,
) -> Result<(&'static str, Vec<BoardRow>), AppError> {
    match q.view.as_deref() {
        None | Some("") | Some("main") => Ok(("main", board_for(rows, task, obs))),
        Some("data-fraction") => Ok((
            "data-fraction",
            crate::pages::fraction_rows(rows, task, obs),
        )),
        Some(other) => Err(AppError::invalid(
            "view",
            format!("unknown view `{other}`; use `main` or `data-fraction`"),
        )),
    }
}

pub fn parse_task(s: &str) -> Result<TaskId, AppError> {
    TaskId::from_str(s).map_err(|e| AppError::NotFound(e.to_string()))
}

pub fn parse_obs_query(q: &BoardQuery) -> Result<ObsType, AppError> {
    match q.obs.as_deref() {
        None | Some("") => Ok(ObsType::State),
        Some(o) => ObsType::from_str(o).map_err(|e| AppError::invalid("obs", e)),
    }
}

/// Rows of the leaderboard of `task` and `obs`: full training data, no
/// control ablation, no data-size table (that is the data-fraction view).
pub fn board_for(rows: &[BoardRow], task: TaskId, obs: ObsType) -> Vec<BoardRow> {
    rows.iter()
        .filter(|r| {
            r.task == Some(task)
                && r.obs == obs
                && r.data_fraction == 1.0
                && r.control.is_none()
                && r.paper_table != "datasize"
        })
        .cloned()
        .collect()
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
    Path(task): Path<String>,
    Query(q): Query<BoardQuery>,
) -> Result<Json<Value>, AppError> {
    let task = parse_task(&task)?;
    let obs = parse_obs_query(&q)?;
    let (view, rows) = view_rows(&state.store.board_rows().await?, task, obs, &q)?;
    Ok(Json(json!({
        "task": task.slug(),
        "title": task.title(),
        "obs_type": obs.as_str(),
        "view": view,
        "rows": rows,
    })))
}

async fn get_leaderboard_csv(
    State(state): State<AppState>,
    Path(task): Path<String>,
    Query(q): Query<BoardQuery>,
) -> Result<Response, AppError> {
    let task = parse_task(&task)?;
    let obs = parse_obs_query(&q)?;
    let (view, rows) = view_rows(&state.store.board_rows().await?, task, obs, &q)?;
    let suffix = if view == "main" {
        String::new()
    } else {
        format!("-{view}")
    };
    Ok(csv_response(
        &format!("d3il-{}-{}{suffix}.csv", task.slug(), obs),
        &board_csv(&rows),
    ))
}

pub fn csv_response(filename: &str, body: &str) -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{filename}\""),
            ),
        ],
        body.to_string(),
    )
        .into_response()
}

fn csv_field(s: &str) -> String {
    // Quote fields with separators; neutralise spreadsheet formulas.
    let s = if s.starts_with(['=', '+', '-', '@']) && s.parse::<f64>().is_err() {
        format!("'{s}")
    } else {
        s.to_string()
    };
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s
    }
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        String::new()
    }
}

/// CSV of leaderboard rows (one header line, one line per row).
pub fn board_csv(rows: &[BoardRow]) -> String {
    let mut out = String::from(
        "task,obs_type,method,source,protocol,data_fraction,control,success_mean,success_std,\
         conditional_entropy_mean,conditional_entropy_std,behaviour_entropy_mean,behaviour_entropy_std,\
         n_seeds,inference_ms\n",
    );
    for r in rows {
        let fields = [
            csv_field(&r.task_title),
            r.obs.as_str().to_string(),
            csv_field(&r.method),
            match r.source {
                d3il_protocol::Source::Reported => "reported".into(),
                d3il_protocol::Source::Evaluated => "evaluated".into(),
            },
            r.protocol
                .map(crate::store::protocol_str)
                .unwrap_or("")
                .to_string(),
            format!("{}", r.data_fraction),
            r.control.clone().unwrap_or_default(),
            num(r.success.mean),
            num(r.success.std),
            num(r.entropy.mean),
            num(r.entropy.std),
            r.behaviour_entropy.map(|s| num(s.mean)).unwrap_or_default(),
            r.behaviour_entropy.map(|s| num(s.std)).unwrap_or_default(),
            r.n_seeds.to_string(),
            r.inference_ms.map(num).unwrap_or_default(),
        ];
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    out
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
