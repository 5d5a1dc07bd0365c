//! The zoo's cells as finished submissions of the built-in `zoo`
//! submitter: loaded at every start (idempotently: a cell whose result
//! document is unchanged is left alone, a changed one is loaded again into
//! the same submission), with their ONNX in the policy store, their result
//! and rollouts stored as any evaluation's, a data-source mark and the
//! provenance record. Reading the cells from disk and checking them is
//! `crate::zoo`'s.

use super::types::{JobState, SubmissionStatus};
use super::{io_err, now, to_json, Store, StoreError};
use crate::leaderboard::protocol_str;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::EvalResult;
use std::path::PathBuf;

/// The submitter owning the zoo's submissions.
pub const ZOO_SUBMITTER: &str = "zoo";

/// One checked zoo cell, ready to store.
#[derive(Debug)]
pub struct NewZooCell {
    /// `<task>/<method-slug>-s<seed>`, the cell's directory under the zoo.
    pub cell: String,
    /// The paper's method name (`BC-MLP`).
    pub method: String,
    pub training_seed: i64,
    /// "trained here on d3il demos v1".
    pub data_source: String,
    pub result: EvalResult,
    pub result_sha256: String,
    /// The policy manifest (`policy.json`) as shipped.
    pub manifest_json: String,
    /// The shipped `policy.onnx`, its sha256 and size.
    pub onnx: PathBuf,
    pub onnx_sha256: String,
    pub onnx_bytes: i64,
    /// `provenance.json` as shipped (kept verbatim, shown as pretty JSON).
    pub provenance_json: String,
    /// The cell's robustness document, if it has one (its sha256 is in
    /// the provenance: a new or changed document changes the provenance).
    pub robustness: Option<RobustnessResult>,
}

/// What loading a cell did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZooLoad {
    /// A new submission.
    Inserted(i64),
    /// The result document changed: the submission holds the new one.
    Replaced(i64),
    /// Already stored with this result document.
    Unchanged(i64),
}

impl ZooLoad {
    pub fn submission_id(self) -> i64 {
        match self {
            ZooLoad::Inserted(id) | ZooLoad::Replaced(id) | ZooLoad::Unchanged(id) => id,
        }
    }
}

/// A zoo cell as stored: its submission and provenance record.
#[derive(Debug, Clone)]
pub struct ZooCellRow {
    pub cell: String,
    pub submission_id: i64,
    pub result_sha256: String,
    pub provenance_json: String,
    pub loaded_at: i64,
}

from_row!(ZooCellRow {
    cell,
    submission_id,
    result_sha256,
    provenance_json,
    loaded_at
});

impl ZooCellRow {
    /// The provenance record (the raw text when it does not parse, which a
    /// loaded cell's always does).
    pub fn provenance(&self) -> serde_json::Value {
        serde_json::from_str(&self.provenance_json)
            .unwrap_or_else(|_| serde_json::Value::String(self.provenance_json.clone()))
    }
}

impl Store {
    /// Stores `c` as a finished submission of the `zoo` submitter (see the
    /// module docs). The ONNX is copied into the policy store first.
    pub async fn load_zoo_cell(&self, c: &NewZooCell) -> Result<ZooLoad, StoreError> {
        let existing = self.zoo_cell(&c.cell).await?;
        if let Some(e) = &existing {
            if e.result_sha256 == c.result_sha256 {
                if e.provenance_json != c.provenance_json {
                    // A robustness document run since (or again) is in the
                    // provenance's hashes.
                    self.store_zoo_robustness(e.submission_id, c.robustness.as_ref())
                        .await?;
                    on_db!(&self.db, pool => sqlx::query("UPDATE zoo_cells SET provenance_json = $1 WHERE cell = $2")
                        .bind(&c.provenance_json)
                        .bind(&c.cell)
                        .execute(pool)
                        .await
                        .map(|_| ()))?;
                }
                return Ok(ZooLoad::Unchanged(e.submission_id));
            }
        }
        let onnx_path = self.store_zoo_onnx(c).await?;
        let existing_id = existing.map(|e| e.submission_id);
        let loaded =
            match super::retry_busy(|| self.load_zoo_cell_once(c, &onnx_path, existing_id)).await {
                // Front ends starting together on one PostgreSQL: another one
                // stored the same cell first.
                Err(StoreError::Conflict(m)) => match self.zoo_cell(&c.cell).await? {
                    Some(e) if e.result_sha256 == c.result_sha256 => {
                        Ok(ZooLoad::Unchanged(e.submission_id))
                    }
                    _ => Err(StoreError::Conflict(m)),
                },
                r => r,
            }?;
        if !matches!(loaded, ZooLoad::Unchanged(_)) {
            self.store_zoo_robustness(loaded.submission_id(), c.robustness.as_ref())
                .await?;
        }
        Ok(loaded)
    }

