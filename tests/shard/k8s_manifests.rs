//! The Kubernetes manifests of docs/cluster.md, without a Kubernetes cluster:
//! they parse (PyYAML, installed by `./dev test`), the eval Job is an Indexed
//! Job with as many completions as shards and shares its results volume with
//! the merge Job, and their containers' shell commands, run with `sh` as the
//! pods would (one per JOB_COMPLETION_INDEX, with the manifest's environment,
//! `d3il` on PATH, the results volume at a temporary directory), give the
//! result of a plain `d3il eval`.

use crate::shard_support;

use serde_json::Value;
use shard_support::assert_same_result;
use std::path::Path;
use std::process::Command;

fn load(name: &str) -> Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/cluster")
        .join(name);
    let out = Command::new("python3")
        .args([
            "-c",
            "import json, sys, yaml; json.dump(yaml.safe_load(open(sys.argv[1])), sys.stdout)",
        ])
        .arg(&path)
        .output()
        .expect("python3 (./dev test installs python3-yaml)");
    let json = d3il_test_support::succeeded(&out, &format!("parsing {}", path.display()));
    serde_json::from_str(&json).unwrap()
}

fn container(job: &Value) -> &Value {
    &job["spec"]["template"]["spec"]["containers"][0]
}

fn env(c: &Value) -> Vec<(String, String)> {
    c["env"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|e| {
                    (
                        e["name"].as_str().unwrap().to_string(),
                        e["value"].as_str().unwrap().to_string(),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

fn mount(c: &Value, volume: &str) -> String {
    c["volumeMounts"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == volume)
        .and_then(|m| m["mountPath"].as_str())
        .unwrap_or_else(|| panic!("no mount of {volume}"))
        .to_string()
}

/// Runs the container's command with `sh` as the pod would.
fn run_pod(c: &Value, vars: &[(String, String)], results: &Path, bin: &Path, index: Option<usize>) {
    let cmd: Vec<&str> = c["command"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(cmd, ["/bin/sh", "-c"]);
    let script = c["args"][0].as_str().unwrap();
    // The results volume is a directory here.
    let script = script.replace(&mount(c, "results"), &results.to_string_lossy());
    let mut sh = Command::new("/bin/sh");
    sh.args(["-c", &script]);
    for (k, v) in vars {
        sh.env(k, v);
    }
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    sh.env("PATH", path);
    if let Some(i) = index {
        sh.env("JOB_COMPLETION_INDEX", i.to_string());
    }
    let out = sh.output().unwrap();
    assert!(
        out.status.success(),
        "pod {index:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn indexed_job_and_merge_job_give_the_plain_evaluation() {
    let eval = load("d3il-indexed-job.yaml");
    let merge = load("d3il-merge-job.yaml");
    assert_eq!(eval["kind"], "Job");
    assert_eq!(eval["spec"]["completionMode"], "Indexed");
    let (ce, cm) = (container(&eval), container(&merge));
    let shards: usize = env(ce)
        .iter()
        .find(|(k, _)| k == "D3IL_SHARDS")
        .map(|(_, v)| v.parse().unwrap())
        .unwrap();
    assert_eq!(eval["spec"]["completions"], shards);
    assert!(env(cm).contains(&("D3IL_SHARDS".to_string(), shards.to_string())));
    // Both jobs mount the same claim at the same place.
    let claim = |job: &Value| {
        job["spec"]["template"]["spec"]["volumes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|v| v["name"] == "results")
            .map(|v| v["persistentVolumeClaim"]["claimName"].clone())
            .unwrap()
    };
    assert_eq!(claim(&eval), claim(&merge));
    assert_eq!(mount(ce, "results"), mount(cm, "results"));

    let dir = std::env::temp_dir().join(format!("d3il-k8s-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (results, bin) = (dir.join("results"), dir.join("bin"));
    std::fs::create_dir_all(&results).unwrap();
    std::fs::create_dir_all(&bin).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_d3il"), bin.join("d3il")).unwrap();
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");

    // The quick protocol has 3 initial states: 3 shards of a scripted policy.
    let over = |vars: Vec<(String, String)>| -> Vec<(String, String)> {
        vars.into_iter()
            .map(|(k, v)| {
                let v = match k.as_str() {
                    "D3IL_TASK" => "pushing".into(),
                    "D3IL_POLICY" => "scripted:pushing:all-modes".into(),
                    "D3IL_PROTOCOL" => "quick".into(),
                    "D3IL_SEED" => "7".into(),
                    "D3IL_SHARDS" => "3".into(),
                    "D3IL_ASSETS" => assets.to_string_lossy().into_owned(),
                    _ => v,
                };
                (k, v)
            })
            .collect()
    };
    let (ve, vm) = (over(env(ce)), over(env(cm)));
    for i in 0..3 {
        run_pod(ce, &ve, &results, &bin, Some(i));
    }
    for k in 1..=3 {
        assert!(results.join(format!("part-{k}-of-3.json")).is_file());
    }
    run_pod(cm, &vm, &results, &bin, None);

    let plain = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args([
            "eval",
            "--task",
            "pushing",
            "--policy",
            "scripted:pushing:all-modes",
        ])
        .args(["--protocol", "quick", "--seed", "7", "--json"])
        .arg(dir.join("plain.json"))
        .env("D3IL_ASSETS", &assets)
        .output()
        .unwrap();
    assert!(plain.status.success());
    assert_same_result(&dir.join("plain.json"), &results.join("result.json"));
    let _ = std::fs::remove_dir_all(&dir);
}
