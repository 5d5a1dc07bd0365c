//! Issue 31: every stored rollout of a real evaluation replays bit for bit
//! from its record (`d3il replay --result out.json --rollout N`), for every
//! task (scripted experts), an ONNX state policy, an ONNX image policy and a
//! sharded run; an edited record is reported as not replaying, naming the
//! first step that differs, and never crashes anything.

use d3il_protocol::rollout::{pack_f32, unpack_f32};
use d3il_test_support::succeeded;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Arc, Mutex, OnceLock};

const EXE: &str = env!("CARGO_BIN_EXE_d3il");

fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("replay-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn d3il(args: &[&str], dir: &Path) -> Output {
    Command::new(EXE)
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// `d3il eval --task TASK --protocol quick --policy POLICY EXTRA --json OUT` in `dir`, run to the end.
fn eval_quick(dir: &Path, task: &str, policy: &str, extra: &[&str], out: &str) {
    let mut args = vec![
        "eval",
        "--task",
        task,
        "--protocol",
        "quick",
        "--policy",
        policy,
    ];
    args.extend_from_slice(extra);
    args.extend(["--json", out]);
    succeeded(
        &d3il(&args, dir),
        &format!("eval {policy} {}", extra.join(" ")),
    );
}

/// The quick evaluations more than one test reads (`d3il eval --protocol
/// quick` of a scripted expert), each run once for the tests of this file
/// into a directory of its own: the scripted test replays them, the refusal
/// and video tests edit copies of them. Returns the result file.
fn shared_quick(task: &'static str, policy: &'static str) -> PathBuf {
    type Key = (&'static str, &'static str);
    type Slot = Arc<OnceLock<PathBuf>>;
    static SHARED: OnceLock<Mutex<BTreeMap<Key, Slot>>> = OnceLock::new();
    let slot = SHARED
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry((task, policy))
        .or_default()
        .clone();
    slot.get_or_init(|| {
        let dir = scratch(&format!("shared-{task}"));
        eval_quick(&dir, task, policy, &[], "r.json");
        dir.join("r.json")
    })
    .clone()
}

/// [`shared_quick`]'s result copied into `dir` as `r.json`.
fn quick_into(dir: &Path, task: &'static str, policy: &'static str) {
    std::fs::copy(shared_quick(task, policy), dir.join("r.json")).unwrap();
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The rollout numbers of a result document.
fn numbers(doc: &Value) -> Vec<usize> {
    let per = doc["manifest"]["rollouts_per_context"].as_u64().unwrap() as usize;
    doc["rollouts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r["context_index"].as_u64().unwrap() as usize * per
                + r["rollout_index"].as_u64().unwrap() as usize
        })
        .collect()
}

/// Replays every rollout of `file` in `dir` and checks the CLI's verdict
/// against the record (steps, success, behaviour as the record says).
fn every_rollout_replays(dir: &Path, file: &str) -> Value {
    rollouts_replay(dir, file, usize::MAX)
}

/// [`every_rollout_replays`] for the first `at_most` rollouts and the last
/// (the long tasks' rollouts cost as much to replay as to evaluate).
fn rollouts_replay(dir: &Path, file: &str, at_most: usize) -> Value {
    let doc = read_json(&dir.join(file));
    let per = doc["manifest"]["rollouts_per_context"].as_u64().unwrap() as usize;
    let all = numbers(&doc);
    let last = all.len().saturating_sub(1);
    for (i, (n, record)) in all
        .into_iter()
        .zip(doc["rollouts"].as_array().unwrap())
        .enumerate()
    {
        if i >= at_most && i != last {
            continue;
        }
        let stdout = succeeded(
            &d3il(
                &[
                    "replay",
                    "--result",
                    file,
                    "--rollout",
                    &n.to_string(),
                    "--json",
                ],
                dir,
            ),
            &format!("replay of rollout {n} of {file}"),
        );
        let check: Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(check["differences"], Value::Array(vec![]), "{stdout}");
        assert_eq!(check["steps"], record["steps"], "rollout {n}");
        assert_eq!(check["success"], record["success"], "rollout {n}");
        assert_eq!(check["behaviour"], record["behaviour"], "rollout {n}");
        assert_eq!(check["ending"], record["ending"], "rollout {n}");
        assert_eq!(
            check["number"].as_u64().unwrap() as usize,
            n,
            "{per} rollouts per state"
        );
        // Bit for bit: the final poses print the same shortest round-trip decimals.
        let finals = record["trace"]["final_objects"].clone();
        if !finals.is_null() {
            assert_eq!(check["final_objects"], finals, "rollout {n}");
        }
    }
    doc
}

/// Writes `doc` with rollout `index`'s action at `step` (0-based) nudged,
/// and returns the file name.
fn with_nudged_action(dir: &Path, doc: &Value, index: usize, step: usize) -> String {
    let mut doc = doc.clone();
    let trace = &mut doc["rollouts"][index]["trace"];
    let act_dim = trace["act_dim"].as_u64().unwrap() as usize;
    let mut actions = unpack_f32("actions", trace["actions"].as_str().unwrap()).unwrap();
    actions[step * act_dim] += 0.01;
    trace["actions"] = Value::String(pack_f32(&actions));
    let name = format!("nudged-{index}-{step}.json");
    std::fs::write(dir.join(&name), serde_json::to_string(&doc).unwrap()).unwrap();
    name
}

/// An edited record does not replay: the CLI fails and names the step.
fn nudged_record_names_its_step(dir: &Path, doc: &Value, index: usize, step: usize) {
    let file = with_nudged_action(dir, doc, index, step);
    let n = numbers(doc)[index].to_string();
    let out = d3il(&["replay", "--result", &file, "--rollout", &n], dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "an edited record replayed: {stderr}");
    assert!(
        stderr.contains(&format!(
            "first differs from the record's after step {}",
            step + 1
        )),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Each task's scripted expert under the quick protocol: every rollout
/// replays, and an edited action is named by its step.
#[test]
fn scripted_rollouts_of_every_task_replay_bit_for_bit() {
    let scripts = [
        ("avoiding", "scripted:avoiding:all-paths"),
        ("aligning", "scripted:aligning:both"),
        ("pushing", "scripted:pushing:all-modes"),
        ("sorting-2", "scripted:sorting-2:all-orders"),
        ("sorting-4", "scripted:sorting-4:all-orders"),
        ("sorting-6", "scripted:sorting-6:all-orders"),
        ("stacking", "scripted:stacking:all-orders"),
        ("inserting", "scripted:inserting:box=r"),
    ];
    for (task, policy) in scripts {
        let dir = scratch(&format!("scripted-{task}"));
        quick_into(&dir, task, policy);
        // The first and the last rollout of each task (first and last
        // initial state): a replay costs what the rollout cost, and every
        // rollout of a result replays in the ONNX and sharded tests below.
        // An edited record (replayed to its end) on the shorter tasks only
        // (the check does not depend on the task).
        let long = ["sorting-6", "stacking", "inserting"].contains(&task);
        let doc = rollouts_replay(&dir, "r.json", 1);
        let steps = doc["rollouts"][0]["steps"].as_u64().unwrap() as usize;
        assert!(steps > 20, "{task}: {steps} steps");
        if !long {
            nudged_record_names_its_step(&dir, &doc, 0, 10);
        }
    }
}

#[test]
fn onnx_state_and_image_rollouts_replay_bit_for_bit() {
    for (task, policy) in [
        ("aligning", "aligning_mlp_noise.onnx"),
        ("avoiding", "avoiding_k5_h3.onnx"),
        ("aligning", "aligning_image.onnx"),
    ] {
        let dir = scratch(policy);
        eval_quick(&dir, task, &fixture(policy), &[], "r.json");
        let doc = every_rollout_replays(&dir, "r.json");
        // The last rollout with a trace of its own (a deterministic
        // policy's copies share their state's).
        let traced = doc["rollouts"]
            .as_array()
            .unwrap()
            .iter()
            .rposition(|r| !r["trace"].is_null())
            .unwrap();
        nudged_record_names_its_step(&dir, &doc, traced, 5);
    }
}

/// A deterministic policy is simulated once per initial state: the copies
/// share rollout 0's trace and replay from it.
#[test]
fn copies_of_a_rollout_simulated_once_replay_from_the_shared_trace() {
    let dir = scratch("once");
    let path = fixture("aligning_mlp.onnx");
    eval_quick(&dir, "aligning", &path, &[], "r.json");
    let doc = every_rollout_replays(&dir, "r.json");
    assert_eq!(doc["manifest"]["simulated_once"], true);
    let rollouts = doc["rollouts"].as_array().unwrap();
    assert!(
        rollouts.iter().any(|r| r["trace"].is_null()),
        "copies carry no trace"
    );
    assert!(rollouts.iter().all(|r| r["ending"].is_string()));
}

#[test]
fn rollouts_of_a_sharded_run_replay_from_the_parts_and_the_merged_result() {
    let dir = scratch("sharded");
    let path = fixture("aligning_mlp_noise.onnx");
    for k in 1..=2 {
        let shard = format!("{k}/2");
        let file = format!("part{k}.json");
        eval_quick(&dir, "aligning", &path, &["--shard", &shard], &file);
    }
    succeeded(
        &d3il(
            &["merge", "part1.json", "part2.json", "--json", "merged.json"],
            &dir,
        ),
        "merge",
    );
    every_rollout_replays(&dir, "part2.json");
    let merged = every_rollout_replays(&dir, "merged.json");
    assert_eq!(numbers(&merged), (0..6).collect::<Vec<_>>());
}

#[test]
fn records_that_cannot_replay_say_why() {
    let dir = scratch("bad");
    quick_into(&dir, "aligning", "scripted:aligning:both");
    let doc = read_json(&dir.join("r.json"));
    let refused = |edit: &dyn Fn(&mut Value), n: &str, expect: &str| {
        let mut d = doc.clone();
        edit(&mut d);
        std::fs::write(dir.join("e.json"), serde_json::to_string(&d).unwrap()).unwrap();
        let out = d3il(&["replay", "--result", "e.json", "--rollout", n], &dir);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{expect}: {stderr}");
        assert!(stderr.contains(expect), "expected {expect:?} in {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    };
    refused(&|_| {}, "99", "has no rollout 99");
    refused(
        &|d| d["rollouts"][0]["success"] = Value::Bool(false),
        "0",
        "success: the record says false, the replay gives true",
    );
    refused(
        &|d| d["rollouts"][0]["trace"]["actions"] = "@@@".into(),
        "0",
        "`actions` is not base64",
    );
    refused(
        &|d| d["rollouts"][0]["trace"] = Value::Null,
        "0",
        "has no trace",
    );
    refused(
        &|d| d["manifest"]["mjcf_sha256"] = "0".repeat(64).into(),
        "0",
        "made by another build",
    );
    refused(
        &|d| d["manifest"]["initial_states_sha256"] = "ab".into(),
        "0",
        "initial-state set",
    );
    // A record cut short: the replay ends early and says so.
    refused(
        &|d| {
            let t = &mut d["rollouts"][0]["trace"];
            let dim = t["act_dim"].as_u64().unwrap() as usize;
            let a = unpack_f32("actions", t["actions"].as_str().unwrap()).unwrap();
            t["actions"] = pack_f32(&a[..a.len() - 3 * dim]).into();
        },
        "0",
        "digests",
    );
}

/// The video of a rollout: an MP4 with one frame per state at 200/7 fps.
#[test]
fn a_video_is_written_only_for_a_record_that_replays() {
    let dir = scratch("video");
    quick_into(&dir, "pushing", "scripted:pushing:all-modes");
    succeeded(
        &d3il(
            &[
                "replay",
                "--result",
                "r.json",
                "--rollout",
                "1",
                "--video",
                "v.mp4",
            ],
            &dir,
        ),
        "video",
    );
    let doc = read_json(&dir.join("r.json"));
    let steps = doc["rollouts"][1]["steps"].as_u64().unwrap() as f64;
    let probe = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_frames"])
        .args([
            "-show_entries",
            "stream=codec_name,width,height,nb_read_frames,avg_frame_rate",
        ])
        .args(["-of", "json", "v.mp4"])
        .current_dir(&dir)
        .output()
        .unwrap();
    let info: Value = serde_json::from_slice(&probe.stdout).unwrap();
    let s = &info["streams"][0];
    assert_eq!(s["codec_name"], "h264", "{info}");
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(640), Some(320))
    );
    assert_eq!(s["avg_frame_rate"], "200/7");
    assert_eq!(s["nb_read_frames"], (steps as u64 + 1).to_string());
    // An edited record gets no video, and no file is left behind.
    let file = with_nudged_action(&dir, &doc, 1, 3);
    let out = d3il(
        &[
            "replay",
            "--result",
            &file,
            "--rollout",
            "1",
            "--video",
            "bad.mp4",
        ],
        &dir,
    );
    assert!(!out.status.success());
    let left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("bad"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
