//! A remote endpoint's shared secret, end to end: the reference Python policy
//! server (`python -m d3il_client.serve`, its secret from
//! `$D3IL_ENDPOINT_SECRET`) on 127.0.0.1, a real `d3il serve` with a real
//! sandboxed worker. Submitted without the secret, or with another, the
//! endpoint is refused at its dry run with a message that says which; with
//! it, the evaluation completes. The secret appears in no API answer and no
//! page, whoever asks (its submitter included).
//!
//! Needs python3 with numpy, websockets and msgpack (the `serve` extra of clients/python).

use crate::D3IL;
use d3il_server::client::ClientError;
use d3il_test_support::server::*;
use serde_json::Value;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const SECRET: &str = "s3cret-only-the-evaluator-knows";

/// The reference policy server, killed (by its own pid) when dropped.
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

fn policy_server_with_secret() -> PolicyServer {
    let clients = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("clients/python");
    let mut child = Command::new("python3")
        .args([
            "-m",
            "d3il_client.serve",
            "--demo",
            "avoiding",
            "--port",
            "0",
        ])
        .env("PYTHONPATH", clients)
        .env("D3IL_ENDPOINT_SECRET", SECRET)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3 is needed for the remote tests");
    let line = wait_for_line(&mut child, "listening on ", "the policy server");
    let addr = line.trim().trim_start_matches("listening on ").to_string();
    PolicyServer {
        child,
        url: format!("ws://{addr}/"),
    }
}

fn fields(method: &str, url: &str, secret: Option<&str>) -> Vec<(&'static str, String)> {
    let mut f = vec![
        ("method", method.to_string()),
        ("task", "avoiding".to_string()),
        ("training_seed", "0".to_string()),
        ("protocol", "quick".to_string()),
        ("endpoint_url", url.to_string()),
    ];
    if let Some(s) = secret {
        f.push(("endpoint_secret", s.to_string()));
    }
    f
}

/// The refusal of a submission: (status, code, field, message).
fn refusal(r: Result<Value, ClientError>) -> (u16, String, Option<String>, String) {
    match r {
        Err(ClientError::Api {
            status,
            code,
            message,
            field,
        }) => (status, code, field, message),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn an_endpoint_with_a_secret_serves_the_evaluator_that_sends_it_and_no_page_shows_it() {
    let dir = TempDir::new("endpoint-secret");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "secret-keeper");
    let admin = D3IL.create_admin_token(&db, "operator");
    let server = D3IL.serve(&db, &["--workers", "1", "--allow-private-endpoints"]);
    let policy = policy_server_with_secret();
    let client = server.client(Some(&token));

    // No secret: the dry run's connection is refused, and the message says
    // the server wants one and how to give it.
    let (status, code, field, m) =
        refusal(client.submit(&fields("Secret-None", &policy.url, None), None));
    assert_eq!((status, code.as_str()), (422, "endpoint_rejected"), "{m}");
    assert_eq!(field.as_deref(), Some("endpoint_url"));
    assert!(
        m.contains("refused the evaluator (HTTP 401: this endpoint needs its shared secret"),
        "{m}"
    );
    assert!(
        m.contains("no endpoint secret was sent") && m.contains("`endpoint_secret`"),
        "{m}"
    );

    // Another secret: refused as not matching, and not echoed.
    let wrong = "another-secret-entirely";
    let (status, _, _, m) =
        refusal(client.submit(&fields("Secret-Wrong", &policy.url, Some(wrong)), None));
    assert_eq!(status, 422, "{m}");
    assert!(
        m.contains("the endpoint secret sent does not match the server's"),
        "{m}"
    );
    assert!(!m.contains(wrong), "{m}");

    // A secret that could not be sent as a header is refused before any dry run.
    let (status, code, field, m) = refusal(client.submit(
        &fields("Secret-Bad", &policy.url, Some("two words here!!")),
        None,
    ));
    assert_eq!((status, code.as_str()), (400, "invalid_field"), "{m}");
    assert_eq!(field.as_deref(), Some("endpoint_secret"));
    assert!(m.contains("no spaces"), "{m}");

    // The secret: accepted, evaluated to the end.
    let created = client
        .submit(&fields("Secret-Right", &policy.url, Some(SECRET)), None)
        .expect("the endpoint with its secret is accepted");
    assert!(!created.to_string().contains(SECRET), "{created}");
    let id = created["id"].as_i64().unwrap();
    let done = client
        .wait(id, Duration::from_secs(600), |_| {})
        .expect("the evaluation ends");
    assert_eq!(done["status"], "completed", "{done}");
    assert!(
        done["result"]["metrics"]["success_rate"]["value"].is_number(),
        "{done}"
    );

    // Nowhere to be read: the API (anonymous, the submitter, an admin) and
    // the pages the submission is on.
    let mut seen = vec![];
    for who in [None, Some(token.as_str()), Some(admin.as_str())] {
        let c = server.client(who);
        for path in [
            format!("/api/v1/submissions/{id}"),
            format!("/api/v1/submissions/{id}/results"),
            "/api/v1/submissions".to_string(),
            "/api/v1/leaderboards/avoiding".to_string(),
            format!("/submissions/{id}"),
            format!("/submissions/{id}/json"),
            "/api/v1/methods".to_string(),
            "/submissions".to_string(),
            "/tasks/avoiding".to_string(),
            "/tasks/avoiding/csv".to_string(),
            "/methods/Secret-Right".to_string(),
            "/admin".to_string(),
        ] {
            let (status, body) = c.get_text(&path).expect("the server answers");
            assert!(!body.contains(SECRET), "{path} as {who:?} shows the secret");
            seen.push((path, status));
        }
    }
    // The submitter's own document has the URL (so the answers looked at
    // are the full ones), never the secret.
    let own = client.submission(id).unwrap();
    assert_eq!(own["policy"]["endpoint_url"], policy.url.as_str(), "{own}");
    assert!(
        seen.iter().filter(|(_, s)| *s == 200).count() >= 20,
        "most of the pages answered: {seen:?}"
    );
}
