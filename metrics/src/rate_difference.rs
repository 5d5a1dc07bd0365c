//! The difference of two success rates, A − B, by the design that measured
//! them (docs/intervals.md): which test's p-value is printed and which
//! interval, the test inverted, goes with it.
//!
//! * **One rollout a state** ([`ExactMcNemar`]): each state is a pair of
//!   binary outcomes, concordant (both succeed or both fail) or discordant
//!   (`x` won by A, `y` by B, `D = x + y`). The per-state differences are
//!   then −1, 0 or +1, where the sign-flip interval's shift model fails
//!   (its coverage fell to 66 % at 10 states and rates near 0 in `d3il bench
//!   intervals`). The p-value is the exact McNemar test, the conditional
//!   binomial `x ~ Bin(D, ½)` (McNemar 1947, Psychometrika 12, 153–157; the
//!   exact form in Agresti, *Categorical Data Analysis*, 3rd ed., §11.1),
//!   two-sided as twice the smaller tail, which is also what the sign-flip
//!   test of these differences gives. The difference is
//!   `δ = p_A − p_B = ψ(2q − 1)`, `ψ` the share of discordant states and
//!   `q` the share of them A wins. The interval is the image of the two
//!   Clopper–Pearson intervals, `q` of `x` in `D` (exact given `D`: the
//!   inversion of the conditional test whose value at `q = ½` is the
//!   printed p-value) and `ψ` of `D` in `n` (exact), through
//!   `(ψ, q) ↦ ψ(2q − 1)`. Since `ψ`'s lower bound is above 0 whenever
//!   `D ≥ 1`, the interval excludes 0 exactly when `q`'s excludes ½, i.e.
//!   exactly when `p ≤ α`: the interval and the printed p-value agree by
//!   construction. Coverage is at least `1 − 2α` by the union bound and
//!   measured above `1 − α` (the bench); with no discordant state it is
//!   `[−ψ_U, ψ_U]`, `ψ_U = 1 − (α/2)^(1/n)`, not a point. When the test
//!   cannot reject at all (`2/2^n > α`: 5 states or fewer at 95 %) there is
//!   no interval, as for the sign-flip test.
//! * **One initial state** ([`ScoreTwoSample`]; Avoiding): there is nothing
//!   to pair over; the rollouts of each arm are independent trials of its
//!   rate, and the two rates are compared as two samples. The p-value is the
//!   Miettinen–Nurminen score test (Miettinen & Nurminen 1985, Stat. Med. 4,
//!   213–226: the difference over its standard error at the rates' maximum
//!   likelihood under `p_A − p_B = δ`, with the factor `N/(N − 1)`; at
//!   `δ = 0` it is Pearson's χ² test times `(N − 1)/N`) and the interval is
//!   that test inverted, `{δ : p(δ) > α}`, found by bisection on the same
//!   `p(δ)`; the score statistic is monotone in `δ`, so 0 lies outside
//!   exactly when `p(0) ≤ α`. Not exact; its coverage is close to nominal
//!   (Newcombe 1998, Stat. Med. 17, 873–890, method 10) and measured in the
//!   bench. The rollouts of the two arms are treated as independent; the
//!   robustness suite runs both with the same policy noise, which can only
//!   correlate them positively and make the test conservative.
//! * **Otherwise** (several rollouts on each of several states): the inverted
//!   sign-flip test of [`crate::intervals::SignFlip`].

use crate::intervals::{
    clopper_pearson, incomplete_beta, paired_difference_interval, Interval, Method, NoInterval,
    PairedInterval,
};

