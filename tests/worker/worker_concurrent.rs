//! Hostile ONNX jobs side by side with a good one through the real `d3il worker`:
//! each ends with its own typed outcome, the parent (this process) and the good
//! job carry on, and nothing is left behind — no process in any worker's group,
//! no file in the temp or working directory the workers inherited (issue 6).

use crate::worker_common;

use d3il_protocol::{ErrorKind, Limits, PolicyManifest};
use d3il_sandbox::Outcome;
use std::time::Duration;
use worker_common::*;

#[test]
fn hostile_onnx_jobs_next_to_a_good_one_leave_nothing_behind() {
    let cases: Vec<(&str, Option<ErrorKind>)> = vec![
        ("avoiding_path", None),
        ("hostile_truncated", Some(ErrorKind::BadModel)),
        ("hostile_garbage", Some(ErrorKind::BadModel)),
        ("hostile_nan", Some(ErrorKind::BadAction)),
        ("hostile_endless", Some(ErrorKind::CpuLimit)),
        ("hostile_huge_initializer", Some(ErrorKind::BadModel)),
        ("hostile_wrong_act_dim", Some(ErrorKind::BadModel)),
    ];
    let handles: Vec<_> = cases
        .into_iter()
        .map(|(stem, want)| {
            // One upload directory per job: nothing may appear next to it.
            let uploads = scratch(&format!("upload-{stem}"));
            let onnx = fixture_copy(&uploads, &format!("{stem}.onnx"));
            let manifest: PolicyManifest = serde_json::from_str(
                &std::fs::read_to_string(fixtures_dir().join(format!("{stem}.json"))).unwrap(),
            )
            .unwrap();
            let mut job = avoiding_job(
                onnx_policy(&onnx),
                Limits {
                    cpu_seconds: 10,
                    ..limits()
                },
            );
            job.manifest = manifest;
            std::thread::spawn(move || {
                // Checks the worker's group and the inherited TMPDIR and
                // working directory after each job (worker_common::run).
                let (r, _) = run(&job, Duration::from_secs(600));
                std::fs::remove_dir_all(&uploads).unwrap();
                (stem, want, r)
            })
        })
        .collect();
    for h in handles {
        let (stem, want, r) = h.join().expect("supervising thread panicked");
        match (want, &r.outcome) {
            (None, Outcome::Completed(res)) => assert!(!res.rollouts.is_empty()),
            (Some(kind), Outcome::Failed(e)) => {
                assert_eq!(e.kind, kind, "{stem}: {e:?}\n{}", r.stderr)
            }
            (_, other) => panic!("{stem}: unexpected {other:?}\n{}", r.stderr),
        }
    }
    let files = leftover_files();
    assert!(files.is_empty(), "files left behind: {files:?}");
}
