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

/// One cell of `d3il bench intervals`' robustness-score table: how often the
/// score's 95 % paired bootstrap interval covered the score's expected value
/// at this size, over [`SCORE_COVERAGE_REPLICATIONS`] simulated datasets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScoreCoverageCell {
    /// Level 0's success rate of the simulated policy, in percent.
    pub rate_percent: u32,
    pub states: usize,
    pub rollouts: usize,
    /// The coverage as the bench printed it, in per mille.
    pub coverage_per_mille: u32,
}

impl ScoreCoverageCell {
    pub fn coverage(&self) -> f64 {
        self.coverage_per_mille as f64 / 1000.0
    }
}

/// Simulated datasets per cell of the bench's score table.
pub const SCORE_COVERAGE_REPLICATIONS: usize = 400;

/// The nominal coverage of every interval the service prints.
pub const NOMINAL_COVERAGE: f64 = 0.95;

/// How many Monte-Carlo standard errors below [`NOMINAL_COVERAGE`] a cell may
/// read and still count as covering: with some 100 cells of true coverage
/// 95 % the lowest is expected near 92.5 %, 2.3 standard errors down
/// (docs/intervals.md).
pub const MONTE_CARLO_TOLERANCE: f64 = 3.0;

/// The robustness scores' measured coverage: `d3il bench intervals`' score
/// table as run for docs/intervals.md (one axis, three levels at 0.75^l of
/// level 0's rate; 1000 resamples; fixed seeds). The bench runs exactly these
/// cells, in this order, and says whether its run still gives these figures.
/// Every label of a score's interval ([`score_coverage`]) is read off it.
pub const SCORE_COVERAGE_MEASURED: [ScoreCoverageCell; 12] = {
    const fn cell(rate: u32, states: usize, rollouts: usize, per_mille: u32) -> ScoreCoverageCell {
        ScoreCoverageCell {
            rate_percent: rate,
            states,
            rollouts,
            coverage_per_mille: per_mille,
        }
    }
    [
        cell(80, 3, 2, 662),
        cell(80, 3, 8, 735),
        cell(80, 10, 2, 900),
        cell(80, 10, 8, 907),
        cell(80, 30, 2, 963),
        cell(80, 30, 8, 938),
        cell(80, 60, 2, 950),
        cell(80, 60, 8, 943),
        cell(50, 10, 8, 907),
        cell(50, 30, 2, 955),
        cell(20, 30, 8, 948),
        cell(20, 60, 2, 927),
    ]
};

/// The Monte-Carlo standard error of one cell's coverage at the nominal level.
pub fn score_coverage_standard_error() -> f64 {
    (NOMINAL_COVERAGE * (1.0 - NOMINAL_COVERAGE) / SCORE_COVERAGE_REPLICATIONS as f64).sqrt()
}

fn within_monte_carlo_error(c: &ScoreCoverageCell) -> bool {
    c.coverage() >= NOMINAL_COVERAGE - MONTE_CARLO_TOLERANCE * score_coverage_standard_error()
}

/// The fewest initial states from which every measured cell (of as many
/// states or more) covers within Monte-Carlo error of the nominal 95 %: 30
/// with the figures of [`SCORE_COVERAGE_MEASURED`]. A score from fewer
/// carries a [`ScoreCoverage`] label.
pub fn score_coverage_min_states() -> usize {
    let mut states: Vec<usize> = SCORE_COVERAGE_MEASURED.iter().map(|c| c.states).collect();
    states.sort_unstable();
    states.dedup();
    states
        .iter()
        .copied()
        .find(|&n| {
            SCORE_COVERAGE_MEASURED
                .iter()
                .filter(|c| c.states >= n)
                .all(within_monte_carlo_error)
        })
        .unwrap_or(usize::MAX)
}

/// A robustness score's interval whose measured coverage is below the
/// nominal 95 %: the label its row carries on the pages, in the API and in
/// the tables (docs/intervals.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScoreCoverage {
    /// Initial states behind the score.
    pub states: usize,
    /// The fewest and most initial states of the measured cells it is read
    /// against (the measured state counts nearest to `states`).
    pub measured_states: [usize; 2],
    /// The lowest and highest coverage of those cells.
    pub measured_coverage: [f64; 2],
    pub nominal: f64,
    /// The Monte-Carlo standard error of one measured cell.
    pub monte_carlo_standard_error: f64,
    /// From this many initial states on the measured coverage is within
    /// Monte-Carlo error of the nominal: no label.
    pub min_states: usize,
    /// What pages and tables print.
    pub label: String,
}

fn percent(c: f64) -> String {
    format!("{:.0}", (c * 100.0).round())
}

fn percent_range(lo: f64, hi: f64) -> String {
    if percent(lo) == percent(hi) {
        format!("{} %", percent(lo))
    } else {
        format!("{}–{} %", percent(lo), percent(hi))
    }
}

fn states_range(lo: usize, hi: usize) -> String {
    if lo == hi {
        format!("{lo}")
    } else {
        format!("{lo}–{hi}")
    }
}

