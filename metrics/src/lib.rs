//! D3IL metrics as pure functions over per-rollout outcomes.
//!
//! The reference code computes the "entropy" differently per task, and the
//! leaderboard reproduces each variant exactly (see [`EntropyConvention`]):
//!
//! * Avoiding (docs/original-d3il.md §10.2.6): one start state; entropy over the codes of all
//!   successful rollouts, `-Σ p ln p / ln 24`, no numerical guard, every observed
//!   code counted (codes with a missed row are separate behaviours).
//! * Aligning, Pushing (docs/original-d3il.md §10.3.6, §10.4.6): per context
//!   `p = k / (Σk + N·1e-12)`, `H_c = -Σ p ln(p + 1e-12) / ln|B|`, averaged over
//!   **all** contexts; contexts without a (labelled) success contribute 0.
//! * Sorting, Stacking (docs/original-d3il.md §11.6) and Inserting (docs/original-d3il.md §11.3.6, assumed like
//!   Stacking-3): same per-context formula, but contexts without a counted success
//!   are **dropped** from the average.
//!
//! Unlabeled successes (`behaviour == None`, e.g. Pushing's mode −1 or a Sorting
//! code outside the mode set) count for the success rate but for no behaviour bin.
//!
//! Seed aggregation uses the **sample** standard deviation (ddof = 1): the paper's
//! Avoiding rows (BC-MLP 0.666 ± 0.512, BC-GPT 0.833 ± 0.408 over 6 seeds) exceed
//! the largest population std a mean of values in [0, 1] allows (0.472, 0.373)
//! and match the sample std (BC-GPT: five seeds at 1, one at 0 → 0.408).

#![forbid(unsafe_code)]

mod bootstrap;
pub mod compare;
pub mod horizon;
pub mod interval_sim;
pub mod intervals;
pub mod order;
mod quantile;
pub mod rate_difference;
pub mod recompute;
pub mod robustness;
pub mod sequential;
pub mod sequential_sim;
pub mod shard;
pub mod sign_test;
pub mod suite_shard;
pub(crate) use bootstrap::bias_corrected_interval;
pub use bootstrap::{bootstrap, bootstrap_all, Bootstrap, Statistic};
#[cfg(test)]
use bootstrap::{Compact, Tally};
pub use compare::{
    compare, compare_parts, compare_states, normal_quantile, wilson_interval, ContextSummary,
};
pub use d3il_protocol::StackingLevel;
use d3il_protocol::{ContextResult, Estimate, Metrics, Stat, TaskId};
use std::collections::BTreeMap;

/// What one rollout produced, as the metrics need it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Outcome {
    /// Index of the fixed initial state (0 for Avoiding).
    pub context_index: usize,
    /// Final success flag (Stacking: the full three-box stack, "Stacking-3").
    pub success: bool,
    /// Behaviour label in the reference encoding as a string key; `None` for a
    /// success the reference puts in no behaviour bin. Stacking: the letters
    /// `r`/`g`/`b` of the boxes registered so far, in order (docs/original-d3il.md §11.2.6), e.g.
    /// `"gbr"`, `"g"`, or `None`/`""` when none registered.
    pub behaviour: Option<String>,
}

impl Outcome {
    pub fn new(context_index: usize, success: bool, behaviour: Option<&str>) -> Self {
        Outcome {
            context_index,
            success,
            behaviour: behaviour.map(str::to_string),
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    #[error("no rollout outcomes were given; an evaluation needs at least one rollout")]
    NoOutcomes,
    #[error(
        "the entropy log base |B| is {0}; it must be at least 2 (number of behaviours of the task)"
    )]
    BadBehaviourCount(usize),
    #[error("stacking behaviour `{label}` of rollout {rollout} (context {context}) is not a registration order; expected up to three distinct letters from r, g, b (e.g. `gbr`)")]
    BadStackingLabel {
        label: String,
        rollout: usize,
        context: usize,
    },
    #[error("bootstrap confidence level {0} is outside (0, 1); use e.g. 0.95")]
    BadConfidence(f64),
    #[error("seed aggregation needs at least one value")]
    NoSeeds,
    #[error("the two results cannot be compared: {0}")]
    NotComparable(String),
    /// Rollout records that do not fit together (e.g. one behaviour key per record).
    #[error("inconsistent rollout records: {0}")]
    Records(String),
}

/// How contexts without any labelled success enter the conditional entropy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EmptyContexts {
    /// Counted with H_c = 0 (Avoiding, Aligning, Pushing; docs/original-d3il.md §10.6.3).
    CountAsZero,
    /// Dropped from the average (Sorting, Stacking, Inserting; docs/original-d3il.md §11.6).
    Drop,
}

