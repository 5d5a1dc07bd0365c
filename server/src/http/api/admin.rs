//! `/api/v1/admin/…`: moderation and quota overrides, for admin
//! tokens only. Every action is written to the audit log (`/admin` shows it).

use crate::auth::Admin;
use crate::cache::Rendered;
use crate::error::{AppError, ErrorBody};
use crate::http::extract::{parse_json_request, Param, Query};
use crate::state::AppState;
use crate::store::{AuditEntry, QuotaOverrides};
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::routing::{get, post, put};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/submissions/{id}/withdraw", post(withdraw))
        .route("/submissions/{id}/reinstate", post(reinstate))
        .route("/methods/{name}/baseline", post(baseline))
        .route("/tokens/{prefix}/revoke", post(revoke))
        .route("/submitters/{name}/quota", put(set_quota))
        .route("/audit", get(audit))
        .layer(axum::middleware::from_fn(json_only))
}

/// Every admin action (anything but a GET) must say `Content-Type:
/// application/json`: a browser holding an admin's Basic
/// credentials sends them with any cross-site form, but a form cannot send
/// that content type, so no other site can act as the admin.
async fn json_only(
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::response::IntoResponse;
    let json = req
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("application/json"));
    if req.method() != axum::http::Method::GET && !json {
        return AppError::Invalid {
            field: None,
            message:
                "admin actions need `Content-Type: application/json` (with a JSON body, `{}` when \
                      the action takes none)"
                    .into(),
        }
        .into_response();
    }
    next.run(req).await
}

/// `withdraw`'s body.
#[derive(Debug, Deserialize, ToSchema)]
pub struct WithdrawRequest {
    /// Shown on the submission's page (1-500 characters).
    pub reason: String,
}

/// What an admin action did.
#[derive(Debug, Serialize, ToSchema)]
pub struct AdminDone {
    /// The audit log entry it wrote.
    pub audit: AuditEntry,
}

fn done(audit: AuditEntry) -> Json<AdminDone> {
    Json(AdminDone { audit })
}

