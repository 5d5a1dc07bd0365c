//! The endpoint conformance dry-run of the submit path (issue 7): a remote
//! endpoint is evaluated briefly (quick protocol, real sandboxed `d3il worker`)
//! before it is queued. Real WebSocket policy servers on 127.0.0.1 (the
//! reference Python server, `python -m d3il_client.serve.testing`) and the real
//! `d3il serve`. The server is started with --allow-private-endpoints (loopback
//! is refused otherwise, last test) and no worker slots, so an accepted
//! submission stays visibly queued.
//!
//! Needs python3 with numpy, websockets and msgpack (the `serve` extra of clients/python).

use crate::D3IL;
use d3il_server::client::ClientError;
use d3il_test_support::server::*;
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

/// A policy server on 127.0.0.1; killed (by its own pid) when dropped.
struct PolicyServer {
    child: Child,
    url: String,
}

impl Drop for PolicyServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn policy_server(mode: &str) -> PolicyServer {
    let clients = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("clients/python");
    let mut child = Command::new("python3")
        .args(["-m", "d3il_client.serve.testing", "--mode", mode])
        .env("PYTHONPATH", clients)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3 is needed for the remote tests");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port: u16 = line
        .trim()
        .rsplit(':')
        .next()
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("{mode}: policy server did not start: `{line}`"));
    PolicyServer {
        child,
        url: format!("ws://127.0.0.1:{port}/"),
    }
}

fn fields(method: &str, url: &str) -> Vec<(&'static str, String)> {
    vec![
        ("method", method.to_string()),
        ("task", "avoiding".to_string()),
        ("training_seed", "0".to_string()),
        ("protocol", "quick".to_string()),
        (
            "manifest",
            r#"{"task":"avoiding","obs_type":"state","history":1,"horizon":1,"execute":1}"#
                .to_string(),
        ),
        ("endpoint_url", url.to_string()),
    ]
}

/// "N jobs waiting" from the admin page's queue line.
fn queue_line(server: &TestServer, admin: &str) -> String {
    let (s, page) = server.client(Some(admin)).get_text("/admin").unwrap();
    assert_eq!(s, 200);
    page.split("<p id=\"queue\">")
        .nth(1)
        .and_then(|p| p.split(',').next())
        .expect("queue line on the admin page")
        .to_string()
}

/// Submits `url` and expects the dry-run to refuse it: 422, the one JSON error
/// format naming the `endpoint_url` field, a message that says what failed.
fn expect_refused(server: &TestServer, token: &str, method: &str, url: &str) -> String {
    let client = server.client(Some(token));
    match client.submit(&fields(method, url), None) {
        Err(ClientError::Api {
            status,
            code,
            message,
            field,
        }) => {
            assert_eq!(status, 422, "{message}");
            assert_eq!(code, "endpoint_rejected");
            assert_eq!(field.as_deref(), Some("endpoint_url"));
            assert!(
                message.starts_with(
                    "the endpoint failed the conformance dry-run (docs/remote-protocol.md): "
                ),
                "{message}"
            );
            // Nothing stored: not even the method.
            let (s, _) = server.get_text_blocking(&format!("/methods/{method}"));
            assert_eq!(s, 404, "method {method} was created");
            message
        }
        other => panic!("{method}: expected a refusal, got {other:?}"),
    }
}

#[test]
fn a_conforming_endpoint_is_queued_and_non_conforming_ones_are_refused() {
    let dir = TempDir::new("dry-run");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "dry-run-tester");
    let admin = D3IL.create_admin_token(&db, "operator");
    let server = D3IL.serve(&db, &["--workers", "0", "--allow-private-endpoints"]);
    assert_eq!(queue_line(&server, &admin), "0 job(s) waiting");

    // Conforming: accepted after its dry run and queued.
    let ok = policy_server("ok");
    let created: Value = server
        .client(Some(&token))
        .submit(&fields("Remote-OK", &ok.url), None)
        .expect("a conforming endpoint is accepted");
    let id = created["id"].as_i64().unwrap();
    let v = server
        .client(Some(&token))
        .submission(id)
        .expect("the submission exists");
    assert_eq!(v["status"], "queued", "{v}");
    assert_eq!(v["policy"]["endpoint_url"], ok.url.as_str(), "{v}");
    assert_eq!(queue_line(&server, &admin), "1 job(s) waiting");
    drop(ok);

    // Wrong action shapes: named with what was expected.
    let wrong = policy_server("wrong-shape");
    let m = expect_refused(&server, &token, "Remote-WrongShape", &wrong.url);
    assert!(
        m.ends_with("policy returned actions [8, 1, 3] for a query of 8 rollouts (first rollout 0 at step 0); expected [8, 1, 2]"),
        "{m}"
    );
    drop(wrong);

    // Not answering: the per-request deadline (10 s by default).
    let hang = policy_server("hang");
    let m = expect_refused(&server, &token, "Remote-Hang", &hang.url);
    assert!(
        m.contains("the policy server did not answer the infer within 10000 ms"),
        "{m}"
    );
    drop(hang);

    // Garbage replies.
    let garbage = policy_server("garbage");
    let m = expect_refused(&server, &token, "Remote-Garbage", &garbage.url);
    assert!(
        m.contains("sent a malformed infer reply: not valid msgpack"),
        "{m}"
    );
    drop(garbage);

    // Nobody listening at all.
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = closed.local_addr().unwrap().port();
    drop(closed);
    let m = expect_refused(
        &server,
        &token,
        "Remote-Closed",
        &format!("ws://127.0.0.1:{port}/"),
    );
    assert!(
        m.contains(&format!(
            "could not connect to the policy server at `ws://127.0.0.1:{port}/`"
        )),
        "{m}"
    );

    // Only the conforming submission was queued.
    assert_eq!(queue_line(&server, &admin), "1 job(s) waiting");
    server.kill();
}

#[test]
fn loopback_endpoints_are_refused_without_the_explicit_setting() {
    let dir = TempDir::new("dry-run-ssrf");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "ssrf-tester");
    let admin = D3IL.create_admin_token(&db, "operator");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let ok = policy_server("ok");
    match server
        .client(Some(&token))
        .submit(&fields("Remote-Loopback", &ok.url), None)
    {
        Err(ClientError::Api {
            status,
            code,
            message,
            field,
        }) => {
            assert_eq!((status, code.as_str()), (400, "invalid_field"), "{message}");
            assert_eq!(field.as_deref(), Some("endpoint_url"));
            assert!(message.contains("loopback or private address"), "{message}");
            // The refusal names the setting that would admit it.
            assert!(
                message.contains("`d3il serve`") && message.contains("`--allow-private-endpoints`"),
                "{message}"
            );
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    let (s, _) = server.get_text_blocking("/methods/Remote-Loopback");
    assert_eq!(s, 404);
    assert_eq!(queue_line(&server, &admin), "0 job(s) waiting");
    server.kill();
}
