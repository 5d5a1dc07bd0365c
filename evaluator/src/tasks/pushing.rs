//! Pushing (docs/original-d3il.md §10.4): push a red and a green cube into two target zones,
//! colour-matched or swapped; the behaviour is the assignment and which box
//! arrives first (modes 0…3, −1 unlabeled).

use super::aligning::{parse_poses, PlanarPose};
use super::geometry::{dist3, quat_to_yaw};
use super::{CommandKind, ContextSet, TaskDef, TaskError, TaskLogic};
use crate::mujoco::Model;
use crate::robot::control::FingerCommand;
use crate::robot::{init_qpos, RobotVariant};
use crate::sim::scene::{Primitive, SceneSpec, Shape};
use crate::sim::Sim;
use d3il_protocol::TaskId;
use serde_json::{json, Map, Value};

/// Target zone centres (docs/original-d3il.md §10.4.1): red (0.42, 0.30, 0), green (0.63, 0.30, 0).
pub const RED_TARGET: [f64; 3] = [0.42, 0.30, 0.0];
pub const GREEN_TARGET: [f64; 3] = [0.63, 0.30, 0.0];
/// docs/original-d3il.md §10.4.5: 3-D distance threshold for success and visits.
pub const TAU: f64 = 0.05;

const CONTEXTS_V1: &[u8] = include_bytes!("../../../assets/contexts/pushing-v1.json");
pub const CONTEXTS_V1_SHA256: &str =
    "932dce2d7100e99d55fff4e9d2bae89ec872497608f43efa6b1e321878f23dd0";
/// The original D3IL test contexts (`test_contexts.pkl` of the reference,
/// decoded in shared/reference-contexts; `d3il contexts import`): the set in use.
const CONTEXTS_V2: &[u8] = include_bytes!("../../../assets/contexts/pushing-v2.json");
pub const CONTEXTS_V2_SHA256: &str =
    "16e158084f5a7940e3dac06b1d91a58a853b5a3fdc6b1a5783dccaa5d21b789f";

pub struct Pushing;

impl TaskDef for Pushing {
    fn id(&self) -> TaskId {
        TaskId::Pushing
    }
    fn version(&self) -> &'static str {
        "v1"
    }
    fn scene(&self) -> SceneSpec {
        let mut s = SceneSpec::new(RobotVariant::Rod);
        // docs/original-d3il.md §10.4.1, in the reference's order: red box, green box, red
        // target, green target. The MJCF poses are overwritten at reset.
        let flipped = [0.0, 1.0, 0.0, 0.0];
        for (name, x, rgba) in [
            ("push_box", 0.4, [1.0, 0.0, 0.0, 1.0]),
            ("push_box2", 0.5, [0.0, 1.0, 0.0, 1.0]),
        ] {
            let mut p = Primitive::new(name, Shape::Box, [x, -0.3, -0.0072], &[0.03, 0.03, 0.03]);
            p.quat = flipped;
            p.mass = 0.05;
            p.rgba = rgba;
            s.primitives.push(p);
        }
        // The reference names the targets SIM_OBJ_<k>; the name is irrelevant
        // (visual only, static), ours says what they are.
        for (name, pos, rgba) in [
            ("target_red", RED_TARGET, [1.0, 0.0, 0.0, 0.3]),
            ("target_green", GREEN_TARGET, [0.0, 1.0, 0.0, 0.3]),
        ] {
            let mut p = Primitive::new(name, Shape::Box, pos, &[0.05, 0.05, 0.04]);
            p.quat = flipped;
            p.rgba = rgba;
            p.is_static = true;
            p.visual_only = true;
            s.primitives.push(p);
        }
        s
    }
    fn init_qpos(&self) -> [f64; 7] {
        init_qpos::AVOIDING
    }
    fn env_obs_dim(&self) -> usize {
        8
    }
    fn command_kind(&self) -> CommandKind {
        CommandKind::XyDelta
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        ContextSet::verify("pushing-v2.json", CONTEXTS_V2, CONTEXTS_V2_SHA256)
    }
    /// v2 (in use) and our earlier sample v1, which stored results refer to.
    fn context_sets(&self) -> Result<Vec<ContextSet>, TaskError> {
        Ok(vec![
            self.context_set()?,
            ContextSet::verify("pushing-v1.json", CONTEXTS_V1, CONTEXTS_V1_SHA256)?,
        ])
    }
    /// docs/original-d3il.md §10.4.2 random distribution (independent uniform, no rejection).
    fn sample_context(&self, rng: &mut dyn rand::RngCore) -> Value {
        let r = PlanarPose::sample(rng, (0.4, 0.5), (-0.15, 0.0), (-90.0, 90.0));
        let g = PlanarPose::sample(rng, (0.55, 0.65), (-0.15, 0.0), (-90.0, 90.0));
        let mut obj = Map::new();
        r.to_json("red", &mut obj);
        g.to_json("green", &mut obj);
        Value::Object(obj)
    }
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError> {
        Ok(Box::new(PushingLogic {
            red_qpos: model.joint_qpos_addr("push_box:joint")?,
            green_qpos: model.joint_qpos_addr("push_box2:joint")?,
            first_visit: -1,
            mode: -1,
            stepped: false,
            success: false,
            terminated: false,
        }))
    }
}

