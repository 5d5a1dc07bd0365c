//! Inserting (spec/11 §3): push the red, green and blue boxes through the
//! entrance of a grey barrier into three parking slots; the order in which
//! boxes reach their slots is the behaviour (|B| = 6).
//!
//! The reference has only the environment; the evaluation loop (Sorting's
//! xy-delta convention, 2000 steps, 60 initial states × 8 rollouts) is ours
//! and documented in docs/tasks.md.

use super::geometry::dist3;
use super::sorting::{movable_box, static_box, FreeBox, PoseSample};
use super::stacking::parse_colour_poses;
use super::{xy_delta_command, Command, ContextSet, TaskDef, TaskError, TaskLogic};
use crate::mujoco::Model;
use crate::robot::control::FingerCommand;
use crate::robot::{init_qpos, RobotVariant};
use crate::sim::scene::SceneSpec;
use crate::sim::Sim;
use d3il_protocol::TaskId;
use serde_json::{json, Value};

const LETTERS: [char; 3] = ['r', 'g', 'b'];
const NAMES: [&str; 3] = ["push_box1", "push_box2", "push_box3"];
/// Target centres, red, green, blue (spec/11 §3.1).
pub const TARGETS: [[f64; 3]; 3] = [
    [0.3575, 0.276, 0.0],
    [0.525, 0.4535, 0.0],
    [0.6925, 0.276, 0.0],
];
/// 3-D insertion radius (spec/11 §3.5): an effective ≈8 mm in xy.
const NEAR: f64 = 0.01;

/// Colour regions (spec/11 §3.2): red, green, blue, no shuffling.
pub const REGIONS: [([f32; 2], [f32; 2]); 3] = [
    ([0.35, 0.50], [-0.20, -0.15]),
    ([0.55, 0.70], [-0.10, -0.05]),
    ([0.35, 0.50], [0.00, 0.05]),
];

/// Barrier walls maze_3 … maze_19 (name, centre xy, half-sizes xy, quat),
/// half-height 0.03, centred at z = 0 (spec/11 §3.1). The two diagonal pairs
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

