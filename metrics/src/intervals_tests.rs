//! Properties of `crate::intervals`, the intervals that must agree with their
//! own p-values: the paired interval agrees with its p-value, intervals shrink
//! as states are added, contain their estimate, and are never of width 0 on
//! non-degenerate small samples.

use crate::compare::{compare_states, ContextSummary};
use crate::intervals::*;
use crate::{Bootstrap, EmptyContexts};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Per-state rates of `n` states × `m` rollouts, states at `p ± h`.
fn rates(rng: &mut ChaCha8Rng, n: usize, m: u32, p: f64, h: f64) -> Vec<u32> {
    (0..n)
        .map(|_| {
            let q = if rng.random_bool(0.5) { p + h } else { p - h };
            (0..m)
                .filter(|_| rng.random_bool(q.clamp(0.0, 1.0)))
                .count() as u32
        })
        .collect()
}

/// Random paired differences: n states, m rollouts, A and B correlated
/// through the state, B's rate scaled by a random ratio.
fn paired(rng: &mut ChaCha8Rng) -> (Vec<f64>, u32) {
    let n = rng.random_range(3..=60usize);
    let m = [1u32, 2, 3, 8][rng.random_range(0..4usize)];
    let p: f64 = rng.random_range(0.02..0.98);
    let r: f64 = rng.random_range(0.3..1.2f64);
    let d = (0..n)
        .map(|_| {
            let q: f64 = rng.random_range(0.0..1.0f64).min(p * 2.0).min(1.0);
            let ka = (0..m).filter(|_| rng.random_bool(q)).count() as f64;
            let kb = (0..m).filter(|_| rng.random_bool((q * r).min(1.0))).count() as f64;
            (ka - kb) / m as f64
        })
        .collect();
    (d, m)
}

#[test]
fn sign_flip_interval_agrees_with_its_p_value_on_random_paired_data() {
    let mut rng = ChaCha8Rng::seed_from_u64(51);
    let (mut with_interval, mut excluding_zero) = (0, 0);
    for case in 0..600 {
        let (d, _) = paired(&mut rng);
        let test = SignFlip::new(&d, 999, case);
        for confidence in [0.9, 0.95, 0.99] {
            let alpha = 1.0 - confidence;
            let p0 = test.p_value(0.0);
            match test.interval(confidence) {
                Ok(i) => {
                    with_interval += 1;
                    excluding_zero += !i.contains(0.0) as usize;
                    assert_eq!(
                        !i.contains(0.0),
                        p0 <= alpha,
                        "case {case} at {confidence}: {i:?} but p(0) = {p0}, d = {d:?}"
                    );
                    // The ends are the last shifts the test keeps.
                    assert!(test.p_value(i.low) > alpha && test.p_value(i.high) > alpha);
                    assert!(test.p_value(i.low - 1e-9) <= alpha, "case {case}");
                    assert!(test.p_value(i.high + 1e-9) <= alpha, "case {case}");
                }
                Err(NoInterval::TestCannotReject { smallest_p, .. }) => {
                    assert!(smallest_p > alpha && p0 > alpha, "case {case}");
                }
                Err(NoInterval::NoSpread { difference, .. }) => {
                    // Every d_s the same: 0 is rejected exactly when it is not
                    // that difference (and the test can reject at all).
                    assert!(d.iter().all(|x| (x - difference).abs() < 1e-9));
                    let can_reject = 2.0 / (1u64 << d.len().min(60)) as f64 <= alpha;
                    let rejects =
                        difference.abs() > 1e-9 && (can_reject || d.len() > EXACT_MAX_STATES);
                    if d.len() <= EXACT_MAX_STATES {
                        assert_eq!(p0 <= alpha, rejects, "case {case}: {d:?} p {p0}");
                    }
                }
                Err(e) => panic!("case {case}: {e}"),
            }
        }
    }
    // The cases exercise both outcomes.
    assert!(
        with_interval > 1000 && excluding_zero > 200,
        "{with_interval} {excluding_zero}"
    );
}

