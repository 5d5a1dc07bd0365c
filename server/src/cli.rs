//! Blocking entry points for the `d3il` binary (which has no async runtime).

use crate::app::{serve, ServeError, ServerConfig};
use crate::store::{DbTarget, Revoked, Store, StoreError};
use std::path::{Path, PathBuf};

fn runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
}

/// Logs go to stderr; stdout carries the lines tests and scripts read.
fn log_to_stderr() {
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(tracing::Level::INFO)
        .try_init();
}

/// Runs the server until the process is stopped. Prints one line
/// `listening on http://ADDR` (tests read the port from it).
pub fn serve_blocking(cfg: ServerConfig) -> Result<(), ServeError> {
    log_to_stderr();
    let rt = runtime()?;
    rt.block_on(async move {
        let runner = crate::app::default_runner(&cfg);
        let (db, workers) = (cfg.db.clone(), cfg.workers);
        serve(cfg, runner, |r| {
            println!("listening on http://{}", r.addr);
            if let Some(m) = r.metrics_addr {
                println!("metrics on http://{m}/metrics");
            }
            println!("database {db} · {workers} worker slot(s)");
        })
        .await
    })
}

/// Runs a worker host (`d3il workers`) until the process is stopped. Prints
/// one line `worker host ready: …` once its pool runs (tests wait for it).
pub fn workers_blocking(cfg: ServerConfig) -> Result<(), ServeError> {
    log_to_stderr();
    let rt = runtime()?;
    rt.block_on(async move {
        let runner = crate::app::default_runner(&cfg);
        let (db, workers) = (cfg.db.clone(), cfg.workers);
        crate::app::run_workers(cfg, runner, |_, metrics| {
            if let Some(m) = metrics {
                println!("metrics on http://{m}/metrics");
            }
            println!(
                "worker host ready: {workers} worker slot(s) (plus one for quick jobs) on {db}"
            );
        })
        .await
    })
}

/// Mints an API token for `name` in the database at `db` (`admin`: it may
/// also see `/admin`).
pub fn create_token_blocking(
    db: &DbTarget,
    policy_store: Option<&Path>,
    name: &str,
    admin: bool,
) -> Result<String, StoreError> {
    let rt = runtime().map_err(|source| StoreError::Io {
        path: PathBuf::from(db.to_string()),
        source,
    })?;
    rt.block_on(async {
        let store = Store::connect(db, policy_store).await?;
        store.create_token_with(name, admin).await
    })
}

/// Revokes a token (the whole token or its printed prefix) in `db`.
pub fn revoke_token_blocking(
    db: &DbTarget,
    policy_store: Option<&Path>,
    token_or_prefix: &str,
) -> Result<Revoked, StoreError> {
    let rt = runtime().map_err(|source| StoreError::Io {
        path: PathBuf::from(db.to_string()),
        source,
    })?;
    rt.block_on(async {
        let store = Store::connect(db, policy_store).await?;
        // The audit entry is written with the revocation (one transaction).
        store.revoke_token(token_or_prefix, &cli_actor()).await
    })
}

/// Who the audit log names for an action of the `d3il` command on the
/// database: `cli:<login>` ($USER, else `cli:unknown`).
pub fn cli_actor() -> String {
    let user = std::env::var("USER")
        .ok()
        .filter(|u| !u.is_empty())
        .unwrap_or_else(|| "unknown".into());
    format!("cli:{user}")
}

/// Sets submitter `name`'s quota overrides in `db` (`d3il token
/// set-quota`), written to the audit log.
pub fn set_quota_blocking(
    db: &DbTarget,
    policy_store: Option<&Path>,
    name: &str,
    q: crate::store::QuotaOverrides,
) -> Result<crate::store::AuditEntry, StoreError> {
    let rt = runtime().map_err(|source| StoreError::Io {
        path: PathBuf::from(db.to_string()),
        source,
    })?;
    rt.block_on(async {
        let store = Store::connect(db, policy_store).await?;
        store.set_quota(name, q, &cli_actor()).await
    })
}
