//! Monte Carlo coverage of the intervals the service prints (`d3il bench
//! intervals`): the success-rate and paired-difference intervals
//! (`crate::intervals`, `crate::rate_difference`) next to the ones the
//! service printed up to 0.4 (`crate::bootstrap`'s bias-corrected two-stage
//! bootstrap, the paired bias-corrected bootstrap), and the entropies' and
//! robustness scores' bootstrap intervals, which 0.5 kept.
//!
//! **Model.** Initial states differ: half of them (at random) succeed with
//! probability `p + h`, the others with `p − h`, `h = 0.8·min(p, 1 − p)`,
//! so the expected rate over fresh states is `p`, the quantity every
//! interval is for. Each state's rollouts are independent given its rate.
//! Paired: policy B on the same state succeeds with probability `r` times
//! A's (A and B correlated through the state), the true difference
//! A − B is `p(1 − r)`; `r = 1` is two exchangeable policies (difference 0,
//! the null the p-value tests). Two samples: one initial state (Avoiding),
//! A's rollouts succeed with probability `p`, B's with `r·p`.
//! Entropies ([`simulate_entropy_cell`]) and robustness scores
//! ([`simulate_score_cell`]) have models of their own, below.

use crate::bootstrap::success_rate_before_0_5;
use crate::compare::{compare_states, ContextSummary};
use crate::intervals::{success_rate_interval, StateCount};
use crate::rate_difference::ScoreTwoSample;
use crate::robustness::robustness_scores;
use crate::{
    behaviour_entropy, bootstrap_all, conditional_entropy, success_rate, Bootstrap, EmptyContexts,
    EntropyConvention, Outcome,
};
use d3il_protocol::ContextResult;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What is simulated in one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Design {
    /// One policy's success rate.
    Single,
    /// A − B on the same states, B's state rate `ratio` times A's.
    Paired { ratio: f64 },
    /// A − B on one initial state (`states` is 1), B's rate `ratio` times
    /// A's: the rollouts as two samples.
    TwoSample { ratio: f64 },
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
            Design::Paired { ratio } | Design::TwoSample { ratio } => self.rate * (1.0 - ratio),
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
        if let Design::TwoSample { ratio } = cell.design {
            // One state, no state-to-state variation: each arm's rollouts
            // are independent trials of its rate.
            let (ka, kb) = (draw(&mut rng, cell.rate), draw(&mut rng, ratio * cell.rate));
            let t = ScoreTwoSample::new(ka as u64, m as u64, kb as u64, m as u64);
            let i = t.interval(confidence);
            out.new_given += 1;
            out.new_covered += i.contains(truth) as usize;
            out.new_width_sum += i.width();
            out.new_zero_width += (i.width() <= 0.0) as usize;
            out.new_disagree += (i.contains(0.0) == (t.p_value(0.0) <= alpha)) as usize;
            // Up to 0.4: a paired bootstrap over one state, the point [d, d].
            let d = (ka as f64 - kb as f64) / m as f64;
            out.current_covered += (d == truth) as usize;
            out.current_zero_width += 1;
            out.current_disagree += (d != 0.0) as usize;
            continue;
        }
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
                let e = success_rate_before_0_5(&outcomes, &cfg);
                out.current_covered += (e.ci_low <= truth && truth <= e.ci_high) as usize;
                out.current_width_sum += e.ci_high - e.ci_low;
                out.current_zero_width += (e.ci_high <= e.ci_low) as usize;
            }
            Design::Paired { ratio } => {
                let b: Vec<u32> = q.iter().map(|&x| draw(&mut rng, ratio * x)).collect();
                // Each state's rate as its own "entropy", compared under
                // the rule that drops states without one (none is dropped):
                // `compare_states` then gives the 0.4 paired bootstrap and
                // its swap test for it, beside the success rate's test.
                let summary = |k: &[u32]| -> Vec<ContextSummary> {
                    k.iter()
                        .map(|&k| {
                            let x = k as f64 / m as f64;
                            ContextSummary {
                                success_rate: x,
                                entropy: Some(x),
                            }
                        })
                        .collect()
                };
                let [new, cur] = compare_states(
                    &summary(&a),
                    &summary(&b),
                    cell.rollouts,
                    EmptyContexts::Drop,
                    &cfg,
                )
                .expect("paired simulated states");
                if let Some((lo, hi)) = new.difference.interval() {
                    out.new_given += 1;
                    out.new_covered += (lo <= truth && truth <= hi) as usize;
                    out.new_width_sum += hi - lo;
                    out.new_zero_width += (hi <= lo) as usize;
                    let excludes = !(lo <= 0.0 && 0.0 <= hi);
                    out.new_disagree += (excludes != (new.p_value <= alpha)) as usize;
                }
                let e = cur.difference;
                out.current_covered += (e.ci_low <= truth && truth <= e.ci_high) as usize;
                out.current_width_sum += e.ci_high - e.ci_low;
                out.current_zero_width += (e.ci_high <= e.ci_low) as usize;
                let excludes = !(e.ci_low <= 0.0 && 0.0 <= e.ci_high);
                out.current_disagree += (excludes != (cur.p_value < alpha)) as usize;
            }
            Design::TwoSample { .. } => unreachable!("simulated above"),
        }
    }
    out
}

