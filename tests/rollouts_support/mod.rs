//! Real results with rollout traces for the server's rollout views (issue
//! 31): a `d3il eval --json` of a scripted expert, written into a SQLite
//! store as a worker would leave it, and plain HTTP requests to the server
//! (headless Chromium is d3il_test_support::chromium).
#![allow(dead_code)]

use d3il_protocol::rollout::{pack_f32, unpack_f32};
use d3il_protocol::EvalResult;
use std::path::Path;
use std::process::Command;

pub const EXE: &str = env!("CARGO_BIN_EXE_d3il");

/// `d3il eval --task TASK --policy POLICY --protocol quick --json` in `dir`.
pub fn eval(dir: &Path, task: &str, policy: &str) -> EvalResult {
    let out = dir.join(format!("{task}.json"));
    let run = Command::new(EXE)
        .args([
            "eval",
            "--task",
            task,
            "--policy",
            policy,
            "--protocol",
            "quick",
            "--json",
        ])
        .arg(&out)
        .output()
        .expect("run d3il eval");
    d3il_test_support::succeeded(&run, "d3il eval");
    serde_json::from_slice(&std::fs::read(&out).expect("eval JSON")).expect("an EvalResult")
}

/// `result` with rollout `number`'s action at `step` (0-based) nudged: a
/// record that no longer replays (the replay names step `step + 1`).
pub fn nudged(result: &EvalResult, number: usize, step: usize) -> EvalResult {
    let mut r = result.clone();
    let per = r.manifest.rollouts_per_context;
    let rec = r
        .rollouts
        .iter_mut()
        .find(|x| x.number(per) == number)
        .expect("the rollout");
    let trace = rec.trace.as_mut().expect("a trace of its own");
    let mut actions = unpack_f32("actions", &trace.actions).unwrap();
    actions[step * trace.act_dim] += 0.01;
    trace.actions = pack_f32(&actions);
    r
}

/// Completed submissions of `(method, result)` written into the SQLite
/// store `db` (the store's claim and completion), before a server starts.
pub fn store_finished(db: &Path, results: &[(&str, &EvalResult)]) -> Vec<i64> {
    use d3il_server::store::{NewPolicy, NewSubmission, Store};
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let store = Store::open(db).await.expect("open store");
        let mut ids = vec![];
        for (method, result) in results {
            let method_id = d3il_test_support::server::method_id(&store, method).await;
            let man = &result.manifest;
            let id = store
                .create_submission(
                    &NewSubmission {
                        method_id,
                        submitter_id: None,
                        task: man.task,
                        obs_type: man.obs_type,
                        training_seed: 0,
                        data_fraction: 1.0,
                        protocol: man.protocol,
                        policy: NewPolicy::Remote {
                            url: "ws://127.0.0.1:9/".into(),
                            secret: None,
                        },
                        manifest_json: "{}".into(),
                        simulated_once: Some(man.simulated_once),
                    },
                    3,
                )
                .await
                .expect("submission");
            let c = store
                .claim_job("test", 60)
                .await
                .expect("claim")
                .expect("a job");
            assert_eq!(c.submission.id, id);
            store
                .complete_job(c.job.id, id, result, &[])
                .await
                .expect("complete");
            ids.push(id);
        }
        ids
    })
}

/// The video's duration in seconds, as ffprobe reads it.
pub fn duration_seconds(mp4: &Path) -> f64 {
    let out = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "format=duration",
            "-of",
            "csv=p=0",
        ])
        .arg(mp4)
        .output()
        .expect("ffprobe (Debian's ffmpeg) is required: apt-get install -y ffmpeg");
    d3il_test_support::succeeded(&out, "ffprobe")
        .trim()
        .parse()
        .expect("a duration")
}

/// An HTTP answer: status, headers (names lowercase) and body.
pub struct Answer {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Answer {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("JSON: {e}: {}", self.text()))
    }
}

/// `GET base+path` with `headers` over a plain HTTP/1.1 connection (closed
/// after the answer; the server's bodies here have a Content-Length).
pub fn http_get(base: &str, path: &str, headers: &[(&str, &str)]) -> Answer {
    use std::io::{Read, Write};
    let host = base.strip_prefix("http://").expect("an http:// base");
    let mut s = std::net::TcpStream::connect(host).expect("connect");
    let mut req = format!("GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n");
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).expect("send");
    let mut raw = vec![];
    s.read_to_end(&mut raw).expect("read");
    let end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("end of the header");
    let head = String::from_utf8_lossy(&raw[..end]).into_owned();
    let mut lines = head.split("\r\n");
    let status = lines
        .next()
        .and_then(|l| l.split(' ').nth(1))
        .and_then(|c| c.parse().ok())
        .expect("a status line");
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[end + 4..].to_vec();
    if let Some(n) = headers
        .iter()
        .find(|(k, _)| k == "content-length")
        .and_then(|(_, v)| v.parse::<usize>().ok())
    {
        body.truncate(n);
    }
    Answer {
        status,
        headers,
        body,
    }
}
