//! One run of the chaos bench: the service started on a fresh database, the
//! submission stream and (in the soak) the fault injector at once, a watcher
//! that notes when each submission ends, then the wait for every accepted
//! submission to end and a snapshot of what the service left behind.

use super::cluster::{Cluster, Fault, FaultKind, FRONT_ENDS};
use super::load::{self, Answer, Endpoint, Rng, Sent};
use super::Plan;
use anyhow::Context;
use d3il_protocol::EvalResult;
use d3il_server::ops::sqlx;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A submission row as the watcher saw it.
#[derive(Debug, Clone)]
pub struct Seen {
    pub status: String,
    /// When the watcher first saw it completed or failed.
    pub ended_at: Option<Instant>,
}

/// A submission row at the end.
#[derive(Debug, Clone)]
pub struct SubmissionEnd {
    pub id: i64,
    pub method: String,
    pub status: String,
    pub error_kind: Option<String>,
    pub error_message: Option<String>,
    pub onnx_path: Option<String>,
}

/// A job row (one shard) at the end.
#[derive(Debug, Clone)]
pub struct JobEnd {
    pub id: i64,
    pub submission_id: i64,
    pub state: String,
    pub attempts: i64,
    pub leased: bool,
    pub has_part: bool,
}

/// What one run did and left.
pub struct PhaseRun {
    pub name: &'static str,
    pub sent: Vec<Sent>,
    pub faults: Vec<Fault>,
    pub seen: HashMap<i64, Seen>,
    pub submissions: Vec<SubmissionEnd>,
    pub jobs: Vec<JobEnd>,
    /// Submissions with a results row, and their count of rollout rows.
    pub results: Vec<i64>,
    pub rollouts: HashMap<i64, i64>,
    /// Methods no submission (nor a result the paper reported) refers to.
    pub lone_methods: Vec<String>,
    /// Files in the policy directory.
    pub files: Vec<String>,
    pub policies_dir: PathBuf,
    /// Job ids started more than once (taken over or retried).
    pub reruns: usize,
    /// Per job id, attempts that ended with the worker killed from outside.
    pub outside_kills: HashMap<i64, usize>,
    /// The stored results of completed submissions.
    pub stored: HashMap<i64, EvalResult>,
    /// Members that had exited on their own by the end.
    pub exited: Vec<String>,
}

const TERMINAL: [&str; 2] = ["completed", "failed"];
/// The status the watcher gives a row it saw before and no longer finds.
pub const VANISHED: &str = "gone from the database";

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?)
}

async fn pool(url: &str) -> anyhow::Result<sqlx::PgPool> {
    Ok(sqlx::postgres::PgPoolOptions::new()
        .max_connections(2)
        .acquire_timeout(Duration::from_secs(3))
        .connect(url)
        .await?)
}

