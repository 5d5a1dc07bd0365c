//! `d3il bench serve`: latency of a normal request while the server is under
//! attack. The server runs in this process on its own runtime
//! (two threads) with a temporary database holding a finished 480-rollout
//! Pushing submission; a load generator on another runtime drives the
//! Pushing leaderboard page with closed-loop keep-alive clients, first quiet,
//! then while 2,000 half-open connections (from 20 loopback addresses) are
//! held and two 200 MiB uploads stream in, one after another. Prints
//! requests/s and p50/p99 of both phases; the last line is
//! `ratio <attack p99 / quiet p99>` (goal: at most 3).
//!
//! The uploads are filler bytes, not models, so the server runs with its
//! submission-time dry run off (`dry_run_uploads`; the bench says so): what
//! is measured is admission up to the dry run (authentication, streaming,
//! hashing and writing 200 MiB, storing the submission, queueing its job).
//! With the dry run on, every upload would also start a sandboxed worker that
//! loads the model, which is the evaluation's cost, not the server's.
//! `--smoke`: 1 s phases, 100 half-open connections, 8 MiB uploads.

use anyhow::{bail, Context};
use d3il_protocol::*;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const PAGE: &str = "/tasks/pushing";
const CLIENTS: usize = 8;
const ATTACK_ADDRS: usize = 20;

/// How long each phase runs and how hard the attack is.
#[derive(Clone, Copy)]
struct Size {
    phase: Duration,
    half_open: usize,
    upload_bytes: usize,
}

const FULL: Size = Size {
    phase: Duration::from_secs(8),
    half_open: 2000,
    upload_bytes: 200 << 20,
};

const SMOKE: Size = Size {
    phase: Duration::from_secs(1),
    half_open: 100,
    upload_bytes: 8 << 20,
};

