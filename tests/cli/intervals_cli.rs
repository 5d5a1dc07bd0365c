//! Issue 51 through the real `d3il` binary: the issue's run (a trained
//! Pushing BC policy, the quick protocol's robustness suite, 3 initial
//! states × 2 rollouts a level) now prints no interval for any drop or
//! success rate, with the reason, instead of intervals that excluded 0
//! beside p-values that did not; and `d3il intervals` brings a 0.4 document
//! to this version's intervals.

use std::path::Path;
use std::process::Command;

fn d3il() -> Command {
    Command::new(env!("CARGO_BIN_EXE_d3il"))
}

/// A fresh directory of this test's own under the system's temporary one.
fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("d3il-intervals-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn read(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

#[test]
fn the_issues_quick_suite_gives_no_interval_and_says_why() {
    let dir = scratch("suite");
    let doc = dir.join("r.json");
    let policy =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/zoo/pushing/bc-mlp-s0/policy.onnx");
    let out = d3il()
        .args(["eval", "--task", "pushing", "--policy"])
        .arg(&policy)
        .args(["--protocol", "quick", "--suite", "robustness", "--json"])
        .arg(&doc)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Every level's drop: no interval, and the least p-value 3 states allow.
    let levels: Vec<&str> = stdout
        .lines()
        .filter(|l| l.chars().next().is_some_and(|c| c.is_ascii_digit()) && !l.starts_with("0 "))
        .collect();
    assert_eq!(levels.len(), 13, "{stdout}");
    for l in &levels {
        assert!(l.contains("no interval (3 states, p ≥ 0.25)"), "{l}");
    }
    assert!(
        stdout.contains("drop: no interval: with 3 initial states the paired test's smallest possible p-value is 0.250, so it cannot exclude any difference"),
        "{stdout}"
    );
    let r = read(&doc);
    let sr = &r["control"]["metrics"]["success_rate"];
    assert_eq!(sr["no_interval"]["reason"], "too_few_states", "{sr}");
    assert_eq!(sr["ci_low"], sr["value"]);
    for l in r["levels"].as_array().unwrap() {
        let d = &l["paired"]["success_rate"];
        assert_eq!(
            d["difference"]["no_interval"]["reason"], "test_cannot_reject",
            "{d}"
        );
        assert!(d["p_value"].as_f64().unwrap() >= 0.25, "{d}");
        assert_eq!(
            l["result"]["metrics"]["success_rate"]["no_interval"]["reason"],
            "too_few_states"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn d3il_intervals_recomputes_a_0_4_document_and_prints_what_moved() {
    let dir = scratch("recompute");
    let out_doc = dir.join("new.json");
    let old = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("server/tests/fixtures/zoo/avoiding/bc-mlp-s0/result.json");
    let out = d3il()
        .arg("intervals")
        .arg(&old)
        .arg("--out")
        .arg(&out_doc)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // All of Avoiding's rollouts succeeded: the old interval was [1, 1].
    let line = stdout
        .lines()
        .find(|l| l.contains("| success rate |"))
        .unwrap();
    assert!(line.contains("| 1.000 [1.000, 1.000] |"), "{line}");
    let new = read(&out_doc);
    let sr = &new["metrics"]["success_rate"];
    assert_eq!(sr["method"], "clopper_pearson_rollouts", "{sr}");
    assert_eq!(sr["value"], read(&old)["metrics"]["success_rate"]["value"]);
    assert!(sr["ci_low"].as_f64().unwrap() < 1.0);
    assert!(
        line.contains(&format!(
            "| 1.000 [{:.3}, 1.000] |",
            sr["ci_low"].as_f64().unwrap()
        )),
        "{line}"
    );
    // Bad input: says what to give.
    let out = d3il()
        .args(["intervals", "a.json", "b.json", "--out", "x.json"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("give one input file"));
    std::fs::remove_dir_all(&dir).unwrap();
}
