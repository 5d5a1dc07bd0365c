//! Issue 18: a quick smoke test has its own worker slot and never waits
//! behind a paper run; ETAs come from past runs of the same task,
//! observation type and protocol, or say there is no estimate (never "0 s"). Real server on
//! 127.0.0.1 port 0, real SQLite, real worker processes (shell fixtures
//! speaking the worker's JSON lines).

use d3il_protocol::*;
use d3il_test_support::server::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::Duration;

fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

/// A small quick-protocol Aligning result as the worker prints it.
fn result_line() -> String {
    result_line_once(false)
}

/// [`result_line`] of a deterministic policy (`simulated_once`) or not.
fn result_line_once(once: bool) -> String {
    let outcomes: Vec<d3il_metrics::Outcome> = (0..6)
        .map(|i| d3il_metrics::Outcome::new(i / 3, i % 2 == 0, Some("0")))
        .collect();
    let ev = d3il_metrics::evaluate(
        TaskId::Aligning,
        &outcomes,
        1.0,
        &d3il_metrics::Bootstrap::default(),
    )
    .unwrap();
    let r = EvalResult {
        manifest: ProtocolManifest {
            task: TaskId::Aligning,
            task_version: "fixture".into(),
            obs_type: ObsType::State,
            protocol: ProtocolKind::Quick,
            robot_look: None,
            mjcf_sha256: "a".repeat(64),
            initial_states: "test-v1.json".into(),
            initial_states_sha256: "b".repeat(64),
            mujoco_version: "2.2.2".into(),
            evaluator_version: "fixture".into(),
            n_contexts: 2,
            rollouts_per_context: 3,
            max_steps: 100,
            policy_sha256: "c".repeat(64),
            history: 1,
            horizon: 1,
            execute: 1,
            seed: 0,
            simulated_once: once,
            build: None,
            perturbation: None,
        },
        metrics: ev.metrics,
        per_context: ev.per_context,
        rollouts: (0..6)
            .map(|i| RolloutRecord {
                context_index: i / 3,
                rollout_index: i % 3,
                success: i % 2 == 0,
                behaviour: serde_json::json!(0),
                steps: 40,
                path: None,
                failure: None,
                ending: None,
                trace: None,
            })
            .collect(),
        rollouts_ended_unstable: 0,
    };
    serde_json::to_string(&WorkerMessage::Result(Box::new(r))).unwrap()
}

async fn submit(app: &TestServer, method: &str, task: &str, protocol: &str) -> i64 {
    submit_obs(app, method, task, "state", protocol).await
}

async fn submit_obs(app: &TestServer, method: &str, task: &str, obs: &str, protocol: &str) -> i64 {
    submit_fields(app, method, task, obs, protocol, 1, &[]).await
}

/// A state Aligning quick submission whose manifest declares `history`.
async fn submit_history(app: &TestServer, method: &str, history: usize) -> i64 {
    submit_fields(app, method, "aligning", "state", "quick", history, &[]).await
}

/// A state Aligning quick submission asking for the robustness suite.
async fn submit_suite(app: &TestServer, method: &str) -> i64 {
    let suite = [("suite", "robustness")];
    submit_fields(app, method, "aligning", "state", "quick", 1, &suite).await
}

