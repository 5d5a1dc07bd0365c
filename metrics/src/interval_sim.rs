//! Monte Carlo coverage of the success-rate and paired-difference intervals
//! (`crate::intervals`) next to the ones the service prints today
//! (`crate::bootstrap`'s bias-corrected two-stage bootstrap and
//! `crate::compare::compare_states`' paired bootstrap), for `d3il bench
//! intervals`.
//!
//! **Model.** Initial states differ: half of them (at random) succeed with
//! probability `p + h`, the others with `p − h`, `h = 0.8·min(p, 1 − p)`,
//! so the expected rate over fresh states is `p`, the quantity every
//! interval is for. Each state's rollouts are independent given its rate.
//! Paired: policy B on the same state succeeds with probability `r` times
//! A's (A and B correlated through the state), the true difference
//! A − B is `p(1 − r)`; `r = 1` is two exchangeable policies (difference 0,
//! the null the p-value tests).

use crate::compare::{compare_states, ContextSummary};
use crate::intervals::{paired_difference_interval, success_rate_interval, StateCount};
use crate::{bootstrap, Bootstrap, EmptyContexts, Outcome, Statistic};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What is simulated in one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Design {
    /// One policy's success rate.
    Single,
    /// A − B on the same states, B's state rate `ratio` times A's.
    Paired { ratio: f64 },
}

/// One cell of the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    pub rate: f64,
    pub states: usize,
    pub rollouts: usize,
    pub design: Design,
}

impl Cell {
    /// The true value the intervals are for.
    pub fn truth(&self) -> f64 {
        match self.design {
            Design::Single => self.rate,
            Design::Paired { ratio } => self.rate * (1.0 - ratio),
        }
    }
}

/// What the replications of one cell showed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CellCoverage {
    pub reps: usize,
    /// Replications the new method gave an interval for.
    pub new_given: usize,
    pub new_covered: usize,
    pub new_width_sum: f64,
    /// New intervals of width 0 (only the flagged degenerate kind).
    pub new_zero_width: usize,
    /// Paired: new interval excludes 0 but p > α, or the reverse.
    pub new_disagree: usize,
    pub current_covered: usize,
    pub current_width_sum: f64,
    pub current_zero_width: usize,
    pub current_disagree: usize,
}

impl CellCoverage {
    /// Coverage of the new method among the replications it gave an
    /// interval for (`None`: it never did).
    pub fn new_coverage(&self) -> Option<f64> {
        (self.new_given > 0).then(|| self.new_covered as f64 / self.new_given as f64)
    }
    pub fn current_coverage(&self) -> f64 {
        self.current_covered as f64 / self.reps as f64
    }
}

/// Simulates `reps` replications of `cell` at level `confidence`, both
/// methods with `resamples` (bootstrap resamples, Monte-Carlo sign vectors).
pub fn simulate_cell(
    cell: &Cell,
    reps: usize,
    resamples: usize,
    confidence: f64,
    seed: u64,
) -> CellCoverage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let alpha = 1.0 - confidence;
    let h = 0.8 * cell.rate.min(1.0 - cell.rate);
    let truth = cell.truth();
    let cfg = Bootstrap {
        resamples,
        confidence,
        seed: 0,
    };
    let mut out = CellCoverage {
        reps,
        ..Default::default()
    };
    let m = cell.rollouts as u32;
    let draw = |rng: &mut ChaCha8Rng, q: f64| (0..m).filter(|_| rng.random_bool(q)).count() as u32;
    for rep in 0..reps {
        let q: Vec<f64> = (0..cell.states)
            .map(|_| {
                if rng.random_bool(0.5) {
                    cell.rate + h
                } else {
                    cell.rate - h
                }
            })
            .collect();
        let a: Vec<u32> = q.iter().map(|&x| draw(&mut rng, x)).collect();
        let cfg = Bootstrap {
            seed: rep as u64,
            ..cfg
        };
        match cell.design {
            Design::Single => {
                let states: Vec<StateCount> = a.iter().map(|&k| StateCount::new(k, m)).collect();
                if let Ok(i) = success_rate_interval(&states, confidence, resamples, rep as u64) {
                    out.new_given += 1;
                    out.new_covered += i.contains(truth) as usize;
                    out.new_width_sum += i.width();
                    out.new_zero_width += (i.width() <= 0.0) as usize;
                }
                let outcomes: Vec<Outcome> = a
                    .iter()
                    .enumerate()
                    .flat_map(|(s, &k)| (0..m).map(move |j| Outcome::new(s, j < k, None)))
                    .collect();
                let e = bootstrap(&outcomes, &cfg, Statistic::SuccessRate)
                    .expect("a simulated evaluation has outcomes");
                out.current_covered += (e.ci_low <= truth && truth <= e.ci_high) as usize;
                out.current_width_sum += e.ci_high - e.ci_low;
                out.current_zero_width += (e.ci_high <= e.ci_low) as usize;
            }
            Design::Paired { ratio } => {
                let b: Vec<u32> = q.iter().map(|&x| draw(&mut rng, ratio * x)).collect();
                let ra: Vec<f64> = a.iter().map(|&k| k as f64 / m as f64).collect();
                let rb: Vec<f64> = b.iter().map(|&k| k as f64 / m as f64).collect();
                let new = paired_difference_interval(&ra, &rb, confidence, resamples, rep as u64);
                if let Ok(i) = new.interval {
                    out.new_given += 1;
                    out.new_covered += i.contains(truth) as usize;
                    out.new_width_sum += i.width();
                    out.new_zero_width += (i.width() <= 0.0) as usize;
                    let excludes = !i.contains(0.0);
                    out.new_disagree += (excludes != (new.p_value <= alpha)) as usize;
                }
                let summary = |r: &[f64]| -> Vec<ContextSummary> {
                    r.iter()
                        .map(|&x| ContextSummary {
                            success_rate: x,
                            entropy: None,
                        })
                        .collect()
                };
                let [d, _] = compare_states(
                    &summary(&ra),
                    &summary(&rb),
                    EmptyContexts::CountAsZero,
                    &cfg,
                )
                .expect("paired simulated states");
                let e = d.difference;
                out.current_covered += (e.ci_low <= truth && truth <= e.ci_high) as usize;
                out.current_width_sum += e.ci_high - e.ci_low;
                out.current_zero_width += (e.ci_high <= e.ci_low) as usize;
                let excludes = !(e.ci_low <= 0.0 && 0.0 <= e.ci_high);
                out.current_disagree += (excludes != (d.p_value < alpha)) as usize;
            }
        }
    }
    out
}
