//! Fair use under hostile load (issue 17), against a real server on
//! 127.0.0.1/127.0.0.2 with a fresh SQLite file: per-address rate limits for
//! anonymous requests and failed token checks (behind a trusted proxy, per
//! X-Forwarded-For client), endpoint dry-runs that share
//! the worker slots, and a busy database answered with 503 + Retry-After
//! rather than 500.

use d3il_test_support::server::*;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

#[tokio::test]
async fn anonymous_requests_are_limited_per_client_address() {
    let app = spawn_app_configured(|c| c.anonymous_rate_limit_per_minute = 5, idle_runner()).await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let a = client_from("127.0.0.1");
    for _ in 0..5 {
        let r = a.get(app.url("/api/v1/leaderboards")).send().await.unwrap();
        assert_eq!(r.status(), 200);
    }
    let r = a.get(app.url("/api/v1/leaderboards")).send().await.unwrap();
    assert_eq!(r.status(), 429);
    let wait: u64 = r.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=60).contains(&wait), "{wait}");
    let body: serde_json::Value = r.json().await.unwrap();
    assert_eq!(body["error"]["code"], "rate_limited", "{body}");
    // A page answers with the HTML error page.
    let r = a.get(app.url("/")).send().await.unwrap();
    assert_eq!(r.status(), 429);
    assert!(r.text().await.unwrap().contains("rate limit"));
    // With a token the per-token limit applies instead.
    let r = a
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    // Another address has its own budget.
    let b = client_from("127.0.0.2");
    let r = b.get(app.url("/api/v1/leaderboards")).send().await.unwrap();
    assert_eq!(r.status(), 200);
}

#[tokio::test]
async fn failed_token_checks_are_limited_per_client_address() {
    let app = spawn_app_configured(|c| c.failed_auth_per_minute = 3, idle_runner()).await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let a = client_from("127.0.0.1");
    for i in 0..3 {
        let r = a
            .get(app.url("/api/v1/whoami"))
            .bearer_auth(format!("d3il_guess{i}"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 401);
    }
    // Now even the right token is refused from this address for the minute,
    // and so are POSTs (the form carries its token in the body).
    let r = a
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 429);
    assert!(r.headers().contains_key("retry-after"));
    let r = a.post(app.url("/submit")).send().await.unwrap();
    assert_eq!(r.status(), 429);
    // Reading pages without a token still works.
    let r = a.get(app.url("/api/v1/leaderboards")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    // Another address is not affected.
    let r = client_from("127.0.0.2")
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
}

/// Behind a trusted reverse proxy (`--trusted-proxy`, here 127.0.0.2) the
/// per-address limits key on the client that X-Forwarded-For names (its
/// right-most entry that is not a trusted proxy), never on what a client
/// wrote left of it; from any other peer (127.0.0.1) the header is ignored;
/// the proxy's connections are not capped per address.
#[tokio::test]
async fn behind_a_trusted_proxy_the_limits_key_on_the_forwarded_client() {
    let app = spawn_app_configured(
        |c| {
            c.anonymous_rate_limit_per_minute = 3;
            c.failed_auth_per_minute = 2;
            c.connections.max_connections_per_client = 2;
            c.connections.trusted_proxies = ["127.0.0.2".parse().unwrap()].into_iter().collect();
        },
        idle_runner(),
    )
    .await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let board = app.url("/api/v1/leaderboards");
    let whoami = app.url("/api/v1/whoami");
    let proxy = client_from("127.0.0.2");
    // Client A through the proxy: its own budget of 3, which a spoofed
    // entry left of the proxy's does not escape.
    for xff in ["203.0.113.7", "203.0.113.7", "6.6.6.6, 203.0.113.7"] {
        assert_eq!(
            status_of(&proxy, &board, Some(xff), None).await,
            200,
            "{xff}"
        );
    }
    let spoofed = Some("198.51.100.99, 203.0.113.7");
    assert_eq!(status_of(&proxy, &board, spoofed, None).await, 429);
    // Client B has its own, also through a second trusted hop.
    for xff in ["203.0.113.8", "203.0.113.8, 127.0.0.2", "203.0.113.8"] {
        assert_eq!(
            status_of(&proxy, &board, Some(xff), None).await,
            200,
            "{xff}"
        );
    }
    let two_hops = Some("203.0.113.8, 127.0.0.2");
    assert_eq!(status_of(&proxy, &board, two_hops, None).await, 429);
    // The proxy's own requests (no header) are one more client.
    assert_eq!(status_of(&proxy, &board, None, None).await, 200);
    // A peer that is not a trusted proxy cannot pick its address.
    let direct = client_from("127.0.0.1");
    for i in 1..=3 {
        let xff = format!("198.51.100.{i}");
        assert_eq!(status_of(&direct, &board, Some(&xff), None).await, 200);
    }
    let fresh = Some("198.51.100.4");
    assert_eq!(
        status_of(&direct, &board, fresh, None).await,
        429,
        "the header is ignored"
    );
    // Failed token checks are counted per forwarded client too.
    let c = Some("203.0.113.20");
    for guess in ["d3il_guess1", "d3il_guess2"] {
        assert_eq!(status_of(&proxy, &whoami, c, Some(guess)).await, 401);
    }
    assert_eq!(status_of(&proxy, &whoami, c, Some(&token)).await, 429);
    let d = Some("203.0.113.21");
    assert_eq!(status_of(&proxy, &whoami, d, Some(&token)).await, 200);
    // Three connections at once from the proxy, past the per-address cap of
    // 2, are all served (each a fresh client).
    let mut conns = Vec::new();
    for _ in 0..3 {
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.bind("127.0.0.2:0".parse().unwrap()).unwrap();
        conns.push(sock.connect(app.addr).await.unwrap());
    }
    for (i, conn) in conns.iter_mut().enumerate() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let req = format!(
            "GET /healthz HTTP/1.1\r\nHost: x\r\nX-Forwarded-For: 192.0.2.{i}\r\nConnection: close\r\n\r\n"
        );
        conn.write_all(req.as_bytes()).await.unwrap();
        let mut answer = String::new();
        conn.read_to_string(&mut answer).await.unwrap();
        assert!(
            answer.starts_with("HTTP/1.1 200"),
            "connection {i}: {answer:?}"
        );
    }
}

