//! A rejection boundary for the paired sequential test calibrated exactly to
//! the protocol's horizon: when the most pairs a comparison can
//! see is known (`N`, the protocol's initial states), the anytime-valid
//! e-process's threshold `1/α` is conservative (its type-I error over 480
//! pairs is 0.034 at α = 0.05), and a boundary whose exact type-I error over
//! at most `N` discordant pairs is `≤ α` decides sooner. STEP (Snyder et al.,
//! RSS 2025) calibrates its boundary to the horizon in the same spirit; this
//! is our own construction from the published idea. docs/sequential.md has
//! the argument.
//!
//! Under "A and B succeed equally often", with pairs drawn i.i.d. (initial
//! states in random order), each discordant pair is A's or B's with
//! probability ½ whatever the rates and independently of which pairs are
//! discordant. So `S_d = w − l` after `d` discordant pairs is a symmetric
//! ±1 random walk, independent of the discordance process, and the
//! probability that it crosses a boundary `b(d)` within `m` steps is exact
//! by dynamic programming. The boundary is a repeated significance test
//! (Armitage, McPherson & Rowe 1969; Pocock 1977) on the discordant pairs:
//!
//! * running: decide as soon as `|w − l| ≥ b(d) = ⌈z √d⌉`, `z` the smallest
//!   for which `P(∃ d ≤ N: |S_d| ≥ b(d)) ≤ RUNNING_SHARE · α`;
//! * last look: at the protocol's last pair, with `m` discordant pairs,
//!   decide if `|w − l| ≥ f(m)`, the smallest `f` with
//!   `P(∃ d ≤ m: |S_d| ≥ b(d)) + P(no crossing, |S_m| ≥ f) ≤ α`.
//!
//! For every `m ≤ N` the probability of a decision given `m` discordant
//! pairs by the end is then `≤ α` ([`CalibratedBoundary::type_i_error`] is
//! the largest), so it is `≤ α` for any number of discordant pairs, whatever
//! the rate of concordant pairs.

/// Share of α the running boundary spends; the last look spends the rest
/// (chosen on the bench's grid, computed exactly: shares 0.6, 0.8, 0.9,
/// 0.95, 0.98 give a protocol-view ratio of 0.621, 0.603, 0.591, 0.588,
/// 0.586; no last look at all, 0.644).
pub const RUNNING_SHARE: f64 = 0.98;

/// Longest horizon calibrated (the DP costs about `N^1.5` per bisection
/// step); a longer protocol decides by the e-value alone.
pub const MAX_HORIZON: usize = 20_000;

/// The calibrated two-sided boundary on `w − l` for a horizon of `N` pairs.
#[derive(Debug, Clone)]
pub struct CalibratedBoundary {
    alpha: f64,
    horizon: usize,
    z: f64,
    /// `running[d]`: the `|w − l|` from which the test decides after `d`
    /// discordant pairs, `d ≤ N` (`running[0]` never reached).
    running: Vec<u64>,
    /// `last[m]`: the `|w − l|` from which it decides at the last pair with
    /// `m` discordant pairs.
    last: Vec<u64>,
    /// `P₀(decision | m discordant pairs by the end)` for each `m`.
    type_i: Vec<f64>,
}

fn pocock(z: f64, horizon: usize) -> Vec<u64> {
    (0..=horizon)
        .map(|d| {
            if d == 0 {
                u64::MAX
            } else {
                ((z * (d as f64).sqrt() - 1e-9).ceil() as u64).max(1)
            }
        })
        .collect()
}

/// The walk `S_d` (a step +1 with probability `q`) stopped at `|S| ≥ b(d)`,
/// step by step: calls `each(d, survivors, up, down)` after step `d` with
/// the distribution of the survivors (`survivors[N + 1 + s]` for `S = s`,
/// `N = bound.len() − 1`) and the probabilities of having crossed up and
/// down so far. `bound` must not decrease (only the survivors' range,
/// which then only grows, is computed).
fn walk(bound: &[u64], q: f64, mut each: impl FnMut(usize, &[f64], f64, f64)) {
    debug_assert!(bound.windows(2).skip(1).all(|w| w[0] <= w[1]));
    let n = bound.len() - 1;
    let mut dist = vec![0.0; 2 * n + 3];
    let mut next = dist.clone();
    let o = n + 1;
    dist[o] = 1.0;
    let (mut up, mut down) = (0.0, 0.0);
    // Survivors lie within ±reach of 0; everything else in both buffers
    // is 0 (the range only grows).
    let mut reach = 0usize;
    for (d, &b) in bound.iter().enumerate().skip(1) {
        let span = (reach + 1).min(d);
        for s in (o - span)..=(o + span) {
            next[s] = q * dist[s - 1] + (1.0 - q) * dist[s + 1];
        }
        let b = b.min(d as u64 + 1) as usize;
        for s in b..=span {
            up += next[o + s];
            down += next[o - s];
            next[o + s] = 0.0;
            next[o - s] = 0.0;
        }
        reach = span.min(b.saturating_sub(1));
        std::mem::swap(&mut dist, &mut next);
        each(d, &dist, up, down);
    }
}

