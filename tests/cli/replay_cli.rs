//! `d3il replay` through the real binary, on the episode recorded in the
//! original D3IL simulator, plus the errors bad input gets.

use serde_json::{json, Value};
use std::process::Command;

fn replay(task: &str, input: &Value) -> (bool, String, String) {
    let dir = tempfile_dir();
    let path = dir.join("episode.json");
    std::fs::write(&path, serde_json::to_vec(input).unwrap()).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(["replay", "--task", task, "--input"])
        .arg(&path)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "d3il-replay-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn avoiding_reference_route_replays_through_the_cli() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/reference-rollouts/avoiding/route_top_top_top.json"
    ))
    .unwrap();
    let r: Value = serde_json::from_str(&text).unwrap();
    let input = json!({"context": null, "actions": r["policy_actions"]});
    let (ok, stdout, stderr) = replay("avoiding", &input);
    assert!(ok, "{stderr}");
    let out: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["success"], true);
    assert_eq!(out["behaviour"], r["mode"]);
    assert_eq!(out["steps"], r["n_steps"]);
    let ours = out["tcp"].as_array().unwrap();
    let theirs = r["ee_pos"].as_array().unwrap();
    assert_eq!(ours.len(), theirs.len());
    for (t, (a, b)) in ours.iter().zip(theirs).enumerate() {
        for k in 0..3 {
            let d = (a[k].as_f64().unwrap() - b[k].as_f64().unwrap()).abs();
            assert!(d < 1e-4, "tcp row {t} axis {k} deviates {d}");
        }
    }
}

#[test]
fn bad_input_names_the_field() {
    let (ok, _, err) = replay(
        "avoiding",
        &json!({"context": null, "actions": [[0.0, 0.0, 0.0]]}),
    );
    assert!(!ok);
    assert!(
        err.contains("actions[0] has 3 values") && err.contains("expects 2"),
        "{err}"
    );
    let (ok, _, err) = replay("avoiding", &json!({"context": null}));
    assert!(!ok && err.contains("actions"), "{err}");
    let (ok, _, err) = replay("nonsense", &json!({"actions": []}));
    assert!(!ok && err.contains("unknown task"), "{err}");
    let (ok, _, err) = replay(
        "pushing",
        &json!({"context": {"red_xy_deg": "x"}, "actions": []}),
    );
    assert!(!ok && err.contains("context"), "{err}");
}

/// A reference episode from tests/data/reference-rollouts.
fn reference(rel: &str) -> Value {
    let path = format!(
        "{}/tests/data/reference-rollouts/{rel}",
        env!("CARGO_MANIFEST_DIR")
    );
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

fn rows(v: &Value) -> Vec<Vec<f64>> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        })
        .collect()
}

fn max_dev(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The step after which a reference object first moved more than 1e-5 m in xy.
fn first_motion(path: &[Vec<f64>]) -> usize {
    path.iter()
        .position(|p| (p[0] - path[0][0]).hypot(p[1] - path[0][1]) > 1e-5)
        .unwrap_or(path.len())
}

/// Replays a reference rollout of a Cartesian task through the CLI and checks
/// what the Env-level tests establish: the reset observation and the
/// free-motion TCP path (before any reference object moves) within 1e-4 m,
/// the objects' final xy within 0.05 m (the contact phase is chaotic,
/// docs/original-d3il.md §01.7.10), and the outcome (success, label, steps) as recorded.
/// `names` maps our object names to the reference's.
fn check_cartesian_reference(task: &str, rel: &str, names: &[(&str, &str)]) {
    let r = reference(rel);
    let input = json!({"context": r["context"], "actions": r["policy_actions"]});
    let (ok, stdout, stderr) = replay(task, &input);
    assert!(ok, "{stderr}");
    let out: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["task"], task);
    assert_eq!(out["success"], r["success"], "{task}: success");
    assert_eq!(out["behaviour"], r["mode"], "{task}: behaviour");
    assert_eq!(out["steps"], r["n_steps"], "{task}: steps");
    assert_eq!(out["done"], true);

    let obs = rows(&out["observations"]);
    let ref_obs0: Vec<f64> = rows(&json!([r["reset"]["obs"]])).remove(0);
    assert!(
        max_dev(&obs[0], &ref_obs0) < 1e-4,
        "{task}: reset observation"
    );

    let tcp = rows(&out["tcp"]);
    let ref_tcp = rows(&r["ee_pos"]);
    assert_eq!(tcp.len(), ref_tcp.len(), "{task}: one TCP row per state");
    let mut contact = usize::MAX;
    for (ours, theirs) in names {
        let path = rows(&out["objects"][*ours]);
        let ref_path = rows(&r["objects"][*theirs]["pos"]);
        assert_eq!(path.len(), ref_path.len(), "{task}: rows of {ours}");
        contact = contact.min(first_motion(&ref_path));
        let (a, b) = (path.last().unwrap(), ref_path.last().unwrap());
        let d = (a[0] - b[0]).hypot(a[1] - b[1]);
        assert!(d < 0.05, "{task}: {ours} ends {d} m from the reference");
    }
    assert!(
        contact > 10,
        "{task}: reference objects move from step {contact}"
    );
    for t in 0..contact.min(tcp.len()) {
        let d = max_dev(&tcp[t], &ref_tcp[t]);
        assert!(d < 1e-4, "{task}: free-motion TCP row {t} deviates {d}");
    }
    // Observations of the free phase (float32, step t returns the state
    // before step t's physics).
    let ref_steps = rows(&r["observations"]);
    for t in 1..contact.min(obs.len()) {
        let d = max_dev(&obs[t], &ref_steps[t - 1]);
        assert!(d < 1e-4, "{task}: observation {t} deviates {d}");
    }
}

