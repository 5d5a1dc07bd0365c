//! Kill `d3il serve` (SIGKILL) in the middle of an evaluation and start it
//! again on the same database: the job is requeued and finishes, nothing is
//! lost. The worker here is a protocol fixture (a shell script that speaks the
//! worker's JSON-lines protocol slowly), so the test is about the server's
//! durability, independent of the simulator.

mod server_support;
use d3il_protocol::*;
use server_support::*;
use std::time::Duration;

fn fixture_result() -> EvalResult {
    let manifest = ProtocolManifest {
        task: TaskId::Avoiding,
        task_version: "fixture".into(),
        obs_type: ObsType::State,
        protocol: ProtocolKind::Quick,
        mjcf_sha256: "0".repeat(64),
        initial_states_sha256: "0".repeat(64),
        mujoco_version: "2.2.2".into(),
        evaluator_version: "fixture".into(),
        n_contexts: 2,
        rollouts_per_context: 2,
        max_steps: 100,
        policy_sha256: "0".repeat(64),
        history: 1,
        horizon: 1,
        execute: 1,
        seed: 0,
    };
    let est = |v: f64| Estimate {
        value: v,
        ci_low: v - 0.1,
        ci_high: v + 0.1,
    };
    EvalResult {
        manifest,
        metrics: Metrics {
            success_rate: est(0.75),
            behaviour_entropy: est(0.5),
            conditional_entropy: est(0.25),
            stacking: None,
            stacking_levels: None,
            inference_ms: 0.8,
        },
        per_context: vec![],
        rollouts: (0..4)
            .map(|i| RolloutRecord {
                context_index: i / 2,
                rollout_index: i % 2,
                success: i != 3,
                behaviour: serde_json::json!([i % 2, 1, 0]),
                steps: 50,
                path: Some(vec![[0.5, -0.3], [0.5 + 0.01 * i as f32, 0.0], [0.52, 0.3]]),
            })
            .collect(),
    }
}

/// A worker that reports progress every 0.4 s for 10 steps, then the result.
fn write_slow_worker(dir: &std::path::Path) -> std::path::PathBuf {
    let result = dir.join("result.jsonl");
    let line = serde_json::to_string(&WorkerMessage::Result(Box::new(fixture_result()))).unwrap();
    std::fs::write(&result, format!("{line}\n")).unwrap();
    let script = dir.join("slow-worker.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\ncat > /dev/null\necho '{{\"type\":\"sandbox\",\"mechanisms\":[]}}'\ni=0\nwhile [ $i -lt 10 ]; do i=$((i+1)); echo \"{{\\\"type\\\":\\\"progress\\\",\\\"rollouts_done\\\":$i,\\\"rollouts_total\\\":10}}\"; sleep 0.4; done\ncat '{}'\n",
            result.display()
        ),
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    script
}

#[test]
fn server_killed_mid_job_finishes_it_after_restart() {
    let dir = TempDir::new("restart");
    let db = dir.path().join("lb.sqlite");
    let worker = write_slow_worker(dir.path());
    let worker_s = worker.to_string_lossy().to_string();
    let args = ["--workers", "1", "--worker-exe", worker_s.as_str()];
    let token = create_token(&db, "restart-tester");
    let server = Server::start(&db, &args);
    let client = server.client(Some(&token));
    let created = client
        .submit(
            &[
                ("method", "Durable".to_string()),
                ("task", "avoiding".to_string()),
                ("training_seed", "0".to_string()),
                ("protocol", "quick".to_string()),
                (
                    "manifest",
                    r#"{"task":"avoiding","obs_type":"state"}"#.to_string(),
                ),
            ],
            Some(&worker), // any bytes do: the fixture worker ignores the policy
        )
        .expect("submission accepted");
    let id = created["id"].as_i64().unwrap();
    // Wait until the evaluation is visibly under way, then kill the server.
    wait_for(Duration::from_secs(30), || {
        let v = client.submission(id).ok()?;
        (v["status"] == "running" && v["progress"]["rollouts_done"].as_i64()? >= 2).then_some(())
    })
    .expect("the job started and reported progress");
    server.kill();

    // Restart on the same database: the interrupted job is requeued and done.
    let server = Server::start(&db, &args);
    let client = server.client(Some(&token));
    let done = client
        .wait(id, Duration::from_secs(60), |_| {})
        .expect("the job finishes after the restart");
    assert_eq!(done["status"], "completed", "{done}");
    assert_eq!(
        done["attempts"], 2,
        "one interrupted attempt, one complete: {done}"
    );
    assert_eq!(done["result"]["metrics"]["success_rate"]["value"], 0.75);
    assert_eq!(done["result"]["rollouts"].as_array().unwrap().len(), 4);
    // Exactly one submission and one result row: nothing lost, nothing doubled.
    let (_, csv) = server.get_text("/tasks/avoiding/csv");
    let mine: Vec<&str> = csv.lines().filter(|l| l.contains(",Durable,")).collect();
    assert_eq!(mine.len(), 1, "{csv}");
    assert!(
        mine[0].contains(",evaluated,quick,1,,0.7500,0.0000,0.2500,"),
        "{}",
        mine[0]
    );
    let (s, page) = server.get_text(&format!("/submissions/{id}"));
    assert_eq!(s, 200);
    assert!(
        page.contains("id=\"paths-plot\""),
        "Avoiding paths are plotted"
    );
    server.kill();
}
