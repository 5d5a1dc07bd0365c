//! Properties of `crate::rate_difference`: each interval agrees with the
//! p-value printed beside it, contains its estimate and has width; the
//! exact McNemar p-value is the sign test's; the score interval matches
//! published values; the design picks the method.

use super::*;
use crate::intervals::SignFlip;
use crate::sign_test::FixedPairedTest;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn mcnemar_interval_agrees_with_its_p_value_on_random_pairs() {
    let mut rng = ChaCha8Rng::seed_from_u64(47);
    let (mut given, mut excluding) = (0, 0);
    let mut fixed = FixedPairedTest::new(0.05);
    for case in 0..1500 {
        let n = rng.random_range(1..=150usize);
        // Discordant shares from none to all, lopsided or balanced.
        let psi: f64 = rng.random_range(0.0..1.0);
        let q: f64 = [0.5, 0.7, 0.9, 1.0, rng.random_range(0.0..1.0)][rng.random_range(0..5usize)];
        let (mut x, mut y) = (0u64, 0u64);
        for _ in 0..n {
            if rng.random_bool(psi) {
                if rng.random_bool(q) {
                    x += 1
                } else {
                    y += 1
                }
            }
        }
        let t = ExactMcNemar::new(n, x, y);
        let p = t.p_value();
        // The exact sign test on the discordant pairs (the races' fixed-size
        // test), and for few states the sign-flip test of the ±1/0 differences.
        assert!(
            (p - fixed.p_value(x, y)).abs() < 1e-10,
            "case {case}: {x} {y}"
        );
        if n <= 14 {
            let d: Vec<f64> = (0..n)
                .map(|i| {
                    if (i as u64) < x {
                        1.0
                    } else if (i as u64) < x + y {
                        -1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            assert!((p - SignFlip::new(&d, 0, 0).p_value(0.0)).abs() < 1e-10);
        }
        for confidence in [0.9, 0.95, 0.99] {
            match t.interval(confidence) {
                Ok(i) => {
                    given += 1;
                    let outside = !i.contains(0.0);
                    excluding += outside as usize;
                    assert_eq!(
                        outside,
                        p <= 1.0 - confidence,
                        "case {case} at {confidence}: {i:?}, p {p}, {x}:{y} of {n}"
                    );
                    assert!(i.contains(i.estimate) && i.width() > 0.0, "{i:?}");
                    assert!(i.low >= -1.0 && i.high <= 1.0, "{i:?}");
                    assert_eq!(i.method, Method::McNemarExact);
                }
                Err(NoInterval::TestCannotReject { states, smallest_p }) => {
                    assert_eq!((states, smallest_p), (n, 2f64.powi(1 - n as i32).min(1.0)));
                    assert!(smallest_p > 1.0 - confidence && p > 1.0 - confidence);
                }
                Err(e) => panic!("case {case}: {e}"),
            }
        }
    }
    assert!(given > 3000 && excluding > 500, "{given} {excluding}");
}

#[test]
fn mcnemar_without_discordant_states_is_an_interval_not_a_point() {
    // 30 states, both succeed (or both fail) on every one: the difference
    // is 0 with p = 1, and the interval is what 0 discordant states of 30
    // allow, [−ψ_U, ψ_U] with ψ_U = 1 − 0.025^(1/30).
    let t = ExactMcNemar::new(30, 0, 0);
    assert_eq!(t.p_value(), 1.0);
    let i = t.interval(0.95).unwrap();
    let psi = 1.0 - 0.025f64.powf(1.0 / 30.0);
    assert!(
        (i.high - psi).abs() < 1e-9 && (i.low + psi).abs() < 1e-9,
        "{i:?}"
    );
    // Three states: the test cannot reject, so no interval.
    assert!(matches!(
        ExactMcNemar::new(3, 3, 0).interval(0.95),
        Err(NoInterval::TestCannotReject { states: 3, smallest_p }) if smallest_p == 0.25
    ));
}

#[test]
fn score_interval_matches_published_values() {
    // Newcombe 1998 (Stat. Med. 17, 873-890), Table II, method 10
    // (Miettinen-Nurminen): 56/70 − 48/80 and 9/10 − 3/10.
    for (x1, n1, x2, n2, lo, hi) in [
        (56, 70, 48, 80, 0.0528, 0.3382),
        (9, 10, 3, 10, 0.1700, 0.8406),
    ] {
        let i = ScoreTwoSample::new(x1, n1, x2, n2).interval(0.95);
        assert!(
            (i.low - lo).abs() < 6e-4 && (i.high - hi).abs() < 6e-4,
            "{x1}/{n1} − {x2}/{n2}: {i:?}"
        );
    }
    // At δ = 0 the score statistic is Pearson's χ² times (N − 1)/N.
    let t = ScoreTwoSample::new(56, 70, 48, 80);
    let (a, b, c, d) = (56.0, 14.0, 48.0, 32.0);
    let n: f64 = a + b + c + d;
    let chi2 = n * (a * d - b * c) * (a * d - b * c) / ((a + b) * (c + d) * (a + c) * (b + d));
    assert!((t.z(0.0).powi(2) - chi2 * (n - 1.0) / n).abs() < 1e-9);
}

#[test]
fn score_interval_agrees_with_its_p_value_and_p_falls_away_from_the_estimate() {
    let mut rng = ChaCha8Rng::seed_from_u64(53);
    let (mut excluding, mut cases) = (0, 0);
    for case in 0..800 {
        let n = [2u64, 8, 30, 480][rng.random_range(0..4usize)];
        let (p1, p2): (f64, f64) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
        let x1 = (0..n).filter(|_| rng.random_bool(p1)).count() as u64;
        let x2 = (0..n).filter(|_| rng.random_bool(p2)).count() as u64;
        let t = ScoreTwoSample::new(x1, n, x2, n);
        let p0 = t.p_value(0.0);
        for confidence in [0.9, 0.95, 0.99] {
            let i = t.interval(confidence);
            cases += 1;
            let outside = !i.contains(0.0);
            excluding += outside as usize;
            assert_eq!(
                outside,
                p0 <= 1.0 - confidence,
                "case {case}: {x1}/{n} − {x2}/{n}: {i:?}, p {p0}"
            );
            assert!(
                i.contains(i.estimate) && i.width() > 0.0,
                "case {case}: {i:?}"
            );
            assert!(i.low >= -1.0 && i.high <= 1.0);
        }
        // p(δ) does not rise moving away from the estimate (a grid of 50).
        let e = t.estimate();
        for side in [-1.0, 1.0] {
            let edge = if side > 0.0 { 1.0 } else { -1.0 };
            let mut last = 1.0 + 1e-12;
            for k in 0..=50 {
                let delta = e + (edge - e) * k as f64 / 50.0;
                let p = t.p_value(delta);
                assert!(
                    p <= last + 1e-9,
                    "case {case}: p({delta}) = {p} after {last}"
                );
                last = p;
            }
        }
    }
    assert!(
        excluding > 300 && excluding < cases,
        "{excluding} of {cases}"
    );
}

#[test]
fn the_design_picks_the_test() {
    let cfg = (0.95, 999, 0);
    // One rollout a state: exact McNemar on the discordant states.
    let a = [1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 0.0];
    let b = [0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0];
    let d = success_rate_difference(&a, &b, 1, cfg.0, cfg.1, cfg.2);
    assert_eq!(d.interval.unwrap().method, Method::McNemarExact);
    assert_eq!(d.p_value, ExactMcNemar::new(10, 4, 1).p_value());
    assert!((d.estimate - 0.3).abs() < 1e-12);
    // One initial state: the rollouts as two samples.
    let d = success_rate_difference(&[0.75], &[0.25], 8, cfg.0, cfg.1, cfg.2);
    let i = d.interval.unwrap();
    assert_eq!(i.method, Method::ScoreTwoSample);
    assert_eq!(d.p_value, ScoreTwoSample::new(6, 8, 2, 8).p_value(0.0));
    assert!((d.estimate - 0.5).abs() < 1e-12 && i.low < 0.5 && i.high > 0.5);
    // Several rollouts on several states: the sign-flip test.
    let a = [0.5, 1.0, 0.25, 0.75, 1.0, 0.5, 0.0];
    let b = [0.25, 0.5, 0.25, 0.5, 0.75, 0.75, 0.0];
    let d = success_rate_difference(&a, &b, 4, cfg.0, cfg.1, cfg.2);
    assert_eq!(d.interval.unwrap().method, Method::SignFlipExact);
}