#[test]
fn sign_flip_segments_match_the_test_statistic_computed_directly() {
    // p(δ) from the segments equals #{ε : |Σ ε(d − δ)| ≥ |Σ (d − δ)|} / 2^n.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for case in 0..200 {
        let n = rng.random_range(2..=9usize);
        let d: Vec<f64> = (0..n)
            .map(|_| rng.random_range(-8i32..=8) as f64 / 8.0)
            .collect();
        let test = SignFlip::new(&d, 0, 0);
        for _ in 0..5 {
            // Shifts on a grid finer than the data's, so that ties occur.
            let delta = rng.random_range(-64i32..=64) as f64 / 64.0;
            let obs: f64 = d.iter().map(|x| x - delta).sum::<f64>().abs();
            let count = (0u32..1 << n)
                .filter(|mask| {
                    let t: f64 = d
                        .iter()
                        .enumerate()
                        .map(|(i, x)| {
                            if mask >> i & 1 == 1 {
                                delta - x
                            } else {
                                x - delta
                            }
                        })
                        .sum();
                    t.abs() >= obs - 1e-12
                })
                .count();
            let direct = count as f64 / (1u32 << n) as f64;
            assert_eq!(
                test.p_value(delta),
                direct,
                "case {case}, δ {delta}, d {d:?}"
            );
        }
    }
}

#[test]
fn a_comparison_prints_the_p_value_of_the_test_whose_inversion_is_its_interval() {
    // `compare_states` (d3il compare, the server's comparisons, every
    // robustness drop): its success-rate difference is `SignFlip`'s estimate,
    // p-value and interval, exact up to 14 states and Monte Carlo above; so
    // the interval excludes 0 exactly when p < 0.05. The same for the
    // conditional entropy where states without a success count as 0.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut given, mut excluding) = (0, 0);
    for case in 0..60u64 {
        let n = rng.random_range(3..=40usize);
        let a: Vec<u32> = rates(&mut rng, n, 8, 0.6, 0.3);
        let b: Vec<u32> = rates(&mut rng, n, 8, 0.45, 0.3);
        let ra: Vec<f64> = a.iter().map(|&k| k as f64 / 8.0).collect();
        let rb: Vec<f64> = b.iter().map(|&k| k as f64 / 8.0).collect();
        let summary = |r: &[f64], flip: bool| -> Vec<ContextSummary> {
            r.iter()
                .enumerate()
                .map(|(i, &x)| ContextSummary {
                    success_rate: x,
                    entropy: (flip == (i % 2 == 0)).then_some(x / 2.0),
                })
                .collect()
        };
        let cfg = Bootstrap {
            resamples: 999,
            confidence: 0.95,
            seed: case,
        };
        let (sa, sb) = (summary(&ra, false), summary(&rb, true));
        let [sr, h] = compare_states(&sa, &sb, 8, EmptyContexts::CountAsZero, &cfg).unwrap();
        let d: Vec<f64> = ra.iter().zip(&rb).map(|(x, y)| x - y).collect();
        let test = SignFlip::new(&d, cfg.resamples, cfg.seed);
        assert_eq!(sr.p_value, test.p_value(0.0), "case {case}");
        match test.interval(0.95) {
            Ok(i) => {
                assert_eq!(
                    sr.difference.interval(),
                    Some((i.low, i.high)),
                    "case {case}"
                );
                assert_eq!(sr.difference.method, Some(i.method));
                given += 1;
            }
            Err(why) => assert_eq!(sr.difference.no_interval, Some(why), "case {case}"),
        }
        for x in [&sr, &h] {
            match x.difference.interval() {
                Some((lo, hi)) => {
                    let outside = lo > 0.0 || hi < 0.0;
                    assert_eq!(outside, x.p_value <= 0.05, "case {case}: {x:?}");
                    excluding += outside as usize;
                    assert!(hi > lo, "case {case}: width 0: {x:?}");
                }
                None => assert!(n <= 5 || x.difference.no_interval.is_some()),
            }
        }
    }
    assert!(given > 40 && excluding > 5, "{given} {excluding}");
}

