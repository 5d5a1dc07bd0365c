//! `--db` and `--policy-store`, defined once for every subcommand that opens
//! the leaderboard's store (`serve`, `workers`, `token`, `tables`).

use d3il_server::store::DbTarget;
use std::path::PathBuf;

#[derive(clap::Args, Debug, Clone)]
pub struct DbArgs {
    /// The database: a SQLite file (created and migrated if missing; the
    /// embedded default) or a PostgreSQL URL `postgres://user@host/db`
    /// shared by several front ends and worker hosts (docs/cluster.md).
    #[arg(long, default_value = "d3il.sqlite")]
    pub db: DbTarget,
    /// Directory of uploaded policies (they go in its `policies/`). Needed
    /// with PostgreSQL: the same shared directory (e.g. NFS) on every host,
    /// so any host can run any job. Default with SQLite: `<db stem>-data/`
    /// next to the database file.
    #[arg(long)]
    pub policy_store: Option<PathBuf>,
}
