//! Shared by the tests of tests/worker/: jobs for the real `d3il worker`,
//! fixture copies and leftover checks.
#![allow(dead_code, unused_imports)] // each test file uses a subset

use d3il_protocol::{Job, Limits, PolicySource};
use d3il_sandbox::{run_worker, Outcome, WorkerCommand, WorkerRun};
use std::path::{Path, PathBuf};
use std::time::Duration;

pub fn d3il() -> PathBuf {
    isolation();
    PathBuf::from(env!("CARGO_BIN_EXE_d3il"))
}

pub use d3il_test_support::{assets_dir, fixtures_dir};

/// Per test binary: the TMPDIR and working directory every worker inherits
/// (both must stay empty: the sandbox lets a worker write nowhere) and the
/// parent of the tests' scratch directories. Set once, before the first worker
/// or scratch directory, by every helper here.
struct Isolation {
    tmp: PathBuf,
    cwd: PathBuf,
    scratch: PathBuf,
}

fn isolation() -> &'static Isolation {
    static ONCE: std::sync::OnceLock<Isolation> = std::sync::OnceLock::new();
    ONCE.get_or_init(|| {
        // Cargo's scratch space for integration tests, one fixed directory per
        // test binary (recreated empty on each run).
        let base = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(env!("CARGO_CRATE_NAME"));
        let _ = std::fs::remove_dir_all(&base);
        let iso = Isolation {
            tmp: base.join("tmp"),
            cwd: base.join("cwd"),
            scratch: base.join("scratch"),
        };
        for d in [&iso.tmp, &iso.cwd, &iso.scratch] {
            std::fs::create_dir_all(d).unwrap();
        }
        // Inherited by every worker (and python server) started from now on.
        std::env::set_var("TMPDIR", &iso.tmp);
        std::env::set_current_dir(&iso.cwd).unwrap();
        iso
    })
}

/// A fresh directory for one test's files, removed by the test.
pub fn scratch(name: &str) -> PathBuf {
    let d = isolation().scratch.join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Files in the workers' TMPDIR and working directory (must be none).
pub fn leftover_files() -> Vec<PathBuf> {
    let iso = isolation();
    std::fs::read_dir(&iso.tmp)
        .unwrap()
        .chain(std::fs::read_dir(&iso.cwd).unwrap())
        .map(|e| e.unwrap().path())
        .collect()
}

fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|r| r.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

pub fn limits() -> Limits {
    Limits {
        allow_private_endpoints: true,
        ..Limits::default()
    }
}

pub fn avoiding_job(policy: PolicySource, limits: Limits) -> Job {
    Job {
        kind: d3il_protocol::JobKind::Plain,
        job_id: "worker-test".into(),
        ..d3il_test_support::avoiding_job(policy, limits)
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

/// Run `job` through the real binary with the wall clock `wall`; asserts that
/// nothing of the worker is left (no process in its group, no file in the
/// inherited TMPDIR or working directory, none added next to the policy file).
pub fn run(job: &Job, wall: Duration) -> (WorkerRun, Vec<(usize, usize)>) {
    let mut cmd = WorkerCommand::for_job(d3il(), job);
    cmd.wall_clock = wall;
    run_cmd(&cmd, job)
}

/// As [`run`], with an explicit command (self-test modes, other wall clocks).
pub fn run_cmd(cmd: &WorkerCommand, job: &Job) -> (WorkerRun, Vec<(usize, usize)>) {
    let policy_dir = match &job.policy {
        PolicySource::Onnx { path, .. } => Path::new(path).parent().map(Path::to_path_buf),
        _ => None,
    };
    let before = policy_dir.as_deref().map(listing);
    let mut seen = Vec::new();
    let r = run_worker(cmd, job, &mut |d, t| seen.push((d, t)));
    assert!(r.pid > 0, "worker not started: {:?}", r.outcome);
    assert_nothing_left(&r);
    if let (Some(dir), Some(before)) = (policy_dir, before) {
        assert_eq!(listing(&dir), before, "files added next to the policy");
    }
    (r, seen)
}

/// No process left in the worker's group, no file in the workers' TMPDIR or
/// working directory.
pub fn assert_nothing_left(r: &WorkerRun) {
    let left = group_members(r.pid as i32);
    assert!(
        left.is_empty(),
        "processes left in the worker's group: {left:?}"
    );
    let files = leftover_files();
    assert!(files.is_empty(), "files left behind: {files:?}");
}

pub fn failure(r: &WorkerRun) -> &d3il_protocol::WorkerError {
    match &r.outcome {
        Outcome::Failed(e) => e,
        other => panic!("expected a failure, got {other:?}\n{}", r.stderr),
    }
}

/// Live (not zombie) processes whose process group is `pgid`.
pub fn group_members(pgid: i32) -> Vec<i32> {
    d3il_sandbox::live_group_members(pgid)
}

/// Copy a fixture next to nothing else, as an uploaded submission would be (a
/// fixture inside the assets directory would be readable through the assets).
pub fn fixture_copy(dir: &Path, name: &str) -> PathBuf {
    let to = dir.join(name);
    std::fs::copy(fixtures_dir().join(name), &to)
        .unwrap_or_else(|e| panic!("fixture {name}: {e} (generate with scripts/make_fixtures.py)"));
    to
}
