//! `d3il replay` through the real binary, on the episode recorded in the
//! original D3IL simulator, plus the errors bad input gets.

use serde_json::{json, Value};
use std::process::Command;

fn replay(task: &str, input: &Value) -> (bool, String, String) {
    let dir = tempfile_dir();
    let path = dir.join("episode.json");
    std::fs::write(&path, serde_json::to_vec(input).unwrap()).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(["replay", "--task", task, "--input"])
        .arg(&path)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "d3il-replay-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn avoiding_reference_route_replays_through_the_cli() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/reference-rollouts/avoiding/route_top_top_top.json"
    ))
    .unwrap();
    let r: Value = serde_json::from_str(&text).unwrap();
    let input = json!({"context": null, "actions": r["policy_actions"]});
    let (ok, stdout, stderr) = replay("avoiding", &input);
    assert!(ok, "{stderr}");
    let out: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["success"], true);
    assert_eq!(out["behaviour"], r["mode"]);
    assert_eq!(out["steps"], r["n_steps"]);
    let ours = out["tcp"].as_array().unwrap();
    let theirs = r["ee_pos"].as_array().unwrap();
    assert_eq!(ours.len(), theirs.len());
    for (t, (a, b)) in ours.iter().zip(theirs).enumerate() {
        for k in 0..3 {
            let d = (a[k].as_f64().unwrap() - b[k].as_f64().unwrap()).abs();
            assert!(d < 1e-4, "tcp row {t} axis {k} deviates {d}");
        }
    }
}

#[test]
fn bad_input_names_the_field() {
    let (ok, _, err) = replay(
        "avoiding",
        &json!({"context": null, "actions": [[0.0, 0.0, 0.0]]}),
    );
    assert!(!ok);
    assert!(
        err.contains("actions[0] has 3 values") && err.contains("expects 2"),
        "{err}"
    );
    let (ok, _, err) = replay("avoiding", &json!({"context": null}));
    assert!(!ok && err.contains("actions"), "{err}");
    let (ok, _, err) = replay("nonsense", &json!({"actions": []}));
    assert!(!ok && err.contains("unknown task"), "{err}");
    let (ok, _, err) = replay(
        "pushing",
        &json!({"context": {"red_xy_deg": "x"}, "actions": []}),
    );
    assert!(!ok && err.contains("context"), "{err}");
}
