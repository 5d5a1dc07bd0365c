//! Hostile ONNX submissions through the real `d3il worker` (real sandbox, real
//! tract, real MuJoCo), supervised by `d3il_sandbox::run_worker` (issue 6).
//! Fixtures: assets/fixtures/hostile_*.onnx from scripts/make_fixtures.py, copied
//! to a scratch directory as an uploaded file would be.

use crate::worker_common;

use d3il_protocol::{ErrorKind, Limits, PolicyManifest};
use d3il_sandbox::Outcome;
use std::time::Duration;
use worker_common::*;

const WALL: Duration = Duration::from_secs(600);

fn manifest(name: &str) -> PolicyManifest {
    let text = std::fs::read_to_string(fixtures_dir().join(name)).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// Run fixture `stem` (.onnx + .json) with `limits`; returns the run.
fn run_fixture(stem: &str, limits: Limits) -> (d3il_sandbox::WorkerRun, Vec<(usize, usize)>) {
    let dir = scratch(stem);
    let onnx = fixture_copy(&dir, &format!("{stem}.onnx"));
    let mut job = avoiding_job(onnx_policy(&onnx), limits);
    job.manifest = manifest(&format!("{stem}.json"));
    let r = run(&job, WALL);
    std::fs::remove_dir_all(&dir).unwrap();
    r
}

fn expect(stem: &str, limits: Limits, kind: ErrorKind) -> String {
    let (r, _) = run_fixture(stem, limits);
    let e = failure(&r);
    assert_eq!(e.kind, kind, "{stem}: {e:?}\nstderr:\n{}", r.stderr);
    e.message.clone()
}

#[test]
fn a_good_onnx_policy_completes_inside_the_sandbox() {
    let (r, seen) = run_fixture("avoiding_path", limits());
    match &r.outcome {
        Outcome::Completed(res) => {
            // The numbers are the evaluator's business (issue 5); here: it ran
            // to the end inside the sandbox, on the file it was given.
            assert!(!res.rollouts.is_empty());
            assert_eq!(
                res.manifest.policy_sha256,
                sha256_file(&fixtures_dir().join("avoiding_path.onnx"))
            );
        }
        other => panic!("{other:?}\n{}", r.stderr),
    }
    assert!(!seen.is_empty(), "progress was reported");
    assert!(r.mechanisms.iter().all(|m| m.active), "{:?}", r.mechanisms);
}

#[test]
fn a_truncated_onnx_file_is_a_bad_model() {
    let m = expect("hostile_truncated", limits(), ErrorKind::BadModel);
    assert!(
        m.starts_with("the ONNX file could not be parsed: ")
            && m.ends_with("upload the .onnx file exported by torch.onnx.export (not a checkpoint, archive or truncated copy)"),
        "{m}"
    );
}

#[test]
fn a_garbage_onnx_file_is_a_bad_model() {
    let m = expect("hostile_garbage", limits(), ErrorKind::BadModel);
    assert!(
        m.starts_with("the ONNX file could not be parsed: ")
            && m.ends_with("upload the .onnx file exported by torch.onnx.export (not a checkpoint, archive or truncated copy)"),
        "{m}"
    );
}

#[test]
fn initializers_declaring_tens_of_gib_are_refused_before_anything_is_allocated() {
    // 100000 x 100000 float32 declared, 16 bytes present: refused by the
    // pre-check of every tensor's declared size against its data, before
    // tract would allocate it.
    let m = expect("hostile_huge_initializer", limits(), ErrorKind::BadModel);
    assert_eq!(
        m,
        "the ONNX file could not be parsed: initializer `huge_weight` declares shape 100000x100000 (37.3 GiB) but holds 16 bytes; \
upload the .onnx file exported by torch.onnx.export (not a checkpoint, archive or truncated copy)"
    );
    // With a small memory limit too: the refusal comes first, so the outcome
    // does not depend on how much memory the worker may use.
    let m = expect(
        "hostile_huge_initializer",
        Limits {
            memory_bytes: 1 << 30,
            ..limits()
        },
        ErrorKind::BadModel,
    );
    assert!(m.contains("declares shape 100000x100000 (37.3 GiB)"), "{m}");
}

const EXTERNAL_DATA_REFUSED: &str = "the ONNX model is not supported: initializer `huge_weight` keeps its data in an external file; \
export with all weights embedded in the .onnx file (torch.onnx.export does this below 2 GB)";

#[test]
fn external_data_outside_the_policy_file_cannot_be_read() {
    let dir = scratch("external");
    let onnx = fixture_copy(&dir, "hostile_external_data.onnx");
    // The 40 GB external file really exists next to the model (sparse): it is
    // never opened, external data is refused outright.
    let f = std::fs::File::create(dir.join("huge_weight.bin")).unwrap();
    f.set_len(40_000_000_000).unwrap();
    drop(f);
    let mut job = avoiding_job(onnx_policy(&onnx), limits());
    job.manifest = manifest("hostile_external_data.json");
    let (r, _) = run(&job, WALL);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::BadModel, "{e:?}\n{}", r.stderr);
    assert_eq!(e.message, EXTERNAL_DATA_REFUSED);

    // The same model pointing its external data at a host file (same length
    // string, patched in place): refused the same way.
    let bytes = std::fs::read(&onnx).unwrap();
    let patched = replace_bytes(&bytes, b"huge_weight.bin", b"../../etc/hosts");
    let evil = dir.join("evil.onnx");
    std::fs::write(&evil, patched).unwrap();
    let mut job = avoiding_job(onnx_policy(&evil), limits());
    job.manifest = manifest("hostile_external_data.json");
    let (r, _) = run(&job, WALL);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::BadModel, "{e:?}\n{}", r.stderr);
    assert_eq!(e.message, EXTERNAL_DATA_REFUSED);
    std::fs::remove_dir_all(&dir).unwrap();
}

