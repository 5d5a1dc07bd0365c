//! The test server harness (feature `server`): the one way the tests start
//! a D3IL server, real parts only (a real SQLite file or PostgreSQL
//! database, a real socket on 127.0.0.1 port 0, real worker processes).
//!
//! A [`TestServer`] is started either
//! - in-process ([`spawn_app`], [`spawn_app_with`] and its [`Options`]: the
//!   server's `prepare` and `serve_listener` on this test's tokio runtime,
//!   with the production runner or one of the test's, a fresh SQLite file or
//!   a fresh database on the throw-away PostgreSQL cluster), or
//! - as the `d3il` binary ([`Binary::serve`]: `d3il serve --bind
//!   127.0.0.1:0` as a child process, its address read from its
//!   `listening on` line).
//!
//! Either way it gives its base URL, a reqwest client and the request
//! helpers the tests use, and stops on drop (the in-process server's accept
//! loop is aborted, the process is killed and reaped).
//!
//! [`store`] seeds databases as a worker leaves them; [`requests`] holds the
//! requests made with a given token or from a given loopback address.

pub mod requests;
pub mod store;

pub use crate::on_both_backends;
/// Scratch directories for the binary's databases.
pub use crate::TempDir;
pub use requests::*;
pub use store::*;

use d3il_protocol::{ErrorKind, Job, WorkerError};
use d3il_server::app::{prepare, AppState, ServerConfig};
use d3il_server::queue::{JobRunner, RunReport};
use serde_json::Value;
use std::ffi::OsStr;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A running test server (stopped on drop).
pub struct TestServer {
    pub addr: SocketAddr,
    /// `http://127.0.0.1:PORT`.
    pub base: String,
    pub http: reqwest::Client,
    /// The database kind it runs on.
    pub backend: Backend,
    /// The SQLite file (in-process), or the `--db` the binary was given.
    pub db: PathBuf,
    run: Run,
    /// The in-process server's scratch directory (database, policy store).
    _dir: Option<tempfile::TempDir>,
}

enum Run {
    InProcess {
        state: AppState,
        /// A token minted at start ("tester").
        token: String,
        serving: tokio::task::JoinHandle<()>,
    },
    Process(Child),
}

impl TestServer {
    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// The in-process server's state (its store, config, queue).
    pub fn state(&self) -> &AppState {
        match &self.run {
            Run::InProcess { state, .. } => state,
            Run::Process(_) => panic!("a `d3il serve` process has no in-process state"),
        }
    }

    /// The in-process server's store.
    pub fn store(&self) -> &d3il_server::store::Store {
        &self.state().store
    }

    /// The token minted when the in-process server started.
    pub fn token(&self) -> &str {
        match &self.run {
            Run::InProcess { token, .. } => token,
            Run::Process(_) => panic!("mint a token with Binary::create_token"),
        }
    }

    /// The `d3il serve` process's id.
    pub fn pid(&self) -> u32 {
        match &self.run {
            Run::Process(child) => child.id(),
            Run::InProcess { .. } => panic!("an in-process server has no process of its own"),
        }
    }

    /// Stops the server at once: SIGKILL for the process (no chance to
    /// clean up: what a crash or power cut looks like), the accept loop
    /// aborted in-process.
    pub fn kill(self) {
        drop(self)
    }

    /// The server's API client (blocking: tests of the binary).
    pub fn client(&self, token: Option<&str>) -> d3il_server::client::Client {
        d3il_server::client::Client::new(&self.base, token.map(str::to_string)).expect("client")
    }

    /// A blocking GET: (status, body).
    pub fn get_text_blocking(&self, path: &str) -> (u16, String) {
        self.client(None).get_text(path).expect("GET")
    }

    pub async fn get_text(&self, path: &str) -> (u16, String) {
        let r = self.http.get(self.url(path)).send().await.expect("GET");
        let s = r.status().as_u16();
        (s, r.text().await.expect("body"))
    }

    pub async fn get_json(&self, path: &str) -> (u16, Value) {
        let r = self.http.get(self.url(path)).send().await.expect("GET");
        let s = r.status().as_u16();
        (s, r.json().await.expect("json body"))
    }

