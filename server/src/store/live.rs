//! The outcomes a running evaluation has reported so far (the
//! basis of its live confidence sequence) and cancelling an evaluation.

use super::moderation::audit_in;
use super::{now, to_json, Store, StoreError};
use serde::{Deserialize, Serialize};

/// The outcome of one finished initial state: how many of its rollouts
/// succeeded. Stored as `[successes, rollouts]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(from = "(u32, u32)", into = "(u32, u32)")]
pub struct StateOutcome {
    pub successes: u32,
    pub rollouts: u32,
}

impl From<(u32, u32)> for StateOutcome {
    fn from((successes, rollouts): (u32, u32)) -> Self {
        StateOutcome {
            successes,
            rollouts,
        }
    }
}

impl From<StateOutcome> for (u32, u32) {
    fn from(o: StateOutcome) -> Self {
        (o.successes, o.rollouts)
    }
}

/// Who cancelled an evaluation, and when.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Cancelled {
    pub at: i64,
    pub by: String,
}

/// What a cancel request found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CancelOutcome {
    /// The evaluation was queued or running and is now cancelled.
    Cancelled,
    /// It had already finished (completed, failed or cancelled): nothing changed.
    AlreadyFinished,
}

/// The error kind (and `error_kind` column value) of a cancelled evaluation.
pub const CANCELLED_KIND: &str = "cancelled";

impl Store {
    /// Records the outcomes the attempt leased to `owner` has reported so far
    /// (the whole list, in order). Returns false if the lease was lost.
    pub async fn record_outcomes(
        &self,
        job_id: i64,
        owner: &str,
        outcomes: &[StateOutcome],
    ) -> Result<bool, StoreError> {
        let n = on_db!(&self.db, pool => sqlx::query(
            "UPDATE jobs SET outcomes_json = $1 WHERE id = $2 AND lease_owner = $3 AND state = 'leased'",
        )
        .bind(to_json(&outcomes))
        .bind(job_id)
        .bind(owner)
        .execute(pool)
        .await
        .map(|r| r.rows_affected()))?;
        Ok(n == 1)
    }

    /// The outcomes each job row (shard) of a submission has reported, in
    /// shard order: those of the running attempt, or of the last one when the
    /// job ended (a cancelled evaluation's partial result).
    pub async fn outcomes_of(
        &self,
        submission_id: i64,
    ) -> Result<Vec<Vec<StateOutcome>>, StoreError> {
        let rows: Vec<(i64, Option<String>)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT shard_index, outcomes_json FROM jobs WHERE submission_id = $1 ORDER BY shard_index",
        )
        .bind(submission_id)
        .fetch_all(pool)
        .await)?;
        rows.into_iter()
            .map(|(index, json)| match json {
                None => Ok(Vec::new()),
                Some(j) => serde_json::from_str(&j).map_err(|e| {
                    StoreError::Corrupt(format!(
                        "outcomes of shard {} of submission {submission_id}: {e}",
                        index + 1
                    ))
                }),
            })
            .collect()
    }

    /// When and by whom the submission was cancelled, if it was.
    pub async fn cancelled(&self, submission_id: i64) -> Result<Option<Cancelled>, StoreError> {
        let row: Option<(Option<i64>, Option<String>)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT cancelled_at, cancelled_by FROM submissions WHERE id = $1",
        )
        .bind(submission_id)
        .fetch_optional(pool)
        .await)?;
        Ok(match row {
            Some((Some(at), by)) => Some(Cancelled {
                at,
                by: by.unwrap_or_default(),
            }),
            _ => None,
        })
    }

    /// Cancels a queued or running evaluation in one transaction: every job
    /// row not done fails with kind `cancelled` (a running worker loses its
    /// lease: its heartbeat says so and the slot stops it, and whatever it
    /// reports afterwards is ignored), the submission fails with the same
    /// kind and records who and when. The outcomes reported so far stay in
    /// the job rows. A failed submission keeps its file's hash, not the file.
    pub async fn cancel_submission(
        &self,
        submission_id: i64,
        by: &str,
        audit: Option<(&str, &str, &str, &str)>,
    ) -> Result<CancelOutcome, StoreError> {
        let t = now();
        let lock = if self.is_postgres() {
            "SELECT status FROM submissions WHERE id = $1 FOR UPDATE"
        } else {
            "SELECT status FROM submissions WHERE id = $1"
        };
        let outcome = on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let status: Option<String> = sqlx::query_scalar(lock)
                .bind(submission_id)
                .fetch_optional(&mut *tx)
                .await?;
            let Some(status) = status else {
                return Err(StoreError::NotFound(format!("submission {submission_id}")));
            };
            if status != "queued" && status != "running" {
                tx.commit().await?;
                return Ok(CancelOutcome::AlreadyFinished);
            }
            let done: Vec<(i64, i64)> = sqlx::query_as(
                "SELECT rollouts_done, rollouts_total FROM jobs WHERE submission_id = $1",
            )
            .bind(submission_id)
            .fetch_all(&mut *tx)
            .await?;
            let (d, n) = done.iter().fold((0, 0), |(d, n), (a, b)| (d + a, n + b));
            let message = format!("cancelled by {by} after {d} of {n} rollouts; the rollouts that ran are kept as a partial result, never ranked");
            sqlx::query(
                "UPDATE jobs SET state = 'failed', lease_owner = NULL, lease_expires_at = NULL, finished_at = $1, \
                 error_kind = $2, error_message = $3 WHERE submission_id = $4 AND state IN ('queued', 'leased')",
            )
            .bind(t)
            .bind(CANCELLED_KIND)
            .bind(&message)
            .bind(submission_id)
            .execute(&mut *tx)
            .await?;
            sqlx::query(
                "UPDATE submissions SET status = 'failed', error_kind = $1, error_message = $2, updated_at = $3, \
                 cancelled_at = $3, cancelled_by = $4 WHERE id = $5",
            )
            .bind(CANCELLED_KIND)
            .bind(&message)
            .bind(t)
            .bind(by)
            .bind(submission_id)
            .execute(&mut *tx)
            .await?;
            // The audit entry (an admin cancelling another's evaluation)
            // commits with the cancel.
            if let Some((actor, action, target, detail)) = audit {
                audit_in!(&mut *tx, t, actor, action, target, detail);
            }
            tx.commit().await?;
            CancelOutcome::Cancelled
        });
        if let Err(e) = self.release_policy_of(submission_id).await {
            tracing::warn!("submission {submission_id}: policy file not deleted: {e}");
        }
        Ok(outcome)
    }
}
