//! The robustness track's perturbations (docs/robustness.md): the
//! fixed, versioned suite files (`assets/robustness/<task>-v<N>.json`, sha256
//! checked at load like the initial-state sets) and what each axis does.
//!
//! Every axis leaves the initial states, the seed and the rollout ids alone,
//! so a perturbed level gets the same policy noise as level 0 (the ONNX
//! `noise` input is a function of seed, rollout id and step) and its drop is
//! paired by initial state:
//!
//! * `start_shift`: each listed coordinate of a test state is pushed away
//!   from the centre `c` of the task's sampling range, `x' = c + (x − c)(1 +
//!   w)`: the range widened by `w`, and every shifted state the twin of the
//!   level-0 state it came from (the same "seed" at every level).
//! * `obs_noise`: Gaussian noise on the environment observation (not on the
//!   previous-command prefix, which is the controller's own variable), in
//!   task units: metres on positions, radians on yaw angles (applied to the
//!   angle behind a `tan(yaw)` or a quaternion); drawn from a ChaCha8 stream
//!   keyed by (seed, rollout id, step) and a tag of its own, so it is
//!   reproducible and independent of the policy's noise.
//! * `latency`: the action the policy gives at step t is applied at step
//!   t + L; the first L steps apply the hold action (a zero delta: stay at
//!   the previous command). A fractional L = n + f (suites v2) applies the
//!   blend `(1 − f)·a(t − n) + f·a(t − n − 1)`: latency interpolated between
//!   n and n + 1 steps (`CommandKind::blend_late`: Stacking's absolute
//!   gripper value is not blended but taken whole from the action of the
//!   larger share, the older on a tie). The record holds what the
//!   environment received.
//! * `dynamics`: the boxes' mass and inertia scaled, and the box–table
//!   sliding friction scaled: MuJoCo takes a contact's friction from the geom
//!   of higher priority (the larger of the two at equal priority), so the
//!   boxes' geoms get priority over the table and the scaled value of the
//!   friction the contact had.
//! * `camera` and `lighting` (image suites only, `crate::perturb_view`): the
//!   cameras moved and turned in their own frames, the lights dimmed and
//!   tilted, in a fresh compile of the scene like `dynamics`. State suites
//!   have no image axes, image suites no `obs_noise` (an image policy does
//!   not observe the state).

use crate::mujoco::ObjKind;
use crate::tasks::{CommandKind, LoadedTask, TaskError};
use d3il_protocol::perturbation::{Axis, LevelSetting, Perturbation};
use d3il_protocol::{ObsType, TaskId};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::sync::Arc;

mod files;
use files::SUITES;
pub use files::*;

#[derive(Debug, thiserror::Error)]
pub enum PerturbError {
    #[error("robustness suite `{name}`: {message}")]
    Suite { name: String, message: String },
    #[error("task {0} has no robustness suite for {1} observations yet (suites: {2})")]
    NoSuite(TaskId, ObsType, String),
    #[error(transparent)]
    Task(#[from] TaskError),
}

/// A coordinate of the initial state that `start_shift` moves.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ShiftField {
    /// Context field, e.g. `box_xy_deg`.
    pub field: String,
    /// 0 = x, 1 = y.
    pub index: usize,
    /// The task's sampling range of that coordinate (docs/original-d3il.md).
    pub range: [f64; 2],
}

/// Poses kept in an array, each drawn from one of several regions and then
/// permuted (Sorting's `entries`, docs/original-d3il.md §11.1.2): which range
/// a pose was drawn from is the region that contains it, and `start_shift`
/// pushes it away from that region's centre.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ShiftRegions {
    /// The context's array of poses, e.g. `entries`.
    pub array: String,
    /// Each element's pose field (x, y, yaw in degrees), e.g. `xy_deg`.
    pub pose: String,
    /// The sampling regions: (x range, y range) each.
    pub regions: Vec<[[f64; 2]; 2]>,
}

impl ShiftRegions {
    /// The region containing (x, y) (bounds included).
    fn containing(&self, x: f64, y: f64) -> Option<&[[f64; 2]; 2]> {
        self.regions
            .iter()
            .find(|[rx, ry]| (rx[0]..=rx[1]).contains(&x) && (ry[0]..=ry[1]).contains(&y))
    }
}

