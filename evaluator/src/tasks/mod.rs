//! The D3IL tasks on top of the simulation core. A task is a static
//! definition ([`TaskDef`]: scene, constants, contexts, command convention)
//! plus per-episode logic ([`TaskLogic`]: observation, termination, success,
//! behaviour). [`Env`] runs the generic step of docs/original-d3il.md §01.4.2 / docs/original-d3il.md §10.1.5
//! for any task.

pub mod aligning;
pub mod avoiding;
pub mod command;
pub mod contexts;
pub mod geometry;
pub mod inserting;
pub mod landmarks;
pub mod pushing;
pub mod sorting;
pub mod stacking;

use crate::mujoco::{Data, MjError, Model, ObjKind};
use crate::robot::control::FingerCommand;
use crate::sim::scene::{best_look, meshes_available, RobotLook, SceneSpec};
use crate::sim::{RobotIds, Sim};
use d3il_protocol::{ObsType, TaskId, TaskSpec};
use serde_json::Value;
use std::sync::Arc;

pub use command::CommandKind;
pub use contexts::ContextSet;

/// Errors from task set-up and stepping.
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    #[error(transparent)]
    MuJoCo(#[from] MjError),
    #[error("invalid context for task {task}: {message}")]
    Context { task: TaskId, message: String },
    #[error("action has {got} values but task {task} expects {expected} ({meaning})")]
    ActionWidth {
        task: TaskId,
        got: usize,
        expected: usize,
        meaning: &'static str,
    },
    #[error("action value {index} is {value} at step {step}; actions must be finite numbers")]
    NonFinite {
        index: usize,
        value: f32,
        step: usize,
    },
    #[error("initial-state set `{name}`: {message}")]
    ContextSet { name: String, message: String },
    #[error("the episode is over (done was returned); reset before stepping again")]
    EpisodeOver,
    #[error("the simulation raised MuJoCo warnings at step {step} ({warnings}); the result would not be trustworthy, so the rollout is stopped")]
    SimulationWarning { step: usize, warnings: String },
    #[error("task {0} is not available in this build")]
    Unavailable(TaskId),
    #[error("this build has no Panda meshes: ./dev installs the example-robot-data and pymeshlab packages and converts them (scripts/panda_meshes.py) before building")]
    NoMeshes,
    #[error("task {0} has no image-observation variant (image tasks: aligning, sorting-4, sorting-6, stacking)")]
    NoImageVariant(TaskId),
}

/// What the arm controller gets for one env step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Absolute Cartesian target (position, quaternion wxyz) for the IK tracker.
    Cartesian { pos: [f64; 3], quat: [f64; 4] },
    /// Absolute joint targets (float32-rounded) and the gripper value (Stacking).
    Joint { q: [f64; 7], gripper: f64 },
}

/// The hand points straight down in every Cartesian task (docs/original-d3il.md §01.3.1).
pub const QUAT_DOWN: [f64; 4] = [0.0, 1.0, 0.0, 0.0];