#[test]
fn the_issues_four_drops_through_the_comparison_get_no_interval_and_say_why() {
    // Issue 51: a Pushing BC policy, quick protocol suite, 3 states × 2
    // rollouts. Per-state rates of level 0 and of the level; the service
    // printed, e.g., `start_shift 2: drop +1.000, 95% CI +1.000 – +1.000,
    // p 0.2319`. Now: no interval, the reason, and the exact p-value.
    let s = |r: [f64; 3]| -> Vec<ContextSummary> {
        r.iter()
            .map(|&x| ContextSummary {
                success_rate: x,
                entropy: None,
            })
            .collect()
    };
    let cfg = Bootstrap {
        resamples: 2000,
        confidence: 0.95,
        seed: 0,
    };
    for (name, control, level, drop) in [
        ("latency 3", [0.5, 1.0, 0.5], [0.0, 1.0, 0.0], 1.0 / 3.0),
        ("dynamics 1", [0.5, 1.0, 0.5], [0.5, 0.5, 0.0], 1.0 / 3.0),
        ("start_shift 2", [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], 1.0),
        ("obs_noise 1", [1.0, 0.5, 1.0], [0.5, 0.0, 0.5], 0.5),
    ] {
        let [d, _] =
            compare_states(&s(control), &s(level), 2, EmptyContexts::CountAsZero, &cfg).unwrap();
        assert!((d.difference.value - drop).abs() < 1e-12, "{name}: {d:?}");
        assert_eq!(d.difference.interval(), None, "{name}: {d:?}");
        assert!(
            matches!(
                d.difference.no_interval,
                Some(NoInterval::TestCannotReject { states: 3, .. })
            ),
            "{name}: {d:?}"
        );
        assert!(d.p_value >= 0.25, "{name}: {d:?}");
        assert!(
            d.interval_note().contains("with 3 initial states"),
            "{name}: {}",
            d.interval_note()
        );
    }
}

#[test]
fn issue_51_three_state_drops_get_no_interval_and_their_exact_p_values() {
    // The issue's quick-protocol drops (3 states × 2 rollouts): the printed
    // intervals excluded 0 (or had width 0) beside p ≥ 0.23.
    for d in [
        [0.5, 0.0, 0.5],
        [0.0, 0.5, 0.5],
        [1.0, 1.0, 1.0],
        [0.5, 0.5, 0.5],
    ] {
        let test = SignFlip::new(&d, 1000, 0);
        assert!(test.p_value(0.0) >= 0.25, "{d:?}");
        assert!(
            matches!(
                test.interval(0.95),
                Err(NoInterval::TestCannotReject { states: 3, smallest_p }) if smallest_p == 0.25
            ),
            "{d:?}"
        );
    }
    // 2 of 3 states: no success-rate interval either.
    let s = [
        StateCount::new(2, 2),
        StateCount::new(2, 2),
        StateCount::new(0, 2),
    ];
    assert!(matches!(
        success_rate_interval(&s, 0.95, 1000, 0),
        Err(NoInterval::TooFewStates { states: 3, .. })
    ));
    // Five states cannot reject at 5 % (2/32 > 0.05), six can (2/64).
    assert!(SignFlip::new(&[1.0; 5], 0, 0).interval(0.95).is_err());
    let six = SignFlip::new(&[1.0, 1.0, 1.0, 1.0, 1.0, 0.5], 0, 0);
    let i = six.interval(0.95).unwrap();
    assert!(
        !i.contains(0.0) && six.p_value(0.0) <= 0.05 && i.width() > 0.0,
        "{i:?}"
    );
}

