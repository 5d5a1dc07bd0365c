//! Sequential comparisons on the server (issue 41): `POST /api/v1/comparisons`
//! races two submissions' policies in one race job (`d3il_protocol::race`),
//! run by the app's job runner (a sandboxed `d3il worker`, through the same
//! slots as every job) on a background task; the comparison's row holds its
//! live state while it runs and the race's report when it ends. The rule is
//! `d3il_evaluator::eval::race` (the same as `d3il compare --sequential
//! --task`); docs/sequential.md.

use crate::error::AppError;
use crate::queue::policy_of;
use crate::state::AppState;
use crate::store::{ComparisonRow, NewComparison, SubmissionStatus, Submitter};
use d3il_protocol::race::{RaceJob, RaceProgress, RaceReport};
use d3il_protocol::{Evaluated, Job, ProtocolKind};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// Rollouts simulated at once per policy (as `d3il compare --max-live`'s default).
pub const MAX_LIVE: usize = 8;

/// `POST /api/v1/comparisons`: two submission ids and the test's options.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ComparisonRequest {
    /// Submission id of policy A.
    pub a: i64,
    /// Submission id of policy B (another submission on the same task and observation type).
    pub b: i64,
    /// The task both were submitted for (optional: checked when given).
    #[serde(default)]
    pub task: Option<String>,
    /// Two-sided level of the sequential test, in (0, 1); default 0.05.
    #[serde(default)]
    pub alpha: Option<f64>,
    /// Margin in (0, 2): also stop with "no difference larger than δ".
    #[serde(default)]
    pub delta: Option<f64>,
    /// `paper` (default) or `quick`: the full size the race may run to.
    #[serde(default)]
    pub protocol: Option<String>,
    /// Seed of both policies' noise and of the states' random order; default 0.
    #[serde(default)]
    pub seed: Option<u64>,
}

/// Where a running race stands after its latest pair.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct RaceLive {
    /// Initial states complete for both policies (one pair each).
    pub states: u64,
    pub states_total: u64,
    pub pairs: u64,
    /// The paired counts: both succeed, only A, only B, neither.
    pub both: u64,
    pub only_a: u64,
    pub only_b: u64,
    pub neither: u64,
    /// The two-sided e-value and the anytime-valid p-value now.
    pub e_value: f64,
    pub p_value: f64,
    /// Set once decided: "A better", "B better" or "no difference larger than δ".
    pub decision: Option<String>,
    /// The pairs so far in the test's order, one `race::pair_code` each
    /// (the race page draws the walk from them).
    #[serde(default)]
    pub outcomes: String,
}

impl RaceLive {
    /// Adds the pair the progress report carries.
    pub fn add(&mut self, p: &RaceProgress) {
        let x = p.a.successes.first().copied().unwrap_or(false);
        let y = p.b.successes.first().copied().unwrap_or(false);
        match (x, y) {
            (true, true) => self.both += 1,
            (true, false) => self.only_a += 1,
            (false, true) => self.only_b += 1,
            (false, false) => self.neither += 1,
        }
        self.outcomes.push(d3il_protocol::race::pair_code(x, y));
        self.states = p.states as u64;
        self.states_total = p.states_total as u64;
        self.pairs = p.pairs;
        self.e_value = p.e_value;
        self.p_value = p.p_value;
        self.decision = p.decision.clone();
    }
}

/// A comparison as the API shows it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ComparisonView {
    pub id: i64,
    pub a: i64,
    pub b: i64,
    pub task: String,
    pub protocol: String,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
    /// queued | running | completed | failed
    pub status: String,
    /// The race so far (null until its first pair).
    pub live: Option<RaceLive>,
    /// The finished race: the same document as `d3il compare --sequential
    /// --task T A B --json` (decision, decided_at, e_value, p_value,
    /// discordant, rates, pairs/states/rollouts used and full, the
    /// fixed-size sign test's p-value and pairs for 90 % power).
    #[schema(value_type = Option<Object>)]
    pub report: Option<serde_json::Value>,
    /// Why it failed.
    pub error: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
}

