//! Upgrades keep everything (issue 42, item 4). For every schema version k
//! of migrations/sqlite and migrations/postgres, a database is made at k:
//! migrated level by level to k, each level filled with the rows of
//! tests/data/upgrade/NNNN.sql (submissions, results, rollout records with
//! traces, jobs, tokens: rows valid at that level, in the SQL both backends
//! read; `<backend>/NNNN.sql` where they differ). Then the current store
//! opens it (migrating to the latest) and every row is still there with
//! every value it had, `d3il db check` passes, and a server on it shows
//! every old result: its submission page and its row on the board.
//!
//! A migration without a fixture fails `every_schema_version_has_an_upgrade_fixture`.

use crate::db_support;
use crate::D3IL;
use d3il_server::store::sqlx::{self, migrate::Migrator, Executor};
use d3il_server::store::{DbTarget, MIGRATOR, MIGRATOR_PG};
use d3il_test_support::server::*;
use db_support::*;
use std::path::{Path, PathBuf};

/// Placeholder in fixtures for the store's policy directory.
const POLICIES: &str = "@POLICIES@";

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/upgrade")
}

fn migrator(pg: bool) -> &'static Migrator {
    if pg {
        &MIGRATOR_PG
    } else {
        &MIGRATOR
    }
}

/// The fixture of migration `version` for the backend, if any.
fn fixture_sql(pg: bool, version: i64) -> Option<PathBuf> {
    let name = format!("{version:04}.sql");
    let own = data_dir()
        .join(if pg { "postgres" } else { "sqlite" })
        .join(&name);
    let shared = data_dir().join(&name);
    [own, shared].into_iter().find(|p| p.is_file())
}

