//! Issue 41: sequential comparisons of two submissions (`comparisons`
//! table, migration 0011): a race job's row, its live state while it runs
//! and its report when it ends.

use super::{now, Store, StoreError};

/// A comparison as stored.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct ComparisonRow {
    pub id: i64,
    pub submission_a: i64,
    pub submission_b: i64,
    pub submitter_id: Option<i64>,
    pub task: String,
    pub protocol: String,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
    /// queued | running | completed | failed
    pub status: String,
    pub live_json: Option<String>,
    pub report_json: Option<String>,
    pub error_message: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
}

/// What a new comparison records.
#[derive(Debug, Clone)]
pub struct NewComparison {
    pub submission_a: i64,
    pub submission_b: i64,
    pub submitter_id: i64,
    pub task: String,
    pub protocol: String,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
}

impl Store {
    /// Records a queued comparison; returns its id.
    pub async fn create_comparison(&self, c: &NewComparison) -> Result<i64, StoreError> {
        let t = now();
        let (id,): (i64,) = on_db!(&self.db, pool => sqlx::query_as(
            "INSERT INTO comparisons (submission_a, submission_b, submitter_id, task, protocol, \
             seed, alpha, delta, status, created_at, updated_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, 'queued', $9, $9) RETURNING id",
        )
        .bind(c.submission_a)
        .bind(c.submission_b)
        .bind(c.submitter_id)
        .bind(&c.task)
        .bind(&c.protocol)
        .bind(c.seed)
        .bind(c.alpha)
        .bind(c.delta)
        .bind(t)
        .fetch_one(pool)
        .await)?;
        Ok(id)
    }

    /// The comparison `id` (404 when there is none).
    pub async fn comparison(&self, id: i64) -> Result<ComparisonRow, StoreError> {
        let row: Option<ComparisonRow> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT id, submission_a, submission_b, submitter_id, task, protocol, seed, alpha, \
             delta, status, live_json, report_json, error_message, created_at, updated_at \
             FROM comparisons WHERE id = $1",
        )
            .bind(id)
            .fetch_optional(pool)
            .await)?;
        row.ok_or_else(|| StoreError::NotFound(format!("comparison {id}")))
    }

    /// Comparisons not finished (queued, or running when the server
    /// stopped): run again at start-up, from the beginning.
    pub async fn unfinished_comparisons(&self) -> Result<Vec<i64>, StoreError> {
        let rows: Vec<(i64,)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT id FROM comparisons WHERE status IN ('queued', 'running') ORDER BY id",
        )
        .fetch_all(pool)
        .await)?;
        Ok(rows.into_iter().map(|(id,)| id).collect())
    }

    /// Marks it running (its live state starts afresh).
    pub async fn comparison_running(&self, id: i64) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'running', live_json = NULL, report_json = NULL, \
             error_message = NULL, updated_at = $2 WHERE id = $1",
        )
        .bind(id)
        .bind(now())
        .execute(pool)
        .await
        .map(|_| ()))?;
        Ok(())
    }

    /// Its live state after the latest pair.
    pub async fn comparison_live(&self, id: i64, live_json: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET live_json = $3, updated_at = $2 WHERE id = $1",
        )
        .bind(id)
        .bind(now())
        .bind(live_json)
        .execute(pool)
        .await
        .map(|_| ()))?;
        Ok(())
    }

    /// The race's report: completed.
    pub async fn comparison_completed(&self, id: i64, report_json: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'completed', report_json = $3, updated_at = $2 WHERE id = $1",
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
    pub async fn comparison_failed(&self, id: i64, message: &str) -> Result<(), StoreError> {
        on_db!(&self.db, pool => sqlx::query(
            "UPDATE comparisons SET status = 'failed', error_message = $3, updated_at = $2 WHERE id = $1",
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
