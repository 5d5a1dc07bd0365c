//! Bootstrap confidence intervals over initial states: the two-stage
//! resampling, the bias-corrected percentile interval, and the working form
//! (interned labels, reusable tallies) that keeps a resample free of
//! allocation.

use crate::quantile::percentile;
use crate::{
    behaviour_entropy, by_context, conditional_entropy, entropy_of_counts, pooled_entropy,
    success_rate, EmptyContexts, EntropyConvention, MetricsError, Outcome,
};
use d3il_protocol::{Estimate, IntervalMethod, NoInterval};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;

/// Bootstrap settings for confidence intervals over initial states.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bootstrap {
    pub resamples: usize,
    /// Two-sided confidence level, e.g. 0.95.
    pub confidence: f64,
    pub seed: u64,
}

impl Default for Bootstrap {
    fn default() -> Self {
        Bootstrap {
            resamples: 1000,
            confidence: 0.95,
            seed: 0,
        }
    }
}

impl Bootstrap {
    fn check(&self) -> Result<(), MetricsError> {
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(MetricsError::BadConfidence(self.confidence));
        }
        Ok(())
    }
}

/// One of the three reported statistics, for [`bootstrap`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Statistic {
    SuccessRate,
    /// [`behaviour_entropy`] with this log base.
    BehaviourEntropy {
        n_behaviours: usize,
    },
    /// [`conditional_entropy`] under this convention.
    ConditionalEntropy(EntropyConvention),
}

/// Rollouts with interned behaviour labels (ids in label order), grouped by
/// context: the bootstrap's working form, so a resample allocates nothing.
pub(crate) struct Compact {
    pub(crate) groups: Vec<Vec<(bool, Option<u32>)>>,
    pub(crate) n_labels: usize,
}

impl Compact {
    pub(crate) fn new(outcomes: &[Outcome]) -> Compact {
        let mut ids: BTreeMap<&str, u32> = BTreeMap::new();
        for o in outcomes {
            if let Some(b) = &o.behaviour {
                ids.insert(b.as_str(), 0);
            }
        }
        for (i, v) in ids.values_mut().enumerate() {
            *v = i as u32;
        }
        let groups = by_context(outcomes)
            .into_values()
            .map(|g| {
                g.iter()
                    .map(|o| (o.success, o.behaviour.as_deref().map(|b| ids[b])))
                    .collect()
            })
            .collect();
        Compact {
            groups,
            n_labels: ids.len(),
        }
    }
}

/// Scratch space for the three statistics of one (re)sample.
pub(crate) struct Tally {
    pub(crate) rollouts: usize,
    pub(crate) successes: usize,
    pub(crate) pooled: Vec<usize>,
    pub(crate) context: Vec<usize>,
    pub(crate) cond_sum: f64,
    pub(crate) cond_n: usize,
}

impl Tally {
    pub(crate) fn new(n_labels: usize) -> Tally {
        Tally {
            rollouts: 0,
            successes: 0,
            pooled: vec![0; n_labels],
            context: vec![0; n_labels],
            cond_sum: 0.0,
            cond_n: 0,
        }
    }

    pub(crate) fn clear(&mut self) {
        self.rollouts = 0;
        self.successes = 0;
        self.pooled.iter_mut().for_each(|c| *c = 0);
        self.cond_sum = 0.0;
        self.cond_n = 0;
    }

    /// Adds one context made of `rollouts` (yielded with repetition as drawn).
    pub(crate) fn add_context(
        &mut self,
        rollouts: impl Iterator<Item = (bool, Option<u32>)>,
        conv: &EntropyConvention,
    ) {
        self.context.iter_mut().for_each(|c| *c = 0);
        let mut n = 0;
        for (success, label) in rollouts {
            n += 1;
            if success {
                self.successes += 1;
                if let Some(l) = label {
                    self.context[l as usize] += 1;
                    self.pooled[l as usize] += 1;
                }
            }
        }
        self.rollouts += n;
        match entropy_of_counts(self.context.iter().copied(), n, conv) {
            Some(h) => {
                self.cond_sum += h;
                self.cond_n += 1;
            }
            None => {
                if conv.empty_contexts == EmptyContexts::CountAsZero {
                    self.cond_n += 1;
                }
            }
        }
    }

