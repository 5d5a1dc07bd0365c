//! What `d3il serve` can be told, and where the assets are.

use crate::queue::WorkerProcess;
use d3il_protocol::Limits;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Everything `d3il serve` can be told.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    /// SQLite file (created if missing) or PostgreSQL URL.
    pub db: crate::store::DbTarget,
    /// Where uploaded policies live (`Store::connect`); needed with PostgreSQL.
    pub policy_store: Option<PathBuf>,
    pub bind: SocketAddr,
    /// A second listener serving `/metrics`, `/healthz` and `/readyz`
    /// without credentials (a private address); None: none.
    pub metrics_bind: Option<SocketAddr>,
    /// Worker slots (concurrent evaluations).
    pub workers: usize,
    /// The project's assets (MJCF, initial-state sets, CSS).
    pub assets_dir: PathBuf,
    /// Largest accepted request body (ONNX upload plus form fields).
    pub max_upload_bytes: usize,
    /// Authenticated API requests per token per minute.
    pub rate_limit_per_minute: u32,
    /// Requests without a token per client address per minute.
    pub anonymous_rate_limit_per_minute: u32,
    /// Failed token checks per client address per minute; past it the
    /// address gets 429 until the minute is over.
    pub failed_auth_per_minute: u32,
    /// Bytes of policy files one submitter may keep on disk (None: no cap).
    pub max_disk_bytes_per_submitter: Option<u64>,
    /// Uploads streaming at once; more wait before their body is read.
    pub max_concurrent_uploads: usize,
    /// Attempts per job before the submission fails (crashes, lost leases).
    pub max_attempts: i64,
    /// Shards a paper-protocol job is split into (whole initial states each,
    /// at most the protocol's number); 1: not split. Shards run on any worker
    /// slot or host and are merged when all are done.
    pub shards: usize,
    /// Uploaded models run a short sandboxed dry run before they are queued
    /// (`intake::dry_run`); off, a model that cannot run fails at its
    /// evaluation instead.
    pub dry_run_uploads: bool,
    pub lease_seconds: i64,
    /// Limits handed to every worker.
    pub limits: Limits,
    /// The worker command (`d3il worker`).
    pub worker: WorkerProcess,
    /// Connection hygiene.
    pub connections: ConnectionLimits,
    /// Rollout videos, rendered on demand by `d3il replay`.
    pub videos: VideoConfig,
    /// The fidelity report of `/fidelity`, made by `d3il fidelity`.
    pub fidelity: crate::fidelity::FidelityConfig,
    /// The drift canary run at start (`d3il verify`).
    pub canary: crate::canary::CanaryConfig,
    /// Submission quotas per submitter (`crate::quota`).
    pub quotas: QuotaLimits,
    /// The zoo loaded at every start (`crate::zoo`): `d3il serve`
    /// loads `<assets>/zoo` unless told `--zoo none`; servers built in code
    /// (tests) load none unless asked.
    pub zoo: Option<PathBuf>,
}

/// How rollout videos are made: the `d3il` binary replays the stored record
/// (`d3il replay --result DOC --rollout N --video OUT`) in a process of its
/// own, never the server itself, in a pool apart from the evaluation workers
/// so that viewers never take an evaluation's slot.
#[derive(Debug, Clone)]
pub struct VideoConfig {
    /// The executable (default: the worker executable, i.e. this `d3il`).
    pub exe: PathBuf,
    /// Arguments before `--result …` (default `replay`).
    pub args: Vec<String>,
    /// Renders running at once (default 1).
    pub renders: usize,
    /// Distinct videos that may wait for a render slot; past it a request is
    /// answered 503 with `Retry-After`.
    pub max_waiting: usize,
    /// A render taking longer is stopped and reported.
    pub timeout: Duration,
    /// Where rendered videos are kept (default: `videos/` in the store's
    /// data directory, next to the policies).
    pub dir: Option<PathBuf>,
}

impl VideoConfig {
    pub fn new(exe: PathBuf) -> Self {
        VideoConfig {
            exe,
            args: vec!["replay".into()],
            renders: 1,
            max_waiting: 16,
            timeout: Duration::from_secs(600),
            dir: None,
        }
    }
}