/// Static definition of a task.
pub trait TaskDef: Send + Sync {
    fn id(&self) -> TaskId;
    /// Version of our implementation of the task (scene + logic + contexts).
    fn version(&self) -> &'static str;
    fn scene(&self) -> SceneSpec;
    /// Physics steps per environment step ([`TaskId::substeps`], the one
    /// statement of them).
    fn n_substeps(&self) -> usize {
        self.id().substeps()
    }
    fn init_qpos(&self) -> [f64; 7];
    /// Episode limit of the state variant (`TaskId::paper_protocol`, the one
    /// statement of the protocol's constants).
    fn max_steps(&self) -> usize {
        self.id().paper_protocol().max_steps
    }
    /// Width of the environment observation.
    fn env_obs_dim(&self) -> usize;
    /// How an action becomes a controller command (one of the shared
    /// conventions in [`command`]).
    fn command_kind(&self) -> CommandKind;
    /// Width of the "previous command" prefix of the policy input.
    fn cmd_dim(&self) -> usize {
        self.command_kind().dim()
    }
    /// Width of one policy action.
    fn act_dim(&self) -> usize {
        self.command_kind().dim()
    }
    /// What the action means, for error messages.
    fn act_meaning(&self) -> &'static str {
        self.command_kind().meaning()
    }
    /// The fixed test set (file bytes and its expected sha256).
    fn context_set(&self) -> Result<ContextSet, TaskError>;
    /// Every committed set of the task, the one in use first; older sets stay
    /// loadable so that stored results keep meaning what they meant.
    fn context_sets(&self) -> Result<Vec<ContextSet>, TaskError> {
        Ok(vec![self.context_set()?])
    }
    /// Rollouts per initial state in the paper's protocol.
    fn rollouts_per_context(&self) -> usize {
        self.id().paper_protocol().rollouts
    }
    /// Initial states the paper's protocol uses out of a set of `set_len`
    /// (e.g. Pushing uses the first 30 of the 60 stored, docs/original-d3il.md §10.1.10).
    fn n_contexts_paper(&self, set_len: usize) -> usize {
        set_len.min(self.id().paper_protocol().contexts)
    }
    /// Draws one context from the task's distribution.
    fn sample_context(&self, rng: &mut dyn rand::RngCore) -> Value;
    /// Fresh per-episode logic bound to a compiled model.
    fn new_logic(&self, model: &Model) -> Result<Box<dyn TaskLogic>, TaskError>;
    /// The first "previous command" after reset (e.g. the measured TCP xy).
    fn initial_command(&self, sim: &Sim) -> Vec<f64> {
        self.command_kind().initial(sim)
    }
    /// Previous command + policy action -> (new previous command, controller command).
    fn command(&self, prev: &[f64], action: &[f32], fixed_z: f64) -> (Vec<f64>, Command) {
        self.command_kind().apply(prev, action, fixed_z)
    }

    /// Episode limit of the image variant (the reference's vision configs).
    fn max_steps_image(&self) -> usize {
        self.id()
            .paper_protocol()
            .max_steps_image
            .unwrap_or_else(|| self.max_steps())
    }

    fn spec(&self) -> TaskSpec {
        TaskSpec {
            task: self.id(),
            obs_dim: self.cmd_dim() + self.env_obs_dim(),
            act_dim: self.act_dim(),
            max_steps: self.max_steps(),
            n_behaviours: self.id().n_behaviours(),
        }
    }

    /// The policy interface for an observation type. Image variants get the
    /// previous command as their low-dimensional `obs` (docs/original-d3il.md §11.1.3, §11.2.3:
    /// desired TCP xy for Sorting, desired joints + gripper for Stacking; the
    /// desired TCP xyz for Aligning by the same convention) plus the images.
    fn spec_for(&self, obs: ObsType) -> TaskSpec {
        match obs {
            ObsType::State => self.spec(),
            ObsType::Image => TaskSpec {
                obs_dim: self.cmd_dim(),
                max_steps: self.max_steps_image(),
                ..self.spec()
            },
        }
    }
}

/// Per-episode task logic.
pub trait TaskLogic: Send {
    /// Places the context's objects (free-joint qpos or model poses, no forward)
    /// and runs the reset sequence through `sim.reset`.
    fn reset(
        &mut self,
        sim: &mut Sim,
        init_qpos: &[f64; 7],
        context: &Value,
    ) -> Result<(), TaskError>;
    /// Environment observation from the current (pre-physics) state, float32.
    fn observe(&self, sim: &Sim) -> Vec<f32>;
    /// Termination test before the physics; returns true when the episode ends
    /// with this step (the step's physics still run).
    fn pre_physics_done(&mut self, sim: &Sim) -> bool;
    /// Bookkeeping after the physics of a step (modes, success).
    fn post_physics(&mut self, sim: &Sim);
    fn success(&self) -> bool;
    /// Behaviour in the reference's encoding (vector, integer or string).
    fn behaviour(&self) -> Value;
    /// Behaviour label for the metrics, None for failures and unlabeled successes.
    fn behaviour_key(&self) -> Option<String>;
    /// Positions of the task's objects, for replay output and plots.
    fn objects(&self, sim: &Sim) -> Vec<(String, [f64; 3])>;
    /// Stacking only: Stacking-1/2/3 (≥ 1 / ≥ 2 boxes registered, full stack), docs/original-d3il.md §11.2.5.
    fn stacking_levels(&self) -> Option<[bool; 3]> {
        None
    }
}

