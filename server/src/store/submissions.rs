//! Submissions: the uploaded policy file, the record and its queued job
//! (written in one transaction), and the training-seed uniqueness rule.

use super::types::Json;
use super::types::{JobState, PolicyKind, Stored, StoredSecret, SubmissionStatus};
use super::{now, Store, StoreError};
use crate::leaderboard::protocol_str;
use d3il_protocol::{EndpointSecret, ObsType, ProtocolKind, TaskId};
use std::path::PathBuf;

/// The id of the live submission holding this seed, if any, read through
/// `$db` (a pool or the caller's transaction).
macro_rules! duplicate_seed {
    ($db:expr, $s:expr) => {{
        let s: &SeedKey = $s;
        let id: Option<i64> = sqlx::query_scalar(
            "SELECT id FROM submissions WHERE method_id = $1 AND task = $2 AND obs_type = $3 AND data_fraction = $4 \
             AND protocol = $5 AND training_seed = $6 AND status != 'failed' AND data_source IS NULL",
        )
        .bind(s.method_id)
        .bind(s.task.slug())
        .bind(s.obs_type.as_str())
        .bind(s.data_fraction)
        .bind(protocol_str(s.protocol))
        .bind(s.training_seed)
        .fetch_optional($db)
        .await?;
        id
    }};
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct SubmissionRow {
    pub id: i64,
    pub method_id: i64,
    pub method: String,
    pub submitter: Option<String>,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub policy_kind: PolicyKind,
    pub onnx_sha256: Option<String>,
    pub onnx_bytes: Option<i64>,
    #[serde(skip)]
    pub onnx_path: Option<String>,
    pub endpoint_url: Option<String>,
    /// The remote endpoint's shared secret, sent by the evaluator only: no
    /// page or API answer carries it (not serialised; `Debug` hides it).
    #[serde(skip)]
    pub endpoint_secret: Option<StoredSecret>,
    /// The policy manifest as submitted.
    pub manifest_json: Json<serde_json::Value>,
    pub status: SubmissionStatus,
    pub error_kind: Option<String>,
    pub error_message: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
    /// Whether each initial state's rollouts are simulated once (see
    /// [`NewSubmission::simulated_once`]; the result sets it too).
    #[serde(skip)]
    pub simulated_once: Option<bool>,
    /// The perturbation suite the submission asked for (`robustness`, issue
    /// 40), None for a plain evaluation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub suite: Option<String>,
    /// Where the policy's training data came from, for the zoo's
    /// submissions ("trained here on d3il demos v1"); None for
    /// what submitters send.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub data_source: Option<String>,
}

from_row!(SubmissionRow { id, method_id, method, submitter, task: Stored<TaskId>, obs_type: Stored<ObsType>, training_seed, data_fraction, protocol: Stored<ProtocolKind>, policy_kind, onnx_sha256, onnx_bytes, onnx_path, endpoint_url, endpoint_secret, manifest_json, status, error_kind, error_message, created_at, updated_at, simulated_once, suite, data_source });

/// What a new submission needs; validated by the HTTP layer before it gets here.
#[derive(Debug, Clone)]
pub struct NewSubmission {
    pub method_id: i64,
    pub submitter_id: Option<i64>,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub policy: NewPolicy,
    pub manifest_json: String,
    /// Whether the dry run simulated each initial state once (the manifest's
    /// `simulated_once`); None when there was none.
    pub simulated_once: Option<bool>,
}

/// Which submissions a list shows (every field optional; all must match).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SubmissionFilter {
    pub task: Option<TaskId>,
    /// Exact method name.
    pub method: Option<String>,
    pub status: Option<SubmissionStatus>,
    /// Exact submitter (token) name.
    pub submitter: Option<String>,
}

/// What makes a training seed unique (the `submissions_unique_seed` index).
#[derive(Debug, Clone)]
pub struct SeedKey {
    pub method_id: i64,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub training_seed: i64,
}

impl NewSubmission {
    pub fn seed_key(&self) -> SeedKey {
        SeedKey {
            method_id: self.method_id,
            task: self.task,
            obs_type: self.obs_type,
            data_fraction: self.data_fraction,
            protocol: self.protocol,
            training_seed: self.training_seed,
        }
    }
}

#[derive(Debug, Clone)]
pub enum NewPolicy {
    /// Already in the data dir ([`Store::commit_onnx`]).
    Onnx {
        sha256: String,
        bytes: i64,
        path: PathBuf,
    },
    Remote {
        url: String,
        secret: Option<EndpointSecret>,
    },
}

