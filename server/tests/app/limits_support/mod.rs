//! The harness of the fair-use tests (limits.rs): the real server on
//! 127.0.0.1 with a fresh SQLite file and a job runner of the test's choice,
//! clients from a given loopback address.
#![allow(dead_code)]

pub use d3il_protocol::{ErrorKind, Job, WorkerError};
pub use d3il_server::app::{prepare, ServerConfig};
pub use d3il_server::queue::{JobRunner, RunReport};
pub use std::net::SocketAddr;
pub use std::sync::atomic::{AtomicUsize, Ordering};
pub use std::sync::Arc;
pub use std::time::Duration;

pub struct App {
    pub addr: SocketAddr,
    pub state: d3il_server::app::AppState,
    pub _dir: tempfile::TempDir,
}

impl App {
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }
}

pub async fn spawn(cfg: impl FnOnce(&mut ServerConfig), runner: Arc<dyn JobRunner>) -> App {
    let dir = tempfile::tempdir().unwrap();
    let mut c = ServerConfig::new(
        dir.path().join("t.sqlite"),
        "127.0.0.1:0".parse().unwrap(),
        "/bin/false".into(),
    );
    c.workers = 0;
    // The runner here is a stub: uploads are not dry-run (root tests cover it).
    c.dry_run_uploads = false;
    cfg(&mut c);
    let (listener, running) = prepare(c, runner).await.expect("server starts");
    tokio::spawn(d3il_server::app::serve_listener(
        listener,
        running.state.clone(),
    ));
    App {
        addr: running.addr,
        state: running.state,
        _dir: dir,
    }
}

/// A client whose connections come from `ip` (127.0.0.0/8).
pub fn client_from(ip: &str) -> reqwest::Client {
    reqwest::Client::builder()
        .local_address(Some(ip.parse().unwrap()))
        .build()
        .unwrap()
}

/// A runner that fails every job after a while, counting how many run at once.
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

pub fn idle_runner() -> Arc<dyn JobRunner> {
    Arc::new(Counting::default())
}

/// The status of a GET of `url` from `c`, with `X-Forwarded-For: xff` (if
/// given) and a bearer `token` (if given).
pub async fn status_of(
    c: &reqwest::Client,
    url: &str,
    xff: Option<&str>,
    token: Option<&str>,
) -> u16 {
    let mut rb = c.get(url);
    if let Some(x) = xff {
        rb = rb.header("x-forwarded-for", x);
    }
    if let Some(t) = token {
        rb = rb.bearer_auth(t);
    }
    rb.send().await.unwrap().status().as_u16()
}
