//! `d3il db check`: the schema version (and whether this binary knows newer
//! or older migrations), the database's own integrity checks (SQLite:
//! `PRAGMA integrity_check` and `foreign_key_check`; PostgreSQL: invalid
//! indexes and constraints not validated) and what the store relies on
//! (every result, rollout and job has its submission; every completed
//! submission its result; every live ONNX submission its policy file, with
//! its sha256). Reads only; opens the database without migrating it.

use super::{data_dir, open_existing, BackupError};
use crate::fidelity::file_sha256;
use crate::store::{Db, DbTarget, MIGRATOR, MIGRATOR_PG, TMP_MARKER};
use std::path::Path;

/// What [`check`] found: `ok` lines and `problems`, each saying what to fix.
#[derive(Debug, Default)]
pub struct CheckReport {
    pub schema_version: i64,
    pub ok: Vec<String>,
    pub notes: Vec<String>,
    pub problems: Vec<String>,
}

/// At most this many ids are listed per finding.
const SAMPLE: usize = 10;

fn ids(v: &[i64]) -> String {
    let mut s: Vec<String> = v.iter().take(SAMPLE).map(|i| i.to_string()).collect();
    if v.len() > SAMPLE {
        s.push(format!("… {} in all", v.len()));
    }
    s.join(", ")
}

/// Runs every check on the store at `target` (policy files in
/// `policy_store`, see [`super::data_dir`]).
pub async fn check(
    target: &DbTarget,
    policy_store: Option<&Path>,
) -> Result<CheckReport, BackupError> {
    let db = open_existing(target).await?;
    let mut r = CheckReport::default();
    if !schema(&db, &mut r).await? {
        return Ok(r);
    }
    integrity(&db, &mut r).await?;
    consistency(&db, &mut r).await?;
    let policies = data_dir(target, policy_store)?.join("policies");
    policy_files(&db, &policies, &mut r).await?;
    Ok(r)
}

/// Returns false when the database has no d3il schema at all.
async fn schema(db: &Db, r: &mut CheckReport) -> Result<bool, BackupError> {
    let has: i64 = match db {
        Db::Sqlite(p) => sqlx::query_scalar(
            "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND name = '_sqlx_migrations'",
        )
        .fetch_one(p)
        .await?,
        Db::Postgres(p) => sqlx::query_scalar(
            "SELECT COUNT(*) FROM pg_tables WHERE schemaname = 'public' AND tablename = '_sqlx_migrations'",
        )
        .fetch_one(p)
        .await?,
    };
    if has == 0 {
        r.problems.push(
            "no schema: this is not a d3il database (no _sqlx_migrations table); check --db, or let \
             `d3il serve --db` create a new one"
                .into(),
        );
        return Ok(false);
    }
    let applied: Vec<(i64, bool, Vec<u8>)> = crate::on_db!(db, pool => sqlx::query_as(
        "SELECT version, success, checksum FROM _sqlx_migrations ORDER BY version")
        .fetch_all(pool).await?);
    let known = match db {
        Db::Sqlite(_) => &MIGRATOR,
        Db::Postgres(_) => &MIGRATOR_PG,
    };
    let latest_known = known.iter().map(|m| m.version).max().unwrap_or(0);
    r.schema_version = applied
        .iter()
        .filter(|a| a.1)
        .map(|a| a.0)
        .max()
        .unwrap_or(0);
    for (version, success, checksum) in &applied {
        match known.iter().find(|m| m.version == *version) {
            _ if !success => r.problems.push(format!(
                "migration {version} failed part-way: restore the last backup (docs/ops.md, Restore)"
            )),
            None => r.problems.push(format!(
                "migration {version} is newer than this d3il knows (up to {latest_known}): the database \
                 was upgraded by a newer release; run that release, or restore a backup made before the upgrade"
            )),
            Some(m) if m.checksum.as_ref() != checksum.as_slice() => r.problems.push(format!(
                "migration {version} applied differs from this d3il's migrations/{}: the database was \
                 made by a modified build; restore a backup made by a release",
                m.description
            )),
            Some(_) => {}
        }
    }
    let pending: Vec<i64> = known
        .iter()
        .map(|m| m.version)
        .filter(|v| !applied.iter().any(|a| a.0 == *v))
        .collect();
    if pending.is_empty() {
        r.ok.push(format!(
            "schema version {} (the latest this d3il knows)",
            r.schema_version
        ));
    } else {
        r.notes.push(format!(
            "schema version {}; this d3il knows up to {latest_known}: migrations {pending:?} will be applied \
             when `d3il serve` next opens the database (back it up first: `d3il db backup`)",
            r.schema_version
        ));
    }
    Ok(true)
}

