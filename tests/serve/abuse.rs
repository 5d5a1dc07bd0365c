//! Issue 52's abuse test: a real `d3il serve` on 127.0.0.1 with real
//! sandboxed `d3il worker` processes (`--workers 1`, the race slot's own
//! worker, real upload dry runs), while four tokens (each from its own
//! loopback address) flood it at once with races, robustness suites, bogus
//! uploads and anonymous reads, another address sends bogus tokens and a
//! third trickles the bodies of refused uploads. Everything is bounded in
//! count and time. Meanwhile a normal submitter's quick evaluation must
//! complete within `NORMAL_BOUND` (a liveness bound, generous on purpose: the
//! machine is shared), nothing accepted may be lost, and every refusal must
//! name its limit (its flag) or say what to fix.

use crate::D3IL;
use d3il_test_support::server::*;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// How long the normal submitter's quick evaluation may take under the flood.
const NORMAL_BOUND: Duration = Duration::from_secs(600);
/// Attackers, each a token of its own on its own address.
const ATTACKERS: usize = 4;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

/// One HTTP/1.1 request from local address `ip` (`Connection: close`): the
/// status and the body, or the I/O error as text (status 0).
async fn http(
    addr: std::net::SocketAddr,
    ip: &str,
    method: &str,
    path: &str,
    token: Option<&str>,
    content_type: Option<&str>,
    body: &[u8],
) -> (u16, String) {
    let go = async {
        let sock = tokio::net::TcpSocket::new_v4()?;
        sock.bind(format!("{ip}:0").parse().unwrap())?;
        let mut s = sock.connect(addr).await?;
        let mut head = format!(
            "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n",
            body.len()
        );
        if let Some(t) = token {
            head.push_str(&format!("Authorization: Bearer {t}\r\n"));
        }
        if let Some(c) = content_type {
            head.push_str(&format!("Content-Type: {c}\r\n"));
        }
        head.push_str("\r\n");
        s.write_all(head.as_bytes()).await?;
        s.write_all(body).await?;
        let mut answer = Vec::new();
        s.read_to_end(&mut answer).await?;
        Ok::<_, std::io::Error>(answer)
    };
    match tokio::time::timeout(Duration::from_secs(120), go).await {
        Ok(Ok(answer)) => {
            let text = String::from_utf8_lossy(&answer).into_owned();
            let status = text
                .split_whitespace()
                .nth(1)
                .and_then(|c| c.parse().ok())
                .unwrap_or(0);
            let body = text.split_once("\r\n\r\n").map_or("", |(_, b)| b);
            (status, body.to_string())
        }
        Ok(Err(e)) => (0, e.to_string()),
        Err(_) => (0, "no answer within 120 s".into()),
    }
}