#[test]
fn intervals_shrink_as_states_are_added_at_the_same_rate() {
    // The same pattern of states repeated: 5, 10, 20, ... copies.
    let pattern = [3u32, 8, 5, 0, 6, 8, 2, 7, 4, 8];
    let mut last = f64::INFINITY;
    for n in [5usize, 10, 20, 40, 80, 160, 320] {
        let s: Vec<StateCount> = (0..n)
            .map(|i| StateCount::new(pattern[i % pattern.len()], 8))
            .collect();
        let i = success_rate_interval(&s, 0.95, 2000, 0).unwrap();
        assert!(
            i.width() < last,
            "{n} states: {i:?} not narrower than {last}"
        );
        last = i.width();
    }
    // One rollout a state: exact Clopper–Pearson, 40 % at every size.
    let mut last = f64::INFINITY;
    for n in [5usize, 10, 20, 40, 80, 160] {
        let s: Vec<StateCount> = (0..n)
            .map(|i| StateCount::new((i % 5 < 2) as u32, 1))
            .collect();
        let i = success_rate_interval(&s, 0.95, 2000, 0).unwrap();
        assert_eq!(i.method, Method::ClopperPearson);
        assert!(i.width() < last, "{n} states: {i:?}");
        last = i.width();
    }
    // All failures: [0, 1 − 0.025^(1/n)] shrinks too.
    let mut last = f64::INFINITY;
    for n in [5usize, 10, 30, 60] {
        let s = vec![StateCount::new(0, 8); n];
        let i = success_rate_interval(&s, 0.95, 2000, 0).unwrap();
        assert_eq!((i.low, i.method), (0.0, Method::ClopperPearsonAllEqual));
        assert!((i.high - (1.0 - 0.025f64.powf(1.0 / n as f64))).abs() < 1e-12);
        assert!(i.width() < last);
        last = i.width();
    }
    // Paired differences, repeated: exact at 6 and 12, Monte Carlo above.
    let pattern = [0.25, -0.125, 0.5, 0.0, 0.375, 0.125];
    let mut last = f64::INFINITY;
    for n in [6usize, 12, 24, 48, 96] {
        let d: Vec<f64> = (0..n).map(|i| pattern[i % pattern.len()]).collect();
        let i = SignFlip::new(&d, 2000, 0).interval(0.95).unwrap();
        assert!(
            i.width() < last,
            "{n} states: {i:?} not narrower than {last}"
        );
        last = i.width();
    }
}

#[test]
fn intervals_contain_their_estimate_and_have_width_on_non_degenerate_data() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for case in 0..400 {
        let n = rng.random_range(5..=70usize);
        let m = [1u32, 2, 8][rng.random_range(0..3usize)];
        let p: f64 = [0.02, 0.05, 0.2, 0.5, 0.8, 0.95, 0.98][rng.random_range(0..7usize)];
        let h = rng.random_range(0.0..1.0) * p.min(1.0 - p);
        let k = rates(&mut rng, n, m, p, h);
        let s: Vec<StateCount> = k.iter().map(|&k| StateCount::new(k, m)).collect();
        let i = success_rate_interval(&s, 0.95, 500, case).unwrap();
        let mean = k.iter().map(|&k| k as f64 / m as f64).sum::<f64>() / n as f64;
        assert!((i.estimate - mean).abs() < 1e-12);
        assert!(i.contains(i.estimate), "case {case}: {i:?}");
        // Rates: no width 0 ever, even when every state is 0 or 1.
        assert!(i.width() > 0.0, "case {case}: {i:?} from {k:?}");
        assert!(i.low >= 0.0 && i.high <= 1.0);

        let (d, _) = paired(&mut rng);
        let test = SignFlip::new(&d, 999, case);
        let constant = d.iter().all(|x| (x - d[0]).abs() < 1e-12);
        match test.interval(0.95) {
            Ok(i) => {
                assert!(i.contains(i.estimate), "case {case}: {i:?}");
                assert!(i.width() > 0.0, "case {case}: {i:?} from {d:?}");
                assert!(!constant);
            }
            Err(NoInterval::NoSpread { .. }) => assert!(constant, "case {case}"),
            Err(NoInterval::TestCannotReject { states, .. }) => assert!(states <= 5),
            Err(e) => panic!("case {case}: {e}"),
        }
    }
}

