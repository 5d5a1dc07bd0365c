//! Helpers shared by the sandbox's integration tests: jobs for the self-test
//! child, and a /proc scan for processes left in a worker's process group.
#![allow(dead_code, unused_imports)] // each test file uses a subset

use d3il_protocol::{Job, Limits, PolicySource};
use d3il_sandbox::{run_worker, Outcome, WorkerCommand, WorkerRun};
use std::path::PathBuf;
use std::time::Duration;

pub use d3il_test_support::assets_dir;

pub fn limits() -> Limits {
    Limits {
        memory_bytes: 512 << 20,
        cpu_seconds: 30,
        wall_seconds: 60,
        open_files: 64,
        file_size_bytes: 1 << 20,
        remote_deadline_ms: 2000,
        remote_frame_bytes: 1 << 20,
        allow_private_endpoints: false,
        extra_ca_pem: None,
    }
}

pub fn job(policy: PolicySource, limits: Limits) -> Job {
    Job {
        job_id: "selftest".into(),
        protocol: Default::default(),
        seed: 7,
        ..d3il_test_support::avoiding_job(policy, limits)
    }
}

pub fn scripted() -> PolicySource {
    PolicySource::Scripted {
        name: "selftest".into(),
    }
}

pub fn selftest_command(mode: &str, wall: Duration) -> WorkerCommand {
    WorkerCommand {
        exe: PathBuf::from(env!("CARGO_BIN_EXE_d3il-sandbox-selftest")),
        args: vec![mode.to_string()],
        wall_clock: wall,
        max_output_bytes: 1 << 20,
    }
}

/// Run a self-test mode; also asserts that nothing of the worker is left running.
pub fn run_mode(mode: &str, job: &Job, wall: Duration) -> (WorkerRun, Vec<(usize, usize)>) {
    let mut seen = Vec::new();
    let run = run_worker(&selftest_command(mode, wall), job, &mut |d, t| {
        seen.push((d, t))
    });
    assert_no_stray(&run);
    (run, seen)
}

pub fn assert_no_stray(run: &WorkerRun) {
    assert!(run.pid > 0, "worker was not started: {:?}", run.outcome);
    let left = group_members(run.pid as i32);
    assert!(
        left.is_empty(),
        "processes left in the worker's group {}: {left:?}",
        run.pid
    );
}

/// Pids of live (not zombie) processes whose process group is `pgid`.
pub fn group_members(pgid: i32) -> Vec<i32> {
    d3il_sandbox::live_group_members(pgid)
}

pub fn expect_failed(run: &WorkerRun) -> &d3il_protocol::WorkerError {
    match &run.outcome {
        Outcome::Failed(e) => e,
        other => panic!("expected a failure, got {other:?} (stderr: {})", run.stderr),
    }
}
