//! Property tests of the anytime-valid statistics, as seeded Monte Carlo
//! loops: coverage at every look, type-I error, the supermartingale property.

use super::*;
use crate::sequential_sim::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Draws a pair with A winning with probability `p10`, B with `p01`, and
/// both succeeding in half of the concordant rest.
fn draw_pair(rng: &mut ChaCha8Rng, p10: f64, p01: f64) -> (bool, bool) {
    let u: f64 = rng.random();
    if u < p10 {
        (true, false)
    } else if u < p10 + p01 {
        (false, true)
    } else {
        let both = rng.random_bool(0.5);
        (both, both)
    }
}

#[test]
fn the_confidence_sequence_covers_the_true_rate_at_every_look() {
    let alpha = 0.1;
    let (sequences, looks) = (300, 250);
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    for rate in [0.05, 0.3, 0.5, 0.9] {
        let mut missed = 0;
        let mut width_at_end = 0.0;
        for _ in 0..sequences {
            let mut cs = BettingCs::with_grid(alpha, 201);
            assert_eq!(cs.interval(), (0.0, 1.0));
            let mut ever_missed = false;
            for _ in 0..looks {
                cs.update(rng.random_bool(rate) as u8 as f64);
                let (lo, hi) = cs.interval();
                assert!(lo <= hi, "{lo} > {hi}");
                if !(lo <= rate && rate <= hi) {
                    ever_missed = true;
                }
            }
            missed += ever_missed as usize;
            let (lo, hi) = cs.interval();
            width_at_end += (hi - lo) / sequences as f64;
        }
        let miss_rate = missed as f64 / sequences as f64;
        // Sampling noise of a rate ≤ 0.1 over 300 sequences is ≤ 0.017; the
        // betting sequence is conservative and rarely misses at all.
        assert!(
            miss_rate <= alpha,
            "rate {rate}: the sequence missed at some look in {miss_rate} of the runs"
        );
        // And it is not trivially wide: after 250 looks a success rate is
        // pinned to within about ±0.1 (wider near ½).
        assert!(
            width_at_end < 0.3,
            "rate {rate}: mean width {width_at_end} after {looks} looks"
        );
    }
}

#[test]
fn the_confidence_sequence_only_narrows_and_shrinks_like_one_over_root_n() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut cs = BettingCs::new(0.05);
    let mut last = (0.0, 1.0);
    let mut width_100 = 0.0;
    for t in 1..=1600 {
        cs.update(rng.random_bool(0.4) as u8 as f64);
        let now = cs.interval();
        assert!(now.0 >= last.0 && now.1 <= last.1, "{last:?} -> {now:?}");
        last = now;
        if t == 100 {
            width_100 = now.1 - now.0;
        }
    }
    let width_1600 = last.1 - last.0;
    // 16 times the data: about a quarter of the width (log factors aside).
    assert!(
        width_1600 < 0.4 * width_100 && width_1600 > 0.15 * width_100,
        "{width_100} -> {width_1600}"
    );
    assert_eq!(cs.n(), 1600);
}

#[test]
fn the_mixture_e_process_is_a_nonnegative_supermartingale_under_the_null() {
    // Exactly, step by step: E[E(w', l') | w, l] ≤ E(w, l) when A and B win
    // a discordant pair equally often (and = when the bet is symmetric).
    for w in 0..40u64 {
        for l in 0..40u64 {
            let now = mixture_e_value(w, l);
            assert!(now > 0.0 && now.is_finite());
            let next = 0.5 * mixture_e_value(w + 1, l) + 0.5 * mixture_e_value(w, l + 1);
            assert!(next <= now * (1.0 + 1e-12), "({w}, {l}): {now} -> {next}");
            // B winning more often: A's one-sided e-process loses in expectation.
            let next_b = 0.3 * mixture_e_value(w + 1, l) + 0.7 * mixture_e_value(w, l + 1);
            assert!(next_b < now, "({w}, {l})");
        }
    }
    assert_eq!(mixture_e_value(0, 0), 1.0);
    // And in Monte Carlo over whole sequences: the mean two-sided e-value
    // stays at 1 (it is a martingale) at every look.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (runs, looks) = (20_000, 20);
    let mut mean = vec![0.0; looks];
    for _ in 0..runs {
        let mut e = PairedEProcess::new();
        for m in mean.iter_mut() {
            let (a, b) = draw_pair(&mut rng, 0.2, 0.2);
            e.observe(a, b);
            let v = e.e_value();
            assert!(v >= 0.0);
            *m += v / runs as f64;
        }
    }
    for (t, m) in mean.iter().enumerate() {
        assert!(*m < 1.1, "mean e-value {m} at look {}", t + 1);
    }
}

