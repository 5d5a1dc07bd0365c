//! Hostile ONNX jobs side by side with a good one through the real `d3il worker`:
//! each ends with its own typed outcome, the parent (this process) and the good
//! job carry on, and nothing is left behind — no process in any worker's group,
//! no file in the temp or working directory the workers inherited (issue 6).
//!
//! One test in its own binary, because it changes the process-wide TMPDIR and
//! working directory that the workers inherit.

mod worker_common;

use d3il_protocol::{ErrorKind, Limits, PolicyManifest};
use d3il_sandbox::Outcome;
use std::time::Duration;
use worker_common::*;

#[test]
fn hostile_onnx_jobs_next_to_a_good_one_leave_nothing_behind() {
    let base = scratch("concurrent");
    let uploads = base.join("uploads");
    let tmp = base.join("tmp");
    let cwd = base.join("cwd");
    for d in [&uploads, &tmp, &cwd] {
        std::fs::create_dir_all(d).unwrap();
    }
    std::env::set_var("TMPDIR", &tmp);
    std::env::set_current_dir(&cwd).unwrap();

    let cases: Vec<(&str, Option<ErrorKind>)> = vec![
        ("avoiding_path", None),
        ("hostile_truncated", Some(ErrorKind::BadModel)),
        ("hostile_garbage", Some(ErrorKind::BadModel)),
        ("hostile_nan", Some(ErrorKind::BadAction)),
        ("hostile_endless", None),
        ("hostile_huge_initializer", None),
    ];
    let handles: Vec<_> = cases
        .into_iter()
        .map(|(stem, want)| {
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
                let (r, _) = run(&job, Duration::from_secs(600));
                (stem, want, r)
            })
        })
        .collect();
    for h in handles {
        let (stem, want, r) = h.join().expect("supervising thread panicked");
        match (stem, want, &r.outcome) {
            ("avoiding_path", _, Outcome::Completed(res)) => assert!(!res.rollouts.is_empty()),
            // A resource limit, whichever bites first (see worker_onnx.rs).
            ("hostile_endless", _, Outcome::Failed(e)) => assert!(
                matches!(e.kind, ErrorKind::CpuLimit | ErrorKind::MemoryLimit),
                "{e:?}"
            ),
            // Memory limit or refused at load, as in worker_onnx.rs.
            ("hostile_huge_initializer", _, Outcome::Failed(e)) => assert!(
                matches!(e.kind, ErrorKind::MemoryLimit | ErrorKind::BadModel),
                "{e:?}"
            ),
            (_, Some(kind), Outcome::Failed(e)) => {
                assert_eq!(e.kind, kind, "{stem}: {e:?}\n{}", r.stderr)
            }
            (_, _, other) => panic!("{stem}: unexpected {other:?}\n{}", r.stderr),
        }
    }
    let left: Vec<_> = std::fs::read_dir(&tmp)
        .unwrap()
        .chain(std::fs::read_dir(&cwd).unwrap())
        .map(|e| e.unwrap().path())
        .collect();
    assert!(left.is_empty(), "files left behind: {left:?}");
    std::env::set_current_dir(std::env::temp_dir()).unwrap();
    std::fs::remove_dir_all(&base).unwrap();
}
