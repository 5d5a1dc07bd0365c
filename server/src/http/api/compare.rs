//! `GET /api/v1/compare?a=<submission>&b=<submission>`: paired comparison of
//! two evaluated submissions on the same task, protocol and initial states
//! (`d3il_metrics::compare`, the same as `d3il compare a.json b.json`).

use crate::error::{AppError, ErrorBody};
use crate::state::AppState;
use axum::extract::{Query, State};
use axum::Json;
use d3il_metrics::Bootstrap;
use crate::store::{ResultRow, SubmissionRow, SubmissionStatus};
use d3il_protocol::{Comparison, ProtocolManifest};
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
        (status = 200, description = "Differences in success rate and conditional entropy with paired bootstrap intervals, p-values and minimum detectable differences", body = Object),
        (status = 400, description = "Missing or malformed ids, or results that cannot be paired (different task, protocol or initial states)", body = ErrorBody),
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

/// A finished submission with its stored result and protocol manifest: what
/// a paired comparison needs (the API and the `/compare` page).
pub struct Finished {
    pub submission: SubmissionRow,
    pub result: ResultRow,
    pub manifest: ProtocolManifest,
}

/// Loads submission `sid` (query field `field`) for a comparison: it must
/// exist (404), be completed (a 400 naming its status otherwise: queued, running, failed) and
/// have a result.
pub async fn finished(state: &AppState, field: &str, sid: i64) -> Result<Finished, AppError> {
    let submission = state.store.submission(sid).await?;
    if submission.status != SubmissionStatus::Completed {
        return Err(AppError::invalid(
            field,
            format!(
                "submission {sid} (`{field}`) is {}; only finished submissions can be compared: wait for its result (/submissions/{sid})",
                submission.status
            ),
        ));
    }
    let result = state.store.result_for(sid).await?.ok_or_else(|| {
        AppError::NotFound(format!(
            "submission {sid} (`{field}`) has no results yet; poll /api/v1/submissions/{sid}"
        ))
    })?;
    let manifest = result.manifest().ok_or_else(|| {
        AppError::Internal(format!("submission {sid}: stored manifest does not parse"))
    })?;
    Ok(Finished {
        submission,
        result,
        manifest,
    })
}

/// The paired comparison A − B (`d3il_metrics::compare_parts`, the same as
/// `d3il compare`); results that cannot be paired are a 400 on `b`.
pub fn paired(a: &Finished, b: &Finished) -> Result<Comparison, AppError> {
    let cfg = Bootstrap {
        resamples: 2000,
        confidence: 0.95,
        seed: 0,
    };
    d3il_metrics::compare_parts(
        (&a.manifest, &a.result.per_context_json.0),
        (&b.manifest, &b.result.per_context_json.0),
        &cfg,
    )
    .map_err(|e| AppError::invalid("b", e.to_string()))
}
