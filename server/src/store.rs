//! The SQLite store: schema (migrations/), the paper's reported results, methods,
//! tokens, submissions, the durable job queue and evaluation results.
//!
//! Everything is plain runtime SQL (`query`/`query_as` + `FromRow`), so building
//! needs no database.

use crate::stats::{mean_std, Agg};
use d3il_protocol::paper::PaperResults;
use d3il_protocol::{
    EvalResult, ObsType, ProtocolKind, ResultCell, SandboxMechanism, Source, StackingLevel, Stat,
    TaskId, WorkerError,
};
use sha2::{Digest, Sha256};
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::{FromRow, SqlitePool};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;

/// Migrations embedded at compile time (server/build.rs reruns on change).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    #[error("database migration failed: {0}; the database file may come from a newer version, use a fresh --db file")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("cannot use {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("stored data is corrupt: {0}")]
    Corrupt(String),
    #[error("{0} not found")]
    NotFound(String),
    /// A uniqueness rule was violated (e.g. the same training seed twice).
    #[error("{0}")]
    Conflict(String),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub fn now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0)
}

/// Maps a task title as the paper prints it (`Stacking-2 (T5)`) to our task.
pub fn task_for_title(title: &str) -> Option<TaskId> {
    if let Some(t) = TaskId::ALL.into_iter().find(|t| t.title() == title) {
        return Some(t);
    }
    if title.starts_with("Stacking-") {
        return Some(TaskId::Stacking);
    }
    None
}

#[derive(Debug, Clone)]
pub struct Store {
    pool: SqlitePool,
    data_dir: PathBuf,
}

#[derive(Debug, Clone, FromRow, serde::Serialize)]
pub struct MethodRow {
    pub id: i64,
    pub name: String,
    pub history: Option<i64>,
    pub backbone: Option<String>,
    pub prediction: Option<String>,
    pub diversity: Option<String>,
    pub code_url: Option<String>,
    pub paper_url: Option<String>,
    pub description: Option<String>,
    pub from_paper: bool,
    pub state_inference_ms: Option<f64>,
    pub image_inference_ms: Option<f64>,
    pub submitter_id: Option<i64>,
}

/// Metadata for a new method created by a submission.
#[derive(Debug, Clone, Default)]
pub struct NewMethod {
    pub name: String,
    pub history: Option<i64>,
    pub backbone: Option<String>,
    pub prediction: Option<String>,
    pub diversity: Option<String>,
    pub code_url: Option<String>,
    pub paper_url: Option<String>,
    pub description: Option<String>,
}

#[derive(Debug, Clone, FromRow)]
pub struct Submitter {
    pub id: i64,
    pub name: String,
    /// The token that authenticated this request.
    pub token_id: i64,
}

#[derive(Debug, Clone, FromRow, serde::Serialize)]
pub struct SubmissionRow {
    pub id: i64,
    pub method_id: i64,
    pub method: String,
    pub submitter: Option<String>,
    pub task: String,
    pub obs_type: String,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: String,
    pub policy_kind: String,
    pub onnx_sha256: Option<String>,
    pub onnx_bytes: Option<i64>,
    #[serde(skip)]
    pub onnx_path: Option<String>,
    pub endpoint_url: Option<String>,
    pub manifest_json: String,
    pub status: String,
    pub error_kind: Option<String>,
    pub error_message: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
}

#[derive(Debug, Clone, FromRow, serde::Serialize)]
pub struct JobRow {
    pub id: i64,
    pub submission_id: i64,
    pub state: String,
    pub attempts: i64,
    pub max_attempts: i64,
    pub lease_owner: Option<String>,
    pub lease_expires_at: Option<i64>,
    pub heartbeat_at: Option<i64>,
    pub rollouts_done: i64,
    pub rollouts_total: i64,
    pub error_kind: Option<String>,
    pub error_message: Option<String>,
    pub sandbox_json: Option<String>,
    pub created_at: i64,
    /// When the current (latest) attempt started: ETAs extrapolate from it.
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
}

#[derive(Debug, Clone, FromRow, serde::Serialize)]
pub struct ResultRow {
    pub submission_id: i64,
    pub success_rate: f64,
    pub success_ci_low: f64,
    pub success_ci_high: f64,
    pub behaviour_entropy: f64,
    pub behaviour_ci_low: f64,
    pub behaviour_ci_high: f64,
    pub conditional_entropy: f64,
    pub conditional_ci_low: f64,
    pub conditional_ci_high: f64,
    pub stacking_json: Option<String>,
    /// Stacking-1/2/3 metrics (JSON `[StackingLevel; 3]`), see migration 0002.
    pub stacking_levels_json: Option<String>,
    pub inference_ms: f64,
    pub manifest_json: String,
    pub per_context_json: String,
    pub created_at: i64,
}

#[derive(Debug, Clone, FromRow, serde::Serialize)]
pub struct RolloutRow {
    pub context_index: i64,
    pub rollout_index: i64,
    pub success: bool,
    pub behaviour_json: String,
    pub steps: i64,
    #[serde(skip)]
    pub path_json: Option<String>,
}

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
    /// Already written to the data dir by [`Store::store_onnx`].
    Onnx {
        sha256: String,
        bytes: i64,
        path: PathBuf,
    },
    Remote {
        url: String,
    },
}

