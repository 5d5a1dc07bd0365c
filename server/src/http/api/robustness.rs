//! A submission's robustness document (docs/robustness.md): what
//! a submission with `suite=robustness` produced, level 0 and every level of
//! the task's perturbation suite with paired drops and scores, served with
//! the label of its score intervals when they come from too few initial
//! states to cover as they say (`score_interval_coverage`).

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
    /// Served, not stored: when the scores' intervals come from fewer
    /// initial states than their measured coverage reaches the nominal 95 %
    /// from (`d3il bench intervals`, docs/intervals.md), what was measured
    /// and the label the pages print; null from enough states (30) or
    /// without a score interval.
    score_interval_coverage: Option<ScoreIntervalCoverage>,
}

/// The label of a robustness document's score intervals
/// (`d3il_protocol::interval::ScoreCoverage`).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // a schema only: the handler serializes the protocol's type
pub struct ScoreIntervalCoverage {
    /// Initial states behind the scores (level 0's, which every level shares).
    states: usize,
    /// The fewest and most initial states of the measured cells the scores
    /// are read against.
    measured_states: [usize; 2],
    /// The lowest and highest coverage measured in those cells.
    measured_coverage: [f64; 2],
    /// 0.95.
    nominal: f64,
    /// The Monte-Carlo standard error of one measured cell's coverage.
    monte_carlo_standard_error: f64,
    /// From this many initial states on, the measured coverage is within
    /// Monte-Carlo error of the nominal: no label.
    min_states: usize,
    /// The label as the pages and tables print it, e.g. `from 3 initial
    /// states: measured coverage 66–74 %, below the nominal 95 %`.
    label: String,
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
    let summary = state
        .store
        .robustness_summary(id)
        .await?
        .ok_or_else(missing)?;
    let coverage = summary.score_coverage();
    let document = if q.rollouts.unwrap_or(true) {
        state
            .store
            .robustness_document(id)
            .await?
            .ok_or_else(missing)?
    } else {
        serde_json::to_string(&summary)
            .map_err(|e| AppError::Internal(format!("robustness encoding: {e}")))?
    };
    let body = with_score_coverage(&document, &coverage)?;
    Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
}

/// The document with `score_interval_coverage` as its first member. The
/// stored document (an object, as serde wrote it) is spliced rather than
/// parsed again: with its rollout records it runs to megabytes.
fn with_score_coverage(
    document: &str,
    coverage: &Option<d3il_protocol::ScoreCoverage>,
) -> Result<String, AppError> {
    let rest = document.trim_start().strip_prefix('{').ok_or_else(|| {
        AppError::Internal("a stored robustness document is not an object".into())
    })?;
    let field = serde_json::to_string(coverage)
        .map_err(|e| AppError::Internal(format!("robustness encoding: {e}")))?;
    let sep = if rest.trim_start().starts_with('}') {
        ""
    } else {
        ","
    };
    Ok(format!("{{\"score_interval_coverage\":{field}{sep}{rest}"))
}

#[cfg(test)]
mod tests {
    use super::with_score_coverage;

    #[test]
    fn the_label_is_spliced_in_as_a_member() {
        let c = d3il_protocol::interval::score_coverage(3);
        for doc in [r#"{"format":"d3il-robustness-v1","levels":[]}"#, " {}"] {
            let v: serde_json::Value =
                serde_json::from_str(&with_score_coverage(doc, &c).unwrap()).unwrap();
            assert_eq!(v["score_interval_coverage"]["states"], 3);
            let plain: serde_json::Value = serde_json::from_str(doc).unwrap();
            for (k, x) in plain.as_object().unwrap() {
                assert_eq!(&v[k], x);
            }
        }
        let v: serde_json::Value =
            serde_json::from_str(&with_score_coverage("{}", &None).unwrap()).unwrap();
        assert!(v["score_interval_coverage"].is_null());
        assert!(with_score_coverage("[]", &None).is_err());
    }
}
