//! How an [`crate::Estimate`]'s interval was made, or why there is none
//! (docs/intervals.md). The rules that choose between them live in
//! `d3il_metrics::intervals` (which re-exports these types); the names and
//! reasons are here, once, because every document, page and command that
//! shows an estimate says them.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Which method made an interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntervalMethod {
    /// Success rate, one rollout per state: exact binomial (Clopper & Pearson 1934).
    ClopperPearson,
    /// Success rate of a task with one fixed initial state (Avoiding):
    /// exact binomial on its rollouts.
    ClopperPearsonRollouts,
    /// Success rate, every state at 0 (or at 1): Clopper–Pearson counting
    /// each state as one trial.
    ClopperPearsonAllEqual,
    /// Success rate, 100 states or more: percentile bootstrap over states
    /// (Davison & Hinkley 1997, §3.8).
    ClusterBootstrap,
    /// Success rate otherwise: Clopper–Pearson at an effective sample size
    /// (Korn & Graubard 1998).
    KornGraubard,
    /// Paired difference: the sign-flip test inverted, all `2^n` sign vectors.
    SignFlipExact,
    /// Paired difference: the sign-flip test inverted, Monte Carlo over sign vectors.
    SignFlipMonteCarlo,
    /// Paired difference, one rollout a state: the exact McNemar test
    /// (conditional binomial on the discordant states) inverted through
    /// Clopper–Pearson intervals of its two shares.
    #[serde(rename = "mcnemar_exact")]
    McNemarExact,
    /// Difference on one initial state (Avoiding): the rollouts of each
    /// side as two independent samples, the Miettinen–Nurminen score test
    /// inverted.
    ScoreTwoSample,
    /// Entropies and robustness scores: two-stage bootstrap (states, then
    /// rollouts within them), bias-corrected percentile interval.
    BiasCorrectedBootstrap,
    /// A paired difference of conditional entropies on tasks that drop
    /// states without a labelled success (Sorting, Stacking, Inserting):
    /// paired bootstrap over states, bias-corrected percentile interval; its
    /// p-value is the randomisation test's and the two can disagree.
    PairedBootstrap,
}

impl IntervalMethod {
    /// The method's name as pages and commands print it.
    pub fn name(self) -> &'static str {
        match self {
            IntervalMethod::ClopperPearson => "Clopper-Pearson (one rollout per state)",
            IntervalMethod::ClopperPearsonRollouts => {
                "Clopper-Pearson (rollouts of the one initial state)"
            }
            IntervalMethod::ClopperPearsonAllEqual => {
                "Clopper-Pearson on states (all states equal)"
            }
            IntervalMethod::ClusterBootstrap => "percentile cluster bootstrap",
            IntervalMethod::KornGraubard => "Korn-Graubard (Clopper-Pearson, effective size)",
            IntervalMethod::SignFlipExact => "inverted sign-flip test (exact)",
            IntervalMethod::SignFlipMonteCarlo => "inverted sign-flip test (Monte Carlo)",
            IntervalMethod::McNemarExact => "inverted exact McNemar test (one rollout per state)",
            IntervalMethod::ScoreTwoSample => {
                "Miettinen-Nurminen score, two-sample (rollouts of the one initial state)"
            }
            IntervalMethod::BiasCorrectedBootstrap => "two-stage bootstrap, bias-corrected",
            IntervalMethod::PairedBootstrap => "paired bootstrap, bias-corrected",
        }
    }

    /// Whether "0 outside the interval" and "p ≤ α" agree by construction
    /// (the interval is the printed test inverted).
    pub fn agrees_with_p_value(self) -> bool {
        matches!(
            self,
            IntervalMethod::SignFlipExact
                | IntervalMethod::SignFlipMonteCarlo
                | IntervalMethod::McNemarExact
                | IntervalMethod::ScoreTwoSample
        )
    }
}

impl fmt::Display for IntervalMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why no interval is given.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum NoInterval {
    /// No states, or a state without rollouts.
    NoData,
    /// Fewer states than the success-rate rule's minimum.
    TooFewStates { states: usize, min: usize },
    /// The paired test cannot reject any shift at this level: its smallest
    /// attainable p-value is above α.
    TestCannotReject { states: usize, smallest_p: f64 },
    /// Every state shows the same paired difference: no spread for the
    /// test to resample.
    NoSpread { states: usize, difference: f64 },
    /// A bootstrap interval asked for with no resamples.
    NoResamples,
}

impl fmt::Display for NoInterval {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NoInterval::NoData => write!(f, "no interval: no rollouts"),
            NoInterval::TooFewStates { states, min } => write!(
                f,
                "no interval: {states} initial states cannot show how much states differ (an interval needs at least {min})"
            ),
            NoInterval::TestCannotReject { states: 1, .. } => write!(
                f,
                "no interval: a paired test over initial states needs more than one initial state (this protocol has one; its rollouts are not paired)"
            ),
            NoInterval::TestCannotReject { states, smallest_p } => write!(
                f,
                "no interval: with {states} initial states the paired test's smallest possible p-value is {smallest_p:.3}, so it cannot exclude any difference"
            ),
            NoInterval::NoSpread { states, difference } => write!(
                f,
                "no interval: all {states} initial states show the same difference {difference:+.3}, so there is no spread to measure its uncertainty from"
            ),
            NoInterval::NoResamples => {
                write!(f, "no interval: computed without bootstrap resamples")
            }
        }
    }
}

impl NoInterval {
    /// The reason in a few words, for table cells (the full sentence is
    /// [`fmt::Display`]).
    pub fn short(&self) -> String {
        match self {
            NoInterval::NoData => "no interval (no rollouts)".into(),
            NoInterval::TooFewStates { states, .. } => {
                format!("no interval ({states} states)")
            }
            NoInterval::TestCannotReject { states: 1, .. } => {
                "no interval (one initial state)".into()
            }
            NoInterval::TestCannotReject { states, smallest_p } => {
                format!("no interval ({states} states, p ≥ {smallest_p:.2})")
            }
            NoInterval::NoSpread { .. } => "no interval (no spread)".into(),
            NoInterval::NoResamples => "no interval (no resamples)".into(),
        }
    }
}
