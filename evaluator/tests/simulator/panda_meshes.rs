//! The Panda meshes (links, hand, fingers) change the picture only: with the
//! meshed look (visual-only mesh geoms, primitive collision geoms hidden in
//! group 3) the same actions give bit-identical states to the primitive look,
//! and the bodies' masses and inertias are unchanged. And the reduced meshes
//! compiled in draw the frames the full meshes draw, to within a small
//! difference. The meshes come from example-robot-data, which ./dev installs
//! and converts before the build (docs/images.md).

use d3il_evaluator::sim::scene::{meshes_available, RobotLook};
use d3il_evaluator::tasks::{task_def, Env, LoadedTask};
use d3il_protocol::{ObsType, TaskId};
use std::path::Path;

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
        meshes_available(),
        "assets/meshes/panda_*.obj were missing when the evaluator was built: \
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
        // The same geoms: each visual geom becomes its mesh (the links' two
        // drawings are one blend, docs/images.md), no geom is added.
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

/// The front view (`bp_cam`, where the arm is) of a task's image variant in
/// `task`, after reset to context 0 and 30 zero-action steps, as RGB bytes.
fn front_view(task: LoadedTask) -> Vec<u8> {
    let set = task.def.context_set().unwrap();
    let mut env = task.env().unwrap();
    env.reset(set.get(0).unwrap()).unwrap();
    let zero = vec![0.0f32; task.def.act_dim()];
    for _ in 0..30 {
        env.step(&zero).unwrap();
    }
    let images = env.policy_images().unwrap();
    let plane = 96 * 96;
    // Camera 0, [3, 96, 96] BGR in [0, 1].
    (0..plane)
        .flat_map(|i| (0..3).rev().map(move |c| c * plane + i))
        .map(|k| (images[k] * 255.0).round() as u8)
        .collect()
}

/// (mean |difference| over all channels in 1/255, share of pixels where some
/// channel differs by more than 8).
fn difference(a: &[u8], b: &[u8]) -> (f64, f64) {
    let mean = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum::<f64>()
        / a.len() as f64;
    let pixels = a.len() / 3;
    let far = a
        .chunks(3)
        .zip(b.chunks(3))
        .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > 8))
        .count();
    (mean, far as f64 / pixels as f64)
}

/// The links are compiled in reduced to 2 000 triangles each and the hand to
/// 3 000 (scripts/panda_meshes.py, MeshLab's quadric edge collapse, MuJoCo's
/// own vertex normals): the full meshes (12 000-22 000 triangles per link) cost
/// the front view about 9 times its rendering time. The frames stay those of
/// the full meshes to within a mean of 0.45/255 and 1.5% of pixels differing
/// by more than 8/255 (measured 0.29-0.31 and 1.1%; with the 1 000
/// fast-simplification triangles before, 0.78-0.90 and 3.6-4.3%), while the
/// primitive capsules and boxes are much further from them (the test checks
/// that it can tell).
#[test]
fn reduced_meshes_draw_the_frames_of_the_full_meshes() {
    let full_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/meshes/full");
    let full: Vec<(String, String)> = std::fs::read_dir(&full_dir)
        .unwrap_or_else(|e| {
            panic!(
                "{}: {e}; run ./dev test (scripts/panda_meshes.py writes the full meshes there)",
                full_dir.display()
            )
        })
        .map(|e| e.unwrap().path())
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect();
    assert_eq!(full.len(), 10, "links 0-7, hand and finger");
    for id in [TaskId::Aligning, TaskId::Stacking, TaskId::Sorting4] {
        let reduced =
            front_view(LoadedTask::load_look(id, ObsType::Image, RobotLook::Meshes).unwrap());
        let primitive =
            front_view(LoadedTask::load_look(id, ObsType::Image, RobotLook::Primitives).unwrap());
        let def = task_def(id).unwrap();
        let mut scene = def.scene();
        scene.look = RobotLook::Meshes;
        scene.meshes = full.clone();
        let fine = front_view(LoadedTask::from_scene(def, scene, ObsType::Image).unwrap());
        let (mean, far) = difference(&reduced, &fine);
        assert!(
            mean < 0.45 && far < 0.015,
            "{id}: reduced meshes differ from the full ones by {mean:.2}/255 on average, \
             {:.1}% of pixels by more than 8",
            100.0 * far
        );
        let (pmean, pfar) = difference(&primitive, &fine);
        eprintln!(
            "{id}: against the full meshes, reduced {mean:.2}/255 and {:.1}% of pixels > 8, \
             primitives {pmean:.2}/255 and {:.1}%",
            100.0 * far,
            100.0 * pfar
        );
        assert!(
            pmean > 2.0 * mean && pfar > 2.0 * far,
            "{id}: the primitive robot ({pmean:.2}, {:.1}%) should be much further from the \
             full meshes than the reduced ones ({mean:.2}, {:.1}%)",
            100.0 * pfar,
            100.0 * far
        );
    }
}