/// `P(∃ d ≤ N: |S_d| ≥ bound[d])` for the symmetric walk.
fn running_type_i(bound: &[u64]) -> f64 {
    let mut total = 0.0;
    walk(bound, 0.5, |_, _, up, down| total = up + down);
    total
}

impl CalibratedBoundary {
    /// The boundary at two-sided level `alpha` for at most `horizon` pairs
    /// (`1 ≤ horizon ≤ MAX_HORIZON`).
    pub fn new(alpha: f64, horizon: usize) -> Self {
        assert!(alpha > 0.0 && alpha < 1.0, "alpha {alpha} is not in (0, 1)");
        assert!(
            (1..=MAX_HORIZON).contains(&horizon),
            "horizon {horizon} is not in 1..={MAX_HORIZON}"
        );
        // The smallest z whose boundary spends at most the running share:
        // the crossing probability falls as z grows.
        let budget = RUNNING_SHARE * alpha;
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        while running_type_i(&pocock(hi, horizon)) > budget {
            lo = hi;
            hi *= 2.0;
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if running_type_i(&pocock(mid, horizon)) > budget {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let running = pocock(hi, horizon);
        // The last look: per m, the smallest f the rest of α allows.
        let mut last = vec![u64::MAX; horizon + 1];
        let mut type_i = vec![0.0; horizon + 1];
        let n = horizon;
        walk(&running, 0.5, |m, dist, up, down| {
            let crossed = up + down;
            // tail[f] = P(no crossing, |S_m| ≥ f), f from running[m] down.
            let b = running[m].min(m as u64 + 1) as usize;
            let (mut tail, mut f) = (0.0, b);
            type_i[m] = crossed;
            // f ≥ 1: a tie decides nothing.
            for g in (1..b).rev() {
                let p = dist[n + 1 + g] + dist[n + 1 - g];
                // A margin for rounding: never spend beyond α.
                if crossed + tail + p > alpha * (1.0 - 1e-9) {
                    break;
                }
                tail += p;
                f = g;
            }
            last[m] = if f >= b { u64::MAX } else { f as u64 };
            type_i[m] = crossed + tail;
        });
        CalibratedBoundary {
            alpha,
            horizon,
            z: hi,
            running,
            last,
            type_i,
        }
    }

    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// The most pairs the comparison sees.
    pub fn horizon(&self) -> usize {
        self.horizon
    }

    /// The running boundary's `z`: it decides at `|w − l| ≥ ⌈z √(w + l)⌉`.
    pub fn z(&self) -> f64 {
        self.z
    }

    /// `|w − l|` from which the test decides after `d` discordant pairs
    /// (`None`: it cannot, or `d` is beyond the horizon).
    pub fn running_bound(&self, d: usize) -> Option<u64> {
        self.running.get(d).copied().filter(|&b| b <= d as u64)
    }

    /// `|w − l|` from which it decides at the last pair, `m` discordant.
    pub fn last_bound(&self, m: usize) -> Option<u64> {
        let r = self.running_bound(m);
        let f = self.last.get(m).copied().filter(|&f| f <= m as u64);
        match (r, f) {
            (Some(r), Some(f)) => Some(r.min(f)),
            (r, f) => r.or(f),
        }
    }

    /// The decision after `w` discordant pairs won by A and `l` by B;
    /// `last`: this is the protocol's last pair.
    pub fn decide(&self, w: u64, l: u64, last: bool) -> Option<Decision> {
        let d = (w + l) as usize;
        let bound = if last {
            self.last_bound(d)
        } else {
            self.running_bound(d)
        }?;
        if w >= l + bound {
            Some(Decision::ABetter)
        } else if l >= w + bound {
            Some(Decision::BBetter)
        } else {
            None
        }
    }

    /// The exact type-I error: the largest, over the number `m ≤ N` of
    /// discordant pairs by the end, of the probability that the symmetric
    /// walk is decided within `m` steps (running or at the last look).
    pub fn type_i_error(&self) -> f64 {
        self.type_i.iter().copied().fold(0.0, f64::max)
    }

    /// `P₀(decision | m discordant pairs by the end)`, exactly.
    pub fn type_i_given(&self, m: usize) -> f64 {
        self.type_i.get(m).copied().unwrap_or(0.0)
    }

    /// The exact type-I error of a whole comparison of `N` pairs, each
    /// discordant with probability `discordance`:
    /// `Σ_m Bin(m; N, discordance) · P₀(decision | m)`.
    pub fn type_i_at(&self, discordance: f64) -> f64 {
        let (n, p) = (self.horizon, discordance.clamp(0.0, 1.0));
        if p <= 0.0 || p >= 1.0 {
            return self.type_i_given(if p >= 1.0 { n } else { 0 });
        }
        let mut ln_fact = vec![0.0f64; n + 1];
        for k in 1..=n {
            ln_fact[k] = ln_fact[k - 1] + (k as f64).ln();
        }
        (0..=n)
            .map(|m| {
                let ln = ln_fact[n] - ln_fact[m] - ln_fact[n - m]
                    + m as f64 * p.ln()
                    + (n - m) as f64 * (-p).ln_1p();
                ln.exp() * self.type_i[m]
            })
            .sum()
    }

    /// Exactly, when each discordant pair is A's with probability `q` and
    /// the comparison ends with `m ≤ N` discordant pairs: the probabilities
    /// that it decides "A better" and "B better" (running or at the last
    /// look).
    pub fn decision_probabilities(&self, q: f64, m: usize) -> (f64, f64) {
        let m = m.min(self.horizon);
        if m == 0 {
            return (0.0, 0.0);
        }
        let f = self.last_bound(m).map_or(usize::MAX, |f| f as usize);
        let mut out = (0.0, 0.0);
        // The walk of the first m steps: its survivors are indexed from m + 1.
        walk(&self.running[..=m], q, |d, dist, up, down| {
            if d == m {
                let (mut a, mut b) = (up, down);
                for s in f.max(1)..=m {
                    a += dist[m + 1 + s];
                    b += dist[m + 1 - s];
                }
                out = (a, b);
            }
        });
        out
    }
}

/// The rule in one line, for reports: "boundary calibrated to 60 pairs:
/// |w − l| ≥ ⌈2.683 √(w + l)⌉, last look at pair 60 (exact type-I ≤ 0.05)".
impl std::fmt::Display for CalibratedBoundary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "boundary calibrated to {n} pairs: |w − l| ≥ ⌈{z:.3} √(w + l)⌉, last look at pair {n} \
             (exact type-I ≤ {a})",
            n = self.horizon,
            z = self.z,
            a = self.alpha
        )
    }
}

