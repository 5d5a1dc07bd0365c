//! The store, on SQLite (the embedded default, a file) or PostgreSQL (shared
//! by several hosts, `--db postgres://…`): schema (migrations/sqlite and
//! migrations/postgres, kept in step), one module per resource: the
//! paper's reported results ([`paper`]), [`methods`], API [`tokens`],
//! [`submissions`], the durable job queue ([`jobs`]), evaluation
//! [`results`], [`races`] and the [`zoo`]'s cells. Column types are in [`types`]: states, statuses and kinds are
//! enums and JSON columns are `sqlx::types::Json`, so a row holding bad data
//! fails to decode (a `StoreError::Db` naming the column) rather than being
//! read as an empty value.
//!
//! Everything is plain runtime SQL (`query`/`query_as` + `FromRow`), so building
//! needs no database. Each query is written once, in the SQL both backends
//! understand (`$1` parameters, `CASE` instead of two-argument `MAX`, `CAST`
//! to `BIGINT`/`DOUBLE PRECISION`), and runs on either pool through
//! [`on_db!`]; the few statements that differ (row locks, JSON access) are
//! chosen by [`Store::is_postgres`].

/// Runs `$body` with `$pool` bound to the store's pool, whichever backend it
/// is: the body is compiled once per backend, so a query written once runs
/// on both. Exported for tests that write raw SQL (`Store::db`).
#[macro_export]
macro_rules! on_db {
    ($db:expr, $pool:ident => $body:expr) => {
        match $db {
            $crate::store::Db::Sqlite($pool) => $body,
            $crate::store::Db::Postgres($pool) => $body,
        }
    };
}

/// Begins a write transaction on `$pool` (inside [`on_db!`]): SQLite takes
/// the write lock at once (`BEGIN IMMEDIATE`), so a transaction that reads and
/// then writes waits on the busy timeout instead of failing with
/// SQLITE_BUSY; PostgreSQL begins normally and its statements lock rows.
macro_rules! begin_write {
    ($store:expr, $pool:ident) => {
        if $store.is_postgres() {
            $pool.begin().await?
        } else {
            $pool.begin_with("BEGIN IMMEDIATE").await?
        }
    };
}

/// `FromRow` for both backends' rows: each named field is read from the
/// column of its name (`field: Via` reads the column as `Via` and converts,
/// as `Stored<TaskId>` into `TaskId`, an error naming the column), and each
/// field after `flatten` is read from the same row by its own `FromRow`.
/// Written out rather than derived: sqlx's derive crate compiles both
/// database drivers, bundled SQLite included, a second time for the host.
macro_rules! from_row {
    ($name:ident { $($field:ident $(: $via:ty)?),* $(,)? } $(flatten { $($flat:ident),* $(,)? })?) => {
        from_row!(@impl sqlx::sqlite::SqliteRow, $name { $($field $(: $via)?),* } $({ $($flat),* })?);
        from_row!(@impl sqlx::postgres::PgRow, $name { $($field $(: $via)?),* } $({ $($flat),* })?);
    };
    (@impl $row:ty, $name:ident { $($field:ident $(: $via:ty)?),* } $({ $($flat:ident),* })?) => {
        impl<'r> sqlx::FromRow<'r, $row> for $name {
            fn from_row(row: &'r $row) -> Result<Self, sqlx::Error> {
                Ok($name {
                    $($field: from_row!(@get row, $field $(: $via)?),)*
                    $($($flat: sqlx::FromRow::from_row(row)?,)*)?
                })
            }
        }
    };
    (@get $row:ident, $field:ident) => {
        sqlx::Row::try_get($row, stringify!($field))?
    };
    (@get $row:ident, $field:ident : $via:ty) => {{
        let stored: $via = sqlx::Row::try_get($row, stringify!($field))?;
        stored.into()
    }};
}

mod files;
mod intervals;
#[macro_use]
mod jobs;
mod live;
mod methods;
mod moderation;
mod paper;
mod races;
mod results;
#[macro_use]
mod robustness;
mod shards;
mod submissions;
mod tokens;
pub mod types;
mod zoo;

