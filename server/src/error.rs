//! One error type for the HTTP layer, one JSON error format:
//! `{"error": {"code": ..., "message": ..., "field": ...}}`.
//! Database details are logged, never sent to the client.

use crate::store::StoreError;
use askama::Template;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use serde::Serialize;

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// A request field is missing or invalid.
    #[error("{message}")]
    Invalid {
        field: Option<String>,
        message: String,
    },
    #[error("{0}")]
    Unauthorized(String),
    /// Authenticated, but not allowed (a non-admin token on `/admin`).
    #[error("{0}")]
    Forbidden(String),
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    MethodNotAllowed(String),
    #[error("{message}")]
    Conflict {
        field: Option<String>,
        message: String,
    },
    #[error("{0}")]
    PayloadTooLarge(String),
    /// A rate limit refused the request; `limit` names it (
    /// every refusal names its limit): one of the `RATE_LIMIT_*` texts.
    #[error("rate limit exceeded: {limit}; retry in {retry_after} s")]
    RateLimited {
        retry_after: u64,
        limit: &'static str,
    },
    /// The submitter's submission quota allows no submission now
    /// (`crate::quota`): the message says why and when the next is possible.
    #[error("{message}")]
    QuotaExceeded {
        message: String,
        retry_after: Option<u64>,
        /// Unix seconds, when known.
        next_at: Option<i64>,
    },
    /// The database stayed locked by another writer past the busy timeout
    /// (and the store's retries), or too many videos wait to be rendered:
    /// try again shortly. `reason` says which.
    #[error("{reason}; retry in {retry_after} s")]
    Busy {
        retry_after: u64,
        reason: &'static str,
    },
    /// The remote endpoint failed its conformance dry-run.
    #[error("{message}")]
    EndpointRejected { kind: String, message: String },
    /// A stored rollout could not be made into what was asked (its video):
    /// the replay's own words.
    #[error("{0}")]
    NotRendered(String),
    /// Something broke on our side; the detail is logged only.
    #[error("internal error")]
    Internal(String),
}

/// The rate limits as refusals name them.
pub const RATE_LIMIT_TOKEN: &str = "requests per token per minute (--rate-limit)";
pub const RATE_LIMIT_ANONYMOUS: &str =
    "requests without a valid token per client address per minute (--anonymous-rate-limit)";
pub const RATE_LIMIT_FAILED_AUTH: &str =
    "failed token checks per client address per minute (--failed-auth-limit)";

impl AppError {
    pub fn invalid(field: &str, message: impl Into<String>) -> Self {
        AppError::Invalid {
            field: Some(field.to_string()),
            message: message.into(),
        }
    }

    pub fn status(&self) -> StatusCode {
        match self {
            AppError::Invalid { .. } => StatusCode::BAD_REQUEST,
            AppError::Unauthorized(_) => StatusCode::UNAUTHORIZED,
            AppError::Forbidden(_) => StatusCode::FORBIDDEN,
            AppError::NotFound(_) => StatusCode::NOT_FOUND,
            AppError::MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            AppError::Conflict { .. } => StatusCode::CONFLICT,
            AppError::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            AppError::RateLimited { .. } | AppError::QuotaExceeded { .. } => {
                StatusCode::TOO_MANY_REQUESTS
            }
            AppError::Busy { .. } => StatusCode::SERVICE_UNAVAILABLE,
            AppError::EndpointRejected { .. } => StatusCode::UNPROCESSABLE_ENTITY,
            AppError::NotRendered(_) => StatusCode::UNPROCESSABLE_ENTITY,
            AppError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    pub fn code(&self) -> &'static str {
        match self {
            AppError::Invalid { .. } => "invalid_field",
            AppError::Unauthorized(_) => "unauthorized",
            AppError::Forbidden(_) => "forbidden",
            AppError::NotFound(_) => "not_found",
            AppError::MethodNotAllowed(_) => "method_not_allowed",
            AppError::Conflict { .. } => "conflict",
            AppError::PayloadTooLarge(_) => "payload_too_large",
            AppError::RateLimited { .. } => "rate_limited",
            AppError::QuotaExceeded { .. } => "quota_exceeded",
            AppError::Busy { .. } => "busy",
            AppError::EndpointRejected { .. } => "endpoint_rejected",
            AppError::NotRendered(_) => "not_rendered",
            AppError::Internal(_) => "internal",
        }
    }

    pub fn field(&self) -> Option<&str> {
        match self {
            AppError::Invalid { field, .. } | AppError::Conflict { field, .. } => field.as_deref(),
            AppError::EndpointRejected { .. } => Some("endpoint_url"),
            _ => None,
        }
    }

    pub fn body(&self) -> ErrorBody {
        ErrorBody {
            error: ErrorDetail {
                code: self.code().to_string(),
                message: self.to_string(),
                field: self.field().map(str::to_string),
                next_submission_at: match self {
                    AppError::QuotaExceeded { next_at, .. } => *next_at,
                    _ => None,
                },
            },
        }
    }

    fn log(&self) {
        if let AppError::Internal(detail) = self {
            tracing::error!("internal error: {detail}");
        }
    }

    fn headers(&self, resp: &mut Response) {
        match self {
            AppError::RateLimited { retry_after, .. }
            | AppError::Busy { retry_after, .. }
            | AppError::QuotaExceeded {
                retry_after: Some(retry_after),
                ..
            } => {
                if let Ok(v) = HeaderValue::from_str(&retry_after.to_string()) {
                    resp.headers_mut().insert(header::RETRY_AFTER, v);
                }
            }
            AppError::Unauthorized(_) => {
                resp.headers_mut().insert(
                    header::WWW_AUTHENTICATE,
                    HeaderValue::from_static("Bearer realm=\"d3il\""),
                );
            }
            _ => {}
        }
    }
}

/// Every API error: `{"error": {"code", "message", "field"}}`.
#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[schema(as = Error)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ErrorDetail {
    #[schema(schema_with = code_schema)]
    pub code: String,
    /// What went wrong and what to do about it.
    pub message: String,
    /// The request field at fault, if one is.
    pub field: Option<String>,
    /// `quota_exceeded`: when the next submission is possible (unix
    /// seconds), when that is a time (not "when an evaluation finishes").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next_submission_at: Option<i64>,
}