pub struct PushingLogic {
    red_qpos: usize,
    green_qpos: usize,
    /// docs/original-d3il.md §10.4.6: latched first box–zone pair, −1 until any box is in any zone.
    first_visit: i8,
    /// Mode of the last step (−1 none, 0 rr→gg, 1 gg→rr, 2 rg→gr, 3 gr→rg).
    mode: i8,
    stepped: bool,
    success: bool,
    terminated: bool,
}

/// The four box–target distances (d_rr, d_rg, d_gr, d_gg), 3-D (docs/original-d3il.md §10.4.5).
pub fn distances(red: &[f64; 3], green: &[f64; 3]) -> [f64; 4] {
    [
        dist3(red, &RED_TARGET),
        dist3(red, &GREEN_TARGET),
        dist3(green, &RED_TARGET),
        dist3(green, &GREEN_TARGET),
    ]
}

/// docs/original-d3il.md §10.4.5 success condition.
pub fn solved(d: &[f64; 4]) -> bool {
    (d[0] <= TAU && d[3] <= TAU) || (d[1] <= TAU && d[2] <= TAU)
}

/// One step of the docs/original-d3il.md §10.4.6 mode detector: returns (new first_visit, mode).
pub fn detect_mode(first_visit: i8, d: &[f64; 4]) -> (i8, i8) {
    let mut v = -1;
    for (i, &di) in d.iter().enumerate() {
        if di <= TAU && first_visit != i as i8 {
            v = i as i8;
            break;
        }
    }
    if first_visit == -1 {
        return (v, -1);
    }
    let mode = match (first_visit, v) {
        (0, 3) => 0,
        (3, 0) => 1,
        (1, 2) => 2,
        (2, 1) => 3,
        _ => -1,
    };
    (first_visit, mode)
}

impl PushingLogic {
    fn boxes(&self, sim: &Sim) -> ([f64; 3], [f64; 4], [f64; 3], [f64; 4]) {
        let d = &sim.data;
        (
            super::free_body_pos(d, self.red_qpos),
            super::free_body_quat(d, self.red_qpos),
            super::free_body_pos(d, self.green_qpos),
            super::free_body_quat(d, self.green_qpos),
        )
    }

    fn distances(&self, sim: &Sim) -> [f64; 4] {
        let (r, _, g, _) = self.boxes(sim);
        distances(&r, &g)
    }
}

impl TaskLogic for PushingLogic {
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError> {
        let [r, g] = parse_poses(TaskId::Pushing, context, ["red", "green"])?;
        let (ra, ga) = (self.red_qpos, self.green_qpos);
        // docs/original-d3il.md §10.4.2: boxes at (x, y, 0) with the context quaternions; the
        // targets never move.
        sim.reset(init_qpos, FingerCommand::RESET, |data| {
            let q = data.qpos_mut();
            for (adr, p) in [(ra, r), (ga, g)] {
                q[adr..adr + 3].copy_from_slice(&[p.x, p.y, 0.0]);
                q[adr + 3..adr + 7].copy_from_slice(&p.quat);
            }
        })?;
        Ok(())
    }

