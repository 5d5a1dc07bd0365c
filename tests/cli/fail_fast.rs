//! Issue 43 item 1, "fail fast": every argument, file and name a command can
//! check is checked before anything slow runs (this build's physics
//! fingerprint, a model load, a simulation). Each refusal here runs with
//! `D3IL_CACHE_DIR` pointing at an empty directory, so a command that computed
//! the fingerprint first would say so on stderr and leave its cache file
//! there; the tests assert that neither happened, not how long it took.

use std::path::Path;
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_d3il");
const FINGERPRINTING: &str = "computing this build's physics fingerprint";

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

/// `d3il ARGS...` with an empty fingerprint cache.
fn d3il(cache: &Path, args: &[&str]) -> Output {
    Command::new(EXE)
        .args(args)
        .env("D3IL_CACHE_DIR", cache)
        .output()
        .unwrap()
}

/// The command failed with `want` on stderr, and neither computed nor cached
/// the fingerprint.
fn refused_before_fingerprint(cache: &Path, args: &[&str], want: &[&str]) {
    let out = d3il(cache, args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded:\n{stderr}");
    for w in want {
        assert!(
            stderr.contains(w),
            "{args:?}: `{w}` missing from:\n{stderr}"
        );
    }
    assert!(
        !stderr.contains(FINGERPRINTING),
        "{args:?} computed the fingerprint before refusing:\n{stderr}"
    );
    untouched(cache, args);
}

fn untouched(cache: &Path, args: &[&str]) {
    let left: Vec<_> = std::fs::read_dir(cache)
        .map(|d| d.flatten().map(|e| e.file_name()).collect())
        .unwrap_or_default();
    assert!(left.is_empty(), "{args:?} left {left:?} in the cache");
}

#[test]
fn eval_refuses_bad_names_files_manifests_and_shards_before_the_fingerprint() {
    let dir = d3il_test_support::TempDir::new("fail-fast-eval");
    let cache = dir.path().join("cache");
    std::fs::create_dir_all(&cache).unwrap();
    // A scripted name that does not exist (the issue's example).
    refused_before_fingerprint(
        &cache,
        &["eval", "--task", "avoiding", "--policy", "scripted:path-0"],
        &["unknown scripted policy `path-0`", "avoiding:path=<0..23>"],
    );
    // A name of another task.
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "avoiding",
            "--policy",
            "scripted:aligning:inside",
        ],
        &["unknown scripted policy `aligning:inside`"],
    );
    // A missing ONNX file.
    let missing = dir.path().join("nothing-here.onnx");
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--policy",
            missing.to_str().unwrap(),
        ],
        &["no such file", "nothing-here.onnx"],
    );
    // A manifest that does not parse, one outside the limits, one missing.
    let onnx = dir.path().join("p.onnx");
    std::fs::copy(fixture("aligning_mlp.onnx"), &onnx).unwrap();
    let p = onnx.to_str().unwrap();
    std::fs::write(dir.path().join("p.json"), "{\"task\": \"aligning\", ").unwrap();
    refused_before_fingerprint(
        &cache,
        &["eval", "--task", "aligning", "--policy", p],
        &["is not a valid policy manifest"],
    );
    std::fs::write(
        dir.path().join("p.json"),
        r#"{"task": "aligning", "history": 0}"#,
    )
    .unwrap();
    refused_before_fingerprint(
        &cache,
        &["eval", "--task", "aligning", "--policy", p],
        &["history k = 0 must be from 1 to 64"],
    );
    let other = dir.path().join("other.json");
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--policy",
            p,
            "--manifest",
            other.to_str().unwrap(),
        ],
        &["reading the policy manifest", "other.json"],
    );
    // A manifest for another task.
    std::fs::write(dir.path().join("p.json"), r#"{"task": "pushing"}"#).unwrap();
    refused_before_fingerprint(
        &cache,
        &["eval", "--task", "aligning", "--policy", p],
        &["the manifest is for task `pushing` but --task is `aligning`"],
    );
    // A model the admission refuses (its observation has the wrong length):
    // loaded before the fingerprint is computed.
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "avoiding",
            "--protocol",
            "quick",
            "--policy",
            fixture("hostile_wrong_obs_dim.onnx").to_str().unwrap(),
        ],
        &["obs"],
    );
    // Shards: more than the protocol's initial states, or no part file.
    let part = dir.path().join("part.json");
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--protocol",
            "quick",
            "--policy",
            "scripted:aligning:inside",
            "--shard",
            "4/4",
            "--json",
            part.to_str().unwrap(),
        ],
        &["only 3 initial states"],
    );
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--policy",
            "scripted:aligning:inside",
            "--shard",
            "1/2",
        ],
        &["--shard 1/2 needs --json FILE"],
    );
    // A result file that could not be written at the end.
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--policy",
            "scripted:aligning:inside",
            "--json",
            dir.path().join("no/such/dir/r.json").to_str().unwrap(),
        ],
        &["--json", "does not exist"],
    );
    // An endpoint URL that is not one.
    refused_before_fingerprint(
        &cache,
        &[
            "eval",
            "--task",
            "aligning",
            "--policy",
            "ws://user:pw@127.0.0.1:9/",
        ],
        &["user name or password"],
    );
    assert!(!part.exists());
}

