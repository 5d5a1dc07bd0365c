//! `d3il db backup` / `d3il db restore` / `d3il db check` (issue 42, items 3
//! and 4): a round trip under load on SQLite and on PostgreSQL. A real
//! `d3il serve` with two real sandboxed workers evaluates four ONNX
//! submissions (two different policy files, quick protocol); the backup is
//! taken once the first has finished and while the others are queued or
//! running. After everything has finished and the server is gone, the archive
//! is restored into a fresh database and directory: every row of the
//! backup's moment comes back (compared column by column with the live
//! database, which only moved on), every policy file comes back with its
//! sha256, `d3il db check` passes, and a server on the restored store serves
//! every restored result.

use crate::db_support;
use crate::D3IL;
use d3il_test_support::server::*;
use db_support::*;
use std::path::Path;
use std::time::Duration;

/// `(fixture stem, training seed)` of the four submissions.
const SUBMISSIONS: [(&str, u32); 4] = [
    ("aligning_mlp", 0),
    ("aligning_mlp_noise", 0),
    ("aligning_mlp", 1),
    ("aligning_mlp_noise", 1),
];

/// `--db` and `--policy-store` arguments of a store.
struct StoreArgs {
    db: String,
    policy_store: Option<String>,
}

impl StoreArgs {
    fn args(&self) -> Vec<&str> {
        let mut a = vec!["--db", self.db.as_str()];
        if let Some(p) = &self.policy_store {
            a.extend(["--policy-store", p.as_str()]);
        }
        a
    }

    fn policies_dir(&self) -> std::path::PathBuf {
        match &self.policy_store {
            Some(p) => Path::new(p).join("policies"),
            None => d3il_server::store::sqlite_data_dir(Path::new(&self.db)).join("policies"),
        }
    }
}