/// How noise enters one entry of the environment observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObsUnit {
    /// A position in metres: `+ σ_position · z`.
    Position,
    /// `tan(yaw)`: the yaw gets `σ_angle · z`.
    TanYaw,
    /// A quaternion (w, x, y, z; four entries): turned about the vertical
    /// by `σ_angle · z`.
    QuatYaw,
    /// Left exact.
    Exact,
}

impl ObsUnit {
    fn width(self) -> usize {
        match self {
            ObsUnit::QuatYaw => 4,
            _ => 1,
        }
    }
}

/// One axis of a suite and its levels (1, 2, ...; level 0 is implicit).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SuiteAxis {
    pub axis: Axis,
    /// Why these levels.
    #[serde(default)]
    pub rationale: String,
    pub levels: Vec<LevelSetting>,
}

/// A suite file as committed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SuiteFile {
    pub task: TaskId,
    /// The policies the suite is for (files before the image suites: state).
    #[serde(default = "state")]
    pub obs_type: ObsType,
    pub version: String,
    pub description: String,
    /// The coordinates `start_shift` moves, with their sampling ranges
    /// (none: a task whose start does not vary, e.g. Avoiding).
    #[serde(default)]
    pub start_shift_fields: Vec<ShiftField>,
    /// Poses drawn from permuted regions (Sorting).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_shift_regions: Option<ShiftRegions>,
    /// The environment observation entry by entry (a `quat_yaw` covers four).
    pub obs_units: Vec<ObsUnit>,
    /// The bodies `dynamics` changes, and the geom they rest on (the table,
    /// Sorting's platform) whose contacts with them get the scaled friction;
    /// none for a task without movable objects (Avoiding).
    #[serde(default)]
    pub dynamics_bodies: Vec<String>,
    #[serde(default)]
    pub table_geom: Option<String>,
    /// The cameras `camera` moves (image suites).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cameras: Vec<String>,
    pub axes: Vec<SuiteAxis>,
}

fn state() -> ObsType {
    ObsType::State
}

/// A verified suite.
#[derive(Debug, Clone)]
pub struct Suite {
    pub name: String,
    pub sha256: String,
    pub file: Arc<SuiteFile>,
}

impl Suite {
    /// The current suite of `task` for state policies, sha256 checked.
    pub fn for_task(task: TaskId) -> Result<Suite, PerturbError> {
        Suite::current(task, ObsType::State)
    }

    /// The current suite of `task` for `obs` policies (its newest version),
    /// sha256 checked.
    pub fn current(task: TaskId, obs: ObsType) -> Result<Suite, PerturbError> {
        let &(_, _, name, bytes, sha) = SUITES
            .iter()
            .rev()
            .find(|s| s.0 == task && s.1 == obs)
            .ok_or_else(|| {
                PerturbError::NoSuite(
                    task,
                    obs,
                    SUITES
                        .iter()
                        .map(|s| format!("{} ({})", s.0, s.1.as_str()))
                        .collect::<std::collections::BTreeSet<_>>()
                        .into_iter()
                        .collect::<Vec<_>>()
                        .join(", "),
                )
            })?;
        Suite::verify(name, bytes, sha)
    }

    /// The committed suite named `name` (as a manifest records it) of `task`.
    pub fn named(task: TaskId, name: &str) -> Result<Suite, PerturbError> {
        let &(_, _, name, bytes, sha) = SUITES
            .iter()
            .find(|s| s.0 == task && s.2 == name)
            .ok_or_else(|| PerturbError::Suite {
                name: name.into(),
                message: format!("this build has no such robustness suite for {task}"),
            })?;
        Suite::verify(name, bytes, sha)
    }

    /// Parses `bytes` after checking their sha256 against `expected_sha256`.
    pub fn verify(name: &str, bytes: &[u8], expected_sha256: &str) -> Result<Suite, PerturbError> {
        let bad = |message: String| PerturbError::Suite {
            name: name.into(),
            message,
        };
        let got = crate::tasks::contexts::sha256_hex(bytes);
        if got != expected_sha256 {
            return Err(bad(format!(
                "sha256 is {got} but this evaluator expects {expected_sha256}; the file was modified. \
                 Restore it from the repository (git checkout assets/robustness/{name}) — suites are versioned and never edited in place: a new version is a new file"
            )));
        }
        let file: SuiteFile = serde_json::from_slice(bytes)
            .map_err(|e| bad(format!("not a valid suite file: {e}")))?;
        let suite = Suite {
            name: name.into(),
            sha256: got,
            file: Arc::new(file),
        };
        suite.check().map_err(bad)?;
        Ok(suite)
    }