    /// GET with a freshly minted admin token (`/admin`).
    pub async fn get_admin_text(&self, path: &str) -> (u16, String) {
        let admin = self
            .store()
            .create_token_with("operator", true)
            .await
            .expect("admin token");
        let r = self
            .http
            .get(self.url(path))
            .bearer_auth(admin)
            .send()
            .await
            .expect("GET");
        let s = r.status().as_u16();
        (s, r.text().await.expect("body"))
    }

    /// POSTs a submission form with the server's token.
    pub async fn submit(
        &self,
        fields: &[(&str, &str)],
        onnx: Option<Vec<u8>>,
    ) -> reqwest::Response {
        let mut form = reqwest::multipart::Form::new();
        for (k, v) in fields {
            form = form.text(k.to_string(), v.to_string());
        }
        if let Some(b) = onnx {
            form = form.part(
                "onnx",
                reqwest::multipart::Part::bytes(b).file_name("p.onnx"),
            );
        }
        self.http
            .post(self.url("/api/v1/submissions"))
            .bearer_auth(self.token())
            .multipart(form)
            .send()
            .await
            .expect("POST")
    }

    /// The in-process server served again on a new 127.0.0.1 port with its
    /// config changed by `f` (the config is shared by the handlers: call
    /// before any request); the old port stops.
    pub async fn reconfigured(mut self, f: impl FnOnce(&mut ServerConfig)) -> TestServer {
        let Run::InProcess { state, serving, .. } = &mut self.run else {
            panic!("restart the binary with other flags instead")
        };
        let mut cfg = (*state.cfg).clone();
        f(&mut cfg);
        state.cfg = Arc::new(cfg);
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        serving.abort();
        *serving = tokio::spawn(d3il_server::app::serve_listener(listener, state.clone()));
        self.addr = addr;
        self.base = format!("http://{addr}");
        self
    }

