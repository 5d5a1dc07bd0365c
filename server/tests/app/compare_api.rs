//! Issue 16 on the server: `GET /api/v1/compare`, and the submission page and
//! results API naming the initial-state set and counting rollouts that ended
//! with an unstable simulation. Real SQLite, real HTTP on 127.0.0.1.

use d3il_protocol::*;
use d3il_test_support::server::*;
use d3il_test_support::{pushing_result, SynthRollout};
use serde_json::Value;

/// A Pushing paper-protocol result on the original contexts: 30 states × 16
/// rollouts, state c succeeding in `k(c)` of 16 rollouts; the first
/// `unstable` rollouts are failures that ended unstable.
fn result(k: impl Fn(usize) -> usize, unstable: usize) -> EvalResult {
    pushing_result(ProtocolKind::Paper, |c, r| SynthRollout {
        success: r < k(c),
        label: r % 2,
        unstable: c * 16 + r < unstable,
    })
}

async fn submit(app: &TestServer, method: &str, task: &str) -> i64 {
    let m = manifest(task);
    let r = app
        .submit(
            &[
                ("method", method),
                ("task", task),
                ("training_seed", "0"),
                ("protocol", "paper"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 201);
    r.json::<Value>().await.unwrap()["id"].as_i64().unwrap()
}

/// Completes the oldest queued job with `result`, as a worker would.
async fn complete(app: &TestServer, result: &EvalResult) -> i64 {
    let store = &app.state().store;
    let claimed = store.claim_job("test", 60).await.unwrap().unwrap();
    store
        .complete_job(claimed.job.id, claimed.submission.id, result, &[])
        .await
        .unwrap();
    claimed.submission.id
}

#[tokio::test]
async fn compare_endpoint_pairs_two_submissions_by_initial_state() {
    let app = spawn_app().await;
    let a = submit(&app, "A", "pushing").await;
    let b = submit(&app, "B", "pushing").await;
    let c = submit(&app, "C", "pushing").await;
    // A succeeds in 12 of 16 rollouts everywhere, B in 8 (gap 0.25); C like
    // B but with 300 of its 480 rollouts ended unstable.
    assert_eq!(complete(&app, &result(|_| 12, 0)).await, a);
    assert_eq!(complete(&app, &result(|_| 8, 0)).await, b);
    assert_eq!(complete(&app, &result(|_| 8, 300)).await, c);

    let (s, v) = app.get_json(&format!("/api/v1/compare?a={a}&b={b}")).await;
    assert_eq!(s, 200, "{v}");
    let d = &v["success_rate"];
    assert!(
        (d["difference"]["value"].as_f64().unwrap() - 0.25).abs() < 1e-9,
        "{v}"
    );
    assert!(d["p_value"].as_f64().unwrap() < 0.01, "{v}");
    assert!(d["difference"]["ci_low"].as_f64().unwrap() <= 0.25);
    assert_eq!(v["initial_states"], "pushing-v2.json");
    assert_eq!(v["n_contexts"], 30);

    let (s, v) = app.get_json(&format!("/api/v1/compare?a={a}&b={a}")).await;
    assert_eq!(s, 200, "{v}");
    assert_eq!(v["success_rate"]["difference"]["value"], 0.0);
    assert_eq!(v["success_rate"]["p_value"], 1.0);
    assert_eq!(v["conditional_entropy"]["p_value"], 1.0);

    // Clear errors for bad requests.
    let (s, v) = app.get_json(&format!("/api/v1/compare?a={a}")).await;
    assert_eq!(s, 400, "{v}");
    assert_eq!(v["error"]["field"], "b");
    let (s, v) = app.get_json("/api/v1/compare?a=x&b=1").await;
    assert_eq!(s, 400, "{v}");
    let (s, v) = app
        .get_json(&format!("/api/v1/compare?a={a}&b=999999"))
        .await;
    assert_eq!(s, 404, "{v}");
    // Results on a different set are not paired.
    let mut other = result(|_| 8, 0);
    other.manifest.initial_states = "pushing-v1.json".into();
    other.manifest.initial_states_sha256 = "932d".into();
    let d = submit(&app, "D", "pushing").await;
    assert_eq!(complete(&app, &other).await, d);
    let (s, v) = app.get_json(&format!("/api/v1/compare?a={a}&b={d}")).await;
    assert_eq!(s, 400, "{v}");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("initial-state set"),
        "{v}"
    );

    // The results API and the page name the set and count unstable rollouts.
    let (_, r) = app
        .get_json(&format!("/api/v1/submissions/{c}/results"))
        .await;
    assert_eq!(r["rollouts_ended_unstable"], 300, "{r}");
    assert_eq!(r["mostly_unstable"], true);
    assert_eq!(r["initial_states_label"], "the original D3IL test contexts");
    assert_eq!(r["rollouts"][0]["failure"]["reason"], "sim_unstable");
    let (_, page) = app.get_text(&format!("/submissions/{c}")).await;
    assert!(
        page.contains("Rollouts ended unstable: 300 of 480"),
        "{page}"
    );
    assert!(page.contains("id=\"unstable-warning\""));
    assert!(page.contains("pushing-v2.json (the original D3IL test contexts)"));
    let (_, page) = app.get_text(&format!("/submissions/{a}")).await;
    assert!(page.contains("Rollouts ended unstable: 0 of 480"));
    assert!(!page.contains("id=\"unstable-warning\""));
    let (_, page) = app.get_text(&format!("/submissions/{d}")).await;
    assert!(page.contains("pushing-v1.json (our sample)"), "{page}");
    // The leaderboard says which initial states each evaluated row used.
    let (_, board) = app.get_text("/tasks/pushing").await;
    assert!(board.contains("badge-states"), "{board}");
    assert!(board.contains(">the original D3IL test contexts</span>"));
    assert!(board.contains(">our sample</span>"));
    let (_, v) = app.get_json("/api/v1/leaderboards/pushing").await;
    let labels: Vec<&str> = v["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|r| r["initial_states_label"].as_str())
        .collect();
    assert!(
        labels.contains(&"our sample") && labels.contains(&"the original D3IL test contexts"),
        "{v}"
    );
    // Sorting pages carry the protocol caveat.
    let (_, board) = app.get_text("/tasks/sorting-2").await;
    assert!(board.contains("id=\"sorting-caveat\""));
    assert!(board.contains("60 × 8 (some agents 600 × 1)"));
}

/// A finished submission's results document is rendered once and then
/// served from memory (issue 17 item 8): a change behind the server's back
/// does not reach it, while a submission without a result is not cached.
#[tokio::test]
async fn results_of_a_finished_submission_are_served_from_memory() {
    let app = spawn_app().await;
    let a = submit(&app, "A", "pushing").await;
    let path = format!("/api/v1/submissions/{a}/results");
    let (s, _) = app.get_text(&path).await;
    assert_eq!(s, 404, "no result yet, nothing cached");
    assert_eq!(complete(&app, &result(|_| 12, 0)).await, a);
    let (s, first) = app.get_text(&path).await;
    assert_eq!(s, 200, "{first}");
    let v: Value = serde_json::from_str(&first).unwrap();
    assert_eq!(v["metrics"]["success_rate"]["value"], 0.75, "{v}");
    assert_served_from_memory(&app, a, &path, &first).await;
}

/// The status document of a submission embeds its results: once completed
/// it is rendered once too, while a queued one is built afresh on every poll.
#[tokio::test]
async fn status_of_a_completed_submission_is_served_from_memory() {
    let app = spawn_app().await;
    let a = submit(&app, "A", "pushing").await;
    let path = format!("/api/v1/submissions/{a}");
    let (s, queued) = app.get_text(&path).await;
    assert_eq!(s, 200, "{queued}");
    let v: Value = serde_json::from_str(&queued).unwrap();
    assert_eq!(v["status"], "queued", "{v}");
    assert_eq!(
        app.state().finished.len(),
        0,
        "a queued submission is not cached"
    );
    assert_eq!(complete(&app, &result(|_| 12, 0)).await, a);
    let (s, first) = app.get_text(&path).await;
    assert_eq!(s, 200, "{first}");
    let v: Value = serde_json::from_str(&first).unwrap();
    assert_eq!(v["status"], "completed", "{v}");
    assert_eq!(v["result"]["metrics"]["success_rate"]["value"], 0.75, "{v}");
    assert_served_from_memory(&app, a, &path, &first).await;
}

/// Changes submission `id`'s stored result behind the server's back; `path`
/// must still answer `first`, from the one cached document.
async fn assert_served_from_memory(app: &TestServer, id: i64, path: &str, first: &str) {
    sqlx::query("UPDATE results SET success_rate = 0.5 WHERE submission_id = ?")
        .bind(id)
        .execute(app.state().store.sqlite_pool().expect("a SQLite store"))
        .await
        .unwrap();
    let (s, again) = app.get_text(path).await;
    assert_eq!(s, 200);
    assert_eq!(again, first, "served from memory");
    assert_eq!(app.state().finished.len(), 1);
}
