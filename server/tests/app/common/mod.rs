//! spawn_app(): the real server on 127.0.0.1 port 0 with a fresh SQLite file.
#![allow(dead_code)]

pub mod quotas;

use d3il_server::app::{prepare, ServerConfig};
use d3il_server::queue::JobRunner;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

pub struct TestApp {
    pub addr: SocketAddr,
    pub base: String,
    pub db: PathBuf,
    pub token: String,
    pub state: d3il_server::app::AppState,
    pub http: reqwest::Client,
    pub dir: tempfile::TempDir,
}

impl TestApp {
    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// GET with a freshly minted admin token (`/admin`).
    pub async fn get_admin_text(&self, path: &str) -> (u16, String) {
        let admin = self
            .state
            .store
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

    pub async fn get_text(&self, path: &str) -> (u16, String) {
        let r = self.http.get(self.url(path)).send().await.expect("GET");
        let s = r.status().as_u16();
        (s, r.text().await.expect("body"))
    }

    pub async fn get_json(&self, path: &str) -> (u16, serde_json::Value) {
        let r = self.http.get(self.url(path)).send().await.expect("GET");
        let s = r.status().as_u16();
        (s, r.json().await.expect("json body"))
    }

    /// POSTs a submission form with the app's token.
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
            .bearer_auth(&self.token)
            .multipart(form)
            .send()
            .await
            .expect("POST")
    }
}

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
    /// The zoo loaded at start (issue 50); default none.
    pub zoo: Option<PathBuf>,
    /// This build's physics fingerprint as the server is told it (its
    /// canary is not run in tests); default unknown.
    pub canary_fingerprint: Option<String>,
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
        }
    }
}

pub async fn spawn_app() -> TestApp {
    spawn_app_with(Options::default()).await
}

pub async fn spawn_app_with(o: Options) -> TestApp {
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
    // The worker here is /bin/false or a test script, not `d3il worker`:
    // uploads are judged by their evaluation (root tests cover the dry run
    // with the real worker) unless a test asks for it.
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
    cfg.worker.wall_clock = std::time::Duration::from_secs(60);
    // The production runner: the sandbox supervisor.
    let runner: Arc<dyn JobRunner> = d3il_server::runner::production_runner(&cfg.worker);
    let (listener, running) = prepare(cfg, runner).await.expect("server starts");
    tokio::spawn(d3il_server::app::serve_listener(
        listener,
        running.state.clone(),
    ));
    let token = running
        .state
        .store
        .create_token("tester")
        .await
        .expect("token");
    TestApp {
        addr: running.addr,
        base: format!("http://{}", running.addr),
        db,
        token,
        state: running.state,
        http: reqwest::Client::new(),
        dir,
    }
}

/// A valid manifest for `task`.
pub fn manifest(task: &str) -> String {
    format!(
        r#"{{"task": "{task}", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}}"#
    )
}

/// Bytes that pass the server's size check (the worker judges ONNX validity).
pub fn fake_onnx() -> Vec<u8> {
    let mut v = b"\x08\x07\x12\x04test".to_vec();
    v.resize(64, 0);
    v
}

/// Which database a store test runs on.
#[derive(Debug, Clone, Copy)]
pub enum Backend {
    Sqlite,
    Postgres,
}

impl Backend {
    /// A fresh database: the SQLite file `sqlite`, or a new database on the
    /// throw-away PostgreSQL cluster.
    pub fn target(self, sqlite: PathBuf) -> d3il_server::store::DbTarget {
        match self {
            Backend::Sqlite => d3il_server::store::DbTarget::Sqlite(sqlite),
            Backend::Postgres => {
                d3il_server::store::DbTarget::Postgres(d3il_test_support::pg::fresh_database())
            }
        }
    }
}

/// A fresh database of either backend (a SQLite file in a temporary
/// directory, or a new database on the throw-away PostgreSQL cluster) with
/// its own policy store; `open` may be called again to simulate a restart.
pub struct TestDb {
    pub target: d3il_server::store::DbTarget,
    pub policies: PathBuf,
    pub dir: tempfile::TempDir,
}

impl TestDb {
    pub fn new(b: Backend) -> TestDb {
        let dir = tempfile::tempdir().expect("temp dir");
        let target = b.target(dir.path().join("lb.sqlite"));
        TestDb {
            target,
            policies: dir.path().join("policy-store"),
            dir,
        }
    }

    pub async fn open(&self) -> d3il_server::store::Store {
        d3il_server::store::Store::connect(&self.target, Some(&self.policies))
            .await
            .expect("open the test store")
    }
}