/// A compiled task, shared read-only by all rollouts of an evaluation.
#[derive(Clone)]
pub struct LoadedTask {
    pub def: Arc<dyn TaskDef>,
    pub model: Arc<Model>,
    pub ids: Arc<RobotIds>,
    pub mjcf_sha256: String,
    /// State or image observations (image: rollouts render both cameras).
    pub obs_type: ObsType,
    /// How the robot is drawn ([`SceneSpec::drawn_look`]).
    pub look: RobotLook,
    /// The scene's table, targets and obstacles seen from above.
    pub landmarks: Arc<Vec<d3il_protocol::Landmark>>,
}

impl LoadedTask {
    pub fn load(id: TaskId) -> Result<LoadedTask, TaskError> {
        Self::load_obs(id, ObsType::State)
    }

    /// Loads the task for policies with observation type `obs`.
    /// Image variants get the Panda meshes when this build
    /// has them ([`best_look`]); state variants keep primitives (the
    /// look changes no physics, see [`RobotLook`]).
    pub fn load_obs(id: TaskId, obs: ObsType) -> Result<LoadedTask, TaskError> {
        let look = match obs {
            ObsType::Image => best_look(),
            ObsType::State => RobotLook::Primitives,
        };
        Self::load_look(id, obs, look)
    }

    /// [`LoadedTask::load_obs`] with an explicit robot look.
    pub fn load_look(id: TaskId, obs: ObsType, look: RobotLook) -> Result<LoadedTask, TaskError> {
        if obs == ObsType::Image && !id.has_image_variant() {
            return Err(TaskError::NoImageVariant(id));
        }
        if look == RobotLook::Meshes && !meshes_available() {
            return Err(TaskError::NoMeshes);
        }
        let def = task_def(id)?;
        let mut scene = def.scene();
        scene.look = look;
        Self::from_scene(def, scene, obs)
    }

    /// The task `def` in `scene`: its own ([`TaskDef::scene`]) with another
    /// look or other meshes (a test draws the full meshes this way).
    pub fn from_scene(
        def: Arc<dyn TaskDef>,
        scene: SceneSpec,
        obs: ObsType,
    ) -> Result<LoadedTask, TaskError> {
        let model = Arc::new(scene.compile()?);
        let ids = Arc::new(RobotIds::lookup(&model)?);
        Ok(LoadedTask {
            landmarks: Arc::new(landmarks::scene_landmarks(&scene)),
            obs_type: obs,
            look: scene.drawn_look(),
            mjcf_sha256: scene.sha256(),
            def,
            model,
            ids,
        })
    }

    pub fn env(&self) -> Result<Env, TaskError> {
        Env::new(self)
    }

    /// The policy interface of this task and observation type.
    pub fn spec(&self) -> TaskSpec {
        self.def.spec_for(self.obs_type)
    }
}

/// All tasks implemented in this build.
pub fn task_def(id: TaskId) -> Result<Arc<dyn TaskDef>, TaskError> {
    match id {
        TaskId::Avoiding => Ok(Arc::new(avoiding::Avoiding)),
        TaskId::Aligning => Ok(Arc::new(aligning::Aligning)),
        TaskId::Pushing => Ok(Arc::new(pushing::Pushing)),
        TaskId::Sorting2 => Ok(Arc::new(sorting::Sorting::new(2))),
        TaskId::Sorting4 => Ok(Arc::new(sorting::Sorting::new(4))),
        TaskId::Sorting6 => Ok(Arc::new(sorting::Sorting::new(6))),
        TaskId::Stacking => Ok(Arc::new(stacking::Stacking)),
        TaskId::Inserting => Ok(Arc::new(inserting::Inserting)),
    }
}

/// Result of one env step.
#[derive(Debug, Clone)]
pub struct StepOutcome {
    /// The observation `step` returns: the state at which the action was issued (docs/original-d3il.md §01.4.2).
    pub obs: Vec<f32>,
    pub done: bool,
}

/// One rollout: a simulation plus the task logic and the evaluation loop's
/// bookkeeping (previous command, fixed z, step counter).
pub struct Env {
    pub sim: Sim,
    def: Arc<dyn TaskDef>,
    logic: Box<dyn TaskLogic>,
    step_counter: usize,
    finished: bool,
    prev_cmd: Vec<f64>,
    fixed_z: f64,
    last_obs: Vec<f32>,
    max_steps: usize,
    /// Image variants: the two policy cameras and the last image observation.
    cameras: Option<[usize; 2]>,
    last_images: Vec<f32>,
    /// Seconds this env spent rendering its cameras in `step` (benchmarks
    /// compare it with the step's physics; reset renders are not counted).
    render_seconds: f64,
    /// Image observations rendered in `step` (both cameras each).
    rendered: usize,
    /// Set by [`Env::skip_next_frame`] for the next `step` only.
    skip_next_frame: bool,
}

