//! Sorting-2/4/6 (docs/original-d3il.md §11.1): push red and blue boxes off a raised platform
//! into the bin of their colour; the colour sequence in which boxes are
//! sorted is the behaviour (|B| = 2 / 6 / 20, packed MSB-first into a byte).
//!
//! The pose-sample and free-box helpers at the top are shared with Stacking
//! and Inserting (same context conventions, docs/original-d3il.md §11.0.7).

use super::geometry::{dist2, quat_to_yaw};
use super::{
    free_body_pos, free_body_quat, CommandKind, ContextSet, TaskDef, TaskError, TaskLogic,
};
use crate::mujoco::{Data, Model};
use crate::robot::control::FingerCommand;
use crate::robot::{init_qpos, RobotVariant};
use crate::sim::scene::{Primitive, SceneSpec, Shape};
use crate::sim::Sim;
use d3il_protocol::TaskId;
use rand::seq::SliceRandom;
use rand::Rng;
use serde_json::{json, Value};

// ---------------------------------------------------------------------------
// Shared context helpers (docs/original-d3il.md §11.0.7)
// ---------------------------------------------------------------------------

/// One pose sample: (x, y, yaw in degrees) as float32 values plus the float64
/// quaternion the reference applies (the yaw itself is not re-used at reset).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    pub x: f64,
    pub y: f64,
    pub yaw_deg: f64,
    /// (w, x, y, z)
    pub quat: [f64; 4],
}

impl PoseSample {
    /// Uniform float32 sample of [x_lo, x_hi] × [y_lo, y_hi] × [−90°, 90°]
    /// (the reference's `Box.sample`), quaternion (cos θ/2, 0, 0, sin θ/2)
    /// computed in float64 from the float32 yaw.
    pub fn sample(rng: &mut dyn rand::RngCore, x: [f32; 2], y: [f32; 2]) -> PoseSample {
        let mut uni = |lo: f32, hi: f32| -> f32 { lo + (hi - lo) * rng.gen::<f32>() };
        let px = uni(x[0], x[1]);
        let py = uni(y[0], y[1]);
        let yaw = uni(-90.0, 90.0);
        let theta = (yaw as f64).to_radians();
        PoseSample {
            x: px as f64,
            y: py as f64,
            yaw_deg: yaw as f64,
            quat: [(theta / 2.0).cos(), 0.0, 0.0, (theta / 2.0).sin()],
        }
    }

    pub fn xy_deg_json(&self) -> Value {
        json!([self.x, self.y, self.yaw_deg])
    }

    pub fn quat_json(&self) -> Value {
        json!(self.quat)
    }

    /// Parses `xy_deg` (3 numbers) and `quat` (4 numbers, wxyz, non-zero);
    /// `field` names the location for error messages.
    pub fn parse(
        task: TaskId,
        field: &str,
        xy_deg: Option<&Value>,
        quat: Option<&Value>,
        xy_name: &str,
        quat_name: &str,
    ) -> Result<PoseSample, TaskError> {
        let err = |message: String| TaskError::Context { task, message };
        let nums = |v: Option<&Value>, name: &str, n: usize| -> Result<Vec<f64>, TaskError> {
            let v = v.ok_or_else(|| err(format!("field `{field}{name}` is missing")))?;
            let arr = v.as_array().filter(|a| a.len() == n).ok_or_else(|| {
                err(format!(
                    "field `{field}{name}` must be an array of {n} numbers, got {v}"
                ))
            })?;
            arr.iter()
                .map(|x| x.as_f64().filter(|f| f.is_finite()))
                .collect::<Option<Vec<f64>>>()
                .ok_or_else(|| {
                    err(format!(
                        "field `{field}{name}` must hold finite numbers, got {v}"
                    ))
                })
        };
        let p = nums(xy_deg, xy_name, 3)?;
        let q = nums(quat, quat_name, 4)?;
        if q.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
            return Err(err(format!(
                "field `{field}{quat_name}` is a zero quaternion; give (w, x, y, z) of the yaw"
            )));
        }
        Ok(PoseSample {
            x: p[0],
            y: p[1],
            yaw_deg: p[2],
            quat: [q[0], q[1], q[2], q[3]],
        })
    }
}

/// A movable box with a free joint named `<name>:joint`.
#[derive(Debug, Clone)]
pub struct FreeBox {
    pub name: String,
    pub qpos: usize,
}

