//! Issue 50: the zoo (the paper's methods trained here on our own
//! demonstrations) is on the board from the first start: each cell a
//! finished submission of the `zoo` submitter, marked with its data source,
//! linked to its provenance, never ranked with the paper's rows; a restart
//! does not duplicate it, a tampered cell is skipped, and a row made by
//! another build than this one says so.
//!
//! The fixture cell (tests/fixtures/zoo/avoiding/bc-mlp-s0) is a real
//! `d3il eval --protocol paper --json` of assets/fixtures/avoiding_path.onnx
//! with a provenance record written by hand.

use d3il_test_support::server::*;
use serde_json::Value;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

const SOURCE: &str = "trained here on d3il demos v1";
const CELL: &str = "avoiding/bc-mlp-s0";

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zoo")
}

/// A copy of the fixture zoo to edit.
fn zoo_copy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("temp dir");
    let cell = dir.path().join(CELL);
    std::fs::create_dir_all(&cell).unwrap();
    for e in std::fs::read_dir(fixture().join(CELL)).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, cell.join(p.file_name().unwrap())).unwrap();
    }
    dir
}

fn sha256(path: &Path) -> String {
    hex::encode(Sha256::digest(std::fs::read(path).unwrap()))
}

/// Rewrites the copy's result document with `edit` and its provenance's
/// hash of it (a cell regenerated, not tampered with).
fn regenerate_result(zoo: &Path, edit: impl FnOnce(&mut Value)) {
    let cell = zoo.join(CELL);
    let rpath = cell.join("result.json");
    let mut r: Value = serde_json::from_slice(&std::fs::read(&rpath).unwrap()).unwrap();
    edit(&mut r);
    std::fs::write(&rpath, serde_json::to_vec_pretty(&r).unwrap()).unwrap();
    let ppath = cell.join("provenance.json");
    let mut p: Value = serde_json::from_slice(&std::fs::read(&ppath).unwrap()).unwrap();
    p["sha256"]["result"] = Value::from(sha256(&rpath));
    std::fs::write(&ppath, serde_json::to_vec_pretty(&p).unwrap()).unwrap();
}

/// The recorded physics fingerprint of the fixture's result.
fn recorded_fingerprint() -> String {
    let r: Value =
        serde_json::from_slice(&std::fs::read(fixture().join(CELL).join("result.json")).unwrap())
            .unwrap();
    r["manifest"]["build"]["physics_fingerprint"]
        .as_str()
        .expect("the fixture's result records its build")
        .to_string()
}

async fn zoo_app(zoo: &Path, db: Option<PathBuf>, fingerprint: Option<&str>) -> TestServer {
    spawn_app_with(Options {
        zoo: Some(zoo.to_path_buf()),
        db,
        canary_fingerprint: fingerprint.map(str::to_string),
        ..Options::default()
    })
    .await
}

/// The board's rows of the zoo on Avoiding (API).
async fn zoo_rows(app: &TestServer) -> Vec<Value> {
    let (s, board) = app.get_json("/api/v1/leaderboards/avoiding").await;
    assert_eq!(s, 200, "{board}");
    board["rows"]
        .as_array()
        .expect("rows")
        .iter()
        .filter(|r| !r["data_source"].is_null())
        .cloned()
        .collect()
}