impl Env {
    pub fn new(task: &LoadedTask) -> Result<Env, TaskError> {
        let sim = Sim::new(task.model.clone(), task.ids.clone(), task.def.n_substeps())?;
        let cameras = match task.obs_type {
            ObsType::State => None,
            ObsType::Image => Some(crate::camera::camera_ids(&task.model)?),
        };
        Ok(Env {
            max_steps: task.spec().max_steps,
            cameras,
            last_images: Vec::new(),
            render_seconds: 0.0,
            rendered: 0,
            skip_next_frame: false,
            sim,
            logic: task.def.new_logic(&task.model)?,
            def: task.def.clone(),
            step_counter: 0,
            finished: false,
            prev_cmd: Vec::new(),
            fixed_z: f64::NAN,
            last_obs: Vec::new(),
        })
    }

    /// Reset to `context` (docs/original-d3il.md §01.4.4) and return the first observation.
    pub fn reset(&mut self, context: &Value) -> Result<Vec<f32>, TaskError> {
        self.logic = self.def.new_logic(self.sim.data.model())?;
        self.logic
            .reset(&mut self.sim, &self.def.init_qpos(), context)?;
        self.step_counter = 0;
        self.finished = false;
        // docs/original-d3il.md §10.1.7: d <- measured TCP after reset; z is frozen at its value.
        self.fixed_z = self.sim.tcp_pos()[2];
        self.prev_cmd = self.def.initial_command(&self.sim);
        self.last_obs = self.logic.observe(&self.sim);
        if let Some(cams) = self.cameras {
            self.last_images.clear();
            crate::camera::capture(&mut self.sim.data, &cams, &mut self.last_images)?;
        }
        Ok(self.last_obs.clone())
    }

    /// Total seconds spent rendering the policy cameras in `step` since this
    /// env was made.
    pub fn render_seconds(&self) -> f64 {
        self.render_seconds
    }

    /// Image observations rendered in `step` since this env was made.
    pub fn frames_rendered(&self) -> usize {
        self.rendered
    }

    /// The next `step` does not render its image observation: the caller
    /// knows the policy will never see it (it leaves the observation window
    /// before the next query). That step's [`Env::policy_images`] are zeros.
    /// Applies to the next step only.
    pub fn skip_next_frame(&mut self) {
        self.skip_next_frame = true;
    }

    /// The policy input: concat(previous command, last observation), float32.
    /// Image variants get the previous command only (their `obs`), the rest
    /// is in [`Env::policy_images`].
    pub fn policy_obs(&self) -> Vec<f32> {
        let mut v: Vec<f32> = self.prev_cmd.iter().map(|&x| x as f32).collect();
        if self.cameras.is_none() {
            v.extend_from_slice(&self.last_obs);
        }
        v
    }

    /// Image variants: the last image observation, `[2, 3, 96, 96]` (BGR,
    /// [0, 1]), rendered at the same moment as the state observation.
    pub fn policy_images(&self) -> Option<&[f32]> {
        self.cameras.map(|_| self.last_images.as_slice())
    }

    /// The previous command as the controller holds it (float64; the
    /// policy observation starts with it rounded to float32).
    pub fn prev_command(&self) -> &[f64] {
        &self.prev_cmd
    }

    pub fn fixed_z(&self) -> f64 {
        self.fixed_z
    }

    pub fn steps(&self) -> usize {
        self.step_counter
    }

    pub fn is_done(&self) -> bool {
        self.finished
    }

