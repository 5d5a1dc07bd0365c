//! The worker pool: N slots (plus one for quick smoke tests) lease jobs from
//! the durable queue in the database,
//! run them through a [`JobRunner`] (a sandboxed `d3il worker` process in
//! production), heartbeat while they run and write the result idempotently.

use crate::store::{ClaimedJob, PolicyKind, Store, StoreError};
use d3il_protocol::{
    ErrorKind, Evaluated, Job, JobKind, Limits, PolicyManifest, PolicySource, ProtocolKind,
    SandboxMechanism, SuiteName, WorkerError,
};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, Notify};

/// What one run of a job produced.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// A whole result, or the part of the shard the job asked for.
    pub outcome: Result<Evaluated, WorkerError>,
    /// Confinement mechanisms that were in force (shown on the submission page).
    pub mechanisms: Vec<SandboxMechanism>,
}

/// Runs one job to completion. Blocking: the pool calls it on a blocking thread.
pub trait JobRunner: Send + Sync + 'static {
    fn run(&self, job: &Job, on_progress: &mut dyn FnMut(usize, usize)) -> RunReport;

    /// [`JobRunner::run`] that stops the run soon after `cancel` becomes true
    /// (the evaluation was cancelled). Runners that cannot stop a
    /// run let it finish; its report is then ignored.
    /// Its `on_progress` gets every progress report whole, with the initial
    /// states newly finished in the evaluation's random order.
    fn run_cancellable(
        &self,
        job: &Job,
        on_progress: &mut dyn FnMut(&d3il_protocol::Progress),
        _cancel: &std::sync::atomic::AtomicBool,
    ) -> RunReport {
        self.run(job, &mut |done, total| {
            on_progress(&d3il_protocol::Progress::counts(done, total))
        })
    }

    /// The sandbox mechanisms a job would run under on this host (and the
    /// probes that they hold), for the admin page. Blocking.
    fn check_sandbox(
        &self,
        _assets_dir: &std::path::Path,
    ) -> Result<Vec<SandboxMechanism>, String> {
        Err("this job runner does not run jobs in a sandbox".into())
    }
}

/// How to start a worker process.
#[derive(Debug, Clone)]
pub struct WorkerProcess {
    pub exe: PathBuf,
    pub args: Vec<String>,
    pub wall_clock: Duration,
    pub max_output_bytes: usize,
}

/// Pool settings.
#[derive(Debug, Clone)]
pub struct PoolConfig {
    pub workers: usize,
    /// Lease length; heartbeats renew it every third of it.
    pub lease_seconds: i64,
    pub assets_dir: PathBuf,
    pub limits: Limits,
    /// The build identity results record; the pool waits for its canary.
    pub canary: Arc<crate::canary::Canary>,
    /// Where the pool counts its jobs (`/metrics`).
    pub metrics: crate::telemetry::PoolMetrics,
}

/// Failures worth another attempt: the process died or our side broke, or the
/// remote endpoint had a transient problem. Everything else is about the
/// policy and would fail the same way again.
pub fn is_retryable(kind: ErrorKind) -> bool {
    matches!(
        kind,
        ErrorKind::Crashed | ErrorKind::Internal | ErrorKind::Remote
    )
}

/// The policy a submission names and its manifest, as stored: what a job
/// (an evaluation, or one side of a race) runs.
pub fn policy_of(
    s: &crate::store::SubmissionRow,
) -> Result<(PolicySource, PolicyManifest), String> {
    let manifest: PolicyManifest = serde_json::from_value(s.manifest_json.0.clone())
        .map_err(|e| format!("stored manifest is invalid: {e}"))?;
    let policy = match s.policy_kind {
        PolicyKind::Onnx => PolicySource::Onnx {
            path: s
                .onnx_path
                .clone()
                .ok_or("onnx submission without a stored file")?,
            sha256: s
                .onnx_sha256
                .clone()
                .ok_or("onnx submission without a stored sha256")?,
        },
        PolicyKind::Remote => PolicySource::Remote {
            url: s
                .endpoint_url
                .clone()
                .ok_or("remote submission without a URL")?,
            secret: s.endpoint_secret.as_ref().map(|s| s.0.clone()),
        },
    };
    Ok((policy, manifest))
}

