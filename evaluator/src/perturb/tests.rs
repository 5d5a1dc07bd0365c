use super::*;

#[test]
fn committed_suites_load_and_a_changed_byte_is_refused_naming_the_hash() {
    for task in TaskId::ALL {
        let current = Suite::for_task(task).unwrap().name;
        let version = match task {
            TaskId::Aligning | TaskId::Pushing | TaskId::Stacking => "v2",
            _ => "v1",
        };
        assert_eq!(
            current,
            format!("{}-{version}.json", task.slug()),
            "the current suite"
        );
    }
    assert_eq!(
        Suite::current(TaskId::Aligning, ObsType::Image)
            .unwrap()
            .name,
        "aligning-image-v1.json"
    );
    assert!(Suite::current(TaskId::Pushing, ObsType::Image).is_err());
    for &(task, _, name, bytes, sha) in SUITES {
        let s = Suite::named(task, name).unwrap();
        assert_eq!((s.name.as_str(), s.sha256.as_str()), (name, sha));
        assert!(!s.perturbations().is_empty());
        let mut changed = bytes.to_vec();
        let at = changed.iter().position(|&b| b == b'5').unwrap();
        changed[at] = b'6';
        let e = Suite::verify(name, &changed, sha).unwrap_err().to_string();
        let got = crate::tasks::contexts::sha256_hex(&changed);
        assert!(
            e.contains(&got) && e.contains(sha) && e.contains(name),
            "{e}"
        );
    }
}

#[test]
fn start_shift_widens_about_the_range_centre() {
    let s = Suite::for_task(TaskId::Pushing).unwrap();
    let ctx =
        serde_json::json!({"red_xy_deg": [0.5, -0.15, 10.0], "green_xy_deg": [0.6, 0.0, 5.0]});
    let out = shift_context(&s.file, 1.0, &ctx);
    // Red x range 0.4..0.5 (centre 0.45): 0.5 -> 0.55; y -0.15..0 -> -0.225.
    let r = out["red_xy_deg"].as_array().unwrap();
    assert!((r[0].as_f64().unwrap() - 0.55).abs() < 1e-12);
    assert!((r[1].as_f64().unwrap() + 0.225).abs() < 1e-12);
    assert_eq!(r[2], 10.0, "yaw is not shifted");
}

/// The sampling regions of each task's suite as its code samples them
/// (float32 in the code, float64 in the file): (task, [(x range, y range)]).
fn code_regions(task: TaskId) -> Vec<([f32; 2], [f32; 2])> {
    use crate::tasks::{inserting, sorting, stacking};
    match task {
        TaskId::Sorting2 | TaskId::Sorting4 | TaskId::Sorting6 => sorting::REGIONS.to_vec(),
        // The fourth Stacking sample (the target) is never applied.
        TaskId::Stacking => stacking::REGIONS[..3].to_vec(),
        TaskId::Inserting => inserting::REGIONS.to_vec(),
        _ => vec![],
    }
}

/// Every task has a state suite that fits it: obs_units cover its
/// observation (checked at load), start_shift's ranges are the ones the
/// task's code samples from, and the bodies and geom `dynamics` changes are
/// in its scene. Avoiding, with a fixed start and no movable object, has
/// neither axis.
#[test]
fn every_task_has_a_state_suite_that_fits_its_scene_and_sampling() {
    for task in TaskId::ALL {
        let s = Suite::for_task(task).unwrap_or_else(|e| panic!("{task}: {e}"));
        let f = &s.file;
        let axes: Vec<Axis> = f.axes.iter().map(|a| a.axis).collect();
        assert!(axes.contains(&Axis::ObsNoise) && axes.contains(&Axis::Latency));
        let regions: Vec<[[f64; 2]; 2]> = match &f.start_shift_regions {
            Some(r) => r.regions.clone(),
            None => f
                .start_shift_fields
                .chunks(2)
                .map(|xy| {
                    assert_eq!((xy[0].index, xy[1].index), (0, 1));
                    assert_eq!(xy[0].field, xy[1].field);
                    [xy[0].range, xy[1].range]
                })
                .collect(),
        };
        if !matches!(task, TaskId::Aligning | TaskId::Pushing) {
            let from_code: Vec<[[f64; 2]; 2]> = code_regions(task)
                .iter()
                .map(|(x, y)| [x.map(|v| v as f64), y.map(|v| v as f64)])
                .collect();
            let as_f32 = |r: &Vec<[[f64; 2]; 2]>| -> Vec<[[f32; 2]; 2]> {
                r.iter().map(|xy| xy.map(|a| a.map(|v| v as f32))).collect()
            };
            assert_eq!(as_f32(&regions), as_f32(&from_code), "{task}");
        }
        assert_eq!(axes.contains(&Axis::StartShift), task != TaskId::Avoiding);
        assert_eq!(axes.contains(&Axis::Dynamics), task != TaskId::Avoiding);
        let loaded = crate::tasks::LoadedTask::load(task).unwrap();
        for b in &f.dynamics_bodies {
            loaded.model.id(ObjKind::Body, b).unwrap();
        }
        if let Some(g) = &f.table_geom {
            loaded.model.id(ObjKind::Geom, g).unwrap();
        }
    }
}

