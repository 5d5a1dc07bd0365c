//! Anytime-valid statistics: answers that stay valid however often, and
//! whenever, someone looks. docs/sequential.md has the formulas.
//!
//! * [`BettingCs`]: a confidence *sequence* for the mean of values in [0, 1]
//!   (a success rate), by betting: the hedged capital process with
//!   predictable plug-in bets of Waudby-Smith & Ramdas (2023), "Estimating
//!   means of bounded random variables by betting", JRSS-B 86(1), Theorem 3
//!   and eq. (26). With probability at least 1 − α the true mean lies in every
//!   interval it ever reports.
//! * [`PairedEProcess`]: a test martingale for "A and B succeed equally
//!   often" on paired binary outcomes. Only discordant pairs move it: a
//!   mixture over constant bets on the sign of `a − b` (Cover's universal
//!   portfolio; Ramdas, Grünwald, Vovk & Shafer 2023, "Game-theoretic
//!   statistics and safe anytime-valid inference", Statist. Sci. 38(4)), one
//!   per direction, averaged for the two-sided test.
//! * [`SequentialComparison`]: the decision rule: "A better" or "B better"
//!   when `w − l` crosses the [`CalibratedBoundary`] of the protocol's
//!   horizon (`crate::horizon`: exact type-I error ≤ α over at most N
//!   pairs), or, with no horizon, when the two-sided e-value reaches 1/α;
//!   "no difference larger than δ" when the betting confidence sequence of
//!   the paired difference lies inside (−δ, δ).
//! * [`FixedPairedTest`]: the fixed-size test the sequential one is measured
//!   against: the exact two-sided sign test on the discordant pairs (exact
//!   McNemar), which is what `compare`'s randomisation test paired by initial
//!   state computes when every state has one rollout; its exact power and the
//!   sample size it needs for a given power.

pub use crate::horizon::CalibratedBoundary;
pub use crate::sign_test::FixedPairedTest;

/// Points of the grid of candidate means a [`BettingCs`] tracks by default:
/// intervals are exact to 1/1000 (and widened by that, never narrowed).
pub const CS_GRID_POINTS: usize = 1001;

/// Truncation `c` of the bets (Waudby-Smith & Ramdas use 1/2 or 3/4): a bet
/// never stakes more than this fraction of the capital.
const BET_CAP: f64 = 0.5;

/// Betting confidence sequence for the mean `m` of values in [0, 1].
///
/// For each candidate mean `m` on a grid, two gamblers bet that the mean is
/// above (`K⁺`) or below (`K⁻`) `m`:
/// `K⁺_t(m) = Π (1 + λ⁺_i(m)(x_i − m))`, `K⁻_t(m) = Π (1 − λ⁻_i(m)(x_i − m))`,
/// with the predictable plug-in bet
/// `λ_i = sqrt(2 ln(2/α) / (σ̂²_{i−1} · i · ln(1 + i)))`,
/// `λ⁺_i(m) = min(λ_i, c/m)`, `λ⁻_i(m) = min(λ_i, c/(1 − m))`, and
/// `μ̂_i = (1/2 + Σ x) / (i + 1)`, `σ̂²_i = (1/4 + Σ (x_j − μ̂_j)²) / (i + 1)`.
/// At the true mean both are nonnegative martingales, so by Ville's
/// inequality `P(∃t: max(K⁺/2, K⁻/2) ≥ 1/α) ≤ α`. The set
/// `{m : K⁺_t(m) < 2/α and K⁻_t(m) < 2/α}` is an interval (`K⁺` falls and
/// `K⁻` rises with `m`), intersected over time.
#[derive(Debug, Clone)]
pub struct BettingCs {
    alpha: f64,
    grid: Vec<f64>,
    log_plus: Vec<f64>,
    log_minus: Vec<f64>,
    n: u64,
    sum: f64,
    mu_hat: f64,
    sq_dev: f64,
    lo: f64,
    hi: f64,
}

impl BettingCs {
    /// A confidence sequence at level `1 − alpha`, `alpha` in (0, 1).
    pub fn new(alpha: f64) -> Self {
        Self::with_grid(alpha, CS_GRID_POINTS)
    }