#[test]
fn type_one_error_stays_below_alpha_under_equal_rates() {
    let alpha = 0.05;
    let (runs, pairs) = (2000, 300);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (rate, discordance) in [(0.5, 0.5), (0.3, 0.1), (0.9, 0.18)] {
        let (p10, p01) = discordant_probabilities(rate, rate, discordance);
        assert_eq!(p10, p01);
        let mut rejected = 0;
        for _ in 0..runs {
            let mut test = SequentialComparison::new(alpha, None);
            for _ in 0..pairs {
                if test.observe_pair(draw_pair(&mut rng, p10, p01)).is_some() {
                    break;
                }
            }
            if matches!(test.decision(), Some(Decision::ABetter | Decision::BBetter)) {
                rejected += 1;
            }
        }
        let rate_i = rejected as f64 / runs as f64;
        assert!(
            rate_i <= alpha,
            "rate {rate}, discordance {discordance}: rejected {rate_i}"
        );
    }
}

#[test]
fn a_worse_a_is_declared_better_at_most_alpha_of_the_time_and_a_clear_difference_is_found() {
    let alpha = 0.05;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (runs, pairs) = (1000, 200);
    let (mut wrong, mut found, mut used) = (0, 0, 0u64);
    for _ in 0..runs {
        // B succeeds more often: "A better" is the wrong answer.
        let mut worse = SequentialComparison::new(alpha, None);
        let (p10, p01) = discordant_probabilities(0.5, 0.55, 0.2);
        for _ in 0..pairs {
            if worse.observe_pair(draw_pair(&mut rng, p10, p01)).is_some() {
                break;
            }
        }
        wrong += (worse.decision() == Some(Decision::ABetter)) as usize;
        // A clearly better, paired.
        let mut better = SequentialComparison::new(alpha, None);
        let (p10, p01) = discordant_probabilities(0.8, 0.5, 0.35);
        for _ in 0..pairs {
            if better.observe_pair(draw_pair(&mut rng, p10, p01)).is_some() {
                break;
            }
        }
        if better.decision() == Some(Decision::ABetter) {
            found += 1;
            used += better.decided_at().unwrap();
        }
    }
    assert!(wrong as f64 / runs as f64 <= alpha, "{wrong}");
    assert!(found as f64 / runs as f64 > 0.95, "{found}");
    // A difference of 0.3 with 35 % discordant pairs needs a few dozen pairs.
    let mean_used = used as f64 / found as f64;
    assert!(mean_used < 80.0, "{mean_used}");
}

#[test]
fn the_anytime_p_value_is_one_over_the_running_maximum_e_value() {
    let mut e = PairedEProcess::new();
    assert_eq!(e.p_value(), 1.0);
    let mut max_e: f64 = 1.0;
    for (a, b) in [(true, false); 6]
        .into_iter()
        .chain([(false, true); 8])
        .chain([(true, true); 3])
    {
        e.observe(a, b);
        max_e = max_e.max(e.e_value());
        assert!((e.p_value() - (1.0 / max_e).min(1.0)).abs() < 1e-15);
    }
    assert!(e.p_value() < 1.0);
    // The running maximum was reached earlier than the end.
    assert!(e.e_value() < max_e);
    assert_eq!(e.discordant(), (6, 8));
    assert_eq!(e.pairs(), 17);
}

