//! `d3il db backup` and `d3il db restore`: one archive
//! (a gzipped tar) holding a consistent copy of the database, taken while the
//! server serves (SQLite: `VACUUM INTO`, a read transaction; PostgreSQL:
//! `pg_dump` on a snapshot exported from a repeatable-read transaction), the
//! policy files the copied rows refer to, and `manifest.json` saying what it
//! holds: row counts per table and the schema version *of that moment*, and
//! the size and sha256 of every file.
//!
//! Caches in the data directory (rendered videos, fidelity reports) are not
//! backed up: they are made again on demand.
//!
//! Restore goes into an empty database and an empty policy directory (unless
//! forced), checks every file against the manifest before writing anything,
//! points the restored submissions at the new policy directory and compares
//! the restored row counts with the manifest's.

mod archive;
pub mod check;
mod postgres;
mod sqlite;

pub use archive::{Manifest, PolicyFile, FORMAT};

use crate::store::{Db, DbTarget, MIGRATOR, MIGRATOR_PG};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum BackupError {
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    #[error("cannot use {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// What was asked cannot be done as asked; the message says what to change.
    #[error("{0}")]
    Refused(String),
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BackupError + '_ {
    move |source| BackupError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What a consistent view of the database holds (read inside one snapshot).
#[derive(Debug, Clone, Default)]
pub struct Inventory {
    /// The latest migration applied (0: none).
    pub schema_version: i64,
    /// Rows per table (every table, `_sqlx_migrations` included).
    pub tables: BTreeMap<String, i64>,
    /// Every distinct `submissions.onnx_path` with its sha256 and whether a
    /// submission that has not failed uses it (only such files must exist:
    /// a failed submission's file is deleted once unused).
    pub policy_paths: Vec<PolicyPath>,
}

#[derive(Debug, Clone)]
pub struct PolicyPath {
    pub path: String,
    pub sha256: Option<String>,
    pub live: bool,
}

/// Every table's name, in the SQL of either backend.
const SQLITE_TABLES: &str =
    "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%' ORDER BY name";
const PG_TABLES: &str =
    "SELECT CAST(tablename AS TEXT) FROM pg_tables WHERE schemaname = 'public' ORDER BY tablename";
const POLICY_PATHS: &str = "SELECT onnx_path, MAX(onnx_sha256), \
     MAX(CASE WHEN status != 'failed' THEN 1 ELSE 0 END) \
     FROM submissions WHERE onnx_path IS NOT NULL GROUP BY onnx_path ORDER BY onnx_path";
const SCHEMA_VERSION: &str =
    "SELECT CAST(COALESCE(MAX(version), 0) AS BIGINT) FROM _sqlx_migrations WHERE success";

/// Reads the [`Inventory`] through one executor (a transaction or a
/// connection that sees one snapshot).
macro_rules! inventory {
    ($conn:expr, $tables_sql:expr) => {{
        let names: Vec<String> = sqlx::query_scalar($tables_sql)
            .fetch_all(&mut *$conn)
            .await?;
        let mut inv = $crate::backup::Inventory::default();
        for name in names {
            let n: i64 = sqlx::query_scalar(sqlx::AssertSqlSafe(format!(
                "SELECT COUNT(*) FROM \"{name}\""
            )))
            .fetch_one(&mut *$conn)
            .await?;
            inv.tables.insert(name, n);
        }
        if inv.tables.contains_key("_sqlx_migrations") {
            inv.schema_version = sqlx::query_scalar($crate::backup::SCHEMA_VERSION)
                .fetch_one(&mut *$conn)
                .await?;
        }
        if inv.tables.contains_key("submissions") {
            let rows: Vec<(String, Option<String>, i32)> =
                sqlx::query_as($crate::backup::POLICY_PATHS)
                    .fetch_all(&mut *$conn)
                    .await?;
            inv.policy_paths = rows
                .into_iter()
                .map(|(path, sha256, live)| $crate::backup::PolicyPath {
                    path,
                    sha256,
                    live: live != 0,
                })
                .collect();
        }
        inv
    }};
}
pub(crate) use inventory;

/// The newest migration this binary knows for the backend.
pub fn latest_known(postgres: bool) -> i64 {
    let m = if postgres { &MIGRATOR_PG } else { &MIGRATOR };
    m.iter().map(|m| m.version).max().unwrap_or(0)
}

/// Opens the database `target` names as it is: never created, never
/// migrated (backup, restore and check look at what is there).
pub async fn open_existing(target: &DbTarget) -> Result<Db, BackupError> {
    match target {
        DbTarget::Sqlite(path) => {
            if !path.is_file() {
                return Err(BackupError::Refused(format!(
                    "--db {}: no such database file; give the path `d3il serve --db` uses",
                    path.display()
                )));
            }
            Ok(Db::Sqlite(sqlite::pool(path, false).await?))
        }
        DbTarget::Postgres(url) => Ok(Db::Postgres(
            sqlx::postgres::PgPoolOptions::new()
                .max_connections(2)
                .acquire_timeout(std::time::Duration::from_secs(10))
                .connect(url)
                .await?,
        )),
    }
}

/// The policy directory of a store: `--policy-store DIR` (its `policies/`),
/// required with PostgreSQL; with SQLite by default `<db stem>-data/`, as
/// the server uses.
pub fn data_dir(target: &DbTarget, policy_store: Option<&Path>) -> Result<PathBuf, BackupError> {
    let dir = match (target, policy_store) {
        (_, Some(dir)) => dir.to_path_buf(),
        (DbTarget::Sqlite(path), None) => crate::store::sqlite_data_dir(path),
        (DbTarget::Postgres(_), None) => {
            return Err(BackupError::Refused(format!(
                "--db {target}: a PostgreSQL store keeps its policy files in a shared directory; \
                 add --policy-store DIR (the one `d3il serve` uses)"
            )))
        }
    };
    std::path::absolute(&dir).map_err(io_err(&dir))
}

/// What [`backup`] wrote.
#[derive(Debug)]
pub struct BackupSummary {
    pub manifest: Manifest,
    pub out: PathBuf,
}

/// Writes the archive `out` of the store at `target` (policy files in
/// `policy_store`, see [`data_dir`]) while it may be serving.
pub async fn backup(
    target: &DbTarget,
    policy_store: Option<&Path>,
    out: &Path,
) -> Result<BackupSummary, BackupError> {
    let data_dir = data_dir(target, policy_store)?;
    let work = archive::WorkDir::next_to(out)?;
    let (db_file, inv) = match target {
        DbTarget::Sqlite(path) => {
            sqlite::snapshot(path, &work.path().join(archive::SQLITE_DB)).await?
        }
        DbTarget::Postgres(url) => postgres::dump(url, &work.path().join(archive::PG_DUMP)).await?,
    };
    let manifest = archive::write(out, &work, &db_file, &inv, target.is_postgres(), &data_dir)?;
    Ok(BackupSummary {
        manifest,
        out: out.to_path_buf(),
    })
}

/// Restores the archive `input` into the store at `target` (policy files
/// into `policy_store`, see [`data_dir`]). Both must be empty unless
/// `force`. Returns the archive's manifest once the restored rows and files
/// match it.
pub async fn restore(
    input: &Path,
    target: &DbTarget,
    policy_store: Option<&Path>,
    force: bool,
) -> Result<Manifest, BackupError> {
    let data_dir = data_dir(target, policy_store)?;
    let work_base = match target {
        DbTarget::Sqlite(path) => path.clone(),
        DbTarget::Postgres(_) => data_dir.join("restore"),
    };
    if let Some(parent) = work_base.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    let work = archive::WorkDir::next_to(&work_base)?;
    let manifest = archive::unpack_and_verify(input, &work)?;
    if manifest.postgres != target.is_postgres() {
        return Err(BackupError::Refused(format!(
            "{} holds a {} database and --db {target} is {}; restore into the same kind of database",
            input.display(),
            backend_name(manifest.postgres),
            backend_name(target.is_postgres()),
        )));
    }
    let known = latest_known(manifest.postgres);
    if manifest.schema_version > known {
        return Err(BackupError::Refused(format!(
            "{} was made at schema version {} and this d3il knows only up to {known}: restore it with \
             the d3il release that made it (d3il {})",
            input.display(),
            manifest.schema_version,
            manifest.d3il_version
        )));
    }
    let policies = data_dir.join("policies");
    archive::check_policy_dir_empty(&policies, force)?;
    let db_file = work.path().join(manifest.database.path.as_str());
    let db = match target {
        DbTarget::Sqlite(path) => sqlite::restore(&db_file, path, force).await?,
        DbTarget::Postgres(url) => postgres::restore(&db_file, url, force).await?,
    };
    if let Err(refused) = check_policy_paths(&db, &manifest.source_policies_dir, input).await {
        undo_restore(db, target).await?;
        return Err(refused);
    }
    let relocated = archive::place_policy_files(&work, &manifest, &policies)?;
    repoint_policy_paths(&db, &manifest.source_policies_dir, &policies).await?;
    let inv = match &db {
        Db::Sqlite(pool) => {
            let mut c = pool.acquire().await?;
            inventory!(c, SQLITE_TABLES)
        }
        Db::Postgres(pool) => {
            let mut c = pool.acquire().await?;
            inventory!(c, PG_TABLES)
        }
    };
    let mut differ = vec![];
    for (table, n) in &manifest.tables {
        let got = inv.tables.get(table).copied();
        if got != Some(*n) {
            differ.push(format!(
                "{table}: {n} in the archive, {} restored",
                got.map_or("none".to_string(), |g| g.to_string())
            ));
        }
    }
    if !differ.is_empty() {
        return Err(BackupError::Refused(format!(
            "the restored database does not match the archive's manifest ({}); the archive or the \
             target is damaged: restore again into an empty database",
            differ.join("; ")
        )));
    }
    tracing::info!(
        "restored {relocated} policy file(s) into {}",
        policies.display()
    );
    Ok(manifest)
}

fn backend_name(postgres: bool) -> &'static str {
    if postgres {
        "PostgreSQL"
    } else {
        "SQLite"
    }
}

