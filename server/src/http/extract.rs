//! The one way a URL names a task or a submission: `{task}` and `{id}` path
//! segments are parsed here, and a segment that names nothing is a 404 in
//! every part of the site (a JSON error under `/api/`, an HTML page elsewhere).
//! The `?obs=` query is parsed here too, and every query string is read
//! with [`Query`], whose refusal is the same error as any other (JSON under
//! `/api/`, an HTML page elsewhere), not axum's plain-text one; so is a JSON
//! request body ([`parse_json_request`]).

use crate::error::{AppError, PageError};
use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::response::{IntoResponse, Response};
use d3il_protocol::{ObsType, TaskId};
use std::str::FromStr;

/// A value named by the URL's one path parameter.
pub trait PathValue: Sized {
    fn from_segment(s: &str) -> Result<Self, AppError>;
}

impl PathValue for TaskId {
    fn from_segment(s: &str) -> Result<Self, AppError> {
        TaskId::from_str(s).map_err(|e| AppError::NotFound(e.to_string()))
    }
}

/// Submission ids are positive integers.
impl PathValue for i64 {
    fn from_segment(s: &str) -> Result<Self, AppError> {
        s.parse::<i64>()
            .ok()
            .filter(|i| *i > 0)
            .ok_or_else(|| AppError::NotFound(format!("no submission `{s}`")))
    }
}

/// `Param<TaskId>` or `Param<i64>`: the route's path parameter, parsed.
pub struct Param<T>(pub T);

/// A path parameter that names nothing, shown as the part of the site asked
/// for it expects (JSON under `/api/`, HTML elsewhere).
pub struct ParamRejection {
    error: AppError,
    api: bool,
}

impl IntoResponse for ParamRejection {
    fn into_response(self) -> Response {
        if self.api {
            self.error.into_response()
        } else {
            PageError(self.error).into_response()
        }
    }
}

impl<S: Send + Sync, T: PathValue> FromRequestParts<S> for Param<T> {
    type Rejection = ParamRejection;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ParamRejection> {
        let api = is_api(parts);
        let reject = |error| ParamRejection { error, api };
        let axum::extract::Path(segment) =
            axum::extract::Path::<String>::from_request_parts(parts, state)
                .await
                .map_err(|e| reject(AppError::NotFound(e.body_text())))?;
        T::from_segment(&segment).map(Param).map_err(reject)
    }
}

/// `{id}/…/{n}`: a submission and one of its rollouts by number, parsed
/// like [`Param`] (a segment that names nothing is a 404).
pub struct RolloutParam(pub i64, pub usize);

impl<S: Send + Sync> FromRequestParts<S> for RolloutParam {
    type Rejection = ParamRejection;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ParamRejection> {
        let api = is_api(parts);
        let reject = |error| ParamRejection { error, api };
        let axum::extract::Path((id, n)) =
            axum::extract::Path::<(String, String)>::from_request_parts(parts, state)
                .await
                .map_err(|e| reject(AppError::NotFound(e.body_text())))?;
        let id = i64::from_segment(&id).map_err(reject)?;
        let n = n.parse::<usize>().map_err(|_| {
            reject(AppError::NotFound(format!(
                "no rollout `{n}`: rollouts are numbered from 0"
            )))
        })?;
        Ok(RolloutParam(id, n))
    }
}

/// Whether the request is for the API (nested routers see the path below
/// their prefix: ask for the original).
fn is_api(parts: &Parts) -> bool {
    parts
        .extensions
        .get::<axum::extract::OriginalUri>()
        .map_or(parts.uri.path(), |u| u.0.path())
        .starts_with("/api/")
}

/// A route's query string read into `T` (every field a string, so only a
/// malformed or repeated parameter is refused here; the handler checks the
/// values and names the field).
pub struct Query<T>(pub T);

impl<S: Send + Sync, T: serde::de::DeserializeOwned> FromRequestParts<S> for Query<T> {
    type Rejection = ParamRejection;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ParamRejection> {
        match axum::extract::Query::<T>::from_request_parts(parts, state).await {
            Ok(axum::extract::Query(q)) => Ok(Query(q)),
            Err(e) => Err(ParamRejection {
                error: AppError::Invalid {
                    field: None,
                    message: format!(
                        "the query string cannot be read ({}); give each parameter at most once, as docs/api.md lists them",
                        e.body_text()
                    ),
                },
                api: is_api(parts),
            }),
        }
    }
}

/// `?obs=state|image` (state when absent or empty).
pub fn obs_query(obs: Option<&str>) -> Result<ObsType, AppError> {
    match obs {
        None | Some("") => Ok(ObsType::State),
        Some(o) => ObsType::from_str(o).map_err(|e| AppError::invalid("obs", e)),
    }
}

/// A JSON request body read as `T`, refused with the same error format as
/// the rest (a 400 that shows `example`, a body the endpoint takes).
pub fn parse_json_request<T: serde::de::DeserializeOwned>(
    body: &[u8],
    example: &str,
) -> Result<T, AppError> {
    serde_json::from_slice(body).map_err(|e| AppError::Invalid {
        field: None,
        message: format!("expected a JSON body like {example}: {e}"),
    })
}
