//! Shared by the tests/worker_*.rs tests: jobs for the real `d3il worker`,
//! fixture copies and leftover checks.
#![allow(dead_code)]

use d3il_protocol::{Job, Limits, ObsType, PolicyManifest, PolicySource, ProtocolKind, TaskId};
use d3il_sandbox::{run_worker, Outcome, WorkerCommand, WorkerRun};
use std::path::{Path, PathBuf};
use std::time::Duration;

pub fn d3il() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_d3il"))
}

pub fn assets_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets")
}

/// A fresh directory for one test's files, removed by the test.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("d3il-worker-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

pub fn limits() -> Limits {
    Limits {
        allow_private_endpoints: true,
        ..Limits::default()
    }
}

pub fn avoiding_job(policy: PolicySource, limits: Limits) -> Job {
    Job {
        job_id: "worker-test".into(),
        task: TaskId::Avoiding,
        protocol: ProtocolKind::Quick,
        policy,
        manifest: PolicyManifest {
            task: TaskId::Avoiding,
            obs_type: ObsType::State,
            history: 1,
            horizon: 1,
            execute: 1,
            normalisation: None,
        },
        seed: 1,
        limits,
        assets_dir: assets_dir().display().to_string(),
    }
}

pub fn sha256_file(path: &Path) -> String {
    let out = std::process::Command::new("sha256sum")
        .arg(path)
        .output()
        .expect("sha256sum (coreutils) is needed by the tests");
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .next()
        .unwrap_or_default()
        .to_string()
}

pub fn onnx_policy(path: &Path) -> PolicySource {
    PolicySource::Onnx {
        path: path.display().to_string(),
        sha256: sha256_file(path),
    }
}

/// Run `job` through the real binary; asserts nothing of the worker is left.
pub fn run(job: &Job, wall: Duration) -> (WorkerRun, Vec<(usize, usize)>) {
    let mut cmd = WorkerCommand::for_job(d3il(), job);
    cmd.wall_clock = wall;
    let mut seen = Vec::new();
    let r = run_worker(&cmd, job, &mut |d, t| seen.push((d, t)));
    assert!(r.pid > 0, "worker not started: {:?}", r.outcome);
    let left = group_members(r.pid as i32);
    assert!(
        left.is_empty(),
        "processes left in the worker's group: {left:?}"
    );
    (r, seen)
}

pub fn failure(r: &WorkerRun) -> &d3il_protocol::WorkerError {
    match &r.outcome {
        Outcome::Failed(e) => e,
        Outcome::Completed(_) => panic!("expected a failure, got a result\n{}", r.stderr),
    }
}

/// Live (not zombie) processes whose process group is `pgid`.
pub fn group_members(pgid: i32) -> Vec<i32> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        let Some(rest) = stat.rfind(')').map(|i| &stat[i + 1..]) else {
            continue;
        };
        let f: Vec<&str> = rest.split_whitespace().collect();
        if f.len() > 2 && f[2].parse::<i32>() == Ok(pgid) && f[0] != "Z" {
            out.push(pid);
        }
    }
    out
}

pub fn fixtures_dir() -> PathBuf {
    assets_dir().join("fixtures")
}

/// Copy a fixture next to nothing else, as an uploaded submission would be (a
/// fixture inside the assets directory would be readable through the assets).
pub fn fixture_copy(dir: &Path, name: &str) -> PathBuf {
    let to = dir.join(name);
    std::fs::copy(fixtures_dir().join(name), &to)
        .unwrap_or_else(|e| panic!("fixture {name}: {e} (generate with scripts/make_fixtures.py)"));
    to
}