/// Every value of [`AppError::code`].
pub const ERROR_CODES: [&str; 13] = [
    "invalid_field",
    "unauthorized",
    "forbidden",
    "not_found",
    "method_not_allowed",
    "conflict",
    "payload_too_large",
    "rate_limited",
    "quota_exceeded",
    "busy",
    "endpoint_rejected",
    "not_rendered",
    "internal",
];

fn code_schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
    utoipa::openapi::schema::ObjectBuilder::new()
        .schema_type(utoipa::openapi::schema::Type::String)
        .enum_values(Some(ERROR_CODES))
        .into()
}

impl From<StoreError> for AppError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::NotFound(what) => AppError::NotFound(format!("{what} not found")),
            StoreError::Conflict(message) => AppError::Conflict {
                field: Some("training_seed".into()),
                message,
            },
            e if e.is_busy() => AppError::Busy {
                retry_after: 2,
                reason: "the database is busy",
            },
            other => AppError::Internal(other.to_string()),
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        self.log();
        let mut resp = (self.status(), axum::Json(self.body())).into_response();
        self.headers(&mut resp);
        resp
    }
}

#[derive(Template)]
#[template(path = "error.html")]
struct ErrorPage<'a> {
    status: u16,
    reason: &'a str,
    message: String,
    field: Option<String>,
}

/// The error as the HTML page the browser-facing routes show.
pub fn error_page(e: &AppError) -> String {
    let status = e.status();
    ErrorPage {
        status: status.as_u16(),
        reason: status.canonical_reason().unwrap_or("Error"),
        message: e.to_string(),
        field: e.field().map(str::to_string),
    }
    .render()
    .unwrap_or_else(|_| "error".into())
}

/// The same errors rendered as an HTML page (for the browser-facing routes).
#[derive(Debug)]
pub struct PageError(pub AppError);

impl From<AppError> for PageError {
    fn from(e: AppError) -> Self {
        PageError(e)
    }
}

impl From<StoreError> for PageError {
    fn from(e: StoreError) -> Self {
        PageError(e.into())
    }
}

impl IntoResponse for PageError {
    fn into_response(self) -> Response {
        let e = self.0;
        e.log();
        let page = error_page(&e);
        let mut resp = (e.status(), Html(page)).into_response();
        e.headers(&mut resp);
        resp
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_is_in_the_documented_list() {
        let all = [
            AppError::invalid("f", "m"),
            AppError::Unauthorized(String::new()),
            AppError::Forbidden(String::new()),
            AppError::NotFound(String::new()),
            AppError::MethodNotAllowed(String::new()),
            AppError::Conflict {
                field: None,
                message: String::new(),
            },
            AppError::PayloadTooLarge(String::new()),
            AppError::RateLimited {
                retry_after: 1,
                limit: RATE_LIMIT_TOKEN,
            },
            AppError::QuotaExceeded {
                message: String::new(),
                retry_after: None,
                next_at: None,
            },
            AppError::Busy {
                retry_after: 1,
                reason: "busy",
            },
            AppError::EndpointRejected {
                kind: String::new(),
                message: String::new(),
            },
            AppError::NotRendered(String::new()),
            AppError::Internal(String::new()),
        ];
        let codes: Vec<&str> = all.iter().map(AppError::code).collect();
        assert_eq!(codes, ERROR_CODES);
    }
}