/// Builds the worker's job document from a claimed submission.
pub fn job_from_claim(
    c: &ClaimedJob,
    assets_dir: &std::path::Path,
    limits: &Limits,
    build: d3il_protocol::BuildIdentity,
) -> Result<Job, String> {
    let s = &c.submission;
    let (policy, manifest) = policy_of(s)?;
    // The store keeps the suite's name as text; a name this build does not
    // know fails the job with the message of `SuiteName::parse`.
    let suite = s.suite.as_deref().map(SuiteName::parse).transpose()?;
    Ok(Job {
        kind: JobKind::of(suite, c.job.shard()),
        job_id: c.job.id.to_string(),
        task: s.task,
        protocol: s.protocol,
        policy,
        manifest,
        // The evaluator seed is the training seed, so each seed's policy noise
        // is independent and every evaluation is reproducible.
        seed: s.training_seed.max(0) as u64,
        limits: limits.clone(),
        assets_dir: assets_dir.to_string_lossy().into_owned(),
        dry_run_steps: None,
        build: Some(build),
    })
}

/// Handle to wake the pool when a job was queued, and the race slot when a
/// race was.
#[derive(Clone, Default)]
pub struct QueueSignal(Arc<Notify>, Arc<Notify>);

impl QueueSignal {
    pub fn job_queued(&self) {
        self.0.notify_waiters();
    }

    pub fn race_queued(&self) {
        self.1.notify_waiters();
    }

    /// Completes at the next [`QueueSignal::race_queued`] after this call.
    pub fn race_notified(&self) -> tokio::sync::futures::Notified<'_> {
        self.1.notified()
    }
}

/// Requeues abandoned jobs (SQLite: the one server owns the file, so every
/// lease left is its own from before a restart; on PostgreSQL other hosts'
/// leases are live, and a dead host's lease expires instead), then starts
/// `cfg.workers` slots that take any job, oldest first, plus (when
/// `cfg.workers > 0`) one slot that takes only quick-protocol jobs.
pub async fn start_pool(
    store: Store,
    runner: Arc<dyn JobRunner>,
    cfg: PoolConfig,
    signal: QueueSignal,
) -> Result<(), StoreError> {
    if !store.is_postgres() {
        let n = store.requeue_abandoned().await?;
        if n > 0 {
            tracing::info!("requeued {n} job(s) interrupted by the previous shutdown");
            cfg.metrics.leases_lost.inc_by(n);
        }
    }
    let cfg = Arc::new(cfg);
    // Lease owners name the host and process, so hosts sharing a database
    // never hold a lease under the same name.
    let host = owner_host();
    for slot in 0..cfg.workers {
        let owner = format!("{host}-{}-slot{slot}", std::process::id());
        tokio::spawn(slot_loop(
            store.clone(),
            runner.clone(),
            cfg.clone(),
            signal.clone(),
            owner,
            None,
        ));
    }
    if cfg.workers > 0 {
        // One more slot for quick-protocol jobs only: a smoke test never
        // waits behind hour-long paper runs (the other slots take any job).
        tokio::spawn(slot_loop(
            store.clone(),
            runner.clone(),
            cfg.clone(),
            signal.clone(),
            format!("{host}-{}-quick", std::process::id()),
            Some(ProtocolKind::Quick),
        ));
    }
    Ok(())
}

/// This host's name (`/proc/sys/kernel/hostname`), for lease owners.
pub fn owner_host() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "host".into())
}

