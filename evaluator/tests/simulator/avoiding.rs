//! Avoiding end to end in real MuJoCo (docs/original-d3il.md §10.2).

use crate::common;

use d3il_evaluator::tasks::avoiding::{path_code, AvoidingScript};
use d3il_evaluator::tasks::{LoadedTask, TaskError};
use d3il_protocol::TaskId;
use serde_json::Value;

fn run_script(task: &LoadedTask, script: &AvoidingScript) -> (bool, Value, Option<String>, usize) {
    let mut env = task.env().unwrap();
    env.reset(&Value::Null).unwrap();
    loop {
        let a = script.act(&env.policy_obs());
        if env.step(&a).unwrap().done {
            break;
        }
    }
    (
        env.success(),
        env.behaviour(),
        env.behaviour_key(),
        env.steps(),
    )
}

#[test]
fn every_path_succeeds_with_its_label() {
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let mut failures = Vec::new();
    for path in 0..24 {
        let (success, bits, key, steps) = run_script(&task, &AvoidingScript::new(path).unwrap());
        let want = path_code(path).unwrap().to_string();
        if !success || key.as_deref() != Some(want.as_str()) {
            failures.push(format!("path {path}: success {success}, key {key:?} (want {want}), bits {bits}, {steps} steps"));
        }
        let ones = bits
            .as_array()
            .unwrap()
            .iter()
            .filter(|b| b.as_f64() == Some(1.0))
            .count();
        assert!(ones <= 3);
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn straight_ahead_hits_the_first_obstacle() {
    // docs/original-d3il.md §10.2.5 check case: Δ = (0, 0.008) every step ends after 19 steps
    // at y ≈ −0.128 with success = false and bit b1 set.
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let mut env = task.env().unwrap();
    env.reset(&Value::Null).unwrap();
    let mut steps = 0;
    while !env.step(&[0.0, 0.008]).unwrap().done {
        steps += 1;
        assert!(steps < 100, "never terminated");
    }
    assert!(!env.success());
    assert_eq!(env.steps(), 19, "terminates at the collision");
    let y = env.sim.tcp_pos()[1];
    assert!((y + 0.128).abs() < 0.003, "y at the end {y}");
    assert_eq!(env.behaviour()[1], 1.0);
    assert_eq!(env.behaviour_key(), None);
}

#[test]
fn zero_action_times_out_without_success() {
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let mut env = task.env().unwrap();
    env.reset(&Value::Null).unwrap();
    let mut n = 0;
    while !env.step(&[0.0, 0.0]).unwrap().done {
        n += 1;
    }
    assert_eq!(n + 1, 250);
    assert!(!env.success());
    assert!(matches!(env.step(&[0.0, 0.0]), Err(TaskError::EpisodeOver)));
}

#[test]
fn bad_actions_are_refused_before_mujoco() {
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let mut env = task.env().unwrap();
    env.reset(&Value::Null).unwrap();
    let e = env.step(&[0.0, 0.0, 0.0]).unwrap_err().to_string();
    assert!(e.contains("3 values") && e.contains("expects 2"), "{e}");
    let e = env.step(&[f32::NAN, 0.0]).unwrap_err().to_string();
    assert!(e.contains("NaN") && e.contains("step 0"), "{e}");
    assert_eq!(env.steps(), 0);
}

#[test]
fn same_actions_give_identical_observations() {
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let script = AvoidingScript::new(7).unwrap();
    common::assert_deterministic(&task, &Value::Null, usize::MAX, &|env| {
        script.act(&env.policy_obs()).to_vec()
    });
}

#[test]
fn fixed_set_loads_and_verifies() {
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let set = task.def.context_set().unwrap();
    assert_eq!(set.len(), 1);
    assert!(set.get(0).unwrap().is_null());
}
