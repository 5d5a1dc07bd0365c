//! Robustness results (migration 0008): the robustness document of
//! a submission that asked for the suite, stored whole for the API and as a
//! summary without rollout records for the boards and tables.

use super::types::Json;
use super::types::Stored;
use super::{Store, StoreError};
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use d3il_tables::robustness::RobustnessEntry;

/// Writes a submission's robustness document and its summary (idempotent:
/// a document already stored for the submission is kept), on a pool or
/// inside the caller's transaction (the merge of a sharded suite job,
/// `super::shards`).
macro_rules! insert_robustness {
    ($exec:expr, $submission_id:expr, $doc:expr) => {{
        let (submission_id, doc): (i64, &d3il_protocol::robustness::RobustnessResult) =
            ($submission_id, $doc);
        let document = serde_json::to_string(doc).map_err(|e| {
            StoreError::Corrupt(format!("robustness document not encoded: {e}"))
        })?;
        let summary = serde_json::to_string(&$crate::store::summary_of(doc)).map_err(|e| {
            StoreError::Corrupt(format!("robustness summary not encoded: {e}"))
        })?;
        sqlx::query(
            "INSERT INTO robustness_results (submission_id, suite, suite_sha256, overall, overall_ci_low, \
             overall_ci_high, summary_json, document_json, created_at, intervals_rules) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) ON CONFLICT (submission_id) DO NOTHING",
        )
        .bind(submission_id)
        .bind(&doc.suite)
        .bind(&doc.suite_sha256)
        .bind(doc.overall.map(|e| e.value))
        .bind(doc.overall.map(|e| e.ci_low))
        .bind(doc.overall.map(|e| e.ci_high))
        .bind(summary)
        .bind(document)
        .bind($crate::store::now())
        .bind(d3il_metrics::recompute::rules_of(
            &doc.control.manifest,
            &doc.control.metrics,
        ))
        .execute($exec)
        .await?;
    }};
}

/// One evaluated submission's robustness, as the board and tables read it.
#[derive(Debug, Clone)]
pub struct RobustnessRow {
    pub submission_id: i64,
    pub method: String,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub protocol: ProtocolKind,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub suite: String,
    pub suite_sha256: String,
    /// The document without rollout records (per-initial-state outcomes,
    /// metrics, paired drops and scores are all there).
    pub summary_json: Json<RobustnessResult>,
}

from_row!(RobustnessRow { submission_id, method, task: Stored<TaskId>, obs_type: Stored<ObsType>, protocol: Stored<ProtocolKind>, training_seed, data_fraction, suite, suite_sha256, summary_json });

impl RobustnessRow {
    /// The row as the robustness tables and figures take it.
    pub fn into_entry(self) -> RobustnessEntry {
        RobustnessEntry {
            submission_id: self.submission_id,
            method: self.method,
            training_seed: self.training_seed,
            protocol: self.protocol,
            doc: self.summary_json.0,
        }
    }
}

/// The document without its rollout records (what boards and tables need).
pub fn summary_of(doc: &RobustnessResult) -> RobustnessResult {
    let mut s = doc.clone();
    s.control.rollouts.clear();
    for l in &mut s.levels {
        l.result.rollouts.clear();
    }
    s
}

impl Store {
    /// Stores a submission's robustness document (idempotent: a document
    /// already stored for the submission is kept).
    pub async fn save_robustness(
        &self,
        submission_id: i64,
        doc: &RobustnessResult,
    ) -> Result<(), StoreError> {
        on_db!(&self.db, pool => {
            insert_robustness!(pool, submission_id, doc);
        });
        Ok(())
    }

    /// The whole robustness document of a submission, as stored (JSON text),
    /// or None when it has none (yet).
    pub async fn robustness_document(
        &self,
        submission_id: i64,
    ) -> Result<Option<String>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT document_json FROM robustness_results WHERE submission_id = $1",
        )
        .bind(submission_id)
        .fetch_optional(pool)
        .await)?)
    }

    /// The summary (document without rollout records) of a submission.
    pub async fn robustness_summary(
        &self,
        submission_id: i64,
    ) -> Result<Option<RobustnessResult>, StoreError> {
        let j: Option<Json<RobustnessResult>> = on_db!(&self.db, pool => sqlx::query_scalar(
            "SELECT summary_json FROM robustness_results WHERE submission_id = $1",
        )
        .bind(submission_id)
        .fetch_optional(pool)
        .await)?;
        Ok(j.map(|j| j.0))
    }

    /// Every completed public submission's robustness for `task` (all tasks
    /// when None), oldest first. The zoo's methods are named `METHOD (zoo)`:
    /// never grouped with a submitted method of the same name.
    pub async fn robustness_rows(
        &self,
        task: Option<TaskId>,
    ) -> Result<Vec<RobustnessRow>, StoreError> {
        // Public rows only: a withdrawn submission leaves this view and the
        // tables drawn from it.
        let sql = format!(
            "SELECT r.submission_id, CASE WHEN s.data_source IS NULL THEN m.name ELSE m.name || ' (zoo)' END AS method, s.task, s.obs_type, s.protocol, s.training_seed, \
             s.data_fraction, r.suite, r.suite_sha256, r.summary_json FROM robustness_results r \
             JOIN submissions s ON s.id = r.submission_id JOIN methods m ON m.id = s.method_id \
             WHERE s.status = 'completed' AND {} AND ($1 IS NULL OR s.task = $1) ORDER BY r.submission_id",
            super::submissions::PUBLIC
        );
        Ok(
            on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(sql.as_str()))
        .bind(task.map(|t| t.slug()))
        .fetch_all(pool)
        .await)?,
        )
    }
}
