//! Races on the server: `POST /api/v1/races` races two submissions'
//! policies in one race job (`d3il_protocol::race`): both on the same
//! initial states in the same random order, stopped by the sequential
//! paired test; the race's row holds its live state while it runs and its
//! report when it ends. The rule is `d3il_evaluator::eval::race` (the same
//! as `d3il race --task`); docs/sequential.md. (A race is not a paired
//! comparison: that is of two finished results, [`crate::comparison`].)
//!
//! A race is metered work. It needs one of the racer's own
//! submissions (against any public one), counts [`crate::quota::RACE_EVALUATIONS`]
//! against the quota, and a submitter has at most `--max-queued-races`
//! queued or running. It waits in the durable queue (the races' table)
//! holding nothing: the front end's race slot ([`start_race_slot`]) leases
//! the oldest one, runs it in a sandboxed `d3il worker` through the shared
//! worker slots, heartbeats, and stops its worker when the race is
//! cancelled ([`cancel_as`]: its starter or an admin). A restart resumes
//! what the queue says.

use crate::error::AppError;
use crate::queue::policy_of;
use crate::state::AppState;
use crate::store::{NewRace, RaceCancel, RaceRow, RaceStatus, SubmissionStatus, Submitter};
use d3il_protocol::race::{RaceJob, RaceProgress, RaceReport};
use d3il_protocol::{Evaluated, Job, JobKind, ProtocolKind, TaskId};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// Rollouts simulated at once per policy (as `d3il race --max-live`'s default).
pub const MAX_LIVE: usize = 8;

/// `POST /api/v1/races`: two submission ids and the test's options.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RaceRequest {
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

/// A race as the API shows it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RaceView {
    pub id: i64,
    pub a: i64,
    pub b: i64,
    #[schema(value_type = crate::schema::Task)]
    pub task: TaskId,
    #[schema(value_type = crate::schema::Protocol)]
    pub protocol: ProtocolKind,
    pub seed: i64,
    pub alpha: f64,
    pub delta: Option<f64>,
    pub status: RaceStatus,
    /// Who cancelled it (its starter or an admin).
    pub cancelled_by: Option<String>,
    /// The race so far (null until its first pair).
    pub live: Option<RaceLive>,
    /// The finished race: the same document as `d3il race --task T A B
    /// --json` (decision, decided_at, e_value, p_value,
    /// discordant, rates, pairs/states/rollouts used and full, the
    /// fixed-size sign test's p-value and pairs for 90 % power).
    #[schema(value_type = Option<Object>)]
    pub report: Option<serde_json::Value>,
    /// The finished race's pairs as a fixed-size comparison
    /// ([`fixed_comparison`]); null until it finishes.
    pub fixed_comparison: Option<FixedComparison>,
    /// Why it failed.
    pub error: Option<String>,
    pub created_at: i64,
    pub updated_at: i64,
}

