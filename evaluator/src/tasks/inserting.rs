//! Inserting (docs/original-d3il.md §11.3): push the red, green and blue boxes through the
//! entrance of a grey barrier into three parking slots; the order in which
//! boxes reach their slots is the behaviour (|B| = 6).
//!
//! The reference has only the environment; the evaluation loop (Sorting's
//! xy-delta convention, 2000 steps, 60 initial states × 8 rollouts) is ours
//! and documented in docs/tasks.md.

use super::geometry::dist3;
use super::sorting::{movable_box, static_box, FreeBox, PoseSample};
use super::stacking::parse_colour_poses;
use super::{CommandKind, ContextSet, TaskDef, TaskError, TaskLogic};
use crate::mujoco::Model;
use crate::robot::control::FingerCommand;
use crate::robot::{init_qpos, RobotVariant};
use crate::sim::scene::SceneSpec;
use crate::sim::Sim;
use d3il_protocol::TaskId;
use serde_json::{json, Value};

const LETTERS: [char; 3] = ['r', 'g', 'b'];
const NAMES: [&str; 3] = ["push_box1", "push_box2", "push_box3"];
/// Target centres, red, green, blue (docs/original-d3il.md §11.3.1).
pub const TARGETS: [[f64; 3]; 3] = [
    [0.3575, 0.276, 0.0],
    [0.525, 0.4535, 0.0],
    [0.6925, 0.276, 0.0],
];
/// 3-D insertion radius (docs/original-d3il.md §11.3.5): an effective ≈8 mm in xy.
const NEAR: f64 = 0.01;

/// Colour regions (docs/original-d3il.md §11.3.2): red, green, blue, no shuffling.
pub const REGIONS: [([f32; 2], [f32; 2]); 3] = [
    ([0.35, 0.50], [-0.20, -0.15]),
    ([0.55, 0.70], [-0.10, -0.05]),
    ([0.35, 0.50], [0.00, 0.05]),
];

