//! Intervals chosen for their coverage (docs/intervals.md): one method per quantity.
//!
//! * **Success rate over initial states** ([`success_rate_interval`]): the
//!   data are clustered binary, `k_s` successes of `m_s` rollouts on each of
//!   `n` initial states, and the quantity is the expected success rate over
//!   fresh initial states, estimated by the mean of the state rates
//!   `p̂ = mean_s(k_s / m_s)` (the pooled rate when every state has the same
//!   number of rollouts, as every protocol has). The method depends on `n`
//!   and on the data, by an explicit rule (first match wins):
//!
//!   1. `n < MIN_STATES` (5): **no interval** ([`NoInterval::TooFewStates`]).
//!      Three states cannot say how much states differ; any interval would
//!      be a guess about that spread (the bias-corrected bootstrap printed
//!      [0.015, 1.0] for 2 of 3 states, excluding a true rate of 0).
//!   2. every state has one rollout: **Clopper–Pearson** on `k` of `n`
//!      (Clopper & Pearson 1934, Biometrika 26, 404–413). States drawn
//!      independently with one rollout each make independent Bernoulli
//!      trials of the rate itself, so the interval is exact (conservative).
//!   3. every state at 0 (or every state at 1): the **Clopper–Pearson
//!      interval of 0 (n) successes in n trials**, `[0, 1 − (α/2)^(1/n)]`
//!      (or its mirror), counting each state as ONE trial however many
//!      rollouts it had. That is the worst case of the design effect (a
//!      state's rollouts all agree) and so never too narrow; the data
//!      themselves show no spread to estimate it from.
//!   4. `n ≥ BOOTSTRAP_MIN_STATES` (100) and at least `BOOTSTRAP_MIN_EVENTS`
//!      (10) effective successes and failures (`n_eff·p̂`, `n_eff·(1 − p̂)`,
//!      `n_eff` as in 5): the **percentile cluster bootstrap** — states
//!      resampled with replacement keeping their observed rates (Davison &
//!      Hinkley 1997, *Bootstrap Methods and their Application*, §3.8,
//!      "strategy 1"; resampling the rollouts again inside each state would
//!      count the within-state variance twice), the interval the `α/2` and
//!      `1 − α/2` percentiles of the resampled means, with **no bias shift**
//!      (for a mean the bootstrap's bias is resampling noise; shifting by it
//!      moved intervals off an atom). Below 100 states the
//!      percentile interval is too narrow (by about `√((n−1)/n)` and by
//!      using normal rather than t quantiles, in effect) and skewed near 0
//!      and 1: at 60 states × 8 rollouts it covered 92–93 % in `d3il bench
//!      intervals` where Korn–Graubard kept 95 %.
//!   5. otherwise: **Korn–Graubard**, the Clopper–Pearson interval at an
//!      effective sample size (Korn & Graubard 1998, Survey Methodology 24,
//!      193–201; Dean & Pagano 2015, J. Survey Stat. Methodol. 3, 484–503,
//!      found it the one that keeps its coverage in small clustered
//!      samples): `n_eff = p̂(1−p̂)/v̂` with `v̂ = s²/n` the variance of the
//!      mean of the state rates (`s²` with `n − 1`), capped at the number of
//!      rollouts (a clustered design is taken to be no better than
//!      independent rollouts; the cap also serves when all states show the
//!      same rate, `s² = 0`), then shrunk for the degrees of freedom of `s²`,
//!      `n_df = n_eff·(z_{1−α/2} / t_{n−1, 1−α/2})²`, and Clopper–Pearson
//!      bounds with `x = p̂·n_df` successes in `n_df` trials (beta quantiles,
//!      real-valued arguments).
//!
//!   Width is never 0: rules 2, 3 and 5 are Clopper–Pearson intervals of at
//!   most `n_df` (finite) trials, and rule 4 only applies with at least 10
//!   effective successes and failures.
//!
//! * **Paired difference of success rates** ([`SignFlip`]): policy A and B
//!   (or robustness level 0 and a level) on the same `n` states, state
//!   differences `d_s = p̂_A,s − p̂_B,s`. The p-value is the paired
//!   randomisation test of the paired comparison, compare.rs (A and B swapped within each
//!   state, i.e. `d_s` sign-flipped, statistic `|mean(d)|`; Fisher 1935,
//!   Pitman 1937). The interval is that test **inverted** (Lehmann &
//!   Romano, *Testing Statistical Hypotheses*, §3.5 and §5.9; Hartigan
//!   1969, JASA 64, 1303–1317): the shifts δ whose test of `d_s − δ` does
//!   not reject, `{δ : p(δ) > α}`. For one sign vector ε with flipped set F
//!   (and the rest K), `|Σε(d−δ)| ≥ |Σ(d−δ)|` holds exactly when δ lies
//!   between `mean_F(d)` and `mean_K(d)` (the difference of the squares
//!   factors into two linear terms, one vanishing at each mean); every such
//!   segment contains `mean(d)`, so `p(δ)` falls away from the estimate on
//!   both sides and `{δ : p(δ) > α}` is the closed interval from the k-th
//!   smallest segment start to the k-th largest segment end, `k` the
//!   fewest segments with `k/N > α`. `p(δ)` and the interval are computed
//!   from the same segments, so **0 lies outside the interval exactly when
//!   p(0) ≤ α** (α = 0.05 never equals a p-value of these tests: `2^n/20`
//!   and `(R+1)/20` for R = 999, 1000 are not integers).
//!
//!   Exact enumeration of the `2^n` sign vectors for `n ≤ EXACT_MAX_STATES`
//!   (14); above, the identity plus `R` random sign vectors from a seeded
//!   ChaCha8 (`p = (1 + #)/(1 + R)`, as the paired comparison (compare.rs) counts; the
//!   interval is then that of the Monte-Carlo test, exactly consistent
//!   with its p-value, and both move by Monte-Carlo error of order
//!   `√(α(1−α)/R)` in level). When the test cannot reject anything at
//!   level α (exactly: `2/2^n > α`, i.e. n ≤ 5 at 95 %) there is **no
//!   interval** ([`NoInterval::TestCannotReject`]). When every state shows
//!   the same difference (typically 0: both policies succeed, or fail, on
//!   every state) the inverted test would give that single point, certainty
//!   from data without spread; there is **no interval** then either
//!   ([`NoInterval::NoSpread`]), while the p-value stands (for a common
//!   difference c ≠ 0 it is `2/2^n`: every state moved the same way).
//!
//!   What it guarantees: exact level (coverage ≥ 1 − α) for the shift model
//!   `d_s = δ + e_s` with `e_s` symmetric about 0; in particular the
//!   coverage of δ = 0 is exact when A and B are exchangeable within states
//!   (the null the p-value tests). For differences of bounded rates the
//!   shift model is approximate and coverage is asymptotic; `d3il bench
//!   intervals` measures it (docs/intervals.md).
//!
//!   Where it does not hold: the interval never reaches beyond the range of
//!   the observed differences (for δ above every `d_s`, all `d_s − δ` have
//!   one sign and the test rejects once `2/2^n ≤ α`). With sparse binary
//!   data, one rollout a state and rates near 0 or 1, most `d_s` are 0 and
//!   the few others often fall on one side, so a small true difference of
//!   the other sign is excluded: coverage dropped to 66 % there
//!   (docs/intervals.md). Any interval that agrees with a test of symmetry
//!   by construction shares this, so success rates measured with one
//!   rollout a state are compared by another test, the exact McNemar test
//!   on the discordant states (`crate::rate_difference`).