    /// With `points` ≥ 3 candidate means, equally spaced on [0, 1]: the
    /// reported bounds are conservative by one grid step.
    pub fn with_grid(alpha: f64, points: usize) -> Self {
        assert!(alpha > 0.0 && alpha < 1.0, "alpha {alpha} is not in (0, 1)");
        let points = points.max(3);
        let grid = (0..points)
            .map(|j| j as f64 / (points - 1) as f64)
            .collect();
        BettingCs {
            alpha,
            grid,
            log_plus: vec![0.0; points],
            log_minus: vec![0.0; points],
            n: 0,
            sum: 0.0,
            mu_hat: 0.5,
            sq_dev: 0.0,
            lo: 0.0,
            hi: 1.0,
        }
    }

    /// Observations so far.
    pub fn n(&self) -> u64 {
        self.n
    }

    /// Their mean (0.5 before the first).
    pub fn mean(&self) -> f64 {
        if self.n == 0 {
            0.5
        } else {
            self.sum / self.n as f64
        }
    }

    /// The level: the interval covers the true mean at every look with
    /// probability at least `1 − alpha`.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// The running interval `(low, high)`; `(0, 1)` before the first
    /// observation.
    pub fn interval(&self) -> (f64, f64) {
        (self.lo, self.hi)
    }

    /// Adds one observation `x` in [0, 1] (clamped: a rate's outcomes are 0
    /// or 1, a paired difference's 0, ½ or 1).
    pub fn update(&mut self, x: f64) {
        let x = if x.is_nan() { 0.5 } else { x.clamp(0.0, 1.0) };
        let t = (self.n + 1) as f64;
        // σ̂²_{t−1} from the observations before this one.
        let var_prev = (0.25 + self.sq_dev) / t;
        let lambda = (2.0 * (2.0 / self.alpha).ln() / (var_prev * t * (1.0 + t).ln())).sqrt();
        for (j, &m) in self.grid.iter().enumerate() {
            let lp = lambda.min(BET_CAP / m);
            let lm = lambda.min(BET_CAP / (1.0 - m));
            self.log_plus[j] += (lp * (x - m)).ln_1p();
            self.log_minus[j] += (-lm * (x - m)).ln_1p();
        }
        self.n += 1;
        self.sum += x;
        // μ̂_t includes x; σ̂² accumulates (x_t − μ̂_t)² as the paper's does.
        self.mu_hat = (0.5 + self.sum) / (t + 1.0);
        self.sq_dev += (x - self.mu_hat).powi(2);
        self.narrow();
    }

    fn narrow(&mut self) {
        let threshold = (2.0 / self.alpha).ln();
        let h = 1.0 / (self.grid.len() - 1) as f64;
        // K⁺ is non-increasing in m: the candidates it rejects are a prefix.
        let first_kept = self.log_plus.iter().position(|&l| l < threshold);
        // K⁻ is non-decreasing in m: the candidates it rejects are a suffix.
        let last_kept = self.log_minus.iter().rposition(|&l| l < threshold);
        let (Some(a), Some(b)) = (first_kept, last_kept) else {
            return;
        };
        // The true boundary lies between a rejected and a kept grid point:
        // widen by one step so the interval contains it.
        let lo = if a == 0 { 0.0 } else { self.grid[a] - h };
        let hi = if b + 1 == self.grid.len() {
            1.0
        } else {
            self.grid[b] + h
        };
        let (lo, hi) = (lo.max(self.lo), hi.min(self.hi));
        // An empty intersection happens with probability at most α (the
        // sequence has already missed): keep the last non-empty interval.
        if lo <= hi {
            self.lo = lo;
            self.hi = hi;
        }
    }
}

/// A discrete uniform prior over the constant bets of a [`PairedEProcess`]:
/// `λ_k = (k − ½)/K`, k = 1..K, on (0, 1).
const MIXTURE_BETS: usize = 64;

