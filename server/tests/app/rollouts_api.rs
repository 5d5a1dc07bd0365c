//! What a policy did (issue 31), on a real server with a real SQLite store:
//! the rollout lists' filters and pages, 400s that say what is allowed,
//! one rollout's record with its trace, results stored before traces (still
//! listed, saying what was not recorded), and the failure browser and
//! rollout page of the HTML front end.

use crate::rollout_support;

use d3il_test_support::server::*;
use rollout_support::*;
use serde_json::Value;

fn numbers(list: &Value) -> Vec<u64> {
    list["items"]
        .as_array()
        .expect("items")
        .iter()
        .map(|i| i["number"].as_u64().expect("number"))
        .collect()
}

async fn bad(app: &TestServer, path: &str, field: &str, says: &[&str]) {
    let (s, v) = app.get_json(path).await;
    assert_eq!(s, 400, "{path}: {v}");
    assert_eq!(v["error"]["code"], "invalid_field", "{path}");
    assert_eq!(v["error"]["field"], field, "{path}");
    let message = v["error"]["message"].as_str().unwrap_or_default();
    for s in says {
        assert!(message.contains(s), "{path}: `{message}` should say `{s}`");
    }
}

#[tokio::test]
async fn filters_narrow_the_list_and_pages_split_it() {
    let app = spawn_app().await;
    let result = traced_result(false);
    let id = finished_submission(&app.state().store, "Tracer", &result).await;
    let base = format!("/api/v1/submissions/{id}/rollouts");

    let (s, all) = app.get_json(&base).await;
    assert_eq!(s, 200, "{all}");
    assert_eq!(all["total"], 480);
    assert_eq!(all["all"], 480);
    assert_eq!(
        (
            all["page"].as_u64(),
            all["per_page"].as_u64(),
            all["pages"].as_u64()
        ),
        (Some(1), Some(50), Some(10))
    );
    assert_eq!(numbers(&all), (0..50).collect::<Vec<_>>());
    assert_eq!(all["behaviours"], serde_json::json!(["0", "1"]));
    assert!(all["traces_note"].is_null());
    let first = &all["items"][0];
    assert_eq!(
        first["links"]["page"],
        format!("/submissions/{id}/rollouts/0")
    );
    assert_eq!(first["links"]["record"], format!("{base}/0"));
    assert_eq!(first["links"]["video"], format!("{base}/0/video"));
    assert_eq!(first["has_trace"], true);
    assert_eq!(
        first["ending"], "time_limit",
        "(0, 0) fails in an even state"
    );

    // Each outcome narrows the list to the rollouts that have it.
    let failures = result.rollouts.iter().filter(|r| !r.success).count();
    let expect = [
        ("success", 480 - failures),
        ("failure", failures),
        ("unstable", 1),
        (
            "time_limit",
            result
                .rollouts
                .iter()
                .filter(|r| r.ending == Some(d3il_protocol::Ending::TimeLimit))
                .count(),
        ),
    ];
    for (outcome, n) in expect {
        let (s, v) = app
            .get_json(&format!("{base}?outcome={outcome}&per_page=500"))
            .await;
        assert_eq!(s, 200, "{v}");
        assert_eq!(v["total"].as_u64(), Some(n as u64), "{outcome}");
        assert_eq!(v["items"].as_array().unwrap().len(), n, "{outcome}");
        assert!(n < 480 && n > 0, "{outcome}: a real narrowing");
        let counted = v["outcomes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["outcome"] == outcome)
            .unwrap()["count"]
            .as_u64();
        assert_eq!(counted, Some(n as u64), "{outcome} count");
    }
    let (_, v) = app.get_json(&format!("{base}?outcome=unstable")).await;
    let unstable = &v["items"][0];
    assert_eq!(
        (unstable["context"].as_u64(), unstable["rollout"].as_u64()),
        (Some(4), Some(2))
    );
    assert_eq!(unstable["ending"], "sim_unstable");
    assert_eq!(unstable["failure"]["step"], 17);
    assert_eq!(unstable["ending_text"], "the simulation became unstable");

    // Initial state, behaviour and outcome together.
    let (_, v) = app.get_json(&format!("{base}?context=3")).await;
    assert_eq!(numbers(&v), (48..64).collect::<Vec<_>>());
    let (_, v) = app
        .get_json(&format!("{base}?context=3&behaviour=1&outcome=failure"))
        .await;
    let want: Vec<u64> = (0..16u64)
        .filter(|i| i % 2 == 1 && (3 + i) % 3 == 0)
        .map(|i| 48 + i)
        .collect();
    assert_eq!(numbers(&v), want);
    assert_eq!(v["filters"]["outcome"], "failure");
    assert_eq!(v["filters"]["behaviour"], "1");
    assert_eq!(v["filters"]["context"], 3);
    // Empty values filter nothing (an unset form select).
    let (_, v) = app
        .get_json(&format!("{base}?outcome=&behaviour=&context="))
        .await;
    assert_eq!(v["total"], 480);

    // Pages.
    let (_, v) = app.get_json(&format!("{base}?page=2&per_page=100")).await;
    assert_eq!(numbers(&v), (100..200).collect::<Vec<_>>());
    assert_eq!(v["pages"], 5);
    let (_, v) = app.get_json(&format!("{base}?page=10")).await;
    assert_eq!(numbers(&v), (450..480).collect::<Vec<_>>());
    let (_, v) = app
        .get_json(&format!("{base}?context=3&behaviour=0&outcome=unstable"))
        .await;
    assert_eq!(
        (v["total"].as_u64(), v["pages"].as_u64()),
        (Some(0), Some(0)),
        "nothing matches: page 1 of nothing"
    );

    // Values that name nothing say what is allowed.
    bad(
        &app,
        &format!("{base}?outcome=crashed"),
        "outcome",
        &["`crashed`", "success, failure, unstable or time_limit"],
    )
    .await;
    bad(
        &app,
        &format!("{base}?context=30"),
        "context",
        &["0 to 29", "`30`"],
    )
    .await;
    bad(
        &app,
        &format!("{base}?context=two"),
        "context",
        &["0 to 29"],
    )
    .await;
    bad(
        &app,
        &format!("{base}?behaviour=2"),
        "behaviour",
        &["`2`", "0, 1"],
    )
    .await;
    bad(&app, &format!("{base}?page=0"), "page", &["from 1"]).await;
    bad(
        &app,
        &format!("{base}?page=11"),
        "page",
        &["last page (10)"],
    )
    .await;
    bad(
        &app,
        &format!("{base}?per_page=501"),
        "per_page",
        &["1 to 500"],
    )
    .await;

    // A submission without a result, and one that does not exist.
    let (s, v) = app.get_json("/api/v1/submissions/999/rollouts").await;
    assert_eq!((s, v["error"]["code"].as_str()), (404, Some("not_found")));
}

#[tokio::test]
async fn a_record_comes_with_its_trace_and_actions() {
    let app = spawn_app().await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let (s, v) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/37"))
        .await;
    assert_eq!(s, 200, "{v}");
    // Rollout 37 = initial state 2, rollout 5 (16 per state).
    let rec = &v["rollouts"][0];
    assert_eq!(
        (rec["context_index"].as_u64(), rec["rollout_index"].as_u64()),
        (Some(2), Some(5))
    );
    assert_eq!(v["rollouts"].as_array().unwrap().len(), 1);
    assert_eq!(v["manifest"]["task"], "pushing");
    assert_eq!(v["manifest"]["rollouts_per_context"], 16);
    // The packed trace, as stored, reads back as the one packed.
    let trace: d3il_protocol::RolloutTrace =
        serde_json::from_value(rec["trace"].clone()).expect("a trace");
    assert_eq!(
        trace,
        trace_of(2, 5, rec["steps"].as_u64().unwrap() as usize)
    );
    let steps = rec["steps"].as_u64().unwrap() as usize;
    // The actions unpacked, as f32 written shortest (bit for bit back).
    let got: Vec<Vec<f32>> = serde_json::from_value(v["actions"].clone()).unwrap();
    assert_eq!(got, actions(2, 5, steps));
    assert_eq!(v["summary"]["number"], 37);
    assert!(v["trace_note"].is_null());

    for n in ["480", "9999"] {
        let (s, v) = app
            .get_json(&format!("/api/v1/submissions/{id}/rollouts/{n}"))
            .await;
        assert_eq!(s, 404, "{v}");
        assert!(
            v["error"]["message"].as_str().unwrap().contains("0 to 479"),
            "{v}"
        );
    }
    let (s, _) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/x"))
        .await;
    assert_eq!(s, 404);
}

fn trace_of(c: usize, i: usize, steps: usize) -> d3il_protocol::RolloutTrace {
    trace(c, i, steps)
}

#[tokio::test]
async fn copies_of_a_rollout_simulated_once_share_its_trace() {
    let app = spawn_app().await;
    let result = traced_result(true);
    let id = finished_submission(&app.state().store, "Once", &result).await;
    // Only each state's rollout 0 stored a trace.
    let stored = app.state().store.rollout_traces(id, false).await.unwrap();
    assert_eq!(stored.len(), 30);
    let (_, list) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts?per_page=500"))
        .await;
    assert!(list["items"]
        .as_array()
        .unwrap()
        .iter()
        .all(|i| i["has_trace"] == true));
    // Rollout 19 = state 1, copy 3: the trace of state 1's rollout 0.
    let (s, v) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/19"))
        .await;
    assert_eq!(s, 200);
    let rec = &v["rollouts"][0];
    assert_eq!(
        (rec["context_index"].as_u64(), rec["rollout_index"].as_u64()),
        (Some(1), Some(3))
    );
    let trace: d3il_protocol::RolloutTrace = serde_json::from_value(rec["trace"].clone()).unwrap();
    let first = result.rollout(16).unwrap();
    assert_eq!(Some(&trace), result.trace_of(first));
    assert_eq!(
        result.trace_of(result.rollout(19).unwrap()),
        Some(&trace),
        "as EvalResult::trace_of says"
    );
}

#[tokio::test]
async fn results_stored_before_traces_are_still_listed() {
    let app = spawn_app().await;
    let id = finished_submission(&app.state().store, "Elder", &old_result()).await;
    let base = format!("/api/v1/submissions/{id}/rollouts");
    let (s, v) = app.get_json(&base).await;
    assert_eq!(s, 200, "{v}");
    assert_eq!(v["total"], 480);
    let note = v["traces_note"].as_str().expect("a note");
    assert!(
        note.contains("not recorded for results stored before"),
        "{note}"
    );
    let item = &v["items"][0];
    assert_eq!(item["has_trace"], false);
    assert!(item["ending"].is_null());
    assert!(item["links"]["video"].is_null());
    assert!(item["ending_text"]
        .as_str()
        .unwrap()
        .contains("not recorded"));
    // Without endings, a rollout that took the protocol's 400 steps ran to
    // the limit (unless it became unstable).
    let (_, v) = app.get_json(&format!("{base}?outcome=time_limit")).await;
    assert_eq!(v["total"], 479);
    let (_, v) = app.get_json(&format!("{base}?outcome=unstable")).await;
    assert_eq!(v["total"], 1);
    // The record has no trace and says why; the video and pictures too.
    let (s, v) = app.get_json(&format!("{base}/3")).await;
    assert_eq!(s, 200);
    assert!(v["rollouts"][0].get("trace").is_none());
    assert!(v["actions"].is_null());
    assert!(v["trace_note"].as_str().unwrap().contains("not recorded"));
    let (s, v) = app.get_json(&format!("{base}/3/video")).await;
    assert_eq!(s, 404, "{v}");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("not recorded"),
        "{v}"
    );
    for path in [
        format!("/plots/submissions/{id}/rollouts/3/paths.svg"),
        format!("/plots/submissions/{id}/paths.svg"),
        format!("/plots/submissions/{id}/starts.svg"),
    ] {
        let (s, svg) = app.get_text(&path).await;
        assert_eq!(s, 200, "{path}");
        assert!(svg.contains("class=\"no-data\""), "{path}: {svg}");
    }
    let (_, svg) = app
        .get_text(&format!("/plots/submissions/{id}/paths.svg"))
        .await;
    assert!(
        svg.contains("no rollout traces: stored before they were recorded"),
        "{svg}"
    );
    // The results document still reads, with no endings in it.
    let (s, v) = app
        .get_json(&format!("/api/v1/submissions/{id}/results"))
        .await;
    assert_eq!(s, 200);
    assert!(v["rollouts"][0].get("ending").is_none());
    // The pages say what was not recorded.
    let (s, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert_eq!(s, 200);
    assert!(page.contains("id=\"traces-note\""), "{page}");
    let (s, page) = app.get_text(&format!("/submissions/{id}/rollouts/3")).await;
    assert_eq!(s, 200);
    assert!(
        page.contains("id=\"no-trace\"") && page.contains("not recorded for results stored before")
    );
    assert!(!page.contains("<video"));
}

#[tokio::test]
async fn the_failure_browser_filters_with_a_plain_form() {
    let app = spawn_app().await;
    let result = traced_result(false);
    let id = finished_submission(&app.state().store, "Tracer", &result).await;
    let rows = |page: &str| page.matches("class=\"rollout-row\"").count();

    let (s, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert_eq!(s, 200);
    assert!(page.contains("id=\"rollout-filters\""));
    assert_eq!(rows(&page), 50, "the first page of all rollouts");
    assert!(page.contains("480 of 480 rollouts, page 1 of 10"));
    assert!(page.contains(&format!("href=\"/submissions/{id}?page=2#rollouts\"")));
    // The per-state table links to the state's rollouts and failures.
    assert!(page.contains(&format!("href=\"/submissions/{id}?context=3#rollouts\"")));
    assert!(page.contains(&format!(
        "href=\"/submissions/{id}?context=3&amp;outcome=failure#rollouts\""
    )));
    // Pictures of every rollout and of the initial states.
    assert!(page.contains("id=\"paths-plot\"") && page.contains("id=\"starts-plot\""));
    assert!(
        page.contains("Every rollout's TCP path"),
        "the overlay, not the Avoiding figure"
    );

    let (s, page) = app
        .get_text(&format!("/submissions/{id}?outcome=unstable"))
        .await;
    assert_eq!(s, 200);
    assert_eq!(rows(&page), 1);
    assert!(
        page.contains(&format!("href=\"/submissions/{id}/rollouts/66\"")),
        "state 4, rollout 2"
    );
    assert!(page.contains("<option value=\"unstable\" selected>unstable (1)</option>"));

    let failures = result
        .rollouts
        .iter()
        .filter(|r| !r.success && r.context_index == 3)
        .count();
    let (_, page) = app
        .get_text(&format!("/submissions/{id}?outcome=failure&context=3"))
        .await;
    assert_eq!(rows(&page), failures);

    let (s, page) = app
        .get_text(&format!("/submissions/{id}?outcome=exploded"))
        .await;
    assert_eq!(s, 400);
    assert!(page.contains("id=\"rollouts-error\""));
    assert!(page.contains("success, failure, unstable or time_limit"));
    assert_eq!(rows(&page), 50, "the whole list under the message");

    // The rollout page: how it ended, the video, the pictures, the record.
    let (s, page) = app
        .get_text(&format!("/submissions/{id}/rollouts/66"))
        .await;
    assert_eq!(s, 200);
    assert!(page.contains("the simulation became unstable"));
    assert!(page.contains("id=\"failure\"") && page.contains("at step 17"));
    assert!(page.contains("<video controls preload=\"metadata\""));
    assert!(page.contains(&format!("src=\"/submissions/{id}/rollouts/66/video\"")));
    assert!(page.contains(&format!("href=\"/api/v1/submissions/{id}/rollouts/66\"")));
    assert!(
        page.contains("class=\"tcp-path"),
        "the top-down picture inline"
    );
    let (s, _) = app
        .get_text(&format!("/submissions/{id}/rollouts/480"))
        .await;
    assert_eq!(s, 404);

    // Its pictures on their own.
    let (s, svg) = app
        .get_text(&format!("/api/v1/submissions/{id}/rollouts/66/paths.svg"))
        .await;
    assert_eq!(s, 200);
    assert!(svg.contains("class=\"tcp-path"), "{svg}");
    let (s, svg) = app
        .get_text(&format!("/plots/submissions/{id}/rollouts/66/steps.svg"))
        .await;
    assert_eq!(s, 200);
    assert!(svg.starts_with("<svg") || svg.contains("<svg"), "{svg}");
}

/// Endings and traces go into the store and come back on both backends:
/// each row's own trace, the first rollouts' traces, and NULL for copies.
async fn traces_round_trip(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let result = traced_result(true);
    let id = finished_submission(&store, "Once", &result).await;
    let rows = store.rollouts_for(id).await.unwrap();
    assert_eq!(rows.len(), 480);
    assert_eq!(rows.iter().filter(|r| r.has_trace).count(), 30);
    for (row, rec) in rows.iter().zip(&result.rollouts) {
        assert_eq!(row.ending(), rec.ending);
        assert_eq!(row.has_trace, rec.trace.is_some());
    }
    let firsts = store.rollout_traces(id, true).await.unwrap();
    let all = store.rollout_traces(id, false).await.unwrap();
    assert_eq!(firsts.len(), 30);
    assert_eq!(firsts, all);
    assert_eq!(Some(&firsts[2].2), result.rollouts[32].trace.as_deref());
    let copy = store.rollout_trace(id, 2, 5).await.unwrap();
    assert_eq!(copy, None, "a copy stores no trace");
    let old = finished_submission(&store, "Elder", &old_result()).await;
    assert!(store
        .rollouts_for(old)
        .await
        .unwrap()
        .iter()
        .all(|r| !r.has_trace && r.ending().is_none()));
    assert!(store.rollout_traces(old, false).await.unwrap().is_empty());
}

on_both_backends!(traces_round_trip);