/// Six concurrent endpoint submissions on a one-worker server (one general
/// slot plus the quick slot) run at most two dry-runs at a time (they used
/// to start a worker process each, without bound).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn endpoint_dry_runs_share_the_worker_slots() {
    let counting = Arc::new(Counting::default());
    let app = spawn_app_configured(|c| c.workers = 1, counting.clone()).await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let http = reqwest::Client::new();
    let mut tasks = Vec::new();
    for seed in 0..6 {
        let form = reqwest::multipart::Form::new()
            .text("method", "Remote")
            .text("task", "pushing")
            .text("training_seed", seed.to_string())
            .text("endpoint_url", "wss://policy.example.org/ws");
        tasks.push(tokio::spawn(
            http.post(app.url("/api/v1/submissions"))
                .bearer_auth(&token)
                .multipart(form)
                .send(),
        ));
    }
    for t in tasks {
        let r = t.await.unwrap().unwrap();
        assert_eq!(r.status(), 422, "the dry-run fails");
    }
    assert_eq!(counting.runs.load(Ordering::SeqCst), 6);
    let max = counting.max.load(Ordering::SeqCst);
    assert!(
        (1..=2).contains(&max),
        "{max} dry-runs ran at once on a pool of 2 slots"
    );
}

/// A write that finds the database locked past the busy timeout is answered
/// with 503 `busy` and Retry-After (a real SQLITE_BUSY from a second
/// connection), and the store's retry turns a lock held briefly into a
/// normal answer.
#[tokio::test]
async fn a_busy_database_is_retried_then_answered_with_503() {
    use d3il_server::error::AppError;
    use d3il_server::store::StoreError;
    use sqlx::ConnectOptions;
    let app = spawn_app_configured(|_| {}, idle_runner()).await;
    let d3il_server::store::DbTarget::Sqlite(db) = app.state().cfg.db.clone() else {
        panic!("this test holds SQLite's write lock")
    };
    let opts = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(&db)
        .busy_timeout(Duration::ZERO);
    let mut holder = opts.connect().await.unwrap();
    sqlx::query("BEGIN IMMEDIATE")
        .execute(&mut holder)
        .await
        .unwrap();
    let mut other = opts.connect().await.unwrap();
    let err = sqlx::query("BEGIN IMMEDIATE")
        .execute(&mut other)
        .await
        .expect_err("the lock is held");
    let e = StoreError::Db(err);
    assert!(e.is_busy(), "{e}");
    let app_err: AppError = e.into();
    assert_eq!(app_err.status().as_u16(), 503);
    assert_eq!(app_err.code(), "busy");
    sqlx::query("ROLLBACK").execute(&mut holder).await.unwrap();

    // A submission while another process holds the write lock for 2 s: it
    // waits (busy timeout) and is accepted, never a 500.
    let token = app.state().store.create_token("alice").await.unwrap();
    sqlx::query("BEGIN IMMEDIATE")
        .execute(&mut holder)
        .await
        .unwrap();
    let release = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_secs(2)).await;
        sqlx::query("ROLLBACK").execute(&mut holder).await.unwrap();
    });
    let mut onnx = b"\x08\x07\x12\x04test".to_vec();
    onnx.resize(64, 0);
    let form = reqwest::multipart::Form::new()
        .text("method", "Locked")
        .text("task", "pushing")
        .text("training_seed", "1")
        .text(
            "manifest",
            r#"{"task": "pushing", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#,
        )
        .part(
            "onnx",
            reqwest::multipart::Part::bytes(onnx).file_name("p.onnx"),
        );
    let r = reqwest::Client::new()
        .post(app.url("/api/v1/submissions"))
        .bearer_auth(&token)
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201, "{}", r.text().await.unwrap());
    release.await.unwrap();
}