impl FreeBox {
    pub fn lookup(model: &Model, name: &str) -> Result<FreeBox, TaskError> {
        Ok(FreeBox {
            name: name.to_string(),
            qpos: model.joint_qpos_addr(&format!("{name}:joint"))?,
        })
    }

    /// Box centre, read from qpos (docs/original-d3il.md §11.8.14).
    pub fn pos(&self, data: &Data) -> [f64; 3] {
        free_body_pos(data, self.qpos)
    }

    pub fn quat(&self, data: &Data) -> [f64; 4] {
        free_body_quat(data, self.qpos)
    }

    /// tan of the rotating-frame x-y-z yaw (docs/original-d3il.md §11.0.6).
    pub fn tan_yaw(&self, data: &Data) -> f64 {
        quat_to_yaw(&self.quat(data)).tan()
    }

    /// Overwrites the free-joint pose (velocities stay zero; no forward),
    /// docs/original-d3il.md §11.0.5 step 4.
    pub fn place(&self, data: &mut Data, pose: &PoseSample, z: f64) {
        let q = data.qpos_mut();
        q[self.qpos..self.qpos + 7].copy_from_slice(&[
            pose.x,
            pose.y,
            z,
            pose.quat[0],
            pose.quat[1],
            pose.quat[2],
            pose.quat[3],
        ]);
    }
}

/// A movable box primitive with the spec's mass (MuJoCo's box inertia from it).
pub fn movable_box(name: &str, half: [f64; 3], rgba: [f64; 4], mass: f64) -> Primitive {
    let mut p = Primitive::new(name, Shape::Box, [0.5, -0.1, 0.0], &half);
    p.quat = [0.0, 1.0, 0.0, 0.0];
    p.mass = mass;
    p.rgba = rgba;
    p
}

/// A static box primitive (walls, markers).
pub fn static_box(
    name: &str,
    pos: [f64; 3],
    quat: [f64; 4],
    half: [f64; 3],
    rgba: [f64; 4],
) -> Primitive {
    let mut p = Primitive::new(name, Shape::Box, pos, &half);
    p.quat = quat;
    p.rgba = rgba;
    p.is_static = true;
    p
}

// ---------------------------------------------------------------------------
// Sorting
// ---------------------------------------------------------------------------

const BOX_HALF: f64 = 0.03;
const BOX_MASS: f64 = 0.05;
/// Spawn height inside the platform (docs/original-d3il.md §11.1.2): the solver ejects the boxes.
const SPAWN_Z: f64 = 0.05;
/// Bin reference points of the behaviour tracker (docs/original-d3il.md §11.1.1).
pub const RED_BIN: [f64; 2] = [0.4, 0.32];
pub const BLUE_BIN: [f64; 2] = [0.625, 0.32];

/// The six sampling regions (docs/original-d3il.md §11.1.2).
pub const REGIONS: [([f32; 2], [f32; 2]); 6] = [
    ([0.40, 0.50], [-0.15, -0.10]),
    ([0.40, 0.50], [-0.05, 0.00]),
    ([0.40, 0.50], [0.05, 0.10]),
    ([0.55, 0.65], [-0.15, -0.10]),
    ([0.55, 0.65], [-0.05, 0.00]),
    ([0.55, 0.65], [0.05, 0.10]),
];