use crate::quantile::{normal_quantile, percentile};
use d3il_protocol::{Estimate, TaskId};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Fewest initial states a success-rate interval is given for.
pub const MIN_STATES: usize = 5;
/// Fewest initial states for the percentile cluster bootstrap (rule 4).
pub const BOOTSTRAP_MIN_STATES: usize = 100;
/// Fewest effective successes and failures for the bootstrap (rule 4).
pub const BOOTSTRAP_MIN_EVENTS: f64 = 10.0;
/// Most initial states whose sign vectors are enumerated exactly.
pub const EXACT_MAX_STATES: usize = 14;
/// Tolerance on a sign vector's segment, so that float noise in a mean
/// that ties the observed one does not make it "less extreme" (the same
/// tolerance as the paired comparison's randomisation test).
const TIE: f64 = 1e-12;

/// Which method made an [`Interval`] (the names pages print are
/// [`Method::name`]; the type lives in `d3il_protocol` so that every
/// document can carry it).
pub use d3il_protocol::IntervalMethod as Method;

/// A two-sided interval and the method that made it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub estimate: f64,
    pub low: f64,
    pub high: f64,
    pub method: Method,
}

impl Interval {
    /// The interval as a result document carries it.
    pub fn to_estimate(self) -> Estimate {
        Estimate::with_interval(self.estimate, self.low, self.high, self.method)
    }
    pub fn contains(&self, x: f64) -> bool {
        self.low <= x && x <= self.high
    }
    pub fn width(&self) -> f64 {
        self.high - self.low
    }
}