async fn integrity(db: &Db, r: &mut CheckReport) -> Result<(), BackupError> {
    match db {
        Db::Sqlite(p) => {
            let rows: Vec<String> = sqlx::query_scalar("PRAGMA integrity_check")
                .fetch_all(p)
                .await?;
            if rows == ["ok"] {
                r.ok.push("SQLite integrity_check: ok".into());
            } else {
                r.problems.push(format!(
                    "SQLite integrity_check reports damage ({}): restore the last backup",
                    rows.iter()
                        .take(SAMPLE)
                        .cloned()
                        .collect::<Vec<_>>()
                        .join("; ")
                ));
            }
            let fk: Vec<(String, Option<i64>, String)> =
                sqlx::query_as("SELECT \"table\", rowid, parent FROM pragma_foreign_key_check")
                    .fetch_all(p)
                    .await?;
            if fk.is_empty() {
                r.ok.push("foreign keys: every reference resolves".into());
            } else {
                let what: Vec<String> = fk
                    .iter()
                    .take(SAMPLE)
                    .map(|(t, id, parent)| format!("{t} row {} -> {parent}", id.unwrap_or(-1)))
                    .collect();
                r.problems.push(format!(
                    "{} row(s) refer to rows that do not exist ({}): restore the last backup, or delete them",
                    fk.len(),
                    what.join(", ")
                ));
            }
        }
        Db::Postgres(p) => {
            let bad_idx: Vec<String> = sqlx::query_scalar(
                "SELECT CAST(indexrelid::regclass AS TEXT) FROM pg_index i JOIN pg_class c ON c.oid = i.indrelid \
                 JOIN pg_namespace n ON n.oid = c.relnamespace WHERE n.nspname = 'public' AND NOT i.indisvalid",
            )
            .fetch_all(p)
            .await?;
            let bad_con: Vec<String> = sqlx::query_scalar(
                "SELECT CAST(conname AS TEXT) FROM pg_constraint c JOIN pg_namespace n ON n.oid = c.connamespace \
                 WHERE n.nspname = 'public' AND NOT c.convalidated",
            )
            .fetch_all(p)
            .await?;
            if bad_idx.is_empty() && bad_con.is_empty() {
                r.ok.push("PostgreSQL: every index valid, every constraint validated".into());
            }
            if !bad_idx.is_empty() {
                r.problems.push(format!(
                    "invalid index(es) {}: REINDEX them (an interrupted CREATE INDEX CONCURRENTLY leaves these)",
                    bad_idx.join(", ")
                ));
            }
            if !bad_con.is_empty() {
                r.problems.push(format!(
                    "constraint(s) {} not validated: ALTER TABLE … VALIDATE CONSTRAINT, and fix the rows it names",
                    bad_con.join(", ")
                ));
            }
        }
    }
    Ok(())
}

