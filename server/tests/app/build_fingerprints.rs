//! Issue 32: results from builds whose physics fingerprints differ are never
//! averaged or ranked together: the board keeps them in tables of their
//! own, headed with the fingerprint, the API names each row's fingerprint
//! and `d3il tables`' cells keep them apart with the reason.

use d3il_protocol::*;
use d3il_test_support::server::*;

/// An Aligning result made by a build with `fingerprint` (None: before
/// builds were identified).
fn result(success: f64, fingerprint: Option<&str>) -> EvalResult {
    let mut r = aligning_result(ProtocolKind::Paper, success, 0.2, "aligning-v2.json");
    r.manifest.evaluator_version = "0.2.0".into();
    r.manifest.build = fingerprint.map(|f| BuildIdentity {
        git_commit: "c".repeat(40),
        physics_fingerprint: Some(f.into()),
    });
    r
}

async fn evaluated(app: &TestServer, seed: i64, success: f64, fingerprint: Option<&str>) {
    let store = &app.state().store;
    let id = queued_submission(
        store,
        "Mine",
        TaskId::Aligning,
        ProtocolKind::Paper,
        seed,
        1,
    )
    .await;
    let job = store.job_for(id).await.expect("job");
    store
        .complete_job(job.id, id, &result(success, fingerprint), &[])
        .await
        .expect("complete");
}

#[tokio::test]
async fn results_of_different_fingerprints_are_never_ranked_together() {
    let app = spawn_app().await;
    // Two seeds of one method by one build, one seed by another build and
    // one made before builds were identified.
    evaluated(&app, 0, 0.9, Some("aaaaaaaaaaaaaaaa")).await;
    evaluated(&app, 1, 0.7, Some("aaaaaaaaaaaaaaaa")).await;
    evaluated(&app, 2, 0.1, Some("bbbbbbbbbbbbbbbb")).await;
    evaluated(&app, 3, 0.5, None).await;

    let (s, board) = app.get_json("/api/v1/leaderboards/aligning").await;
    assert_eq!(s, 200, "{board}");
    let rows: Vec<&serde_json::Value> = board["rows"]
        .as_array()
        .expect("rows")
        .iter()
        .filter(|r| r["method"] == "Mine")
        .collect();
    let mut seen: Vec<(Option<String>, u64, f64)> = rows
        .iter()
        .map(|r| {
            (
                r["physics_fingerprint"].as_str().map(str::to_string),
                r["n_seeds"].as_u64().unwrap(),
                r["success"]["mean"].as_f64().unwrap(),
            )
        })
        .collect();
    seen.sort_by(|a, b| a.0.cmp(&b.0));
    assert_eq!(seen.len(), 3, "{rows:?}");
    assert_eq!(seen[0], (None, 1, 0.5));
    assert_eq!(seen[1].0.as_deref(), Some("aaaaaaaaaaaaaaaa"));
    assert_eq!(seen[1].1, 2, "the same build's seeds are averaged");
    assert!((seen[1].2 - 0.8).abs() < 1e-12);
    assert_eq!(seen[2], (Some("bbbbbbbbbbbbbbbb".into()), 1, 0.1));

    // The API says which build this server is (its canary is off in tests).
    let (s, build) = app.get_json("/api/v1/build").await;
    assert_eq!(s, 200, "{build}");
    assert_eq!(build["evaluator_version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(build["canary"]["state"], "off");

    // The page ranks each build in a table of its own, each from 1, and says why.
    let (s, page) = app.get_text("/tasks/aligning").await;
    assert_eq!(s, 200);
    let evaluated_tables = page.matches("data-group=\"evaluated\"").count();
    assert_eq!(evaluated_tables, 3, "one table per fingerprint");
    assert!(
        page.contains("physics fingerprint aaaaaaaaaaaaaaaa"),
        "headings name the build"
    );
    assert!(page.contains("physics fingerprint bbbbbbbbbbbbbbbb"));

    // d3il tables keeps the cells apart, with the reason in the row's
    // annotation (tables/tests/tables/evaluated.rs: separate rows).
    let cells = app.state().store.result_cells(None).await.expect("cells");
    let mine: Vec<&ResultCell> = cells.iter().filter(|c| c.method == "Mine").collect();
    assert_eq!(mine.len(), 3);
    let builds: Vec<Option<&str>> = mine.iter().map(|c| c.build.as_deref()).collect();
    assert!(
        builds
            .iter()
            .any(|b| b.is_some_and(|l| l.contains("physics fingerprint bbbbbbbbbbbbbbbb"))),
        "{builds:?}"
    );
    assert!(
        mine.iter().all(|c| !c
            .initial_states
            .as_deref()
            .unwrap_or("")
            .contains("fingerprint")),
        "the initial-states label says only which states"
    );
}