/// Why no interval is given (its sentence is its `Display`).
pub use d3il_protocol::NoInterval;

/// Successes and rollouts of one initial state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StateCount {
    pub successes: u32,
    pub rollouts: u32,
}

impl StateCount {
    pub fn new(successes: u32, rollouts: u32) -> Self {
        StateCount {
            successes,
            rollouts,
        }
    }
    fn rate(self) -> f64 {
        self.successes as f64 / self.rollouts as f64
    }
}

/// The success-rate interval at two-sided level `confidence` (see the module
/// documentation for the rule); `resamples` and `seed` are the bootstrap's
/// (rule 4 only).
pub fn success_rate_interval(
    states: &[StateCount],
    confidence: f64,
    resamples: usize,
    seed: u64,
) -> Result<Interval, NoInterval> {
    assert!(
        confidence > 0.0 && confidence < 1.0,
        "confidence {confidence} is not in (0, 1)"
    );
    let n = states.len();
    if n == 0
        || states
            .iter()
            .any(|s| s.rollouts == 0 || s.successes > s.rollouts)
    {
        return Err(NoInterval::NoData);
    }
    if n < MIN_STATES {
        return Err(NoInterval::TooFewStates {
            states: n,
            min: MIN_STATES,
        });
    }
    let alpha = 1.0 - confidence;
    let rates: Vec<f64> = states.iter().map(|s| s.rate()).collect();
    let nf = n as f64;
    let p = rates.iter().sum::<f64>() / nf;
    let out = |low: f64, high: f64, method| {
        Ok(Interval {
            estimate: p,
            low: low.min(p),
            high: high.max(p),
            method,
        })
    };
    // Rule 2.
    if states.iter().all(|s| s.rollouts == 1) {
        let k: f64 = states.iter().map(|s| s.successes as f64).sum();
        let (lo, hi) = clopper_pearson(k, nf, alpha);
        return out(lo, hi, Method::ClopperPearson);
    }
    // Rule 3.
    if states.iter().all(|s| s.successes == 0) {
        return out(
            0.0,
            1.0 - (alpha / 2.0).powf(1.0 / nf),
            Method::ClopperPearsonAllEqual,
        );
    }
    if states.iter().all(|s| s.successes == s.rollouts) {
        return out(
            (alpha / 2.0).powf(1.0 / nf),
            1.0,
            Method::ClopperPearsonAllEqual,
        );
    }
    let rollouts: f64 = states.iter().map(|s| s.rollouts as f64).sum();
    let s2 = rates.iter().map(|r| (r - p).powi(2)).sum::<f64>() / (nf - 1.0);
    let v = s2 / nf;
    let n_eff = if v > 0.0 {
        (p * (1.0 - p) / v).min(rollouts)
    } else {
        rollouts
    };
    // Rule 4.
    if n >= BOOTSTRAP_MIN_STATES && n_eff * p.min(1.0 - p) >= BOOTSTRAP_MIN_EVENTS && resamples > 0
    {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut means: Vec<f64> = (0..resamples)
            .map(|_| {
                (0..n)
                    .map(|_| rates[rng.random_range(0..n as u64) as usize])
                    .sum::<f64>()
                    / nf
            })
            .collect();
        means.sort_by(f64::total_cmp);
        let lo = percentile(&means, alpha / 2.0);
        let hi = percentile(&means, 1.0 - alpha / 2.0);
        return out(lo, hi, Method::ClusterBootstrap);
    }
    // Rule 5.
    let z = normal_quantile(1.0 - alpha / 2.0);
    let t = t_quantile(1.0 - alpha / 2.0, nf - 1.0);
    let n_df = n_eff * (z / t).powi(2);
    let (lo, hi) = clopper_pearson(p * n_df, n_df, alpha);
    out(lo, hi, Method::KornGraubard)
}

