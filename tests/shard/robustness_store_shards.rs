//! The store's side of a sharded robustness submission (issue 40), on both
//! backends (a real SQLite file and a real PostgreSQL database): a suite
//! submission queued as two shard jobs, real parts of the scripted Aligning
//! expert's suite (real MuJoCo, quick protocol, every rollout cut after a
//! few steps to keep it cheap), the first part kept without a merge, the
//! last one merged in its transaction into the document the unsharded run
//! gives (level 0 stored as the plain result), a report from a lost lease
//! refused, and parts of another suite failing the submission with the
//! merge's reason. `tests/robustness_server_shards.rs` runs the whole path
//! through real workers.

use d3il_evaluator::eval::{EvalOptions, PolicyInfo};
use d3il_evaluator::robustness::{self, SuiteObserver};
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::suite_shard::evaluate_suite_shard;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult};
use d3il_protocol::shard::Shard;
use d3il_protocol::{ObsType, ProtocolKind, SuiteName, TaskId};
use d3il_server::store::{
    DbTarget, NewMethod, NewPolicy, NewSubmission, Store, StoreError, SubmissionStatus,
};
use serde_json::Value;

struct Quiet;

impl SuiteObserver for Quiet {
    fn progress(&mut self, _done: usize, _total: usize) {}
}

/// The whole suite and its two shards' parts, each run with a fresh policy
/// as separate workers run them.
fn whole_and_parts() -> (RobustnessResult, Vec<RobustnessPart>) {
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    let suite =
        robustness::suite_for(SuiteName::Robustness, TaskId::Aligning, ObsType::State).unwrap();
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        step_cap: Some(6),
        ..EvalOptions::default()
    };
    let info = PolicyInfo {
        sha256: "scripted".into(),
        obs_type: ObsType::State,
    };
    let policy = || ScriptedPolicy::from_name("aligning:inside", task.spec()).unwrap();
    let plan = robustness::plan(&task, &policy(), &opts, &suite).unwrap();
    let whole = robustness::evaluate_suite(
        &task,
        &mut policy(),
        &info,
        &opts,
        &suite,
        &plan,
        &mut Quiet,
    )
    .unwrap();
    let parts = (1..=2)
        .map(|index| {
            let shard = Shard { index, count: 2 };
            evaluate_suite_shard(
                &task,
                &mut policy(),
                &info,
                &opts,
                &suite,
                &plan,
                shard,
                &mut Quiet,
            )
            .unwrap()
        })
        .collect();
    (whole, parts)
}

/// The document without the measured inference times (wall clock; a
/// merge's is the mean over both shards' calls).
fn timeless(doc: &RobustnessResult) -> Value {
    let mut v = serde_json::to_value(doc).unwrap();
    v["control"]["metrics"]["inference_ms"] = Value::Null;
    for l in v["levels"].as_array_mut().unwrap() {
        l["result"]["metrics"]["inference_ms"] = Value::Null;
    }
    v
}

async fn suite_submission(store: &Store, seed: i64) -> i64 {
    let m = store
        .ensure_method(
            &NewMethod {
                name: "Sharded-Scripted".into(),
                ..NewMethod::default()
            },
            None,
        )
        .await
        .unwrap();
    let new = NewSubmission {
        method_id: m.id,
        submitter_id: None,
        task: TaskId::Aligning,
        obs_type: ObsType::State,
        training_seed: seed,
        data_fraction: 1.0,
        protocol: ProtocolKind::Quick,
        policy: NewPolicy::Remote {
            url: "ws://127.0.0.1:9/".into(),
            secret: None,
        },
        manifest_json:
            r#"{"task": "aligning", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#
                .into(),
        simulated_once: None,
    };
    store
        .create_suite_submission(&new, 3, "robustness", 2)
        .await
        .unwrap()
}

async fn check(store: Store, whole: &RobustnessResult, parts: &[RobustnessPart]) {
    let id = suite_submission(&store, 0).await;
    let a = store.claim_job("w0", 60).await.unwrap().unwrap();
    let b = store.claim_job("w1", 60).await.unwrap().unwrap();
    assert_eq!(a.submission.suite.as_deref(), Some("robustness"));
    assert_eq!(
        (a.job.shard(), b.job.shard()),
        (
            Some(Shard { index: 1, count: 2 }),
            Some(Shard { index: 2, count: 2 })
        )
    );
    // A slot whose lease is gone changes nothing.
    let lost = store
        .complete_suite_shard(b.job.id, "w9", &parts[1], &[])
        .await;
    assert!(
        matches!(lost, Err(StoreError::LeaseLost { .. })),
        "{lost:?}"
    );
    // The second shard first: kept, nothing merged yet.
    assert!(!store
        .complete_suite_shard(b.job.id, "w1", &parts[1], &[])
        .await
        .unwrap());
    assert!(store.robustness_document(id).await.unwrap().is_none());
    assert_ne!(
        store.submission(id).await.unwrap().status,
        SubmissionStatus::Completed
    );
    // The last one merges: the unsharded document, level 0 the plain result.
    assert!(store
        .complete_suite_shard(a.job.id, "w0", &parts[0], &[])
        .await
        .unwrap());
    let text = store
        .robustness_document(id)
        .await
        .unwrap()
        .expect("document");
    let doc: RobustnessResult = serde_json::from_str(&text).unwrap();
    assert_eq!(timeless(&doc), timeless(whole));
    assert_eq!(
        store.submission(id).await.unwrap().status,
        SubmissionStatus::Completed
    );
    let job = store.job_for(id).await.unwrap();
    let recorded = 6 * (whole.levels.len() as i64 + 1);
    assert_eq!(
        (job.rollouts_done, job.rollouts_total),
        (recorded, recorded)
    );
    let summary = store.robustness_summary(id).await.unwrap().unwrap();
    assert_eq!(summary.overall, whole.overall);
    let rows = store.robustness_rows(Some(TaskId::Aligning)).await.unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(
        rows[0].summary_json.0.control.per_context,
        whole.control.per_context
    );

    // Parts that do not make one suite (one shard lost a level) fail the
    // submission with the merge's reason.
    let id = suite_submission(&store, 1).await;
    let a = store.claim_job("w0", 60).await.unwrap().unwrap();
    let b = store.claim_job("w1", 60).await.unwrap().unwrap();
    let mut short = parts[1].clone();
    short.levels.pop();
    assert!(!store
        .complete_suite_shard(a.job.id, "w0", &parts[0], &[])
        .await
        .unwrap());
    assert!(store
        .complete_suite_shard(b.job.id, "w1", &short, &[])
        .await
        .unwrap());
    let s = store.submission(id).await.unwrap();
    assert_eq!(s.status, SubmissionStatus::Failed);
    let message = s.error_message.unwrap_or_default();
    assert!(
        message.contains("the shards could not be merged") && message.contains("levels"),
        "{message}"
    );
    assert!(store.robustness_document(id).await.unwrap().is_none());
}

#[test]
fn sharded_suite_parts_merge_in_the_store_into_the_unsharded_document() {
    let (whole, parts) = whole_and_parts();
    let dir = d3il_test_support::TempDir::new("robustness-store-shards");
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    for target in [
        DbTarget::Sqlite(dir.path().join("lb.sqlite")),
        DbTarget::Postgres(d3il_test_support::pg::fresh_database()),
    ] {
        rt.block_on(async {
            let store = Store::connect(&target, Some(&dir.path().join("policies")))
                .await
                .unwrap_or_else(|e| panic!("{target}: {e}"));
            check(store, &whole, &parts).await;
        });
    }
}
