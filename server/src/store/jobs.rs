//! The durable job queue: leasing, heartbeats, completion and failed
//! attempts. A slot acts on a job only while it holds the job's lease.

use super::submissions::SubmissionRow;
use super::types::Json;
use super::types::{JobState, SubmissionStatus};
use super::{now, to_json, Store, StoreError};
use crate::leaderboard::protocol_str;
use d3il_protocol::{EvalResult, ProtocolKind, SandboxMechanism, WorkerError};

/// Writes a submission's result and rollouts and marks it completed, inside
/// the caller's transaction (idempotent: an existing result is kept).
macro_rules! insert_result {
    ($tx:expr, $submission_id:expr, $result:expr, $t:expr) => {{
        let (submission_id, result, t): (i64, &EvalResult, i64) = ($submission_id, $result, $t);
        let m = &result.metrics;
        sqlx::query(
            "INSERT INTO results (submission_id, success_rate, success_ci_low, success_ci_high, behaviour_entropy, \
             behaviour_ci_low, behaviour_ci_high, conditional_entropy, conditional_ci_low, conditional_ci_high, \
             stacking_json, stacking_levels_json, inference_ms, manifest_json, per_context_json, created_at, \
             rollouts_ended_unstable, intervals_json, intervals_rules) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17, $18, $19) \
             ON CONFLICT(submission_id) DO NOTHING",
        )
        .bind(submission_id)
        .bind(m.success_rate.value)
        .bind(m.success_rate.ci_low)
        .bind(m.success_rate.ci_high)
        .bind(m.behaviour_entropy.value)
        .bind(m.behaviour_entropy.ci_low)
        .bind(m.behaviour_entropy.ci_high)
        .bind(m.conditional_entropy.value)
        .bind(m.conditional_entropy.ci_low)
        .bind(m.conditional_entropy.ci_high)
        .bind(m.stacking.map(|s| to_json(&s)))
        .bind(m.stacking_levels.map(|s| to_json(&s)))
        .bind(m.inference_ms)
        .bind(to_json(&result.manifest))
        .bind(to_json(&result.per_context))
        .bind(t)
        .bind(result.rollouts_ended_unstable as i64)
        .bind(to_json(&$crate::store::IntervalNotes::of(m)))
        .bind(d3il_metrics::recompute::rules_of(&result.manifest, m))
        .execute($tx)
        .await?;
        for r in &result.rollouts {
            sqlx::query(
                "INSERT INTO rollouts (submission_id, context_index, rollout_index, success, behaviour_json, steps, path_json, \
                 failure_json, ending, trace_json) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) \
                 ON CONFLICT(submission_id, context_index, rollout_index) DO NOTHING",
            )
            .bind(submission_id)
            .bind(r.context_index as i64)
            .bind(r.rollout_index as i64)
            .bind(r.success)
            .bind(r.behaviour.to_string())
            .bind(r.steps as i64)
            .bind(r.path.as_ref().map(to_json))
            .bind(r.failure.as_ref().map(to_json))
            .bind(r.ending.map(|e| e.name()))
            // Copies of a rollout simulated once carry no trace of their
            // own (`EvalResult::trace_of`): NULL, resolved when read.
            .bind(r.trace.as_ref().map(to_json))
            .execute($tx)
            .await?;
        }
        sqlx::query(
            "UPDATE submissions SET status = 'completed', error_kind = NULL, error_message = NULL, updated_at = $1, \
             simulated_once = $2 WHERE id = $3",
        )
        .bind(t)
        .bind(result.manifest.simulated_once)
        .bind(submission_id)
        .execute($tx)
        .await?;
    }};
}