/// One kind of initial state: success probability and the behaviour
/// distribution of its successes.
#[derive(Debug, Clone, PartialEq)]
pub struct Kind {
    pub success: f64,
    pub behaviours: Vec<f64>,
}

/// An index drawn from the distribution `p`.
pub fn draw_index(rng: &mut ChaCha8Rng, p: &[f64]) -> usize {
    let u: f64 = rng.random();
    let mut acc = 0.0;
    for (i, x) in p.iter().enumerate() {
        acc += x;
        if u < acc {
            return i;
        }
    }
    p.len() - 1
}

/// A dataset: `n_ctx` states, each of a kind drawn uniformly, `per_ctx`
/// rollouts each.
pub fn simulate(
    rng: &mut ChaCha8Rng,
    kinds: &[Kind],
    n_ctx: usize,
    per_ctx: usize,
) -> Vec<Outcome> {
    let mut v = Vec::with_capacity(n_ctx * per_ctx);
    for c in 0..n_ctx {
        let k = &kinds[rng.random_range(0..kinds.len() as u64) as usize];
        for _ in 0..per_ctx {
            let success = rng.random_bool(k.success);
            let b = draw_index(rng, &k.behaviours).to_string();
            v.push(Outcome::new(c, success, Some(&b)));
        }
    }
    v
}

/// The values the estimates target: each statistic's expectation under the
/// protocol (states drawn from the population, `per_ctx` rollouts each), by
/// Monte Carlo over `runs` independent datasets. For the success rate it is
/// the population rate; for an entropy it is what the reference's plug-in
/// formula gives on average at this protocol size, the quantity the paper's
/// numbers estimate too (it lies below the entropy of the behaviour
/// distribution itself, which no protocol with 8–18 rollouts per state
/// reports).
pub fn truth(
    kinds: &[Kind],
    conv: &EntropyConvention,
    n_ctx: usize,
    per_ctx: usize,
    runs: usize,
) -> [f64; 3] {
    let mut rng = ChaCha8Rng::seed_from_u64(1_000_003);
    let mut sum = [0.0; 3];
    for _ in 0..runs {
        let d = simulate(&mut rng, kinds, n_ctx, per_ctx);
        sum[0] += success_rate(&d);
        sum[1] += behaviour_entropy(&d, conv.n_behaviours).unwrap_or(0.0);
        sum[2] += conditional_entropy(&d, conv).unwrap_or(0.0);
    }
    sum.map(|x| x / runs as f64)
}

/// Coverage of one statistic's interval over the replications of a cell.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Covered {
    pub reps: usize,
    pub covered: usize,
    pub width_sum: f64,
    pub zero_width: usize,
}

impl Covered {
    fn add(&mut self, lo: f64, hi: f64, truth: f64) {
        self.reps += 1;
        self.covered += (lo <= truth && truth <= hi) as usize;
        self.width_sum += hi - lo;
        self.zero_width += (hi <= lo) as usize;
    }
    pub fn coverage(&self) -> f64 {
        self.covered as f64 / self.reps.max(1) as f64
    }
    pub fn mean_width(&self) -> f64 {
        self.width_sum / self.reps.max(1) as f64
    }
}