/// For each `async fn name(b: Backend)`, a module `name` with the tests
/// `sqlite` and `postgres` running it on each backend.
#[allow(unused_macros)]
macro_rules! on_both_backends {
    ($($name:ident),+ $(,)?) => {$(
        mod $name {
            #[tokio::test]
            async fn sqlite() {
                super::$name(super::Backend::Sqlite).await
            }
            #[tokio::test]
            async fn postgres() {
                super::$name(super::Backend::Postgres).await
            }
        }
    )+};
}
#[allow(unused_imports)]
pub(crate) use on_both_backends;

/// A queued paper-protocol submission ([`queued_submission`], one job row);
/// returns (submission, job id).
pub async fn submit(
    store: &d3il_server::store::Store,
    method: &str,
    task: d3il_protocol::TaskId,
    seed: i64,
) -> (i64, i64) {
    submit_sharded(store, method, task, seed, 1).await
}

/// A paper-protocol submission whose job is split into `shards` rows;
/// returns (submission, first shard's job id).
pub async fn submit_sharded(
    store: &d3il_server::store::Store,
    method: &str,
    task: d3il_protocol::TaskId,
    seed: i64,
    shards: usize,
) -> (i64, i64) {
    let protocol = d3il_protocol::ProtocolKind::Paper;
    let id = queued_submission(store, method, task, protocol, seed, shards).await;
    let job = store.job_for(id).await.unwrap();
    (id, job.id)
}

/// A queued state-observation submission of `method` with a remote policy,
/// its job in `shards` rows, as the intake stores it (the method is made if
/// needed); returns its id.
pub async fn queued_submission(
    store: &d3il_server::store::Store,
    method: &str,
    task: d3il_protocol::TaskId,
    protocol: d3il_protocol::ProtocolKind,
    training_seed: i64,
    shards: usize,
) -> i64 {
    let obs = d3il_protocol::ObsType::State;
    queued_submission_of(store, method, task, obs, protocol, training_seed, shards).await
}

/// [`queued_submission`] for policies observing `obs`.
pub async fn queued_submission_of(
    store: &d3il_server::store::Store,
    method: &str,
    task: d3il_protocol::TaskId,
    obs: d3il_protocol::ObsType,
    protocol: d3il_protocol::ProtocolKind,
    training_seed: i64,
    shards: usize,
) -> i64 {
    use d3il_server::store::{NewMethod, NewPolicy, NewSubmission};
    let m = store
        .ensure_method(
            &NewMethod {
                name: method.into(),
                ..Default::default()
            },
            None,
        )
        .await
        .expect("method");
    store
        .create_submission_sharded(
            &NewSubmission {
                method_id: m.id,
                submitter_id: None,
                task,
                obs_type: obs,
                training_seed,
                data_fraction: 1.0,
                protocol,
                policy: NewPolicy::Remote {
                    url: "ws://127.0.0.1:1/".into(),
                    secret: None,
                },
                manifest_json: "{}".into(),
                simulated_once: None,
            },
            3,
            shards,
        )
        .await
        .expect("submission")
}

/// A completed submission of `method` on `result`'s task and protocol, as
/// a worker leaves it (the store's claim and completion); returns its id.
/// Call while no other job is queued.
pub async fn finished_submission(
    store: &d3il_server::store::Store,
    method: &str,
    result: &d3il_protocol::EvalResult,
) -> i64 {
    let m = &result.manifest;
    let id = queued_submission_of(store, method, m.task, m.obs_type, m.protocol, 0, 1).await;
    let c = store
        .claim_job("test", 60)
        .await
        .expect("claim")
        .expect("a queued job");
    assert_eq!(c.submission.id, id, "the job of the new submission");
    store
        .complete_job(c.job.id, id, result, &[])
        .await
        .expect("complete");
    id
}

/// The result a worker stores for an Aligning (state) evaluation.
pub fn aligning_result(
    protocol: d3il_protocol::ProtocolKind,
    success: f64,
    cond: f64,
    initial_states: &str,
) -> d3il_protocol::EvalResult {
    let est = |v: f64| {
        d3il_protocol::Estimate::with_interval(
            v,
            v - 0.05,
            v + 0.05,
            d3il_protocol::IntervalMethod::KornGraubard,
        )
    };
    d3il_protocol::EvalResult {
        manifest: d3il_protocol::ProtocolManifest {
            initial_states: initial_states.into(),
            rollouts_per_context: 2,
            ..d3il_test_support::test_manifest(d3il_protocol::TaskId::Aligning, protocol)
        },
        metrics: d3il_protocol::Metrics {
            success_rate: est(success),
            behaviour_entropy: est(0.5),
            conditional_entropy: est(cond),
            stacking: None,
            stacking_levels: None,
            inference_ms: 1.5,
        },
        per_context: vec![],
        rollouts: vec![],
        rollouts_ended_unstable: 0,
    }
}
