//! The real `d3il` binary's sandbox: `d3il worker --check-sandbox`, an ONNX job
//! that tries to reach a listener on 127.0.0.1, a worker killed by a signal, and
//! the documented exit codes (issue 6).

use crate::worker_common;

use d3il_protocol::{exit_code, ErrorKind, SandboxMechanism, WorkerMessage};
use d3il_sandbox::WorkerCommand;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::Duration;
use worker_common::*;

#[test]
fn check_sandbox_lists_the_mechanisms_in_force() {
    let out = Command::new(d3il())
        .args(["worker", "--check-sandbox", "--json", "--assets"])
        .arg(assets_dir())
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ms: Vec<SandboxMechanism> = serde_json::from_slice(&out.stdout).unwrap();
    for name in d3il_sandbox::confine::names::ALL {
        let m = ms
            .iter()
            .find(|m| m.name == name)
            .unwrap_or_else(|| panic!("{name} missing"));
        assert!(m.active, "{name}: {}", m.detail);
    }
    let probes: Vec<&SandboxMechanism> =
        ms.iter().filter(|m| m.name.starts_with("probe:")).collect();
    assert!(probes.len() >= 6, "{probes:?}");
    assert!(probes.iter().all(|p| p.active), "{probes:?}");

    // The human-readable table has one line per entry.
    let out = Command::new(d3il())
        .args(["worker", "--check-sandbox", "--assets"])
        .arg(assets_dir())
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(text.lines().count(), ms.len(), "{text}");
    assert!(
        text.contains("seccomp") && text.contains("landlock-fs"),
        "{text}"
    );
}

/// The real worker binary with a self-test evaluation (hidden flag).
fn self_test(mode: &str, job: &d3il_protocol::Job) -> d3il_sandbox::WorkerRun {
    let mut cmd = WorkerCommand::for_job(d3il(), job);
    cmd.args = vec!["worker".into(), "--self-test".into(), mode.into()];
    cmd.wall_clock = Duration::from_secs(120);
    run_cmd(&cmd, job).0
}

#[test]
fn an_onnx_job_cannot_open_a_tcp_connection_to_loopback() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let dir = scratch("tcp");
    let onnx = fixture_copy(&dir, "avoiding_path.onnx");
    let job = avoiding_job(onnx_policy(&onnx), limits());
    let r = self_test(&format!("connect:{port}"), &job);
    let e = failure(&r);
    assert!(
        e.message.starts_with("selftest connect: denied"),
        "the worker must report the refused connection: {e:?}"
    );
    listener.set_nonblocking(true).unwrap();
    let mut connected = 0;
    while let Ok((mut s, _)) = listener.accept() {
        let mut buf = Vec::new();
        let _ = s.read_to_end(&mut buf);
        connected += 1;
    }
    assert_eq!(connected, 0, "the sandboxed job reached 127.0.0.1:{port}");
    let netns = r
        .mechanisms
        .iter()
        .find(|m| m.name == "network-namespace")
        .unwrap();
    assert!(netns.active, "{}", netns.detail);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_worker_killed_by_a_signal_is_a_crash() {
    let job = avoiding_job(
        d3il_protocol::PolicySource::Scripted {
            name: "selftest".into(),
        },
        limits(),
    );
    let r = self_test("signal:9", &job);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::Crashed);
    assert!(e.message.contains("SIGKILL"), "{}", e.message);
    let r = self_test("segfault", &job);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::Crashed);
    assert!(e.message.contains("SIGSEGV"), "{}", e.message);
}

#[test]
fn memory_exhaustion_in_the_real_worker_names_the_limit() {
    let dir = scratch("alloc");
    let onnx = fixture_copy(&dir, "avoiding_path.onnx");
    let l = d3il_protocol::Limits {
        memory_bytes: 1 << 30,
        ..limits()
    };
    let job = avoiding_job(onnx_policy(&onnx), l);
    let r = self_test("alloc", &job);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::MemoryLimit, "{e:?}\n{}", r.stderr);
    assert_eq!(
        e.message,
        "exceeded the 1 GiB memory limit while loading the ONNX file; make the model smaller or ask for a higher limit"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn exit_codes_are_the_documented_ones() {
    // Not a job at all: BAD_JOB and a structured error line.
    let mut child = Command::new(d3il())
        .arg("worker")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(b"hello").unwrap();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(exit_code::BAD_JOB));
    let msg: WorkerMessage = serde_json::from_slice(&out.stdout).unwrap();
    assert!(matches!(msg, WorkerMessage::Error(e) if e.kind == ErrorKind::BadJob));

    // A job that fails: JOB_FAILED, sandbox line first, error line last.
    let dir = scratch("exit-codes");
    let onnx = fixture_copy(&dir, "hostile_garbage.onnx");
    let job = avoiding_job(onnx_policy(&onnx), limits());
    let mut child = Command::new(d3il())
        .arg("worker")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&serde_json::to_vec(&job).unwrap())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(exit_code::JOB_FAILED));
    let lines: Vec<WorkerMessage> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(
        matches!(lines.first(), Some(WorkerMessage::Sandbox { .. })),
        "{lines:?}"
    );
    assert!(
        matches!(lines.last(), Some(WorkerMessage::Error(e)) if e.kind == ErrorKind::BadModel),
        "{lines:?}"
    );

    // Requiring an unknown mechanism: SANDBOX_FAILED.
    let mut child = Command::new(d3il())
        .args(["worker", "--require", "selinux"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&serde_json::to_vec(&job).unwrap())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(exit_code::SANDBOX_FAILED));
    let files = leftover_files();
    assert!(files.is_empty(), "files left behind: {files:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The sandbox limits are knobs: `d3il eval --sandbox --memory-mb N` runs the
/// worker under N MiB, and a worker that runs out names that limit.
#[test]
fn the_memory_limit_flag_reaches_the_worker_and_names_itself() {
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/fixtures");
    let eval = |extra: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_d3il"))
            .args([
                "eval",
                "--task",
                "avoiding",
                "--protocol",
                "quick",
                "--sandbox",
            ])
            .arg("--policy")
            // A policy with noise: all 8 rollouts are simulated (a
            // deterministic one would be simulated once and fit in 100 MiB).
            .arg(format!("{fixtures}/avoiding_noise.onnx"))
            .args(extra)
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, stderr) = eval(&["--memory-mb", "100"]);
    assert!(!ok);
    assert!(
        stderr.contains("sandbox: rlimits active (address space 100 MiB"),
        "{stderr}"
    );
    assert!(
        stderr.contains("MemoryLimit: exceeded the 100 MiB memory limit while"),
        "{stderr}"
    );
    let (ok, stderr) = eval(&["--memory-mb", "0"]);
    assert!(!ok);
    assert!(
        stderr.contains("--memory-mb must be at least 1 (got 0)"),
        "{stderr}"
    );
}
