//! Every way a worker can end, through the real parent (`run_worker`) and the
//! real child flow (`worker_main` + `confine`), with the self-test child as the
//! misbehaving worker (issue 6). Each test also checks that nothing of the worker
//! is left running (see common::run_mode).

mod common;

use common::*;
use d3il_protocol::{ErrorKind, PolicySource};
use d3il_sandbox::Outcome;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const WALL: Duration = Duration::from_secs(60);

#[test]
fn a_good_run_completes_with_progress_and_all_mechanisms_active() {
    let (run, seen) = run_mode("ok", &job(scripted(), limits()), WALL);
    match &run.outcome {
        Outcome::Completed(r) => assert_eq!(r.manifest.evaluator_version, "selftest"),
        other => panic!("{other:?}\n{}", run.stderr),
    }
    assert_eq!(seen, vec![(0, 2), (1, 2), (2, 2)]);
    let names: Vec<&str> = run.mechanisms.iter().map(|m| m.name.as_str()).collect();
    for n in d3il_sandbox::confine::names::ALL {
        assert!(names.contains(&n), "mechanism {n} not reported: {names:?}");
    }
    // This machine's kernel (landlock ABI >= 6, seccomp, namespaces) has them all;
    // on a weaker kernel the test says which one is missing and why.
    for m in &run.mechanisms {
        assert!(m.active, "{} inactive: {}", m.name, m.detail);
    }
}

#[test]
fn library_output_on_fd1_does_not_corrupt_the_protocol() {
    let (run, _) = run_mode("printf", &job(scripted(), limits()), WALL);
    assert!(
        matches!(run.outcome, Outcome::Completed(_)),
        "{:?}",
        run.outcome
    );
    assert!(
        run.stderr.contains("raw write to fd 1"),
        "the noise goes to stderr: {}",
        run.stderr
    );
}

#[test]
fn threads_still_work_inside_the_sandbox() {
    let (run, _) = run_mode("threads", &job(scripted(), limits()), WALL);
    assert!(
        matches!(run.outcome, Outcome::Completed(_)),
        "{:?}",
        run.outcome
    );
}

