//! The remote client against the reference Python server (clients/python),
//! started as a real process on 127.0.0.1. Needs python3 with numpy, websockets
//! and msgpack (the `serve` extra of clients/python).

use crate::common;

use common::{repo, spec};
use d3il_policy::{validate_actions, Policy, PolicyError, Query, RemotePolicy};
use d3il_protocol::{EndpointSecret, ErrorKind, Limits, ObsType, TaskId};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

/// A server process, killed when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs `python3 -m MODULE ARGS` of the d3il_client package in clients/python.
fn start(module: &str, args: &[&str]) -> Server {
    let dir = repo().join("clients/python");
    let mut child = Command::new("python3")
        .args(["-m", module])
        .args(args)
        .current_dir(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("python3 must be installed to run the remote-policy tests");
    let stdout = child.stdout.take().expect("stdout");
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("server prints its port");
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| {
            panic!("unexpected server output {line:?} (pip install './clients/python[serve]')")
        })
        .to_string();
    Server {
        child,
        url: format!("ws://{addr}/"),
    }
}

fn testing(mode: &str) -> Server {
    start("d3il_client.serve.testing", &["--mode", mode])
}

fn limits() -> Limits {
    Limits {
        remote_deadline_ms: 1500,
        ..d3il_test_support::loopback_limits()
    }
}

fn connect(server: &Server) -> Result<RemotePolicy, PolicyError> {
    RemotePolicy::connect(
        &server.url,
        None,
        &spec(TaskId::Avoiding),
        ObsType::State,
        7,
        &limits(),
    )
}

const START: [f32; 8] = [
    0.5249, -0.2797, 0.5249, -0.2797, // start: towards 0.57
    0.55, 0.0, 0.55, 0.0, // phase 2: towards 0.50
];

/// Query two rollouts; returns the error of the first failing call.
fn query(p: &mut RemotePolicy) -> Result<d3il_policy::ActionChunks, PolicyError> {
    p.reset(&[1, 2])?;
    let q = Query::new(&[1, 2], &[0, 30], &START);
    let a = p.infer(&q)?;
    validate_actions(&q, &p.shape(), &a)?;
    Ok(a)
}

#[test]
fn reference_server_serves_the_demo_policy() {
    let s = start("d3il_client.serve", &["--demo", "avoiding", "--port", "0"]);
    let mut p = connect(&s).unwrap();
    let sh = p.shape();
    assert_eq!(
        (sh.history, sh.horizon, sh.execute, sh.act_dim),
        (1, 1, 1, 2)
    );
    let a = query(&mut p).unwrap();
    let want = [0.008f32, 0.008, -0.008, 0.008];
    for (g, w) in a.data.iter().zip(want) {
        assert!((g - w).abs() < 1e-6, "{:?}", a.data);
    }
    // Many queries on one connection.
    for step in 1..50u64 {
        let steps = [step, step];
        let q = Query::new(&[1, 2], &steps, &START);
        assert_eq!(p.infer(&q).unwrap().data, a.data);
    }
}

#[test]
fn chunks_history_and_resets_reach_the_server() {
    let s = start(
        "d3il_client.serve.testing",
        &[
            "--mode",
            "ok",
            "--history",
            "2",
            "--horizon",
            "3",
            "--execute",
            "2",
        ],
    );
    let mut p = connect(&s).unwrap();
    let sh = p.shape();
    assert_eq!((sh.history, sh.horizon, sh.execute), (2, 3, 2));
    p.reset(&[1, 2]).unwrap();
    p.reset(&[5]).unwrap();
    // Newest history entry last: [old, new] per rollout.
    let obs = [9.0, 9.0, 9.0, 9.0, 0.5249, -0.2797, 0.5249, -0.2797];
    let a = p.infer(&Query::new(&[5], &[0], &obs)).unwrap();
    assert_eq!((a.batch, a.horizon, a.act_dim), (1, 3, 2));
    for h in 0..3 {
        assert!((a.action(0, h)[0] - 0.008).abs() < 1e-6);
    }
    // Rollout id 999 makes the testing server report the resets it saw.
    let e = p.infer(&Query::new(&[999], &[0], &obs)).unwrap_err();
    assert!(e.to_string().contains("resets seen: [[1, 2], [5]]"), "{e}");
    assert_eq!(e.kind(), ErrorKind::Remote);
}

fn failure(mode: &str) -> PolicyError {
    let s = testing(mode);
    let r = connect(&s).and_then(|mut p| query(&mut p).map(|_| p));
    match r {
        Ok(_) => panic!("mode {mode}: expected an error"),
        Err(e) => e,
    }
}