    /// docs/original-d3il.md §10.4.3: TCP xy, red xy, tan(yaw_red), green xy, tan(yaw_green).
    /// tan is not wrapped: it is huge near ±90°, as in the reference.
    fn observe(&self, sim: &Sim) -> Vec<f32> {
        let tcp = sim.tcp_pos();
        let (r, rq, g, gq) = self.boxes(sim);
        [
            tcp[0],
            tcp[1],
            r[0],
            r[1],
            quat_to_yaw(&rq).tan(),
            g[0],
            g[1],
            quat_to_yaw(&gq).tan(),
        ]
        .iter()
        .map(|&v| v as f32)
        .collect()
    }

    fn pre_physics_done(&mut self, sim: &Sim) -> bool {
        if !self.terminated && solved(&self.distances(sim)) {
            self.terminated = true;
        }
        self.terminated
    }

    fn post_physics(&mut self, sim: &Sim) {
        let d = self.distances(sim);
        self.success = solved(&d);
        if self.success {
            self.terminated = true;
        }
        let (fv, mode) = detect_mode(self.first_visit, &d);
        self.first_visit = fv;
        self.mode = mode;
        self.stepped = true;
    }

    fn success(&self) -> bool {
        self.success
    }

    fn behaviour(&self) -> Value {
        if self.stepped {
            json!(self.mode)
        } else {
            Value::Null
        }
    }

    /// Successes with mode −1 count in the success rate but in no mode bin
    /// (docs/original-d3il.md §10.4.6, §10.6.5).
    fn behaviour_key(&self) -> Option<String> {
        (self.success && self.mode >= 0).then(|| self.mode.to_string())
    }

    fn objects(&self, sim: &Sim) -> Vec<(String, [f64; 3])> {
        let (r, _, g, _) = self.boxes(sim);
        vec![
            ("push_box".into(), r),
            ("push_box2".into(), g),
            ("target_red".into(), RED_TARGET),
            ("target_green".into(), GREEN_TARGET),
        ]
    }
}

// ---------------------------------------------------------------------------
// Scripted reference policy
// ---------------------------------------------------------------------------

/// Scripted reference policy for Pushing: delivers the boxes in the order and
/// assignment of one mode (0 rr→gg, 1 gg→rr, 2 rg→gr, 3 gr→rg). Stateless: it
/// reads everything from the 10-D policy observation (privileged: box poses).
///
/// Per step: the active box is the first one until it sits within 2 cm of its
/// zone centre, then the second. The rod pushes the box face that looks
/// against the desired motion, at the point where the line through the box
/// centre along the motion meets that face, so the box translates towards its
/// goal (re-aimed every step). Between contacts the rod circles around boxes
/// at a safe distance (it cannot be lifted: z is fixed, docs/original-d3il.md §10.4.4). In the
/// swapped assignments a box is first pushed straight up (+y) past the other
/// box's row so the two paths do not cross.
#[derive(Debug, Clone)]
pub struct PushingScript {
    mode: u8,
}

const HALF: f64 = 0.03;
const ROD_R: f64 = 0.01;
/// Keep-out radius around a box centre for the rod axis while travelling.
const KEEP_OUT: f64 = HALF * std::f64::consts::SQRT_2 + ROD_R + 0.012;
const MAX_STEP: f64 = 0.008;
/// y above which a box has cleared the start row (swapped assignments).
const CLEAR_Y: f64 = 0.08;

type V2 = [f64; 2];
fn sub(a: V2, b: V2) -> V2 {
    [a[0] - b[0], a[1] - b[1]]
}
fn add(a: V2, b: V2) -> V2 {
    [a[0] + b[0], a[1] + b[1]]
}
fn scale(a: V2, k: f64) -> V2 {
    [a[0] * k, a[1] * k]
}
fn norm(a: V2) -> f64 {
    a[0].hypot(a[1])
}
fn dot(a: V2, b: V2) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}
fn cross(a: V2, b: V2) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}
fn rot(v: V2, a: f64) -> V2 {
    let (s, c) = a.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}
fn unit(v: V2) -> V2 {
    let n = norm(v);
    if n > 1e-12 {
        scale(v, 1.0 / n)
    } else {
        [0.0, 1.0]
    }
}

const NORMALS: [V2; 4] = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]];

