//! The worker pool with real worker processes. The workers here are protocol
//! fixtures (shell scripts printing the worker's JSON lines, or dying), so the
//! tests cover the server's side: leasing, progress, retries, typed errors and
//! result storage.

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

fn result_line(task: TaskId) -> String {
    let est = |v: f64| {
        d3il_protocol::Estimate::with_interval(
            v,
            v - 0.05,
            v + 0.05,
            d3il_protocol::IntervalMethod::KornGraubard,
        )
    };
    let r = EvalResult {
        manifest: ProtocolManifest {
            task,
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
            simulated_once: false,
            build: None,
            perturbation: None,
        },
        metrics: Metrics {
            success_rate: est(0.5),
            behaviour_entropy: est(0.9),
            conditional_entropy: est(0.4),
            stacking: None,
            stacking_levels: None,
            inference_ms: 2.0,
        },
        per_context: vec![ContextResult {
            context_index: 0,
            success_rate: 0.5,
            conditional_entropy: 0.4,
            behaviours: vec![("[0, 1]".into(), 2), ("[1, 0]".into(), 1)],
        }],
        rollouts: (0..6)
            .map(|i| RolloutRecord {
                context_index: i / 3,
                rollout_index: i % 3,
                success: i % 2 == 0,
                behaviour: serde_json::json!([i % 3, 1]),
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

async fn wait_final(app: &TestServer, id: i64) -> Value {
    for _ in 0..300 {
        let (_, v) = app.get_json(&format!("/api/v1/submissions/{id}")).await;
        if v["status"] == "completed" || v["status"] == "failed" {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("submission {id} did not finish");
}

async fn submit_one(app: &TestServer, method: &str, task: &str) -> i64 {
    let m = manifest(task);
    let r = app
        .submit(
            &[
                ("method", method),
                ("task", task),
                ("training_seed", "0"),
                ("protocol", "quick"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 201);
    r.json::<Value>().await.unwrap()["id"].as_i64().unwrap()
}

async fn completed_job_is_stored_and_shown(b: Backend) {
    let dir = tempfile::tempdir().unwrap();
    let result = dir.path().join("result.jsonl");
    std::fs::write(&result, result_line(TaskId::Pushing) + "\n").unwrap();
    let worker = script(
        dir.path(),
        "ok.sh",
        &format!(
            "cat > /dev/null\necho '{{\"type\":\"sandbox\",\"mechanisms\":[{{\"name\":\"rlimits\",\"active\":true,\"detail\":\"fixture\"}}]}}'\necho '{{\"type\":\"progress\",\"rollouts_done\":3,\"rollouts_total\":6}}'\ncat '{}'",
            result.display()
        ),
    );
    let app = spawn_app_with(Options {
        backend: b,
        workers: 1,
        worker_exe: Some(worker),
        ..Default::default()
    })
    .await;
    let id = submit_one(&app, "Fixture", "pushing").await;
    let v = wait_final(&app, id).await;
    assert_eq!(v["status"], "completed", "{v}");
    assert_eq!(v["result"]["metrics"]["success_rate"]["value"], 0.5);
    assert_eq!(v["result"]["sandbox"][0]["name"], "rlimits");
    let (s, r) = app
        .get_json(&format!("/api/v1/submissions/{id}/results"))
        .await;
    assert_eq!(s, 200);
    assert_eq!(r["rollouts"].as_array().unwrap().len(), 6);
    let (_, page) = app.get_text("/tasks/pushing").await;
    assert!(page.contains("badge-evaluated"));
    assert!(page.contains("badge-quick"));
    assert!(page.contains(&format!("href=\"/submissions/{id}\"")));
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert!(page.contains("id=\"metrics\""));
    assert!(page.contains("id=\"behaviour-plot\""));
    assert!(page.contains("id=\"protocol-manifest\""));
    assert!(
        !page.contains("http-equiv=\"refresh\""),
        "no refresh once finished"
    );
    let (s, svg) = app
        .get_text(&format!("/plots/submissions/{id}/behaviours.svg"))
        .await;
    assert_eq!(s, 200);
    assert!(svg.contains("<svg"));
    // The tables' cells exclude quick-protocol runs.
    let cells = app.state().store.result_cells(None).await.unwrap();
    assert!(cells.iter().all(|c| c.method != "Fixture"));
}

async fn crashing_worker_is_retried_then_fails_with_a_typed_error(b: Backend) {
    let dir = tempfile::tempdir().unwrap();
    let count = dir.path().join("count");
    let worker = script(
        dir.path(),
        "crash.sh",
        &format!(
            "cat > /dev/null\necho x >> '{}'\nkill -9 $$",
            count.display()
        ),
    );
    let app = spawn_app_with(Options {
        backend: b,
        workers: 1,
        worker_exe: Some(worker),
        ..Default::default()
    })
    .await;
    let id = submit_one(&app, "Crasher", "aligning").await;
    let v = wait_final(&app, id).await;
    assert_eq!(v["status"], "failed");
    assert_eq!(v["error"]["kind"], "crashed");
    assert!(
        v["error"]["message"].as_str().unwrap().contains("SIGKILL"),
        "{v}"
    );
    assert_eq!(v["attempts"], 3);
    assert_eq!(std::fs::read_to_string(&count).unwrap().lines().count(), 3);
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert!(page.contains("Evaluation failed: <code>crashed</code>"));
}

async fn policy_errors_fail_at_once_and_garbage_output_is_a_protocol_violation(b: Backend) {
    let dir = tempfile::tempdir().unwrap();
    let bad_model = script(
        dir.path(),
        "bad.sh",
        "cat > /dev/null\necho '{\"type\":\"error\",\"kind\":\"bad_model\",\"message\":\"input `obs` has 3 columns, the task needs 4\"}'\nexit 2",
    );
    let app = spawn_app_with(Options {
        backend: b,
        workers: 1,
        worker_exe: Some(bad_model),
        ..Default::default()
    })
    .await;
    let id = submit_one(&app, "BadModel", "avoiding").await;
    let v = wait_final(&app, id).await;
    assert_eq!(v["error"]["kind"], "bad_model");
    assert_eq!(v["attempts"], 1, "not retried");
    assert!(v["error"]["message"].as_str().unwrap().contains("columns"));

    let garbage = script(
        dir.path(),
        "garbage.sh",
        "cat > /dev/null\necho 'hello, I am not JSON'\nsleep 5",
    );
    let app = spawn_app_with(Options {
        backend: b,
        workers: 1,
        worker_exe: Some(garbage),
        ..Default::default()
    })
    .await;
    let id = submit_one(&app, "Garbage", "avoiding").await;
    let v = wait_final(&app, id).await;
    assert_eq!(v["error"]["kind"], "protocol_violation", "{v}");
}

async fn stacking_levels_are_stored_and_shown_each_with_its_own_numbers(b: Backend) {
    // Two initial states, levels that see different data (the fixture's doc).
    let rollouts = d3il_test_support::STACKING_ROLLOUTS;
    let outcomes = d3il_test_support::stacking_outcomes();
    let ev = d3il_metrics::evaluate(
        TaskId::Stacking,
        &outcomes,
        1.0,
        &d3il_metrics::Bootstrap::default(),
    )
    .unwrap();
    let levels = ev.metrics.stacking_levels.unwrap();
    let result = EvalResult {
        manifest: ProtocolManifest {
            task: TaskId::Stacking,
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
            rollouts_per_context: 5,
            max_steps: 1000,
            policy_sha256: "c".repeat(64),
            history: 1,
            horizon: 1,
            execute: 1,
            seed: 0,
            simulated_once: false,
            build: None,
            perturbation: None,
        },
        metrics: ev.metrics.clone(),
        per_context: ev.per_context.clone(),
        rollouts: rollouts
            .iter()
            .enumerate()
            .map(|(i, &(c, order, full))| RolloutRecord {
                context_index: c,
                rollout_index: i,
                success: full,
                behaviour: serde_json::json!(order),
                steps: 1000,
                path: None,
                failure: None,
                ending: None,
                trace: None,
            })
            .collect(),
        rollouts_ended_unstable: 0,
    };
    let dir = tempfile::tempdir().unwrap();
    let line = dir.path().join("result.jsonl");
    std::fs::write(
        &line,
        serde_json::to_string(&WorkerMessage::Result(Box::new(result))).unwrap() + "\n",
    )
    .unwrap();
    let worker = script(
        dir.path(),
        "stacking.sh",
        &format!(
            "cat > /dev/null\necho '{{\"type\":\"sandbox\",\"mechanisms\":[]}}'\ncat '{}'",
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
    let id = submit_one(&app, "Stacker", "stacking").await;
    let v = wait_final(&app, id).await;
    assert_eq!(v["status"], "completed", "{v}");

    // The API returns the three levels as computed.
    let api_levels: [StackingLevel; 3] =
        serde_json::from_value(v["result"]["metrics"]["stacking_levels"].clone()).unwrap();
    // (serde_json's default float parsing may differ in the last bit.)
    for (got, want) in api_levels.iter().zip(&levels) {
        for (g, w) in [
            (got.success_rate, want.success_rate),
            (got.behaviour_entropy, want.behaviour_entropy),
            (got.conditional_entropy, want.conditional_entropy),
        ] {
            for (a, b) in [
                (g.value, w.value),
                (g.ci_low, w.ci_low),
                (g.ci_high, w.ci_high),
            ] {
                assert!((a - b).abs() < 1e-12, "{got:?} vs {want:?}");
            }
        }
    }

    // The leaderboard CSV has three rows, each with its level's numbers.
    let (s, csv) = app
        .get_text("/api/v1/leaderboards/stacking/csv?obs=state")
        .await;
    assert_eq!(s, 200);
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (task, method, success, cond, behaviour) = (
        col("task"),
        col("method"),
        col("success_mean"),
        col("conditional_entropy_mean"),
        col("behaviour_entropy_mean"),
    );
    let mut seen = vec![];
    for (k, l) in levels.iter().enumerate() {
        let title = format!("Stacking-{} (T5)", k + 1);
        let row: Vec<&str> = csv
            .lines()
            .map(|l| l.split(',').collect::<Vec<_>>())
            .find(|f| f[method] == "Stacker" && f[task] == title)
            .unwrap_or_else(|| panic!("no {title} row:\n{csv}"));
        let num = |i: usize| row[i].parse::<f64>().unwrap();
        // The CSV prints four decimals.
        assert!(
            (num(success) - l.success_rate.value).abs() < 5e-5,
            "{title}"
        );
        assert!(
            (num(cond) - l.conditional_entropy.value).abs() < 5e-5,
            "{title}"
        );
        assert!(
            (num(behaviour) - l.behaviour_entropy.value).abs() < 5e-5,
            "{title}"
        );
        seen.push((num(success), num(cond), num(behaviour)));
    }
    // Different data per level, different rows.
    assert!(
        seen[0] != seen[1] && seen[1] != seen[2] && seen[0] != seen[2],
        "{seen:?}"
    );
    assert!(seen[0].1 != seen[1].1 && seen[1].1 != seen[2].1, "{seen:?}");

    // The submission page lists every level's three metrics.
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    for (k, l) in levels.iter().enumerate() {
        let name = format!("Stacking-{}: conditional behaviour entropy", k + 1);
        let cell = page
            .split(&format!("<td>{name}</td>"))
            .nth(1)
            .unwrap_or_else(|| panic!("no `{name}` on the submission page"));
        assert!(
            cell.starts_with(&format!(
                "<td class=\"num\">{:.3}</td>",
                l.conditional_entropy.value
            )),
            "{name}: {}",
            &cell[..80.min(cell.len())]
        );
    }
}

d3il_test_support::on_both_backends!(
    completed_job_is_stored_and_shown,
    crashing_worker_is_retried_then_fails_with_a_typed_error,
    policy_errors_fail_at_once_and_garbage_output_is_a_protocol_violation,
    stacking_levels_are_stored_and_shown_each_with_its_own_numbers
);
