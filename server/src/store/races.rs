//! Races: sequential tests of two submissions' policies run side by side
//! (`POST /api/v1/races`, [`crate::races`]): a race job's row, its live
//! state while it runs and its report when it ends. A race waits in its
//! table as in a durable queue (migration 0013); a race slot leases it,
//! heartbeats while it runs, and loses the lease when it is cancelled.
//!
//! The table is still called `comparisons` (migration 0011 created it when
//! races were "sequential comparisons"): it holds races only. Renaming it
//! would need a migration on SQLite and on PostgreSQL and would break
//! backups and the upgrade fixtures made before it, for a name no user
//! sees; the Rust side calls it what it holds. The paired comparison of two
//! finished results (`GET /api/v1/compare`, [`crate::comparison`]) stores
//! nothing.

use super::moderation::audit_in;
use super::types::{RaceStatus, Stored};
use super::{now, Store, StoreError};
use d3il_protocol::{ProtocolKind, TaskId};

/// A race as stored.
#[derive(Debug, Clone)]
pub struct RaceRow {
    pub id: i64,
    pub submission_a: i64,
    pub submission_b: i64,
    pub submitter_id: Option<i64>,
    pub task: TaskId,
    pub protocol: ProtocolKind,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
    pub status: RaceStatus,
    pub live_json: Option<String>,
    pub report_json: Option<String>,
    pub error_message: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
    /// Who cancelled it (its starter or an admin).
    pub cancelled_by: Option<String>,
}

from_row!(RaceRow { id, submission_a, submission_b, submitter_id, task: Stored<TaskId>, protocol: Stored<ProtocolKind>, seed, alpha, delta, status, live_json, report_json, error_message, created_at, updated_at, cancelled_by });

/// What cancelling a race did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RaceCancel {
    /// It was queued or running and is cancelled now.
    Cancelled,
    /// It had ended already (completed, failed or cancelled).
    AlreadyFinished,
}

const COLUMNS: &str = "id, submission_a, submission_b, submitter_id, task, protocol, seed, alpha, \
     delta, status, live_json, report_json, error_message, created_at, updated_at, cancelled_by";

/// What a new race records.
#[derive(Debug, Clone)]
pub struct NewRace {
    pub submission_a: i64,
    pub submission_b: i64,
    pub submitter_id: i64,
    pub task: TaskId,
    pub protocol: ProtocolKind,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
}

impl Store {
    /// Records a queued race; returns its id.
    pub async fn create_race(&self, c: &NewRace) -> Result<i64, StoreError> {
        let t = now();
        let (id,): (i64,) = on_db!(&self.db, pool => sqlx::query_as(
            "INSERT INTO comparisons (submission_a, submission_b, submitter_id, task, protocol, \
             seed, alpha, delta, status, created_at, updated_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, 'queued', $9, $9) RETURNING id",
        )
        .bind(c.submission_a)
        .bind(c.submission_b)
        .bind(c.submitter_id)
        .bind(c.task.slug())
        .bind(c.protocol.as_str())
        .bind(c.seed)
        .bind(c.alpha)
        .bind(c.delta)
        .bind(t)
        .fetch_one(pool)
        .await)?;
        Ok(id)
    }