/// The paired difference of success rates per state `a[i]`, `b[i]` (the
/// same state i, each the share of `rollouts_per_state` rollouts), with the
/// test and interval its design calls for (see the module documentation).
pub fn success_rate_difference(
    a: &[f64],
    b: &[f64],
    rollouts_per_state: usize,
    confidence: f64,
    resamples: usize,
    seed: u64,
) -> PairedInterval {
    assert_eq!(a.len(), b.len(), "paired rates of different lengths");
    let m = rollouts_per_state;
    // Successes of each state, when the rates are shares of m rollouts.
    let counts = |r: &[f64]| -> Option<Vec<u64>> {
        r.iter()
            .map(|&x| {
                let k = (x * m as f64).round();
                ((x * m as f64 - k).abs() < 1e-9 && (0.0..=m as f64).contains(&k))
                    .then_some(k as u64)
            })
            .collect()
    };
    if m >= 1 {
        if let (Some(ka), Some(kb)) = (counts(a), counts(b)) {
            if let ([x1], [x2]) = (&ka[..], &kb[..]) {
                return ScoreTwoSample::new(*x1, m as u64, *x2, m as u64)
                    .paired_interval(confidence);
            }
            if m == 1 && !ka.is_empty() {
                let x = ka.iter().zip(&kb).filter(|(a, b)| a > b).count() as u64;
                let y = ka.iter().zip(&kb).filter(|(a, b)| a < b).count() as u64;
                return ExactMcNemar::new(ka.len(), x, y).paired_interval(confidence);
            }
        }
    }
    paired_difference_interval(a, b, confidence, resamples, seed)
}

/// `P(X ≥ k)` and `P(X ≤ k)` for `X ~ Bin(n, q)` (regularised incomplete
/// beta, as [`clopper_pearson`] inverts them).
fn binomial_tails(k: u64, n: u64, q: f64) -> (f64, f64) {
    let (k, n) = (k as f64, n as f64);
    let upper = if k <= 0.0 {
        1.0
    } else {
        incomplete_beta(q, k, n - k + 1.0)
    };
    let lower = if k >= n {
        1.0
    } else {
        1.0 - incomplete_beta(q, k + 1.0, n - k)
    };
    (upper, lower)
}

/// The exact McNemar test on `n` states with one rollout each and its
/// inverted interval (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExactMcNemar {
    pub states: usize,
    /// Discordant states won by A and by B.
    pub a_wins: u64,
    pub b_wins: u64,
}

impl ExactMcNemar {
    pub fn new(states: usize, a_wins: u64, b_wins: u64) -> Self {
        assert!(
            (a_wins + b_wins) as usize <= states,
            "{a_wins} + {b_wins} discordant of {states} states"
        );
        ExactMcNemar {
            states,
            a_wins,
            b_wins,
        }
    }

    pub fn estimate(&self) -> f64 {
        if self.states == 0 {
            return 0.0;
        }
        (self.a_wins as f64 - self.b_wins as f64) / self.states as f64
    }

    /// Two-sided p-value of "no difference": twice the smaller tail of
    /// `Bin(D, ½)` at `x`, at most 1.
    pub fn p_value(&self) -> f64 {
        let (up, low) = binomial_tails(self.a_wins, self.a_wins + self.b_wins, 0.5);
        (2.0 * up.min(low)).min(1.0)
    }

    pub fn interval(&self, confidence: f64) -> Result<Interval, NoInterval> {
        assert!(
            confidence > 0.0 && confidence < 1.0,
            "confidence {confidence} is not in (0, 1)"
        );
        let n = self.states;
        if n == 0 {
            return Err(NoInterval::NoData);
        }
        let alpha = 1.0 - confidence;
        // All n states discordant one way gives the smallest p, 2/2^n.
        let smallest_p = 2f64.powi(1 - n.min(1000) as i32).min(1.0);
        if smallest_p > alpha {
            return Err(NoInterval::TestCannotReject {
                states: n,
                smallest_p,
            });
        }
        let d = self.a_wins + self.b_wins;
        // Clopper–Pearson's bisection starts at ½, so q's interval excludes
        // ½ exactly when a tail at ½ is below α/2: when p ≤ α.
        let (q_lo, q_hi) = clopper_pearson(self.a_wins as f64, d as f64, alpha);
        let (psi_lo, psi_hi) = clopper_pearson(d as f64, n as f64, alpha);
        let (lo, hi) = (2.0 * q_lo - 1.0, 2.0 * q_hi - 1.0);
        let estimate = self.estimate();
        Ok(Interval {
            estimate,
            low: (psi_lo * lo).min(psi_hi * lo).min(estimate),
            high: (psi_lo * hi).max(psi_hi * hi).max(estimate),
            method: Method::McNemarExact,
        })
    }