/// Bin walls (name, centre, half-sizes, rgba), docs/original-d3il.md §11.1.1.
/// (name, position, half-size, rgba) of a static wall.
type WallSpec = (&'static str, [f64; 3], [f64; 3], [f64; 4]);
const WALLS: [WallSpec; 8] = [
    (
        "target_box_1",
        [0.4, 0.41, 0.0],
        [0.1, 0.01, 0.1],
        [1.0, 0.0, 0.0, 0.5],
    ),
    (
        "target_box_2",
        [0.3, 0.32, 0.0],
        [0.005, 0.1, 0.1],
        [1.0, 0.0, 0.0, 0.5],
    ),
    (
        "target_box_3",
        [0.5, 0.32, 0.0],
        [0.005, 0.1, 0.1],
        [1.0, 0.0, 0.0, 0.5],
    ),
    (
        "target_box_4",
        [0.4, 0.22, 0.0],
        [0.1, 0.005, 0.1],
        [1.0, 0.0, 0.0, 0.5],
    ),
    (
        "target_box_5",
        [0.625, 0.41, 0.0],
        [0.1, 0.01, 0.1],
        [0.0, 0.0, 1.0, 0.5],
    ),
    (
        "target_box_6",
        [0.525, 0.32, 0.0],
        [0.005, 0.1, 0.1],
        [0.0, 0.0, 1.0, 0.5],
    ),
    (
        "target_box_7",
        [0.725, 0.32, 0.0],
        [0.005, 0.1, 0.1],
        [0.0, 0.0, 1.0, 0.5],
    ),
    (
        "target_box_8",
        [0.625, 0.22, 0.0],
        [0.1, 0.005, 0.1],
        [0.0, 0.0, 1.0, 0.5],
    ),
];

/// The platform as the task's XML object (docs/original-d3il.md §11.1.1): a raised static work
/// surface, z ∈ [−0.1, 0.1]; friction 0.3 with priority 1 so box contacts use 0.3.
const PLATFORM_XML: &str = r#"<mujoco>
  <worldbody>
    <body name="platform" pos="0.5 -0.1 0.0" quat="1 0 0 0">
      <geom name="platform:geom" type="box" size="0.3 0.3 0.1" rgba="0.5 0.5 0.5 0.5" mass="10"
            friction="0.3 0.001 0.0001" priority="1" contype="1" conaffinity="1"/>
    </body>
  </worldbody>
</mujoco>
"#;

const CONTEXTS_2_V1: &[u8] = include_bytes!("../../../assets/contexts/sorting-2-v1.json");
pub const CONTEXTS_2_V1_SHA256: &str =
    "631b5f0a166c0f4238360e33a4424d99da217af5dcedff2d77241c36361f23bb";
const CONTEXTS_4_V1: &[u8] = include_bytes!("../../../assets/contexts/sorting-4-v1.json");
pub const CONTEXTS_4_V1_SHA256: &str =
    "b74b3066de6ec017fbec8d6b38b3cc1449cf68a34ae791b7e7e9b55a91436933";
const CONTEXTS_6_V1: &[u8] = include_bytes!("../../../assets/contexts/sorting-6-v1.json");
pub const CONTEXTS_6_V1_SHA256: &str =
    "e08eb49be28ce161f73e73279f5c25bcdf15b6ba789fa37b4893be820ffff594";

/// Box colour; also the bit value of the behaviour code (red 0, blue 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colour {
    Red,
    Blue,
}

impl Colour {
    pub fn letter(self) -> char {
        match self {
            Colour::Red => 'R',
            Colour::Blue => 'B',
        }
    }
    fn bin(self) -> [f64; 2] {
        match self {
            Colour::Red => RED_BIN,
            Colour::Blue => BLUE_BIN,
        }
    }
    /// Colour zone on the box-centre xy, strict inequalities, z ignored (docs/original-d3il.md §11.1.5).
    pub fn in_zone(self, p: &[f64]) -> bool {
        let (x_lo, x_hi) = match self {
            Colour::Red => (0.3, 0.5),
            Colour::Blue => (0.525, 0.725),
        };
        x_lo < p[0] && p[0] < x_hi && 0.22 < p[1] && p[1] < 0.41
    }
}

/// Packed behaviour code of a colour sequence (docs/original-d3il.md §11.1.6): MSB first,
/// red → 0, blue → 1, unfilled slots → 1.
pub fn pack_code(slots: &[Option<Colour>]) -> u32 {
    slots
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let bit = u32::from(!matches!(s, Some(Colour::Red)));
            bit << (7 - i)
        })
        .sum()
}

/// Whether `code` packs a complete Sorting-`n_boxes` colour sequence: of its
/// `n_boxes` leading bits exactly half are blue (1), the rest zero.
pub fn is_sequence_code(code: u32, n_boxes: usize) -> bool {
    let used = (0xFFu32 << (8 - n_boxes)) & 0xFF;
    code & !used == 0 && code.count_ones() as usize == n_boxes / 2
}

/// Parses an order like "RBBR" into colours.
pub fn parse_order(order: &str) -> Option<Vec<Colour>> {
    order
        .chars()
        .map(|c| match c.to_ascii_uppercase() {
            'R' => Some(Colour::Red),
            'B' => Some(Colour::Blue),
            _ => None,
        })
        .collect()
}

/// Sorting-X, X ∈ {2, 4, 6}.
pub struct Sorting {
    pub n_boxes: usize,
}

impl Sorting {
    pub fn new(n_boxes: usize) -> Sorting {
        debug_assert!(matches!(n_boxes, 2 | 4 | 6));
        Sorting { n_boxes }
    }