#[test]
fn memory_exhaustion_while_loading_is_a_memory_limit_error() {
    // The policy file must exist: confine() opens it (and landlock allows it).
    let dir = std::env::temp_dir().join(format!("d3il-sandbox-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let onnx = dir.join("model.onnx");
    std::fs::write(&onnx, b"not really onnx").unwrap();
    let policy = PolicySource::Onnx {
        path: onnx.display().to_string(),
        sha256: String::new(),
    };
    let (run, _) = run_mode("alloc", &job(policy, limits()), WALL);
    std::fs::remove_dir_all(&dir).unwrap();
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::MemoryLimit, "{e:?}\n{}", run.stderr);
    assert_eq!(
        e.message,
        "exceeded the 512 MiB memory limit while loading the ONNX file; make the model smaller or ask for a higher limit"
    );
}

#[test]
fn memory_exhaustion_during_rollouts_says_how_far_it_got() {
    let (run, seen) = run_mode("progress-then-alloc", &job(scripted(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::MemoryLimit, "{e:?}");
    assert!(
        e.message
            .contains("while running the rollouts (3 of 10 done)"),
        "{}",
        e.message
    );
    assert_eq!(seen, vec![(3, 10)]);
}

#[test]
fn cpu_exhaustion_is_a_cpu_limit_error() {
    let mut l = limits();
    l.cpu_seconds = 1;
    let (run, _) = run_mode("spin", &job(scripted(), l), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::CpuLimit, "{e:?}\n{}", run.stderr);
    assert!(e.message.contains("1 s CPU-time limit"), "{}", e.message);
}

#[test]
fn a_hanging_worker_is_killed_at_the_wall_clock() {
    let start = Instant::now();
    let (run, _) = run_mode("sleep", &job(scripted(), limits()), Duration::from_secs(2));
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::WallClock, "{e:?}");
    assert!(e.message.contains("2 s wall-clock limit"), "{}", e.message);
    // Not a speed goal: only that the kill happened instead of waiting forever.
    assert!(start.elapsed() < Duration::from_secs(50));
}

#[test]
fn garbage_on_stdout_is_a_protocol_violation() {
    let (run, _) = run_mode("garbage", &job(scripted(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::ProtocolViolation);
    assert!(
        e.message
            .contains("Hello! I am definitely not a JSON line."),
        "{}",
        e.message
    );
}

#[test]
fn endless_output_is_cut_at_the_cap() {
    let (run, _) = run_mode("flood", &job(scripted(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::ProtocolViolation);
    assert!(e.message.contains("more than 1 MiB"), "{}", e.message);
}

#[test]
fn exiting_without_a_result_is_a_crash() {
    let (run, _) = run_mode("silent-exit", &job(scripted(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::Crashed);
    assert!(
        e.message.contains("without reporting a result"),
        "{}",
        e.message
    );
}

#[test]
fn a_panic_is_a_crash_with_the_panic_message() {
    let (run, _) = run_mode("panic", &job(scripted(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::Crashed);
    assert!(e.message.contains("node of type Foo"), "{}", e.message);
}

#[test]
fn death_by_signal_is_a_crash_naming_the_signal() {
    for (mode, name) in [
        ("segfault", "SIGSEGV"),
        ("signal:9", "SIGKILL"),
        ("signal:6", "SIGABRT"),
        ("signal:15", "SIGTERM"),
    ] {
        let (run, _) = run_mode(mode, &job(scripted(), limits()), WALL);
        let e = expect_failed(&run);
        assert_eq!(e.kind, ErrorKind::Crashed, "{mode}: {e:?}");
        assert!(e.message.contains(name), "{mode}: {}", e.message);
    }
}

#[test]
fn processes_left_in_the_group_are_killed() {
    // The orphan is forked before confinement and sleeps forever; run_mode
    // asserts the group is empty afterwards.
    let (run, _) = run_mode("orphan", &job(scripted(), limits()), WALL);
    assert_eq!(expect_failed(&run).kind, ErrorKind::Crashed);
}

fn probe(mode: &str, policy: PolicySource, l: d3il_protocol::Limits) -> String {
    let (run, _) = run_mode(mode, &job(policy, l), WALL);
    let e = expect_failed(&run);
    assert!(
        e.message.starts_with("selftest"),
        "{mode}: {e:?}\n{}",
        run.stderr
    );
    e.message.clone()
}

#[test]
fn process_creation_is_denied() {
    assert!(probe("fork", scripted(), limits()).contains("denied"));
    assert!(probe("exec", scripted(), limits()).contains("denied"));
}

#[test]
fn the_filesystem_is_read_only_and_limited_to_the_assets() {
    let target = std::env::temp_dir().join(format!("d3il-sandbox-write-{}", std::process::id()));
    let m = probe(&format!("write:{}", target.display()), scripted(), limits());
    assert!(m.contains("denied"), "{m}");
    assert!(!target.exists(), "the worker created {}", target.display());
    assert!(probe("read:/etc/passwd", scripted(), limits()).contains("denied"));
    let asset = assets_dir().join("paper-results.json");
    let m = probe(&format!("read:{}", asset.display()), scripted(), limits());
    assert!(m.ends_with("allowed"), "{m}");
}

#[test]
fn the_worker_cannot_signal_its_parent() {
    assert!(probe("kill-parent", scripted(), limits()).contains("denied"));
}

fn accepted(listener: &TcpListener) -> usize {
    listener.set_nonblocking(true).unwrap();
    let mut n = 0;
    while let Ok((mut s, _)) = listener.accept() {
        let mut buf = Vec::new();
        let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
        let _ = s.read_to_end(&mut buf);
        n += 1;
    }
    n
}

#[test]
fn a_file_policy_job_cannot_connect_to_loopback() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let m = probe(&format!("connect:{port}"), scripted(), limits());
    assert!(m.contains("denied"), "{m}");
    assert_eq!(
        accepted(&listener),
        0,
        "something connected to the test listener"
    );
}

#[test]
fn a_remote_policy_job_reaches_only_its_endpoint_port() {
    let endpoint = TcpListener::bind("127.0.0.1:0").unwrap();
    let other = TcpListener::bind("127.0.0.1:0").unwrap();
    let ep = endpoint.local_addr().unwrap().port();
    let op = other.local_addr().unwrap().port();
    let mut l = limits();
    l.allow_private_endpoints = true;
    let remote = PolicySource::Remote {
        url: format!("ws://127.0.0.1:{ep}/policy"),
        secret: None,
    };
    let m = probe(&format!("connect:{ep}"), remote.clone(), l.clone());
    assert!(m.ends_with("allowed"), "{m}");
    assert_eq!(accepted(&endpoint), 1);
    let m = probe(&format!("connect:{op}"), remote, l);
    assert!(m.contains("denied"), "{m}");
    assert_eq!(
        accepted(&other),
        0,
        "connected to a port that is not the endpoint's"
    );
}

#[test]
fn private_endpoints_are_refused_unless_allowed() {
    let remote = PolicySource::Remote {
        url: "ws://127.0.0.1:9/policy".into(),
        secret: None,
    };
    let (run, _) = run_mode("ok", &job(remote.clone(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::BadEndpoint);
    assert!(e.message.contains("loopback"), "{}", e.message);
    let mut l = limits();
    l.allow_private_endpoints = true;
    let (run, _) = run_mode("ok", &job(remote, l.clone()), WALL);
    assert!(
        matches!(run.outcome, Outcome::Completed(_)),
        "{:?}",
        run.outcome
    );
    // A host name is resolved inside the sandbox (landlock allows the resolver
    // files) and every address is checked.
    let by_name = PolicySource::Remote {
        url: "ws://localhost:9/policy".into(),
        secret: None,
    };
    let (run, _) = run_mode("ok", &job(by_name.clone(), limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::BadEndpoint);
    assert!(
        e.message.contains("`localhost` resolves to"),
        "{}",
        e.message
    );
    // Refused at resolution time, naming the setting that would allow it.
    assert!(
        e.message.contains("--allow-private-endpoints"),
        "{}",
        e.message
    );
    let (run, _) = run_mode("ok", &job(by_name, l), WALL);
    assert!(
        matches!(run.outcome, Outcome::Completed(_)),
        "{:?}",
        run.outcome
    );
    let (run, _) = run_mode(
        "ok",
        &job(
            PolicySource::Remote {
                url: "http://8.8.8.8/".into(),
                secret: None,
            },
            limits(),
        ),
        WALL,
    );
    assert_eq!(expect_failed(&run).kind, ErrorKind::BadEndpoint);
}

#[test]
fn a_missing_policy_file_is_a_bad_model() {
    let policy = PolicySource::Onnx {
        path: "/nonexistent/model.onnx".into(),
        sha256: String::new(),
    };
    let (run, _) = run_mode("ok", &job(policy, limits()), WALL);
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::BadModel);
    assert!(
        e.message.contains("/nonexistent/model.onnx"),
        "{}",
        e.message
    );
}

#[test]
fn a_garbage_job_document_exits_with_bad_job() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_d3il-sandbox-selftest"))
        .arg("ok")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"{\"job_id\": 3")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(d3il_protocol::exit_code::BAD_JOB));
    let line: d3il_protocol::WorkerMessage = serde_json::from_slice(&out.stdout).unwrap();
    assert!(matches!(line, d3il_protocol::WorkerMessage::Error(e) if e.kind == ErrorKind::BadJob));
}

#[test]
fn requiring_all_mechanisms_passes_on_this_kernel() {
    let mut cmd = selftest_command("ok", WALL);
    cmd.args.extend(["--require".into(), "all".into()]);
    let run = d3il_sandbox::run_worker(&cmd, &job(scripted(), limits()), &mut |_, _| {});
    assert_no_stray(&run);
    assert!(
        matches!(run.outcome, Outcome::Completed(_)),
        "{:?}",
        run.outcome
    );
    let mut cmd = selftest_command("ok", WALL);
    cmd.args.extend(["--require".into(), "apparmor".into()]);
    let run = d3il_sandbox::run_worker(&cmd, &job(scripted(), limits()), &mut |_, _| {});
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::Internal);
    assert!(
        e.message.contains("unknown sandbox mechanism"),
        "{}",
        e.message
    );
}

#[test]
fn a_missing_worker_executable_is_an_internal_error() {
    let mut cmd = selftest_command("ok", WALL);
    cmd.exe = "/nonexistent/d3il".into();
    let run = d3il_sandbox::run_worker(&cmd, &job(scripted(), limits()), &mut |_, _| {});
    let e = expect_failed(&run);
    assert_eq!(e.kind, ErrorKind::Internal);
    assert!(e.message.contains("/nonexistent/d3il"), "{}", e.message);
}

#[test]
fn check_sandbox_reports_every_mechanism_and_every_probe_stopped() {
    let out = Command::new(env!("CARGO_BIN_EXE_d3il-sandbox-selftest"))
        .args(["check-sandbox", &assets_dir().display().to_string()])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ms: Vec<d3il_protocol::SandboxMechanism> = serde_json::from_slice(&out.stdout).unwrap();
    let names: Vec<&str> = ms.iter().map(|m| m.name.as_str()).collect();
    for n in d3il_sandbox::confine::names::ALL {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    for p in [
        "probe:tcp-connect-127.0.0.1",
        "probe:fork",
        "probe:exec",
        "probe:write-tmp",
        "probe:read-etc-passwd",
        "probe:signal-parent",
        "probe:read-assets",
        "probe:threads",
    ] {
        let m = ms
            .iter()
            .find(|m| m.name == p)
            .unwrap_or_else(|| panic!("{p} missing"));
        assert!(m.active, "{p}: {}", m.detail);
    }
}

fn pids_with_arg(tag: &str) -> Vec<i32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| e.file_name().to_string_lossy().parse::<i32>().ok())
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline"))
                .map(|c| c.split(|&b| b == 0).any(|a| a == tag.as_bytes()))
                .unwrap_or(false)
        })
        .collect()
}

#[test]
fn a_panicking_progress_callback_still_cleans_up_the_worker() {
    // A unique extra argument (ignored by the child) to find this test's worker.
    let tag = format!("--tag=panic-cleanup-{}", std::process::id());
    let mut cmd = selftest_command("progress-then-alloc", WALL);
    cmd.args.push(tag.clone());
    let job = job(scripted(), limits());
    let mut seen_alive = Vec::new();
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        d3il_sandbox::run_worker(&cmd, &job, &mut |_, _| {
            seen_alive = pids_with_arg(&tag);
            panic!("the caller's progress handler failed");
        })
    }));
    assert!(r.is_err(), "the panic propagates to the caller");
    assert_eq!(
        seen_alive.len(),
        1,
        "the worker was running during the callback"
    );
    assert!(
        pids_with_arg(&tag).is_empty(),
        "the worker survived the caller's panic"
    );
    assert!(group_members(seen_alive[0]).is_empty());
}