    /// One policy-level step: previous command + action -> command -> env step.
    pub fn step(&mut self, action: &[f32]) -> Result<StepOutcome, TaskError> {
        if self.finished {
            return Err(TaskError::EpisodeOver);
        }
        let expected = self.def.act_dim();
        if action.len() != expected {
            return Err(TaskError::ActionWidth {
                task: self.def.id(),
                got: action.len(),
                expected,
                meaning: self.def.act_meaning(),
            });
        }
        if let Some((index, &value)) = action.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(TaskError::NonFinite {
                index,
                value,
                step: self.step_counter,
            });
        }
        let (new_cmd, command) = self.def.command(&self.prev_cmd, action, self.fixed_z);
        let outcome = self.env_step(command)?;
        self.prev_cmd = new_cmd;
        Ok(outcome)
    }

    /// The generic env step of docs/original-d3il.md §01.4.2 with an absolute command.
    pub fn env_step(&mut self, command: Command) -> Result<StepOutcome, TaskError> {
        match command {
            Command::Cartesian { pos, quat } => {
                self.sim.fingers = FingerCommand::OPEN;
                self.sim.set_cartesian_target(pos, quat);
            }
            Command::Joint { q, gripper } => {
                // docs/original-d3il.md §01.3.6: > 0.075 opens, otherwise close with constant squeeze.
                self.sim.fingers = if gripper > 0.075 {
                    FingerCommand::OPEN
                } else {
                    FingerCommand::CLOSE
                };
                self.sim.arm = crate::sim::ArmController::Joint(q);
            }
        }
        // Observation and done BEFORE the physics (docs/original-d3il.md §01.4.2 step 3).
        let obs = self.logic.observe(&self.sim);
        let mut images = Vec::new();
        if let Some(cams) = self.cameras {
            if std::mem::take(&mut self.skip_next_frame) {
                images.resize(crate::camera::OBS_LEN, 0.0);
            } else {
                let t = std::time::Instant::now();
                crate::camera::capture(&mut self.sim.data, &cams, &mut images)?;
                self.render_seconds += t.elapsed().as_secs_f64();
                self.rendered += 1;
            }
        }
        let early = self.logic.pre_physics_done(&self.sim);
        let done = early || self.step_counter + 1 >= self.max_steps;
        self.sim.step_physics()?;
        self.step_counter += 1;
        // Buffer overflows and instabilities (MuJoCo then resets the state by
        // itself) must never pass silently.
        if self.sim.data.warning_count() > 0 {
            let mut w = crate::mujoco::take_warnings();
            w.dedup();
            return Err(TaskError::SimulationWarning {
                step: self.step_counter,
                warnings: if w.is_empty() {
                    "see MuJoCo's warning counters".into()
                } else {
                    w.join("; ")
                },
            });
        }
        self.logic.post_physics(&self.sim);
        self.finished = done;
        self.last_obs = obs.clone();
        if self.cameras.is_some() {
            self.last_images = images;
        }
        Ok(StepOutcome { obs, done })
    }

    pub fn success(&self) -> bool {
        self.logic.success()
    }
    pub fn behaviour(&self) -> Value {
        self.logic.behaviour()
    }
    pub fn behaviour_key(&self) -> Option<String> {
        self.logic.behaviour_key()
    }
    pub fn objects(&self) -> Vec<(String, [f64; 3])> {
        self.logic.objects(&self.sim)
    }
    /// A digest of the physics state (positions and velocities, bit for
    /// bit): a rollout's trace holds one per step, and a replay compares them.
    pub fn state_digest(&self) -> u32 {
        d3il_protocol::rollout::state_digest([self.sim.data.qpos(), self.sim.data.qvel()])
    }
    pub fn stacking_levels(&self) -> Option<[bool; 3]> {
        self.logic.stacking_levels()
    }
    pub fn task(&self) -> TaskId {
        self.def.id()
    }
    pub fn def(&self) -> &Arc<dyn TaskDef> {
        &self.def
    }
}

/// Position of a free-joint body (its qpos), docs/original-d3il.md §01.5.
pub fn free_body_pos(data: &Data, qpos_adr: usize) -> [f64; 3] {
    let q = &data.qpos()[qpos_adr..qpos_adr + 3];
    [q[0], q[1], q[2]]
}

/// Quaternion (wxyz) of a free-joint body.
pub fn free_body_quat(data: &Data, qpos_adr: usize) -> [f64; 4] {
    let q = &data.qpos()[qpos_adr + 3..qpos_adr + 7];
    [q[0], q[1], q[2], q[3]]
}

/// Geom id of `<name>:geom`.
pub fn geom_id(model: &Model, name: &str) -> Result<usize, TaskError> {
    Ok(model.id(ObjKind::Geom, name)?)
}