    /// (success rate, behaviour entropy, conditional entropy).
    pub(crate) fn stats(&self, conv: &EntropyConvention) -> [f64; 3] {
        let sr = if self.rollouts == 0 {
            0.0
        } else {
            self.successes as f64 / self.rollouts as f64
        };
        let cond = if self.cond_n == 0 {
            0.0
        } else {
            self.cond_sum / self.cond_n as f64
        };
        [
            sr,
            pooled_entropy(self.pooled.iter().copied(), conv.n_behaviours),
            cond,
        ]
    }
}

/// The success rate, the behaviour entropy and the conditional entropy (in
/// that order), each with its interval.
///
/// **Success rate**: [`crate::intervals::success_rate_estimate`] (
/// no interval under 5 initial states, Clopper–Pearson, Korn–Graubard or the
/// percentile cluster bootstrap by the rule documented there).
///
/// **Entropies**: a two-stage bootstrap. Resampling follows how the data
/// arose: the initial states are drawn with replacement (a state drawn twice
/// counts as two states), then within each drawn state its rollouts are drawn
/// with replacement. With a single initial state (Avoiding) only the second
/// stage varies. Deterministic for a given seed (ChaCha8, portable).
///
/// **What the entropy interval is for**: the statistic's expected value
/// under the protocol, i.e. what the same policy's plug-in entropy would be
/// on average over fresh initial states and rollout noise at this protocol's
/// size (8–18 rollouts per state, the quantity the paper's numbers estimate
/// as well), which lies below the entropy of the behaviour distribution
/// itself. It is not an interval for that entropy.
///
/// **Interval**: resampling rollouts makes the plug-in entropies lower still
/// (a resample of n rollouts from n observed ones shows fewer distinct
/// behaviours), so the bootstrap distribution sits below the estimate and its
/// plain percentiles can exclude it (Avoiding's quick protocol printed 0.654
/// with 0.340–0.600). We use the bias-corrected percentile interval: the
/// percentiles of the resampled statistic moved by the bootstrap's estimate of
/// that bias, `[q(α/2) − b, q(1 − α/2) − b]` with `b = mean(θ*) − θ̂`. It is
/// widened to include the estimate should Monte Carlo noise leave it just
/// outside, and clipped to [0, 1] (entropies in log base `n_behaviours`).
/// **Where it does not hold**: with few initial states (a percentile
/// bootstrap over 3 states cannot cover; the success rate gives no interval
/// there, the entropies still print one, labelled by its method) and where
/// every resample shows one behaviour (width 0: a deterministic policy's
/// entropy is 0 by definition). Coverage on known distributions (≥ 93 % for a
/// 95 % interval, Aligning/Pushing/Sorting/Avoiding-like designs) is tested
/// in `interval_tests.rs`.
pub fn bootstrap_all(
    outcomes: &[Outcome],
    cfg: &Bootstrap,
    conv: &EntropyConvention,
) -> Result<[Estimate; 3], MetricsError> {
    if outcomes.is_empty() {
        return Err(MetricsError::NoOutcomes);
    }
    cfg.check()?;
    conv.check()?;
    // The success rate's interval is `intervals::success_rate_estimate`'s
    // (docs/intervals.md); the entropies keep the two-stage bootstrap below.
    let success = crate::intervals::success_rate_estimate(
        &crate::intervals::state_counts(outcomes.iter().map(|o| (o.context_index, o.success))),
        cfg.confidence,
        cfg.resamples,
        cfg.seed,
    );
    debug_assert_eq!(success.value, success_rate(outcomes));
    let values = [
        behaviour_entropy(outcomes, conv.n_behaviours)?,
        conditional_entropy(outcomes, conv)?,
    ];
    if cfg.resamples == 0 {
        let [b, c] = values.map(|v| Estimate::without_interval(v, NoInterval::NoResamples));
        return Ok([success, b, c]);
    }
    let stats = two_stage_resamples(outcomes, cfg, conv);
    // Both entropies lie in [0, 1] (log base `n_behaviours`, at most 1 while
    // the labels are the task's behaviours; the clip never excludes the
    // estimate itself). The bias correction can push an upper end past 1
    // (Aligning's quick protocol printed 0.492-1.492). The success rate's
    // resamples (`stats[0]`) are drawn to keep the entropies' stream as it
    // was, and not used.
    let [_, mut sb, mut sc] = stats;
    Ok([
        success,
        bias_corrected_interval(values[0], &mut sb, cfg.confidence, (0.0, 1.0)),
        bias_corrected_interval(values[1], &mut sc, cfg.confidence, (0.0, 1.0)),
    ])
}

