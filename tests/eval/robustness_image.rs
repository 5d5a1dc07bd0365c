//! The image suites of the robustness track (issue 40), table-driven over
//! every task with an image variant (Aligning, Sorting-4, Sorting-6,
//! Stacking): each has an image suite with its state suite's start_shift,
//! latency and dynamics levels and the shared camera and lighting levels,
//! acting on both policy cameras and the scene's light. Level 0 of both
//! image axes (a zero setting through the perturbation's recompile) draws
//! the plain frames bit for bit and evaluates as the plain evaluation; a
//! camera level moves both policy cameras by exactly its offset, changes
//! their frames and keeps every object in the front view; the lighting
//! levels darken the frames level by level; perturbed image rollouts replay
//! with `d3il replay --level AXIS/N`, video included.
//!
//! Policies: Aligning's image fixture `aligning_image` (ONNX); for the
//! other tasks, which have no image fixture, [`PixelPolicy`], whose actions
//! are a function of the mean of each camera's frame (so any changed pixel
//! changes the rollout). A few steps and the quick protocol's three initial
//! states keep the rendering cheap.

use d3il_evaluator::camera::{camera_ids, project, CAMERAS};
use d3il_evaluator::eval::{evaluate, sha256_hex, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::fidelity::frames::our_frames;
use d3il_evaluator::perturb::{Active, Suite};
use d3il_evaluator::perturb_view::{quat_mat, tilt_about_y, turned_quat};
use d3il_evaluator::robustness::{evaluate_suite, plan, SuiteObserver};
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{ActionChunks, OnnxPolicy, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::perturbation::{Axis, LevelSetting, Perturbation};
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, TaskId};
use d3il_test_support::{fixture_manifest, fixtures_dir};

/// Every task with an image variant.
fn image_tasks() -> Vec<TaskId> {
    TaskId::ALL
        .into_iter()
        .filter(|t| t.has_image_variant())
        .collect()
}

fn image_task(id: TaskId) -> LoadedTask {
    LoadedTask::load_obs(id, ObsType::Image).unwrap()
}

fn suite(id: TaskId) -> Suite {
    Suite::current(id, ObsType::Image).unwrap_or_else(|e| panic!("{id}: {e}"))
}

/// A deterministic image policy for tasks without an image fixture: the
/// task's hold action (zero deltas; Stacking's gripper open) plus, on the
/// first two action entries, a small step proportional to the mean of the
/// front and of the in-hand frame, so the rollout depends on every pixel.
struct PixelPolicy {
    shape: PolicyShape,
    hold: Vec<f32>,
}

impl Policy for PixelPolicy {
    fn shape(&self) -> PolicyShape {
        self.shape
    }
    fn reset(&mut self, _: &[u64]) -> Result<(), PolicyError> {
        Ok(())
    }
    fn infer(&mut self, query: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        let images = query.images.expect("an image policy gets images");
        let per_camera = d3il_policy::IMAGE_LEN / 2;
        let mut data = vec![];
        for row in images.chunks(d3il_policy::IMAGE_LEN) {
            let mut action = self.hold.clone();
            for (cam, pixels) in row.chunks(per_camera).enumerate() {
                let mean = pixels.iter().sum::<f32>() / per_camera as f32;
                action[cam] += 0.01 * (mean - 0.5);
            }
            data.extend(action);
        }
        Ok(ActionChunks {
            batch: query.batch(),
            horizon: 1,
            act_dim: self.shape.act_dim,
            data,
        })
    }
    fn deterministic(&self) -> bool {
        true
    }
}

/// The image policy the test runs on `task`, and what the manifest records.
fn policy(task: &LoadedTask) -> (Box<dyn Policy>, PolicyInfo) {
    let id = task.def.id();
    let (policy, sha256): (Box<dyn Policy>, String) = if id == TaskId::Aligning {
        let fixture = "aligning_image";
        let bytes = std::fs::read(fixtures_dir().join(format!("{fixture}.onnx"))).unwrap();
        let p = OnnxPolicy::load(&bytes, &fixture_manifest(fixture), &task.spec(), 0).unwrap();
        (Box::new(p), sha256_hex(&bytes))
    } else {
        let spec = task.spec();
        let p = PixelPolicy {
            shape: PolicyShape {
                history: 1,
                horizon: 1,
                execute: 1,
                obs_dim: spec.obs_dim,
                act_dim: spec.act_dim,
                obs_type: ObsType::Image,
            },
            hold: task.def.command_kind().hold(),
        };
        (
            Box::new(p),
            sha256_hex(b"tests/robustness_image.rs PixelPolicy"),
        )
    };
    let info = PolicyInfo {
        sha256,
        obs_type: ObsType::Image,
    };
    (policy, info)
}

fn opts() -> EvalOptions {
    EvalOptions {
        protocol: ProtocolKind::Quick,
        bootstrap_resamples: 10,
        step_cap: Some(4),
        ..EvalOptions::default()
    }
}

fn at(id: TaskId, axis: Axis, setting: LevelSetting) -> Perturbation {
    let s = suite(id);
    Perturbation {
        suite: s.name,
        suite_sha256: s.sha256,
        axis,
        level: 1,
        setting,
    }
}

fn perturbed(task: &LoadedTask, p: &Perturbation) -> LoadedTask {
    Active::new(p, task.def.id()).unwrap().task(task).unwrap()
}

/// The suite's levels of `axis`.
fn levels(id: TaskId, axis: Axis) -> Vec<Perturbation> {
    let l: Vec<_> = suite(id)
        .perturbations()
        .into_iter()
        .filter(|p| p.axis == axis)
        .collect();
    assert_eq!(l.len(), 3, "{id}: small, medium, large");
    l
}

fn comparable(r: &EvalResult) -> serde_json::Value {
    let mut v = serde_json::to_value(r).unwrap();
    v["metrics"]["inference_ms"] = serde_json::Value::Null;
    v["manifest"]
        .as_object_mut()
        .unwrap()
        .remove("perturbation");
    v
}

fn mean(pixels: &[u8]) -> f64 {
    pixels.iter().map(|&p| p as f64).sum::<f64>() / pixels.len() as f64
}

/// An axis's levels as the file gives them.
fn axis_levels(s: &Suite, axis: Axis) -> Option<Vec<LevelSetting>> {
    s.file
        .axes
        .iter()
        .find(|a| a.axis == axis)
        .map(|a| a.levels.clone())
}

#[test]
fn every_image_variant_has_a_suite_of_its_state_levels_and_the_shared_image_levels() {
    let aligning = suite(TaskId::Aligning);
    for id in image_tasks() {
        let s = suite(id);
        let f = &s.file;
        assert_eq!(f.obs_type, ObsType::Image, "{id}");
        assert_eq!(f.cameras, CAMERAS, "{id}: both policy cameras");
        let axes: Vec<Axis> = f.axes.iter().map(|a| a.axis).collect();
        assert_eq!(
            axes,
            [
                Axis::StartShift,
                Axis::Latency,
                Axis::Dynamics,
                Axis::Camera,
                Axis::Lighting
            ],
            "{id}: no obs_noise"
        );
        // The levels of the task's current state suite (Aligning and
        // Stacking v2, Sorting v1).
        let state = Suite::for_task(id).unwrap();
        for axis in [Axis::StartShift, Axis::Latency, Axis::Dynamics] {
            assert_eq!(
                axis_levels(&s, axis),
                axis_levels(&state, axis),
                "{id} {axis}"
            );
        }
        assert_eq!(
            json(&f.start_shift_fields),
            json(&state.file.start_shift_fields)
        );
        assert_eq!(
            json(&f.start_shift_regions),
            json(&state.file.start_shift_regions)
        );
        assert_eq!(
            (&f.dynamics_bodies, &f.table_geom),
            (&state.file.dynamics_bodies, &state.file.table_geom)
        );
        for axis in [Axis::Camera, Axis::Lighting] {
            assert_eq!(axis_levels(&s, axis), axis_levels(&aligning, axis), "{id}");
        }
        // What the image axes act on is in the task's image scene.
        let task = image_task(id);
        camera_ids(&task.model).unwrap();
        assert!(!task.model.lights().is_empty(), "{id}: a light to dim");
    }
}

/// A suite field serialised, for comparison (the file's types are not
/// `PartialEq`).
fn json<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap()
}