/// Fails the job and its submission for good, inside the caller's transaction.
macro_rules! finish_failed {
    ($tx:expr, $job_id:expr, $submission_id:expr, $kind:expr, $message:expr, $t:expr) => {{
        sqlx::query(
            "UPDATE jobs SET state = 'failed', lease_owner = NULL, lease_expires_at = NULL, finished_at = $1, \
             error_kind = $2, error_message = $3 WHERE id = $4",
        )
        .bind($t)
        .bind($kind)
        .bind($message)
        .bind($job_id)
        .execute($tx)
        .await?;
        // The other shards of a sharded job end with it (a shard still
        // running loses its lease: its report is ignored).
        sqlx::query(
            "UPDATE jobs SET state = 'failed', lease_owner = NULL, lease_expires_at = NULL, finished_at = $1, \
             error_kind = $2, error_message = $3 WHERE submission_id = $4 AND state IN ('queued', 'leased')",
        )
        .bind($t)
        .bind($kind)
        .bind($message)
        .bind($submission_id)
        .execute($tx)
        .await?;
        sqlx::query(
            "UPDATE submissions SET status = 'failed', error_kind = $1, error_message = $2, updated_at = $3 WHERE id = $4",
        )
        .bind($kind)
        .bind($message)
        .bind($t)
        .bind($submission_id)
        .execute($tx)
        .await?;
    }};
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct JobRow {
    pub id: i64,
    pub submission_id: i64,
    pub state: JobState,
    pub attempts: i64,
    pub max_attempts: i64,
    pub lease_owner: Option<String>,
    pub lease_expires_at: Option<i64>,
    pub heartbeat_at: Option<i64>,
    pub rollouts_done: i64,
    pub rollouts_total: i64,
    pub error_kind: Option<String>,
    pub error_message: Option<String>,
    /// The sandbox mechanisms the (finished) job ran under.
    pub sandbox_json: Option<Json<Vec<SandboxMechanism>>>,
    pub created_at: i64,
    /// When the current (latest) attempt started: ETAs extrapolate from it.
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
    /// This row's shard (0-based) of `shard_count`: a paper-protocol job
    /// may be split into shards of whole initial states; a
    /// plain job is shard 0 of 1.
    pub shard_index: i64,
    pub shard_count: i64,
}

from_row!(JobRow {
    id,
    submission_id,
    state,
    attempts,
    max_attempts,
    lease_owner,
    lease_expires_at,
    heartbeat_at,
    rollouts_done,
    rollouts_total,
    error_kind,
    error_message,
    sandbox_json,
    created_at,
    started_at,
    finished_at,
    shard_index,
    shard_count
});

impl JobRow {
    /// The shard this row runs (1-based, as `d3il eval --shard` writes it),
    /// `None` for an unsharded job.
    pub fn shard(&self) -> Option<d3il_protocol::shard::Shard> {
        (self.shard_count > 1).then(|| d3il_protocol::shard::Shard {
            index: self.shard_index.max(0) as usize + 1,
            count: self.shard_count as usize,
        })
    }

    /// The rows of one submission's shards seen as one job: failed if one
    /// failed, done when all are, leased while any runs, else queued; counts
    /// and attempts summed up, the first start and the last finish.
    fn summarise(rows: Vec<JobRow>) -> Option<JobRow> {
        let mut it = rows.into_iter();
        let mut job = it.next()?;
        for r in it {
            use JobState::*;
            job.state = match (job.state, r.state) {
                (Failed, _) | (_, Failed) => Failed,
                (Leased, _) | (_, Leased) => Leased,
                (Queued, _) | (_, Queued) => Queued,
                (Done, Done) => Done,
            };
            job.attempts = job.attempts.max(r.attempts);
            job.lease_owner = job.lease_owner.or(r.lease_owner);
            job.lease_expires_at = job.lease_expires_at.max(r.lease_expires_at);
            job.heartbeat_at = job.heartbeat_at.max(r.heartbeat_at);
            job.rollouts_done += r.rollouts_done;
            job.rollouts_total += r.rollouts_total;
            job.error_kind = job.error_kind.or(r.error_kind);
            job.error_message = job.error_message.or(r.error_message);
            job.sandbox_json = job.sandbox_json.or(r.sandbox_json);
            job.started_at = match (job.started_at, r.started_at) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            job.finished_at = job.finished_at.max(r.finished_at);
        }
        if job.state != JobState::Done {
            job.finished_at = None;
        }
        Some(job)
    }
}

/// A queued submission's kind as [`Store::queued_ahead`] reads it: task,
/// observation type, protocol, simulated once, suite.
type QueuedKind = (String, String, String, Option<bool>, Option<String>);

/// A job handed to a worker slot.
#[derive(Debug, Clone)]
pub struct ClaimedJob {
    pub job: JobRow,
    pub submission: SubmissionRow,
}

/// What an evaluation's duration depends on, for queue estimates (not what
/// a worker's job runs: that is `d3il_protocol::JobKind`): task slug,
/// observation type, protocol, whether each initial state's rollouts are
/// simulated once (a deterministic policy; unknown counts as not), and the
/// perturbation suite asked for (a suite run is level 0 and every
/// level, each a whole evaluation).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct DurationClass {
    pub task: String,
    pub obs_type: String,
    pub protocol: String,
    pub simulated_once: bool,
    pub suite: Option<String>,
}