#[test]
fn hanging_server_is_late() {
    let e = failure("hang");
    assert!(matches!(e, PolicyError::Late { .. }), "{e}");
    assert!(e.to_string().contains("within 1500 ms"), "{e}");
    assert_eq!(e.kind(), ErrorKind::Remote);
}

#[test]
fn dribbling_server_is_late() {
    let e = failure("slow-drip");
    assert!(matches!(e, PolicyError::Late { .. }), "{e}");
}

#[test]
fn nan_actions_fail_validation() {
    let e = failure("nan");
    assert_eq!(e.kind(), ErrorKind::BadAction);
    assert!(e.to_string().contains("rollout 1 at step 0"), "{e}");
}

#[test]
fn wrong_shape_is_reported() {
    let e = failure("wrong-shape");
    assert!(matches!(e, PolicyError::WrongShape { .. }), "{e}");
    assert!(
        e.to_string().contains("actions [2, 1, 3]") && e.to_string().contains("expected [2, 1, 2]"),
        "{e}"
    );
}

#[test]
fn oversized_reply_is_refused() {
    let e = failure("oversized");
    assert!(matches!(e, PolicyError::Oversized { .. }), "{e}");
    assert!(e.to_string().contains("1048576 byte frame limit"), "{e}");
}

#[test]
fn garbage_and_text_frames_are_malformed() {
    let e = failure("garbage");
    assert!(e.to_string().contains("not valid msgpack"), "{e}");
    let e = failure("text");
    assert!(e.to_string().contains("text frame"), "{e}");
    let e = failure("wrong-id");
    assert!(e.to_string().contains("reply is for request 12345"), "{e}");
}

#[test]
fn disconnect_and_server_errors() {
    let e = failure("disconnect");
    assert!(matches!(e, PolicyError::Disconnected { .. }), "{e}");
    let e = failure("error");
    assert!(e.to_string().contains("model exploded"), "{e}");
}

#[test]
fn bad_hello_is_refused() {
    let e = failure("bad-version");
    assert!(
        matches!(e, PolicyError::ProtocolVersion { got: 99, .. }),
        "{e}"
    );
    let e = failure("bad-hello");
    assert!(e.to_string().contains("missing field `history`"), "{e}");
}

#[test]
fn connection_is_unusable_after_a_failure() {
    let s = testing("error");
    let mut p = connect(&s).unwrap();
    assert!(query(&mut p).is_err());
    let e = p.reset(&[1]).unwrap_err();
    assert!(e.to_string().contains("already unusable"), "{e}");
}

#[test]
fn nothing_listening_is_a_connect_error() {
    // Bind and drop to get a port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let e = RemotePolicy::connect(
        &format!("ws://127.0.0.1:{port}/"),
        None,
        &spec(TaskId::Avoiding),
        ObsType::State,
        0,
        &limits(),
    )
    .unwrap_err();
    assert!(matches!(e, PolicyError::Connect { .. }), "{e}");
}

/// A server started with a shared secret (`--secret`) serves the client
/// that sends it in the handshake and refuses one without it, or with
/// another, with a message that says which and what to do.
#[test]
fn a_server_with_a_secret_serves_only_the_client_that_sends_it() {
    let secret = "correct-horse-battery-staple";
    let s = start(
        "d3il_client.serve",
        &["--demo", "avoiding", "--port", "0", "--secret", secret],
    );
    let connect_with = |secret: Option<&str>| {
        let secret = secret.map(|t| EndpointSecret::new(t).unwrap());
        RemotePolicy::connect(
            &s.url,
            secret.as_ref(),
            &spec(TaskId::Avoiding),
            ObsType::State,
            7,
            &limits(),
        )
    };
    let mut p = connect_with(Some(secret)).expect("the right secret is served");
    assert_eq!(
        query(&mut p).unwrap().data.len(),
        4,
        "two rollouts' xy actions"
    );

    let e = connect_with(None).unwrap_err();
    assert!(
        matches!(e, PolicyError::Unauthorized { status: 401, .. }),
        "{e:?}"
    );
    assert_eq!(e.kind(), ErrorKind::BadEndpoint, "not retried");
    let m = e.to_string();
    assert!(
        m.contains("refused the evaluator (HTTP 401: this endpoint needs its shared secret"),
        "{m}"
    );
    assert!(m.contains("no endpoint secret was sent"), "{m}");

    let e = connect_with(Some("not-the-right-secret")).unwrap_err();
    let m = e.to_string();
    assert!(
        m.contains("the shared secret sent does not match this endpoint's"),
        "{m}"
    );
    assert!(
        m.contains("the endpoint secret sent does not match the server's"),
        "{m}"
    );
    assert!(
        !m.contains("not-the-right-secret") && !m.contains(secret),
        "{m}"
    );
}
