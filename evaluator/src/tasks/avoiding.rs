//! Avoiding (docs/original-d3il.md §10.2): move the rod through three rows of cylinders to the
//! finish line; the path through the rows is the behaviour (|B| = 24).

use super::{geom_id, CommandKind, ContextSet, TaskDef, TaskError, TaskLogic};
use crate::mujoco::Model;
use crate::robot::control::FingerCommand;
use crate::robot::{init_qpos, RobotVariant};
use crate::sim::scene::{Primitive, SceneSpec, Shape};
use crate::sim::Sim;
use d3il_protocol::TaskId;
use serde_json::{json, Value};

// The field is named once, in the protocol crate (the figures draw the same
// one; docs/original-d3il.md §10.2.1).
use d3il_protocol::behaviour::avoiding::{finish_y, obstacles, row_y, MID_X, OFFSET};

const CONTEXTS_V1: &[u8] = include_bytes!("../../../assets/contexts/avoiding-v1.json");
pub const CONTEXTS_V1_SHA256: &str =
    "14ab254ead0ad7d1c2cf4cf49db5f96d7e111f1f0babe1b3e38ba9684ebb85fe";

pub struct Avoiding;

impl TaskDef for Avoiding {
    fn id(&self) -> TaskId {
        TaskId::Avoiding
    }
    fn version(&self) -> &'static str {
        "v1"
    }
    fn scene(&self) -> SceneSpec {
        let mut s = SceneSpec::new(RobotVariant::Rod);
        for o in obstacles() {
            let mut p = Primitive::new(
                o.name,
                Shape::Cylinder,
                [o.x, o.y, 0.0],
                &[o.radius, o.half_length],
            );
            p.rgba = [1.0, 0.0, 0.0, 1.0];
            p.is_static = true;
            s.primitives.push(p);
        }
        let mut fl = Primitive::new(
            "finish_line",
            Shape::Box,
            [0.4, finish_y(), 0.0],
            &[0.5, 0.01, 0.005],
        );
        fl.rgba = [0.0, 1.0, 0.0, 0.3];
        fl.is_static = true;
        fl.visual_only = true;
        s.primitives.push(fl);
        s
    }
    fn init_qpos(&self) -> [f64; 7] {
        init_qpos::AVOIDING
    }
    fn env_obs_dim(&self) -> usize {
        2
    }
    fn command_kind(&self) -> CommandKind {
        CommandKind::XyDelta
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        ContextSet::verify("avoiding-v1.json", CONTEXTS_V1, CONTEXTS_V1_SHA256)
    }
    fn sample_context(&self, _rng: &mut dyn rand::RngCore) -> Value {
        // docs/original-d3il.md §10.2.2: a single fixed start, no context.
        Value::Null
    }
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError> {
        let mut obstacle_geoms = [0; 6];
        for (i, o) in obstacles().iter().enumerate() {
            obstacle_geoms[i] = geom_id(model, &format!("{}:geom", o.name))?;
        }
        Ok(Box::new(AvoidingLogic {
            rod: geom_id(model, "rod:geom_rb0")?,
            obstacle_geoms,
            bits: [0.0; 9],
            rows_passed: [false; 3],
            success: false,
            terminated: false,
        }))
    }
}

pub struct AvoidingLogic {
    rod: usize,
    obstacle_geoms: [usize; 6],
    bits: [f64; 9],
    rows_passed: [bool; 3],
    success: bool,
    terminated: bool,
}

impl AvoidingLogic {
    /// docs/original-d3il.md §10.2.6, including the row-3 threshold quirk (b8 uses 0.35).
    fn detect_modes(&mut self, x: f64, y: f64) {
        let l2_top = MID_X - OFFSET;
        let l2_bottom = MID_X + OFFSET;
        let l3_top = MID_X - 2.0 * OFFSET;
        let l3_bottom = MID_X + 2.0 * OFFSET;
        if !self.rows_passed[0] && (y - row_y(0.0)).abs() <= 0.03 {
            if x < MID_X {
                self.bits[0] = 1.0;
            } else if x > MID_X {
                self.bits[1] = 1.0;
            }
            self.rows_passed[0] = true;
        }
        if !self.rows_passed[1] && (y - row_y(1.0)).abs() <= 0.03 {
            if x < l2_top {
                self.bits[2] = 1.0;
            } else if l2_top < x && x < l2_bottom {
                self.bits[3] = 1.0;
            } else if x > l2_bottom {
                self.bits[4] = 1.0;
            }
            self.rows_passed[1] = true;
        }
        if !self.rows_passed[2] && y >= row_y(2.0) {
            if x < l3_top {
                self.bits[5] = 1.0;
            }
            if l3_top < x && x < MID_X {
                self.bits[6] = 1.0;
            } else if MID_X < x && x < l3_bottom {
                self.bits[7] = 1.0;
            } else if x > l3_top {
                // The reference compares with the row-3 *top* threshold here.
                self.bits[8] = 1.0;
            }
            self.rows_passed[2] = true;
        }
    }

