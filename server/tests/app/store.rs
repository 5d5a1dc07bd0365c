//! Store tests, each on both backends: a real SQLite file and a real
//! PostgreSQL database (a throw-away cluster, `d3il_test_support::pg`).

use d3il_test_support::server::{queued_submission_of, submit, Backend, TestDb};

use d3il_protocol::*;
use d3il_server::on_db;
use d3il_server::store::{JobState, NewMethod, NewPolicy, NewSubmission, StoreError};

fn eval_result(task: TaskId, success: f64, cond: f64, paths: bool) -> EvalResult {
    let manifest = ProtocolManifest {
        initial_states: "test-v1.json".into(),
        n_contexts: 2,
        rollouts_per_context: 2,
        ..d3il_test_support::test_manifest(task, ProtocolKind::Paper)
    };
    let est = |v| {
        d3il_protocol::Estimate::with_interval(
            v,
            v - 0.1,
            v + 0.1,
            d3il_protocol::IntervalMethod::KornGraubard,
        )
    };
    let rollouts = (0..4)
        .map(|i| RolloutRecord {
            context_index: i / 2,
            rollout_index: i % 2,
            success: i % 2 == 0,
            behaviour: serde_json::json!([i % 2, 0, 1]),
            steps: 5,
            path: paths.then(|| vec![[0.5, -0.3], [0.52, -0.1 + i as f32 * 0.01]]),
            failure: None,
            ending: None,
            trace: None,
        })
        .collect();
    EvalResult {
        manifest,
        metrics: Metrics {
            success_rate: est(success),
            behaviour_entropy: est(0.5),
            conditional_entropy: est(cond),
            stacking: (task == TaskId::Stacking).then_some([success, success / 2.0, success / 4.0]),
            stacking_levels: None,
            inference_ms: 1.5,
        },
        per_context: vec![],
        rollouts,
        rollouts_ended_unstable: 0,
    }
}

async fn paper_rows_load_once_and_match_the_embedded_cells(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let cells = store.result_cells(None).await.unwrap();
    let paper = paper::load_embedded();
    assert_eq!(cells, paper.cells());
    assert_eq!(store.methods().await.unwrap().len(), 11);
    drop(store);
    // A second start must not duplicate anything.
    let store = db.open().await;
    assert_eq!(
        store.result_cells(None).await.unwrap().len(),
        paper.cells().len()
    );
    let bc = store.method_by_name("BC-MLP").await.unwrap().unwrap();
    assert_eq!(bc.history, Some(1));
    assert_eq!(bc.backbone.as_deref(), Some("MLP"));
    assert!(bc.from_paper);
}

async fn evaluated_rows_aggregate_over_seeds_with_sample_std(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    for (seed, s) in [(0, 0.6), (1, 0.8)] {
        let (sub, job) = submit(&store, "MyPolicy", TaskId::Aligning, seed).await;
        let claimed = store.claim_job("w0", 60).await.unwrap().unwrap();
        assert_eq!(claimed.job.id, job);
        let r = eval_result(TaskId::Aligning, s, 0.2 * (seed as f64 + 1.0), false);
        store.complete_job(job, sub, &r, &[]).await.unwrap();
        // A second (duplicate) result write changes nothing.
        let r2 = eval_result(TaskId::Aligning, 0.0, 0.0, false);
        store.complete_job(job, sub, &r2, &[]).await.unwrap();
    }
    let cells = store.result_cells(None).await.unwrap();
    let mine: Vec<_> = cells.iter().filter(|c| c.method == "MyPolicy").collect();
    assert_eq!(mine.len(), 1);
    let c = mine[0];
    assert_eq!(c.source, Source::Evaluated);
    assert_eq!(c.task, "Aligning (T2)");
    assert_eq!(c.table, "main");
    assert_eq!(c.n_seeds, 2);
    assert!((c.success_rate.mean - 0.7).abs() < 1e-12);
    // sample std of {0.6, 0.8} = 0.1414...
    assert!((c.success_rate.std - 0.02f64.sqrt()).abs() < 1e-12);
    assert!((c.entropy.mean - 0.3).abs() < 1e-12);
}

