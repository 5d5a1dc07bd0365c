//! Hostile ONNX submissions through the real `d3il worker` (real sandbox, real
//! tract, real MuJoCo), supervised by `d3il_sandbox::run_worker` (issue 6).
//! Fixtures: assets/fixtures/hostile_*.onnx from scripts/make_fixtures.py, copied
//! to a scratch directory as an uploaded file would be.

mod worker_common;

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
        Outcome::Failed(e) => panic!("{e:?}\n{}", r.stderr),
    }
    assert!(!seen.is_empty(), "progress was reported");
    assert!(r.mechanisms.iter().all(|m| m.active), "{:?}", r.mechanisms);
}

#[test]
fn a_truncated_onnx_file_is_a_bad_model() {
    let m = expect("hostile_truncated", limits(), ErrorKind::BadModel);
    assert!(!m.is_empty());
}

#[test]
fn a_garbage_onnx_file_is_a_bad_model() {
    let m = expect("hostile_garbage", limits(), ErrorKind::BadModel);
    assert!(!m.is_empty());
}

#[test]
fn initializers_declaring_tens_of_gib_hit_the_memory_limit_or_are_refused() {
    let (r, _) = run_fixture("hostile_huge_initializer", limits());
    let e = failure(&r);
    match e.kind {
        ErrorKind::MemoryLimit => assert_eq!(
            e.message,
            "exceeded the 4 GiB memory limit while loading the ONNX file; make the model smaller or ask for a higher limit"
        ),
        // tract may notice that 16 bytes of data cannot fill 40 GB first.
        ErrorKind::BadModel => {}
        other => panic!("{other:?}: {}\n{}", e.message, r.stderr),
    }
}

#[test]
fn external_data_outside_the_policy_file_cannot_be_read() {
    let dir = scratch("external");
    let onnx = fixture_copy(&dir, "hostile_external_data.onnx");
    // The 40 GB external file really exists next to the model (sparse): only
    // the ONNX file itself is readable in the sandbox.
    let f = std::fs::File::create(dir.join("huge_weight.bin")).unwrap();
    f.set_len(40_000_000_000).unwrap();
    drop(f);
    let mut job = avoiding_job(onnx_policy(&onnx), limits());
    job.manifest = manifest("hostile_external_data.json");
    let (r, _) = run(&job, WALL);
    let e = failure(&r);
    assert!(
        matches!(e.kind, ErrorKind::BadModel | ErrorKind::MemoryLimit),
        "{e:?}\n{}",
        r.stderr
    );

    // The same model pointing its external data at a host file (same length
    // string, patched in place): refused as well.
    let bytes = std::fs::read(&onnx).unwrap();
    let patched = replace_bytes(&bytes, b"huge_weight.bin", b"../../etc/hosts");
    let evil = dir.join("evil.onnx");
    std::fs::write(&evil, patched).unwrap();
    let mut job = avoiding_job(onnx_policy(&evil), limits());
    job.manifest = manifest("hostile_external_data.json");
    let (r, _) = run(&job, WALL);
    let e = failure(&r);
    assert!(
        matches!(e.kind, ErrorKind::BadModel | ErrorKind::MemoryLimit),
        "{e:?}\n{}",
        r.stderr
    );
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
fn a_graph_that_takes_forever_hits_a_resource_limit() {
    let l = Limits {
        cpu_seconds: 5,
        ..limits()
    };
    let (r, _) = run_fixture("hostile_endless", l);
    let e = failure(&r);
    match e.kind {
        ErrorKind::CpuLimit => assert!(e.message.contains("5 s CPU-time limit"), "{}", e.message),
        // tract may materialise the 64 x 64 MiB weight matrices at load time.
        ErrorKind::MemoryLimit => {
            assert!(e.message.contains("4 GiB memory limit"), "{}", e.message)
        }
        other => panic!("{other:?}: {}\n{}", e.message, r.stderr),
    }
}

#[test]
fn a_graph_that_takes_forever_is_stopped_by_the_wall_clock_too() {
    let dir = scratch("endless-wall");
    let onnx = fixture_copy(&dir, "hostile_endless.onnx");
    let mut job = avoiding_job(onnx_policy(&onnx), limits());
    job.manifest = manifest("hostile_endless.json");
    let mut cmd = d3il_sandbox::WorkerCommand::for_job(d3il(), &job);
    cmd.wall_clock = Duration::from_secs(5);
    let r = d3il_sandbox::run_worker(&cmd, &job, &mut |_, _| {});
    assert!(group_members(r.pid as i32).is_empty());
    let e = failure(&r);
    // Whichever comes first within 5 s: the wall clock, or the memory limit
    // if tract materialises the weights at load time.
    match e.kind {
        ErrorKind::WallClock => {
            assert!(e.message.contains("5 s wall-clock limit"), "{}", e.message)
        }
        ErrorKind::MemoryLimit => {}
        other => panic!("{other:?}: {}", e.message),
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn nan_actions_are_a_bad_action() {
    let m = expect("hostile_nan", limits(), ErrorKind::BadAction);
    assert!(!m.is_empty());
}

#[test]
fn wrong_shapes_are_refused() {
    for stem in ["hostile_wrong_act_dim", "hostile_wrong_obs_dim"] {
        let (r, _) = run_fixture(stem, limits());
        let e = failure(&r);
        assert!(
            matches!(e.kind, ErrorKind::BadModel | ErrorKind::BadAction),
            "{stem}: {e:?}\n{}",
            r.stderr
        );
    }
}
