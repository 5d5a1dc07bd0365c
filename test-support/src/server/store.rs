//! Databases for the server's tests: either backend, fresh per test, and
//! submissions written into a store as the intake or a worker leaves them.

use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, TaskId};
use d3il_server::store::{DbTarget, NewMethod, NewPolicy, NewSubmission, Store};
use std::path::{Path, PathBuf};

/// Which database a server or store test runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Sqlite,
    Postgres,
}

impl Backend {
    /// A fresh database: the SQLite file `sqlite`, or a new database on the
    /// throw-away PostgreSQL cluster.
    pub fn target(self, sqlite: PathBuf) -> DbTarget {
        match self {
            Backend::Sqlite => DbTarget::Sqlite(sqlite),
            Backend::Postgres => DbTarget::Postgres(crate::pg::fresh_database()),
        }
    }
}

/// For each `async fn name(b: Backend)`, a module `name` with the tests
/// `sqlite` and `postgres` running it on each backend (`Backend` in scope).
#[macro_export]
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

/// A fresh database of either backend (a SQLite file in a temporary
/// directory, or a new database on the throw-away PostgreSQL cluster) with
/// its own policy store; `open` may be called again to simulate a restart.
pub struct TestDb {
    pub target: DbTarget,
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

    pub async fn open(&self) -> Store {
        Store::connect(&self.target, Some(&self.policies))
            .await
            .expect("open the test store")
    }
}

/// Runs `f` on the SQLite store `db` (created if missing) on a runtime of
/// its own: seeding before a `d3il serve` process starts.
pub fn with_sqlite_store<T>(db: &Path, f: impl AsyncFnOnce(&Store) -> T) -> T {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let store = Store::open(db).await.expect("open store");
        f(&store).await
    })
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

/// A queued paper-protocol submission ([`queued_submission`], one job row);
/// returns (submission, job id).
pub async fn submit(store: &Store, method: &str, task: TaskId, seed: i64) -> (i64, i64) {
    submit_sharded(store, method, task, seed, 1).await
}

/// A paper-protocol submission whose job is split into `shards` rows;
/// returns (submission, first shard's job id).
pub async fn submit_sharded(
    store: &Store,
    method: &str,
    task: TaskId,
    seed: i64,
    shards: usize,
) -> (i64, i64) {
    let id = queued_submission(store, method, task, ProtocolKind::Paper, seed, shards).await;
    let job = store.job_for(id).await.unwrap();
    (id, job.id)
}

/// A queued state-observation submission of `method` with a remote policy,
/// its job in `shards` rows, as the intake stores it (the method is made if
/// needed); returns its id.
pub async fn queued_submission(
    store: &Store,
    method: &str,
    task: TaskId,
    protocol: ProtocolKind,
    training_seed: i64,
    shards: usize,
) -> i64 {
    let obs = ObsType::State;
    queued_submission_of(store, method, task, obs, protocol, training_seed, shards).await
}

/// The id of the method named `method`, created if the store has none.
pub async fn method_id(store: &Store, method: &str) -> i64 {
    let m = store
        .ensure_method(
            &NewMethod {
                name: method.into(),
                ..NewMethod::default()
            },
            None,
        )
        .await
        .expect("method");
    m.id
}

/// [`queued_submission`] for policies observing `obs`.
pub async fn queued_submission_of(
    store: &Store,
    method: &str,
    task: TaskId,
    obs: ObsType,
    protocol: ProtocolKind,
    training_seed: i64,
    shards: usize,
) -> i64 {
    store
        .create_submission_sharded(
            &NewSubmission {
                method_id: method_id(store, method).await,
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
pub async fn finished_submission(store: &Store, method: &str, result: &EvalResult) -> i64 {
    let m = &result.manifest;
    let id = queued_submission_of(store, method, m.task, m.obs_type, m.protocol, 0, 1).await;
    complete_as_worker(store, id, Finished::Evaluation(result)).await;
    id
}

/// Claims the one queued job, which must be submission `id`'s, and completes
/// it with `finished` as a worker does (a suite's document saved first).
async fn complete_as_worker(store: &Store, id: i64, finished: Finished<'_>) {
    let c = store
        .claim_job("test", 60)
        .await
        .expect("claim")
        .expect("a queued job");
    assert_eq!(c.submission.id, id, "the job of the new submission");
    let result = match finished {
        Finished::Evaluation(result) => result,
        Finished::Robustness(doc) => {
            assert_eq!(c.submission.suite.as_deref(), Some("robustness"));
            store.save_robustness(id, doc).await.expect("save");
            &doc.control
        }
    };
    store
        .complete_job(c.job.id, id, result, &[])
        .await
        .expect("complete");
}

/// What a finished Pushing submission ([`finished_pushing`]) ran.
pub enum Finished<'a> {
    /// An evaluation with this result.
    Evaluation(&'a EvalResult),
    /// The robustness suite with this document.
    Robustness(&'a RobustnessResult),
}

/// A finished Pushing (state, paper protocol, remote policy) submission of
/// `method`, written as a worker leaves it (the store's claim, for a suite
/// `save_robustness`, and completion); returns its id. Call while no other
/// job is queued.
pub async fn finished_pushing(
    store: &Store,
    method: &str,
    training_seed: i64,
    finished: Finished<'_>,
) -> i64 {
    let new = NewSubmission {
        method_id: method_id(store, method).await,
        submitter_id: None,
        task: TaskId::Pushing,
        obs_type: ObsType::State,
        training_seed,
        data_fraction: 1.0,
        protocol: ProtocolKind::Paper,
        policy: NewPolicy::Remote {
            url: "http://127.0.0.1:9/".into(),
            secret: None,
        },
        manifest_json: manifest("pushing"),
        simulated_once: None,
    };
    let id = match finished {
        Finished::Evaluation(_) => store.create_submission(&new, 3).await,
        Finished::Robustness(_) => {
            store
                .create_suite_submission(&new, 3, "robustness", 1)
                .await
        }
    }
    .expect("submission");
    complete_as_worker(store, id, finished).await;
    id
}

/// The result a worker stores for an Aligning (state) evaluation.
pub fn aligning_result(
    protocol: ProtocolKind,
    success: f64,
    cond: f64,
    initial_states: &str,
) -> EvalResult {
    let est = |v: f64| {
        d3il_protocol::Estimate::with_interval(
            v,
            v - 0.05,
            v + 0.05,
            d3il_protocol::IntervalMethod::KornGraubard,
        )
    };
    EvalResult {
        manifest: d3il_protocol::ProtocolManifest {
            initial_states: initial_states.into(),
            rollouts_per_context: 2,
            ..crate::test_manifest(TaskId::Aligning, protocol)
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