pub fn run(smoke: bool) -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("d3il-bench-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let result = bench(&dir, if smoke { SMOKE } else { FULL });
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn bench(dir: &std::path::Path, size: Size) -> anyhow::Result<()> {
    raise_fd_limit();
    let server_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut cfg = d3il_server::app::ServerConfig::new(
        dir.join("bench.sqlite"),
        "127.0.0.1:0".parse()?,
        "/bin/false".into(),
    );
    cfg.workers = 0;
    // Filler bytes are no model: a dry run would rightly refuse them (400).
    cfg.dry_run_uploads = false;
    // The load generator is one address; its own limits are not measured here.
    cfg.anonymous_rate_limit_per_minute = u32::MAX;
    cfg.rate_limit_per_minute = u32::MAX;
    let runner = d3il_server::app::default_runner(&cfg);
    let (addr, token) = server_rt.block_on(async {
        let (listener, running) = d3il_server::app::prepare(cfg, runner).await?;
        let token = seed_database(&running.state).await?;
        server_rt_spawn(listener, running.state.clone());
        anyhow::Ok((running.addr, token))
    })?;

    let load_rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    load_rt.block_on(async move {
        // Warm up (templates, caches, connections).
        measure(addr, Duration::from_secs(1)).await?;
        println!(
            "uploads are admitted without their dry run (filler bytes, not models): \
             authentication, streaming, hashing, writing, storing and queueing are measured"
        );
        let quiet = measure(addr, size.phase).await?;
        report("quiet", &quiet);

        let stop = Arc::new(AtomicBool::new(false));
        let held = Arc::new(AtomicUsize::new(0));
        let flood = tokio::spawn(hold_half_open(addr, size.half_open, stop.clone(), held.clone()));
        // Let the flood build up before measuring.
        let t0 = Instant::now();
        while held.load(Ordering::Relaxed) < size.half_open && t0.elapsed() < Duration::from_secs(20) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let uploaded = Arc::new(AtomicUsize::new(0));
        let mut uploads = Vec::new();
        for k in 0..2 {
            uploads.push(tokio::spawn(upload_loop(
                addr,
                token.clone(),
                k,
                size.upload_bytes,
                stop.clone(),
                uploaded.clone(),
            )));
        }
        let attack = measure(addr, size.phase).await?;
        let held_now = held.load(Ordering::Relaxed);
        stop.store(true, Ordering::Relaxed);
        for u in uploads {
            u.await??;
        }
        flood.await?;
        report(
            &format!(
                "under attack ({held_now} half-open connections held, {} MiB uploaded in {} MiB uploads, 2 at a time)",
                uploaded.load(Ordering::Relaxed) >> 20,
                size.upload_bytes >> 20
            ),
            &attack,
        );
        let ratio = attack.p99 / quiet.p99;
        println!("goal: attack p99 at most 3x quiet p99");
        println!("ratio {ratio:.3}");
        anyhow::Ok(())
    })?;
    drop(server_rt);
    Ok(())
}

fn server_rt_spawn(listener: tokio::net::TcpListener, state: d3il_server::app::AppState) {
    tokio::spawn(d3il_server::app::serve_listener(listener, state));
}

/// A token and a finished paper-protocol Pushing submission (30 initial
/// states x 16 rollouts).
async fn seed_database(state: &d3il_server::app::AppState) -> anyhow::Result<String> {
    let store = &state.store;
    let token = store.create_token("bench").await?;
    let who = store
        .authenticate(&token)
        .await?
        .context("the new token authenticates")?;
    let method = store
        .ensure_method(
            &d3il_server::ops::NewMethod {
                name: "BenchPolicy".into(),
                history: Some(1),
                backbone: None,
                prediction: None,
                diversity: None,
                code_url: None,
                paper_url: None,
                description: None,
            },
            Some(who.id),
        )
        .await?;
    let manifest = PolicyManifest {
        task: TaskId::Pushing,
        obs_type: ObsType::State,
        history: 1,
        horizon: 1,
        execute: 1,
        normalisation: None,
        window: Default::default(),
    };
    store
        .create_submission(
            &d3il_server::ops::NewSubmission {
                method_id: method.id,
                submitter_id: Some(who.id),
                task: TaskId::Pushing,
                obs_type: ObsType::State,
                training_seed: 0,
                data_fraction: 1.0,
                protocol: ProtocolKind::Paper,
                policy: d3il_server::ops::NewPolicy::Remote {
                    url: "wss://policy.example.org/".into(),
                    secret: None,
                },
                manifest_json: serde_json::to_string(&manifest)?,
                simulated_once: None,
            },
            1,
        )
        .await?;
    let claimed = store
        .claim_job("bench", 600)
        .await?
        .context("the queued job")?;
    store
        .complete_job(claimed.job.id, claimed.submission.id, &result_480()?, &[])
        .await?;
    Ok(token)
}

fn result_480() -> anyhow::Result<EvalResult> {
    let (n_contexts, per) = (30, 16);
    let mut outcomes = vec![];
    let mut rollouts = vec![];
    for c in 0..n_contexts {
        for r in 0..per {
            let success = (c + r) % 3 != 0;
            let label = (r % 2).to_string();
            outcomes.push(d3il_metrics::Outcome::new(c, success, Some(&label)));
            rollouts.push(RolloutRecord {
                context_index: c,
                rollout_index: r,
                success,
                behaviour: serde_json::json!(r % 2),
                steps: 400,
                path: None,
                failure: None,
                ending: None,
                trace: None,
            });
        }
    }
    let ev = d3il_metrics::evaluate(
        TaskId::Pushing,
        &outcomes,
        1.0,
        &d3il_metrics::Bootstrap::default(),
    )?;
    Ok(EvalResult {
        manifest: ProtocolManifest {
            task: TaskId::Pushing,
            task_version: "v1".into(),
            obs_type: ObsType::State,
            protocol: ProtocolKind::Paper,
            robot_look: None,
            mjcf_sha256: "bench".into(),
            initial_states_sha256: "bench".into(),
            initial_states: "pushing-v2.json".into(),
            mujoco_version: "2.2.2".into(),
            evaluator_version: "bench".into(),
            n_contexts,
            rollouts_per_context: per,
            max_steps: 400,
            policy_sha256: "bench".into(),
            history: 1,
            horizon: 1,
            execute: 1,
            seed: 0,
            simulated_once: false,
            build: None,
            perturbation: None,
        },
        metrics: ev.metrics,
        per_context: ev.per_context,
        rollouts,
        rollouts_ended_unstable: 0,
    })
}

struct Phase {
    requests: usize,
    seconds: f64,
    p50: f64,
    p99: f64,
}

fn report(label: &str, p: &Phase) {
    println!(
        "{label}: {} requests of {PAGE} in {:.1} s by {CLIENTS} clients = {:.0} req/s, p50 {:.2} ms, p99 {:.2} ms",
        p.requests,
        p.seconds,
        p.requests as f64 / p.seconds,
        p.p50 * 1e3,
        p.p99 * 1e3
    );
}

/// `CLIENTS` keep-alive clients GET the page back to back for `len`.
async fn measure(addr: SocketAddr, len: Duration) -> anyhow::Result<Phase> {
    let start = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..CLIENTS {
        tasks.push(tokio::spawn(async move {
            let mut lat = Vec::new();
            let mut conn = TcpStream::connect(addr).await?;
            conn.set_nodelay(true)?;
            while start.elapsed() < len {
                let t = Instant::now();
                get(&mut conn, PAGE).await?;
                lat.push(t.elapsed().as_secs_f64());
            }
            anyhow::Ok(lat)
        }));
    }
    let mut all = Vec::new();
    for t in tasks {
        all.extend(t.await??);
    }
    let seconds = start.elapsed().as_secs_f64();
    if all.is_empty() {
        bail!("no request finished");
    }
    all.sort_by(f64::total_cmp);
    let q = |p: f64| all[((all.len() - 1) as f64 * p).round() as usize];
    Ok(Phase {
        requests: all.len(),
        seconds,
        p50: q(0.50),
        p99: q(0.99),
    })
}

/// One GET over a keep-alive connection; the body is read to its
/// Content-Length.
async fn get(conn: &mut TcpStream, path: &str) -> anyhow::Result<()> {
    conn.write_all(format!("GET {path} HTTP/1.1\r\nHost: bench\r\n\r\n").as_bytes())
        .await?;
    let (status, body) = read_response(conn).await?;
    if status != 200 {
        bail!(
            "GET {path} answered {status}: {}",
            String::from_utf8_lossy(&body)
        );
    }
    Ok(())
}

async fn read_response(conn: &mut TcpStream) -> anyhow::Result<(u16, Vec<u8>)> {
    let mut buf = Vec::with_capacity(64 << 10);
    let mut chunk = [0u8; 32 << 10];
    let header_end = loop {
        let n = conn.read(&mut chunk).await?;
        if n == 0 {
            bail!("the server closed the connection");
        }
        buf.extend_from_slice(&chunk[..n]);
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break i + 4;
        }
    };
    let head = String::from_utf8_lossy(&buf[..header_end]).to_string();
    let status: u16 = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .context("no status line")?;
    let len: usize = head
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case("content-length")
                .then(|| v.trim().parse().ok())?
        })
        .context("the response has no Content-Length")?;
    while buf.len() < header_end + len {
        let n = conn.read(&mut chunk).await?;
        if n == 0 {
            bail!("the server closed the connection mid-body");
        }
        buf.extend_from_slice(&chunk[..n]);
    }
    Ok((status, buf[header_end..header_end + len].to_vec()))
}

