//! Statistical properties of the intervals and of the paired comparison,
//! checked on simulated data from known distributions.

use super::*;
use crate::compare::{compare_states, ContextSummary};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

// The model (kinds of state, datasets and the values the estimates target)
// is `d3il bench intervals`' too.
use crate::interval_sim::{draw_index as draw, simulate, truth, Kind};

fn h(p: &[f64], base: usize) -> f64 {
    -p.iter()
        .filter(|&&x| x > 0.0)
        .map(|x| x * x.ln())
        .sum::<f64>()
        / (base as f64).ln()
}

/// The entropies of the behaviour distributions themselves (infinitely many
/// rollouts per state), for the record: (behaviour, conditional).
fn limit_entropies(kinds: &[Kind], n_behaviours: usize) -> [f64; 2] {
    let n = kinds.len() as f64;
    let sr = kinds.iter().map(|k| k.success).sum::<f64>() / n;
    let width = kinds[0].behaviours.len();
    let pooled: Vec<f64> = (0..width)
        .map(|i| {
            kinds
                .iter()
                .map(|k| k.success * k.behaviours[i])
                .sum::<f64>()
                / (sr * n)
        })
        .collect();
    let cond = kinds
        .iter()
        .map(|k| h(&k.behaviours, n_behaviours))
        .sum::<f64>()
        / n;
    [h(&pooled, n_behaviours), cond]
}

