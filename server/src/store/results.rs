//! Evaluation results: the leaderboard rows (reported and evaluated, seeds
//! grouped by [`crate::leaderboard`]), one submission's result and rollouts,
//! and the training seeds of a leaderboard row.

use super::submissions::SubmissionRow;
use super::types::Json;
use super::types::{Stored, SubmissionStatus};
use super::{Store, StoreError};
use crate::leaderboard::{evaluated_rows, protocol_str, BoardRow, EvaluatedSeed};
use d3il_protocol::{
    ContextResult, Ending, Estimate, EvalResult, IntervalMethod, Metrics, NoInterval, ObsType,
    ProtocolKind, ProtocolManifest, ResultCell, RobotLook, RolloutFailure, RolloutRecord,
    RolloutTrace, Source, StackingLevel, TaskId,
};

#[derive(Debug, Clone, serde::Serialize)]
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
    /// Stacking-1/2/3 success rates (results stored before the levels).
    pub stacking_json: Option<Json<[f64; 3]>>,
    /// Stacking-1/2/3 metrics (JSON `[StackingLevel; 3]`), see migration 0002.
    pub stacking_levels_json: Option<Json<[StackingLevel; 3]>>,
    pub inference_ms: f64,
    /// The protocol manifest of the evaluation.
    pub manifest_json: Json<serde_json::Value>,
    pub per_context_json: Json<Vec<ContextResult>>,
    pub created_at: i64,
    /// Rollouts ended as failures because the simulation became unstable.
    pub rollouts_ended_unstable: i64,
    /// How each estimate's interval was made (migration 0014); NULL for
    /// results stored before 0.5.0 until the start-up recomputation.
    pub intervals_json: Option<Json<IntervalNotes>>,
    /// The interval rules the row was computed under
    /// (`d3il_metrics::recompute::RULES_VERSION`); NULL before 0.5.0.
    pub intervals_rules: Option<i64>,
}

from_row!(ResultRow {
    submission_id,
    success_rate,
    success_ci_low,
    success_ci_high,
    behaviour_entropy,
    behaviour_ci_low,
    behaviour_ci_high,
    conditional_entropy,
    conditional_ci_low,
    conditional_ci_high,
    stacking_json,
    stacking_levels_json,
    inference_ms,
    manifest_json,
    per_context_json,
    created_at,
    rollouts_ended_unstable,
    intervals_json,
    intervals_rules
});

/// What an [`Estimate`] says about its interval besides its ends.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IntervalNote {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<IntervalMethod>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_interval: Option<NoInterval>,
}

/// The three estimates' [`IntervalNote`]s (`results.intervals_json`).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IntervalNotes {
    pub success_rate: IntervalNote,
    pub behaviour_entropy: IntervalNote,
    pub conditional_entropy: IntervalNote,
}

impl IntervalNotes {
    pub fn of(m: &Metrics) -> IntervalNotes {
        let note = |e: &Estimate| IntervalNote {
            method: e.method,
            no_interval: e.no_interval,
        };
        IntervalNotes {
            success_rate: note(&m.success_rate),
            behaviour_entropy: note(&m.behaviour_entropy),
            conditional_entropy: note(&m.conditional_entropy),
        }
    }
}

impl ResultRow {
    /// The protocol manifest, if it parses (every result the worker stored does).
    pub fn manifest(&self) -> Option<ProtocolManifest> {
        serde_json::from_value(self.manifest_json.0.clone()).ok()
    }