#[test]
fn level_zero_of_the_image_axes_is_the_plain_evaluation_bit_for_bit() {
    for id in image_tasks() {
        let task = image_task(id);
        let plain_frames = our_frames(&task, 0, 96).unwrap();
        let (mut pol, info) = policy(&task);
        let (plain, _) = evaluate(&task, &mut *pol, &info, &opts(), EvalRun::all()).unwrap();
        for (axis, setting) in [
            (
                Axis::Camera,
                LevelSetting {
                    camera_shift_m: Some([0.0; 3]),
                    camera_turn_deg: Some([0.0; 3]),
                    ..Default::default()
                },
            ),
            (
                Axis::Lighting,
                LevelSetting {
                    light_scale: Some(1.0),
                    light_tilt_deg: Some(0.0),
                    ..Default::default()
                },
            ),
        ] {
            let p = at(id, axis, setting);
            let moved = perturbed(&task, &p);
            assert!(
                !std::sync::Arc::ptr_eq(&moved.model, &task.model),
                "{id} {axis}: the scene is compiled afresh"
            );
            assert_eq!(
                our_frames(&moved, 0, 96).unwrap(),
                plain_frames,
                "{id} {axis}: level 0 drew other frames"
            );
            let (r, _) = evaluate(
                &task,
                &mut *pol,
                &info,
                &opts(),
                EvalRun::all().perturbed(&p),
            )
            .unwrap();
            assert_eq!(comparable(&r), comparable(&plain), "{id} {axis}");
        }
    }
}