/// Test martingale for "A and B succeed equally often" on paired binary
/// outcomes `(a_i, b_i)`.
///
/// The one-sided e-process for "A better" is the mixture over constant bets
/// `E⁺_t = (1/K) Σ_k Π_i (1 + λ_k (a_i − b_i))`; for "B better"
/// `E⁻_t` bets on `b_i − a_i`. Concordant pairs multiply by 1. Under
/// `P(a = 1) ≤ P(b = 1)` (given the past) every term of `E⁺` has
/// conditional expectation at most 1, so `E⁺` is a nonnegative
/// supermartingale starting at 1 and `P(∃t: E⁺_t ≥ 1/α) ≤ α` (Ville). The
/// mixture is itself a predictable bet: it stakes the prior-weighted mean of
/// the `λ_k`, weighted by what each has won so far. The two-sided e-value is
/// `E_t = (E⁺_t + E⁻_t)/2`. Both depend only on the counts of discordant
/// pairs `(w, l)` won by A and by B.
#[derive(Debug, Clone)]
pub struct PairedEProcess {
    wins_a: u64,
    wins_b: u64,
    pairs: u64,
    /// `(E⁺, E⁻)` at the current counts.
    one_sided: (f64, f64),
    max_e: f64,
}

impl Default for PairedEProcess {
    fn default() -> Self {
        Self::new()
    }
}

impl PairedEProcess {
    pub fn new() -> Self {
        PairedEProcess {
            wins_a: 0,
            wins_b: 0,
            pairs: 0,
            one_sided: (1.0, 1.0),
            max_e: 1.0,
        }
    }

    /// Adds one pair: `a`, `b` whether A and B succeeded on it.
    pub fn observe(&mut self, a: bool, b: bool) {
        self.pairs += 1;
        match (a, b) {
            (true, false) => self.wins_a += 1,
            (false, true) => self.wins_b += 1,
            // A concordant pair multiplies every bet's capital by 1.
            _ => return,
        }
        self.one_sided = (
            mixture_e_value(self.wins_a, self.wins_b),
            mixture_e_value(self.wins_b, self.wins_a),
        );
        self.max_e = self.max_e.max(self.e_value());
    }

    /// Pairs seen.
    pub fn pairs(&self) -> u64 {
        self.pairs
    }

    /// Discordant pairs A won (A succeeded, B failed) and B won.
    pub fn discordant(&self) -> (u64, u64) {
        (self.wins_a, self.wins_b)
    }

    /// `(E⁺, E⁻)`: the one-sided e-values for "A better" and "B better".
    pub fn one_sided(&self) -> (f64, f64) {
        self.one_sided
    }

    /// The two-sided e-value `(E⁺ + E⁻)/2`.
    pub fn e_value(&self) -> f64 {
        0.5 * (self.one_sided.0 + self.one_sided.1)
    }

    /// The anytime-valid p-value `min(1, 1 / max_{s ≤ t} E_s)`: valid at
    /// every look, and when the looks stop for any reason.
    pub fn p_value(&self) -> f64 {
        (1.0 / self.max_e).min(1.0)
    }
}

/// `ln(1 + λ_k)` and `ln(1 − λ_k)` of the mixture's bets.
fn bet_logs() -> &'static [(f64, f64); MIXTURE_BETS] {
    static LOGS: std::sync::OnceLock<[(f64, f64); MIXTURE_BETS]> = std::sync::OnceLock::new();
    LOGS.get_or_init(|| {
        std::array::from_fn(|i| {
            let lambda = (i as f64 + 0.5) / MIXTURE_BETS as f64;
            (lambda.ln_1p(), (-lambda).ln_1p())
        })
    })
}

/// `(1/K) Σ_k (1 + λ_k)^w (1 − λ_k)^l`: the one-sided mixture e-value after
/// `w` discordant pairs won and `l` lost.
pub fn mixture_e_value(w: u64, l: u64) -> f64 {
    let (w, l) = (w as f64, l as f64);
    let logs = bet_logs();
    let top = logs
        .iter()
        .map(|(up, down)| w * up + l * down)
        .fold(f64::NEG_INFINITY, f64::max);
    let sum: f64 = logs
        .iter()
        .map(|(up, down)| (w * up + l * down - top).exp())
        .sum();
    top.exp() * sum / MIXTURE_BETS as f64
}

