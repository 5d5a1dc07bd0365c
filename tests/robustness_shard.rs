//! The robustness track's cost and records on the command line (issue 40):
//! `d3il eval --suite robustness --shard K/N` parts (one of them run in the
//! sandboxed worker) merged by `d3il merge` give the unsharded document bit
//! for bit (but for the measured inference time), a fractional latency applies the blend of the two late actions,
//! and a perturbed rollout of every axis gets its video from `d3il replay
//! --level AXIS/N --video`.

use d3il_evaluator::eval::{evaluate, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::perturb::Suite;
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::perturbation::{Axis, LevelSetting, Perturbation};
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use d3il_test_support::succeeded;
use serde_json::Value;
use std::path::Path;
use std::process::Command;

fn d3il(args: &[&str], dir: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// The document without the measured inference times (wall clock).
fn read_doc(path: &Path) -> Value {
    let mut v: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    v["control"]["metrics"]["inference_ms"] = Value::Null;
    for l in v["levels"].as_array_mut().unwrap() {
        l["result"]["metrics"]["inference_ms"] = Value::Null;
    }
    v
}

#[test]
fn sharded_suite_merges_to_the_whole_document_and_every_axis_has_videos() {
    let dir = std::env::temp_dir().join(format!("d3il-robustness-shard-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let common = [
        "eval",
        "--task",
        "aligning",
        "--policy",
        "scripted:aligning:inside",
        "--protocol",
        "quick",
        "--suite",
        "robustness",
    ];
    let whole = succeeded(
        &d3il(&[&common[..], &["--json", "whole.json"]].concat(), &dir),
        "whole",
    );
    // The first part in the sandboxed worker (`--sandbox`, the job a
    // server's worker slot runs for a suite's shard), the second in process:
    // they merge into the same document.
    for (k, sandbox) in [("1/2", &["--sandbox"][..]), ("2/2", &[][..])] {
        let part = format!("part{}.json", &k[..1]);
        let out = succeeded(
            &d3il(
                &[&common[..], sandbox, &["--shard", k, "--json", &part]].concat(),
                &dir,
            ),
            k,
        );
        assert!(out.contains(&format!("shard {k}: initial states")), "{out}");
    }
    // Any order of the parts.
    let merged = succeeded(
        &d3il(
            &["merge", "part2.json", "part1.json", "--json", "merged.json"],
            &dir,
        ),
        "merge",
    );
    assert_eq!(
        read_doc(&dir.join("merged.json")),
        read_doc(&dir.join("whole.json")),
        "the merged parts are not the whole document"
    );
    // The same tables (the drops, entropies, retained and scores).
    let tables = |s: &str| s[s.find("robustness of").unwrap()..].to_string();
    assert_eq!(tables(&merged), tables(&whole));
    // A missing shard is named.
    let out = d3il(&["merge", "part1.json"], &dir);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("missing shard 2/2"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A perturbed rollout of every axis replays into a video.
    let suite = Suite::for_task(TaskId::Aligning).unwrap();
    for a in &suite.file.axes {
        let level = format!("{}/{}", a.axis, a.levels.len());
        let video = format!("{}.mp4", a.axis);
        let out = d3il(
            &[
                "replay",
                "--result",
                "merged.json",
                "--level",
                &level,
                "--rollout",
                "1",
                "--video",
                &video,
                "--video-size",
                "64",
            ],
            &dir,
        );
        succeeded(&out, &level);
        let bytes = std::fs::metadata(dir.join(&video)).unwrap().len();
        assert!(bytes > 1000, "{level}: a {bytes}-byte video");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Latency 0.5 steps: the environment receives the mean of the action the
/// policy gave at this step and the one before (the hold action before the
/// first).
#[test]
fn a_fractional_latency_applies_the_blend_of_the_two_late_actions() {
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    let suite = Suite::for_task(TaskId::Aligning).unwrap();
    let p = Perturbation {
        suite: suite.name,
        suite_sha256: suite.sha256,
        axis: Axis::Latency,
        level: 1,
        setting: LevelSetting {
            label: "1.5 steps".into(),
            steps: Some(1),
            fraction: Some(0.5),
            ..Default::default()
        },
    };
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        bootstrap_resamples: 100,
        ..EvalOptions::default()
    };
    let info = PolicyInfo {
        sha256: "scripted".into(),
        obs_type: ObsType::State,
    };
    let mut policy = ScriptedPolicy::from_name("aligning:inside", task.spec()).unwrap();
    let (late, _) = evaluate(
        &task,
        &mut policy,
        &info,
        &opts,
        EvalRun::all().perturbed(&p),
    )
    .unwrap();
    let mut policy = ScriptedPolicy::from_name("aligning:inside", task.spec()).unwrap();
    let whole = Perturbation {
        setting: LevelSetting {
            label: "1 step".into(),
            steps: Some(1),
            ..Default::default()
        },
        ..p.clone()
    };
    let (one, _) = evaluate(
        &task,
        &mut policy,
        &info,
        &opts,
        EvalRun::all().perturbed(&whole),
    )
    .unwrap();
    for (a, b) in late.rollouts.iter().zip(&one.rollouts) {
        let a = late.trace_of(a).unwrap().unpack().unwrap().actions;
        let b = one.trace_of(b).unwrap().unpack().unwrap().actions;
        // At 1 step the environment gets a(t − 1): b[t] = a(t − 1). Both runs
        // see the same observations up to t = 1 (the hold action at t = 0),
        // so they issue the same a(0) and a(1); at 1.5 steps the
        // environment gets 0.5·a(t − 1) + 0.5·a(t − 2).
        assert!(a[0].iter().chain(&b[0]).all(|&x| x == 0.0));
        assert!(b[1].iter().any(|&x| x != 0.0), "the expert moves at once");
        for (x, y) in a[1].iter().zip(&b[1]) {
            assert_eq!(*x, 0.5 * y, "t = 1: half of a(0), half the hold");
        }
        for ((x, y1), y2) in a[2].iter().zip(&b[2]).zip(&b[1]) {
            assert_eq!(*x, 0.5 * y1 + 0.5 * y2, "t = 2: the mean of a(1) and a(0)");
        }
    }
}
