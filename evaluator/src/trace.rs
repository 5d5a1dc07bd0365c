//! Rollout traces: recorded by the engine while a rollout runs, replayed here
//! bit for bit (DESIGN.md: a rollout is reproducible from its initial state
//! and the actions the environment received). The replay needs no policy:
//! ONNX, remote and scripted rollouts, state and image, replay alike.

use crate::tasks::landmarks::rollout_landmarks;
use crate::tasks::{Env, LoadedTask, TaskError};
use d3il_protocol::rollout::{RolloutTrace, TraceBuilder};
use d3il_protocol::{Ending, ObsType, ProtocolManifest, RolloutRecord, TaskId};
use serde::Serialize;
use serde_json::Value;

/// Starts the trace of a rollout whose env was just reset.
pub fn begin(task: &LoadedTask, env: &Env) -> TraceBuilder {
    let objects = env.objects();
    let landmarks = rollout_landmarks(&task.landmarks, &objects);
    TraceBuilder::start(
        task.def.act_dim(),
        env.sim.tcp_pos(),
        moving(objects),
        landmarks,
    )
}

/// The objects that move: targets are landmarks, not paths.
fn moving(objects: Vec<(String, [f64; 3])>) -> Vec<(String, [f64; 3])> {
    objects
        .into_iter()
        .filter(|(n, _)| !n.starts_with("target"))
        .collect()
}

/// Records one step: the action the env received and the state after it.
pub fn record_step(trace: &mut TraceBuilder, env: &Env, action: &[f32]) {
    trace.push_step(
        action,
        env.state_digest(),
        env.sim.tcp_pos(),
        &moving(env.objects()),
    );
}

/// Packs the trace of a rollout that ended.
pub fn finish(trace: TraceBuilder, env: &Env) -> RolloutTrace {
    trace.finish(env.objects())
}

