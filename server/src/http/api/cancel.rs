//! `POST /api/v1/submissions/{id}/cancel`: stop a queued or
//! running evaluation, keeping what ran as a partial result.

use crate::auth::Authed;
use crate::cancel::cancel_as;
use crate::error::{AppError, ErrorBody};
use crate::http::extract::Param;
use crate::state::AppState;
use crate::views::SubmissionView;
use axum::extract::State;
use axum::Json;

#[utoipa::path(post, path = "/submissions/{id}/cancel", tag = "submissions",
    summary = "Cancel a queued or running evaluation (what ran is kept, marked partial, never ranked)",
    security(("bearer" = [])),
    params(("id" = i64, Path, description = "Submission id")),
    responses(
        (status = 200, description = "Cancelled: status `failed`, error kind `cancelled`, `cancelled` set, the partial outcomes in `progress.live`", body = SubmissionView),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 403, description = "Not the submission's submitter nor an admin", body = ErrorBody),
        (status = 404, description = "No such submission", body = ErrorBody),
        (status = 409, description = "The evaluation has finished already", body = ErrorBody),
        (status = 429, description = "Rate limit exceeded; see the Retry-After header", body = ErrorBody)))]
pub async fn cancel_submission(
    State(state): State<AppState>,
    Param(id): Param<i64>,
    Authed(who): Authed,
) -> Result<Json<SubmissionView>, AppError> {
    cancel_as(&state, id, &who).await?;
    Ok(Json(
        crate::views::submission_view_for(&state, id, Some(&who)).await?,
    ))
}
