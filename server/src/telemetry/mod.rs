//! What an operator watches: the Prometheus metrics of
//! `/metrics` and the readiness of `/readyz` ([`readiness`]).
//!
//! Counters and histograms are counted where their events happen, once: the
//! worker pool ([`crate::queue`]) counts jobs started, finished and failed,
//! evaluation durations and lost leases; the HTTP layer counts requests by
//! route template and status; the intake counts upload bytes; the video pool
//! ([`crate::videos`]) its renders and cache hits; the result cache
//! ([`crate::cache`]) its hits; the rate limiters ([`crate::ratelimit`])
//! their refusals. Those components hold clones of the counters made here
//! (a counter is a shared atomic), so one registry encodes them all. What
//! the database knows (queue depth by state, expired leases, worker hosts
//! connected) is read when `/metrics` is scraped.
//!
//! The exposition is the OpenMetrics text format, which Prometheus scrapes
//! natively; names are documented in docs/ops.md.

pub mod presence;
pub mod readiness;

use crate::canary::Canary;
use crate::store::Store;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use std::sync::Arc;

/// A label set: (name, value) pairs.
pub type Labels = Vec<(&'static str, String)>;

/// Upper bounds (seconds) of the evaluation-duration buckets: a quick
/// smoke test takes seconds to a minute, a paper-protocol run up to hours.
pub const DURATION_BUCKETS: [f64; 14] = [
    1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1200.0, 1800.0, 3600.0, 7200.0, 14400.0,
];

fn duration_histogram() -> Histogram {
    Histogram::new(DURATION_BUCKETS)
}

/// The counters of the worker pool, cloned into [`crate::queue::PoolConfig`].
#[derive(Clone, Debug)]
pub struct PoolMetrics {
    /// Jobs (shards count one each) handed to a worker, by task and protocol.
    pub jobs_started: Family<Labels, Counter>,
    /// Jobs whose result (or shard part) was written, by task and protocol.
    pub jobs_finished: Family<Labels, Counter>,
    /// Failed attempts, by reason (the worker's error kind) and whether the
    /// job was requeued for another attempt.
    pub jobs_failed: Family<Labels, Counter>,
    /// Wall time of each finished job, by task and protocol.
    pub evaluation_seconds: Family<Labels, Histogram, fn() -> Histogram>,
    /// Leases this process lost while it ran their job (they expired and the
    /// job was requeued or taken over), plus leases of a previous run that
    /// were requeued at start (SQLite).
    pub leases_lost: Counter,
    /// Worker slots of this process whose loop runs.
    pub slots_alive: Gauge,
}

impl PoolMetrics {
    /// Zero series for every task and protocol and every failure reason, so
    /// that each family is in `/metrics` (and `rate()` starts from 0) before
    /// its first event.
    fn precreate(&self) {
        use d3il_protocol::{ErrorKind as E, ProtocolKind, TaskId};
        for task in TaskId::ALL {
            for protocol in [ProtocolKind::Paper, ProtocolKind::Quick] {
                let kind = labels_of(&[("task", task.slug()), ("protocol", protocol.as_str())]);
                let _ = self.jobs_started.get_or_create(&kind);
                let _ = self.jobs_finished.get_or_create(&kind);
                let _ = self.evaluation_seconds.get_or_create(&kind);
            }
        }
        for kind in [
            E::BadJob,
            E::BadModel,
            E::BadAction,
            E::Remote,
            E::BadEndpoint,
            E::MemoryLimit,
            E::CpuLimit,
            E::WallClock,
            E::Crashed,
            E::ProtocolViolation,
            E::Internal,
        ] {
            if let Some(reason) = serde_json::to_value(kind)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
            {
                let _ = self.jobs_failed.get_or_create(&labels_of(&[
                    ("reason", reason.as_str()),
                    ("requeued", "false"),
                ]));
            }
        }
    }
}

impl Default for PoolMetrics {
    fn default() -> Self {
        PoolMetrics {
            jobs_started: Family::default(),
            jobs_finished: Family::default(),
            jobs_failed: Family::default(),
            evaluation_seconds: Family::new_with_constructor(duration_histogram),
            leases_lost: Counter::default(),
            slots_alive: Gauge::default(),
        }
    }
}

/// The registry and every metric `/metrics` shows, with what readiness and
/// the scrape-time gauges read.
pub struct Telemetry {
    registry: Registry,
    pub store: Store,
    pub canary: Arc<Canary>,
    /// Worker slots configured on this process (0: a front end only).
    pub configured_slots: usize,
    pub pool: PoolMetrics,
    /// Requests by method, route template and status.
    pub http_requests: Family<Labels, Counter>,
    /// Bytes of uploaded policy files received.
    pub upload_bytes: Counter,
    /// Requests refused by a rate limit, by limit (token, anonymous,
    /// failed_auth).
    pub rate_limit_refusals: Family<Labels, Counter>,
    /// Video renders by outcome (ok, failed).
    pub video_renders: Family<Labels, Counter>,
    /// Videos served from the cache without a render.
    pub video_cache_hits: Counter,
    /// Lookups of the finished-results cache, by outcome (hit, miss).
    pub results_cache: Family<Labels, Counter>,
    // Read from the database at scrape time.
    queue_jobs: Family<Labels, Gauge>,
    leases_expired: Gauge,
    worker_hosts: Gauge,
    database_up: Gauge,
    ready: Gauge,
}

impl Telemetry {
    pub fn new(store: Store, canary: Arc<Canary>, configured_slots: usize) -> Telemetry {
        let mut t = Telemetry {
            registry: Registry::default(),
            store,
            canary,
            configured_slots,
            pool: PoolMetrics::default(),
            http_requests: Family::default(),
            upload_bytes: Counter::default(),
            rate_limit_refusals: Family::default(),
            video_renders: Family::default(),
            video_cache_hits: Counter::default(),
            results_cache: Family::default(),
            queue_jobs: Family::default(),
            leases_expired: Gauge::default(),
            worker_hosts: Gauge::default(),
            database_up: Gauge::default(),
            ready: Gauge::default(),
        };
        t.pool.precreate();
        let r = &mut t.registry;
        let p = &t.pool;
        r.register(
            "d3il_jobs_started",
            "Jobs handed to a worker (a shard counts one), by task and protocol",
            p.jobs_started.clone(),
        );
        r.register(
            "d3il_jobs_finished",
            "Jobs whose result or shard part was written, by task and protocol",
            p.jobs_finished.clone(),
        );
        r.register(
            "d3il_jobs_failed",
            "Failed job attempts, by reason (worker error kind) and whether the job was requeued",
            p.jobs_failed.clone(),
        );
        r.register(
            "d3il_evaluation_duration_seconds",
            "Wall time of finished jobs, by task and protocol",
            p.evaluation_seconds.clone(),
        );
        r.register(
            "d3il_leases_lost",
            "Leases this process lost while running their job, and leases of a previous run requeued at start",
            p.leases_lost.clone(),
        );
        r.register(
            "d3il_worker_slots_alive",
            "Worker slots of this process whose loop runs",
            p.slots_alive.clone(),
        );
        r.register(
            "d3il_http_requests",
            "HTTP requests by method, route template and status",
            t.http_requests.clone(),
        );
        r.register(
            "d3il_upload_bytes",
            "Bytes of uploaded policy files received",
            t.upload_bytes.clone(),
        );
        r.register(
            "d3il_rate_limit_refusals",
            "Requests refused by a rate limit, and connections cut by a connection limit, by limit \
             (token, anonymous, failed_auth; connections, client_connections, linger_deadline)",
            t.rate_limit_refusals.clone(),
        );
        r.register(
            "d3il_video_renders",
            "Rollout video renders (d3il replay processes), by outcome",
            t.video_renders.clone(),
        );
        r.register(
            "d3il_video_cache_hits",
            "Rollout videos served from the cache without a render",
            t.video_cache_hits.clone(),
        );
        r.register(
            "d3il_results_cache_lookups",
            "Lookups of the finished-results cache, by outcome (hit, miss)",
            t.results_cache.clone(),
        );
        r.register(
            "d3il_queue_jobs",
            "Job rows by state (queued, leased, done, failed), read at scrape time",
            t.queue_jobs.clone(),
        );
        r.register(
            "d3il_leases_expired",
            "Leased jobs whose lease has expired and that no slot has taken over yet",
            t.leases_expired.clone(),
        );
        r.register(
            "d3il_worker_hosts_alive",
            "Worker hosts (d3il workers) connected to the PostgreSQL queue",
            t.worker_hosts.clone(),
        );
        r.register(
            "d3il_database_up",
            "1 when the database answered at this scrape",
            t.database_up.clone(),
        );
        r.register(
            "d3il_ready",
            "1 when /readyz would answer 200",
            t.ready.clone(),
        );
        t
    }

    /// A counter of one label set: components keep it and count into it.
    pub fn counter(family: &Family<Labels, Counter>, labels: &[(&'static str, &str)]) -> Counter {
        family.get_or_create_owned(&labels_of(labels))
    }

    /// Reads the database's gauges and readiness, then encodes everything.
    pub async fn scrape(&self) -> String {
        let report = self.readiness().await;
        self.ready.set(i64::from(report.ready));
        let mut out = String::new();
        if let Err(e) = prometheus_client::encoding::text::encode(&mut out, &self.registry) {
            tracing::error!("encoding metrics: {e}");
        }
        out
    }

    /// What `/readyz` answers; also refreshes the database gauges.
    pub async fn readiness(&self) -> readiness::Report {
        let db = self.database_state().await;
        self.database_up.set(i64::from(db.is_ok()));
        let hosts = db.as_ref().map(|s| s.worker_hosts).unwrap_or(0);
        readiness::Report::from_parts(readiness::Parts {
            database: db.as_ref().map(|_| ()).map_err(Clone::clone),
            canary: self.canary.state(),
            configured_slots: self.configured_slots,
            slots_alive: self.pool.slots_alive.get().max(0) as usize,
            worker_hosts: hosts,
        })
    }

    async fn database_state(&self) -> Result<DbState, String> {
        let t = crate::store::now();
        let read = async {
            let rows: Vec<(String, i64)> = crate::on_db!(self.store.db(), pool => sqlx::query_as(
                "SELECT state, CAST(COUNT(*) AS BIGINT) FROM jobs GROUP BY state",
            )
            .fetch_all(pool)
            .await)?;
            let (expired,): (i64,) = crate::on_db!(self.store.db(), pool => sqlx::query_as(
                "SELECT CAST(COUNT(*) AS BIGINT) FROM jobs WHERE state = 'leased' AND lease_expires_at < $1",
            )
            .bind(t)
            .fetch_one(pool)
            .await)?;
            let hosts = presence::hosts_connected(&self.store).await?;
            Ok::<_, sqlx::Error>((rows, expired, hosts))
        };
        let (rows, expired, hosts) =
            match tokio::time::timeout(std::time::Duration::from_secs(5), read).await {
                Err(_) => return Err("the database did not answer within 5 s".into()),
                Ok(Err(e)) => return Err(format!("the database did not answer: {e}")),
                Ok(Ok(v)) => v,
            };
        for state in ["queued", "leased", "done", "failed"] {
            let n = rows.iter().find(|(s, _)| s == state).map_or(0, |r| r.1);
            self.queue_jobs
                .get_or_create(&labels_of(&[("state", state)]))
                .set(n);
        }
        self.leases_expired.set(expired);
        self.worker_hosts.set(hosts);
        Ok(DbState {
            worker_hosts: hosts.max(0) as usize,
        })
    }
}

struct DbState {
    worker_hosts: usize,
}

pub fn labels_of(pairs: &[(&'static str, &str)]) -> Labels {
    pairs.iter().map(|(k, v)| (*k, v.to_string())).collect()
}

/// Counts a worker slot as alive while it lives (also when its task ends by
/// a panic: the guard is dropped on unwinding).
pub struct SlotAlive(Gauge);

impl SlotAlive {
    pub fn new(g: &Gauge) -> SlotAlive {
        g.inc();
        SlotAlive(g.clone())
    }
}

impl Drop for SlotAlive {
    fn drop(&mut self) {
        self.0.dec();
    }
}