impl RaceView {
    pub fn of(row: &RaceRow) -> RaceView {
        fn parse<T: serde::de::DeserializeOwned>(j: &Option<String>) -> Option<T> {
            j.as_deref().and_then(|j| serde_json::from_str(j).ok())
        }
        RaceView {
            id: row.id,
            a: row.submission_a,
            b: row.submission_b,
            task: row.task,
            protocol: row.protocol,
            seed: row.seed,
            alpha: row.alpha,
            delta: row.delta,
            status: row.status,
            cancelled_by: row.cancelled_by.clone(),
            live: parse(&row.live_json),
            report: parse(&row.report_json),
            fixed_comparison: parse::<RaceReport>(&row.report_json)
                .as_ref()
                .map(fixed_comparison),
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

/// A finished race's pairs (one a state: its rollout 0) compared as if
/// their number had been fixed in advance: the exact McNemar test on the
/// discordant pairs (the report's `fixed_p_value`) and its inverted
/// interval at the race's level (`d3il_metrics::rate_difference::ExactMcNemar`,
/// docs/intervals.md), so 0 lies outside it exactly when p ≤ α. For
/// reference only: the race stopped when its data said so, which neither
/// allows for; the race's own decision is the sequential test's.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct FixedComparison {
    /// Pairs used.
    pub pairs: u64,
    /// A − B of the pairs' success rates, with its interval (`ci_low`,
    /// `ci_high`, `method`: `mcnemar_exact`) or `no_interval`.
    #[schema(value_type = Object)]
    pub difference: d3il_protocol::Estimate,
    /// The exact McNemar test's two-sided p-value.
    pub p_value: f64,
}

/// [`FixedComparison`] of a race's report
/// (`d3il_metrics::rate_difference::fixed_size_comparison`, as `d3il race`
/// prints it).
pub fn fixed_comparison(r: &RaceReport) -> FixedComparison {
    let f =
        d3il_metrics::rate_difference::fixed_size_comparison(r.pairs_used, r.discordant, r.alpha);
    FixedComparison {
        pairs: f.pairs,
        difference: f.difference,
        p_value: f.p_value,
    }
}

/// Checks a request (a 400 naming the field for each problem), meters it
/// (one of `a` and `b` must be the racer's own, the other public; the race
/// counts [`crate::quota::RACE_EVALUATIONS`] and must fit the quota and the
/// cap on races at once: else 429 naming the limit and when) and queues it.
pub async fn create(state: &AppState, who: &Submitter, req: &RaceRequest) -> Result<i64, AppError> {
    let alpha = req.alpha.unwrap_or(d3il_protocol::race::DEFAULT_ALPHA);
    d3il_protocol::race::check_race_params(alpha, req.delta)
        .map_err(|e| AppError::invalid(e.field, e.message))?;
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
    if !who.is_admin {
        let own =
            |s: &crate::store::SubmissionRow| s.submitter.as_deref() == Some(who.name.as_str());
        if !own(&a) && !own(&b) {
            return Err(AppError::QuotaExceeded {
                message: format!(
                    "a race needs one of your own submissions: neither submission {} (`a`) nor {} (`b`) is yours; \
                     race a policy you submitted against any public one (POST /api/v1/submissions first)",
                    a.id, b.id
                ),
                retry_after: None,
                next_at: None,
            });
        }
        for (field, s) in [("a", &a), ("b", &b)] {
            if !own(s) && state.store.withdrawal(s.id).await?.is_some() {
                return Err(AppError::invalid(
                    field,
                    format!(
                        "submission {} (`{field}`) was withdrawn; race against a public submission",
                        s.id
                    ),
                ));
            }
        }
    }
    let quota = crate::quota::admit(
        state,
        who,
        crate::quota::RACE_EVALUATIONS,
        "a race (both policies up to the protocol's full size)",
    )
    .await?;
    if let Some(e) = quota.race_refusal() {
        return Err(e);
    }
    let id = state
        .store
        .create_race(&NewRace {
            submission_a: a.id,
            submission_b: b.id,
            submitter_id: who.id,
            task: a.task,
            protocol,
            seed: req.seed.unwrap_or(0).min(i64::MAX as u64) as i64,
            alpha,
            delta: req.delta,
        })
        .await?;
    state.signal.race_queued();
    Ok(id)
}

/// Cancels race `id` as `who`: its starter or an admin may (the one rule
/// for the API and the race page's button). Audited in the same
/// transaction; a running race's worker is stopped by its slot.
pub async fn cancel_as(state: &AppState, id: i64, who: &Submitter) -> Result<(), AppError> {
    let row = state.store.race(id).await?;
    let starter = row.submitter_id == Some(who.id);
    if !who.is_admin && !starter {
        return Err(AppError::Forbidden(format!(
            "race {id} was started by another submitter; only its starter or an admin may cancel it"
        )));
    }
    let target = format!("race {id}");
    let detail = format!("cancelled a {} race", row.status);
    let audit = Some((
        who.name.as_str(),
        "cancel_race",
        target.as_str(),
        detail.as_str(),
    ));
    match state.store.cancel_race(id, &who.name, audit).await? {
        RaceCancel::Cancelled => {
            tracing::info!("race {id} cancelled by {}", who.name);
            Ok(())
        }
        RaceCancel::AlreadyFinished => Err(AppError::Conflict {
            field: None,
            message: format!(
                "race {id} is {} already; only a queued or running race can be cancelled",
                row.status
            ),
        }),
    }
}

async fn job_of(state: &AppState, row: &RaceRow) -> Result<Job, String> {
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
        job_id: format!("race-{}", row.id),
        task: row.task,
        protocol: row.protocol,
        policy,
        manifest,
        seed: row.seed.max(0) as u64,
        limits: state.cfg.limits.clone(),
        assets_dir: state.cfg.assets_dir.to_string_lossy().into_owned(),
        dry_run_steps: None,
        build: None,
        kind: JobKind::Race(Box::new(RaceJob {
            policy_b,
            manifest_b,
            alpha: row.alpha,
            delta: row.delta,
            max_live: MAX_LIVE,
        })),
    })
}