impl ComparisonView {
    pub fn of(row: &ComparisonRow) -> ComparisonView {
        fn parse<T: serde::de::DeserializeOwned>(j: &Option<String>) -> Option<T> {
            j.as_deref().and_then(|j| serde_json::from_str(j).ok())
        }
        ComparisonView {
            id: row.id,
            a: row.submission_a,
            b: row.submission_b,
            task: row.task.clone(),
            protocol: row.protocol.clone(),
            seed: row.seed,
            alpha: row.alpha,
            delta: row.delta,
            status: row.status.clone(),
            live: parse(&row.live_json),
            report: parse(&row.report_json),
            error: row.error_message.clone(),
            created_at: row.created_at,
            updated_at: row.updated_at,
        }
    }

    /// The report, typed.
    pub fn race_report(&self) -> Option<RaceReport> {
        self.report
            .as_ref()
            .and_then(|r| serde_json::from_value(r.clone()).ok())
    }
}

/// Checks a request (a 400 naming the field for each problem), records the
/// comparison and starts its race. Admitted like a submission (a submitter
/// out of quota is refused) but not counted against the quota.
pub async fn create(
    state: &AppState,
    who: &Submitter,
    req: &ComparisonRequest,
) -> Result<i64, AppError> {
    let alpha = req.alpha.unwrap_or(0.05);
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(AppError::invalid(
            "alpha",
            format!("alpha {alpha} is not in (0, 1); use e.g. 0.05"),
        ));
    }
    if let Some(d) = req.delta {
        if !(d > 0.0 && d < 2.0) {
            return Err(AppError::invalid(
                "delta",
                format!("delta {d} is not in (0, 2); use e.g. 0.1 (ten points of success rate)"),
            ));
        }
    }
    let protocol: ProtocolKind = match req.protocol.as_deref() {
        None => ProtocolKind::default(),
        Some(p) => p.parse().map_err(|_| {
            AppError::invalid(
                "protocol",
                format!("unknown protocol `{p}`; use paper or quick"),
            )
        })?,
    };
    if req.a == req.b {
        return Err(AppError::invalid(
            "b",
            format!(
                "a and b are both submission {}; race two different submissions",
                req.a
            ),
        ));
    }
    let side = |field: &'static str, id: i64| async move {
        let s = state.store.submission(id).await.map_err(|e| match e {
            crate::store::StoreError::NotFound(_) => AppError::invalid(
                field,
                format!("there is no submission {id} (`{field}`); give the id of a submission (GET /api/v1/submissions)"),
            ),
            e => e.into(),
        })?;
        if s.status == SubmissionStatus::Failed {
            return Err(AppError::invalid(
                field,
                format!("submission {id} (`{field}`) failed; a failed submission's policy is not kept, so it cannot race"),
            ));
        }
        Ok(s)
    };
    let a = side("a", req.a).await?;
    let b = side("b", req.b).await?;
    if let Some(t) = &req.task {
        if *t != a.task.to_string() {
            return Err(AppError::invalid(
                "task",
                format!("submission {} (`a`) is for {}, not {t}", a.id, a.task),
            ));
        }
    }
    if a.task != b.task {
        return Err(AppError::invalid(
            "b",
            format!(
                "submission {} (`a`) is for {} and submission {} (`b`) for {}: a race runs both on the same task",
                a.id, a.task, b.id, b.task
            ),
        ));
    }
    if a.obs_type != b.obs_type {
        return Err(AppError::invalid(
            "b",
            format!(
                "submission {} (`a`) takes {} observations and submission {} (`b`) {}: a race runs both on the same task variant",
                a.id, a.obs_type, b.id, b.obs_type
            ),
        ));
    }
    crate::quota::admit(state, who).await?;
    let id = state
        .store
        .create_comparison(&NewComparison {
            submission_a: a.id,
            submission_b: b.id,
            submitter_id: who.id,
            task: a.task.to_string(),
            protocol: protocol.as_str().to_string(),
            seed: req.seed.unwrap_or(0).min(i64::MAX as u64) as i64,
            alpha,
            delta: req.delta,
        })
        .await?;
    spawn(state.clone(), id);
    Ok(id)
}