/// The name of the file `path` names directly in the directory `dir`, or
/// None when it names anything else (another directory, `..`, the directory
/// itself). Paths are compared as written: a store's rows hold absolute paths.
fn file_in(path: &Path, dir: &Path) -> Option<std::path::PathBuf> {
    let rest = path.strip_prefix(dir).ok()?;
    let mut parts = rest.components();
    match (parts.next(), parts.next()) {
        (Some(std::path::Component::Normal(name)), None) => Some(name.into()),
        _ => None,
    }
}

/// Refuses a restored database in which a submission's `onnx_path` is not a
/// file directly in the backed-up store's policy directory (`source`): the
/// archive holds only that directory's files, so such a row would point the
/// restored store at a file of this host that no backup put there, which the
/// worker would read as the policy and the store could delete. The message
/// names the rows and what to do.
async fn check_policy_paths(db: &Db, source: &str, input: &Path) -> Result<(), BackupError> {
    let source_dir = Path::new(source);
    let rows: Vec<(i64, String)> = crate::on_db!(db, pool => sqlx::query_as(
        "SELECT id, onnx_path FROM submissions WHERE onnx_path IS NOT NULL ORDER BY id")
        .fetch_all(pool).await?);
    let outside: Vec<String> = rows
        .iter()
        .filter(|(_, path)| file_in(Path::new(path), source_dir).is_none())
        .map(|(id, path)| format!("submission {id} (`{path}`)"))
        .collect();
    if outside.is_empty() {
        return Ok(());
    }
    const SHOWN: usize = 20;
    let more = match outside.len().saturating_sub(SHOWN) {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    Err(BackupError::Refused(format!(
        "{} has {} submission(s) whose policy file is not in the backed-up store's policy directory {source}: \
         {}{more}. The archive holds only that directory's files, so the restored store would read (and \
         could delete) whatever those paths name on this host; nothing was restored. Fix the store that was \
         backed up: move each file into {source} as <sha256>.onnx, set the submission's onnx_path to it \
         (`d3il db check` lists what is still wrong), and take a new backup",
        input.display(),
        outside.len(),
        outside.iter().take(SHOWN).cloned().collect::<Vec<_>>().join(", "),
    )))
}

/// Takes back a database restore that was refused after it was loaded: the
/// SQLite file (and its -wal and -shm) is removed, a PostgreSQL database's
/// tables are dropped, so the target is empty as restore found it (or, with
/// --force, as empty as the replaced contents left it).
async fn undo_restore(db: Db, target: &DbTarget) -> Result<(), BackupError> {
    match (db, target) {
        (Db::Sqlite(pool), DbTarget::Sqlite(path)) => {
            pool.close().await;
            for suffix in ["", "-wal", "-shm"] {
                let mut p = path.as_os_str().to_owned();
                p.push(suffix);
                let p = PathBuf::from(p);
                if p.exists() {
                    std::fs::remove_file(&p).map_err(io_err(&p))?;
                }
            }
        }
        (Db::Postgres(pool), _) => {
            // Restore's own test of an empty database: no tables.
            let tables: Vec<String> = sqlx::query_scalar(PG_TABLES).fetch_all(&pool).await?;
            for t in tables {
                sqlx::query(sqlx::AssertSqlSafe(format!(
                    "DROP TABLE IF EXISTS \"{t}\" CASCADE"
                )))
                .execute(&pool)
                .await?;
            }
            pool.close().await;
        }
        (Db::Sqlite(_), DbTarget::Postgres(_)) => {
            return Err(BackupError::Refused(
                "internal error: a SQLite pool for a PostgreSQL target".into(),
            ))
        }
    }
    Ok(())
}

/// Points every submission whose file lived in the backed-up store's
/// policy directory at the same file name in `policies` (after
/// [`check_policy_paths`], that is every submission with a file).
async fn repoint_policy_paths(db: &Db, old: &str, policies: &Path) -> Result<(), BackupError> {
    let old_dir = Path::new(old);
    let paths: Vec<String> = crate::on_db!(db, pool => sqlx::query_scalar(
        "SELECT DISTINCT onnx_path FROM submissions WHERE onnx_path IS NOT NULL")
        .fetch_all(pool).await?);
    for path in paths {
        let Some(name) = file_in(Path::new(&path), old_dir) else {
            continue;
        };
        let new = policies.join(name).to_string_lossy().into_owned();
        crate::on_db!(db, pool => sqlx::query("UPDATE submissions SET onnx_path = $1 WHERE onnx_path = $2")
            .bind(&new).bind(&path).execute(pool).await.map(|_| ())?);
    }
    Ok(())
}
