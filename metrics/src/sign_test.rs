//! The fixed-size test the sequential comparison (`crate::sequential`) is
//! measured against: the exact two-sided sign test on the discordant pairs
//! (exact McNemar), its critical values, exact power and the number of pairs
//! it needs for a given power.

use crate::quantile::normal_quantile;

/// The exact two-sided sign test on discordant pairs (exact McNemar) at
/// level α, for a fixed number of pairs: its critical values, power, and
/// the number of pairs it needs for a power.
#[derive(Debug, Clone)]
pub struct FixedPairedTest {
    alpha: f64,
    /// ln k! for k < len.
    ln_fact: Vec<f64>,
    /// `crit[D]`: A's wins among D discordant pairs from which the test
    /// rejects in A's favour (`D + 1` when it never does).
    crit: Vec<u64>,
}

impl FixedPairedTest {
    pub fn new(alpha: f64) -> Self {
        assert!(alpha > 0.0 && alpha < 1.0, "alpha {alpha} is not in (0, 1)");
        FixedPairedTest {
            alpha,
            ln_fact: vec![0.0],
            crit: vec![],
        }
    }

    fn grow(&mut self, n: usize) {
        while self.ln_fact.len() <= n {
            let k = self.ln_fact.len();
            let last = self.ln_fact[k - 1];
            self.ln_fact.push(last + (k as f64).ln());
        }
        while self.crit.len() <= n {
            let d = self.crit.len() as u64;
            // Smallest k > D/2 with 2·P(Bin(D, ½) ≥ k) ≤ α.
            let mut tail = 0.0;
            let mut k = d + 1;
            for j in (0..=d).rev() {
                let next = tail + self.pmf(d, j, 0.5);
                if 2 * j <= d || 2.0 * next > self.alpha {
                    break;
                }
                tail = next;
                k = j;
            }
            self.crit.push(k);
        }
    }

    fn pmf(&self, n: u64, k: u64, p: f64) -> f64 {
        let (n_, k_) = (n as usize, k as usize);
        let ln = self.ln_fact[n_] - self.ln_fact[k_] - self.ln_fact[n_ - k_]
            + if k == 0 { 0.0 } else { k as f64 * p.ln() }
            + if n == k {
                0.0
            } else {
                (n - k) as f64 * (1.0 - p).ln()
            };
        ln.exp()
    }

    /// The exact two-sided p-value of `wins_a` against `wins_b` discordant
    /// pairs: `min(1, 2·P(Bin(D, ½) ≥ max(w, D − w)))`.
    pub fn p_value(&mut self, wins_a: u64, wins_b: u64) -> f64 {
        let d = wins_a + wins_b;
        self.grow(d as usize);
        let k = wins_a.max(wins_b);
        let tail: f64 = (k..=d).map(|j| self.pmf(d, j, 0.5)).sum();
        (2.0 * tail).min(1.0)
    }

    /// Whether the test at `n` pairs rejects in A's favour.
    pub fn rejects_for_a(&mut self, wins_a: u64, wins_b: u64) -> bool {
        let d = wins_a + wins_b;
        self.grow(d as usize);
        wins_a >= self.crit[d as usize]
    }

    /// Probability that the test on `n` pairs decides "A better" when a pair
    /// is won by A with probability `p_a` and by B with `p_b` (concordant
    /// otherwise): `Σ_D Bin(D; n, p_a + p_b) · P(Bin(D, q) ≥ crit_D)`,
    /// `q = p_a / (p_a + p_b)`.
    pub fn power(&mut self, n: usize, p_a: f64, p_b: f64) -> f64 {
        let mut given_d = vec![];
        self.power_cached(n, p_a, p_b, &mut given_d)
    }

    /// [`Self::power`] with `given_d[D] = P(reject for A | D discordant)`
    /// kept between calls with the same `p_a`, `p_b`.
    fn power_cached(&mut self, n: usize, p_a: f64, p_b: f64, given_d: &mut Vec<f64>) -> f64 {
        let d = p_a + p_b;
        if n == 0 || d <= 0.0 {
            return 0.0;
        }
        self.grow(n);
        let q = p_a / d;
        let d = d.min(1.0);
        while given_d.len() <= n {
            let dd = given_d.len() as u64;
            let k = self.crit[dd as usize];
            given_d.push(if k > dd {
                0.0
            } else {
                self.upper_tail(dd, k, q)
            });
        }
        // Bin(n, d) outside mean ± 12 sd carries nothing at f64 precision.
        let (mean, sd) = (n as f64 * d, (n as f64 * d * (1.0 - d)).sqrt());
        let from = (mean - 12.0 * sd - 2.0).floor().max(0.0) as u64;
        let to = ((mean + 12.0 * sd + 2.0).ceil() as u64).min(n as u64);
        let total: f64 = (from..=to)
            .map(|dd| self.pmf(n as u64, dd, d) * given_d[dd as usize])
            .sum();
        total.min(1.0)
    }

    /// `P(Bin(n, q) ≥ k)`.
    fn upper_tail(&self, n: u64, k: u64, q: f64) -> f64 {
        if q >= 1.0 {
            return 1.0;
        }
        if q <= 0.0 {
            return if k == 0 { 1.0 } else { 0.0 };
        }
        (k..=n).map(|j| self.pmf(n, j, q)).sum()
    }

    /// The smallest number of pairs at which the test decides "A better"
    /// with probability at least `power` (`None` beyond `max_pairs`).
    pub fn pairs_for_power(
        &mut self,
        p_a: f64,
        p_b: f64,
        power: f64,
        max_pairs: usize,
    ) -> Option<usize> {
        if p_a <= p_b {
            return None;
        }
        // Start below the normal approximation (Connor 1987) and walk up:
        // power is not monotone in n for an exact test, so "smallest" needs
        // the walk, and the approximation only saves the first steps.
        let (d, diff) = (p_a + p_b, p_a - p_b);
        let za = normal_quantile(1.0 - self.alpha / 2.0);
        let zb = normal_quantile(power.clamp(0.5, 1.0 - 1e-12));
        let approx =
            (za * d.sqrt() + zb * (d - diff * diff).max(0.0).sqrt()).powi(2) / (diff * diff);
        let mut given_d = vec![];
        let start = ((0.5 * approx).floor() as usize).clamp(1, max_pairs.max(1));
        let start = if self.power_cached(start, p_a, p_b, &mut given_d) >= power {
            1
        } else {
            start
        };
        (start..=max_pairs).find(|&n| self.power_cached(n, p_a, p_b, &mut given_d) >= power)
    }
}