    fn check(&self) -> Result<(), String> {
        let def = crate::tasks::task_def(self.file.task).map_err(|e| e.to_string())?;
        let width: usize = self.file.obs_units.iter().map(|u| u.width()).sum();
        if width != def.env_obs_dim() {
            return Err(format!(
                "obs_units cover {width} observation entries but {} observes {}",
                self.file.task,
                def.env_obs_dim()
            ));
        }
        let regions = self.file.start_shift_regions.as_ref();
        if regions.is_some_and(|r| {
            r.regions.is_empty() || r.regions.iter().any(|[x, y]| x[0] >= x[1] || y[0] >= y[1])
        }) {
            return Err("start_shift_regions needs regions with increasing x and y ranges".into());
        }
        for f in &self.file.start_shift_fields {
            if f.index > 1 || !f.field.ends_with("_xy_deg") || f.range[0] >= f.range[1] {
                return Err(format!(
                    "start_shift field {}[{}] must be the x or y of a `_xy_deg` pose with an increasing range",
                    f.field, f.index
                ));
            }
        }
        let image = self.file.obs_type == ObsType::Image;
        for a in &self.file.axes {
            let fits = match a.axis {
                Axis::Camera | Axis::Lighting => image,
                Axis::ObsNoise => !image,
                _ => true,
            };
            if !fits {
                return Err(format!(
                    "axis {} is not for {} policies (camera and lighting are image axes; obs_noise acts on the state observation)",
                    a.axis,
                    self.file.obs_type.as_str()
                ));
            }
            if a.axis == Axis::Camera && self.file.cameras.is_empty() {
                return Err("axis camera needs the `cameras` it moves".into());
            }
            if a.axis == Axis::StartShift
                && self.file.start_shift_fields.is_empty()
                && regions.is_none()
            {
                return Err("axis start_shift needs the `start_shift_fields` or `start_shift_regions` it moves; leave the axis out for a task whose start does not vary".into());
            }
            if a.axis == Axis::Dynamics
                && (self.file.dynamics_bodies.is_empty() || self.file.table_geom.is_none())
            {
                return Err("axis dynamics needs the `dynamics_bodies` it changes and the `table_geom` they rest on; leave the axis out for a task without movable objects".into());
            }
            for (i, l) in a.levels.iter().enumerate() {
                let ok = match a.axis {
                    Axis::StartShift => l.widen.is_some_and(|w| w > 0.0),
                    Axis::ObsNoise => {
                        l.position_m.is_some_and(|v| v >= 0.0)
                            && l.angle_rad.is_some_and(|v| v >= 0.0)
                    }
                    Axis::Latency => {
                        let f = l.fraction.unwrap_or(0.0);
                        (0.0..1.0).contains(&f) && l.steps.unwrap_or(0) as f64 + f > 0.0
                    }
                    Axis::Dynamics => {
                        l.mass.is_some_and(|m| m > 0.0) && l.friction.is_some_and(|f| f > 0.0)
                    }
                    Axis::Camera => l.camera_shift_m.is_some() && l.camera_turn_deg.is_some(),
                    Axis::Lighting => {
                        l.light_scale.is_some_and(|s| s > 0.0) && l.light_tilt_deg.is_some()
                    }
                };
                if !ok {
                    return Err(format!(
                        "level {} of axis {} does not give what the axis needs (start_shift: widen > 0; obs_noise: position_m and angle_rad ≥ 0; latency: steps + fraction > 0 with 0 ≤ fraction < 1; dynamics: mass and friction > 0; camera: camera_shift_m and camera_turn_deg; lighting: light_scale > 0 and light_tilt_deg)",
                        i + 1,
                        a.axis
                    ));
                }
            }
        }
        Ok(())
    }

    /// Every perturbed level of the suite, axis by axis in the file's order.
    pub fn perturbations(&self) -> Vec<Perturbation> {
        self.file
            .axes
            .iter()
            .flat_map(|a| {
                a.levels.iter().enumerate().map(|(i, l)| Perturbation {
                    suite: self.name.clone(),
                    suite_sha256: self.sha256.clone(),
                    axis: a.axis,
                    level: i + 1,
                    setting: l.clone(),
                })
            })
            .collect()
    }
}