/// [`success_rate_interval`] as a result document carries it: the estimate
/// (the mean of the state rates) with its interval, or without one and why.
pub fn success_rate_estimate(
    states: &[StateCount],
    confidence: f64,
    resamples: usize,
    seed: u64,
) -> Estimate {
    // The value printed is the pooled rate, bit for bit the one results
    // carried before 0.5.0 (`crate::success_rate`); with the same number of
    // rollouts on every state it is the interval's mean of state rates up to
    // the last bit, and the interval is widened to contain it.
    let rollouts: u32 = states.iter().map(|s| s.rollouts).sum();
    let successes: u32 = states.iter().map(|s| s.successes).sum();
    let value = if rollouts == 0 {
        0.0
    } else {
        successes as f64 / rollouts as f64
    };
    match success_rate_interval(states, confidence, resamples, seed) {
        Ok(i) => Estimate::with_interval(value, i.low.min(value), i.high.max(value), i.method),
        Err(why) => Estimate::without_interval(value, why),
    }
}

/// The success-rate estimate of an evaluation of `task`: on a task with one
/// fixed initial state (Avoiding) the rollouts are independent trials of the
/// rate itself, and the interval is Clopper–Pearson on all of them (exact);
/// on every other task [`success_rate_estimate`]'s rule over states.
pub fn task_success_estimate(
    task: TaskId,
    states: &[StateCount],
    confidence: f64,
    resamples: usize,
    seed: u64,
) -> Estimate {
    match states {
        [one] if task.paper_protocol().contexts == 1 && one.rollouts > 0 => {
            let (k, n) = (one.successes as f64, one.rollouts as f64);
            let (lo, hi) = clopper_pearson(k, n, 1.0 - confidence);
            let value = k / n;
            Estimate::with_interval(
                value,
                lo.min(value),
                hi.max(value),
                Method::ClopperPearsonRollouts,
            )
        }
        _ => success_rate_estimate(states, confidence, resamples, seed),
    }
}

/// Successes and rollouts of each initial state (ascending state index) of
/// `(state index, success)` pairs, one a rollout.
pub fn state_counts(rollouts: impl IntoIterator<Item = (usize, bool)>) -> Vec<StateCount> {
    let mut by_state: std::collections::BTreeMap<usize, StateCount> = Default::default();
    for (state, success) in rollouts {
        let c = by_state.entry(state).or_insert(StateCount::new(0, 0));
        c.rollouts += 1;
        c.successes += success as u32;
    }
    by_state.into_values().collect()
}

