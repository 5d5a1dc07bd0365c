//! PostgreSQL: a repeatable-read, read-only transaction exports its
//! snapshot; the inventory is read in it and `pg_dump --snapshot` dumps
//! exactly that state (custom format), so counts and dump agree while the
//! front ends and worker hosts keep writing. `pg_restore` loads it.

use super::{inventory, BackupError, Inventory, PG_TABLES};
use sqlx::postgres::PgPoolOptions;
use sqlx::Connection;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The PostgreSQL client program `name`: `$D3IL_PG_BIN/<name>`, else the
/// one on `PATH`, else Debian's newest `/usr/lib/postgresql/<v>/bin/<name>`.
fn tool(name: &str) -> Result<PathBuf, BackupError> {
    if let Some(dir) = std::env::var_os("D3IL_PG_BIN") {
        return Ok(Path::new(&dir).join(name));
    }
    let on_path = std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join(name))
        .find(|p| p.is_file());
    if let Some(p) = on_path {
        return Ok(p);
    }
    let mut debian: Vec<(u32, PathBuf)> = std::fs::read_dir("/usr/lib/postgresql")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let v = e.file_name().to_string_lossy().parse::<u32>().ok()?;
            let p = e.path().join("bin").join(name);
            p.is_file().then_some((v, p))
        })
        .collect();
    debian.sort();
    debian.pop().map(|(_, p)| p).ok_or_else(|| {
        BackupError::Refused(format!(
            "{name} not found (not on PATH, not in /usr/lib/postgresql/*/bin): install the PostgreSQL \
             client of the server's version (Debian: postgresql-client) or set D3IL_PG_BIN to its bin directory"
        ))
    })
}

fn run(cmd: &mut Command, what: &str) -> Result<(), BackupError> {
    let out = cmd
        .output()
        .map_err(|e| BackupError::Refused(format!("cannot run {what}: {e}")))?;
    if !out.status.success() {
        return Err(BackupError::Refused(format!(
            "{what} failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    Ok(())
}

/// Dumps the database at `url` into `dest` and reads what the dump holds.
pub(super) async fn dump(url: &str, dest: &Path) -> Result<(PathBuf, Inventory), BackupError> {
    let mut conn = sqlx::PgConnection::connect(url).await?;
    let mut tx = conn.begin().await?;
    sqlx::query("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ, READ ONLY")
        .execute(&mut *tx)
        .await?;
    let snapshot: String = sqlx::query_scalar("SELECT pg_export_snapshot()")
        .fetch_one(&mut *tx)
        .await?;
    let inv = inventory!(tx, PG_TABLES);
    let pg_dump = tool("pg_dump")?;
    let dest_owned = dest.to_path_buf();
    let url_owned = url.to_string();
    // The snapshot lives as long as the transaction: pg_dump runs while it is open.
    tokio::task::spawn_blocking(move || {
        run(
            Command::new(pg_dump)
                .args(["--format=custom", "--no-owner", "--no-privileges"])
                .arg(format!("--snapshot={snapshot}"))
                .arg("--file")
                .arg(&dest_owned)
                .arg(format!("--dbname={url_owned}")),
            "pg_dump",
        )
    })
    .await
    .map_err(|e| BackupError::Refused(format!("pg_dump did not finish: {e}")))??;
    tx.commit().await?;
    conn.close().await?;
    Ok((dest.to_path_buf(), inv))
}

/// Loads the dump `src` into the database at `url`: an empty one (no
/// tables) unless `force` (then what is there is dropped and replaced).
pub(super) async fn restore(src: &Path, url: &str, force: bool) -> Result<super::Db, BackupError> {
    let pool = PgPoolOptions::new().max_connections(2).connect(url).await?;
    let tables: i64 =
        sqlx::query_scalar("SELECT COUNT(*) FROM pg_tables WHERE schemaname = 'public'")
            .fetch_one(&pool)
            .await?;
    if tables > 0 && !force {
        return Err(BackupError::Refused(format!(
            "the database {} already has {tables} table(s); restore into a new, empty database \
             (createdb NAME), or add --force to replace its contents (stop every front end and worker host first)",
            crate::store::DbTarget::Postgres(url.to_string())
        )));
    }
    let pg_restore = tool("pg_restore")?;
    let mut cmd = Command::new(pg_restore);
    cmd.args([
        "--no-owner",
        "--no-privileges",
        "--exit-on-error",
        "--single-transaction",
    ]);
    if tables > 0 {
        cmd.args(["--clean", "--if-exists"]);
    }
    cmd.arg(format!("--dbname={url}")).arg(src);
    tokio::task::spawn_blocking(move || run(&mut cmd, "pg_restore"))
        .await
        .map_err(|e| BackupError::Refused(format!("pg_restore did not finish: {e}")))??;
    Ok(super::Db::Postgres(pool))
}