/// A perturbation ready to act: what the engine and a replay need.
#[derive(Debug, Clone)]
pub struct Active {
    pub perturbation: Perturbation,
    pub suite: Suite,
    /// Env steps by which actions are late (0: none).
    pub latency: usize,
    /// A further fraction of a step (0: none): the environment gets the
    /// blend `(1 − f)·a(t − latency) + f·a(t − latency − 1)` of the task's
    /// command convention (`CommandKind::blend_late`).
    pub late_fraction: f32,
    /// What the environment receives while the first actions are in flight.
    pub hold: Vec<f32>,
    /// The task's command convention, which says how two late actions blend.
    pub command: CommandKind,
    pub noise: Option<ObsNoise>,
}

impl Active {
    /// `perturbation` (as a manifest records it) against its suite: the
    /// suite must be this build's file with that sha256.
    pub fn new(perturbation: &Perturbation, task: TaskId) -> Result<Active, PerturbError> {
        let suite = Suite::named(task, &perturbation.suite)?;
        if suite.sha256 != perturbation.suite_sha256 {
            return Err(PerturbError::Suite {
                name: suite.name,
                message: format!(
                    "the result was made with the suite of sha256 {}, this build's has sha256 {}",
                    perturbation.suite_sha256, suite.sha256
                ),
            });
        }
        let def = crate::tasks::task_def(task)?;
        let s = &perturbation.setting;
        let noise = (perturbation.axis == Axis::ObsNoise).then(|| ObsNoise {
            units: suite.file.obs_units.clone(),
            position_m: s.position_m.unwrap_or(0.0),
            angle_rad: s.angle_rad.unwrap_or(0.0),
            offset: def.cmd_dim(),
        });
        Ok(Active {
            latency: match perturbation.axis {
                Axis::Latency => s.steps.unwrap_or(0),
                _ => 0,
            },
            late_fraction: match perturbation.axis {
                Axis::Latency => s.fraction.unwrap_or(0.0) as f32,
                _ => 0.0,
            },
            hold: def.command_kind().hold(),
            command: def.command_kind(),
            noise,
            perturbation: perturbation.clone(),
            suite,
        })
    }

    /// The task as this perturbation simulates it: `task` itself, or for
    /// `dynamics` a fresh compile of its scene with the changed masses and
    /// friction (the scene file, hence `mjcf_sha256`, is the same).
    pub fn task(&self, task: &LoadedTask) -> Result<LoadedTask, PerturbError> {
        if task.obs_type != self.suite.file.obs_type {
            return Err(PerturbError::Suite {
                name: self.suite.name.clone(),
                message: format!(
                    "this suite is for {} policies, the evaluation's policy observes {}",
                    self.suite.file.obs_type.as_str(),
                    task.obs_type.as_str()
                ),
            });
        }
        let axis = self.perturbation.axis;
        if !matches!(axis, Axis::Dynamics | Axis::Camera | Axis::Lighting) {
            return Ok(task.clone());
        }
        let mut fresh = LoadedTask::load_look(task.def.id(), task.obs_type, task.look)?;
        let model = std::sync::Arc::get_mut(&mut fresh.model)
            .expect("a freshly compiled model has no other user");
        let s = &self.perturbation.setting;
        if axis != Axis::Dynamics {
            crate::perturb_view::apply(model, &self.suite.file.cameras, s)
                .map_err(TaskError::from)?;
            return Ok(fresh);
        }
        let (mass, friction) = (s.mass.unwrap_or(1.0), s.friction.unwrap_or(1.0));
        let file = &self.suite.file;
        let mut bodies = vec![];
        for b in &file.dynamics_bodies {
            bodies.push(model.id(ObjKind::Body, b).map_err(TaskError::from)?);
        }
        let table_geom = file.table_geom.as_deref().unwrap_or_default();
        let table = model
            .id(ObjKind::Geom, table_geom)
            .map_err(TaskError::from)?;
        let (mut frictions, mut priorities) = (vec![], vec![]);
        if friction != 1.0 {
            let (prio, fric) = (model.geom_priority(), model.geom_friction());
            let (pt, ft) = (prio[table], fric[3 * table]);
            for (g, &b) in model.geom_bodyid().iter().enumerate() {
                if !bodies.contains(&(b as usize)) {
                    continue;
                }
                let (pg, fg) = (prio[g], fric[3 * g]);
                // The friction the box–table contact has now.
                let mixed = match pg.cmp(&pt) {
                    std::cmp::Ordering::Greater => fg,
                    std::cmp::Ordering::Equal => fg.max(ft),
                    std::cmp::Ordering::Less => ft,
                };
                frictions.push((g, mixed * friction));
                priorities.push((g, pg.max(pt + 1)));
            }
        }
        model
            .perturb_dynamics(&bodies, mass, &frictions, &priorities)
            .map_err(TaskError::from)?;
        Ok(fresh)
    }