/// Fraction of `datasets` simulated datasets whose 95 % interval covers the
/// true value, per statistic; also checks every interval contains its estimate.
fn coverage(
    kinds: &[Kind],
    task: TaskId,
    n_ctx: usize,
    per_ctx: usize,
    datasets: usize,
) -> [f64; 3] {
    let conv = EntropyConvention::for_task(task);
    let t = truth(kinds, &conv, n_ctx, per_ctx, 4000);
    let limit = limit_entropies(kinds, conv.n_behaviours);
    // The plug-in at this size sits below the limit (fewer distinct
    // behaviours seen), never above it.
    assert!(
        t[1] <= limit[0] + 1e-3 && t[2] <= limit[1] + 1e-3,
        "{t:?} {limit:?}"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let mut hits = [0usize; 3];
    for d in 0..datasets {
        let data = simulate(&mut rng, kinds, n_ctx, per_ctx);
        let cfg = Bootstrap {
            resamples: 400,
            confidence: 0.95,
            seed: d as u64,
        };
        // The evaluation's own path: a one-start task's success rate is
        // Clopper-Pearson on its rollouts there, not the rule over states.
        let m = evaluate(task, &data, 0.0, &cfg).unwrap().metrics;
        let est = [m.success_rate, m.behaviour_entropy, m.conditional_entropy];
        for i in 0..3 {
            let e = est[i];
            assert!(e.ci_low <= e.value && e.value <= e.ci_high, "{i}: {e:?}");
            if e.ci_low <= t[i] && t[i] <= e.ci_high {
                hits[i] += 1;
            }
        }
    }
    let cov = hits.map(|x| x as f64 / datasets as f64);
    eprintln!("coverage {cov:?}, truth {t:?}, limit {limit:?}");
    cov
}

fn assert_coverage(name: &str, cov: [f64; 3]) {
    for (what, c) in ["success rate", "behaviour entropy", "conditional entropy"]
        .iter()
        .zip(cov)
    {
        assert!(
            c >= 0.90,
            "{name}: the 95 % interval of the {what} covers the true value in only {:.1} % of datasets ({cov:?})",
            100.0 * c
        );
    }
}

#[test]
fn intervals_cover_the_truth_aligning_like() {
    // 60 states × 8 rollouts, 2 behaviours, states vary in success and mix.
    let kinds = [
        Kind {
            success: 0.9,
            behaviours: vec![0.8, 0.2],
        },
        Kind {
            success: 0.6,
            behaviours: vec![0.65, 0.35],
        },
        Kind {
            success: 0.75,
            behaviours: vec![0.3, 0.7],
        },
    ];
    let task = TaskId::Aligning;
    assert_coverage("aligning-like", coverage(&kinds, task, 60, 8, 300));
}

#[test]
fn intervals_cover_the_truth_pushing_like() {
    // 30 states × 16 rollouts, 4 behaviours (log 4).
    let kinds = [
        Kind {
            success: 0.8,
            behaviours: vec![0.4, 0.3, 0.2, 0.1],
        },
        Kind {
            success: 0.5,
            behaviours: vec![0.1, 0.2, 0.3, 0.4],
        },
    ];
    let task = TaskId::Pushing;
    assert_coverage("pushing-like", coverage(&kinds, task, 30, 16, 300));
}

#[test]
fn intervals_cover_the_truth_sorting_like_dropping_empty_states() {
    // 60 states × 18 rollouts, 6 behaviours, low success (states without one
    // are dropped from the conditional entropy).
    let kinds = [
        Kind {
            success: 0.4,
            behaviours: vec![0.5, 0.2, 0.1, 0.1, 0.05, 0.05],
        },
        Kind {
            success: 0.7,
            behaviours: vec![0.2, 0.2, 0.2, 0.2, 0.1, 0.1],
        },
    ];
    let task = TaskId::Sorting4;
    let conv = EntropyConvention::for_task(task);
    assert_eq!(conv.n_behaviours, 6);
    assert_coverage("sorting-like", coverage(&kinds, task, 60, 18, 300));
}

#[test]
fn intervals_cover_the_truth_avoiding_like_single_start() {
    // One start, 480 rollouts, 24 possible codes of which 8 occur.
    let kinds = [Kind {
        success: 0.85,
        behaviours: vec![0.3, 0.2, 0.15, 0.1, 0.1, 0.05, 0.05, 0.05],
    }];
    let task = TaskId::Avoiding;
    assert_coverage("avoiding-like", coverage(&kinds, task, 1, 480, 300));
}

#[test]
fn the_interval_always_contains_the_estimate() {
    // Avoiding's quick protocol as `d3il eval` ran it: one start, 8 rollouts,
    // 8 different paths → H = ln 8 / ln 24 = 0.654; the old percentile
    // interval was 0.340–0.600.
    let v: Vec<Outcome> = (0..8)
        .map(|i| Outcome::new(0, true, Some(&format!("{}", 10 + i))))
        .collect();
    let ev = evaluate(TaskId::Avoiding, &v, 0.0, &Bootstrap::default()).unwrap();
    let c = ev.metrics.conditional_entropy;
    assert!((c.value - 8f64.ln() / 24f64.ln()).abs() < 1e-12);
    assert!(c.ci_low <= c.value && c.value <= c.ci_high, "{c:?}");
    assert!(c.ci_low < c.value, "a real interval, not a point: {c:?}");
    // Aligning's quick protocol as `d3il eval` ran `scripted:aligning:both`:
    // 3 starts × 2 rollouts, each start one of each behaviour → conditional
    // entropy 1; the bias-corrected upper end was 1.492 before the clip.
    let v: Vec<Outcome> = (0..6)
        .map(|i| Outcome::new(i / 2, true, Some(&format!("{}", i % 2))))
        .collect();
    let ev = evaluate(TaskId::Aligning, &v, 0.0, &Bootstrap::default()).unwrap();
    let c = ev.metrics.conditional_entropy;
    assert!(c.ci_low <= c.value && c.ci_high <= 1.0, "{c:?}");
    // Many small and odd shapes, every task and statistic.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for task in TaskId::ALL {
        for &(n_ctx, per_ctx) in &[(1, 8), (3, 2), (5, 4), (60, 8), (2, 1)] {
            for _ in 0..5 {
                let nb = task.n_behaviours();
                let data: Vec<Outcome> = (0..n_ctx * per_ctx)
                    .map(|i| {
                        let label = if task == TaskId::Stacking {
                            ["", "r", "rg", "rgb", "gbr", "b"][rng.random_range(0..6u64) as usize]
                                .to_string()
                        } else {
                            rng.random_range(0..nb as u64).to_string()
                        };
                        Outcome::new(i / per_ctx, rng.random_bool(0.6), Some(&label))
                    })
                    .collect();
                let ev = evaluate(task, &data, 0.0, &Bootstrap::default()).unwrap();
                let m = &ev.metrics;
                let mut all = vec![m.success_rate, m.behaviour_entropy, m.conditional_entropy];
                for l in m.stacking_levels.iter().flatten() {
                    all.extend([l.success_rate, l.behaviour_entropy, l.conditional_entropy]);
                }
                for e in all {
                    assert!(
                        e.ci_low <= e.value && e.value <= e.ci_high,
                        "{task} {n_ctx}x{per_ctx}: {e:?}"
                    );
                    // Rates and normalised entropies never leave [0, 1]
                    // (Aligning's quick protocol once printed 0.492-1.492).
                    assert!(
                        e.ci_low >= 0.0 && e.ci_high <= 1f64.max(e.value),
                        "{task} {n_ctx}x{per_ctx}: interval outside [0, 1]: {e:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn the_bootstrap_statistics_match_the_reference_formulas() {
    // The bootstrap's allocation-free tally gives the same numbers as the
    // public functions on the same data (no resampling: every state once).
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let kinds = [Kind {
        success: 0.6,
        behaviours: vec![0.5, 0.3, 0.2],
    }];
    let data = simulate(&mut rng, &kinds, 12, 5);
    for task in [TaskId::Aligning, TaskId::Sorting6, TaskId::Avoiding] {
        let conv = EntropyConvention::for_task(task);
        let c = Compact::new(&data);
        let mut t = Tally::new(c.n_labels);
        for g in &c.groups {
            t.add_context(g.iter().copied(), &conv);
        }
        let s = t.stats(&conv);
        assert_eq!(s[0], success_rate(&data));
        assert_eq!(s[1], behaviour_entropy(&data, conv.n_behaviours).unwrap());
        assert_eq!(s[2], conditional_entropy(&data, &conv).unwrap());
    }
}

fn summaries(data: &[Outcome], conv: &EntropyConvention) -> Vec<ContextSummary> {
    per_context(data, conv)
        .unwrap()
        .iter()
        .map(ContextSummary::from_result)
        .collect()
}

/// A pair of results on the same 60 states: state i has its own success
/// probability p_i (shared, so the pair is correlated), A succeeds with
/// p_i + gap/2 and B with p_i − gap/2.
fn pair(
    rng: &mut ChaCha8Rng,
    gap: f64,
    n_ctx: usize,
    per_ctx: usize,
) -> (Vec<Outcome>, Vec<Outcome>) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for c in 0..n_ctx {
        let p: f64 = rng.random_range(0.3..0.7);
        let mix = [rng.random_range(0.2..0.8), 0.0];
        let mix = [mix[0], 1.0 - mix[0]];
        for _ in 0..per_ctx {
            let la = draw(rng, &mix).to_string();
            let lb = draw(rng, &mix).to_string();
            a.push(Outcome::new(c, rng.random_bool(p + gap / 2.0), Some(&la)));
            b.push(Outcome::new(c, rng.random_bool(p - gap / 2.0), Some(&lb)));
        }
    }
    (a, b)
}

#[test]
fn identical_results_differ_by_zero_with_p_one() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (a, _) = pair(&mut rng, 0.0, 60, 8);
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let s = summaries(&a, &conv);
    let [sr, ce] = compare_states(&s, &s, 8, conv.empty_contexts, &Bootstrap::default()).unwrap();
    for d in [sr, ce] {
        assert_eq!(d.difference.value, 0.0);
        assert_eq!((d.difference.ci_low, d.difference.ci_high), (0.0, 0.0));
        assert_eq!(d.p_value, 1.0);
        assert_eq!(d.a, d.b);
    }
    assert!((sr.a - success_rate(&a)).abs() < 1e-12);
    assert!((ce.a - conditional_entropy(&a, &conv).unwrap()).abs() < 1e-12);
}

#[test]
fn a_success_gap_of_0_2_on_60_states_is_detected() {
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (a, b) = pair(&mut rng, 0.2, 60, 8);
    let cfg = Bootstrap {
        resamples: 2000,
        ..Bootstrap::default()
    };
    let [sr, _] = compare_states(
        &summaries(&a, &conv),
        &summaries(&b, &conv),
        8,
        conv.empty_contexts,
        &cfg,
    )
    .unwrap();
    assert!(sr.p_value < 0.01, "{sr:?}");
    assert!((sr.difference.value - 0.2).abs() < 0.08, "{sr:?}");
    assert!(sr.difference.ci_low > 0.0 && sr.difference.ci_low <= sr.difference.value);
    // The protocol's size detects 0.2 with room to spare.
    assert!(
        sr.min_detectable > 0.02 && sr.min_detectable < 0.2,
        "{sr:?}"
    );
}

#[test]
fn with_no_true_gap_the_test_rejects_at_its_nominal_rate() {
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let pairs = 400;
    let mut rejected = [0usize; 2];
    let mut covered = 0usize;
    for i in 0..pairs {
        let (a, b) = pair(&mut rng, 0.0, 60, 8);
        let cfg = Bootstrap {
            resamples: 400,
            confidence: 0.95,
            seed: i,
        };
        let d = compare_states(
            &summaries(&a, &conv),
            &summaries(&b, &conv),
            8,
            conv.empty_contexts,
            &cfg,
        )
        .unwrap();
        for k in 0..2 {
            if d[k].p_value < 0.05 {
                rejected[k] += 1;
            }
        }
        let e = d[0].difference;
        if e.ci_low <= 0.0 && 0.0 <= e.ci_high {
            covered += 1;
        }
    }
    eprintln!("rejected {rejected:?} of {pairs}, interval covered 0 in {covered}");
    for (k, r) in rejected.iter().enumerate() {
        let rate = *r as f64 / pairs as f64;
        // Nominal 5 %; 400 pairs give a standard error of 1.1 %.
        assert!(
            (0.02..=0.085).contains(&rate),
            "metric {k}: rejected {rate}"
        );
    }
    assert!(covered as f64 / pairs as f64 >= 0.9, "{covered}");
}

#[test]
fn normal_quantiles() {
    assert!((normal_quantile(0.975) - 1.959963984540054).abs() < 1e-8);
    assert!((normal_quantile(0.8) - 0.8416212335729143).abs() < 1e-8);
    assert!((normal_quantile(0.01) + 2.326347874040841).abs() < 1e-8);
    assert_eq!(normal_quantile(0.5), 0.0);
}
