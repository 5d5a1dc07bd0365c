//! Pairing two finished submissions for a comparison (`GET /api/v1/compare`
//! and the `/compare` page): loading them with clear errors, and the paired
//! comparison itself (`d3il_metrics::compare_parts`, as `d3il compare`).

use crate::error::AppError;
use crate::state::AppState;
use crate::store::{ResultRow, SubmissionRow, SubmissionStatus};
use d3il_metrics::Bootstrap;
use d3il_protocol::{Comparison, ProtocolManifest};

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