/// The reference's `info.mode` for a complete order (spec/11 §3.6), 0 otherwise.
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
    fn n_substeps(&self) -> usize {
        35
    }
    /// Same TCP target and start as Avoiding/Pushing (spec/01 §4.5).
    fn init_qpos(&self) -> [f64; 7] {
        init_qpos::AVOIDING
    }
    /// The environment default (spec/11 §3.4, spec/01 §4.6); no evaluation value exists.
    fn max_steps(&self) -> usize {
        2000
    }
    fn env_obs_dim(&self) -> usize {
        11
    }
    fn cmd_dim(&self) -> usize {
        2
    }
    fn act_dim(&self) -> usize {
        2
    }
    fn act_meaning(&self) -> &'static str {
        "the xy delta of the desired TCP position"
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        ContextSet::verify("inserting-v1.json", CONTEXTS_V1, CONTEXTS_V1_SHA256)
    }
    /// Our protocol (docs/tasks.md): 60 initial states × 8 rollouts.
    fn rollouts_per_context(&self) -> usize {
        8
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
    fn initial_command(&self, sim: &Sim) -> Vec<f64> {
        let p = sim.tcp_pos();
        vec![p[0], p[1]]
    }
    /// Assumed like Sorting/Pushing (spec/11 §3.4): previous desired xy + Δ,
    /// z fixed at the post-reset TCP z (≈0.1224).
    fn command(&self, prev: &[f64], action: &[f32], fixed_z: f64) -> (Vec<f64>, Command) {
        xy_delta_command(prev, action, fixed_z)
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
        let poses = parse_colour_poses(TaskId::Inserting, context, &["red", "green", "blue"])?;
        let boxes = self.boxes.clone();
        sim.reset(init_qpos, FingerCommand::RESET, |data| {
            for (b, pose) in boxes.iter().zip(&poses) {
                b.place(data, pose, 0.0);
            }
        })?;
        Ok(())
    }

    /// spec/11 §3.3: TCP xy, then red, green, blue (x, y, tan yaw).
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
        // spec/11 §3.6: no gating, several boxes may register in one step (r, g, b order).
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

/// Scripted reference policy: pushes one box with the rod through a list of
/// xy subgoals (through the entrance, then into its slot), steering on the
/// box position from the observation.
#[derive(Debug, Clone)]
pub struct InsertingScript {
    box_idx: usize,
    subgoals: Vec<[f64; 2]>,
    approach: Vec<[f64; 2]>,
    started: bool,
}

impl InsertingScript {
    /// A script for box `box_idx` (0 red, 1 green, 2 blue); only the green
    /// box (the top slot) has a script so far.
    pub fn new(box_idx: usize) -> Option<InsertingScript> {
        (box_idx == 1).then(InsertingScript::green)
    }

    /// Pushes the green box straight into the top slot.
    pub fn green() -> InsertingScript {
        InsertingScript {
            box_idx: 1,
            subgoals: vec![[0.525, 0.10], [0.525, 0.50]],
            approach: Vec::new(),
            started: false,
        }
    }

    fn box_xy(&self, obs: &[f32]) -> [f64; 2] {
        let b = &obs[4 + 3 * self.box_idx..];
        [b[0] as f64, b[1] as f64]
    }

    /// Policy input (13 values) -> xy delta.
    pub fn act(&mut self, obs: &[f32]) -> [f32; 2] {
        let d = [obs[0] as f64, obs[1] as f64];
        let b = self.box_xy(obs);
        let toward = |t: [f64; 2], max: f64| -> [f32; 2] {
            let e = [t[0] - d[0], t[1] - d[1]];
            let n = (e[0] * e[0] + e[1] * e[1]).sqrt();
            let s = if n > max { max / n } else { 1.0 };
            [(e[0] * s) as f32, (e[1] * s) as f32]
        };
        // Drop reached subgoals (the last one is behind the slot's back wall,
        // so the push ends with the box pressed into the slot).
        while self.subgoals.len() > 1 && b[1] > self.subgoals[0][1] - 0.02 {
            self.subgoals.remove(0);
        }
        let mut g = self.subgoals[0];
        if self.subgoals.len() == 1 {
            // Last leg: follow the slot's centre line, steering back onto it.
            g = [g[0], b[1] + 0.025];
        }
        let u = {
            let v = [g[0] - b[0], g[1] - b[1]];
            let n = (v[0] * v[0] + v[1] * v[1]).sqrt().max(1e-9);
            [v[0] / n, v[1] / n]
        };
        if !self.started {
            let pre = [b[0] - u[0] * 0.06, b[1] - u[1] * 0.06];
            self.approach = vec![[pre[0], d[1].min(pre[1] - 0.05)], pre];
            self.started = true;
        }
        if let Some(&w) = self.approach.first() {
            if ((w[0] - d[0]).powi(2) + (w[1] - d[1]).powi(2)).sqrt() > 0.003 {
                return toward(w, 0.008);
            }
            self.approach.remove(0);
        }
        let mut aim = [b[0] - u[0] * 0.02, b[1] - u[1] * 0.02];
        if self.subgoals.len() == 1 {
            // The slot takes the box only within ≈6° of square: push off-centre
            // on the back face to turn it (a push at +x of the centre turns it
            // counter-clockwise), yaw taken modulo 90° for the cube.
            let b_yaw = obs[6 + 3 * self.box_idx] as f64;
            let mut yaw = b_yaw.atan();
            let q = std::f64::consts::FRAC_PI_4;
            if yaw > q {
                yaw -= 2.0 * q;
            } else if yaw < -q {
                yaw += 2.0 * q;
            }
            // Centre the box on the slot line first, square it once centred.
            let centred = (b[0] - self.subgoals[0][0]).abs() < 0.005;
            let off = if centred {
                -0.015 * (yaw / 10f64.to_radians()).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            aim = [aim[0] + u[1] * off, aim[1] - u[0] * off];
            return toward(aim, 0.003);
        }
        toward(aim, 0.005)
    }
}