/// The line a report prints about which rule decides a comparison of at
/// most `horizon` pairs at `alpha` (`SequentialComparison::with_horizon`).
pub fn rule_line(alpha: f64, horizon: usize) -> String {
    if (1..=MAX_HORIZON).contains(&horizon) {
        format!(
            "rule: {}; the e-value and p-value are anytime-valid, for any stop",
            CalibratedBoundary::new(alpha, horizon)
        )
    } else {
        format!("rule: the e-value reaching 1/α = {:.0}", 1.0 / alpha)
    }
}

/// The rule a comparison of at most `horizon` pairs at `alpha`
/// (`SequentialComparison::with_horizon`) decides by, and its guarantee, in
/// words; with `decision` (what it decided: "A better", "B better", "no
/// difference larger than δ"), which of its rules decided.
pub fn decided_by(alpha: f64, horizon: usize, decision: Option<&str>) -> String {
    let calibrated = (1..=MAX_HORIZON).contains(&horizon);
    let boundary = || {
        format!(
            "the {} (docs/sequential.md): its exact type-I error is at most {alpha} for a comparison of at most {horizon} pairs, wherever it stops; the e-value and anytime-valid p-value are reported beside it and did not decide (they do not know the horizon, so a decision can come with a p-value above α)",
            CalibratedBoundary::new(alpha, horizon)
        )
    };
    let e_value = || {
        format!(
            "the e-value reaching 1/α = {:.0}: anytime-valid, P(it ever does under equal rates) ≤ {alpha} for any number of pairs and any stop",
            1.0 / alpha
        )
    };
    match decision {
        Some(d) if d.starts_with("no difference") => format!(
            "Decided by the confidence sequence of rate(A) − rate(B) lying inside (−δ, δ): it misses the true difference at some time with probability at most {alpha}"
        ),
        Some(_) if calibrated => format!("Decided by {}", boundary()),
        Some(_) => format!("Decided by {}", e_value()),
        None if calibrated => format!("Decides by {}", boundary()),
        None => format!("Decides by {}", e_value()),
    }
}

#[cfg(test)]
#[path = "horizon_tests.rs"]
mod tests;

/// What a sequential comparison decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Decision {
    /// A succeeds more often than B (the e-value reached 1/α, A's side ahead).
    ABetter,
    /// B succeeds more often than A.
    BBetter,
    /// The confidence sequence of `rate(A) − rate(B)` lies inside (−δ, δ).
    NoDifferenceLargerThan(f64),
}

impl std::fmt::Display for Decision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Decision::ABetter => f.write_str("A better"),
            Decision::BBetter => f.write_str("B better"),
            Decision::NoDifferenceLargerThan(d) => {
                write!(f, "no difference larger than {d}")
            }
        }
    }
}