/// Barrier walls maze_3 … maze_19 (name, centre xy, half-sizes xy, quat),
/// half-height 0.03, centred at z = 0 (docs/original-d3il.md §11.3.1). The two diagonal pairs
/// keep the reference's non-unit quaternions; MuJoCo normalises them.
/// maze_1/maze_2 (the "gate") are excluded, as in the reference.
const AXIS: [f64; 4] = [1.0, 0.0, 0.0, 0.0];
const DIAG_L: [f64; 4] = [0.0, 0.5, 1.0, 0.0];
const DIAG_R: [f64; 4] = [0.0, 0.5, -1.0, 0.0];
/// (name, centre xy, half-sizes xy, quaternion).
type Wall = (&'static str, [f64; 2], [f64; 2], [f64; 4]);
const WALLS: [Wall; 17] = [
    ("maze_3", [0.400, 0.170], [0.03, 0.01], DIAG_L),
    ("maze_4", [0.650, 0.170], [0.03, 0.01], DIAG_R),
    ("maze_5", [0.383, 0.2185], [0.01, 0.03], AXIS),
    ("maze_6", [0.667, 0.2185], [0.01, 0.03], AXIS),
    ("maze_7", [0.3525, 0.2385], [0.04, 0.01], AXIS),
    ("maze_8", [0.6975, 0.2385], [0.04, 0.01], AXIS),
    ("maze_9", [0.320, 0.276], [0.01, 0.0475], AXIS),
    ("maze_10", [0.730, 0.276], [0.01, 0.0475], AXIS),
    ("maze_11", [0.3525, 0.3135], [0.04, 0.01], AXIS),
    ("maze_12", [0.6975, 0.3135], [0.04, 0.01], AXIS),
    ("maze_13", [0.383, 0.3335], [0.01, 0.03], AXIS),
    ("maze_14", [0.667, 0.3335], [0.01, 0.03], AXIS),
    ("maze_15", [0.435, 0.3975], [0.01, 0.07], DIAG_L),
    ("maze_16", [0.615, 0.3975], [0.01, 0.07], DIAG_R),
    ("maze_17", [0.4875, 0.4585], [0.01, 0.04], AXIS),
    ("maze_18", [0.5625, 0.4585], [0.01, 0.04], AXIS),
    ("maze_19", [0.525, 0.491], [0.0475, 0.01], AXIS),
];

const CONTEXTS_V1: &[u8] = include_bytes!("../../../assets/contexts/inserting-v1.json");
pub const CONTEXTS_V1_SHA256: &str =
    "3125bac0ea16de061fad046413f859825eb3dcd8b16b2cc60bc41da67fa28405";

/// The reference's `info.mode` for a complete order (docs/original-d3il.md §11.3.6), 0 otherwise.
pub fn mode_code(order: &str) -> u32 {
    match order {
        "rgb" => 1,
        "rbg" => 2,
        "grb" => 3,
        "gbr" => 4,
        "brg" => 5,
        "bgr" => 6,
        _ => 0,
    }
}

pub struct Inserting;

impl TaskDef for Inserting {
    fn id(&self) -> TaskId {
        TaskId::Inserting
    }
    fn version(&self) -> &'static str {
        "v1"
    }
    fn scene(&self) -> SceneSpec {
        let mut s = SceneSpec::new(RobotVariant::Rod);
        let rgba = [
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0, 1.0],
        ];
        for (name, c) in NAMES.iter().zip(rgba) {
            // 0.025 cube, 0.05 kg: inertia 2.083e-5 from MuJoCo's box formula.
            s.primitives.push(movable_box(name, [0.025; 3], c, 0.05));
        }
        for (i, (t, mut c)) in TARGETS.iter().zip(rgba).enumerate() {
            c[3] = 0.3;
            let mut p = static_box(
                &format!("target_{}", LETTERS[i]),
                *t,
                [0.0, 1.0, 0.0, 0.0],
                [0.025, 0.025, 0.02],
                c,
            );
            p.visual_only = true;
            s.primitives.push(p);
        }
        for (name, xy, half, quat) in WALLS {
            s.primitives.push(static_box(
                name,
                [xy[0], xy[1], 0.0],
                quat,
                [half[0], half[1], 0.03],
                [0.5, 0.5, 0.5, 1.0],
            ));
        }
        s
    }
    /// Same TCP target and start as Avoiding/Pushing (docs/original-d3il.md §01.4.5).
    fn init_qpos(&self) -> [f64; 7] {
        init_qpos::AVOIDING
    }
    fn env_obs_dim(&self) -> usize {
        11
    }
    fn command_kind(&self) -> CommandKind {
        CommandKind::XyDelta
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        ContextSet::verify("inserting-v1.json", CONTEXTS_V1, CONTEXTS_V1_SHA256)
    }
    fn sample_context(&self, rng: &mut dyn rand::RngCore) -> Value {
        let p: Vec<PoseSample> = REGIONS
            .iter()
            .map(|(x, y)| PoseSample::sample(rng, *x, *y))
            .collect();
        json!({
            "red_xy_deg": p[0].xy_deg_json(), "red_quat": p[0].quat_json(),
            "green_xy_deg": p[1].xy_deg_json(), "green_quat": p[1].quat_json(),
            "blue_xy_deg": p[2].xy_deg_json(), "blue_quat": p[2].quat_json(),
        })
    }
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError> {
        Ok(Box::new(InsertingLogic {
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

pub struct InsertingLogic {
    boxes: [FreeBox; 3],
    order: String,
    success: bool,
    terminated: bool,
}

impl InsertingLogic {
    fn inserted(&self, sim: &Sim) -> [bool; 3] {
        std::array::from_fn(|i| dist3(&self.boxes[i].pos(&sim.data), &TARGETS[i]) <= NEAR)
    }
}

impl TaskLogic for InsertingLogic {
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError> {
        // The original environment names the boxes box1/box2/box3 (red,
        // green, blue; docs/original-d3il.md §11.3.1): its context keys are accepted as they are.
        let context = super::contexts::rename_objects(
            TaskId::Inserting,
            context,
            &[("box1", "red"), ("box2", "green"), ("box3", "blue")],
        )?;
        let poses = parse_colour_poses(TaskId::Inserting, &context, &["red", "green", "blue"])?;
        let boxes = self.boxes.clone();
        sim.reset(init_qpos, FingerCommand::RESET, |data| {
            for (b, pose) in boxes.iter().zip(&poses) {
                b.place(data, pose, 0.0);
            }
        })?;
        Ok(())
    }

    /// docs/original-d3il.md §11.3.3: TCP xy, then red, green, blue (x, y, tan yaw).
    fn observe(&self, sim: &Sim) -> Vec<f32> {
        let p = sim.tcp_pos();
        let mut v = vec![p[0] as f32, p[1] as f32];
        for b in &self.boxes {
            let q = b.pos(&sim.data);
            v.extend([q[0] as f32, q[1] as f32, b.tan_yaw(&sim.data) as f32]);
        }
        v
    }

    fn pre_physics_done(&mut self, sim: &Sim) -> bool {
        self.terminated || self.inserted(sim).iter().all(|&b| b)
    }

    fn post_physics(&mut self, sim: &Sim) {
        let inside = self.inserted(sim);
        self.success = inside.iter().all(|&b| b);
        if self.success {
            self.terminated = true;
        }
        // docs/original-d3il.md §11.3.6: no gating, several boxes may register in one step (r, g, b order).
        for (i, &inn) in inside.iter().enumerate() {
            if inn && !self.order.contains(LETTERS[i]) {
                self.order.push(LETTERS[i]);
            }
        }
    }

    fn success(&self) -> bool {
        self.success
    }

    /// The insertion order so far, e.g. "g" or "rgb"; the reference's integer
    /// `info.mode` is [`mode_code`] of it.
    fn behaviour(&self) -> Value {
        json!(self.order)
    }

    fn behaviour_key(&self) -> Option<String> {
        self.success.then(|| self.order.clone())
    }

    fn objects(&self, sim: &Sim) -> Vec<(String, [f64; 3])> {
        self.boxes
            .iter()
            .map(|b| (b.name.clone(), b.pos(&sim.data)))
            .collect()
    }
}

/// Where each box is pushed from and into: the slot's centre line runs
/// through its target along `dir` (the push direction into the slot), and the
/// box is first brought to `staging` on that line, inside the enclosure.
struct Slot {
    dir: [f64; 2],
    staging: [f64; 2],
}

const SLOTS: [Slot; 3] = [
    // Red: left slot, opens toward +x, pushed toward −x.
    Slot {
        dir: [-1.0, 0.0],
        staging: [0.4875, 0.276],
    },
    // Green: top slot, opens toward −y, pushed toward +y.
    Slot {
        dir: [0.0, 1.0],
        staging: [0.525, 0.26],
    },
    // Blue: right slot, opens toward −x, pushed toward +x.
    Slot {
        dir: [1.0, 0.0],
        staging: [0.5625, 0.276],
    },
];

/// Radius of the circle the rod travels around a box to change sides.
const ORBIT: f64 = 0.075;

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}
fn add(a: [f64; 2], b: [f64; 2], k: f64) -> [f64; 2] {
    [a[0] + k * b[0], a[1] + k * b[1]]
}
fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}
fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}
fn unit(a: [f64; 2]) -> [f64; 2] {
    let n = norm(a).max(1e-12);
    [a[0] / n, a[1] / n]
}
/// `a` turned by +90°.
fn left(a: [f64; 2]) -> [f64; 2] {
    [-a[1], a[0]]
}
/// Angle wrapped into (−π, π].
fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let r = a.rem_euclid(t);
    if r > std::f64::consts::PI {
        r - t
    } else {
        r
    }
}

