//! The router and `serve`: opens the store, starts the worker pool, listens.

pub use crate::config::{default_assets_dir, ServerConfig};
use crate::queue::{start_pool, JobRunner, PoolConfig, QueueSignal};
use crate::ratelimit::RateLimiter;
use crate::sandbox_status::SandboxStatus;
pub use crate::state::AppState;
use crate::store::{Store, StoreError};
use axum::Router;
use std::net::SocketAddr;
use std::sync::Arc;

pub fn router(state: AppState) -> Router {
    Router::new()
        .merge(crate::http::router(state.cfg.max_upload_bytes))
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