    /// The estimate, p-value and interval together.
    pub fn paired_interval(&self, confidence: f64) -> PairedInterval {
        PairedInterval {
            estimate: self.estimate(),
            p_value: self.p_value(),
            interval: self.interval(confidence),
        }
    }
}

/// A race's pairs (one a state, its rollout 0) compared as if their number
/// had been fixed in advance: the exact McNemar test on the discordant pairs
/// and its inverted interval at the race's level `alpha` ([`ExactMcNemar`]),
/// so 0 lies outside the interval exactly when `p ≤ alpha`. For reference
/// only: a race stops when its data say so, which neither allows for; the
/// race's decision is the sequential test's. The one computation behind the
/// race page, the race's JSON (`fixed_comparison`) and `d3il race`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixedSizeComparison {
    /// Pairs used.
    pub pairs: u64,
    /// The race's level.
    pub alpha: f64,
    /// A − B of the pairs' success rates, with its interval
    /// (`mcnemar_exact`) or the reason there is none.
    pub difference: d3il_protocol::Estimate,
    /// The exact McNemar test's two-sided p-value.
    pub p_value: f64,
}

/// [`FixedSizeComparison`] of `pairs_used` pairs with `discordant` (won by
/// A, won by B) at level `alpha`.
pub fn fixed_size_comparison(
    pairs_used: u64,
    discordant: (u64, u64),
    alpha: f64,
) -> FixedSizeComparison {
    let (x, y) = discordant;
    // A stored report's counts are the race's own; the max only keeps a
    // corrupt one from asserting.
    let pairs = pairs_used.max(x + y);
    let paired = ExactMcNemar::new(pairs as usize, x, y).paired_interval(1.0 - alpha);
    FixedSizeComparison {
        pairs,
        alpha,
        difference: paired.to_estimate(),
        p_value: paired.p_value,
    }
}

impl FixedSizeComparison {
    /// The comparison in words, with the note that neither the interval nor
    /// the p-value holds after the race's data-dependent stop (the race page
    /// and `d3il race` print this sentence).
    pub fn line(&self) -> String {
        let d = &self.difference;
        let interval = match d.interval() {
            Some(_) => format!(
                "{:.0} % interval {} ({})",
                100.0 * (1.0 - self.alpha),
                d.interval_text(3),
                d.interval_note()
            ),
            None => d.interval_note(),
        };
        format!(
            "Fixed-size comparison of the {} pairs used: A − B {:+.3}, {interval}, exact McNemar p-value {:.4} (0 lies outside the interval exactly when p ≤ {}; for reference: neither is valid after the race's data-dependent stop)",
            self.pairs, d.value, self.p_value, self.alpha
        )
    }
}

/// Two independent samples, `x1` successes of `n1` (A) and `x2` of `n2`
/// (B): the Miettinen–Nurminen score test of `p1 − p2 = δ` and its
/// inversion (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScoreTwoSample {
    pub x1: u64,
    pub n1: u64,
    pub x2: u64,
    pub n2: u64,
}

impl ScoreTwoSample {
    pub fn new(x1: u64, n1: u64, x2: u64, n2: u64) -> Self {
        assert!(
            x1 <= n1 && x2 <= n2 && n1 > 0 && n2 > 0,
            "{x1} of {n1} and {x2} of {n2}"
        );
        ScoreTwoSample { x1, n1, x2, n2 }
    }

    pub fn estimate(&self) -> f64 {
        self.x1 as f64 / self.n1 as f64 - self.x2 as f64 / self.n2 as f64
    }