    /// The metrics as the worker (or the merge of its shards) made them.
    pub fn metrics(&self) -> Metrics {
        let notes = self
            .intervals_json
            .as_ref()
            .map(|j| j.0)
            .unwrap_or_default();
        let est = |value, ci_low, ci_high, note: IntervalNote| Estimate {
            value,
            ci_low,
            ci_high,
            method: note.method,
            no_interval: note.no_interval,
        };
        Metrics {
            success_rate: est(
                self.success_rate,
                self.success_ci_low,
                self.success_ci_high,
                notes.success_rate,
            ),
            behaviour_entropy: est(
                self.behaviour_entropy,
                self.behaviour_ci_low,
                self.behaviour_ci_high,
                notes.behaviour_entropy,
            ),
            conditional_entropy: est(
                self.conditional_entropy,
                self.conditional_ci_low,
                self.conditional_ci_high,
                notes.conditional_entropy,
            ),
            stacking: self.stacking_json.as_ref().map(|j| j.0),
            stacking_levels: self.stacking_levels_json.as_ref().map(|j| j.0),
            inference_ms: self.inference_ms,
        }
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct RolloutRow {
    pub context_index: i64,
    pub rollout_index: i64,
    pub success: bool,
    /// The behaviour code (column `behaviour_json`).
    pub behaviour: Json<serde_json::Value>,
    pub steps: i64,
    #[serde(skip)]
    pub path_json: Option<Json<Vec<[f32; 2]>>>,
    /// Why the rollout was ended as a failure (`sim_unstable`), if it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failure: Option<Json<RolloutFailure>>,
    /// How it ended; None for results stored before endings were recorded.
    #[serde(skip)]
    pub ending: Option<Stored<Ending>>,
    /// The row holds a trace of its own (`trace_json`; a copy of a rollout
    /// simulated once has none: see `crate::rollouts::trace_holder`).
    pub has_trace: bool,
}

from_row!(RolloutRow {
    context_index,
    rollout_index,
    success,
    behaviour,
    steps,
    path_json,
    failure,
    ending,
    has_trace
});

impl RolloutRow {
    pub fn ending(&self) -> Option<Ending> {
        self.ending.map(|e| e.0)
    }
}

/// An end-effector path in the table plane.
type XyPath = Vec<[f32; 2]>;

/// A rollout row with everything it stores, trace included.
struct StoredRollout {
    context_index: i64,
    rollout_index: i64,
    success: bool,
    behaviour_json: Json<serde_json::Value>,
    steps: i64,
    path_json: Option<Json<XyPath>>,
    failure_json: Option<Json<RolloutFailure>>,
    ending: Option<Stored<Ending>>,
    trace_json: Option<Json<RolloutTrace>>,
}

from_row!(StoredRollout {
    context_index,
    rollout_index,
    success,
    behaviour_json,
    steps,
    path_json,
    failure_json,
    ending,
    trace_json
});

impl From<StoredRollout> for RolloutRecord {
    fn from(r: StoredRollout) -> RolloutRecord {
        RolloutRecord {
            context_index: r.context_index.max(0) as usize,
            rollout_index: r.rollout_index.max(0) as usize,
            success: r.success,
            behaviour: r.behaviour_json.0,
            steps: r.steps.max(0) as usize,
            path: r.path_json.map(|p| p.0),
            failure: r.failure_json.map(|f| f.0),
            ending: r.ending.map(|e| e.0),
            trace: r.trace_json.map(|t| Box::new(t.0)),
        }
    }
}

/// One training seed of a leaderboard row (the submission page's seed list).
#[derive(Debug, Clone)]
pub struct SeedSummary {
    pub id: i64,
    pub training_seed: i64,
    pub status: SubmissionStatus,
    /// None until the seed is evaluated.
    pub success_rate: Option<f64>,
}

from_row!(SeedSummary {
    id,
    training_seed,
    status,
    success_rate
});

/// A completed submission's result as the leaderboard query reads it.
struct SeedDbRow {
    submission_id: i64,
    method: String,
    method_id: i64,
    task: TaskId,
    obs_type: ObsType,
    training_seed: i64,
    data_fraction: f64,
    protocol: ProtocolKind,
    success_rate: f64,
    behaviour_entropy: f64,
    conditional_entropy: f64,
    stacking_json: Option<Json<[f64; 3]>>,
    stacking_levels_json: Option<Json<[StackingLevel; 3]>>,
    inference_ms: f64,
    /// The manifest's `initial_states` (NULL or empty before sets were named).
    initial_states: Option<String>,
    /// The manifest's `robot_look` (NULL for state results and before it was
    /// recorded).
    robot_look: Option<Stored<RobotLook>>,
    /// The manifest's `build.physics_fingerprint` (NULL before builds were identified).
    physics_fingerprint: Option<String>,
    /// The zoo's data source (NULL: a submitted policy).
    data_source: Option<String>,
}

from_row!(SeedDbRow { submission_id, method, method_id, task: Stored<TaskId>, obs_type: Stored<ObsType>, training_seed, data_fraction, protocol: Stored<ProtocolKind>, success_rate, behaviour_entropy, conditional_entropy, stacking_json, stacking_levels_json, inference_ms, initial_states, robot_look, physics_fingerprint, data_source });

impl SeedDbRow {
    fn into_seed(self) -> EvaluatedSeed {
        EvaluatedSeed {
            submission_id: self.submission_id,
            method: self.method,
            method_id: self.method_id,
            task: self.task,
            obs: self.obs_type,
            training_seed: self.training_seed,
            data_fraction: self.data_fraction,
            protocol: self.protocol,
            success_rate: self.success_rate,
            behaviour_entropy: self.behaviour_entropy,
            conditional_entropy: self.conditional_entropy,
            stacking: self.stacking_json.map(|j| j.0),
            stacking_levels: self.stacking_levels_json.map(|j| j.0),
            inference_ms: self.inference_ms,
            initial_states: d3il_protocol::initial_states_name(
                self.task,
                self.initial_states.as_deref().unwrap_or(""),
            ),
            robot_look: self.robot_look.map(|l| l.0),
            physics_fingerprint: self.physics_fingerprint,
            data_source: self.data_source,
        }
    }
}

impl Store {
    /// Reported rows (as the paper printed them) and evaluated rows aggregated
    /// over training seeds (mean, sample std, n_seeds), for `d3il tables`.
    /// Only paper-protocol evaluations are included: quick-protocol runs are
    /// smoke tests and do not belong in the paper's tables, nor does the zoo
    /// (its own table: `d3il tables --table zoo`). `current`: the
    /// physics fingerprint of the build showing them (rows of others say so).
    pub async fn result_cells(&self, current: Option<&str>) -> Result<Vec<ResultCell>, StoreError> {
        Ok(self
            .board_rows()
            .await?
            .iter()
            .filter(|r| r.data_source.is_none())
            .filter(|r| r.source == Source::Reported || r.protocol == Some(ProtocolKind::Paper))
            .map(|r| r.to_cell(current))
            .collect())
    }

    /// All leaderboard rows: reported first (paper order of insertion), then
    /// evaluated ones.
    /// Withdrawn submissions are left out; rows of methods marked as
    /// baselines say so.
    pub async fn board_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        let mut rows = self.reported_rows().await?;
        rows.extend(self.evaluated_rows().await?);
        let baselines = self.baseline_methods().await?;
        for r in &mut rows {
            r.baseline = baselines.contains(&r.method_id);
        }
        Ok(rows)
    }

    async fn evaluated_rows(&self) -> Result<Vec<BoardRow>, StoreError> {
        // Fields of the manifest, read by each backend's JSON function.
        let manifest = |field: &str| {
            if self.is_postgres() {
                format!("CAST(r.manifest_json AS JSONB) ->> '{field}'")
            } else {
                format!("json_extract(r.manifest_json, '$.{field}')")
            }
        };
        let (initial_states, robot_look) = (manifest("initial_states"), manifest("robot_look"));
        let fingerprint = if self.is_postgres() {
            "CAST(r.manifest_json AS JSONB) -> 'build' ->> 'physics_fingerprint'".to_string()
        } else {
            "json_extract(r.manifest_json, '$.build.physics_fingerprint')".to_string()
        };
        let sql = format!(
            "SELECT s.id AS submission_id, m.name AS method, m.id AS method_id, s.task, s.obs_type, s.training_seed, \
             s.data_fraction, s.protocol, r.success_rate, r.behaviour_entropy, r.conditional_entropy, r.stacking_json, \
             r.stacking_levels_json, r.inference_ms, {initial_states} AS initial_states, {robot_look} AS robot_look, \
             {fingerprint} AS physics_fingerprint, s.data_source \
             FROM submissions s JOIN results r ON r.submission_id = s.id \
             JOIN methods m ON m.id = s.method_id WHERE s.status = $1 AND {PUBLIC} ORDER BY s.id",
            PUBLIC = super::submissions::PUBLIC
        );
        let db: Vec<SeedDbRow> = on_db!(&self.db, pool => sqlx::query_as(sqlx::AssertSqlSafe(sql.as_str()))
        .bind(SubmissionStatus::Completed)
        .fetch_all(pool)
        .await)?;
        let seeds: Vec<EvaluatedSeed> = db.into_iter().map(SeedDbRow::into_seed).collect();
        Ok(evaluated_rows(&seeds)?)
    }

    /// End-effector paths of an Avoiding submission's rollouts, with their
    /// behaviour labels (for the paper's trajectory figure).
    pub async fn avoiding_paths(
        &self,
        submission_id: i64,
    ) -> Result<Vec<(serde_json::Value, Vec<[f32; 2]>)>, StoreError> {
        let rows: Vec<(Json<serde_json::Value>, Json<XyPath>)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT behaviour_json, path_json FROM rollouts WHERE submission_id = $1 AND path_json IS NOT NULL \
             ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .fetch_all(pool)
        .await)?;
        Ok(rows.into_iter().map(|(b, p)| (b.0, p.0)).collect())
    }

