//! `d3il db restore` and policy paths outside the store: an archive whose
//! database has a submission pointing at a file that is not directly in
//! the backed-up store's policy directory (another directory, or `..` out of
//! it) is refused, naming those submissions and what to fix, and leaves the
//! target empty; once the source is fixed, the new backup restores. Real
//! SQLite files and a real PostgreSQL database, real archives.

use d3il_server::backup;
use d3il_server::store::{sqlx, NewMethod, NewPolicy, NewSubmission, Store};
use d3il_test_support::server::*;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// A queued ONNX submission whose row points at `path` (which the test
/// placed); returns its id.
async fn onnx_submission(store: &Store, seed: i64, path: &Path, sha256: &str) -> i64 {
    let m = store
        .ensure_method(
            &NewMethod {
                name: "Restored".into(),
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
                task: d3il_protocol::TaskId::Aligning,
                obs_type: d3il_protocol::ObsType::State,
                training_seed: seed,
                data_fraction: 1.0,
                protocol: d3il_protocol::ProtocolKind::Quick,
                policy: NewPolicy::Onnx {
                    sha256: sha256.into(),
                    bytes: 64,
                    path: path.to_path_buf(),
                },
                manifest_json: manifest("aligning"),
                simulated_once: None,
            },
            3,
        )
        .await
        .unwrap()
}

/// A policy file's bytes and sha256.
fn policy_bytes(tag: u8) -> (Vec<u8>, String) {
    let bytes = vec![tag; 64];
    let sha = hex::encode(Sha256::digest(&bytes));
    (bytes, sha)
}

/// Whether the target holds any table (restore's own test of "empty").
async fn has_tables(target: &d3il_server::store::DbTarget) -> bool {
    match target {
        d3il_server::store::DbTarget::Sqlite(path) => path.exists(),
        d3il_server::store::DbTarget::Postgres(_) => {
            let db = backup::open_existing(target).await.unwrap();
            let d3il_server::store::Db::Postgres(pool) = db else {
                unreachable!()
            };
            let n: i64 =
                sqlx::query_scalar("SELECT COUNT(*) FROM pg_tables WHERE schemaname = 'public'")
                    .fetch_one(&pool)
                    .await
                    .unwrap();
            n > 0
        }
    }
}

async fn paths_outside_the_store_are_refused(b: Backend) {
    let src = TestDb::new(b);
    let store = src.open().await;
    let policies = store.policies_dir();

    // In the store, as the intake puts it.
    let (bytes, sha_in) = policy_bytes(1);
    let upload = src.dir.path().join("upload.onnx");
    std::fs::write(&upload, &bytes).unwrap();
    let (inside, _) = store.commit_onnx(&upload, &sha_in).await.unwrap();
    let ok_id = onnx_submission(&store, 0, &inside, &sha_in).await;
    // Elsewhere on the host, and `..` out of the policy directory.
    let (bytes, sha_out) = policy_bytes(2);
    let elsewhere = src.dir.path().join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let outside = elsewhere.join("policy.onnx");
    std::fs::write(&outside, &bytes).unwrap();
    let far_id = onnx_submission(&store, 1, &outside, &sha_out).await;
    let dotdot = policies.join("../../elsewhere/policy.onnx");
    let dotdot_id = onnx_submission(&store, 2, &dotdot, &sha_out).await;

    let archive = src.dir.path().join("backup.tar.gz");
    backup::backup(&src.target, Some(&src.policies), &archive)
        .await
        .expect("the backup is taken");

    let dst = TestDb::new(b);
    let e = backup::restore(&archive, &dst.target, Some(&dst.policies), false)
        .await
        .expect_err("the restore is refused")
        .to_string();
    assert!(
        e.contains(&format!(
            "has 2 submission(s) whose policy file is not in the backed-up store's policy directory {}",
            policies.display()
        )),
        "{e}"
    );
    assert!(
        e.contains(&format!("submission {far_id} (`{}`)", outside.display())),
        "{e}"
    );
    assert!(
        e.contains(&format!("submission {dotdot_id} (`{}`)", dotdot.display())),
        "{e}"
    );
    assert!(!e.contains(&format!("submission {ok_id} ")), "{e}");
    assert!(e.contains("nothing was restored"), "{e}");
    assert!(
        e.contains("move each file into") && e.contains("take a new backup"),
        "{e}"
    );
    // Nothing written: no database, no policy file.
    assert!(!has_tables(&dst.target).await, "the target is empty again");
    let placed = std::fs::read_dir(dst.policies.join("policies")).map_or(0, |d| d.count());
    assert_eq!(placed, 0, "no policy file was placed");

    // Fixed as the message says: the file moved into the store and both
    // rows pointed at it. The new backup restores, every row in the new store.
    let home: PathBuf = policies.join(format!("{sha_out}.onnx"));
    std::fs::rename(&outside, &home).unwrap();
    d3il_server::on_db!(store.db(), pool => {
        sqlx::query("UPDATE submissions SET onnx_path = $1 WHERE id = $2 OR id = $3")
            .bind(home.to_string_lossy().into_owned())
            .bind(far_id)
            .bind(dotdot_id)
            .execute(pool)
            .await
            .map(|_| ())
            .unwrap()
    });
    let fixed = src.dir.path().join("fixed.tar.gz");
    backup::backup(&src.target, Some(&src.policies), &fixed)
        .await
        .unwrap();
    let dst = TestDb::new(b);
    backup::restore(&fixed, &dst.target, Some(&dst.policies), false)
        .await
        .expect("the fixed backup restores");
    let restored = dst.open().await;
    for id in [ok_id, far_id, dotdot_id] {
        let s = restored.submission(id).await.unwrap();
        let path = PathBuf::from(s.onnx_path.unwrap());
        assert_eq!(path.parent(), Some(restored.policies_dir().as_path()));
        assert!(path.is_file(), "{}", path.display());
    }
}

on_both_backends!(paths_outside_the_store_are_refused);