    /// Replaces the zoo submission's robustness document with `doc` (none:
    /// removes it); the submission is one with the `robustness` suite while
    /// it has one (its API document and page link it).
    async fn store_zoo_robustness(
        &self,
        submission_id: i64,
        doc: Option<&RobustnessResult>,
    ) -> Result<(), StoreError> {
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            sqlx::query("DELETE FROM robustness_results WHERE submission_id = $1")
                .bind(submission_id)
                .execute(&mut *tx)
                .await?;
            if let Some(doc) = doc {
                insert_robustness!(&mut *tx, submission_id, doc);
            }
            sqlx::query("UPDATE submissions SET suite = $1 WHERE id = $2")
                .bind(doc.map(|_| "robustness"))
                .bind(submission_id)
                .execute(&mut *tx)
                .await?;
            tx.commit().await?;
        });
        Ok(())
    }

    /// Copies the cell's ONNX to `<policies>/<sha256>.onnx` (kept if there).
    async fn store_zoo_onnx(&self, c: &NewZooCell) -> Result<String, StoreError> {
        let dest = self.policies_dir().join(format!("{}.onnx", c.onnx_sha256));
        if !tokio::fs::try_exists(&dest).await.unwrap_or(false) {
            let tmp = self.new_upload_path();
            tokio::fs::copy(&c.onnx, &tmp)
                .await
                .map_err(io_err(&c.onnx))?;
            self.commit_onnx(&tmp, &c.onnx_sha256).await?;
        }
        Ok(dest.to_string_lossy().into_owned())
    }

    async fn load_zoo_cell_once(
        &self,
        c: &NewZooCell,
        onnx_path: &str,
        existing: Option<i64>,
    ) -> Result<ZooLoad, StoreError> {
        let m = &c.result.manifest;
        let t = now();
        on_db!(&self.db, pool => {
        let mut tx = begin_write!(self, pool);
        sqlx::query("INSERT INTO submitters (name) VALUES ($1) ON CONFLICT(name) DO NOTHING")
            .bind(ZOO_SUBMITTER)
            .execute(&mut *tx)
            .await?;
        let submitter: i64 = sqlx::query_scalar("SELECT id FROM submitters WHERE name = $1")
            .bind(ZOO_SUBMITTER)
            .fetch_one(&mut *tx)
            .await?;
        // The paper's methods are there (loaded at every open); another
        // name gets a method of its own.
        sqlx::query(
            "INSERT INTO methods (name, description, submitter_id) VALUES ($1, $2, $3) ON CONFLICT(name) DO NOTHING",
        )
        .bind(&c.method)
        .bind("Trained here for the zoo (docs/zoo.md).")
        .bind(submitter)
        .execute(&mut *tx)
        .await?;
        let method_id: i64 = sqlx::query_scalar("SELECT id FROM methods WHERE name = $1")
            .bind(&c.method)
            .fetch_one(&mut *tx)
            .await?;
        let id = match existing {
            Some(id) => {
                // The old result, its rollouts and job make way for the new.
                for sql in [
                    "DELETE FROM rollouts WHERE submission_id = $1",
                    "DELETE FROM results WHERE submission_id = $1",
                    "DELETE FROM jobs WHERE submission_id = $1",
                ] {
                    sqlx::query(sql).bind(id).execute(&mut *tx).await?;
                }
                sqlx::query(
                    "UPDATE submissions SET method_id = $1, task = $2, obs_type = $3, training_seed = $4, protocol = $5, \
                     onnx_sha256 = $6, onnx_bytes = $7, onnx_path = $8, manifest_json = $9, data_source = $10, \
                     updated_at = $11 WHERE id = $12",
                )
                .bind(method_id)
                .bind(m.task.slug())
                .bind(m.obs_type.as_str())
                .bind(c.training_seed)
                .bind(protocol_str(m.protocol))
                .bind(&c.onnx_sha256)
                .bind(c.onnx_bytes)
                .bind(onnx_path)
                .bind(&c.manifest_json)
                .bind(&c.data_source)
                .bind(t)
                .bind(id)
                .execute(&mut *tx)
                .await?;
                id
            }
            None => sqlx::query_scalar(
                "INSERT INTO submissions (method_id, submitter_id, task, obs_type, training_seed, data_fraction, protocol, \
                 policy_kind, onnx_sha256, onnx_bytes, onnx_path, manifest_json, status, created_at, updated_at, data_source) \
                 VALUES ($1, $2, $3, $4, $5, 1.0, $6, 'onnx', $7, $8, $9, $10, $11, $12, $12, $13) RETURNING id",
            )
            .bind(method_id)
            .bind(submitter)
            .bind(m.task.slug())
            .bind(m.obs_type.as_str())
            .bind(c.training_seed)
            .bind(protocol_str(m.protocol))
            .bind(&c.onnx_sha256)
            .bind(c.onnx_bytes)
            .bind(onnx_path)
            .bind(&c.manifest_json)
            .bind(SubmissionStatus::Queued)
            .bind(t)
            .bind(&c.data_source)
            .fetch_one(&mut *tx)
            .await
            .map_err(|e| match &e {
                sqlx::Error::Database(d) if d.is_unique_violation() => StoreError::Conflict(format!(
                    "zoo cell {}: {} seed {} on {} is already in the zoo under another cell directory",
                    c.cell, c.method, c.training_seed, m.task
                )),
                _ => e.into(),
            })?,
        };
        let total = c.result.rollouts.len() as i64;
        // No start time: the evaluation ran elsewhere (`d3il eval`), and
        // queue ETAs are made from this server's own runs only.
        sqlx::query(
            "INSERT INTO jobs (submission_id, state, attempts, max_attempts, rollouts_done, rollouts_total, created_at, \
             finished_at, shard_index, shard_count) VALUES ($1, $2, 1, 1, $3, $3, $4, $4, 0, 1)",
        )
        .bind(id)
        .bind(JobState::Done)
        .bind(total)
        .bind(t)
        .execute(&mut *tx)
        .await?;
        insert_result!(&mut *tx, id, &c.result, t);
        sqlx::query(
            "INSERT INTO zoo_cells (cell, submission_id, result_sha256, provenance_json, loaded_at) \
             VALUES ($1, $2, $3, $4, $5) ON CONFLICT(cell) DO UPDATE SET result_sha256 = $3, provenance_json = $4, \
             loaded_at = $5",
        )
        .bind(&c.cell)
        .bind(id)
        .bind(&c.result_sha256)
        .bind(&c.provenance_json)
        .bind(t)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(if existing.is_some() { ZooLoad::Replaced(id) } else { ZooLoad::Inserted(id) })
        })
    }

    /// A stored zoo cell by its directory name.
    pub async fn zoo_cell(&self, cell: &str) -> Result<Option<ZooCellRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT cell, submission_id, result_sha256, provenance_json, loaded_at FROM zoo_cells WHERE cell = $1",
        )
        .bind(cell)
        .fetch_optional(pool)
        .await)?)
    }

    /// The zoo cell a submission is (None: not one of the zoo's).
    pub async fn zoo_cell_of(&self, submission_id: i64) -> Result<Option<ZooCellRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT cell, submission_id, result_sha256, provenance_json, loaded_at FROM zoo_cells \
             WHERE submission_id = $1",
        )
        .bind(submission_id)
        .fetch_optional(pool)
        .await)?)
    }

    /// Every stored zoo cell, by cell name.
    pub async fn zoo_cells(&self) -> Result<Vec<ZooCellRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT cell, submission_id, result_sha256, provenance_json, loaded_at FROM zoo_cells ORDER BY cell",
        )
        .fetch_all(pool)
        .await)?)
    }
}