pub use files::{PolicyFilesGuard, TMP_MARKER};
pub use jobs::{ClaimedJob, DurationClass, JobRow};
pub use live::{CancelOutcome, Cancelled, StateOutcome, CANCELLED_KIND};
pub use methods::{MethodRow, NewMethod};
pub use moderation::{
    AuditEntry, QuotaOverrides, QuotaUsage, QuotaWork, Withdrawal, WorkKind, DAY_S,
};
pub use races::{NewRace, RaceCancel, RaceRow};
pub use results::{IntervalNote, IntervalNotes, ResultRow, RolloutRow, SeedSummary};
pub use robustness::{summary_of, RobustnessRow};
pub use shards::ShardPart;
/// Re-exported so that callers reading the rows themselves (`d3il bench
/// chaos` checks what a run left behind) need no own dependency.
pub use sqlx;
pub use submissions::{
    NewPolicy, NewSubmission, SeedKey, SubmissionFilter, SubmissionRow, WithdrawnSubmission,
};
pub use tokens::{token_hash, Revoked, Submitter, LAST_USED_RESOLUTION_S, TOKEN_PREFIX_LEN};
pub use types::{JobState, PolicyKind, RaceStatus, StoredSecret, SubmissionStatus};
pub use zoo::{NewZooCell, ZooCellRow, ZooLoad, ZOO_SUBMITTER};

use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::postgres::PgPoolOptions;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::{PgPool, SqlStr, SqlitePool};
use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::LazyLock;
use std::time::Duration;

// (version, description, SQL) of every migration file, embedded by server/build.rs.
include!(concat!(env!("OUT_DIR"), "/migrations.rs"));

/// The SQLite schema's migrations (migrations/sqlite), embedded at compile time.
pub static MIGRATOR: LazyLock<Migrator> = LazyLock::new(|| migrator(SQLITE_MIGRATIONS));
/// The same schema for PostgreSQL (one file per SQLite migration).
pub static MIGRATOR_PG: LazyLock<Migrator> = LazyLock::new(|| migrator(POSTGRES_MIGRATIONS));

/// A migrator of embedded files, as sqlx's `migrate!` makes one: plain
/// (not reversible) migrations, checksummed over their SQL, in a transaction
/// unless the file starts with `-- no-transaction`.
fn migrator(files: &[(i64, &'static str, &'static str)]) -> Migrator {
    Migrator::with_migrations(
        files
            .iter()
            .map(|&(version, description, sql)| {
                Migration::new(
                    version,
                    Cow::Borrowed(description),
                    MigrationType::Simple,
                    SqlStr::from_static(sql),
                    sql.starts_with("-- no-transaction"),
                )
            })
            .collect(),
    )
}

/// The database a store lives in, as `--db` gives it: a PostgreSQL URL
/// (`postgres://…` or `postgresql://…`), else a SQLite file path (an optional
/// `sqlite://` prefix is accepted).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DbTarget {
    Sqlite(PathBuf),
    Postgres(String),
}

impl DbTarget {
    pub fn parse(s: &str) -> DbTarget {
        if s.starts_with("postgres://") || s.starts_with("postgresql://") {
            DbTarget::Postgres(s.to_string())
        } else {
            DbTarget::Sqlite(PathBuf::from(s.strip_prefix("sqlite://").unwrap_or(s)))
        }
    }

    pub fn is_postgres(&self) -> bool {
        matches!(self, DbTarget::Postgres(_))
    }
}

impl std::str::FromStr for DbTarget {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(DbTarget::parse(s))
    }
}

impl From<PathBuf> for DbTarget {
    fn from(p: PathBuf) -> Self {
        DbTarget::Sqlite(p)
    }
}

impl From<&Path> for DbTarget {
    fn from(p: &Path) -> Self {
        DbTarget::Sqlite(p.to_path_buf())
    }
}

/// Shown in logs and errors: a PostgreSQL URL without its password.
impl std::fmt::Display for DbTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DbTarget::Sqlite(p) => write!(f, "{}", p.display()),
            DbTarget::Postgres(url) => match url.parse::<url::Url>() {
                Ok(mut u) if u.password().is_some() => {
                    let _ = u.set_password(Some("***"));
                    write!(f, "{u}")
                }
                _ => f.write_str(url),
            },
        }
    }
}

