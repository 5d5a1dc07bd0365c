//! The robustness track through the server, end to end: `d3il serve` with a
//! real sandboxed worker, `d3il submit --suite robustness --protocol quick
//! --wait` of the deterministic Aligning MLP fixture (level 0 and every level
//! of the suite, real tract and MuJoCo), then what is stored and served: the
//! plain result (level 0) on the ordinary board, the robustness document
//! through the API (whole and without records), the OpenAPI document, the
//! Robustness view, and a perturbed rollout of the served document replaying
//! with `d3il replay --level`. Tasks without a suite are refused up front.

mod server_support;
use server_support::*;
use std::process::Command;

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

#[test]
fn a_robustness_submission_is_evaluated_stored_and_served() {
    let dir = TempDir::new("robustness-e2e");
    let db = dir.path().join("lb.sqlite");
    let token = create_token(&db, "robustness-tester");
    let server = Server::start(&db, &["--workers", "1"]);
    let client = server.client(Some(&token));

    // Refused for a task and observation type without a suite (every task
    // has a state suite; Stacking's image variant has none yet), by the
    // server (field `suite`) and by `d3il submit` before anything is
    // uploaded.
    let fields = |suite: &str| {
        vec![
            ("method", "Robust-MLP".to_string()),
            ("task", "stacking".to_string()),
            ("obs_type", "image".to_string()),
            ("training_seed", "0".to_string()),
            ("protocol", "quick".to_string()),
            ("suite", suite.to_string()),
            (
                "manifest",
                r#"{"task": "stacking", "obs_type": "image", "history": 1, "horizon": 1, "execute": 1}"#
                    .to_string(),
            ),
        ]
    };
    let onnx = fixture("aligning_image.onnx");
    let err = client
        .submit(&fields("robustness"), Some(&onnx))
        .expect_err("stacking's image variant has no suite");
    let msg = err.to_string();
    assert!(
        msg.contains("no robustness suite")
            && msg.contains("image observations: aligning")
            && msg.contains("state observations: avoiding, aligning, pushing, sorting-2"),
        "{msg}"
    );
    let err = client
        .submit(&fields("sturdiness"), Some(&onnx))
        .expect_err("unknown suite");
    assert!(
        err.to_string().contains("the one suite is `robustness`"),
        "{err}"
    );
    let out = Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", &token])
        .args([
            "--method",
            "X",
            "--task",
            "stacking",
            "--obs-type",
            "image",
            "--training-seed",
            "0",
        ])
        .args(["--suite", "robustness", "--onnx"])
        .arg(&onnx)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--suite robustness"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // The suite, quick protocol, through a real worker.
    let out = Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", &token])
        .args([
            "--method",
            "Robust-MLP",
            "--task",
            "aligning",
            "--training-seed",
            "0",
        ])
        .args(["--protocol", "quick", "--suite", "robustness", "--wait"])
        .args(["--timeout", "1500", "--onnx"])
        .arg(fixture("aligning_mlp.onnx"))
        .output()
        .expect("run d3il submit");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "d3il submit failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("overall robustness score") && stdout.contains("latency: score"),
        "--wait prints the robustness tables: {stdout}"
    );
    let id: i64 = stdout
        .split("submission ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .expect("submission id");

    // Level 0 is the plain result of the submission.
    let results = client
        .get(&format!("/api/v1/submissions/{id}/results"))
        .unwrap();
    let doc = client
        .get(&format!("/api/v1/submissions/{id}/robustness"))
        .unwrap();
    assert_eq!(doc["format"], "d3il-robustness-v1");
    assert_eq!(doc["task"], "aligning");
    let suite = d3il_evaluator::perturb::Suite::for_task(d3il_protocol::TaskId::Aligning).unwrap();
    assert_eq!(doc["suite"], suite.name.as_str());
    assert_eq!(doc["suite_sha256"], suite.sha256.as_str());
    assert_eq!(doc["suite_sha256"].as_str().unwrap().len(), 64);
    for m in ["success_rate", "conditional_entropy", "behaviour_entropy"] {
        assert_eq!(doc["control"]["metrics"][m], results["metrics"][m], "{m}");
    }
    assert_eq!(doc["control"]["per_context"], results["per_context"]);
    let levels = doc["levels"].as_array().unwrap();
    assert_eq!(
        levels.len(),
        suite.perturbations().len(),
        "the suite's levels"
    );
    for l in levels {
        let m = &l["result"]["manifest"];
        assert_eq!(m["perturbation"]["axis"], l["axis"]);
        assert_eq!(m["perturbation"]["level"], l["level"]);
        assert_eq!(
            l["result"]["rollouts"].as_array().unwrap().len(),
            6,
            "3 states × 2 rollouts"
        );
        assert!(l["paired"]["success_rate"]["p_value"].is_number());
    }
    assert_eq!(doc["axes"].as_array().unwrap().len(), suite.file.axes.len());
    let summary = client
        .get(&format!(
            "/api/v1/submissions/{id}/robustness?rollouts=false"
        ))
        .unwrap();
    assert_eq!(summary["overall"], doc["overall"]);
    assert!(summary["levels"]
        .as_array()
        .unwrap()
        .iter()
        .all(|l| l["result"]["rollouts"].as_array().unwrap().is_empty()));
    // A plain submission has no robustness part.
    let (s, body) = server.get_text("/api/v1/submissions/999/robustness");
    assert_eq!(s, 404, "{body}");

    // A perturbed rollout of the served document replays bit for bit.
    let path = dir.path().join("robustness.json");
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
    let out = Command::new(EXE)
        .args(["replay", "--result"])
        .arg(&path)
        .args(["--level", "latency/1", "--rollout", "0"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "replay: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );

    // OpenAPI, the board (level 0 as a quick row), the view, the submission page.
    let openapi = client.get("/api/v1/openapi.json").unwrap();
    assert!(openapi["paths"]["/submissions/{id}/robustness"]["get"].is_object());
    let (_, board) = server.get_text("/tasks/aligning");
    assert!(board.contains("Robust-MLP") && board.contains("/tasks/aligning/robustness"));
    let (s, view) = server.get_text("/tasks/aligning/robustness");
    assert_eq!(s, 200);
    assert!(view.contains("Robust-MLP") && view.contains(&suite.name));
    assert!(view.contains("smoke test"), "quick runs are labelled");
    let (_, page) = server.get_text(&format!("/submissions/{id}"));
    assert!(page.contains(&format!("/api/v1/submissions/{id}/robustness")));
    server.kill();
}
