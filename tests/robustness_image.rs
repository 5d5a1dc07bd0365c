//! The image axes of the robustness track (issue 40): `camera` and
//! `lighting` of Aligning's image suite, with the image fixture
//! `aligning_image` and a few steps. Level 0 of both axes (a zero setting
//! through the perturbation's recompile) draws the plain frames bit for bit
//! and evaluates as the plain evaluation; a camera level moves both policy
//! cameras by exactly its offset and changes their frames; the lighting
//! levels darken the frames level by level; a perturbed image rollout
//! replays with `d3il replay --level AXIS/N`, video included.

use d3il_evaluator::camera::camera_ids;
use d3il_evaluator::eval::{evaluate, evaluate_perturbed, sha256_hex, EvalOptions, PolicyInfo};
use d3il_evaluator::fidelity::frames::our_frames;
use d3il_evaluator::perturb::{Active, Suite};
use d3il_evaluator::perturb_view::{quat_mat, tilt_about_y, turned_quat};
use d3il_evaluator::robustness::{evaluate_suite, plan, SuiteObserver};
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::OnnxPolicy;
use d3il_protocol::perturbation::{Axis, LevelSetting, Perturbation};
use d3il_protocol::{EvalResult, ObsType, ProtocolKind, TaskId};
use d3il_test_support::{fixture_manifest, fixtures_dir};

const FIXTURE: &str = "aligning_image";

fn image_task() -> LoadedTask {
    LoadedTask::load_obs(TaskId::Aligning, ObsType::Image).unwrap()
}

fn suite() -> Suite {
    Suite::current(TaskId::Aligning, ObsType::Image).unwrap()
}

fn policy(task: &LoadedTask) -> (OnnxPolicy, PolicyInfo) {
    let bytes = std::fs::read(fixtures_dir().join(format!("{FIXTURE}.onnx"))).unwrap();
    let policy = OnnxPolicy::load(&bytes, &fixture_manifest(FIXTURE), &task.spec(), 0).unwrap();
    let info = PolicyInfo {
        sha256: sha256_hex(&bytes),
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

fn at(axis: Axis, setting: LevelSetting) -> Perturbation {
    let s = suite();
    Perturbation {
        suite: s.name,
        suite_sha256: s.sha256,
        axis,
        level: 1,
        setting,
    }
}

fn perturbed(task: &LoadedTask, p: &Perturbation) -> LoadedTask {
    Active::new(p, TaskId::Aligning)
        .unwrap()
        .task(task)
        .unwrap()
}

/// The suite's levels of `axis`.
fn levels(axis: Axis) -> Vec<Perturbation> {
    let l: Vec<_> = suite()
        .perturbations()
        .into_iter()
        .filter(|p| p.axis == axis)
        .collect();
    assert_eq!(l.len(), 3, "small, medium, large");
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

#[test]
fn level_zero_of_the_image_axes_is_the_plain_evaluation_bit_for_bit() {
    let task = image_task();
    let plain_frames = our_frames(&task, 0, 96).unwrap();
    let (mut pol, info) = policy(&task);
    let (plain, _) = evaluate(&task, &mut pol, &info, &opts(), &mut |_, _| {}).unwrap();
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
        let p = at(axis, setting);
        let moved = perturbed(&task, &p);
        assert!(
            !std::sync::Arc::ptr_eq(&moved.model, &task.model),
            "{axis}: the scene is compiled afresh"
        );
        assert_eq!(
            our_frames(&moved, 0, 96).unwrap(),
            plain_frames,
            "{axis}: level 0 drew other frames"
        );
        let (r, _) =
            evaluate_perturbed(&task, &mut pol, &info, &opts(), &p, &mut |_, _| {}).unwrap();
        assert_eq!(comparable(&r), comparable(&plain), "{axis}");
    }
}

#[test]
fn camera_levels_move_both_cameras_by_exactly_the_offset_and_change_their_frames() {
    let task = image_task();
    let ctx = task.def.context_set().unwrap().get(0).unwrap().clone();
    let mut plain = task.env().unwrap();
    plain.reset(&ctx).unwrap();
    let plain_frames = our_frames(&task, 0, 96).unwrap();
    let cams = camera_ids(&task.model).unwrap();
    let mut moved_pixels = vec![];
    for p in levels(Axis::Camera) {
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
                assert!((x1[i] - want).abs() < 1e-12, "camera {c} level {}", p.level);
                // Then turned in its own frame: R' = R·R_turn.
                for j in 0..3 {
                    let want = (0..3).map(|k| m0[3 * i + k] * turn[3 * k + j]).sum::<f64>();
                    assert!((m1[3 * i + j] - want).abs() < 1e-12, "camera {c}");
                }
            }
        }
        let frames = our_frames(&moved, 0, 96).unwrap();
        for cam in 0..2 {
            let changed = frames[cam]
                .iter()
                .zip(&plain_frames[cam])
                .filter(|(a, b)| a != b)
                .count();
            assert!(changed > 0, "level {} left camera {cam} alone", p.level);
            moved_pixels.push(changed);
        }
    }
    // Each larger level changes more of the front view than the one before.
    assert!(
        moved_pixels[0] < moved_pixels[2] && moved_pixels[2] < moved_pixels[4],
        "{moved_pixels:?}"
    );
}

#[test]
fn lighting_levels_darken_the_frames_level_by_level() {
    let task = image_task();
    let plain = our_frames(&task, 0, 96).unwrap();
    let light0 = task.model.lights();
    let mut last = [mean(&plain[0]), mean(&plain[1])];
    for p in levels(Axis::Lighting) {
        let moved = perturbed(&task, &p);
        let s = &p.setting;
        for ((c0, d0), (c1, d1)) in light0.iter().zip(moved.model.lights()) {
            assert_eq!(c1, c0.map(|v| v * s.light_scale.unwrap() as f32));
            let want = tilt_about_y(*d0, s.light_tilt_deg.unwrap().to_radians());
            assert!((0..3).all(|k| (d1[k] - want[k]).abs() < 1e-12));
        }
        let frames = our_frames(&moved, 0, 96).unwrap();
        for cam in 0..2 {
            let m = mean(&frames[cam]);
            assert!(
                m < last[cam],
                "level {} camera {cam}: mean {m} is not below {}",
                p.level,
                last[cam]
            );
            last[cam] = m;
        }
    }
    // Recognizable: the largest level keeps more than half the brightness.
    assert!(last[0] > 0.5 * mean(&plain[0]), "{last:?}");
}

struct Quiet;
impl SuiteObserver for Quiet {
    fn progress(&mut self, _: usize, _: usize) {}
}

#[test]
fn a_perturbed_image_rollout_replays_on_the_command_line() {
    use std::process::Command;
    let task = image_task();
    let (mut pol, info) = policy(&task);
    let s = suite();
    let o = opts();
    let plan = plan(&task, &pol, &o, &s).unwrap();
    let doc = evaluate_suite(&task, &mut pol, &info, &o, &s, &plan, &mut Quiet).unwrap();
    let dir = std::env::temp_dir().join(format!("d3il-robustness-image-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("r.json");
    std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
    for (level, video) in [
        ("camera/3", true),
        ("lighting/3", false),
        ("latency/2", false),
    ] {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_d3il"));
        cmd.args(["replay", "--result"])
            .arg(&file)
            .args(["--level", level, "--rollout", "1"]);
        if video {
            cmd.arg("--video").arg(dir.join("v.mp4"));
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{level}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert!(std::fs::metadata(dir.join("v.mp4")).unwrap().len() > 0);
    std::fs::remove_dir_all(&dir).unwrap();
}
