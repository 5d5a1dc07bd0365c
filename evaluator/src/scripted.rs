//! Scripted reference policies as [`Policy`] implementations: the leaderboard's
//! sanity baselines. They act on the policy observation only, like a submission.
//!
//! Names (`scripted:<name>` in `d3il eval` and jobs; docs/tasks.md):
//! `avoiding:path=<0..23>`, `avoiding:all-paths`, `aligning:inside|outside|both`,
//! `pushing:mode=<0..3>`, `pushing:all-modes`, `sorting-X:order=<R/B sequence>`,
//! `sorting-X:all-orders`, `stacking:order=<r/g/b sequence>`, `stacking:all-orders`,
//! `inserting:box=<r|g|b>`.

use crate::tasks::aligning::{AligningScript, AligningStyle};
use crate::tasks::avoiding::AvoidingScript;
use crate::tasks::inserting::InsertingScript;
use crate::tasks::pushing::PushingScript;
use crate::tasks::sorting::{parse_order, SortingScript};
use crate::tasks::stacking::StackingScript;
use d3il_policy::{ActionChunks, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::{ObsType, TaskId, TaskSpec};
use std::collections::HashMap;

/// A scripted controller for one rollout: policy observation -> one action.
/// May keep state (a plan, a phase); a fresh instance is made per rollout.
pub trait Script: Send {
    fn act(&mut self, obs: &[f32]) -> Vec<f32>;
}

impl Script for AvoidingScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        AvoidingScript::act(self, obs).to_vec()
    }
}

impl Script for AligningScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        AligningScript::act(self, obs).to_vec()
    }
}

impl Script for PushingScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        PushingScript::act(self, obs).to_vec()
    }
}

impl Script for SortingScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        SortingScript::act(self, obs).to_vec()
    }
}

impl Script for StackingScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        StackingScript::act(self, obs).to_vec()
    }
}

impl Script for InsertingScript {
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        InsertingScript::act(self, obs).to_vec()
    }
}

/// Makes a fresh script for a new rollout.
type Factory = Box<dyn Fn() -> Box<dyn Script> + Send + Sync>;

/// A factory that clones a prototype script (which must be in its start state).
fn cloning<S: Script + Clone + Sync + 'static>(proto: S) -> Factory {
    Box::new(move || Box::new(proto.clone()))
}

/// Runs one script variant per rollout, chosen by rollout id (so a set of
/// variants covers several behaviours deterministically). Each rollout gets
/// its own script instance, created when the engine announces the rollout's
/// start through [`Policy::reset`].
pub struct ScriptedPolicy {
    name: String,
    variants: Vec<Factory>,
    live: HashMap<u64, Box<dyn Script>>,
    spec: TaskSpec,
}

#[derive(Debug, thiserror::Error)]
#[error(
    "unknown scripted policy `{name}` for task {task}; the scripted policies of {task} are: {}",
    names_for(*task)
)]
pub struct UnknownScript {
    pub name: String,
    /// The task evaluated: the message lists its scripted policies.
    pub task: TaskId,
}

/// The scripted policy names of `task` (`scripted:<name>`), as the error
/// for an unknown name lists them.
pub fn names_for(task: TaskId) -> &'static str {
    match task {
        TaskId::Avoiding => "avoiding:path=<0..23>, avoiding:all-paths",
        TaskId::Aligning => "aligning:inside, aligning:outside, aligning:both",
        TaskId::Pushing => "pushing:mode=<0..3>, pushing:all-modes",
        TaskId::Sorting2 => "sorting-2:order=<R and B, one of each, e.g. RB>, sorting-2:all-orders",
        TaskId::Sorting4 => {
            "sorting-4:order=<R and B, two of each, e.g. RBBR>, sorting-4:all-orders"
        }
        TaskId::Sorting6 => {
            "sorting-6:order=<R and B, three of each, e.g. RBRBRB>, sorting-6:all-orders"
        }
        TaskId::Stacking => {
            "stacking:order=<distinct letters of r, g, b, e.g. r, rgb>, stacking:all-orders"
        }
        TaskId::Inserting => "inserting:box=<r|g|b>",
    }
}

