//! wss:// endpoints through the real sandboxed `d3il worker` and `d3il eval`:
//! the reference Python server (`python -m d3il_client.serve`, clients/python) serves
//! TLS on 127.0.0.1 with a certificate from a CA generated here (rcgen). The
//! extra CA reaches the worker in the job (Limits::extra_ca_pem), filled by the
//! parent from $D3IL_EXTRA_CA_FILE; the worker itself reads no CA file.
//!
//! Needs python3 with numpy, websockets and msgpack
//! (the `serve` extra of clients/python).

use crate::worker_common;

use d3il_protocol::{ErrorKind, EvalResult, Limits, PolicySource};
use d3il_sandbox::{Outcome, WorkerRun};
use d3il_test_support::listening::Listening;
use d3il_test_support::Pki;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use worker_common::*;

/// The reference server with its avoiding demo policy, killed when dropped.
fn start(tls: Option<&Pki>) -> Listening {
    let clients = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("clients/python");
    let mut cmd = Command::new("python3");
    cmd.args([
        "-m",
        "d3il_client.serve",
        "--demo",
        "avoiding",
        "--port",
        "0",
    ])
    .env("PYTHONPATH", clients);
    if let Some(p) = tls {
        cmd.arg("--certfile")
            .arg(&p.cert)
            .arg("--keyfile")
            .arg(&p.key);
    }
    Listening::spawn(&mut cmd, "python3 is needed for the remote tests")
}

fn tls_limits(extra_ca: Option<&str>) -> Limits {
    Limits {
        remote_deadline_ms: 5000,
        remote_frame_bytes: 1 << 20,
        allow_private_endpoints: true,
        extra_ca_pem: extra_ca.map(str::to_string),
        ..Limits::default()
    }
}

fn run_url(url: String, limits: Limits) -> WorkerRun {
    let job = avoiding_job(PolicySource::Remote { url, secret: None }, limits);
    run(&job, Duration::from_secs(300)).0
}

fn completed(r: &WorkerRun) -> &EvalResult {
    match &r.outcome {
        Outcome::Completed(res) => res,
        other => panic!("{other:?}\n{}", r.stderr),
    }
}