/// Clopper–Pearson bounds of `k` successes in `n` trials (real-valued, as
/// Korn–Graubard needs): `B(α/2; k, n−k+1)` and `B(1−α/2; k+1, n−k)`.
pub fn clopper_pearson(k: f64, n: f64, alpha: f64) -> (f64, f64) {
    let lo = if k <= 0.0 {
        0.0
    } else {
        beta_quantile(alpha / 2.0, k, n - k + 1.0)
    };
    let hi = if k >= n {
        1.0
    } else {
        beta_quantile(1.0 - alpha / 2.0, k + 1.0, n - k)
    };
    (lo, hi)
}

/// The paired randomisation (sign-flip) test of the state differences and
/// its inversion (see the module documentation).
#[derive(Debug, Clone)]
pub struct SignFlip {
    n: usize,
    mean: f64,
    constant: bool,
    exact: bool,
    /// For every sign vector (the identity included), the closed segment of
    /// shifts δ at which it is at least as extreme as the observed data.
    starts: Vec<f64>,
    ends: Vec<f64>,
}

impl SignFlip {
    /// The test of the differences `d` (one a state); `resamples` sign
    /// vectors drawn with `seed` when `d.len() > EXACT_MAX_STATES`.
    pub fn new(d: &[f64], resamples: usize, seed: u64) -> SignFlip {
        let n = d.len();
        let mean = if n == 0 {
            0.0
        } else {
            d.iter().sum::<f64>() / n as f64
        };
        let total: f64 = d.iter().sum();
        let (lo, hi) = d
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        let constant = n > 0 && hi - lo <= TIE;
        let exact = n <= EXACT_MAX_STATES;
        let mut starts = Vec::new();
        let mut ends = Vec::new();
        let mut push = |flipped_sum: f64, flipped: usize| {
            if flipped == 0 || flipped == n {
                starts.push(f64::NEG_INFINITY);
                ends.push(f64::INFINITY);
            } else {
                let mf = flipped_sum / flipped as f64;
                let mk = (total - flipped_sum) / (n - flipped) as f64;
                starts.push(mf.min(mk).min(mean) - TIE);
                ends.push(mf.max(mk).max(mean) + TIE);
            }
        };
        if exact {
            for mask in 0u32..(1u32 << n) {
                let (mut s, mut c) = (0.0, 0usize);
                for (i, x) in d.iter().enumerate() {
                    if mask >> i & 1 == 1 {
                        s += x;
                        c += 1;
                    }
                }
                push(s, c);
            }
        } else {
            push(0.0, 0); // the identity
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..resamples {
                let (mut s, mut c) = (0.0, 0usize);
                let mut bits = 0u64;
                for (i, x) in d.iter().enumerate() {
                    if i % 64 == 0 {
                        bits = rng.random();
                    }
                    if bits >> (i % 64) & 1 == 1 {
                        s += x;
                        c += 1;
                    }
                }
                push(s, c);
            }
        }
        SignFlip {
            n,
            mean,
            constant,
            exact,
            starts,
            ends,
        }
    }

    /// The observed mean difference.
    pub fn estimate(&self) -> f64 {
        self.mean
    }

    /// Whether the sign vectors were enumerated exactly.
    pub fn is_exact(&self) -> bool {
        self.exact
    }

    /// The two-sided p-value of "the differences are symmetric about δ"
    /// (δ = 0: the p-value a comparison prints).
    pub fn p_value(&self, delta: f64) -> f64 {
        let c = self
            .starts
            .iter()
            .zip(&self.ends)
            .filter(|(s, e)| **s <= delta && delta <= **e)
            .count();
        c as f64 / self.starts.len() as f64
    }

