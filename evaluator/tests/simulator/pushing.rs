//! Pushing end to end in real MuJoCo (docs/original-d3il.md §10.4).

use crate::common;

use d3il_evaluator::tasks::pushing::{detect_mode, PushingScript};
use d3il_evaluator::tasks::{LoadedTask, TaskError};
use d3il_protocol::TaskId;
use d3il_test_support::reference_rollout;
use serde_json::{json, Value};

struct Run {
    success: bool,
    behaviour: Value,
    key: Option<String>,
    steps: usize,
}

fn run_script(task: &LoadedTask, ctx: &Value, script: &PushingScript) -> Run {
    let mut env = task.env().unwrap();
    env.reset(ctx).unwrap();
    loop {
        let a = script.act(&env.policy_obs());
        if env.step(&a).unwrap().done {
            break;
        }
    }
    Run {
        success: env.success(),
        behaviour: env.behaviour(),
        key: env.behaviour_key(),
        steps: env.steps(),
    }
}

/// Every order on a few fixed contexts: successes must carry the order's label.
fn order_successes(mode: u8, contexts: std::ops::Range<usize>) -> (usize, Vec<String>) {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    let script = PushingScript::new(mode).unwrap();
    let mut ok = 0;
    let mut report = Vec::new();
    for i in contexts {
        let r = run_script(&task, set.get(i).unwrap(), &script);
        if r.success && r.key.as_deref() == Some(mode.to_string().as_str()) {
            ok += 1;
        }
        report.push(format!(
            "ctx {i}: success {} behaviour {} key {:?} steps {}",
            r.success, r.behaviour, r.key, r.steps
        ));
    }
    (ok, report)
}

#[test]
fn order_red_red_then_green_green() {
    let (ok, report) = order_successes(0, 0..4);
    assert!(ok >= 3, "mode 0: {ok}/4\n{report:#?}");
}

#[test]
fn order_green_green_then_red_red() {
    let (ok, report) = order_successes(1, 0..4);
    assert!(ok >= 3, "mode 1: {ok}/4\n{report:#?}");
}

#[test]
fn order_red_green_then_green_red() {
    let (ok, report) = order_successes(2, 0..4);
    assert!(ok >= 3, "mode 2: {ok}/4\n{report:#?}");
}

#[test]
fn order_green_red_then_red_green() {
    let (ok, report) = order_successes(3, 0..4);
    assert!(ok >= 3, "mode 3: {ok}/4\n{report:#?}");
}

#[test]
fn mode_detector_follows_the_reference_rules() {
    let far = 1.0;
    let near = 0.01;
    // Red in the red zone first, later green in the green zone -> mode 0.
    let (fv, m) = detect_mode(-1, &[near, far, far, far]);
    assert_eq!((fv, m), (0, -1));
    assert_eq!(detect_mode(fv, &[near, far, far, near]), (0, 0));
    // Both at once: first visit takes the higher-priority pair, mode -1, and
    // the next step yields the mode.
    let (fv, m) = detect_mode(-1, &[near, far, far, near]);
    assert_eq!((fv, m), (0, -1));
    assert_eq!(detect_mode(fv, &[near, far, far, near]).1, 0);
    // Green first in the green zone, then red in red -> 1; swapped -> 2, 3.
    assert_eq!(detect_mode(3, &[near, far, far, near]).1, 1);
    assert_eq!(detect_mode(1, &[far, near, near, far]).1, 2);
    assert_eq!(detect_mode(2, &[far, near, near, far]).1, 3);
    // A first visit not completed by its partner stays unlabeled.
    assert_eq!(detect_mode(0, &[far, near, near, far]).1, -1);
}

#[test]
fn zero_action_times_out_without_success() {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    let mut env = task.env().unwrap();
    env.reset(set.get(0).unwrap()).unwrap();
    let mut n = 1;
    while !env.step(&[0.0, 0.0]).unwrap().done {
        n += 1;
    }
    assert_eq!(n, 400);
    assert!(!env.success());
    assert_eq!(env.behaviour(), json!(-1));
    assert_eq!(env.behaviour_key(), None);
    assert!(matches!(env.step(&[0.0, 0.0]), Err(TaskError::EpisodeOver)));
}

#[test]
fn boxes_settle_like_the_reference() {
    // docs/original-d3il.md §10.4.1: placed at z = 0 (11 mm in the table), ≈ 0.00005 after the
    // reset substep, ≈ 0.006 after step 1, ≈ 0.009 after step 2, ≈ 0.0109 at rest.
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    let mut env = task.env().unwrap();
    env.reset(set.get(0).unwrap()).unwrap();
    let z = |env: &d3il_evaluator::tasks::Env| env.objects()[0].1[2];
    assert!(z(&env).abs() < 2e-4, "after reset {}", z(&env));
    env.step(&[0.0, 0.0]).unwrap();
    assert!((z(&env) - 0.006).abs() < 1e-3, "after step 1 {}", z(&env));
    env.step(&[0.0, 0.0]).unwrap();
    assert!((z(&env) - 0.009).abs() < 1e-3, "after step 2 {}", z(&env));
    for _ in 0..20 {
        env.step(&[0.0, 0.0]).unwrap();
    }
    assert!((z(&env) - 0.01097).abs() < 3e-4, "at rest {}", z(&env));
}

#[test]
fn same_actions_give_identical_observations() {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    let script = PushingScript::new(2).unwrap();
    let a = common::assert_deterministic(&task, set.get(1).unwrap(), 150, &|env| {
        script.act(&env.policy_obs()).to_vec()
    });
    assert!(a.len() > 100);
}

