//! Property tests of the boundary calibrated to a horizon: its exact type-I
//! error (dynamic programming) is ≤ α for every number of discordant pairs,
//! the DP agrees with brute-force enumeration and with simulation, and the
//! comparison and the simulation table decide by it.

use super::*;
use crate::sequential::SequentialComparison;
use crate::sequential_sim::{simulate, truncate, DecisionTable};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn the_exact_type_one_error_is_at_most_alpha_for_every_number_of_discordant_pairs() {
    for (alpha, horizon) in [(0.05, 480), (0.05, 60), (0.01, 200), (0.1, 7), (0.05, 1)] {
        let b = CalibratedBoundary::new(alpha, horizon);
        for m in 0..=horizon {
            let e = b.type_i_given(m);
            assert!(e <= alpha, "alpha {alpha}, N {horizon}, m {m}: {e}");
            // The same from the decision probabilities at q = ½, split evenly.
            let (up, down) = b.decision_probabilities(0.5, m);
            assert!((up + down - e).abs() < 1e-12, "m {m}: {up} + {down} vs {e}");
            assert!((up - down).abs() < 1e-12);
        }
        assert!(b.type_i_error() <= alpha);
        // Where it can decide at all, it spends nearly all of α (the running
        // share plus the last look; discreteness leaves a little).
        if horizon >= 60 {
            assert!(b.type_i_error() > 0.9 * alpha, "{}", b.type_i_error());
        }
    }
    // The bench's horizon: a repeated significance test at z ≈ 2.94.
    let b = CalibratedBoundary::new(0.05, 480);
    assert!((b.z() - 2.94).abs() < 0.01, "{}", b.z());
    assert_eq!(b.running_bound(100), Some(30));
    assert!(b.last_bound(200).unwrap() < b.running_bound(200).unwrap());
}

/// Every sign sequence of a short horizon, enumerated: the DP's exact
/// probabilities are the enumeration's.
#[test]
fn the_dynamic_programme_equals_brute_force_enumeration() {
    let horizon = 14;
    let b = CalibratedBoundary::new(0.1, horizon);
    for q in [0.5, 0.7] {
        for m in 1..=horizon {
            let (mut up, mut down) = (0.0, 0.0);
            for bits in 0u32..(1 << m) {
                let (mut w, mut l, mut p) = (0u64, 0u64, 1.0);
                let mut decided = None;
                for i in 0..m {
                    if bits >> i & 1 == 1 {
                        w += 1;
                        p *= q;
                    } else {
                        l += 1;
                        p *= 1.0 - q;
                    }
                    if decided.is_none() {
                        decided = b.decide(w, l, false);
                    }
                }
                let decided = decided.or_else(|| b.decide(w, l, true));
                match decided {
                    Some(Decision::ABetter) => up += p,
                    Some(Decision::BBetter) => down += p,
                    _ => {}
                }
            }
            let (dp_up, dp_down) = b.decision_probabilities(q, m);
            assert!(
                (up - dp_up).abs() < 1e-12 && (down - dp_down).abs() < 1e-12,
                "q {q}, m {m}: enumerated ({up}, {down}), DP ({dp_up}, {dp_down})"
            );
        }
    }
}

/// Seeded walks: the share decided within m steps matches the DP within
/// 4.5 standard errors, under the null and under an alternative.
#[test]
fn simulated_walks_decide_as_often_as_the_dynamic_programme_says() {
    let horizon = 120;
    let b = CalibratedBoundary::new(0.05, horizon);
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let runs = 20_000;
    for (q, ms) in [(0.5, [30, 120]), (0.62, [40, 120])] {
        for m in ms {
            let (mut up, mut down) = (0usize, 0usize);
            for _ in 0..runs {
                let (mut w, mut l) = (0u64, 0u64);
                let mut decided = None;
                for _ in 0..m {
                    if rng.random::<f64>() < q {
                        w += 1;
                    } else {
                        l += 1;
                    }
                    decided = b.decide(w, l, false);
                    if decided.is_some() {
                        break;
                    }
                }
                match decided.or_else(|| b.decide(w, l, true)) {
                    Some(Decision::ABetter) => up += 1,
                    Some(Decision::BBetter) => down += 1,
                    _ => {}
                }
            }
            let (pu, pd) = b.decision_probabilities(q, m);
            for (got, p) in [(up, pu), (down, pd)] {
                let se = (p * (1.0 - p) / runs as f64).sqrt().max(1e-4);
                let got = got as f64 / runs as f64;
                assert!((got - p).abs() < 4.5 * se, "q {q}, m {m}: {got} vs {p}");
            }
            if q == 0.5 {
                assert!(pu + pd <= 0.05);
            }
        }
    }
}