#[tokio::test]
async fn a_fresh_server_shows_the_zoo_marked_with_its_provenance_and_a_restart_does_not_duplicate()
{
    let zoo = zoo_copy();
    let dbdir = tempfile::tempdir().unwrap();
    let db = dbdir.path().join("lb.sqlite");
    let app = zoo_app(zoo.path(), Some(db.clone()), None).await;

    let rows = zoo_rows(&app).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    let row = &rows[0];
    assert_eq!(row["data_source"], SOURCE);
    assert_eq!(row["method"], "BC-MLP");
    assert_eq!(row["source"], "evaluated");
    assert_eq!(row["n_seeds"], 1);
    let id = row["submission_ids"][0].as_i64().expect("a submission");

    // A finished submission of the built-in submitter, with its data source.
    let (s, sub) = app.get_json(&format!("/api/v1/submissions/{id}")).await;
    assert_eq!(s, 200, "{sub}");
    assert_eq!(sub["status"], "completed", "{sub}");
    assert_eq!(sub["data_source"], SOURCE, "{sub}");
    let stored = app.state().store.submission(id).await.unwrap();
    assert_eq!(stored.submitter.as_deref(), Some("zoo"));
    assert_eq!(stored.data_source.as_deref(), Some(SOURCE));
    // Its ONNX is in the policy store.
    let onnx = std::path::PathBuf::from(stored.onnx_path.expect("an ONNX path"));
    assert!(
        onnx.starts_with(app.state().store.policies_dir()),
        "{onnx:?}"
    );
    assert_eq!(
        sha256(&onnx),
        sha256(&fixture().join(CELL).join("policy.onnx"))
    );

    // The task board: a group of its own, the mark and the provenance link.
    let (s, page) = app.get_text("/tasks/avoiding").await;
    assert_eq!(s, 200);
    assert!(page.contains("data-group=\"zoo\""), "the zoo's own table");
    assert!(page.contains("class=\"badge badge-zoo\""), "the mark");
    assert!(page.contains(SOURCE));
    assert!(
        page.contains(&format!("href=\"/submissions/{id}/provenance\"")),
        "the provenance link"
    );
    assert!(page.contains("Trained here on d3il demos v1: the zoo"));
    assert!(
        !page.contains("badge-drift"),
        "no drift without this build's fingerprint"
    );

    // The home page says where the zoo is (not in the paper's table).
    let (s, page) = app.get_text("/").await;
    assert_eq!(s, 200);
    assert!(page.contains("zoo-note") && page.contains(SOURCE), "{page}");
    assert!(page.contains("href=\"/tasks/avoiding?obs=state\">Avoiding (T1)</a> (1 row)"));

    // The method page shows it, marked.
    let (s, page) = app.get_text("/methods/BC-MLP").await;
    assert_eq!(s, 200);
    assert!(
        page.contains("badge-zoo") && page.contains(SOURCE),
        "{page}"
    );

    // The provenance, as a page and as JSON.
    let (s, page) = app.get_text(&format!("/submissions/{id}/provenance")).await;
    assert_eq!(s, 200, "{page}");
    assert!(
        page.contains("zoo_version") && page.contains(CELL),
        "{page}"
    );
    let (s, prov) = app
        .get_json(&format!("/api/v1/submissions/{id}/provenance"))
        .await;
    assert_eq!(s, 200, "{prov}");
    assert_eq!(prov["cell"], CELL);
    assert_eq!(prov["data_source"], SOURCE);
    assert_eq!(prov["provenance"]["zoo_version"], "v1");
    assert_eq!(prov["provenance"]["reference"]["repo"], "ALRhub/d3il");
    assert!(prov["drift"].is_null(), "{prov}");
    // A submitted policy has none.
    let (s, _) = app.get_json("/api/v1/submissions/999999/provenance").await;
    assert_eq!(s, 404);

    // Its result page and rollouts work as any evaluation's.
    let (s, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert_eq!(s, 200);
    assert!(
        page.contains("id=\"data-source\""),
        "the submission page says so"
    );
    let (s, list) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts"))
        .await;
    assert_eq!(s, 200, "{list}");
    let (s, one) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/0"))
        .await;
    assert_eq!(s, 200, "{one}");

    // Never in the paper's tables: the result cells leave it out.
    let cells = app.state().store.result_cells(None).await.unwrap();
    assert!(
        cells
            .iter()
            .all(|c| !(c.method == "BC-MLP" && c.source == d3il_protocol::Source::Evaluated)),
        "the zoo is not mixed into the paper's tables"
    );
    drop(app);

    // A restart on the same database: the same one submission.
    let again = zoo_app(zoo.path(), Some(db.clone()), None).await;
    let rows = zoo_rows(&again).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["submission_ids"], serde_json::json!([id]));
    let zoo_subs = again
        .state()
        .store
        .list_submissions(
            &d3il_server::store::SubmissionFilter {
                submitter: Some("zoo".into()),
                ..Default::default()
            },
            100,
        )
        .await
        .unwrap();
    assert_eq!(zoo_subs.len(), 1);
    drop(again);

    // A regenerated cell (new result document) replaces the old result in
    // the same submission.
    regenerate_result(zoo.path(), |r| {
        r["metrics"]["success_rate"]["value"] = Value::from(0.25)
    });
    // A video cached from the old result goes; another submission's stays.
    let videos = d3il_server::store::sqlite_data_dir(&db).join("videos");
    std::fs::create_dir_all(&videos).unwrap();
    let (old, other) = (
        videos.join(format!("{id}-3-0.4.0-abc.mp4")),
        videos.join(format!("{}-3-0.4.0-abc.mp4", id + 1000)),
    );
    std::fs::write(&old, b"old").unwrap();
    std::fs::write(&other, b"other").unwrap();
    let third = zoo_app(zoo.path(), Some(db), None).await;
    assert!(!old.exists(), "the old result's video is gone");
    assert!(other.exists());
    let rows = zoo_rows(&third).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["submission_ids"], serde_json::json!([id]));
    assert_eq!(rows[0]["success"]["mean"], 0.25);
}