#[utoipa::path(post, path = "/admin/submissions/{id}/withdraw", tag = "admin",
    summary = "Withdraw a submission: kept, shown with the reason on its page, hidden from boards and tables",
    security(("bearer" = [])),
    params(("id" = i64, Path, description = "Submission id")),
    request_body = WithdrawRequest,
    responses(
        (status = 200, description = "Withdrawn", body = AdminDone),
        (status = 400, description = "No reason, or one over 500 characters", body = ErrorBody),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such submission", body = ErrorBody)))]
pub async fn withdraw(
    State(state): State<AppState>,
    Admin(admin): Admin,
    Param(id): Param<i64>,
    body: Bytes,
) -> Result<Json<AdminDone>, AppError> {
    let req: WithdrawRequest = parse_json_request(&body, r#"{"reason": "duplicate of #12"}"#)?;
    let reason = req.reason.trim();
    if reason.is_empty() || reason.chars().count() > 500 {
        return Err(AppError::invalid(
            "reason",
            "`reason` must be 1-500 characters: it is shown on the submission's page",
        ));
    }
    let entry = state
        .store
        .withdraw_submission(id, reason, &admin.name)
        .await?;
    state.finished.forget(Rendered::Submission, id);
    Ok(done(entry))
}

#[utoipa::path(post, path = "/admin/submissions/{id}/reinstate", tag = "admin",
    summary = "Put a withdrawn submission back on the boards",
    security(("bearer" = [])),
    params(("id" = i64, Path, description = "Submission id")),
    responses(
        (status = 200, description = "Reinstated", body = AdminDone),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such submission", body = ErrorBody)))]
pub async fn reinstate(
    State(state): State<AppState>,
    Admin(admin): Admin,
    Param(id): Param<i64>,
) -> Result<Json<AdminDone>, AppError> {
    let entry = state.store.reinstate_submission(id, &admin.name).await?;
    state.finished.forget(Rendered::Submission, id);
    Ok(done(entry))
}

/// `baseline`'s body.
#[derive(Debug, Deserialize, ToSchema)]
pub struct BaselineRequest {
    /// true: the method's rows are marked as baselines on the boards; false: no longer.
    pub baseline: bool,
}

#[utoipa::path(post, path = "/admin/methods/{name}/baseline", tag = "admin",
    summary = "Mark a method's rows as baselines on the boards (or not)",
    security(("bearer" = [])),
    params(("name" = String, Path, description = "Method name")),
    request_body = BaselineRequest,
    responses(
        (status = 200, description = "Marked", body = AdminDone),
        (status = 400, description = "No `baseline` flag", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such method", body = ErrorBody)))]
pub async fn baseline(
    State(state): State<AppState>,
    Admin(admin): Admin,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Json<AdminDone>, AppError> {
    let req: BaselineRequest = parse_json_request(&body, r#"{"baseline": true}"#)?;
    let entry = state
        .store
        .set_baseline(&name, req.baseline, &admin.name)
        .await?;
    Ok(done(entry))
}

#[utoipa::path(post, path = "/admin/tokens/{prefix}/revoke", tag = "admin",
    summary = "Revoke a token (its 13-character prefix, as `d3il token create` prints it)",
    security(("bearer" = [])),
    params(("prefix" = String, Path, description = "The token's prefix `d3il_…`")),
    responses(
        (status = 200, description = "Revoked (or revoked before: the detail says so)", body = AdminDone),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such token", body = ErrorBody)))]
pub async fn revoke(
    State(state): State<AppState>,
    Admin(admin): Admin,
    Path(prefix): Path<String>,
) -> Result<Json<AdminDone>, AppError> {
    let revoked = state.store.revoke_token(&prefix, &admin.name).await?;
    Ok(done(revoked.audit))
}

/// `set_quota`'s body: each limit a number (0: no limit) or null (the
/// server's default); a limit left out is null.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct QuotaRequest {
    #[serde(default)]
    pub per_day: Option<i64>,
    #[serde(default)]
    pub total: Option<i64>,
    #[serde(default)]
    pub concurrent: Option<i64>,
}

#[utoipa::path(put, path = "/admin/submitters/{name}/quota", tag = "admin",
    summary = "Set a submitter's quota overrides (null: the server's default; 0: no limit)",
    security(("bearer" = [])),
    params(("name" = String, Path, description = "Submitter (token) name")),
    request_body = QuotaRequest,
    responses(
        (status = 200, description = "Set", body = AdminDone),
        (status = 400, description = "A limit is negative or not a number", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such submitter", body = ErrorBody)))]
pub async fn set_quota(
    State(state): State<AppState>,
    Admin(admin): Admin,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Json<AdminDone>, AppError> {
    let req: QuotaRequest =
        parse_json_request(&body, r#"{"per_day": 20, "total": null, "concurrent": 4}"#)?;
    let q = QuotaOverrides {
        per_day: req.per_day,
        total: req.total,
        concurrent: req.concurrent,
    };
    for (field, v) in [
        ("per_day", q.per_day),
        ("total", q.total),
        ("concurrent", q.concurrent),
    ] {
        if v.is_some_and(|v| v < 0) {
            return Err(AppError::invalid(
                field,
                format!("`{field}` must be 0 (no limit), a positive number, or null (the server's default)"),
            ));
        }
    }
    let entry = state.store.set_quota(&name, q, &admin.name).await?;
    Ok(done(entry))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AuditQuery {
    /// At most this many entries, newest first (default 100, at most 1000).
    pub limit: Option<i64>,
}

/// The audit log, newest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct AuditList {
    pub entries: Vec<AuditEntry>,
}

#[utoipa::path(get, path = "/admin/audit", tag = "admin",
    summary = "The audit log of admin actions, newest first",
    security(("bearer" = [])),
    params(AuditQuery),
    responses(
        (status = 200, description = "Entries", body = AuditList),
        (status = 403, description = "Not an admin token", body = ErrorBody)))]
pub async fn audit(
    State(state): State<AppState>,
    Admin(_admin): Admin,
    Query(q): Query<AuditQuery>,
) -> Result<Json<AuditList>, AppError> {
    let limit = q.limit.unwrap_or(100).clamp(1, 1000);
    Ok(Json(AuditList {
        entries: state.store.audit_log(limit).await?,
    }))
}