    /// Starts `EXE serve --db DB --bind 127.0.0.1:0 ARGS...` exactly so
    /// (see [`Binary::serve`] for the test defaults) and waits for its
    /// `listening on` line.
    pub fn binary(exe: impl AsRef<OsStr>, db: &OsStr, args: &[&str]) -> TestServer {
        let mut child = Command::new(exe)
            .arg("serve")
            .arg("--db")
            .arg(db)
            .args(["--bind", "127.0.0.1:0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start d3il serve");
        let line = wait_for_line(&mut child, "listening on ", "d3il serve");
        let base = line["listening on ".len()..].trim().to_string();
        let addr = base
            .trim_start_matches("http://")
            .parse()
            .unwrap_or_else(|e| panic!("d3il serve's address {base}: {e}"));
        let postgres = db.to_string_lossy().starts_with("postgres");
        TestServer {
            addr,
            base,
            http: reqwest::Client::new(),
            backend: if postgres {
                Backend::Postgres
            } else {
                Backend::Sqlite
            },
            db: PathBuf::from(db),
            run: Run::Process(child),
            _dir: None,
        }
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        match &mut self.run {
            Run::InProcess { serving, .. } => serving.abort(),
            Run::Process(child) => {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

/// A last change to an in-process server's config ([`Options::configure`]).
pub type Configure = Box<dyn FnOnce(&mut ServerConfig) + Send>;

/// How an in-process server is set up.
pub struct Options {
    pub workers: usize,
    pub worker_exe: Option<PathBuf>,
    pub rate_limit: u32,
    pub max_upload: usize,
    pub db: Option<PathBuf>,
    /// Connection limits; default: the server's.
    pub connections: Option<d3il_server::config::ConnectionLimits>,
    /// SQLite (default) or a fresh database on the test PostgreSQL.
    pub backend: Backend,
    /// Run each upload through the worker before queueing it (the server's
    /// default; off here, where the worker is /bin/false or a test script).
    pub dry_run_uploads: bool,
    /// What renders rollout videos (instead of `d3il replay`: a test
    /// script taking the same arguments), and how many at once.
    pub video_exe: Option<PathBuf>,
    pub video_renders: usize,
    /// The zoo of trained reference agents loaded at start; default none.
    pub zoo: Option<PathBuf>,
    /// This build's physics fingerprint as the server is told it (its
    /// canary is not run in tests); default unknown.
    pub canary_fingerprint: Option<String>,
    /// What runs the jobs; default the production runner (the sandbox
    /// supervisor running `worker_exe`).
    pub runner: Option<Arc<dyn JobRunner>>,
    /// Last changes to the config, after the fields above.
    pub configure: Option<Configure>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            workers: 0,
            worker_exe: None,
            rate_limit: 1000,
            max_upload: 1 << 20,
            db: None,
            connections: None,
            backend: Backend::Sqlite,
            dry_run_uploads: false,
            video_exe: None,
            video_renders: 1,
            zoo: None,
            canary_fingerprint: None,
            runner: None,
            configure: None,
        }
    }
}

/// The in-process server with the default [`Options`].
pub async fn spawn_app() -> TestServer {
    spawn_app_with(Options::default()).await
}

/// The in-process server with the default [`Options`], its config changed
/// by `configure` and its jobs run by `runner`.
pub async fn spawn_app_configured(
    configure: impl FnOnce(&mut ServerConfig) + Send + 'static,
    runner: Arc<dyn JobRunner>,
) -> TestServer {
    spawn_app_with(Options {
        runner: Some(runner),
        configure: Some(Box::new(configure)),
        ..Options::default()
    })
    .await
}

/// The in-process server on 127.0.0.1 port 0, set up by `o`.
pub async fn spawn_app_with(o: Options) -> TestServer {
    let dir = tempfile::tempdir().expect("tempdir");
    let db =
        o.db.clone()
            .unwrap_or_else(|| dir.path().join("test.sqlite"));
    let exe = o
        .worker_exe
        .clone()
        .unwrap_or_else(|| PathBuf::from("/bin/false"));
    let target = o.backend.target(db.clone());
    let mut cfg = ServerConfig::new(target, "127.0.0.1:0".parse().unwrap(), exe);
    cfg.policy_store =
        matches!(o.backend, Backend::Postgres).then(|| dir.path().join("policy-store"));
    cfg.workers = o.workers;
    cfg.rate_limit_per_minute = o.rate_limit;
    cfg.max_upload_bytes = o.max_upload;
    cfg.lease_seconds = 3;
    // The worker here is /bin/false, a test script or a stub runner, not
    // `d3il worker`: uploads are judged by their evaluation (root tests
    // cover the dry run with the real worker) unless a test asks for it.
    cfg.dry_run_uploads = o.dry_run_uploads;
    if let Some(c) = o.connections.clone() {
        cfg.connections = c;
    }
    cfg.worker.args = vec![];
    if let Some(exe) = o.video_exe.clone() {
        cfg.videos.exe = exe;
        cfg.videos.args = vec![];
    }
    cfg.videos.renders = o.video_renders;
    cfg.zoo = o.zoo.clone();
    cfg.canary.fingerprint = o.canary_fingerprint.clone();
    cfg.worker.wall_clock = Duration::from_secs(60);
    if let Some(f) = o.configure {
        f(&mut cfg);
    }
    // The production runner (the sandbox supervisor) unless the test has one.
    let runner = o
        .runner
        .unwrap_or_else(|| d3il_server::runner::production_runner(&cfg.worker));
    let (listener, running) = prepare(cfg, runner).await.expect("server starts");
    let serving = tokio::spawn(d3il_server::app::serve_listener(
        listener,
        running.state.clone(),
    ));
    let token = running
        .state
        .store
        .create_token("tester")
        .await
        .expect("token");
    TestServer {
        addr: running.addr,
        base: format!("http://{}", running.addr),
        http: reqwest::Client::new(),
        backend: o.backend,
        db,
        run: Run::InProcess {
            state: running.state,
            token,
            serving,
        },
        _dir: Some(dir),
    }
}

/// A stub runner that fails every job after 300 ms (a remote policy that
/// is not there), counting how many ran and how many ran at once.
#[derive(Default)]
pub struct Counting {
    pub now: AtomicUsize,
    pub max: AtomicUsize,
    pub runs: AtomicUsize,
}

impl JobRunner for Counting {
    fn run(&self, _job: &Job, _p: &mut dyn FnMut(usize, usize)) -> RunReport {
        let n = self.now.fetch_add(1, Ordering::SeqCst) + 1;
        self.max.fetch_max(n, Ordering::SeqCst);
        std::thread::sleep(Duration::from_millis(300));
        self.now.fetch_sub(1, Ordering::SeqCst);
        self.runs.fetch_add(1, Ordering::SeqCst);
        RunReport {
            outcome: Err(WorkerError {
                kind: ErrorKind::Remote,
                message: "no endpoint here".into(),
            }),
            mechanisms: vec![],
        }
    }
}

/// A [`Counting`] runner nobody reads.
pub fn idle_runner() -> Arc<dyn JobRunner> {
    Arc::new(Counting::default())
}

/// The `d3il` binary under test, by its path (in the root crate's tests:
/// `Binary(env!("CARGO_BIN_EXE_d3il"))`).
#[derive(Debug, Clone, Copy)]
pub struct Binary(pub &'static str);

impl Binary {
    /// Starts `d3il serve --db DB --bind 127.0.0.1:0 EXTRA...` and waits for
    /// its `listening on` line.
    pub fn serve(self, db: &Path, extra: &[&str]) -> TestServer {
        self.serve_on(db.as_os_str(), extra)
    }

    /// [`Binary::serve`] on any `--db` (a SQLite path or a PostgreSQL URL).
    /// Test servers skip the background work of a real start unless asked:
    /// the drift canary (`--no-verify`; [`Binary::serve_with_canary`] runs
    /// it) and the fidelity report (`--fidelity off` unless EXTRA sets it),
    /// and have no submission quota unless EXTRA sets a `--quota-*` flag,
    /// and load no zoo (`--zoo none`) unless EXTRA names one.
    pub fn serve_on(self, db: &OsStr, extra: &[&str]) -> TestServer {
        let mut args = vec!["--no-verify"];
        args.extend_from_slice(extra);
        self.serve_with_defaults(db, &args)
    }

    /// [`Binary::serve`] with the drift canary run at start, as `d3il serve` does.
    pub fn serve_with_canary(self, db: &Path, extra: &[&str]) -> TestServer {
        self.serve_with_defaults(db.as_os_str(), extra)
    }

    fn serve_with_defaults(self, db: &OsStr, extra: &[&str]) -> TestServer {
        let mut args: Vec<&str> = extra.to_vec();
        if !extra.contains(&"--fidelity") {
            args.extend(["--fidelity", "off"]);
        }
        // The zoo only where a test asks for it: the boards of
        // the other tests hold their own submissions and the paper's rows.
        if !extra.contains(&"--zoo") {
            args.extend(["--zoo", "none"]);
        }
        // No submission quota unless asked: tests submit many
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
        TestServer::binary(self.0, db, &args)
    }

    /// `d3il token create --db DB --name NAME`; returns the token.
    pub fn create_token(self, db: &Path, name: &str) -> String {
        self.create_token_args(db, name, &[])
    }

    /// An operator's token (`d3il token create --admin`): it opens `/admin`.
    pub fn create_admin_token(self, db: &Path, name: &str) -> String {
        self.create_token_args(db, name, &["--admin"])
    }

    fn create_token_args(self, db: &Path, name: &str, extra: &[&str]) -> String {
        let mut args = vec!["--db", db.to_str().expect("utf-8 path")];
        args.extend_from_slice(extra);
        self.create_token_on(name, &args)
    }

    /// `d3il token create --name NAME ARGS...` (ARGS give `--db` and, for
    /// PostgreSQL, `--policy-store`); returns the token.
    pub fn create_token_on(self, name: &str, args: &[&str]) -> String {
        let out = Command::new(self.0)
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

    /// The result of the same fixture evaluated by a plain `d3il eval` (one
    /// process, no shards, Aligning quick protocol) with the training seed
    /// as the evaluator seed.
    pub fn plain_eval(self, dir: &Path, policy: &Path, seed: u32) -> Value {
        let out_json = dir.join(format!("plain-{seed}.json"));
        let out = Command::new(self.0)
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