async fn image_rows_keep_the_robot_look_their_manifests_record(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let looks = [Some(RobotLook::Meshes), Some(RobotLook::Primitives), None];
    for (seed, look) in looks.into_iter().enumerate() {
        let (task, obs, protocol) = (TaskId::Aligning, ObsType::Image, ProtocolKind::Paper);
        let id = queued_submission_of(&store, "Look", task, obs, protocol, seed as i64, 1).await;
        let job = store.job_for(id).await.unwrap();
        let mut r = eval_result(task, 0.5, 0.2, false);
        r.manifest.obs_type = obs;
        r.manifest.robot_look = look;
        store.complete_job(job.id, id, &r, &[]).await.unwrap();
    }
    // Read back from the manifests by each backend's JSON function; seeds
    // drawn differently stay in rows of their own.
    let rows: Vec<(Option<RobotLook>, usize)> = store
        .board_rows()
        .await
        .unwrap()
        .into_iter()
        .filter(|r| r.method == "Look")
        .map(|r| (r.robot_look, r.n_seeds))
        .collect();
    assert_eq!(rows, looks.map(|l| (l, 1)));
    // `d3il tables` keeps them apart too, labelled as on the board.
    let cells: Vec<Option<String>> = store
        .result_cells(None)
        .await
        .unwrap()
        .into_iter()
        .filter(|c| c.method == "Look")
        .map(|c| c.robot_look)
        .collect();
    let badges = [
        None,
        Some("primitive robot"),
        Some("robot look not recorded"),
    ];
    assert_eq!(cells, badges.map(|b| b.map(str::to_string)));
}

async fn duplicate_seed_is_refused_and_stacking_expands(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "Stacker", TaskId::Stacking, 7).await;
    let m = store.method_by_name("Stacker").await.unwrap().unwrap();
    let dup = store
        .create_submission(
            &NewSubmission {
                method_id: m.id,
                submitter_id: None,
                task: TaskId::Stacking,
                obs_type: ObsType::State,
                training_seed: 7,
                data_fraction: 1.0,
                protocol: ProtocolKind::Paper,
                policy: NewPolicy::Remote {
                    url: "ws://127.0.0.1:1/".into(),
                    secret: None,
                },
                manifest_json: "{}".into(),
                simulated_once: None,
            },
            3,
        )
        .await;
    assert!(matches!(dup, Err(StoreError::Conflict(_))), "{dup:?}");
    store.claim_job("w", 60).await.unwrap().unwrap();
    let result = stacking_result(&[
        ("gbr", true),
        ("rgb", true),
        ("gb", false),
        ("bg", false),
        ("r", false),
        ("", false),
    ]);
    let levels = result.metrics.stacking_levels.unwrap();
    store.complete_job(job, sub, &result, &[]).await.unwrap();
    let cells = store.result_cells(None).await.unwrap();
    let rows: Vec<_> = cells
        .iter()
        .filter(|c| c.method == "Stacker")
        .map(|c| (c.task.clone(), c.success_rate.mean, c.entropy.mean))
        .collect();
    assert_eq!(
        rows,
        vec![
            (
                "Stacking-1 (T5)".to_string(),
                levels[0].success_rate.value,
                levels[0].conditional_entropy.value
            ),
            (
                "Stacking-2 (T5)".to_string(),
                levels[1].success_rate.value,
                levels[1].conditional_entropy.value
            ),
            (
                "Stacking-3 (T5)".to_string(),
                levels[2].success_rate.value,
                levels[2].conditional_entropy.value
            ),
        ]
    );
    // The data differ per level, so do the rows: 5/6, 4/6, 2/6 succeed, and
    // the entropies are those of the first letter (g, r, g, b, r), the first
    // two (gb, rg, gb, bg) and the full order (gbr, rgb).
    assert!((rows[0].1 - 5.0 / 6.0).abs() < 1e-12 && (rows[2].1 - 2.0 / 6.0).abs() < 1e-12);
    assert!(rows[0].2 != rows[1].2 && rows[1].2 != rows[2].2 && rows[0].2 != rows[2].2);
    let behaviour: Vec<f64> = store
        .board_rows()
        .await
        .unwrap()
        .iter()
        .filter(|r| r.method == "Stacker")
        .map(|r| r.behaviour_entropy.unwrap().mean)
        .collect();
    assert_eq!(
        behaviour,
        levels
            .iter()
            .map(|l| l.behaviour_entropy.value)
            .collect::<Vec<_>>()
    );
}

