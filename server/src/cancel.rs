//! Cancelling an evaluation (issue 41): the one rule the API
//! (`POST /api/v1/submissions/{id}/cancel`) and the submission page's
//! button share.

use crate::error::AppError;
use crate::state::AppState;
use crate::store::{CancelOutcome, Submitter};

/// Cancels submission `id` as `who`: its submitter or an admin may. The one
/// rule for the API and the submission page's button.
pub async fn cancel_as(state: &AppState, id: i64, who: &Submitter) -> Result<(), AppError> {
    let s = state.store.submission(id).await?;
    if !who.is_admin && s.submitter.as_deref() != Some(who.name.as_str()) {
        return Err(AppError::Forbidden(format!(
            "submission {id} belongs to {}; only its submitter or an admin may cancel it",
            s.submitter.as_deref().unwrap_or("nobody")
        )));
    }
    match state.store.cancel_submission(id, &who.name).await? {
        CancelOutcome::Cancelled => {
            tracing::info!("submission {id} cancelled by {}", who.name);
            // An admin stopping someone else's evaluation is moderation:
            // it goes to the audit log like a withdrawal.
            if who.is_admin && s.submitter.as_deref() != Some(who.name.as_str()) {
                state
                    .store
                    .audit(
                        &who.name,
                        "cancel",
                        &format!("submission {id}"),
                        "cancelled a queued or running evaluation",
                    )
                    .await?;
            }
            Ok(())
        }
        CancelOutcome::AlreadyFinished => Err(AppError::Conflict {
            field: None,
            message: format!(
                "submission {id} is {} already; only a queued or running evaluation can be cancelled",
                s.status.as_str()
            ),
        }),
    }
}