/// Scripted reference policy: pushes one box (red, green or blue) through
/// the barrier's entrance, brings it onto its slot's centre line and pushes it
/// into the slot until it registers (3-D distance ≤ 0.01 to its target), then
/// backs off and waits. It steers on the box pose from the observation: the
/// push direction pursues a point ahead on the current route leg, the rod
/// pushes through the box centre along that direction, offset sideways on the
/// face in proportion to the box's yaw (mod 90°) to keep the cube square —
/// the slot is only 2.5 mm wider than the box on each side. When the rod is
/// not behind the box for the wanted direction it backs off and travels
/// around the box on a circle before pushing again. Other boxes are not
/// planned around.
#[derive(Debug, Clone)]
pub struct InsertingScript {
    box_idx: usize,
    /// Route legs for the box centre; the last is the target.
    route: Vec<[f64; 2]>,
    started: bool,
    /// Waypoints of the current repositioning move (rod centre).
    moves: Vec<[f64; 2]>,
    /// Go around the box the long way (the short way was blocked by a wall).
    flip: bool,
    /// Correcting the lateral offset from the slot line with a side push.
    sideways: bool,
    finished: bool,
}

impl InsertingScript {
    /// Pushes box `box_idx` (0 red, 1 green, 2 blue) into its own slot.
    pub fn new(box_idx: usize) -> Option<InsertingScript> {
        (box_idx < 3).then(|| InsertingScript {
            box_idx,
            route: Vec::new(),
            started: false,
            moves: Vec::new(),
            flip: false,
            sideways: false,
            finished: false,
        })
    }