#[test]
fn aligning_reference_replays_through_the_cli() {
    check_cartesian_reference(
        "aligning",
        "aligning/ctx0_inside_push.json",
        &[("aligning_box", "aligning_box")],
    );
}

#[test]
fn pushing_reference_replays_through_the_cli() {
    check_cartesian_reference(
        "pushing",
        "pushing/ctx0_red_to_red_green_to_green.json",
        &[
            ("push_box", "push_box (red)"),
            ("push_box2", "push_box2 (green)"),
        ],
    );
}

#[test]
fn sorting_2_reference_replays_through_the_cli() {
    check_cartesian_reference(
        "sorting-2",
        "sorting_2/ctxA_sort_all.json",
        &[("red_1", "red_1"), ("blue_1", "blue_1")],
    );
}

/// Stacking's joint-space sweep touches no object: joints within 1e-4 rad of
/// the reference for the whole episode, boxes still within 1e-4 m, no stack.
#[test]
fn stacking_reference_replays_through_the_cli() {
    let r = reference("stacking/ctx0_joint_sweep_gripper.json");
    let input = json!({"context": r["context"], "actions": r["policy_actions"]});
    let (ok, stdout, stderr) = replay("stacking", &input);
    assert!(ok, "{stderr}");
    let out: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["success"], false);
    assert_eq!(out["behaviour"], r["mode"]);
    assert_eq!(out["behaviour"], "");
    assert_eq!(out["steps"], r["n_steps"]);
    let joints = rows(&out["joints"]);
    let ref_joints = rows(&r["joint_pos"]);
    assert_eq!(joints.len(), ref_joints.len());
    for (t, (a, b)) in joints.iter().zip(&ref_joints).enumerate() {
        let d = max_dev(a, b);
        assert!(d < 1e-4, "joint row {t} deviates {d} rad");
    }
    for name in ["red_box", "green_box", "blue_box"] {
        let path = rows(&out["objects"][name]);
        let ref_path = rows(&r["objects"][name]["pos"]);
        assert_eq!(path.len(), ref_path.len(), "rows of {name}");
        for (t, (a, b)) in path.iter().zip(&ref_path).enumerate() {
            let d = (a[0] - b[0]).abs().max((a[1] - b[1]).abs());
            assert!(d < 1e-4, "{name} row {t} deviates {d} m");
        }
    }
    // The gripper really moved: the finger paths are not constant.
    let fingers = rows(&out["fingers"]);
    let (lo, hi) = fingers.iter().fold((f64::MAX, f64::MIN), |(lo, hi), f| {
        (lo.min(f[0]), hi.max(f[0]))
    });
    assert!(hi - lo > 0.01, "finger travel {lo}..{hi}");
}

