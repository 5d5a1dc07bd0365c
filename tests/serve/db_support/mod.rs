//! Reading a whole store's rows for comparison (the backup round trip and
//! the upgrade test): every table, every row as a JSON object keyed by its
//! `id` (or first column), through the store's raw connection.
#![allow(dead_code)]

use d3il_server::store::sqlx;
use d3il_server::store::{Db, DbTarget};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Output};

pub use super::EXE;

/// Rows of one table by key.
pub type Rows = BTreeMap<String, Value>;

/// Runs `d3il db ARGS...` and returns its output.
pub fn d3il_db(args: &[&str]) -> Output {
    Command::new(EXE)
        .arg("db")
        .args(args)
        .output()
        .expect("run d3il db")
}

/// `d3il db ARGS...`, which must succeed; returns stdout.
pub fn d3il_db_ok(args: &[&str]) -> String {
    d3il_test_support::succeeded(&d3il_db(args), &format!("d3il db {args:?}"))
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

/// The database `--db` names, opened as it is (no migration).
pub fn open(target: &str) -> Db {
    runtime()
        .block_on(d3il_server::backup::open_existing(&DbTarget::parse(target)))
        .expect("open the database")
}

/// Every table's rows.
pub fn all_rows(target: &str) -> BTreeMap<String, Rows> {
    let rt = runtime();
    rt.block_on(async {
        let db = d3il_server::backup::open_existing(&DbTarget::parse(target))
            .await
            .expect("open the database");
        let mut out = BTreeMap::new();
        match &db {
            Db::Sqlite(p) => {
                let tables: Vec<String> = sqlx::query_scalar(
                    "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'",
                )
                .fetch_all(p)
                .await
                .unwrap();
                for t in tables {
                    let cols: Vec<String> =
                        sqlx::query_scalar(sqlx::AssertSqlSafe(format!("SELECT name FROM pragma_table_info('{t}')")))
                            .fetch_all(p)
                            .await
                            .unwrap();
                    let fields: Vec<String> = cols
                        .iter()
                        .map(|c| format!("'{c}', CASE WHEN typeof(\"{c}\") = 'blob' THEN hex(\"{c}\") ELSE \"{c}\" END"))
                        .collect();
                    let json: Vec<String> = sqlx::query_scalar(sqlx::AssertSqlSafe(format!(
                        "SELECT json_object({}) FROM \"{t}\"",
                        fields.join(", ")
                    )))
                    .fetch_all(p)
                    .await
                    .unwrap();
                    out.insert(t, keyed(&cols[0], json));
                }
            }
            Db::Postgres(p) => {
                let tables: Vec<String> = sqlx::query_scalar(
                    "SELECT CAST(tablename AS TEXT) FROM pg_tables WHERE schemaname = 'public'",
                )
                .fetch_all(p)
                .await
                .unwrap();
                for t in tables {
                    let first: String = sqlx::query_scalar(
                        "SELECT CAST(column_name AS TEXT) FROM information_schema.columns \
                         WHERE table_schema = 'public' AND table_name = $1 ORDER BY ordinal_position LIMIT 1",
                    )
                    .bind(&t)
                    .fetch_one(p)
                    .await
                    .unwrap();
                    let json: Vec<String> = sqlx::query_scalar(sqlx::AssertSqlSafe(format!(
                        "SELECT CAST(to_jsonb(t) AS TEXT) FROM \"{t}\" AS t"
                    )))
                    .fetch_all(p)
                    .await
                    .unwrap();
                    out.insert(t, keyed(&first, json));
                }
            }
        }
        out
    })
}

fn keyed(key: &str, json: Vec<String>) -> Rows {
    json.into_iter()
        .map(|j| {
            let v: Value = serde_json::from_str(&j).unwrap();
            (v[key].to_string(), v)
        })
        .collect()
}

/// `row` without the columns `except`.
pub fn without(row: &Value, except: &[&str]) -> Value {
    let mut r = row.clone();
    if let Some(o) = r.as_object_mut() {
        for k in except {
            o.remove(*k);
        }
    }
    r
}

/// sha256 of a file.
pub fn sha256_file(p: &std::path::Path) -> String {
    d3il_server::fidelity::file_sha256(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A repository fixture (assets/fixtures/NAME).
pub fn fixture(name: &str) -> PathBuf {
    d3il_test_support::fixtures_dir().join(name)
}
