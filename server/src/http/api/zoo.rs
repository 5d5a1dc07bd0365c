//! The zoo's provenance records: what a zoo submission was
//! trained from and with, as shipped in its cell's `provenance.json`.

use crate::error::{AppError, ErrorBody};
use crate::http::extract::Param;
use crate::state::AppState;
use crate::zoo::{provenance_view, ProvenanceView};
use axum::extract::State;
use axum::Json;

#[utoipa::path(get, path = "/submissions/{id}/provenance", tag = "submissions",
    summary = "The provenance of a zoo submission (one of the paper's methods trained here on our demonstrations): its provenance.json, data source and whether this build made its result",
    params(("id" = i64, Path, description = "Submission id")),
    responses(
        (status = 200, description = "The provenance record", body = ProvenanceView),
        (status = 404, description = "No such submission, or not one of the zoo's", body = ErrorBody)))]
pub async fn get_provenance(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Json<ProvenanceView>, AppError> {
    let current = state.canary.fingerprint();
    provenance_view(&state.store, id, current.as_deref())
        .await?
        .map(Json)
        .ok_or_else(|| {
            AppError::NotFound(format!(
                "submission {id} is not one of the zoo's: only the zoo's submissions have a provenance record"
            ))
        })
}