/// A multipart/form-data body of `fields` and, if given, an `onnx` file part.
fn multipart(fields: &[(&str, String)], onnx: Option<&[u8]>) -> (String, Vec<u8>) {
    let b = "d3ilabuseboundary";
    let mut body = Vec::new();
    for (k, v) in fields {
        body.extend_from_slice(
            format!("--{b}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n")
                .as_bytes(),
        );
    }
    if let Some(bytes) = onnx {
        body.extend_from_slice(
            format!(
                "--{b}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\nContent-Type: application/octet-stream\r\n\r\n"
            )
            .as_bytes(),
        );
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{b}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={b}"), body)
}

fn fields(method: &str, task: &str, seed: u32, manifest: &str) -> Vec<(&'static str, String)> {
    vec![
        ("method", method.to_string()),
        ("task", task.to_string()),
        ("training_seed", seed.to_string()),
        ("protocol", "quick".to_string()),
        ("manifest", manifest.to_string()),
    ]
}

/// What one request got, by kind of request.
#[derive(Debug, Clone)]
struct Outcome {
    what: &'static str,
    status: u16,
    body: String,
}

/// The flags a 429 may name: every limit of the service.
const LIMIT_FLAGS: [&str; 7] = [
    "--quota-per-day",
    "--quota-total",
    "--quota-concurrent",
    "--max-queued-races",
    "--rate-limit",
    "--anonymous-rate-limit",
    "--failed-auth-limit",
];

fn message(body: &str) -> String {
    serde_json::from_str::<Value>(body)
        .ok()
        .and_then(|v| v["error"]["message"].as_str().map(str::to_string))
        .unwrap_or_else(|| body.chars().take(300).collect())
}

/// One attacker: its own submission, then races, suites, bogus uploads and
/// anonymous reads, each a fixed number of times.
async fn attack(
    addr: std::net::SocketAddr,
    ip: String,
    token: String,
    n: u32,
    target: i64,
) -> (Option<i64>, Vec<i64>, Vec<Outcome>) {
    let mut out = Vec::new();
    let manifest = std::fs::read_to_string(fixture("aligning_mlp.json")).unwrap();
    let onnx = std::fs::read(fixture("aligning_mlp.onnx")).unwrap();
    let (ct, body) = multipart(
        &fields(&format!("Flood{n}"), "aligning", 0, &manifest),
        Some(&onnx),
    );
    let (status, b) = http(
        addr,
        &ip,
        "POST",
        "/api/v1/submissions",
        Some(&token),
        Some(&ct),
        &body,
    )
    .await;
    let own = (status == 201)
        .then(|| serde_json::from_str::<Value>(&b).ok()?["id"].as_i64())
        .flatten();
    out.push(Outcome {
        what: "own upload",
        status,
        body: b,
    });
    let mut races = Vec::new();
    let mut races_left = 6;
    let mut suites_left = 3;
    let mut bogus_left = 3;
    let mut reads_left = 70;
    let mut k = 0u32;
    while races_left + suites_left + bogus_left + reads_left > 0 {
        k += 1;
        if races_left > 0 {
            races_left -= 1;
            let race =
                json!({"a": own.unwrap_or(target), "b": target, "protocol": "paper"}).to_string();
            let (status, b) = http(
                addr,
                &ip,
                "POST",
                "/api/v1/races",
                Some(&token),
                Some("application/json"),
                race.as_bytes(),
            )
            .await;
            if status == 202 {
                if let Some(id) = serde_json::from_str::<Value>(&b)
                    .ok()
                    .and_then(|v| v["id"].as_i64())
                {
                    races.push(id);
                }
            }
            out.push(Outcome {
                what: "race",
                status,
                body: b,
            });
        }
        if suites_left > 0 {
            suites_left -= 1;
            let mut f = fields(&format!("FloodSuite{n}"), "aligning", 100 + k, &manifest);
            f.push(("suite", "robustness".into()));
            let (ct, body) = multipart(&f, Some(&onnx));
            let (status, b) = http(
                addr,
                &ip,
                "POST",
                "/api/v1/submissions",
                Some(&token),
                Some(&ct),
                &body,
            )
            .await;
            out.push(Outcome {
                what: "suite",
                status,
                body: b,
            });
        }
        if bogus_left > 0 {
            bogus_left -= 1;
            let junk: Vec<u8> = (0..64 * 1024).map(|i| (i * 7 + n as usize) as u8).collect();
            let (ct, body) = multipart(
                &fields(&format!("FloodJunk{n}"), "aligning", 200 + k, &manifest),
                Some(&junk),
            );
            let (status, b) = http(
                addr,
                &ip,
                "POST",
                "/api/v1/submissions",
                Some(&token),
                Some(&ct),
                &body,
            )
            .await;
            out.push(Outcome {
                what: "bogus upload",
                status,
                body: b,
            });
        }
        for _ in 0..10.min(reads_left) {
            reads_left -= 1;
            let (status, b) = http(addr, &ip, "GET", "/api/v1/leaderboards", None, None, b"").await;
            out.push(Outcome {
                what: "anonymous read",
                status,
                body: b,
            });
        }
    }
    (own, races, out)
}

/// Bogus tokens from one address: refused 401, then 429 at the failed-check limit.
async fn bogus_tokens(addr: std::net::SocketAddr) -> Vec<Outcome> {
    let mut out = Vec::new();
    for i in 0..12 {
        let (status, b) = http(
            addr,
            "127.0.0.40",
            "GET",
            "/api/v1/leaderboards",
            Some(&format!("d3il_bogus{i}")),
            None,
            b"",
        )
        .await;
        out.push(Outcome {
            what: "bogus token",
            status,
            body: b,
        });
    }
    out
}

/// Uploads without a token whose bodies are trickled a byte every 400 ms
/// after the early 401: each connection must be closed by the server; the
/// seconds each stayed open.
async fn trickle(addr: std::net::SocketAddr, connections: usize) -> Vec<f64> {
    let mut tasks = Vec::new();
    for _ in 0..connections {
        tasks.push(tokio::spawn(async move {
            let sock = tokio::net::TcpSocket::new_v4().unwrap();
            sock.bind("127.0.0.41:0".parse().unwrap()).unwrap();
            let mut s = sock.connect(addr).await.unwrap();
            s.write_all(
                b"POST /api/v1/submissions HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\nContent-Length: 2000000\r\n\r\n--b\r\n",
            )
            .await
            .unwrap();
            let began = Instant::now();
            let mut buf = [0u8; 4096];
            loop {
                assert!(began.elapsed() < Duration::from_secs(120), "a trickled body held its connection");
                if s.write_all(b"x").await.is_err() {
                    break;
                }
                match tokio::time::timeout(Duration::from_millis(400), s.read(&mut buf)).await {
                    Ok(Ok(0)) | Ok(Err(_)) => break,
                    _ => {}
                }
            }
            began.elapsed().as_secs_f64()
        }));
    }
    let mut held = Vec::new();
    for t in tasks {
        held.push(t.await.unwrap());
    }
    held
}

#[test]
fn a_flood_of_races_suites_uploads_trickles_and_bogus_tokens_does_not_stall_a_normal_submitter() {
    let dir = TempDir::new("abuse");
    let db = dir.path().join("lb.sqlite");
    let alice = D3IL.create_token(&db, "alice");
    let admin = D3IL.create_admin_token(&db, "op");
    let attackers: Vec<String> = (0..ATTACKERS)
        .map(|i| D3IL.create_token(&db, &format!("mallory{i}")))
        .collect();
    let server = D3IL.serve(
        &db,
        &[
            "--workers",
            "1",
            "--quota-per-day",
            "40",
            "--quota-total",
            "100",
            "--quota-concurrent",
            "8",
            "--max-queued-races",
            "1",
            "--anonymous-rate-limit",
            "40",
            "--failed-auth-limit",
            "5",
            "--header-timeout",
            "2",
            "--linger-timeout",
            "3",
        ],
    );
    let addr: std::net::SocketAddr = server.base.trim_start_matches("http://").parse().unwrap();
    let client = server.client(Some(&alice));
    let submit = |stem: &str, task: &str, method: &str| {
        let manifest = std::fs::read_to_string(fixture(&format!("{stem}.json"))).unwrap();
        client
            .submit(
                &[
                    ("method", method.to_string()),
                    ("task", task.to_string()),
                    ("training_seed", "0".into()),
                    ("protocol", "quick".into()),
                    ("manifest", manifest),
                ],
                Some(&fixture(&format!("{stem}.onnx"))),
            )
            .unwrap_or_else(|e| panic!("alice's {stem}: {e}"))["id"]
            .as_i64()
            .unwrap()
    };
    // Alice's public Aligning submission: what the attackers race against.
    let target = submit("aligning_mlp_noise", "aligning", "AliceTarget");

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(4)
        .enable_all()
        .build()
        .unwrap();
    let began = Instant::now();
    let flood = rt.spawn(async move {
        let mut tasks = Vec::new();
        for (i, token) in attackers.into_iter().enumerate() {
            tasks.push(tokio::spawn(attack(
                addr,
                format!("127.0.0.{}", 20 + i),
                token,
                i as u32,
                target,
            )));
        }
        let bogus = tokio::spawn(bogus_tokens(addr));
        let held = tokio::spawn(trickle(addr, 3));
        let mut results = Vec::new();
        for t in tasks {
            results.push(t.await.unwrap());
        }
        (results, bogus.await.unwrap(), held.await.unwrap())
    });
    // Meanwhile alice submits a quick evaluation and waits for it.
    std::thread::sleep(Duration::from_secs(2));
    let quick = submit("avoiding_path", "avoiding", "AliceQuick");
    let done = client
        .wait(quick, NORMAL_BOUND, |_| {})
        .unwrap_or_else(|e| panic!("alice's quick evaluation under the flood: {e}"));
    let normal = began.elapsed();
    assert_eq!(done["status"], "completed", "{done}");
    let (attacks, bogus, held) = rt.block_on(flood).unwrap();
    let flood_time = began.elapsed();
    eprintln!(
        "abuse: alice's quick evaluation completed in {:.1} s under the flood (bound {} s); the flood took {:.1} s",
        normal.as_secs_f64(),
        NORMAL_BOUND.as_secs(),
        flood_time.as_secs_f64()
    );

    // Every refusal names its limit or what to fix; nothing failed on our side.
    let mut all: Vec<Outcome> = attacks.iter().flat_map(|a| a.2.clone()).collect();
    all.extend(bogus);
    let mut seen = std::collections::BTreeMap::<String, usize>::new();
    for o in &all {
        let m = message(&o.body);
        match o.status {
            200..=202 => {}
            429 => {
                let flag = LIMIT_FLAGS
                    .iter()
                    .find(|f| m.contains(*f))
                    .unwrap_or_else(|| panic!("{}: a 429 that names no limit: {m}", o.what));
                *seen.entry(flag.to_string()).or_default() += 1;
            }
            401 => assert!(m.contains("token"), "{}: {m}", o.what),
            400 | 422 => assert!(
                m.contains("dry run") || m.contains("ONNX") || m.contains("onnx"),
                "{}: {m}",
                o.what
            ),
            s => panic!("{}: status {s}: {m}", o.what),
        }
    }
    eprintln!("abuse: refusals by limit: {seen:?}");
    for flag in [
        "--max-queued-races",
        "--quota-concurrent",
        "--anonymous-rate-limit",
        "--failed-auth-limit",
    ] {
        assert!(seen.contains_key(flag), "no refusal named {flag}: {seen:?}");
    }
    // The trickled bodies were cut off at the linger deadline (3 s; the
    // bound is generous), not held.
    assert_eq!(held.len(), 3);
    for s in &held {
        assert!(*s < 60.0, "a trickled body held its connection {s:.1} s");
    }

    // Nothing accepted is lost: every accepted submission and race is there.
    let op = server.client(Some(&admin));
    let mut races = Vec::new();
    for (own, r, _) in &attacks {
        let own = own.expect("each attacker's own submission was accepted");
        let s = client
            .submission(own)
            .expect("an accepted submission is there");
        assert!(
            ["queued", "running", "completed", "failed"].contains(&s["status"].as_str().unwrap()),
            "{s}"
        );
        assert_eq!(r.len(), 1, "one race each (--max-queued-races 1)");
        races.extend(r.iter().copied());
    }
    for id in &races {
        let v = client.get_race(*id).expect("an accepted race is there");
        if matches!(v["status"].as_str(), Some("queued" | "running")) {
            op.cancel_race(*id).expect("an admin cancels it");
        }
    }
    for id in &races {
        let v = client.get_race(*id).unwrap();
        assert!(
            ["cancelled", "completed", "failed"].contains(&v["status"].as_str().unwrap()),
            "{v}"
        );
    }
    assert_eq!(client.submission(target).unwrap()["status"], "completed");
}