    /// Box names in observation order: red_1.., then blue_1..
    pub fn box_names(&self) -> Vec<(String, Colour)> {
        let half = self.n_boxes / 2;
        let mut v: Vec<(String, Colour)> = (1..=half)
            .map(|i| (format!("red_{i}"), Colour::Red))
            .collect();
        v.extend((1..=half).map(|i| (format!("blue_{i}"), Colour::Blue)));
        v
    }

    /// Parses a context `{"entries": [{"xy_deg": [x, y, deg], "quat": [w, x, y, z]}, ...]}`
    /// (the reference rollouts' format; `format` and other keys are ignored).
    pub fn parse_context(&self, context: &Value) -> Result<Vec<PoseSample>, TaskError> {
        let task = self.id();
        let entries = context
            .get("entries")
            .and_then(Value::as_array)
            .ok_or_else(|| TaskError::Context {
                task,
                message: "field `entries` is missing or not an array; a Sorting context is {\"entries\": [{\"xy_deg\": [x, y, yaw_deg], \"quat\": [w, x, y, z]}, ... 6 entries]}".into(),
            })?;
        if entries.len() < self.n_boxes || entries.len() > 6 {
            return Err(TaskError::Context {
                task,
                message: format!(
                    "field `entries` has {} poses; {task} needs between {} and 6 (first half red, then blue)",
                    entries.len(),
                    self.n_boxes
                ),
            });
        }
        entries
            .iter()
            .take(self.n_boxes)
            .enumerate()
            .map(|(i, e)| {
                PoseSample::parse(
                    task,
                    &format!("entries[{i}]."),
                    e.get("xy_deg"),
                    e.get("quat"),
                    "xy_deg",
                    "quat",
                )
            })
            .collect()
    }
}

impl TaskDef for Sorting {
    fn id(&self) -> TaskId {
        match self.n_boxes {
            2 => TaskId::Sorting2,
            4 => TaskId::Sorting4,
            _ => TaskId::Sorting6,
        }
    }
    fn version(&self) -> &'static str {
        "v1"
    }
    fn scene(&self) -> SceneSpec {
        let mut s = SceneSpec::new(RobotVariant::Rod);
        for (name, colour) in self.box_names() {
            let rgba = match colour {
                Colour::Red => [1.0, 0.0, 0.0, 1.0],
                Colour::Blue => [0.0, 0.0, 1.0, 1.0],
            };
            s.primitives
                .push(movable_box(&name, [BOX_HALF; 3], rgba, BOX_MASS));
        }
        for (name, pos, half, rgba) in WALLS {
            s.primitives
                .push(static_box(name, pos, [0.0, 1.0, 0.0, 0.0], half, rgba));
        }
        s.includes
            .push(("sorting_platform.xml".into(), PLATFORM_XML.into()));
        s
    }
    fn init_qpos(&self) -> [f64; 7] {
        init_qpos::SORTING
    }
    fn env_obs_dim(&self) -> usize {
        2 + 3 * self.n_boxes
    }
    fn command_kind(&self) -> CommandKind {
        CommandKind::XyDelta
    }
    fn context_set(&self) -> Result<ContextSet, TaskError> {
        let (name, bytes, sha) = match self.n_boxes {
            2 => ("sorting-2-v1.json", CONTEXTS_2_V1, CONTEXTS_2_V1_SHA256),
            4 => ("sorting-4-v1.json", CONTEXTS_4_V1, CONTEXTS_4_V1_SHA256),
            _ => ("sorting-6-v1.json", CONTEXTS_6_V1, CONTEXTS_6_V1_SHA256),
        };
        ContextSet::verify(name, bytes, sha)
    }
    /// docs/original-d3il.md §11.1.2: one pose per region, then a random permutation of the six.
    fn sample_context(&self, rng: &mut dyn rand::RngCore) -> Value {
        let mut poses: Vec<PoseSample> = REGIONS
            .iter()
            .map(|(x, y)| PoseSample::sample(rng, *x, *y))
            .collect();
        poses.shuffle(rng);
        json!({
            "entries": poses
                .iter()
                .map(|p| json!({"xy_deg": p.xy_deg_json(), "quat": p.quat_json()}))
                .collect::<Vec<_>>()
        })
    }
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError> {
        let boxes = self
            .box_names()
            .into_iter()
            .map(|(n, c)| Ok((FreeBox::lookup(model, &n)?, c)))
            .collect::<Result<Vec<_>, TaskError>>()?;
        Ok(Box::new(SortingLogic {
            parser: Sorting::new(self.n_boxes),
            boxes,
            slots: [None; 6],
            registered: Vec::new(),
            success: false,
            terminated: false,
        }))
    }
}

