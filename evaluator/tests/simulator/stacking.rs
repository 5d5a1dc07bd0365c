//! Stacking end to end in real MuJoCo (docs/original-d3il.md §11.2).

use crate::common;

use d3il_evaluator::tasks::stacking::StackingScript;
use d3il_evaluator::tasks::{Env, LoadedTask};
use d3il_protocol::TaskId;
use d3il_test_support::reference_rollout;
use serde_json::{json, Value};

fn f32s(v: &Value) -> Vec<f32> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// A context with the boxes at given (x, y, yaw_deg), red, green, blue.
fn context(poses: [(f64, f64, f64); 3]) -> Value {
    let mut c = serde_json::Map::new();
    for (name, (x, y, deg)) in ["red", "green", "blue"].iter().zip(poses) {
        let t = deg.to_radians();
        c.insert(format!("{name}_xy_deg"), json!([x, y, deg]));
        c.insert(
            format!("{name}_quat"),
            json!([(t / 2.0).cos(), 0.0, 0.0, (t / 2.0).sin()]),
        );
    }
    Value::Object(c)
}

fn run_script(env: &mut Env, ctx: &Value, order: &str) {
    let mut script = StackingScript::new(order).unwrap();
    env.reset(ctx).unwrap();
    loop {
        let a = script.act(&env.policy_obs());
        if env.step(&a).unwrap().done {
            break;
        }
    }
}

#[test]
fn joint_space_replay_tracks_the_reference_joint_trajectory() {
    let r = reference_rollout("stacking/ctx0_joint_sweep_gripper.json");
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    let mut env = task.env().unwrap();
    // The reference's context object is accepted as-is.
    let first = env.reset(&r["context"]).unwrap();
    let want_obs = f32s(&r["reset"]["obs"]);
    for (i, (a, b)) in first.iter().zip(&want_obs).enumerate() {
        assert!(
            (a - b).abs() <= 1e-6 * b.abs().max(1.0),
            "reset obs[{i}]: {a} vs {b}"
        );
    }
    // The first policy input is [joint_pos, gripper width] as float32 + obs.
    let p0 = env.policy_obs();
    let want_p0 = f32s(&r["policy_observations"][0]);
    for i in 0..8 {
        assert!(
            (p0[i] - want_p0[i]).abs() < 1e-6,
            "policy obs[{i}]: {} vs {}",
            p0[i],
            want_p0[i]
        );
    }
    let actions = r["policy_actions"].as_array().unwrap();
    let commands = r["actions"].as_array().unwrap();
    let joint_pos = r["joint_pos"].as_array().unwrap();
    let mut max_err: f64 = 0.0;
    let mut steps = 0;
    for (t, a) in actions.iter().enumerate() {
        let a = f32s(a);
        let out = env.step(&a).unwrap();
        steps += 1;
        // Our float32 command integration equals the reference's commands,
        // visible as the next policy input's prefix.
        if !out.done {
            let p = env.policy_obs();
            let want = f32s(&commands[t]);
            assert_eq!(&p[..8], &want[..], "command of step {t}");
        }
        let want = f64s(&joint_pos[t + 1]);
        let got = env.sim.joint_pos();
        for j in 0..7 {
            max_err = max_err.max((got[j] - want[j]).abs());
        }
        // No object is touched: the boxes stay where they settled.
        for (name, p) in env.objects() {
            let w = f64s(&r["objects"][&name]["pos"][t + 1]);
            assert!(
                (p[0] - w[0]).abs() < 1e-4 && (p[1] - w[1]).abs() < 1e-4,
                "{name} moved at step {t}: {p:?} vs {w:?}"
            );
        }
        if out.done {
            break;
        }
    }
    assert_eq!(steps, r["n_steps"].as_u64().unwrap() as usize);
    assert!(
        max_err < 1e-4,
        "joint trajectory deviates by {max_err} rad from the reference"
    );
    assert!(!env.success());
    assert_eq!(env.behaviour(), json!(""));
    assert_eq!(env.stacking_levels(), Some([false, false, false]));
}

#[test]
fn scripted_pick_and_place_registers_the_block_at_the_target() {
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    let mut env = task.env().unwrap();
    let ctx = context([
        (0.40, -0.20, 20.0),
        (0.40, -0.05, -30.0),
        (0.575, -0.10, 10.0),
    ]);
    run_script(&mut env, &ctx, "g");
    assert_eq!(env.behaviour(), json!("g"), "objects {:?}", env.objects());
    let green = env.objects()[1].1;
    let d = ((green[0] - 0.5).powi(2) + (green[1] - 0.2).powi(2)).sqrt();
    assert!(d < 0.03, "green placed {d} m from the target: {green:?}");
    assert!(green[2] < 0.02, "green rests on the table: {green:?}");
    assert_eq!(env.stacking_levels(), Some([true, false, false]));
    assert!(!env.success());
    assert_eq!(env.behaviour_key().as_deref(), Some("g"));
}

#[test]
fn scripted_full_stack_succeeds_with_its_order() {
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    let mut env = task.env().unwrap();
    let ctx = context([
        (0.40, -0.20, 20.0),
        (0.40, -0.05, -30.0),
        (0.575, -0.10, 10.0),
    ]);
    run_script(&mut env, &ctx, "rgb");
    assert!(
        env.success(),
        "objects {:?}, order {}",
        env.objects(),
        env.behaviour()
    );
    assert_eq!(env.behaviour(), json!("rgb"));
    assert_eq!(env.stacking_levels(), Some([true, true, true]));
}

#[test]
fn fixed_set_loads_and_verifies() {
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    // v2: the 100 original test contexts (the paper protocol uses 60).
    let set = task.def.context_set().unwrap();
    assert_eq!(set.len(), 100);
    common::reset_every_context(&task, |_, _, obs| assert_eq!(obs.len(), 12));
}

#[test]
fn a_wrong_context_names_the_field() {
    let task = LoadedTask::load(TaskId::Stacking).unwrap();
    let mut env = task.env().unwrap();
    let mut ctx = context([
        (0.40, -0.20, 20.0),
        (0.40, -0.05, -30.0),
        (0.575, -0.10, 10.0),
    ]);
    ctx.as_object_mut().unwrap().remove("green_quat");
    let e = env.reset(&ctx).unwrap_err().to_string();
    assert!(e.contains("green_quat"), "{e}");
    ctx["green_quat"] = json!([1.0, 0.0]);
    let e = env.reset(&ctx).unwrap_err().to_string();
    assert!(e.contains("green_quat") && e.contains("4 numbers"), "{e}");
}
