//! Image evaluations skip the frames a policy never sees: with history 2 and
//! chunks of 4 executed whole (`aligning_image_k2_h4`), two of every four
//! frames leave the observation window before the next query. The results
//! are the same as rendering every frame, in every rollout record, and half
//! the frames are drawn.

use d3il_evaluator::eval::{evaluate, sha256_hex, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::OnnxPolicy;
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use d3il_test_support::{fixture_manifest, fixtures_dir};

#[test]
fn frames_the_policy_never_sees_are_not_rendered_and_change_nothing() {
    let task = LoadedTask::load_obs(TaskId::Aligning, ObsType::Image).unwrap();
    let bytes = std::fs::read(fixtures_dir().join("aligning_image_k2_h4.onnx")).unwrap();
    let manifest = fixture_manifest("aligning_image_k2_h4");
    let info = PolicyInfo {
        sha256: sha256_hex(&bytes),
        obs_type: ObsType::Image,
    };
    let run = |every_frame: bool| {
        let mut policy = OnnxPolicy::load(&bytes, &manifest, &task.spec(), 0).unwrap();
        let opts = EvalOptions {
            protocol: ProtocolKind::Quick,
            bootstrap_resamples: 10,
            step_cap: Some(40),
            render_every_frame: every_frame,
            // Count the frames of every rollout, not of one per initial state.
            simulate_every_rollout: true,
            ..EvalOptions::default()
        };
        evaluate(&task, &mut policy, &info, &opts, EvalRun::all()).unwrap()
    };
    let (all, t_all) = run(true);
    let (skipping, t_skip) = run(false);
    let steps: usize = all.rollouts.iter().map(|r| r.steps).sum();
    assert!(steps > 0);
    assert_eq!(
        t_all.frames_rendered, steps,
        "every step rendered its frame"
    );
    assert_eq!(
        serde_json::to_value(&all.rollouts).unwrap(),
        serde_json::to_value(&skipping.rollouts).unwrap(),
        "skipping unseen frames changed a rollout"
    );
    // Per query of 4 steps, the frames of the 2 steps with 3 and 2 actions
    // still queued are skipped.
    assert_eq!(t_skip.frames_rendered, steps / 2, "{t_skip:?}");
    // The policy depends on the pixels: the TCP moved differently per context.
    let finals: Vec<_> = all
        .rollouts
        .iter()
        .map(|r| serde_json::to_string(r).unwrap())
        .collect();
    assert!(finals.windows(2).any(|w| w[0] != w[1]));
}
