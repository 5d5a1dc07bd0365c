//! Loops every task's tests share: a rollout traced twice must give identical
//! observations, and every initial state of a task's fixed set must reset.

#![allow(dead_code)] // each test file uses a subset

use d3il_evaluator::tasks::{Env, LoadedTask};
use serde_json::Value;

/// Reset a fresh environment of `task` to `context` and step it with `act`
/// (given the environment, returns the action) until `done` or `max_steps`
/// steps; returns the reset observation followed by every step's.
pub fn trace(
    task: &LoadedTask,
    context: &Value,
    max_steps: usize,
    act: &dyn Fn(&Env) -> Vec<f32>,
) -> Vec<Vec<f32>> {
    let mut env = task.env().unwrap();
    let mut obs = vec![env.reset(context).unwrap()];
    for _ in 0..max_steps {
        let out = env.step(&act(&env)).unwrap();
        obs.push(out.obs);
        if out.done {
            break;
        }
    }
    obs
}

/// Trace the same rollout twice in fresh environments and assert that every
/// observation is bit-identical; returns the trace (to check its length).
pub fn assert_deterministic(
    task: &LoadedTask,
    context: &Value,
    max_steps: usize,
    act: &dyn Fn(&Env) -> Vec<f32>,
) -> Vec<Vec<f32>> {
    let a = trace(task, context, max_steps, act);
    let b = trace(task, context, max_steps, act);
    assert_eq!(
        a,
        b,
        "{}: the same actions gave different observations",
        task.def.id()
    );
    a
}

/// Reset one environment to every initial state of the task's fixed set and
/// hand each (index, context, first observation) to `check`; returns the set
/// size.
pub fn reset_every_context(
    task: &LoadedTask,
    mut check: impl FnMut(usize, &Value, &[f32]),
) -> usize {
    let set = task.def.context_set().unwrap();
    let mut env = task.env().unwrap();
    for (i, c) in set.file.contexts.iter().enumerate() {
        let obs = env
            .reset(c)
            .unwrap_or_else(|e| panic!("{} context {i}: {e}", task.def.id()));
        check(i, c, &obs);
    }
    set.len()
}
