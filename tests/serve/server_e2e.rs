//! End to end through the real binary: `d3il serve` with one sandboxed worker,
//! `d3il token create`, `d3il submit --wait [--json]` of an ONNX fixture under the quick
//! protocol (real `d3il worker`, tract, MuJoCo), then the result on the
//! leaderboard page, in the CSV and on the submission page.

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
use std::process::Command;

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

#[test]
fn onnx_submission_is_evaluated_and_published() {
    let dir = TempDir::new("e2e");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "e2e-tester");
    let server = D3IL.serve(&db, &["--workers", "1"]);

    let out = Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", &token])
        .args([
            "--method",
            "E2E-Path",
            "--task",
            "avoiding",
            "--training-seed",
            "0",
        ])
        .args([
            "--protocol",
            "quick",
            "--backbone",
            "MLP",
            "--description",
            "Follows one path <between> the obstacles",
            "--wait",
            "--json",
            "--timeout",
            "900",
        ])
        .arg("--onnx")
        .arg(fixture("avoiding_path.onnx"))
        .arg("--manifest")
        .arg(fixture("avoiding_path.json"))
        .output()
        .expect("run d3il submit");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "d3il submit failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let progress = String::from_utf8_lossy(&out.stderr);
    assert!(
        progress.contains("completed ") && !progress.contains(" 0/0"),
        "--wait's progress lines: {progress}"
    );
    let json_start = stdout.find('{').expect("the final submission JSON");
    let done: serde_json::Value = serde_json::from_str(&stdout[json_start..]).expect("JSON");
    assert_eq!(done["status"], "completed", "{done}");
    let id = done["id"].as_i64().unwrap();
    let success = done["result"]["metrics"]["success_rate"]["value"]
        .as_f64()
        .unwrap();
    assert!(
        success > 0.9,
        "the path fixture reaches the goal: {success}"
    );
    assert_eq!(
        done["result"]["protocol_manifest"]["policy_sha256"], done["policy"]["sha256"],
        "the evaluated policy is the uploaded file"
    );
    assert!(done["result"]["sandbox"]
        .as_array()
        .is_some_and(|m| !m.is_empty()));

    // On the leaderboard page, marked evaluated and quick, linked to the submission.
    let (s, page) = server.get_text_blocking("/tasks/avoiding");
    assert_eq!(s, 200);
    let row = page
        .split("<tr class=\"evaluated\">")
        .nth(1)
        .expect("an evaluated row on the Avoiding leaderboard");
    assert!(row.contains("E2E-Path"));
    assert!(row.contains("badge-quick"));
    assert!(row.contains(&format!("href=\"/submissions/{id}\"")));
    // In the CSV with its numbers.
    let (s, csv) = server.get_text_blocking("/api/v1/leaderboards/avoiding/csv");
    assert_eq!(s, 200);
    let line = csv
        .lines()
        .find(|l| l.contains(",E2E-Path,"))
        .expect("the CSV has the evaluated row");
    assert!(line.contains(",evaluated,quick,1,,"), "{line}");
    assert!(
        line.contains(&format!("{success:.4}")),
        "{line} vs {success}"
    );
    // The method page shows the description given to `d3il submit`, escaped.
    let (s, page) = server.get_text_blocking("/methods/E2E-Path");
    assert_eq!(s, 200);
    assert!(
        page.contains("Follows one path &#60;between&#62; the obstacles"),
        "{page}"
    );
    // The submission page shows results and the Avoiding path figure.
    let (s, page) = server.get_text_blocking(&format!("/submissions/{id}"));
    assert_eq!(s, 200);
    assert!(page.contains("id=\"metrics\""));
    assert!(page.contains("id=\"paths-plot\""));
    let (s, svg) = server.get_text_blocking(&format!("/plots/submissions/{id}/paths.svg"));
    assert_eq!(s, 200);
    assert!(
        svg.contains("<polyline") || svg.contains("<path"),
        "paths are drawn"
    );

    // Without --json, `submit --wait` prints the metrics table of `d3il
    // eval`; the manifest is found next to the .onnx (no --manifest).
    let out = Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", &token])
        .args(["--method", "E2E-Path", "--task", "avoiding"])
        .args(["--training-seed", "1", "--protocol", "quick"])
        .args(["--wait", "--timeout", "900", "--onnx"])
        .arg(fixture("avoiding_path.onnx"))
        .output()
        .expect("run d3il submit");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "d3il submit failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!stdout.contains('{'), "a table, not JSON: {stdout}");
    assert!(
        stdout.contains("task avoiding, state observations (") && stdout.contains("quick protocol"),
        "{stdout}"
    );
    assert!(stdout.contains("success rate") && stdout.contains("conditional entropy"));
    assert!(stdout.contains("behaviours of the "), "{stdout}");
}