/// Sorting's poses are permuted over its six regions: each test state's
/// pose lies in exactly one, and start_shift pushes it away from that
/// region's centre (x and y; yaw and quaternion untouched).
#[test]
fn start_shift_moves_sortings_permuted_poses_about_their_own_region() {
    let s = Suite::for_task(TaskId::Sorting6).unwrap();
    let r = s.file.start_shift_regions.as_ref().unwrap();
    let set = crate::tasks::task_def(TaskId::Sorting6)
        .unwrap()
        .context_set()
        .unwrap();
    for i in 0..set.len() {
        let ctx = set.get(i).unwrap();
        let out = shift_context(&s.file, 1.0, ctx);
        for (e, moved) in ctx["entries"]
            .as_array()
            .unwrap()
            .iter()
            .zip(out["entries"].as_array().unwrap())
        {
            let p: Vec<f64> = serde_json::from_value(e["xy_deg"].clone()).unwrap();
            let q: Vec<f64> = serde_json::from_value(moved["xy_deg"].clone()).unwrap();
            let inside: Vec<_> = r
                .regions
                .iter()
                .filter(|[x, y]| (x[0]..=x[1]).contains(&p[0]) && (y[0]..=y[1]).contains(&p[1]))
                .collect();
            assert_eq!(inside.len(), 1, "state {i}: {p:?}");
            let [x, y] = inside[0];
            let (cx, cy) = (0.5 * (x[0] + x[1]), 0.5 * (y[0] + y[1]));
            assert!((q[0] - (cx + 2.0 * (p[0] - cx))).abs() < 1e-12);
            assert!((q[1] - (cy + 2.0 * (p[1] - cy))).abs() < 1e-12);
            assert_eq!((q[2], &moved["quat"]), (p[2], &e["quat"]));
        }
    }
}

/// A suite file's axes need what they act on: start_shift its fields or
/// regions, dynamics its bodies and table geom (a suite without those
/// axes, like Avoiding's, loads); latency takes whole and fractional steps
/// on every task (Stacking too: `CommandKind::blend_late` takes its
/// gripper value whole), but not a fraction of a step or more.
#[test]
fn an_axis_without_what_it_acts_on_is_refused_and_a_suite_without_it_loads() {
    let load = |task: TaskId, axis: &str, mut level: serde_json::Value| {
        level["label"] = "probe".into();
        let suite = Suite::for_task(task).unwrap();
        let mut v = serde_json::to_value(&*suite.file).unwrap();
        v["axes"] = serde_json::json!([{"axis": axis, "levels": [level]}]);
        let bytes = serde_json::to_vec(&v).unwrap();
        let sha = crate::tasks::contexts::sha256_hex(&bytes);
        Suite::verify("probe.json", &bytes, &sha).map(|_| ())
    };
    let noise = serde_json::json!({"position_m": 0.002, "angle_rad": 0.04});
    load(TaskId::Avoiding, "obs_noise", noise).unwrap();
    let e = load(
        TaskId::Avoiding,
        "start_shift",
        serde_json::json!({"widen": 0.5}),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("start_shift_fields") && e.contains("leave the axis out"),
        "{e}"
    );
    let e = load(
        TaskId::Avoiding,
        "dynamics",
        serde_json::json!({"mass": 2.0, "friction": 1.0}),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("dynamics_bodies") && e.contains("table_geom"),
        "{e}"
    );
    load(TaskId::Stacking, "latency", serde_json::json!({"steps": 2})).unwrap();
    load(
        TaskId::Stacking,
        "latency",
        serde_json::json!({"steps": 0, "fraction": 0.25}),
    )
    .unwrap();
    let e = load(
        TaskId::Stacking,
        "latency",
        serde_json::json!({"steps": 1, "fraction": 1.0}),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("0 ≤ fraction < 1"), "{e}");
    load(
        TaskId::Sorting2,
        "latency",
        serde_json::json!({"steps": 1, "fraction": 0.5}),
    )
    .unwrap();
}
