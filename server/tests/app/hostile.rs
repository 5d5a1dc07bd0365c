//! The server under hostile use (issue 17), against a real server on
//! 127.0.0.1 (port 0) with a fresh SQLite file.

use d3il_test_support::server::*;

/// Every response carries the security headers: pages, API, plots, the
/// stylesheet, errors and the fallback 404.
#[tokio::test]
async fn every_response_carries_the_security_headers() {
    let app = spawn_app().await;
    let gets = [
        ("/", 200),
        ("/tasks/pushing", 200),
        ("/api/v1/leaderboards", 200),
        ("/api/v1/openapi.json", 200),
        ("/plots/tasks/pushing/pareto.svg", 200),
        ("/static/style.css", 200),
        ("/no/such/page", 404),
        ("/api/v1/submissions/999999", 404),
        ("/api/v1/whoami", 401),
        ("/admin", 401),
    ];
    for (path, status) in gets {
        let r = app.http.get(app.url(path)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), status, "{path}");
        let h = r.headers();
        let get = |name: &str| {
            h.get(name)
                .and_then(|v| v.to_str().ok())
                .unwrap_or_else(|| panic!("{path}: no {name} header"))
                .to_string()
        };
        let csp = get("content-security-policy");
        assert!(csp.contains("script-src 'none'"), "{path}: {csp}");
        assert!(csp.contains("frame-ancestors 'none'"), "{path}: {csp}");
        assert_eq!(get("x-content-type-options"), "nosniff", "{path}");
        assert_eq!(get("x-frame-options"), "DENY", "{path}");
        assert_eq!(get("referrer-policy"), "no-referrer", "{path}");
    }
    // A POST that fails validation too.
    let r = app
        .http
        .post(app.url("/api/v1/submissions"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 401);
    assert_eq!(r.headers()["x-frame-options"], "DENY");
}

async fn last_used(app: &TestServer, token: &str) -> Option<i64> {
    sqlx::query_scalar("SELECT last_used_at FROM api_tokens WHERE prefix = ?")
        .bind(&token[..d3il_server::store::TOKEN_PREFIX_LEN])
        .fetch_one(app.state().store.sqlite_pool().expect("a SQLite store"))
        .await
        .unwrap()
}

async fn whoami(app: &TestServer, token: &str) -> u16 {
    app.http
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(token)
        .timeout(std::time::Duration::from_secs(5))
        .send()
        .await
        .expect("whoami answers within 5 s")
        .status()
        .as_u16()
}

/// `last_used_at` is written at most once a minute and off the request's
/// path: while another process holds SQLite's write lock, authenticated
/// requests still answer at once (they used to wait 10 s and fail with 500).
#[tokio::test]
async fn last_used_is_written_once_a_minute_and_a_held_write_lock_does_not_fail_requests() {
    let app = spawn_app().await;
    let token = app.token().to_string();
    assert_eq!(last_used(&app, &token).await, None);
    assert_eq!(whoami(&app, &token).await, 200);
    let first = wait_until(|| async { last_used(&app, &token).await }).await;
    // Used again at once: not written again within the minute.
    sqlx::query("UPDATE api_tokens SET last_used_at = ? WHERE prefix = ?")
        .bind(first - 30)
        .bind(&token[..d3il_server::store::TOKEN_PREFIX_LEN])
        .execute(app.state().store.sqlite_pool().expect("a SQLite store"))
        .await
        .unwrap();
    assert_eq!(whoami(&app, &token).await, 200);
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    assert_eq!(
        last_used(&app, &token).await,
        Some(first - 30),
        "written again within a minute"
    );

    // Another connection (as another process would) takes the write lock; a
    // token used for the first time now has its write pending meanwhile.
    let fresh = app.state().store.create_token("newcomer").await.unwrap();
    let opts = sqlx::sqlite::SqliteConnectOptions::new().filename(&app.db);
    let mut other = sqlx::ConnectOptions::connect(&opts).await.unwrap();
    sqlx::query("BEGIN IMMEDIATE")
        .execute(&mut other)
        .await
        .unwrap();
    // Each answers within whoami's 5 s timeout (the busy timeout is 10 s).
    for t in [&fresh, &token, &fresh, &token, &fresh] {
        assert_eq!(whoami(&app, t).await, 200);
    }
    assert_eq!(last_used(&app, &fresh).await, None, "the lock is held");
    sqlx::query("ROLLBACK").execute(&mut other).await.unwrap();
    // Once the lock is released the pending write lands.
    let later = wait_until(|| async { last_used(&app, &fresh).await }).await;
    assert!(later >= first, "{later} {first}");
}