    /// The race `id` (404 when there is none).
    pub async fn race(&self, id: i64) -> Result<RaceRow, StoreError> {
        let q = format!("SELECT {COLUMNS} FROM comparisons WHERE id = $1");
        let row: Option<RaceRow> = on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(q.as_str()))
            .bind(id)
            .fetch_optional(pool)
            .await)?;
        row.ok_or_else(|| StoreError::NotFound(format!("race {id}")))
    }

    /// Races this server's slots held when it stopped (SQLite: the one
    /// server owns the file, so every lease left is its own) go back to the
    /// queue, to run again from their first pair; returns how many.
    pub async fn requeue_abandoned_races(&self) -> Result<u64, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'queued', lease_owner = NULL, lease_expires_at = NULL, \
             live_json = NULL, updated_at = $1 WHERE status = 'running'",
        )
        .bind(now())
        .execute(pool)
        .await
        .map(|r| r.rows_affected()))?)
    }

    /// Leases the oldest runnable race (queued, or running under an expired
    /// lease: its slot died) to `owner` for `lease` seconds and marks it
    /// running, its live state afresh; None when none waits.
    pub async fn claim_race(&self, owner: &str, lease: i64) -> Result<Option<RaceRow>, StoreError> {
        const PICK: &str = "SELECT id FROM comparisons WHERE status = 'queued' \
             OR (status = 'running' AND lease_expires_at < $1) ORDER BY id LIMIT 1";
        let pick = if self.is_postgres() {
            format!("{PICK} FOR UPDATE SKIP LOCKED")
        } else {
            PICK.to_string()
        };
        let t = now();
        // A read first: an idle slot's poll takes no write lock.
        let waiting: Option<i64> = on_db!(&self.db, pool => sqlx::query_scalar(PICK)
            .bind(t)
            .fetch_optional(pool)
            .await)?;
        if waiting.is_none() {
            return Ok(None);
        }
        let claimed: Option<i64> = on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let id: Option<i64> = sqlx::query_scalar(sqlx::AssertSqlSafe(pick.as_str()))
                .bind(t)
                .fetch_optional(&mut *tx)
                .await?;
            if let Some(id) = id {
                sqlx::query(
                    "UPDATE comparisons SET status = 'running', lease_owner = $2, lease_expires_at = $3, \
                     live_json = NULL, report_json = NULL, error_message = NULL, updated_at = $4 WHERE id = $1",
                )
                .bind(id)
                .bind(owner)
                .bind(t + lease)
                .bind(t)
                .execute(&mut *tx)
                .await?;
            }
            tx.commit().await?;
            id
        });
        match claimed {
            Some(id) => Ok(Some(self.race(id).await?)),
            None => Ok(None),
        }
    }

    /// Extends `owner`'s lease of race `id`; false when it no longer holds
    /// it (the race was cancelled, or another slot took it over).
    pub async fn race_heartbeat(
        &self,
        id: i64,
        owner: &str,
        lease: i64,
    ) -> Result<bool, StoreError> {
        let t = now();
        let n = on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET lease_expires_at = $3 WHERE id = $1 AND lease_owner = $2 AND status = 'running'",
        )
        .bind(id)
        .bind(owner)
        .bind(t + lease)
        .execute(pool)
        .await
        .map(|r| r.rows_affected()))?;
        Ok(n > 0)
    }

    /// Cancels race `id` if it is queued or running, with the audit entry
    /// `audit` (actor, action, target, detail) in the same transaction; a
    /// running race's slot sees its lease gone and stops its worker.
    pub async fn cancel_race(
        &self,
        id: i64,
        by: &str,
        audit: Option<(&str, &str, &str, &str)>,
    ) -> Result<RaceCancel, StoreError> {
        let t = now();
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query(
                "UPDATE comparisons SET status = 'cancelled', cancelled_by = $2, lease_owner = NULL, \
                 lease_expires_at = NULL, error_message = $3, updated_at = $4 \
                 WHERE id = $1 AND status IN ('queued', 'running')",
            )
            .bind(id)
            .bind(by)
            .bind(format!("cancelled by {by}"))
            .bind(t)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if n == 0 {
                tx.rollback().await?;
                return Ok(RaceCancel::AlreadyFinished);
            }
            if let Some((actor, action, target, detail)) = audit {
                audit_in!(&mut *tx, t, actor, action, target, detail);
            }
            tx.commit().await?;
            Ok(RaceCancel::Cancelled)
        })
    }

    /// Races of submitter `id` queued or running.
    pub async fn active_races(&self, submitter_id: i64) -> Result<i64, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT COUNT(*) FROM comparisons WHERE submitter_id = $1 AND status IN ('queued', 'running')",
        )
        .bind(submitter_id)
        .fetch_one(pool)
        .await)?)
    }

    /// Its live state after the latest pair.
    pub async fn race_live(&self, id: i64, live_json: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET live_json = $3, updated_at = $2 WHERE id = $1 AND status = 'running'",
        )
        .bind(id)
        .bind(now())
        .bind(live_json)
        .execute(pool)
        .await
        .map(|_| ()))?;
        Ok(())
    }

    /// The race's report: completed (unless it was cancelled meanwhile).
    pub async fn race_completed(&self, id: i64, report_json: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'completed', report_json = $3, updated_at = $2, lease_owner = NULL, \
             lease_expires_at = NULL WHERE id = $1 AND status = 'running'",
        )
        .bind(id)
        .bind(now())
        .bind(report_json)
        .execute(pool)
        .await
        .map(|_| ()))?;
        Ok(())
    }

    /// The race failed (a policy broke, or the worker did): the message says why.
    pub async fn race_failed(&self, id: i64, message: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'failed', error_message = $3, updated_at = $2, lease_owner = NULL, \
             lease_expires_at = NULL WHERE id = $1 AND status IN ('queued', 'running')",
        )
        .bind(id)
        .bind(now())
        .bind(message)
        .execute(pool)
        .await
        .map(|_| ()))?;
        Ok(())
    }
}