/// Every distinct arrangement of `n` R and `n` B, in lexicographic order.
fn sorting_orders(n: usize) -> Vec<String> {
    let mut out = Vec::new();
    for bits in 0u32..(1 << (2 * n)) {
        if bits.count_ones() as usize == n {
            let s: String = (0..2 * n)
                .rev()
                .map(|i| if bits >> i & 1 == 1 { 'B' } else { 'R' })
                .collect();
            out.push(s);
        }
    }
    out.sort();
    out
}

fn sorting_script(order: &str, boxes: usize) -> Option<SortingScript> {
    let colours = parse_order(order)?;
    let reds = order
        .chars()
        .filter(|c| c.eq_ignore_ascii_case(&'r'))
        .count();
    (colours.len() == boxes && reds * 2 == boxes)
        .then(|| SortingScript::new(order))
        .flatten()
}

fn stacking_script(order: &str) -> Option<StackingScript> {
    let mut seen = String::new();
    for c in order.chars() {
        if !"rgb".contains(c) || seen.contains(c) {
            return None;
        }
        seen.push(c);
    }
    (!seen.is_empty())
        .then(|| StackingScript::new(order))
        .flatten()
}

impl ScriptedPolicy {
    /// Parses names like `avoiding:path=3`, `sorting-4:order=RBBR` or
    /// `stacking:all-orders`; the task part must be `spec.task`.
    pub fn from_name(name: &str, spec: TaskSpec) -> Result<Self, UnknownScript> {
        let unknown = || UnknownScript {
            name: name.to_string(),
            task: spec.task,
        };
        let (task, what) = name.split_once(':').ok_or_else(unknown)?;
        let task: TaskId = task.parse().map_err(|_| unknown())?;
        if task != spec.task {
            return Err(unknown());
        }
        let param = |key: &str| what.strip_prefix(key).filter(|v| !v.is_empty());
        let variants: Vec<Factory> = match (task, what) {
            (TaskId::Avoiding, "all-paths") => (0..24)
                .filter_map(AvoidingScript::new)
                .map(cloning)
                .collect(),
            (TaskId::Avoiding, _) => {
                let path: usize = param("path=")
                    .and_then(|p| p.parse().ok())
                    .ok_or_else(unknown)?;
                vec![cloning(AvoidingScript::new(path).ok_or_else(unknown)?)]
            }
            (TaskId::Aligning, "inside") => {
                vec![cloning(AligningScript::new(AligningStyle::Inside))]
            }
            (TaskId::Aligning, "outside") => {
                vec![cloning(AligningScript::new(AligningStyle::Outside))]
            }
            (TaskId::Aligning, "both") => vec![
                cloning(AligningScript::new(AligningStyle::Inside)),
                cloning(AligningScript::new(AligningStyle::Outside)),
            ],
            (TaskId::Pushing, "all-modes") => {
                (0..4).filter_map(PushingScript::new).map(cloning).collect()
            }
            (TaskId::Pushing, _) => {
                let mode: u8 = param("mode=")
                    .and_then(|p| p.parse().ok())
                    .ok_or_else(unknown)?;
                vec![cloning(PushingScript::new(mode).ok_or_else(unknown)?)]
            }
            (TaskId::Sorting2 | TaskId::Sorting4 | TaskId::Sorting6, _) => {
                let boxes = match task {
                    TaskId::Sorting2 => 2,
                    TaskId::Sorting4 => 4,
                    _ => 6,
                };
                let orders = if what == "all-orders" {
                    sorting_orders(boxes / 2)
                } else {
                    vec![param("order=").ok_or_else(unknown)?.to_string()]
                };
                orders
                    .iter()
                    .map(|o| sorting_script(o, boxes).map(cloning).ok_or_else(unknown))
                    .collect::<Result<_, _>>()?
            }
            (TaskId::Stacking, _) => {
                let orders: Vec<String> = if what == "all-orders" {
                    ["rgb", "rbg", "grb", "gbr", "brg", "bgr"]
                        .map(String::from)
                        .into()
                } else {
                    vec![param("order=").ok_or_else(unknown)?.to_string()]
                };
                orders
                    .iter()
                    .map(|o| stacking_script(o).map(cloning).ok_or_else(unknown))
                    .collect::<Result<_, _>>()?
            }
            (TaskId::Inserting, _) => {
                let b = match param("box=").ok_or_else(unknown)? {
                    "r" => 0,
                    "g" => 1,
                    "b" => 2,
                    _ => return Err(unknown()),
                };
                vec![cloning(InsertingScript::new(b).ok_or_else(unknown)?)]
            }
            (TaskId::Aligning, _) => return Err(unknown()),
        };
        if variants.is_empty() {
            return Err(unknown());
        }
        Ok(ScriptedPolicy {
            name: name.to_string(),
            variants,
            live: HashMap::new(),
            spec,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Number of script variants the rollouts cycle through.
    pub fn variants(&self) -> usize {
        self.variants.len()
    }

    /// A fresh instance of variant `v` (modulo the number of variants),
    /// in its start state: for recorders that drive a script themselves
    /// (`crate::demos`).
    pub fn script(&self, v: usize) -> Box<dyn Script> {
        (self.variants[v % self.variants.len()])()
    }

    fn fresh(&self, rollout_id: u64) -> Box<dyn Script> {
        (self.variants[rollout_id as usize % self.variants.len()])()
    }
}

impl Policy for ScriptedPolicy {
    fn shape(&self) -> PolicyShape {
        PolicyShape {
            history: 1,
            horizon: 1,
            execute: 1,
            obs_dim: self.spec.obs_dim,
            act_dim: self.spec.act_dim,
            obs_type: ObsType::State,
        }
    }

    /// New episodes: a fresh script instance for each of these rollouts.
    fn reset(&mut self, rollout_ids: &[u64]) -> Result<(), PolicyError> {
        for &id in rollout_ids {
            let s = self.fresh(id);
            self.live.insert(id, s);
        }
        Ok(())
    }

    fn infer(&mut self, query: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        query.check(&self.shape())?;
        let d = self.spec.obs_dim;
        let mut data = Vec::with_capacity(query.batch() * self.spec.act_dim);
        for (row, id) in query.rollout_ids.iter().enumerate() {
            // A rollout the engine did not announce (or one restarting at
            // step 0 under an old id) gets a fresh script too.
            if query.steps[row] == 0 || !self.live.contains_key(id) {
                let s = self.fresh(*id);
                self.live.insert(*id, s);
            }
            let script = self.live.get_mut(id).expect("inserted above");
            data.extend(script.act(&query.obs[row * d..(row + 1) * d]));
        }
        Ok(ActionChunks {
            batch: query.batch(),
            horizon: 1,
            act_dim: self.spec.act_dim,
            data,
        })
    }

    /// A script is a function of the observations it was given (no random
    /// numbers, no clock), so with one variant every rollout of an initial
    /// state is the same computation and the engine simulates it once (the
    /// results are the same bit for bit, `tests/eval/identical_rollouts.rs`).
    /// Several variants are chosen by rollout id: the rollouts of a state
    /// differ.
    fn deterministic(&self) -> bool {
        self.variants.len() == 1
    }
}

#[cfg(test)]
mod tests {
    use super::sorting_orders;

    #[test]
    fn sorting_orders_are_all_arrangements() {
        assert_eq!(sorting_orders(1), ["BR", "RB"]);
        assert_eq!(sorting_orders(2).len(), 6);
        assert_eq!(sorting_orders(3).len(), 20);
        assert!(sorting_orders(3).contains(&"RBBRRB".to_string()));
    }
}
