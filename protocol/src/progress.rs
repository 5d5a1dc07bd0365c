//! What an evaluation reports while it runs: the rollouts done,
//! and the outcomes of the initial states finished so far **in the
//! evaluation's random order** (`d3il_metrics::order::state_order` of the
//! protocol's initial states under the manifest's seed), so that every
//! prefix of the reported states is a fair sample and a confidence sequence
//! fed with them is valid at every look (docs/sequential.md).

use serde::{Deserialize, Serialize};

/// One progress report (a worker's `progress` line carries the same fields).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub rollouts_done: usize,
    pub rollouts_total: usize,
    /// The initial states whose rollouts have all finished since the
    /// previous report, in the random order: a state is reported once every
    /// state before it in the order has been (a state that finishes early
    /// waits for them), so the concatenation of all reports' `states` is a
    /// prefix of the order. Empty when nothing new is complete.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<StateOutcome>,
    /// A race job's progress: where the paired test stands after
    /// the latest pair; one report per pair.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub race: Option<Box<crate::race::RaceProgress>>,
}

/// The outcomes of one initial state's rollouts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateOutcome {
    /// Its place in the evaluation's random order (0 for the first reported).
    pub position: usize,
    /// The initial state (global index into the protocol's states).
    pub context_index: usize,
    /// Success of each rollout of the state, by rollout index. A
    /// deterministic policy simulated once per state (`simulated_once`)
    /// has every entry equal: one outcome, recorded under every index.
    pub successes: Vec<bool>,
}

impl StateOutcome {
    /// The state's success rate: the value a confidence sequence of the
    /// evaluation's success rate is fed, one per state (rollouts of one
    /// state are not independent of each other; states drawn in random
    /// order are exchangeable).
    pub fn rate(&self) -> f64 {
        if self.successes.is_empty() {
            return 0.0;
        }
        self.successes.iter().filter(|s| **s).count() as f64 / self.successes.len() as f64
    }
}

impl Progress {
    /// A report with counts only (loading, or nothing newly complete).
    pub fn counts(rollouts_done: usize, rollouts_total: usize) -> Progress {
        Progress {
            rollouts_done,
            rollouts_total,
            states: Vec::new(),
            race: None,
        }
    }
}