#[tokio::test]
async fn a_tampered_cell_is_skipped_and_the_start_goes_on() {
    let zoo = zoo_copy();
    let onnx = zoo.path().join(CELL).join("policy.onnx");
    let mut bytes = std::fs::read(&onnx).unwrap();
    bytes.push(0);
    std::fs::write(&onnx, bytes).unwrap();

    // What the start logs: the cell, the file and why.
    let dir = tempfile::tempdir().unwrap();
    let store = d3il_server::store::Store::open(&dir.path().join("s.sqlite"))
        .await
        .unwrap();
    let report = d3il_server::zoo::load(&store, zoo.path()).await.unwrap();
    assert!(report.loaded.is_empty(), "{report:?}");
    assert_eq!(report.skipped.len(), 1, "{report:?}");
    let why = &report.skipped[0].1;
    assert!(
        why.contains("policy.onnx") && why.contains("provenance.json lists"),
        "{why}"
    );

    // The server starts and shows no zoo row.
    let app = zoo_app(zoo.path(), None, None).await;
    assert!(zoo_rows(&app).await.is_empty());
    let (s, page) = app.get_text("/tasks/avoiding").await;
    assert_eq!(s, 200);
    assert!(!page.contains("badge-zoo"));
}

#[tokio::test]
async fn a_zoo_row_of_another_build_says_so() {
    let recorded = recorded_fingerprint();
    let zoo = zoo_copy();

    // This build is the one that made the result: no drift.
    let app = zoo_app(zoo.path(), None, Some(&recorded)).await;
    let (_, page) = app.get_text("/tasks/avoiding").await;
    assert!(page.contains("badge-zoo"));
    assert!(!page.contains("badge-drift"), "same build, no drift");
    drop(app);

    // Another build: the row, its method page and its provenance say so.
    let other = "0123456789abcdef";
    assert_ne!(other, recorded);
    let app = zoo_app(zoo.path(), None, Some(other)).await;
    let (_, page) = app.get_text("/tasks/avoiding").await;
    assert!(page.contains("badge-drift"), "the drift mark");
    // (askama escapes the apostrophe of "build's")
    let named = format!("other build: physics fingerprint {recorded}, this build");
    assert!(
        page.contains(&named) && page.contains(&format!("s is {other}")),
        "the row names both fingerprints"
    );
    let (_, page) = app.get_text("/methods/BC-MLP").await;
    assert!(page.contains("badge-drift"));
    let id = zoo_rows(&app).await[0]["submission_ids"][0]
        .as_i64()
        .unwrap();
    let (_, prov) = app
        .get_json(&format!("/api/v1/submissions/{id}/provenance"))
        .await;
    assert_eq!(prov["physics_fingerprint"], recorded.as_str());
    assert_eq!(prov["this_build"], other);
    assert!(
        prov["drift"].as_str().unwrap_or("").contains(&recorded),
        "{prov}"
    );
    drop(app);

    // The copy's result edited to this build's fingerprint: no drift.
    regenerate_result(zoo.path(), |r| {
        r["manifest"]["build"]["physics_fingerprint"] = Value::from(other)
    });
    let app = zoo_app(zoo.path(), None, Some(other)).await;
    let (_, page) = app.get_text("/tasks/avoiding").await;
    assert!(page.contains("badge-zoo"));
    assert!(!page.contains("badge-drift"));
}