    pub async fn result_for(&self, submission_id: i64) -> Result<Option<ResultRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT submission_id, success_rate, success_ci_low, success_ci_high, behaviour_entropy, behaviour_ci_low, \
             behaviour_ci_high, conditional_entropy, conditional_ci_low, conditional_ci_high, stacking_json, \
             stacking_levels_json, inference_ms, manifest_json, per_context_json, created_at, rollouts_ended_unstable, \
             intervals_json, intervals_rules FROM results WHERE submission_id = $1",
        )
        .bind(submission_id)
        .fetch_optional(pool)
        .await)?)
    }

    /// The stored result of a submission as the worker (or the merge of its
    /// shards) made it: metrics, per-initial-state results and every rollout
    /// record with its trace, in rollout order. `None` until it is stored.
    /// What `d3il bench chaos` compares with a plain `d3il eval`.
    pub async fn eval_result(&self, submission_id: i64) -> Result<Option<EvalResult>, StoreError> {
        let Some(r) = self.result_for(submission_id).await? else {
            return Ok(None);
        };
        let manifest = r.manifest().ok_or_else(|| {
            StoreError::Corrupt(format!(
                "the protocol manifest stored with submission {submission_id}'s result does not parse"
            ))
        })?;
        let rows: Vec<StoredRollout> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT context_index, rollout_index, success, behaviour_json, steps, path_json, failure_json, ending, \
             trace_json FROM rollouts WHERE submission_id = $1 ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .fetch_all(pool)
        .await)?;
        Ok(Some(EvalResult {
            manifest,
            metrics: r.metrics(),
            per_context: r.per_context_json.0,
            rollouts: rows.into_iter().map(RolloutRecord::from).collect(),
            rollouts_ended_unstable: r.rollouts_ended_unstable.max(0) as usize,
        }))
    }

    pub async fn rollouts_for(&self, submission_id: i64) -> Result<Vec<RolloutRow>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT context_index, rollout_index, success, behaviour_json AS behaviour, steps, path_json, \
             failure_json AS failure, ending, trace_json IS NOT NULL AS has_trace FROM rollouts \
             WHERE submission_id = $1 ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .fetch_all(pool)
        .await)?)
    }

    /// The trace stored on one rollout row (None: the row has none, or
    /// there is no such row). Which row holds a rollout's trace is
    /// `crate::rollouts::trace_holder`'s to say.
    pub async fn rollout_trace(
        &self,
        submission_id: i64,
        context_index: i64,
        rollout_index: i64,
    ) -> Result<Option<RolloutTrace>, StoreError> {
        let row: Option<(Option<Json<RolloutTrace>>,)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT trace_json FROM rollouts WHERE submission_id = $1 AND context_index = $2 AND rollout_index = $3",
        )
        .bind(submission_id)
        .bind(context_index)
        .bind(rollout_index)
        .fetch_optional(pool)
        .await)?;
        Ok(row.and_then(|(t,)| t).map(|t| t.0))
    }

    /// Every trace stored for a submission (with `first_only`, those of each
    /// initial state's rollout 0), by (initial state, rollout index), in that
    /// order (the copies of a rollout simulated once have none).
    pub async fn rollout_traces(
        &self,
        submission_id: i64,
        first_only: bool,
    ) -> Result<Vec<(i64, i64, RolloutTrace)>, StoreError> {
        let rows: Vec<(i64, i64, Json<RolloutTrace>)> = on_db!(&self.db, pool => sqlx::query_as(
            "SELECT context_index, rollout_index, trace_json FROM rollouts \
             WHERE submission_id = $1 AND trace_json IS NOT NULL AND ($2 = FALSE OR rollout_index = 0) \
             ORDER BY context_index, rollout_index",
        )
        .bind(submission_id)
        .bind(first_only)
        .fetch_all(pool)
        .await)?;
        Ok(rows.into_iter().map(|(c, r, t)| (c, r, t.0)).collect())
    }

    /// Every training seed of the leaderboard row `s` belongs to (same method,
    /// task, observation type, data fraction, protocol and data source), `s`
    /// included, with its success rate once evaluated: one query.
    pub async fn sibling_seeds(&self, s: &SubmissionRow) -> Result<Vec<SeedSummary>, StoreError> {
        Ok(on_db!(&self.db, pool => sqlx::query_as(
            "SELECT s.id, s.training_seed, s.status, r.success_rate FROM submissions s \
             LEFT JOIN results r ON r.submission_id = s.id WHERE s.method_id = $1 AND s.task = $2 \
             AND s.obs_type = $3 AND s.data_fraction = $4 AND s.protocol = $5 \
             AND COALESCE(s.data_source, '') = COALESCE($6, '') ORDER BY s.training_seed, s.id",
        )
        .bind(s.method_id)
        .bind(s.task.slug())
        .bind(s.obs_type.as_str())
        .bind(s.data_fraction)
        .bind(protocol_str(s.protocol))
        .bind(s.data_source.as_deref())
        .fetch_all(pool)
        .await)?)
    }
}