/// The SELECT of a [`SubmissionRow`], with `$extra` columns after its own.
macro_rules! submission_select {
    ($extra:literal) => {
        concat!(
            "SELECT s.id, s.method_id, m.name AS method, sub.name AS submitter, s.task, s.obs_type, \
             s.training_seed, s.data_fraction, s.protocol, s.policy_kind, s.onnx_sha256, s.onnx_bytes, s.onnx_path, \
             s.endpoint_url, s.endpoint_secret, s.manifest_json, s.status, s.error_kind, s.error_message, s.created_at, s.updated_at, \
             s.simulated_once, s.suite, s.data_source",
            $extra,
            " FROM submissions s JOIN methods m ON m.id = s.method_id LEFT JOIN submitters sub ON sub.id = s.submitter_id"
        )
    };
}
const SUBMISSION_SELECT: &str = submission_select!("");

/// What the public sees, the one rule every list, board, view
/// and table applies to the submissions it shows (alias `s`): a submission
/// not withdrawn. Its own page and document still show it, with the reason.
pub(crate) const PUBLIC: &str = "s.withdrawn_at IS NULL";

/// A withdrawn submission and why (the list on `/admin`).
#[derive(Debug, Clone)]
pub struct WithdrawnSubmission {
    pub submission: SubmissionRow,
    pub withdrawal: super::Withdrawal,
}

from_row!(WithdrawnSubmission {  } flatten { submission, withdrawal });

impl Store {
    /// The submission that already holds this seed, if any (checked before an
    /// endpoint's dry-run so a duplicate is refused at once; the insert checks
    /// again under the write lock).
    pub async fn check_seed_free(&self, s: &SeedKey) -> Result<(), StoreError> {
        match on_db!(&self.db, pool => duplicate_seed!(pool, s)) {
            Some(id) => Err(duplicate_seed_error(s.training_seed, Some(id))),
            None => Ok(()),
        }
    }

    /// Inserts the submission and its queued job in one transaction; when this
    /// returns the submission is durable.
    /// A database kept busy by another writer is retried
    /// ([`super::retry_busy`]) before the error reaches the caller.
    pub async fn create_submission(
        &self,
        s: &NewSubmission,
        max_attempts: i64,
    ) -> Result<i64, StoreError> {
        self.create_submission_sharded(s, max_attempts, 1).await
    }

    /// [`Store::create_submission`] with its job split into `shards` shards
    /// of whole initial states (at least 1), each a job row that any worker
    /// slot or host leases on its own; the last one to finish merges.
    pub async fn create_submission_sharded(
        &self,
        s: &NewSubmission,
        max_attempts: i64,
        shards: usize,
    ) -> Result<i64, StoreError> {
        let shards = shards.max(1) as i64;
        super::retry_busy(|| self.create_submission_once(s, max_attempts, shards, None)).await
    }

    /// [`Store::create_submission_sharded`] of a submission asking for the
    /// perturbation suite `suite`: each shard runs level 0 and
    /// every level on its block of initial states, and the last one to
    /// finish merges the robustness document (`Store::complete_suite_shard`).
    pub async fn create_suite_submission(
        &self,
        s: &NewSubmission,
        max_attempts: i64,
        suite: &str,
        shards: usize,
    ) -> Result<i64, StoreError> {
        let shards = shards.max(1) as i64;
        super::retry_busy(|| self.create_submission_once(s, max_attempts, shards, Some(suite)))
            .await
    }