/// The e-process's part of the decision after `w` discordant pairs won by A
/// and `l` by B: "A better" or "B better" once `(E⁺ + E⁻)/2 ≥ 1/α`, on the
/// side whose one-sided e-value is larger. [`SequentialComparison`] decides
/// by it; the simulations of `d3il bench sequential` tabulate it.
pub fn e_value_decision(w: u64, l: u64, alpha: f64) -> Option<Decision> {
    decide((mixture_e_value(w, l), mixture_e_value(l, w)), alpha)
}

fn decide((ep, em): (f64, f64), alpha: f64) -> Option<Decision> {
    if 0.5 * (ep + em) < 1.0 / alpha {
        None
    } else if ep >= em {
        Some(Decision::ABetter)
    } else {
        Some(Decision::BBetter)
    }
}

/// What a sequential comparison decided (defined beside the boundary that
/// decides it, [`crate::horizon`]).
pub use crate::horizon::Decision;

/// The sequential paired comparison of A and B at level `alpha`.
///
/// After each pair, "A better" or "B better" is decided by one of two
/// rules:
///
/// * with a horizon ([`Self::with_horizon`]: the protocol's most pairs `N`,
///   known before the first), by the [`CalibratedBoundary`]: `|w − l|`
///   reaching its running bound, or its last-look bound at pair `N`, on the
///   side ahead. Its exact type-I error over at most `N` pairs is `≤ α`;
///   pairs beyond `N` decide nothing.
/// * without ([`Self::new`]), by the e-value: `E_t ≥ 1/α`, "A better" when
///   `E⁺ ≥ E⁻`, else "B better"; valid with no horizon at all.
///
/// The e-value and its anytime p-value are reported either way. Otherwise,
/// if a margin `δ` was given and the betting confidence sequence (level
/// `1 − α`) of the paired difference `rate(A) − rate(B)` (from
/// `x = (a − b + 1)/2`) lies inside `(−δ, δ)`, decide "no difference larger
/// than δ". Each wrong decision has probability at most α: "A better"
/// wrongly needs the boundary crossed upwards (or `E⁺ ≥ 1/α`) under
/// `rate(A) ≤ rate(B)`; "no difference" wrongly needs the confidence
/// sequence to miss.
#[derive(Debug, Clone)]
pub struct SequentialComparison {
    alpha: f64,
    delta: Option<f64>,
    eprocess: PairedEProcess,
    difference: Option<BettingCs>,
    boundary: Option<CalibratedBoundary>,
    decided: Option<(Decision, u64)>,
}

impl SequentialComparison {
    /// `alpha` in (0, 1); `delta`, if given, in (0, 2). Decides by the
    /// e-value (no horizon).
    pub fn new(alpha: f64, delta: Option<f64>) -> Self {
        assert!(alpha > 0.0 && alpha < 1.0, "alpha {alpha} is not in (0, 1)");
        SequentialComparison {
            alpha,
            delta,
            eprocess: PairedEProcess::new(),
            difference: delta.map(|_| BettingCs::new(alpha)),
            boundary: None,
            decided: None,
        }
    }

    /// Decides by the boundary calibrated to at most `max_pairs` pairs (the
    /// protocol's size); beyond [`crate::horizon::MAX_HORIZON`] pairs, or
    /// with none, by the e-value as [`Self::new`].
    pub fn with_horizon(alpha: f64, delta: Option<f64>, max_pairs: usize) -> Self {
        let mut s = Self::new(alpha, delta);
        if (1..=crate::horizon::MAX_HORIZON).contains(&max_pairs) {
            s.boundary = Some(CalibratedBoundary::new(alpha, max_pairs));
        }
        s
    }

    /// The calibrated boundary, when it decides.
    pub fn boundary(&self) -> Option<&CalibratedBoundary> {
        self.boundary.as_ref()
    }