/// Starts the race slot: requeues the races this server's slots held
/// before a restart (SQLite; on PostgreSQL an abandoned lease expires and is
/// taken over), then runs queued races one after the other, oldest first,
/// each in a worker of `runner` (one at a time: the slot's own worker, apart
/// from the pool's slots and dry runs). A waiting race holds no thread: it
/// is a row until the slot claims it.
pub async fn start_race_slot(
    state: AppState,
    runner: std::sync::Arc<dyn crate::queue::JobRunner>,
) -> Result<(), crate::store::StoreError> {
    if !state.store.is_postgres() {
        let n = state.store.requeue_abandoned_races().await?;
        if n > 0 {
            tracing::info!("requeued {n} race(s) interrupted by the previous shutdown");
        }
    }
    let owner = format!("{}-{}-race", crate::queue::owner_host(), std::process::id());
    // Races record no build fingerprint: they do not wait for the canary.
    tokio::spawn(async move {
        loop {
            let notified = state.signal.race_notified();
            match state
                .store
                .claim_race(&owner, state.cfg.lease_seconds)
                .await
            {
                Ok(Some(row)) => {
                    let id = row.id;
                    if let Err(e) = run(&state, &runner, &owner, row).await {
                        tracing::warn!("race {id}: {e}");
                        let _ = state.store.race_failed(id, &e).await;
                    }
                }
                Ok(None) => {
                    // Also poll: an expired lease becomes runnable unannounced.
                    let _ = tokio::time::timeout(std::time::Duration::from_secs(2), notified).await;
                }
                Err(e) => {
                    tracing::error!("race slot: cannot claim a race: {e}");
                    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
                }
            }
        }
    });
    Ok(())
}

async fn run(
    state: &AppState,
    runner: &std::sync::Arc<dyn crate::queue::JobRunner>,
    owner: &str,
    row: RaceRow,
) -> Result<(), String> {
    let id = row.id;
    let job = job_of(state, &row).await?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<RaceLive>();
    let runner = runner.clone();
    let cancel = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop = cancel.clone();
    let mut run = tokio::task::spawn_blocking(move || {
        let mut live = RaceLive::default();
        runner.run_cancellable(
            &job,
            &mut |p| {
                if let Some(r) = &p.race {
                    live.add(r);
                    let _ = tx.send(live.clone());
                }
            },
            &stop,
        )
    });
    let lease = state.cfg.lease_seconds;
    let mut ticker =
        tokio::time::interval(std::time::Duration::from_secs((lease / 3).max(1) as u64));
    let report = loop {
        tokio::select! {
            res = &mut run => break res,
            Some(mut live) = rx.recv() => {
                // Only the newest state matters.
                while let Ok(newer) = rx.try_recv() {
                    live = newer;
                }
                write_live(state, id, &live).await;
            }
            _ = ticker.tick() => {
                // A lost lease: the race was cancelled (or taken over after
                // this slot stalled): its worker stops, its report is dropped.
                if let Ok(false) = state.store.race_heartbeat(id, owner, lease).await {
                    if !cancel.swap(true, std::sync::atomic::Ordering::Relaxed) {
                        tracing::info!("race {id}: lease lost (cancelled); stopping its worker");
                    }
                }
            }
        }
    };
    // The last pairs' states can arrive with the end of the run, and the
    // select above may take the end first: the newest one still waiting is
    // written before the report (a one-pair race had none written at all).
    let mut newest = None;
    while let Ok(newer) = rx.try_recv() {
        newest = Some(newer);
    }
    if let Some(live) = newest {
        write_live(state, id, &live).await;
    }
    let report = report.map_err(|e| format!("the race panicked: {e}"))?;
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        return Ok(());
    }
    match report.outcome {
        Ok(Evaluated::Race(r)) => {
            let j = serde_json::to_string(&r).map_err(|e| e.to_string())?;
            state
                .store
                .race_completed(id, &j)
                .await
                .map_err(|e| e.to_string())?;
            tracing::info!(
                "race {id} completed: {}",
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

/// Stores a race's live state (pairs so far, paired counts, e-value); a
/// failed write is logged and the race goes on.
async fn write_live(state: &AppState, id: i64, live: &RaceLive) {
    if let Ok(j) = serde_json::to_string(live) {
        if let Err(e) = state.store.race_live(id, &j).await {
            tracing::warn!("race {id}: live state not written: {e}");
        }
    }
}
