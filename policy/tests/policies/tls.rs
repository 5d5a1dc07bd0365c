//! wss:// endpoints: the remote client against the reference Python server
//! serving TLS (`python -m d3il_client.serve --certfile/--keyfile`, clients/python) on
//! 127.0.0.1, with a CA and certificates generated here by rcgen. Needs python3
//! with numpy, websockets and msgpack (the `serve` extra of clients/python).

use crate::common;

use common::{repo, spec};
use d3il_policy::{validate_actions, Policy, PolicyError, Query, RemotePolicy};
use d3il_protocol::{ErrorKind, Limits, ObsType, TaskId};
use d3il_test_support::{loopback_limits, Pki};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

fn scratch(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("policy-tls")
        .join(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The reference server (avoiding demo policy), killed when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start(tls: Option<&Pki>) -> Server {
    let dir = repo().join("clients/python");
    let mut cmd = Command::new("python3");
    cmd.args(["-m", "d3il_client.serve"])
        .env("PYTHONPATH", &dir)
        .args(["--demo", "avoiding", "--port", "0"]);
    if let Some(p) = tls {
        cmd.arg("--certfile")
            .arg(&p.cert)
            .arg("--keyfile")
            .arg(&p.key);
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("python3 must be installed to run the remote-policy tests");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| {
            panic!("unexpected server output {line:?} (pip install './clients/python[serve]')")
        })
        .to_string();
    Server { child, addr }
}

fn limits(extra_ca: Option<&str>) -> Limits {
    Limits {
        remote_deadline_ms: 3000,
        extra_ca_pem: extra_ca.map(str::to_string),
        ..loopback_limits()
    }
}

fn connect(url: &str, extra_ca: Option<&str>) -> Result<RemotePolicy, PolicyError> {
    RemotePolicy::connect(
        url,
        None,
        &spec(TaskId::Avoiding),
        ObsType::State,
        3,
        &limits(extra_ca),
    )
}

fn err(r: Result<RemotePolicy, PolicyError>) -> PolicyError {
    match r {
        Ok(p) => panic!("expected an error, connected: {p:?}"),
        Err(e) => e,
    }
}

#[test]
fn a_wss_endpoint_trusted_through_the_extra_ca_serves_actions() {
    let p = Pki::new(&scratch("ok"), &["127.0.0.1", "localhost"]);
    let s = start(Some(&p));
    let url = format!("wss://{}/", s.addr);
    let mut policy = connect(&url, Some(&p.ca_pem)).unwrap();
    assert_eq!(policy.url(), url);
    policy.reset(&[1, 2]).unwrap();
    // The demo's steering: towards x = 0.57 below y = -0.04, 0.50 above.
    let obs = [0.5249f32, -0.2797, 0.5249, -0.2797, 0.55, 0.0, 0.55, 0.0];
    for step in 0..20u64 {
        let steps = [step, step];
        let q = Query::new(&[1, 2], &steps, &obs);
        let a = policy.infer(&q).unwrap();
        validate_actions(&q, &policy.shape(), &a).unwrap();
        let want = [0.008f32, 0.008, -0.008, 0.008];
        for (g, w) in a.data.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{:?}", a.data);
        }
    }
}

#[test]
fn without_the_extra_ca_the_certificate_is_refused() {
    let p = Pki::new(&scratch("untrusted"), &["127.0.0.1"]);
    let s = start(Some(&p));
    let e = err(connect(&format!("wss://{}/", s.addr), None));
    assert_eq!(e.kind(), ErrorKind::BadEndpoint, "{e}");
    let m = e.to_string();
    assert!(
        m.starts_with("the endpoint's TLS certificate is not valid for host `127.0.0.1`: "),
        "{m}"
    );
    assert!(m.contains("not signed by a publicly trusted CA"), "{m}");
    // Another CA (here with the same name) does not help either.
    let other_ca = Pki::new(&scratch("other-ca"), &["127.0.0.1"]).ca_pem;
    let e = err(connect(&format!("wss://{}/", s.addr), Some(&other_ca)));
    let m = e.to_string();
    assert!(
        m.starts_with("the endpoint's TLS certificate is not valid for host `127.0.0.1`: ")
            && m.contains("not signed by a publicly trusted CA"),
        "{m}"
    );
}

#[test]
fn a_certificate_for_another_name_is_refused_naming_the_host() {
    let p = Pki::new(&scratch("wrong-name"), &["policy.example.org"]);
    let s = start(Some(&p));
    let e = err(connect(&format!("wss://{}/", s.addr), Some(&p.ca_pem)));
    assert_eq!(e.kind(), ErrorKind::BadEndpoint, "{e}");
    let m = e.to_string();
    assert!(
        m.starts_with("the endpoint's TLS certificate is not valid for host `127.0.0.1`: "),
        "{m}"
    );
    assert!(m.contains("does not name `127.0.0.1`"), "{m}");
}

#[test]
fn ws_against_a_tls_port_and_wss_against_a_plain_port_say_which_to_use() {
    let p = Pki::new(&scratch("mismatch"), &["127.0.0.1"]);
    let tls = start(Some(&p));
    // OpenSSL drops a plain HTTP request without answering, so the client
    // only sees the connection close (a transient-looking Remote error).
    let e = err(connect(&format!("ws://{}/", tls.addr), Some(&p.ca_pem)));
    assert_eq!(e.kind(), ErrorKind::Remote, "{e}");
    assert!(
        e.to_string()
            .contains("closed the connection without answering the WebSocket handshake")
            && e.to_string()
                .contains("if it serves TLS, use wss:// instead of ws://"),
        "{e}"
    );

    // The Python server drops a TLS ClientHello without an answer too.
    let plain = start(None);
    let e = err(connect(&format!("wss://{}/", plain.addr), Some(&p.ca_pem)));
    assert_eq!(e.kind(), ErrorKind::Remote, "{e}");
    assert!(
        e.to_string()
            .contains("closed the connection during the TLS handshake")
            && e.to_string().contains("use ws:// instead of wss://"),
        "{e}"
    );
    // The plain server still serves plain ws:// as before.
    let mut policy = connect(&format!("ws://{}/", plain.addr), None).unwrap();
    policy.reset(&[4]).unwrap();
}

#[test]
fn an_unusable_extra_ca_is_an_operator_error() {
    let p = Pki::new(&scratch("bad-ca"), &["127.0.0.1"]);
    let s = start(Some(&p));
    let e = err(connect(&format!("wss://{}/", s.addr), Some("no PEM here")));
    assert_eq!(e.kind(), ErrorKind::Internal, "{e}");
    assert!(
        e.to_string()
            .contains("the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) holds no"),
        "{e}"
    );
}

/// A TCP server on 127.0.0.1 that answers the first connection with `reply`
/// (whatever the client sent) and closes it.
fn answering(reply: &'static [u8]) -> (String, std::thread::JoinHandle<()>) {
    use std::io::{Read, Write};
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let t = std::thread::spawn(move || {
        let (mut s, _) = l.accept().unwrap();
        let mut buf = [0u8; 512];
        let _ = s.read(&mut buf);
        let _ = s.write_all(reply);
        let _ = s.flush();
        // Let the client read the reply before the close.
        let _ = s.read(&mut buf);
    });
    (addr, t)
}

#[test]
fn servers_that_answer_in_the_other_protocol_are_named() {
    // A plain HTTP answer to the TLS ClientHello.
    let (addr, t) = answering(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n");
    let e = err(connect(&format!("wss://{addr}/"), None));
    t.join().unwrap();
    assert_eq!(e.kind(), ErrorKind::BadEndpoint, "{e}");
    assert!(
        e.to_string().contains("did not answer with TLS")
            && e.to_string().contains("use ws:// instead of wss://"),
        "{e}"
    );
    // A TLS alert record (fatal, protocol_version) answering the HTTP upgrade.
    let (addr, t) = answering(&[0x15, 0x03, 0x03, 0x00, 0x02, 0x02, 0x46]);
    let e = err(connect(&format!("ws://{addr}/"), None));
    t.join().unwrap();
    assert_eq!(e.kind(), ErrorKind::BadEndpoint, "{e}");
    assert_eq!(
        e.to_string(),
        format!(
            "the policy server at `ws://{addr}/` answered with TLS; use wss:// instead of ws://"
        )
    );
}