/// The reference's per-task way of computing the conditional entropy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EntropyConvention {
    /// Log base |B|.
    pub n_behaviours: usize,
    pub empty_contexts: EmptyContexts,
    /// Whether the reference's 1e-12 guards are applied
    /// (`p = k/(Σk + N·1e-12)`, `ln(p + 1e-12)`); Avoiding's code has none.
    pub reference_guard: bool,
}

impl EntropyConvention {
    /// The convention the reference uses for `task` (for Stacking: Stacking-3,
    /// see [`stacking_levels`] for the other two levels).
    pub fn for_task(task: TaskId) -> Self {
        let n_behaviours = task.n_behaviours();
        match task {
            TaskId::Avoiding => EntropyConvention {
                n_behaviours,
                empty_contexts: EmptyContexts::CountAsZero,
                reference_guard: false,
            },
            TaskId::Aligning | TaskId::Pushing => EntropyConvention {
                n_behaviours,
                empty_contexts: EmptyContexts::CountAsZero,
                reference_guard: true,
            },
            TaskId::Sorting2
            | TaskId::Sorting4
            | TaskId::Sorting6
            | TaskId::Stacking
            | TaskId::Inserting => EntropyConvention {
                n_behaviours,
                empty_contexts: EmptyContexts::Drop,
                reference_guard: true,
            },
        }
    }

    fn check(&self) -> Result<(), MetricsError> {
        if self.n_behaviours < 2 {
            return Err(MetricsError::BadBehaviourCount(self.n_behaviours));
        }
        Ok(())
    }
}

/// Fraction of successful rollouts over all rollouts (failures and timeouts are 0).
pub fn success_rate(outcomes: &[Outcome]) -> f64 {
    if outcomes.is_empty() {
        return 0.0;
    }
    outcomes.iter().filter(|o| o.success).count() as f64 / outcomes.len() as f64
}

/// Counts of each behaviour label among the labelled successful rollouts.
pub fn behaviour_counts<'a>(
    outcomes: impl IntoIterator<Item = &'a Outcome>,
) -> BTreeMap<String, usize> {
    let mut counts = BTreeMap::new();
    for o in outcomes {
        if let (true, Some(b)) = (o.success, &o.behaviour) {
            *counts.entry(b.clone()).or_insert(0) += 1;
        }
    }
    counts
}

/// H(π(β)): entropy of the behaviour distribution pooled over all labelled
/// successful rollouts, log base `n_behaviours`; 0 without any.
/// Equals the reference's Avoiding entropy (docs/original-d3il.md §10.2.6); the reference computes
/// no marginal entropy for the other tasks, this is the natural pooling
/// (docs/original-d3il.md §11.6 last item).
pub fn behaviour_entropy(outcomes: &[Outcome], n_behaviours: usize) -> Result<f64, MetricsError> {
    if n_behaviours < 2 {
        return Err(MetricsError::BadBehaviourCount(n_behaviours));
    }
    Ok(pooled_entropy(
        behaviour_counts(outcomes).values().copied(),
        n_behaviours,
    ))
}

/// Plug-in entropy of behaviour counts, log base `n_behaviours` (>= 2); 0
/// without any count. Zero counts are skipped.
fn pooled_entropy(counts: impl Iterator<Item = usize> + Clone, n_behaviours: usize) -> f64 {
    let total: usize = counts.clone().sum();
    if total == 0 {
        return 0.0;
    }
    let ln_b = (n_behaviours as f64).ln();
    let h: f64 = counts
        .filter(|&n| n > 0)
        .map(|n| {
            let p = n as f64 / total as f64;
            -p * p.ln()
        })
        .sum();
    // A single behaviour sums to -0.0 (-1 * ln 1); report it as 0.
    if h > 0.0 {
        h / ln_b
    } else {
        0.0
    }
}

/// Entropy of one context as the reference computes it; `None` when the context
/// has no labelled success (the caller's [`EmptyContexts`] rule decides).
fn context_entropy(
    counts: &BTreeMap<String, usize>,
    n_rollouts: usize,
    conv: &EntropyConvention,
) -> Option<f64> {
    entropy_of_counts(counts.values().copied(), n_rollouts, conv)
}

