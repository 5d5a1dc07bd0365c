//! Scripted reference policies as [`Policy`] implementations: the leaderboard's
//! sanity baselines. They act on the policy observation only, like a submission.

use crate::tasks::aligning::{AligningScript, AligningStyle};
use crate::tasks::avoiding::AvoidingScript;
use crate::tasks::pushing::PushingScript;
use d3il_policy::{ActionChunks, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::{ObsType, TaskId, TaskSpec};

/// A per-rollout scripted controller: policy observation -> one action.
pub trait Script: Send + Sync {
    fn act(&self, obs: &[f32]) -> Vec<f32>;
}

impl Script for AvoidingScript {
    fn act(&self, obs: &[f32]) -> Vec<f32> {
        AvoidingScript::act(self, obs).to_vec()
    }
}

impl Script for AligningScript {
    fn act(&self, obs: &[f32]) -> Vec<f32> {
        AligningScript::act(self, obs).to_vec()
    }
}

impl Script for PushingScript {
    fn act(&self, obs: &[f32]) -> Vec<f32> {
        PushingScript::act(self, obs).to_vec()
    }
}

/// Runs one script per rollout (chosen by rollout id, so a set of scripts
/// covers several behaviours deterministically).
pub struct ScriptedPolicy {
    name: String,
    scripts: Vec<Box<dyn Script>>,
    spec: TaskSpec,
}

#[derive(Debug, thiserror::Error)]
#[error("unknown scripted policy `{0}`; available: avoiding:path=<0..23>, avoiding:all-paths, aligning:inside, aligning:outside, aligning:both, pushing:mode=<0..3>, pushing:all-modes")]
pub struct UnknownScript(pub String);

impl ScriptedPolicy {
    /// Parses names like `avoiding:path=3` or `avoiding:all-paths`.
    pub fn from_name(name: &str, spec: TaskSpec) -> Result<Self, UnknownScript> {
        let unknown = || UnknownScript(name.to_string());
        let (task, what) = name.split_once(':').ok_or_else(unknown)?;
        let task: TaskId = task.parse().map_err(|_| unknown())?;
        if task != spec.task {
            return Err(unknown());
        }
        let scripts: Vec<Box<dyn Script>> = match (task, what) {
            (TaskId::Avoiding, "all-paths") => (0..24)
                .filter_map(AvoidingScript::new)
                .map(|s| Box::new(s) as Box<dyn Script>)
                .collect(),
            (TaskId::Avoiding, w) => {
                let path: usize = w
                    .strip_prefix("path=")
                    .and_then(|p| p.parse().ok())
                    .ok_or_else(unknown)?;
                vec![Box::new(AvoidingScript::new(path).ok_or_else(unknown)?)]
            }
            (TaskId::Aligning, "inside") => {
                vec![Box::new(AligningScript::new(AligningStyle::Inside))]
            }
            (TaskId::Aligning, "outside") => {
                vec![Box::new(AligningScript::new(AligningStyle::Outside))]
            }
            (TaskId::Aligning, "both") => vec![
                Box::new(AligningScript::new(AligningStyle::Inside)),
                Box::new(AligningScript::new(AligningStyle::Outside)),
            ],
            (TaskId::Pushing, "all-modes") => (0..4)
                .filter_map(PushingScript::new)
                .map(|s| Box::new(s) as Box<dyn Script>)
                .collect(),
            (TaskId::Pushing, w) => {
                let mode: u8 = w
                    .strip_prefix("mode=")
                    .and_then(|p| p.parse().ok())
                    .ok_or_else(unknown)?;
                vec![Box::new(PushingScript::new(mode).ok_or_else(unknown)?)]
            }
            _ => return Err(unknown()),
        };
        Ok(ScriptedPolicy {
            name: name.to_string(),
            scripts,
            spec,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
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

    fn reset(&mut self, _rollout_ids: &[u64]) -> Result<(), PolicyError> {
        Ok(())
    }

    fn infer(&mut self, query: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        query.check(&self.shape())?;
        let d = self.spec.obs_dim;
        let mut data = Vec::with_capacity(query.batch() * self.spec.act_dim);
        for (row, id) in query.rollout_ids.iter().enumerate() {
            let script = &self.scripts[*id as usize % self.scripts.len()];
            data.extend(script.act(&query.obs[row * d..(row + 1) * d]));
        }
        Ok(ActionChunks {
            batch: query.batch(),
            horizon: 1,
            act_dim: self.spec.act_dim,
            data,
        })
    }
}