/// The store's side on both backends: a second load changes nothing, and
/// the zoo's seed does not block a submitter's own seed of the same method.
async fn loading_is_idempotent_and_apart_from_submitted_seeds(b: Backend) {
    use d3il_protocol::{ObsType, ProtocolKind, TaskId};
    use d3il_server::store::{NewPolicy, NewSubmission, ZooLoad};
    let db = TestDb::new(b);
    let store = db.open().await;
    let first = d3il_server::zoo::load(&store, &fixture()).await.unwrap();
    let id = match first.loaded.as_slice() {
        [(cell, ZooLoad::Inserted(id))] if cell == CELL => *id,
        other => panic!("{other:?}"),
    };
    let again = db.open().await;
    let second = d3il_server::zoo::load(&again, &fixture()).await.unwrap();
    assert_eq!(
        second.loaded,
        vec![(CELL.to_string(), ZooLoad::Unchanged(id))]
    );
    let stored = again.eval_result(id).await.unwrap().expect("the result");
    assert_eq!(stored.rollouts.len(), 2);
    assert_eq!(again.zoo_cells().await.unwrap().len(), 1);

    let m = again.method_by_name("BC-MLP").await.unwrap().unwrap();
    let mine = again
        .create_submission(
            &NewSubmission {
                method_id: m.id,
                submitter_id: None,
                task: TaskId::Avoiding,
                obs_type: ObsType::State,
                training_seed: 0,
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
        .await
        .expect("a submitter's BC-MLP seed 0 beside the zoo's");
    assert_ne!(mine, id);
    // Each row's seeds are its own source's.
    let zoo_sub = again.submission(id).await.unwrap();
    let seeds = again.sibling_seeds(&zoo_sub).await.unwrap();
    assert_eq!(seeds.iter().map(|s| s.id).collect::<Vec<_>>(), vec![id]);
}

on_both_backends!(loading_is_idempotent_and_apart_from_submitted_seeds);

/// A cell the training command is still writing (`.<dir>.tmp`, or a record
/// saying `"complete": false`) is not loaded.
#[test]
fn cells_being_written_are_not_loaded() {
    let zoo = zoo_copy();
    let tmp = zoo.path().join("avoiding/.bc-mlp-s1.tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    for e in std::fs::read_dir(zoo.path().join(CELL)).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, tmp.join(p.file_name().unwrap())).unwrap();
    }
    assert_eq!(
        d3il_server::zoo::cell_dirs(zoo.path()),
        vec![zoo.path().join(CELL)]
    );
    let ppath = zoo.path().join(CELL).join("provenance.json");
    let mut p: Value = serde_json::from_slice(&std::fs::read(&ppath).unwrap()).unwrap();
    p["complete"] = Value::from(false);
    std::fs::write(&ppath, serde_json::to_vec(&p).unwrap()).unwrap();
    let e = d3il_server::zoo::read_cell(&zoo.path().join(CELL)).unwrap_err();
    assert!(e.to_string().contains("not complete"), "{e}");
}

/// A cell with a robustness document (`scripts/zoo/suites.py`) is on its
/// task's Robustness view, named apart from submitted methods, linked to
/// the method's page.
#[tokio::test]
async fn a_cells_robustness_document_is_on_the_robustness_view() {
    let zoo = zoo_copy();
    let app = zoo_app(zoo.path(), None, None).await;
    let (s, page) = app.get_text("/tasks/avoiding/robustness").await;
    assert_eq!(s, 200);
    assert!(page.contains("BC-MLP (zoo)"), "{page}");
    assert!(page.contains("href=\"/methods/BC-MLP\""), "{page}");
    // Every method link of the view (the methods table and the per-seed
    // one) opens a method page: a zoo row is labelled `METHOD (zoo)` but
    // its method is the paper's.
    let links: std::collections::BTreeSet<&str> = page
        .split("href=\"/methods/")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .collect();
    assert!(!links.is_empty(), "{page}");
    for link in links {
        let (s, _) = app.get_text(&format!("/methods/{link}")).await;
        assert_eq!(s, 200, "/methods/{link} from the robustness view");
    }
    let id = zoo_rows(&app).await[0]["submission_ids"][0]
        .as_i64()
        .unwrap();
    let (s, doc) = app
        .get_json(&format!(
            "/api/v1/submissions/{id}/robustness?rollouts=false"
        ))
        .await;
    assert_eq!(s, 200);
    assert_eq!(doc["task"], "avoiding");
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert!(page.contains("id=\"robustness\""), "the page links it");
    // Queue ETAs are made from this server's own runs only.
    assert!(app
        .state()
        .store
        .mean_job_seconds_by_kind()
        .await
        .unwrap()
        .is_empty());
}

/// Issue 52: a withdrawn submission leaves the Robustness view and the
/// rows `d3il tables` draws its robustness tables from, as it leaves every
/// other public list (the one rule: `store::PUBLIC`); reinstated, it is back.
#[tokio::test]
async fn a_withdrawn_submission_leaves_the_robustness_view_and_its_tables() {
    let zoo = zoo_copy();
    let app = zoo_app(zoo.path(), None, None).await;
    let store = &app.state().store;
    let id = zoo_rows(&app).await[0]["submission_ids"][0]
        .as_i64()
        .unwrap();
    assert_eq!(store.robustness_rows(None).await.unwrap().len(), 1);
    store
        .withdraw_submission(id, "test: hidden", "op")
        .await
        .unwrap();
    let (s, page) = app.get_text("/tasks/avoiding/robustness").await;
    assert_eq!(s, 200);
    assert!(!page.contains("BC-MLP (zoo)"), "{page}");
    assert!(store.robustness_rows(None).await.unwrap().is_empty());
    assert!(store
        .robustness_rows(Some(d3il_protocol::TaskId::Avoiding))
        .await
        .unwrap()
        .is_empty());
    store.reinstate_submission(id, "op").await.unwrap();
    let (_, page) = app.get_text("/tasks/avoiding/robustness").await;
    assert!(page.contains("BC-MLP (zoo)"), "{page}");
}

/// The suites run after the cell was made (`scripts/zoo/suites.py` adds
/// `robustness.json` and its hash to the provenance): the next start loads
/// the document into the submission already there.
#[tokio::test]
async fn a_robustness_document_run_later_is_loaded_at_the_next_start() {
    let zoo = zoo_copy();
    let cell = zoo.path().join(CELL);
    let (rpath, ppath) = (cell.join("robustness.json"), cell.join("provenance.json"));
    let (doc, full) = (
        std::fs::read(&rpath).unwrap(),
        std::fs::read(&ppath).unwrap(),
    );
    std::fs::remove_file(&rpath).unwrap();
    let mut p: Value = serde_json::from_slice(&full).unwrap();
    p["sha256"].as_object_mut().unwrap().remove("robustness");
    p.as_object_mut().unwrap().remove("robustness");
    std::fs::write(&ppath, serde_json::to_vec_pretty(&p).unwrap()).unwrap();

    let dir = tempfile::tempdir().unwrap();
    let store = d3il_server::store::Store::open(&dir.path().join("s.sqlite"))
        .await
        .unwrap();
    let first = d3il_server::zoo::load(&store, zoo.path()).await.unwrap();
    assert_eq!(first.loaded.len(), 1, "{first:?}");
    assert!(store.robustness_rows(None).await.unwrap().is_empty());

    std::fs::write(&rpath, doc).unwrap();
    std::fs::write(&ppath, full).unwrap();
    let second = d3il_server::zoo::load(&store, zoo.path()).await.unwrap();
    assert!(
        matches!(
            second.loaded.as_slice(),
            [(_, d3il_server::store::ZooLoad::Unchanged(_))]
        ),
        "{second:?}"
    );
    let rows = store.robustness_rows(None).await.unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].method, "BC-MLP (zoo)");
}