#[test]
fn every_schema_version_has_an_upgrade_fixture() {
    let mut missing = vec![];
    for pg in [false, true] {
        for m in migrator(pg).iter() {
            if fixture_sql(pg, m.version).is_none() {
                missing.push(format!(
                    "{} migration {:04} ({})",
                    if pg { "postgres" } else { "sqlite" },
                    m.version,
                    m.description
                ));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "no upgrade fixture for {missing:?}: add tests/data/upgrade/NNNN.sql (or <backend>/NNNN.sql) with rows \
         that use what the migration adds (docs/ops.md, Upgrade)"
    );
}

/// Makes the database at `target` at schema version `migrations[k-1]`,
/// each level with its fixture rows.
async fn build_at_level(target: &DbTarget, k: usize, policies: &Path) {
    let pg = target.is_postgres();
    let all: Vec<_> = migrator(pg).iter().cloned().collect();
    let db = match target {
        DbTarget::Sqlite(path) => {
            let opts = sqlx::sqlite::SqliteConnectOptions::new()
                .filename(path)
                .create_if_missing(true)
                .foreign_keys(true);
            d3il_server::store::Db::Sqlite(sqlx::SqlitePool::connect_with(opts).await.unwrap())
        }
        DbTarget::Postgres(url) => {
            d3il_server::store::Db::Postgres(sqlx::PgPool::connect(url).await.unwrap())
        }
    };
    for level in 1..=k {
        let m = Migrator::with_migrations(all[..level].to_vec());
        let version = all[level - 1].version;
        let sql = std::fs::read_to_string(
            fixture_sql(pg, version).expect("a fixture (see the test above)"),
        )
        .unwrap()
        .replace(POLICIES, policies.to_str().unwrap());
        d3il_server::on_db!(&db, pool => {
            m.run(pool).await.unwrap_or_else(|e| panic!("migrate to {version}: {e}"));
            pool.execute(sqlx::raw_sql(sqlx::AssertSqlSafe(sql)))
                .await
                .unwrap_or_else(|e| panic!("fixture {version:04}.sql at level {version}: {e}"));
        });
    }
    if let d3il_server::store::Db::Postgres(pool) = &db {
        // Fixtures give ids; the identity sequences go past them.
        pool.execute(
            "DO $$ DECLARE t record; BEGIN FOR t IN SELECT c.table_name FROM information_schema.columns c \
             WHERE c.table_schema = 'public' AND c.column_name = 'id' AND c.is_identity = 'YES' LOOP \
             EXECUTE format('SELECT setval(pg_get_serial_sequence(%L, ''id''), GREATEST((SELECT MAX(id) FROM %I), 1))', \
             t.table_name, t.table_name); END LOOP; END $$",
        )
        .await
        .unwrap();
    }
}

fn upgrade_from_every_level(pg: bool, dir: &Path) {
    let levels = migrator(pg).iter().count();
    for k in 1..=levels {
        let (target, store_dir) = if pg {
            let s = dir.join(format!("store-{k}"));
            (
                DbTarget::Postgres(d3il_test_support::pg::fresh_database()),
                s,
            )
        } else {
            let db = dir.join(format!("level-{k}/lb.sqlite"));
            std::fs::create_dir_all(db.parent().unwrap()).unwrap();
            (
                DbTarget::Sqlite(db.clone()),
                d3il_server::store::sqlite_data_dir(&db),
            )
        };
        let policies = store_dir.join("policies");
        std::fs::create_dir_all(&policies).unwrap();
        // The fixtures' ONNX submissions use this file (named by its sha256).
        let onnx = fixture("aligning_mlp.onnx");
        std::fs::copy(&onnx, policies.join(format!("{}.onnx", sha256_file(&onnx)))).unwrap();
        let target_s = match &target {
            DbTarget::Sqlite(p) => p.to_str().unwrap().to_string(),
            DbTarget::Postgres(u) => u.clone(),
        };
        runtime().block_on(build_at_level(&target, k, &policies));
        let before = all_rows(&target_s);

        // The current store opens it: every migration since k, the paper's rows.
        runtime()
            .block_on(d3il_server::store::Store::connect(
                &target,
                Some(&store_dir),
            ))
            .unwrap_or_else(|e| panic!("level {k}: the store does not open: {e}"));
        let after = all_rows(&target_s);
        for (table, rows) in &before {
            for (key, row) in rows {
                let now = after
                    .get(table)
                    .and_then(|t| t.get(key))
                    .unwrap_or_else(|| panic!("level {k}: {table} row {key} lost in the upgrade"));
                for (col, v) in row.as_object().unwrap() {
                    assert_eq!(
                        &now[col], v,
                        "level {k}: {table} row {key} column {col} changed"
                    );
                }
            }
        }

        let store_s = store_dir.to_str().unwrap();
        let args = ["--db", target_s.as_str(), "--policy-store", store_s];
        let mut check = vec!["check"];
        check.extend(args);
        let report = d3il_db_ok(&check);
        assert!(!report.contains("PROBLEM"), "level {k}: {report}");

        // Every old result renders: its page, its row on the board.
        let server = D3IL.serve_on(
            target_s.as_ref(),
            &["--policy-store", store_s, "--workers", "0"],
        );
        let subs = &after["submissions"];
        let mut shown = 0;
        for (id, sub) in subs {
            if sub["status"] != "completed" {
                continue;
            }
            let (s, page) = server.get_text_blocking(&format!("/submissions/{id}"));
            assert_eq!(s, 200, "level {k}: submission {id}: {page}");
            assert!(
                page.contains("id=\"metrics\""),
                "level {k}: submission {id} shows its metrics"
            );
            let api = server.client(None).submission(id.parse().unwrap()).unwrap();
            let result = after["results"]
                .values()
                .find(|r| r["submission_id"].as_i64() == id.parse::<i64>().ok())
                .unwrap();
            assert_eq!(
                api["result"]["metrics"]["success_rate"]["value"].as_f64(),
                result["success_rate"].as_f64(),
                "level {k}: {api}"
            );
            // The start recomputed every result made under earlier interval
            // rules from its rollout records (issue 51): each names its
            // method or why it has none (these have 3 initial states).
            let sr = &api["result"]["metrics"]["success_rate"];
            assert_eq!(
                sr["no_interval"]["reason"], "too_few_states",
                "level {k}: submission {id}: {sr}"
            );
            assert!(
                sr["interval"]
                    .as_str()
                    .unwrap()
                    .contains("3 initial states"),
                "level {k}: {sr}"
            );
            let withdrawn = sub.get("withdrawn_at").is_some_and(|w| !w.is_null());
            let method = after["methods"][&sub["method_id"].to_string()]["name"]
                .as_str()
                .unwrap();
            let task = sub["task"].as_str().unwrap();
            let (s, csv) = server.get_text_blocking(&format!("/tasks/{task}/csv"));
            assert_eq!(s, 200);
            // A withdrawn submission is hidden, but its method may be shown
            // through another one.
            if !withdrawn {
                assert!(
                    csv.contains(method),
                    "level {k}: {method} on the {task} board: {csv}"
                );
            }
            shown += 1;
        }
        assert!(shown >= 1, "level {k}: a completed result to show");
        // Recomputed once: the rows now record this build's rules.
        for (key, r) in &all_rows(&target_s)["results"] {
            assert_eq!(
                r["intervals_rules"].as_i64(),
                Some(d3il_metrics::recompute::RULES_VERSION),
                "level {k}: result {key} not recomputed"
            );
        }
    }
}

#[test]
fn upgrade_from_every_schema_version_keeps_every_row_sqlite() {
    let dir = TempDir::new("db-upgrade-sqlite");
    upgrade_from_every_level(false, dir.path());
}

#[test]
fn upgrade_from_every_schema_version_keeps_every_row_postgres() {
    let dir = TempDir::new("db-upgrade-pg");
    upgrade_from_every_level(true, dir.path());
}