#[test]
fn a_wss_endpoint_trusted_through_the_extra_ca_completes_like_ws() {
    let dir = scratch("wss-ok");
    let p = Pki::new(&dir, &["127.0.0.1"]);
    let tls = start(Some(&p));
    let r = run_url(
        format!("wss://127.0.0.1:{}/", tls.port),
        tls_limits(Some(&p.ca_pem)),
    );
    let over_tls = completed(&r);
    assert!(!over_tls.rollouts.is_empty());
    // The same sandbox as for ws://: network only to the endpoint's port.
    let net = r
        .mechanisms
        .iter()
        .find(|m| m.name == "landlock-net")
        .unwrap();
    assert!(
        net.active
            && net
                .detail
                .contains(&format!("TCP connect only to port {}", tls.port)),
        "{}",
        net.detail
    );
    let fs = r
        .mechanisms
        .iter()
        .find(|m| m.name == "landlock-fs")
        .unwrap();
    assert!(fs.active, "{}", fs.detail);
    // The same policy over plain ws:// gives the same evaluation.
    let plain = start(None);
    let r2 = run_url(format!("ws://127.0.0.1:{}/", plain.port), tls_limits(None));
    let over_ws = completed(&r2);
    assert_eq!(over_tls.rollouts, over_ws.rollouts);
    let (a, b) = (&over_tls.metrics, &over_ws.metrics);
    assert_eq!(
        (a.success_rate, a.behaviour_entropy, a.conditional_entropy),
        (b.success_rate, b.behaviour_entropy, b.conditional_entropy)
    );
    // The demo policy steers past the obstacles.
    assert!(a.success_rate.value > 0.5, "{a:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn without_the_extra_ca_the_worker_reports_the_certificate() {
    let dir = scratch("wss-untrusted");
    let p = Pki::new(&dir, &["127.0.0.1"]);
    let tls = start(Some(&p));
    let r = run_url(format!("wss://127.0.0.1:{}/", tls.port), tls_limits(None));
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::BadEndpoint, "{e:?}\n{}", r.stderr);
    assert!(
        e.message
            .starts_with("the endpoint's TLS certificate is not valid for host `127.0.0.1`: "),
        "{}",
        e.message
    );
    assert!(
        e.message.contains("not signed by a publicly trusted CA"),
        "{}",
        e.message
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn ws_to_a_tls_port_and_wss_to_a_plain_port_fail_clearly() {
    let dir = scratch("wss-mismatch");
    let p = Pki::new(&dir, &["127.0.0.1"]);
    let tls = start(Some(&p));
    let r = run_url(format!("ws://127.0.0.1:{}/", tls.port), tls_limits(None));
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::Remote, "{e:?}\n{}", r.stderr);
    assert!(
        e.message
            .contains("closed the connection without answering the WebSocket handshake")
            && e.message.contains("use wss:// instead of ws://"),
        "{}",
        e.message
    );
    let plain = start(None);
    let r = run_url(
        format!("wss://127.0.0.1:{}/", plain.port),
        tls_limits(Some(&p.ca_pem)),
    );
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::Remote, "{e:?}\n{}", r.stderr);
    assert!(
        e.message
            .contains("closed the connection during the TLS handshake")
            && e.message.contains("use ws:// instead of wss://"),
        "{}",
        e.message
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// `d3il eval` (sandboxed and not) trusts the CA file named by
/// $D3IL_EXTRA_CA_FILE; set here for the child process only.
fn eval_cli(port: u16, ca_file: Option<&Path>, sandbox: bool) -> std::process::Output {
    let mut cmd = Command::new(d3il());
    cmd.args(["eval", "--task", "avoiding", "--protocol", "quick"])
        .args(["--allow-private-endpoints", "--policy"])
        .arg(format!("wss://127.0.0.1:{port}/"))
        .env_remove(Limits::EXTRA_CA_ENV)
        .stdin(Stdio::null());
    if sandbox {
        cmd.arg("--sandbox");
    }
    if let Some(f) = ca_file {
        cmd.env(Limits::EXTRA_CA_ENV, f);
    }
    cmd.output().unwrap()
}

#[test]
fn d3il_eval_trusts_the_ca_file_named_by_the_environment() {
    let dir = scratch("wss-cli");
    let p = Pki::new(&dir, &["127.0.0.1"]);
    let tls = start(Some(&p));
    let mut outputs = Vec::new();
    for sandbox in [true, false] {
        let out = eval_cli(tls.port, Some(&p.ca_file), sandbox);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "sandbox {sandbox}: {stderr}");
        if sandbox {
            assert!(stderr.contains("sandbox: landlock-fs active"), "{stderr}");
        }
        // All but the timing line.
        let stdout = String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter(|l| !l.starts_with("inference ms"))
            .collect::<Vec<_>>()
            .join("\n");
        outputs.push(stdout);
    }
    assert!(
        outputs[0].starts_with(
            "task avoiding, state observations (1 x 8 rollouts, quick protocol, seed 0)"
        ) && outputs[0].contains("success rate"),
        "{}",
        outputs[0]
    );
    // Sandboxed or not, the same evaluation.
    assert_eq!(outputs[0], outputs[1]);

    // Without the variable: the certificate error, named for the submitter.
    let out = eval_cli(tls.port, None, true);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("the endpoint's TLS certificate is not valid for host `127.0.0.1`"),
        "{stderr}"
    );
    // A variable naming a missing file is the operator's error, said so.
    let missing = dir.join("no-such-ca.pem");
    let out = eval_cli(tls.port, Some(&missing), true);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains(&format!(
            "cannot read the extra CA file {} named by $D3IL_EXTRA_CA_FILE",
            missing.display()
        )),
        "{stderr}"
    );
    assert_nothing_left_in_tmp();
    std::fs::remove_dir_all(dir).unwrap();
}

fn assert_nothing_left_in_tmp() {
    let files = leftover_files();
    assert!(files.is_empty(), "files left behind: {files:?}");
}