/// Distance from point `o` to the segment a→b.
fn seg_dist(a: V2, b: V2, o: V2) -> f64 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    let t = if l2 > 0.0 {
        (dot(sub(o, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    norm(sub(add(a, scale(ab, t)), o))
}

/// Next point on the way from `q` to `goal` that keeps out of the boxes'
/// keep-out discs: circle around the first disc in the way, on the side of the goal.
fn navigate(q: V2, goal: V2, obstacles: &[V2]) -> V2 {
    let around = |o: V2| {
        let w = sub(q, o);
        let side = if cross(w, sub(goal, o)) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        add(o, scale(rot(unit(w), side * 0.6), KEEP_OUT + 0.02))
    };
    if let Some(&o) = obstacles.iter().find(|&&o| norm(sub(q, o)) < KEEP_OUT) {
        return around(o);
    }
    let mut blocking: Vec<V2> = obstacles
        .iter()
        .copied()
        .filter(|&o| seg_dist(q, goal, o) < KEEP_OUT)
        .collect();
    blocking.sort_by(|a, b| norm(sub(q, *a)).total_cmp(&norm(sub(q, *b))));
    match blocking.first() {
        Some(&o) => around(o),
        None => goal,
    }
}

fn step_towards(d: V2, goal: V2, max: f64) -> [f32; 2] {
    let mut v = sub(goal, d);
    let n = norm(v);
    if n > max {
        v = scale(v, max / n);
    }
    [v[0] as f32, v[1] as f32]
}

impl PushingScript {
    /// `mode` as the task labels it: 0 rr→gg, 1 gg→rr, 2 rg→gr, 3 gr→rg.
    pub fn new(mode: u8) -> Option<Self> {
        (mode < 4).then_some(PushingScript { mode })
    }

    pub fn mode(&self) -> u8 {
        self.mode
    }

    /// Policy observation (10) -> xy delta.
    pub fn act(&self, obs: &[f32]) -> [f32; 2] {
        let o: Vec<f64> = obs.iter().map(|&v| v as f64).collect();
        let d = [o[0], o[1]];
        let r = [o[2], o[3]];
        let red = ([o[4], o[5]], o[6].atan());
        let green = ([o[7], o[8]], o[9].atan());
        let rt = [RED_TARGET[0], RED_TARGET[1]];
        let gt = [GREEN_TARGET[0], GREEN_TARGET[1]];
        // (box, its target) in delivery order.
        let plan = match self.mode {
            0 => [(red, rt), (green, gt)],
            1 => [(green, gt), (red, rt)],
            2 => [(red, gt), (green, rt)],
            _ => [(green, rt), (red, gt)],
        };
        let swapped = self.mode >= 2;
        let Some(&((b, psi), t)) = plan.iter().find(|((b, _), t)| norm(sub(*t, *b)) > 0.02) else {
            return [0.0, 0.0];
        };
        let dist = norm(sub(t, b));
        let m = if swapped && b[1] < CLEAR_Y {
            [0.0, 1.0]
        } else {
            unit(sub(t, b))
        };
        let to_local = |w: V2| rot(sub(w, b), -psi);
        let to_world = |l: V2| add(b, rot(l, psi));
        let m_l = rot(m, -psi);
        let r_l = to_local(r);
        // The face looking against the motion; keep the one the rod is at
        // while it still faces the motion within 60°.
        let mut face = NORMALS[0];
        for n in NORMALS {
            if -dot(n, m_l) > -dot(face, m_l) {
                face = n;
            }
        }
        for n in NORMALS {
            let tang = [-n[1], n[0]];
            if dot(n, r_l) > HALF && dot(tang, r_l).abs() < HALF + 0.01 && -dot(n, m_l) > 0.5 {
                face = n;
            }
        }
        let tang = [-face[1], face[0]];
        let k = HALF / (-dot(face, m_l)).max(0.3);
        let along = dot(scale(m_l, -k), tang).clamp(-0.022, 0.022);
        let contact_l = add(scale(face, HALF + ROD_R), scale(tang, along));
        let contact = to_world(contact_l);
        let approach = to_world(add(contact_l, scale(face, 0.03)));
        let pushing = (norm(sub(r, contact)) < 0.025 || norm(sub(r, approach)) < 0.015)
            && dot(face, r_l) > HALF;
        if pushing {
            let speed = (0.3 * dist).clamp(0.003, MAX_STEP);
            return step_towards(d, add(contact, scale(m, 0.03)), speed);
        }
        let obstacles = [red.0, green.0];
        let next = navigate(r, approach, &obstacles);
        step_towards(d, next, MAX_STEP)
    }
}
