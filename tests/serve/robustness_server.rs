//! The robustness track through the server, end to end: `d3il serve` with a
//! real sandboxed worker, `d3il submit --suite robustness --protocol quick
//! --wait` of the deterministic Aligning MLP fixture (level 0 and every level
//! of the suite, real tract and MuJoCo), then what is stored and served: the
//! plain result (level 0) on the ordinary board, the robustness document
//! through the API (whole and without records), the OpenAPI document, the
//! Robustness view, and a perturbed rollout of the served document replaying
//! with `d3il replay --level`. Every image variant's suite is accepted
//! (Sorting-4/6 and Stacking by HTTP and by `d3il submit`), and a task and
//! observation type without a suite file in the server's assets is refused
//! up front.

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
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
    let token = D3IL.create_token(&db, "robustness-tester");
    let server = D3IL.serve(&db, &["--workers", "1"]);
    let client = server.client(Some(&token));

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
        assert_eq!(
            doc["control"]["metrics"][m],
            document_estimate(&results["metrics"][m]),
            "{m}"
        );
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
    let (s, body) = server.get_text_blocking("/api/v1/submissions/999/robustness");
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
    let (_, board) = server.get_text_blocking("/tasks/aligning");
    assert!(board.contains("Robust-MLP") && board.contains("/tasks/aligning/robustness"));
    let (s, view) = server.get_text_blocking("/tasks/aligning/robustness");
    assert_eq!(s, 200);
    assert!(view.contains("Robust-MLP") && view.contains(&suite.name));
    assert!(view.contains("smoke test"), "quick runs are labelled");
    let (_, page) = server.get_text_blocking(&format!("/submissions/{id}"));
    assert!(page.contains(&format!("/api/v1/submissions/{id}/robustness")));
    server.kill();
}

/// `d3il submit --suite robustness` to `server` of Aligning's image fixture
/// with a manifest (written in `dir`) for `task` and `obs` observations.
fn submit_cli(
    server: &TestServer,
    token: &str,
    dir: &std::path::Path,
    task: &str,
    obs: &str,
) -> std::process::Output {
    let manifest = dir.join(format!("{task}-{obs}.json"));
    let text = format!(
        r#"{{"task": "{task}", "obs_type": "{obs}", "history": 1, "horizon": 1, "execute": 1}}"#
    );
    std::fs::write(&manifest, text).unwrap();
    Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", token])
        .args([
            "--method",
            "Robust-Image",
            "--task",
            task,
            "--obs-type",
            obs,
        ])
        .args(["--training-seed", "0", "--protocol", "quick"])
        .args(["--suite", "robustness", "--manifest"])
        .arg(&manifest)
        .arg("--onnx")
        .arg(fixture("aligning_image.onnx"))
        .output()
        .unwrap()
}

/// The image variants' suites through the server, up to the queued job: the
/// server finds each task's `<task>-image-v<N>.json` in its assets and
/// queues the suite job (level 0 and every level); a server whose assets
/// lack a task's image suite refuses it by the field `suite`, naming the
/// tasks that have one, and `d3il submit` refuses a task without an image
/// variant before uploading. The image suites' evaluation itself is
/// `tests/eval/robustness_image.rs` (the worker runs the same
/// `evaluate_suite`); here no worker runs (`--workers 0`) and the upload's
/// dry run is off, so the stand-in model (Aligning's image fixture with
/// each task's manifest) is only stored.
#[test]
fn image_suites_are_accepted_and_a_missing_suite_file_is_refused() {
    let dir = TempDir::new("robustness-image-intake");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "robustness-tester");
    let server = D3IL.serve(&db, &["--workers", "0", "--no-upload-dry-run"]);
    let client = server.client(Some(&token));
    let fields = |task: &str, seed: &str| {
        vec![
            ("method", "Robust-Image".to_string()),
            ("task", task.to_string()),
            ("obs_type", "image".to_string()),
            ("training_seed", seed.to_string()),
            ("protocol", "quick".to_string()),
            ("suite", "robustness".to_string()),
            (
                "manifest",
                format!(
                    r#"{{"task": "{task}", "obs_type": "image", "history": 1, "horizon": 1, "execute": 1}}"#
                ),
            ),
        ]
    };
    let onnx = fixture("aligning_image.onnx");
    for task in ["sorting-4", "sorting-6"] {
        let v = client
            .submit(&fields(task, "0"), Some(&onnx))
            .unwrap_or_else(|e| panic!("{task}: {e}"));
        let id = v["id"].as_i64().expect("submission id");
        let s = client.get(&format!("/api/v1/submissions/{id}")).unwrap();
        assert_eq!(
            (&s["status"], &s["task"], &s["obs_type"]),
            (&"queued".into(), &task.into(), &"image".into()),
            "{s}"
        );
        let (_, page) = server.get_text_blocking(&format!("/submissions/{id}"));
        assert!(
            page.contains("Evaluated with the robustness suite"),
            "{task}"
        );
    }
    // Stacking through `d3il submit`, which checks the suite locally first.
    let out = submit_cli(&server, &token, dir.path(), "stacking", "image");
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("submission 3 accepted"));
    let out = submit_cli(&server, &token, dir.path(), "pushing", "image");
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--suite robustness"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    server.kill();

    // A server whose assets have no `stacking-image-v*.json`.
    let assets = dir.path().join("assets");
    let repo_assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    std::fs::create_dir_all(assets.join("robustness")).unwrap();
    for e in std::fs::read_dir(&repo_assets).unwrap().flatten() {
        if e.file_name() != "robustness" {
            std::os::unix::fs::symlink(e.path(), assets.join(e.file_name())).unwrap();
        }
    }
    for e in std::fs::read_dir(repo_assets.join("robustness"))
        .unwrap()
        .flatten()
    {
        if !e
            .file_name()
            .to_string_lossy()
            .starts_with("stacking-image-v")
        {
            std::fs::copy(e.path(), assets.join("robustness").join(e.file_name())).unwrap();
        }
    }
    let db = dir.path().join("lb2.sqlite");
    let token = D3IL.create_token(&db, "robustness-tester");
    let assets_arg = assets.to_str().unwrap();
    let server = D3IL.serve(
        &db,
        &[
            "--workers",
            "0",
            "--no-upload-dry-run",
            "--assets",
            assets_arg,
        ],
    );
    let err = server
        .client(Some(&token))
        .submit(&fields("stacking", "1"), Some(&onnx))
        .expect_err("this server has no image suite for stacking");
    let msg = err.to_string();
    assert!(
        msg.contains("no robustness suite")
            && msg.contains("image observations: aligning, sorting-4, sorting-6;")
            && msg.contains("state observations: avoiding, aligning, pushing, sorting-2"),
        "{msg}"
    );
    let mut unknown = fields("sorting-4", "1");
    unknown.retain(|(k, _)| *k != "suite");
    unknown.push(("suite", "sturdiness".to_string()));
    let err = server
        .client(Some(&token))
        .submit(&unknown, Some(&onnx))
        .expect_err("unknown suite");
    assert!(
        err.to_string().contains("the one suite is `robustness`"),
        "{err}"
    );
    server.kill();
}