/// Runs one phase in `dir`: `faults` says whether the injector runs.
pub fn phase(
    dir: &Path,
    plan: &Plan,
    faults: bool,
    endpoint: &Endpoint,
) -> anyhow::Result<PhaseRun> {
    let name = if faults { "chaos" } else { "quiet" };
    let cluster = Cluster::start(dir)?;
    let n = if faults {
        plan.submissions
    } else {
        plan.quiet_submissions
    };
    let seen: Mutex<HashMap<i64, Seen>> = Mutex::default();
    let sent: Mutex<Vec<Sent>> = Mutex::default();
    let injected: Mutex<Vec<Fault>> = Mutex::default();
    let accepted: load::Accepted = Mutex::default();
    let (stream_done, stop) = (AtomicBool::new(false), AtomicBool::new(false));
    let mut rng = Rng::new(if faults { 0xC4A05 } else { 0x0_9E7 });
    let mut fault_rng = Rng::new(0xFA17);
    let fault_error: Mutex<Option<anyhow::Error>> = Mutex::default();
    std::thread::scope(|s| {
        s.spawn(|| watch(&cluster.url, &seen, &stop));
        if faults {
            s.spawn(|| {
                while !(stream_done.load(Ordering::SeqCst) && lock(&injected).len() >= plan.faults)
                {
                    std::thread::sleep(fault_rng.around(plan.fault_every));
                    let kind = FaultKind::ALL[fault_rng.below(FaultKind::ALL.len())];
                    match cluster.inject(kind, &mut |n| fault_rng.below(n)) {
                        Ok(Some(f)) => {
                            eprintln!("fault {}: killed {}", lock(&injected).len() + 1, f.what);
                            lock(&injected).push(f);
                        }
                        Ok(None) => {}
                        Err(e) => {
                            *lock(&fault_error) = Some(e);
                            break;
                        }
                    }
                }
            });
        }
        // Requests arrive on their own clock (each on a thread of its
        // own), whatever the service is doing.
        std::thread::scope(|r| {
            for i in 0..n {
                let (kind, seed) = load::choose(&mut rng, plan.endless);
                let front = rng.below(FRONT_ENDS);
                let (cluster, sent, accepted) = (&cluster, &sent, &accepted);
                r.spawn(move || {
                    let one =
                        load::send(cluster, name, i, kind, seed, front, &endpoint.url, accepted);
                    lock(sent).push(one);
                });
                std::thread::sleep(rng.around(plan.submit_every));
            }
        });
        stream_done.store(true, Ordering::SeqCst);
        eprintln!("{name}: {n} submissions sent; waiting for the faults and the evaluations");
        // The injector ends once it reached its count.
        while faults && lock(&injected).len() < plan.faults && lock(&fault_error).is_none() {
            std::thread::sleep(Duration::from_millis(200));
        }
        settle(&cluster, plan, &sent, &seen, &injected, faults);
        stop.store(true, Ordering::SeqCst);
    });
    if let Some(e) = lock(&fault_error).take() {
        return Err(e.context("the fault injector could not restart what it killed"));
    }
    let mut run = snapshot(&cluster, name)?;
    run.sent = std::mem::take(&mut *lock(&sent));
    run.sent.sort_by_key(|s| s.n);
    run.faults = std::mem::take(&mut *lock(&injected));
    run.seen = std::mem::take(&mut *lock(&seen));
    let unanswered: Vec<&str> = run
        .sent
        .iter()
        .filter_map(|s| match &s.answer {
            Answer::Unanswered(why) => Some(why.as_str()),
            _ => None,
        })
        .collect();
    if !unanswered.is_empty() {
        eprintln!(
            "{name}: {} request(s) broke after they were sent, e.g.: {}",
            unanswered.len(),
            unanswered[0]
        );
    }
    Ok(run)
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Waits (at most `plan.settle` after the faults ended) until every
/// acknowledged submission is in the database and every row has ended.
fn settle(
    cluster: &Cluster,
    plan: &Plan,
    sent: &Mutex<Vec<Sent>>,
    seen: &Mutex<HashMap<i64, Seen>>,
    injected: &Mutex<Vec<Fault>>,
    faults: bool,
) {
    let deadline = Instant::now() + plan.settle;
    let mut last_report = Instant::now();
    loop {
        let (ids, open): (Vec<i64>, usize) = {
            let seen = lock(seen);
            let open = seen
                .values()
                .filter(|s| !TERMINAL.contains(&s.status.as_str()) && s.status != VANISHED)
                .count();
            (seen.keys().copied().collect(), open)
        };
        let missing = lock(sent)
            .iter()
            .filter(|s| matches!(s.answer, Answer::Accepted(id) if !ids.contains(&id)))
            .count();
        if open == 0 && missing == 0 {
            return;
        }
        if Instant::now() > deadline {
            eprintln!("gave up waiting: {open} submission(s) still open, {missing} acknowledged but not seen");
            return;
        }
        if last_report.elapsed() > Duration::from_secs(20) {
            eprintln!(
                "waiting for {open} submission(s) to end ({} faults so far; {:?})",
                if faults { lock(injected).len() } else { 0 },
                cluster.all_running()
            );
            last_report = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(250));
    }
}

/// Notes each submission's status every 250 ms until `stop`; a query that
/// fails (the database is down) is simply tried again.
fn watch(url: &str, seen: &Mutex<HashMap<i64, Seen>>, stop: &AtomicBool) {
    let Ok(rt) = runtime() else { return };
    rt.block_on(async {
        let mut db = None;
        while !stop.load(Ordering::SeqCst) {
            if db.is_none() {
                db = pool(url).await.ok();
            }
            if let Some(p) = &db {
                let rows: Result<Vec<(i64, String)>, _> =
                    sqlx::query_as("SELECT id, status FROM submissions")
                        .fetch_all(p)
                        .await;
                let now = Instant::now();
                let Ok(rows) = rows else {
                    tokio::time::sleep(Duration::from_millis(250)).await;
                    continue;
                };
                // A row seen before and gone now was lost (a commit the
                // database did not keep): it will not end.
                {
                    let ids: std::collections::HashSet<i64> = rows.iter().map(|r| r.0).collect();
                    for (id, e) in lock(seen).iter_mut() {
                        if !ids.contains(id) {
                            e.status = VANISHED.to_string();
                        }
                    }
                }
                for (id, status) in rows {
                    let mut seen = lock(seen);
                    let e = seen.entry(id).or_insert(Seen {
                        status: String::new(),
                        ended_at: None,
                    });
                    if e.ended_at.is_none() && TERMINAL.contains(&status.as_str()) {
                        e.ended_at = Some(now);
                    }
                    e.status = status;
                }
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
    });
}

/// Everything the service left in its database and policy directory.
fn snapshot(cluster: &Cluster, name: &'static str) -> anyhow::Result<PhaseRun> {
    let rt = runtime()?;
    let url = cluster.url.clone();
    let policies_dir = cluster.store.join("policies");
    let reruns = {
        let mut started: HashMap<i64, usize> = HashMap::new();
        for id in cluster.started_jobs() {
            *started.entry(id).or_default() += 1;
        }
        started.values().filter(|&&n| n > 1).count()
    };
    let exited = cluster.all_running();
    let (submissions, jobs, results, rollouts, lone_methods, stored) = rt.block_on(async {
        let db = pool(&url).await?;
        type SubmissionTuple = (i64, String, String, Option<String>, Option<String>, Option<String>);
        let submissions: Vec<SubmissionTuple> = sqlx::query_as(
            "SELECT s.id, m.name AS method, s.status, s.error_kind, s.error_message, s.onnx_path \
             FROM submissions s JOIN methods m ON m.id = s.method_id ORDER BY s.id",
        )
        .fetch_all(&db)
        .await?;
        let submissions: Vec<SubmissionEnd> = submissions
            .into_iter()
            .map(
                |(id, method, status, error_kind, error_message, onnx_path)| SubmissionEnd {
                    id,
                    method,
                    status,
                    error_kind,
                    error_message,
                    onnx_path,
                },
            )
            .collect();
        let jobs: Vec<(i64, i64, String, i64, bool, bool)> = sqlx::query_as(
            "SELECT id, submission_id, state, attempts, lease_owner IS NOT NULL AS leased, \
             part_json IS NOT NULL AS has_part FROM jobs ORDER BY id",
        )
        .fetch_all(&db)
        .await?;
        let jobs: Vec<JobEnd> = jobs
            .into_iter()
            .map(
                |(id, submission_id, state, attempts, leased, has_part)| JobEnd {
                    id,
                    submission_id,
                    state,
                    attempts,
                    leased,
                    has_part,
                },
            )
            .collect();
        let results: Vec<i64> = sqlx::query_scalar("SELECT submission_id FROM results")
            .fetch_all(&db)
            .await?;
        let rollouts: Vec<(i64, i64)> =
            sqlx::query_as("SELECT submission_id, COUNT(*) FROM rollouts GROUP BY submission_id")
                .fetch_all(&db)
                .await?;
        let lone: Vec<String> = sqlx::query_scalar(
            "SELECT name FROM methods m WHERE NOT EXISTS (SELECT 1 FROM submissions s WHERE s.method_id = m.id) \
             AND NOT EXISTS (SELECT 1 FROM reported_results r WHERE r.method_id = m.id)",
        )
        .fetch_all(&db)
        .await?;
        let store = d3il_server::ops::Store::connect(
            &d3il_server::ops::DbTarget::Postgres(url.clone()),
            Some(&cluster.store),
        )
        .await?;
        let mut stored = HashMap::new();
        for s in submissions.iter().filter(|s| s.status == "completed") {
            if let Some(r) = store.eval_result(s.id).await? {
                stored.insert(s.id, r);
            }
        }
        anyhow::Ok((
            submissions,
            jobs,
            results,
            rollouts.into_iter().collect(),
            lone,
            stored,
        ))
    })?;
    let mut files: Vec<String> = std::fs::read_dir(&policies_dir)
        .with_context(|| format!("listing {}", policies_dir.display()))?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    Ok(PhaseRun {
        name,
        sent: vec![],
        faults: vec![],
        seen: HashMap::new(),
        submissions,
        jobs,
        results,
        rollouts,
        lone_methods,
        files,
        policies_dir,
        reruns,
        outside_kills: cluster.outside_kills(),
        stored,
        exited,
    })
}
