//! Hostile remote endpoints through the real `d3il worker`: a server that hangs,
//! sends oversized frames, sends garbage, disconnects mid-episode or answers
//! with the wrong batch size (`python -m d3il_client.serve.testing`, started here on
//! 127.0.0.1). Each ends with its typed outcome and nothing left behind; the
//! endpoint checks refuse private addresses unless the job allows them (issue 6).
//!
//! Needs python3 with numpy, websockets and msgpack
//! (the `serve` extra of clients/python).

use crate::worker_common;

use d3il_protocol::{ErrorKind, Limits, PolicySource};
use d3il_sandbox::Outcome;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;
use worker_common::*;

fn clients_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("clients/python")
}

/// A policy server on 127.0.0.1; killed (by its own pid) when dropped.
struct Server {
    child: Child,
    port: u16,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Modes that d3il_client.serve.testing lacks, as subclasses defined here.
const EXTRA_MODES: &str = r#"
import asyncio, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from d3il_client.serve.testing import MisbehavingServer

class WrongBatch(MisbehavingServer):
    def policy(self, obs, req):
        a = super().policy(obs, req)
        # One row more than rollouts asked for.
        return np.concatenate([a, a[:1]], axis=0)

server = WrongBatch("ok", history=1, horizon=1, execute=1)
asyncio.run(server.run("127.0.0.1", 0, lambda port: print(f"listening on 127.0.0.1:{port}", flush=True)))
"#;

fn start(mode: &str) -> Server {
    let mut cmd = Command::new("python3");
    if mode == "wrong-batch" {
        cmd.args(["-c", EXTRA_MODES]).arg(clients_dir());
    } else {
        cmd.args(["-m", "d3il_client.serve.testing", "--mode", mode])
            .env("PYTHONPATH", clients_dir());
    }
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3 is needed for the remote tests");
    let stdout = child.stdout.take().unwrap();
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).unwrap();
    let port = line
        .trim()
        .rsplit(':')
        .next()
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("{mode}: server did not start: `{line}`"));
    Server { child, port }
}

fn remote_limits() -> Limits {
    Limits {
        remote_deadline_ms: 2000,
        remote_frame_bytes: 1 << 20,
        allow_private_endpoints: true,
        ..Limits::default()
    }
}

fn run_against(mode: &str) -> d3il_sandbox::WorkerRun {
    let server = start(mode);
    let job = avoiding_job(
        PolicySource::Remote {
            url: format!("ws://127.0.0.1:{}/", server.port),
            secret: None,
        },
        remote_limits(),
    );
    let (r, _) = run(&job, Duration::from_secs(300));
    drop(server);
    r
}

/// The one outcome `mode` must produce: `kind`, with exactly `message`.
fn expect(mode: &str, kind: ErrorKind, message: &str) {
    let r = run_against(mode);
    let e = failure(&r);
    assert_eq!(e.kind, kind, "{mode}: {e:?}\n{}", r.stderr);
    assert_eq!(e.message, message, "{mode}");
}

#[test]
fn a_well_behaved_endpoint_completes_with_network_only_for_it() {
    let r = run_against("ok");
    match &r.outcome {
        Outcome::Completed(res) => assert!(!res.rollouts.is_empty()),
        other => panic!("{other:?}\n{}", r.stderr),
    }
    let net = r
        .mechanisms
        .iter()
        .find(|m| m.name == "landlock-net")
        .unwrap();
    assert!(
        net.active && net.detail.contains("TCP connect only to port"),
        "{}",
        net.detail
    );
    let ns = r
        .mechanisms
        .iter()
        .find(|m| m.name == "network-namespace")
        .unwrap();
    assert!(
        !ns.active && ns.detail.starts_with("not used"),
        "{}",
        ns.detail
    );
}

#[test]
fn a_hanging_endpoint_misses_the_deadline() {
    expect(
        "hang",
        ErrorKind::Remote,
        "the policy server did not answer the infer within 2000 ms; answer every request within the deadline (batch your inference, or ask for a larger deadline)",
    );
}

#[test]
fn oversized_frames_are_refused() {
    expect(
        "oversized",
        ErrorKind::Remote,
        "the policy server sent a infer reply larger than the 1048576 byte frame limit; send float32 arrays and nothing else large",
    );
}

#[test]
fn garbage_frames_are_refused() {
    expect(
        "garbage",
        ErrorKind::Remote,
        "the policy server sent a malformed infer reply: not valid msgpack (starts with the reserved byte 0xc1) (see docs/remote-protocol.md)",
    );
}

#[test]
fn a_disconnect_mid_episode_is_a_remote_error() {
    expect(
        "disconnect",
        ErrorKind::Remote,
        "the policy server closed the connection during the infer (close code 1000: ); it must stay connected for the whole evaluation",
    );
}

#[test]
fn a_connection_dropped_after_some_steps_is_a_remote_error() {
    let r = run_against("drop-later");
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::Remote, "{e:?}\n{}", r.stderr);
    assert!(e.message.starts_with("the policy server "), "{}", e.message);
    assert!(e.message.contains("during the infer"), "{}", e.message);
}

#[test]
fn an_infinite_action_later_in_the_episode_names_its_rollout_and_step() {
    expect(
        "inf-later",
        ErrorKind::BadAction,
        "policy returned a non-finite action (inf) for rollout 3 at step 5 (action 0 of the chunk, component 1); actions must be finite numbers",
    );
}

#[test]
fn a_wrong_batch_size_is_a_bad_action() {
    // The reply decodes fine, so it is the policy's output that is wrong (as
    // for an ONNX policy), not the protocol.
    expect(
        "wrong-batch",
        ErrorKind::BadAction,
        "policy returned actions [9, 1, 2] for a query of 8 rollouts (first rollout 0 at step 0); expected [8, 1, 2]",
    );
}

#[test]
fn nan_and_wrongly_shaped_remote_actions_are_bad_actions() {
    expect(
        "nan",
        ErrorKind::BadAction,
        "policy returned a non-finite action (NaN) for rollout 0 at step 0 (action 0 of the chunk, component 0); actions must be finite numbers",
    );
    expect(
        "wrong-shape",
        ErrorKind::BadAction,
        "policy returned actions [8, 1, 3] for a query of 8 rollouts (first rollout 0 at step 0); expected [8, 1, 2]",
    );
}

#[test]
fn private_endpoints_are_refused_by_default() {
    let server = start("ok");
    let job = avoiding_job(
        PolicySource::Remote {
            url: format!("ws://127.0.0.1:{}/", server.port),
            secret: None,
        },
        Limits {
            allow_private_endpoints: false,
            ..remote_limits()
        },
    );
    let (r, _) = run(&job, Duration::from_secs(120));
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::BadEndpoint, "{e:?}");
    assert!(e.message.contains("loopback"), "{}", e.message);
    // What the operator changes to allow it (a job of `d3il serve` or
    // `d3il workers`; `d3il eval` always allows it).
    assert!(
        e.message.contains("`d3il serve`") && e.message.contains("`--allow-private-endpoints`"),
        "{}",
        e.message
    );
    for url in ["http://127.0.0.1/", "ws:///nohost", "ws://169.254.169.254/"] {
        let job = avoiding_job(
            PolicySource::Remote {
                url: url.into(),
                secret: None,
            },
            Limits::default(),
        );
        let (r, _) = run(&job, Duration::from_secs(120));
        assert_eq!(failure(&r).kind, ErrorKind::BadEndpoint, "{url}");
    }
}