/// How long a connection may take and how many may be open.
#[derive(Debug, Clone)]
pub struct ConnectionLimits {
    /// A request's header must arrive within this time, and an idle
    /// keep-alive connection is closed after it; then the connection closes.
    pub header_read_timeout: Duration,
    /// Open connections of the whole server; past it new ones are closed at once.
    pub max_connections: usize,
    /// Open connections from one client address (a trusted proxy's are not
    /// capped: it carries many clients).
    pub max_connections_per_client: usize,
    /// Reverse proxies whose `X-Forwarded-For` names the client
    /// (`--trusted-proxy`; `crate::client_addr`); empty: the header is ignored.
    pub trusted_proxies: crate::client_addr::TrustedProxies,
    /// How long in all a request body left unread by an early answer is
    /// read on (`crate::linger`), however it trickles in.
    pub linger_deadline: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ConnectionLimits {
            header_read_timeout: Duration::from_secs(20),
            max_connections: 2048,
            max_connections_per_client: 128,
            trusted_proxies: Default::default(),
            linger_deadline: Duration::from_secs(60),
        }
    }
}

impl ServerConfig {
    /// Defaults with the given database, bind address and worker executable.
    pub fn new(
        db: impl Into<crate::store::DbTarget>,
        bind: SocketAddr,
        worker_exe: PathBuf,
    ) -> Self {
        let limits = Limits::default();
        ServerConfig {
            db: db.into(),
            policy_store: None,
            bind,
            metrics_bind: None,
            workers: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            assets_dir: default_assets_dir(),
            max_upload_bytes: 256 << 20,
            rate_limit_per_minute: 60,
            anonymous_rate_limit_per_minute: 1200,
            failed_auth_per_minute: 20,
            max_disk_bytes_per_submitter: Some(4096 << 20),
            max_concurrent_uploads: 4,
            max_attempts: 3,
            shards: 1,
            dry_run_uploads: true,
            lease_seconds: 30,
            videos: VideoConfig::new(worker_exe.clone()),
            fidelity: crate::fidelity::FidelityConfig::new(worker_exe.clone()),
            canary: crate::canary::CanaryConfig::new(worker_exe.clone()),
            worker: WorkerProcess {
                exe: worker_exe,
                args: vec!["worker".into()],
                wall_clock: Duration::from_secs(limits.wall_seconds + 30),
                max_output_bytes: d3il_sandbox::DEFAULT_MAX_OUTPUT_BYTES,
            },
            limits,
            connections: ConnectionLimits::default(),
            quotas: QuotaLimits::NONE,
            zoo: None,
        }
    }
}

/// `$D3IL_ASSETS`; else the repository's `assets/` as seen at compile time if
/// it is still there; else `assets/` next to the executable (a copied or
/// installed binary shipped with its assets); else `./assets`.
pub fn default_assets_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("D3IL_ASSETS") {
        return PathBuf::from(dir);
    }
    let built = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets"));
    if built.is_dir() {
        return built;
    }
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|d| d.join("assets")))
        .filter(|d| d.is_dir())
        .unwrap_or_else(|| PathBuf::from("assets"))
}

/// A server's quota for each submitter, in evaluations (a plain submission
/// is one, a robustness suite its level 0 and every level, a race the two
/// evaluations it may run); 0 is no limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QuotaLimits {
    pub per_day: i64,
    pub total: i64,
    pub concurrent: i64,
    /// Races queued or running at once per submitter (not overridable).
    pub races: i64,
}

impl QuotaLimits {
    /// `d3il serve`'s defaults (its `--quota-*` flags).
    /// Enough for a suite of the largest (18 evaluations) at once, two a day.
    pub const SERVE_DEFAULT: QuotaLimits = QuotaLimits {
        per_day: 40,
        total: 2000,
        concurrent: 20,
        races: 2,
    };
    /// No quota (the library default, for embedded and test servers).
    pub const NONE: QuotaLimits = QuotaLimits {
        per_day: 0,
        total: 0,
        concurrent: 0,
        races: 0,
    };

    /// These limits with a submitter's overrides in place.
    pub fn with(self, o: crate::store::QuotaOverrides) -> QuotaLimits {
        QuotaLimits {
            per_day: o.per_day.unwrap_or(self.per_day),
            total: o.total.unwrap_or(self.total),
            concurrent: o.concurrent.unwrap_or(self.concurrent),
            races: self.races,
        }
    }
}
