//! Issue 32: `d3il verify`, the drift canary, passes on this build, fails on
//! a deliberately changed controller gain naming what drifted, and every
//! `d3il eval` result records the build: its git commit and the same physics
//! fingerprint that `d3il verify` computes.

use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_d3il");

fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("verify-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn d3il(args: &[&str], cache: &PathBuf, envs: &[(&str, &str)]) -> Output {
    let mut c = Command::new(EXE);
    c.args(args)
        .current_dir(cache)
        .env("D3IL_CACHE_DIR", cache)
        .env("RUST_BACKTRACE", "0");
    for (k, v) in envs {
        c.env(k, v);
    }
    c.output().unwrap()
}

#[test]
fn verify_passes_and_every_result_records_its_build() {
    let dir = scratch("pass");
    // Two runs of a build without a report, at once (as a server and a test
    // suite start many): one runs the canary, the other waits for its
    // report rather than running it again (the same report, to its seconds).
    let (out, other) = std::thread::scope(|s| {
        let a = s.spawn(|| d3il(&["verify", "--json", "--cached"], &dir, &[]));
        let b = s.spawn(|| d3il(&["verify", "--json", "--cached"], &dir, &[]));
        (a.join().unwrap(), b.join().unwrap())
    });
    assert_eq!(
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&other.stdout),
        "two concurrent runs both ran the canary: {}",
        String::from_utf8_lossy(&other.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["passed"], true);
    let fp = report["fingerprint"].as_str().unwrap().to_string();
    assert_eq!(report["expected_fingerprint"], fp.as_str());
    let entries = report["entries"].as_array().unwrap();
    assert!(entries.len() >= 12, "{report}");
    assert!(
        entries.iter().all(|e| e["matching"] == e["rollouts"]),
        "{report}"
    );
    // The same build's results carry the fingerprint (from the cache the
    // verify run left) and the commit.
    let out = d3il(
        &[
            "eval",
            "--task",
            "aligning",
            "--protocol",
            "quick",
            "--policy",
            "scripted:aligning:inside",
            "--json",
            "r.json",
        ],
        &dir,
        &[],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("r.json")).unwrap()).unwrap();
    let build = &r["manifest"]["build"];
    assert_eq!(build["physics_fingerprint"], fp.as_str(), "{build}");
    let commit = build["git_commit"].as_str().unwrap();
    assert!(
        commit == "unknown"
            || (commit.len() == 40 && commit.bytes().all(|b| b.is_ascii_hexdigit())),
        "{commit}"
    );
    assert_ne!(r["manifest"]["evaluator_version"], "0.1.0");
}

#[test]
fn verify_fails_on_a_changed_controller_gain() {
    let dir = scratch("drift");
    let out = d3il(&["verify"], &dir, &[("D3IL_DRIFT_TEST_KP_SCALE", "1.001")]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a changed gain passed the canary:\n{stdout}"
    );
    assert!(stdout.contains("DRIFTED"), "{stdout}");
    assert!(
        stderr.contains("the simulator drifted from the committed canary outcomes"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    // The drifted run's fingerprint is not cached as this build's.
    let cached: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with("fingerprint-"))
        .collect();
    assert!(cached.is_empty());
}