/// The admin page shows the limits the server was started with, each named
/// with its flag.
#[tokio::test]
async fn the_admin_page_shows_the_configured_limits() {
    let app = spawn_app_configured(
        |c| {
            c.max_upload_bytes = 7 << 20;
            c.max_disk_bytes_per_submitter = Some(33 << 20);
            c.max_concurrent_uploads = 3;
            c.anonymous_rate_limit_per_minute = 777;
            c.failed_auth_per_minute = 9;
            c.rate_limit_per_minute = 61;
            c.max_attempts = 5;
            c.connections.header_read_timeout = Duration::from_secs(13);
            c.connections.max_connections = 999;
            c.connections.max_connections_per_client = 42;
            c.connections.trusted_proxies = ["10.0.0.0/8".parse().unwrap(), "::1".parse().unwrap()]
                .into_iter()
                .collect();
        },
        idle_runner(),
    )
    .await;
    let admin = app
        .state()
        .store
        .create_token_with("ops", true)
        .await
        .unwrap();
    let r = reqwest::Client::new()
        .get(app.url("/admin"))
        .bearer_auth(&admin)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let page = r.text().await.unwrap();
    let table = page
        .split("id=\"server-limits\">")
        .nth(1)
        .and_then(|t| t.split("</table>").next())
        .expect("the server limits table");
    let row = |flag: &str| {
        table
            .split("<tr>")
            .find(|r| r.contains(flag))
            .unwrap_or_else(|| panic!("no {flag} row in {table}"))
            .to_string()
    };
    for (flag, value) in [
        ("--max-upload-mb", "7 MiB"),
        ("--max-disk-mb-per-submitter", "33 MiB"),
        ("--max-concurrent-uploads", "3"),
        ("--rate-limit)", "61 per minute"),
        ("--anonymous-rate-limit", "777 per minute"),
        ("--failed-auth-limit", "9 per minute"),
        ("--header-timeout", "13 s"),
        ("--max-connections)", "999"),
        ("--max-connections-per-client", "42"),
        ("--max-attempts", "5"),
        (
            "--trusted-proxy",
            "10.0.0.0/8, ::1: their X-Forwarded-For names the client",
        ),
    ] {
        assert!(
            row(flag).contains(&format!("<td>{value}</td>")),
            "{flag}: {}",
            row(flag)
        );
    }
}

/// A raw multipart upload in two halves: `start` sends the header, the fields
/// and `first` bytes of the file; `finish` sends the rest and reads the answer.
struct RawUpload {
    sock: tokio::net::TcpStream,
    rest: usize,
}

const BOUNDARY: &str = "limitsBoundary42";

impl RawUpload {
    async fn start(
        app: &TestServer,
        token: &str,
        seed: u32,
        file: usize,
        first: usize,
    ) -> RawUpload {
        use tokio::io::AsyncWriteExt;
        let mut head = String::new();
        for (k, v) in [
            ("method", "Uploader".to_string()),
            ("task", "pushing".to_string()),
            ("training_seed", seed.to_string()),
            (
                "manifest",
                r#"{"task": "pushing", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#
                    .to_string(),
            ),
        ] {
            head += &format!(
                "--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n"
            );
        }
        head += &format!(
            "--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\n\r\n"
        );
        let len = head.len() + file + format!("\r\n--{BOUNDARY}--\r\n").len();
        let mut sock = tokio::net::TcpStream::connect(app.addr).await.unwrap();
        let req = format!(
            "POST /api/v1/submissions HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {token}\r\n\
             Content-Type: multipart/form-data; boundary={BOUNDARY}\r\nContent-Length: {len}\r\n\r\n{head}"
        );
        sock.write_all(req.as_bytes()).await.unwrap();
        sock.write_all(&vec![7u8; first]).await.unwrap();
        RawUpload {
            sock,
            rest: file - first,
        }
    }

