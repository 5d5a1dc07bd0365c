//! Headless rendering of the two policy cameras (docs/original-d3il.md §01.6) on Mesa's EGL:
//! frames are not blank, objects appear where their projected positions say,
//! and rendering is deterministic for the same state.

use d3il_evaluator::camera::{self, CAMERAS, OBS_LEN, SIZE};
use d3il_evaluator::tasks::{Env, LoadedTask};
use d3il_protocol::{ObsType, TaskId};

fn image_env(task: TaskId, context: usize) -> (LoadedTask, Env) {
    let t = LoadedTask::load_obs(task, ObsType::Image).unwrap();
    let set = t.def.context_set().unwrap();
    let mut env = t.env().unwrap();
    env.reset(set.get(context).unwrap()).unwrap();
    (t, env)
}

/// Pixel (B, G, R) of camera `cam` at column `u`, row `v` (top-down) of a
/// policy image observation `[2, 3, 96, 96]`.
fn bgr(images: &[f32], cam: usize, u: usize, v: usize) -> [f32; 3] {
    let plane = SIZE * SIZE;
    let base = cam * 3 * plane + v * SIZE + u;
    [images[base], images[base + plane], images[base + 2 * plane]]
}

fn channel_std(images: &[f32], cam: usize) -> f32 {
    let n = 3 * SIZE * SIZE;
    let px = &images[cam * n..(cam + 1) * n];
    let mean = px.iter().sum::<f32>() / n as f32;
    (px.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n as f32).sqrt()
}

#[test]
fn both_cameras_render_non_blank_frames_in_the_policy_layout() {
    for task in [
        TaskId::Aligning,
        TaskId::Sorting4,
        TaskId::Sorting6,
        TaskId::Stacking,
    ] {
        let (t, env) = image_env(task, 0);
        let images = env.policy_images().expect("image variant");
        assert_eq!(images.len(), OBS_LEN, "{task}: [2, 3, 96, 96] floats");
        assert!(
            images.iter().all(|v| (0.0..=1.0).contains(v)),
            "{task}: scaled to [0, 1]"
        );
        for (cam, name) in CAMERAS.iter().enumerate() {
            let sd = channel_std(images, cam);
            assert!(sd > 0.05, "{task} camera {name}: blank frame (std {sd})");
        }
        // The image variant's low-dimensional input is the previous command.
        assert_eq!(env.policy_obs().len(), t.def.cmd_dim(), "{task}");
    }
}

#[test]
fn boxes_appear_where_their_projection_says() {
    let (_t, env) = image_env(TaskId::Sorting4, 0);
    let images = env.policy_images().unwrap();
    let bp = env
        .sim
        .data
        .model()
        .id(d3il_evaluator::mujoco::ObjKind::Camera, "bp_cam")
        .unwrap();
    let objects = env.objects();
    assert_eq!(objects.len(), 4);
    let mut checked = 0;
    for (name, pos) in objects {
        let (u, v) = camera::project(&env.sim.data, bp, pos, SIZE).expect("in front of bp_cam");
        assert!(
            (0.0..SIZE as f64).contains(&u) && (0.0..SIZE as f64).contains(&v),
            "{name} projects to ({u:.1}, {v:.1}), outside the frame"
        );
        let [b, g, r] = bgr(images, 0, u as usize, v as usize);
        if name.contains("red") {
            assert!(
                r > b + 0.15 && r > g + 0.15,
                "{name} at ({u:.0},{v:.0}) is not red: bgr {b:.2} {g:.2} {r:.2}"
            );
        } else {
            assert!(name.contains("blue"), "unexpected object {name}");
            assert!(
                b > r + 0.15 && b > g + 0.15,
                "{name} at ({u:.0},{v:.0}) is not blue: bgr {b:.2} {g:.2} {r:.2}"
            );
        }
        checked += 1;
    }
    assert_eq!(checked, 4);
}

#[test]
fn in_hand_camera_sees_the_rod_at_the_bottom_centre() {
    // docs/original-d3il.md §01.6: with the hand pointing down, the in-hand camera looks
    // straight down and the rod is visible at the bottom centre.
    let (_t, env) = image_env(TaskId::Aligning, 0);
    let images = env.policy_images().unwrap();
    let rod = bgr(images, 1, SIZE / 2, SIZE - 3);
    let floor = bgr(images, 1, SIZE / 2, SIZE / 2);
    let lum = |p: [f32; 3]| p.iter().sum::<f32>() / 3.0;
    assert!(
        lum(rod) + 0.2 < lum(floor),
        "expected the dark rod at the bottom centre: rod {rod:?}, centre {floor:?}"
    );
}

#[test]
fn rendering_is_deterministic_for_the_same_state() {
    let (_t, mut env) = image_env(TaskId::Aligning, 3);
    let first = env.policy_images().unwrap().to_vec();
    // Same state, fresh render on this thread.
    let cams = camera::camera_ids(env.sim.data.model()).unwrap();
    let mut again = Vec::new();
    camera::capture(&mut env.sim.data, &cams, &mut again).unwrap();
    assert_eq!(first, again, "re-rendering the same state changed pixels");
    // Same context in another Env on another thread (its own GL context).
    let other = std::thread::spawn(|| {
        let (_t, env) = image_env(TaskId::Aligning, 3);
        env.policy_images().unwrap().to_vec()
    })
    .join()
    .unwrap();
    assert_eq!(
        first, other,
        "another thread's renderer gave different pixels"
    );
    // A different context gives a different picture.
    let (_t, env4) = image_env(TaskId::Aligning, 4);
    assert_ne!(first, env4.policy_images().unwrap());
}