/// The two-stage resamples (states, then rollouts within them) of the
/// success rate, behaviour entropy and conditional entropy.
fn two_stage_resamples(
    outcomes: &[Outcome],
    cfg: &Bootstrap,
    conv: &EntropyConvention,
) -> [Vec<f64>; 3] {
    let data = Compact::new(outcomes);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut tally = Tally::new(data.n_labels);
    let mut stats: [Vec<f64>; 3] = std::array::from_fn(|_| Vec::with_capacity(cfg.resamples));
    let n_groups = data.groups.len() as u64;
    let mut picks: Vec<(bool, Option<u32>)> = Vec::new();
    for _ in 0..cfg.resamples {
        tally.clear();
        for _ in 0..n_groups {
            // u64 ranges keep the stream identical on 32- and 64-bit hosts.
            let g = &data.groups[rng.random_range(0..n_groups) as usize];
            let n = g.len() as u64;
            picks.clear();
            picks.extend((0..n).map(|_| g[rng.random_range(0..n) as usize]));
            tally.add_context(picks.iter().copied(), conv);
        }
        for (s, v) in stats.iter_mut().zip(tally.stats(conv)) {
            s.push(v);
        }
    }
    stats
}

/// The success-rate interval every result carried up to 0.4: the two-stage
/// bootstrap's bias-corrected percentile interval. Kept only so that `d3il
/// bench intervals` can show what it covered beside this version's rule.
pub fn success_rate_before_0_5(outcomes: &[Outcome], cfg: &Bootstrap) -> Estimate {
    let conv = EntropyConvention {
        n_behaviours: 2,
        empty_contexts: EmptyContexts::CountAsZero,
        reference_guard: true,
    };
    let [mut sr, _, _] = two_stage_resamples(outcomes, cfg, &conv);
    bias_corrected_interval(success_rate(outcomes), &mut sr, cfg.confidence, (0.0, 1.0))
}

/// Bootstrap interval of one statistic; see [`bootstrap_all`] for the method.
pub fn bootstrap(
    outcomes: &[Outcome],
    cfg: &Bootstrap,
    stat: Statistic,
) -> Result<Estimate, MetricsError> {
    let (conv, i) = match stat {
        Statistic::SuccessRate => (
            EntropyConvention {
                n_behaviours: 2,
                empty_contexts: EmptyContexts::CountAsZero,
                reference_guard: true,
            },
            0,
        ),
        Statistic::BehaviourEntropy { n_behaviours } => (
            EntropyConvention {
                n_behaviours,
                empty_contexts: EmptyContexts::CountAsZero,
                reference_guard: true,
            },
            1,
        ),
        Statistic::ConditionalEntropy(conv) => (conv, 2),
    };
    Ok(bootstrap_all(outcomes, cfg, &conv)?[i])
}

/// The bias-corrected percentile interval of `value` from its resampled
/// values `stats` (sorted in place), widened to contain `value` and clipped to
/// `bounds`.
pub(crate) fn bias_corrected_interval(
    value: f64,
    stats: &mut [f64],
    confidence: f64,
    bounds: (f64, f64),
) -> Estimate {
    if stats.is_empty() {
        return Estimate::without_interval(value, NoInterval::NoResamples);
    }
    stats.sort_by(f64::total_cmp);
    let alpha = (1.0 - confidence) / 2.0;
    let bias = stats.iter().sum::<f64>() / stats.len() as f64 - value;
    let lo = percentile(stats, alpha) - bias;
    let hi = percentile(stats, 1.0 - alpha) - bias;
    Estimate::with_interval(
        value,
        lo.min(value).max(bounds.0.min(value)),
        hi.max(value).min(bounds.1.max(value)),
        IntervalMethod::BiasCorrectedBootstrap,
    )
}