#[test]
fn methods_switch_by_the_documented_rule() {
    let st = |ks: &[u32], m: u32| -> Vec<StateCount> {
        ks.iter().map(|&k| StateCount::new(k, m)).collect()
    };
    let method = |s: &[StateCount]| success_rate_interval(s, 0.95, 1000, 0).unwrap().method;
    assert_eq!(method(&st(&[1, 0, 1, 1, 0], 1)), Method::ClopperPearson);
    assert_eq!(
        method(&st(&[8, 8, 8, 8, 8], 8)),
        Method::ClopperPearsonAllEqual
    );
    assert_eq!(method(&st(&[3, 5, 8, 0, 4, 6], 8)), Method::KornGraubard);
    let many: Vec<u32> = (0..BOOTSTRAP_MIN_STATES).map(|i| (i % 9) as u32).collect();
    assert_eq!(method(&st(&many, 8)), Method::ClusterBootstrap);
    let many: Vec<u32> = (1..BOOTSTRAP_MIN_STATES).map(|i| (i % 9) as u32).collect();
    assert_eq!(method(&st(&many, 8)), Method::KornGraubard);
    // Rare successes at many states stay with Korn–Graubard.
    let mut rare = vec![0u32; 2 * BOOTSTRAP_MIN_STATES];
    rare[3] = 1;
    rare[40] = 2;
    assert_eq!(method(&st(&rare, 8)), Method::KornGraubard);
    // The paired test: exact up to EXACT_MAX_STATES.
    let d: Vec<f64> = (0..EXACT_MAX_STATES)
        .map(|i| (i % 3) as f64 / 2.0)
        .collect();
    assert!(SignFlip::new(&d, 100, 0).is_exact());
    let d: Vec<f64> = (0..=EXACT_MAX_STATES)
        .map(|i| (i % 3) as f64 / 2.0)
        .collect();
    assert!(!SignFlip::new(&d, 100, 0).is_exact());
}

#[test]
fn special_functions_match_published_values() {
    // Student t (tables): t_{0.975, 1} = 12.7062, t_{0.975, 9} = 2.2622,
    // t_{0.975, 59} = 2.0010.
    for (df, t) in [(1.0, 12.7062), (9.0, 2.2622), (59.0, 2.0010)] {
        assert!((t_quantile(0.975, df) - t).abs() < 1e-3, "{df}");
    }
    // Clopper–Pearson: 2 of 3 is [0.0943, 0.9916]; 30 of 60 [0.3681, 0.6319].
    let (lo, hi) = clopper_pearson(2.0, 3.0, 0.05);
    assert!(
        (lo - 0.0943).abs() < 1e-4 && (hi - 0.9916).abs() < 1e-4,
        "{lo} {hi}"
    );
    let (lo, hi) = clopper_pearson(30.0, 60.0, 0.05);
    assert!(
        (lo - 0.3681).abs() < 1e-4 && (hi - 0.6319).abs() < 1e-4,
        "{lo} {hi}"
    );
    let (lo, hi) = clopper_pearson(0.0, 10.0, 0.05);
    assert_eq!(lo, 0.0);
    assert!((hi - (1.0 - 0.025f64.powf(0.1))).abs() < 1e-9);
    // I_x(a, b) symmetry and a closed form: I_x(1, b) = 1 − (1 − x)^b.
    assert!((incomplete_beta(0.3, 1.0, 4.0) - (1.0 - 0.7f64.powi(4))).abs() < 1e-12);
    assert!((incomplete_beta(0.3, 2.5, 1.5) + incomplete_beta(0.7, 1.5, 2.5) - 1.0).abs() < 1e-12);
}
