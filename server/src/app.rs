//! Application state, configuration, the router and `serve`.

use crate::queue::{start_pool, JobRunner, PoolConfig, QueueSignal, WorkerProcess};
use crate::ratelimit::RateLimiter;
use crate::sandbox_status::SandboxStatus;
use crate::store::{Store, StoreError};
use axum::Router;
use d3il_protocol::Limits;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Everything `d3il serve` can be told.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    /// SQLite file (created if missing).
    pub db: PathBuf,
    pub bind: SocketAddr,
    /// Worker slots (concurrent evaluations).
    pub workers: usize,
    /// The project's assets (MJCF, initial-state sets, CSS).
    pub assets_dir: PathBuf,
    /// Largest accepted request body (ONNX upload plus form fields).
    pub max_upload_bytes: usize,
    /// Authenticated API requests per token per minute.
    pub rate_limit_per_minute: u32,
    /// Attempts per job before the submission fails (crashes, lost leases).
    pub max_attempts: i64,
    pub lease_seconds: i64,
    /// Limits handed to every worker.
    pub limits: Limits,
    /// The worker command (`d3il worker`).
    pub worker: WorkerProcess,
}

impl ServerConfig {
    /// Defaults with the given database, bind address and worker executable.
    pub fn new(db: PathBuf, bind: SocketAddr, worker_exe: PathBuf) -> Self {
        let limits = Limits::default();
        ServerConfig {
            db,
            bind,
            workers: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            assets_dir: default_assets_dir(),
            max_upload_bytes: 256 << 20,
            rate_limit_per_minute: 60,
            max_attempts: 3,
            lease_seconds: 30,
            worker: WorkerProcess {
                exe: worker_exe,
                args: vec!["worker".into()],
                wall_clock: Duration::from_secs(limits.wall_seconds + 30),
                max_output_bytes: d3il_sandbox::DEFAULT_MAX_OUTPUT_BYTES,
            },
            limits,
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

#[derive(Clone)]
pub struct AppState {
    pub store: Store,
    pub cfg: Arc<ServerConfig>,
    pub signal: QueueSignal,
    pub limiter: Arc<RateLimiter>,
    /// Used for endpoint conformance dry-runs.
    pub runner: Arc<dyn JobRunner>,
    /// The sandbox mechanisms in force (admin page).
    pub sandbox: Arc<SandboxStatus>,
}

pub fn router(state: AppState) -> Router {
    Router::new()
        .merge(crate::pages::router(state.cfg.max_upload_bytes))
        .merge(crate::plot_routes::router())
        .nest("/api/v1", crate::api::router(state.cfg.max_upload_bytes))
        .with_state(state)
}

/// The production job runner: the sandboxed worker process.
pub fn default_runner(cfg: &ServerConfig) -> Arc<dyn JobRunner> {
    crate::runner::production_runner(&cfg.worker)
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot listen on {addr}: {source}; pass a free address with --bind")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("server error: {0}")]
    Io(#[from] std::io::Error),
}

/// A running server (used by `d3il serve` and the tests).
pub struct Running {
    pub addr: SocketAddr,
    pub state: AppState,
}

/// Opens the store, starts the worker pool and serves until the process ends.
/// `on_ready` is called with the bound address (port 0 resolves here).
pub async fn serve(
    cfg: ServerConfig,
    runner: Arc<dyn JobRunner>,
    on_ready: impl FnOnce(&Running),
) -> Result<(), ServeError> {
    let (listener, running) = prepare(cfg, runner).await?;
    on_ready(&running);
    let app = router(running.state.clone());
    axum::serve(listener, app).await?;
    Ok(())
}

/// Everything `serve` does before accepting connections.
pub async fn prepare(
    cfg: ServerConfig,
    runner: Arc<dyn JobRunner>,
) -> Result<(tokio::net::TcpListener, Running), ServeError> {
    let store = Store::open(&cfg.db).await?;
    let listener = tokio::net::TcpListener::bind(cfg.bind)
        .await
        .map_err(|source| ServeError::Bind {
            addr: cfg.bind,
            source,
        })?;
    let addr = listener.local_addr()?;
    let signal = QueueSignal::default();
    start_pool(
        store.clone(),
        runner.clone(),
        PoolConfig {
            workers: cfg.workers,
            lease_seconds: cfg.lease_seconds,
            assets_dir: cfg.assets_dir.clone(),
            limits: cfg.limits.clone(),
        },
        signal.clone(),
    )
    .await?;
    let sandbox = Arc::new(SandboxStatus::new(runner.clone(), cfg.assets_dir.clone()));
    let state = AppState {
        sandbox,
        store,
        limiter: Arc::new(RateLimiter::new(cfg.rate_limit_per_minute)),
        cfg: Arc::new(cfg),
        signal,
        runner,
    };
    Ok((listener, Running { addr, state }))
}
