//! A robustness evaluation sharded on the server and sandboxed on the
//! command line (issue 40, docs/robustness.md "On the server"), with real
//! parts: `d3il serve --workers 2 --shards 2` splits a robustness submission
//! of the deterministic Aligning MLP fixture (quick protocol: 3 initial
//! states, level 0 and the 13 levels of the suite) into two shard jobs that
//! its two worker slots run at once, each a sandboxed `d3il worker` running
//! level 0 and every level on its block of states; the last one merges, and
//! the stored document is the one `d3il eval --suite robustness` gives
//! unsharded, bit for bit (but for the measured inference times). Progress sums
//! the shards' rollouts over every level, and a cancelled sharded suite
//! stops both workers and stores nothing.

use d3il_server::store::{sqlx, Store};
use d3il_test_support::server::*;
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The `d3il` binary under test (the server harness starts it, the tests run its other commands).
const D3IL: Binary = Binary(env!("CARGO_BIN_EXE_d3il"));
const EXE: &str = D3IL.0;

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

/// `d3il eval --suite robustness` of the fixture (quick protocol, seed 0);
/// returns the document it wrote.
fn cli_suite(dir: &Path, name: &str) -> Value {
    let path = dir.join(name);
    let out = Command::new(EXE)
        .args(["eval", "--task", "aligning", "--protocol", "quick"])
        .args(["--suite", "robustness", "--policy"])
        .arg(fixture("aligning_mlp.onnx"))
        .arg("--json")
        .arg(&path)
        .output()
        .expect("run d3il eval");
    d3il_test_support::succeeded(&out, "d3il eval --suite robustness");
    serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap()
}

/// The document without the measured inference times (wall clock), which
/// differ from run to run.
fn timeless(mut v: Value) -> Value {
    v["control"]["metrics"]["inference_ms"] = Value::Null;
    for l in v["levels"].as_array_mut().unwrap() {
        l["result"]["metrics"]["inference_ms"] = Value::Null;
    }
    v
}

/// One job row of a submission: shard index and count, state, attempts,
/// started and finished (seconds), and whether its part is still kept.
type ShardRow = (i64, i64, String, i64, Option<i64>, Option<i64>, bool);

fn shard_rows(db: &Path, submission: i64) -> Vec<ShardRow> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(async {
            let store = Store::open(db).await.expect("open store");
            d3il_server::on_db!(store.db(), pool => sqlx::query_as(
                "SELECT shard_index, shard_count, state, attempts, started_at, finished_at, \
                 part_json IS NOT NULL FROM jobs WHERE submission_id = $1 ORDER BY shard_index",
            )
            .bind(submission)
            .fetch_all(pool)
            .await)
            .expect("job rows")
        })
}

fn submit(server: &TestServer, token: &str, seed: u32) -> i64 {
    let created = server
        .client(Some(token))
        .submit(
            &[
                ("method", "Sharded-Robust-MLP".to_string()),
                ("task", "aligning".to_string()),
                ("training_seed", seed.to_string()),
                ("protocol", "quick".to_string()),
                ("suite", "robustness".to_string()),
                (
                    "manifest",
                    std::fs::read_to_string(fixture("aligning_mlp.json")).unwrap(),
                ),
            ],
            Some(&fixture("aligning_mlp.onnx")),
        )
        .expect("robustness submission accepted");
    created["id"].as_i64().unwrap()
}