    /// Pushes the green box into the top slot.
    pub fn green() -> InsertingScript {
        InsertingScript::new(1).expect("box 1 exists")
    }

    fn box_pose(&self, obs: &[f32]) -> ([f64; 2], f64) {
        let b = &obs[4 + 3 * self.box_idx..];
        ([b[0] as f64, b[1] as f64], (b[2] as f64).atan())
    }

    /// Policy input (13 values) -> xy delta.
    pub fn act(&mut self, obs: &[f32]) -> [f32; 2] {
        let d = [obs[0] as f64, obs[1] as f64];
        let m = [obs[2] as f64, obs[3] as f64];
        let (b, yaw) = self.box_pose(obs);
        let target = [TARGETS[self.box_idx][0], TARGETS[self.box_idx][1]];
        let slot = &SLOTS[self.box_idx];
        let toward = |t: [f64; 2], max: f64| -> [f32; 2] {
            let e = sub(t, d);
            let n = norm(e);
            let s = if n > max { max / n } else { 1.0 };
            [(e[0] * s) as f32, (e[1] * s) as f32]
        };
        if !self.started {
            self.started = true;
            // Through the entrance (y 0.14–0.20, x ≈ 0.45–0.60 for a box
            // centre), on the side away from the blue box's start region.
            if b[1] < 0.12 {
                let x = if self.box_idx == 2 { 0.50 } else { 0.55 };
                self.route.push([x, 0.08]);
            }
            self.route.push(slot.staging);
            self.route.push(target);
        }
        if self.finished || norm(sub(b, target)) < 0.004 {
            // Inserted: back off along the slot line once, then hold still.
            if !self.finished {
                self.finished = true;
                self.moves = vec![add(b, slot.dir, -0.09)];
            }
            if let Some(&w) = self.moves.first() {
                if norm(sub(w, d)) > 0.002 {
                    return toward(w, 0.004);
                }
                self.moves.clear();
            }
            return [0.0, 0.0];
        }
        // Advance the route (not past the staging point until the box is on
        // the slot line there).
        while self.route.len() > 2 && norm(sub(b, self.route[0])) < 0.02 {
            self.route.remove(0);
        }
        if self.route.len() == 2 && norm(sub(b, self.route[0])) < 0.012 {
            self.route.remove(0);
        }
        // Wanted box motion: pursue a point ahead on the current leg.
        let v = if self.route.len() == 1 {
            // Final leg: straight along the slot line; before the mouth, a
            // lateral error of more than 3 mm is first pushed out sideways
            // (to within 1 mm): pushing at an angle barely moves the cube
            // sideways, the rod slides along its face.
            let along = dot(sub(b, target), slot.dir);
            let lat = dot(sub(b, target), left(slot.dir));
            let before_mouth = along < -0.063;
            if self.sideways {
                self.sideways = before_mouth && lat.abs() > 0.001;
            } else {
                self.sideways = before_mouth && lat.abs() > 0.0025;
            }
            if self.sideways {
                add([0.0, 0.0], left(slot.dir), -lat.signum())
            } else {
                slot.dir
            }
        } else {
            unit(sub(self.route[0], b))
        };
        // Yaw error modulo 90° (cube), positive = turned counter-clockwise.
        let q = std::f64::consts::FRAC_PI_2;
        let mut err = yaw;
        while err > q / 2.0 {
            err -= q;
        }
        while err < -q / 2.0 {
            err += q;
        }
        // The face the rod pushes: the one whose inward normal is closest to
        // v; the rod sits on the line through the centre along v, where it
        // crosses that face, shifted along the face to turn the box back.
        let face_angle = (0..4)
            .map(|k| yaw + k as f64 * q)
            .max_by(|a, c| dot([a.cos(), a.sin()], v).total_cmp(&dot([c.cos(), c.sin()], v)))
            .unwrap();
        let n = [face_angle.cos(), face_angle.sin()];
        let tf = left(n);
        let cos_a = dot(n, v).max(0.7);
        // Where the line through the centre along v leaves the back face,
        // as an offset along the face, plus the yaw correction; the rod
        // stays on the face.
        let s_line = dot(v, tf) * -0.025 / cos_a;
        let shift = 0.008 * (err / 6f64.to_radians()).clamp(-1.0, 1.0);
        let s = (s_line + shift).clamp(-0.018, 0.018);
        let contact = add(add(b, n, -0.035), tf, s);
        // Is the rod (measured) behind that face?
        let w = sub(m, b);
        let behind = -dot(w, n);
        let lateral = dot(w, tf) - s;
        if !self.moves.is_empty() && norm(sub(d, m)) > 0.03 {
            // The rod is held back by a wall while repositioning: give up
            // this move, bring the desired point back to the rod and go
            // around the other way next time.
            self.moves.clear();
            self.flip = !self.flip;
            return toward(m, 0.01);
        }
        if let Some(&wp) = self.moves.first() {
            // A waypoint counts as reached once the rod itself (not only the
            // desired point) is there.
            if norm(sub(wp, d)) > 0.003 || norm(sub(wp, m)) > 0.004 {
                return toward(wp, 0.005);
            }
            self.moves.remove(0);
            if !self.moves.is_empty() {
                return toward(self.moves[0], 0.005);
            }
        }
        if behind < 0.025 || lateral.abs() > 0.012 {
            // Reposition: around the box on a circle to the pre-push point.
            let pre = add(contact, n, -0.03);
            let phi_rod = w[1].atan2(w[0]);
            let phi_goal = (-n[1]).atan2(-n[0]);
            let mut moves = Vec::new();
            if norm(w) < ORBIT - 0.01 {
                moves.push(add(b, unit(w), ORBIT));
            }
            let mut total = wrap(phi_goal - phi_rod);
            if self.flip && total.abs() > 0.5 {
                total -= total.signum() * std::f64::consts::TAU;
            }
            let n_arc = (total.abs() / 0.5).ceil() as usize;
            for k in 1..n_arc {
                let phi = phi_rod + total * k as f64 / n_arc as f64;
                moves.push(add(b, [phi.cos(), phi.sin()], ORBIT));
            }
            moves.push(pre);
            self.moves = moves;
            return toward(self.moves[0], 0.006);
        }
        // Push: the desired point leads the contact point by a few mm.
        if self.route.len() == 1 {
            // Final leg: slow and gentle, the slot has millimetres to spare.
            toward(add(contact, v, 0.010), 0.002)
        } else {
            toward(add(contact, v, 0.015), 0.004)
        }
    }
}