/// A Stacking result whose metrics are computed by d3il-metrics from one
/// context's rollouts given as (registration order, full stack).
fn stacking_result(rollouts: &[(&str, bool)]) -> EvalResult {
    let outcomes: Vec<d3il_metrics::Outcome> = rollouts
        .iter()
        .map(|(order, full)| {
            d3il_metrics::Outcome::new(0, *full, (!order.is_empty()).then_some(*order))
        })
        .collect();
    let ev = d3il_metrics::evaluate(
        TaskId::Stacking,
        &outcomes,
        1.0,
        &d3il_metrics::Bootstrap::default(),
    )
    .unwrap();
    let mut r = eval_result(TaskId::Stacking, 0.0, 0.0, false);
    r.metrics = ev.metrics;
    r.per_context = ev.per_context;
    r.rollouts = rollouts
        .iter()
        .enumerate()
        .map(|(i, (order, full))| RolloutRecord {
            context_index: 0,
            rollout_index: i,
            success: *full,
            behaviour: serde_json::json!(order),
            steps: 10,
            path: None,
            failure: None,
            ending: None,
            trace: None,
        })
        .collect();
    r
}

async fn stacking_results_stored_before_the_levels_share_one_entropy(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "OldStacker", TaskId::Stacking, 1).await;
    store.claim_job("w", 60).await.unwrap().unwrap();
    // Rates only, as results were stored before migration 0002.
    store
        .complete_job(
            job,
            sub,
            &eval_result(TaskId::Stacking, 0.8, 0.4, false),
            &[],
        )
        .await
        .unwrap();
    let cells = store.result_cells(None).await.unwrap();
    let rows: Vec<_> = cells
        .iter()
        .filter(|c| c.method == "OldStacker")
        .map(|c| (c.task.clone(), c.success_rate.mean, c.entropy.mean))
        .collect();
    assert_eq!(
        rows,
        vec![
            ("Stacking-1 (T5)".to_string(), 0.8, 0.4),
            ("Stacking-2 (T5)".to_string(), 0.4, 0.4),
            ("Stacking-3 (T5)".to_string(), 0.2, 0.4)
        ]
    );
}

async fn avoiding_paths_come_back_with_behaviours(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "Avoider", TaskId::Avoiding, 0).await;
    store.claim_job("w", 60).await.unwrap().unwrap();
    store
        .complete_job(
            job,
            sub,
            &eval_result(TaskId::Avoiding, 0.5, 0.1, true),
            &[],
        )
        .await
        .unwrap();
    let paths = store.avoiding_paths(sub).await.unwrap();
    assert_eq!(paths.len(), 4);
    assert_eq!(paths[1].0, serde_json::json!([1, 0, 1]));
    assert_eq!(paths[1].1[0], [0.5, -0.3]);
}

