//! Results of one evaluation, and aggregated table cells.

use crate::task::{ObsType, TaskId};
use serde::{Deserialize, Serialize};

/// Everything needed to know exactly what was measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProtocolManifest {
    pub task: TaskId,
    pub task_version: String,
    pub obs_type: ObsType,
    pub protocol: crate::job::ProtocolKind,
    pub mjcf_sha256: String,
    pub initial_states_sha256: String,
    pub mujoco_version: String,
    pub evaluator_version: String,
    pub n_contexts: usize,
    pub rollouts_per_context: usize,
    pub max_steps: usize,
    pub policy_sha256: String,
    pub history: usize,
    pub horizon: usize,
    pub execute: usize,
    pub seed: u64,
}

/// A value with a bootstrap confidence interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub value: f64,
    pub ci_low: f64,
    pub ci_high: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub success_rate: Estimate,
    /// H(pi(beta)) over successful rollouts, log base |B|.
    pub behaviour_entropy: Estimate,
    /// E_s0[H(pi(beta|s0))] as the reference computes it.
    pub conditional_entropy: Estimate,
    /// Stacking only: fraction of rollouts with >= 1, 2, 3 boxes stacked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stacking: Option<[f64; 3]>,
    /// Mean policy inference time per batched query, milliseconds.
    pub inference_ms: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContextResult {
    pub context_index: usize,
    pub success_rate: f64,
    pub conditional_entropy: f64,
    /// Count per behaviour label (label as the reference encodes it, as a string).
    pub behaviours: Vec<(String, usize)>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutRecord {
    pub context_index: usize,
    pub rollout_index: usize,
    pub success: bool,
    /// Behaviour label in the reference encoding (JSON: vector, int or string).
    pub behaviour: serde_json::Value,
    pub steps: usize,
    /// End-effector xy path (Avoiding only), for plotting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<Vec<[f32; 2]>>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    pub manifest: ProtocolManifest,
    pub metrics: Metrics,
    pub per_context: Vec<ContextResult>,
    pub rollouts: Vec<RolloutRecord>,
}

/// Mean and standard deviation over training seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub mean: f64,
    pub std: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    Reported,
    Evaluated,
}

/// One leaderboard/table cell group: a method on a task, observation type and
/// data fraction, aggregated over its training seeds. Produced by the server's
/// store (reported rows from the paper, evaluated rows from results) and
/// consumed by the pages and `d3il tables`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultCell {
    /// Paper table this row belongs to: `main`, `datasize`, `posvel`, `prelim`
    /// (evaluated rows use `main` at fraction 1.0 and `datasize` otherwise).
    pub table: String,
    pub method: String,
    /// The paper's task title, e.g. `Stacking-2 (T5)` or `Arranging (T7)`;
    /// for evaluated rows [`TaskId::title`] (Stacking evaluated rows expand to
    /// `Stacking-1/2/3 (T5)`).
    pub task: String,
    pub obs: ObsType,
    pub data_fraction: f64,
    /// `position`/`velocity` for the posvel table, otherwise None.
    pub control: Option<String>,
    pub source: Source,
    pub success_rate: Stat,
    /// Conditional behaviour entropy (the paper's "Entropy" column).
    pub entropy: Stat,
    pub n_seeds: usize,
    /// As the paper printed them (reported rows only).
    pub bold_success: Option<bool>,
    pub bold_entropy: Option<bool>,
}
