//! Runs the real `d3il` binary: `d3il serve` on 127.0.0.1 port 0 with a fresh
//! SQLite file, `d3il token create`, and helpers to talk to it.
#![allow(dead_code)]

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub const EXE: &str = env!("CARGO_BIN_EXE_d3il");

pub use d3il_test_support::TempDir;

/// A running `d3il serve` process (killed on drop).
pub struct Server {
    pub child: Child,
    pub base: String,
}

impl Server {
    /// Starts `d3il serve --db DB --bind 127.0.0.1:0 EXTRA...` and waits for
    /// its `listening on` line.
    pub fn start(db: &Path, extra: &[&str]) -> Server {
        Server::start_on(db.as_os_str(), extra)
    }

    /// [`Server::start`] on any `--db` (a SQLite path or a PostgreSQL URL).
    /// Test servers skip the background work of a real start unless asked:
    /// the drift canary (`--no-verify`; [`Server::start_with_canary`] runs
    /// it) and the fidelity report (`--fidelity off` unless EXTRA sets it),
    /// and have no submission quota unless EXTRA sets a `--quota-*` flag,
    /// and load no zoo (`--zoo none`) unless EXTRA names one.
    pub fn start_on(db: &std::ffi::OsStr, extra: &[&str]) -> Server {
        let mut args = vec!["--no-verify"];
        args.extend_from_slice(extra);
        Server::spawn(db, &args)
    }

    /// [`Server::start`] with the drift canary run at start, as `d3il serve` does.
    pub fn start_with_canary(db: &Path, extra: &[&str]) -> Server {
        Server::spawn(db.as_os_str(), extra)
    }

    fn spawn(db: &std::ffi::OsStr, extra: &[&str]) -> Server {
        let mut args: Vec<&str> = extra.to_vec();
        if !extra.contains(&"--fidelity") {
            args.extend(["--fidelity", "off"]);
        }
        // The zoo (issue 50) only where a test asks for it: the boards of
        // the other tests hold their own submissions and the paper's rows.
        if !extra.contains(&"--zoo") {
            args.extend(["--zoo", "none"]);
        }
        // No submission quota (issue 42) unless asked: tests submit many
        // evaluations with one token to measure other things.
        if !extra.iter().any(|a| a.starts_with("--quota")) {
            args.extend([
                "--quota-per-day",
                "0",
                "--quota-total",
                "0",
                "--quota-concurrent",
                "0",
                "--max-queued-races",
                "0",
            ]);
        }
        let mut child = Command::new(EXE)
            .arg("serve")
            .arg("--db")
            .arg(db)
            .args(["--bind", "127.0.0.1:0"])
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start d3il serve");
        let line = wait_for_line(&mut child, "listening on ", "d3il serve");
        let base = line["listening on ".len()..].trim().to_string();
        Server { child, base }
    }

    /// SIGKILL: no chance to clean up (what a crash or power cut looks like).
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    pub fn client(&self, token: Option<&str>) -> d3il_server::client::Client {
        d3il_server::client::Client::new(&self.base, token.map(str::to_string)).expect("client")
    }

    pub fn get_text(&self, path: &str) -> (u16, String) {
        self.client(None).get_text(path).expect("GET")
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn create_token(db: &Path, name: &str) -> String {
    create_token_args(db, name, &[])
}

/// An operator's token (`d3il token create --admin`): it opens `/admin`.
pub fn create_admin_token(db: &Path, name: &str) -> String {
    create_token_args(db, name, &["--admin"])
}

fn create_token_args(db: &Path, name: &str, extra: &[&str]) -> String {
    let mut args = vec!["--db", db.to_str().expect("utf-8 path")];
    args.extend_from_slice(extra);
    create_token_on(name, &args)
}

/// `d3il token create --name NAME ARGS...` (ARGS give `--db` and, for
/// PostgreSQL, `--policy-store`); returns the token.
pub fn create_token_on(name: &str, args: &[&str]) -> String {
    let out = Command::new(EXE)
        .args(["token", "create", "--name", name])
        .args(args)
        .output()
        .expect("run d3il token create");
    assert!(
        out.status.success(),
        "token create failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let token = String::from_utf8(out.stdout)
        .expect("utf8")
        .trim()
        .to_string();
    assert!(token.starts_with("d3il_"), "{token}");
    token
}

/// Reads `child`'s stdout (piped) until a line starting with `prefix` and
/// returns it; the rest of stdout is drained in the background so the child
/// never blocks on a full pipe. Panics if `what` exits first.
pub fn wait_for_line(child: &mut Child, prefix: &str, what: &str) -> String {
    let stdout = child.stdout.take().expect("stdout is piped");
    let mut lines = BufReader::new(stdout).lines();
    let found = loop {
        let line = lines
            .next()
            .unwrap_or_else(|| panic!("{what} exited before printing `{prefix}…`"))
            .expect("read stdout");
        if line.starts_with(prefix) {
            break line;
        }
    };
    std::thread::spawn(move || for _ in lines {});
    found
}

/// Polls `f` until it returns Some or the timeout passes.
pub fn wait_for<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Some(v) = f() {
            return Some(v);
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    None
}

/// The result of the same fixture evaluated by a plain `d3il eval` (one
/// process, no shards, Aligning quick protocol) with the training seed as the
/// evaluator seed.
pub fn plain_eval(dir: &Path, policy: &Path, seed: u32) -> Value {
    let out_json = dir.join(format!("plain-{seed}.json"));
    let out = Command::new(EXE)
        .args([
            "eval",
            "--task",
            "aligning",
            "--protocol",
            "quick",
            "--seed",
        ])
        .arg(seed.to_string())
        .arg("--policy")
        .arg(policy)
        .arg("--json")
        .arg(&out_json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&std::fs::read(&out_json).unwrap()).unwrap()
}

/// An estimate as the server's views give it, as a result document carries
/// it: the views add the interval's description in words (`interval`),
/// which must be there; everything else is the document's.
pub fn document_estimate(view: &Value) -> Value {
    let mut e = view.clone();
    let words = e
        .as_object_mut()
        .and_then(|o| o.remove("interval"))
        .unwrap_or_else(|| panic!("the view describes the interval: {view}"));
    assert!(words.as_str().is_some_and(|w| !w.is_empty()), "{words}");
    e
}

/// The merged result equals the plain one bit for bit: every metric with
/// its interval, the per-initial-state breakdown and every rollout record.
/// (Only the measured inference time may differ.)
pub fn assert_same_result(done: &Value, plain: &Value) {
    let merged = &done["result"];
    for metric in ["success_rate", "behaviour_entropy", "conditional_entropy"] {
        assert_eq!(
            document_estimate(&merged["metrics"][metric]),
            plain["metrics"][metric],
            "{metric}"
        );
    }
    let rollouts = merged["rollouts"].as_array().unwrap();
    let plain_rollouts = plain["rollouts"].as_array().unwrap();
    assert_eq!(rollouts.len(), plain_rollouts.len());
    for (a, b) in rollouts.iter().zip(plain_rollouts) {
        for k in [
            "context_index",
            "rollout_index",
            "success",
            "steps",
            "behaviour",
        ] {
            assert_eq!(a[k], b[k], "{k}: {a} vs {b}");
        }
    }
    assert_eq!(
        merged["protocol_manifest"]["policy_sha256"], plain["manifest"]["policy_sha256"],
        "the same policy"
    );
}