pub struct SortingLogic {
    parser: Sorting,
    boxes: Vec<(FreeBox, Colour)>,
    /// The tracker's six slots (docs/original-d3il.md §11.1.6); None = −1.
    slots: [Option<Colour>; 6],
    /// Indices into `boxes` of registered boxes, in registration order.
    registered: Vec<usize>,
    success: bool,
    terminated: bool,
}

impl SortingLogic {
    fn all_sorted(&self, sim: &Sim) -> bool {
        self.boxes.iter().all(|(b, c)| c.in_zone(&b.pos(&sim.data)))
    }

    /// docs/original-d3il.md §11.1.6. The reference also lets the absent boxes of Sorting-2/4
    /// take part (their pose lookup falls back to a fixed point far from both
    /// bins); such a "ghost" can never be in a zone, so ignoring absent boxes is
    /// equivalent — except that it must not let a registered box register
    /// again once every present box is registered, which the early return does.
    fn track(&mut self, sim: &Sim) {
        let k = self.registered.len();
        if k > 5 || k == self.boxes.len() {
            return;
        }
        let mut best: Option<(usize, f64)> = None;
        for (i, (b, c)) in self.boxes.iter().enumerate() {
            let d = if self.registered.contains(&i) {
                1e5
            } else {
                dist2(&b.pos(&sim.data), &c.bin())
            };
            if best.is_none_or(|(_, bd)| d < bd) {
                best = Some((i, d));
            }
        }
        if let Some((i, _)) = best {
            let (b, c) = &self.boxes[i];
            if !self.registered.contains(&i) && c.in_zone(&b.pos(&sim.data)) {
                self.slots[k] = Some(*c);
                self.registered.push(i);
            }
        }
    }

    /// The packed code of the first X slots (docs/original-d3il.md §11.1.6).
    pub fn code(&self) -> u32 {
        pack_code(&self.slots[..self.boxes.len()])
    }
}

impl TaskLogic for SortingLogic {
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError> {
        let poses = self.parser.parse_context(context)?;
        let boxes = self.boxes.clone();
        sim.reset(init_qpos, FingerCommand::RESET, |data| {
            for ((b, _), pose) in boxes.iter().zip(&poses) {
                b.place(data, pose, SPAWN_Z);
            }
        })?;
        Ok(())
    }

    /// docs/original-d3il.md §11.1.3: TCP xy, then per box (x, y, tan yaw), red boxes first.
    fn observe(&self, sim: &Sim) -> Vec<f32> {
        let p = sim.tcp_pos();
        let mut v = vec![p[0] as f32, p[1] as f32];
        for (b, _) in &self.boxes {
            let q = b.pos(&sim.data);
            v.extend([q[0] as f32, q[1] as f32, b.tan_yaw(&sim.data) as f32]);
        }
        v
    }

    fn pre_physics_done(&mut self, sim: &Sim) -> bool {
        self.terminated || self.all_sorted(sim)
    }

    /// Success as measured after this step's physics (it goes into the info
    /// the evaluation loop reads), then the order tracker (docs/original-d3il.md §11.0.4).
    fn post_physics(&mut self, sim: &Sim) {
        self.success = self.all_sorted(sim);
        if self.success {
            self.terminated = true;
        }
        self.track(sim);
    }

    fn success(&self) -> bool {
        self.success
    }

    /// The packed integer code (`info.mode`), e.g. 64 = RB for Sorting-2.
    fn behaviour(&self) -> Value {
        json!(self.code())
    }

    /// Only codes of a complete colour sequence (X/2 red, X/2 blue: the keys
    /// of the reference's `<X>_mode_prob.pkl`) are behaviours; a success whose
    /// tracker missed a box packs to another code, which the reference ignores
    /// in its entropies (docs/original-d3il.md §11.1.7), so it is an unlabelled success here.
    fn behaviour_key(&self) -> Option<String> {
        let code = self.code();
        (self.success && is_sequence_code(code, self.boxes.len())).then(|| code.to_string())
    }

    fn objects(&self, sim: &Sim) -> Vec<(String, [f64; 3])> {
        self.boxes
            .iter()
            .map(|(b, _)| (b.name.clone(), b.pos(&sim.data)))
            .collect()
    }
}

#[path = "sorting_script.rs"]
mod script;
pub use script::SortingScript;
