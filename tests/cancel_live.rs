//! Issue 41, end to end through the real binary (`d3il serve` with a real
//! sandboxed worker, MuJoCo, tract): while a paper-protocol evaluation runs,
//! the API shows the success rate so far with its confidence sequence (valid
//! at every look); its submitter cancels it: the worker stops, what ran is
//! kept and marked partial, the submission is never ranked; another token
//! may not cancel, a second cancel is a conflict.

use d3il_test_support::server::*;
use std::time::Duration;

/// The `d3il` binary under test (the server harness starts it, the tests run its other commands).
const D3IL: Binary = Binary(env!("CARGO_BIN_EXE_d3il"));

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

#[test]
fn running_evaluation_shows_a_confidence_sequence_and_cancels_to_a_partial_result() {
    let dir = TempDir::new("cancel-live");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "owner");
    let other = D3IL.create_token(&db, "someone-else");
    let admin = D3IL.create_admin_token(&db, "operator");
    let server = D3IL.serve(&db, &["--workers", "1"]);
    let client = server.client(Some(&token));
    let manifest = std::fs::read_to_string(fixture("aligning_mlp_noise.json")).unwrap();
    let created = client
        .submit(
            &[
                ("method", "Noisy-Cancel".to_string()),
                ("task", "aligning".to_string()),
                ("training_seed", "0".to_string()),
                ("protocol", "paper".to_string()),
                ("manifest", manifest),
            ],
            Some(&fixture("aligning_mlp_noise.onnx")),
        )
        .expect("submit");
    let id = created["id"].as_i64().unwrap();
    assert!(created["progress"]["live"].is_null(), "{created}");

    // Live: a confidence sequence once some initial states have finished.
    let live = wait_for(Duration::from_secs(600), || {
        let v = client.submission(id).unwrap();
        assert_ne!(
            v["status"], "completed",
            "finished before it could be looked at: {v}"
        );
        let l = &v["progress"]["live"];
        (l["states"].as_u64().unwrap_or(0) >= 2).then_some(v)
    })
    .expect("no live estimate within 600 s");
    let l = &live["progress"]["live"];
    assert_eq!(l["valid_at_every_look"], true);
    assert_eq!(l["partial"], false);
    assert_eq!(l["alpha"], 0.05);
    let (lo, hi) = (
        l["cs_low"].as_f64().unwrap(),
        l["cs_high"].as_f64().unwrap(),
    );
    let rate = l["success_rate"].as_f64().unwrap();
    assert!(0.0 <= lo && lo <= rate && rate <= hi && hi <= 1.0, "{l}");
    assert!(hi - lo < 1.0, "a real interval after some states: {l}");
    assert_eq!(
        l["successes"].as_u64().unwrap() as f64 / l["rollouts"].as_u64().unwrap() as f64,
        rate
    );
    // Each state of the paper protocol has its 8 rollouts (stochastic policy).
    assert_eq!(
        l["rollouts"].as_u64().unwrap(),
        8 * l["states"].as_u64().unwrap(),
        "{l}"
    );
    // The OpenAPI document describes it.
    let doc = client.get("/api/v1/openapi.json").unwrap();
    assert!(doc["paths"]["/submissions/{id}/cancel"]["post"].is_object());
    assert!(
        doc["components"]["schemas"]["LiveEstimate"]["properties"]["valid_at_every_look"]
            .is_object()
    );
    // The page shows it, labelled.
    let (status, page) = server.get_text_blocking(&format!("/submissions/{id}"));
    assert_eq!(status, 200);
    assert!(
        page.contains("id=\"so-far\"") && page.contains("valid at every look"),
        "{page}"
    );
    assert!(page.contains("id=\"cancel-form\""));

    // Someone else's token may not cancel it; its submitter may.
    let e = server
        .client(Some(&other))
        .cancel(id)
        .unwrap_err()
        .to_string();
    assert!(e.contains("403") || e.contains("only its submitter"), "{e}");
    let v = client.cancel(id).expect("cancel");
    assert_eq!(v["status"], "failed", "{v}");
    assert_eq!(v["error"]["kind"], "cancelled");
    assert_eq!(v["cancelled"]["by"], "owner");
    assert_eq!(v["progress"]["live"]["partial"], true);
    let kept = v["progress"]["live"]["states"].as_u64().unwrap();
    assert!(kept >= 2, "{v}");
    // A second cancel (here an admin's) is a conflict: it has finished.
    let e = server
        .client(Some(&admin))
        .cancel(id)
        .unwrap_err()
        .to_string();
    assert!(e.contains("409") || e.contains("already"), "{e}");

    // The worker stops: nothing changes any more, no result appears.
    std::thread::sleep(Duration::from_secs(6));
    let after = client.submission(id).unwrap();
    assert_eq!(after["status"], "failed");
    assert!(after["result"].is_null(), "{after}");
    assert_eq!(after["progress"]["live"]["states"].as_u64().unwrap(), kept);
    let ps = std::process::Command::new("pgrep")
        .args(["-f", "d3il worker", "-P", &server.pid().to_string()])
        .output()
        .unwrap();
    assert!(
        ps.stdout.is_empty(),
        "a worker still runs: {}",
        String::from_utf8_lossy(&ps.stdout)
    );
    // Never ranked: the board has no row of it.
    let board = client.get("/api/v1/leaderboards/aligning").unwrap();
    assert!(!board.to_string().contains("Noisy-Cancel"), "{board}");
    let (_, page) = server.get_text_blocking(&format!("/submissions/{id}"));
    assert!(
        page.contains("Partial result (cancelled by owner; never ranked)"),
        "{page}"
    );
    assert!(!page.contains("id=\"cancel-form\""));

    // A restart leaves the same state (nothing is requeued).
    drop(server);
    let server = D3IL.serve(&db, &["--workers", "1"]);
    std::thread::sleep(Duration::from_secs(3));
    let again = server.client(Some(&token)).submission(id).unwrap();
    assert_eq!(again["status"], "failed");
    assert_eq!(again["progress"]["live"]["states"].as_u64().unwrap(), kept);
    assert_eq!(again["cancelled"]["by"], "owner");
}