#[test]
fn images_lag_like_the_state_observation() {
    // The observation returned by a step is rendered before that step's
    // physics (docs/original-d3il.md §01.4.2, §01.6): after one step the policy sees the reset
    // state's frame; after two, the first step's.
    let (_t, mut env) = image_env(TaskId::Aligning, 0);
    let at_reset = env.policy_images().unwrap().to_vec();
    let act = vec![0.01f32; env.def().act_dim()];
    env.step(&act).unwrap();
    assert_eq!(env.policy_images().unwrap(), at_reset.as_slice());
    for _ in 0..5 {
        env.step(&act).unwrap();
    }
    assert_ne!(
        env.policy_images().unwrap(),
        at_reset.as_slice(),
        "the arm moved 5 cm"
    );
}

#[test]
fn tasks_without_an_image_variant_are_refused() {
    let err = LoadedTask::load_obs(TaskId::Avoiding, ObsType::Image)
        .err()
        .unwrap();
    assert!(
        err.to_string().contains("no image-observation variant"),
        "{err}"
    );
}

/// Shadows are never drawn, so the context allocates no shadow map: the
/// spec's shadowsize 8192 would hold 256 MiB per thread's GL context.
#[test]
fn the_render_context_holds_no_shadow_map() {
    let t = LoadedTask::load_obs(TaskId::Aligning, ObsType::Image).unwrap();
    let r = d3il_evaluator::mujoco::Renderer::new(t.model.clone(), SIZE, SIZE).unwrap();
    assert_eq!(r.shadow_map_size(), 0);
}

/// Names of this process's threads (Linux).
fn thread_names() -> Vec<String> {
    std::fs::read_dir("/proc/self/task")
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .map(|n| n.trim().to_string())
        .collect()
}

#[test]
fn rendering_starts_no_rasterizer_threads() {
    // docs/images.md: LP_NUM_THREADS=0 unless the user set it, so a context
    // brings no pool of rasterizer threads of its own ("llvmpipe-N").
    if let Some(v) = std::env::var_os("LP_NUM_THREADS") {
        assert_eq!(
            v, "0",
            "this test checks the default; run it without LP_NUM_THREADS in the environment"
        );
    }
    let (t, mut env) = image_env(TaskId::Aligning, 0);
    let mut r = d3il_evaluator::mujoco::Renderer::new(t.model.clone(), SIZE, SIZE).unwrap();
    let mut rgb = vec![0u8; SIZE * SIZE * 3];
    r.render_raw(&mut env.sim.data, 0, &mut rgb).unwrap();
    let names = thread_names();
    assert!(
        !names.iter().any(|n| n.starts_with("llvmpipe-")),
        "llvmpipe started rasterizer threads: {names:?}"
    );
    assert_eq!(std::env::var("LP_NUM_THREADS").as_deref(), Ok("0"));
}

/// Geoms that the table top hides from a camera (the lab frame's feet under
/// the table) are left out of the frame: the frames are the same as with
/// them, over states of every image task in both looks, and the in-hand
/// camera, which sees nothing else of them, leaves them out.
#[test]
fn geoms_hidden_under_the_table_are_left_out_with_the_same_frames() {
    use d3il_evaluator::mujoco::Renderer;
    use d3il_evaluator::sim::scene::{best_look, RobotLook};
    for task in [
        TaskId::Aligning,
        TaskId::Sorting4,
        TaskId::Sorting6,
        TaskId::Stacking,
    ] {
        for look in [RobotLook::Primitives, best_look()] {
            // The state variant: its environment renders nothing itself.
            let t = LoadedTask::load_look(task, ObsType::State, look).unwrap();
            let set = t.def.context_set().unwrap();
            let cams = camera::camera_ids(&t.model).unwrap();
            let mut culled = Renderer::new(t.model.clone(), SIZE, SIZE).unwrap();
            let mut all = Renderer::new(t.model.clone(), SIZE, SIZE).unwrap();
            all.keep_hidden_geoms(true);
            let mut hidden_in_hand = 0;
            for context in 0..3 {
                let mut env = t.env().unwrap();
                env.reset(set.get(context).unwrap()).unwrap();
                for step in 0..40 {
                    if step % 10 == 0 {
                        for (k, &cam) in cams.iter().enumerate() {
                            let mut a = vec![0u8; SIZE * SIZE * 3];
                            let mut b = vec![0u8; SIZE * SIZE * 3];
                            culled.render_raw(&mut env.sim.data, cam, &mut a).unwrap();
                            all.render_raw(&mut env.sim.data, cam, &mut b).unwrap();
                            assert_eq!(all.hidden_geoms(), 0);
                            assert!(
                                a == b,
                                "{task} {look:?} context {context} step {step}: {} differs \
                                 without the {} hidden geoms",
                                CAMERAS[k],
                                culled.hidden_geoms()
                            );
                            if k == 1 {
                                hidden_in_hand += culled.hidden_geoms();
                            }
                        }
                    }
                    let act: Vec<f32> = (0..t.def.act_dim())
                        .map(|i| 0.004 * ((step as f32) * 0.1 + i as f32).sin())
                        .collect();
                    if env.step(&act).unwrap().done {
                        break;
                    }
                }
            }
            assert!(
                hidden_in_hand > 0,
                "{task} {look:?}: the in-hand camera left nothing out"
            );
        }
    }
}