impl DurationClass {
    pub fn new(
        task: String,
        obs_type: String,
        protocol: String,
        simulated_once: Option<bool>,
    ) -> Self {
        DurationClass {
            task,
            obs_type,
            protocol,
            simulated_once: simulated_once.unwrap_or(false),
            suite: None,
        }
    }

    /// The same kind with perturbation suite `suite` (None: a plain run).
    pub fn with_suite(self, suite: Option<String>) -> Self {
        DurationClass {
            suite: suite.filter(|s| !s.is_empty()),
            ..self
        }
    }

    /// The plain evaluation of the same task, observation type, protocol
    /// and policy kind.
    pub fn plain(&self) -> Self {
        self.clone().with_suite(None)
    }
}

impl Store {
    /// The job of a submission (its shards summarised as one, see
    /// [`JobRow::summarise`]; the id is the first shard's).
    pub async fn job_for(&self, submission_id: i64) -> Result<JobRow, StoreError> {
        let rows: Vec<JobRow> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT * FROM jobs WHERE submission_id = $1 ORDER BY shard_index",
        )
        .bind(submission_id)
        .fetch_all(pool)
        .await)?;
        JobRow::summarise(rows)
            .ok_or_else(|| StoreError::NotFound(format!("job of submission {submission_id}")))
    }

    /// One job row (one shard) by id.
    pub async fn job(&self, job_id: i64) -> Result<JobRow, StoreError> {
        on_db!(&self.db, pool => sqlx::query_as("SELECT * FROM jobs WHERE id = $1")
            .bind(job_id)
            .fetch_optional(pool)
            .await)?
        .ok_or_else(|| StoreError::NotFound(format!("job {job_id}")))
    }

    /// Puts every leased job back in the queue. Called once at start-up: a
    /// single server owns the database file, so any lease left over belongs to
    /// a process that died (a killed server requeues on restart).
    /// The interrupted attempt is given back: an operator's restart is not
    /// the policy's fault and does not count against `--max-attempts`.
    pub async fn requeue_abandoned(&self) -> Result<u64, StoreError> {
        on_db!(&self.db, pool => {
            let mut tx = begin_write!(self, pool);
            let n = sqlx::query(
                "UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_expires_at = NULL, \
                 attempts = CASE WHEN attempts > 0 THEN attempts - 1 ELSE 0 END WHERE state = 'leased'",
            )
            .execute(&mut *tx)
            .await?
            .rows_affected();
            sqlx::query(
                "UPDATE submissions SET status = 'queued', updated_at = $1 WHERE status = 'running' \
                 AND id IN (SELECT submission_id FROM jobs WHERE state = 'queued')",
            )
            .bind(now())
            .execute(&mut *tx)
            .await?;
            tx.commit().await?;
            Ok(n)
        })
    }

    /// Leases the oldest runnable job (queued, or leased with an expired
    /// lease) to `owner` for `lease` seconds. Taking over an expired lease
    /// does not count a new attempt: the lost one had no worker fault (a
    /// fault is recorded by [`Store::fail_attempt`], which is what bounds the
    /// attempts), so the new run replaces it.
    pub async fn claim_job(
        &self,
        owner: &str,
        lease: i64,
    ) -> Result<Option<ClaimedJob>, StoreError> {
        self.claim_job_of(owner, lease, None).await
    }

    /// [`Store::claim_job`] restricted to jobs of one protocol (`None`: any):
    /// the pool's quick slot claims only quick-protocol jobs, so a smoke test
    /// never waits behind paper runs.
    pub async fn claim_job_of(
        &self,
        owner: &str,
        lease: i64,
        only: Option<ProtocolKind>,
    ) -> Result<Option<ClaimedJob>, StoreError> {
        // SQLite: IMMEDIATE, because a deferred transaction that reads and
        // then writes gets SQLITE_BUSY at once (no busy timeout) when another
        // connection wrote in between; taking the write lock first makes it
        // wait like every other writer. PostgreSQL: the row is locked, and
        // rows other hosts hold are skipped, so two pools never take the
        // same job.
        const PICK: &str = "SELECT * FROM jobs WHERE (state = 'queued' OR (state = 'leased' AND lease_expires_at < $1)) \
             AND ($2 IS NULL OR submission_id IN (SELECT id FROM submissions WHERE protocol = $2)) \
             ORDER BY id LIMIT 1";
        let pick = if self.is_postgres() {
            format!("{PICK} FOR UPDATE SKIP LOCKED")
        } else {
            PICK.to_string()
        };
        loop {
            let t = now();
            let claimed = on_db!(&self.db, pool => {
                let mut tx = begin_write!(self, pool);
                let job: Option<JobRow> = sqlx::query_as(sqlx::AssertSqlSafe(pick.as_str()))
                    .bind(t)
                    .bind(only.map(protocol_str))
                    .fetch_optional(&mut *tx)
                    .await?;
                let Some(job) = job else { return Ok(None) };
                let updated = sqlx::query(
                    "UPDATE jobs SET attempts = CASE WHEN state = 'queued' THEN attempts + 1 ELSE attempts END, \
                     state = 'leased', lease_owner = $1, lease_expires_at = $2, heartbeat_at = $3, \
                     started_at = $3, rollouts_done = 0, rollouts_total = 0, outcomes_json = NULL \
                     WHERE id = $4 AND (state = 'queued' OR (state = 'leased' AND lease_expires_at < $3))",
                )
                .bind(owner)
                .bind(t + lease)
                .bind(t)
                .bind(job.id)
                .execute(&mut *tx)
                .await?
                .rows_affected();
                if updated == 0 {
                    // Someone else took it between the select and the update.
                    tx.rollback().await?;
                    None
                } else {
                    sqlx::query("UPDATE submissions SET status = 'running', updated_at = $1 WHERE id = $2")
                        .bind(t)
                        .bind(job.submission_id)
                        .execute(&mut *tx)
                        .await?;
                    tx.commit().await?;
                    Some(job.id)
                }
            });
            let Some(job_id) = claimed else {
                continue;
            };
            // The claimed row (one shard), not the submission's summary.
            let job = self.job(job_id).await?;
            let submission = self.submission(job.submission_id).await?;
            return Ok(Some(ClaimedJob { job, submission }));
        }
    }

    /// Extends the lease and records progress. Returns false if the lease was
    /// lost (the job was requeued or finished by someone else).
    pub async fn heartbeat(
        &self,
        job_id: i64,
        owner: &str,
        lease: i64,
        progress: Option<(usize, usize)>,
    ) -> Result<bool, StoreError> {
        let t = now();
        // Without progress, the counts stay as they are (NULL parameters).
        let (done, total) = match progress {
            Some((d, n)) => (Some(d as i64), Some(n as i64)),
            None => (None, None),
        };
        let n = on_db!(&self.db, pool => sqlx::query(
            "UPDATE jobs SET heartbeat_at = $1, lease_expires_at = $2, rollouts_done = COALESCE($3, rollouts_done), \
             rollouts_total = COALESCE($4, rollouts_total) WHERE id = $5 AND lease_owner = $6 AND state = 'leased'",
        )
        .bind(t)
        .bind(t + lease)
        .bind(done)
        .bind(total)
        .bind(job_id)
        .bind(owner)
        .execute(pool)
        .await
        .map(|r| r.rows_affected()))?;
        Ok(n == 1)
    }

    /// Stores the result (idempotently: a second write for the same
    /// submission changes nothing) and marks the job done.
    pub async fn complete_job(
        &self,
        job_id: i64,
        submission_id: i64,
        result: &EvalResult,
        mechanisms: &[SandboxMechanism],
    ) -> Result<(), StoreError> {
        let t = now();
        let total = result.rollouts.len() as i64;
        on_db!(&self.db, pool => {
            // Reads, then writes: the write lock is taken up front.
            let mut tx = begin_write!(self, pool);
            // A cancelled evaluation stays cancelled (and unranked) even if
            // its worker finished before it noticed.
            let cancelled: Option<i64> =
                sqlx::query_scalar("SELECT cancelled_at FROM submissions WHERE id = $1")
                    .bind(submission_id)
                    .fetch_optional(&mut *tx)
                    .await?
                    .flatten();
            if cancelled.is_some() {
                tx.commit().await?;
                return Ok(());
            }
            insert_result!(&mut *tx, submission_id, result, t);
            sqlx::query(
                "UPDATE jobs SET state = 'done', lease_owner = NULL, lease_expires_at = NULL, finished_at = $1, \
                 rollouts_done = CASE WHEN rollouts_done > $2 THEN rollouts_done ELSE $2 END, \
                 rollouts_total = CASE WHEN rollouts_total > $2 THEN rollouts_total ELSE $2 END, sandbox_json = $3, \
                 error_kind = NULL, error_message = NULL WHERE id = $4",
            )
            .bind(t)
            .bind(total)
            .bind(to_json(&mechanisms))
            .bind(job_id)
            .execute(&mut *tx)
            .await?;
            tx.commit().await?;
            Ok(())
        })
    }

    /// Records a failed attempt of the job leased to `owner`: requeues it when
    /// `retry` and attempts remain, otherwise fails the submission with the
    /// typed error. Returns whether it was requeued. A slot that no longer
    /// holds the lease (it expired and the job was requeued, or another slot
    /// now runs it) changes nothing and gets [`StoreError::LeaseLost`].
    pub async fn fail_attempt(
        &self,
        job_id: i64,
        owner: &str,
        err: &WorkerError,
        retry: bool,
    ) -> Result<bool, StoreError> {
        let t = now();
        let kind = serde_json::to_value(err.kind)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_else(|| "internal".into());
        // The lease check and the update see the same state: SQLite's
        // IMMEDIATE takes the write lock, PostgreSQL locks the row.
        const LEASED: &str = "SELECT * FROM jobs WHERE id = $1 AND state = $2 AND lease_owner = $3";
        let leased = if self.is_postgres() {
            format!("{LEASED} FOR UPDATE")
        } else {
            LEASED.to_string()
        };
        let (requeued, submission_id) = on_db!(&self.db, pool => {
        let mut tx = begin_write!(self, pool);
        let job: Option<JobRow> =
            sqlx::query_as(sqlx::AssertSqlSafe(leased.as_str()))
                .bind(job_id)
                .bind(JobState::Leased)
                .bind(owner)
                .fetch_optional(&mut *tx)
                .await?;
        let Some(job) = job else {
            return Err(StoreError::LeaseLost {
                job_id,
                owner: owner.to_string(),
            });
        };
        let requeued = retry && job.attempts < job.max_attempts;
        if requeued {
            sqlx::query(
                "UPDATE jobs SET state = $1, lease_owner = NULL, lease_expires_at = NULL, error_kind = $2, \
                 error_message = $3 WHERE id = $4",
            )
            .bind(JobState::Queued)
            .bind(&kind)
            .bind(&err.message)
            .bind(job_id)
            .execute(&mut *tx)
            .await?;
            sqlx::query("UPDATE submissions SET status = $1, updated_at = $2 WHERE id = $3")
                .bind(SubmissionStatus::Queued)
                .bind(t)
                .bind(job.submission_id)
                .execute(&mut *tx)
                .await?;
        } else {
            finish_failed!(&mut *tx, job_id, job.submission_id, &kind, &err.message, t);
        }
        tx.commit().await?;
        (requeued, job.submission_id)
        });
        if !requeued {
            // A failed submission keeps its file's hash, not the file.
            if let Err(e) = self.release_policy_of(submission_id).await {
                tracing::warn!("submission {submission_id}: policy file not deleted: {e}");
            }
        }
        Ok(requeued)
    }

    /// Mean wall time, in seconds, of the last 20 completed submissions of
    /// each [`DurationClass`], from the first shard's start to the last shard's
    /// finish: the basis of ETAs (a Stacking paper run and an Aligning smoke
    /// test take very different times, an image evaluation renders two
    /// cameras at every step, and a deterministic policy's evaluation
    /// simulates one rollout per initial state).
    pub async fn mean_job_seconds_by_kind(&self) -> Result<Vec<(DurationClass, f64)>, StoreError> {
        let rows: Vec<(String, String, String, bool, String, f64)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT task, obs_type, protocol, once, suite, AVG(d) FROM (SELECT s.task AS task, \
             s.obs_type AS obs_type, s.protocol AS protocol, COALESCE(s.simulated_once, FALSE) AS once, \
             COALESCE(s.suite, '') AS suite, \
             CAST(MAX(j.finished_at) - MIN(j.started_at) AS DOUBLE PRECISION) AS d, \
             ROW_NUMBER() OVER (PARTITION BY s.task, s.obs_type, s.protocol, COALESCE(s.simulated_once, FALSE), \
             COALESCE(s.suite, '') ORDER BY MAX(j.finished_at) DESC) AS n \
             FROM jobs j JOIN submissions s ON s.id = j.submission_id \
             WHERE s.status = 'completed' AND j.started_at IS NOT NULL AND j.finished_at IS NOT NULL \
             GROUP BY s.id, s.task, s.obs_type, s.protocol, s.simulated_once, s.suite) AS recent \
             WHERE n <= 20 GROUP BY task, obs_type, protocol, once, suite",
        )
        .fetch_all(pool)
        .await)?;
        Ok(rows
            .into_iter()
            .map(|(task, obs_type, protocol, once, suite, d)| {
                (
                    DurationClass::new(task, obs_type, protocol, Some(once))
                        .with_suite(Some(suite)),
                    d,
                )
            })
            .collect())
    }

    /// The kinds of the submissions with queued work ahead of job `job_id`
    /// (one entry per submission, however many shards), oldest first.
    pub async fn queued_ahead(&self, job_id: i64) -> Result<Vec<DurationClass>, StoreError> {
        let rows: Vec<QueuedKind> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT s.task, s.obs_type, s.protocol, s.simulated_once, s.suite FROM submissions s WHERE s.id IN \
             (SELECT submission_id FROM jobs WHERE state = 'queued' AND id < $1) ORDER BY s.id",
        )
        .bind(job_id)
        .fetch_all(pool)
        .await)?;
        Ok(rows
            .into_iter()
            .map(|(task, obs_type, protocol, once, suite)| {
                DurationClass::new(task, obs_type, protocol, once).with_suite(suite)
            })
            .collect())
    }

    /// The sandbox report of the most recently finished job that has one:
    /// (submission id, finished at, mechanisms JSON).
    pub async fn latest_sandbox_report(
        &self,
    ) -> Result<Option<(i64, i64, Json<Vec<SandboxMechanism>>)>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT submission_id, COALESCE(finished_at, 0), sandbox_json FROM jobs \
             WHERE sandbox_json IS NOT NULL ORDER BY finished_at DESC, id DESC LIMIT 1",
        )
        .fetch_optional(pool)
        .await)?)
    }

    /// Submissions waiting (every job row queued) and running (a row leased,
    /// or some shards done while others wait): what the home page shows. A
    /// sharded evaluation counts once, however many rows it has.
    pub async fn submission_counts(&self) -> Result<(i64, i64), StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT CAST(COALESCE(SUM(CASE WHEN n_queued = n THEN 1 ELSE 0 END), 0) AS BIGINT), \
             CAST(COALESCE(SUM(CASE WHEN n_leased > 0 OR (n_queued > 0 AND n_queued < n) \
             THEN 1 ELSE 0 END), 0) AS BIGINT) \
             FROM (SELECT COUNT(*) AS n, \
             SUM(CASE WHEN state = 'queued' THEN 1 ELSE 0 END) AS n_queued, \
             SUM(CASE WHEN state = 'leased' THEN 1 ELSE 0 END) AS n_leased \
             FROM jobs GROUP BY submission_id) AS per_submission",
        )
        .fetch_one(pool)
        .await)?)
    }

    /// Job rows waiting and running, each shard counting once: the admin
    /// page, next to the worker slots that run them.
    pub async fn queue_counts(&self) -> Result<(i64, i64), StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT CAST(COALESCE(SUM(CASE WHEN state = 'queued' THEN 1 ELSE 0 END), 0) AS BIGINT), \
             CAST(COALESCE(SUM(CASE WHEN state = 'leased' THEN 1 ELSE 0 END), 0) AS BIGINT) FROM jobs",
        )
        .fetch_one(pool)
        .await)?)
    }
}
