//! What the API (and the page's JSON download) shows of a submission and its
//! results.

use crate::error::AppError;
use crate::leaderboard::protocol_str;
use crate::leaderboard::BoardRow;
use crate::schema;
use crate::state::AppState;
use crate::store::MethodRow;
use crate::store::{
    now, DurationClass, JobRow, JobState, PolicyKind, ResultRow, SubmissionRow, SubmissionStatus,
};
use d3il_protocol::{
    ContextResult, Estimate, IntervalMethod, NoInterval, ObsType, ProtocolKind, SandboxMechanism,
    StackingLevel, TaskId,
};
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
use utoipa::ToSchema;

/// Progress, queue position and an ETA for a submission.
pub struct Progress {
    pub rollouts_done: i64,
    pub rollouts_total: i64,
    pub queue_position: Option<i64>,
    pub eta_seconds: Option<i64>,
}

/// Estimated seconds until the result of submission `s`'s job.
///
/// Past runs of the same [`DurationClass`] (task, observation type, protocol,
/// whether each initial state is simulated once, and the perturbation suite)
/// are the only basis: without them (and without progress to extrapolate
/// from) there is no estimate, never a guess and never "0 s". A suite run
/// without history of its own counts as its plain kind's mean times the
/// suite's number of evaluations (level 0 and every level), the factor its
/// worker's limits are scaled by (`d3il_sandbox::suite_limits`). A queued job waits for the jobs ahead of it (each
/// at its own kind's mean, spread over the slots: this front end's, or as
/// many as jobs are running when worker hosts run more), then runs; a queued quick
/// job has the pool's quick slot and waits only for quick jobs ahead of it.
pub async fn progress(
    state: &AppState,
    job: &JobRow,
    s: &SubmissionRow,
) -> Result<Progress, AppError> {
    let protocol = s.protocol;
    // A finished job has no position and no estimate: no queries.
    if !matches!(job.state, JobState::Queued | JobState::Leased) {
        return Ok(Progress {
            rollouts_done: job.rollouts_done,
            rollouts_total: job.rollouts_total,
            queue_position: None,
            eta_seconds: None,
        });
    }
    // The kinds of the queued jobs ahead; their count is the position.
    let ahead = match job.state {
        JobState::Queued => Some(state.store.queued_ahead(job.id).await?),
        _ => None,
    };
    let pos = ahead.as_ref().map(|a| a.len() as i64);
    let mut means: HashMap<DurationClass, f64> = state
        .store
        .mean_job_seconds_by_kind()
        .await?
        .into_iter()
        .map(|(k, m)| (k, m.max(1.0)))
        .collect();
    let own_kind = DurationClass::new(
        s.task.slug().to_string(),
        s.obs_type.as_str().to_string(),
        protocol_str(protocol).to_string(),
        s.simulated_once,
    )
    .with_suite(s.suite.clone());
    let kinds = std::iter::once(&own_kind).chain(ahead.iter().flatten());
    add_suite_means(&mut means, kinds, &state.cfg.assets_dir);
    let mean_of = |k: &DurationClass| means.get(k).copied();
    let own = mean_of(&own_kind);
    let workers = state.cfg.workers.max(1) as f64;
    let eta = match (job.state, &ahead) {
        (JobState::Queued, Some(ahead)) => match own {
            None => None,
            Some(own) => {
                let quick_slot = state.cfg.workers > 0 && protocol == ProtocolKind::Quick;
                let waits: Vec<f64> = ahead
                    .iter()
                    .filter(|k| !quick_slot || k.protocol == protocol_str(ProtocolKind::Quick))
                    .map(|k| mean_of(k).unwrap_or(own))
                    .collect();
                // While jobs wait, every slot that exists is busy: worker
                // hosts (`d3il workers`) run as many jobs as there are
                // leases, which may be more than this front end's own slots.
                let (_, running) = state.store.queue_counts().await?;
                let workers = workers.max(running as f64);
                let slots = if quick_slot { workers + 1.0 } else { workers };
                Some(waits.iter().sum::<f64>() / slots + own)
            }
        },
        (JobState::Leased, _) => {
            let frac = if job.rollouts_total > 0 {
                job.rollouts_done as f64 / job.rollouts_total as f64
            } else {
                0.0
            };
            let elapsed = (now() - job.started_at.unwrap_or_else(now)) as f64;
            // Extrapolate from progress once there is some; else from history
            // while the run is within its usual time.
            if frac > 0.05 {
                Some(elapsed / frac - elapsed)
            } else {
                own.map(|m| m - elapsed)
            }
        }
        _ => None,
    };
    Ok(Progress {
        rollouts_done: job.rollouts_done,
        rollouts_total: job.rollouts_total,
        queue_position: pos,
        // Under a second left is "no estimate", not "0 s".
        eta_seconds: eta.filter(|e| *e >= 1.0).map(|e| e.round() as i64),
    })
}