    async fn create_submission_once(
        &self,
        s: &NewSubmission,
        max_attempts: i64,
        shards: i64,
        suite: Option<&str>,
    ) -> Result<i64, StoreError> {
        // SQLite's IMMEDIATE takes the write lock before the duplicate check,
        // so two concurrent submissions of the same seed cannot both pass it
        // (the second waits on the busy timeout, then sees the first). On
        // PostgreSQL both may pass it; the unique index refuses the second.
        on_db!(&self.db, pool => {
        let mut tx = begin_write!(self, pool);
        if let Some(id) = duplicate_seed!(&mut *tx, &s.seed_key()) {
            return Err(duplicate_seed_error(s.training_seed, Some(id)));
        }
        let (kind, sha, bytes, path, url, secret) = match &s.policy {
            NewPolicy::Onnx {
                sha256,
                bytes,
                path,
            } => (
                PolicyKind::Onnx,
                Some(sha256.clone()),
                Some(*bytes),
                Some(path.to_string_lossy().into_owned()),
                None,
                None,
            ),
            NewPolicy::Remote { url, secret } => (
                PolicyKind::Remote,
                None,
                None,
                None,
                Some(url.clone()),
                secret.as_ref().map(|s| s.expose().to_string()),
            ),
        };
        let t = now();
        let id: i64 = sqlx::query_scalar(
            "INSERT INTO submissions (method_id, submitter_id, task, obs_type, training_seed, data_fraction, protocol, \
             policy_kind, onnx_sha256, onnx_bytes, onnx_path, endpoint_url, manifest_json, status, created_at, updated_at, \
             simulated_once, endpoint_secret) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17, $18) RETURNING id",
        )
        .bind(s.method_id)
        .bind(s.submitter_id)
        .bind(s.task.slug())
        .bind(s.obs_type.as_str())
        .bind(s.training_seed)
        .bind(s.data_fraction)
        .bind(protocol_str(s.protocol))
        .bind(kind)
        .bind(sha)
        .bind(bytes)
        .bind(path)
        .bind(url)
        .bind(&s.manifest_json)
        .bind(SubmissionStatus::Queued)
        .bind(t)
        .bind(t)
        .bind(s.simulated_once)
        .bind(secret)
        .fetch_one(&mut *tx)
        .await
        .map_err(|e| match &e {
            // The unique index is the last word on duplicate seeds.
            sqlx::Error::Database(d) if d.is_unique_violation() => {
                duplicate_seed_error(s.training_seed, None)
            }
            _ => e.into(),
        })?;
        if let Some(suite) = suite {
            sqlx::query("UPDATE submissions SET suite = $1 WHERE id = $2")
                .bind(suite)
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        for index in 0..shards {
            sqlx::query(
                "INSERT INTO jobs (submission_id, state, max_attempts, created_at, shard_index, shard_count) \
                 VALUES ($1, $2, $3, $4, $5, $6)",
            )
            .bind(id)
            .bind(JobState::Queued)
            .bind(max_attempts)
            .bind(t)
            .bind(index)
            .bind(shards)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(id)
        })
    }

    pub async fn submission(&self, id: i64) -> Result<SubmissionRow, StoreError> {
        on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} WHERE s.id = $1"
        )))
        .bind(id)
        .fetch_optional(pool)
        .await)?
        .ok_or_else(|| StoreError::NotFound(format!("submission {id}")))
    }

    /// The method's submissions for its public page, newest first; withdrawn
    /// ones are left out (see [`Store::list_submissions`]).
    pub async fn submissions_of_method(
        &self,
        method_id: i64,
    ) -> Result<Vec<SubmissionRow>, StoreError> {
        Ok(
            on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} WHERE s.method_id = $1 AND {PUBLIC} ORDER BY s.id DESC"
        )))
        .bind(method_id)
        .fetch_all(pool)
        .await)?,
        )
    }

    /// Submissions matching every given filter, newest first, at most `limit`:
    /// the public list (`/submissions`, `GET /api/v1/submissions`). Withdrawn
    /// submissions are left out, as they are of every board: a withdrawal
    /// (spam, an offensive name, a leak of the test contexts) takes them out of
    /// what a visitor browses; each stays reachable by its id, with the reason,
    /// and `/admin` lists them ([`Store::withdrawn_submissions`]).
    pub async fn list_submissions(
        &self,
        f: &SubmissionFilter,
        limit: i64,
    ) -> Result<Vec<SubmissionRow>, StoreError> {
        // A filter not given is a NULL parameter that matches every row.
        let sql = format!(
            "{SUBMISSION_SELECT} WHERE {PUBLIC} AND ($1 IS NULL OR s.task = $1) \
             AND ($2 IS NULL OR m.name = $2) AND ($3 IS NULL OR s.status = $3) AND ($4 IS NULL OR sub.name = $4) \
             ORDER BY s.id DESC LIMIT $5"
        );
        Ok(
            on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(sql.as_str()))
            .bind(f.task.map(|t| t.slug()))
            .bind(f.method.as_deref())
            .bind(f.status.map(|s| s.as_str()))
            .bind(f.submitter.as_deref())
            .bind(limit)
            .fetch_all(pool)
            .await)?,
        )
    }

    /// Withdrawn submissions, the most recently withdrawn first, at most
    /// `limit`: what the public lists leave out, for `/admin`.
    pub async fn withdrawn_submissions(
        &self,
        limit: i64,
    ) -> Result<Vec<WithdrawnSubmission>, StoreError> {
        const SQL: &str = concat!(
            submission_select!(
                ", s.withdrawn_at AS at, COALESCE(s.withdrawn_reason, '') AS reason, \
                 COALESCE(s.withdrawn_by, '') AS \"by\""
            ),
            " WHERE s.withdrawn_at IS NOT NULL ORDER BY s.withdrawn_at DESC, s.id DESC LIMIT $1"
        );
        Ok(on_db!(&self.db, pool => sqlx::query_as(SQL)
            .bind(limit)
            .fetch_all(pool)
            .await)?)
    }

    /// The newest `limit` submissions for the home page; withdrawn ones are
    /// left out (see [`Store::list_submissions`]).
    pub async fn latest_submissions(&self, limit: i64) -> Result<Vec<SubmissionRow>, StoreError> {
        Ok(
            on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} WHERE {PUBLIC} ORDER BY s.id DESC LIMIT $1"
        )))
        .bind(limit)
        .fetch_all(pool)
        .await)?,
        )
    }
}

fn duplicate_seed_error(seed: i64, existing: Option<i64>) -> StoreError {
    let which = existing
        .map(|id| format!(" (submission {id})"))
        .unwrap_or_default();
    StoreError::Conflict(format!(
        "training seed {seed} was already submitted for this method, task, observation type, data fraction \
         and protocol{which}; use a different training_seed"
    ))
}