async fn slot_loop(
    store: Store,
    runner: Arc<dyn JobRunner>,
    cfg: Arc<PoolConfig>,
    signal: QueueSignal,
    owner: String,
    only: Option<ProtocolKind>,
) {
    let _alive = crate::telemetry::SlotAlive::new(&cfg.metrics.slots_alive);
    // Every result records the build's physics fingerprint: none is
    // evaluated before the drift canary has run.
    cfg.canary.ready().await;
    loop {
        let notified = signal.0.notified();
        match store.claim_job_of(&owner, cfg.lease_seconds, only).await {
            Ok(Some(c)) => {
                if let Err(e) = run_claimed(&store, &runner, &cfg, &owner, c).await {
                    tracing::error!("worker slot {owner}: {e}");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
            Ok(None) => {
                // Also poll: expired leases become runnable without a signal.
                let _ = tokio::time::timeout(Duration::from_secs(2), notified).await;
            }
            Err(e) => {
                tracing::error!("worker slot {owner}: cannot claim a job: {e}");
                tokio::time::sleep(Duration::from_secs(2)).await;
            }
        }
    }
}

async fn run_claimed(
    store: &Store,
    runner: &Arc<dyn JobRunner>,
    cfg: &PoolConfig,
    owner: &str,
    c: ClaimedJob,
) -> Result<(), StoreError> {
    let job_id = c.job.id;
    let submission_id = c.submission.id;
    let shard = c.job.shard();
    let m = &cfg.metrics;
    let kind = crate::telemetry::labels_of(&[
        ("task", c.submission.task.slug()),
        ("protocol", c.submission.protocol.as_str()),
    ]);
    let lease_lost = |r| lease_lost_is_a_warning(r, m);
    let job = match job_from_claim(&c, &cfg.assets_dir, &cfg.limits, cfg.canary.build()) {
        Ok(j) => j,
        Err(message) => {
            let err = WorkerError {
                kind: ErrorKind::BadJob,
                message,
            };
            let r = lease_lost(store.fail_attempt(job_id, owner, &err, false).await)?;
            count_failure(m, &err, r);
            return Ok(());
        }
    };
    tracing::info!(
        "job {job_id} (submission {submission_id}, attempt {}) started on {owner}",
        c.job.attempts
    );
    m.jobs_started.get_or_create(&kind).inc();
    let began = Instant::now();
    let (ptx, mut prx) = mpsc::unbounded_channel::<d3il_protocol::Progress>();
    let r = runner.clone();
    let cancel = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop = cancel.clone();
    let mut handle = tokio::task::spawn_blocking(move || {
        let mut cb = |p: &d3il_protocol::Progress| {
            let _ = ptx.send(p.clone());
        };
        r.run_cancellable(&job, &mut cb, &stop)
    });
    let beat = Duration::from_secs((cfg.lease_seconds / 3).max(1) as u64);
    let mut ticker = tokio::time::interval(beat);
    let mut latest: Option<(usize, usize)> = None;
    // The states reported so far, written with the heartbeats.
    let mut reported = crate::live::Reported::default();
    let mut last_written = Instant::now() - beat;
    let report = loop {
        tokio::select! {
            res = &mut handle => break res,
            Some(p) = prx.recv() => {
                latest = Some((p.rollouts_done, p.rollouts_total));
                reported.add(&p);
                // Progress is written at most once a second.
                if last_written.elapsed() >= Duration::from_secs(1) {
                    let held = beat_or_warn(store, job_id, owner, cfg.lease_seconds, latest).await;
                    reported.flush(store, job_id, owner).await;
                    stop_if_cancelled(store, held, submission_id, &cancel).await;
                    last_written = Instant::now();
                }
            }
            _ = ticker.tick() => {
                let held = beat_or_warn(store, job_id, owner, cfg.lease_seconds, latest).await;
                reported.flush(store, job_id, owner).await;
                stop_if_cancelled(store, held, submission_id, &cancel).await;
                last_written = Instant::now();
            }
        }
    };
    // The last states reported before the result, while the lease is held.
    while let Ok(p) = prx.try_recv() {
        reported.add(&p);
    }
    reported.flush(store, job_id, owner).await;
    let report = match report {
        Ok(r) => r,
        Err(e) => RunReport {
            outcome: Err(WorkerError {
                kind: ErrorKind::Internal,
                message: format!("the job runner panicked: {e}"),
            }),
            mechanisms: vec![],
        },
    };
    match report.outcome {
        Ok(Evaluated::Result(result)) if shard.is_none() => {
            store
                .complete_job(job_id, submission_id, &result, &report.mechanisms)
                .await?;
            count_finished(m, &kind, began);
            tracing::info!("job {job_id} completed");
        }
        Ok(Evaluated::Robustness(doc)) if shard.is_none() => {
            // The document first: once the submission is completed (level 0
            // stored as its plain result) its robustness is there too.
            store.save_robustness(submission_id, &doc).await?;
            store
                .complete_job(job_id, submission_id, &doc.control, &report.mechanisms)
                .await?;
            count_finished(m, &kind, began);
            tracing::info!("job {job_id} completed (robustness suite {})", doc.suite);
        }
        Ok(Evaluated::Part(part)) if shard == Some(part.shard) && c.submission.suite.is_none() => {
            let part = crate::store::ShardPart::Plain(&part);
            finish_shard(store, m, &kind, owner, &c, part, &report.mechanisms, began).await?;
        }
        Ok(Evaluated::SuitePart(part))
            if shard == Some(part.shard) && c.submission.suite.is_some() =>
        {
            // A robustness submission's shard: level 0 and every level on
            // its initial states; the last shard merges the document.
            let part = crate::store::ShardPart::Suite(&part);
            finish_shard(store, m, &kind, owner, &c, part, &report.mechanisms, began).await?;
        }
        Ok(_) => {
            let err = WorkerError {
                kind: ErrorKind::ProtocolViolation,
                message: match shard {
                    Some(s) => format!(
                        "the worker was asked for shard {s} and answered with something else"
                    ),
                    None => "the worker answered a whole evaluation with a shard's part".into(),
                },
            };
            let r = lease_lost(store.fail_attempt(job_id, owner, &err, false).await)?;
            count_failure(m, &err, r);
        }
        Err(err) => {
            let r = lease_lost(
                store
                    .fail_attempt(job_id, owner, &err, is_retryable(err.kind))
                    .await,
            )?;
            count_failure(m, &err, r);
            let Some(requeued) = r else {
                return Ok(());
            };
            tracing::warn!(
                "job {job_id} failed ({:?}: {}){}",
                err.kind,
                err.message,
                if requeued { "; requeued" } else { "" }
            );
        }
    }
    Ok(())
}

/// Stores a shard's part (the last one merges, `Store::complete_any_shard`).
#[allow(clippy::too_many_arguments)]
async fn finish_shard(
    store: &Store,
    m: &crate::telemetry::PoolMetrics,
    kind: &crate::telemetry::Labels,
    owner: &str,
    c: &ClaimedJob,
    part: crate::store::ShardPart<'_>,
    mechanisms: &[SandboxMechanism],
    began: Instant,
) -> Result<(), StoreError> {
    let (job_id, submission_id) = (c.job.id, c.submission.id);
    let Some(merged) = lease_lost_is_a_warning(
        store
            .complete_any_shard(job_id, owner, part, mechanisms)
            .await,
        m,
    )?
    else {
        return Ok(());
    };
    count_finished(m, kind, began);
    tracing::info!(
        "job {job_id} (shard {} of submission {submission_id}) completed{}",
        c.job.shard().map(|s| s.to_string()).unwrap_or_default(),
        if merged {
            "; all shards done, result merged"
        } else {
            ""
        }
    );
    Ok(())
}

/// A slot whose lease expired leaves the job to whoever holds it now.
fn lease_lost_is_a_warning(
    r: Result<bool, StoreError>,
    m: &crate::telemetry::PoolMetrics,
) -> Result<Option<bool>, StoreError> {
    match r {
        Ok(requeued) => Ok(Some(requeued)),
        Err(e @ StoreError::LeaseLost { .. }) => {
            tracing::warn!("{e}");
            m.leases_lost.inc();
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

/// A job's result (or shard part) was written: counted with its wall time.
fn count_finished(
    m: &crate::telemetry::PoolMetrics,
    kind: &crate::telemetry::Labels,
    began: Instant,
) {
    m.jobs_finished.get_or_create(kind).inc();
    m.evaluation_seconds
        .get_or_create(kind)
        .observe(began.elapsed().as_secs_f64());
}

/// A failed attempt recorded (`Some(requeued)`; `None`: the lease was lost,
/// counted as such).
fn count_failure(m: &crate::telemetry::PoolMetrics, err: &WorkerError, recorded: Option<bool>) {
    let Some(requeued) = recorded else { return };
    let reason = serde_json::to_value(err.kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| "internal".into());
    m.jobs_failed
        .get_or_create(&crate::telemetry::labels_of(&[
            ("reason", reason.as_str()),
            ("requeued", if requeued { "true" } else { "false" }),
        ]))
        .inc();
}

/// A heartbeat that fails (a busy or briefly unavailable database) must not
/// abandon the running worker: returning early would leave its process
/// running while the slot claims another job. The job goes on; if the lease
/// does expire meanwhile, the result write is idempotent.
/// Returns false when the lease is lost.
async fn beat_or_warn(
    store: &Store,
    job_id: i64,
    owner: &str,
    lease_seconds: i64,
    progress: Option<(usize, usize)>,
) -> bool {
    match store
        .heartbeat(job_id, owner, lease_seconds, progress)
        .await
    {
        Ok(true) => true,
        Ok(false) => {
            tracing::warn!("job {job_id}: lease lost; its result will be written idempotently");
            false
        }
        Err(e) => {
            tracing::warn!("job {job_id}: heartbeat not written ({e}); the job goes on");
            true
        }
    }
}

/// A lost lease may mean the evaluation was cancelled: then the
/// run is stopped (its report is ignored: the job is no longer leased).
async fn stop_if_cancelled(
    store: &Store,
    lease_held: bool,
    submission_id: i64,
    cancel: &std::sync::atomic::AtomicBool,
) {
    if lease_held || cancel.load(std::sync::atomic::Ordering::Relaxed) {
        return;
    }
    if let Ok(Some(c)) = store.cancelled(submission_id).await {
        tracing::info!(
            "submission {submission_id}: cancelled by {}; stopping its worker",
            c.by
        );
        cancel.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}
