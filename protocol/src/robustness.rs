//! The robustness document `d3il eval --suite robustness --json` writes: the
//! control arm (level 0, the plain evaluation), every perturbed level of the
//! suite ([`crate::perturbation`]) with its paired drop, and the scores.

use crate::perturbation::{Axis, LevelSetting};
use crate::results::{Comparison, Estimate, EvalResult};
use crate::TaskId;
use serde::{Deserialize, Serialize};

/// Format tag of [`RobustnessResult`].
pub const ROBUSTNESS_FORMAT: &str = "d3il-robustness-v1";

/// One perturbed level of a robustness evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelResult {
    pub axis: Axis,
    pub level: usize,
    pub setting: LevelSetting,
    /// The level's evaluation (its manifest carries the perturbation, its
    /// records replay with `d3il replay --result FILE --level AXIS/LEVEL`).
    pub result: EvalResult,
    /// Level 0 − this level, paired by initial state (`d3il compare`'s
    /// machinery): success-rate drop and conditional-entropy change with
    /// intervals and p-values.
    pub paired: Comparison,
    /// Success retained, in [0, 1]: the share of level 0's successes this
    /// level keeps, paired by initial state, `Σ_s min(p0(s), pL(s)) / Σ_s
    /// p0(s)` (`d3il_metrics::robustness`; gains elsewhere are in `paired`).
    /// None when level 0 has no success.
    pub retained: Option<f64>,
}

/// The robustness score of one axis: success retained (see
/// [`LevelResult::retained`]), averaged over the axis's levels, with a paired
/// bootstrap interval over initial states.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisScore {
    pub axis: Axis,
    /// None when level 0 has no success (nothing to retain).
    pub score: Option<Estimate>,
}

/// What `d3il eval --suite robustness --json FILE` writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobustnessResult {
    /// [`ROBUSTNESS_FORMAT`].
    pub format: String,
    pub task: TaskId,
    pub suite: String,
    pub suite_sha256: String,
    /// Level 0: the plain evaluation, bit for bit.
    pub control: EvalResult,
    /// Every perturbed level, axis by axis in the suite's order.
    pub levels: Vec<LevelResult>,
    pub axes: Vec<AxisScore>,
    /// Mean of the axes' scores, with its interval.
    pub overall: Option<Estimate>,
    pub resamples: usize,
    pub confidence: f64,
}

impl RobustnessResult {
    /// The evaluation of `axis`/`level` (level 0: the control).
    pub fn level(&self, axis: Axis, level: usize) -> Option<&EvalResult> {
        if level == 0 {
            return Some(&self.control);
        }
        self.levels
            .iter()
            .find(|l| l.axis == axis && l.level == level)
            .map(|l| &l.result)
    }

    /// The label of this document's score intervals when their measured
    /// coverage is below the nominal 95 % (from the initial states of level
    /// 0, which every level shares: [`crate::interval::score_coverage`]);
    /// None from enough states, or when there is no score interval.
    pub fn score_coverage(&self) -> Option<crate::interval::ScoreCoverage> {
        let has_interval = self
            .axes
            .iter()
            .filter_map(|a| a.score.as_ref())
            .chain(self.overall.as_ref())
            .any(|e| e.interval().is_some());
        if !has_interval {
            return None;
        }
        crate::interval::score_coverage(self.control.manifest.n_contexts)
    }
}

/// Format tag of [`RobustnessPart`].
pub const ROBUSTNESS_PART_FORMAT: &str = "d3il-robustness-part-v1";

/// What `d3il eval --suite robustness --shard K/N --json FILE` writes: the
/// shard's part of level 0 and of every level (the same block of initial
/// states at every level). `d3il merge` joins the parts of all shards into
/// the [`RobustnessResult`] of the unsharded run, bit for bit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobustnessPart {
    /// [`ROBUSTNESS_PART_FORMAT`].
    pub format: String,
    pub task: TaskId,
    pub suite: String,
    pub suite_sha256: String,
    pub shard: crate::shard::Shard,
    /// Level 0's part.
    pub control: crate::shard::EvalPart,
    /// Every perturbed level's part, in the suite's order (each manifest
    /// records its perturbation).
    pub levels: Vec<crate::shard::EvalPart>,
}