    /// The maximum-likelihood rates under `p1 − p2 = δ` (the cubic's
    /// closed form, Miettinen & Nurminen 1985, appendix; Farrington &
    /// Manning 1990, Stat. Med. 9, 1447–1454).
    fn restricted(&self, delta: f64) -> (f64, f64) {
        let delta = delta.clamp(-1.0, 1.0);
        let (n1, n2) = (self.n1 as f64, self.n2 as f64);
        let (p1, p2) = (self.x1 as f64 / n1, self.x2 as f64 / n2);
        let theta = n2 / n1;
        let a = 1.0 + theta;
        let b = -(1.0 + theta + p1 + theta * p2 + delta * (theta + 2.0));
        let c = delta * delta + delta * (2.0 * p1 + theta + 1.0) + p1 + theta * p2;
        let d = -p1 * delta * (1.0 + delta);
        let v = b.powi(3) / (27.0 * a.powi(3)) - b * c / (6.0 * a * a) + d / (2.0 * a);
        let u = v.signum() * (b * b / (9.0 * a * a) - c / (3.0 * a)).max(0.0).sqrt();
        let ratio = v / u.powi(3);
        let ratio = if ratio.is_finite() {
            ratio.clamp(-1.0, 1.0)
        } else {
            1.0
        };
        let w = (std::f64::consts::PI + ratio.acos()) / 3.0;
        let r1 = (2.0 * u * w.cos() - b / (3.0 * a)).clamp(delta.max(0.0), (1.0 + delta).min(1.0));
        (r1, r1 - delta)
    }

    /// The score statistic at `δ` (0 where the difference is `δ` and the
    /// variance vanishes, ±∞ where only the variance does).
    pub fn z(&self, delta: f64) -> f64 {
        let (n1, n2) = (self.n1 as f64, self.n2 as f64);
        let n = n1 + n2;
        let diff = self.estimate() - delta;
        let (r1, r2) = self.restricted(delta);
        let v = (r1 * (1.0 - r1) / n1 + r2 * (1.0 - r2) / n2) * n / (n - 1.0).max(1.0);
        if diff.abs() < 1e-12 {
            0.0
        } else if v <= 0.0 {
            diff.signum() * f64::INFINITY
        } else {
            diff / v.sqrt()
        }
    }

    /// Two-sided p-value of "p1 − p2 = δ" (δ = 0: the one printed).
    pub fn p_value(&self, delta: f64) -> f64 {
        erfc(self.z(delta).abs() / std::f64::consts::SQRT_2).min(1.0)
    }

    /// `{δ : p(δ) > α}`, its ends found by bisection on `p` itself.
    pub fn interval(&self, confidence: f64) -> Interval {
        assert!(
            confidence > 0.0 && confidence < 1.0,
            "confidence {confidence} is not in (0, 1)"
        );
        let alpha = 1.0 - confidence;
        let keeps = |delta: f64| self.p_value(delta) > alpha;
        let estimate = self.estimate();
        // The last kept shift between the estimate (kept: p = 1) and `edge`.
        let end = |edge: f64| {
            if keeps(edge) {
                return edge;
            }
            let (mut inside, mut outside) = (estimate, edge);
            for _ in 0..200 {
                let mid = 0.5 * (inside + outside);
                if keeps(mid) {
                    inside = mid;
                } else {
                    outside = mid;
                }
                if (outside - inside).abs() < 1e-12 {
                    break;
                }
            }
            inside
        };
        Interval {
            estimate,
            low: end(-1.0),
            high: end(1.0),
            method: Method::ScoreTwoSample,
        }
    }

    /// The estimate, p-value of "no difference" and interval together.
    pub fn paired_interval(&self, confidence: f64) -> PairedInterval {
        PairedInterval {
            estimate: self.estimate(),
            p_value: self.p_value(0.0),
            interval: Ok(self.interval(confidence)),
        }
    }
}

/// The complementary error function (Numerical Recipes, 2nd ed., §6.2,
/// `erfcc`: Chebyshev fit, relative error below 1.2e-7), decreasing on
/// `x ≥ 0`; the score test's two-sided p-value is `erfc(|z|/√2)`.
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
#[path = "rate_difference_tests.rs"]
mod tests;
