//! SQLite: the copy is `VACUUM INTO`, which reads the live database in one
//! read transaction (WAL: writers go on meanwhile) and writes a compact,
//! self-contained file; the inventory is read from that copy.

use super::{inventory, io_err, BackupError, Inventory, SQLITE_TABLES};
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions};
use sqlx::SqlitePool;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A pool on the file at `path` (created only if `create`), foreign keys on,
/// waiting for the server's writers rather than failing busy.
pub(super) async fn pool(path: &Path, create: bool) -> Result<SqlitePool, sqlx::Error> {
    let opts = SqliteConnectOptions::new()
        .filename(path)
        .create_if_missing(create)
        .journal_mode(SqliteJournalMode::Wal)
        .foreign_keys(true)
        .busy_timeout(Duration::from_secs(30));
    SqlitePoolOptions::new()
        .max_connections(1)
        .connect_with(opts)
        .await
}

/// Copies the database at `path` into `dest` and reads what the copy holds.
pub(super) async fn snapshot(
    path: &Path,
    dest: &Path,
) -> Result<(PathBuf, Inventory), BackupError> {
    let live = pool(path, false).await?;
    sqlx::query("VACUUM INTO $1")
        .bind(dest.to_string_lossy().into_owned())
        .execute(&live)
        .await?;
    live.close().await;
    let copy = pool(dest, false).await?;
    let inv = {
        let mut c = copy.acquire().await?;
        inventory!(c, SQLITE_TABLES)
    };
    // The copy goes into the archive as a single file (no -wal beside it).
    sqlx::query("PRAGMA journal_mode = DELETE")
        .execute(&copy)
        .await?;
    copy.close().await;
    Ok((dest.to_path_buf(), inv))
}

/// Puts the archived database file `src` at `target` (refusing an existing,
/// non-empty database unless `force`) and opens it.
pub(super) async fn restore(
    src: &Path,
    target: &Path,
    force: bool,
) -> Result<super::Db, BackupError> {
    let side = |suffix: &str| {
        let mut s = target.as_os_str().to_owned();
        s.push(suffix);
        PathBuf::from(s)
    };
    let non_empty = std::fs::metadata(target).is_ok_and(|m| m.len() > 0);
    if non_empty && !force {
        return Err(BackupError::Refused(format!(
            "--db {} already holds a database; restore into a new file, or add --force to replace it \
             (stop the server first)",
            target.display()
        )));
    }
    for p in [side("-wal"), side("-shm"), target.to_path_buf()] {
        if p.exists() {
            std::fs::remove_file(&p).map_err(io_err(&p))?;
        }
    }
    let tmp = side(".restoring");
    std::fs::copy(src, &tmp).map_err(io_err(&tmp))?;
    std::fs::File::open(&tmp)
        .and_then(|f| f.sync_all())
        .map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, target).map_err(io_err(target))?;
    Ok(super::Db::Sqlite(pool(target, false).await?))
}
