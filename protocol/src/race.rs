//! A sequential race of two policies: what a race reports while
//! it runs and when it ends, and the race job a server sends a worker
//! ([`crate::Job::race`]). The race itself is `d3il_evaluator::eval::race`;
//! docs/sequential.md has the rule.

use crate::{PolicyManifest, PolicySource, ProtocolKind, StateOutcome, TaskId};
use serde::{Deserialize, Serialize};

/// A race's level α when none is given.
pub const DEFAULT_ALPHA: f64 = 0.05;

/// A race parameter out of range: the parameter's name (`alpha`, `delta`)
/// and what to fix.
#[derive(Debug, Clone, PartialEq)]
pub struct RaceParamError {
    pub field: &'static str,
    pub message: String,
}

impl std::fmt::Display for RaceParamError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for RaceParamError {}

/// The one range check of a race's level α, in (0, 1), and margin δ, in
/// (0, 2) (a difference of two success rates lies in [-1, 1], so a margin of
/// 2 or more could never be left): the server's race requests, the worker's
/// race and `d3il compare --sequential` all ask it.
pub fn check_race_params(alpha: f64, delta: Option<f64>) -> Result<(), RaceParamError> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(RaceParamError {
            field: "alpha",
            message: format!("alpha {alpha} is not in (0, 1); use e.g. 0.05"),
        });
    }
    match delta {
        Some(d) if !(d > 0.0 && d < 2.0) => Err(RaceParamError {
            field: "delta",
            message: format!(
                "delta {d} is not in (0, 2); use e.g. 0.1 (ten points of success rate)"
            ),
        }),
        _ => Ok(()),
    }
}

/// The second policy of a race job and the test's level and margin: the
/// job's own policy is A, this one is B, run on the job's task, protocol and
/// seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RaceJob {
    pub policy_b: PolicySource,
    pub manifest_b: PolicyManifest,
    /// Two-sided level α in (0, 1).
    pub alpha: f64,
    /// The margin δ in (0, 2) of "no difference larger than δ", if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delta: Option<f64>,
    /// Rollouts simulated at once per policy (as `d3il compare --max-live`).
    pub max_live: usize,
}

/// Where a race stands after a state completed for both policies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RaceProgress {
    /// Initial states complete for both, in the random order.
    pub states: usize,
    /// The protocol's initial states (the full size).
    pub states_total: usize,
    /// Pairs fed to the test so far.
    pub pairs: u64,
    /// The two-sided e-value now.
    pub e_value: f64,
    /// The anytime-valid p-value now (1 / the running maximum e-value).
    pub p_value: f64,
    /// Discordant pairs won by A and by B.
    pub discordant: (u64, u64),
    /// Set once decided: "A better", "B better" or "no difference larger than δ".
    pub decision: Option<String>,
    /// The state just paired (the last one when several completed at once).
    pub a: StateOutcome,
    pub b: StateOutcome,
}

/// What a race found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RaceReport {
    pub task: TaskId,
    pub protocol: ProtocolKind,
    /// The seed of both evaluations: noise and the order of the states.
    pub seed: u64,
    pub alpha: f64,
    pub delta: Option<f64>,
    /// What one pair is: `"initial state (its rollout 0)"`.
    pub pair: String,
    /// `None` when the protocol's full size ran without a decision.
    pub decision: Option<String>,
    /// The pair (1-based) at which it decided.
    pub decided_at: Option<u64>,
    pub e_value: f64,
    pub p_value: f64,
    pub discordant: (u64, u64),
    /// The confidence sequence of rate(A) − rate(B) (with δ).
    pub difference_interval: Option<(f64, f64)>,
    /// Success rates of A and B over the states used.
    pub rate_a: f64,
    pub rate_b: f64,
    /// Pairs fed to the test, and what the protocol's full size gives.
    pub pairs_used: u64,
    pub pairs_full: u64,
    /// Initial states used (complete for both when the race stopped).
    pub states_used: usize,
    pub states_full: usize,
    /// Rollouts of both policies in the states used (the protocol's
    /// rollouts per state each, copies of once-simulated ones included), and
    /// in the protocol's full size: what the fixed-size paired test of the
    /// leaderboard (`d3il compare`) runs.
    pub rollouts_used: usize,
    pub rollouts_full: usize,
    /// Rollouts actually simulated, both policies, including any that were
    /// running when the race decided and were dropped.
    pub rollouts_simulated: usize,
    /// The exact sign test on the pairs used: its two-sided p-value (not
    /// valid after a data-dependent stop; for reference).
    pub fixed_p_value: f64,
    /// Pairs the exact fixed-size sign test at α needs for 90 % power if the
    /// discordant rates were those observed (`None`: no difference observed,
    /// or more than 100 000 pairs). A plug-in guide, not a guarantee.
    pub fixed_pairs_for_power_90: Option<usize>,
    /// Wall-clock seconds and batched policy calls of both.
    pub seconds: f64,
    pub policy_calls: usize,
    /// The pairs in the order the test saw them, one [`pair_code`] each
    /// (the race page draws its walk from them). Empty in reports made
    /// before it was recorded.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub outcomes: String,
}

/// One pair as a character: `a` only A succeeded, `b` only B, `1` both,
/// `0` neither.
pub fn pair_code(a: bool, b: bool) -> char {
    match (a, b) {
        (true, false) => 'a',
        (false, true) => 'b',
        (true, true) => '1',
        (false, false) => '0',
    }
}

/// The pairs `(A succeeded, B succeeded)` of a string of [`pair_code`]s, or
/// the first character that is none.
pub fn pairs_of(codes: &str) -> Result<Vec<(bool, bool)>, char> {
    codes
        .chars()
        .map(|c| match c {
            'a' => Ok((true, false)),
            'b' => Ok((false, true)),
            '1' => Ok((true, true)),
            '0' => Ok((false, false)),
            other => Err(other),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn race_parameters_are_checked_once_with_what_to_fix() {
        assert_eq!(check_race_params(DEFAULT_ALPHA, None), Ok(()));
        assert_eq!(check_race_params(0.01, Some(0.1)), Ok(()));
        for alpha in [0.0, 1.0, -0.1, f64::NAN] {
            let e = check_race_params(alpha, None).unwrap_err();
            assert_eq!(e.field, "alpha");
            assert!(e.message.contains("is not in (0, 1); use e.g. 0.05"), "{e}");
        }
        for delta in [0.0, 2.0, -1.0, f64::NAN] {
            let e = check_race_params(0.05, Some(delta)).unwrap_err();
            assert_eq!(e.field, "delta");
            assert!(e.message.contains("is not in (0, 2)"), "{e}");
        }
    }
}