    /// Adds one pair; returns the decision once there is one (and keeps it:
    /// later pairs still update the e-value and interval, not the decision).
    pub fn observe(&mut self, a: bool, b: bool) -> Option<Decision> {
        self.eprocess.observe(a, b);
        if let Some(cs) = self.difference.as_mut() {
            cs.update((a as u8 as f64 - b as u8 as f64 + 1.0) / 2.0);
        }
        if self.decided.is_none() {
            let n = self.eprocess.pairs();
            let (w, l) = self.eprocess.discordant();
            let by_test = match &self.boundary {
                Some(b) if n <= b.horizon() as u64 => b.decide(w, l, n == b.horizon() as u64),
                Some(_) => None,
                None => decide(self.eprocess.one_sided(), self.alpha),
            };
            if let Some(d) = by_test {
                self.decided = Some((d, n));
            } else if let (Some(delta), Some((lo, hi))) = (self.delta, self.difference_interval()) {
                if -delta < lo && hi < delta {
                    self.decided = Some((Decision::NoDifferenceLargerThan(delta), n));
                }
            }
        }
        self.decision()
    }

    /// [`Self::observe`] of an `(a, b)` pair.
    pub fn observe_pair(&mut self, (a, b): (bool, bool)) -> Option<Decision> {
        self.observe(a, b)
    }

    pub fn decision(&self) -> Option<Decision> {
        self.decided.map(|(d, _)| d)
    }

    /// The pair at which the decision was made (1-based).
    pub fn decided_at(&self) -> Option<u64> {
        self.decided.map(|(_, n)| n)
    }

    pub fn eprocess(&self) -> &PairedEProcess {
        &self.eprocess
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// The confidence sequence of `rate(A) − rate(B)`, when a margin was given.
    pub fn difference_interval(&self) -> Option<(f64, f64)> {
        self.difference.as_ref().map(|cs| {
            let (lo, hi) = cs.interval();
            (2.0 * lo - 1.0, 2.0 * hi - 1.0)
        })
    }
}

/// The paired outcomes `(A succeeded, B succeeded)` of two finished
/// evaluations on the same initial states, paired by (initial state,
/// rollout), in that order; [`crate::compare::check_comparable`] first.
///
/// When neither result's outcome varies within any initial state
/// (deterministic policies: their rollouts of a state are copies), the pairs
/// are one per initial state (its first rollout), `per_state` true: copies
/// are not independent evidence, and a test fed them would be
/// overconfident.
pub fn paired_outcomes_per_unit(
    a: &d3il_protocol::EvalResult,
    b: &d3il_protocol::EvalResult,
) -> Result<(Vec<(bool, bool)>, bool), crate::MetricsError> {
    let all = paired_outcomes(a, b)?;
    let mut states: Vec<usize> = a.rollouts.iter().map(|r| r.context_index).collect();
    states.sort_unstable();
    Ok(one_pair_per_state_if_copies(&states, all))
}

/// `pairs[i]` belongs to initial state `states[i]` (sorted): one pair per
/// state when every state's pairs are equal, else all of them.
pub(crate) fn one_pair_per_state_if_copies(
    states: &[usize],
    pairs: Vec<(bool, bool)>,
) -> (Vec<(bool, bool)>, bool) {
    let mut groups: Vec<&[(bool, bool)]> = vec![];
    let mut start = 0;
    for i in 1..=states.len().min(pairs.len()) {
        if i == states.len() || states[i] != states[start] {
            groups.push(&pairs[start..i]);
            start = i;
        }
    }
    if groups.iter().all(|g| g.iter().all(|p| *p == g[0])) {
        let firsts = groups.iter().map(|g| g[0]).collect();
        (firsts, true)
    } else {
        (pairs, false)
    }
}

/// [`paired_outcomes_per_unit`]'s pairs, one per rollout, always.
pub fn paired_outcomes(
    a: &d3il_protocol::EvalResult,
    b: &d3il_protocol::EvalResult,
) -> Result<Vec<(bool, bool)>, crate::MetricsError> {
    crate::compare::check_comparable(&a.manifest, &b.manifest)?;
    let by_key = |r: &d3il_protocol::EvalResult| {
        let mut m = std::collections::BTreeMap::new();
        for x in &r.rollouts {
            if m.insert((x.context_index, x.rollout_index), x.success)
                .is_some()
            {
                return Err(crate::MetricsError::NotComparable(format!(
                    "rollout {} of initial state {} appears twice in one result",
                    x.rollout_index, x.context_index
                )));
            }
        }
        Ok(m)
    };
    let (ma, mb) = (by_key(a)?, by_key(b)?);
    if ma.len() != mb.len() || ma.keys().ne(mb.keys()) {
        return Err(crate::MetricsError::NotComparable(format!(
            "their rollout records differ: A has {} rollouts, B has {}, not the same (initial state, rollout) pairs; \
             a sequential replay needs every rollout of both (results of `d3il eval --json`)",
            ma.len(),
            mb.len()
        )));
    }
    if ma.is_empty() {
        return Err(crate::MetricsError::NoOutcomes);
    }
    Ok(ma
        .values()
        .zip(mb.values())
        .map(|(&x, &y)| (x, y))
        .collect())
}

/// What replaying two finished evaluations as a sequential comparison
/// found ([`replay`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Replay {
    pub alpha: f64,
    pub delta: Option<f64>,
    /// Seed of the random order the pairs were replayed in (ChaCha8).
    pub seed: u64,
    /// `"A better"`, `"B better"`, `"no difference larger than δ"`, or
    /// `None` when all pairs ran without a decision.
    pub decision: Option<String>,
    /// The pair (1-based) at which it was decided.
    pub decided_at: Option<u64>,
    /// Pairs used: `decided_at`, or all.
    pub pairs_used: u64,
    /// Pairs the finished evaluations hold: what the fixed-size test used.
    pub pairs_total: u64,
    /// The two-sided e-value when the replay stopped.
    pub e_value: f64,
    /// The anytime-valid p-value when it stopped: 1 / the running maximum e-value.
    pub p_value: f64,
    /// Discordant pairs (A won, B won) when it stopped.
    pub discordant: (u64, u64),
    /// The confidence sequence of rate(A) − rate(B) when it stopped (with δ).
    pub difference_interval: Option<(f64, f64)>,
    /// The exact sign test on all pairs: its two-sided p-value.
    pub fixed_p_value: f64,
    /// Success rates of A and B over all pairs.
    pub rate_a: f64,
    pub rate_b: f64,
}

