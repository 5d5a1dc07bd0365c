//! A submission's robustness document (docs/robustness.md): what
//! a submission with `suite=robustness` produced, level 0 and every level of
//! the task's perturbation suite with paired drops and scores.

use crate::error::{AppError, ErrorBody};
use crate::http::extract::{Param, Query};
use crate::schema;
use crate::state::AppState;
use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use utoipa::IntoParams;

#[derive(Debug, Deserialize, Default, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct RobustnessQuery {
    /// `false`: the document without rollout records (per-initial-state
    /// outcomes, metrics, paired drops and scores only; much smaller).
    /// Default `true`: every level's records, which replay with
    /// `d3il replay --result FILE --level AXIS/N --rollout K`.
    pub rollouts: Option<bool>,
}

/// The robustness document (`format` `d3il-robustness-v1`, type
/// `RobustnessResult` in protocol/src/robustness.rs).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // a schema only: the handler serves the stored document
pub struct RobustnessDocument {
    /// `d3il-robustness-v1`.
    format: String,
    #[schema(value_type = schema::Task)]
    task: String,
    /// The suite file's name (e.g. `aligning-v1.json`).
    suite: String,
    /// The suite file's sha256: documents of different suite versions are
    /// never ranked together.
    suite_sha256: String,
    /// Level 0: the plain evaluation (an evaluation result, as
    /// `/submissions/{id}/results` serves its parts).
    #[schema(value_type = Object)]
    control: (),
    /// Every perturbed level: `axis`, `level`, `setting`, `result` (an
    /// evaluation result), `paired` (level 0 − level, paired by initial
    /// state, as `/compare`), `retained` (success rate over level 0's).
    #[schema(value_type = Vec<Object>)]
    levels: (),
    /// Per axis: `axis` and `score` (success retained averaged over the
    /// axis's levels, `{value, ci_low, ci_high}`; null when level 0 has no
    /// success).
    #[schema(value_type = Vec<Object>)]
    axes: (),
    /// Mean of the axes' scores with its interval (null when level 0 has
    /// no success).
    #[schema(value_type = Option<Object>)]
    overall: (),
    resamples: usize,
    confidence: f64,
}

#[utoipa::path(get, path = "/submissions/{id}/robustness", tag = "submissions",
    summary = "The robustness document of a submission made with `suite=robustness`: level 0 and every perturbed level, paired drops, scores",
    params(("id" = i64, Path, description = "Submission id"), RobustnessQuery),
    responses(
        (status = 200, description = "The robustness document", body = RobustnessDocument),
        (status = 404, description = "No such submission, a submission without the suite, or not evaluated yet", body = ErrorBody)))]
pub async fn get_robustness(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Query(q): Query<RobustnessQuery>,
) -> Result<Response, AppError> {
    let s = state.store.submission(id).await?;
    if s.suite.is_none() {
        return Err(AppError::NotFound(format!(
            "submission {id} was not made with a suite (submit with suite=robustness for a robustness evaluation)"
        )));
    }
    let missing = || {
        AppError::NotFound(format!(
            "submission {id} has no robustness document yet (status: {}); poll /api/v1/submissions/{id}",
            s.status
        ))
    };
    let body = if q.rollouts.unwrap_or(true) {
        state
            .store
            .robustness_document(id)
            .await?
            .ok_or_else(missing)?
    } else {
        let summary = state
            .store
            .robustness_summary(id)
            .await?
            .ok_or_else(missing)?;
        serde_json::to_string(&summary)
            .map_err(|e| AppError::Internal(format!("robustness encoding: {e}")))?
    };
    Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
}