/// A job handed to a worker slot.
#[derive(Debug, Clone)]
pub struct ClaimedJob {
    pub job: JobRow,
    pub submission: SubmissionRow,
}

/// One leaderboard row: a method on a task (paper title), observation type and
/// data fraction, aggregated over training seeds.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BoardRow {
    pub method: String,
    pub method_id: i64,
    pub paper_table: String,
    pub task_title: String,
    pub task: Option<TaskId>,
    pub obs: ObsType,
    pub data_fraction: f64,
    pub control: Option<String>,
    pub source: Source,
    /// Evaluation protocol of evaluated rows (None for reported rows).
    pub protocol: Option<ProtocolKind>,
    pub success: Stat,
    /// Conditional behaviour entropy (the paper's "Entropy").
    pub entropy: Stat,
    /// Marginal behaviour entropy H(pi(beta)) (evaluated rows only).
    pub behaviour_entropy: Option<Stat>,
    pub n_seeds: usize,
    pub inference_ms: Option<f64>,
    pub bold_success: Option<bool>,
    pub bold_entropy: Option<bool>,
    pub submission_ids: Vec<i64>,
}

impl BoardRow {
    pub fn to_cell(&self) -> ResultCell {
        ResultCell {
            table: self.paper_table.clone(),
            method: self.method.clone(),
            task: self.task_title.clone(),
            obs: self.obs,
            data_fraction: self.data_fraction,
            control: self.control.clone(),
            source: self.source,
            success_rate: self.success,
            entropy: self.entropy,
            n_seeds: self.n_seeds,
            bold_success: self.bold_success,
            bold_entropy: self.bold_entropy,
        }
    }
}

#[derive(FromRow)]
struct ReportedDbRow {
    paper_table: String,
    method: String,
    method_id: i64,
    task_title: String,
    obs_type: String,
    data_fraction: f64,
    control: String,
    success_mean: f64,
    success_std: f64,
    success_bold: bool,
    entropy_mean: f64,
    entropy_std: f64,
    entropy_bold: bool,
    n_seeds: i64,
    state_inference_ms: Option<f64>,
    image_inference_ms: Option<f64>,
}

#[derive(FromRow)]
struct EvaluatedDbRow {
    submission_id: i64,
    method: String,
    method_id: i64,
    task: String,
    obs_type: String,
    training_seed: i64,
    data_fraction: f64,
    protocol: String,
    success_rate: f64,
    behaviour_entropy: f64,
    conditional_entropy: f64,
    stacking_json: Option<String>,
    stacking_levels_json: Option<String>,
    inference_ms: f64,
}

const SUBMISSION_SELECT: &str = "SELECT s.id, s.method_id, m.name AS method, sub.name AS submitter, s.task, s.obs_type, \
     s.training_seed, s.data_fraction, s.protocol, s.policy_kind, s.onnx_sha256, s.onnx_bytes, s.onnx_path, \
     s.endpoint_url, s.manifest_json, s.status, s.error_kind, s.error_message, s.created_at, s.updated_at \
     FROM submissions s JOIN methods m ON m.id = s.method_id LEFT JOIN submitters sub ON sub.id = s.submitter_id";