    /// Mode code c = Σ b_i 2^i (docs/original-d3il.md §10.2.6).
    pub fn code(&self) -> u32 {
        self.bits
            .iter()
            .enumerate()
            .map(|(i, b)| (*b as u32) << i)
            .sum()
    }
}

impl TaskLogic for AvoidingLogic {
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError> {
        if !context.is_null() && context != &json!({}) {
            return Err(TaskError::Context {
                task: TaskId::Avoiding,
                message: "Avoiding has a single fixed start; `context` must be null or {}".into(),
            });
        }
        sim.reset(init_qpos, FingerCommand::RESET, |_| {})?;
        Ok(())
    }

    fn observe(&self, sim: &Sim) -> Vec<f32> {
        let p = sim.tcp_pos();
        vec![p[0] as f32, p[1] as f32]
    }

    fn pre_physics_done(&mut self, sim: &Sim) -> bool {
        if self.terminated {
            return true;
        }
        // docs/original-d3il.md §10.2.5: success first (sticky); collision only if not successful.
        if sim.tcp_pos()[1] > finish_y() {
            self.success = true;
            self.terminated = true;
        } else if self
            .obstacle_geoms
            .iter()
            .any(|&g| sim.data.has_contact(self.rod, g))
        {
            self.terminated = true;
        }
        self.terminated
    }

    fn post_physics(&mut self, sim: &Sim) {
        let p = sim.tcp_pos();
        self.detect_modes(p[0], p[1]);
    }

    fn success(&self) -> bool {
        self.success
    }

    fn behaviour(&self) -> Value {
        json!(self.bits.to_vec())
    }

    fn behaviour_key(&self) -> Option<String> {
        self.success.then(|| self.code().to_string())
    }

    fn objects(&self, _sim: &Sim) -> Vec<(String, [f64; 3])> {
        Vec::new()
    }
}

/// Corridor centres for the rod axis (docs/original-d3il.md §10.2.1 free corridors).
const ROW1_X: [f64; 2] = [0.43, 0.57];
const ROW2_X: [f64; 3] = [0.355, 0.50, 0.645];
const ROW3_X: [f64; 4] = [0.28, 0.425, 0.575, 0.72];

/// The 24 behaviours as (row-1 side, row-2 corridor, row-3 corridor).
pub fn path_choice(path: usize) -> Option<(usize, usize, usize)> {
    (path < 24).then_some((path / 12, (path / 4) % 3, path % 4))
}

/// Mode code of a path index, as the detector would produce it.
pub fn path_code(path: usize) -> Option<u32> {
    let (a, b, c) = path_choice(path)?;
    Some((1 << a) + (4 << b) + (32 << c))
}

/// Scripted reference policy: follows one chosen path of the 24 with the
/// demonstrations' step size (≤ 8 mm per axis), moving sideways only between rows.
#[derive(Debug, Clone)]
pub struct AvoidingScript {
    xs: [f64; 3],
}

impl AvoidingScript {
    pub fn new(path: usize) -> Option<Self> {
        let (a, b, c) = path_choice(path)?;
        Some(AvoidingScript {
            xs: [ROW1_X[a], ROW2_X[b], ROW3_X[c]],
        })
    }

    /// A straight line at a fixed x (used to hit an obstacle on purpose).
    pub fn straight(x: f64) -> Self {
        AvoidingScript { xs: [x; 3] }
    }

    /// Policy input [prev_cmd_xy, tcp_xy] -> delta.
    pub fn act(&self, obs: &[f32]) -> [f32; 2] {
        let (dx, dy) = (obs[0] as f64, obs[1] as f64);
        let target = if dy < -0.04 {
            self.xs[0]
        } else if dy < 0.16 {
            self.xs[1]
        } else {
            self.xs[2]
        };
        let err = target - dx;
        let step_x = err.clamp(-0.008, 0.008);
        // Move forward only once lined up with the corridor.
        let step_y = if err.abs() < 0.01 { 0.008 } else { 0.0 };
        [step_x as f32, step_y as f32]
    }
}