#[test]
fn camera_levels_move_both_cameras_by_exactly_the_offset_and_change_their_frames() {
    for id in image_tasks() {
        let task = image_task(id);
        let ctx = task.def.context_set().unwrap().get(0).unwrap().clone();
        let mut plain = task.env().unwrap();
        plain.reset(&ctx).unwrap();
        let plain_frames = our_frames(&task, 0, 96).unwrap();
        let cams = camera_ids(&task.model).unwrap();
        // Objects well inside a view at level 0 (centre at least `margin`
        // pixels from the border): the front view shows every object.
        let inside = |env: &d3il_evaluator::tasks::Env, cam: usize, margin: f64| {
            env.objects()
                .into_iter()
                .filter(|(_, p)| {
                    project(&env.sim.data, cams[cam], *p, 96).is_some_and(|(u, v)| {
                        (margin..96.0 - margin).contains(&u) && (margin..96.0 - margin).contains(&v)
                    })
                })
                .map(|(name, _)| name)
                .collect::<Vec<_>>()
        };
        let objects: Vec<String> = plain.objects().into_iter().map(|o| o.0).collect();
        assert_eq!(inside(&plain, 0, 4.0), objects, "{id}: the front view");
        let in_hand = inside(&plain, 1, 10.0);
        let mut moved_pixels = vec![];
        for p in levels(id, Axis::Camera) {
            let shift = p.setting.camera_shift_m.unwrap();
            let turn = quat_mat(turned_quat(
                [1.0, 0.0, 0.0, 0.0],
                p.setting.camera_turn_deg.unwrap(),
            ));
            let moved = perturbed(&task, &p);
            let mut env = moved.env().unwrap();
            env.reset(&ctx).unwrap();
            for &c in &cams {
                let (x0, m0) = (plain.sim.data.cam_xpos(c), plain.sim.data.cam_xmat(c));
                let (x1, m1) = (env.sim.data.cam_xpos(c), env.sim.data.cam_xmat(c));
                for i in 0..3 {
                    // Moved along its own axes (the columns of its old frame).
                    let want = x0[i] + (0..3).map(|j| m0[3 * i + j] * shift[j]).sum::<f64>();
                    assert!(
                        (x1[i] - want).abs() < 1e-12,
                        "{id}: camera {c} level {}",
                        p.level
                    );
                    // Then turned in its own frame: R' = R·R_turn.
                    for j in 0..3 {
                        let want = (0..3).map(|k| m0[3 * i + k] * turn[3 * k + j]).sum::<f64>();
                        assert!((m1[3 * i + j] - want).abs() < 1e-12, "{id}: camera {c}");
                    }
                }
            }
            // Recognizable: every object still in the front view, and the
            // objects well inside the in-hand view at level 0 still in it.
            assert_eq!(inside(&env, 0, 4.0), objects, "{id} level {}", p.level);
            let kept = inside(&env, 1, 0.0);
            assert!(
                in_hand.iter().all(|o| kept.contains(o)),
                "{id} level {}: in-hand {in_hand:?} -> {kept:?}",
                p.level
            );
            let frames = our_frames(&moved, 0, 96).unwrap();
            for cam in 0..2 {
                let changed = frames[cam]
                    .iter()
                    .zip(&plain_frames[cam])
                    .filter(|(a, b)| a != b)
                    .count();
                assert!(
                    changed > 0,
                    "{id}: level {} left camera {cam} alone",
                    p.level
                );
                moved_pixels.push(changed);
            }
        }
        // Each larger level changes more of the front view than the one before.
        assert!(
            moved_pixels[0] < moved_pixels[2] && moved_pixels[2] < moved_pixels[4],
            "{id}: {moved_pixels:?}"
        );
    }
}