async fn leases_expire_retries_are_bounded_and_restart_requeues(b: Backend) {
    let db = TestDb::new(b);
    let mut store = db.open().await;
    let (sub, job) = submit(&store, "Flaky", TaskId::Pushing, 0).await;
    // Queued, with nothing ahead of it (position 0).
    assert_eq!(store.job_for(sub).await.unwrap().state, JobState::Queued);
    assert!(store.queued_ahead(job).await.unwrap().is_empty());
    let c = store.claim_job("w0", 60).await.unwrap().unwrap();
    assert_eq!(c.job.attempts, 1);
    assert!(
        store.claim_job("w1", 60).await.unwrap().is_none(),
        "a leased job is not handed out twice"
    );
    assert!(store.heartbeat(job, "w0", 60, Some((3, 10))).await.unwrap());
    assert!(!store
        .heartbeat(job, "someone-else", 60, None)
        .await
        .unwrap());
    // Simulated restart: the lease is abandoned and the job goes back to the
    // queue; the interrupted attempt is not counted (issue 17), twice over.
    for _ in 0..2 {
        drop(store);
        store = db.open().await;
        assert_eq!(store.requeue_abandoned().await.unwrap(), 1);
        assert_eq!(store.submission(sub).await.unwrap().status, "queued");
        assert_eq!(store.job_for(sub).await.unwrap().attempts, 0);
        let c = store.claim_job("w0", 60).await.unwrap().unwrap();
        assert_eq!(c.job.attempts, 1, "the restart gave the attempt back");
    }
    let err = WorkerError {
        kind: ErrorKind::Crashed,
        message: "worker killed by signal 9".into(),
    };
    assert!(
        store.fail_attempt(job, "w0", &err, true).await.unwrap(),
        "attempt 1 of 3 is retried"
    );
    let c = store.claim_job("w0", 60).await.unwrap().unwrap();
    assert_eq!(c.job.attempts, 2, "a worker crash counts");
    assert!(
        store.fail_attempt(job, "w0", &err, true).await.unwrap(),
        "attempt 2 of 3 is retried"
    );
    store.claim_job("w0", 60).await.unwrap().unwrap();
    assert!(
        !store.fail_attempt(job, "w0", &err, true).await.unwrap(),
        "attempt 3 of 3 is final"
    );
    let s = store.submission(sub).await.unwrap();
    assert_eq!(s.status, "failed");
    assert_eq!(s.error_kind.as_deref(), Some("crashed"));
    assert!(store.claim_job("w0", 60).await.unwrap().is_none());
    // A failed submission does not block resubmitting the same seed.
    submit(&store, "Flaky", TaskId::Pushing, 0).await;
}

async fn a_slot_that_lost_its_lease_cannot_requeue_or_fail_the_job(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "Slow", TaskId::Pushing, 0).await;
    // w0's lease is already over when it is granted; w1 takes the job over.
    store.claim_job("w0", -1).await.unwrap().unwrap();
    let c = store.claim_job("w1", 60).await.unwrap().unwrap();
    // The lost lease had no worker fault: the takeover is still attempt 1.
    assert_eq!((c.job.id, c.job.attempts), (job, 1));
    let err = WorkerError {
        kind: ErrorKind::Crashed,
        message: "worker killed by signal 9".into(),
    };
    for retry in [true, false] {
        let r = store.fail_attempt(job, "w0", &err, retry).await;
        assert!(
            matches!(r, Err(StoreError::LeaseLost { job_id, ref owner }) if job_id == job && owner == "w0"),
            "{r:?}"
        );
    }
    // Nothing changed: w1 still runs it.
    let j = store.job_for(sub).await.unwrap();
    assert_eq!(j.state, JobState::Leased);
    assert_eq!(j.lease_owner.as_deref(), Some("w1"));
    assert_eq!(j.error_kind, None);
    assert_eq!(store.submission(sub).await.unwrap().status, "running");
    // The holder's report counts.
    assert!(store.fail_attempt(job, "w1", &err, true).await.unwrap());
    assert_eq!(store.job_for(sub).await.unwrap().state, JobState::Queued);
}

async fn sibling_seeds_lists_the_rows_seeds_with_their_success(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (first, job) = submit(&store, "Seeds", TaskId::Aligning, 3).await;
    store.claim_job("w", 60).await.unwrap().unwrap();
    store
        .complete_job(
            job,
            first,
            &eval_result(TaskId::Aligning, 0.75, 0.2, false),
            &[],
        )
        .await
        .unwrap();
    let (second, _) = submit(&store, "Seeds", TaskId::Aligning, 1).await;
    // Another task's seed is another row.
    submit(&store, "Seeds", TaskId::Pushing, 2).await;
    let s = store.submission(second).await.unwrap();
    let seeds = store.sibling_seeds(&s).await.unwrap();
    let got: Vec<(i64, i64, String, Option<f64>)> = seeds
        .iter()
        .map(|x| (x.id, x.training_seed, x.status.to_string(), x.success_rate))
        .collect();
    assert_eq!(
        got,
        vec![
            (second, 1, "queued".to_string(), None),
            (first, 3, "completed".to_string(), Some(0.75)),
        ]
    );
}

