//! A deterministic policy (an ONNX graph without a `noise` input) gives the
//! same rollout every time it starts from the same initial state, so the
//! engine simulates each initial state once and records it under every
//! rollout index. These tests run each protocol both ways and compare every
//! rollout record and metric: state policies on a contact task (Aligning:
//! the box is pushed, where a last-bit difference grows) and on Avoiding
//! (paths recorded), an image policy and a one-variant scripted expert. A
//! policy with a `noise` input, or a script of several variants, is
//! simulated rollout by rollout.

use d3il_evaluator::eval::{evaluate, sha256_hex, EvalOptions, EvalRun, PolicyInfo, Timing};
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{OnnxPolicy, Policy};
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, RobotLook, TaskId};
use d3il_test_support::{fixture_manifest, fixtures_dir};

/// A policy by name: an ONNX fixture, or `scripted:<name>`.
fn load(task: &LoadedTask, name: &str) -> (Box<dyn Policy>, PolicyInfo) {
    let obs_type = task.obs_type;
    if let Some(script) = name.strip_prefix("scripted:") {
        let p = ScriptedPolicy::from_name(script, task.spec()).unwrap();
        let info = PolicyInfo {
            sha256: "scripted".into(),
            obs_type,
        };
        return (Box::new(p), info);
    }
    let bytes = std::fs::read(fixtures_dir().join(format!("{name}.onnx"))).unwrap();
    let policy = OnnxPolicy::load(&bytes, &fixture_manifest(name), &task.spec(), 0).unwrap();
    let info = PolicyInfo {
        sha256: sha256_hex(&bytes),
        obs_type,
    };
    (Box::new(policy), info)
}

fn evaluate_fixture(
    task: TaskId,
    obs_type: ObsType,
    name: &str,
    every_rollout: bool,
) -> (EvalResult, Timing) {
    let task = LoadedTask::load_obs(task, obs_type).unwrap();
    let (mut policy, info) = load(&task, name);
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        bootstrap_resamples: 200,
        max_live: 4, // fewer slots than rollouts: slots are reused
        simulate_every_rollout: every_rollout,
        ..EvalOptions::default()
    };
    evaluate(&task, policy.as_mut(), &info, &opts, EvalRun::all()).unwrap()
}

/// Everything but the measured inference time and the manifest's record of
/// how the rollouts were produced.
fn comparable(r: &EvalResult) -> serde_json::Value {
    // A once-simulated state's copies share its trace.
    let mut r = r.clone();
    r.resolve_traces();
    let mut v = serde_json::to_value(&r).unwrap();
    v["metrics"]["inference_ms"] = serde_json::Value::Null;
    v["manifest"]
        .as_object_mut()
        .unwrap()
        .remove("simulated_once");
    v
}

/// The path of the first value that differs between two JSON documents.
fn first_difference(a: &serde_json::Value, b: &serde_json::Value, at: &str) -> String {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, v) in x {
                match y.get(k) {
                    Some(w) if w == v => {}
                    Some(w) => return first_difference(v, w, &format!("{at}.{k}")),
                    None => return format!("{at}.{k} only in the first"),
                }
            }
            format!("{at}: keys only in the second")
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (v, w)) in x.iter().zip(y).enumerate() {
                if v != w {
                    return first_difference(v, w, &format!("{at}[{i}]"));
                }
            }
            at.to_string()
        }
        _ => format!("{at}: {a} vs {b}"),
    }
}

fn same_both_ways(task: TaskId, obs_type: ObsType, name: &str) -> EvalResult {
    let (all, t_all) = evaluate_fixture(task, obs_type, name, true);
    let (once, t_once) = evaluate_fixture(task, obs_type, name, false);
    let n = all.rollouts.len();
    let states = all.manifest.n_contexts;
    assert!(
        all.manifest.rollouts_per_context > 1,
        "{name}: nothing to share"
    );
    assert_eq!(t_all.rollouts_simulated, n, "{name}");
    assert!(
        !all.manifest.simulated_once && once.manifest.simulated_once,
        "{name}"
    );
    assert_eq!(
        t_once.rollouts_simulated, states,
        "{name}: one per initial state"
    );
    let (a, b) = (comparable(&all), comparable(&once));
    assert!(
        a == b,
        "{name}: simulating each initial state once changed the result: {}",
        first_difference(&a, &b, "")
    );
    all
}

#[test]
fn a_deterministic_state_policy_is_simulated_once_per_initial_state_with_the_same_results() {
    let aligning = same_both_ways(TaskId::Aligning, ObsType::State, "aligning_mlp");
    // The random-weight MLP drives the robot differently from each state.
    let steps: Vec<usize> = aligning.rollouts.iter().map(|r| r.steps).collect();
    assert!(steps.iter().all(|&s| s > 0));
    // Nothing is drawn for a state policy: the manifest names no robot look.
    assert_eq!(aligning.manifest.robot_look, None);
    let avoiding = same_both_ways(TaskId::Avoiding, ObsType::State, "avoiding_path");
    assert!(avoiding.rollouts.iter().all(|r| r.path.is_some()));
    assert_eq!(avoiding.metrics.conditional_entropy.value, 0.0);
}

#[test]
fn a_deterministic_image_policy_is_simulated_once_per_initial_state_with_the_same_results() {
    let r = same_both_ways(TaskId::Aligning, ObsType::Image, "aligning_image_k2_h4");
    // The set-up converts the Panda meshes, so image evaluations draw them,
    // and the manifest says so.
    assert_eq!(r.manifest.robot_look, Some(RobotLook::Meshes));
}

#[test]
fn a_policy_with_noise_is_simulated_rollout_by_rollout() {
    let (bytes, manifest) = (
        std::fs::read(fixtures_dir().join("avoiding_noise.onnx")).unwrap(),
        fixture_manifest("avoiding_noise"),
    );
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let policy = OnnxPolicy::load(&bytes, &manifest, &task.spec(), 0).unwrap();
    assert!(!policy.deterministic());
    let (r, t) = evaluate_fixture(TaskId::Avoiding, ObsType::State, "avoiding_noise", false);
    assert_eq!(t.rollouts_simulated, r.rollouts.len());
    assert!(!r.manifest.simulated_once);
    // Its rollouts of the one initial state differ.
    assert!(r.metrics.conditional_entropy.value > 0.0, "{:?}", r.metrics);
}

/// A script is a function of its observations: with one variant the
/// engine simulates each initial state once, with the same results; with
/// several (chosen by rollout id) rollout by rollout.
#[test]
fn a_one_variant_script_is_simulated_once_and_a_script_of_several_variants_rollout_by_rollout() {
    let r = same_both_ways(TaskId::Aligning, ObsType::State, "scripted:aligning:inside");
    assert!(r.rollouts.iter().any(|x| x.success), "{:?}", r.rollouts);
    let (r, t) = evaluate_fixture(
        TaskId::Aligning,
        ObsType::State,
        "scripted:aligning:both",
        false,
    );
    assert_eq!(t.rollouts_simulated, r.rollouts.len());
    assert!(!r.manifest.simulated_once);
}