/// (what, query returning ids, how to fix)
const RULES: &[(&str, &str, &str)] = &[
    (
        "results of submissions that do not exist",
        "SELECT r.id FROM results r LEFT JOIN submissions s ON s.id = r.submission_id WHERE s.id IS NULL ORDER BY r.id",
        "restore the last backup, or delete these results",
    ),
    (
        "rollout records of submissions that do not exist",
        "SELECT r.id FROM rollouts r LEFT JOIN submissions s ON s.id = r.submission_id WHERE s.id IS NULL ORDER BY r.id",
        "restore the last backup, or delete these rollouts",
    ),
    (
        "jobs of submissions that do not exist",
        "SELECT j.id FROM jobs j LEFT JOIN submissions s ON s.id = j.submission_id WHERE s.id IS NULL ORDER BY j.id",
        "delete these jobs",
    ),
    (
        "submissions of methods that do not exist",
        "SELECT s.id FROM submissions s LEFT JOIN methods m ON m.id = s.method_id WHERE m.id IS NULL ORDER BY s.id",
        "restore the last backup",
    ),
    (
        "completed submissions without a result",
        "SELECT s.id FROM submissions s LEFT JOIN results r ON r.submission_id = s.id \
         WHERE s.status = 'completed' AND r.id IS NULL ORDER BY s.id",
        "restore the last backup, or resubmit these policies",
    ),
    (
        "queued or running submissions without a job",
        "SELECT s.id FROM submissions s LEFT JOIN jobs j ON j.submission_id = s.id \
         WHERE s.status IN ('queued', 'running') AND j.id IS NULL ORDER BY s.id",
        "nothing will evaluate them: resubmit these policies",
    ),
    (
        "live ONNX submissions without a stored file or sha256",
        "SELECT id FROM submissions WHERE policy_kind = 'onnx' AND status != 'failed' \
         AND (onnx_path IS NULL OR onnx_sha256 IS NULL) ORDER BY id",
        "restore the last backup",
    ),
];

async fn consistency(db: &Db, r: &mut CheckReport) -> Result<(), BackupError> {
    let mut clean = 0;
    for (what, sql, fix) in RULES {
        let found: Vec<i64> =
            crate::on_db!(db, pool => sqlx::query_scalar(*sql).fetch_all(pool).await?);
        if found.is_empty() {
            clean += 1;
        } else {
            r.problems.push(format!(
                "{} {what} (ids {}): {fix}",
                found.len(),
                ids(&found)
            ));
        }
    }
    if clean == RULES.len() {
        r.ok.push(format!(
            "consistency: {clean} rules hold (every result, rollout and job has its submission, …)"
        ));
    }
    Ok(())
}

/// Every live ONNX submission's file exists with its sha256; debris and
/// files no submission uses are noted.
async fn policy_files(db: &Db, policies: &Path, r: &mut CheckReport) -> Result<(), BackupError> {
    let rows: Vec<(String, String, i32)> = crate::on_db!(db, pool => sqlx::query_as(
        "SELECT onnx_path, MAX(onnx_sha256), MAX(CASE WHEN status != 'failed' THEN 1 ELSE 0 END) \
         FROM submissions WHERE onnx_path IS NOT NULL AND onnx_sha256 IS NOT NULL \
         GROUP BY onnx_path ORDER BY onnx_path")
        .fetch_all(pool).await?);
    let mut bad = vec![];
    let mut checked = 0;
    for (path, sha, live) in &rows {
        if *live == 0 {
            continue;
        }
        checked += 1;
        match file_sha256(Path::new(path)) {
            Ok(got) if got == *sha => {}
            Ok(got) => bad.push(format!(
                "{path} has sha256 {got}, its submissions say {sha}"
            )),
            Err(e) => bad.push(format!("{path}: {e}")),
        }
    }
    if bad.is_empty() {
        r.ok.push(format!(
            "policy files: {checked} used by live submissions, each present with its sha256"
        ));
    } else {
        r.problems.push(format!(
            "{} policy file(s) missing or changed ({}): restore the policy directory from the last \
             backup (d3il db restore), or give the --policy-store the server uses",
            bad.len(),
            bad.iter().take(SAMPLE).cloned().collect::<Vec<_>>().join("; ")
        ));
    }
    let used: std::collections::HashSet<&str> = rows.iter().map(|r| r.0.as_str()).collect();
    let mut debris = 0;
    let mut unused = 0;
    for e in std::fs::read_dir(policies).into_iter().flatten().flatten() {
        let p = e.path();
        if p.to_string_lossy().contains(TMP_MARKER) {
            debris += 1;
        } else if !used.contains(p.to_string_lossy().as_ref()) {
            unused += 1;
        }
    }
    if debris > 0 {
        r.notes.push(format!(
            "{debris} temporary upload file(s) in {} (uploads in progress, or left by a crash; the server removes the latter at start)",
            policies.display()
        ));
    }
    if unused > 0 {
        r.notes.push(format!(
            "{unused} file(s) in {} that no submission refers to (safe to delete once no upload is in progress)",
            policies.display()
        ));
    }
    Ok(())
}