/// Why a record could not be replayed at all (a record that replays
/// differently is not an error: see [`ReplayCheck::differences`]).
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("the record cannot be replayed: {0}")]
    BadRecord(String),
    #[error(transparent)]
    Task(#[from] TaskError),
    #[error("rendering: {0}")]
    Render(#[from] crate::mujoco::MjError),
    #[error("{0}")]
    Output(String),
    #[error(transparent)]
    Perturbation(#[from] crate::perturb::PerturbError),
}

/// What replaying one record gave, and where it differs from the record.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayCheck {
    pub task: TaskId,
    pub number: usize,
    pub context_index: usize,
    pub rollout_index: usize,
    pub steps: usize,
    pub success: bool,
    pub behaviour: Value,
    pub ending: Ending,
    pub final_objects: Vec<(String, [f64; 3])>,
    /// The first step after which the physics state differs from the
    /// recorded one (1-based: the state after that many actions).
    pub first_differing_step: Option<usize>,
    /// Everything that differs, in words; empty when the record replays bit for bit.
    pub differences: Vec<String>,
}

impl ReplayCheck {
    pub fn replays(&self) -> bool {
        self.differences.is_empty()
    }
}

/// Loads the task as the record's evaluation did (observation type and robot
/// look: physics is the same in every look, the video draws it as the
/// evaluation's cameras did).
/// A result of the robustness track gets its perturbation's task (the
/// dynamics axis changes the model), its suite checked against the sha256
/// the manifest records.
pub fn load_task(manifest: &ProtocolManifest) -> Result<LoadedTask, ReplayError> {
    let task = match (manifest.obs_type, manifest.robot_look) {
        (ObsType::Image, Some(look)) => LoadedTask::load_look(manifest.task, ObsType::Image, look)?,
        (obs, _) => LoadedTask::load_obs(manifest.task, obs)?,
    };
    Ok(match &manifest.perturbation {
        Some(p) => crate::perturb::Active::new(p, manifest.task)?.task(&task)?,
        None => task,
    })
}

/// Replays `record` (with its `trace`) in `task`, calling `on_state` with the
/// env after the reset and after every step (videos render there), and
/// compares every step's state digest, the step count, success, behaviour,
/// ending and the final object poses with the record.
pub fn replay(
    task: &LoadedTask,
    manifest: &ProtocolManifest,
    record: &RolloutRecord,
    trace: &RolloutTrace,
    on_state: &mut dyn FnMut(&mut Env) -> Result<(), ReplayError>,
) -> Result<ReplayCheck, ReplayError> {
    let bad = |m: String| ReplayError::BadRecord(m);
    if manifest.task != task.def.id() {
        return Err(bad(format!(
            "the record is of task {} but {} was loaded",
            manifest.task,
            task.def.id()
        )));
    }
    let set = task.def.context_set()?;
    if set.sha256 != manifest.initial_states_sha256 {
        return Err(bad(format!(
            "it was made on the initial-state set with sha256 {} ({}), which this build does not have (it has {} with sha256 {})",
            manifest.initial_states_sha256,
            manifest.initial_states_name(),
            set.name,
            set.sha256
        )));
    }
    let context = set.get(record.context_index).ok_or_else(|| {
        bad(format!(
            "initial state {} is not in {} ({} states)",
            record.context_index,
            set.name,
            set.len()
        ))
    })?;
    // A shifted start (robustness track) is recomputed from the suite.
    let shifted;
    let context = match &manifest.perturbation {
        Some(p) => {
            shifted = crate::perturb::Active::new(p, manifest.task)?.context(context);
            &shifted
        }
        None => context,
    };
    let t = trace.unpack().map_err(|e| bad(e.to_string()))?;
    if t.act_dim != task.def.act_dim() {
        return Err(bad(format!(
            "its actions have {} values per step but {} takes {}",
            t.act_dim,
            task.def.id(),
            task.def.act_dim()
        )));
    }
    let mut differences = Vec::new();
    if manifest.mjcf_sha256 != task.mjcf_sha256 {
        differences.push(format!(
            "it was made by another build: its scene's MJCF sha256 is {}, this build's is {}",
            manifest.mjcf_sha256, task.mjcf_sha256
        ));
    }
    let image = task.obs_type == ObsType::Image;
    let mut env = task.env()?;
    env.reset(context)?;
    on_state(&mut env)?;
    let mut first_diff = None;
    let mut unstable = None;
    let n = t.actions.len();
    for (i, action) in t.actions.iter().enumerate() {
        if image {
            // The policy's frames are not needed: the actions are recorded.
            env.skip_next_frame();
        }
        match env.step(action) {
            Ok(_) => {}
            Err(TaskError::SimulationWarning { step, warnings }) => {
                unstable = Some((step, warnings));
            }
            Err(e) => {
                differences.push(format!(
                    "step {}: the recorded action is refused: {e}",
                    i + 1
                ));
                first_diff.get_or_insert(i + 1);
                break;
            }
        }
        if t.digests.get(i) != Some(&env.state_digest()) {
            first_diff.get_or_insert(i + 1);
        }
        if unstable.is_some() {
            break;
        }
        on_state(&mut env)?;
        if env.is_done() && i + 1 < n {
            differences.push(format!(
                "the episode ended after {} steps but the record holds {n} actions",
                i + 1
            ));
            break;
        }
    }
    if let Some(step) = first_diff {
        differences.insert(
            0,
            format!("the physics state first differs from the record's after step {step}"),
        );
    }
    if t.digests.len() != n {
        differences.push(format!(
            "the record holds {n} actions but {} state digests",
            t.digests.len()
        ));
    }
    let steps = env.steps();
    let success = unstable.is_none() && env.success();
    let behaviour = if unstable.is_some() {
        Value::Null
    } else {
        env.behaviour()
    };
    let max_steps = task.spec().max_steps;
    let ending = Ending::classify(unstable.is_some(), env.is_done(), success, steps, max_steps);
    let final_objects = env.objects();
    let mut differ = |what: &str, recorded: String, replayed: String| {
        if recorded != replayed {
            differences.push(format!(
                "{what}: the record says {recorded}, the replay gives {replayed}"
            ));
        }
    };
    differ("steps", record.steps.to_string(), steps.to_string());
    differ("success", record.success.to_string(), success.to_string());
    differ(
        "behaviour",
        record.behaviour.to_string(),
        behaviour.to_string(),
    );
    if let Some(e) = record.ending {
        differ("ending", e.to_string(), ending.to_string());
    }
    if let (Some(f), Some((step, _))) = (&record.failure, &unstable) {
        differ("unstable at step", f.step.to_string(), step.to_string());
    }
    let bits = |v: &[(String, [f64; 3])]| -> String {
        v.iter()
            .map(|(n, p)| format!("{n} {:?}", p.map(f64::to_bits)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if bits(&trace.final_objects) != bits(&final_objects) {
        differences.push(format!(
            "final object poses: the record says {:?}, the replay gives {:?}",
            trace.final_objects, final_objects
        ));
    }
    Ok(ReplayCheck {
        task: task.def.id(),
        number: record.number(manifest.rollouts_per_context),
        context_index: record.context_index,
        rollout_index: record.rollout_index,
        steps,
        success,
        behaviour,
        ending,
        final_objects,
        first_differing_step: first_diff,
        differences,
    })
}
