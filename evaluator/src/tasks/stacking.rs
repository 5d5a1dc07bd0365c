//! Stacking (docs/original-d3il.md §11.2): pick the red, green and blue blocks and stack them
//! on the target (0.5, 0.2). Joint-space control: the policy outputs per-step
//! joint increments integrated on the previous *desired* joints in float32,
//! plus an absolute gripper value thresholded at 0.075.

use super::geometry::dist2;
use super::sorting::{movable_box, static_box, FreeBox, PoseSample};
use super::{CommandKind, ContextSet, TaskDef, TaskError, TaskLogic};
use crate::mujoco::Model;
use crate::robot::control::{orientation_error, FingerCommand};
use crate::robot::kinematics::PandaKinematics;
use crate::robot::RobotVariant;
use crate::sim::scene::SceneSpec;
use crate::sim::Sim;
use d3il_protocol::TaskId;
use nalgebra::{SMatrix, SVector};
use serde_json::{json, Value};

/// The stacking target xy; the context's 4th entry is never applied (docs/original-d3il.md §11.2.2, §11.7.4).
pub const TARGET: [f64; 2] = [0.5, 0.2];
/// Registration radius (xy) of the order tracker and the full-stack test (docs/original-d3il.md §11.2.5).
const NEAR: f64 = 0.06;
const LETTERS: [char; 3] = ['r', 'g', 'b'];
const NAMES: [&str; 3] = ["red_box", "green_box", "blue_box"];

/// Sampling regions: red, green, blue, and the ignored target (docs/original-d3il.md §11.2.2).
pub const REGIONS: [([f32; 2], [f32; 2]); 4] = [
    ([0.35, 0.45], [-0.25, -0.15]),
    ([0.35, 0.45], [-0.10, 0.00]),
    ([0.55, 0.60], [-0.20, 0.00]),
    ([0.40, 0.60], [0.15, 0.25]),
];

const CONTEXTS_V1: &[u8] = include_bytes!("../../../assets/contexts/stacking-v1.json");
pub const CONTEXTS_V1_SHA256: &str =
    "f30ae8e79d215a361d7e8961b1de19fd494d6ec451102a7e726ea79b67793fed";
/// The original D3IL test contexts (`test_contexts.pkl` of the reference,
/// decoded in shared/reference-contexts; `d3il contexts import`): the set in use.
const CONTEXTS_V2: &[u8] = include_bytes!("../../../assets/contexts/stacking-v2.json");
pub const CONTEXTS_V2_SHA256: &str =
    "d48c4e9f4b5e5f814470230f069f1ef967757c507dc1cbf9d66cb1a1de3d0afb";

pub struct Stacking;

const INIT_QPOS: [f64; 7] = [
    -1.1708457375620825e-08,
    -0.04361858666849418,
    1.3201479763046068e-08,
    -2.188421166999035,
    -5.946522360234217e-09,
    2.1499041610538177,
    0.7853981672117105,
];