/// Adds to `means` (the mean duration of each kind's past runs) every suite
/// kind of `kinds` without runs of its own: its plain kind's mean times the
/// suite's evaluations (the suite file is read once per kind, not per job).
fn add_suite_means<'a>(
    means: &mut HashMap<DurationClass, f64>,
    kinds: impl Iterator<Item = &'a DurationClass>,
    assets_dir: &std::path::Path,
) {
    let mut tried = std::collections::HashSet::new();
    for k in kinds {
        if k.suite.is_none() || means.contains_key(k) || !tried.insert(k) {
            continue;
        }
        let derived = (|| {
            let task: TaskId = k.task.parse().ok()?;
            let obs: ObsType = k.obs_type.parse().ok()?;
            let evaluations = crate::intake::suite_evaluations(assets_dir, task, obs)?;
            Some(means.get(&k.plain())? * evaluations as f64)
        })();
        if let Some(m) = derived {
            means.insert(k.clone(), m);
        }
    }
}

/// A submission: status, progress, queue position, ETA and result.
#[derive(Debug, Serialize, ToSchema)]
pub struct SubmissionView {
    pub id: i64,
    /// The submission's page.
    pub url: String,
    pub status: SubmissionStatus,
    pub method: String,
    pub submitter: Option<String>,
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    #[schema(value_type = schema::Obs)]
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    #[schema(value_type = schema::Protocol)]
    pub protocol: ProtocolKind,
    pub policy: PolicyView,
    /// The policy manifest as submitted.
    #[schema(value_type = Object)]
    pub manifest: Value,
    /// Why the submission failed (when it did).
    pub error: Option<ErrorView>,
    pub attempts: i64,
    pub max_attempts: i64,
    pub progress: ProgressView,
    /// Jobs ahead of this one (0 = next); null unless queued.
    pub queue_position: Option<i64>,
    /// Estimated seconds until the result, from past runs or this run's
    /// progress; null when finished or when there is no basis for one yet.
    pub eta_seconds: Option<i64>,
    /// Set when the evaluation was cancelled (status `failed`, error kind
    /// `cancelled`): what ran is in `progress.live`, marked partial, and
    /// never ranked.
    pub cancelled: Option<CancelledView>,
    pub created_at: i64,
    pub updated_at: i64,
    /// Set when an admin withdrew the submission: it is kept but
    /// shown on no board or table.
    pub withdrawn: Option<crate::store::Withdrawal>,
    /// The zoo's submissions: where the training data came from
    /// ("trained here on d3il demos v1"; the provenance is at
    /// `/submissions/{id}/provenance`); null for what submitters send.
    pub data_source: Option<String>,
    /// The result once completed.
    pub result: Option<ResultsView>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct PolicyView {
    pub kind: PolicyKind,
    /// SHA-256 of the uploaded ONNX file.
    pub sha256: Option<String>,
    pub bytes: Option<i64>,
    /// A remote endpoint's URL: shown only to its submitter and admins
    /// (a published endpoint would serve anyone); null otherwise.
    pub endpoint_url: Option<String>,
    /// Whether the evaluation simulates each initial state's rollouts once
    /// and records that rollout under every index (a deterministic policy: an
    /// ONNX graph without a `noise` input; docs/submission.md). Known from the
    /// dry run at submission or from the result; null when not known.
    pub simulated_once: Option<bool>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorView {
    pub kind: String,
    pub message: Option<String>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ProgressView {
    pub rollouts_done: i64,
    pub rollouts_total: i64,
    /// The success rate so far with its confidence sequence, valid at every
    /// look (docs/sequential.md); kept once the evaluation ends
    /// (a cancelled one's partial result). Null until the first initial
    /// state has finished.
    pub live: Option<crate::live::LiveEstimate>,
}

/// Who cancelled an evaluation, and when.
#[derive(Debug, Serialize, ToSchema)]
pub struct CancelledView {
    pub at: i64,
    /// The token name of the submitter or admin who cancelled it.
    pub by: String,
}

/// Metrics, protocol manifest, per-context and per-rollout results.
#[derive(Debug, Serialize, ToSchema)]
pub struct ResultsView {
    pub submission_id: i64,
    pub metrics: MetricsView,
    /// What was run: task, protocol, versions and hashes of the assets.
    #[schema(value_type = Object)]
    pub protocol_manifest: Value,
    /// Success rate, entropy and behaviour counts per initial state.
    #[schema(value_type = Vec<Object>)]
    pub per_context: Vec<ContextResult>,
    pub rollouts: Vec<RolloutView>,
    /// The sandbox mechanisms the evaluation ran under.
    #[schema(value_type = Option<Vec<Object>>)]
    pub sandbox: Option<Vec<SandboxMechanism>>,
    pub created_at: i64,
    /// The initial-state set (file name, e.g. `pushing-v2.json`).
    pub initial_states: String,
    /// "the original D3IL test contexts" or "our sample".
    pub initial_states_label: String,
    /// Rollouts ended as failures because the simulation became unstable.
    pub rollouts_ended_unstable: i64,
    /// More than half of the rollouts ended that way.
    pub mostly_unstable: bool,
}

/// A metric with its 95 % confidence interval and the interval's method, or
/// why there is none.
#[derive(Debug, Serialize, ToSchema)]
pub struct EstimateView {
    pub value: f64,
    /// Equal to `value` when `no_interval` is given.
    pub ci_low: f64,
    pub ci_high: f64,
    /// The interval's method (`korn_graubard`, `sign_flip_exact`, ...);
    /// absent for results made before 0.5.0 and when there is no interval.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<String>)]
    pub method: Option<IntervalMethod>,
    /// Why there is no interval (`{"reason": "too_few_states", "states": 3, "min": 5}`).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub no_interval: Option<NoInterval>,
    /// The method's name, or the reason there is no interval, in words.
    pub interval: String,
}

impl From<Estimate> for EstimateView {
    fn from(e: Estimate) -> Self {
        EstimateView {
            value: e.value,
            ci_low: e.ci_low,
            ci_high: e.ci_high,
            method: e.method,
            no_interval: e.no_interval,
            interval: e.interval_note(),
        }
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub struct MetricsView {
    pub success_rate: EstimateView,
    pub behaviour_entropy: EstimateView,
    pub conditional_entropy: EstimateView,
    /// Stacking: success rates with at least 1, 2 and 3 boxes stacked.
    #[schema(value_type = Option<Vec<f64>>)]
    pub stacking: Option<[f64; 3]>,
    /// Stacking-1/2/3 metrics (success rate and entropies, each an estimate).
    #[schema(value_type = Option<Vec<Object>>)]
    pub stacking_levels: Option<[StackingLevel; 3]>,
    /// Mean inference time per policy query.
    pub inference_ms: f64,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct RolloutView {
    pub context_index: i64,
    pub rollout_index: i64,
    pub success: bool,
    /// The behaviour code (the reference's encoding, per task): an integer,
    /// a list of numbers (Avoiding) or a string, so any JSON value.
    #[schema(value_type = Value)]
    pub behaviour: Value,
    pub steps: i64,
    /// End-effector xy path (Avoiding only).
    #[schema(value_type = Option<Vec<Vec<f32>>>)]
    pub path: Option<Vec<[f32; 2]>>,
    /// `{"reason": "sim_unstable", "message", "step"}` when the rollout was
    /// ended as a failure because the simulation became unstable.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub failure: Option<d3il_protocol::RolloutFailure>,
    /// How it ended; absent for results stored before endings were
    /// recorded. Traces are not listed here: see
    /// `/api/v1/submissions/{id}/rollouts/{n}`.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<schema::Ending>)]
    pub ending: Option<d3il_protocol::Ending>,
}

/// Whether `who` may see submission `s`'s endpoint URL: its submitter or
/// an admin (the one rule for every view).
pub fn may_see_endpoint(
    who: Option<&crate::store::Submitter>,
    s: &crate::store::SubmissionRow,
) -> bool {
    who.is_some_and(|w| w.is_admin || s.submitter.as_deref() == Some(w.name.as_str()))
}

/// The submission as the API (and the page's JSON download) shows it to
/// anyone: without a remote endpoint's URL.
pub async fn submission_view(state: &AppState, id: i64) -> Result<SubmissionView, AppError> {
    submission_view_for(state, id, None).await
}

/// [`submission_view`] as `who` sees it: its own (or, for an admin, any)
/// remote endpoint's URL included.
pub async fn submission_view_for(
    state: &AppState,
    id: i64,
    who: Option<&crate::store::Submitter>,
) -> Result<SubmissionView, AppError> {
    let s = state.store.submission(id).await?;
    let endpoint_url = if may_see_endpoint(who, &s) {
        s.endpoint_url.clone()
    } else {
        None
    };
    let job = state.store.job_for(id).await?;
    let p = progress(state, &job, &s).await?;
    let cancelled = state.store.cancelled(id).await?;
    let live = crate::live::live_estimate(&state.store, id, cancelled.is_some()).await?;
    let result = match state.store.result_for(id).await? {
        Some(r) => Some(results_view(state, r).await?),
        None => None,
    };
    Ok(SubmissionView {
        id: s.id,
        url: format!("/submissions/{}", s.id),
        status: s.status,
        method: s.method,
        submitter: s.submitter,
        task: s.task,
        obs_type: s.obs_type,
        training_seed: s.training_seed,
        data_fraction: s.data_fraction,
        protocol: s.protocol,
        policy: PolicyView {
            kind: s.policy_kind,
            sha256: s.onnx_sha256,
            bytes: s.onnx_bytes,
            endpoint_url,
            simulated_once: s.simulated_once,
        },
        manifest: s.manifest_json.0,
        error: s.error_kind.map(|kind| ErrorView {
            kind,
            message: s.error_message,
        }),
        attempts: job.attempts,
        max_attempts: job.max_attempts,
        progress: ProgressView {
            rollouts_done: p.rollouts_done,
            rollouts_total: p.rollouts_total,
            live,
        },
        queue_position: p.queue_position,
        eta_seconds: p.eta_seconds,
        cancelled: cancelled.map(|c| CancelledView { at: c.at, by: c.by }),
        created_at: s.created_at,
        updated_at: s.updated_at,
        withdrawn: state.store.withdrawal(id).await?,
        data_source: s.data_source.clone(),
        result,
    })
}

/// A result with its rollouts and the sandbox report of its job.
pub async fn results_view(state: &AppState, r: ResultRow) -> Result<ResultsView, AppError> {
    let rollouts = state.store.rollouts_for(r.submission_id).await?;
    let job = state.store.job_for(r.submission_id).await?;
    let m = r.metrics();
    let manifest = r.manifest();
    let n_rollouts = rollouts.len() as i64;
    Ok(ResultsView {
        initial_states: manifest
            .as_ref()
            .map(|m| m.initial_states_name())
            .unwrap_or_default(),
        initial_states_label: manifest
            .as_ref()
            .map(|m| m.initial_states_origin().label().to_string())
            .unwrap_or_default(),
        rollouts_ended_unstable: r.rollouts_ended_unstable,
        mostly_unstable: 2 * r.rollouts_ended_unstable > n_rollouts,
        submission_id: r.submission_id,
        metrics: MetricsView {
            success_rate: m.success_rate.into(),
            behaviour_entropy: m.behaviour_entropy.into(),
            conditional_entropy: m.conditional_entropy.into(),
            stacking: r.stacking_json.map(|j| j.0),
            stacking_levels: r.stacking_levels_json.map(|j| j.0),
            inference_ms: r.inference_ms,
        },
        protocol_manifest: r.manifest_json.0,
        per_context: r.per_context_json.0,
        rollouts: rollouts
            .into_iter()
            .map(|x| RolloutView {
                context_index: x.context_index,
                rollout_index: x.rollout_index,
                success: x.success,
                behaviour: x.behaviour.0,
                steps: x.steps,
                path: x.path_json.map(|j| j.0),
                failure: x.failure.map(|j| j.0),
                ending: x.ending.map(|e| e.0),
            })
            .collect(),
        sandbox: job.sandbox_json.map(|j| j.0),
        created_at: r.created_at,
    })
}

/// The caller's identity.
#[derive(Debug, Serialize, ToSchema)]
pub struct WhoAmI {
    pub submitter: String,
    /// What is left of the submission quota.
    pub quota: crate::quota::QuotaView,
}

/// `POST /api/v1/submissions`' answer: the submission and what is left of
/// the submitter's quota after it.
#[derive(Debug, Serialize, ToSchema)]
pub struct CreatedView {
    #[serde(flatten)]
    pub submission: SubmissionView,
    pub quota: crate::quota::QuotaView,
}

/// The build this server runs: what its results record.
#[derive(Debug, Serialize, ToSchema)]
pub struct BuildView {
    /// The evaluator's version (CHANGELOG.md has the versioning rule).
    pub evaluator_version: String,
    /// The git commit the binary was built from (`unknown` outside a checkout).
    pub git_commit: String,
    /// The drift canary's outcome (`d3il verify` run at start); its
    /// fingerprint is what this server's results record.
    pub canary: crate::canary::CanaryState,
}

/// Every method and its properties.
#[derive(Debug, Serialize, ToSchema)]
pub struct MethodList {
    pub methods: Vec<MethodRow>,
}

/// One leaderboard (task and observation type) with its links.
#[derive(Debug, Serialize, ToSchema)]
pub struct LeaderboardLink {
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    #[schema(value_type = String)]
    pub title: &'static str,
    #[schema(value_type = schema::Obs)]
    pub obs_type: ObsType,
    /// Rows in the main view.
    pub rows: usize,
    /// This leaderboard in the API.
    pub url: String,
    /// Its CSV export.
    pub csv: String,
    /// Its page.
    pub page: String,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct LeaderboardList {
    pub leaderboards: Vec<LeaderboardLink>,
}

/// The rows of one leaderboard view.
#[derive(Debug, Serialize, ToSchema)]
pub struct LeaderboardView {
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    #[schema(value_type = String)]
    pub title: &'static str,
    #[schema(value_type = schema::Obs)]
    pub obs_type: ObsType,
    /// `main` or `data-fraction`.
    #[schema(value_type = String)]
    pub view: &'static str,
    pub rows: Vec<BoardRow>,
}

/// The query of the submission lists (`/submissions`, `GET /api/v1/submissions`).
#[derive(Debug, Clone, Default, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SubmissionListQuery {
    /// Task slug (`aligning`).
    pub task: Option<String>,
    /// Exact method name.
    pub method: Option<String>,
    /// `queued`, `running`, `completed` or `failed`.
    pub status: Option<String>,
    /// Exact submitter name.
    pub submitter: Option<String>,
}

impl SubmissionListQuery {
    /// The typed filter; a task or status that names nothing is an error
    /// naming the field and the choices. Empty fields (an unset form
    /// select) filter nothing.
    pub fn filter(&self) -> Result<crate::store::SubmissionFilter, AppError> {
        fn given(v: &Option<String>) -> Option<&str> {
            v.as_deref().map(str::trim).filter(|v| !v.is_empty())
        }
        let task = given(&self.task)
            .map(|t| t.parse::<TaskId>())
            .transpose()
            .map_err(|e| AppError::invalid("task", e.to_string()))?;
        let status = match given(&self.status) {
            None => None,
            Some(st) => Some(
                [
                    SubmissionStatus::Queued,
                    SubmissionStatus::Running,
                    SubmissionStatus::Completed,
                    SubmissionStatus::Failed,
                ]
                .into_iter()
                .find(|s| s.as_str() == st)
                .ok_or_else(|| {
                    AppError::invalid(
                        "status",
                        format!("unknown status `{st}`; use queued, running, completed or failed"),
                    )
                })?,
            ),
        };
        Ok(crate::store::SubmissionFilter {
            task,
            method: given(&self.method).map(String::from),
            status,
            submitter: given(&self.submitter).map(String::from),
        })
    }
}

/// One line of a submission list.
#[derive(Debug, Serialize, ToSchema)]
pub struct SubmissionSummary {
    pub id: i64,
    /// The submission's page.
    pub url: String,
    pub status: SubmissionStatus,
    pub method: String,
    pub submitter: Option<String>,
    #[schema(value_type = schema::Task)]
    pub task: TaskId,
    #[schema(value_type = schema::Obs)]
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    #[schema(value_type = schema::Protocol)]
    pub protocol: ProtocolKind,
    pub created_at: i64,
}

impl From<crate::store::SubmissionRow> for SubmissionSummary {
    fn from(s: crate::store::SubmissionRow) -> Self {
        SubmissionSummary {
            url: format!("/submissions/{}", s.id),
            id: s.id,
            status: s.status,
            method: s.method,
            submitter: s.submitter,
            task: s.task,
            obs_type: s.obs_type,
            training_seed: s.training_seed,
            data_fraction: s.data_fraction,
            protocol: s.protocol,
            created_at: s.created_at,
        }
    }
}

/// Submissions matching a filter, newest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct SubmissionList {
    pub submissions: Vec<SubmissionSummary>,
}