#[test]
fn other_commands_check_their_arguments_before_their_work() {
    let dir = d3il_test_support::TempDir::new("fail-fast-other");
    let cache = dir.path().join("cache");
    std::fs::create_dir_all(&cache).unwrap();
    let nowhere = dir.path().join("no/such/dir/out");
    let nowhere = nowhere.to_str().unwrap();
    refused_before_fingerprint(
        &cache,
        &[
            "render",
            "--task",
            "aligning",
            "--context",
            "999",
            "--out",
            &format!("{}/x.png", dir.path().display()),
        ],
        &["--context 999 is out of range"],
    );
    refused_before_fingerprint(
        &cache,
        &["render", "--task", "aligning", "--out", nowhere],
        &["--out", "does not exist"],
    );
    refused_before_fingerprint(
        &cache,
        &["fidelity", "--quick", "--out", nowhere],
        &["--out", "does not exist"],
    );
    refused_before_fingerprint(
        &cache,
        &[
            "tables",
            "--table",
            "main",
            "--db",
            dir.path().join("t.sqlite").to_str().unwrap(),
            "--out",
            nowhere,
        ],
        &["--out", "does not exist"],
    );
    assert!(
        !dir.path().join("t.sqlite").exists(),
        "the database was opened before the arguments were checked"
    );
    // A submission is checked before anything is sent (no server listens
    // on port 9; a request would fail with a connection error instead).
    let onnx = fixture("aligning_mlp.onnx");
    for (extra, want) in [
        (
            vec!["--task", "avoiding", "--onnx", onnx.to_str().unwrap()],
            "is for task `aligning` but --task is `avoiding`",
        ),
        (
            vec!["--task", "alinging", "--onnx", onnx.to_str().unwrap()],
            "--task alinging",
        ),
        (
            vec!["--task", "aligning", "--endpoint", "http://example.org/"],
            "give a ws:// or wss:// URL",
        ),
        (
            vec![
                "--task",
                "aligning",
                "--onnx",
                dir.path().join("missing.onnx").to_str().unwrap(),
            ],
            "no such file",
        ),
    ] {
        let mut args = vec![
            "submit",
            "--server",
            "http://127.0.0.1:9",
            "--token",
            "d3il_unused",
            "--method",
            "m",
            "--training-seed",
            "0",
        ];
        args.extend(extra);
        refused_before_fingerprint(&cache, &args, &[want]);
    }
}

/// `d3il infer` admits and runs a model without the simulator's slow path:
/// no fingerprint is computed or cached.
#[test]
fn infer_runs_without_the_fingerprint() {
    let dir = d3il_test_support::TempDir::new("fail-fast-infer");
    let cache = dir.path().join("cache");
    std::fs::create_dir_all(&cache).unwrap();
    let cases = dir.path().join("cases.json");
    let obs: Vec<f32> = (0..2 * 20).map(|i| (i as f32 * 0.1).sin()).collect();
    std::fs::write(
        &cases,
        serde_json::json!({"cases": [{"batch": 2, "window": 1, "obs": obs}]}).to_string(),
    )
    .unwrap();
    let mlp = fixture("aligning_mlp.onnx");
    let args = [
        "infer",
        "--policy",
        mlp.to_str().unwrap(),
        "--input",
        cases.to_str().unwrap(),
    ];
    let out = d3il(&cache, &args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["cases"][0]["shape"], serde_json::json!([2, 1, 3]));
    assert_eq!(v["cases"][0]["actions"].as_array().unwrap().len(), 6);
    assert!(!String::from_utf8_lossy(&out.stderr).contains(FINGERPRINTING));
    untouched(&cache, &args);
    // A refused model: the admission's message, a failing exit.
    let hostile = fixture("hostile_wrong_act_dim.onnx");
    let args = [
        "infer",
        "--policy",
        hostile.to_str().unwrap(),
        "--input",
        cases.to_str().unwrap(),
    ];
    refused_before_fingerprint(&cache, &args, &["was refused as a policy for"]);
}