#[test]
fn fixed_set_loads_and_verifies() {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let set = task.def.context_set().unwrap();
    assert_eq!(set.len(), 60);
    // The paper's protocol: the first 30 states × 16 rollouts.
    assert_eq!(task.def.n_contexts_paper(set.len()), 30);
    assert_eq!(task.def.rollouts_per_context(), 16);
    common::reset_every_context(&task, |_, _, obs| {
        assert!((0.4..=0.5).contains(&obs[2]) && (-0.15..=0.0).contains(&obs[3]));
        assert!((0.55..=0.65).contains(&obs[5]) && (-0.15..=0.0).contains(&obs[6]));
    });
}

#[test]
fn bad_contexts_name_the_field() {
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let mut env = task.env().unwrap();
    let ok = json!({"red_xy_deg": [0.45, -0.1, 10.0], "green_xy_deg": [0.6, -0.1, -20.0]});
    env.reset(&ok).unwrap();
    let cases = [
        (json!([1, 2]), "JSON object"),
        (json!({"red_xy_deg": [0.45, -0.1, 10.0]}), "green_xy_deg"),
        (
            json!({"red_xy_deg": [0.45, -0.1, 10.0], "green_xy_deg": [0.6, -0.1, -20.0], "green_quat": [1, 0, 0]}),
            "green_quat",
        ),
        (
            json!({"red_xy_deg": [0.45, null, 10.0], "green_xy_deg": [0.6, -0.1, -20.0]}),
            "red_xy_deg`[1]",
        ),
    ];
    for (ctx, needle) in cases {
        let msg = env.reset(&ctx).unwrap_err().to_string();
        assert!(msg.contains(needle), "{msg} should mention {needle}");
    }
}

/// Open-loop replay of the reference rollout (original D3IL, MuJoCo 2.3.2):
/// reset observation and free motion to 1e-4 m, the contact phase loosely.
#[test]
fn reference_rollout_replays() {
    let r = reference_rollout("pushing/ctx0_red_to_red_green_to_green.json");
    let task = LoadedTask::load(TaskId::Pushing).unwrap();
    let mut env = task.env().unwrap();
    let obs0 = env.reset(&r["context"]).unwrap();
    let ref_obs0: Vec<f32> = serde_json::from_value(r["reset"]["obs"].clone()).unwrap();
    let max0 = obs0
        .iter()
        .zip(&ref_obs0)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(max0 < 1e-4, "reset observation differs by {max0}");
    let fixed_z = r["reset"]["fixed_z"][0].as_f64().unwrap();
    assert!((env.fixed_z() - fixed_z).abs() < 1e-6);

    let actions: Vec<Vec<f32>> = serde_json::from_value(r["policy_actions"].clone()).unwrap();
    let ee: Vec<[f64; 3]> = serde_json::from_value(r["ee_pos"].clone()).unwrap();
    let objects = r["objects"].as_object().unwrap();
    let ref_red: Vec<[f64; 3]> =
        serde_json::from_value(objects["push_box (red)"]["pos"].clone()).unwrap();
    let ref_green: Vec<[f64; 3]> =
        serde_json::from_value(objects["push_box2 (green)"]["pos"].clone()).unwrap();
    // First contact: the step after which a reference box moved in xy.
    let moved = |v: &Vec<[f64; 3]>| {
        v.iter()
            .position(|p| (p[0] - v[0][0]).hypot(p[1] - v[0][1]) > 1e-5)
            .unwrap_or(v.len())
    };
    let contact = moved(&ref_red).min(moved(&ref_green));
    let mut free_max = 0.0f64;
    let mut all_max = 0.0f64;
    let mut box_max = 0.0f64;
    for (t, a) in actions.iter().enumerate() {
        let out = env.step(a).unwrap();
        let p = env.sim.tcp_pos();
        let dev = (0..3)
            .map(|k| (p[k] - ee[t + 1][k]).abs())
            .fold(0.0, f64::max);
        all_max = all_max.max(dev);
        if t + 1 < contact {
            free_max = free_max.max(dev);
        }
        let objs = env.objects();
        for (ours, theirs) in [(objs[0].1, ref_red[t + 1]), (objs[1].1, ref_green[t + 1])] {
            box_max = box_max.max((ours[0] - theirs[0]).hypot(ours[1] - theirs[1]));
        }
        if out.done {
            break;
        }
    }
    let objs = env.objects();
    let final_dev = [
        (objs[0].1, ref_red.last().unwrap()),
        (objs[1].1, ref_green.last().unwrap()),
    ]
    .iter()
    .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
    .fold(0.0, f64::max);
    eprintln!(
        "pushing replay: first box motion after step {contact}; free-motion max TCP deviation {free_max:.3e} m; \
         whole-episode max TCP {all_max:.3e} m; max box xy deviation {box_max:.3e} m; final box xy deviation {final_dev:.3e} m; \
         steps {} (reference {}); success {} mode {}",
        env.steps(),
        r["n_steps"],
        env.success(),
        env.behaviour()
    );
    assert!(contact > 10, "the reference boxes move from step {contact}");
    assert!(free_max < 1e-4, "free-motion TCP deviation {free_max}");
    // Contact phase: chaotic (docs/original-d3il.md §01.7.10); compare the outcome loosely.
    assert!(final_dev < 0.05, "final box xy deviation {final_dev}");
    if env.steps() == r["n_steps"].as_u64().unwrap() as usize {
        assert_eq!(env.success(), r["success"].as_bool().unwrap());
        assert_eq!(env.behaviour(), r["mode"]);
    }
}
