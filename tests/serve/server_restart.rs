//! Kill `d3il serve` (SIGKILL) in the middle of a real evaluation and start it
//! again on the same database: the job is requeued and finishes, nothing is
//! lost or doubled (issue 7). The evaluation is real: the ONNX fixture
//! assets/fixtures/aligning_mlp.onnx (the paper's BC-MLP size) under the quick
//! protocol (3 initial states x 2 rollouts, every rollout runs to Aligning's
//! step limit, several seconds) in the real sandboxed `d3il worker`.

use crate::D3IL;
use d3il_test_support::pg::children;
use d3il_test_support::server::*;
use std::path::PathBuf;
use std::time::Duration;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

/// True while `pid` exists and is not a zombie.
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            s.rfind(')')
                .map(|i| s[i + 1..].trim_start().starts_with('Z'))
        })
        .is_some_and(|zombie| !zombie)
}

#[test]
fn server_killed_twice_mid_evaluation_finishes_it_after_restarts() {
    let dir = TempDir::new("restart");
    let db = dir.path().join("lb.sqlite");
    let args = ["--workers", "1", "--max-attempts", "2"];
    let token = D3IL.create_token(&db, "restart-tester");
    let mut server = D3IL.serve(&db, &args);
    let client = server.client(Some(&token));
    let manifest = std::fs::read_to_string(fixture("aligning_mlp.json")).unwrap();
    let created = client
        .submit(
            &[
                ("method", "Durable-MLP".to_string()),
                ("task", "aligning".to_string()),
                ("training_seed", "0".to_string()),
                ("protocol", "quick".to_string()),
                ("manifest", manifest),
            ],
            Some(&fixture("aligning_mlp.onnx")),
        )
        .expect("submission accepted");
    let id = created["id"].as_i64().unwrap();

    // Twice: wait until the worker has loaded the policy and is running the
    // rollouts (progress 0 of 6 stored), then kill the server and start it
    // again on the same database. With `--max-attempts 2`, restarts that
    // counted as attempts would fail the job as `crashed` (issue 17).
    for _ in 0..2 {
        let client = server.client(Some(&token));
        wait_for(Duration::from_secs(120), || {
            let v = client.submission(id).ok()?;
            (v["status"] == "running" && v["progress"]["rollouts_total"].as_i64()? == 6)
                .then_some(())
        })
        .expect("the evaluation started");
        // "running" is stored as the job is leased, a moment before its
        // worker process is started: wait for it to appear.
        let pid = server.pid();
        let workers = wait_for(Duration::from_secs(10), || {
            let w = children(pid);
            (!w.is_empty()).then_some(w)
        })
        .unwrap_or_default();
        assert_eq!(workers.len(), 1, "one worker process: {workers:?}");
        server.kill();
        // The orphaned worker dies with its server (PR_SET_PDEATHSIG), it does
        // not keep evaluating in the background.
        let worker = workers[0];
        wait_for(Duration::from_secs(30), || (!alive(worker)).then_some(()))
            .unwrap_or_else(|| panic!("worker {worker} outlived the killed server"));
        // Restart on the same database: the interrupted job is requeued.
        server = D3IL.serve(&db, &args);
    }
    let client = server.client(Some(&token));
    let done = client
        .wait(id, Duration::from_secs(600), |_| {})
        .expect("the job finishes after the restart");
    assert_eq!(done["status"], "completed", "{done}");
    assert_eq!(
        done["attempts"], 1,
        "the two interrupted runs are not counted: {done}"
    );
    let result = &done["result"];
    let rollouts = result["rollouts"].as_array().unwrap();
    assert_eq!(rollouts.len(), 6, "{result}");
    let mut keys: Vec<(i64, i64)> = rollouts
        .iter()
        .map(|r| {
            (
                r["context_index"].as_i64().unwrap(),
                r["rollout_index"].as_i64().unwrap(),
            )
        })
        .collect();
    keys.dedup();
    assert_eq!(keys, vec![(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)]);
    assert_eq!(
        result["protocol_manifest"]["policy_sha256"], done["policy"]["sha256"],
        "the evaluated policy is the uploaded file"
    );

    // The stored result is the evaluation itself: the same fixture evaluated
    // directly (same seed, same protocol) gives the same numbers, rollout by
    // rollout.
    assert_same_result(
        &done,
        &D3IL.plain_eval(dir.path(), &fixture("aligning_mlp.onnx"), 0),
    );

    // Exactly one evaluated row: nothing lost, nothing doubled.
    let (_, csv) = server.get_text_blocking("/tasks/aligning/csv");
    let mine: Vec<&str> = csv
        .lines()
        .filter(|l| l.contains(",Durable-MLP,"))
        .collect();
    assert_eq!(mine.len(), 1, "{csv}");
    assert!(mine[0].contains(",evaluated,quick,1,"), "{}", mine[0]);
    let (s, page) = server.get_text_blocking(&format!("/submissions/{id}"));
    assert_eq!(s, 200);
    assert!(page.contains("id=\"metrics\""));
    server.kill();
}