/// [`context_entropy`] over bare counts (zero counts skipped), in the order given.
fn entropy_of_counts(
    counts: impl Iterator<Item = usize> + Clone,
    n_rollouts: usize,
    conv: &EntropyConvention,
) -> Option<f64> {
    let k: usize = counts.clone().sum();
    if k == 0 {
        return None;
    }
    let counts = counts.filter(|&c| c > 0);
    let ln_b = (conv.n_behaviours as f64).ln();
    let h: f64 = if conv.reference_guard {
        // (k/N) / (Σk/N + 1e-12), then -p ln(p + 1e-12): docs/original-d3il.md §10.3.6, docs/original-d3il.md §11.6.
        let n = n_rollouts as f64;
        let denom = k as f64 / n + 1e-12;
        counts
            .map(|c| {
                let p = (c as f64 / n) / denom;
                -p * (p + 1e-12).ln()
            })
            .sum()
    } else {
        counts
            .map(|c| {
                let p = c as f64 / k as f64;
                -p * p.ln()
            })
            .sum()
    };
    Some(exact_zero(h / ln_b))
}

/// A context with one behaviour has entropy 0 by definition; the reference's
/// 1e-12 guards leave about -p ln(p + 1e-12) ≈ 1e-12 · ln 1 + ... ≈ 5e-17
/// there. Values that small are that residue, never an
/// entropy (the smallest non-zero entropy, one rollout of another behaviour
/// is above 0.001 for every task), and are reported as 0.
pub(crate) fn exact_zero(h: f64) -> f64 {
    if h.abs() < 1e-12 {
        0.0
    } else {
        h
    }
}

/// Outcomes grouped by context index (ascending).
fn by_context(outcomes: &[Outcome]) -> BTreeMap<usize, Vec<&Outcome>> {
    let mut m: BTreeMap<usize, Vec<&Outcome>> = BTreeMap::new();
    for o in outcomes {
        m.entry(o.context_index).or_default().push(o);
    }
    m
}