/// The connection pool of either backend (see [`on_db!`]).
#[derive(Debug, Clone)]
pub enum Db {
    Sqlite(SqlitePool),
    Postgres(PgPool),
}

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    #[error("database migration failed: {0}; the database file may come from a newer version, use a fresh --db file")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("cannot use {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("stored data is corrupt: {0}")]
    Corrupt(String),
    /// The store cannot be opened as asked (e.g. PostgreSQL without a
    /// shared policy store).
    #[error("{0}")]
    Config(String),
    #[error("{0} not found")]
    NotFound(String),
    /// A uniqueness rule was violated (e.g. the same training seed twice).
    #[error("{0}")]
    Conflict(String),
    /// A worker slot reported on a job whose lease it no longer holds (the
    /// lease expired and the job was requeued or taken by another slot).
    /// Seed aggregation refused its input (never an empty group in practice).
    #[error("cannot aggregate training seeds: {0}")]
    Aggregate(#[from] d3il_metrics::MetricsError),
    #[error("job {job_id} is not leased to {owner}; its report is ignored")]
    LeaseLost { job_id: i64, owner: String },
}

impl StoreError {
    /// SQLite's write lock stayed taken past the busy timeout
    /// (`SQLITE_BUSY`, also `SQLITE_LOCKED`), or PostgreSQL gave up a
    /// transaction on a serialization failure or deadlock: worth a retry later.
    pub fn is_busy(&self) -> bool {
        match self {
            StoreError::Db(sqlx::Error::Database(d)) => {
                if d.try_downcast_ref::<sqlx::sqlite::SqliteError>().is_some() {
                    // Primary result codes 5 (BUSY) and 6 (LOCKED), with any extension.
                    let code = d.code().and_then(|c| c.parse::<i64>().ok()).unwrap_or(0);
                    matches!(code & 0xff, 5 | 6) || d.message().contains("database is locked")
                } else {
                    matches!(d.code().as_deref(), Some("40001" | "40P01"))
                }
            }
            _ => false,
        }
    }
}

/// Runs a write transaction again (up to three times in all) when SQLite
/// reports it busy, so a writer holding the lock a little past the busy
/// timeout delays a request instead of failing it.
pub(crate) async fn retry_busy<T, F, Fut>(mut f: F) -> Result<T, StoreError>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Result<T, StoreError>>,
{
    let mut tries = 0;
    loop {
        match f().await {
            Err(e) if e.is_busy() && tries < 2 => {
                tries += 1;
                tracing::warn!("database busy; retrying ({tries}/2)");
                tokio::time::sleep(Duration::from_millis(200 * tries)).await;
            }
            r => return r,
        }
    }
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub fn now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0)
}

#[derive(Debug, Clone)]
pub struct Store {
    db: Db,
    data_dir: PathBuf,
    /// Token id -> when this process last wrote (or started writing) its
    /// `last_used_at`: one write per token per minute, even while the
    /// database is locked and the previous write is still waiting.
    /// Held while a policy file is placed and its submission recorded, and
    /// while a file is checked for live submissions and deleted, so that a
    /// failed submission's release never deletes the file an identical
    /// upload is being recorded with.
    files: std::sync::Arc<tokio::sync::Mutex<()>>,
    last_used: std::sync::Arc<std::sync::Mutex<std::collections::HashMap<i64, i64>>>,
}

impl Store {
    /// Opens (creating if needed) the SQLite file at `path`, applies the
    /// migrations and loads the paper's reported results (idempotently).
    /// Uploaded policies live next to it in `<file stem>-data/`.
    pub async fn open(path: &Path) -> Result<Store, StoreError> {
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(io_err(parent))?;
        }
        let data_dir = policy_store_dir(&sqlite_data_dir(path))?;