/// Holds `count` connections that never finish their request header,
/// from 127.0.0.2 .. 127.0.0.21; a connection the server closes (header
/// timeout) is opened again, until `stop`.
async fn hold_half_open(
    addr: SocketAddr,
    count: usize,
    stop: Arc<AtomicBool>,
    held: Arc<AtomicUsize>,
) {
    let mut tasks = Vec::new();
    for i in 0..count {
        let (stop, held) = (stop.clone(), held.clone());
        let from = std::net::Ipv4Addr::new(127, 0, 0, 2 + (i % ATTACK_ADDRS) as u8);
        tasks.push(tokio::spawn(async move {
            while !stop.load(Ordering::Relaxed) {
                let Ok(sock) = tokio::net::TcpSocket::new_v4() else {
                    return;
                };
                if sock.bind(SocketAddr::new(from.into(), 0)).is_err() {
                    return;
                }
                let Ok(mut s) = sock.connect(addr).await else {
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                };
                if s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").await.is_err() {
                    continue;
                }
                held.fetch_add(1, Ordering::Relaxed);
                let mut b = [0u8; 256];
                loop {
                    tokio::select! {
                        r = s.read(&mut b) => match r {
                            Ok(0) | Err(_) => break,
                            Ok(_) => continue,
                        },
                        _ = tokio::time::sleep(Duration::from_millis(200)) => {
                            if stop.load(Ordering::Relaxed) { break; }
                        }
                    }
                }
                held.fetch_sub(1, Ordering::Relaxed);
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
}

/// Streams 200 MiB submissions one after another until `stop` (uploader `k`
/// uses its own training seeds).
async fn upload_loop(
    addr: SocketAddr,
    token: String,
    k: usize,
    upload_bytes: usize,
    stop: Arc<AtomicBool>,
    uploaded: Arc<AtomicUsize>,
) -> anyhow::Result<()> {
    let boundary = "benchBoundary8c1f";
    let filler: Vec<u8> = (0..(1 << 16)).map(|i| (i % 251) as u8).collect();
    let mut seed = 1000 * (k + 1);
    while !stop.load(Ordering::Relaxed) {
        seed += 1;
        let mut head = String::new();
        for (name, v) in [
            ("method", "BenchUpload".to_string()),
            ("task", "pushing".to_string()),
            ("training_seed", seed.to_string()),
            (
                "manifest",
                r#"{"task": "pushing", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#
                    .to_string(),
            ),
        ] {
            head.push_str(&format!(
                "--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n{v}\r\n"
            ));
        }
        head.push_str(&format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\n\
             Content-Type: application/octet-stream\r\n\r\n"
        ));
        let tail = format!("\r\n--{boundary}--\r\n");
        let len = head.len() + upload_bytes + tail.len();
        let mut conn = TcpStream::connect(addr).await?;
        conn.write_all(
            format!(
                "POST /api/v1/submissions HTTP/1.1\r\nHost: bench\r\nAuthorization: Bearer {token}\r\n\
                 Content-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: {len}\r\n\r\n{head}"
            )
            .as_bytes(),
        )
        .await?;
        let mut sent = 0;
        while sent < upload_bytes {
            let n = filler.len().min(upload_bytes - sent);
            conn.write_all(&filler[..n]).await?;
            sent += n;
            uploaded.fetch_add(n, Ordering::Relaxed);
        }
        conn.write_all(tail.as_bytes()).await?;
        let (status, body) = read_response(&mut conn).await?;
        if status != 201 {
            bail!(
                "the {} MiB upload was answered {status}: {}",
                upload_bytes >> 20,
                String::from_utf8_lossy(&body)
            );
        }
    }
    Ok(())
}

/// Both ends of every connection live in this process: raise the soft
/// descriptor limit to the hard one (with util-linux `prlimit`, as this
/// crate has no unsafe code).
fn raise_fd_limit() {
    let needed = 2 * FULL.half_open as u64 + 1000;
    let limits = std::fs::read_to_string("/proc/self/limits").unwrap_or_default();
    let (soft, hard) = limits
        .lines()
        .find(|l| l.starts_with("Max open files"))
        .map(|l| {
            let v: Vec<&str> = l.split_whitespace().collect();
            (
                v.get(3).and_then(|x| x.parse::<u64>().ok()).unwrap_or(0),
                v.get(4)
                    .and_then(|x| x.parse::<u64>().ok())
                    .unwrap_or(u64::MAX),
            )
        })
        .unwrap_or((0, 0));
    if soft >= needed {
        return;
    }
    let raised = std::process::Command::new("prlimit")
        .arg(format!("--pid={}", std::process::id()))
        .arg(format!("--nofile={hard}:{hard}"))
        .status()
        .is_ok_and(|s| s.success());
    if !raised || hard < needed {
        eprintln!(
            "warning: {} file descriptors allowed, {needed} wanted; the flood may be cut short",
            if raised { hard } else { soft }
        );
    }
}