#[test]
fn lighting_levels_darken_the_frames_level_by_level() {
    for id in image_tasks() {
        let task = image_task(id);
        let plain = our_frames(&task, 0, 96).unwrap();
        let light0 = task.model.lights();
        let mut last = [mean(&plain[0]), mean(&plain[1])];
        for p in levels(id, Axis::Lighting) {
            let moved = perturbed(&task, &p);
            let s = &p.setting;
            let lights = moved.model.lights();
            assert_eq!(lights.len(), light0.len());
            for ((c0, d0), (c1, d1)) in light0.iter().zip(lights) {
                assert_eq!(c1, c0.map(|v| v * s.light_scale.unwrap() as f32));
                let want = tilt_about_y(*d0, s.light_tilt_deg.unwrap().to_radians());
                assert!((0..3).all(|k| (d1[k] - want[k]).abs() < 1e-12));
            }
            let frames = our_frames(&moved, 0, 96).unwrap();
            for cam in 0..2 {
                let m = mean(&frames[cam]);
                assert!(
                    m < last[cam],
                    "{id} level {} camera {cam}: mean {m} is not below {}",
                    p.level,
                    last[cam]
                );
                last[cam] = m;
            }
        }
        // Recognizable: the largest level keeps more than half the brightness.
        for cam in 0..2 {
            assert!(last[cam] > 0.5 * mean(&plain[cam]), "{id}: {last:?}");
        }
    }
}

struct Quiet;
impl SuiteObserver for Quiet {
    fn progress(&mut self, _: usize, _: usize) {}
}

/// `d3il replay --result FILE [--level AXIS/N] --rollout 1` (with
/// `--video` when asked) succeeds: the rollout replays bit for bit.
fn replays(file: &std::path::Path, level: Option<&str>, video: Option<&std::path::Path>) {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_d3il"));
    cmd.args(["replay", "--result"]).arg(file);
    if let Some(level) = level {
        cmd.args(["--level", level]);
    }
    cmd.args(["--rollout", "1"]);
    if let Some(video) = video {
        cmd.arg("--video").arg(video);
    }
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{} {level:?}: {}{}",
        file.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    if let Some(video) = video {
        assert!(std::fs::metadata(video).unwrap().len() > 0);
    }
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "d3il-robustness-image-{name}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Aligning's whole image suite, and a level of each axis replayed from
/// the robustness document with `--level`.
#[test]
fn a_perturbed_image_rollout_replays_on_the_command_line() {
    let task = image_task(TaskId::Aligning);
    let (mut pol, info) = policy(&task);
    let s = suite(TaskId::Aligning);
    let o = opts();
    let plan = plan(&task, &*pol, &o, &s).unwrap();
    let doc = evaluate_suite(&task, &mut *pol, &info, &o, &s, &plan, &mut Quiet).unwrap();
    let dir = temp_dir("aligning");
    let file = dir.join("r.json");
    std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
    replays(&file, Some("camera/3"), Some(&dir.join("v.mp4")));
    replays(&file, Some("lighting/3"), None);
    replays(&file, Some("latency/2"), None);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The other image tasks: a perturbed result of the large camera level
/// (with its video), the large lighting level and the second latency level
/// (Sorting 1 step; Stacking 0.9 steps, its joint increments blended,
/// `CommandKind::blend_late`) each replays
/// from its own manifest's perturbation. Level by level rather than the
/// whole suite: each evaluation costs a scene compile and a renderer,
/// whatever its steps, and the `--level` path is Aligning's above.
#[test]
fn perturbed_image_rollouts_of_sorting_and_stacking_replay_on_the_command_line() {
    for id in image_tasks().into_iter().filter(|&t| t != TaskId::Aligning) {
        let task = image_task(id);
        let (mut pol, info) = policy(&task);
        let dir = temp_dir(id.slug());
        let all = suite(id).perturbations();
        for (axis, level, video) in [
            (Axis::Camera, 3, true),
            (Axis::Lighting, 3, false),
            (Axis::Latency, 2, false),
        ] {
            let p = all
                .iter()
                .find(|p| p.axis == axis && p.level == level)
                .unwrap();
            let (r, _) = evaluate(
                &task,
                &mut *pol,
                &info,
                &opts(),
                EvalRun::all().perturbed(p),
            )
            .unwrap();
            assert_eq!(r.manifest.perturbation.as_ref(), Some(p), "{id}");
            let file = dir.join(format!("{axis}.json"));
            std::fs::write(&file, serde_json::to_vec(&r).unwrap()).unwrap();
            replays(&file, None, video.then(|| dir.join("v.mp4")).as_deref());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