fn conditional_from_groups<'a>(
    groups: impl Iterator<Item = &'a [&'a Outcome]>,
    conv: &EntropyConvention,
) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for g in groups {
        match context_entropy(&behaviour_counts(g.iter().copied()), g.len(), conv) {
            Some(h) => {
                sum += h;
                n += 1;
            }
            None => {
                if conv.empty_contexts == EmptyContexts::CountAsZero {
                    n += 1;
                }
            }
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// E_s0[H(π(β|s0))] exactly as the reference computes it for the convention.
pub fn conditional_entropy(
    outcomes: &[Outcome],
    conv: &EntropyConvention,
) -> Result<f64, MetricsError> {
    conv.check()?;
    let groups = by_context(outcomes);
    Ok(conditional_from_groups(
        groups.values().map(|v| v.as_slice()),
        conv,
    ))
}

/// Per-context breakdown: success rate, the context's entropy (0 when it has no
/// labelled success) and its behaviour counts among successful rollouts.
pub fn per_context(
    outcomes: &[Outcome],
    conv: &EntropyConvention,
) -> Result<Vec<ContextResult>, MetricsError> {
    conv.check()?;
    Ok(by_context(outcomes)
        .into_iter()
        .map(|(c, g)| {
            let counts = behaviour_counts(g.iter().copied());
            let successes = g.iter().filter(|o| o.success).count();
            ContextResult {
                context_index: c,
                success_rate: successes as f64 / g.len() as f64,
                conditional_entropy: context_entropy(&counts, g.len(), conv).unwrap_or(0.0),
                behaviours: counts.into_iter().collect(),
            }
        })
        .collect())
}

/// The three Stacking levels (docs/original-d3il.md §11.2.5–11.2.7): level X ∈ {1, 2, 3} is a success
/// when at least X boxes registered (X = 1, 2, sticky proximity events) or on the
/// full stack (X = 3); its behaviour is the first X letters of the registration
/// order, log base 3 / 6 / 6. A rollout with fewer than X letters gets code 0
/// (`r`, `rg`, `rgb`) like the reference (docs/original-d3il.md §11.2.6); this only matters for a
/// full-stack success with fewer than three registrations.
pub fn stacking_levels(
    outcomes: &[Outcome],
) -> Result<[(Vec<Outcome>, EntropyConvention); 3], MetricsError> {
    for (i, o) in outcomes.iter().enumerate() {
        let s = o.behaviour.as_deref().unwrap_or("");
        let mut seen = [false; 3];
        let ok = s.len() <= 3
            && s.chars().all(|ch| {
                let idx = match ch {
                    'r' => 0,
                    'g' => 1,
                    'b' => 2,
                    _ => return false,
                };
                !std::mem::replace(&mut seen[idx], true)
            });
        if !ok {
            return Err(MetricsError::BadStackingLabel {
                label: s.to_string(),
                rollout: i,
                context: o.context_index,
            });
        }
    }
    let level = |x: usize| -> (Vec<Outcome>, EntropyConvention) {
        let code0 = &"rgb"[..x];
        let v = outcomes
            .iter()
            .map(|o| {
                let s = o.behaviour.as_deref().unwrap_or("");
                let success = if x == 3 { o.success } else { s.len() >= x };
                let label = if s.len() >= x { &s[..x] } else { code0 };
                Outcome {
                    context_index: o.context_index,
                    success,
                    behaviour: Some(label.to_string()),
                }
            })
            .collect();
        let conv = EntropyConvention {
            n_behaviours: if x == 1 { 3 } else { 6 },
            empty_contexts: EmptyContexts::Drop,
            reference_guard: true,
        };
        (v, conv)
    };
    Ok([level(1), level(2), level(3)])
}

/// Everything one evaluation reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    pub metrics: Metrics,
    pub per_context: Vec<ContextResult>,
}

/// Build the protocol's [`Metrics`] and per-context breakdown for one evaluation.
/// For Stacking, `success_rate`/entropies in `Metrics` are Stacking-3's,
/// `stacking_levels` holds Stacking-1/2/3 each with its own success rate and
/// entropies, and `stacking` the three rates; see [`Outcome::behaviour`] for
/// the encoding.
pub fn evaluate(
    task: TaskId,
    outcomes: &[Outcome],
    inference_ms: f64,
    cfg: &Bootstrap,
) -> Result<Evaluation, MetricsError> {
    if outcomes.is_empty() {
        return Err(MetricsError::NoOutcomes);
    }
    if task == TaskId::Stacking {
        let levels = stacking_levels(outcomes)?;
        let mut out = Vec::with_capacity(3);
        for (x, (lv, conv)) in levels.iter().enumerate() {
            // Distinct bootstrap streams per level keep them independent yet
            // reproducible.
            let c = |k: u64| Bootstrap {
                seed: cfg.seed.wrapping_add(10 * x as u64 + k),
                ..*cfg
            };
            let [success_rate, behaviour_entropy, conditional_entropy] =
                bootstrap_all(lv, &c(0), conv)?;
            let success_rate = task_success(task, lv, &c(0)).unwrap_or(success_rate);
            out.push(StackingLevel {
                success_rate,
                conditional_entropy,
                behaviour_entropy,
            });
        }
        let levels_arr = [out[0], out[1], out[2]];
        let top = levels_arr[2];
        return Ok(Evaluation {
            metrics: Metrics {
                success_rate: top.success_rate,
                behaviour_entropy: top.behaviour_entropy,
                conditional_entropy: top.conditional_entropy,
                stacking: Some([
                    levels_arr[0].success_rate.value,
                    levels_arr[1].success_rate.value,
                    levels_arr[2].success_rate.value,
                ]),
                stacking_levels: Some(levels_arr),
                inference_ms,
            },
            per_context: per_context(&levels[2].0, &levels[2].1)?,
        });
    }
    let conv = EntropyConvention::for_task(task);
    let [success_rate, behaviour_entropy, conditional_entropy] =
        bootstrap_all(outcomes, cfg, &conv)?;
    let success_rate = task_success(task, outcomes, cfg).unwrap_or(success_rate);
    Ok(Evaluation {
        metrics: Metrics {
            success_rate,
            behaviour_entropy,
            conditional_entropy,
            stacking: None,
            stacking_levels: None,
            inference_ms,
        },
        per_context: per_context(outcomes, &conv)?,
    })
}

/// The success rate's estimate when `task` has one fixed initial state
/// ([`intervals::task_success_estimate`]); `None`: [`bootstrap_all`]'s
/// rule over states is the task's.
fn task_success(task: TaskId, outcomes: &[Outcome], cfg: &Bootstrap) -> Option<Estimate> {
    (task.paper_protocol().contexts == 1).then(|| {
        intervals::task_success_estimate(
            task,
            &intervals::state_counts(outcomes.iter().map(|o| (o.context_index, o.success))),
            cfg.confidence,
            cfg.resamples,
            cfg.seed,
        )
    })
}

/// Mean and **sample** standard deviation (ddof = 1) over training seeds, as the
/// paper reports them (see the crate docs for the evidence). One seed → std 0.
pub fn aggregate_seeds(values: &[f64]) -> Result<Stat, MetricsError> {
    if values.is_empty() {
        return Err(MetricsError::NoSeeds);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let std = if values.len() < 2 {
        0.0
    } else {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    };
    Ok(Stat { mean, std })
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod interval_tests;

#[cfg(test)]
mod intervals_tests;