    async fn finish(mut self) -> String {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        self.sock.write_all(&vec![7u8; self.rest]).await.unwrap();
        self.sock
            .write_all(format!("\r\n--{BOUNDARY}--\r\n").as_bytes())
            .await
            .unwrap();
        let mut got = vec![0u8; 4096];
        let n = tokio::time::timeout(Duration::from_secs(20), self.sock.read(&mut got))
            .await
            .expect("an answer")
            .unwrap();
        String::from_utf8_lossy(&got[..n]).into_owned()
    }
}

fn temp_uploads(app: &TestServer) -> usize {
    std::fs::read_dir(app.state().store.policies_dir())
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .count()
}

/// With `--max-concurrent-uploads 1` a second upload waits, its body unread,
/// until the first is stored; then it streams in too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_uploads_are_capped() {
    let app = spawn_app_configured(|c| c.max_concurrent_uploads = 1, idle_runner()).await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let a = RawUpload::start(&app, &token, 1, 512 << 10, 256 << 10).await;
    for _ in 0..100 {
        if temp_uploads(&app) == 1 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(temp_uploads(&app), 1, "the first upload streams to disk");
    let b = RawUpload::start(&app, &token, 2, 512 << 10, 32 << 10).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(temp_uploads(&app), 1, "the second upload waits for a slot");
    let answer = a.finish().await;
    assert!(answer.starts_with("HTTP/1.1 201"), "{answer}");
    let answer = b.finish().await;
    assert!(answer.starts_with("HTTP/1.1 201"), "{answer}");
    assert_eq!(temp_uploads(&app), 0);
}

/// Issue 52: only a valid token lifts the anonymous limit. A made-up token
/// on a public GET (which needs none) is a 401 that counts as a failed token
/// check, not a free pass past the anonymous limit; a valid one still
/// browses past it.
#[tokio::test]
async fn only_a_valid_token_lifts_the_anonymous_limit() {
    let app = spawn_app_configured(
        |c| {
            c.anonymous_rate_limit_per_minute = 3;
            c.failed_auth_per_minute = 3;
        },
        idle_runner(),
    )
    .await;
    let token = app.state().store.create_token("alice").await.unwrap();
    let a = client_from("127.0.0.3");
    for _ in 0..3 {
        assert_eq!(
            status_of(&a, &app.url("/api/v1/leaderboards"), None, None).await,
            200
        );
    }
    assert_eq!(
        status_of(&a, &app.url("/api/v1/leaderboards"), None, None).await,
        429
    );
    // A bogus token does not get past it: 401 (saying what to do), counted.
    let r = a
        .get(app.url("/api/v1/leaderboards"))
        .bearer_auth("d3il_made_up")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let body: serde_json::Value = r.json().await.unwrap();
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("leave the Authorization header out"),
        "{body}"
    );
    // A page too, and a header that is no bearer token.
    let r = a
        .get(app.url("/"))
        .bearer_auth("d3il_made_up")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let r = a
        .get(app.url("/api/v1/leaderboards"))
        .header("authorization", "Token abc")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    // Three failed checks: the failed-check limit refuses the address now.
    let r = a
        .get(app.url("/api/v1/leaderboards"))
        .bearer_auth("d3il_another")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 429);
    // A valid token from an address past its anonymous limit browses on.
    let b = client_from("127.0.0.4");
    for _ in 0..3 {
        assert_eq!(
            status_of(&b, &app.url("/api/v1/leaderboards"), None, None).await,
            200
        );
    }
    assert_eq!(
        status_of(&b, &app.url("/api/v1/leaderboards"), None, None).await,
        429
    );
    for _ in 0..5 {
        assert_eq!(
            status_of(&b, &app.url("/api/v1/leaderboards"), None, Some(&token)).await,
            200
        );
    }
    assert_eq!(
        status_of(&b, &app.url("/api/v1/whoami"), None, Some(&token)).await,
        200
    );
}