    /// `{δ : p(δ) > 1 − confidence}`, or why there is none.
    pub fn interval(&self, confidence: f64) -> Result<Interval, NoInterval> {
        assert!(
            confidence > 0.0 && confidence < 1.0,
            "confidence {confidence} is not in (0, 1)"
        );
        if self.n == 0 {
            return Err(NoInterval::NoData);
        }
        let alpha = 1.0 - confidence;
        let total = self.starts.len();
        // Fewest segments k with k/N > α, by the same arithmetic as p_value.
        let accepts = |k: usize| k as f64 / total as f64 > alpha;
        let mut k = ((alpha * total as f64).floor() as usize).min(total);
        while k < total && !accepts(k) {
            k += 1;
        }
        while k > 1 && accepts(k - 1) {
            k -= 1;
        }
        let mut starts = self.starts.clone();
        let mut ends = self.ends.clone();
        starts.sort_by(f64::total_cmp);
        ends.sort_by(|a, b| b.total_cmp(a));
        let (low, high) = (starts[k.max(1) - 1], ends[k.max(1) - 1]);
        if !low.is_finite() || !high.is_finite() {
            let trivial = self.starts.iter().filter(|s| !s.is_finite()).count();
            return Err(NoInterval::TestCannotReject {
                states: self.n,
                smallest_p: trivial as f64 / total as f64,
            });
        }
        if self.constant {
            return Err(NoInterval::NoSpread {
                states: self.n,
                difference: self.mean,
            });
        }
        Ok(Interval {
            estimate: self.mean,
            low,
            high,
            method: if self.exact {
                Method::SignFlipExact
            } else {
                Method::SignFlipMonteCarlo
            },
        })
    }
}

/// A paired difference A − B of success rates on the same states: the
/// estimate, the sign-flip p-value of "no difference" and the interval from
/// the same test (see [`SignFlip`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PairedInterval {
    pub estimate: f64,
    pub p_value: f64,
    pub interval: Result<Interval, NoInterval>,
}

impl PairedInterval {
    /// The difference as a result document carries it.
    pub fn to_estimate(&self) -> Estimate {
        match self.interval {
            Ok(i) => i.to_estimate(),
            Err(why) => Estimate::without_interval(self.estimate, why),
        }
    }
}

/// [`PairedInterval`] of per-state rates `a[i]`, `b[i]` (same state i).
pub fn paired_difference_interval(
    a: &[f64],
    b: &[f64],
    confidence: f64,
    resamples: usize,
    seed: u64,
) -> PairedInterval {
    assert_eq!(a.len(), b.len(), "paired rates of different lengths");
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let test = SignFlip::new(&d, resamples, seed);
    PairedInterval {
        estimate: test.estimate(),
        p_value: test.p_value(0.0),
        interval: test.interval(confidence),
    }
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, n = 9; relative error ~1e-15).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection.
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised incomplete beta `I_x(a, b)` (continued fraction, modified
/// Lentz; Press et al., *Numerical Recipes*, 3rd ed., §6.4).
pub fn incomplete_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    if x < (a + 1.0) / (a + b + 2.0) {
        ln_front.exp() * beta_cf(x, a, b) / a
    } else {
        1.0 - ln_front.exp() * beta_cf(1.0 - x, b, a) / b
    }
}

fn beta_cf(x: f64, a: f64, b: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..=300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        if d.abs() < TINY {
            d = TINY;
        }
        c = 1.0 + aa / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        if d.abs() < TINY {
            d = TINY;
        }
        c = 1.0 + aa / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// The `q` quantile of Beta(a, b), by bisection on [`incomplete_beta`].
pub fn beta_quantile(q: f64, a: f64, b: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if incomplete_beta(mid, a, b) < q {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-14 {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// The `q ≥ 0.5` quantile of Student's t with `df` degrees of freedom:
/// `P(T > t) = I_{df/(df+t²)}(df/2, 1/2) / 2`, solved by bisection.
pub fn t_quantile(q: f64, df: f64) -> f64 {
    assert!((0.5..1.0).contains(&q), "t quantile {q} not in [0.5, 1)");
    let upper = |t: f64| 0.5 * incomplete_beta(df / (df + t * t), df / 2.0, 0.5);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while upper(hi) > 1.0 - q {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if upper(mid) > 1.0 - q {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 * hi.max(1.0) {
            break;
        }
    }
    0.5 * (lo + hi)
}