#[test]
fn no_difference_is_declared_when_the_difference_interval_fits_inside_the_margin() {
    let alpha = 0.05;
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    // Equal rates, few discordant pairs: decided "no difference > 0.2".
    let (p10, p01) = discordant_probabilities(0.6, 0.6, 0.05);
    let mut test = SequentialComparison::new(alpha, Some(0.2));
    let mut n = 0;
    while test.decision().is_none() && n < 2000 {
        test.observe_pair(draw_pair(&mut rng, p10, p01));
        n += 1;
    }
    assert_eq!(test.decision(), Some(Decision::NoDifferenceLargerThan(0.2)));
    let (lo, hi) = test.difference_interval().unwrap();
    assert!(-0.2 < lo && hi < 0.2, "{lo} {hi}");
    // A true difference of 0.25: "no difference larger than 0.2" is wrong,
    // and is said at most α of the time.
    let (p10, p01) = discordant_probabilities(0.6, 0.35, 0.3);
    let runs = 500;
    let mut wrong = 0;
    for _ in 0..runs {
        let mut t = SequentialComparison::new(alpha, Some(0.2));
        for _ in 0..400 {
            if t.observe_pair(draw_pair(&mut rng, p10, p01)).is_some() {
                break;
            }
        }
        wrong += matches!(t.decision(), Some(Decision::NoDifferenceLargerThan(_))) as usize;
    }
    assert!(wrong as f64 / runs as f64 <= alpha, "{wrong}");
}

#[test]
fn the_fixed_sign_test_has_exact_p_values_and_critical_values() {
    let mut t = FixedPairedTest::new(0.05);
    assert!((t.p_value(10, 0) - 2.0 / 1024.0).abs() < 1e-12);
    assert_eq!(t.p_value(3, 3), 1.0);
    // 5 of 5 discordant pairs: p = 2/32 = 0.0625, never rejected.
    assert!(!t.rejects_for_a(5, 0));
    // 6 of 6: p = 2/64.
    assert!(t.rejects_for_a(6, 0));
    assert!(!t.rejects_for_a(0, 6));
    // The critical value agrees with the p-value everywhere.
    for d in 0..60u64 {
        for w in 0..=d {
            let by_p = t.p_value(w, d - w) <= 0.05 && 2 * w > d;
            assert_eq!(t.rejects_for_a(w, d - w), by_p, "{w} of {d}");
        }
    }
}

#[test]
fn the_fixed_test_power_matches_simulation_and_its_sample_size_is_the_smallest() {
    let mut t = FixedPairedTest::new(0.05);
    let (p10, p01) = discordant_probabilities(0.7, 0.5, 0.3);
    let n = 60;
    let exact = t.power(n, p10, p01);
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let runs = 20_000;
    let mut hits = 0;
    for _ in 0..runs {
        let (mut w, mut l) = (0, 0);
        for _ in 0..n {
            match draw_pair(&mut rng, p10, p01) {
                (true, false) => w += 1,
                (false, true) => l += 1,
                _ => {}
            }
        }
        hits += t.rejects_for_a(w, l) as usize;
    }
    let sim = hits as f64 / runs as f64;
    assert!(
        (sim - exact).abs() < 0.015,
        "exact {exact}, simulated {sim}"
    );

    let need = t.pairs_for_power(p10, p01, 0.8, 10_000).unwrap();
    assert!(t.power(need, p10, p01) >= 0.8);
    for m in 1..need {
        assert!(
            t.power(m, p10, p01) < 0.8,
            "{m} < {need} already has the power"
        );
    }
    // Near the normal approximation (Connor 1987): d = 0.3, Δ = 0.2 gives
    // (1.96·√0.3 + 0.84·√0.26)² / 0.04 ≈ 57.
    assert!((45..75).contains(&need), "{need}");
    assert_eq!(t.pairs_for_power(p01, p10, 0.8, 10_000), None);
}

#[test]
fn discordance_is_clamped_to_what_the_rates_allow() {
    let (a, b) = discordant_probabilities(0.8, 0.5, 0.1);
    assert!((a - 0.3).abs() < 1e-12 && b.abs() < 1e-12);
    let (a, b) = discordant_probabilities(0.9, 0.8, 0.9);
    // At most 2 − 0.9 − 0.8 = 0.3 discordant.
    assert!((a + b - 0.3).abs() < 1e-12 && (a - b - 0.1).abs() < 1e-12);
    assert!((independent_discordance(0.5, 0.5) - 0.5).abs() < 1e-12);
}