/// Issue 52: the body of a refused upload is read on so its client gets
/// the answer, but a client trickling that body a byte at a time (never idle
/// for the idle timeout) is cut off at the linger deadline, and while it is
/// read on, its connection counts against its client's connection cap.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trickled_unread_body_is_cut_off_at_the_linger_deadline() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let app = spawn_app_configured(
        |c| {
            c.connections.header_read_timeout = Duration::from_secs(2);
            c.connections.linger_deadline = Duration::from_secs(3);
            c.connections.max_connections_per_client = 2;
        },
        idle_runner(),
    )
    .await;
    let connect = |ip: &'static str| async move {
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.bind(format!("{ip}:0").parse().unwrap()).unwrap();
        sock.connect(app.addr).await.unwrap()
    };
    // Two uploads without a token, 1 MB declared: answered 401 at once.
    let mut trickling = Vec::new();
    for _ in 0..2 {
        let mut s = connect("127.0.0.5").await;
        s.write_all(
            b"POST /api/v1/submissions HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\nContent-Length: 1000000\r\n\r\n--b\r\n",
        )
        .await
        .unwrap();
        let mut head = [0u8; 12];
        tokio::time::timeout(Duration::from_secs(10), s.read_exact(&mut head))
            .await
            .expect("the answer comes before the body")
            .unwrap();
        assert_eq!(&head, b"HTTP/1.1 401", "{}", String::from_utf8_lossy(&head));
        trickling.push(s);
    }
    let began = std::time::Instant::now();
    // While both are read on, a third connection from that client is
    // closed at once (the cap is 2); another client is served.
    let mut third = connect("127.0.0.5").await;
    let _ = third
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .await;
    let mut buf = [0u8; 64];
    let n = tokio::time::timeout(Duration::from_secs(10), third.read(&mut buf))
        .await
        .expect("closed, not held")
        .unwrap_or(0);
    assert_eq!(n, 0, "past the cap: {}", String::from_utf8_lossy(&buf[..n]));
    let r = client_from("127.0.0.6")
        .get(app.url("/healthz"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    // Trickle a byte every 500 ms (never idle for 2 s): the server stops
    // reading at the 3 s deadline and closes both; then the client may
    // connect again. The bound of 20 s is a liveness bound, not a timing.
    let mut closed = [false, false];
    while closed.iter().any(|c| !c) {
        assert!(
            began.elapsed() < Duration::from_secs(20),
            "a trickled body held its connection past the deadline"
        );
        for (i, s) in trickling.iter_mut().enumerate() {
            if closed[i] {
                continue;
            }
            if s.write_all(b"x").await.is_err() {
                closed[i] = true;
                continue;
            }
            let mut rest = [0u8; 4096];
            match tokio::time::timeout(Duration::from_millis(250), s.read(&mut rest)).await {
                Ok(Ok(0)) | Ok(Err(_)) => closed[i] = true,
                _ => {}
            }
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    assert!(
        began.elapsed() >= Duration::from_secs(2),
        "read on for a while first"
    );
    // The operator sees both limits at work in /metrics.
    let metrics = app.state().telemetry.scrape().await;
    for want in [
        "d3il_rate_limit_refusals_total{limit=\"linger_deadline\"} 2",
        "d3il_rate_limit_refusals_total{limit=\"client_connections\"} 1",
    ] {
        assert!(metrics.contains(want), "{want} not in {metrics}");
    }
    let mut again = connect("127.0.0.5").await;
    again
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), again.read_to_end(&mut answer))
        .await
        .unwrap()
        .unwrap();
    assert!(
        answer.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&answer)
    );
}

/// Issue 52: the public `/readyz` says whether each check passed and names
/// the failing ones, but its detail (a database's error text, hosts) only
/// to an admin token; the metrics listener shows it (tests/serve/ops_metrics.rs).
#[tokio::test]
async fn public_readyz_shows_its_detail_only_to_an_admin() {
    let app = spawn_app_configured(|_| {}, idle_runner()).await;
    let admin = app
        .state()
        .store
        .create_token_with("ready-op", true)
        .await
        .unwrap();
    let user = app.state().store.create_token("ready-user").await.unwrap();
    let c = reqwest::Client::new();
    let get = |token: Option<String>| {
        let mut r = c.get(app.url("/readyz"));
        if let Some(t) = token {
            r = r.bearer_auth(t);
        }
        async move {
            r.send()
                .await
                .unwrap()
                .json::<serde_json::Value>()
                .await
                .unwrap()
        }
    };
    let hidden = "on the metrics listener (--metrics-bind) or with an admin token";
    for v in [get(None).await, get(Some(user)).await] {
        for check in ["database", "canary", "workers"] {
            assert_eq!(v[check]["detail"], hidden, "{v}");
            assert!(v[check]["ok"].is_boolean(), "{v}");
        }
        assert!(v["not_ready"].is_array(), "{v}");
    }
    let v = get(Some(admin)).await;
    assert!(
        v["workers"]["detail"]
            .as_str()
            .unwrap()
            .contains("worker slot"),
        "{v}"
    );
}
