//! Cancelling an evaluation: the one rule the API
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
    // An admin stopping someone else's evaluation is moderation: it goes to
    // the audit log like a withdrawal, in the cancel's own transaction.
    let target = format!("submission {id}");
    let moderation = who.is_admin && s.submitter.as_deref() != Some(who.name.as_str());
    let audit = moderation.then_some((
        who.name.as_str(),
        "cancel",
        target.as_str(),
        "cancelled a queued or running evaluation",
    ));
    match state.store.cancel_submission(id, &who.name, audit).await? {
        CancelOutcome::Cancelled => {
            tracing::info!("submission {id} cancelled by {}", who.name);
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