async fn bad_stored_data_fails_to_decode_naming_the_column(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "Corrupt", TaskId::Aligning, 0).await;
    store.claim_job("w", 60).await.unwrap().unwrap();
    store
        .complete_job(
            job,
            sub,
            &eval_result(TaskId::Aligning, 0.5, 0.1, false),
            &[],
        )
        .await
        .unwrap();
    let rows = store.board_rows().await.unwrap();
    assert!(rows.iter().any(|r| r.method == "Corrupt"));
    for (sql, column) in [
        (
            "UPDATE submissions SET task = 'juggling' WHERE id = $1",
            "task",
        ),
        (
            "UPDATE results SET per_context_json = '{oops' WHERE submission_id = $1",
            "per_context_json",
        ),
    ] {
        let restore: (String, String, String) = on_db!(store.db(), pool => sqlx::query_as(
            "SELECT s.task, s.status, r.per_context_json FROM submissions s JOIN results r ON r.submission_id = s.id WHERE s.id = $1",
        )
        .bind(sub)
        .fetch_one(pool)
        .await
        .unwrap());
        on_db!(store.db(), pool => sqlx::query(sql)
            .bind(sub)
            .execute(pool)
            .await
            .map(|_| ())
            .unwrap());
        let e = match column {
            "per_context_json" => store.result_for(sub).await.unwrap_err(),
            _ => store.submission(sub).await.unwrap_err(),
        };
        assert!(e.to_string().contains(column), "{column}: {e}");
        if column == "task" {
            let e = store.board_rows().await.unwrap_err();
            assert!(e.to_string().contains("juggling"), "{e}");
        }
        on_db!(store.db(), pool => {
            sqlx::query("UPDATE submissions SET task = $1, status = $2 WHERE id = $3")
                .bind(&restore.0)
                .bind(&restore.1)
                .bind(sub)
                .execute(pool)
                .await
                .unwrap();
            sqlx::query("UPDATE results SET per_context_json = $1 WHERE submission_id = $2")
                .bind(&restore.2)
                .bind(sub)
                .execute(pool)
                .await
                .unwrap();
        });
        store.submission(sub).await.unwrap();
    }
}

/// A failed submission's file release waits while another request places
/// the same file and records its submission, then sees the new reference and
/// keeps the file (the release used to count references while the new
/// submission was not recorded yet, and delete its file).
async fn releasing_a_file_waits_for_an_upload_being_recorded(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let sha = "ab".repeat(32);
    let tmp = store.policies_dir().join("upload.onnx.tmp1-0");
    std::fs::write(&tmp, b"model").unwrap();
    let files = store.lock_policy_files().await.unwrap();
    let (path, _) = store.commit_onnx(&tmp, &sha).await.unwrap();
    let path_s = path.to_string_lossy().into_owned();
    let release = tokio::spawn({
        let store = store.clone();
        let p = path_s.clone();
        async move { store.release_policy_file(&p).await.unwrap() }
    });
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    assert!(!release.is_finished(), "the release did not wait");
    assert!(path.exists());
    let m = store
        .ensure_method(
            &NewMethod {
                name: "M".into(),
                ..Default::default()
            },
            None,
        )
        .await
        .unwrap();
    store
        .create_submission(
            &NewSubmission {
                method_id: m.id,
                submitter_id: None,
                task: TaskId::Aligning,
                obs_type: ObsType::State,
                training_seed: 0,
                data_fraction: 1.0,
                protocol: ProtocolKind::Paper,
                policy: NewPolicy::Onnx {
                    sha256: sha.clone(),
                    bytes: 5,
                    path: path.clone(),
                },
                manifest_json: "{}".into(),
                simulated_once: None,
            },
            3,
        )
        .await
        .unwrap();
    drop(files);
    assert!(
        !release.await.unwrap(),
        "a live submission's file was released"
    );
    assert!(path.exists());
}

/// Front ends on one PostgreSQL database share the policy directory: a
/// release on one waits while another places a file and records its
/// submission (an advisory lock every front end takes), and the lock goes
/// with the guard.
#[tokio::test]
async fn a_release_on_another_front_end_waits_for_an_upload_being_recorded() {
    let db = TestDb::new(Backend::Postgres);
    let (one, two) = (db.open().await, db.open().await);
    let path = one.policies_dir().join(format!("{}.onnx", "cd".repeat(32)));
    std::fs::write(&path, b"model").unwrap();
    let files = one.lock_policy_files().await.unwrap();
    let release = tokio::spawn({
        let p = path.to_string_lossy().into_owned();
        async move { two.release_policy_file(&p).await.unwrap() }
    });
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    assert!(!release.is_finished(), "the other front end did not wait");
    assert!(path.exists());
    drop(files);
    // No submission uses the file: once the lock is gone it is deleted.
    assert!(release.await.unwrap());
    assert!(!path.exists());
}