/// Parses `{"red_xy_deg", "red_quat", "green_xy_deg", "green_quat",
/// "blue_xy_deg", "blue_quat"}` (the reference rollouts' format; the ignored
/// target entries and `format` may be present).
pub fn parse_colour_poses(
    task: TaskId,
    context: &Value,
    colours: &[&str],
) -> Result<Vec<PoseSample>, TaskError> {
    if !context.is_object() {
        return Err(TaskError::Context {
            task,
            message: format!(
                "the context must be an object with fields {}",
                colours
                    .iter()
                    .map(|c| format!("`{c}_xy_deg`, `{c}_quat`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        });
    }
    colours
        .iter()
        .map(|c| {
            let xy = format!("{c}_xy_deg");
            let q = format!("{c}_quat");
            PoseSample::parse(task, "", context.get(&xy), context.get(&q), &xy, &q)
        })
        .collect()
}

impl TaskDef for Stacking {
    fn id(&self) -> TaskId {
        TaskId::Stacking
    }
    fn version(&self) -> &'static str {
        "v1"
    }
    fn scene(&self) -> SceneSpec {
        let mut s = SceneSpec::new(RobotVariant::Gripper);
        s.primitives.push(movable_box(
            "red_box",
            [0.03, 0.03, 0.03],
            [1.0, 0.0, 0.0, 1.0],
            0.05,
        ));
        let mut g = movable_box("green_box", [0.03, 0.03, 0.03], [0.0, 1.0, 0.0, 1.0], 0.05);
        g.pos = [0.5, 0.0, 0.0];
        s.primitives.push(g);
        // 10 cm long in its local y: inertia (5.667e-5, 3e-5, 5.667e-5) from the mass.
        let mut b = movable_box("blue_box", [0.03, 0.05, 0.03], [0.0, 0.0, 1.0, 1.0], 0.05);
        b.pos = [0.5, 0.0, 0.0];
        s.primitives.push(b);
        let mut t = static_box(
            "target_box",
            [TARGET[0], TARGET[1], 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.05, 0.05, 0.04],
            [1.0, 0.65, 0.0, 0.3],
        );
        t.visual_only = true;
        s.primitives.push(t);
        s
    }
    /// `init_qpos::STACKING` at full precision: the table in docs/original-d3il.md §01.4.5 rounds
    /// the three near-zero joints to 4 digits, which shows up as 5e-13 rad in the
    /// float32 commands; these are the reference rollouts' `reset.init_qpos`.
    fn init_qpos(&self) -> [f64; 7] {
        INIT_QPOS
    }
    fn env_obs_dim(&self) -> usize {
        12
    }
    fn command_kind(&self) -> CommandKind {
        CommandKind::JointDelta
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        ContextSet::verify("stacking-v2.json", CONTEXTS_V2, CONTEXTS_V2_SHA256)
    }
    /// v2 (in use) and our earlier sample v1, which stored results refer to.
    fn context_sets(&self) -> Result<Vec<ContextSet>, TaskError> {
        Ok(vec![
            self.context_set()?,
            ContextSet::verify("stacking-v1.json", CONTEXTS_V1, CONTEXTS_V1_SHA256)?,
        ])
    }
    /// Four pose samples in fixed order; the target one is stored, never applied.
    fn sample_context(&self, rng: &mut dyn rand::RngCore) -> Value {
        let p: Vec<PoseSample> = REGIONS
            .iter()
            .map(|(x, y)| PoseSample::sample(rng, *x, *y))
            .collect();
        json!({
            "red_xy_deg": p[0].xy_deg_json(), "red_quat": p[0].quat_json(),
            "green_xy_deg": p[1].xy_deg_json(), "green_quat": p[1].quat_json(),
            "blue_xy_deg": p[2].xy_deg_json(), "blue_quat": p[2].quat_json(),
            "target_xy_deg_ignored": p[3].xy_deg_json(), "target_quat_ignored": p[3].quat_json(),
        })
    }
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError> {
        Ok(Box::new(StackingLogic {
            boxes: [
                FreeBox::lookup(model, NAMES[0])?,
                FreeBox::lookup(model, NAMES[1])?,
                FreeBox::lookup(model, NAMES[2])?,
            ],
            order: String::new(),
            success: false,
            terminated: false,
        }))
    }
}

pub struct StackingLogic {
    boxes: [FreeBox; 3],
    /// Registration order, letters r/g/b (docs/original-d3il.md §11.2.6).
    order: String,
    success: bool,
    terminated: bool,
}

impl StackingLogic {
    /// Full stack (Stacking-3): all three within 0.06 (xy) of the target and
    /// every pair of centres more than 0.03 apart in z (docs/original-d3il.md §11.2.5).
    fn stacked(&self, sim: &Sim) -> bool {
        let p: [[f64; 3]; 3] = std::array::from_fn(|i| self.boxes[i].pos(&sim.data));
        let near = p.iter().all(|q| dist2(q, &TARGET) <= NEAR);
        let dz = [(0, 1), (0, 2), (1, 2)]
            .iter()
            .map(|&(i, j)| (p[i][2] - p[j][2]).abs())
            .fold(f64::INFINITY, f64::min);
        near && dz > 0.03
    }

    /// At most one box per step: the closest unregistered box, if within 0.06.
    fn track(&mut self, sim: &Sim) {
        let mut best = (0, f64::INFINITY);
        for (i, b) in self.boxes.iter().enumerate() {
            let d = if self.order.contains(LETTERS[i]) {
                1e5
            } else {
                dist2(&b.pos(&sim.data), &TARGET)
            };
            if d < best.1 {
                best = (i, d);
            }
        }
        if best.1 <= NEAR {
            self.order.push(LETTERS[best.0]);
        }
    }

    pub fn order(&self) -> &str {
        &self.order
    }
}

impl TaskLogic for StackingLogic {
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError> {
        let poses = parse_colour_poses(TaskId::Stacking, context, &["red", "green", "blue"])?;
        let boxes = self.boxes.clone();
        // docs/original-d3il.md §01.4.4 step 6: Stacking opens the fingers before the reset substep.
        sim.reset(init_qpos, FingerCommand::OPEN, |data| {
            for (b, pose) in boxes.iter().zip(&poses) {
                b.place(data, pose, 0.0);
            }
        })?;
        Ok(())
    }

    /// docs/original-d3il.md §11.2.3: per box (x, y, z, tan yaw), red, green, blue.
    fn observe(&self, sim: &Sim) -> Vec<f32> {
        let mut v = Vec::with_capacity(12);
        for b in &self.boxes {
            let p = b.pos(&sim.data);
            v.extend([
                p[0] as f32,
                p[1] as f32,
                p[2] as f32,
                b.tan_yaw(&sim.data) as f32,
            ]);
        }
        v
    }

    fn pre_physics_done(&mut self, sim: &Sim) -> bool {
        self.terminated || self.stacked(sim)
    }

    fn post_physics(&mut self, sim: &Sim) {
        self.success = self.stacked(sim);
        if self.success {
            self.terminated = true;
        }
        self.track(sim);
    }

    fn success(&self) -> bool {
        self.success
    }

    /// The registration order string (`info.mode`), e.g. "gbr", "" if none.
    fn behaviour(&self) -> Value {
        json!(self.order)
    }

    /// Always the order string, success or not: the metrics derive
    /// Stacking-1/2 (≥ 1 / ≥ 2 letters) from it and Stacking-3 from `success`.
    fn behaviour_key(&self) -> Option<String> {
        Some(self.order.clone())
    }

    fn stacking_levels(&self) -> Option<[bool; 3]> {
        Some([!self.order.is_empty(), self.order.len() >= 2, self.success])
    }

    fn objects(&self, sim: &Sim) -> Vec<(String, [f64; 3])> {
        self.boxes
            .iter()
            .map(|b| (b.name.clone(), b.pos(&sim.data)))
            .collect()
    }
}

// ---------------------------------------------------------------------------
// Scripted reference policy
// ---------------------------------------------------------------------------

type J6x7 = SMatrix<f64, 6, 7>;

/// One waypoint of the scripted gripper: TCP position, hand yaw (rad), gripper
/// value sent, and how many steps to wait after the desired pose is reached.
#[derive(Debug, Clone, Copy)]
struct Waypoint {
    pos: [f64; 3],
    yaw: f64,
    gripper: f32,
    hold: usize,
    /// Maximum TCP motion per 30 ms step (m).
    speed: f64,
}

/// Scripted pick-and-place in joint space: Cartesian waypoints turned into
/// joint increments by damped least squares on the *desired* joints (the
/// previous command in the observation), exactly the interface a learned
/// policy has. Picks the boxes in the given order (letters r/g/b) and stacks
/// them on the target.
#[derive(Debug, Clone)]
pub struct StackingScript {
    order: Vec<usize>,
    kin: PandaKinematics,
    plan: Vec<Waypoint>,
    next_box: usize,
    waited: usize,
}

/// TCP height that puts the finger pads around a box centre at z.
const GRASP_DZ: f64 = 0.009;
const CARRY_Z: f64 = 0.20;
/// Box centre height on the table, and the tower's step.
const BOX_REST_Z: f64 = 0.011;
const BOX_H: f64 = 0.06;
/// An open gripper command (> 0.075); also latency's hold while the first
/// late actions are in flight (`CommandKind::hold`).
pub(crate) const OPEN: f32 = 0.08;
const CLOSED: f32 = 0.0;

impl StackingScript {
    /// `order`: the boxes to stack, e.g. "r", "rgb", "gbr".
    pub fn new(order: &str) -> Option<StackingScript> {
        let order = order
            .chars()
            .map(|c| LETTERS.iter().position(|&l| l == c))
            .collect::<Option<Vec<_>>>()?;
        Some(StackingScript {
            order,
            kin: PandaKinematics::new(),
            plan: Vec::new(),
            next_box: 0,
            waited: 0,
        })
    }

    /// Hand yaw that puts the fingers across a box side: cubes any side
    /// (yaw mod 90°), the long blue box across its 6 cm local-x side.
    fn grasp_yaw(box_idx: usize, tan_yaw: f64) -> f64 {
        let theta = tan_yaw.atan(); // in (−90°, 90°)
        let q = std::f64::consts::FRAC_PI_2;
        if box_idx == 2 {
            let mut psi = theta + q;
            if psi > q {
                psi -= std::f64::consts::PI;
            }
            psi
        } else {
            let mut psi = theta;
            if psi > q / 2.0 {
                psi -= q;
            } else if psi < -q / 2.0 {
                psi += q;
            }
            psi
        }
    }

    fn plan_box(&mut self, obs: &[f32], level: usize) {
        let i = self.order[self.next_box];
        let b = &obs[8 + 4 * i..12 + 4 * i];
        let (bx, by) = (b[0] as f64, b[1] as f64);
        let yaw = Self::grasp_yaw(i, b[3] as f64);
        let grasp_z = b[2] as f64 + GRASP_DZ;
        let place_z = BOX_REST_Z + BOX_H * level as f64 + GRASP_DZ + 0.012;
        // The joint PD lags the desired joints by 1-3 cm while moving, so the
        // script waits above the box and above the target until the arm has
        // settled, and makes the final vertical moves slowly.
        let wp = |pos: [f64; 3], yaw: f64, gripper: f32, hold: usize, speed: f64| Waypoint {
            pos,
            yaw,
            gripper,
            hold,
            speed,
        };
        let (tx, ty) = (TARGET[0], TARGET[1]);
        self.plan = vec![
            wp([bx, by, CARRY_Z], yaw, OPEN, 1, 0.008),
            wp([bx, by, grasp_z + 0.04], yaw, OPEN, 12, 0.008),
            wp([bx, by, grasp_z], yaw, OPEN, 10, 0.003),
            wp([bx, by, grasp_z], yaw, CLOSED, 8, 0.003),
            wp([bx, by, CARRY_Z], yaw, CLOSED, 1, 0.006),
            wp([tx, ty, CARRY_Z], 0.0, CLOSED, 1, 0.008),
            wp([tx, ty, place_z + 0.04], 0.0, CLOSED, 12, 0.006),
            wp([tx, ty, place_z], 0.0, CLOSED, 10, 0.003),
            wp([tx, ty, place_z], 0.0, OPEN, 8, 0.003),
            wp([tx, ty, CARRY_Z], 0.0, OPEN, 1, 0.008),
        ];
        self.waited = 0;
    }

    /// Policy input (20 values) -> action (7 joint increments, gripper).
    pub fn act(&mut self, obs: &[f32]) -> [f32; 8] {
        let q: [f64; 7] = std::array::from_fn(|i| obs[i] as f64);
        if self.plan.is_empty() {
            if self.next_box >= self.order.len() {
                let mut a = [0.0; 8];
                a[7] = OPEN;
                return a;
            }
            let level = self.next_box;
            self.plan_box(obs, level);
        }
        let w = self.plan[0];
        let fk = self.kin.fk(&q);
        let (s, c) = (w.yaw / 2.0).sin_cos();
        let mut quat_d = [0.0, c, s, 0.0];
        let cur = fk.quat_wxyz();
        let same: f64 = (0..4).map(|k| cur[k] * quat_d[k]).sum();
        if same < 0.0 {
            quat_d = quat_d.map(|v| -v);
        }
        let ex = [
            w.pos[0] - fk.pos[0],
            w.pos[1] - fk.pos[1],
            w.pos[2] - fk.pos[2],
        ];
        let eo = orientation_error(&cur, &quat_d);
        let n = (ex[0] * ex[0] + ex[1] * ex[1] + ex[2] * ex[2]).sqrt();
        let reached = n < 0.002 && eo.norm() < 0.01;
        // At most 6 mm and ~0.05 rad of TCP motion per 30 ms step.
        let s_pos = if n > w.speed { w.speed / n } else { 1.0 };
        let s_ori = (0.05 / eo.norm().max(1e-12)).min(1.0);
        let v = SVector::<f64, 6>::from_column_slice(&[
            ex[0] * s_pos,
            ex[1] * s_pos,
            ex[2] * s_pos,
            eo[0] * s_ori,
            eo[1] * s_ori,
            eo[2] * s_ori,
        ]);
        let j: J6x7 = fk.jacobian();
        let a = j * j.transpose() + SMatrix::<f64, 6, 6>::identity() * 1e-4;
        let dq = match a.cholesky() {
            Some(ch) => j.transpose() * ch.solve(&v),
            None => SVector::<f64, 7>::zeros(),
        };
        let out: [f32; 8] = std::array::from_fn(|k| {
            if k < 7 {
                dq[k].clamp(-0.05, 0.05) as f32
            } else {
                w.gripper
            }
        });
        if reached {
            self.waited += 1;
            if self.waited >= w.hold {
                self.plan.remove(0);
                self.waited = 0;
                if self.plan.is_empty() {
                    self.next_box += 1;
                }
            }
        }
        out
    }
}