/// Coverage of the behaviour and conditional entropies' intervals (the
/// two-stage bias-corrected bootstrap of [`bootstrap_all`]) of datasets of
/// `kinds` under `conv`, `n_ctx` states × `per_ctx` rollouts, of the value
/// they are for: the statistic's expectation at this size ([`truth`], over
/// `truth_runs` datasets). Returns (behaviour, conditional) and that value.
#[allow(clippy::too_many_arguments)]
pub fn simulate_entropy_cell(
    kinds: &[Kind],
    conv: &EntropyConvention,
    n_ctx: usize,
    per_ctx: usize,
    reps: usize,
    resamples: usize,
    truth_runs: usize,
    seed: u64,
) -> ([Covered; 2], [f64; 2]) {
    let t = truth(kinds, conv, n_ctx, per_ctx, truth_runs);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = [Covered::default(); 2];
    for rep in 0..reps {
        let data = simulate(&mut rng, kinds, n_ctx, per_ctx);
        let cfg = Bootstrap {
            resamples,
            confidence: 0.95,
            seed: rep as u64,
        };
        let [_, be, ce] = bootstrap_all(&data, &cfg, conv).expect("a simulated evaluation");
        out[0].add(be.ci_low, be.ci_high, t[1]);
        out[1].add(ce.ci_low, ce.ci_high, t[2]);
    }
    (out, [t[1], t[2]])
}

/// Coverage of a robustness score's interval ([`robustness_scores`]: the
/// paired bootstrap over states, bias-corrected) for one axis of `levels`
/// levels, on `n_ctx` states × `per_ctx` rollouts of the state model above
/// at rate `rate` (level 0), level `l` (1-based) at `ratio^l` times level
/// 0's rate on each state. Returns the coverage of the score's expectation
/// at this size (what the interval is for; by Monte Carlo over `truth_runs`
/// datasets), of the population's score (the mean of `ratio^l`, what no
/// finite protocol measures), and the two values.
#[allow(clippy::too_many_arguments)]
pub fn simulate_score_cell(
    rate: f64,
    ratio: f64,
    levels: usize,
    n_ctx: usize,
    per_ctx: usize,
    reps: usize,
    resamples: usize,
    truth_runs: usize,
    seed: u64,
) -> ([Covered; 2], [f64; 2]) {
    let h = 0.8 * rate.min(1.0 - rate);
    let m = per_ctx as u32;
    let dataset = |rng: &mut ChaCha8Rng| -> Vec<Vec<ContextResult>> {
        let q: Vec<f64> = (0..n_ctx)
            .map(|_| {
                if rng.random_bool(0.5) {
                    rate + h
                } else {
                    rate - h
                }
            })
            .collect();
        (0..=levels)
            .map(|l| {
                q.iter()
                    .enumerate()
                    .map(|(i, &x)| {
                        let p = x * ratio.powi(l as i32);
                        let k = (0..m).filter(|_| rng.random_bool(p)).count();
                        ContextResult {
                            context_index: i,
                            success_rate: k as f64 / m as f64,
                            conditional_entropy: 0.0,
                            behaviours: vec![],
                        }
                    })
                    .collect()
            })
            .collect()
    };
    let score = |d: &[Vec<ContextResult>], cfg: &Bootstrap| {
        let lv: Vec<(usize, &[ContextResult])> = d[1..].iter().map(|l| (0, &l[..])).collect();
        robustness_scores(&d[0], &lv, 1, cfg)
            .expect("a simulated suite")
            .axes[0]
    };
    let none = Bootstrap {
        resamples: 0,
        confidence: 0.95,
        seed: 0,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5C0E);
    let (mut sum, mut scored) = (0.0, 0usize);
    for _ in 0..truth_runs {
        if let Some(e) = score(&dataset(&mut rng), &none) {
            sum += e.value;
            scored += 1;
        }
    }
    let at_size = sum / scored.max(1) as f64;
    let population = (1..=levels).map(|l| ratio.powi(l as i32)).sum::<f64>() / levels as f64;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = [Covered::default(); 2];
    for rep in 0..reps {
        let cfg = Bootstrap {
            resamples,
            confidence: 0.95,
            seed: rep as u64,
        };
        // A suite whose level 0 never succeeded has no score (and prints none).
        if let Some(e) = score(&dataset(&mut rng), &cfg) {
            out[0].add(e.ci_low, e.ci_high, at_size);
            out[1].add(e.ci_low, e.ci_high, population);
        }
    }
    (out, [at_size, population])
}