/// Whole comparisons with concordant pairs, equal rates: the share that
/// decides by the horizon is the DP's mixture over the number of discordant
/// pairs, `Σ_m Bin(m; N, p) · P₀(decision | m)`, and stays ≤ α.
#[test]
fn a_comparison_with_a_horizon_keeps_its_type_one_error_at_alpha() {
    let (horizon, runs) = (80usize, 4000);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for disc in [0.15, 0.6] {
        let mut decided = 0usize;
        let fresh = SequentialComparison::with_horizon(0.05, None, horizon);
        for _ in 0..runs {
            let mut test = fresh.clone();
            for _ in 0..horizon {
                let u: f64 = rng.random();
                let (a, b) = if u < disc / 2.0 {
                    (true, false)
                } else if u < disc {
                    (false, true)
                } else {
                    (u < 0.5 + disc / 2.0, u < 0.5 + disc / 2.0)
                };
                if test.observe(a, b).is_some() {
                    break;
                }
            }
            decided += test.decision().is_some() as usize;
        }
        let boundary = CalibratedBoundary::new(0.05, horizon);
        // Σ_m Bin(m; N, disc) P₀(decision | m).
        let mut pmf = vec![1.0];
        for _ in 0..horizon {
            let mut next = vec![0.0; pmf.len() + 1];
            for (k, p) in pmf.iter().enumerate() {
                next[k] += p * (1.0 - disc);
                next[k + 1] += p * disc;
            }
            pmf = next;
        }
        let exact: f64 = (0..=horizon)
            .map(|m| pmf[m] * boundary.type_i_given(m))
            .sum();
        assert!((boundary.type_i_at(disc) - exact).abs() < 1e-12);
        let got = decided as f64 / runs as f64;
        let se = (exact * (1.0 - exact) / runs as f64).sqrt();
        assert!(exact <= 0.05);
        assert!(
            (got - exact).abs() < 4.5 * se,
            "disc {disc}: {got} vs {exact}"
        );
    }
}

#[test]
fn the_table_and_the_comparison_decide_by_the_boundary_and_its_last_look() {
    let horizon = 150;
    let table = DecisionTable::with_horizon(0.05, horizon);
    assert_eq!(table.horizon(), Some(horizon));
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut last_looks = 0;
    let fresh = SequentialComparison::with_horizon(0.05, None, horizon);
    for _ in 0..400 {
        let mut test = fresh.clone();
        let (mut w, mut l) = (0usize, 0usize);
        for t in 1..=horizon {
            let u: f64 = rng.random();
            let (a, b) = (u < 0.16, (0.1..0.2).contains(&u));
            w += (a && !b) as usize;
            l += (b && !a) as usize;
            let d = test.observe(a, b);
            assert_eq!(d, table.at(t, w, l), "pair {t}: ({w}, {l})");
            if d.is_some() {
                last_looks += (t == horizon) as usize;
                assert_eq!(test.decided_at(), Some(t as u64));
                break;
            }
        }
    }
    assert!(last_looks > 0, "some runs are decided at the last look");
    // The simulation decides at the last look too, and never after N.
    let runs = simulate(&table, 0.16, 0.1, 3000, horizon, 5);
    assert!(runs
        .iter()
        .any(|r| r.pair as usize == horizon && r.decision.is_some()));
    assert!(runs.iter().all(|r| r.pair as usize <= horizon));
    let null = truncate(
        &simulate(&table, 0.2, 0.2, 3000, horizon, 6),
        horizon as u32,
    );
    assert!(null.a_better + null.b_better <= 0.05 + 4.5 * (0.05f64 * 0.95 / 3000.0).sqrt());
    // Past the horizon nothing more is decided; the e-value still moves.
    let mut test = SequentialComparison::with_horizon(0.05, None, 3);
    for _ in 0..3 {
        test.observe(true, true);
    }
    for _ in 0..20 {
        test.observe(true, false);
    }
    assert_eq!(test.decision(), None);
    assert!(test.eprocess().e_value() > 20.0);
}

#[test]
fn reports_say_which_rule_decides() {
    let line = rule_line(0.05, 60);
    assert!(
        line.starts_with("rule: boundary calibrated to 60 pairs: |w − l| ≥ ⌈2.683 √(w + l)⌉, last look at pair 60"),
        "{line}"
    );
    assert!(line.contains("anytime-valid"), "{line}");
    assert_eq!(rule_line(0.05, 0), "rule: the e-value reaching 1/α = 20");
}

#[test]
fn the_deciding_rule_is_named_with_its_guarantee() {
    let s = decided_by(0.05, 30, Some("A better"));
    assert!(
        s.starts_with("Decided by the boundary calibrated to 30 pairs"),
        "{s}"
    );
    assert!(s.contains("did not decide"), "{s}");
    let s = decided_by(0.05, MAX_HORIZON + 1, Some("B better"));
    assert!(
        s.starts_with("Decided by the e-value reaching 1/α = 20"),
        "{s}"
    );
    let s = decided_by(0.05, 30, Some("no difference larger than 0.1"));
    assert!(s.contains("confidence sequence"), "{s}");
    assert!(decided_by(0.05, 30, None).starts_with("Decides by the boundary"));
}