#[test]
fn the_table_simulation_decides_as_the_comparison_does() {
    let table = DecisionTable::new(0.05, 200);
    for w in 0..=120usize {
        for l in 0..=(200 - w) {
            assert_eq!(
                table.get(w, l),
                e_value_decision(w as u64, l as u64, 0.05),
                "({w}, {l})"
            );
        }
    }
    assert_eq!(table.get(300, 0), None);
    // Pair by pair, the comparison stops where the table says.
    let mut rng = ChaCha8Rng::seed_from_u64(29);
    for _ in 0..200 {
        let mut test = SequentialComparison::new(0.05, None);
        let (mut w, mut l) = (0, 0);
        for t in 1..=200u64 {
            let (a, b) = draw_pair(&mut rng, 0.25, 0.1);
            w += (a && !b) as usize;
            l += (b && !a) as usize;
            let d = test.observe(a, b);
            assert_eq!(d, table.get(w, l), "pair {t}: ({w}, {l})");
            if d.is_some() {
                assert_eq!(test.decided_at(), Some(t));
                break;
            }
        }
    }
    let runs = simulate(&table, 0.3, 0.05, 2000, 200, 1);
    let sim = truncate(&runs, 200);
    assert!(sim.a_better > 0.9 && sim.b_better < 0.01, "{sim:?}");
    assert!(sim.mean_pairs > 10.0 && sim.mean_pairs < 120.0, "{sim:?}");
    // Truncating earlier: fewer decisions, fewer pairs.
    let short = truncate(&runs, 30);
    assert!(short.a_better < sim.a_better && short.mean_pairs < sim.mean_pairs);
    assert!(short.mean_pairs <= 30.0);
    let null = truncate(&simulate(&table, 0.2, 0.2, 2000, 200, 2), 200);
    assert!(null.a_better + null.b_better <= 0.05, "{null:?}");
}

#[test]
fn a_replay_stops_at_the_decision_in_a_seeded_order() {
    // 200 pairs: A wins 40 discordant pairs, B wins 5, 155 concordant.
    let mut pairs = vec![(true, false); 40];
    pairs.extend([(false, true); 5]);
    pairs.extend([(true, true); 100]);
    pairs.extend([(false, false); 55]);
    let r = replay(&pairs, 0.05, None, 3);
    assert_eq!(r.decision.as_deref(), Some("A better"));
    let used = r.decided_at.unwrap();
    assert_eq!(r.pairs_used, used);
    assert!(used < 200, "{used}");
    assert!(r.e_value >= 20.0 && r.p_value <= 0.05, "{r:?}");
    assert_eq!(r.pairs_total, 200);
    assert!(r.fixed_p_value < 1e-6);
    assert!((r.rate_a - 0.7).abs() < 1e-12 && (r.rate_b - 0.525).abs() < 1e-12);
    // The same seed, the same order; another seed, (almost surely) another.
    assert_eq!(replay(&pairs, 0.05, None, 3), r);
    assert!((0..5).any(|s| replay(&pairs, 0.05, None, 10 + s).decided_at != Some(used)));
    // Nothing to tell apart: no decision, all pairs used, p-value 1.
    let same = vec![(true, true); 50];
    let r = replay(&same, 0.05, None, 0);
    assert_eq!((r.decision, r.pairs_used, r.p_value), (None, 50, 1.0));
}

#[test]
fn copies_of_a_deterministic_rollout_are_one_pair_per_initial_state() {
    let (tf, tt, ff) = ((true, false), (true, true), (false, false));
    // Three states, two rollouts each, copies within every state.
    let states = [0, 0, 1, 1, 2, 2];
    let pairs = vec![tf, tf, tt, tt, ff, ff];
    assert_eq!(
        one_pair_per_state_if_copies(&states, pairs),
        (vec![tf, tt, ff], true)
    );
    // One rollout of state 1 differs: every rollout is a pair.
    let pairs = vec![tf, tf, tt, ff, ff, ff];
    assert_eq!(
        one_pair_per_state_if_copies(&states, pairs.clone()),
        (pairs, false)
    );
}