#[test]
fn a_sharded_robustness_submission_stores_the_unsharded_document() {
    let dir = TempDir::new("robustness-shards");
    // The command line, unsharded and in process (its sandboxed shards
    // merge into the same document: tests/robustness_shard.rs).
    let plain = timeless(cli_suite(dir.path(), "plain.json"));
    // Quick protocol: 3 states × 2 rollouts at level 0 and 13 levels.
    let levels = plain["levels"].as_array().unwrap().len();
    assert_eq!(levels, 13);
    let recorded = 6 * (levels as i64 + 1);

    // The server: two worker slots, every job in two shards (the drift
    // canary runs, so results record this build as `d3il eval` does).
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "shards-tester");
    let server = D3IL.serve_with_canary(
        &db,
        &["--workers", "2", "--shards", "2", "--no-upload-dry-run"],
    );
    let client = server.client(Some(&token));
    let id = submit(&server, &token, 0);
    let mut seen: Vec<(i64, i64)> = vec![];
    let done = client
        .wait(id, Duration::from_secs(900), |v| {
            let p = &v["progress"];
            if let (Some(d), Some(t)) = (p["rollouts_done"].as_i64(), p["rollouts_total"].as_i64())
            {
                seen.push((d, t));
            }
        })
        .expect("the sharded suite finishes");
    assert_eq!(done["status"], "completed", "{done}");

    // Two shard jobs (1 and 2 of the 3 states), each run once, at the same
    // time on two worker slots; the parts are gone into the result.
    let rows = shard_rows(&db, id);
    assert_eq!(rows.len(), 2, "{rows:?}");
    for (index, count, state, attempts, _, _, part_kept) in &rows {
        assert_eq!(
            (*count, state.as_str(), *attempts),
            (2, "done", 1),
            "shard {index}: {rows:?}"
        );
        assert!(!part_kept, "shard {index}'s part is merged and dropped");
    }
    let last_start = rows.iter().filter_map(|r| r.4).max().unwrap();
    let first_end = rows.iter().filter_map(|r| r.5).min().unwrap();
    assert!(
        last_start <= first_end,
        "the shards ran one after the other, not on two workers: {rows:?}"
    );
    // Progress counts every level's rollouts of both shards.
    assert_eq!(done["progress"]["rollouts_done"], recorded, "{done}");
    assert_eq!(done["progress"]["rollouts_total"], recorded, "{done}");
    assert!(
        seen.iter().any(|&(d, t)| 0 < d && d < t),
        "no progress seen while it ran: {seen:?}"
    );

    // The stored document is the unsharded one, bit for bit, and level 0
    // is the submission's plain result.
    let mut doc = client
        .get(&format!("/api/v1/submissions/{id}/robustness"))
        .unwrap();
    // The server adds the scores' coverage label to what it serves (the
    // document's own rule, RobustnessResult::score_coverage); the rest is
    // the document as stored.
    let coverage = doc
        .as_object_mut()
        .unwrap()
        .remove("score_interval_coverage")
        .expect("the served document carries score_interval_coverage");
    let stored: d3il_protocol::robustness::RobustnessResult =
        serde_json::from_value(doc.clone()).unwrap();
    assert_eq!(
        coverage,
        serde_json::to_value(stored.score_coverage()).unwrap()
    );
    assert_eq!(timeless(doc.clone()), plain, "the merged document differs");
    let results = client
        .get(&format!("/api/v1/submissions/{id}/results"))
        .unwrap();
    assert_eq!(results["per_context"], plain["control"]["per_context"]);
    assert_eq!(
        document_estimate(&results["metrics"]["success_rate"]),
        plain["control"]["metrics"]["success_rate"]
    );
    let (status, view) = server.get_text_blocking("/tasks/aligning/robustness");
    assert_eq!(status, 200);
    assert!(view.contains("Sharded-Robust-MLP"), "{view}");

    // Cancelled while both shards run: both workers stop, nothing is stored.
    let id = submit(&server, &token, 1);
    wait_for(Duration::from_secs(300), || {
        let rows = shard_rows(&db, id);
        let v = client.submission(id).unwrap();
        assert_ne!(v["status"], "completed", "finished before the cancel: {v}");
        let both = rows.iter().all(|r| r.2 == "leased");
        (both && v["progress"]["rollouts_done"].as_i64().unwrap_or(0) > 0).then_some(())
    })
    .expect("both shards running within 300 s");
    let v = client.cancel(id).expect("cancel");
    assert_eq!(v["status"], "failed", "{v}");
    assert_eq!(v["error"]["kind"], "cancelled", "{v}");
    let stopped = wait_for(Duration::from_secs(30), || {
        let ps = Command::new("pgrep")
            .args(["-f", "d3il worker", "-P", &server.pid().to_string()])
            .output()
            .unwrap();
        ps.stdout.is_empty().then_some(())
    });
    assert!(
        stopped.is_some(),
        "a shard's worker still runs after the cancel"
    );
    let rows = shard_rows(&db, id);
    assert!(rows.iter().all(|r| r.2 == "failed"), "{rows:?}");
    let (s, body) = server.get_text_blocking(&format!("/api/v1/submissions/{id}/robustness"));
    assert_eq!(s, 404, "a cancelled suite has no document: {body}");
    let after = client.submission(id).unwrap();
    assert_eq!(after["status"], "failed");
    assert!(after["result"].is_null(), "{after}");
    server.kill();
}
