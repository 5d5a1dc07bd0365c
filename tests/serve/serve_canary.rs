//! Issue 32: `d3il serve` runs the drift canary at start (`d3il verify` as a
//! subprocess), shows its outcome on the home page, and every result its
//! workers make records the build: the git commit and the physics
//! fingerprint that `d3il verify` computes for this binary.

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
use std::process::Command;
use std::time::Duration;

#[test]
fn serve_runs_the_canary_and_stamps_every_result_with_the_build() {
    let dir = TempDir::new("serve-canary");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "canary-tester");
    let server = D3IL.serve_with_canary(&db, &["--workers", "1"]);

    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/fixtures");
    let out = Command::new(EXE)
        .arg("submit")
        .args(["--server", &server.base, "--token", &token])
        .args([
            "--method",
            "Canary-Path",
            "--task",
            "avoiding",
            "--training-seed",
            "0",
        ])
        .args([
            "--protocol",
            "quick",
            "--wait",
            "--json",
            "--timeout",
            "900",
        ])
        .arg("--onnx")
        .arg(fixtures.join("avoiding_path.onnx"))
        .arg("--manifest")
        .arg(fixtures.join("avoiding_path.json"))
        .output()
        .expect("run d3il submit");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // `submission N accepted: URL`, then the server's document.
    let doc = &stdout[stdout.find('{').expect("a JSON document")..];
    let done: serde_json::Value = serde_json::from_str(doc).expect("json");
    let build = &done["result"]["protocol_manifest"]["build"];
    let fingerprint = build["physics_fingerprint"]
        .as_str()
        .expect("a fingerprint")
        .to_string();
    assert_eq!(fingerprint.len(), 16, "{build}");

    // The same binary's canary says the same (its report is kept per binary).
    let verify = Command::new(EXE)
        .args(["verify", "--json", "--cached"])
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&verify.stdout).expect("verify json");
    assert_eq!(report["fingerprint"], fingerprint.as_str());
    assert_eq!(report["passed"], true);

    // The home page says the canary passed, with the fingerprint.
    let page = wait_for(Duration::from_secs(60), || {
        let (s, page) = server.get_text_blocking("/");
        (s == 200 && page.contains("drift canary passed")).then_some(page)
    })
    .expect("the home page shows the canary's outcome");
    assert!(
        page.contains(&format!("physics fingerprint {fingerprint}")),
        "{page}"
    );
}
