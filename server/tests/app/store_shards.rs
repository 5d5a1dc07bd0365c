//! Store tests of sharded jobs (issue 19), each on both backends: a real
//! SQLite file and a real PostgreSQL database (a throw-away cluster,
//! `d3il_test_support::pg`).

use d3il_test_support::server::{submit, submit_sharded, Backend, TestDb};

use d3il_protocol::*;
use d3il_server::store::{JobState, StoreError};

/// Two pools (two store handles with their own connections, as two hosts
/// have) claim from one queue at once, four slots each: every shard is
/// handed out exactly once.
async fn concurrent_pools_never_take_a_shard_twice(b: Backend) {
    let db = TestDb::new(b);
    let (one, two) = (db.open().await, db.open().await);
    let mut subs = vec![];
    for seed in 0..4 {
        subs.push(
            submit_sharded(&one, "Shards", TaskId::Aligning, seed, 5)
                .await
                .0,
        );
    }
    let mut slots = vec![];
    for (n, store) in [one.clone(), two.clone()].into_iter().enumerate() {
        for slot in 0..4 {
            let store = store.clone();
            slots.push(tokio::spawn(async move {
                let mut got = vec![];
                while let Some(c) = store
                    .claim_job(&format!("host{n}-slot{slot}"), 60)
                    .await
                    .unwrap()
                {
                    got.push(c.job.id);
                }
                got
            }));
        }
    }
    let mut claimed = vec![];
    for s in slots {
        claimed.extend(s.await.unwrap());
    }
    claimed.sort();
    assert_eq!(claimed.len(), 20, "4 submissions x 5 shards: {claimed:?}");
    claimed.dedup();
    assert_eq!(claimed.len(), 20, "no shard handed out twice");
    for sub in subs {
        let j = one.job_for(sub).await.unwrap();
        assert_eq!((j.state, j.shard_count), (JobState::Leased, 5));
    }
}

/// A shard that fails for good fails its submission and the sibling shards
/// (one still queued, one running: its later report is refused).
async fn a_failed_shard_ends_its_siblings(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, _) = submit_sharded(&store, "Broken", TaskId::Aligning, 0, 3).await;
    let first = store.claim_job("w0", 60).await.unwrap().unwrap();
    let second = store.claim_job("w1", 60).await.unwrap().unwrap();
    assert_eq!(
        (first.job.shard(), second.job.shard()),
        (
            Some(d3il_protocol::shard::Shard { index: 1, count: 3 }),
            Some(d3il_protocol::shard::Shard { index: 2, count: 3 })
        )
    );
    let err = WorkerError {
        kind: ErrorKind::BadAction,
        message: "NaN action".into(),
    };
    assert!(!store
        .fail_attempt(first.job.id, "w0", &err, false)
        .await
        .unwrap());
    let j = store.job_for(sub).await.unwrap();
    assert_eq!(j.state, JobState::Failed);
    assert_eq!(store.submission(sub).await.unwrap().status, "failed");
    assert!(
        store.claim_job("w2", 60).await.unwrap().is_none(),
        "the queued shard ended too"
    );
    let r = store.fail_attempt(second.job.id, "w1", &err, true).await;
    assert!(matches!(r, Err(StoreError::LeaseLost { .. })), "{r:?}");
}

/// A slot's heartbeats keep the lease of the shard it claimed, with and
/// without progress.
async fn heartbeats_keep_a_shards_lease(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    submit_sharded(&store, "Beating", TaskId::Aligning, 0, 3).await;
    let c = store.claim_job("host-slot0", 3).await.unwrap().unwrap();
    assert!(store
        .heartbeat(c.job.id, "host-slot0", 3, None)
        .await
        .unwrap());
    assert!(store
        .heartbeat(c.job.id, "host-slot0", 3, Some((1, 2)))
        .await
        .unwrap());
    let j = store.job(c.job.id).await.unwrap();
    assert_eq!((j.rollouts_done, j.rollouts_total), (1, 2));
}

/// The home page counts submissions, the admin page job rows: a sharded
/// evaluation with one shard running is one running submission.
async fn queue_counts_submissions_once_and_jobs_per_shard(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    assert_eq!(store.submission_counts().await.unwrap(), (0, 0));
    submit_sharded(&store, "Sharded", TaskId::Aligning, 0, 3).await;
    let c = store.claim_job("w0", 60).await.unwrap().unwrap();
    submit(&store, "Single", TaskId::Aligning, 0).await;
    assert_eq!(store.submission_counts().await.unwrap(), (1, 1));
    assert_eq!(store.queue_counts().await.unwrap(), (3, 1));
    assert_eq!(c.job.shard().map(|s| s.count), Some(3));
}

d3il_test_support::on_both_backends!(
    queue_counts_submissions_once_and_jobs_per_shard,
    concurrent_pools_never_take_a_shard_twice,
    a_failed_shard_ends_its_siblings,
    heartbeats_keep_a_shards_lease
);