        // FULL synchronous: an accepted submission must survive a power cut
        // once the response is sent ("durable before the response").
        let opts = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .foreign_keys(true)
            .busy_timeout(Duration::from_secs(10));
        let pool = SqlitePoolOptions::new()
            .max_connections(4)
            .connect_with(opts)
            .await?;
        MIGRATOR.run(&pool).await?;
        Store::ready(Db::Sqlite(pool), data_dir).await
    }

    /// Opens the store `--db` names. A SQLite file keeps its policies next to
    /// it unless `policy_store` is given; PostgreSQL, shared by several
    /// hosts, needs `policy_store`: a directory every host reads (uploaded
    /// policies live in its `policies/`).
    pub async fn connect(
        target: &DbTarget,
        policy_store: Option<&Path>,
    ) -> Result<Store, StoreError> {
        match target {
            DbTarget::Sqlite(path) => {
                let mut store = Store::open(path).await?;
                if let Some(dir) = policy_store {
                    store.data_dir = policy_store_dir(dir)?;
                }
                Ok(store)
            }
            DbTarget::Postgres(url) => {
                let dir = policy_store.ok_or_else(|| {
                    StoreError::Config(format!(
                        "--db {target} is shared by several hosts, so uploaded policies need a directory every \
                         host can read: add --policy-store DIR (the same shared directory on every host)"
                    ))
                })?;
                let data_dir = policy_store_dir(dir)?;
                let pool = PgPoolOptions::new()
                    .max_connections(8)
                    .acquire_timeout(Duration::from_secs(10))
                    .connect(url)
                    .await?;
                // Concurrent hosts starting together: the migrator takes an
                // advisory lock, so the schema is applied once.
                MIGRATOR_PG.run(&pool).await?;
                Store::ready(Db::Postgres(pool), data_dir).await
            }
        }
    }

    async fn ready(db: Db, data_dir: PathBuf) -> Result<Store, StoreError> {
        let store = Store {
            db,
            data_dir,
            last_used: Default::default(),
            files: Default::default(),
        };
        store
            .load_paper(&d3il_protocol::paper::load_embedded())
            .await?;
        Ok(store)
    }

    /// The connection pool of either backend (tests use it for raw SQL).
    pub fn db(&self) -> &Db {
        &self.db
    }

    /// The SQLite pool, for callers that only ever open a SQLite file.
    pub fn sqlite_pool(&self) -> Option<&SqlitePool> {
        match &self.db {
            Db::Sqlite(p) => Some(p),
            Db::Postgres(_) => None,
        }
    }

    /// Whether the store is PostgreSQL (shared by hosts) rather than a file
    /// one process owns.
    pub fn is_postgres(&self) -> bool {
        matches!(self.db, Db::Postgres(_))
    }

    pub fn data_dir(&self) -> &Path {
        &self.data_dir
    }
}

/// Where a SQLite store at `path` keeps uploaded policies unless
/// `--policy-store` says otherwise: `<file stem>-data/` next to it.
pub fn sqlite_data_dir(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "d3il".into());
    path.with_file_name(format!("{stem}-data"))
}

/// `dir` made absolute (the sandboxed worker is given paths inside it to
/// read) with its `policies/` created.
fn policy_store_dir(dir: &Path) -> Result<PathBuf, StoreError> {
    let abs = std::path::absolute(dir).map_err(io_err(dir))?;
    std::fs::create_dir_all(abs.join("policies")).map_err(io_err(&abs))?;
    Ok(abs)
}

/// JSON encoding of plain data (these types always serialise).
fn to_json<T: serde::Serialize + ?Sized>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "null".into())
}

#[cfg(test)]
mod migration_tests {
    use super::{MIGRATOR, MIGRATOR_PG};
    use sha2::{Digest, Sha384};
    use std::path::Path;

    /// The embedded migrations are what `sqlx::migrate!` embedded in earlier
    /// builds, so that a database they migrated opens here: every file of the
    /// directory in version order, its description the file name's rest with
    /// `_` read as a space, and its checksum the SHA-384 of its bytes (sqlx
    /// refuses a database whose applied checksums differ).
    #[test]
    fn embedded_migrations_are_the_files_as_sqlx_names_and_checksums_them() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../migrations");
        for (backend, migrator) in [("sqlite", &*MIGRATOR), ("postgres", &*MIGRATOR_PG)] {
            let mut files: Vec<_> = std::fs::read_dir(root.join(backend))
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|x| x == "sql"))
                .collect();
            files.sort();
            let embedded: Vec<_> = migrator.iter().collect();
            assert_eq!(embedded.len(), files.len(), "{backend}");
            for (m, file) in embedded.iter().zip(&files) {
                let name = file.file_stem().unwrap().to_str().unwrap();
                let (version, description) = name.split_once('_').unwrap();
                assert_eq!(m.version, version.parse::<i64>().unwrap(), "{name}");
                assert_eq!(m.description, description.replace('_', " "), "{name}");
                let bytes = std::fs::read(file).unwrap();
                assert_eq!(&*m.checksum, Sha384::digest(&bytes).as_slice(), "{name}");
                assert!(!m.no_tx, "{name}");
            }
        }
    }
}
