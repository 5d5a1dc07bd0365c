//! Races and suites are metered by their evaluations over HTTP on 127.0.0.1,
//! on SQLite and PostgreSQL: a race needs the racer's own submission, races
//! at once are capped, and a race is cancelled by its starter or an admin
//! (audited), its running worker stopped.

use d3il_server::config::QuotaLimits;
use d3il_test_support::server::*;
use serde_json::{json, Value};

/// An app with quotas `limits` whose race slot's worker runs until it is
/// killed (a race stays running until it is cancelled).
async fn app_with_endless_races(
    b: Backend,
    limits: QuotaLimits,
) -> (TestServer, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let worker = dir.path().join("endless.sh");
    std::fs::write(
        &worker,
        format!(
            "#!/bin/sh\ncat > /dev/null\necho started >> '{}'\nsleep 600\n",
            dir.path().join("started").display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&worker, std::fs::Permissions::from_mode(0o755)).unwrap();
    let app = spawn_app_with(Options {
        backend: b,
        worker_exe: Some(worker),
        ..Options::default()
    })
    .await;
    (with_quotas(app, limits).await, dir)
}

async fn race_as(app: &TestServer, token: &str, a: i64, b: i64) -> (u16, Value, Option<String>) {
    race_at(app, "/api/v1/races", token, a, b).await
}

/// `race_as` at `path`: `/api/v1/races`, or its deprecated alias.
async fn race_at(
    app: &TestServer,
    path: &str,
    token: &str,
    a: i64,
    b: i64,
) -> (u16, Value, Option<String>) {
    let r = app
        .http
        .post(app.url(path))
        .bearer_auth(token)
        .json(&json!({"a": a, "b": b, "protocol": "quick"}))
        .send()
        .await
        .unwrap();
    answer_with_retry(r).await
}

async fn cancel_race_as(app: &TestServer, token: &str, id: i64) -> (u16, Value) {
    let r = app
        .http
        .post(app.url(&format!("/api/v1/races/{id}/cancel")))
        .bearer_auth(token)
        .send()
        .await
        .unwrap();
    assert!(r.headers().get("deprecation").is_none());
    (r.status().as_u16(), r.json().await.unwrap())
}

/// Cancels race `id` through the deprecated alias
/// `/api/v1/comparisons/{id}/cancel`: the same answer, with the
/// deprecation note naming the successor.
async fn cancel_race_by_old_route(app: &TestServer, token: &str, id: i64) -> (u16, Value) {
    let r = app
        .http
        .post(app.url(&format!("/api/v1/comparisons/{id}/cancel")))
        .bearer_auth(token)
        .send()
        .await
        .unwrap();
    assert_eq!(r.headers()["deprecation"], "true");
    assert_eq!(
        r.headers()["link"],
        format!("</api/v1/races/{id}/cancel>; rel=\"successor-version\"").as_str()
    );
    (r.status().as_u16(), r.json().await.unwrap())
}

/// Waits until no worker process running `script` is left (30 s at most):
/// a cancelled race's worker is stopped.
async fn workers_stop(script: &str) {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        let alive = std::process::Command::new("pgrep")
            .args(["-f", script])
            .output()
            .unwrap();
        if !alive.status.success() {
            return;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "the cancelled race's worker still runs"
        );
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
}

/// Issue 52, item 1 and the cancel route of item 2: races and suites are
/// metered by their evaluations, a race needs the racer's own submission,
/// races at once are capped, and a race is cancelled by its starter or an
/// admin (audited), its running worker killed.
async fn races_and_suites_are_metered_in_evaluations(b: Backend) {
    let (app, dir) = app_with_endless_races(
        b,
        QuotaLimits {
            per_day: 20,
            total: 100,
            concurrent: 16,
            races: 1,
        },
    )
    .await;
    let store = &app.state().store;
    let erin = store.create_token("erin").await.unwrap();
    let dave = store.create_token("dave").await.unwrap();
    let admin = store.create_token_with("op52", true).await.unwrap();
    let (s, e1, _) = submit_as(&app, &erin, &fields("Erin", 0)).await;
    assert_eq!(s, 201, "{e1}");
    let (s, e2, _) = submit_as(&app, &erin, &fields("Erin", 1)).await;
    assert_eq!(s, 201, "{e2}");
    let (e1, e2) = (e1["id"].as_i64().unwrap(), e2["id"].as_i64().unwrap());

    // A token with no submission of its own races nobody: 429, saying why.
    let (s, refused, _) = race_as(&app, &dave, e1, e2).await;
    assert_eq!(s, 429, "{refused}");
    assert_eq!(refused["error"]["code"], "quota_exceeded");
    assert!(
        refused["error"]["message"]
            .as_str()
            .unwrap()
            .contains("a race needs one of your own submissions"),
        "{refused}"
    );
    let (_, who) = get_json_as(&app, &dave, "/api/v1/whoami").await;
    assert_eq!(
        who["quota"]["per_day"]["used"], 0,
        "refusals are not counted: {who}"
    );

    // With one of its own, against another's public one: accepted, and
    // counted as two evaluations and one race.
    let (s, d1, _) = submit_as(&app, &dave, &fields("Dave", 0)).await;
    assert_eq!(s, 201, "{d1}");
    let d1 = d1["id"].as_i64().unwrap();
    let (s, race, _) = race_as(&app, &dave, d1, e1).await;
    assert_eq!(s, 202, "{race}");
    let race = race["id"].as_i64().unwrap();
    let (_, who) = get_json_as(&app, &dave, "/api/v1/whoami").await;
    let q = &who["quota"];
    assert_eq!(
        (
            q["per_day"]["used"].as_i64(),
            q["concurrent"]["used"].as_i64(),
            q["races"]["used"].as_i64()
        ),
        (Some(3), Some(3), Some(1)),
        "{who}"
    );
    assert!(
        q["summary"]
            .as_str()
            .unwrap()
            .contains("0 of 1 races at once left"),
        "{who}"
    );

    // The race slot runs it (its worker starts and keeps running).
    let started = dir.path().join("started");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while !started.exists() {
        assert!(
            std::time::Instant::now() < deadline,
            "the race never started"
        );
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    let (_, running) = app.get_json(&format!("/api/v1/races/{race}")).await;
    assert_eq!(running["status"], "running", "{running}");

    // A second race at once is past the cap: 429 naming it, Retry-After.
    let (s, capped, retry) = race_as(&app, &dave, d1, e2).await;
    assert_eq!(s, 429, "{capped}");
    let m = capped["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("1 races of yours are queued or running (limit 1 at once, --max-queued-races)"),
        "{m}"
    );
    assert_eq!(retry.as_deref(), Some("60"));

    let script_path = dir.path().join("endless.sh").display().to_string();
    let seen = std::process::Command::new("pgrep")
        .args(["-f", &script_path])
        .output()
        .unwrap();
    assert!(
        seen.status.success(),
        "the running race's worker is visible"
    );
    // Only its starter or an admin cancels it.
    let (s, body) = cancel_race_as(&app, &erin, race).await;
    assert_eq!(s, 403, "{body}");
    let (s, body) = cancel_race_as(&app, &dave, race).await;
    assert_eq!(s, 200, "{body}");
    assert_eq!(
        (body["status"].as_str(), body["cancelled_by"].as_str()),
        (Some("cancelled"), Some("dave"))
    );
    let (s, body) = cancel_race_as(&app, &dave, race).await;
    assert_eq!(s, 409, "{body}");
    // Its worker is stopped: no `sleep 600` of this test is left.
    let script = dir.path().join("endless.sh").display().to_string();
    workers_stop(&script).await;
    // The cap is free again; an admin cancels the next one, audited.
    let (s, second, _) = race_as(&app, &dave, d1, e2).await;
    assert_eq!(s, 202, "{second}");
    let second = second["id"].as_i64().unwrap();
    // It runs (a second worker started), then an admin cancels it.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::fs::read_to_string(&started)
        .unwrap_or_default()
        .lines()
        .count()
        < 2
    {
        assert!(
            std::time::Instant::now() < deadline,
            "the second race never started"
        );
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    let (s, body) = cancel_race_by_old_route(&app, &admin, second).await;
    assert_eq!(s, 200, "{body}");
    assert_eq!(body["status"], "cancelled", "{body}");
    workers_stop(&script).await;
    let log = store.audit_log(10).await.unwrap();
    let targets: Vec<(String, String, String)> = log
        .iter()
        .filter(|e| e.action == "cancel_race")
        .map(|e| (e.actor.clone(), e.target.clone(), e.action.clone()))
        .collect();
    assert!(
        targets.contains(&(
            "op52".into(),
            format!("race {second}"),
            "cancel_race".into()
        )),
        "{log:?}"
    );
    assert!(
        targets.contains(&("dave".into(), format!("race {race}"), "cancel_race".into())),
        "{log:?}"
    );

    // A withdrawn submission is no longer public: nobody races against it.
    let (s, _) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/submissions/{e2}/withdraw"),
        Some(json!({"reason": "spam"})),
    )
    .await;
    assert_eq!(s, 200);
    let (s, body, _) = race_as(&app, &dave, d1, e2).await;
    assert_eq!(
        (s, body["error"]["field"].as_str()),
        (400, Some("b")),
        "{body}"
    );
    // The deprecated alias of `POST /api/v1/races` checks the same way.
    let (s, old, _) = race_at(&app, "/api/v1/comparisons", &dave, d1, e2).await;
    assert_eq!((s, &old), (400, &body));

    // A robustness suite counts its level 0 and every level: Aligning's
    // state suite is 14. Used so far: 1 + 2 + 2 = 5 of 20 today.
    let mut suite = fields("DaveSuite", 0);
    suite.push(("suite".into(), "robustness".into()));
    let (s, body, _) = submit_as(&app, &dave, &suite).await;
    assert_eq!(s, 201, "{body}");
    assert_eq!(body["quota"]["per_day"]["used"], 19, "{body}");
    let mut again = fields("DaveSuite", 1);
    again.push(("suite".into(), "robustness".into()));
    let (s, body, retry) = submit_as(&app, &dave, &again).await;
    assert_eq!(s, 429, "{body}");
    let m = body["error"]["message"].as_str().unwrap();
    assert!(m.starts_with("daily evaluation quota reached: 19 evaluations in the last 24 hours (limit 20, --quota-per-day) and the robustness suite of aligning (state observations: level 0 and 13 levels) counts 14;"), "{m}");
    assert!(
        retry.is_some() && body["error"]["next_submission_at"].is_i64(),
        "{body}"
    );
}

on_both_backends!(races_and_suites_are_metered_in_evaluations);
