//! Replaying policy-level actions open-loop from an initial state: what
//! `d3il replay --task T --input ep.json` prints, and what the fidelity
//! report compares with the episodes recorded in the original.

use crate::tasks::{Env, LoadedTask, TaskError};
use serde_json::Value;
use std::collections::BTreeMap;

/// Everything an open-loop replay recorded: one row per state (after reset,
/// then after every step), so `steps + 1` rows.
#[derive(Debug, Clone)]
pub struct OpenLoopRun {
    pub observations: Vec<Vec<f32>>,
    pub tcp: Vec<[f64; 3]>,
    pub joints: Vec<[f64; 7]>,
    pub fingers: Vec<[f64; 2]>,
    /// Positions of the task's objects ([`Env::objects`]).
    pub objects: BTreeMap<String, Vec<[f64; 3]>>,
    pub success: bool,
    pub behaviour: Value,
    pub steps: usize,
    pub done: bool,
}

/// How to replay.
#[derive(Debug, Clone, Copy, Default)]
pub struct OpenLoopOptions {
    /// Change `qpos[0]` by one ulp (towards +∞) right after reset: the
    /// first free object's x where the task has free objects (they come
    /// first in qpos), else the first arm joint. A perturbation as small as
    /// a state can have, to measure how fast two runs drift apart.
    pub nudge_one_ulp: bool,
}

/// A replay that stopped: `index` is the action it stopped at (None: at reset).
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", .index.map(|i| format!("actions[{i}]")).unwrap_or_else(|| "context".into()))]
pub struct OpenLoopError {
    pub index: Option<usize>,
    #[source]
    pub source: TaskError,
}

/// Replays `actions` (policy-level, the task's action width) from
/// `context` until the episode ends or the actions run out.
pub fn replay_actions(
    task: &LoadedTask,
    context: &Value,
    actions: &[Vec<f32>],
    opts: OpenLoopOptions,
) -> Result<OpenLoopRun, OpenLoopError> {
    let at = |index| move |source| OpenLoopError { index, source };
    let mut env = task.env().map_err(at(None))?;
    let first = env.reset(context).map_err(at(None))?;
    if opts.nudge_one_ulp {
        let q = &mut env.sim.data.qpos_mut()[0];
        *q = q.next_up();
    }
    let mut run = OpenLoopRun {
        observations: vec![first],
        tcp: vec![],
        joints: vec![],
        fingers: vec![],
        objects: BTreeMap::new(),
        success: false,
        behaviour: Value::Null,
        steps: 0,
        done: false,
    };
    record(&env, &mut run);
    for (i, a) in actions.iter().enumerate() {
        let out = env.step(a).map_err(at(Some(i)))?;
        run.observations.push(out.obs);
        record(&env, &mut run);
        if out.done {
            break;
        }
    }
    run.success = env.success();
    run.behaviour = env.behaviour();
    run.steps = env.steps();
    run.done = env.is_done();
    Ok(run)
}

fn record(env: &Env, run: &mut OpenLoopRun) {
    run.tcp.push(env.sim.tcp_pos());
    run.joints.push(env.sim.joint_pos());
    run.fingers.push(env.sim.finger_pos());
    for (name, p) in env.objects() {
        run.objects.entry(name).or_default().push(p);
    }
}