async fn wait_until<T, F, Fut>(mut f: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    for _ in 0..150 {
        if let Some(v) = f().await {
            return v;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    panic!("condition not reached in 15 s")
}

/// Raises this process's soft RLIMIT_NOFILE to its hard limit; returns it.
fn raise_fd_limit() -> u64 {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: plain syscalls on a local struct.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut r), 0);
        r.rlim_cur = r.rlim_max;
        assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &r), 0);
    }
    r.rlim_cur
}

/// Thousands of connections that never finish their request header (from
/// 127.0.0.2) neither starve other clients nor stay open: past the per-client
/// cap they are closed at once, the rest after the header-read timeout, and a
/// normal request (from 127.0.0.1) answers meanwhile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_open_connections_are_capped_and_dropped_after_the_header_timeout() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let fds = raise_fd_limit();
    // Both ends live in this process: two descriptors per connection.
    let n = (5000u64).min(fds.saturating_sub(200) / 2) as usize;
    assert!(n >= 1000, "fd limit {fds} too low for the flood");
    let app = spawn_app_with(Options {
        connections: Some(d3il_server::config::ConnectionLimits {
            header_read_timeout: std::time::Duration::from_secs(2),
            max_connections: n + 100,
            max_connections_per_client: 500,
            trusted_proxies: Default::default(),
            ..Default::default()
        }),
        ..Options::default()
    })
    .await;
    let mut flood = Vec::with_capacity(n);
    for _ in 0..n {
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.bind("127.0.0.2:0".parse().unwrap()).unwrap();
        let mut s = sock.connect(app.addr).await.expect("connect");
        // Half a request header, never finished.
        s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").await.unwrap();
        flood.push(s);
    }
    // A normal client still gets its answer.
    let (status, page) = app.get_text("/").await;
    assert_eq!(status, 200, "{page}");
    // Every flood connection is closed by the server: past the per-client cap
    // at once, the others after the 2 s header timeout.
    let deadline = std::time::Duration::from_secs(20);
    let mut closed = 0;
    for s in &mut flood {
        let mut buf = [0u8; 512];
        loop {
            match tokio::time::timeout(deadline, s.read(&mut buf)).await {
                Ok(Ok(0)) | Ok(Err(_)) => {
                    closed += 1;
                    break;
                }
                // hyper may answer 408 before closing: read on to the end.
                Ok(Ok(_)) => continue,
                Err(_) => panic!("a half-open connection is still open after {deadline:?}"),
            }
        }
    }
    assert_eq!(closed, n);
    let (status, _) = app.get_text("/").await;
    assert_eq!(status, 200);

    // A keep-alive connection that answered a request and then idles is
    // closed too (the header timeout is also the idle timeout).
    let mut s = tokio::net::TcpStream::connect(app.addr).await.unwrap();
    s.write_all(b"GET /static/style.css HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    let end = tokio::time::timeout(deadline, async {
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(k) => got.extend_from_slice(&buf[..k]),
            }
        }
    })
    .await;
    assert!(end.is_ok(), "an idle keep-alive connection stayed open");
    assert!(
        got.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&got)
    );
}

/// Issue 52: a stored policy path that climbs out of the policies directory
/// (`<policies>/../x`, as a crafted backup could hold) or a symlink in it to
/// a file elsewhere is resolved before anything is deleted, and kept.
#[tokio::test]
async fn a_policy_path_outside_the_store_is_never_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let store = d3il_server::store::Store::open(&dir.path().join("s.sqlite"))
        .await
        .unwrap();
    let policies = store.policies_dir();
    std::fs::create_dir_all(&policies).unwrap();
    let outside = dir.path().join("precious.txt");
    std::fs::write(&outside, b"keep me").unwrap();
    let climbing = policies
        .join("..")
        .join("..")
        .join(dir.path().file_name().unwrap())
        .join("precious.txt");
    assert!(
        climbing.starts_with(&policies),
        "the old check let it through"
    );
    assert!(!store
        .release_policy_file(&climbing.to_string_lossy())
        .await
        .unwrap());
    let link = policies.join("link.onnx");
    std::os::unix::fs::symlink(&outside, &link).unwrap();
    assert!(!store
        .release_policy_file(&link.to_string_lossy())
        .await
        .unwrap());
    assert_eq!(std::fs::read(&outside).unwrap(), b"keep me");
    // A file of the store itself is released as before.
    let own = policies.join("own.onnx");
    std::fs::write(&own, b"x").unwrap();
    assert!(store
        .release_policy_file(&own.to_string_lossy())
        .await
        .unwrap());
    assert!(!own.exists());
}
