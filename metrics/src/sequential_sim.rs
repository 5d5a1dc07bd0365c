//! Monte Carlo of the sequential paired test (`crate::sequential`) for
//! `d3il bench sequential` and the property tests: what the test decides
//! depends only on the discordant pairs won by A and by B (and, with a
//! horizon, on whether the pair is the last), so simulations look it up in
//! a [`DecisionTable`].

use crate::horizon::CalibratedBoundary;
use crate::sequential::{e_value_decision, Decision};

/// What the sequential test decides for every `(w, l)` with
/// `w + l ≤ max_pairs`: [`e_value_decision`] (no horizon), or the
/// [`CalibratedBoundary`] of a horizon ([`Self::with_horizon`]). It depends
/// only on these counts (and, with a horizon, on whether the pair is the
/// last), so simulations look it up instead of recomputing it.
#[derive(Debug, Clone)]
pub struct DecisionTable {
    max_pairs: usize,
    cells: Vec<Vec<Option<Decision>>>,
    /// With a horizon: the boundary (its last look decides at pair N).
    boundary: Option<CalibratedBoundary>,
}

impl DecisionTable {
    /// The e-value rule (anytime-valid, no horizon) up to `max_pairs`.
    pub fn new(alpha: f64, max_pairs: usize) -> Self {
        let cells = (0..=max_pairs as u64)
            .map(|w| {
                (0..=(max_pairs as u64 - w))
                    .map(|l| e_value_decision(w, l, alpha))
                    .collect()
            })
            .collect();
        DecisionTable {
            max_pairs,
            cells,
            boundary: None,
        }
    }

    /// The boundary calibrated to a horizon of `horizon` pairs (which is
    /// also the most pairs a run goes on for).
    pub fn with_horizon(alpha: f64, horizon: usize) -> Self {
        let boundary = CalibratedBoundary::new(alpha, horizon);
        let cells = (0..=horizon as u64)
            .map(|w| {
                (0..=(horizon as u64 - w))
                    .map(|l| boundary.decide(w, l, false))
                    .collect()
            })
            .collect();
        DecisionTable {
            max_pairs: horizon,
            cells,
            boundary: Some(boundary),
        }
    }

    /// The decision at `(w, l)` before the last pair.
    pub fn get(&self, w: usize, l: usize) -> Option<Decision> {
        self.cells
            .get(w)
            .and_then(|row| row.get(l))
            .copied()
            .flatten()
    }

    /// The decision at `(w, l)` at pair `t`: with a horizon, its last look
    /// at `t = N`.
    pub fn at(&self, t: usize, w: usize, l: usize) -> Option<Decision> {
        match &self.boundary {
            Some(b) if t == b.horizon() => b.decide(w as u64, l as u64, true),
            _ => self.get(w, l),
        }
    }

    pub fn max_pairs(&self) -> usize {
        self.max_pairs
    }

    /// The horizon, when the table is calibrated to one.
    pub fn horizon(&self) -> Option<usize> {
        self.boundary.as_ref().map(|b| b.horizon())
    }
}

/// One simulated run of the sequential test: the pair it decided at and
/// what it decided, or `None` if it had not decided by the simulation's end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Run {
    pub pair: u32,
    pub decision: Option<Decision>,
}

/// What the runs of [`simulate`] show when each is stopped at `max_pairs`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Simulated {
    /// Share of runs that decided "A better".
    pub a_better: f64,
    /// Share that decided "B better".
    pub b_better: f64,
    /// Mean pairs used: the pair of the decision, or all `max_pairs`.
    pub mean_pairs: f64,
}

/// [`Simulated`] of `runs` truncated at `max_pairs`: a run that decides
/// later counts as undecided after `max_pairs` pairs.
pub fn truncate(runs: &[Run], max_pairs: u32) -> Simulated {
    let (mut a_better, mut b_better, mut used) = (0usize, 0usize, 0u64);
    for r in runs {
        match r.decision {
            Some(d) if r.pair <= max_pairs => {
                used += r.pair as u64;
                match d {
                    Decision::ABetter => a_better += 1,
                    Decision::BBetter => b_better += 1,
                    Decision::NoDifferenceLargerThan(_) => {}
                }
            }
            _ => used += max_pairs as u64,
        }
    }
    let n = runs.len().max(1) as f64;
    Simulated {
        a_better: a_better as f64 / n,
        b_better: b_better as f64 / n,
        mean_pairs: used as f64 / n,
    }
}

/// Monte Carlo of the sequential test (the table's rule; with a horizon,
/// its last look at pair N) on i.i.d. pairs A wins with probability `p10`
/// and B with `p01`, each run up to its decision or `max_pairs` pairs (at
/// most the table's): `runs` runs from a
/// ChaCha8 stream seeded with `seed`.
pub fn simulate(
    table: &DecisionTable,
    p10: f64,
    p01: f64,
    runs: usize,
    max_pairs: usize,
    seed: u64,
) -> Vec<Run> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let max_pairs = max_pairs.min(table.max_pairs);
    (0..runs)
        .map(|_| {
            let (mut w, mut l) = (0usize, 0usize);
            for t in 1..=max_pairs {
                let u: f64 = rng.random();
                if u < p10 {
                    w += 1;
                } else if u < p10 + p01 {
                    l += 1;
                } else if t < max_pairs || table.horizon().is_none() {
                    // Concordant: nothing moves (but the last look decides).
                    continue;
                }
                if let Some(d) = table.at(t, w, l) {
                    return Run {
                        pair: t as u32,
                        decision: Some(d),
                    };
                }
            }
            Run {
                pair: max_pairs as u32,
                decision: None,
            }
        })
        .collect()
}

/// One pair of outcomes with success rates `rate_a`, `rate_b` and a share
/// `discordance` of discordant pairs: the probabilities `(p10, p01)` that A
/// wins / B wins a pair. `discordance` is clamped to what the two rates
/// allow: at least `|rate_a − rate_b|`, at most
/// `min(rate_a + rate_b, 2 − rate_a − rate_b)`.
pub fn discordant_probabilities(rate_a: f64, rate_b: f64, discordance: f64) -> (f64, f64) {
    let diff = rate_a - rate_b;
    let most = (rate_a + rate_b).min(2.0 - rate_a - rate_b);
    let d = discordance.clamp(diff.abs(), most.max(diff.abs()));
    ((d + diff) / 2.0, (d - diff) / 2.0)
}

/// The share of discordant pairs when A and B succeed independently:
/// `a(1 − b) + b(1 − a)`.
pub fn independent_discordance(rate_a: f64, rate_b: f64) -> f64 {
    rate_a * (1.0 - rate_b) + rate_b * (1.0 - rate_a)
}
