//! What `d3il serve` can be told, and where the assets are.

use crate::queue::WorkerProcess;
use d3il_protocol::Limits;
use std::net::SocketAddr;
use std::path::PathBuf;
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