/// A cell shipped with its documents gzipped (scripts/zoo/pack.py: the
/// provenance hashes the `.gz` files) loads as the plain one does, robustness
/// document included; a damaged `.gz` whose hash still matches is refused
/// with the file named.
#[tokio::test]
async fn a_cell_with_gzipped_documents_loads_like_a_plain_one() {
    use std::io::Write;
    let zoo = zoo_copy();
    let cell = zoo.path().join(CELL);
    let ppath = cell.join("provenance.json");
    let mut p: Value = serde_json::from_slice(&std::fs::read(&ppath).unwrap()).unwrap();
    for (kind, name) in [("result", "result.json"), ("robustness", "robustness.json")] {
        let plain = cell.join(name);
        if !plain.exists() {
            continue;
        }
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        gz.write_all(&std::fs::read(&plain).unwrap()).unwrap();
        let packed = cell.join(format!("{name}.gz"));
        std::fs::write(&packed, gz.finish().unwrap()).unwrap();
        std::fs::remove_file(&plain).unwrap();
        p["sha256"][kind] = Value::from(sha256(&packed));
    }
    std::fs::write(&ppath, serde_json::to_vec_pretty(&p).unwrap()).unwrap();

    let dir = tempfile::tempdir().unwrap();
    let store = d3il_server::store::Store::open(&dir.path().join("s.sqlite"))
        .await
        .unwrap();
    let report = d3il_server::zoo::load(&store, zoo.path()).await.unwrap();
    assert_eq!(report.loaded.len(), 1, "{report:?}");
    assert!(report.skipped.is_empty(), "{report:?}");
    let app = zoo_app(zoo.path(), None, None).await;
    assert_eq!(zoo_rows(&app).await.len(), 1);

    // Not gzip at all, but listed with its own hash: refused, named.
    let packed = cell.join("result.json.gz");
    std::fs::write(&packed, b"{\"not\": \"gzip\"}").unwrap();
    p["sha256"]["result"] = Value::from(sha256(&packed));
    std::fs::write(&ppath, serde_json::to_vec_pretty(&p).unwrap()).unwrap();
    let store2 = d3il_server::store::Store::open(&dir.path().join("s2.sqlite"))
        .await
        .unwrap();
    let report = d3il_server::zoo::load(&store2, zoo.path()).await.unwrap();
    assert_eq!(report.skipped.len(), 1, "{report:?}");
    let why = &report.skipped[0].1;
    assert!(
        why.contains("result.json.gz") && why.contains("not a gzip file"),
        "{why}"
    );
}