    /// The initial state as this perturbation starts it.
    pub fn context(&self, context: &Value) -> Value {
        match (self.perturbation.axis, self.perturbation.setting.widen) {
            (Axis::StartShift, Some(w)) => shift_context(&self.suite.file, w, context),
            _ => context.clone(),
        }
    }
}

/// `start_shift`: every listed coordinate pushed away from its range's
/// centre by `widen` (see the module's documentation).
pub fn shift_context(file: &SuiteFile, widen: f64, context: &Value) -> Value {
    let mut out = context.clone();
    if widen == 0.0 {
        // `c + (x − c)` need not be `x` to the last bit.
        return out;
    }
    let push = |v: &mut Value, range: [f64; 2]| {
        let c = 0.5 * (range[0] + range[1]);
        if let Some(x) = v.as_f64() {
            *v = Value::from(c + (x - c) * (1.0 + widen));
        }
    };
    for f in &file.start_shift_fields {
        if let Some(v) = out.get_mut(&f.field).and_then(|a| a.get_mut(f.index)) {
            push(v, f.range);
        }
    }
    if let Some(r) = &file.start_shift_regions {
        let poses = out.get_mut(&r.array).and_then(Value::as_array_mut);
        for pose in poses.into_iter().flatten() {
            let Some(xy) = pose.get_mut(&r.pose).and_then(Value::as_array_mut) else {
                continue;
            };
            let (Some(x), Some(y)) = (
                xy.first().and_then(Value::as_f64),
                xy.get(1).and_then(Value::as_f64),
            ) else {
                continue;
            };
            // A pose in no region (not from the task's distribution) stays.
            if let Some(&[rx, ry]) = r.containing(x, y) {
                push(&mut xy[0], rx);
                push(&mut xy[1], ry);
            }
        }
    }
    out
}

/// `obs_noise` of one level.
#[derive(Debug, Clone)]
pub struct ObsNoise {
    pub units: Vec<ObsUnit>,
    pub position_m: f64,
    pub angle_rad: f64,
    /// Entries of the policy observation before the environment's (the
    /// previous command), left exact.
    pub offset: usize,
}

impl ObsNoise {
    /// Adds the noise of (seed, rollout, step) to a policy observation. A
    /// zero deviation leaves its entries untouched to the bit (`tan(atan(v))`
    /// need not be `v`).
    pub fn apply(&self, seed: u64, rollout: u64, step: u64, obs: &mut [f32]) {
        let mut key = [0u8; 32];
        key[0..8].copy_from_slice(&seed.to_le_bytes());
        key[8..16].copy_from_slice(&rollout.to_le_bytes());
        key[16..24].copy_from_slice(&step.to_le_bytes());
        key[24..32].copy_from_slice(b"d3ilobsn");
        let mut rng = ChaCha8Rng::from_seed(key);
        let mut i = self.offset;
        for &u in &self.units {
            match u {
                ObsUnit::Position if self.position_m > 0.0 => {
                    obs[i] = (obs[i] as f64 + self.position_m * normal(&mut rng)) as f32;
                }
                ObsUnit::TanYaw if self.angle_rad > 0.0 => {
                    let yaw = (obs[i] as f64).atan() + self.angle_rad * normal(&mut rng);
                    obs[i] = yaw.tan() as f32;
                }
                ObsUnit::QuatYaw if self.angle_rad > 0.0 => {
                    let e = self.angle_rad * normal(&mut rng);
                    let (a, d) = ((0.5 * e).cos(), (0.5 * e).sin());
                    let q: Vec<f64> = obs[i..i + 4].iter().map(|&v| v as f64).collect();
                    // (a, 0, 0, d) ⊗ q: a turn about the world's vertical.
                    let r = [
                        a * q[0] - d * q[3],
                        a * q[1] - d * q[2],
                        a * q[2] + d * q[1],
                        a * q[3] + d * q[0],
                    ];
                    for (o, v) in obs[i..i + 4].iter_mut().zip(r) {
                        *o = v as f32;
                    }
                }
                _ => {}
            }
            i += u.width();
        }
    }
}

/// A standard normal draw (Box–Muller, one per call).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.gen::<f64>();
    let u2: f64 = rng.gen::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests;