/// Runs a scripted policy closed-loop in-process from initial state `ctx` of
/// the task's fixed set, then replays the recorded actions open-loop through
/// the CLI: the simulator is deterministic, so the CLI must reproduce the
/// in-process run exactly (observations, object paths, success, label, steps).
/// Returns the CLI output.
fn scripted_run_replays(
    task: d3il_protocol::TaskId,
    ctx: usize,
    mut act: impl FnMut(&[f32]) -> Vec<f32>,
) -> Value {
    use d3il_evaluator::tasks::LoadedTask;
    let loaded = LoadedTask::load(task).unwrap();
    let set = loaded.def.context_set().unwrap();
    let context = set.get(ctx).unwrap().clone();
    let mut env = loaded.env().unwrap();
    env.reset(&context).unwrap();
    let mut actions = Vec::new();
    let mut observations = vec![];
    loop {
        let a = act(&env.policy_obs());
        let out = env.step(&a).unwrap();
        observations.push(out.obs);
        actions.push(a);
        if out.done {
            break;
        }
    }
    let input = json!({"context": context, "actions": actions});
    let (ok, stdout, stderr) = replay(&task.to_string(), &input);
    assert!(ok, "{stderr}");
    let out: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["task"], json!(task));
    assert_eq!(out["steps"], env.steps(), "{task}: steps");
    assert_eq!(out["success"], env.success(), "{task}: success");
    assert_eq!(out["behaviour"], env.behaviour(), "{task}: behaviour");
    assert_eq!(out["done"], true);
    let replayed: Vec<Vec<f32>> = serde_json::from_value(out["observations"].clone()).unwrap();
    assert_eq!(replayed[1..], observations[..], "{task}: observations");
    for (name, p) in env.objects() {
        let path = rows(&out["objects"][&name]);
        assert_eq!(path.len(), env.steps() + 1, "{task}: rows of {name}");
        // Equal up to the JSON float round trip (serde_json parses the last
        // digit of a float64 to within an ulp).
        let d = max_dev(path.last().unwrap(), &p);
        assert!(d < 1e-12, "{task}: final {name} differs by {d}");
    }
    out
}

#[test]
fn sorting_4_scripted_episode_replays_with_its_label() {
    use d3il_evaluator::tasks::sorting::SortingScript;
    let mut script = SortingScript::new("RBRB").unwrap();
    let out = scripted_run_replays(d3il_protocol::TaskId::Sorting4, 0, |o| {
        script.act(o).to_vec()
    });
    assert_eq!(out["success"], true);
    // R B R B packed MSB first: 0101 0000.
    assert_eq!(out["behaviour"], 0b0101_0000);
    assert!(out["steps"].as_u64().unwrap() < 700, "ended by success");
}

#[test]
fn sorting_6_scripted_episode_replays_with_its_label() {
    use d3il_evaluator::tasks::sorting::SortingScript;
    let mut script = SortingScript::new("RBRBRB").unwrap();
    // Initial state 2: the six-box script sorts every box there (in a
    // different order than asked for: it does not plan around blockers).
    let out = scripted_run_replays(d3il_protocol::TaskId::Sorting6, 2, |o| {
        script.act(o).to_vec()
    });
    assert_eq!(out["success"], true);
    // A complete Sorting-6 label: six slots, three of them blue (bit 1), the
    // two padding bits 0.
    let code = out["behaviour"].as_u64().unwrap();
    assert_eq!(code & 0b11, 0, "padding bits of {code:#010b}");
    assert_eq!(code.count_ones(), 3, "three blue slots in {code:#010b}");
    assert!(out["steps"].as_u64().unwrap() < 1200, "ended by success");
}

#[test]
fn sorting_6_zero_actions_replay_with_the_nothing_sorted_label() {
    let out = scripted_run_replays(d3il_protocol::TaskId::Sorting6, 0, |_| vec![0.0, 0.0]);
    assert_eq!(out["success"], false);
    assert_eq!(
        out["behaviour"], 252,
        "-1 in all six slots packs as 111111 00"
    );
    assert_eq!(out["steps"], 1200);
}

#[test]
fn inserting_scripted_episode_replays_with_its_label() {
    use d3il_evaluator::tasks::inserting::InsertingScript;
    let mut script = InsertingScript::green();
    // Initial state 3: the green script inserts its box there.
    let out = scripted_run_replays(d3il_protocol::TaskId::Inserting, 3, |o| {
        script.act(o).to_vec()
    });
    assert_eq!(out["behaviour"], "g");
    assert_eq!(out["success"], false, "one box of three");
    assert_eq!(out["steps"], 2000);
    let green = rows(&out["objects"]["push_box2"]);
    let (a, b) = (&green[0], green.last().unwrap());
    assert!((b[1] - a[1]) > 0.4, "green moved {a:?} -> {b:?}");
}
