//! Blocking entry points for the `d3il` binary (which has no async runtime).

use crate::app::{serve, ServeError, ServerConfig};
use crate::store::{Store, StoreError};
use std::path::Path;

fn runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
}

/// Runs the server until the process is stopped. Prints one line
/// `listening on http://ADDR` (tests read the port from it).
pub fn serve_blocking(cfg: ServerConfig) -> Result<(), ServeError> {
    // Logs go to stderr; stdout carries the `listening on` line.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(tracing::Level::INFO)
        .try_init();
    let rt = runtime()?;
    rt.block_on(async move {
        let runner = crate::app::default_runner(&cfg);
        let (db, workers) = (cfg.db.clone(), cfg.workers);
        serve(cfg, runner, |r| {
            println!("listening on http://{}", r.addr);
            println!("database {} · {workers} worker slot(s)", db.display());
        })
        .await
    })
}

/// Mints an API token for `name` in the database at `db`.
pub fn create_token_blocking(db: &Path, name: &str) -> Result<String, StoreError> {
    let rt = runtime().map_err(|source| StoreError::Io {
        path: db.to_path_buf(),
        source,
    })?;
    rt.block_on(async {
        let store = Store::open(db).await?;
        store.create_token(name).await
    })
}
