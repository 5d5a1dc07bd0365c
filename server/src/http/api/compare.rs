//! `GET /api/v1/compare?a=<submission>&b=<submission>`: paired comparison of
//! two evaluated submissions on the same task, protocol and initial states
//! (`d3il_metrics::compare`, the same as `d3il compare a.json b.json`).

use crate::comparison::{finished, paired};
use crate::error::{AppError, ErrorBody};
use crate::http::extract::Query;
use crate::schema;
use crate::state::AppState;
use axum::extract::State;
use axum::Json;
use d3il_protocol::Comparison;
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
        (status = 200, description = "Differences in success rate and conditional entropy with paired bootstrap intervals, p-values and minimum detectable differences", body = ComparisonSchema),
        (status = 400, description = "Missing or malformed ids, a submission that has not finished, or results that cannot be paired (different task, protocol or initial states)", body = ErrorBody),
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

// A schema only, of `d3il_protocol::Comparison` as serde writes it, so that
// clients can check the comparison as they check every other answer.
/// A paired comparison A − B of two results on the same task, protocol and
/// initial states (as `d3il compare --json` prints it).
#[derive(utoipa::ToSchema)]
#[schema(as = Comparison)]
#[allow(dead_code)] // a schema only: the handler returns d3il_protocol::Comparison
pub struct ComparisonSchema {
    #[schema(value_type = schema::Task)]
    task: String,
    #[schema(value_type = schema::Protocol)]
    protocol: String,
    /// The shared initial-state set's file name.
    initial_states: String,
    initial_states_sha256: String,
    n_contexts: u64,
    rollouts_per_context: u64,
    /// Resamples of the bootstrap and of the randomisation test.
    resamples: u64,
    confidence: f64,
    /// Stacking: Stacking-3's.
    success_rate: PairedDifferenceSchema,
    conditional_entropy: PairedDifferenceSchema,
    /// What else differs between A and B, so that the difference is not the
    /// policies' alone; absent when nothing does.
    caveats: Option<Vec<String>>,
}

/// An estimate as a result document carries it (`d3il_protocol::Estimate`):
/// the value, its interval and the interval's method, or why there is none.
/// Unlike the result views' estimates it has no `interval` text.
#[derive(utoipa::ToSchema)]
#[schema(as = DocumentEstimate)]
#[allow(dead_code)] // a schema only
pub struct DocumentEstimateSchema {
    value: f64,
    /// Equal to `value` when `no_interval` is given.
    ci_low: f64,
    ci_high: f64,
    /// The interval's method (`sign_flip_exact`, ...); absent when there is none.
    #[schema(value_type = Option<String>)]
    method: Option<String>,
    /// Why there is no interval (`{"reason": "too_few_states", "states": 3, "min": 5}`).
    #[schema(value_type = Option<Object>)]
    no_interval: Option<serde_json::Value>,
}

/// One metric of a paired comparison.
#[derive(utoipa::ToSchema)]
#[schema(as = PairedDifference)]
#[allow(dead_code)] // a schema only
pub struct PairedDifferenceSchema {
    /// The metric of A, the mean over the shared initial states.
    a: f64,
    /// The metric of B.
    b: f64,
    /// A − B with its interval over initial states (the inverted paired
    /// test whose p-value is `p_value`, or why there is none).
    difference: DocumentEstimateSchema,
    /// Two-sided p-value of "no difference" (randomisation test paired by initial state).
    p_value: f64,
    /// The smallest true |A − B| detected with 80 % power at the 5 % level.
    min_detectable: f64,
}