/// At start, a temporary upload whose writer (a process of this machine) has
/// ended is removed at once, on PostgreSQL too, where the directory is shared
/// and a temporary upload of unknown origin is debris only after an hour; one
/// whose writer runs is kept there; a policy file no submission refers to is
/// removed at once (files are placed and their submissions recorded under
/// the lock the clean-up holds). A front end killed mid-upload left both
/// behind for an hour before (found by `d3il bench chaos`).
async fn a_killed_writers_debris_is_removed_at_start(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let live = store.new_upload_path();
    std::fs::write(&live, b"being written").unwrap();
    // The same name with the pid of a process that has ended.
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let gone = child.id();
    child.wait().unwrap();
    let name = live
        .file_name()
        .unwrap()
        .to_string_lossy()
        .replace(&format!("-{}-", std::process::id()), &format!("-{gone}-"));
    let abandoned = live.with_file_name(name);
    assert_ne!(abandoned, live);
    std::fs::write(&abandoned, b"half an upload").unwrap();
    let orphan = store
        .policies_dir()
        .join(format!("{}.onnx", "e".repeat(64)));
    std::fs::write(&orphan, b"nobody's file").unwrap();
    store.clean_policy_files().await.unwrap();
    assert!(!abandoned.exists(), "{}", abandoned.display());
    assert!(!orphan.exists(), "{}", orphan.display());
    // SQLite: the one server owns the directory, so at its start every
    // temporary upload is debris.
    assert_eq!(live.exists(), matches!(b, Backend::Postgres));
}

/// The stored result reads back as the worker made it (Store::eval_result),
/// equal to it but for nothing (difference_except_timings); a result that
/// differs in its measured inference time only is the same evaluation, one
/// that differs in a rollout is not, and the difference names the rollout.
/// What `d3il bench chaos` compares with a plain `d3il eval`.
async fn a_stored_result_reads_back_bit_for_bit(b: Backend) {
    let db = TestDb::new(b);
    let store = db.open().await;
    let (sub, job) = submit(&store, "Stored", TaskId::Pushing, 0).await;
    store.claim_job("w0", 60).await.unwrap().unwrap();
    let r = d3il_test_support::pushing_result(ProtocolKind::Paper, |c, i| {
        d3il_test_support::SynthRollout {
            success: (c + i) % 3 != 0,
            label: (c * 7 + i) % 4,
            unstable: c == 2 && i == 5,
        }
    });
    store.complete_job(job, sub, &r, &[]).await.unwrap();
    let back = store.eval_result(sub).await.unwrap().expect("stored");
    assert_eq!(back.difference_except_timings(&r), None);
    assert_eq!(back, r);
    let mut timed = r.clone();
    timed.metrics.inference_ms += 1.5;
    assert_eq!(back.difference_except_timings(&timed), None);
    let mut other = r.clone();
    other.rollouts[17].steps += 1;
    let d = back
        .difference_except_timings(&other)
        .expect("a difference");
    assert!(d.starts_with("rollout 1 of initial state 1:"), "{d}");
    assert_eq!(store.eval_result(sub + 1000).await.unwrap(), None);
}

d3il_test_support::on_both_backends!(
    paper_rows_load_once_and_match_the_embedded_cells,
    evaluated_rows_aggregate_over_seeds_with_sample_std,
    image_rows_keep_the_robot_look_their_manifests_record,
    duplicate_seed_is_refused_and_stacking_expands,
    stacking_results_stored_before_the_levels_share_one_entropy,
    avoiding_paths_come_back_with_behaviours,
    leases_expire_retries_are_bounded_and_restart_requeues,
    a_slot_that_lost_its_lease_cannot_requeue_or_fail_the_job,
    sibling_seeds_lists_the_rows_seeds_with_their_success,
    bad_stored_data_fails_to_decode_naming_the_column,
    releasing_a_file_waits_for_an_upload_being_recorded,
    a_killed_writers_debris_is_removed_at_start,
    a_stored_result_reads_back_bit_for_bit
);
