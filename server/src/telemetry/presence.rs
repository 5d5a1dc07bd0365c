//! Which worker hosts (`d3il workers`) are alive, without a table of its
//! own: each host keeps one connection to the PostgreSQL queue open under
//! the application name `d3il-workers <host>-<pid>`, and whoever asks counts
//! those sessions in `pg_stat_activity`. A host that dies (or loses its
//! network) drops its session, so it stops counting at once, not after a
//! timeout. On SQLite there are no worker hosts.

use crate::store::{Db, Store};
use sqlx::postgres::PgConnectOptions;
use sqlx::{ConnectOptions, Connection};
use std::time::Duration;

/// Prefix of the application name of a worker host's presence session.
pub const APPLICATION_PREFIX: &str = "d3il-workers ";

/// Keeps this host's presence session open (reconnecting after the
/// database comes back) for as long as the process runs.
pub fn announce(url: &str, host: String) -> Result<(), sqlx::Error> {
    let opts: PgConnectOptions = url.parse::<PgConnectOptions>()?;
    let opts = opts
        .application_name(&format!("{APPLICATION_PREFIX}{host}"))
        .disable_statement_logging();
    tokio::spawn(async move {
        loop {
            match opts.connect().await {
                Ok(mut conn) => loop {
                    tokio::time::sleep(Duration::from_secs(10)).await;
                    if let Err(e) = conn.ping().await {
                        tracing::warn!("worker host presence session lost ({e}); reconnecting");
                        break;
                    }
                },
                Err(e) => tracing::warn!("worker host presence session: cannot connect ({e})"),
            }
            tokio::time::sleep(Duration::from_secs(2)).await;
        }
    });
    Ok(())
}

/// Worker hosts with a presence session on this database (0 on SQLite).
pub async fn hosts_connected(store: &Store) -> Result<i64, sqlx::Error> {
    match store.db() {
        Db::Sqlite(_) => Ok(0),
        Db::Postgres(pool) => {
            let (n,): (i64,) = sqlx::query_as(
                "SELECT CAST(COUNT(DISTINCT application_name) AS BIGINT) FROM pg_stat_activity \
                 WHERE datname = current_database() AND application_name LIKE $1",
            )
            .bind(format!("{APPLICATION_PREFIX}%"))
            .fetch_one(pool)
            .await?;
            Ok(n)
        }
    }
}