/// A submission of `task` with the manifest declaring `history`, and the
/// form fields `extra` besides the usual ones.
async fn submit_fields(
    app: &TestServer,
    method: &str,
    task: &str,
    obs: &str,
    protocol: &str,
    history: usize,
    extra: &[(&str, &str)],
) -> i64 {
    let m = manifest(task)
        .replace(r#""obs_type": "state""#, &format!(r#""obs_type": "{obs}""#))
        .replace(r#""history": 1"#, &format!(r#""history": {history}"#));
    let mut fields = vec![
        ("method", method),
        ("task", task),
        ("obs_type", obs),
        ("training_seed", "0"),
        ("protocol", protocol),
        ("manifest", m.as_str()),
    ];
    fields.extend_from_slice(extra);
    let r = app.submit(&fields, Some(fake_onnx())).await;
    let status = r.status();
    let v = r.json::<Value>().await.unwrap();
    assert_eq!(status, 201, "{v}");
    v["id"].as_i64().unwrap()
}

/// Claims the next queued job, which must be submission `id`'s, and
/// completes it at once with [`result_line`]'s result.
async fn complete_next(app: &TestServer, id: i64) {
    complete_next_once(app, id, false).await
}

/// [`complete_next`] with [`result_line_once`]'s result.
async fn complete_next_once(app: &TestServer, id: i64, once: bool) {
    let store = &app.state().store;
    let c = store.claim_job("test", 60).await.unwrap().unwrap();
    assert_eq!(c.submission.id, id);
    let WorkerMessage::Result(r) = serde_json::from_str(&result_line_once(once)).unwrap() else {
        panic!("a result line")
    };
    store.complete_job(c.job.id, id, &r, &[]).await.unwrap();
}

/// Claims the next queued job, which must be submission `id`'s, and fails
/// it for good (a bad model: not retried).
async fn fail_next(app: &TestServer, id: i64) {
    let store = &app.state().store;
    let c = store.claim_job("test", 60).await.unwrap().unwrap();
    assert_eq!(c.submission.id, id);
    let e = WorkerError {
        kind: ErrorKind::BadModel,
        message: "x".into(),
    };
    store
        .fail_attempt(c.job.id, "test", &e, false)
        .await
        .unwrap();
}

async fn status(app: &TestServer, id: i64) -> Value {
    app.get_json(&format!("/api/v1/submissions/{id}")).await.1
}

async fn a_quick_job_runs_on_its_own_slot_while_paper_runs_hold_every_other_slot(b: Backend) {
    let dir = tempfile::tempdir().unwrap();
    let line = dir.path().join("result.jsonl");
    std::fs::write(&line, result_line() + "\n").unwrap();
    // Paper jobs hang (until the wall clock); quick jobs answer at once.
    let worker = script(
        dir.path(),
        "worker.sh",
        &format!(
            "job=$(cat)\ncase \"$job\" in *'\"protocol\":\"paper\"'*) sleep 15 ;; esac\n\
             echo '{{\"type\":\"sandbox\",\"mechanisms\":[]}}'\ncat '{}'",
            line.display()
        ),
    );
    let app = spawn_app_with(Options {
        backend: b,
        workers: 1,
        worker_exe: Some(worker),
        ..Default::default()
    })
    .await;
    let p1 = submit(&app, "PaperOne", "aligning", "paper").await;
    let p2 = submit(&app, "PaperTwo", "aligning", "paper").await;
    let q = submit(&app, "Smoke", "aligning", "quick").await;
    let mut done = None;
    for _ in 0..300 {
        let v = status(&app, q).await;
        if v["status"] == "completed" || v["status"] == "failed" {
            done = Some(v);
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let v = done.expect("the quick job finished while a paper run held the only general slot");
    assert_eq!(v["status"], "completed", "{v}");
    // The paper runs: one running on the general slot, one still waiting.
    let s1 = status(&app, p1).await;
    let s2 = status(&app, p2).await;
    assert_eq!(s1["status"], "running", "{s1}");
    assert_eq!(s2["status"], "queued", "{s2}");
    assert_eq!(s2["queue_position"], 0);
}

async fn etas_come_from_past_runs_of_the_same_task_and_protocol(b: Backend) {
    let app = spawn_app_with(Options {
        backend: b,
        ..Default::default()
    })
    .await; // no worker slots: jobs stay queued
    let first = submit(&app, "First", "pushing", "paper").await;
    // No past run: no estimate, on the API and the page (never "0 s").
    let v = status(&app, first).await;
    assert_eq!(v["eta_seconds"], Value::Null, "{v}");
    let (_, page) = app.get_text(&format!("/submissions/{first}")).await;
    assert!(page.contains("Estimated time to result: no estimate yet"));
    assert!(page.contains("Waiting (position 1 in the queue, 0 ahead)"));
    assert!(!page.contains("Attempt 0"));
    // One finished Pushing paper run (it took under a second: counted as 1 s).
    let store = &app.state().store;
    fail_next(&app, first).await;
    let means = store.mean_job_seconds_by_kind().await.unwrap();
    assert!(means.is_empty(), "a failed job is no basis: {means:?}");
    let second = submit(&app, "Second", "pushing", "paper").await;
    complete_next(&app, second).await;
    let means = store.mean_job_seconds_by_kind().await.unwrap();
    assert_eq!(
        means,
        vec![(
            d3il_server::store::DurationClass::new(
                "pushing".to_string(),
                "state".to_string(),
                "paper".to_string(),
                None
            ),
            0.0
        )],
        "{means:?}"
    );
    // Two queued Pushing paper jobs: 1 s each at the kind's mean; the second
    // waits for the first.
    let a = submit(&app, "Third", "pushing", "paper").await;
    let b = submit(&app, "Fourth", "pushing", "paper").await;
    assert_eq!(status(&app, a).await["eta_seconds"], 1);
    assert_eq!(status(&app, b).await["eta_seconds"], 2);
    let (_, page) = app.get_text(&format!("/submissions/{b}")).await;
    assert!(page.contains("Estimated time to result: 2 s"), "{page}");
    // Another task or protocol has no history yet: no estimate.
    let other = submit(&app, "Fifth", "pushing", "quick").await;
    assert_eq!(status(&app, other).await["eta_seconds"], Value::Null);
    let other = submit(&app, "Sixth", "aligning", "paper").await;
    assert_eq!(status(&app, other).await["eta_seconds"], Value::Null);
}

/// An image evaluation renders two cameras at every step: a state run's time
/// is no estimate for it, nor the reverse.
async fn etas_keep_state_and_image_runs_apart(b: Backend) {
    let app = spawn_app_with(Options {
        backend: b,
        ..Default::default()
    })
    .await; // no worker slots: jobs stay queued
    let first = submit(&app, "First", "aligning", "quick").await;
    complete_next(&app, first).await;
    let image = submit_obs(&app, "Image", "aligning", "image", "quick").await;
    assert_eq!(status(&app, image).await["eta_seconds"], Value::Null);
    // A state run of the same kind has its estimate: 1 s for the image job
    // ahead of it (no history of its own: counted at this job's mean), 1 s
    // for itself.
    let state = submit(&app, "State", "aligning", "quick").await;
    assert_eq!(status(&app, state).await["eta_seconds"], 2);
}

/// A deterministic policy's evaluation simulates each initial state once
/// and takes a fraction of the time: its runs are no estimate for other runs,
/// nor the reverse. The dry run at submission (here a script answering as a
/// deterministic policy when the manifest declares history 2) tells a queued
/// submission's kind.
async fn etas_keep_once_simulated_runs_apart(b: Backend) {
    let dir = tempfile::tempdir().unwrap();
    let once = dir.path().join("once.jsonl");
    let plain = dir.path().join("plain.jsonl");
    std::fs::write(&once, result_line_once(true) + "\n").unwrap();
    std::fs::write(&plain, result_line_once(false) + "\n").unwrap();
    let worker = script(
        dir.path(),
        "worker.sh",
        &format!(
            "job=$(cat)\necho '{{\"type\":\"sandbox\",\"mechanisms\":[]}}'\n\
             case \"$job\" in *'\"history\":2,'*) cat '{}' ;; *) cat '{}' ;; esac",
            once.display(),
            plain.display()
        ),
    );
    let app = spawn_app_with(Options {
        backend: b,
        worker_exe: Some(worker),
        dry_run_uploads: true,
        ..Default::default()
    })
    .await; // no worker slots: jobs stay queued
    let kind = |v: Value| v["policy"]["simulated_once"].clone();
    let first = submit_history(&app, "OnceFirst", 2).await;
    assert_eq!(kind(status(&app, first).await), Value::Bool(true));
    let stochastic = submit_history(&app, "Stochastic", 1).await;
    assert_eq!(kind(status(&app, stochastic).await), Value::Bool(false));
    complete_next_once(&app, first, true).await;
    // Only a once-simulated run has finished: no basis for a stochastic one.
    assert_eq!(status(&app, stochastic).await["eta_seconds"], Value::Null);
    // A second deterministic submission has its estimate: 1 s for the
    // stochastic job ahead (no history of its own: counted at this job's
    // mean) and 1 s for itself.
    let second = submit_history(&app, "OnceSecond", 2).await;
    assert_eq!(status(&app, second).await["eta_seconds"], 2);
    // The result says so too, and keeps the kind.
    complete_next_once(&app, stochastic, false).await;
    assert_eq!(kind(status(&app, stochastic).await), Value::Bool(false));
}

/// A robustness suite run is level 0 and every level of its suite, each a
/// whole evaluation (issue 40): a plain run's time is not its estimate, nor
/// the reverse. Without suite runs of its own, its kind counts as the plain
/// kind's mean times the suite's evaluations (14 for Aligning's v2: level 0
/// and 13 levels).
async fn etas_scale_suite_runs_by_their_evaluations(b: Backend) {
    let app = spawn_app_with(Options {
        backend: b,
        ..Default::default()
    })
    .await; // no worker slots: jobs stay queued
    let evaluations = d3il_server::intake::suite_evaluations(
        &app.state().cfg.assets_dir,
        TaskId::Aligning,
        ObsType::State,
    )
    .unwrap();
    assert_eq!(evaluations, 14);
    // No plain history either: no estimate.
    let early = submit_suite(&app, "Early").await;
    assert_eq!(status(&app, early).await["eta_seconds"], Value::Null);
    let plain = submit(&app, "Plain", "aligning", "quick").await;
    let store = &app.state().store;
    fail_next(&app, early).await;
    complete_next(&app, plain).await;
    // One plain run of 1 s: the suite run is estimated at 14 s; the plain
    // run queued behind it waits for those and takes its own 1 s.
    let suite = submit_suite(&app, "Suite").await;
    let v = status(&app, suite).await;
    assert_eq!(v["eta_seconds"], 14, "{v}");
    let behind = submit(&app, "Behind", "aligning", "quick").await;
    assert_eq!(status(&app, behind).await["eta_seconds"], 15);
    let kinds = store.queued_ahead(i64::MAX).await.unwrap();
    assert_eq!(
        kinds.iter().map(|k| k.suite.as_deref()).collect::<Vec<_>>(),
        [Some("robustness"), None]
    );
}

d3il_test_support::on_both_backends!(
    etas_scale_suite_runs_by_their_evaluations,
    a_quick_job_runs_on_its_own_slot_while_paper_runs_hold_every_other_slot,
    etas_come_from_past_runs_of_the_same_task_and_protocol,
    etas_keep_state_and_image_runs_apart,
    etas_keep_once_simulated_runs_apart
);
