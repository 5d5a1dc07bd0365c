//! Issue 16, end to end with real MuJoCo and the real binary: the original
//! D3IL test contexts named in every manifest, the original context formats
//! accepted, a rollout whose simulation becomes unstable failing alone, the
//! intervals `d3il eval` prints, and `d3il compare`.

use d3il_evaluator::eval::{evaluate, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::tasks::contexts::sha256_hex;
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{ActionChunks, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::{EvalResult, FailureReason, ObsType, ProtocolKind, TaskId};
use d3il_test_support::TempDir;
use serde_json::{json, Value};
use std::path::Path;
use std::process::Command;

fn d3il(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn asset_sha(name: &str) -> String {
    let path = format!("{}/assets/contexts/{name}", env!("CARGO_MANIFEST_DIR"));
    sha256_hex(&std::fs::read(path).unwrap())
}

fn read_result(path: &Path) -> EvalResult {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Pushing runs the original test contexts (v2), and the manifest of
/// `d3il eval --json` says so with the file's sha256. The CLI runs the quick
/// protocol here (the paper's 30 × 16 rollouts take minutes in a debug
/// build); the paper protocol draws from the same set, its size is checked
/// on the engine.
#[test]
fn pushing_names_the_original_contexts_in_its_manifest() {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    assert_eq!(set.name, "pushing-v2.json");
    assert_eq!(
        d3il_evaluator::eval::protocol_size(&task, ProtocolKind::Paper, set.len()),
        (30, 16)
    );
    let tmp = TempDir::new("issue16-pushing");
    let dir = tmp.path().to_path_buf();
    let out = dir.join("out.json");
    let (ok, stdout, stderr) = d3il(&[
        "eval",
        "--task",
        "pushing",
        "--policy",
        "scripted:pushing:all-modes",
        "--protocol",
        "quick",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let r = read_result(&out);
    let m = &r.manifest;
    assert_eq!(m.initial_states, "pushing-v2.json");
    assert_eq!(m.initial_states_sha256, asset_sha("pushing-v2.json"));
    assert_eq!(m.initial_states_sha256, set.sha256);
    assert_eq!((m.n_contexts, m.rollouts_per_context), (3, 2));
    assert_eq!(
        m.initial_states_origin().label(),
        "the original D3IL test contexts"
    );
    assert!(
        stdout.contains("initial states: pushing-v2.json (the original D3IL test contexts)"),
        "{stdout}"
    );
    assert!(stdout.contains(&m.initial_states_sha256), "{stdout}");
    // The contexts the rollouts started from are the reference's, in order:
    // entry 0 of shared/reference-contexts/pushing.json is the set's entry 0.
    let set: Value = serde_json::from_str(
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/assets/contexts/pushing-v2.json"
        ))
        .unwrap(),
    )
    .unwrap();
    assert_eq!(
        set["contexts"][0]["red_xy_deg"],
        json!([0.46460434794425964, -0.07941832393407822, 69.60380554199219])
    );
    assert_eq!(set["contexts"].as_array().unwrap().len(), 60);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Avoiding's quick protocol: the printed intervals contain their estimates
/// (the conditional entropy used to print 0.654 with 0.340–0.600).
#[test]
fn avoiding_quick_prints_intervals_that_contain_the_estimates() {
    let tmp = TempDir::new("issue16-avoiding");
    let dir = tmp.path().to_path_buf();
    let out = dir.join("a.json");
    let (ok, stdout, stderr) = d3il(&[
        "eval",
        "--task",
        "avoiding",
        "--policy",
        "scripted:avoiding:all-paths",
        "--protocol",
        "quick",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let mut rows = 0;
    for line in stdout.lines() {
        let name = line.get(..28).unwrap_or("").trim();
        if !["success rate", "conditional entropy", "behaviour entropy"].contains(&name) {
            continue;
        }
        let nums: Vec<f64> = line[28..]
            .split(|c: char| c.is_whitespace() || c == '–')
            .filter_map(|t| t.parse().ok())
            .collect();
        assert_eq!(nums.len(), 3, "{line}");
        assert!(nums[1] <= nums[0] && nums[0] <= nums[2], "{line}");
        rows += 1;
    }
    assert_eq!(rows, 3, "{stdout}");
    assert!(
        stdout.contains("rollouts ended unstable: 0 of 8"),
        "{stdout}"
    );
    assert!(
        stdout.contains("the original D3IL test contexts"),
        "{stdout}"
    );
    let r = read_result(&out);
    let c = r.metrics.conditional_entropy;
    assert!((c.value - 8f64.ln() / 24f64.ln()).abs() < 1e-9, "{c:?}");
    assert!(c.ci_low <= c.value && c.value <= c.ci_high, "{c:?}");

    // The same file against itself: difference 0, p = 1.
    let (ok, stdout, stderr) = d3il(&[
        "compare",
        out.to_str().unwrap(),
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let cmp: Value = serde_json::from_str(&stdout).unwrap();
    for k in ["success_rate", "conditional_entropy"] {
        assert_eq!(cmp[k]["difference"]["value"], 0.0, "{cmp}");
        assert_eq!(cmp[k]["p_value"], 1.0, "{cmp}");
    }
    assert_eq!(cmp["initial_states"], "avoiding-v1.json");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `d3il compare` pairs two different policies on Aligning's original
/// contexts, prints a table, and refuses results from different tasks.
#[test]
fn compare_pairs_two_policies_and_refuses_different_tasks() {
    let tmp = TempDir::new("issue16-compare");
    let dir = tmp.path().to_path_buf();
    let run = |policy: &str, task: &str, file: &str| {
        let p = dir.join(file);
        let (ok, _, stderr) = d3il(&[
            "eval",
            "--task",
            task,
            "--policy",
            policy,
            "--protocol",
            "quick",
            "--json",
            p.to_str().unwrap(),
        ]);
        assert!(ok, "{stderr}");
        p
    };
    let a = run("scripted:aligning:inside", "aligning", "a.json");
    let b = run("scripted:aligning:outside", "aligning", "b.json");
    let (ok, stdout, stderr) = d3il(&["compare", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("aligning-v2.json"), "{stdout}");
    assert!(stdout.contains("success rate") && stdout.contains("conditional entropy"));
    let ra = read_result(&a);
    let rb = read_result(&b);
    let expected = ra.metrics.success_rate.value - rb.metrics.success_rate.value;
    assert!(
        stdout.contains(&format!("{expected:+.3}")),
        "{expected} {stdout}"
    );
    assert!(!stdout.contains("note:"), "nothing else differs: {stdout}");

    // Paired anyway, but said: results that observe differently, or image
    // results whose frames drew the robot differently.
    let edited = |from: &std::path::Path, name: &str, obs: &str, look: Option<&str>| {
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(from).unwrap()).unwrap();
        v["manifest"]["obs_type"] = obs.into();
        if let Some(look) = look {
            v["manifest"]["robot_look"] = look.into();
        }
        let p = dir.join(name);
        std::fs::write(&p, v.to_string()).unwrap();
        p
    };
    let a_meshes = edited(&a, "a-meshes.json", "image", Some("meshes"));
    let b_prims = edited(&b, "b-primitives.json", "image", Some("primitives"));
    let (ok, stdout, stderr) = d3il(&[
        "compare",
        a_meshes.to_str().unwrap(),
        b_prims.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("note: A's camera frames drew the robot with the Panda's meshes and B's with primitive shapes"),
        "{stdout}"
    );
    let (ok, stdout, stderr) = d3il(&["compare", a.to_str().unwrap(), b_prims.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("note: A observes the state and B the camera images"),
        "{stdout}"
    );

    // Results of builds with different physics fingerprints are paired
    // only with that said (issue 32).
    let mut other: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&b).unwrap()).unwrap();
    other["manifest"]["build"]["physics_fingerprint"] = "0123456789abcdef".into();
    let b_other = dir.join("b-other-build.json");
    std::fs::write(&b_other, other.to_string()).unwrap();
    let (ok, stdout, stderr) = d3il(&["compare", a.to_str().unwrap(), b_other.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("note: A and B were made by builds that may simulate differently")
            && stdout.contains("B: physics fingerprint 0123456789abcdef"),
        "{stdout}"
    );

    let c = run("scripted:avoiding:all-paths", "avoiding", "c.json");
    let (ok, _, stderr) = d3il(&["compare", a.to_str().unwrap(), c.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        stderr.contains("cannot be compared") && stderr.contains("task"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Inserting contexts in the original environment's names (box1 = red,
/// box2 = green, box3 = blue) replay as they are, identically to ours.
#[test]
fn inserting_replay_accepts_the_original_box_names() {
    let tmp = TempDir::new("issue16-inserting");
    let dir = tmp.path().to_path_buf();
    let pose = |x: f64, y: f64, yaw: f64| json!([x, y, yaw]);
    let quat = |yaw: f64| {
        let h = yaw.to_radians() / 2.0;
        json!([h.cos(), 0.0, 0.0, h.sin()])
    };
    let ours = json!({
        "red_xy_deg": pose(0.42, -0.18, 10.0), "red_quat": quat(10.0),
        "green_xy_deg": pose(0.62, -0.08, -20.0), "green_quat": quat(-20.0),
        "blue_xy_deg": pose(0.40, 0.02, 30.0), "blue_quat": quat(30.0),
    });
    let theirs = json!({
        "box1_xy_deg": pose(0.42, -0.18, 10.0), "box1_quat": quat(10.0),
        "box2_xy_deg": pose(0.62, -0.08, -20.0), "box2_quat": quat(-20.0),
        "box3_xy_deg": pose(0.40, 0.02, 30.0), "box3_quat": quat(30.0),
    });
    let mut outs = vec![];
    for (name, ctx) in [("ours", &ours), ("theirs", &theirs)] {
        let path = dir.join(format!("{name}.json"));
        let input = json!({"context": ctx, "actions": vec![vec![0.0f32, 0.0]; 5]});
        std::fs::write(&path, input.to_string()).unwrap();
        let (ok, stdout, stderr) = d3il(&[
            "replay",
            "--task",
            "inserting",
            "--input",
            path.to_str().unwrap(),
        ]);
        assert!(ok, "{name}: {stderr}");
        let v: Value = serde_json::from_str(&stdout).unwrap();
        outs.push(v);
    }
    assert_eq!(outs[0]["objects"], outs[1]["objects"]);
    assert_eq!(outs[0]["observations"], outs[1]["observations"]);
    // The red box really is where box1 said (observation: TCP xy, then red x, y, tan yaw).
    let red0 = &outs[1]["observations"][0];
    assert!((red0[2].as_f64().unwrap() - 0.42).abs() < 0.01, "{red0}");
    // The same box under both names is refused, naming both.
    let path = dir.join("both.json");
    let mut both = theirs.clone();
    both["red_xy_deg"] = pose(0.42, -0.18, 10.0);
    std::fs::write(
        &path,
        json!({"context": both, "actions": [[0.0, 0.0]]}).to_string(),
    )
    .unwrap();
    let (ok, _, stderr) = d3il(&[
        "replay",
        "--task",
        "inserting",
        "--input",
        path.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        stderr.contains("box1_xy_deg") && stderr.contains("red_xy_deg"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Holds the arm still (zero joint deltas, gripper open), except that
/// rollout `wild` commands a joint target 1e30 rad away from step 5 on,
/// which makes MuJoCo's accelerations blow up.
struct Wild {
    wild: u64,
}

impl Policy for Wild {
    fn shape(&self) -> PolicyShape {
        PolicyShape {
            history: 1,
            horizon: 1,
            execute: 1,
            obs_dim: 20,
            act_dim: 8,
            obs_type: ObsType::State,
        }
    }
    fn reset(&mut self, _ids: &[u64]) -> Result<(), PolicyError> {
        Ok(())
    }
    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        let mut data = Vec::new();
        for (id, step) in q.rollout_ids.iter().zip(q.steps) {
            let mut a = [0.0f32; 8];
            a[7] = 1.0;
            if *id == self.wild && *step >= 5 {
                a[0] = 1e30;
            }
            data.extend(a);
        }
        Ok(ActionChunks {
            batch: q.rollout_ids.len(),
            horizon: 1,
            act_dim: 8,
            data,
        })
    }
}

#[test]
fn an_unstable_rollout_fails_alone_and_the_evaluation_completes() {
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    assert_eq!(task.spec().obs_dim, 20);
    let mut policy = Wild { wild: 1 };
    let info = PolicyInfo {
        sha256: "wild".into(),
        obs_type: ObsType::State,
    };
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        seed: 0,
        max_live: 6,
        bootstrap_resamples: 100,
        ..EvalOptions::default()
    };
    let (r, _) = evaluate(&task, &mut policy, &info, &opts, EvalRun::all()).unwrap();
    assert_eq!(r.rollouts.len(), 6);
    assert_eq!(r.rollouts_ended_unstable, 1, "{:?}", r.rollouts);
    assert!(!r.mostly_unstable());
    for (i, x) in r.rollouts.iter().enumerate() {
        if i == 1 {
            let f = x.failure.as_ref().expect("rollout 1 ended unstable");
            assert_eq!(f.reason, FailureReason::SimUnstable);
            assert!(!f.message.is_empty());
            assert!(f.step >= 6 && f.step < 1000, "{f:?}");
            assert!(!x.success);
            assert_eq!(x.steps, f.step);
        } else {
            assert!(x.failure.is_none(), "rollout {i}: {x:?}");
            assert_eq!(x.steps, 1000, "rollout {i} ran its course");
        }
    }
    assert_eq!(r.metrics.success_rate.value, 0.0);
    // The record says so in JSON, as the server stores it.
    let v = serde_json::to_value(&r).unwrap();
    assert_eq!(v["rollouts"][1]["failure"]["reason"], "sim_unstable");
    assert_eq!(v["rollouts_ended_unstable"], 1);
    assert_eq!(r.manifest.initial_states, "stacking-v2.json");
}