/// The label of a robustness score computed from `states` initial states, or
/// None from [`score_coverage_min_states`] on. Its figures are those of the
/// measured cells nearest to `states` below that threshold: the cells of
/// `states` itself, of the measured counts on either side of it, or of the
/// nearest one when `states` is outside them.
pub fn score_coverage(states: usize) -> Option<ScoreCoverage> {
    let min_states = score_coverage_min_states();
    if states >= min_states {
        return None;
    }
    let below: Vec<&ScoreCoverageCell> = SCORE_COVERAGE_MEASURED
        .iter()
        .filter(|c| c.states < min_states)
        .collect();
    let under = below
        .iter()
        .map(|c| c.states)
        .filter(|&n| n <= states)
        .max();
    let over = below
        .iter()
        .map(|c| c.states)
        .filter(|&n| n >= states)
        .min();
    let (lo_states, hi_states) = match (under, over) {
        (Some(a), Some(b)) => (a, b),
        (Some(a), None) => (a, a),
        (None, Some(b)) => (b, b),
        // No measured cell below the threshold: nothing to read it against.
        (None, None) => return None,
    };
    let cells: Vec<f64> = below
        .iter()
        .filter(|c| (lo_states..=hi_states).contains(&c.states))
        .map(|c| c.coverage())
        .collect();
    let lo = cells.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = cells.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let measured = percent_range(lo, hi);
    let grid = states_range(lo_states, hi_states);
    let place = match (under, over) {
        (Some(a), Some(b)) if a == b => String::new(),
        (Some(_), Some(_)) => format!(" with {grid} initial states"),
        (None, _) => format!(" with {grid} initial states (fewer not measured)"),
        (_, None) => format!(
            " with {grid} initial states (within Monte-Carlo error of {} % from {min_states})",
            percent(NOMINAL_COVERAGE)
        ),
    };
    let label = format!(
        "from {states} initial state{}: measured coverage {measured}{place}, below the nominal {} %",
        if states == 1 { "" } else { "s" },
        percent(NOMINAL_COVERAGE)
    );
    Some(ScoreCoverage {
        states,
        measured_states: [lo_states, hi_states],
        measured_coverage: [lo, hi],
        nominal: NOMINAL_COVERAGE,
        monte_carlo_standard_error: score_coverage_standard_error(),
        min_states,
        label,
    })
}

/// One sentence on the scores' measured coverage for the notes of the
/// Robustness view and the tables: which rows are labelled and why.
pub fn score_coverage_note() -> String {
    let min_states = score_coverage_min_states();
    let (below, above): (Vec<&ScoreCoverageCell>, Vec<&ScoreCoverageCell>) =
        SCORE_COVERAGE_MEASURED
            .iter()
            .partition(|c| c.states < min_states);
    let range = |cells: &[&ScoreCoverageCell]| {
        let lo = cells
            .iter()
            .map(|c| c.coverage())
            .fold(f64::INFINITY, f64::min);
        let hi = cells
            .iter()
            .map(|c| c.coverage())
            .fold(f64::NEG_INFINITY, f64::max);
        let s_lo = cells.iter().map(|c| c.states).min().unwrap_or(0);
        let s_hi = cells.iter().map(|c| c.states).max().unwrap_or(0);
        format!(
            "{} with {} initial states",
            percent_range(lo, hi),
            states_range(s_lo, s_hi)
        )
    };
    format!(
        "measured coverage (`d3il bench intervals`, {} datasets a cell, Monte-Carlo standard error {:.1} points): {}, {}; rows from fewer than {min_states} initial states are labelled with theirs",
        SCORE_COVERAGE_REPLICATIONS,
        score_coverage_standard_error() * 100.0,
        range(&below),
        range(&above),
    )
}

#[cfg(test)]
mod score_coverage_tests {
    use super::*;

    #[test]
    fn scores_from_fewer_than_30_states_are_labelled_with_the_benchs_figures() {
        assert_eq!(score_coverage_min_states(), 30);
        assert_eq!(score_coverage(30), None);
        assert_eq!(score_coverage(60), None);
        assert_eq!(score_coverage(480), None);
        let three = score_coverage(3).expect("3 states: labelled");
        assert_eq!(
            three.label,
            "from 3 initial states: measured coverage 66–74 %, below the nominal 95 %"
        );
        assert_eq!(three.measured_coverage, [0.662, 0.735]);
        let ten = score_coverage(10).unwrap();
        assert_eq!(ten.measured_coverage, [0.9, 0.907]);
        assert_eq!(
            score_coverage(5).unwrap().label,
            "from 5 initial states: measured coverage 66–91 % with 3–10 initial states, below the nominal 95 %"
        );
        assert_eq!(
            score_coverage(1).unwrap().label,
            "from 1 initial state: measured coverage 66–74 % with 3 initial states (fewer not measured), below the nominal 95 %"
        );
        let twenty = score_coverage(29).unwrap();
        assert_eq!(twenty.measured_states, [10, 10]);
        assert!(twenty.label.contains("from 30"), "{}", twenty.label);
        // The threshold is where the figures say: every cell from 30 states
        // within 3 standard errors (1.1 points each), every 10-state cell not.
        assert!((score_coverage_standard_error() - 0.0109).abs() < 1e-4);
        assert!(SCORE_COVERAGE_MEASURED
            .iter()
            .filter(|c| c.states == 10)
            .all(|c| !within_monte_carlo_error(c)));
    }

    #[test]
    fn the_note_names_both_ranges_and_the_threshold() {
        let n = score_coverage_note();
        assert!(n.contains("66–91 % with 3–10 initial states"), "{n}");
        assert!(n.contains("93–96 % with 30–60 initial states"), "{n}");
        assert!(n.contains("fewer than 30 initial states"), "{n}");
        assert!(n.contains("1.1 points"), "{n}");
    }
}
