//! The two inputs of `d3il replay`, read and checked before anything is
//! simulated: a stored rollout of a result-like document (`--result out.json
//! --rollout N`) and an episode of actions (`--task T --input ep.json`).
//! They are outside input (a result from anywhere, a hand-written episode),
//! so every problem is an error that says what to fix; the fuzz target
//! `replay` (fuzz-targets) calls these same functions.

use crate::tasks::LoadedTask;
use d3il_protocol::{trace_of, ProtocolManifest, RolloutRecord, RolloutTrace};
use serde::Deserialize;
use serde_json::Value;

#[derive(Debug, thiserror::Error)]
pub enum ReplayInputError {
    #[error("the result must be a JSON object with `manifest` and `rollouts` as `d3il eval --json` writes it: {0}")]
    NotAResult(serde_json::Error),
    #[error("this is a robustness document (`d3il eval --suite robustness --json`): name the level whose rollout to replay with --level AXIS/LEVEL; it has levels {levels}")]
    NeedsLevel { levels: String },
    #[error("the result has no rollout {number}; it has {have}")]
    NoSuchRollout { number: usize, have: String },
    #[error("rollout {0} has no trace: the result was made before rollouts were recorded for replay (evaluate it again to replay it)")]
    NoTrace(usize),
    #[error("the input must be a JSON object {{\"context\": ..., \"actions\": [[...], ...]}} with numeric action rows: {0}")]
    NotAnEpisode(serde_json::Error),
    #[error("actions[{index}] has {got} values but task {task} expects {expected} ({meaning})")]
    ActionWidth {
        index: usize,
        got: usize,
        task: d3il_protocol::TaskId,
        expected: usize,
        meaning: &'static str,
    },
}

/// The levels (`axis/level`, comma-separated) of a robustness document: an
/// object whose `levels` are objects with an `axis` and a `level`, the shape
/// `d3il eval --suite robustness --json` writes. `None` for anything else.
fn robustness_levels(text: &str) -> Option<String> {
    let doc: Value = serde_json::from_str(text).ok()?;
    let levels = doc.get("levels")?.as_array()?;
    let names: Option<Vec<String>> = levels
        .iter()
        .map(|l| {
            Some(format!(
                "{}/{}",
                l.get("axis")?.as_str()?,
                l.get("level")?.as_u64()?
            ))
        })
        .collect();
    names.filter(|n| !n.is_empty()).map(|n| n.join(", "))
}

/// What `--result` reads: the manifest and the rollouts of any result-like
/// document (other fields are ignored).
#[derive(Debug, Deserialize)]
pub struct ReplayDoc {
    pub manifest: ProtocolManifest,
    pub rollouts: Vec<RolloutRecord>,
}

impl ReplayDoc {
    pub fn parse(text: &str) -> Result<ReplayDoc, ReplayInputError> {
        serde_json::from_str(text).map_err(|e| match robustness_levels(text) {
            Some(levels) => ReplayInputError::NeedsLevel { levels },
            None => ReplayInputError::NotAResult(e),
        })
    }

    /// Rollout `number` (initial state × rollouts per state + index) and its
    /// trace (its own, or its state's rollout 0 for a policy simulated once).
    pub fn rollout(
        &self,
        number: usize,
    ) -> Result<(&RolloutRecord, &RolloutTrace), ReplayInputError> {
        let per = self.manifest.rollouts_per_context;
        let record = self
            .rollouts
            .iter()
            .find(|r| r.number(per) == number)
            .ok_or_else(|| {
                let numbers: Vec<usize> = self.rollouts.iter().map(|r| r.number(per)).collect();
                ReplayInputError::NoSuchRollout {
                    number,
                    have: summarize(&numbers),
                }
            })?;
        let trace = trace_of(&self.manifest, &self.rollouts, record)
            .ok_or(ReplayInputError::NoTrace(number))?;
        Ok((record, trace))
    }
}

/// "rollouts 0 to 15" for a run of numbers, else the list.
fn summarize(numbers: &[usize]) -> String {
    match (numbers.first(), numbers.last()) {
        (Some(a), Some(b))
            if b.checked_sub(*a).and_then(|d| d.checked_add(1)) == Some(numbers.len()) =>
        {
            format!("rollouts {a} to {b}")
        }
        _ => format!("rollouts {numbers:?}"),
    }
}

/// What `--input` reads: `{"context": ..., "actions": [[...], ...]}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Episode {
    #[serde(default)]
    pub context: Value,
    pub actions: Vec<Vec<f32>>,
}

impl Episode {
    /// Parses the episode and checks every action row's width against `task`.
    pub fn parse(text: &str, task: &LoadedTask) -> Result<Episode, ReplayInputError> {
        let episode: Episode =
            serde_json::from_str(text).map_err(ReplayInputError::NotAnEpisode)?;
        let expected = task.def.act_dim();
        if let Some((index, a)) = episode
            .actions
            .iter()
            .enumerate()
            .find(|(_, a)| a.len() != expected)
        {
            return Err(ReplayInputError::ActionWidth {
                index,
                got: a.len(),
                task: task.def.id(),
                expected,
                meaning: task.def.act_meaning(),
            });
        }
        Ok(episode)
    }
}