impl Store {
    /// Opens (creating if needed) the SQLite file at `path`, applies the
    /// migrations and loads the paper's reported results (idempotently).
    /// Uploaded policies live next to it in `<file stem>-data/`.
    pub async fn open(path: &Path) -> Result<Store, StoreError> {
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(io_err(parent))?;
        }
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "d3il".into());
        // Absolute, because the sandboxed worker is given this path to read.
        let data_dir = std::path::absolute(path.with_file_name(format!("{stem}-data")))
            .map_err(io_err(path))?;
        std::fs::create_dir_all(data_dir.join("policies")).map_err(io_err(&data_dir))?;

        // FULL synchronous: an accepted submission must survive a power cut
        // once the response is sent (issue 7, "durable before the response").
        let opts = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .foreign_keys(true)
            .busy_timeout(Duration::from_secs(10));
        let pool = SqlitePoolOptions::new()
            .max_connections(4)
            .connect_with(opts)
            .await?;
        MIGRATOR.run(&pool).await?;
        let store = Store { pool, data_dir };
        store
            .load_paper(&d3il_protocol::paper::load_embedded())
            .await?;
        Ok(store)
    }

    pub fn pool(&self) -> &SqlitePool {
        &self.pool
    }

    pub fn data_dir(&self) -> &Path {
        &self.data_dir
    }

    /// Inserts the paper's methods and reported rows; rows already present are
    /// left untouched, so this runs on every start.
    pub async fn load_paper(&self, paper: &PaperResults) -> Result<(), StoreError> {
        let mut tx = self.pool.begin().await?;
        for (name, m) in &paper.methods {
            sqlx::query(
                "INSERT INTO methods (name, history, backbone, prediction, diversity, paper_url, description, \
                 from_paper, state_inference_ms, image_inference_ms) VALUES (?, ?, ?, ?, ?, ?, ?, 1, ?, ?) \
                 ON CONFLICT(name) DO NOTHING",
            )
            .bind(name)
            .bind(m.history as i64)
            .bind(&m.backbone)
            .bind(&m.prediction)
            .bind(&m.diversity)
            .bind(&paper.source)
            .bind("Baseline of the D3IL paper; numbers are as reported there.")
            .bind(m.inference_ms.state_ms)
            .bind(m.inference_ms.image_ms)
            .execute(&mut *tx)
            .await?;
        }
        for r in &paper.results {
            let method_id: i64 = sqlx::query_scalar("SELECT id FROM methods WHERE name = ?")
                .bind(&r.method)
                .fetch_optional(&mut *tx)
                .await?
                .ok_or_else(|| {
                    StoreError::Corrupt(format!(
                        "paper row for unknown method `{}` (not in the methods table)",
                        r.method
                    ))
                })?;
            sqlx::query(
                "INSERT INTO reported_results (paper_table, method_id, task_title, obs_type, data_fraction, control, \
                 success_mean, success_std, success_bold, entropy_mean, entropy_std, entropy_bold, n_seeds, subtasks_json) \
                 VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) \
                 ON CONFLICT(paper_table, method_id, task_title, obs_type, data_fraction, control) DO NOTHING",
            )
            .bind(&r.table)
            .bind(method_id)
            .bind(&r.task)
            .bind(&r.obs)
            .bind(r.data_fraction)
            .bind(r.control.clone().unwrap_or_default())
            .bind(r.success_rate.mean)
            .bind(r.success_rate.std)
            .bind(r.success_rate.bold)
            .bind(r.entropy.mean)
            .bind(r.entropy.std)
            .bind(r.entropy.bold)
            .bind(r.seeds as i64)
            .bind(r.subtasks.as_ref().map(|v| v.to_string()))
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    // ---------------------------------------------------------------- results

    /// Reported rows (as the paper printed them) and evaluated rows aggregated
    /// over training seeds (mean, sample std, n_seeds), for `d3il tables`.
    /// Only paper-protocol evaluations are included: quick-protocol runs are
    /// smoke tests and do not belong in the paper's tables.
    pub async fn result_cells(&self) -> Result<Vec<ResultCell>, StoreError> {
        Ok(self
            .board_rows()
            .await?
            .iter()
            .filter(|r| r.source == Source::Reported || r.protocol == Some(ProtocolKind::Paper))
            .map(BoardRow::to_cell)
            .collect())
    }

    /// All leaderboard rows: reported first (paper order of insertion), then
    /// evaluated ones.
    pub async fn board_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        let mut rows = self.reported_rows().await?;
        rows.extend(self.evaluated_rows().await?);
        Ok(rows)
    }

    async fn reported_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        let db: Vec<ReportedDbRow> = sqlx::query_as(
            "SELECT r.paper_table, m.name AS method, m.id AS method_id, r.task_title, r.obs_type, r.data_fraction, \
             r.control, r.success_mean, r.success_std, r.success_bold, r.entropy_mean, r.entropy_std, r.entropy_bold, \
             r.n_seeds, m.state_inference_ms, m.image_inference_ms \
             FROM reported_results r JOIN methods m ON m.id = r.method_id ORDER BY r.id",
        )
        .fetch_all(&self.pool)
        .await?;
        db.into_iter()
            .map(|r| {
                let obs = parse_obs(&r.obs_type)?;
                Ok(BoardRow {
                    method: r.method,
                    method_id: r.method_id,
                    paper_table: r.paper_table,
                    task: task_for_title(&r.task_title),
                    task_title: r.task_title,
                    obs,
                    data_fraction: r.data_fraction,
                    control: (!r.control.is_empty()).then_some(r.control),
                    source: Source::Reported,
                    protocol: None,
                    success: Stat {
                        mean: r.success_mean,
                        std: r.success_std,
                    },
                    entropy: Stat {
                        mean: r.entropy_mean,
                        std: r.entropy_std,
                    },
                    behaviour_entropy: None,
                    n_seeds: r.n_seeds.max(0) as usize,
                    inference_ms: match obs {
                        ObsType::State => r.state_inference_ms,
                        ObsType::Image => r.image_inference_ms,
                    },
                    bold_success: Some(r.success_bold),
                    bold_entropy: Some(r.entropy_bold),
                    submission_ids: vec![],
                })
            })
            .collect()
    }

    async fn evaluated_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        let db: Vec<EvaluatedDbRow> = sqlx::query_as(
            "SELECT s.id AS submission_id, m.name AS method, m.id AS method_id, s.task, s.obs_type, s.training_seed, \
             s.data_fraction, s.protocol, r.success_rate, r.behaviour_entropy, r.conditional_entropy, r.stacking_json, \
             r.stacking_levels_json, r.inference_ms FROM submissions s JOIN results r ON r.submission_id = s.id \
             JOIN methods m ON m.id = s.method_id WHERE s.status = 'completed' ORDER BY s.id",
        )
        .fetch_all(&self.pool)
        .await?;
        // Group key: method, task title, obs, fraction (as bits), protocol.
        type Key = (i64, String, String, u64, String);
        struct Group {
            method: String,
            task: TaskId,
            obs: ObsType,
            fraction: f64,
            protocol: ProtocolKind,
            success: Agg,
            entropy: Agg,
            behaviour: Agg,
            inference: Agg,
            seeds: Vec<i64>,
            submissions: Vec<i64>,
        }
        let mut groups: BTreeMap<Key, Group> = BTreeMap::new();
        let mut order: Vec<Key> = vec![];
        for r in db {
            let task = TaskId::from_str(&r.task)
                .map_err(|e| StoreError::Corrupt(format!("submission {}: {e}", r.submission_id)))?;
            let obs = parse_obs(&r.obs_type)?;
            let protocol = ProtocolKind::from_str(&r.protocol).map_err(StoreError::Corrupt)?;
            // Stacking is reported as the paper's Stacking-1/2/3 rows (spec/11
            // §2.7), each with its own success rate and entropies.
            let corrupt = |what: &str, e: serde_json::Error| {
                StoreError::Corrupt(format!("submission {} {what}: {e}", r.submission_id))
            };
            let levels: Option<[StackingLevel; 3]> = match &r.stacking_levels_json {
                Some(s) => {
                    Some(serde_json::from_str(s).map_err(|e| corrupt("stacking levels", e))?)
                }
                None => None,
            };
            let rates: Option<[f64; 3]> = match &r.stacking_json {
                Some(s) => Some(serde_json::from_str(s).map_err(|e| corrupt("stacking", e))?),
                None => None,
            };
            // (title, success, conditional entropy, behaviour entropy)
            let variants: Vec<(String, f64, f64, f64)> = match (task, levels, rates) {
                (TaskId::Stacking, Some(l), _) => (0..3)
                    .map(|k| {
                        (
                            format!("Stacking-{} (T5)", k + 1),
                            l[k].success_rate.value,
                            l[k].conditional_entropy.value,
                            l[k].behaviour_entropy.value,
                        )
                    })
                    .collect(),
                // Stored before the levels had their own entropies: the three
                // rates with the one (Stacking-3) entropy the result carries.
                (TaskId::Stacking, None, Some(s)) => (0..3)
                    .map(|k| {
                        (
                            format!("Stacking-{} (T5)", k + 1),
                            s[k],
                            r.conditional_entropy,
                            r.behaviour_entropy,
                        )
                    })
                    .collect(),
                _ => vec![(
                    task.title().to_string(),
                    r.success_rate,
                    r.conditional_entropy,
                    r.behaviour_entropy,
                )],
            };
            for (title, success, conditional, behaviour) in variants {
                let key: Key = (
                    r.method_id,
                    title.clone(),
                    r.obs_type.clone(),
                    r.data_fraction.to_bits(),
                    r.protocol.clone(),
                );
                let g = groups.entry(key.clone()).or_insert_with(|| {
                    order.push(key.clone());
                    Group {
                        method: r.method.clone(),
                        task,
                        obs,
                        fraction: r.data_fraction,
                        protocol,
                        success: Agg::default(),
                        entropy: Agg::default(),
                        behaviour: Agg::default(),
                        inference: Agg::default(),
                        seeds: vec![],
                        submissions: vec![],
                    }
                });
                g.success.push(success);
                g.entropy.push(conditional);
                g.behaviour.push(behaviour);
                g.inference.push(r.inference_ms);
                g.seeds.push(r.training_seed);
                g.submissions.push(r.submission_id);
            }
        }
        Ok(order
            .into_iter()
            .filter_map(|k| groups.remove(&k).map(|g| (k, g)))
            .map(|((method_id, title, ..), g)| {
                let mut seeds = g.seeds.clone();
                seeds.sort_unstable();
                seeds.dedup();
                BoardRow {
                    method: g.method,
                    method_id,
                    paper_table: if g.fraction == 1.0 {
                        "main"
                    } else {
                        "datasize"
                    }
                    .into(),
                    task_title: title,
                    task: Some(g.task),
                    obs: g.obs,
                    data_fraction: g.fraction,
                    control: None,
                    source: Source::Evaluated,
                    protocol: Some(g.protocol),
                    success: g.success.stat(),
                    entropy: g.entropy.stat(),
                    behaviour_entropy: Some(g.behaviour.stat()),
                    n_seeds: seeds.len(),
                    inference_ms: Some(mean_std(&g.inference.values).0),
                    bold_success: None,
                    bold_entropy: None,
                    submission_ids: g.submissions,
                }
            })
            .collect())
    }

    /// End-effector paths of an Avoiding submission's rollouts, with their
    /// behaviour labels (for the paper's trajectory figure).
    pub async fn avoiding_paths(
        &self,
        submission_id: i64,
    ) -> Result<Vec<(serde_json::Value, Vec<[f32; 2]>)>, StoreError> {
        let rows: Vec<(String, Option<String>)> = sqlx::query_as(
            "SELECT behaviour_json, path_json FROM rollouts WHERE submission_id = ? AND path_json IS NOT NULL \
             ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .fetch_all(&self.pool)
        .await?;
        rows.into_iter()
            .filter_map(|(b, p)| p.map(|p| (b, p)))
            .map(|(b, p)| {
                let behaviour = serde_json::from_str(&b)
                    .map_err(|e| StoreError::Corrupt(format!("rollout behaviour: {e}")))?;
                let path = serde_json::from_str(&p)
                    .map_err(|e| StoreError::Corrupt(format!("rollout path: {e}")))?;
                Ok((behaviour, path))
            })
            .collect()
    }

    // ---------------------------------------------------------------- methods

    pub async fn methods(&self) -> Result<Vec<MethodRow>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT id, name, history, backbone, prediction, diversity, code_url, paper_url, description, \
             from_paper, state_inference_ms, image_inference_ms, submitter_id FROM methods ORDER BY from_paper DESC, id",
        )
        .fetch_all(&self.pool)
        .await?)
    }

    pub async fn method_by_name(&self, name: &str) -> Result<Option<MethodRow>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT id, name, history, backbone, prediction, diversity, code_url, paper_url, description, \
             from_paper, state_inference_ms, image_inference_ms, submitter_id FROM methods WHERE name = ?",
        )
        .bind(name)
        .fetch_optional(&self.pool)
        .await?)
    }

    /// Returns the method with this name, creating it (owned by `submitter_id`)
    /// if it does not exist. Existing methods keep their metadata.
    pub async fn ensure_method(
        &self,
        m: &NewMethod,
        submitter_id: Option<i64>,
    ) -> Result<MethodRow, StoreError> {
        sqlx::query(
            "INSERT INTO methods (name, history, backbone, prediction, diversity, code_url, paper_url, description, submitter_id) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT(name) DO NOTHING",
        )
        .bind(&m.name)
        .bind(m.history)
        .bind(&m.backbone)
        .bind(&m.prediction)
        .bind(&m.diversity)
        .bind(&m.code_url)
        .bind(&m.paper_url)
        .bind(&m.description)
        .bind(submitter_id)
        .execute(&self.pool)
        .await?;
        self.method_by_name(&m.name)
            .await?
            .ok_or_else(|| StoreError::NotFound(format!("method `{}`", m.name)))
    }

    // ----------------------------------------------------------------- tokens

    /// Mints a new API token for `name` (creating the submitter). Returns the
    /// plaintext token, which is shown once: only its SHA-256 is stored.
    pub async fn create_token(&self, name: &str) -> Result<String, StoreError> {
        let mut raw = [0u8; 24];
        getrandom::fill(&mut raw)
            .map_err(|e| StoreError::Corrupt(format!("no randomness available: {e}")))?;
        let token = format!("d3il_{}", hex::encode(raw));
        let mut tx = self.pool.begin().await?;
        sqlx::query("INSERT INTO submitters (name) VALUES (?) ON CONFLICT(name) DO NOTHING")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let submitter_id: i64 = sqlx::query_scalar("SELECT id FROM submitters WHERE name = ?")
            .bind(name)
            .fetch_one(&mut *tx)
            .await?;
        sqlx::query("INSERT INTO api_tokens (submitter_id, token_sha256, prefix) VALUES (?, ?, ?)")
            .bind(submitter_id)
            .bind(token_hash(&token))
            .bind(&token[..13])
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(token)
    }

    /// The submitter owning this (unrevoked) token, if any.
    pub async fn authenticate(&self, token: &str) -> Result<Option<Submitter>, StoreError> {
        let row: Option<Submitter> = sqlx::query_as(
            "SELECT s.id, s.name, t.id AS token_id FROM api_tokens t JOIN submitters s ON s.id = t.submitter_id \
             WHERE t.token_sha256 = ? AND t.revoked_at IS NULL",
        )
        .bind(token_hash(token))
        .fetch_optional(&self.pool)
        .await?;
        if let Some(s) = &row {
            sqlx::query("UPDATE api_tokens SET last_used_at = ? WHERE id = ?")
                .bind(now())
                .bind(s.token_id)
                .execute(&self.pool)
                .await?;
        }
        Ok(row)
    }

    // ------------------------------------------------------------ submissions

    /// Writes an uploaded ONNX file into the data dir under its SHA-256
    /// (written to a temporary name, synced, then renamed, so a crash never
    /// leaves a half file under a valid name).
    pub async fn store_onnx(&self, bytes: &[u8]) -> Result<(String, PathBuf), StoreError> {
        let sha = hex::encode(Sha256::digest(bytes));
        let dir = self.data_dir.join("policies");
        let path = dir.join(format!("{sha}.onnx"));
        if tokio::fs::try_exists(&path).await.unwrap_or(false) {
            return Ok((sha, path));
        }
        // One temporary name per write: concurrent uploads of the same file
        // in this process must not rename each other's temporary away.
        static WRITES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let tmp = dir.join(format!("{sha}.onnx.tmp{}-{n}", std::process::id()));
        let data = bytes.to_vec();
        let (tmp2, path2) = (tmp.clone(), path.clone());
        tokio::task::spawn_blocking(move || -> std::io::Result<()> {
            use std::io::Write;
            let mut f = std::fs::File::create(&tmp2)?;
            f.write_all(&data)?;
            f.sync_all()?;
            std::fs::rename(&tmp2, &path2)
        })
        .await
        .map_err(|e| StoreError::Corrupt(format!("file writer panicked: {e}")))?
        .map_err(io_err(&tmp))?;
        Ok((sha, path))
    }

    /// The submission that already holds this seed, if any (checked before an
    /// endpoint's dry-run so a duplicate is refused at once; the insert checks
    /// again under the write lock).
    pub async fn check_seed_free(&self, s: &SeedKey) -> Result<(), StoreError> {
        match duplicate_seed(&self.pool, s).await? {
            Some(id) => Err(duplicate_seed_error(s.training_seed, Some(id))),
            None => Ok(()),
        }
    }

    /// Inserts the submission and its queued job in one transaction; when this
    /// returns the submission is durable.
    pub async fn create_submission(
        &self,
        s: &NewSubmission,
        max_attempts: i64,
    ) -> Result<i64, StoreError> {
        // IMMEDIATE takes the write lock before the duplicate check, so two
        // concurrent submissions of the same seed cannot both pass it (the
        // second waits on the busy timeout, then sees the first).
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        if let Some(id) = duplicate_seed(&mut *tx, &s.seed_key()).await? {
            return Err(duplicate_seed_error(s.training_seed, Some(id)));
        }
        let (kind, sha, bytes, path, url) = match &s.policy {
            NewPolicy::Onnx {
                sha256,
                bytes,
                path,
            } => (
                "onnx",
                Some(sha256.clone()),
                Some(*bytes),
                Some(path.to_string_lossy().into_owned()),
                None,
            ),
            NewPolicy::Remote { url } => ("remote", None, None, None, Some(url.clone())),
        };
        let t = now();
        let id: i64 = sqlx::query_scalar(
            "INSERT INTO submissions (method_id, submitter_id, task, obs_type, training_seed, data_fraction, protocol, \
             policy_kind, onnx_sha256, onnx_bytes, onnx_path, endpoint_url, manifest_json, status, created_at, updated_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'queued', ?, ?) RETURNING id",
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
        .bind(t)
        .bind(t)
        .fetch_one(&mut *tx)
        .await
        .map_err(|e| match &e {
            // The unique index is the last word on duplicate seeds.
            sqlx::Error::Database(d) if d.is_unique_violation() => {
                duplicate_seed_error(s.training_seed, None)
            }
            _ => e.into(),
        })?;
        sqlx::query(
            "INSERT INTO jobs (submission_id, state, max_attempts, created_at) VALUES (?, 'queued', ?, ?)",
        )
        .bind(id)
        .bind(max_attempts)
        .bind(t)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(id)
    }

    pub async fn submission(&self, id: i64) -> Result<SubmissionRow, StoreError> {
        sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} WHERE s.id = ?"
        )))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?
        .ok_or_else(|| StoreError::NotFound(format!("submission {id}")))
    }

    pub async fn submissions_of_method(
        &self,
        method_id: i64,
    ) -> Result<Vec<SubmissionRow>, StoreError> {
        Ok(sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} WHERE s.method_id = ? ORDER BY s.id DESC"
        )))
        .bind(method_id)
        .fetch_all(&self.pool)
        .await?)
    }

    pub async fn latest_submissions(&self, limit: i64) -> Result<Vec<SubmissionRow>, StoreError> {
        Ok(sqlx::query_as(sqlx::AssertSqlSafe(format!(
            "{SUBMISSION_SELECT} ORDER BY s.id DESC LIMIT ?"
        )))
        .bind(limit)
        .fetch_all(&self.pool)
        .await?)
    }

    pub async fn job_for(&self, submission_id: i64) -> Result<JobRow, StoreError> {
        sqlx::query_as("SELECT * FROM jobs WHERE submission_id = ?")
            .bind(submission_id)
            .fetch_optional(&self.pool)
            .await?
            .ok_or_else(|| StoreError::NotFound(format!("job of submission {submission_id}")))
    }

    pub async fn result_for(&self, submission_id: i64) -> Result<Option<ResultRow>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT submission_id, success_rate, success_ci_low, success_ci_high, behaviour_entropy, behaviour_ci_low, \
             behaviour_ci_high, conditional_entropy, conditional_ci_low, conditional_ci_high, stacking_json, \
             stacking_levels_json, inference_ms, manifest_json, per_context_json, created_at FROM results WHERE submission_id = ?",
        )
        .bind(submission_id)
        .fetch_optional(&self.pool)
        .await?)
    }

    pub async fn rollouts_for(&self, submission_id: i64) -> Result<Vec<RolloutRow>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT context_index, rollout_index, success, behaviour_json, steps, path_json FROM rollouts \
             WHERE submission_id = ? ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .fetch_all(&self.pool)
        .await?)
    }

    // ------------------------------------------------------------------ queue

    /// Puts every leased job back in the queue. Called once at start-up: a
    /// single server owns the database file, so any lease left over belongs to
    /// a process that died (issue 7: a killed server requeues on restart).
    pub async fn requeue_abandoned(&self) -> Result<u64, StoreError> {
        let mut tx = self.pool.begin().await?;
        let n = sqlx::query(
            "UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_expires_at = NULL WHERE state = 'leased'",
        )
        .execute(&mut *tx)
        .await?
        .rows_affected();
        sqlx::query(
            "UPDATE submissions SET status = 'queued', updated_at = ? WHERE status = 'running' \
             AND id IN (SELECT submission_id FROM jobs WHERE state = 'queued')",
        )
        .bind(now())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(n)
    }

    /// Leases the oldest runnable job (queued, or leased with an expired
    /// lease) to `owner` for `lease` seconds. Jobs whose attempts are used up
    /// are failed instead of leased.
    pub async fn claim_job(
        &self,
        owner: &str,
        lease: i64,
    ) -> Result<Option<ClaimedJob>, StoreError> {
        loop {
            let t = now();
            let mut tx = self.pool.begin().await?;
            let job: Option<JobRow> = sqlx::query_as(
                "SELECT * FROM jobs WHERE state = 'queued' OR (state = 'leased' AND lease_expires_at < ?) \
                 ORDER BY id LIMIT 1",
            )
            .bind(t)
            .fetch_optional(&mut *tx)
            .await?;
            let Some(job) = job else { return Ok(None) };
            if job.attempts >= job.max_attempts {
                let msg = format!(
                    "the evaluation was interrupted {} times (lease expired without a result); giving up",
                    job.attempts
                );
                finish_failed(&mut tx, job.id, job.submission_id, "crashed", &msg, t).await?;
                tx.commit().await?;
                continue;
            }
            let updated = sqlx::query(
                "UPDATE jobs SET state = 'leased', lease_owner = ?, lease_expires_at = ?, heartbeat_at = ?, \
                 attempts = attempts + 1, started_at = ?, rollouts_done = 0 \
                 WHERE id = ? AND (state = 'queued' OR (state = 'leased' AND lease_expires_at < ?))",
            )
            .bind(owner)
            .bind(t + lease)
            .bind(t)
            .bind(t)
            .bind(job.id)
            .bind(t)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if updated == 0 {
                // Someone else took it between the select and the update.
                tx.rollback().await?;
                continue;
            }
            sqlx::query("UPDATE submissions SET status = 'running', updated_at = ? WHERE id = ?")
                .bind(t)
                .bind(job.submission_id)
                .execute(&mut *tx)
                .await?;
            tx.commit().await?;
            let job = self.job_for(job.submission_id).await?;
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
        let n = match progress {
            Some((done, total)) => sqlx::query(
                "UPDATE jobs SET heartbeat_at = ?, lease_expires_at = ?, rollouts_done = ?, rollouts_total = ? \
                 WHERE id = ? AND lease_owner = ? AND state = 'leased'",
            )
            .bind(t)
            .bind(t + lease)
            .bind(done as i64)
            .bind(total as i64)
            .bind(job_id)
            .bind(owner),
            None => sqlx::query(
                "UPDATE jobs SET heartbeat_at = ?, lease_expires_at = ? WHERE id = ? AND lease_owner = ? AND state = 'leased'",
            )
            .bind(t)
            .bind(t + lease)
            .bind(job_id)
            .bind(owner),
        }
        .execute(&self.pool)
        .await?
        .rows_affected();
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
        let m = &result.metrics;
        let mut tx = self.pool.begin().await?;
        sqlx::query(
            "INSERT INTO results (submission_id, success_rate, success_ci_low, success_ci_high, behaviour_entropy, \
             behaviour_ci_low, behaviour_ci_high, conditional_entropy, conditional_ci_low, conditional_ci_high, \
             stacking_json, stacking_levels_json, inference_ms, manifest_json, per_context_json, created_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT(submission_id) DO NOTHING",
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
        .execute(&mut *tx)
        .await?;
        for r in &result.rollouts {
            sqlx::query(
                "INSERT INTO rollouts (submission_id, context_index, rollout_index, success, behaviour_json, steps, path_json) \
                 VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(submission_id, context_index, rollout_index) DO NOTHING",
            )
            .bind(submission_id)
            .bind(r.context_index as i64)
            .bind(r.rollout_index as i64)
            .bind(r.success)
            .bind(r.behaviour.to_string())
            .bind(r.steps as i64)
            .bind(r.path.as_ref().map(to_json))
            .execute(&mut *tx)
            .await?;
        }
        let total = result.rollouts.len() as i64;
        sqlx::query(
            "UPDATE jobs SET state = 'done', lease_owner = NULL, lease_expires_at = NULL, finished_at = ?, \
             rollouts_done = MAX(rollouts_done, ?), rollouts_total = MAX(rollouts_total, ?), sandbox_json = ?, \
             error_kind = NULL, error_message = NULL WHERE id = ?",
        )
        .bind(t)
        .bind(total)
        .bind(total)
        .bind(to_json(&mechanisms))
        .bind(job_id)
        .execute(&mut *tx)
        .await?;
        sqlx::query(
            "UPDATE submissions SET status = 'completed', error_kind = NULL, error_message = NULL, updated_at = ? WHERE id = ?",
        )
        .bind(t)
        .bind(submission_id)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// Records a failed attempt: requeues it when `retry` and attempts remain,
    /// otherwise fails the submission with the typed error.
    pub async fn fail_attempt(
        &self,
        job_id: i64,
        err: &WorkerError,
        retry: bool,
    ) -> Result<bool, StoreError> {
        let t = now();
        let kind = serde_json::to_value(err.kind)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_else(|| "internal".into());
        let mut tx = self.pool.begin().await?;
        let job: JobRow = sqlx::query_as("SELECT * FROM jobs WHERE id = ?")
            .bind(job_id)
            .fetch_one(&mut *tx)
            .await?;
        let requeued = retry && job.attempts < job.max_attempts;
        if requeued {
            sqlx::query(
                "UPDATE jobs SET state = 'queued', lease_owner = NULL, lease_expires_at = NULL, error_kind = ?, \
                 error_message = ? WHERE id = ?",
            )
            .bind(&kind)
            .bind(&err.message)
            .bind(job_id)
            .execute(&mut *tx)
            .await?;
            sqlx::query("UPDATE submissions SET status = 'queued', updated_at = ? WHERE id = ?")
                .bind(t)
                .bind(job.submission_id)
                .execute(&mut *tx)
                .await?;
        } else {
            finish_failed(&mut tx, job_id, job.submission_id, &kind, &err.message, t).await?;
        }
        tx.commit().await?;
        Ok(requeued)
    }

    /// Jobs ahead of this one in the queue (0 = next), or None if it is not queued.
    pub async fn queue_position(&self, job_id: i64) -> Result<Option<i64>, StoreError> {
        let state: String = sqlx::query_scalar("SELECT state FROM jobs WHERE id = ?")
            .bind(job_id)
            .fetch_one(&self.pool)
            .await?;
        if state != "queued" {
            return Ok(None);
        }
        Ok(Some(
            sqlx::query_scalar("SELECT COUNT(*) FROM jobs WHERE state = 'queued' AND id < ?")
                .bind(job_id)
                .fetch_one(&self.pool)
                .await?,
        ))
    }

    /// Mean wall time of the last 20 finished jobs, seconds.
    pub async fn mean_job_seconds(&self) -> Result<Option<f64>, StoreError> {
        Ok(sqlx::query_scalar(
            "SELECT AVG(finished_at - started_at) FROM (SELECT finished_at, started_at FROM jobs \
             WHERE state = 'done' AND started_at IS NOT NULL ORDER BY finished_at DESC LIMIT 20)",
        )
        .fetch_one(&self.pool)
        .await?)
    }

    /// The sandbox report of the most recently finished job that has one:
    /// (submission id, finished at, mechanisms JSON).
    pub async fn latest_sandbox_report(&self) -> Result<Option<(i64, i64, String)>, StoreError> {
        Ok(sqlx::query_as(
            "SELECT submission_id, COALESCE(finished_at, 0), sandbox_json FROM jobs \
             WHERE sandbox_json IS NOT NULL ORDER BY finished_at DESC, id DESC LIMIT 1",
        )
        .fetch_optional(&self.pool)
        .await?)
    }

    pub async fn queue_counts(&self) -> Result<(i64, i64), StoreError> {
        Ok(sqlx::query_as(
            "SELECT COALESCE(SUM(state = 'queued'), 0), COALESCE(SUM(state = 'leased'), 0) FROM jobs",
        )
        .fetch_one(&self.pool)
        .await?)
    }
}

async fn finish_failed(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    job_id: i64,
    submission_id: i64,
    kind: &str,
    message: &str,
    t: i64,
) -> Result<(), StoreError> {
    sqlx::query(
        "UPDATE jobs SET state = 'failed', lease_owner = NULL, lease_expires_at = NULL, finished_at = ?, \
         error_kind = ?, error_message = ? WHERE id = ?",
    )
    .bind(t)
    .bind(kind)
    .bind(message)
    .bind(job_id)
    .execute(&mut **tx)
    .await?;
    sqlx::query(
        "UPDATE submissions SET status = 'failed', error_kind = ?, error_message = ?, updated_at = ? WHERE id = ?",
    )
    .bind(kind)
    .bind(message)
    .bind(t)
    .bind(submission_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

pub fn token_hash(token: &str) -> String {
    hex::encode(Sha256::digest(token.as_bytes()))
}

pub fn protocol_str(p: ProtocolKind) -> &'static str {
    match p {
        ProtocolKind::Paper => "paper",
        ProtocolKind::Quick => "quick",
    }
}

fn parse_obs(s: &str) -> Result<ObsType, StoreError> {
    ObsType::from_str(s).map_err(StoreError::Corrupt)
}

/// JSON encoding of plain data (these types always serialise).
fn to_json<T: serde::Serialize + ?Sized>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "null".into())
}

async fn duplicate_seed<'e>(
    db: impl sqlx::SqliteExecutor<'e>,
    s: &SeedKey,
) -> Result<Option<i64>, StoreError> {
    Ok(sqlx::query_scalar(
        "SELECT id FROM submissions WHERE method_id = ? AND task = ? AND obs_type = ? AND data_fraction = ? \
         AND protocol = ? AND training_seed = ? AND status != 'failed'",
    )
    .bind(s.method_id)
    .bind(s.task.slug())
    .bind(s.obs_type.as_str())
    .bind(s.data_fraction)
    .bind(protocol_str(s.protocol))
    .bind(s.training_seed)
    .fetch_optional(db)
    .await?)
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
