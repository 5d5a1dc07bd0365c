//! The Panda hand and finger meshes change the picture only: with the meshed
//! look (visual-only mesh geoms, collision boxes hidden in group 3) the same
//! actions give bit-identical states to the primitive look, and the bodies'
//! masses and inertias are unchanged. The meshes come from example-robot-data,
//! which ./dev installs and converts before the build (docs/images.md).

use d3il_evaluator::sim::scene::RobotLook;
use d3il_evaluator::tasks::{Env, LoadedTask};
use d3il_protocol::{ObsType, TaskId};

fn env(task: TaskId, look: RobotLook) -> (LoadedTask, Env) {
    let t = LoadedTask::load_look(task, ObsType::State, look).unwrap();
    let set = t.def.context_set().unwrap();
    let mut env = t.env().unwrap();
    env.reset(set.get(1).unwrap()).unwrap();
    (t, env)
}

#[test]
fn this_build_has_the_meshes() {
    assert!(
        RobotLook::meshes_available(),
        "assets/meshes/panda_{{hand,finger}}.obj were missing when the evaluator was built: \
         run ./dev test (it installs example-robot-data and runs scripts/panda_meshes.py)"
    );
}

#[test]
fn meshes_change_no_physics() {
    for task in [TaskId::Aligning, TaskId::Stacking] {
        let (tp, mut prim) = env(task, RobotLook::Primitives);
        let (tm, mut mesh) = env(task, RobotLook::Meshes);
        assert_ne!(
            tp.mjcf_sha256, tm.mjcf_sha256,
            "{task}: the scenes are the same"
        );
        assert_eq!(tp.model.ngeom(), tm.model.ngeom());
        assert_eq!(tp.model.body_mass(), tm.model.body_mass(), "{task}: masses");
        let act_dim = tp.def.act_dim();
        for step in 0..60 {
            // Small smooth deltas (Aligning) or a slow joint motion (Stacking).
            let a: Vec<f32> = (0..act_dim)
                .map(|i| 0.004 * ((step as f32) * 0.1 + i as f32).sin())
                .collect();
            let op = prim.step(&a).unwrap();
            let om = mesh.step(&a).unwrap();
            assert_eq!(op.done, om.done);
            assert_eq!(
                prim.sim.data.qpos(),
                mesh.sim.data.qpos(),
                "{task}: qpos differs at step {step}"
            );
            assert_eq!(prim.sim.data.qvel(), mesh.sim.data.qvel());
            if op.done {
                break;
            }
        }
    }
}