/// Starts the races of comparisons left queued or running (a restart):
/// each runs again from its first pair.
pub async fn resume(state: &AppState) {
    match state.store.unfinished_comparisons().await {
        Ok(ids) => ids.into_iter().for_each(|id| spawn(state.clone(), id)),
        Err(e) => tracing::warn!("unfinished comparisons not resumed: {e}"),
    }
}

/// Runs comparison `id`'s race on a background task.
pub fn spawn(state: AppState, id: i64) {
    tokio::spawn(async move {
        if let Err(e) = run(&state, id).await {
            tracing::warn!("comparison {id}: {e}");
            let _ = state.store.comparison_failed(id, &e).await;
        }
    });
}

async fn job_of(state: &AppState, row: &ComparisonRow) -> Result<Job, String> {
    let a = state
        .store
        .submission(row.submission_a)
        .await
        .map_err(|e| e.to_string())?;
    let b = state
        .store
        .submission(row.submission_b)
        .await
        .map_err(|e| e.to_string())?;
    let (policy, manifest) = policy_of(&a)?;
    let (policy_b, manifest_b) = policy_of(&b)?;
    Ok(Job {
        job_id: format!("comparison-{}", row.id),
        task: a.task,
        protocol: row
            .protocol
            .parse()
            .map_err(|_| "stored protocol is invalid")?,
        policy,
        manifest,
        seed: row.seed.max(0) as u64,
        limits: state.cfg.limits.clone(),
        assets_dir: state.cfg.assets_dir.to_string_lossy().into_owned(),
        dry_run_steps: None,
        shard: None,
        build: None,
        suite: None,
        race: Some(RaceJob {
            policy_b,
            manifest_b,
            alpha: row.alpha,
            delta: row.delta,
            max_live: MAX_LIVE,
        }),
    })
}

async fn run(state: &AppState, id: i64) -> Result<(), String> {
    let row = state
        .store
        .comparison(id)
        .await
        .map_err(|e| e.to_string())?;
    let job = job_of(state, &row).await?;
    state
        .store
        .comparison_running(id)
        .await
        .map_err(|e| e.to_string())?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<RaceLive>();
    let runner = state.runner.clone();
    let run = tokio::task::spawn_blocking(move || {
        let mut live = RaceLive::default();
        runner.run_cancellable(
            &job,
            &mut |p| {
                if let Some(r) = &p.race {
                    live.add(r);
                    let _ = tx.send(live.clone());
                }
            },
            &std::sync::atomic::AtomicBool::new(false),
        )
    });
    let store = state.store.clone();
    let writer = tokio::spawn(async move {
        while let Some(mut live) = rx.recv().await {
            // Only the newest state matters.
            while let Ok(newer) = rx.try_recv() {
                live = newer;
            }
            if let Ok(j) = serde_json::to_string(&live) {
                if let Err(e) = store.comparison_live(id, &j).await {
                    tracing::warn!("comparison {id}: live state not written: {e}");
                }
            }
        }
    });
    let report = run.await.map_err(|e| format!("the race panicked: {e}"))?;
    let _ = writer.await;
    match report.outcome {
        Ok(Evaluated::Race(r)) => {
            let j = serde_json::to_string(&r).map_err(|e| e.to_string())?;
            state
                .store
                .comparison_completed(id, &j)
                .await
                .map_err(|e| e.to_string())?;
            tracing::info!(
                "comparison {id} completed: {}",
                r.decision.as_deref().unwrap_or("no decision at full size")
            );
            Ok(())
        }
        Ok(_) => {
            Err("the worker answered a race job with something else than a race report".into())
        }
        Err(e) => Err(e.message),
    }
}
