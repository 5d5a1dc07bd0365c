//! Issue 18, the CLI: `d3il eval` prints the observation type, the protocol
//! in lowercase and a behaviour histogram; scripted names are checked against
//! the task with the task's own names listed; `d3il eval` and `d3il submit`
//! find the manifest next to the .onnx the same way.

use std::process::Command;

const EXE: &str = env!("CARGO_BIN_EXE_d3il");

/// `d3il eval --task TASK --protocol quick --policy POLICY EXTRA...`, run to the end.
fn eval_quick(
    task: &str,
    policy: impl AsRef<std::ffi::OsStr>,
    extra: &[&str],
) -> std::process::Output {
    Command::new(EXE)
        .args(["eval", "--task", task, "--protocol", "quick", "--policy"])
        .arg(policy)
        .args(extra)
        .output()
        .unwrap()
}

/// A quick Avoiding evaluation of `onnx` with `extra` flags, run to success
/// with `--json dir/out`: the result (inference times blanked), stdout and
/// stderr.
fn eval_json(
    dir: &std::path::Path,
    onnx: &std::path::Path,
    extra: &[&str],
    out: &str,
) -> (serde_json::Value, String, String) {
    let path = dir.join(out);
    let o = eval_quick(
        "avoiding",
        onnx,
        &[extra, &["--json", path.to_str().unwrap()]].concat(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    v["metrics"]["inference_ms"] = serde_json::Value::Null;
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (v, text(&o.stdout), text(&o.stderr))
}

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

#[test]
fn eval_prints_observation_type_lowercase_protocol_and_behaviour_histogram() {
    let dir = std::env::temp_dir().join(format!("d3il-cli-output-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("r.json");
    let out = eval_quick(
        "aligning",
        "scripted:aligning:both",
        &["--json", json.to_str().unwrap()],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.starts_with(
            "task aligning, state observations (3 x 2 rollouts, quick protocol, seed 0)"
        ),
        "{stdout}"
    );
    assert!(!stdout.contains("Quick"), "{stdout}");
    // The histogram counts the successful rollouts by behaviour.
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let successes = r["rollouts"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|x| x["success"] == true)
        .count();
    assert!(successes > 0, "the scripted policy succeeds: {stdout}");
    assert!(
        stdout.contains(&format!(
            "behaviours of the {successes} successful rollouts:"
        )),
        "{stdout}"
    );
    let hist: Vec<&str> = stdout
        .lines()
        .skip_while(|l| !l.starts_with("behaviours of the"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .collect();
    assert!(!hist.is_empty(), "{stdout}");
    let counted: usize = hist
        .iter()
        .map(|l| {
            let mut f = l.split_whitespace();
            f.next();
            f.next().unwrap().parse::<usize>().unwrap()
        })
        .sum();
    assert_eq!(counted, successes, "{stdout}");
    assert!(hist.iter().all(|l| l.trim_end().ends_with('#')), "{stdout}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_scripted_name_of_another_task_is_refused_with_the_tasks_own_names() {
    let out = eval_quick("avoiding", "scripted:aligning:both", &[]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(
            "unknown scripted policy `aligning:both` for task avoiding; the scripted policies of avoiding are: avoiding:path=<0..23>, avoiding:all-paths"
        ),
        "{stderr}"
    );
    assert!(!stderr.contains("aligning:inside"), "{stderr}");
}

#[test]
fn eval_and_submit_find_the_manifest_next_to_the_onnx_file_the_same_way() {
    let dir = std::env::temp_dir().join(format!("d3il-cli-manifest-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let onnx = dir.join("policy.onnx");
    std::fs::copy(fixture("avoiding_path.onnx"), &onnx).unwrap();
    let expect = format!(
        "reading the policy manifest {} (put it next to the .onnx file with the same name, or pass --manifest",
        dir.join("policy.json").display()
    );
    let eval = eval_quick("avoiding", &onnx, &[]);
    assert!(!eval.status.success());
    assert!(String::from_utf8_lossy(&eval.stderr).contains(&expect));
    let submit = Command::new(EXE)
        .args([
            "submit",
            "--server",
            "http://127.0.0.1:9",
            "--token",
            "d3il_x",
            "--method",
            "M",
            "--task",
            "avoiding",
            "--training-seed",
            "0",
            "--onnx",
        ])
        .arg(&onnx)
        .output()
        .unwrap();
    assert!(!submit.status.success());
    let stderr = String::from_utf8_lossy(&submit.stderr);
    assert!(stderr.contains(&expect), "{stderr}");
    // With the manifest next to the file, eval runs.
    std::fs::copy(fixture("avoiding_path.json"), dir.join("policy.json")).unwrap();
    let eval = eval_quick("avoiding", &onnx, &[]);
    assert!(
        eval.status.success(),
        "{}",
        String::from_utf8_lossy(&eval.stderr)
    );
    assert!(String::from_utf8_lossy(&eval.stdout).contains("task avoiding, state observations"));
    // A deterministic policy: the one initial state is simulated once, and eval says so.
    let stderr = String::from_utf8_lossy(&eval.stderr);
    assert!(
        stderr.contains("each initial state was simulated once")
            && stderr.contains("(1 of 8 rollouts simulated, same results)"),
        "{stderr}"
    );
    // --every-rollout simulates all 8 and gets the same records and metrics;
    // only the manifest says how the rollouts were produced.
    let run_json = |extra: &[&str], out: &str| {
        let (v, _, stderr) = eval_json(&dir, &onnx, extra, out);
        (v, stderr)
    };
    let (mut once, _) = run_json(&[], "once.json");
    let (every, stderr) = run_json(&["--every-rollout"], "every.json");
    assert!(!stderr.contains("simulated once"), "{stderr}");
    assert_eq!(once["manifest"]["simulated_once"], true);
    assert_eq!(
        every["manifest"].get("simulated_once"),
        None,
        "written only when true"
    );
    once["manifest"]
        .as_object_mut()
        .unwrap()
        .remove("simulated_once");
    // The copies of a once-simulated state share rollout 0's trace; the
    // every-rollout run's copies carry their own, equal to it.
    let mut every = every;
    for doc in [&mut once, &mut every] {
        for r in doc["rollouts"].as_array_mut().unwrap() {
            if r["rollout_index"] != 0 {
                r.as_object_mut().unwrap().remove("trace");
            }
        }
    }
    assert_eq!(once, every);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--rollouts-per-state N`: the protocol's initial states with N rollouts
/// each (a sample for measurements), recorded in the manifest; the same
/// records as the first N of the protocol's for a deterministic policy; the
/// robustness suite's count up front follows it.
#[test]
fn rollouts_per_state_samples_the_protocol_and_the_suite_counts_it() {
    let dir = std::env::temp_dir().join(format!("d3il-cli-sample-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let onnx = fixture("avoiding_path.onnx");
    let json = |extra: &[&str], out: &str| {
        let (v, stdout, _) = eval_json(&dir, &onnx, extra, out);
        (v, stdout)
    };
    let (full, _) = json(&[], "full.json");
    let (sample, _) = json(&["--rollouts-per-state", "3"], "sample.json");
    assert_eq!(full["manifest"]["rollouts_per_context"], 8);
    assert_eq!(sample["manifest"]["rollouts_per_context"], 3);
    let rollouts = |v: &serde_json::Value| v["rollouts"].as_array().unwrap().clone();
    assert_eq!(rollouts(&sample).len(), 3);
    assert_eq!(rollouts(&sample)[..], rollouts(&full)[..3]);
    // The suite: level 0 and 6 levels (Avoiding v1: noise and latency, three
    // levels each) of one state with 1 rollout each.
    let (doc, stdout) = json(
        &["--rollouts-per-state", "1", "--suite", "robustness"],
        "suite.json",
    );
    assert!(
        stdout.contains("each 1 initial states × 1 rollouts (quick protocol): 7 rollouts recorded"),
        "{stdout}"
    );
    assert_eq!(doc["control"]["rollouts"].as_array().unwrap().len(), 1);
    // Bad values are refused, naming the flag.
    for (extra, says) in [
        (&["--rollouts-per-state", "0"][..], "--rollouts-per-state"),
        (&["--rollouts-per-state", "2", "--sandbox"][..], "--sandbox"),
    ] {
        let o = eval_quick("avoiding", &onnx, extra);
        assert!(!o.status.success());
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(stderr.contains(says), "{stderr}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