fn round_trip(dir: &Path, source: StoreArgs, restored: StoreArgs) {
    // An operator's token: four evaluations at once, whatever the quotas.
    let mut token_args = source.args();
    token_args.push("--admin");
    let token = D3IL.create_token_on("backup-tester", &token_args);
    let mut serve_args = source.args()[2..].to_vec();
    serve_args.extend(["--workers", "2", "--no-upload-dry-run"]);
    let server = D3IL.serve_on(source.db.as_ref(), &serve_args);
    let client = server.client(Some(&token));
    let mut ids = vec![];
    for (stem, seed) in SUBMISSIONS {
        let manifest = std::fs::read_to_string(fixture(&format!("{stem}.json"))).unwrap();
        let created = client
            .submit(
                &[
                    ("method", format!("Backup-{stem}")),
                    ("task", "aligning".to_string()),
                    ("training_seed", seed.to_string()),
                    ("protocol", "quick".to_string()),
                    ("manifest", manifest),
                ],
                Some(&fixture(&format!("{stem}.onnx"))),
            )
            .expect("submission accepted");
        ids.push(created["id"].as_i64().unwrap());
    }
    let status = |id: i64| {
        client.submission(id).unwrap()["status"]
            .as_str()
            .unwrap()
            .to_string()
    };
    // Under load: the first evaluation has finished, the others have not.
    let completed_before = wait_for(Duration::from_secs(600), || {
        let done: Vec<i64> = ids
            .iter()
            .copied()
            .filter(|&id| status(id) == "completed")
            .collect();
        (!done.is_empty()).then_some(done)
    })
    .expect("an evaluation finishes");
    let archive = dir.join("backup.tar.gz");
    let archive_s = archive.to_str().unwrap();
    let mut backup_args = vec!["backup"];
    backup_args.extend(source.args());
    backup_args.extend(["--out", archive_s]);
    let printed = d3il_db_ok(&backup_args);
    assert!(printed.contains("backed up"), "{printed}");
    let pending_after: Vec<i64> = ids
        .iter()
        .copied()
        .filter(|&id| status(id) != "completed")
        .collect();
    assert!(
        !pending_after.is_empty(),
        "the backup ran while evaluations were still going on"
    );
    for &id in &ids {
        client
            .wait(id, Duration::from_secs(900), |_| {})
            .expect("every evaluation finishes");
    }
    drop(server);

    // Restore into a fresh store.
    let mut restore_args = vec!["restore", "--in", archive_s];
    restore_args.extend(restored.args());
    let printed = d3il_db_ok(&restore_args);
    assert!(
        printed.contains("rows and files match the manifest"),
        "{printed}"
    );

    let live = all_rows(&source.db);
    let back = all_rows(&restored.db);
    // The backup's moment: the finished evaluations then are there, and at
    // least one was still queued or running.
    let subs = &back["submissions"];
    for id in &completed_before {
        assert_eq!(
            subs[&id.to_string()]["status"],
            "completed",
            "submission {id}"
        );
    }
    assert!(
        subs.values().any(|s| s["status"] != "completed"),
        "the archive holds a moment with unfinished work: {subs:#?}"
    );
    assert_eq!(subs.len(), ids.len());
    assert!(back["results"].len() >= completed_before.len());
    assert!(back["rollouts"].len() >= 6 * completed_before.len());
    for (table, rows) in &back {
        let live_rows = &live[table];
        for (key, row) in rows {
            let now = live_rows
                .get(key)
                .unwrap_or_else(|| panic!("{table} {key} restored but not in the live database"));
            // What may have moved on since the backup: a submission's and a
            // job's progress, a token's last use; the file path is the
            // restored store's.
            let volatile: &[&str] = match table.as_str() {
                "submissions" if row["status"] != "completed" => &[
                    "status",
                    "updated_at",
                    "error_kind",
                    "error_message",
                    "simulated_once",
                    "onnx_path",
                ],
                "submissions" => &["onnx_path"],
                "jobs" => continue,
                "api_tokens" => &["last_used_at"],
                _ => &[],
            };
            assert_eq!(
                without(row, volatile),
                without(now, volatile),
                "{table} {key} differs"
            );
        }
    }
    // Every result and rollout of a finished submission came back whole.
    for (table, rows) in [
        ("results", &back["results"]),
        ("rollouts", &back["rollouts"]),
    ] {
        for (key, row) in &live[table] {
            let sub = row["submission_id"].to_string();
            if completed_before.iter().any(|id| id.to_string() == sub) {
                assert!(
                    rows.contains_key(key),
                    "{table} {key} of a finished submission is missing"
                );
            }
        }
    }
    // Policy files, hash by hash, at the restored store's place.
    let restored_dir = restored.policies_dir();
    for sub in subs.values() {
        let path = Path::new(sub["onnx_path"].as_str().unwrap());
        assert!(
            path.starts_with(&restored_dir),
            "{} points into the restored store",
            path.display()
        );
        let sha = sub["onnx_sha256"].as_str().unwrap();
        assert_eq!(sha256_file(path), sha);
        assert_eq!(
            sha256_file(&source.policies_dir().join(path.file_name().unwrap())),
            sha
        );
    }
    let files = std::fs::read_dir(&restored_dir).unwrap().count();
    assert_eq!(files, 2, "the two distinct policy files");

    let mut check_args = vec!["check"];
    check_args.extend(restored.args());
    let report = d3il_db_ok(&check_args);
    assert!(
        report.contains("ok: SQLite integrity_check") || report.contains("ok: PostgreSQL"),
        "{report}"
    );
    assert!(!report.contains("PROBLEM"), "{report}");

    // A second restore into the now non-empty store is refused.
    let again = d3il_db(&restore_args);
    assert!(!again.status.success());
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("--force"), "{err}");

    // The restored store serves every restored result.
    let mut serve_args = restored.args()[2..].to_vec();
    serve_args.extend(["--workers", "1", "--no-upload-dry-run"]);
    let server = D3IL.serve_on(restored.db.as_ref(), &serve_args);
    let (_, csv) = server.get_text_blocking("/tasks/aligning/csv");
    for (key, sub) in subs {
        if sub["status"] != "completed" {
            continue;
        }
        let (s, page) = server.get_text_blocking(&format!("/submissions/{key}"));
        assert_eq!(s, 200);
        assert!(
            page.contains("id=\"metrics\""),
            "submission {key}'s page shows its metrics"
        );
        let method = &back["methods"][&sub["method_id"].to_string()]["name"];
        assert!(
            csv.contains(method.as_str().unwrap()),
            "{method} on the board: {csv}"
        );
        let api = server
            .client(None)
            .submission(key.parse().unwrap())
            .unwrap();
        let live_result = &back["results"]
            .values()
            .find(|r| r["submission_id"].as_i64() == key.parse::<i64>().ok())
            .unwrap();
        assert_eq!(
            api["result"]["metrics"]["success_rate"]["value"].as_f64(),
            live_result["success_rate"].as_f64(),
            "{api}"
        );
    }
}

#[test]
fn backup_under_load_restores_every_row_and_file_sqlite() {
    let dir = TempDir::new("db-backup-sqlite");
    let source = StoreArgs {
        db: dir
            .path()
            .join("live/lb.sqlite")
            .to_str()
            .unwrap()
            .to_string(),
        policy_store: None,
    };
    let restored = StoreArgs {
        db: dir
            .path()
            .join("restored/lb.sqlite")
            .to_str()
            .unwrap()
            .to_string(),
        policy_store: None,
    };
    round_trip(dir.path(), source, restored);
}

#[test]
fn backup_under_load_restores_every_row_and_file_postgres() {
    let dir = TempDir::new("db-backup-pg");
    let store = |name: &str| {
        let p = dir.path().join(name);
        std::fs::create_dir_all(&p).unwrap();
        p.to_str().unwrap().to_string()
    };
    let source = StoreArgs {
        db: d3il_test_support::pg::fresh_database(),
        policy_store: Some(store("live-store")),
    };
    let restored = StoreArgs {
        db: d3il_test_support::pg::fresh_database(),
        policy_store: Some(store("restored-store")),
    };
    round_trip(dir.path(), source, restored);
}
