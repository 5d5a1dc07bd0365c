//! The fixed features of a task's scene seen from above (table, targets,
//! obstacles), for the pictures of a rollout ([`d3il_protocol::Landmark`]).
//! Read from the scene the task compiles, so they cannot drift from it.

use crate::sim::scene::{SceneSpec, Shape};
use d3il_protocol::{Landmark, LandmarkKind};

/// The table top (assets/mjcf/table.xml: `table_plane` at x 0.4, half extents
/// 0.49 × 0.98).
const TABLE: ([f64; 2], [f64; 2]) = ([0.4, 0.0], [0.49, 0.98]);

/// Size drawn for a target that is an object of the task's logic without a
/// static primitive (Aligning's mocap target: a 0.1 m square tray).
const OBJECT_TARGET_HALF: f64 = 0.05;

fn is_target_name(name: &str) -> bool {
    ["target", "finish", "goal"]
        .iter()
        .any(|k| name.contains(k))
}

/// The landmarks every rollout of `scene` shares: the table and each static
/// primitive, as the axis-aligned box its footprint fills.
pub fn scene_landmarks(scene: &SceneSpec) -> Vec<Landmark> {
    let mut out = vec![Landmark {
        kind: LandmarkKind::Table,
        label: "table".into(),
        center: TABLE.0,
        half: TABLE.1,
        round: false,
    }];
    for p in scene.primitives.iter().filter(|p| p.is_static) {
        let kind = if is_target_name(&p.name) {
            LandmarkKind::Target
        } else {
            LandmarkKind::Obstacle
        };
        let (half, round) = match p.shape {
            Shape::Box => (footprint(p.quat, [p.size[0], p.size[1], p.size[2]]), false),
            Shape::Cylinder | Shape::Sphere => ([p.size[0], p.size[0]], true),
        };
        out.push(Landmark {
            kind,
            label: p.name.clone(),
            center: [p.pos[0], p.pos[1]],
            half,
            round,
        });
    }
    out
}

/// Half extents in x and y of a box with half sizes `h` rotated by `q`
/// (w, x, y, z): the axis-aligned bounds of its footprint.
fn footprint(q: [f64; 4], h: [f64; 3]) -> [f64; 2] {
    let [w, x, y, z] = q;
    // Rows 0 and 1 of the rotation matrix.
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
    ];
    let ext = |row: [f64; 3]| (0..3).map(|i| row[i].abs() * h[i]).sum::<f64>();
    [ext(r[0]), ext(r[1])]
}

/// The landmarks of one rollout: the scene's, with the targets that the
/// task places per initial state (objects named `target…`) where they are
/// after the reset.
pub fn rollout_landmarks(
    scene: &[Landmark],
    start_objects: &[(String, [f64; 3])],
) -> Vec<Landmark> {
    let mut out = scene.to_vec();
    for (name, p) in start_objects
        .iter()
        .filter(|(n, _)| n.starts_with("target"))
    {
        match out.iter_mut().find(|l| &l.label == name) {
            Some(l) => l.center = [p[0], p[1]],
            None => out.push(Landmark {
                kind: LandmarkKind::Target,
                label: name.clone(),
                center: [p[0], p[1]],
                half: [OBJECT_TARGET_HALF; 2],
                round: false,
            }),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_turned_a_quarter_about_z_swaps_its_extents() {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let h = footprint([s, 0.0, 0.0, s], [0.1, 0.3, 0.05]);
        assert!(
            (h[0] - 0.3).abs() < 1e-12 && (h[1] - 0.1).abs() < 1e-12,
            "{h:?}"
        );
        // Half a turn about x (the tasks' targets) keeps them.
        assert_eq!(
            footprint([0.0, 1.0, 0.0, 0.0], [0.1, 0.3, 0.05]),
            [0.1, 0.3]
        );
    }

    #[test]
    fn every_task_has_its_targets_and_obstacles() {
        use d3il_protocol::TaskId;
        for task in TaskId::ALL {
            let def = crate::tasks::task_def(task).unwrap();
            let marks = scene_landmarks(&def.scene());
            assert_eq!(marks[0].kind, LandmarkKind::Table);
            let targets = marks
                .iter()
                .filter(|l| l.kind == LandmarkKind::Target)
                .count();
            let obstacles = marks
                .iter()
                .filter(|l| l.kind == LandmarkKind::Obstacle)
                .count();
            match task {
                TaskId::Avoiding => assert_eq!((targets, obstacles), (1, 6), "{marks:?}"),
                TaskId::Pushing => assert_eq!(targets, 2, "{marks:?}"),
                TaskId::Stacking => assert_eq!(targets, 1, "{marks:?}"),
                _ => {}
            }
        }
        let placed = rollout_landmarks(
            &[],
            &[
                ("target_box".into(), [0.6, 0.1, 0.0]),
                ("box".into(), [0.5, 0.0, 0.0]),
            ],
        );
        assert_eq!(placed.len(), 1);
        assert_eq!(
            (placed[0].kind, placed[0].center),
            (LandmarkKind::Target, [0.6, 0.1])
        );
    }
}