/// Replays paired outcomes in a seeded random order
/// ([`crate::order::random_order`]) through a [`SequentialComparison`], stopping at its decision.
pub fn replay(pairs: &[(bool, bool)], alpha: f64, delta: Option<f64>, seed: u64) -> Replay {
    let order = crate::order::random_order(pairs.len(), seed);
    // The finished results fix the horizon: all their pairs.
    let mut test = SequentialComparison::with_horizon(alpha, delta, pairs.len());
    for &i in &order {
        let (a, b) = pairs[i];
        if test.observe(a, b).is_some() {
            break;
        }
    }
    let (wa, wb) = pairs.iter().fold((0, 0), |(x, y), &(a, b)| {
        (x + (a && !b) as u64, y + (b && !a) as u64)
    });
    let n = pairs.len().max(1) as f64;
    Replay {
        alpha,
        delta,
        seed,
        decision: test.decision().map(|d| d.to_string()),
        decided_at: test.decided_at(),
        pairs_used: test.eprocess().pairs(),
        pairs_total: pairs.len() as u64,
        e_value: test.eprocess().e_value(),
        p_value: test.eprocess().p_value(),
        discordant: test.eprocess().discordant(),
        difference_interval: test.difference_interval(),
        fixed_p_value: FixedPairedTest::new(alpha).p_value(wa, wb),
        rate_a: pairs.iter().filter(|p| p.0).count() as f64 / n,
        rate_b: pairs.iter().filter(|p| p.1).count() as f64 / n,
    }
}

#[cfg(test)]
#[path = "sequential_tests.rs"]
mod tests;