fn replace_bytes(hay: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    assert_eq!(from.len(), to.len());
    let i = hay
        .windows(from.len())
        .position(|w| w == from)
        .expect("pattern in fixture");
    let mut out = hay.to_vec();
    out[i..i + to.len()].copy_from_slice(to);
    out
}

#[test]
fn a_graph_that_takes_forever_hits_the_cpu_limit_in_its_first_query() {
    let l = Limits {
        cpu_seconds: 5,
        ..limits()
    };
    let (r, seen) = run_fixture("hostile_endless", l);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::CpuLimit, "{e:?}\n{}", r.stderr);
    // Loaded fine (progress 0 of 8 was reported), then the first query never
    // finished.
    assert_eq!(seen, vec![(0, 8)]);
    assert_eq!(
        e.message,
        "used up the 5 s CPU-time limit while running the rollouts (0 of 8 done); make inference cheaper or ask for a higher limit"
    );
}

#[test]
fn a_graph_that_takes_forever_is_stopped_by_the_wall_clock_too() {
    let dir = scratch("endless-wall");
    let onnx = fixture_copy(&dir, "hostile_endless.onnx");
    let mut job = avoiding_job(onnx_policy(&onnx), limits());
    job.manifest = manifest("hostile_endless.json");
    let mut cmd = d3il_sandbox::WorkerCommand::for_job(d3il(), &job);
    // Far below the 3600 s CPU limit: the wall clock ends it.
    cmd.wall_clock = Duration::from_secs(5);
    let (r, _) = run_cmd(&cmd, &job);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::WallClock, "{e:?}\n{}", r.stderr);
    assert_eq!(
        e.message,
        "the evaluation did not finish within the 5 s wall-clock limit while running the rollouts (0 of 8 done); make the policy faster or ask for a higher limit"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_tile_memory_bomb_is_a_memory_limit_error() {
    // One Tile node asks for a 4 TiB tensor at run time; tract asserts its
    // allocation succeeded, the worker catches the panic and reports the
    // memory limit (issue 17 item 7), not a bad action.
    let l = Limits {
        memory_bytes: 1 << 30,
        ..limits()
    };
    let (r, seen) = run_fixture("hostile_tile_bomb", l);
    let e = failure(&r);
    assert_eq!(e.kind, ErrorKind::MemoryLimit, "{e:?}\n{}", r.stderr);
    assert_eq!(seen, vec![(0, 8)], "it loaded, then the first query failed");
    assert!(
        e.message.starts_with(
            "the ONNX runtime ran out of memory in the query of rollout 0 at step 0 (failed to allocate"
        ) && e.message.ends_with(
            "the model needs more memory than the worker's memory limit allows: make its tensors smaller or ask for a higher limit"
        ),
        "{}",
        e.message
    );
}

#[test]
fn nan_actions_are_a_bad_action() {
    let m = expect("hostile_nan", limits(), ErrorKind::BadAction);
    assert_eq!(
        m,
        "policy returned a non-finite action (NaN) for rollout 0 at step 0 (action 0 of the chunk, component 0); actions must be finite numbers"
    );
}

#[test]
fn wrong_shapes_are_refused_at_load_time() {
    let m = expect("hostile_wrong_act_dim", limits(), ErrorKind::BadModel);
    assert_eq!(
        m,
        "output `actions` has last dimension 3 but task avoiding expects 2 (xy delta of the desired position)"
    );
    let m = expect("hostile_wrong_obs_dim", limits(), ErrorKind::BadModel);
    assert_eq!(
        m,
        "input `obs` has last dimension 3 but task avoiding expects 4 (previous command xy + observation xy)"
    );
}

#[test]
fn irreproducible_graphs_are_refused_with_the_fix() {
    // Its own random generator: results would differ run to run.
    let m = expect("hostile_random_op", limits(), ErrorKind::BadModel);
    assert!(
        m.contains("is a RandomNormalLike operator") && m.contains("`noise` input"),
        "{m}"
    );
    // Batch statistics: a row's actions would depend on its company.
    let m = expect("hostile_mixes_rows", limits(), ErrorKind::BadModel);
    assert!(
        m.contains("the graph mixes the rows of the batch") && m.contains("model.eval()"),
        "{m}"
    );
}
