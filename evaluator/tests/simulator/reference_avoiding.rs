//! Replays the episode recorded in the ORIGINAL D3IL simulator
//! (../shared/reference-rollouts/avoiding) through our simulator: free-motion
//! parity of the TCP path, observations, success and the 9-bit label.

use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::TaskId;
use serde_json::Value;

fn reference() -> Value {
    d3il_test_support::reference_rollout("avoiding/route_top_top_top.json")
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

#[test]
fn avoiding_route_replays_within_1e4_of_the_original() {
    let r = reference();
    let task = LoadedTask::load(TaskId::Avoiding).unwrap();
    let mut env = task.env().unwrap();
    let obs0 = env.reset(&Value::Null).unwrap();
    let ref_obs0: Vec<f32> = rows(&Value::Array(vec![r["reset"]["obs"].clone()]))[0]
        .iter()
        .map(|&x| x as f32)
        .collect();
    assert_eq!(obs0, ref_obs0, "observation after reset");
    assert!((env.fixed_z() - r["reset"]["fixed_z"][0].as_f64().unwrap()).abs() < 1e-9);

    let actions = rows(&r["policy_actions"]);
    let ee = rows(&r["ee_pos"]);
    let ref_obs = rows(&r["observations"]);
    let mut max_dev: f64 = 0.0;
    for (t, a) in actions.iter().enumerate() {
        let policy_in = env.policy_obs();
        let ref_in = rows(&r["policy_observations"])[t].clone();
        for k in 0..4 {
            assert!(
                (policy_in[k] as f64 - ref_in[k]).abs() < 1e-4,
                "policy input {k} at step {t}: {} vs {}",
                policy_in[k],
                ref_in[k]
            );
        }
        let a32: Vec<f32> = a.iter().map(|&x| x as f32).collect();
        let out = env.step(&a32).unwrap();
        let p = env.sim.tcp_pos();
        for (ours, theirs) in p.iter().zip(&ee[t + 1]) {
            max_dev = max_dev.max((ours - theirs).abs());
        }
        for (ours, theirs) in out.obs.iter().zip(&ref_obs[t]) {
            assert!((*ours as f64 - theirs).abs() < 1e-4, "obs at step {t}");
        }
        if out.done {
            break;
        }
    }
    eprintln!("max TCP deviation from the original over the route: {max_dev:e} m");
    assert!(max_dev < 1e-4, "TCP deviates {max_dev} m from the original");
    assert_eq!(env.steps(), r["n_steps"].as_u64().unwrap() as usize);
    assert_eq!(env.success(), r["success"].as_bool().unwrap());
    assert_eq!(env.behaviour(), r["mode"]);
}
